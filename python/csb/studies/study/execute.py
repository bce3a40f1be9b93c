"""Running a study: the missing cells on Dask (or in this process), their records stored as they
end, and the outputs (the tidy table as CSV and Parquet, the accuracy-against-cost chart, the
report section)."""

from __future__ import annotations

import csv
import importlib
import importlib.util
import io
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ... import _core
from . import charts as charts_module
from .cells import _machine, _read_record, _write_atomic, compute_reference, cost_range, run_cell
from .schema import _NEEDS_REFERENCE, _PARAMS, Cell, Study, cell_key, load_study


# ------------------------------------------------------------------------------------ execution


def _executor(workers: int | None, scheduler: str | None, jobs: int):
    """A function running [(fn, args)] and yielding (index, result or exception) as each ends."""
    want_dask = scheduler is not None or (workers is not None and workers > 0)
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        if want_dask:
            raise _core.ParameterError(
                "running a study on Dask (--workers N > 0 or --scheduler) needs dask.distributed: "
                "pip install 'csb[study]'") from None
        Client = None
    if Client is None or workers == 0 or (scheduler is None and jobs <= 1 and workers is None):
        def serial(tasks):
            for i, (fn, args) in enumerate(tasks):
                try:
                    yield i, fn(*args)
                except Exception as e:
                    yield i, e
        return serial, None

    if scheduler is not None:
        client = Client(scheduler)
        cluster = None
    else:
        n = workers if workers is not None else max(1, min(os.cpu_count() or 1, jobs))
        # The dashboard on a free port: two studies (or a study and a notebook) at once do not collide.
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=40)
        client = Client(cluster)

    def on_dask(tasks):
        futures = {client.submit(fn, *args, pure=False): i for i, (fn, args) in enumerate(tasks)}
        for f in as_completed(futures):
            try:
                yield futures[f], f.result()
            except Exception as e:
                yield futures[f], e
            finally:
                f.release()

    def close():
        client.close()
        if cluster is not None:
            cluster.close()

    return on_dask, close


@dataclass
class StudyResult:
    study: Study
    out: Path
    table: list[dict]                    # one row per cell, in the study's order
    computed: int = 0
    reused: int = 0
    failed: int = 0
    files: list[Path] = field(default_factory=list)
    references: dict[str, "Reference"] = field(default_factory=dict)  # by scene

    def summary(self) -> str:
        lines = [f"{self.study.name}: {len(self.table)} cells, {self.computed} computed, {self.reused} reused, "
                 f"{self.failed} failed"]
        for r in self.table:
            if r["status"] == "failed":
                lines.append(f"  failed: {r['scene']} / {r['method']} {_param_text(r)}: {r['error_type']}: {r['error']}")
        return "\n".join(lines)

    def _profile_lines(self) -> list[str]:
        target = self.study.profile_accuracy
        prof = _profile(self)
        if prof is None:
            return [f"Performance profile at {target:g} m: no scene is solved to that accuracy by any method.", ""]
        taus = [1.0, 2.0, 4.0, 10.0, 100.0]
        lines = [f"Performance profile (Dolan and Moré 2002) over {len(prof.problems)} scene(s): the share of "
                 f"scenes on which each method reaches a largest distance to the reference of {target:g} m "
                 f"within a factor τ of the cheapest method's cost.", "", "![performance profile](profile.png)", "",
                 "| method | " + " | ".join(f"τ = {t:g}" for t in taus) + " | solved |",
                 "|---|" + "---:|" * (len(taus) + 1)]
        for s in prof.methods:
            lines.append(f"| {s} | " + " | ".join(f"{prof.at(s, t):.2f}" for t in taus) + f" | {prof.solved(s):.2f} |")
        return lines + [""]

    def _budget_lines(self) -> list[str]:
        """The tuning budget: how many parameter settings each method had per scene."""
        counts = {m.label: math.prod(len(v) for v in m.grid.values()) for m in self.study.methods}
        same = len(set(counts.values())) == 1
        text = ", ".join(f"{m} {n}" for m, n in counts.items())
        if same:
            return [f"Tuning budget: every method had the same {next(iter(counts.values()))} parameter settings "
                    "per scene" + (" (the study's budget)." if self.study.budget else "."), ""]
        return [f"Tuning budget: not equal ({text} settings per scene): a method with more settings had more "
                "chances to reach a point of the front. Give the study a budget to hold every method to one.", ""]

    def _reference_lines(self) -> list[str]:
        lines = ["The continuous reference (CVODE) of each scene: its tolerance, its own error (its largest "
                 "distance from a run 100 times looser, an upper estimate of it) against the smallest error a "
                 "cell of the scene shows, and its energy drift.", "",
                 "| scene | rtol | atol | own error (m) | smallest cell error (m) | ratio | bound | energy drift |",
                 "|---|---:|---:|---:|---:|---:|---:|---:|"]

        def g(v: Any, fmt: str = ".3g") -> str:
            return "" if v is None else format(v, fmt)

        for scene, ref in self.references.items():
            if ref.x is None:
                lines.append(f"| {scene} | failed: {ref.error} | | | | | | |")
                continue
            ratio = None if ref.self_error is None or not ref.smallest_error else ref.self_error / ref.smallest_error
            bound = "" if ref.fraction is None else (f"≤ {ref.fraction:g}" + ("" if ref.met else ": not met"))
            lines.append(f"| {scene} | {g(ref.rtol, '.0e')} | {g(ref.atol, '.0e')} | {g(ref.self_error)} | "
                         f"{g(ref.smallest_error)} | {g(ratio)} | {bound} | {g(ref.energy_drift)} |")
        if any(r.met is False for r in self.references.values()):
            lines += ["", "Where the bound is not met, the reference could not be made accurate enough (rtol "
                      "reached its floor): errors near its own are not resolved."]
        return lines + [""]

    def report(self) -> str:
        """The study as a report section (Markdown): what it is, its cells, per scene the cells on
        the accuracy-against-cost front (when position_error is measured), what blew up or failed."""
        st = self.study
        lines = [f"## Study: {st.name}", ""]
        if st.description:
            lines += [st.description, ""]
        repeats = (f"{cells_auto_text()}" if st.repeats == "auto" else f"{st.repeats} run(s)")
        lines += [f"`csb study run {st.path}`: {len(self.table)} cells ({len(st.scenes)} scenes, {len(st.methods)} "
                  f"methods), {st.duration:g} s each, metrics at {st.outputs + 1} times. Cost: the median CPU time "
                  f"per simulated second, on one thread, after an untimed warm-up step, of {repeats}; the "
                  "machine's load average is in the table. Table: `results.csv`.", ""]
        lines += self._budget_lines()
        if self.references:
            lines += self._reference_lines()
        if "position_error" in st.metrics:
            lines += ["![accuracy against cost](accuracy_cost.png)", ""]
            for scene in st.scenes:
                if not scene.measures("position_error", st.metrics):
                    continue
                front = _front([r for r in self.table if r["scene"] == scene.label])
                ranks = _cost_ranks(front)
                lines += [f"{scene.label}: the cells no other cell beats in both error and cost. Cost rank: 1 + the "
                          "number of cells whose whole cost range (of the repeats: their range, from four runs the "
                          "quartiles) lies below the cell's; cells whose ranges overlap are ties, not a ranking.",
                          "", "| cost rank | method | parameters | largest distance to the reference (m) | "
                          "CPU s per simulated s (median, spread) |", "|---:|---|---|---:|---:|"]
                lines += [f"| {rank} | {r['method']} | {_param_text(r)} | {r['position_error']:.3g} | "
                          f"{r['cpu_per_simulated_s']:.3g} ({_range_text(r)}) |" for r, rank in zip(front, ranks)]
                lines.append("")
        for k, chart in enumerate(st.charts):
            lines += [f"![{_chart_title(chart)}](chart_{k + 1}.png)", ""]
        if st.profile_accuracy is not None:
            lines += self._profile_lines()
        blown = [r for r in self.table if r.get("stability") == "blew-up"]
        if blown:
            lines += ["Blew up: " + ", ".join(f"{r['scene']} / {r['method']} {_param_text(r)}" for r in blown), ""]
        failed = [r for r in self.table if r["status"] == "failed"]
        if failed:
            lines += ["Failed: " + "; ".join(f"{r['scene']} / {r['method']} {_param_text(r)}: {r['error_type']}: "
                                             f"{r['error']}" for r in failed), ""]
        return "\n".join(lines)


def _profile(result: "StudyResult"):
    """The performance profile of the study's methods over its scenes at profile_accuracy (None
    when no scene is solved by any method at that accuracy)."""
    from ..profiles import cost_to_accuracy, performance_profile

    rows = [r for r in result.table if r.get("stability") != "blew-up"]
    costs = cost_to_accuracy(rows, target=result.study.profile_accuracy, cost="cpu_per_simulated_s")
    try:
        return performance_profile(costs)
    except ValueError:
        return None


def cells_auto_text() -> str:
    from .cells import AUTO_BUDGET, AUTO_MAX, AUTO_MIN, AUTO_SPREAD

    return (f"as many runs as the spread asks (at least {AUTO_MIN}, until the spread of the costs — their range, "
            f"from four runs their interquartile range — is within {AUTO_SPREAD:.0%} of their median; at most "
            f"{AUTO_MAX} runs, or {AUTO_BUDGET:g} s of CPU time)")


def _cost_ranks(rows: list[dict]) -> list[int]:
    """Each row's cost rank: 1 + the number of rows whose whole cost range (cpu_low..cpu_high; a
    single run's cost alone) lies below its own. Rows whose ranges overlap are not ranked apart."""
    def span(r: dict) -> tuple[float, float]:
        lo, hi = r.get("cpu_low"), r.get("cpu_high")
        m = r["cpu_per_simulated_s"]
        return (m if lo is None else lo), (m if hi is None else hi)

    spans = [span(r) for r in rows]
    return [1 + sum(hi < lo for _, hi in spans) for lo, _ in spans]


def _range_text(row: dict) -> str:
    lo, hi = row.get("cpu_low"), row.get("cpu_high")
    if lo is None or hi is None:
        return "one run"
    n = row.get("repeats")
    return f"{'quartiles ' if n and n >= 4 else ''}{lo:.3g}-{hi:.3g}, {n} runs"


def _chart_title(chart: dict) -> str:
    if chart["title"]:
        return chart["title"]
    if chart["kind"] == "line":
        return f"{chart['y']} against {chart['x']}"
    return f"stability over {chart['x']} and {chart['y']}"


def _front(rows: list[dict]) -> list[dict]:
    """The rows no other row beats in both position_error and cost, cheapest first."""
    good = sorted((r for r in rows if r["status"] == "ok" and r.get("stability") != "blew-up"
                   and r.get("position_error") is not None and r.get("cpu_per_simulated_s") is not None),
                  key=lambda r: (r["cpu_per_simulated_s"], r["position_error"]))
    front, best = [], math.inf
    for r in good:
        if r["position_error"] < best:
            best = r["position_error"]
            front.append(r)
    return front


def _param_text(row: dict) -> str:
    return " ".join(f"{p}={row[p]:g}" for p in _PARAMS if row.get(p) is not None)


def run_study(path: str | os.PathLike[str], *, out: str | os.PathLike[str] | None = None, workers: int | None = None,
              scheduler: str | None = None, retry_failed: bool = False, progress: bool = False,
              extra_methods: tuple[str, ...] | list[str] = (), like: str | None = None) -> StudyResult:
    """Run the study file at ``path``: the cells without a stored result are computed (on Dask:
    ``scheduler`` an address, else a LocalCluster of ``workers`` processes, default one per core
    up to the cells; ``workers=0`` in this process), each stored as ``<out>/cells/<key>.json``
    (with its positions at the output times, ``<key>.npy``) as it ends; then the references the
    metrics need (their tolerance chosen, with ``rtol = "auto"``, from the smallest error the
    cells show against them), the table (``results.csv``, ``results.parquet`` with pyarrow), the
    charts and the report section are written to ``out`` (default ``out/studies/<name>``). A
    stored failed cell is run again only with ``retry_failed``. ``extra_methods`` and ``like``:
    methods the file does not name, over the grid of one it does (see :func:`load_study`)."""
    study = load_study(path, extra_methods=extra_methods, like=like)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise _core.ParameterError(f"workers must be an integer >= 0 (0: in this process), got {workers!r}")
    out_dir = Path(out) if out is not None else Path("out") / "studies" / study.name
    cells_dir = out_dir / "cells"
    cells = study.cells()
    records: dict[str, dict] = {}
    missing: list[Cell] = []
    seen: set[str] = set()
    for c in cells:
        if c.key in seen:
            continue
        seen.add(c.key)
        r = _read_record(cells_dir / f"{c.key}.json")
        if r is not None and r.get("has_positions") and not (cells_dir / f"{c.key}.npy").is_file():
            r = None  # its positions were lost: computed again
        if r is not None and (r["status"] == "ok" or not retry_failed):
            records[c.key] = r
        else:
            missing.append(c)
    reused = len(records)
    need_ref = any(s.measures(m, study.metrics) for s in study.scenes for m in _NEEDS_REFERENCE)
    run, close = None, None
    try:
        if missing or need_ref:
            run, close = _executor(workers, scheduler, max(len(missing), len(study.scenes) if need_ref else 0))
        if missing:
            _compute(study, missing, out_dir, records, run, progress)
        positions = _Positions(cells_dir)
        references = _references(study, cells, records, positions, out_dir, run) if need_ref else {}
    finally:
        if close is not None:
            close()
    table = [_row(study, c, records[c.key], positions, references.get(c.scene)) for c in cells]
    result = StudyResult(study, out_dir, table, computed=len(missing), reused=reused,
                         failed=sum(r["status"] == "failed" for r in table), references=references)
    result.files = _write_outputs(result)
    return result


class _Positions:
    """The cells' stored positions (T, N, 3), read once each."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.cache: dict[str, np.ndarray | None] = {}

    def __call__(self, key: str) -> np.ndarray | None:
        if key not in self.cache:
            try:
                self.cache[key] = np.load(self.folder / f"{key}.npy")
            except (OSError, ValueError):
                self.cache[key] = None
        return self.cache[key]


def _compute(study: Study, missing: list[Cell], out_dir: Path, records: dict[str, dict], run, progress: bool) -> None:
    from tqdm import tqdm

    bar = tqdm(total=len(missing), desc=study.name, unit="cell", disable=not progress)
    for i, value in run([(run_cell, (c.definition, c.context)) for c in missing]):
        c = missing[i]
        if isinstance(value, BaseException):  # the worker died, or the task could not run
            value = dict(key=c.key, machine={}, status="failed", error_type=type(value).__name__,
                         error=str(value), warnings=[])
        _store(out_dir, c, value, records)
        bar.update()
    bar.close()


@dataclass
class Reference:
    """The continuous reference of one scene, as the study chose it."""

    x: np.ndarray | None                  # (T, N, 3) m, None when it failed
    rtol: float | None = None
    atol: float | None = None
    energy_drift: float | None = None     # its own, relative (the energy_drift measure)
    self_error: float | None = None       # m: the largest distance of the run 100 times looser from it
    smallest_error: float | None = None   # m: the smallest position_error a cell of the scene shows
    fraction: float | None = None         # the study's bound on self_error / smallest_error
    met: bool | None = None               # whether the bound holds
    error: str | None = None              # why it failed
    cpu_s: float = 0.0                    # CPU time of the runs it took to choose it


def _reference_setting(study: Study, rtol: Any) -> dict[str, Any]:
    ref = study.reference
    assert ref is not None
    return dict(rtol=rtol, atol=ref["atol"] if rtol == ref["rtol"] else "auto", energy_tolerance=ref["energy_tolerance"])


def _reference_key(study: Study, scene, rtol: Any) -> str:
    return cell_key(dict(scene=scene.definition, duration=scene.definition.get("duration", study.duration),
                         outputs=study.outputs, reference=_reference_setting(study, rtol), csb=_core.build_info()))


def _references(study: Study, cells: list[Cell], records: dict[str, dict], positions: _Positions, out_dir: Path,
                run) -> dict[str, Reference]:
    """Each scene's reference. A fixed rtol is used as given. With rtol = "auto", the energy
    rule's tolerance (csb.energy_rtol) is the start; a run 100 times tighter measures its error,
    and the tolerance is tightened a hundredfold until that error is within ``fraction`` of the
    smallest error any cell of the scene shows against the tighter run (and, with the
    energy_drift metric, the tighter run's energy drift within ``fraction`` of the smallest drift
    a cell shows), or until RTOL_FLOOR; the tighter run is then the reference."""
    from ...reference import RTOL_FLOOR

    ref = study.reference
    assert ref is not None
    folder = out_dir / "references"
    stored: dict[str, tuple[np.ndarray | None, dict]] = {}

    def get(pending: list[tuple[Any, Any]]) -> None:
        """Compute (or read) the references [(scene, rtol)] not stored yet."""
        tasks, keys = [], []
        for scene, rtol in pending:
            k = _reference_key(study, scene, rtol)
            if k in stored or k in keys:
                continue
            try:
                stored[k] = (np.load(folder / f"{k}.npy"), json.loads((folder / f"{k}.json").read_text()))
                continue
            except (OSError, ValueError):
                pass
            tasks.append((compute_reference, (scene.definition, scene.context, _reference_setting(study, rtol),
                                              scene.definition.get("duration", study.duration), study.outputs)))
            keys.append(k)
        for i, value in (run(tasks) if tasks else ()):
            k = keys[i]
            if isinstance(value, BaseException):
                stored[k] = (None, dict(error=f"{type(value).__name__}: {value}"))
                continue
            x, info = value
            buf = io.BytesIO()
            np.save(buf, x)
            _write_atomic(folder / f"{k}.npy", buf.getvalue())
            _write_atomic(folder / f"{k}.json", json.dumps(info, sort_keys=True).encode())
            stored[k] = (x, info)

    def made(scene, rtol) -> tuple[np.ndarray | None, dict]:
        return stored[_reference_key(study, scene, rtol)]

    def smallest(scene, x: np.ndarray, metric: str) -> float | None:
        values = []
        for c in cells:
            r = records[c.key]
            if c.scene != scene.label or r["status"] != "ok" or r.get("metrics", {}).get("stability") == "blew-up":
                continue
            if metric == "position_error":
                p = positions(c.key)
                if p is not None and p.shape == x.shape:
                    values.append(float(np.linalg.norm(p - x, axis=2).max()))
            elif r.get("metrics", {}).get(metric) is not None:
                values.append(float(r["metrics"][metric]))
        values = [v for v in values if v > 0]
        return min(values) if values else None

    out: dict[str, Reference] = {}
    scenes = [s for s in study.scenes if s.measures("position_error", study.metrics)]
    if ref["rtol"] != "auto":
        get([(s, ref["rtol"]) for s in scenes])
        for s in scenes:
            x, info = made(s, ref["rtol"])
            out[s.label] = Reference(x, info.get("rtol"), info.get("atol"), info.get("energy_drift"),
                                     error=info.get("error"), cpu_s=info.get("cpu_s", 0.0))
        return out
    # rtol = "auto": level[scene] is the tolerance under test, its run 100 times tighter the check.
    get([(s, "auto") for s in scenes])
    level: dict[str, Any] = {}
    for s in scenes:
        x, info = made(s, "auto")
        if x is None:
            out[s.label] = Reference(None, error=info["error"])
        else:
            level[s.label] = "auto"
    fraction = ref["fraction"]
    def rtol_of(scene) -> float:  # the tolerance under test, as a number
        r = level[scene.label]
        return made(scene, "auto")[1]["rtol"] if r == "auto" else r

    while level:
        tighter = {s.label: rtol_of(s) / 100 for s in scenes if s.label in level}
        get([(s, tighter[s.label]) for s in scenes if s.label in level])
        for s in scenes:
            if s.label not in level:
                continue
            x0, _ = made(s, level[s.label])
            x1, info1 = made(s, tighter[s.label])
            if x1 is None:
                out[s.label] = Reference(None, error=info1["error"])
                del level[s.label]
                continue
            self_error = float(np.linalg.norm(x0 - x1, axis=2).max())
            e_min = smallest(s, x1, "position_error")
            met = e_min is None or self_error <= fraction * e_min
            if met and "energy_drift" in study.metrics:
                d_min = smallest(s, x1, "energy_drift")
                met = d_min is None or info1["energy_drift"] <= fraction * d_min
            if met or tighter[s.label] / 100 < RTOL_FLOOR * (1 - 1e-9):
                out[s.label] = Reference(x1, info1["rtol"], info1["atol"], info1["energy_drift"], self_error, e_min,
                                         fraction, met)
                del level[s.label]
            else:
                level[s.label] = tighter[s.label]
    return out


def _store(out_dir: Path, cell: Cell, record: dict, records: dict[str, dict]) -> None:
    record = dict(record, definition=cell.definition)
    x = record.pop("positions", None)
    record["has_positions"] = x is not None
    if x is not None:  # the positions first: the JSON file marks the cell done
        buf = io.BytesIO()
        np.save(buf, np.asarray(x, dtype=np.float64))
        _write_atomic(out_dir / "cells" / f"{cell.key}.npy", buf.getvalue())
    text = json.dumps(record, sort_keys=True, indent=1, allow_nan=True)
    _write_atomic(out_dir / "cells" / f"{cell.key}.json", text.encode())
    records[cell.key] = record


def _row(study: Study, cell: Cell, record: dict, positions: _Positions, reference: Reference | None) -> dict:
    row: dict[str, Any] = dict(study=study.name, scene=cell.scene, method=cell.method)
    for name in study.scene_parameters():  # the scene grids' arguments (a material swept, say)
        row[name] = cell.scene_params.get(name)
    for p in _PARAMS:
        row[p] = cell.params.get(p)
    row["dt_used"] = record.get("dt_used")
    row["steps"] = record.get("steps")
    values = record.get("metrics", {})
    notes = list(record.get("notes", []))
    for m in study.metrics:
        row[m] = values.get(m)
    measured = cell.definition["metrics"]
    notes += [f"{m}: not measured on this scene (its [[scene]] metrics)" for m in study.metrics if m not in measured]
    if "position_error" in measured and record["status"] == "ok" and values.get("stability") != "blew-up":
        x = positions(cell.key)
        if reference is None or reference.x is None:
            notes.append("position_error: the reference failed" + (f" ({reference.error})" if reference else ""))
        elif x is None or x.shape != reference.x.shape:
            notes.append("position_error: the cell's positions are not stored, or not the reference's shape")
        else:
            row["position_error"] = float(np.linalg.norm(x - reference.x, axis=2).max())
    cost = record.get("cost", {})
    row["cpu_per_simulated_s"] = cost.get("cpu_per_simulated_s")
    low, high = cost_range(cost["samples"]) if cost.get("samples") else (cost.get("low"), cost.get("high"))
    row["cpu_spread"] = None if low is None else high - low
    row["cpu_low"] = low
    row["cpu_high"] = high
    row["repeats"] = cost.get("repeats", len(cost.get("samples", [])) or None)
    row["status"] = record["status"]
    row["error_type"] = record.get("error_type")
    row["error"] = record.get("error")
    row["notes"] = "; ".join(notes + record.get("warnings", []))
    build = cell.definition["csb"]["build"]
    row["csb_version"] = build["csb"]
    row["build"] = f"{build.get('compiler')}, {build.get('simd')}, SUNDIALS {build.get('sundials')}"
    machine = record.get("machine", {})
    row["platform"] = machine.get("platform")
    row["cpu_count"] = machine.get("cpu_count")
    load = record.get("load_average")
    row["load_average"] = None if load is None else load[0]
    row["key"] = cell.key
    return row


def _write_outputs(result: StudyResult) -> list[Path]:
    out = result.out
    out.mkdir(parents=True, exist_ok=True)
    rows = result.table
    files = []
    columns = list(rows[0])
    s = io.StringIO()
    w = csv.DictWriter(s, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    text = s.getvalue().encode()
    unchanged = _same_bytes(out / "results.csv", text)
    if not unchanged:
        _write_atomic(out / "results.csv", text)
    files.append(out / "results.csv")
    chart = "position_error" in result.study.metrics
    profile = _profile(result) if result.study.profile_accuracy is not None else None
    charts = [out / f"chart_{k + 1}.png" for k in range(len(result.study.charts))]
    wanted = ([out / "report.md"] + [out / "results.parquet"] * _has_pyarrow() + [out / "accuracy_cost.png"] * chart
              + [out / "profile.png"] * (profile is not None) + charts)
    if unchanged and all(f.is_file() for f in wanted):  # a re-run of an unchanged study: nothing to draw
        return files + wanted
    _write_atomic(out / "report.md", result.report().encode())
    files.append(out / "report.md")
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        pass
    else:
        table = pa.Table.from_pylist(rows)
        tmp = out / ".results.parquet.tmp"
        pq.write_table(table, tmp)
        os.replace(tmp, out / "results.parquet")
        files.append(out / "results.parquet")
    scenes = [s.label for s in result.study.scenes]
    methods = [m.label for m in result.study.methods]
    if chart:
        files.append(charts_module.accuracy_cost(rows, scenes, methods, out / "accuracy_cost.png",
                                                 f"{result.study.name}: accuracy against cost"))
    for spec, path in zip(result.study.charts, charts):
        draw = charts_module.line_chart if spec["kind"] == "line" else charts_module.stability_map
        chosen_scenes = [s.label for s in result.study.scenes
                         if not spec.get("scenes") or s.label in spec["scenes"] or s.definition.get("setup") in spec["scenes"]]
        chosen_methods = [m for m in methods if not spec.get("methods") or m in spec["methods"]]
        files.append(draw(rows, spec, chosen_scenes, chosen_methods, path,
                          f"{result.study.name}: {_chart_title(spec)}"))
    if profile is not None:
        from ..profiles import plot_performance_profile

        plot_performance_profile(profile, out / "profile.png", title=f"{result.study.name}: performance profile at "
                                 f"{result.study.profile_accuracy:g} m", cost_label="CPU time per simulated second")
        files.append(out / "profile.png")
    return files


def _same_bytes(path: Path, data: bytes) -> bool:
    try:
        return path.read_bytes() == data
    except OSError:
        return False


def _has_pyarrow() -> bool:
    return importlib.util.find_spec("pyarrow") is not None
