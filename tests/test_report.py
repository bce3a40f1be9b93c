"""The main job's report gathers what each study printed and wrote, and says when one failed."""

import subprocess
import sys
import textwrap

from csb.studies.report import main


def _study(path, body):
    path.write_text(textwrap.dedent(body))


def test_report_gathers_outputs_and_flags_failures(tmp_path):
    studies = tmp_path / "studies"
    studies.mkdir()
    _study(studies / "alpha.py", '''
        """Study: alpha, a made-up study.

        Second paragraph, not in the report."""
        import argparse, pathlib
        a = argparse.ArgumentParser(); a.add_argument("--out"); out = pathlib.Path(a.parse_args().out)
        (out / "alpha.csv").write_text("x,y\\n1,2\\n")
        (out / "alpha.png").write_bytes(b"\\x89PNG")
        print("alpha: measured 42")
    ''')
    _study(studies / "beta.py", '''
        """Study: beta, which fails."""
        raise SystemExit("beta: no reference available")
    ''')
    out = tmp_path / "out"
    (out / "drape").mkdir(parents=True)
    (out / "drape" / "run.txt").write_text("drape: 10 steps, max strain 1 %\n")
    (out / "drape" / "snapshot.png").write_bytes(b"\x89PNG")
    code = main(["--studies", str(studies), "--out", str(out), "--no-bench"])
    assert code == 1  # beta failed, so the main job fails
    report = (out / "report.md").read_text()
    assert "Study: alpha, a made-up study." in report and "Second paragraph" not in report
    assert "alpha: measured 42" in report
    assert "![alpha: alpha](validation/alpha.png)" in report
    assert "[`alpha.csv`](validation/alpha.csv)" in report
    assert "**Failed:** beta" in report and "beta: no reference available" in report
    assert (out / "validation" / "alpha.txt").read_text() == "alpha: measured 42\n"
    # Scenes run by ./dev run come first, with their summary and picture.
    assert "## Scene drape" in report and "drape: 10 steps, max strain 1 %" in report
    assert "![drape: the last frame](drape/snapshot.png)" in report
    assert report.index("## Scene drape") < report.index("## alpha")


def test_report_runs_as_module(tmp_path):
    studies = tmp_path / "s"
    studies.mkdir()
    _study(studies / "ok.py", '''
        """Study: ok."""
        print("fine")
    ''')
    r = subprocess.run([sys.executable, "-m", "csb.studies.report", "--studies", str(studies), "--out", str(tmp_path / "o"),
                        "--no-bench"], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "wrote" in r.stdout and (tmp_path / "o" / "report.md").exists()


COUNTING = '''
    """Study: counted, which counts its runs."""
    import argparse, pathlib
    a = argparse.ArgumentParser(); a.add_argument("--out"); a.add_argument("--quick", action="store_true")
    args = a.parse_args(); out = pathlib.Path(args.out)
    runs = pathlib.Path(__file__).with_suffix(".runs")
    runs.write_text(runs.read_text() + "x" if runs.exists() else "x")
    (out / "counted.csv").write_text("quick\\n" if args.quick else "full\\n")
    print("counted: quick" if args.quick else "counted: full")
'''

STUDY_FILE = '''
    [study]
    tier = "{tier}"
    name = "{name}"
    duration = 0.05
    metrics = ["max_strain", "stability"]

    [[scene]]
    setup = "swinging_chain"
    args = {{ links = 3, compliance = 1e-5 }}

    [[method]]
    name = "xpbd"
    dt = 0.01
    iterations = [1, 5]
'''


def test_a_second_run_with_nothing_changed_reuses_every_result_and_says_when_it_was_measured(tmp_path):
    studies = tmp_path / "studies"
    (studies / "studies").mkdir(parents=True)
    _study(studies / "counted.py", COUNTING)
    _study(studies / "studies" / "small.toml", STUDY_FILE.format(tier="quick", name="small"))
    _study(studies / "studies" / "big.toml", STUDY_FILE.format(tier="full", name="big"))
    out = tmp_path / "out"
    argv = ["--studies", str(studies), "--out", str(out), "--no-bench"]
    assert main(argv) == 0
    report = (out / "report.md").read_text()
    # The quick tier: the quick study file only, the script with --quick.
    assert "## Study: small" in report and "## Study: big" not in report
    assert "counted: quick" in report and (out / "validation" / "counted.csv").read_text() == "quick\n"
    assert "2 cells computed, 0 stored cells used" in report
    assert main(argv) == 0  # nothing changed: nothing runs
    report = (out / "report.md").read_text()
    assert (studies / "counted.runs").read_text() == "x"
    assert "0 cells computed, 2 stored cells used" in report
    assert "and stored: its inputs are unchanged" in report and "counted: quick" in report
    # The full tier runs every study file and the script without --quick; its outputs overwrite
    # the quick ones, so that going back to the quick tier runs the script again.
    assert main(argv + ["--full"]) == 0
    report = (out / "report.md").read_text()
    assert "## Study: small" in report and "## Study: big" in report and "counted: full" in report
    assert main(argv) == 0
    assert (studies / "counted.runs").read_text() == "xxx"
    assert (out / "validation" / "counted.csv").read_text() == "quick\n"
    # An edited script runs again; --fresh runs everything again.
    _study(studies / "counted.py", COUNTING.replace("which counts its runs", "which counts its runs, edited"))
    assert main(argv) == 0
    assert (studies / "counted.runs").read_text() == "xxxx"
    assert main(argv + ["--fresh"]) == 0
    assert (studies / "counted.runs").read_text() == "xxxxx"


def test_a_study_file_that_cannot_run_fails_the_job_and_failed_cells_do_not(tmp_path):
    studies = tmp_path / "studies"
    (studies / "studies").mkdir(parents=True)
    (studies / "studies" / "nope.py").write_text(textwrap.dedent("""\
        import csb

        class Nope(csb.Integrator):
            def __init__(self, dt):
                raise ValueError("Nope refuses every scene")
        """))
    refused = STUDY_FILE.format(tier="quick", name="refused") + '\n[[method]]\npython = "nope:Nope"\ndt = 0.01\n'
    _study(studies / "studies" / "refused.toml", refused)
    out = tmp_path / "out"
    argv = ["--studies", str(studies), "--out", str(out), "--no-bench"]
    assert main(argv) == 0  # a failed cell is a result
    report = (out / "report.md").read_text()
    assert "## Study: refused" in report and "Nope refuses every scene" in report and "**Failed:**" not in report
    _study(studies / "studies" / "broken.toml", STUDY_FILE.format(tier="quick", name="broken")
           .replace('setup = "swinging_chain"', 'setup = "no_such_set_up"'))
    assert main(argv) == 1
    report = (out / "report.md").read_text()
    assert "**Failed:** broken" in report and "no_such_set_up" in report
