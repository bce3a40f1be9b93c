"""MuJoCo's flex as a side of `csb bench --peers`: a different method (force-based springs stepped
by MuJoCo's semi-implicit Euler, not PBD), at its own stable sub-steps, on csb's cloth. Without
mujoco (the optional `bench` extra) the side is skipped and says how to install it; with it, the
side builds csb's cloth, counts it as csb does, is served through the driver's own path and is
reported as a different method with its stability."""

from __future__ import annotations

import importlib.util
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from csb.bench import peers
from csb.bench.peers import CsbSide, MujocoSide, check_cloth, cloth_arrays

METHOD = "MuJoCo flex (springs, Euler), a different method"
N = 8  # 64 particles, 161 distance pairs, 133 bending quadruples: 28 sub-steps a frame


@pytest.fixture(scope="module")
def arrays():
    return cloth_arrays(N)


def test_without_mujoco_the_side_is_skipped_and_says_how_to_install_it(monkeypatch, arrays):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # as if it were not installed
    assert not peers.peer_available("mujoco")
    runs, skipped = peers.plan_runs(["csb", "mujoco"], [1], newton_cold=False)
    assert [r.label for r in runs] == ["csb"]
    assert skipped == ["mujoco: not installed (pip install 'csb[bench]'), skipped"]
    with pytest.raises(ImportError, match=r"the peer 'mujoco' is not installed: it is part of csb's optional "
                                          r"'bench' extra \(pip install 'csb\[bench\]'\)"):
        MujocoSide(arrays, 10, 1)


def test_mujoco_is_in_the_optional_bench_extra_only():
    project = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]
    assert any(p.startswith("mujoco") for p in project["optional-dependencies"]["bench"])
    assert not any(p.startswith("mujoco") for p in project["dependencies"])


def test_mujoco_is_timed_in_the_rows_of_one_iteration_only():
    run = peers.Run("mujoco", "mujoco")
    peers.run_row([run], N, (1, 10), frames=2, rounds=1, warmup=1, min_time=0.0, passes=1)
    assert run.result is None and run.error is None
    assert run.skipped == [(N, (1, 10), peers.case_reason("mujoco", (1, 10)))]
    assert peers.format_notes([run]).startswith(f"mujoco: skipped 8x8 1x10: {METHOD}: force-based, no iterations")
    assert peers.case_reason("mujoco", (10, 1)) is None


def test_the_edges_take_csbs_compliance_when_finite_and_a_stated_stiffness_when_hard(arrays):
    k, why = peers.mujoco_edge_stiffness(arrays)
    assert arrays["stretch_compliance"] == 0 and k == peers.MUJOCO_EDGE_STIFFNESS == 3000.0
    assert why.startswith("csb's edges are hard (compliance 0) and a spring cannot be")
    k, why = peers.mujoco_edge_stiffness({**arrays, "stretch_compliance": 1e-3})
    assert k == pytest.approx(1e3) and why.startswith("1/α of csb's distance compliance")
    # the sub-steps follow the explicit limit, ω ~ √(k/m) with m ~ spacing²: ω grows as 1/spacing
    # (7 gaps a side at 8², 15 at 16²) and as √k
    assert peers.mujoco_substeps(arrays, 3000.0) == 28
    assert peers.mujoco_substeps(cloth_arrays(2 * N), 3000.0) == 60
    assert peers.mujoco_substeps(arrays, 4 * 3000.0) == 56


# ---------------------------------------------------------------------------------------------
# With mujoco installed

needs_mujoco = pytest.mark.skipif(importlib.util.find_spec("mujoco") is None,
                                  reason="mujoco (csb's optional 'bench' extra) is not installed")


@needs_mujoco
def test_mujoco_builds_csbs_cloth_and_it_falls_stably(arrays):
    side = MujocoSide(arrays, 10, 1)
    ref = CsbSide(arrays, 10, 1).counts
    assert {k: side.counts[k] for k in ("particles", "distance", "bending")} == \
        {k: ref[k] for k in ("particles", "distance", "bending")} == dict(particles=64, distance=161, bending=133)
    assert side.counts["constraints"] == 0 and side.counts["projections_per_frame"] is None  # springs, not constraints
    v = side.verified
    assert v["method"] == METHOD and v["integrator"] == "mjINT_EULER" and v["threads"] == 1 == side.threads_used()
    assert v["mujoco_substeps"] == 28 and v["dt"] == pytest.approx(1 / 60) and v["gravity_y"] == pytest.approx(-9.81)
    assert v["edge_stiffness"] == 3000.0 and v["edge_damping"] == 0 and v["hinge_stiffness"] == pytest.approx(1e-3)
    assert not v["contacts"]
    side.frames(3)
    check = check_cloth(arrays, side.positions(), 3)
    assert check["ok"], check
    assert side.stability(check) == dict(stable=True, finite=True, max_strain=check["max_strain"], strain_limit=0.1)
    side.reset()
    assert np.array_equal(side.positions(), arrays["positions"])
    side.frames(3)  # the same 3 frames from rest: the same cloth
    assert check_cloth(arrays, side.positions(), 3) == check


@needs_mujoco
def test_a_diverging_mujoco_step_is_said_not_hidden(arrays, monkeypatch):
    monkeypatch.setattr(peers, "MUJOCO_COURANT", 20.0)  # sub-steps far beyond the explicit limit
    side = MujocoSide(arrays, 10, 1)
    with pytest.raises(RuntimeError, match="MuJoCo's flex diverged at 4 sub-steps a frame"):
        side.frames(2)
    assert peers.stability_note(side.stability(dict(finite=True, max_strain=0.25))) == \
        "NOT stable: max strain 25.0 % >= 10 %"
    assert peers.stability_note(side.stability(dict(finite=False, max_strain=np.inf))) == "NOT stable: not finite"


@needs_mujoco
def test_mujoco_takes_its_turns_in_a_row_of_the_driver_as_a_different_method():
    csb = peers.Run("csb", "csb", {"OMP_NUM_THREADS": "1"})
    mujoco = peers.Run("mujoco", "mujoco")
    peers.run_row([csb, mujoco], N, (10, 1), frames=2, rounds=2, warmup=1, hold_frames=3, min_time=0.02, passes=2)
    assert mujoco.error is None, mujoco.error
    row, ref = mujoco.result["rows"][0], csb.result["rows"][0]
    assert row["method"] == METHOD and "method" not in ref
    assert all(row["counts"][k] == ref["counts"][k] for k in ("particles", "distance", "bending"))
    assert row["ms_per_frame"] > 0 and row["rounds"] >= 2 and set(row["threads"]) == {1}
    assert row["check"]["ok"] and row["check"]["stability"]["stable"] and row["hold"]["stability"]["stable"]
    assert mujoco.result["versions"]["mujoco"].count(".") == 2
    table = peers.format_peer_table([csb, mujoco])
    line = next(t for t in table.splitlines() if " mujoco " in t)
    assert f"{METHOD}: 28 sub-steps/frame, edges 3000 N/m; stable: max strain" in line and line.endswith("threads 1")
    notes = peers.format_notes([csb, mujoco])
    assert f"mujoco: {METHOD}, not equal work with csb" in notes and "8² 28 of 595.2 µs" in notes
    assert "stable: max strain" in peers.format_hold_table([csb, mujoco])
