"""The fuzzing harness's quick run and its regression files (tests/fuzz/harness.py says more).

Every file in tests/fuzz/regressions/<target>/ once made a loader crash, hang, print, blow up or
raise an exception of the wrong type; each must now give a result or a csb error. The quick run
mutates the seed corpus for a fixed set of cases per target (deterministic: the same files on
every run); the long run is ``./dev fuzz``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
import harness  # noqa: E402

REGRESSION_FILES = sorted(p for t in harness.TARGETS if (harness.REGRESSIONS / t).is_dir()
                          for p in (harness.REGRESSIONS / t).iterdir() if p.is_file() and not p.name.endswith(".txt"))


def test_every_target_has_seeds_and_the_seeds_load():
    """Every seed loads (a scene's seed is read beside the meshes it names, as replay arranges)."""
    for target in harness.TARGETS:
        files = harness.seeds(target)
        assert len(files) >= 9, target
        for path, out in harness.replay(files):
            assert out.outcome == "result", f"{path}: {out.outcome} {out.message}"


@pytest.mark.parametrize("path", REGRESSION_FILES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_regression_file_gives_a_result_or_a_csb_error(path):
    [(_, out)] = harness.replay([path])
    assert out.outcome in harness.ACCEPTED, f"{path.name}: {out.outcome} {out.kind}: {out.message}"


def test_mutation_is_deterministic():
    corpus = harness.Corpus("mesh", harness.seeds("mesh"))
    assert [corpus.case(5, k).data for k in range(20)] == [corpus.case(5, k).data for k in range(20)]
    assert len({corpus.case(5, k).digest for k in range(20)}) == 20


@pytest.mark.slow
def test_quick_fuzz_run_finds_nothing(tmp_path):
    tallies, found = harness.fuzz(list(harness.TARGETS), seed=0, cases=60, out_dir=tmp_path, progress=False)
    assert all(t.cases == 60 for t in tallies.values())
    # Each target reaches both accepted outcomes, so the mutations are neither all fatal nor all harmless.
    for target, t in tallies.items():
        assert t.outcomes.get("error", 0) > 0, (target, t.outcomes)
    messages = [p.with_name(p.name + ".txt").read_text() for p in found]
    assert not found, "\n".join(messages)
