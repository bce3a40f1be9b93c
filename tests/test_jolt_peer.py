"""Jolt Physics as a side of `csb bench --peers`: a jolt_cloth program built against the user's own
Jolt tree (scripts/jolt_cloth.py; csb never builds, ships or downloads Jolt, and neither do these
tests). Without one, the side is skipped and says how to build it; with one in CSB_JOLT_CLOTH, it
builds csb's cloth, counts it as csb does and the cloth falls as it should."""

from __future__ import annotations

import os

import numpy as np
import pytest

from csb.bench import peers
from csb.bench.peers import CsbSide, JoltSide, check_cloth, cloth_arrays

HINT = "python scripts/jolt_cloth.py --jolt <Jolt tree> --build <dir>"


def test_without_a_jolt_cloth_the_side_is_skipped_saying_how_to_build_it(monkeypatch, tmp_path):
    monkeypatch.delenv(peers.JOLT_ENV, raising=False)
    runs, skipped = peers.plan_runs(["csb", "jolt"], [1], newton_cold=False)
    assert [r.label for r in runs] == ["csb"]
    assert skipped == [f"jolt: no jolt_cloth given (--jolt PATH or CSB_JOLT_CLOTH); build it with: {HINT}; skipped"]
    assert not peers.peer_available("jolt")
    # a path that is not a program is named
    not_a_program = tmp_path / "jolt_cloth"
    not_a_program.write_text("")
    runs, skipped = peers.plan_runs(["jolt"], [1], newton_cold=False, jolt=str(not_a_program))
    assert runs == [] and skipped[0].startswith(f"jolt: jolt_cloth '{not_a_program}' is not an executable file")
    with pytest.raises(FileNotFoundError, match="no jolt_cloth given"):
        JoltSide(cloth_arrays(4), 10, 1)


def test_a_given_jolt_cloth_runs_with_one_and_two_threads(monkeypatch, tmp_path):
    exe = tmp_path / "jolt_cloth"
    exe.write_text("#!/bin/sh\n")
    exe.chmod(0o755)
    monkeypatch.setenv(peers.JOLT_ENV, "/nowhere/jolt_cloth")  # --jolt wins over the environment
    runs, skipped = peers.plan_runs(["jolt"], [1], newton_cold=False, jolt=str(exe))
    assert skipped == [] and [r.label for r in runs] == ["jolt 1T", "jolt 2T"]
    assert [r.env for r in runs] == [{peers.JOLT_ENV: str(exe), peers.JOLT_THREADS_ENV: t} for t in ("1", "2")]


def test_jolt_has_no_one_substep_of_ten_iterations(capsys):
    # refused before any program is looked for: never run as 10 sub-steps instead
    with pytest.raises(ValueError, match="Jolt has no 1 x 10 case: each Jolt iteration is a whole XPBD sub-step"):
        JoltSide(cloth_arrays(4), 1, 10, binary="/nowhere/jolt_cloth")
    # in a row, the driver skips it with that reason and starts no process
    run = peers.Run("jolt 1T", "jolt", {peers.JOLT_ENV: "/nowhere/jolt_cloth", peers.JOLT_THREADS_ENV: "1"})
    peers.run_row([run], 8, (1, 10), frames=2, rounds=1, warmup=1, min_time=0.0, passes=1)
    assert run.result is None and run.error is None and run.skipped == [(8, (1, 10), peers.jolt_case_reason(1, 10))]
    assert peers.format_notes([run]) == ("jolt 1T: skipped 8x8 1x10: Jolt has no 1 x 10 case: each Jolt iteration "
                                         "is a whole XPBD sub-step, so it cannot project 10 times within one")


# ---------------------------------------------------------------------------------------------
# With a built jolt_cloth (CSB_JOLT_CLOTH=/tmp/jolt-build/jolt_cloth, say)

needs_jolt = pytest.mark.skipif(peers.jolt_binary()[0] is None,
                                reason=f"no jolt_cloth in CSB_JOLT_CLOTH (build one with {HINT})")


@pytest.fixture(scope="module")
def arrays():
    return cloth_arrays(32)


@needs_jolt
@pytest.mark.parametrize("threads", [1, 2])
def test_jolt_builds_csbs_cloth_and_it_falls(arrays, threads):
    side = JoltSide(arrays, 10, 1, threads=threads)
    try:
        assert side.counts == CsbSide(arrays, 10, 1).counts
        v = side.verified
        assert (v["substeps"], v["iterations"], v["threads"]) == (10, 1, threads)
        assert v["constraints_identical"] and v["other_constraints"] == 0 and v["linear_damping"] == 0
        assert v["dt"] == pytest.approx(1 / 60) and v["gravity_y"] == pytest.approx(-9.81)
        side.frames(3)
        check = check_cloth(arrays, side.positions(), 3)
        assert check["ok"], check
        # back to rest (Jolt keeps float32 positions)
        side.reset()
        assert np.allclose(side.positions(), arrays["positions"], atol=1e-6)
        # the same 3 frames from rest again: the same cloth
        side.frames(3)
        assert check_cloth(arrays, side.positions(), 3) == check
    finally:
        side.close()
    assert side.proc.returncode == 0


@needs_jolt
def test_jolt_takes_its_turns_in_a_row_of_the_driver():
    exe = peers.jolt_binary()[0]
    csb = peers.Run("csb", "csb", {"OMP_NUM_THREADS": "1"})
    jolt = peers.Run("jolt 2T", "jolt", {peers.JOLT_ENV: exe, peers.JOLT_THREADS_ENV: "2"})
    peers.run_row([csb, jolt], 16, (10, 1), frames=2, rounds=2, warmup=1, min_time=0.02, passes=2)
    assert jolt.error is None, jolt.error
    row, ref = jolt.result["rows"][0], csb.result["rows"][0]
    assert row["counts"] == ref["counts"] and row["check"]["ok"] and row["rounds"] >= 2
    assert jolt.result["versions"]["jolt"].split()[0].count(".") == 2  # "5.5.0 (avx512)"
    assert "jolt 2T" in peers.format_peer_table([csb, jolt])
