"""The peer comparison (`csb bench --peers`) builds the same cloth on every side and
counts it correctly; its timings are printed, never asserted. The peers are the optional `bench`
extra: without it, their tests skip and the command says it skipped them."""

from __future__ import annotations

import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from csb.bench import peers as bench_peers
from csb.bench.peers import CsbSide, check_cloth, cloth_arrays, corrected_stiffness

N = 8  # 64 particles, 161 distance constraints (112 structural + 49 diagonal), 133 interior edges


@pytest.fixture(scope="module")
def arrays():
    return cloth_arrays(N)


def test_the_cloth_arrays_are_cloth_grid(arrays):
    assert arrays["positions"].shape == (64, 3) and arrays["triangles"].shape == (2 * 7 * 7, 3)
    assert len(arrays["pinned"]) == 2 and np.allclose(arrays["positions"][arrays["pinned"]][:, 2], -0.5)
    assert len(arrays["distance"]) == 2 * N * (N - 1) + (N - 1) ** 2 == 161
    assert len(arrays["bending"]) == 161 - 4 * (N - 1) == 133  # every edge but the 28 on the boundary
    assert np.isclose(arrays["mass"].sum(), 0.2)  # 0.2 kg/m² over 1 m²
    assert arrays["stretch_stiffness"] == 1.0 and arrays["bending_stiffness"] == 0.1
    assert corrected_stiffness(1.0, 10) == 1.0 and np.isclose(1 - (1 - corrected_stiffness(0.1, 10)) ** 10, 0.1)


def test_the_csb_side_counts_what_it_steps(arrays):
    side = CsbSide(arrays, 2, 3)
    assert side.counts == dict(particles=64, distance=161, bending=133, constraints=294,
                               projections_per_frame=2 * 3 * 294)
    assert side.verified["substeps"] == 2 and side.verified["iterations"] == 3
    side.frames(3)
    check = check_cloth(arrays, side.positions(), 3)
    assert check["ok"] and check["pin_moved"] == 0 and 0 < check["mean_drop"] <= check["free_fall"]
    side.reset()
    assert np.array_equal(side.positions(), arrays["positions"])


def test_the_check_catches_a_broken_cloth(arrays):
    x = arrays["positions"].copy()
    assert not check_cloth(arrays, x, 3)["ok"]  # did not fall
    x[:, 1] -= 0.01
    assert not check_cloth(arrays, x, 3)["ok"]  # the pins moved
    x[arrays["pinned"], 1] += 0.01
    assert check_cloth(arrays, x, 3)["ok"]
    x[5, 1] = np.nan
    assert not check_cloth(arrays, x, 3)["ok"]


class _SlowSide:
    """A side whose frame takes `ms` ms: counts its resets and frames, and logs its turns."""

    def __init__(self, ms=1.0, log=None, name=""):
        self.ms, self.log, self.name = ms, log, name
        self.resets = self.frames_stepped = 0

    def reset(self):
        self.resets += 1

    def frames(self, k):
        self.frames_stepped += k
        time.sleep(1e-3 * self.ms * k)

    def threads_used(self):
        return None


class _LoggedTurns(bench_peers.Turns):
    def turn(self, min_rounds, seconds, max_rounds):
        self.side.log.append(self.side.name)
        return super().turn(min_rounds, seconds, max_rounds)


class _FailingTurns:
    def __init__(self, after):
        self.after, self.turns = after, 0

    def turn(self, min_rounds, seconds, max_rounds):
        self.turns += 1
        if self.turns > self.after:
            raise bench_peers.WorkerFailed("exit -9: killed")
        return dict(times=[1.0] * min_rounds, threads=[None] * min_rounds)


def test_a_turn_warms_up_then_times_rounds_from_rest_for_at_least_its_time():
    side = _SlowSide()
    turn = bench_peers.Turns(side, frames=2, warmup=1).turn(min_rounds=3, seconds=0.1, max_rounds=2000)
    # rounds of ~2 ms: at least 0.1 s of them, so some 50 rounds, each from rest (a reset)
    assert 20 <= len(turn["times"]) <= 60 and len(turn["threads"]) == len(turn["times"])
    assert side.resets == len(turn["times"]) + 1 and side.frames_stepped == 1 + 2 * len(turn["times"])
    assert min(turn["times"]) >= 1.0
    # never fewer than `min_rounds`, never more than `max_rounds`
    assert len(bench_peers.Turns(_SlowSide(), 1, 0).turn(4, 0.0, 2000)["times"]) == 4
    assert len(bench_peers.Turns(_SlowSide(), 1, 0).turn(2, 10.0, 5)["times"]) == 5


def test_the_sides_of_a_row_take_turns_and_each_gets_its_rounds_and_time():
    log = []
    fast, slow = _SlowSide(1.0, log, "fast"), _SlowSide(4.0, log, "slow")
    got = bench_peers.alternate([_LoggedTurns(fast, 2, 1), _LoggedTurns(slow, 2, 1)], rounds=7, min_time=0.2,
                                passes=4, settle=0)
    assert log == ["fast", "slow"] * 4  # one turn each per pass, in turn
    for side, g in zip((fast, slow), got):
        # ceil(7 / 4) = 2 rounds and 0.05 s a turn at least: >= 8 rounds, >= 0.2 s of timed frames
        # (the timed frames add up to at most rounds x 2 frames x the slowest round's ms per frame)
        assert g["rounds"] >= 8 and g["rounds"] * 2 * g["ms_max"] * 1e-3 >= 0.2
        assert g["rounds"] <= 0.2 / (2 * side.ms * 1e-3) + 4  # and not much more: one round a turn over
        assert side.ms <= g["ms_min"] <= g["ms_per_frame"] <= g["ms_max"] and len(g["threads"]) == g["rounds"]
    assert got[0]["rounds"] > 2 * got[1]["rounds"]  # the same time in shorter rounds
    # at most ceil(max_rounds / passes) rounds a turn
    capped = bench_peers.alternate([bench_peers.Turns(_SlowSide(), 1, 0)], rounds=1, min_time=10, passes=3,
                                   max_rounds=7, settle=0)
    assert capped[0]["rounds"] == 9


def test_a_side_that_fails_midway_leaves_the_others_timed():
    good = _SlowSide(0.5, [], "good")
    bad = _FailingTurns(after=1)
    got = bench_peers.alternate([bench_peers.Turns(good, 1, 0), bad], rounds=3, min_time=0.0, passes=3, settle=0)
    assert got[1] == {"failed": "exit -9: killed"} and bad.turns == 2  # asked once more, then left out
    assert got[0]["rounds"] == 3


def test_a_side_process_answers_its_turns_and_checks_its_cloth():
    import io
    import json

    out = io.StringIO()
    assert bench_peers.serve("csb", 8, 10, 1, frames=2, warmup=1, stdin=io.StringIO("turn 2 0 5\nfinish 3\n"),
                             stdout=out) == 0
    lines = out.getvalue().splitlines()
    assert [line.split()[0] for line in lines] == ["CSB_PEERS_READY", "CSB_PEERS_TURN", "CSB_PEERS_DONE"]
    ready, turn, done = (json.loads(line.split(" ", 1)[1]) for line in lines)
    assert ready["counts"]["particles"] == 64 and ready["verified"]["substeps"] == 10
    assert len(turn["times"]) == 2 and turn["threads"] == [1, 1]
    assert done["check"]["ok"] and done["check"]["frames"] == 2 and done["hold"]["frames"] == 3
    with pytest.raises(ValueError, match="unknown command 'jump'"):
        bench_peers.serve("csb", 8, 10, 1, 2, 1, stdin=io.StringIO("jump\n"), stdout=io.StringIO())


def _same_fall_as_csb(arrays, side, frames=3):
    ref = CsbSide(arrays, side.verified["substeps"], side.verified["iterations"])
    ref.frames(frames)
    side.frames(frames)
    mine, theirs = check_cloth(arrays, side.positions(), frames), check_cloth(arrays, ref.positions(), frames)
    assert mine["ok"], mine
    return mine, theirs


@pytest.mark.parametrize("substeps, iterations", [(10, 1), (1, 10)])
def test_pypbd_builds_the_same_cloth_and_it_falls(arrays, substeps, iterations):
    pytest.importorskip("pypbd")
    side = bench_peers.PypbdSide(arrays, substeps, iterations)
    assert side.counts == CsbSide(arrays, substeps, iterations).counts
    assert side.verified["substeps"] == substeps and side.verified["iterations"] == iterations
    assert side.verified["velocity_iterations"] == 0 and side.verified["other_constraints"] == {}
    mine, theirs = _same_fall_as_csb(arrays, side)
    # the same PBD on the same cloth: the same fall to a few parts in a thousand
    assert mine["mean_drop"] == pytest.approx(theirs["mean_drop"], rel=5e-3)


@pytest.mark.parametrize("substeps, iterations", [(10, 1), (1, 10)])
def test_newton_builds_the_same_cloth_and_it_falls(arrays, substeps, iterations):
    pytest.importorskip("newton")
    pytest.importorskip("warp")
    side = bench_peers.NewtonSide(arrays, substeps, iterations, graph=True)
    assert side.counts == CsbSide(arrays, substeps, iterations).counts
    assert side.verified["iterations"] == iterations and side.verified["particle_max_radius"] == 0
    mine, theirs = _same_fall_as_csb(arrays, side)
    assert mine["mean_drop"] == pytest.approx(theirs["mean_drop"], rel=0.1)  # XPBD, softer springs
    # the replayed graph steps exactly as the launched kernels do
    launched = bench_peers.NewtonSide(arrays, substeps, iterations, graph=False)
    launched.frames(3)
    assert np.array_equal(launched.positions(), side.positions())


def test_a_missing_peer_is_skipped_and_said(monkeypatch):
    monkeypatch.setattr(bench_peers, "peer_available", lambda side: side == "csb")
    runs, skipped = bench_peers.plan_runs(["csb", "pypbd", "newton"], [1, 2], newton_cold=False)
    assert [r.label for r in runs] == ["csb"]
    assert skipped == ["pypbd: not installed (pip install 'csb[bench]'), skipped",
                       "newton: not installed (pip install 'csb[bench]'), skipped"]


def test_the_peers_are_an_optional_extra_only():
    project = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]
    extra = " ".join(project["optional-dependencies"]["bench"])
    assert all(p in extra for p in ("pypbd", "newton", "warp-lang"))
    assert not any(p in " ".join(project["dependencies"]) for p in ("pypbd", "newton", "warp"))


def test_bench_peers_command_prints_a_table():
    r = subprocess.run([sys.executable, "-m", "csb.cli", "bench", "--peers", "--sides", "csb", "--sizes", "8",
                        "--rounds", "2", "--peer-frames", "2", "--hold-frames", "4", "--peer-min-time", "0.05"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    rows = [line.split() for line in r.stdout.splitlines() if line.strip().startswith("8x8")]
    assert len(rows) == 4  # two timed cases, then the two untimed holds
    assert [row[:9] for row in rows[:2]] == [["8x8", "10", "x", "1", "csb", "64", "161", "133", "2940"],
                                             ["8x8", "1", "x", "10", "csb", "64", "161", "133", "2940"]]
    assert all("ok:" in row for row in rows)
    # csb's threads per timed round are printed: one, since an 8 x 8 cloth is a model of one part
    assert [row[-2:] for row in rows[:2]] == [["threads", "1"], ["threads", "1"]]
    assert "substeps and iterations read back from the peer as asked" in r.stdout
    assert "The sides of a row take turns, 10 each" in r.stdout and "filling at least 0.05 s" in r.stdout
    assert all(int(row[11]) >= 10 for row in rows[:2])  # the rounds column: one round a turn at least


@pytest.mark.parametrize("option, value, message", [
    ("--rounds", "0", "argument --rounds: must be at least 1, got 0"),
    ("--peer-frames", "0", "argument --peer-frames: must be at least 1, got 0"),
    ("--peer-min-time", "-1", "argument --peer-min-time: must be at least 0, got -1"),
    ("--peer-min-time", "nan", "argument --peer-min-time: must be at least 0, got nan"),
    ("--sizes", "1", "argument --sizes: must be at least 2, got 1"),
    ("--pypbd-threads", "0", "argument --pypbd-threads: must be at least 1, got 0"),
    ("--rounds", "x", "argument --rounds: expected an integer, got 'x'"),
])
def test_impossible_bench_options_are_refused_by_name(capsys, option, value, message):
    from csb import cli

    with pytest.raises(SystemExit) as exit_:
        cli.main(["bench", "--peers", "--sides", "csb", option, value])
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


def test_a_side_process_that_fails_is_reported_with_its_error(monkeypatch):
    # a 1 x 1 cloth is refused by cloth_grid in the side's process: the driver says how it ended
    with pytest.raises(bench_peers.WorkerFailed) as failed:
        bench_peers.Worker(bench_peers.Run("csb", "csb"), 1, (10, 1), frames=2, warmup=1)
    message = str(failed.value)
    assert message.startswith("exit 1: ") and message.split(" | ")[-1].startswith("csb.ParameterError: cloth_grid")

    # in a row, the side that failed is noted and the others are timed
    class OneBadSize(bench_peers.Worker):
        def __init__(self, run, n, *args, **kwargs):
            super().__init__(run, 1 if run.label == "bad" else n, *args, **kwargs)

    monkeypatch.setattr(bench_peers, "Worker", OneBadSize)
    good, bad = bench_peers.Run("csb", "csb"), bench_peers.Run("bad", "csb")
    bench_peers.run_row([good, bad], 8, (10, 1), frames=2, rounds=2, warmup=1, min_time=0.02, passes=2)
    assert good.error is None and len(good.result["rows"]) == 1 and good.result["rows"][0]["rounds"] >= 2
    assert bad.result is None and bad.error.startswith("8 (10, 1): exit 1: ")
