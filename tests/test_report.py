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
