#!/usr/bin/env python3
"""Study: the claims of XPBD (Macklin, Müller, Chentanez 2016), measured.

1. Stiffness independent of the iteration count and the time step. A 64 x 64 cloth (1 m,
   0.2 kg/m²) hangs from its top edge until at rest (Müller damping 0.1 per sub-step); its sag
   (how far the bottom edge's middle ends up below where an inextensible cloth would) measures
   how stiff it behaves. PBD with k = 0.01 (no correction, as in the paper) and XPBD with
   α = 0.05 m/N per edge (a static sag of about 5 cm) run at 20, 40, 80, 160 and 320 iterations
   (dt = 1/60 s), and at the most iterations with dt = 1/30 and 1/120 s.
2. Constraint forces. A chain of 20 particles (m = 1 kg, links of 0.1 m, α = 1e-8 m/N) hangs
   straight at rest length from a pin; one 1/60 s step of XPBD with n iterations gives the
   support force λ/h², compared with a Newton solve of the chain's static equilibrium.
3. The cost of XPBD over PBD: ms per step on the bundled cloth_grid scene (stretch and
   bending, whose compliance XPBD uses) at 64 x 64 and 128 x 128, 10 iterations, median of 7
   rounds.

Writes xpbd_stiffness.csv, xpbd_forces.csv, xpbd_cost.csv and xpbd.png.

    python validation/xpbd_claims.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

import csb
from csb.studies import write_csv
from csb.bench import cloth_simulation

G = (0.0, -9.81, 0.0)


def hanging_cloth(n: int, *, stiffness: float, compliance: float) -> csb.Model:
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n, plane="xy"), density=0.2, stretch_stiffness=stiffness,
                      stretch_compliance=compliance)
    top = inst.vertices[:, 1].max()
    for i in inst.particles:
        if abs(inst.vertices[i - inst.first_particle, 1] - top) < 1e-9:
            b.pin(int(i))
    return b.build()


def sag(model: csb.Model, *, method: str, iterations: int, dt: float, correction: bool, seconds: float) -> float:
    """Drop of the bottom edge's middle below the inextensible cloth's (m), at rest."""
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, dt=dt, iterations=iterations, stiffness_correction=correction,
                             damping=0.1)
    stepper.step(model, state, int(round(seconds / dt)))
    x0 = np.asarray(model.rest_positions)
    bottom = np.where(np.abs(x0[:, 1] - x0[:, 1].min()) < 1e-9)[0]
    middle = bottom[np.argmin(np.abs(x0[bottom, 0]))]
    return float(x0[middle, 1] - state.x[middle, 1])


def static_support_force(model: csb.Model) -> float:
    """Newton's method on the static equilibrium -∇E(x) + M g = 0 of the compliant chain, using
    the reference's analytic Jacobian; returns the force in the link at the pin (N)."""
    state = model.initial_state()
    net = csb.SpringNetwork(model, state, gravity=G)
    n3 = net.size // 2
    y = net.pack(state)
    for _ in range(50):
        f = net.rhs(y)[n3:]  # accelerations at v = 0
        indptr, indices, data = net.jacobian(y)
        A = np.zeros((n3, n3))
        for col in range(n3):
            for e in range(indptr[col], indptr[col + 1]):
                if indices[e] >= n3:
                    A[indices[e] - n3, col] = data[e]
        # A straight chain at rest length has no sideways stiffness: take the least-squares step.
        step = np.linalg.lstsq(A, -f, rcond=None)[0]
        y[:n3] += step
        if np.abs(step).max() < 1e-15:
            break
    s = model.initial_state()
    s.x = np.vstack([np.asarray(state.x)[:1], y[:n3].reshape(-1, 3)])
    stretch = csb.distance_violations(model, s)[0]
    return float(stretch / model.distance["compliance"][0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="a 16 x 16 cloth and fewer settings (the tests' version)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    n = 16 if args.quick else 64
    seconds = 2.0 if args.quick else 3.0
    iterations = (20, 80) if args.quick else (20, 40, 80, 160, 320)
    alpha = 0.05  # m/N per edge: sag ≈ α (m) for this cloth
    rows = []
    for label, method, k, a, corr in (("PBD k=0.01", "pbd", 0.01, 0.0, False),
                                      (f"XPBD alpha={alpha:g}", "xpbd", 1.0, alpha, False)):
        model = hanging_cloth(n, stiffness=k, compliance=a)
        for it in iterations:
            rows.append(dict(method=label, iterations=it, dt=1 / 60,
                             sag_m=sag(model, method=method, iterations=it, dt=1 / 60, correction=corr, seconds=seconds)))
        for dt in ((1 / 30, 1 / 120) if not args.quick else (1 / 30,)):
            rows.append(dict(method=label, iterations=iterations[-1], dt=dt,
                             sag_m=sag(model, method=method, iterations=iterations[-1], dt=dt, correction=corr,
                                       seconds=seconds)))
    write_csv(out / "xpbd_stiffness.csv", rows)

    b = csb.ModelBuilder()
    g = b.add_group("chain")
    for i in range(20):
        b.add_particle([0, -0.1 * i, 0], 1.0, g)
    for i in range(19):
        b.add_distance(i, i + 1, compliance=1e-8)
    b.pin(0)
    chain = b.build()
    exact = static_support_force(chain)
    forces = []
    for it in ((10, 50, 100, 1000) if args.quick else (10, 20, 50, 100, 200, 500, 1000, 2000)):
        stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, iterations=it)
        s = chain.initial_state()
        stepper.step(chain, s)
        force = -stepper.multipliers()["distance"][0] / stepper.substep_size**2
        forces.append(dict(iterations=it, support_force_N=force, newton_N=exact, relative_error=abs(force / exact - 1)))
    write_csv(out / "xpbd_forces.csv", forces)

    cost = []
    for size in ((32,) if args.quick else (64, 128)):
        row = dict(cloth=f"{size}x{size}")
        for method in ("pbd", "xpbd"):
            sim = cloth_simulation(size, iterations=10)
            if method == "xpbd":
                sim.stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, iterations=10)
            sim.stepper.step(sim.model, sim.state, 3)
            times = []
            for _ in range(7):
                t0 = time.perf_counter()
                sim.stepper.step(sim.model, sim.state, 5)
                times.append((time.perf_counter() - t0) / 5 * 1e3)
            row[f"{method}_ms"] = statistics.median(times)
        row["xpbd_over_pbd"] = row["xpbd_ms"] / row["pbd_ms"]
        cost.append(row)
    write_csv(out / "xpbd_cost.csv", cost)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b2, c) = plt.subplots(1, 3, figsize=(14, 4.2), constrained_layout=True)
    for label in dict.fromkeys(r["method"] for r in rows):
        pts = [r for r in rows if r["method"] == label and r["dt"] == 1 / 60]
        a.plot([r["iterations"] for r in pts], [100 * r["sag_m"] for r in pts], "o-", label=label)
        pts = [r for r in rows if r["method"] == label and r["iterations"] == iterations[-1]]
        pts.sort(key=lambda r: r["dt"])
        b2.plot([r["dt"] for r in pts], [100 * r["sag_m"] for r in pts], "o-", label=label)
    a.set_xscale("log", base=2)
    a.set_xlabel("iterations (dt = 1/60 s)")
    a.set_ylabel(f"sag after {seconds:g} s (cm)")
    a.set_title(f"hanging {n} x {n} cloth: iterations", fontsize="medium")
    a.legend(fontsize="x-small")
    b2.set_xscale("log")
    b2.set_xlabel(f"time step (s), {iterations[-1]} iterations")
    b2.set_ylabel(f"sag after {seconds:g} s (cm)")
    b2.set_title("time step", fontsize="medium")
    c.loglog([r["iterations"] for r in forces], [100 * r["relative_error"] for r in forces], "o-")
    c.set_xlabel("XPBD iterations (one 1/60 s step)")
    c.set_ylabel("support force error (%)")
    c.set_title("20-particle chain, α = 1e-8 m/N", fontsize="medium")
    for ax in (a, b2, c):
        ax.grid(alpha=0.3, which="both")
    fig.savefig(out / "xpbd.png", dpi=120)

    print(f"hanging {n} x {n} cloth, sag after {seconds:g} s (cm; XPBD is at rest by then, PBD at k = 0.01 still sinking):")
    for label in dict.fromkeys(r["method"] for r in rows):
        pts = [r for r in rows if r["method"] == label]
        print(f"  {label:24s} " + "  ".join(
            f"{r['iterations']} it, 1/{round(1 / r['dt'])} s: {100 * r['sag_m']:.3f}" for r in pts))
    print(f"chain support force (Newton: {exact:.4f} N): " + ", ".join(
        f"{r['iterations']} it {100 * r['relative_error']:.2f} %" for r in forces))
    print("cost: " + ", ".join(f"{r['cloth']} PBD {r['pbd_ms']:.2f} ms, XPBD {r['xpbd_ms']:.2f} ms "
                               f"(x{r['xpbd_over_pbd']:.3f})" for r in cost))
    print(f"  wrote {out}/xpbd_stiffness.csv, xpbd_forces.csv, xpbd_cost.csv and xpbd.png")


if __name__ == "__main__":
    main()
