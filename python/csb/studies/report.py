"""The main job: runs the bundled scenes, the study files, the validation scripts and the
benchmarks, keeps what each printed and wrote, and gathers it all into one Markdown page,
``<out>/report.md``.

    python -m csb.studies.report --studies validation --out out            # the quick tiers
    python -m csb.studies.report --studies validation --out out --full     # the full tiers

What runs, in order:

* the bundled scenes (``csb run`` and ``csb render``, two at a time), each into ``<out>/<scene>/``;
* the study files ``<studies>/studies/*.toml`` of the tier asked for (``tier = "quick"`` by
  default; with ``--full`` every file), on one Dask LocalCluster, each into
  ``<out>/studies/<name>/``; a study keeps its cells, so an unchanged one computes nothing;
* the validation scripts ``<studies>/*.py``, two at a time (but those in ALONE, which time the
  machine, alone after the others), each with ``--quick`` unless ``--full``, their files gathered
  into ``<out>/validation/`` (what a script printed is kept beside them as ``<script>.txt``);
* the benchmarks (``csb bench``: the quick tier's tables, QUICK_BENCH_PARTS, or with ``--full``
  every table; ``--no-bench`` skips them), into ``<out>/validation/benchmarks.txt``.

A scene, a script or the benchmarks whose inputs have not changed since they last ran (the
installed csb, to the byte, the script's source and its arguments) is not run again: its stored
output is used, and the page says when it was measured. ``--fresh`` runs everything again.
Nothing in the page is typed by hand: it is what a run measured.
"""

from __future__ import annotations

import argparse
import ast
import datetime
import hashlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

# The bundled scenes the main job runs: cloth from a mesh file, cloth on colliders, a tet soft
# body, a balloon, tearing.
SCENES = ("cloth_drop", "cloth_sphere", "cloth_table", "soft_cube_drop", "balloon_squeeze", "cloth_tear")
PARALLEL = 2  # scenes and scripts run two at a time (the studies on a LocalCluster of as many workers)
ALONE = ("machine_limits.py",)  # validation scripts that run alone, after the others (they time the machine)
# The benchmark tables of the quick tier (about 2 minutes on a 2-core machine); the full tier
# prints every table (csb bench --help lists them: front ends, frames per second of big cloths,
# cost per particle up to a million, a million-particle cloth, the reference's KLU cost, ...).
QUICK_BENCH_PARTS = ("step", "dispatch", "xpbd", "precision", "types", "threads", "memory", "viewer")


@dataclass
class Section:
    """One study script's entry in the report: what it is, what it printed, what it wrote."""

    name: str
    summary: str
    output: str
    returncode: int
    seconds: float
    files: list[Path] = field(default_factory=list)
    measured: str = ""       # when it ran (ISO date and time, UTC)
    reused: bool = False     # its stored output, its inputs unchanged


# ------------------------------------------------------------------------------------ the cache


def csb_fingerprint() -> str:
    """SHA-256 of the installed csb package, every file to the byte (its Python modules, the
    compiled module, its scenes), and of the Python running it: what a stored result depends on
    besides its own inputs."""
    import csb

    root = Path(csb.__file__).parent
    h = hashlib.sha256(sys.version.encode())
    for f in sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        h.update(str(f.relative_to(root)).encode() + b"\0")
        h.update(hashlib.sha256(f.read_bytes()).digest())
    return h.hexdigest()


def _sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


class Cache:
    """Stored results of the job's commands, one JSON file each in ``<out>/.cache/``: the key of
    their inputs, when they ran, how long they took, their exit status, what they printed, the
    files they wrote. A result is used again only if its key matches and its files exist."""

    def __init__(self, out: Path, fingerprint: str, fresh: bool):
        self.folder = out / ".cache"
        self.fingerprint = fingerprint
        self.fresh = fresh

    def key(self, *parts: str | bytes) -> str:
        h = hashlib.sha256(self.fingerprint.encode())
        for p in parts:
            h.update(hashlib.sha256(p if isinstance(p, bytes) else p.encode()).digest())
        return h.hexdigest()

    def get(self, name: str, key: str) -> dict | None:
        if self.fresh:
            return None
        try:
            entry = json.loads((self.folder / f"{name}.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        if entry.get("key") != key or entry.get("returncode") != 0:
            return None  # changed, or failed last time: run again
        files = entry.get("files", {})
        if not isinstance(files, dict) or any(_sha256(Path(f)) != h for f, h in files.items()):
            return None  # a file it wrote is gone or was overwritten (by the other tier, say)
        entry["files"] = list(files)
        return entry

    def put(self, name: str, key: str, **entry) -> dict:
        entry = dict(entry, key=key, files={f: _sha256(Path(f)) for f in entry.get("files", [])})
        self.folder.mkdir(parents=True, exist_ok=True)
        tmp = self.folder / f".{name}.json.tmp"
        tmp.write_text(json.dumps(entry, indent=1), encoding="utf-8")
        os.replace(tmp, self.folder / f"{name}.json")
        return entry


# ------------------------------------------------------------------------------------ running


def _docstring_summary(script: Path) -> str:
    doc = ast.get_docstring(ast.parse(script.read_text(encoding="utf-8"))) or ""
    return " ".join(doc.split("\n\n")[0].split())


def _run(cmd: list[str], log: Path | None = None, echo: bool = True) -> tuple[int, str]:
    """Runs ``cmd``; returns its exit status and output (stdout and stderr), echoed line by line
    when ``echo`` and kept in ``log``."""
    lines = []
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1) as p:
        assert p.stdout is not None
        for line in p.stdout:
            if echo:
                sys.stdout.write(line)
                sys.stdout.flush()
            lines.append(line)
    text = "".join(lines)
    if log is not None:
        log.write_text(text, encoding="utf-8")
    return p.returncode, text


def run_study(script: Path, out: Path, *, quick: bool = False, cache: Cache | None = None,
              echo: bool = True) -> Section:
    """Runs one study script into ``out``, in a folder of its own first, so that two can run at
    once: the files it wrote are moved into ``out`` and listed in its section."""
    args = ["--quick"] if quick and "--quick" in script.read_text(encoding="utf-8") else []
    summary = _docstring_summary(script)
    key = cache.key(script.read_bytes(), " ".join(args)) if cache else ""
    if cache is not None and (hit := cache.get(f"script-{script.stem}", key)) is not None:
        print(f"[report] study: {script} (unchanged since {hit['measured']}: its stored output)", flush=True)
        return Section(script.stem, summary, hit["output"], 0, hit["seconds"], [Path(f) for f in hit["files"]],
                       hit["measured"], reused=True)
    print(f"[report] study: {script} {' '.join(args)}".rstrip(), flush=True)
    work = out / ".work" / script.stem
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    start = time.time()
    code, text = _run([sys.executable, str(script), "--out", str(work), *args], echo=echo)
    seconds = time.time() - start
    text = text.replace(str(work), str(out))  # the files it names are moved there below
    (out / f"{script.stem}.txt").write_text(text, encoding="utf-8")
    files = []
    for f in sorted(work.iterdir()):
        if f.is_file():
            target = out / f.name
            os.replace(f, target)
            if f.suffix in (".png", ".csv"):
                files.append(target)
    shutil.rmtree(work, ignore_errors=True)
    section = Section(script.stem, summary, text, code, seconds, files, _now())
    if cache is not None:
        cache.put(f"script-{script.stem}", key, output=text, seconds=seconds, returncode=code,
                  files=[str(f) for f in files], measured=section.measured)
    return section


def run_scene(scene: str, out: Path, cache: Cache | None = None) -> tuple[str, bool]:
    """``csb run`` and ``csb render`` of a bundled scene into ``out/<scene>``; returns what they
    printed (also in ``run.txt``) and whether it was the stored output."""
    folder = out / scene
    key = cache.key("scene", scene) if cache else ""
    if cache is not None and (hit := cache.get(f"scene-{scene}", key)) is not None:
        return hit["output"], True
    folder.mkdir(parents=True, exist_ok=True)
    csb_cli = [sys.executable, "-m", "csb.cli"]
    code, text = _run([*csb_cli, "run", scene, "--out", str(folder), "--quiet"], echo=False)
    if code == 0:
        code, more = _run([*csb_cli, "render", scene, "--every", "60", "--out", str(folder / "render")], echo=False)
        text += more
    (folder / "run.txt").write_text(text, encoding="utf-8")
    if cache is not None:
        files = [str(f) for f in (folder / "run.txt", folder / "snapshot.png", folder / "summary.png") if f.is_file()]
        cache.put(f"scene-{scene}", key, output=text, returncode=code, files=files, measured=_now(), seconds=0.0)
    if code != 0:
        raise RuntimeError(f"csb run/render {scene} exited with status {code}:\n{text}")
    return text, False


@dataclass
class StudySection:
    """A study file's entry: its report section (Markdown), its folder, how it went."""

    name: str
    path: Path
    folder: Path
    markdown: str
    seconds: float
    computed: int
    reused: int
    failed: int
    error: str | None = None


def run_study_files(files: list[Path], out: Path) -> list[StudySection]:
    """Runs the study files on one LocalCluster (started only if a study has cells to compute),
    each into ``out/studies/<name>``."""
    from .study import load_study, run_study as run_study_file
    from .study.cells import _read_record

    def pending(path: Path) -> bool:
        try:
            st = load_study(path)
        except Exception:
            return False  # reported below
        cells = out / "studies" / st.name / "cells"
        return any(_read_record(cells / f"{c.key}.json") is None for c in st.cells())

    sections = []
    cluster = client = None
    try:
        if not any(pending(f) for f in files):
            pass
        elif importlib.util.find_spec("dask") is None:
            print("[report] Dask (csb's 'study' extra) is not installed: the studies run in this process", flush=True)
        else:
            from dask.distributed import Client, LocalCluster

            cluster = LocalCluster(n_workers=PARALLEL, threads_per_worker=1, processes=True, dashboard_address=":0",
                                   silence_logs=40)
            client = Client(cluster)
        for f in files:
            print(f"[report] study file: {f}", flush=True)
            start = time.time()
            try:
                st = load_study(f)
                r = run_study_file(f, out=out / "studies" / st.name, progress=True,
                                   **(dict(scheduler=cluster.scheduler_address) if cluster else dict(workers=0)))
            except Exception as e:  # a study that cannot run is reported, the others go on
                sections.append(StudySection(f.stem, f, out / "studies", "", time.time() - start, 0, 0, 0,
                                             f"{type(e).__name__}: {e}"))
                print(f"[report] {f}: {type(e).__name__}: {e}", flush=True)
                continue
            print(r.summary(), flush=True)
            sections.append(StudySection(st.name, f, r.out, r.report(), time.time() - start, r.computed, r.reused,
                                         r.failed))
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    return sections


# ------------------------------------------------------------------------------------ the page


def _block(text: str) -> str:
    return "```text\n" + text.rstrip() + "\n```\n"


def _study_markdown(s: StudySection, out: Path) -> list[str]:
    """A study's own report section, its images' links made relative to ``out``, with a line on how
    its run went."""
    rel = s.folder.relative_to(out).as_posix() if s.folder.is_relative_to(out) else s.folder.as_posix()
    lines = []
    for line in s.markdown.splitlines():
        if line.startswith("!["):
            alt, _, target = line.partition("](")
            line = f"{alt}]({rel}/{target}"
        lines.append(line)
    lines.insert(1, "")
    lines.insert(2, f"{s.seconds:.0f} s: {s.computed} cells computed, {s.reused} stored cells used"
                    f"{f', {s.failed} failed' if s.failed else ''}; outputs in `{rel}/` (table `results.csv`).")
    return lines + [""]


def write_report(out: Path, sections: list[Section], bench: str | None, bench_code: int,
                 studies: list[StudySection] | None = None, tier: str = "quick", bench_measured: str = "",
                 seconds: float | None = None) -> Path:
    """Writes ``out/report.md``: the bundled scenes run into ``out/<scene>``, the study files'
    sections, the scripts' sections and the benchmark output."""
    studies = studies or []
    lines = ["# csb: the main job's report", "",
             f"Written by `python -m csb.studies.report` (run by `./dev run`), the {tier} tiers of the studies. "
             "Every figure below was measured by a run of the job: this one, or an earlier one whose inputs (the "
             "installed csb, to the byte, and the script) are unchanged, as the section says. The methods and "
             "their papers are described in `papers/` of the repository."
             + (f" This run of the job took {seconds:.0f} s of wall time (after the set-up)." if seconds is not None
                else ""), ""]
    failed = ([s.name for s in studies if s.error] + [s.name for s in sections if s.returncode != 0]
              + (["benchmarks"] if bench_code != 0 else []))
    if failed:
        lines += [f"**Failed:** {', '.join(failed)} (their output below says why).", ""]
    lines += ["## Contents", ""]
    scenes = sorted(d for d in out.iterdir() if d.is_dir() and (d / "run.txt").exists())
    for d in scenes:
        lines.append(f"- [Scene {d.name}](#scene-{d.name})")
    for s in studies:
        lines.append(f"- [Study: {s.name}](#study-{s.name}) ({s.seconds:.0f} s)")
    for s in sections:
        lines.append(f"- [{s.name}](#{s.name}) ({s.seconds:.0f} s{', stored' if s.reused else ''})")
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
    for s in studies:
        if s.error:
            lines += [f"## Study: {s.name}", "", f"`csb study run {s.path}` failed: {s.error}", ""]
        else:
            lines += _study_markdown(s, out)
    for s in sections:
        when = (f"measured {s.measured} and stored: its inputs are unchanged" if s.reused
                else f"measured {s.measured}" if s.measured else "")
        lines += [f"## {s.name}", "", s.summary, "",
                  f"`validation/{s.name}.py`, {s.seconds:.0f} s, exit status {s.returncode}"
                  + (f"; {when}" if when else "") + ".", "", _block(s.output)]
        for f in s.files:
            if f.suffix == ".png":
                lines += [f"![{s.name}: {f.stem}](validation/{f.name})", ""]
        tables = [f.name for f in s.files if f.suffix == ".csv"]
        if tables:
            lines += ["Tables: " + ", ".join(f"[`{t}`](validation/{t})" for t in tables), ""]
    if bench is not None:
        lines += ["## Benchmarks", "",
                  "`csb bench`: medians of timed rounds on this machine; compare ratios within one run"
                  + (f" (measured {bench_measured})" if bench_measured else "") + ".", "", _block(bench)]
    path = out / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m csb.studies.report", description=__doc__.split("\n\n")[0])
    parser.add_argument("--studies", default="validation",
                        help="directory of study scripts, with the study files in its studies/ (default: validation)")
    parser.add_argument("--out", default="out", help="output directory (default: out); scripts write to OUT/validation, "
                                                     "study files to OUT/studies/<name>")
    parser.add_argument("--full", action="store_true", help="the full tiers: every study file, the scripts without "
                                                            "--quick (tens of minutes)")
    parser.add_argument("--scenes", action="store_true", help="run the bundled scenes first (csb run, csb render)")
    parser.add_argument("--fresh", action="store_true", help="run everything again, stored results or not")
    parser.add_argument("--no-bench", action="store_true", help="skip the benchmarks")
    parser.add_argument("--bench-args", nargs=argparse.REMAINDER, default=[],
                        help="arguments passed on to 'csb bench' (must come last)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    vdir = out / "validation"
    vdir.mkdir(parents=True, exist_ok=True)
    folder = Path(args.studies)
    scripts = sorted(folder.glob("*.py"))
    study_files = sorted((folder / "studies").glob("*.toml"))
    if not scripts and not study_files:
        parser.error(f"no study scripts or study files in {args.studies}")
    tier = "full" if args.full else "quick"
    cache = Cache(out, csb_fingerprint(), args.fresh)
    start = time.time()
    failures = 0
    if args.scenes:
        print(f"[report] scenes: {', '.join(SCENES)}", flush=True)
        with ThreadPoolExecutor(PARALLEL) as pool:
            for scene, outcome in zip(SCENES, pool.map(lambda s: _scene_or_error(s, out, cache), SCENES)):
                text, reused = outcome
                print(f"[report] scene {scene}{' (unchanged: its stored output)' if reused else ''}:\n{text.rstrip()}",
                      flush=True)
                failures += reused is None
    if study_files:
        chosen = [f for f in study_files if args.full or _tier(f) == "quick"]
        studies = run_study_files(chosen, out)
    else:
        studies = []
    # The scripts that measure the machine itself run alone, after the others: a script beside
    # them would take half of what they measure.
    together = [s for s in scripts if s.name not in ALONE]
    with ThreadPoolExecutor(PARALLEL) as pool:
        done = dict(zip(together, pool.map(lambda s: run_study(s, vdir, quick=not args.full, cache=cache, echo=False),
                                           together)))
    for s in scripts:
        if s.name in ALONE:
            done[s] = run_study(s, vdir, quick=not args.full, cache=cache, echo=False)
    sections = [done[s] for s in scripts]
    for s in sections:
        print(f"[report] {s.name}: exit status {s.returncode}, {s.seconds:.0f} s{' (stored)' if s.reused else ''}",
              flush=True)
        if s.returncode != 0:
            print(s.output, flush=True)
    bench, bench_code, bench_measured = None, 0, ""
    if not args.no_bench:
        if not args.bench_args and not args.full:
            args.bench_args = ["--parts", *QUICK_BENCH_PARTS]
        key = cache.key("bench", " ".join(args.bench_args))
        hit = cache.get("bench", key)
        if hit is not None:
            print(f"[report] benchmarks: unchanged since {hit['measured']}: their stored figures", flush=True)
            bench, bench_measured = hit["output"], f"{hit['measured']} and stored: csb is unchanged"
            (vdir / "benchmarks.txt").write_text(bench, encoding="utf-8")
        else:
            print("[report] benchmarks (figures, not tests)", flush=True)
            bench_code, bench = _run([sys.executable, "-m", "csb.cli", "bench", *args.bench_args],
                                     vdir / "benchmarks.txt")
            bench_measured = _now()
            cache.put("bench", key, output=bench, returncode=bench_code, files=[str(vdir / "benchmarks.txt")],
                      measured=bench_measured, seconds=0.0)
    path = write_report(out, sections, bench, bench_code, studies, tier, bench_measured, time.time() - start)
    print(f"[report] wrote {path} ({time.time() - start:.0f} s)")
    # A study's failed cells are results (a peer not installed, a method that refuses a scene), in
    # its section; a study that cannot run at all fails the job.
    failed = failures or any(s.returncode for s in sections) or bench_code or any(s.error for s in studies)
    return 1 if failed else 0


def _tier(path: Path) -> str:
    """A study file's tier; "quick" if it cannot be read (so that it runs, and its error is reported)."""
    from .study import load_study

    try:
        return load_study(path).tier
    except Exception:
        return "quick"


def _scene_or_error(scene: str, out: Path, cache: Cache) -> tuple[str, bool | None]:
    try:
        return run_scene(scene, out, cache)
    except RuntimeError as e:
        return str(e), None


if __name__ == "__main__":
    sys.exit(main())
