"""scripts/machine_limits.py builds src/bench/machine/machine_limits.cpp with the system's g++, runs
it and tabulates this machine's arithmetic peaks and memory bandwidths. Here it runs --quick
(small arrays, 3 short repetitions): every figure the program prints is a finite positive number
and the JSON holds every figure this processor can measure. No speed is asserted: the figures of
a --quick run are not the machine's limits. These tests read the checkout, not the installed
package."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "machine_limits.py"

pytestmark = pytest.mark.skipif(shutil.which("g++") is None,
                                reason="no g++ on PATH to build src/bench/machine/machine_limits.cpp")

TYPES = ("double", "float")


def expected_figures(info: dict[str, str]) -> set[str]:
    """The figure names the program prints on a processor with these info lines."""
    names = {"clock_ghz"}
    vectors = ["scalar"] + [v for v, key in (("avx2", "avx2_fma"), ("avx512", "avx512f")) if info[key] == "1"]
    for t in TYPES:
        for v in vectors:
            names |= {f"sqrt_{t}_{v}_per_ns", f"div_{t}_{v}_per_ns"}
            if v != "scalar":
                names |= {f"fma_{t}_{v}_gflops", f"fma_{t}_{v}_2threads_gflops", f"addmul_{t}_{v}_gflops"}
    for kernel in ("copy", "triad"):
        for level in ("l2", "l3small", "l3", "dram"):
            names |= {f"{kernel}_{level}_1thread_gbps", f"{kernel}_{level}_2threads_gbps"}
    return names


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory) -> tuple[subprocess.CompletedProcess, dict, Path]:
    tmp = tmp_path_factory.mktemp("machine_limits")
    out = tmp / "limits.json"
    r = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--build", str(tmp), "--json", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return r, json.loads(out.read_text()), tmp / "machine_limits"


def test_every_figure_the_program_prints_is_finite_and_positive(quick_run):
    _, _, exe = quick_run
    out = subprocess.run([str(exe), "--quick"], capture_output=True, text=True, timeout=120, check=True).stdout
    names = []
    for line in out.splitlines():
        words = line.split()
        if not words or words[0].startswith("#") or words[0] == "info":
            continue
        assert len(words) == 4, line  # name median min max
        median, low, high = (float(w) for w in words[1:])
        assert all(math.isfinite(x) and x > 0 for x in (median, low, high)), line
        assert low <= median <= high, line
        names.append(words[0])
    assert len(names) == len(set(names)) and "clock_ghz" in names


def test_the_json_holds_every_figure_with_its_unit(quick_run):
    _, data, _ = quick_run
    assert {"processor", "compiler", "flags", "load_average", "info", "figures"} <= data.keys()
    assert data["flags"] == ["-O2", "-std=c++17", "-pthread"]
    info = data["info"]
    assert info["quick"] == "1" and int(info["reps"]) == 3
    assert {"avx2_fma", "avx512f", "cpus_allowed", "array_bytes_l2", "array_bytes_l3small", "array_bytes_l3",
            "array_bytes_dram", "stream_vectors"} <= info.keys()
    figures = data["figures"]
    assert set(figures) == expected_figures(info)
    units = {"_gflops": "GFLOP/s", "_per_ns": "1/ns", "_gbps": "GB/s", "_ghz": "GHz"}
    for name, f in figures.items():
        assert set(f) == {"median", "min", "max", "unit"}, name
        assert all(math.isfinite(f[k]) and f[k] > 0 for k in ("median", "min", "max")), name
        assert f["unit"] == next(u for suffix, u in units.items() if name.endswith(suffix)), name


def test_the_table_names_its_units_and_says_a_quick_run_is_not_the_limits(quick_run):
    r, _, _ = quick_run
    for label in ("GFLOP/s", "GB/s", "1/ns", "GHz", "FMA peak, double", "DRAM (dram): 3 x 1 MiB",
                  "not this machine's limits"):
        assert label in r.stdout, label


def test_the_validation_study_sets_the_xpbd_step_against_the_machine(tmp_path):
    """validation/machine_limits.py --quick: the machine's figures, the 128² cloth's XPBD frames in
    float64 and float32 with their elements and bounds (finite, positive), and a profile where perf
    can take one, else a sentence saying why not."""
    import csv

    r = subprocess.run([sys.executable, str(ROOT / "validation" / "machine_limits.py"), "--quick", "--out",
                        str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert json.loads((tmp_path / "machine_limits.json").read_text())["figures"]
    with (tmp_path / "machine_limits_csb.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [(row["cloth"], row["precision"]) for row in rows] == [("128x128", "float64"), ("128x128", "float32")]
    for row in rows:
        assert int(row["elements_per_frame"]) > 0
        for key in ("ms_per_frame", "ns_per_element", "workspace_mb", "ms_at_dram", "ms_at_l3"):
            assert math.isfinite(float(row[key])) and float(row[key]) > 0, (key, row)
    assert "samples by function" in r.stdout or "no profile:" in r.stdout
