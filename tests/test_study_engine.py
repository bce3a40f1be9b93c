"""Declarative studies (csb.studies.study): the file's schema and its errors, cells as the
product of the grids, keys, a Dask run equal to the serial one, resuming after a SIGKILL,
failed cells, and a user's Integrator class in a study."""

from __future__ import annotations

import importlib.util
import json
import re
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

import csb
from csb.studies.study import StudyError, cell_key, load_study, run_study

HAS_DASK = importlib.util.find_spec("dask") is not None and importlib.util.find_spec("distributed") is not None
needs_dask = pytest.mark.skipif(not HAS_DASK, reason="dask.distributed is not installed (pip install 'csb[study]')")

# Columns that depend on the run (timing, load, machine), not on the cell's definition.
RUN_COLUMNS = {"cpu_per_simulated_s", "cpu_spread", "cpu_low", "cpu_high", "load_average", "platform", "cpu_count"}

QUICK = """\
[study]
name = "quick"
duration = 0.3
metrics = ["position_error", "energy_drift", "max_strain", "max_violation", "stability"]

[reference]
rtol = 1e-10

[[scene]]
setup = "swinging_chain"
args = { links = 5, compliance = 1e-6 }

[[method]]
name = "xpbd"
dt = [0.0333, 0.00833]
iterations = [1, 20]

[[method]]
name = "pbd"
dt = 0.01
iterations = 5

[[method]]
name = "cvode"
rtol = [1e-3, 1e-6]
"""


def write(tmp_path: Path, text: str, name: str = "study.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def deterministic(table: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in RUN_COLUMNS} for row in table]


# ------------------------------------------------------------------------------------ schema


@pytest.mark.parametrize("bad, key, line", [
    ('iterations = [1, 0]', "method[0].iterations", 16),
    ('iterations = [1, 20]\nspeed = 3', "method[0].speed", 17),
    ('iterations = "many"', "method[0].iterations", 16),
])
def test_a_bad_method_key_names_file_line_and_key(tmp_path, bad, key, line):
    text = QUICK.replace("iterations = [1, 20]", bad)
    p = write(tmp_path, text)
    with pytest.raises(StudyError, match=re.escape(f"{p}:{line}: {key}: ")):
        load_study(p)


def test_other_schema_errors_name_the_key(tmp_path):
    cases = [
        (QUICK.replace('"max_violation"', '"smoothness"'), r":4: study.metrics: unknown metric 'smoothness'"),
        (QUICK.replace("links = 5", "linkz = 5"), r":11: scene\[0\].args: swinging_chain: .*linkz"),
        (QUICK.replace('name = "pbd"', 'name = "rk4"'), r":19: method\[1\].name: must be one of"),
        (QUICK.replace("dt = 0.01\n", ""), r":18: method\[1\]: missing key 'dt'"),
        (QUICK.replace("[reference]\nrtol = 1e-10\n", ""), r":4: study.metrics: position_error .*\[reference\]"),
        (QUICK.replace('setup = "swinging_chain"', 'file = "nowhere.toml"'), r":10: scene\[0\].file: .*nowhere"),
        (QUICK.replace('name = "pbd"', 'python = "no_such_module:Mine"'), r":19: method\[1\].python: cannot import"),
        (QUICK.replace("duration = 0.3", "duration = -1"), r":3: study.duration: must be a duration > 0 s"),
        (QUICK + '[[scene]]\nsetup = "swinging_chain"\n', r":26: scene\[1\].name: two scenes are called"),
        (QUICK.replace(", compliance = 1e-6 }", " }\ngrid = { compliance = [1e-6, -1.0] }"),
         r":12: scene\[0\].grid: swinging_chain\(compliance=-1.0\): "),
        (QUICK.replace("links = 5", "links = 5, angle = inf"), r":11: scene\[0\].args: must hold finite numbers"),
    ]
    for text, message in cases:
        with pytest.raises(StudyError, match=message):
            load_study(write(tmp_path, text))


def test_a_built_in_methods_own_settings_reach_its_cells(tmp_path):
    """A [[method]]'s settings (csb.method_info(name).settings) are part of its cells' definition,
    reach the stepper, and are checked when the file is read; a method with a `threads` setting
    runs on one thread unless the file says otherwise (its cost is one core's)."""
    text = QUICK + ('\n[[method]]\nname = "projective-dynamics"\nlabel = "pd-chebyshev"\ndt = 0.01\n'
                    'iterations = 20\nsettings = { chebyshev = true }\n')
    study = load_study(write(tmp_path, text))
    cell = [c for c in study.cells() if c.method == "pd-chebyshev"][0]
    assert cell.definition["method"] == dict(name="projective-dynamics", settings=dict(chebyshev=True))
    from csb.studies.study.cells import _make_stepper
    made = _make_stepper(cell.definition, cell.context, cell.params, 0.01, (0, -9.81, 0))
    assert made.chebyshev and made.threads == 1
    # no settings: the definition (and the key of every existing cell) is as before
    assert [c for c in study.cells() if c.method == "xpbd"][0].definition["method"] == dict(name="xpbd")
    for bad, message in [("settings = { chebyshev = 1.5 }", r"method\[3\].settings: setting 'chebyshev' must be true or false"),
                         ("settings = { chebyshevv = true }", r"method\[3\].settings: method 'projective-dynamics' has no "
                                                              r"setting 'chebyshevv'"),
                         ("settings = 3", r"method\[3\].settings: must be a table of the method's own settings")]:
        with pytest.raises(StudyError, match=message):
            load_study(write(tmp_path, text.replace("settings = { chebyshev = true }", bad)))


def test_cells_are_the_product_of_scenes_methods_and_grids(tmp_path):
    text = QUICK + '\n[[scene]]\nscene = "chain"\n'
    study = load_study(write(tmp_path, text))
    cells = study.cells()
    assert len(cells) == 2 * (2 * 2 + 1 + 2)
    assert [(c.scene, c.method, c.params) for c in cells[:4]] == [
        ("swinging_chain", "xpbd", dict(dt=0.0333, substeps=1, iterations=1)),
        ("swinging_chain", "xpbd", dict(dt=0.0333, substeps=1, iterations=20)),
        ("swinging_chain", "xpbd", dict(dt=0.00833, substeps=1, iterations=1)),
        ("swinging_chain", "xpbd", dict(dt=0.00833, substeps=1, iterations=20)),
    ]
    assert {c.scene for c in cells} == {"swinging_chain", "chain"}
    keys = [c.key for c in cells]
    assert len(set(keys)) == len(keys)
    assert keys == [c.key for c in load_study(write(tmp_path, text)).cells()]  # a key is the definition's
    # A scene file's bytes are part of its cells' keys; the file's path is not.
    scene = tmp_path / "my_chain.toml"
    scene.write_bytes(csb.find_scene("chain").read_bytes())
    one = load_study(write(tmp_path, QUICK + '\n[[scene]]\nfile = "my_chain.toml"\n')).cells()[-1]
    scene.write_bytes(scene.read_bytes() + b"\n# changed\n")
    two = load_study(write(tmp_path, QUICK + '\n[[scene]]\nfile = "my_chain.toml"\n')).cells()[-1]
    assert one.key != two.key and cell_key(one.definition) == one.key
    assert one.definition["csb"]["build"] == csb.build_info()


# ------------------------------------------------------------------------------------ running


def test_a_rerun_of_an_unchanged_study_computes_nothing(tmp_path):
    p = write(tmp_path, QUICK)
    first = run_study(p, out=tmp_path / "out", workers=0)
    assert (first.computed, first.reused, first.failed) == (7, 0, 0)
    assert all(r["status"] == "ok" for r in first.table)
    cells = sorted((tmp_path / "out" / "cells").glob("*.json"))
    assert len(cells) == 7
    # The Parquet table is written when pyarrow (the 'study' extra) is installed.
    names = ("results.csv", "report.md", "results.parquet", "accuracy_cost.png")
    outputs = [tmp_path / "out" / n for n in names if n != "results.parquet" or importlib.util.find_spec("pyarrow")]
    stamps = {f: f.stat().st_mtime_ns for f in cells + outputs}
    again = run_study(p, out=tmp_path / "out", workers=0)
    assert (again.computed, again.reused) == (0, 7)
    assert again.table == first.table
    assert {f: f.stat().st_mtime_ns for f in cells + outputs} == stamps  # nothing computed, nothing rewritten
    assert all(f.stat().st_size > 0 for f in outputs) and again.files == outputs
    report = (tmp_path / "out" / "report.md").read_text()
    assert report.startswith("## Study: quick") and "7 cells" in report and "| cvode | rtol=1e-06 |" in report
    rows = {(r["method"], r["dt"], r["iterations"], r["rtol"]): r for r in first.table}
    # More iterations bring XPBD closer to the reference, and CVODE at 1e-6 is closer than any.
    assert rows[("xpbd", 0.00833, 20, None)]["position_error"] < rows[("xpbd", 0.00833, 1, None)]["position_error"]
    assert rows[("cvode", None, None, 1e-6)]["position_error"] < 1e-6


@needs_dask
def test_a_two_worker_local_cluster_equals_the_serial_run_cell_by_cell(tmp_path):
    p = write(tmp_path, QUICK)
    serial = run_study(p, out=tmp_path / "serial", workers=0)
    on_dask = run_study(p, out=tmp_path / "dask", workers=2)
    assert on_dask.computed == serial.computed == 7
    assert deterministic(on_dask.table) == deterministic(serial.table)  # metrics bit-equal
    for a, b in zip(serial.table, on_dask.table):
        assert a["key"] == b["key"] and a["position_error"] == b["position_error"]


KILL = """\
[study]
name = "kill"
duration = 1.0
metrics = ["max_strain", "stability"]

[[scene]]
setup = "hanging_cloth"
args = { n = 24 }

[[method]]
name = "small-steps"
dt = 0.0166
substeps = [100, 101, 102, 103, 104, 105, 106, 107]
"""


def test_a_study_killed_midway_resumes_computing_only_the_missing_cells(tmp_path):
    p = write(tmp_path, KILL)
    out = tmp_path / "out"
    cells_dir = out / "cells"
    log = tmp_path / "stderr.txt"
    with open(log, "wb") as err:
        proc = subprocess.Popen([sys.executable, "-m", "csb.cli", "study", "run", str(p), "--out", str(out),
                                 "--workers", "0", "--quiet"], stdout=subprocess.DEVNULL, stderr=err)
        deadline = time.monotonic() + 60
        try:
            while time.monotonic() < deadline and proc.poll() is None:
                if len(list(cells_dir.glob("*.json"))) >= 2:
                    break
                time.sleep(0.02)
            os.kill(proc.pid, signal.SIGKILL)
        finally:
            proc.wait()
    before = {f.name: (f.stat().st_mtime_ns, f.read_bytes()) for f in cells_dir.glob("*.json")}
    assert 2 <= len(before) < 8, f"killed with {len(before)} of 8 cells stored: {log.read_text()}"
    assert all(json.loads(b)["status"] == "ok" for _, b in before.values())

    resumed = run_study(p, out=out, workers=0)
    assert resumed.reused == len(before)
    assert resumed.computed == 8 - len(before)
    assert resumed.failed == 0
    for name, (mtime, data) in before.items():  # the earlier cells were read, not recomputed
        assert (cells_dir / name).stat().st_mtime_ns == mtime and (cells_dir / name).read_bytes() == data

    whole = run_study(p, out=tmp_path / "whole", workers=0)
    assert deterministic(resumed.table) == deterministic(whole.table)


USER_MODULE = '''
import csb


class Wrapped(csb.Integrator):
    """XPBD through csb.make_integrator, stepped from Python; refuses dt below 5 ms."""

    def __init__(self, dt, iterations=10, gravity=(0.0, -9.81, 0.0)):
        super().__init__()
        if dt < 0.005:
            raise ValueError(f"Wrapped refuses dt = {dt} s")
        self.inner = csb.make_integrator("xpbd", dt, iterations=iterations, gravity=gravity)

    def name(self):
        return "wrapped-xpbd"

    def dt(self):
        return self.inner.dt()

    def step(self, model, state, steps=1, interrupt=None):
        self.inner.step(model, state, steps)
'''


def test_a_users_integrator_class_goes_through_a_study_and_a_failed_cell_does_not_stop_the_others(tmp_path):
    (tmp_path / "my_methods.py").write_text(USER_MODULE)
    p = write(tmp_path, """\
        [study]
        duration = 0.3
        metrics = ["position_error", "max_strain", "stability"]

        [reference]
        rtol = 1e-10

        [[scene]]
        setup = "swinging_chain"
        args = { links = 5, compliance = 1e-6 }

        [[method]]
        python = "my_methods:Wrapped"
        dt = [0.01, 0.001, 0.0075]
        iterations = 5

        [[method]]
        name = "xpbd"
        dt = [0.01, 0.0075]
        iterations = 5
        """)
    r = run_study(p, out=tmp_path / "out", workers=0)
    assert (r.computed, r.failed) == (5, 1)
    rows = {(row["method"], row["dt"]): row for row in r.table}
    bad = rows[("Wrapped", 0.001)]
    assert bad["status"] == "failed" and bad["error_type"] == "ValueError" and "refuses dt = 0.001" in bad["error"]
    assert bad["position_error"] is None
    for dt in (0.01, 0.0075):  # the user's class steps the built-in's bits
        mine, builtin = rows[("Wrapped", dt)], rows[("xpbd", dt)]
        assert mine["status"] == builtin["status"] == "ok"
        assert mine["position_error"] == builtin["position_error"] > 0
        assert mine["max_strain"] == builtin["max_strain"]
    assert "failed: swinging_chain / Wrapped dt=0.001" in r.summary()
    # A failed cell is kept as it is, and run again only when asked.
    again = run_study(p, out=tmp_path / "out", workers=0)
    assert (again.computed, again.reused, again.failed) == (0, 5, 1)
    retried = run_study(p, out=tmp_path / "out", workers=0, retry_failed=True)
    assert (retried.computed, retried.reused, retried.failed) == (1, 4, 1)
    # The module's source is part of the key: an edit runs its cells again, with the edited code
    # (in this process too, where the old module is already imported).
    (tmp_path / "my_methods.py").write_text(USER_MODULE.replace("dt < 0.005", "dt < 0.0005"))
    edited = run_study(p, out=tmp_path / "out", workers=0)
    assert (edited.computed, edited.reused, edited.failed) == (3, 2, 0)


def test_asking_for_dask_without_it_names_the_extra(tmp_path, monkeypatch):
    p = write(tmp_path, QUICK.replace("[1, 20]", "1").replace("[1e-3, 1e-6]", "1e-3"))
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # import fails as if not installed
    with pytest.raises(csb.ParameterError, match=r"csb\[study\]"):
        run_study(p, out=tmp_path / "a", workers=2)
    with pytest.raises(csb.ParameterError, match=r"csb\[study\]"):
        run_study(p, out=tmp_path / "a", scheduler="tcp://127.0.0.1:1")
    r = run_study(p, out=tmp_path / "b")  # the default runs in this process when Dask is missing
    assert r.computed == 4 and r.failed == 0


def test_a_metric_that_does_not_apply_to_a_scene_is_null_with_a_note(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.1
        metrics = ["volume_error", "max_strain", "stability"]

        [[scene]]
        setup = "hanging_tet_cube"
        args = { cells = 2 }

        [[scene]]
        scene = "pendulum"

        [[method]]
        name = "xpbd"
        dt = 0.01
        iterations = 5
        """)
    cube, pendulum = run_study(p, out=tmp_path / "out", workers=0).table
    assert cube["status"] == pendulum["status"] == "ok"
    assert 0 < cube["volume_error"] < 0.01 and cube["max_strain"] > 0 and cube["notes"] == ""
    assert pendulum["volume_error"] is None and pendulum["max_strain"] >= 0
    assert pendulum["notes"] == "volume_error: the scene has no tet volume constraints"


def test_a_scene_grid_sweeps_a_set_up_argument(tmp_path):
    p = write(tmp_path, """\
        [study]
        duration = 0.2
        metrics = ["max_strain", "stability"]

        [[scene]]
        name = "chain"
        setup = "swinging_chain"
        args = { links = 5 }
        grid = { compliance = [1e-6, 0.1] }

        [[method]]
        name = "xpbd"
        dt = 0.01
        iterations = [5, 20]
        """)
    study = load_study(p)
    assert [s.label for s in study.scenes] == ["chain compliance=1e-06", "chain compliance=0.1"]
    assert [s.definition["args"] for s in study.scenes] == [dict(links=5, compliance=1e-6), dict(links=5, compliance=0.1)]
    r = run_study(p, out=tmp_path / "out", workers=0)
    assert r.computed == 4 and r.failed == 0
    strain = {(row["scene"], row["iterations"]): row["max_strain"] for row in r.table}
    for it in (5, 20):  # a chain of links 1e5 times as compliant stretches more under XPBD
        assert strain[("chain compliance=0.1", it)] > 2 * strain[("chain compliance=1e-06", it)]


PEER_MODULE = '''
import csb


class Peer(csb.Integrator):
    """A peer's adapter in miniature: steps with the built-in XPBD, and its conformance check
    fails for the swinging chain (as a peer that cannot map it would)."""

    def __init__(self, dt, iterations=10, gravity=(0.0, -9.81, 0.0)):
        super().__init__()
        self.inner = csb.make_integrator("xpbd", dt, iterations=iterations, gravity=gravity)

    def name(self):
        return "peer"

    def dt(self):
        return self.inner.dt()

    def step(self, model, state, steps=1, interrupt=None):
        self.inner.step(model, state, steps)

    def conformance(self, model):
        return Outcome(model.num_particles != 6)  # the 5-link chain fails


class Outcome:
    def __init__(self, ok):
        self.ok = ok

    def __str__(self):
        return "peer: conforms" if self.ok else "peer: does not conform: the first step differs"
'''


def test_a_peer_that_fails_its_conformance_check_is_reported_not_measured(tmp_path):
    (tmp_path / "peers.py").write_text(PEER_MODULE)
    p = write(tmp_path, """\
        [study]
        duration = 0.3
        metrics = ["position_error", "stability"]

        [reference]
        rtol = 1e-10

        [[scene]]
        name = "five"
        setup = "swinging_chain"
        args = { links = 5, compliance = 1e-6 }

        [[scene]]
        name = "seven"
        setup = "swinging_chain"
        args = { links = 7, compliance = 1e-6 }

        [[method]]
        python = "peers:Peer"
        dt = 0.01
        iterations = 5
        """)
    r = run_study(p, out=tmp_path / "out", workers=0)
    rows = {row["scene"]: row for row in r.table}
    assert set(rows) == {"five", "seven"} and r.failed == 1
    bad, good = rows["five"], rows["seven"]
    assert bad["status"] == "failed" and bad["error_type"] == "PeerDoesNotConform"
    assert "does not conform: the first step differs" in bad["error"] and bad["position_error"] is None
    assert good["status"] == "ok" and good["position_error"] > 0


def test_a_study_with_profile_accuracy_reports_a_performance_profile(tmp_path):
    text = QUICK.replace('"stability"]\n', '"stability"]\nprofile_accuracy = 0.01\n', 1)
    r = run_study(write(tmp_path, text), out=tmp_path / "out", workers=0)
    report = (tmp_path / "out" / "report.md").read_text()
    assert "Performance profile (Dolan and Moré 2002) over 1 scene(s)" in report
    assert (tmp_path / "out" / "profile.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The key holds nothing of the profile: the same cells as without it.
    plain = run_study(write(tmp_path, QUICK, "plain.toml"), out=tmp_path / "out", workers=0)
    assert plain.computed == 0 and plain.reused == len(r.table)


@pytest.mark.parametrize("line, message", [
    ("profile_accuracy = 0", r"study\.profile_accuracy: must be a largest distance to the reference > 0 m"),
    ("profile_accuracy = -1e-3", r"study\.profile_accuracy: must be"),
])
def test_bad_profile_accuracy_is_named(tmp_path, line, message):
    text = QUICK.replace('"stability"]\n', f'"stability"]\n{line}\n', 1)
    with pytest.raises(StudyError, match=message):
        load_study(write(tmp_path, text))


def test_a_profile_needs_the_position_error(tmp_path):
    text = QUICK.replace('metrics = ["position_error", "energy_drift", "max_strain", "max_violation", "stability"]',
                         'metrics = ["stability"]\nprofile_accuracy = 0.01')
    with pytest.raises(StudyError, match="a performance profile needs the position_error metric"):
        load_study(write(tmp_path, text))


@pytest.mark.parametrize("content, message", [
    (b"[study]\nname = \"x\xff\"\n", r"study\.toml:2: not UTF-8 text \(byte 0xff"),
    (b"[study\n", r"study\.toml: not valid TOML"),
    (b"a = " + b"[" * 2000 + b"]" * 2000 + b"\n", r"study\.toml: arrays or inline tables nested too deeply to read"),
])
def test_a_study_file_that_is_not_toml_is_named(tmp_path, content, message):
    # Read by the same code as a scene file: a nesting tomllib cannot parse is a StudyError too.
    p = tmp_path / "study.toml"
    p.write_bytes(content)
    with pytest.raises(StudyError, match=message):
        load_study(p)
