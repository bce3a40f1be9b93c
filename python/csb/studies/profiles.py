"""Performance profiles (Dolan and Moré 2002): over a set of problems (scenes), how often each
method is within a factor τ of the cheapest one at a given accuracy.

For problem p and method s let t_ps be the cost (CPU seconds per simulated second, say) of the
cheapest run of s on p that meets the accuracy asked for, and ∞ where none does (a method that
diverged, or never got accurate enough). The performance ratio is r_ps = t_ps / min_s t_ps and
the profile of s is

    ρ_s(τ) = |{p : r_ps ≤ τ}| / (number of problems),

a non-decreasing step function: ρ_s(1) is the share of problems on which s is the cheapest (ties
count for every method that ties), ρ_s(τ) for large τ the share it solves at all. A method whose
curve lies above another's is the better choice over the whole set, whatever the scale of the
problems' costs; that is why the field summarises benchmarks this way.

``cost_to_accuracy`` turns a study's cells (one row per run: problem, method, error, cost) into
the t_ps; ``performance_profile`` computes the ratios and the curves; ``plot_performance_profile``
draws them (log τ, as Dolan and Moré do).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

__all__ = ["Profile", "cost_to_accuracy", "performance_profile", "plot_performance_profile"]


def _finite_nonnegative(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{what} must be a number, got {value!r}")
    v = float(value)
    if math.isnan(v) or v < 0:
        raise ValueError(f"{what} must be >= 0 (inf: not solved), got {value!r}")
    return v


def cost_to_accuracy(rows: Iterable[Mapping[str, Any]], *, target: float, error: str = "position_error",
                     cost: str = "cost", problem: str = "scene", method: str = "method",
                     ok: str | None = "status") -> dict[tuple[str, str], float]:
    """The cheapest cost at which each method meets ``target`` on each problem.

    rows: one mapping per run, with the keys named by `problem`, `method`, `error` (the run's
    error, same unit as target) and `cost` (>= 0). A run counts only if its error is finite and
    <= target and, when `ok` names a key, that key is "ok". A (problem, method) pair whose runs
    all miss the target gets inf; pairs that never ran are absent."""
    target = _finite_nonnegative(target, "target")
    out: dict[tuple[str, str], float] = {}
    for k, row in enumerate(rows):
        try:
            key = (str(row[problem]), str(row[method]))
            e, c = row[error], row[cost]
        except KeyError as missing:
            raise ValueError(f"row {k}: no column {missing.args[0]!r} (columns: {', '.join(map(str, row))})") from None
        out.setdefault(key, math.inf)
        if ok is not None and row.get(ok, "ok") != "ok":
            continue
        if e is None or c is None:
            continue
        e = float(e)
        if not (math.isfinite(e) and e <= target):
            continue
        out[key] = min(out[key], _finite_nonnegative(c, f"row {k}: {cost}"))
    return out


@dataclass
class Profile:
    """Performance ratios and curves. ``ratios[p][s]`` is r_ps (inf: not solved);
    ``rho[s][k]`` is ρ_s(taus[k])."""

    problems: list[str]
    methods: list[str]
    ratios: dict[str, dict[str, float]]
    taus: np.ndarray
    rho: dict[str, np.ndarray] = field(default_factory=dict)

    def at(self, method: str, tau: float) -> float:
        """ρ_method(τ), exactly (not read off the sampled curve)."""
        r = [self.ratios[p][method] for p in self.problems]
        return sum(1 for x in r if x <= tau) / len(self.problems)

    def solved(self, method: str) -> float:
        """The share of problems the method solves at all: ρ(τ) for τ → ∞."""
        return sum(1 for p in self.problems if math.isfinite(self.ratios[p][method])) / len(self.problems)


def performance_profile(costs: Mapping[tuple[str, str], float], *, methods: Sequence[str] | None = None,
                        taus: Sequence[float] | None = None) -> Profile:
    """Dolan and Moré's profile of the costs t_ps, given as {(problem, method): cost} (inf where the
    method did not solve the problem; a pair absent from the mapping counts as not solved).

    A problem no method solves is left out (it says nothing about the methods); it is an error if
    none is left. taus: where to sample the curves; by default every distinct finite ratio and 1,
    so the curves are exact at their steps."""
    if not costs:
        raise ValueError("costs is empty: no (problem, method) pair to profile")
    problems = sorted({p for p, _ in costs})
    names = list(methods) if methods is not None else sorted({s for _, s in costs})
    if not names:
        raise ValueError("methods is empty")
    t = {(p, s): _finite_nonnegative(costs.get((p, s), math.inf), f"cost of {s!r} on {p!r}")
         for p in problems for s in names}
    ratios: dict[str, dict[str, float]] = {}
    for p in problems:
        best = min(t[p, s] for s in names)
        if not math.isfinite(best):
            continue  # solved by no method
        if best == 0:
            # A zero cost (below the clock's resolution) ties with other zeros and beats the rest.
            ratios[p] = {s: 1.0 if t[p, s] == 0 else math.inf for s in names}
        else:
            ratios[p] = {s: t[p, s] / best for s in names}
    kept = [p for p in problems if p in ratios]
    if not kept:
        raise ValueError("no problem is solved by any method: nothing to profile")
    if taus is None:
        finite = sorted({r for p in kept for r in ratios[p].values() if math.isfinite(r)} | {1.0})
        taus_array = np.array(finite)
    else:
        taus_array = np.array([_finite_nonnegative(x, "tau") for x in taus])
        if np.any(taus_array < 1):
            raise ValueError(f"taus must be >= 1 (a ratio to the cheapest), got {list(taus)!r}")
    prof = Profile(kept, names, ratios, taus_array)
    for s in names:
        r = np.array([ratios[p][s] for p in kept])
        prof.rho[s] = np.array([np.count_nonzero(r <= tau) / len(kept) for tau in taus_array])
    return prof


def plot_performance_profile(profile: Profile, path, *, title: str = "", cost_label: str = "cost") -> None:
    """ρ_s(τ) against τ (log scale) as step curves, one per method, into `path` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    top = float(profile.taus.max()) * 1.5 if len(profile.taus) else 2.0
    for s in profile.methods:
        x = np.concatenate([[1.0], profile.taus, [top]])
        y = np.concatenate([[profile.at(s, 1.0)], profile.rho[s], [profile.rho[s][-1] if len(profile.taus) else 0]])
        ax.step(x, y, where="post", label=s)
    ax.set_xscale("log")
    ax.set_xlim(1.0, top)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel(f"τ: within a factor τ of the cheapest {cost_label}")
    ax.set_ylabel(f"share of problems ({len(profile.problems)})")
    ax.set_title(title or "performance profile (Dolan and Moré 2002)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
