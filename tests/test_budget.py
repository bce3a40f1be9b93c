"""Requests whose memory is clearly beyond the machine are refused with the estimate, before
anything is allocated (src/csb/memory_budget.hpp: 1000 B a particle, about what cloths of 512 x 512
and 1024 x 1024 particles peaked at while being built)."""

from __future__ import annotations

import pytest

import csb


@pytest.mark.parametrize("make, what", [
    (lambda: csb.cloth_grid(1.0, 1.0, 100_000, 100_000), r"cloth_grid\(100000, 100000\): 1e\+10 particles"),
    (lambda: csb.chain(100_000_000, 0.01), r"chain\(100000000\): 1e\+08 particles"),
    (lambda: csb.tet_box((1.0, 1.0, 1.0), (1000, 1000, 1000)), r"tet_box\(1000, 1000, 1000\): 1\.003e\+09 particles"),
])
def test_a_shape_beyond_the_machine_is_refused_with_the_estimate(make, what):
    with pytest.raises(csb.ParameterError, match=what + r" would need about [\d.e+]+ GB .* this machine's [\d.]+ GB"):
        make()


def test_a_scene_asking_for_a_chain_of_1e8_links_is_refused(tmp_path):
    scene = tmp_path / "long.toml"
    scene.write_text(csb.find_scene("chain").read_text().replace("links = 20", "links = 100000000"))
    with pytest.raises(csb.Error, match=r"1e\+08 particles would need about 100 GB"):
        csb.load_scene(scene).build()


def test_shapes_that_fit_are_built():
    assert csb.cloth_grid(1.0, 1.0, 64, 64).vertices.shape == (4096, 3)
    assert csb.chain(1000, 0.01).vertices.shape == (1001, 3)


def cloth_64():
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 64, 64), density=0.2, stretch_stiffness=1.0)
    return b.build()


def test_steps_beyond_a_year_of_work_are_refused_with_the_estimate_before_stepping():
    """memory_budget.hpp: at most 1e9 projections and particle updates a second on any machine."""
    model = cloth_64()
    state = model.initial_state()
    stepper = csb.PbdStepper()
    # 12 033 constraints x 10 iterations + 4 096 particles a step: 1.24e17 for 1e12 steps
    assert stepper.operations(model, 1) == 10 * model.num_constraints + model.num_particles == 124_426
    with pytest.raises(csb.ParameterError, match=r"steps = 1000000000000: 1\.24426e\+17 constraint projections and "
                       r"particle updates would take at least 3\.94282 years"):
        stepper.step(model, state, 10**12)
    assert state.step == 0
    # Within a year's work is accepted (and Ctrl-C stops it): 1e9 steps of this cloth is 1.4 days at that rate.
    assert stepper.operations(model, 10**9) / 1e9 < 365.25 * 86400


def test_a_scene_lasting_beyond_a_year_of_work_is_refused(tmp_path):
    scene = tmp_path / "forever.toml"
    scene.write_text(csb.find_scene("cloth_grid").read_text().replace("duration = 2.0", "duration = 1e12"))
    with pytest.raises(csb.SceneError, match=r"forever\.toml: duration 1e\+12 s = \d+ steps of [\d.]+ s: .* years"):
        csb.load_scene(scene).run()
