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
from .cells import _machine, _read_record, _write_atomic, compute_reference, run_cell
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

    def report(self) -> str:
        """The study as a report section (Markdown): what it is, its cells, per scene the cells on
        the accuracy-against-cost front (when position_error is measured), what blew up or failed."""
        st = self.study
        lines = [f"## Study: {st.name}", ""]
        if st.description:
            lines += [st.description, ""]
        lines += [f"`csb study run {st.path}`: {len(self.table)} cells ({len(st.scenes)} scenes, {len(st.methods)} "
                  f"methods), {st.duration:g} s each, metrics at {st.outputs + 1} times, cost the median CPU time "
                  f"per simulated second of {st.repeats} run(s) on one thread. Table: `results.csv`.", ""]
        if "position_error" in st.metrics:
            lines += ["![accuracy against cost](accuracy_cost.png)", ""]
            for scene in st.scenes:
                front = _front([r for r in self.table if r["scene"] == scene.label])
                lines += [f"{scene.label}: the cells no other cell beats in both error and cost", "",
                          "| method | parameters | largest distance to the reference (m) | CPU s per simulated s |",
                          "|---|---|---:|---:|"]
                lines += [f"| {r['method']} | {_param_text(r)} | {r['position_error']:.3g} | "
                          f"{r['cpu_per_simulated_s']:.3g} |" for r in front]
                lines.append("")
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
              scheduler: str | None = None, retry_failed: bool = False, progress: bool = False) -> StudyResult:
    """Run the study file at ``path``: the cells without a stored result are computed (on Dask:
    ``scheduler`` an address, else a LocalCluster of ``workers`` processes, default one per core
    up to the cells; ``workers=0`` in this process), each stored as ``<out>/cells/<key>.json`` as
    it ends; the table (``results.csv``, ``results.parquet`` with pyarrow) and the chart are written
    to ``out`` (default ``out/studies/<name>``). A stored failed cell is run again only with
    ``retry_failed``."""
    study = load_study(path)
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
        if r is not None and (r["status"] == "ok" or not retry_failed):
            records[c.key] = r
        else:
            missing.append(c)
    reused = len(records)
    if missing:
        _compute(study, missing, out_dir, records, workers, scheduler, progress)
    table = [_row(study, c, records[c.key]) for c in cells]
    result = StudyResult(study, out_dir, table, computed=len(missing), reused=reused,
                         failed=sum(r["status"] == "failed" for r in table))
    result.files = _write_outputs(result)
    return result


def _compute(study: Study, missing: list[Cell], out_dir: Path, records: dict[str, dict], workers, scheduler,
             progress: bool) -> None:
    from tqdm import tqdm

    need_ref = any(m in _NEEDS_REFERENCE for m in study.metrics)
    # The references the missing cells need, each stored as its own file by its key.
    refs: dict[str, np.ndarray] = {}
    ref_tasks: list[tuple[str, Any]] = []
    ref_key = {}
    if need_ref:
        for c in missing:
            d = c.definition
            rdef = dict(scene=d["scene"], reference=d["reference"], duration=d["duration"], outputs=d["outputs"],
                        csb=d["csb"])
            k = cell_key(rdef)
            ref_key[c.key] = k
            if k in refs or any(k == t[0] for t in ref_tasks):
                continue
            f = out_dir / "references" / f"{k}.npy"
            try:
                refs[k] = np.load(f)
            except (OSError, ValueError):
                ref_tasks.append((k, (compute_reference, (d["scene"], c.context["scene"], d["reference"],
                                                          d["duration"], d["outputs"]))))
    run, close = _executor(workers, scheduler, len(missing))
    try:
        ref_errors: dict[str, BaseException] = {}
        if ref_tasks:
            for i, value in run([t[1] for t in ref_tasks]):
                k = ref_tasks[i][0]
                if isinstance(value, BaseException):
                    ref_errors[k] = value
                    continue
                buf = io.BytesIO()
                np.save(buf, value)
                _write_atomic(out_dir / "references" / f"{k}.npy", buf.getvalue())
                refs[k] = value
        tasks, todo = [], []
        for c in missing:
            k = ref_key.get(c.key)
            if k in ref_errors:
                e = ref_errors[k]
                record = dict(key=c.key, machine=_machine(), status="failed", error_type=type(e).__name__,
                              error=f"the reference failed: {e}", warnings=[])
                _store(out_dir, c, record, records)
                continue
            tasks.append((run_cell, (c.definition, c.context, refs.get(k) if k else None)))
            todo.append(c)
        bar = tqdm(total=len(todo), desc=study.name, unit="cell", disable=not progress)
        for i, value in run(tasks):
            c = todo[i]
            if isinstance(value, BaseException):  # the worker died, or the task could not run
                value = dict(key=c.key, machine={}, status="failed", error_type=type(value).__name__,
                             error=str(value), warnings=[])
            _store(out_dir, c, value, records)
            bar.update()
        bar.close()
    finally:
        if close is not None:
            close()


def _store(out_dir: Path, cell: Cell, record: dict, records: dict[str, dict]) -> None:
    record = dict(record, definition=cell.definition)
    text = json.dumps(record, sort_keys=True, indent=1, allow_nan=True)
    _write_atomic(out_dir / "cells" / f"{cell.key}.json", text.encode())
    records[cell.key] = record


def _row(study: Study, cell: Cell, record: dict) -> dict:
    row: dict[str, Any] = dict(study=study.name, scene=cell.scene, method=cell.method)
    for p in _PARAMS:
        row[p] = cell.params.get(p)
    row["dt_used"] = record.get("dt_used")
    row["steps"] = record.get("steps")
    values = record.get("metrics", {})
    for m in study.metrics:
        row[m] = values.get(m)
    cost = record.get("cost", {})
    row["cpu_per_simulated_s"] = cost.get("cpu_per_simulated_s")
    row["cpu_spread"] = cost.get("spread")
    row["repeats"] = study.repeats
    row["status"] = record["status"]
    row["error_type"] = record.get("error_type")
    row["error"] = record.get("error")
    row["notes"] = "; ".join(record.get("notes", []) + record.get("warnings", []))
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
    wanted = ([out / "report.md"] + [out / "results.parquet"] * _has_pyarrow() + [out / "accuracy_cost.png"] * chart
              + [out / "profile.png"] * (profile is not None))
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
    if chart:
        files.append(_chart(result))
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


def _chart(result: StudyResult) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = [s.label for s in result.study.scenes]
    fig, axes = plt.subplots(1, len(scenes), figsize=(6.5 * len(scenes), 5.5), constrained_layout=True, squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        for m in result.study.methods:
            pts = [r for r in result.table if r["scene"] == scene and r["method"] == m.label and r["status"] == "ok"
                   and r.get("position_error") and r["cpu_per_simulated_s"]]
            if pts:
                pts.sort(key=lambda r: r["cpu_per_simulated_s"])
                ax.loglog([r["cpu_per_simulated_s"] for r in pts], [r["position_error"] for r in pts], "o",
                          label=m.label, ms=6, alpha=0.85)
        ax.set_title(f"{scene}: error against cost", fontsize="medium")
        ax.set_xlabel("CPU time per simulated second (s), median of the repeats")
        ax.set_ylabel("largest distance to the reference (m)")
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="x-small", ncol=2)
    path = result.out / "accuracy_cost.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

