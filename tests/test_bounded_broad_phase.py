"""The self-collision broad phase stays bounded whatever the positions: a particle flung 3e5 m
or 1e12 m away (a sub-step once took 11 s and 1.5 GB, at 1e12 m the process ran out of memory)
costs bounded time and memory: the triangles it stretches across more than the cloth's size are
left out of self-collision and counted (contacts()["self_skipped"]); and a self-collision layer
thicker than the cloth is refused by name."""

from __future__ import annotations

import resource
import time

import pytest

import csb


def folded_cloth(thickness: float = 0.01) -> csb.Model:
    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, 24, 24, "xz", (0, 1, 0)), mass=0.2, stretch_stiffness=1.0,
                       bending_stiffness=0.1)
    b.enable_self_collision(cloth.group, thickness)
    b.pin(cloth.nearest([-0.5, 1, -0.5]))
    return b.build()


@pytest.mark.parametrize("far", [3e5, 1e12])
def test_a_particle_flung_far_away_costs_bounded_time_and_memory(far):
    model = folded_cloth()
    state = model.initial_state()
    state.x[100] = (far, far, far)
    stepper = csb.PbdStepper(dt=1 / 60, substeps=2, iterations=2, max_speed=float("inf"))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB
    t0 = time.process_time()
    stepper.step(model, state, 3)
    assert time.process_time() - t0 < 5.0
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss < 200_000  # < 200 MB more at the peak
    assert stepper.contacts()["self_skipped"] > 0


def test_a_self_collision_layer_thicker_than_the_cloth_is_refused():
    model = folded_cloth(thickness=50.0)
    with pytest.raises(csb.ParameterError, match=r"self-collision thickness 50 m of group '.*' exceeds the size "
                                                 r"of its cloth \(1\.41\d* m"):
        csb.PbdStepper().step(model, model.initial_state(), 1)


def test_a_thickness_above_the_triangles_altitude_is_warned_of():
    """A 1 m cloth of 32 x 32 vertices (31 cells a side) has right triangles whose smallest
    altitude is 1/31/sqrt(2) = 22.8 mm: a thickness of 25 mm puts particles within the contact distance of
    their flat neighbours and is warned of once (csb.AccuracyWarning, naming the altitude); 10 mm
    is not."""
    import warnings

    for thickness, warned in ((0.025, True), (0.010, False)):
        b = csb.ModelBuilder()
        inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, 32, 32), mass=0.2)
        b.pin(inst.first_particle)
        b.enable_self_collision(inst.group, thickness)
        model = b.build()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            csb.PbdStepper().step(model, model.initial_state(), 2)
        notes = [str(w.message) for w in caught if issubclass(w.category, csb.AccuracyWarning)]
        assert (len(notes) == 1) == warned, notes
        if warned:
            assert "smallest rest altitude of its triangles, 0.0228099 m" in notes[0]
