"""Performance profiles (Dolan and Moré 2002), against values worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from csb.studies.profiles import cost_to_accuracy, performance_profile, plot_performance_profile

INF = math.inf

# Three problems, three methods. Costs, and the ratios to each problem's cheapest:
#         A      B      C           A    B    C
#   p1    1      2      4      p1   1    2    4
#   p2    3      3      inf    p2   1    1    inf
#   p3    10     5      20     p3   2    1    4
COSTS = {("p1", "A"): 1.0, ("p1", "B"): 2.0, ("p1", "C"): 4.0,
         ("p2", "A"): 3.0, ("p2", "B"): 3.0, ("p2", "C"): INF,
         ("p3", "A"): 10.0, ("p3", "B"): 5.0, ("p3", "C"): 20.0}


def test_the_curves_are_the_shares_of_problems_within_each_factor():
    prof = performance_profile(COSTS)
    assert prof.problems == ["p1", "p2", "p3"] and prof.methods == ["A", "B", "C"]
    assert prof.ratios["p3"] == {"A": 2.0, "B": 1.0, "C": 4.0}
    # ρ at τ = 1: cheapest on p1, p2 (tie) for A; p2 (tie), p3 for B; never for C.
    assert (prof.at("A", 1), prof.at("B", 1), prof.at("C", 1)) == (2 / 3, 2 / 3, 0)
    assert (prof.at("A", 2), prof.at("B", 2), prof.at("C", 2)) == (1, 1, 0)
    assert prof.at("C", 4) == 2 / 3 and prof.solved("C") == 2 / 3 and prof.solved("A") == 1
    # Sampled exactly at the distinct ratios (and 1), non-decreasing.
    assert list(prof.taus) == [1.0, 2.0, 4.0]
    assert list(prof.rho["C"]) == [0, 0, 2 / 3]
    for s in prof.methods:
        assert np.all(np.diff(prof.rho[s]) >= 0)


def test_a_problem_no_method_solves_is_left_out_and_absent_pairs_are_unsolved():
    costs = dict(COSTS)
    costs.update({("p4", "A"): INF, ("p4", "B"): INF, ("p4", "C"): INF})
    del costs[("p1", "C")]
    prof = performance_profile(costs)
    assert prof.problems == ["p1", "p2", "p3"]
    assert prof.ratios["p1"]["C"] == INF and prof.solved("C") == 1 / 3


def test_zero_costs_tie_and_beat_the_rest():
    prof = performance_profile({("p", "A"): 0.0, ("p", "B"): 0.0, ("p", "C"): 1e-9})
    assert prof.ratios["p"] == {"A": 1.0, "B": 1.0, "C": INF}


def test_cost_to_accuracy_takes_the_cheapest_run_that_meets_the_target():
    rows = [
        {"scene": "chain", "method": "xpbd", "position_error": 1e-2, "cost": 1.0, "status": "ok"},
        {"scene": "chain", "method": "xpbd", "position_error": 1e-4, "cost": 8.0, "status": "ok"},
        {"scene": "chain", "method": "xpbd", "position_error": 1e-5, "cost": 20.0, "status": "ok"},
        {"scene": "chain", "method": "pbd", "position_error": 1e-1, "cost": 0.5, "status": "ok"},
        {"scene": "chain", "method": "euler", "position_error": math.nan, "cost": 0.1, "status": "ok"},
        {"scene": "chain", "method": "vbd", "position_error": 1e-6, "cost": 2.0, "status": "failed"},
    ]
    t = cost_to_accuracy(rows, target=1e-3)
    assert t == {("chain", "xpbd"): 8.0, ("chain", "pbd"): INF, ("chain", "euler"): INF, ("chain", "vbd"): INF}


@pytest.mark.parametrize("costs, message", [
    ({}, "costs is empty"),
    ({("p", "A"): math.nan}, r"cost of 'A' on 'p' must be >= 0"),
    ({("p", "A"): -1.0}, r"cost of 'A' on 'p' must be >= 0"),
    ({("p", "A"): INF}, "no problem is solved"),
])
def test_bad_costs_are_named(costs, message):
    with pytest.raises(ValueError, match=message):
        performance_profile(costs)


def test_bad_rows_and_taus_are_named():
    with pytest.raises(ValueError, match="no column 'cost'"):
        cost_to_accuracy([{"scene": "s", "method": "m", "position_error": 0.0}], target=1.0)
    with pytest.raises(ValueError, match="target must be >= 0"):
        cost_to_accuracy([], target=math.nan)
    with pytest.raises(ValueError, match="taus must be >= 1"):
        performance_profile(COSTS, taus=[0.5, 2])


def test_the_plot_is_written(tmp_path):
    path = tmp_path / "profile.png"
    plot_performance_profile(performance_profile(COSTS), path, cost_label="CPU s per simulated s")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
