#!/usr/bin/env python3
"""Study: where the methods fail.

1. A map over (time step, stiffness) for each method on a 5-link chain (links of 0.1 m, 10 g
   nodes) pinned at its top and released at 30°, for 1 s: stable, unstable (blew up: a
   non-finite value, or a particle a hundred chain lengths from its start), or stable but wrong (more
   than 10 % of the chain's length from the reference with the same stiffness). Stiffness is
   k = 1/α (N/m) for the reference, XPBD and the force-based integrators; PBD and Jakobsen
   project hard constraints (their k ∈ [0, 1] has no unit) and so model the stiff limit.
2. The explicit stability limit h < 2/ω_max, ω_max² the largest eigenvalue of M⁻¹K, predicted
   and found by bisection for symplectic Euler and velocity Verlet on the chain hanging at rest
   (the threshold is where 4000 steps from a nudge grow the energy tenfold).
3. Gauss-Seidel, averaged Jacobi and summed Jacobi on a 10 x 10 cloth whose edges start 20 %
   too long, and summed Jacobi on the map's 5-link chain (hard links) stretched 20 % about its
   pin: the largest violation after each sweep. Beside them the spectral radius ρ of one
   summed-Jacobi sweep (PBD, k = 1) linearised at rest: the constraint errors go e ← (I - A D⁻¹) e,
   A = J W Jᵀ, D = diag(A), so ρ = max |1 - λ| over the eigenvalues λ of D^-1/2 A D^-1/2 (numpy).
   On a chain the links form a path, so the eigenvalues 1 - λ are symmetric about 0, and λ > 0
   (independent links) bounds them by 1: ρ < 1, it converges, slowly (cos(π/2n) for n equal
   links). The cloth's triangles break that symmetry: λ_max > 2, ρ > 1, it diverges.
4. PBD's stiffness k above 1: the violation left after n projections of one constraint,
   |1 - k|^n of the first, overshooting for 1 < k < 2 and diverging beyond.

Writes stability_map.csv, stability_limits.csv, stability_jacobi.csv, stability_jacobi_radius.csv,
stability_overshoot.csv and stability.png.

    python validation/stability.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

import csb
from csb.studies import make_stepper, omega_max, run_method, write_csv

G = (0.0, -9.81, 0.0)
METHODS = ("explicit-euler", "symplectic-euler", "velocity-verlet", "pbd", "xpbd", "jakobsen")
CLASSES = {"stable": 0, "wrong": 1, "unstable": 2}


def chain(k: float, angle: float = math.radians(30)) -> csb.Model:
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(5, 0.1, direction=(math.sin(angle), -math.cos(angle), 0)), particle_mass=0.01,
               stretch_compliance=1 / k)
    b.pin(0)
    return b.build()


def stability_map(dts, stiffnesses, duration: float):
    rows = []
    for k in stiffnesses:
        model = chain(k)
        start = model.initial_state()
        times = np.linspace(0, duration, 11)
        # A trajectory to classify against (5 cm): rtol 1e-8 converges it (reference_self_convergence);
        # the energy bound of rtol="auto" would need rtol ~1e-14 for the stiffest links here.
        ref = csb.integrate_reference(model, start, times, gravity=G, rtol=1e-8, atol=1e-10)
        for method in METHODS:
            for dt in dts:
                dt_eff = (times[1] - times[0]) / max(1, round((times[1] - times[0]) / dt))
                steps = duration / dt_eff
                if steps > 2e6:  # not worth it: far below every limit that matters here
                    continue
                r = run_method(model, start, times, make_stepper(method, dt=dt_eff, iterations=10), dt=dt_eff,
                               reference_x=ref.x)
                status = "unstable" if r["blew_up"] else ("wrong" if r["error"] > 0.05 else "stable")
                rows.append(dict(method=method, dt=dt_eff, stiffness=k, status=status, error_m=r["error"]))
    return rows


def found_limit(method: str, k: float) -> tuple[float, float]:
    """(predicted, found) critical time step for the chain hanging at rest."""
    model = chain(k, angle=0.0)
    # Hang it at rest: let XPBD with damping settle it, then nudge the bottom sideways.
    rest = model.initial_state()
    csb.PbdStepper(method="xpbd", dt=1 / 600, iterations=50, damping=0.05).step(model, rest, 3000)
    rest.v = np.zeros_like(rest.v)
    predicted = 2 / omega_max(model, rest, G)
    e = lambda s: csb.measure(model, s, G)["total_energy"]  # noqa: E731

    def grows(dt: float) -> bool:
        s = rest.copy()
        s.v[-1] = [1e-3, 0, 0]
        e0 = e(s)
        try:
            csb.ForceStepper(method=method, dt=dt, gravity=G).step(model, s, 4000)
        except csb.SimulationError:
            return True
        return abs(e(s) - e0) > 10 * abs(e0 - e(rest)) + 1e-12 or not np.all(np.isfinite(s.x))

    lo, hi = 0.8 * predicted, 1.2 * predicted
    assert not grows(lo) and grows(hi), (method, k)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if grows(mid) else (mid, hi)
    return predicted, 0.5 * (lo + hi)


def jacobi_scenes() -> dict[str, csb.Model]:
    """The 10 x 10 cloth (1 m, 0.2 kg/m², free) and the map's 5-link chain with hard links."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1, 1, 10, 10), density=0.2)
    cloth = b.build()
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(5, 0.1, direction=(math.sin(math.radians(30)), -math.cos(math.radians(30)), 0)),
               particle_mass=0.01)
    b.pin(0)
    return {"cloth": cloth, "chain": b.build()}


def jacobi_sweeps(max_iterations: int):
    rows = []
    for scene, model in jacobi_scenes().items():
        solvers = ("gauss-seidel", "jacobi", "jacobi-summed") if scene == "cloth" else ("jacobi-summed",)
        for solver in solvers:
            for it in range(1, max_iterations + 1):
                s = model.initial_state()
                x = np.asarray(s.x)
                s.x = x[0] + (x - x[0]) * 1.2  # every edge 20 % too long (the cloth's x[0] is a corner)
                try:
                    csb.PbdStepper(dt=1 / 60, iterations=it, gravity=(0, 0, 0), solver=solver).step(model, s)
                    residual = float(np.abs(csb.distance_violations(model, s)).max())
                except csb.SimulationError:
                    residual = float("inf")
                rows.append(dict(scene=scene, solver=solver, iterations=it, max_violation_m=residual))
    return rows


def summed_jacobi_radius(model: csb.Model) -> tuple[float, float]:
    """(ρ, λ_max) of one summed-Jacobi sweep of the distance constraints (k = 1) linearised at
    the rest positions (module docstring)."""
    x = np.asarray(model.rest_positions)
    pairs = np.asarray(model.distance["particles"])
    w = np.repeat(np.asarray(model.inv_mass), 3)
    J = np.zeros((len(pairs), x.size))
    for c, (a, b) in enumerate(pairs):
        n = (x[a] - x[b]) / np.linalg.norm(x[a] - x[b])
        J[c, 3 * a:3 * a + 3], J[c, 3 * b:3 * b + 3] = n, -n
    A = (J * w) @ J.T
    d = np.sqrt(np.diag(A))
    lam = np.linalg.eigvalsh(A / np.outer(d, d))
    return float(np.abs(1 - lam).max()), float(lam.max())


def overshoot(max_projections: int):
    rows = []
    for k in (0.5, 1.0, 1.5, 1.9, 2.0, 2.1):
        p1, p2 = np.zeros(3), np.array([1.3, 0.0, 0.0])
        for n in range(1, max_projections + 1):
            p1, p2, _ = csb.kernels.project_distance(p1, p2, 1.0, 1.0, 1.0, k)
            c = float(np.linalg.norm(p2 - p1) - 1.0)
            rows.append(dict(stiffness=k, projections=n, violation_m=c, closed_form_m=0.3 * (1 - k) ** n))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="a coarse map and one limit (the tests' version)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    dts = np.logspace(-5, -1, 5 if args.quick else 13)
    stiffnesses = (1e2, 1e5) if args.quick else (1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7)
    rows = stability_map(dts, stiffnesses, duration=0.2 if args.quick else 1.0)
    write_csv(out / "stability_map.csv", rows)
    limits = []
    for method in ("symplectic-euler", "velocity-verlet"):
        for k in ((1e4,) if args.quick else (1e3, 1e4, 1e5)):
            predicted, found = found_limit(method, k)
            limits.append(dict(method=method, stiffness=k, predicted_dt=predicted, found_dt=found,
                               found_over_predicted=found / predicted))
    write_csv(out / "stability_limits.csv", limits)
    jacobi = jacobi_sweeps(20 if args.quick else 60)
    write_csv(out / "stability_jacobi.csv", jacobi)
    radius = []
    for scene, model in jacobi_scenes().items():
        rho, lam_max = summed_jacobi_radius(model)
        v = [r["max_violation_m"] for r in jacobi if r["scene"] == scene and r["solver"] == "jacobi-summed"]
        finite = sum(1 for x in v if math.isfinite(x))  # a diverging sweep ends in the stepper's error
        half = finite // 2  # the measured factor per sweep over the second half of the finite sweeps
        rate = (v[finite - 1] / v[half - 1]) ** (1 / (finite - half))
        radius.append(dict(scene=scene, constraints=len(model.distance["rest_length"]), spectral_radius=rho,
                           lambda_max=lam_max, measured_factor_per_sweep=rate,
                           measured_from_sweep=half, measured_to_sweep=finite, sweeps=len(v)))
    write_csv(out / "stability_jacobi_radius.csv", radius)
    over = overshoot(10)
    write_csv(out / "stability_overshoot.csv", over)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    fig = plt.figure(figsize=(14, 8.5), constrained_layout=True)
    grid = fig.add_gridspec(2, 4)
    cmap = ListedColormap(["#4caf50", "#ffb300", "#e53935"])
    for m, method in enumerate(METHODS):
        ax = fig.add_subplot(grid[m // 3, m % 3])
        pts = [r for r in rows if r["method"] == method]
        ax.scatter([r["dt"] for r in pts], [r["stiffness"] for r in pts], c=[CLASSES[r["status"]] for r in pts],
                   cmap=cmap, vmin=0, vmax=2, marker="s", s=70)
        if method in ("symplectic-euler", "velocity-verlet", "explicit-euler"):
            ks = np.array(stiffnesses)
            # h_crit = 2/ω_max scales as 1/sqrt(k): draw it through the measured limit at 1e4 N/m.
            ref_limit = [lim for lim in limits if lim["stiffness"] == 1e4][0]["predicted_dt"]
            ax.plot(ref_limit * np.sqrt(1e4 / ks), ks, "k--", lw=1, label="2/ω_max")
            ax.legend(fontsize="x-small", loc="lower left")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(method, fontsize="medium")
        ax.set_xlabel("time step (s)")
        ax.set_ylabel("stiffness k = 1/α (N/m)")
    ax = fig.add_subplot(grid[0, 3])
    rho = {r["scene"]: r["spectral_radius"] for r in radius}
    for scene, solver in (("cloth", "gauss-seidel"), ("cloth", "jacobi"), ("cloth", "jacobi-summed"),
                          ("chain", "jacobi-summed")):
        pts = [r for r in jacobi if r["scene"] == scene and r["solver"] == solver and math.isfinite(r["max_violation_m"])]
        label = f"{scene}: {solver}" + (f" (ρ = {rho[scene]:.4g})" if solver == "jacobi-summed" else "")
        ax.semilogy([r["iterations"] for r in pts], [r["max_violation_m"] for r in pts], label=label,
                    ls=":" if scene == "chain" else "-")
    ax.set_xlabel("sweeps")
    ax.set_ylabel("largest violation (m)")
    ax.set_title("stretched 20 %: sweeps", fontsize="medium")
    ax.legend(fontsize="x-small")
    ax = fig.add_subplot(grid[1, 3])
    for k in sorted({r["stiffness"] for r in over}):
        pts = [r for r in over if r["stiffness"] == k]
        ax.plot([0] + [r["projections"] for r in pts], [0.3] + [r["violation_m"] for r in pts], "o-", ms=3,
                label=f"k = {k}")
    ax.set_yscale("symlog", linthresh=1e-4)
    ax.set_xlabel("projections")
    ax.set_ylabel("violation (m), signed")
    ax.set_title("one constraint, PBD stiffness k", fontsize="medium")
    ax.legend(fontsize="x-small")
    fig.suptitle("Stability: green stable, amber stable but > 10 % off the reference, red blew up (5-link chain, 1 s)",
                 fontsize="medium")
    fig.savefig(out / "stability.png", dpi=110)

    print(f"{'method':18s} {'stable':>7s} {'wrong':>7s} {'unstable':>9s}   (cells of the map)")
    for method in METHODS:
        pts = [r["status"] for r in rows if r["method"] == method]
        print(f"{method:18s} {pts.count('stable'):>7d} {pts.count('wrong'):>7d} {pts.count('unstable'):>9d}")
    for lim in limits:
        print(f"{lim['method']:18s} k = {lim['stiffness']:.0e} N/m: 2/ω_max = {lim['predicted_dt']:.4e} s, found "
              f"{lim['found_dt']:.6e} s ({100 * (lim['found_over_predicted'] - 1):+.4f} %)")
    last = {s: [r for r in jacobi if r["scene"] == "cloth" and r["solver"] == s][-1]["max_violation_m"]
            for s in ("gauss-seidel", "jacobi", "jacobi-summed")}
    print("cloth after the last sweep: " + ", ".join(f"{s} {v:.2e} m" for s, v in last.items()))
    for r in radius:
        v = [x["max_violation_m"] for x in jacobi if x["scene"] == r["scene"] and x["solver"] == "jacobi-summed"]
        end = r["measured_to_sweep"]
        print(f"summed Jacobi on the {r['scene']}: spectral radius of a sweep {r['spectral_radius']:.6g} "
              f"(λ_max {r['lambda_max']:.4g}, {r['constraints']} constraints), "
              + ("converges" if r["spectral_radius"] < 1 else "diverges")
              + f": violation {v[0]:.2e} m after 1 sweep, {v[end - 1]:.2e} m after {end}"
              + (f" (from {end + 1} on the step stops as diverging)" if end < r["sweeps"] else "")
              + f"; measured factor per sweep (sweeps {r['measured_from_sweep']}-{end}) "
              f"{r['measured_factor_per_sweep']:.6g}")
    print("one constraint after 10 projections: " + ", ".join(
        f"k={r['stiffness']} {r['violation_m']:+.2e} m" for r in over if r["projections"] == 10))
    print(f"  wrote {out}/stability_map.csv, stability_limits.csv, stability_jacobi.csv, stability_jacobi_radius.csv, "
          f"stability_overshoot.csv, stability.png")


if __name__ == "__main__":
    main()
