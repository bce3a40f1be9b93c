#!/usr/bin/env python3
"""Harness: PBD's convergence against the reference, in iterations and in the time step.

The scene is a 10-link chain (links of 5 cm, 5 g nodes) pinned at its top and released straight
at 20° from the vertical, for 2 s: a smooth motion whose trajectory is reproducible (a chain
released horizontally whips and is chaotic). The reference is CVODE on the same model with link
compliance 1e-7 m/N (stretch ~1e-7 m, far below every error below) at rtol 1e-8, atol 1e-10,
where its trajectory is converged (reference_self_convergence.py).

(a) At dt = 1/240 s, iterations 1, 2, 5, 10, 20, 50, 100: the mean largest constraint violation
    after a step, and the largest distance to the reference over the run.
(b) At 50 iterations, dt = 1/60 ... 1/3840 s: the distance to the reference; the observed order
    in dt is the least-squares slope of log(error) over the four smallest dt.

Writes convergence_iterations.csv, convergence_dt.csv and convergence.png.

    python validation/convergence.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import csb
from csb.studies import observed_order, pbd_errors, swinging_chain, write_csv

G = (0.0, -9.81, 0.0)
ITERATIONS = (1, 2, 5, 10, 20, 50, 100)
DTS = tuple(1 / (60 * 2**k) for k in range(7))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="a 5-link chain for 0.5 s (the tests' version)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = swinging_chain(links=5, compliance=1e-5) if args.quick else swinging_chain(links=10, compliance=1e-7)
    start = model.initial_state()
    times = np.arange(0, 31 if args.quick else 121) / 60  # every 1/60 s: a multiple of every dt below
    # The trajectory is what is compared: converged at rtol 1e-8 (reference_self_convergence); the
    # energy bound of rtol="auto" over this chain's fastest mode would need rtol below 1e-14.
    ref = csb.integrate_reference(model, start, times, gravity=G, rtol=1e-8, atol=1e-10)

    by_iterations = []
    for it in ITERATIONS:
        error, residual = pbd_errors(model, start, times, ref.x, G, dt=1 / 240, iterations=it)
        by_iterations.append(dict(iterations=it, dt=1 / 240, max_error_m=error, mean_residual_m=residual))
    by_dt = []
    for dt in DTS:
        error, residual = pbd_errors(model, start, times, ref.x, G, dt=dt, iterations=50)
        by_dt.append(dict(iterations=50, dt=dt, max_error_m=error, mean_residual_m=residual))
    order = observed_order(np.array([r["dt"] for r in by_dt[-4:]]), np.array([r["max_error_m"] for r in by_dt[-4:]]))

    for name, rows in (("convergence_iterations.csv", by_iterations), ("convergence_dt.csv", by_dt)):
        write_csv(out / name, rows)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    it = [r["iterations"] for r in by_iterations]
    a.loglog(it, [r["max_error_m"] for r in by_iterations], "o-", label="max distance to the reference")
    a.loglog(it, [r["mean_residual_m"] for r in by_iterations], "s-", label="mean largest constraint violation")
    a.set_xlabel("Gauss-Seidel iterations per step (dt = 1/240 s)")
    a.set_ylabel("m")
    a.legend(fontsize="small")
    a.grid(alpha=0.3, which="both")
    h = np.array([r["dt"] for r in by_dt])
    e = np.array([r["max_error_m"] for r in by_dt])
    b.loglog(h, e, "o-", label=f"max distance to the reference (order {order:.2f})")
    b.loglog(h, e[-1] * h / h[-1], "k--", lw=1, label="first order")
    b.set_xlabel("time step dt (s), 50 iterations")
    b.set_ylabel("m")
    b.legend(fontsize="small")
    b.grid(alpha=0.3, which="both")
    fig.suptitle(f"PBD on a swinging {model.num_particles - 1}-link chain against the CVODE reference "
                 f"({times[-1]:.1f} s)", fontsize="medium")
    fig.savefig(out / "convergence.png", dpi=120)

    print(f"reference: {ref.stats['steps']} steps, {ref.stats['wall_time']:.2f} s wall ({ref.stats['linear_solver']})")
    print(f"{'iterations':>10s} {'max error (m)':>14s} {'mean residual (m)':>18s}   (dt = 1/240 s)")
    for r in by_iterations:
        print(f"{r['iterations']:>10d} {r['max_error_m']:>14.3e} {r['mean_residual_m']:>18.3e}")
    print(f"{'dt (s)':>10s} {'max error (m)':>14s} {'mean residual (m)':>18s}   (50 iterations)")
    for r in by_dt:
        print(f"{r['dt']:>10.6f} {r['max_error_m']:>14.3e} {r['mean_residual_m']:>18.3e}")
    print(f"observed order in dt (four smallest dt): {order:.3f}")
    print(f"  wrote {out / 'convergence_iterations.csv'}, {out / 'convergence_dt.csv'} and {out / 'convergence.png'}")


if __name__ == "__main__":
    main()
