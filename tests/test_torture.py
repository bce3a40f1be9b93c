"""The self-collision torture scenes' harness (csb.studies.torture): its checker finds crossings
where there are some and none where there are none, the control scenes without self-collision
do pass through themselves, stepping one sub-step a call is the scenes' own stepping, and a run
is deterministic. Whether self-collision keeps each scene free of crossings is asserted too,
as an expected failure where today's proximity self-collision does not (validation/torture.py
measures the full-size scenes)."""

from __future__ import annotations

import numpy as np
import pytest

import csb
from csb.studies import collisions as cs
from csb.studies import torture as T

ipctk = pytest.importorskip("ipctk", reason="the IPC Toolkit (pip install 'csb[test]') is the torture scenes' checker")


def crossed_sheets() -> csb.Model:
    """Two 6 x 6 sheets of 1 m in one mesh, one in the x-z plane, one in the x-y plane through
    it: every edge of the vertical sheet that spans y = 0 crosses a triangle of the flat one."""
    a, b = csb.cloth_grid(1.0, 1.0, 6, 6, "xz"), csb.cloth_grid(1.0, 1.0, 6, 6, "xy", [0.0, 0.05, 0.013])
    v = np.concatenate([np.asarray(a.vertices), np.asarray(b.vertices)])
    t = np.concatenate([np.asarray(a.triangles), np.asarray(b.triangles) + 36])
    builder = csb.ModelBuilder()
    builder.add_mesh(csb.Mesh(v, t, name="crossed"), mass=0.1)
    return builder.build()


def test_the_checker_finds_crossings_and_counts_them_as_self_intersections():
    """The crossed sheets: ipctk says yes and the count is csb's self_intersections' (a row of
    the vertical sheet's 6 edges that span the flat one's plane, plus its diagonals there: > 5).
    A flat cloth: no, and 0."""
    model = crossed_sheets()
    checker = T.IntersectionChecker(model)
    x = np.asarray(model.initial_state().x)
    assert checker.any(x) and checker.count(x) == checker.count_by_grid(x) > 5
    flat = csb.ModelBuilder()
    flat.add_mesh(csb.cloth_grid(1.0, 1.0, 12, 12), mass=0.1)
    flat_model = flat.build()
    flat_checker = T.IntersectionChecker(flat_model)
    y = np.asarray(flat_model.initial_state().x)
    assert not flat_checker.any(y) and flat_checker.count(y) == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_count_by_ipc_toolkits_broad_phase_is_the_grids(seed):
    """The checker's count takes its pairs from ipctk's hash grid: on crumpled 12 x 12 cloths
    (hundreds of crossings) it is self_intersections' count, and ipctk's verdict agrees."""
    rng = np.random.default_rng(seed)
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 12, 12), mass=0.1)
    model = b.build()
    checker = T.IntersectionChecker(model)
    x = np.asarray(model.initial_state().x) + rng.uniform(-0.27, 0.27, (144, 3))
    n = checker.count(x)
    assert n == checker.count_by_grid(x) > 100 and checker.any(x)


@pytest.fixture(scope="module")
def stack_run():
    scene = T.build("stack", quick=True)
    return scene, T.run(scene, self_collision=False, check="frame")


def test_without_self_collision_the_stacked_layers_pass_through_each_other(stack_run):
    """The control: 4 layers of 10 x 10 dropped on the ground without self-collision intersect
    for ipctk at the end of most frames after the first landing (0.14 s): they fall into one
    another and lie in one plane, the ground contact's height, so that ipctk's conservative test
    (a triangle in another's plane counts) says yes while no edge properly crosses a triangle,
    and csb's count, which the grid's matches, is 0."""
    scene, r = stack_run
    assert r["checked"] == scene.frames and r["intersecting"] > scene.frames // 2
    checker = T.IntersectionChecker(scene.control)
    assert checker.any(r["final"]) and checker.count(r["final"]) == checker.count_by_grid(r["final"])


def test_without_self_collision_the_twisted_band_passes_through_itself():
    """The control of the quick twist (16 x 16, 1.5 s): edges properly cross triangles at the end
    of some frames once the band has turned onto itself (measured: 9 of 90 frames, up to 52 pairs,
    from 1.37 s), not in the first second (by then the edges have turned 2π/3 against each other)."""
    r = T.run(T.build("twist", quick=True), self_collision=False, check="frame")
    assert r["crossing"] > 0 and r["max_crossings"] > 0 and r["first_intersection"] > 1.0


def test_stepping_one_sub_step_a_call_is_the_scenes_own_stepping():
    """run() steps a PbdStepper of substeps=1 and dt = h: after 0.25 s the soft drape (no grabs)
    is where cloth_sphere's own stepper of 30 sub-steps a frame puts it, to the bit, and a scene
    with grabs whose hands move on a straight line at constant speed (the funnel's centre) too,
    within round-off of the hand's position (the stepper interpolates it over a frame: 1e-15 m
    is a few ulps of 0.2 m)."""
    scene = T.soft_drape(seconds=0.25)
    r = T.run(scene, check="none")
    state = scene.model.initial_state()
    settings = dict(scene.settings)
    stepper = csb.PbdStepper(dt=T.FRAME, substeps=scene.substeps, **settings)
    stepper.step(scene.model, state, scene.frames)
    assert np.array_equal(r["final"], np.asarray(state.x))

    funnel = T.funnel(n=10, seconds=0.25)
    r = T.run(funnel, check="none")
    state = funnel.model.initial_state()
    stepper = csb.PbdStepper(dt=T.FRAME, substeps=funnel.substeps, gravity=T.G, **funnel.settings)
    handle = stepper.grab(funnel.model, state, int(funnel.held[0]), funnel.hands(0.0)[0])
    for f in range(funnel.frames):
        stepper.move_grab(handle, funnel.hands((f + 1) * T.FRAME)[0])
        stepper.step(funnel.model, state)
    assert np.abs(r["final"] - np.asarray(state.x)).max() < 1e-12


def test_a_run_is_deterministic():
    """Two runs of the quick twist: the same positions to the bit and the same figures."""
    a, b = (T.run(T.twist(n=10, seconds=0.5)) for _ in range(2))
    assert a["final"].tobytes() == b["final"].tobytes()
    for key in ("checked", "intersecting", "max_crossings", "first_intersection", "max_penetration", "failsafe"):
        assert a[key] == b[key]
    assert a["checked"] == a["substeps"] == 30 * 20


def test_the_figures_measure_what_they_say():
    """measure() on a small twist: every sub-step checked with self-collision, every frame
    without; the cost ratio is the two medians' ratio; no fail-safe counted where the stepper
    reports none."""
    scene = T.twist(n=10, seconds=0.25)
    r = T.measure(scene)
    assert r["checked"] == scene.frames * scene.substeps and r["control_checked"] == scene.frames
    assert r["cost_ratio"] == r["frame_cost"] / r["control_frame_cost"]
    assert len(r["frame_seconds"]) == scene.frames and r["frame_cost"] > 0
    if "self_failsafe" not in csb.PbdStepper(dt=T.FRAME).contacts():
        assert r["failsafe"] == 0
    row = T.row(r)
    assert list(row) == list(T.COLUMNS) and "| twist |" in T.markdown([row])


def test_an_unknown_scene_is_refused_by_name():
    with pytest.raises(csb.ParameterError, match="no torture scene 'spin'"):
        T.build("spin")


@pytest.mark.parametrize("name", T.SCENES)
def test_self_collision_keeps_the_scene_free_of_crossings(name):
    """Every sub-step of the quick tier of each scene, checked by the IPC Toolkit: no edge crosses a
    triangle, exactly 0. Proximity point-triangle contacts alone (Müller 2007 §4.4) did not keep
    three of them so (python -m csb.studies.torture --quick): the twist crossed itself at 75 of
    1800 sub-steps (from 1.41 s), the stack at 973 of 1200 (once the layers landed), the sequential
    soft drape at 520 of 1350 (the hem's whip). The continuous point-triangle and edge-edge test
    after the sweeps, with its fail-safe, allows no new crossing in a sub-step."""
    r = T.run(T.build(name, quick=True))
    assert r["checked"] == r["substeps"] and r["intersecting"] == 0


def test_the_study_script_writes_its_table(tmp_path):
    """validation/torture.py on a quarter of a second of the quick twist: the JSON, Markdown and
    CSV tables and the chart."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "validation" / "torture.py"
    r = subprocess.run([sys.executable, str(script), "--out", str(tmp_path), "--quick", "--no-video", "--seconds", "0.25",
                        "twist"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    data = json.loads((tmp_path / "torture.json").read_text())
    assert [s["scene"] for s in data["scenes"]] == ["twist"] and data["scenes"][0]["checked"] == 15 * 20
    assert "| twist | 256 | 300 |" in (tmp_path / "torture.md").read_text()
    assert (tmp_path / "torture.csv").exists() and (tmp_path / "torture_crossings.png").read_bytes()[:4] == b"\x89PNG"
