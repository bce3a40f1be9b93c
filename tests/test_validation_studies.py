"""The study files of validation/studies: each loads, declares its tier, and each quick one has a
full counterpart (<name>_quick.toml beside <name>.toml) or says why it has none."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from csb.studies.study import load_study

ROOT = Path(__file__).resolve().parent.parent
STUDIES = sorted((ROOT / "validation" / "studies").glob("*.toml"))
# A quick study without a full counterpart says so in a comment line starting with this.
NO_FULL_TIER = "# No full tier:"


def test_there_are_study_files():
    assert len(STUDIES) >= 2


@pytest.mark.parametrize("path", STUDIES, ids=[p.name for p in STUDIES])
def test_each_study_file_loads_and_declares_its_tier(path):
    study = load_study(path)
    assert study.cells(), f"{path.name}: no cells"
    declared = tomllib.loads(path.read_text())["study"].get("tier")
    assert declared in ("quick", "full"), f"{path.name}: [study] tier = \"quick\" or \"full\" is not declared"
    assert study.tier == declared
    if path.stem.endswith("_quick"):
        assert declared == "quick", f"{path.name}: a <name>_quick.toml file is the quick tier of <name>.toml"


QUICK = [p for p in STUDIES if tomllib.loads(p.read_text())["study"].get("tier") == "quick"]


@pytest.mark.parametrize("path", QUICK, ids=[p.name for p in QUICK])
def test_each_quick_study_has_a_full_counterpart_or_says_why_not(path):
    full = path.with_name(path.stem.removesuffix("_quick") + ".toml")
    if not path.stem.endswith("_quick") or not full.is_file():
        reasons = [line for line in path.read_text().splitlines() if line.startswith(NO_FULL_TIER)]
        assert reasons and len(reasons[0]) > len(NO_FULL_TIER) + 10, \
            (f"{path.name}: a quick study without a full counterpart (<name>_quick.toml beside <name>.toml) "
             f"says why in a '{NO_FULL_TIER} <why>' comment line")
        return
    quick, counterpart = load_study(path), load_study(full)
    assert counterpart.tier == "full", f"{full.name}: the counterpart of {path.name} is not tier \"full\""
    # The quick tier runs the full one's set-ups and methods, smaller and shorter.
    assert {s.definition.get("setup") for s in quick.scenes} <= {s.definition.get("setup") for s in counterpart.scenes}
    assert {m.label for m in quick.methods} <= {m.label for m in counterpart.methods}
    assert set(quick.metrics) == set(counterpart.metrics)
    assert len(quick.cells()) <= len(counterpart.cells())
