"""What a study measures and draws beyond position errors: the backward-Euler residual and the
same-step error, a reference whose tolerance the study chooses, costs repeated until their spread
allows a ranking (and ties where it does not), the tuning budget, line charts and stability maps
over a scene's grid, and a user's class with arguments."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

import csb
from csb.studies.study import StudyError, load_study, run_study
from csb.studies.study.cells import AUTO_MAX, AUTO_MIN
from csb.studies.study.charts import map_class
from csb.studies.study.execute import _cost_ranks


def write(tmp_path: Path, text: str, name: str = "study.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


# A user's class: csb's XPBD (one thread) with its damping as a keyword argument.
WRAPPED_XPBD = textwrap.dedent("""\
    import csb

    class Wrapped(csb.Integrator):
        def __init__(self, dt, iterations=10, gravity=(0, -9.81, 0), damping=0.0):
            super().__init__()
            self.inner = csb.PbdStepper(method="xpbd", dt=dt, iterations=iterations, gravity=gravity,
                                        damping=damping, threads=1)
        def name(self):
            return "wrapped"
        def dt(self):
            return self.inner.dt()
        def step(self, model, state, steps=1, interrupt=None):
            self.inner.step(model, state, steps)
    """)

CHAIN = """\
[[scene]]
name = "chain"
setup = "swinging_chain"
args = { links = 5, compliance = 1e-6 }
"""


def test_the_residual_falls_with_the_iterations_and_backward_euler_is_its_own_same_step_reference(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.2
        outputs = 4
        metrics = ["residual", "same_step_error", "stability"]

        [[chart]]
        kind = "line"
        x = "iterations"
        y = "residual"

        [[chart]]
        kind = "line"
        x = "cpu_per_simulated_s"
        y = "residual"
        along = "iterations"
        """ + CHAIN + """
        [[method]]
        name = "xpbd"
        dt = 0.0166666666667
        iterations = [1, 10, 100]

        [[method]]
        name = "backward-euler"
        dt = 0.0166666666667
        """)
    r = run_study(p, out=tmp_path / "out", workers=0)
    assert r.failed == 0
    xpbd = sorted((row for row in r.table if row["method"] == "xpbd"), key=lambda row: row["iterations"])
    res = [row["residual"] for row in xpbd]
    err = [row["same_step_error"] for row in xpbd]
    assert res[0] > res[1] > res[2] > 0 and err[0] > err[1] > err[2] > 0
    be = next(row for row in r.table if row["method"] == "backward-euler")
    # Newton's solve stops at 1e-9 of the step's force scale: orders of magnitude below one
    # XPBD iteration's residual, and the same solve from the same state gives the same step.
    assert be["residual"] < 1e-6 * res[0]
    assert be["same_step_error"] < 1e-12
    assert (tmp_path / "out" / "chart_1.png").stat().st_size > 10_000
    assert (tmp_path / "out" / "chart_2.png").stat().st_size > 10_000
    assert "![residual against iterations](chart_1.png)" in r.report()
    assert "![residual against cpu_per_simulated_s](chart_2.png)" in r.report()


def test_residual_of_a_scene_with_hard_constraints_is_null_with_the_reason(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.1
        metrics = ["residual", "stability"]

        [[scene]]
        setup = "swinging_chain"
        args = { links = 3, compliance = 0.0 }

        [[method]]
        name = "pbd"
        dt = 0.01
        iterations = 4
        """)
    (row,) = run_study(p, out=tmp_path / "out", workers=0).table
    assert row["status"] == "ok" and row["residual"] is None
    assert "residual:" in row["notes"] and "hard" in row["notes"]


def test_the_continuous_reference_gives_no_residual(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.1
        metrics = ["residual", "stability"]
        """ + CHAIN + """
        [[method]]
        name = "cvode"
        rtol = 1e-6
        """)
    (row,) = run_study(p, out=tmp_path / "out", workers=0).table
    assert row["status"] == "failed" and "takes no steps" in row["error"]


def test_rtol_auto_tightens_the_reference_until_its_own_error_is_a_fraction_of_the_smallest_measured(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.3
        metrics = ["position_error", "stability"]

        [reference]
        rtol = "auto"
        fraction = 0.01
        """ + CHAIN + """
        [[method]]
        name = "xpbd"
        dt = [0.0333333333333, 0.00208333333333]
        iterations = 50
        """)
    r = run_study(p, out=tmp_path / "out", workers=0)
    ref = r.references["chain"]
    smallest = min(row["position_error"] for row in r.table)
    assert ref.met and ref.smallest_error == pytest.approx(smallest, rel=1e-12)
    assert 0 < ref.self_error <= 0.01 * smallest
    # The estimate is an upper one: a reference far tighter than the chosen one is closer to it.
    model, start = csb.studies.swinging_chain(links=5, compliance=1e-6), None
    start = model.initial_state()
    times = np.linspace(0, 0.3, 11)
    tight = csb.integrate_reference(model, start, times, rtol=1e-13, atol=1e-15)
    assert np.linalg.norm(tight.x - ref.x, axis=2).max() <= ref.self_error
    assert "| chain |" in r.report() and "own error" in r.report()
    # The references are stored: a second run computes nothing.
    again = run_study(p, out=tmp_path / "out", workers=0)
    assert again.computed == 0 and again.references["chain"].rtol == ref.rtol


def test_fraction_needs_rtol_auto(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.1
        metrics = ["position_error"]

        [reference]
        rtol = 1e-8
        fraction = 0.1
        """ + CHAIN + """
        [[method]]
        name = "xpbd"
        dt = 0.01
        """)
    with pytest.raises(StudyError, match=r"reference\.fraction.*rtol = \"auto\""):
        load_study(p)


def test_repeats_auto_runs_until_the_spread_is_small_and_the_report_says_so(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.2
        repeats = "auto"
        metrics = ["stability"]
        """ + CHAIN + """
        [[method]]
        name = "xpbd"
        dt = 0.01
        iterations = 5
        """)
    r = run_study(p, out=tmp_path / "out", workers=0)
    (row,) = r.table
    assert AUTO_MIN <= row["repeats"] <= AUTO_MAX
    assert row["cpu_low"] <= row["cpu_per_simulated_s"] <= row["cpu_high"]
    assert "as many runs as the spread asks" in r.report()


def test_costs_whose_ranges_overlap_share_a_rank():
    rows = [dict(cpu_per_simulated_s=1.0, cpu_low=0.9, cpu_high=1.1),
            dict(cpu_per_simulated_s=1.05, cpu_low=1.0, cpu_high=1.2),   # overlaps the first: a tie
            dict(cpu_per_simulated_s=2.0, cpu_low=1.9, cpu_high=2.1),    # apart: its own rank
            dict(cpu_per_simulated_s=2.05, cpu_low=None, cpu_high=None),  # one run: its median in 2's range
            dict(cpu_per_simulated_s=5.0, cpu_low=4.9, cpu_high=5.1)]
    assert _cost_ranks(rows) == [1, 1, 3, 3, 5]


def test_a_budget_holds_every_method_to_the_same_number_of_settings(tmp_path):
    body = """\
        [study]
        duration = 0.1
        budget = 2
        metrics = ["stability"]
        """ + CHAIN + """
        [[method]]
        name = "xpbd"
        dt = 0.01
        iterations = [1, 10]

        [[method]]
        name = "symplectic-euler"
        dt = [1e-4, 5e-5, 2e-5]
        """
    with pytest.raises(StudyError, match=r"method\[1\].*symplectic-euler has 3 parameter settings.*budget is 2"):
        load_study(write(tmp_path, body))
    ok = load_study(write(tmp_path, body.replace("[1e-4, 5e-5, 2e-5]", "[1e-4, 5e-5]")))
    assert ok.budget == 2
    unequal = write(tmp_path, body.replace("budget = 2\n", ""), "unequal.toml")
    r = run_study(unequal, out=tmp_path / "out", workers=0)
    assert "Tuning budget: not equal (xpbd 2, symplectic-euler 3 settings per scene)" in r.report()


def test_a_stability_map_over_a_scene_grid_and_the_time_step(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.3
        metrics = ["position_error", "stability"]

        [reference]
        rtol = 1e-8

        [[scene]]
        name = "chain"
        setup = "swinging_chain"
        args = { links = 3 }
        grid = { compliance = [1e-2, 1e-5] }

        [[method]]
        name = "symplectic-euler"
        dt = [2e-3, 1e-4]

        [[chart]]
        kind = "map"
        x = "dt"
        y = "compliance"
        wrong = 0.05
        """)
    r = run_study(p, out=tmp_path / "out", workers=0)
    classes = {(row["compliance"], row["dt"]): map_class(row, 0.05) for row in r.table}
    # Symplectic Euler is stable for dt below 2/ω_max. A chain of springs k = 1/α between nodes of
    # m = 5 g has ω_max below 2 sqrt(k/m): 2/ω_max is above 7e-3 s for α = 1e-2 m/N (stable at both
    # steps) and about 2.2e-4 s for α = 1e-5 m/N (stable only at the small step).
    assert classes[(1e-2, 2e-3)] == classes[(1e-2, 1e-4)] == "stable"
    assert classes[(1e-5, 2e-3)] == "blew up" and classes[(1e-5, 1e-4)] == "stable"
    assert [row["compliance"] for row in r.table] == [1e-2, 1e-2, 1e-5, 1e-5]
    assert (tmp_path / "out" / "chart_1.png").is_file()
    assert "stability over dt and compliance" in r.report()


@pytest.mark.parametrize("chart, message", [
    ('kind = "pie"\nx = "dt"', r"chart\[0\]\.kind"),
    ('kind = "line"\nx = "mass"\ny = "stability"', r"chart\[0\]\.x"),
    ('kind = "line"\nx = "dt"\ny = "stability"', r"chart\[0\]\.y"),
    ('kind = "map"\nx = "dt"\ny = "dt"', r"chart\[0\]\.y: must differ"),
    ('kind = "map"\nx = "dt"\ny = "iterations"\nwrong = 0.1', r"chart\[0\]\.wrong: .*position_error"),
    ('kind = "line"\nx = "cpu_per_simulated_s"\ny = "max_strain"', r"chart\[0\]\.along: .*iterations, say"),
    ('kind = "map"\nx = "cpu_per_simulated_s"\ny = "dt"', r"chart\[0\]\.x"),
])
def test_a_bad_chart_is_named(tmp_path, chart, message):
    p = write(tmp_path, """\
        [study]
        duration = 0.1
        metrics = ["max_strain", "stability"]
        """ + CHAIN + """
        [[method]]
        name = "xpbd"
        dt = 0.01

        [[chart]]
        """ + textwrap.indent(chart, "        ").lstrip() + "\n")
    with pytest.raises(StudyError, match=message):
        load_study(p)


def test_a_scene_grid_may_not_sweep_a_column_of_the_table(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.1
        metrics = ["stability"]

        [[scene]]
        setup = "swinging_chain"
        grid = { dt = [1, 2] }

        [[method]]
        name = "xpbd"
        dt = 0.01
        """)
    with pytest.raises(StudyError, match=r"scene\[0\]\.grid: dt is a column of the study's table"):
        load_study(p)


def test_a_users_class_takes_arguments_from_the_study(tmp_path):
    (tmp_path / "wrapped.py").write_text(WRAPPED_XPBD)
    p = write(tmp_path, """\
        [study]
        duration = 0.2
        metrics = ["energy_drift", "stability"]
        """ + CHAIN + """
        [[method]]
        python = "wrapped:Wrapped"
        label = "undamped"
        dt = 0.01

        [[method]]
        python = "wrapped:Wrapped"
        label = "damped"
        args = { damping = 0.5 }
        dt = 0.01
        """)
    undamped, damped = run_study(p, out=tmp_path / "out", workers=0).table
    assert undamped["key"] != damped["key"]
    assert damped["energy_drift"] > undamped["energy_drift"]
    bad = write(tmp_path, p.read_text().replace("args = { damping = 0.5 }", "args = [1]"), "bad.toml")
    with pytest.raises(StudyError, match=r"method\[1\]\.args: must be a table"):
        load_study(bad)


def test_a_method_the_study_file_does_not_name_runs_through_it_over_another_methods_grid(tmp_path, monkeypatch):
    (tmp_path / "wrapped.py").write_text(WRAPPED_XPBD)
    p = write(tmp_path, """\
        [study]
        duration = 0.2
        metrics = ["max_strain", "stability"]
        """ + CHAIN + """
        [[method]]
        name = "symplectic-euler"
        dt = 1e-4

        [[method]]
        name = "xpbd"
        dt = [0.02, 0.01]
        iterations = [2, 8]
        """)
    monkeypatch.chdir(tmp_path)
    first = run_study(p, out=tmp_path / "out", workers=0)
    r = run_study(p, out=tmp_path / "out", workers=0, extra_methods=["wrapped:Wrapped"], like="xpbd")
    assert (r.computed, r.reused) == (4, first.computed)  # only the added method's cells run
    mine = {(row["dt"], row["iterations"]): row for row in r.table if row["method"] == "Wrapped"}
    xpbd = {(row["dt"], row["iterations"]): row for row in r.table if row["method"] == "xpbd"}
    assert set(mine) == set(xpbd) == {(0.02, 2), (0.02, 8), (0.01, 2), (0.01, 8)}
    assert all(mine[k]["max_strain"] == xpbd[k]["max_strain"] for k in mine)
    with pytest.raises(StudyError, match=r"no method 'pbd' that takes a time step.*symplectic-euler, xpbd"):
        load_study(p, extra_methods=["wrapped:Wrapped"], like="pbd")
    with pytest.raises(StudyError, match=r"method\[2\]\.python: cannot import 'absent'"):
        load_study(p, extra_methods=["absent:Wrapped"])


STUDIES = Path(__file__).resolve().parents[1] / "validation" / "studies"


@pytest.mark.parametrize("study", sorted(STUDIES.glob("*.toml")), ids=lambda p: p.stem)
def test_the_documented_user_method_can_join_every_study_file(study, monkeypatch):
    monkeypatch.chdir(STUDIES)  # where docs/your_own_method.md's MyPbd lives, as my_pbd.py
    if any(m.definition.get("python") == "my_pbd:MyPbd" for m in load_study(study).methods):
        return  # the study names it already
    st = load_study(study, extra_methods=["my_pbd:MyPbd"])
    added = st.methods[-1]
    assert added.label == "MyPbd" and added.definition["python"] == "my_pbd:MyPbd"
    assert len(st.cells()) > len(load_study(study).cells())


def test_the_hanging_cloth_without_bending_has_distance_constraints_only():
    from csb.studies.study.schema import hanging_cloth

    bare, full = hanging_cloth(n=6, bending=False), hanging_cloth(n=6)
    assert bare.num_constraints == len(bare.distance["rest_length"]) == len(full.distance["rest_length"])
    assert full.num_constraints > bare.num_constraints
    with pytest.raises(csb.ParameterError, match="bending must be true or false"):
        hanging_cloth(n=6, bending=1)


def test_a_chart_draws_the_scenes_and_methods_it_names(tmp_path):
    body = """\
        [study]
        duration = 0.1
        metrics = ["max_strain", "stability"]
        """ + CHAIN + """
        [[scene]]
        setup = "mass_ratio_chain"
        grid = { ratio = [1.0, 100.0] }

        [[method]]
        name = "xpbd"
        dt = [0.01, 0.005]

        [[method]]
        name = "pbd"
        dt = [0.01, 0.005]

        [[chart]]
        kind = "map"
        x = "dt"
        y = "ratio"
        scenes = ["mass_ratio_chain"]
        methods = ["xpbd"]
        """
    st = load_study(write(tmp_path, body))
    assert st.charts[0]["scenes"] == ["mass_ratio_chain"] and st.charts[0]["methods"] == ["xpbd"]
    r = run_study(write(tmp_path, body), out=tmp_path / "out", workers=0)
    assert (tmp_path / "out" / "chart_1.png").is_file() and r.failed == 0
    with pytest.raises(StudyError, match=r"chart\[0\]\.scenes: 'cloth' is not one of the study's scenes"):
        load_study(write(tmp_path, body.replace('["mass_ratio_chain"]', '["cloth"]'), "bad.toml"))


def test_a_same_step_reference_that_fails_leaves_the_metric_null_with_the_reason(tmp_path, monkeypatch):
    class Failing:
        def __init__(self, **_):
            pass

        def step(self, model, state, steps=1):
            raise csb.SimulationError("backward Euler: no descent direction")

    monkeypatch.setattr(csb._core, "BackwardEuler", Failing)
    p = write(tmp_path, """\
        [study]
        duration = 0.1
        metrics = ["same_step_error", "residual", "stability"]
        """ + CHAIN + """
        [[method]]
        name = "xpbd"
        dt = 0.01
        """)
    (row,) = run_study(p, out=tmp_path / "out", workers=0).table
    assert row["status"] == "ok" and row["same_step_error"] is None and row["residual"] > 0
    assert "same_step_error: the same-step reference failed: backward Euler: no descent direction" in row["notes"]


def test_one_slow_run_does_not_stretch_the_spread_of_four_or_more():
    from csb.studies.study.cells import _enough, cost_range

    assert cost_range([1.0, 1.2]) == (1.0, 1.2)  # two or three runs: their range
    assert cost_range([1.0, 1.01, 1.02, 1.03, 9.0]) == (1.01, 1.03)  # quartiles: the slow run is an outlier
    assert not _enough([1.0, 1.5, 2.0], "auto")  # a spread of half the median: run again
    assert _enough([1.0, 1.01, 1.02, 1.03, 9.0], "auto")
    assert _enough([1.0, 2.0], 2) and not _enough([1.0], 2)


def test_the_one_step_metrics_with_one_step_between_outputs(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.1
        outputs = 5
        metrics = ["residual", "same_step_error", "stability"]
        """ + CHAIN + """
        [[method]]
        name = "xpbd"
        dt = 0.02
        iterations = 5
        """)
    (row,) = run_study(p, out=tmp_path / "out", workers=0).table
    assert row["steps"] == 5 and row["status"] == "ok" and row["residual"] > 0 and row["same_step_error"] > 0


def test_a_scene_may_leave_out_some_of_the_studys_metrics_and_then_gets_no_reference(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.2
        metrics = ["position_error", "residual", "stability"]

        [reference]
        rtol = 1e-9

        [[scene]]
        name = "chain"
        setup = "swinging_chain"
        args = { links = 3, compliance = 1e-6 }

        [[scene]]
        name = "twisted"
        setup = "twisting_cloth"
        args = { n = 4 }
        metrics = ["residual", "stability"]   # no converged continuous reference here

        [[method]]
        name = "xpbd"
        dt = 0.01
        iterations = 5
        """)
    r = run_study(p, out=tmp_path / "out", workers=0)
    chain, twisted = r.table
    assert chain["position_error"] > 0 and chain["residual"] > 0
    assert twisted["position_error"] is None and twisted["residual"] > 0
    assert "position_error: not measured on this scene" in twisted["notes"]
    assert set(r.references) == {"chain"}  # the reference ran for the chain only
    assert "twisted: the cells no other cell" not in r.report()
    bad = write(tmp_path, p.read_text().replace('metrics = ["residual", "stability"]', 'metrics = ["volume_error"]'),
                "bad.toml")
    with pytest.raises(StudyError, match=r"scene\[1\]\.metrics: 'volume_error' is not one of the study's metrics"):
        load_study(bad)
