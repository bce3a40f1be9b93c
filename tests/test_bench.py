"""The benchmark command works and counts its work correctly (its timings are printed, never
asserted: see `csb bench`)."""

from __future__ import annotations

import subprocess
import sys

import pytest

import csb
from csb.bench import bench_cloth, cloth_simulation, dispatch, format_front_ends, format_table, front_ends


def test_bench_counts_the_projections_it_times():
    row = bench_cloth(8, iterations=3, substeps=2, steps=2, rounds=2, warmup=1)
    model = cloth_simulation(8).model
    assert bench_cloth(8, steps=1, rounds=1, warmup=0, constraints="bending").distance == 0
    assert model.num_constraints == row.distance + row.bending and (model.inv_mass == 0).sum() == 2
    assert row.particles == 64 and row.distance == 2 * 8 * 7 + 49 and row.bending == row.distance - 28
    assert row.projections_per_step == 2 * 3 * (row.distance + row.bending) == 2 * 3 * model.num_constraints
    assert row.ms_spread[0] <= row.ms_per_step <= row.ms_spread[1]
    table = format_table([row])
    assert "8x8" in table and "Mproj/s" in table


def test_dispatch_benchmark_compares_the_same_projections_bit_for_bit():
    rows = dispatch((8,), sweeps=3, repeats=2)
    assert [r["kind"] for r in rows] == ["stretch+bending", "stretch", "bending"]
    for r in rows:
        assert r["identical"] and r["projections"] == 3 * r["constraints"] and r["batched_ns"] > 0


def test_front_end_benchmark_times_both_front_ends():
    (row,) = front_ends((8,), iterations=2, rounds=2)
    assert row["particles"] == 64
    for key in ("alone_euler_ns_per_particle", "alone_verlet_ns_per_particle", "step_euler_ms", "step_verlet_ms"):
        assert row[key] > 0
    assert "Euler/Verlet" in format_front_ends([row])


def test_bench_command_prints_a_table():
    r = subprocess.run([sys.executable, "-m", "csb.cli", "bench", "--sizes", "8", "16", "--rounds", "2", "--steps", "2",
                        "--parts", "step"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith(f"csb {csb.__version__} PBD step benchmark")
    rows = [line.split() for line in lines[3:]]
    assert [(r[0], r[1]) for r in rows] == [(f"{n}x{n}", kind) for n in (8, 16)
                                             for kind in ("stretch+bending", "stretch", "bending")]


def test_cost_helpers_time_frames_and_projections_and_report_consistent_memory():
    from csb.bench import (cloth_ms_per_frame, format_memory, format_projection_rates, make_stepper, memory_report,
                           projection_rates)

    r = cloth_ms_per_frame(8, substeps=2, iterations=1, threads=2, frames=2, rounds=2)
    assert r["threads_used"] == 2 and r["ms"] > 0 and r["fps"] == 1e3 / r["ms"]
    rows = projection_rates(8, sweeps=2, rounds=1)
    assert {r["ordering"] for r in rows} == {"coloured", "sequential", "plain loop"}
    assert "vs plain loop" in format_projection_rates(rows)
    sim = cloth_simulation(16, iterations=1)
    stepper = make_stepper(sim, substeps=1, iterations=1)
    stepper.step(sim.model, sim.state)
    m = memory_report(sim.model, stepper)
    assert m["model_bytes"] == sim.model.memory["total"] and m["workspace_bytes"] == stepper.workspace_bytes
    assert m["bytes_per_particle"] * m["particles"] == m["model_bytes"] + m["workspace_bytes"]
    assert "B/particle" in format_memory([dict(n=16, method="pbd", **m)])


def test_self_collision_sweep_reports_every_size_and_a_slope():
    """The self-collision sweep at two tiny capes, one round: a row per size with finite, positive
    times and ratios, counts that add up, and the fitted slopes (figures, never asserted)."""
    import math

    from csb.bench import cape_thickness, format_self_collision_scaling, self_collision_scaling

    result = self_collision_scaling((6, 9), rounds=1, frames=6, first=2)
    rows = result["rows"]
    assert [r["n"] for r in rows] == [6, 9] and [r["particles"] for r in rows] == [36, 81]
    for r in rows:
        assert r["thickness"] == cape_thickness(r["n"]) == 0.006
        for key in ("ms_none", "ms_self", "ratio", "median_ms_none", "median_ms_self", "median_ratio",
                    "searches_per_step"):
            assert math.isfinite(r[key]) and r[key] > 0, key
        assert r["spread_none"][0] <= r["ms_none"] <= r["spread_none"][1]
        assert r["spread_self"][0] <= r["ms_self"] <= r["spread_self"][1]
        assert math.isfinite(r["extra_ns_per_particle"]) and math.isfinite(r["median_extra_ns_per_particle"])
        assert r["timed_frames"] == 4 and 0 <= r["frames_with_pairs"] <= 4
        for key in ("pairs_per_particle", "max_pairs_per_particle", "tests_per_step", "continuous", "failsafe"):
            assert math.isfinite(r[key]) and r[key] >= 0, key
        assert r["max_pairs_per_particle"] >= r["pairs_per_particle"]
    assert math.isfinite(result["slope_none"])
    table = format_self_collision_scaling(result)
    assert "6x6" in table and "9x9" in table and "slope" in table
    # finer capes than the 6 mm layer allows get half their triangles' smallest rest altitude
    assert cape_thickness(40) == 0.006 and math.isclose(cape_thickness(160), 0.5 / (159 * math.sqrt(2)))


def test_precision_tables_time_both_precisions_of_each_method():
    """The float64 against float32 tables: every side timed, finite positive figures, speed-ups
    that are the ratios of the medians (no timing is asserted)."""
    from csb.bench import (format_precision_rates, format_precision_table, precision_rates,
                           precision_table)

    rows = precision_table(sizes=(8,), rounds=1, threads=1)
    assert [(r["substeps"], r["iterations"]) for r in rows] == [(10, 1), (1, 10)]
    for r in rows:
        for method in ("pbd", "xpbd"):
            f64, f32 = r[method + "_float64"], r[method + "_float32"]
            assert 0 < f64 < 1e3 and 0 < f32 < 1e3
            assert r[method + "_speedup"] == pytest.approx(f64 / f32)
    assert "XPBD 64/32" in format_precision_table(rows)
    kernels = precision_rates(sizes=(8,), sweeps=2, rounds=1)
    assert [(r["kind"], r["method"]) for r in kernels] == [("distance", "pbd"), ("distance", "xpbd"),
                                                           ("bending", "pbd"), ("bending", "xpbd")]
    for r in kernels:
        assert 0 < r["float64"] and 0 < r["float32"] and r["speedup"] == pytest.approx(r["float64"] / r["float32"])
    assert "64/32" in format_precision_rates(kernels)
