"""A simulation that is going wrong says so before it reaches NaN: the stepper's divergence guard,
the element-quality warning when a mesh is added, and the run summary's checks of strain and
energy against what the scene's materials allow."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

import csb
from csb.runner import RunResult

G = 9.81


def runaway_cloth():
    """Summed Jacobi on a cloth: its iteration's spectral radius is about 2 (validation/stability.py),
    so the cloth grows geometrically from the first step."""
    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, 16, 16, "xz", (0, 1, 0)), mass=0.2, stretch_stiffness=1.0,
                       bending_stiffness=0.1)
    b.pin(cloth.nearest([-0.5, 1, -0.5]))
    b.pin(cloth.nearest([0.5, 1, -0.5]))
    return b.build()


def test_a_runaway_is_stopped_early_with_the_step_the_particle_and_the_speed():
    """Unguarded, this cloth reaches 1e24 m by step 5 and NaN at step 11; the guard stops it at step 3,
    when its fastest particle has just passed D/h + 2 (v0 + g t + sqrt(2 g D)) = 96 m/s."""
    model = runaway_cloth()
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=1 / 60, iterations=10, solver="jacobi-summed")
    with pytest.raises(csb.SimulationError) as err:
        stepper.step(model, state, 20)
    message = str(err.value)
    assert state.step <= 4 and np.all(np.isfinite(state.x)) and np.abs(state.x).max() < 1e9
    assert f"step {state.step} " in message and "diverging" in message and "particle " in message
    assert "m/s" in message and "divergence guard" in message and "rest length" in message
    speed = float(message.split(" moves at ")[1].split(" m/s")[0])
    limit = float(message.split("divergence guard's ")[1].split(" m/s")[0])
    size = math.sqrt(2.0)  # the cloth's diagonal, m
    expected = size * 60 + 2 * (G * state.t + math.sqrt(2 * G * size))
    assert limit == pytest.approx(expected, rel=1e-5) and speed > limit


def test_without_the_guard_the_same_run_ends_in_non_finite_positions():
    model = runaway_cloth()
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=1 / 60, iterations=10, solver="jacobi-summed", max_speed=math.inf)
    with pytest.raises(csb.SimulationError, match="non-finite"):
        stepper.step(model, state, 40)
    assert state.step > 5


def test_max_speed_sets_the_limit_by_name():
    b = csb.ModelBuilder()
    g = b.add_group("ball")
    b.add_particle([0, 0, 0], 1.0, g)
    model = b.build()
    for limit, trips in ((5.0, True), (20.0, False)):
        state = model.initial_state()
        state.v[0] = (10.0, 0.0, 0.0)
        stepper = csb.PbdStepper(dt=1 / 60, max_speed=limit)
        if trips:
            with pytest.raises(csb.SimulationError, match=r"particle 0 moves at 10\.\d* m/s.*\(max_speed\)"):
                stepper.step(model, state, 1)
        else:
            stepper.step(model, state, 1)
    with pytest.raises(csb.ParameterError, match="max_speed"):
        csb.PbdStepper(max_speed=-1.0)
    with pytest.raises(csb.ParameterError, match="max_speed"):
        csb.PbdStepper(max_speed=math.nan)


@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
def test_fast_but_stable_motion_does_not_trip_the_automatic_guard(method):
    """A particle thrown at 50 m/s and falling for 20 s (no size: its limit is 2 (v0 + g t)), and a
    chain pendulum released horizontally (its end swings at about sqrt(2 g L))."""
    b = csb.ModelBuilder()
    g = b.add_group("ball")
    b.add_particle([0, 0, 0], 1.0, g)
    ball = b.build()
    state = ball.initial_state()
    state.v[0] = (50.0, 0.0, 0.0)
    csb.PbdStepper(method=method, dt=1 / 60).step(ball, state, 1200)
    assert state.v[0, 1] == pytest.approx(-G * 20, rel=1e-9)
    b = csb.ModelBuilder()
    links = b.add_mesh(csb.chain(10, 0.1), mass=0.1, stretch_stiffness=1.0)
    b.pin(links.nearest([0, 0, 0]))
    chain = b.build()
    state = chain.initial_state()
    csb.PbdStepper(method=method, dt=1 / 60, substeps=4, iterations=20).step(chain, state, 300)
    assert np.abs(state.x[:, 1]).max() > 0.5  # it swung down


def test_a_scene_sets_the_guard_and_refuses_a_negative_one(tmp_path):
    from csb.scene import load_scene, find_scene

    text = find_scene("cloth_grid").read_text()
    good = tmp_path / "guarded.toml"
    good.write_text(text.replace('method = "pbd"', 'method = "pbd"\nmax_speed = inf'))
    assert math.isinf(load_scene(good).solver.max_speed)
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('method = "pbd"', 'method = "pbd"\nmax_speed = -3.0'))
    with pytest.raises(csb.SceneError, match="max_speed"):
        load_scene(bad)


def capped_cylinder(segments: int, rings: int = 4, radius: float = 0.1, height: float = 0.3) -> csb.Mesh:
    """A tube closed by two fans: each cap's centre has `segments` neighbours."""
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    v = [[radius * np.cos(t), y, radius * np.sin(t)] for y in np.linspace(0, height, rings) for t in a]
    tris = []
    for r in range(rings - 1):
        for k in range(segments):
            i0, i1 = r * segments + k, r * segments + (k + 1) % segments
            tris += [[i0, i0 + segments, i1], [i1, i0 + segments, i1 + segments]]
    bottom, top = len(v), len(v) + 1
    v += [[0, 0, 0], [0, height, 0]]
    for k in range(segments):
        tris += [[bottom, k, (k + 1) % segments], [top, (rings - 1) * segments + (k + 1) % segments,
                                                   (rings - 1) * segments + k]]
    return csb.Mesh(np.array(v, float), np.array(tris), name="can")


def test_adding_a_mesh_warns_of_high_valence_vertices_and_slivers():
    with pytest.warns(csb.MeshWarning, match=r"'can' has 2 vertex\(es\) with more than 32 neighbours.*vertex 256, 64"):
        csb.ModelBuilder().add_mesh(capped_cylinder(64), mass=0.5)
    sliver = csb.Mesh(np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.002, 0], [0.5, -0.5, 0]], float),
                      np.array([[0, 1, 2], [0, 3, 1]]), name="sliver")
    with pytest.warns(csb.MeshWarning, match=r"1 sliver triangle.*triangle 0, 500 times"):
        csb.ModelBuilder().add_mesh(sliver, mass=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        csb.ModelBuilder().add_mesh(csb.cloth_grid(1, 1, 8, 8, "xz", (0, 0, 0)), mass=0.1)
        csb.ModelBuilder().add_mesh(capped_cylinder(24), mass=0.5)


def test_the_run_summary_flags_strain_its_material_does_not_allow():
    """The bundled cloth_grid (PBD, hard edges, 1 x 10) stretches hundreds of per cent: flagged."""
    result = csb.load_scene(csb.find_scene("cloth_grid")).run(None)
    assert result.largest_strain > 1.0
    checks = result.checks()
    assert len(checks) == 1 and "largest strain" in checks[0] and "allow" in checks[0]
    assert "CHECK: the largest strain" in result.summary()


def test_the_energy_check_flags_a_gain_a_passive_scene_cannot_have():
    sim = csb.load_scene(csb.find_scene("pendulum")).build()
    rows = [{"t": 0.0, "mechanical_energy": 1.0, "max_strain": 0.0},
            {"t": 1.0, "mechanical_energy": 0.9, "max_strain": 0.0}]
    quiet = RunResult(sim, 2, 0.0, rows=list(rows))
    assert quiet.energy_growth == 0 and quiet.checks() == []
    mass = float(np.sum(sim.model.mass))
    rest = np.asarray(sim.model.rest_positions)
    scale = 0.01 * mass * G * float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0)))
    rows.append({"t": 2.0, "mechanical_energy": 1.0 + 2 * scale, "max_strain": 0.0})
    loud = RunResult(sim, 3, 0.0, rows=rows)
    assert loud.energy_growth == pytest.approx(2 * scale)
    assert any("energy rose" in c for c in loud.checks())
