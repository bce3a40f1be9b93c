"""The main job's report: runs the validation studies and the benchmarks, keeps what each printed
and wrote, and gathers it all into one Markdown page, ``<out>/report.md``.

    python -m csb.studies.report --studies validation --out out

Every study is a script that takes ``--out DIR`` and writes CSV and PNG files there; its printed
findings are kept beside them as ``<study>.txt``. The page has, per study, the first paragraph of
its docstring, what it printed, its charts and the list of its tables; then the benchmark tables
(``benchmarks.txt``); and first, every scene run into ``<out>/<scene>/`` by ``./dev run``
(its printed summary ``run.txt``, a picture of its last frame and its energy/strain chart).
Nothing in the page is typed by hand: it is what the run measured.
"""

from __future__ import annotations

import argparse
import ast
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Section:
    """One study's entry in the report: what it is, what it printed, what it wrote."""

    name: str
    summary: str
    output: str
    returncode: int
    seconds: float
    files: list[Path] = field(default_factory=list)


def _docstring_summary(script: Path) -> str:
    doc = ast.get_docstring(ast.parse(script.read_text(encoding="utf-8"))) or ""
    return " ".join(doc.split("\n\n")[0].split())


def _run_teed(cmd: list[str], log: Path) -> tuple[int, str]:
    """Runs ``cmd``, echoing its output line by line and keeping it in ``log``."""
    lines = []
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1) as p:
        assert p.stdout is not None
        for line in p.stdout:
            sys.stdout.write(line)
            sys.stdout.flush()
            lines.append(line)
    text = "".join(lines)
    log.write_text(text, encoding="utf-8")
    return p.returncode, text


def run_study(script: Path, out: Path) -> Section:
    """Runs one study script into ``out`` and returns its section (the files it wrote are the
    files of ``out`` modified while it ran)."""
    print(f"[report] study: {script}", flush=True)
    start = time.time()
    code, text = _run_teed([sys.executable, str(script), "--out", str(out)], out / f"{script.stem}.txt")
    files = sorted(f for f in out.iterdir()
                   if f.is_file() and f.suffix in (".png", ".csv") and f.stat().st_mtime >= start - 1e-3)
    return Section(script.stem, _docstring_summary(script), text, code, time.time() - start, files)


def _block(text: str) -> str:
    return "```text\n" + text.rstrip() + "\n```\n"


def write_report(out: Path, sections: list[Section], bench: str | None, bench_code: int) -> Path:
    """Writes ``out/report.md`` from the studies' sections, the benchmark output and, if it exists,
    the bundled scene run in ``out/cloth_drop``."""
    lines = ["# csb: the main job's report", "",
             "Written by `python -m csb.studies.report` (run by `./dev run`). Every figure below was measured in this run; "
             "the charts and CSV tables are in `validation/`. The methods and their papers are described in "
             "`papers/` of the repository.", ""]
    failed = [s.name for s in sections if s.returncode != 0] + (["benchmarks"] if bench_code != 0 else [])
    if failed:
        lines += [f"**Failed:** {', '.join(failed)} (their output below says why).", ""]
    lines += ["## Contents", ""]
    scenes = sorted(d for d in out.iterdir() if d.is_dir() and (d / "run.txt").exists())
    for d in scenes:
        lines.append(f"- [Scene {d.name}](#scene-{d.name})")
    for s in sections:
        lines.append(f"- [{s.name}](#{s.name}) ({s.seconds:.0f} s)")
    if bench is not None:
        lines.append("- [Benchmarks](#benchmarks)")
    lines.append("")
    for d in scenes:
        lines += [f"## Scene {d.name}", "", f"`csb run {d.name}`; outputs in `{d.name}/` (open the `.pvd` in ParaView).",
                  "", _block((d / "run.txt").read_text(encoding="utf-8")), ""]
        if (d / "snapshot.png").exists():
            lines += [f"![{d.name}: the last frame]({d.name}/snapshot.png)", ""]
        if (d / "summary.png").exists():
            lines += [f"![{d.name}: energy and strain against time]({d.name}/summary.png)", ""]
    for s in sections:
        lines += [f"## {s.name}", "", s.summary, "",
                  f"`validation/{s.name}.py`, {s.seconds:.0f} s, exit status {s.returncode}.", "", _block(s.output)]
        for f in s.files:
            if f.suffix == ".png":
                lines += [f"![{s.name}: {f.stem}](validation/{f.name})", ""]
        tables = [f.name for f in s.files if f.suffix == ".csv"]
        if tables:
            lines += ["Tables: " + ", ".join(f"[`{t}`](validation/{t})" for t in tables), ""]
    if bench is not None:
        lines += ["## Benchmarks", "",
                  "`csb bench`: medians of timed rounds on this machine; compare ratios within one run.", "",
                  _block(bench)]
    path = out / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m csb.studies.report", description=__doc__.split("\n\n")[0])
    parser.add_argument("--studies", default="validation", help="directory of study scripts (default: validation)")
    parser.add_argument("--out", default="out", help="output directory (default: out); studies write to OUT/validation")
    parser.add_argument("--no-bench", action="store_true", help="skip the benchmarks")
    parser.add_argument("--bench-args", nargs=argparse.REMAINDER, default=[],
                        help="arguments passed on to 'csb bench' (must come last)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    vdir = out / "validation"
    vdir.mkdir(parents=True, exist_ok=True)
    scripts = sorted(Path(args.studies).glob("*.py"))
    if not scripts:
        parser.error(f"no study scripts in {args.studies}")
    sections = [run_study(s, vdir) for s in scripts]
    bench, bench_code = None, 0
    if not args.no_bench:
        print("[report] benchmarks (figures, not tests)", flush=True)
        bench_code, bench = _run_teed([sys.executable, "-m", "csb.cli", "bench", *args.bench_args],
                                      vdir / "benchmarks.txt")
    path = write_report(out, sections, bench, bench_code)
    print(f"[report] wrote {path}")
    return 1 if any(s.returncode for s in sections) or bench_code else 0


if __name__ == "__main__":
    sys.exit(main())
