"""A study's charts, drawn from its table: the accuracy-against-cost front of every scene, and the
charts its [[chart]] tables ask for (a metric against a parameter; a stability map)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from .schema import _PARAMS

# A stability map's classes, in the order of its legend, with their colours.
MAP_CLASSES = (("stable", "#4daf4a"), ("stable but wrong", "#ff9f1c"), ("blew up", "#d7263d"), ("failed", "#999999"))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _styles(methods: list[str]) -> dict[str, dict[str, Any]]:
    """A colour and a marker per method, the same in every panel and chart of a study."""
    plt = _plt()
    colours = plt.get_cmap("tab10" if len(methods) <= 10 else "tab20").colors
    markers = "osD^vP*Xh<>"
    return {m: dict(color=colours[k % len(colours)], marker=markers[k % len(markers)]) for k, m in enumerate(methods)}


def _measured(row: dict, key: str) -> bool:
    v = row.get(key)
    return row["status"] == "ok" and row.get("stability") != "blew-up" and v is not None and v > 0


def accuracy_cost(table: list[dict], scenes: list[str], methods: list[str], path: Path, title: str) -> Path:
    """Per scene, each cell's largest distance to the reference against its cost (the median, with
    the range of its repeats as a horizontal bar), one colour per method."""
    plt = _plt()
    style = _styles(methods)
    fig, axes = plt.subplots(1, len(scenes), figsize=(6.5 * len(scenes), 5.5), constrained_layout=True, squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        for method in methods:
            pts = sorted((r for r in table if r["scene"] == scene and r["method"] == method
                          and _measured(r, "position_error") and _measured(r, "cpu_per_simulated_s")),
                         key=lambda r: r["cpu_per_simulated_s"])
            if not pts:
                continue
            x = [r["cpu_per_simulated_s"] for r in pts]
            lo = [xi - (r.get("cpu_low") if r.get("cpu_low") is not None else xi) for xi, r in zip(x, pts)]
            hi = [(r.get("cpu_high") if r.get("cpu_high") is not None else xi) - xi for xi, r in zip(x, pts)]
            ax.errorbar(x, [r["position_error"] for r in pts], xerr=[lo, hi], fmt=style[method]["marker"], ms=6,
                        alpha=0.85, capsize=2, color=style[method]["color"], label=method)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{scene}: error against cost", fontsize="medium")
        ax.set_xlabel("CPU s per simulated s: median; bar: spread of the repeats")
        ax.set_ylabel("largest distance to the reference (m)")
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="x-small", ncol=2)
    fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _fmt(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def line_chart(table: list[dict], chart: dict, scenes: list[str], methods: list[str], path: Path, title: str) -> Path:
    """Per scene, the metric ``chart["y"]`` against ``chart["x"]`` (a parameter, or the cost): one
    line per method and setting of the parameters other than ``chart["along"]``, the one the
    line runs along (log axes)."""
    plt = _plt()
    x_key, y_key = chart["x"], chart["y"]
    along = chart.get("along", x_key)
    style = _styles(methods)
    fig, axes = plt.subplots(1, len(scenes), figsize=(6.5 * len(scenes), 5.2), constrained_layout=True, squeeze=False)
    others = [p for p in (*_PARAMS, *_scene_columns(table)) if p != along]
    for ax, scene in zip(axes[0], scenes):
        for method in methods:
            rows = [r for r in table if r["scene"] == scene and r["method"] == method and r.get(x_key) is not None]
            groups: dict[tuple, list[dict]] = {}
            for r in rows:
                groups.setdefault(tuple(r.get(p) for p in others), []).append(r)
            for key, group in groups.items():
                pts = sorted((r for r in group if _measured(r, y_key) and r.get(x_key) is not None),
                             key=lambda r: (r[along] if r.get(along) is not None else 0, r[x_key]))
                if not pts:
                    continue
                label = " ".join([method] + [f"{p}={_fmt(v)}" for p, v in zip(others, key)
                                             if v is not None and len({r.get(p) for r in rows}) > 1])
                ax.plot([r[x_key] for r in pts], [r[y_key] for r in pts], "-", marker=style[method]["marker"], ms=4,
                        color=style[method]["color"], label=label)
                blown = [r for r in group if r.get("stability") == "blew-up"]
                if blown:
                    ax.plot([r[x_key] for r in blown], [ax.get_ylim()[1]] * len(blown), "x", color="#d7263d")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(scene, fontsize="medium")
        ax.set_xlabel("CPU time per simulated second (s)" if x_key == "cpu_per_simulated_s" else x_key)
        ax.set_ylabel(y_key)
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="x-small")
    fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def map_class(row: dict, wrong: float | None) -> str:
    """A cell's class on a stability map."""
    if row["status"] != "ok":
        return "failed"
    if row.get("stability") == "blew-up":
        return "blew up"
    if wrong is not None and row.get("position_error") is not None and row["position_error"] > wrong:
        return "stable but wrong"
    return "stable"


def stability_map(table: list[dict], chart: dict, scenes: list[str], methods: list[str], path: Path,
                  title: str) -> Path:
    """One panel per scene (by its set-up, the grid's points merged) and method: a square per
    (x, y) setting in the colour of its class (MAP_CLASSES)."""
    plt = _plt()
    from matplotlib.patches import Patch

    x_key, y_key, wrong = chart["x"], chart["y"], chart.get("wrong")
    # A map's axis may be a scene grid's argument: the scenes of one grid become one panel.
    groups: dict[str, list[str]] = {}
    for scene in scenes:
        groups.setdefault(scene.split(" ")[0] if x_key not in _PARAMS or y_key not in _PARAMS else scene,
                          []).append(scene)
    def cells_of(group: str, method: str) -> list[dict]:
        return [r for r in table if r["scene"] in groups[group] and r["method"] == method
                and r.get(x_key) is not None and r.get(y_key) is not None]

    # Only the scenes (and methods) the map's axes apply to: a panel per pair with cells.
    panels = [(g, m) for g in groups for m in methods if cells_of(g, m)]
    if not panels:
        panels = [(g, m) for g in groups for m in methods][:1]
    cols = min(4, len(panels))
    rows_n = math.ceil(len(panels) / cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(4.2 * cols, 3.6 * rows_n), constrained_layout=True,
                             squeeze=False)
    colour = dict(MAP_CLASSES)
    for ax, (group, method) in zip(axes.flat, panels):
        cells = cells_of(group, method)
        if not cells:
            ax.axis("off")
            ax.set_title(f"no cell has both {x_key} and {y_key}", fontsize="small")
            continue
        xs = sorted({r[x_key] for r in cells})
        ys = sorted({r[y_key] for r in cells})
        for r in cells:
            ax.add_patch(plt.Rectangle((xs.index(r[x_key]) - 0.45, ys.index(r[y_key]) - 0.45), 0.9, 0.9,
                                       color=colour[map_class(r, wrong)]))
        ax.set_xlim(-0.5, len(xs) - 0.5)
        ax.set_ylim(-0.5, len(ys) - 0.5)
        ax.set_xticks(range(len(xs)), [_fmt(v) for v in xs], rotation=45, fontsize="x-small")
        ax.set_yticks(range(len(ys)), [_fmt(v) for v in ys], fontsize="x-small")
        ax.set_xlabel(x_key)
        ax.set_ylabel(y_key)
        ax.set_title(f"{group}: {method}", fontsize="small")
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    labels = [(name, c) for name, c in MAP_CLASSES if name != "stable but wrong" or wrong is not None]
    fig.legend(handles=[Patch(color=c, label=name + (f" (> {wrong:g} m from the reference)"
                                                       if name == "stable but wrong" else ""))
                        for name, c in labels], loc="lower right", fontsize="small")
    fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _scene_columns(table: list[dict]) -> list[str]:
    """The scene grids' argument columns of a table (those between method and the parameters)."""
    if not table:
        return []
    cols = list(table[0])
    return cols[cols.index("method") + 1: cols.index("dt")]
