"""validation/collisions.py run with --quick: its outputs exist and its claims hold."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_collisions_study_quick(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "validation" / "collisions.py"), "--quick", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "friction threshold (found vs atan μ" in r.stdout
    png = (tmp_path / "collisions.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    # 1. no collider is ever entered beyond round-off; nothing tunnels through the thin wall
    pen = rows(tmp_path / "collisions_penetration.csv")
    assert {r["collider"] for r in pen} == {"plane", "sphere", "capsule", "box", "mesh"}
    assert all(float(r["max_penetration_m"]) <= 1e-12 for r in pen)
    # 2. a cloth resting on the ground is still (brief's bounds; measured 0)
    for r in rows(tmp_path / "collisions_rest.csv"):
        assert float(r["max_speed_m_per_s"]) < 1e-3 and float(r["max_drift_m"]) < 1e-4
    # 3. the sliding threshold is atan μ within the sub-step's lag (see tests/test_friction.py)
    for r in rows(tmp_path / "collisions_friction.csv"):
        assert abs(float(r["threshold_deg"]) - math.degrees(math.atan(float(r["mu"])))) < 0.2
    # 4. bounce to e² H within the impact's discretisation bound (tests/test_friction.py)
    for r in rows(tmp_path / "collisions_bounce.csv"):
        e, v, h = float(r["restitution"]), math.sqrt(2 * 9.81), 1 / 600
        assert abs(float(r["error_m"])) <= 2 * e * e * 9.81 * h / v + e * v * h + 1e-12
    # 5. self-collision keeps the folded cloth free of crossings; without it the fold passes through
    selfc = rows(tmp_path / "collisions_self.csv")
    assert max(int(r["crossings"]) for r in selfc if r["case"].startswith("self")) == 0
    assert max(int(r["crossings"]) for r in selfc if r["case"].startswith("no")) > 50
