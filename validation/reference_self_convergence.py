#!/usr/bin/env python3
"""Study: self-convergence of the reference integrator, and what it costs.

For a 10-link chain swinging from its top (links of compliance 1e-7 m/N, 2 s) and an 8 x 8
cloth hanging from two corners (stretch 1e-4 m/N, bending 1 1/(N m), 1 s; the GMRES path),
CVODE runs at rtol 1e-8, 1e-10 and 1e-12 (atol = rtol/100). The spread of the trajectory against
the tightest run is compared with the smallest error a study measures against the reference
(PBD at dt = 1/3840 s, 50 iterations, on the same scene): it must be below 1 %. The total
energy must drift by less than 1e-6 of the largest kinetic energy. Then a 32 x 32 cloth (the
bundled cloth_grid, stretch 1e-4 m/N, bending 1 1/(N m)) runs 2 s at rtol 1e-8, atol 1e-10,
for the cost. Writes reference_self_convergence.csv and reference_cost.csv.

    python validation/reference_self_convergence.py [--out out/validation] [--skip-cost] [--quick]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import csb
from csb.studies import pbd_errors, relative_energy_drift, swinging_chain, write_csv

G = (0.0, -9.81, 0.0)


def pinned_cloth(n: int, size: float) -> csb.Model:
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(size, size, n, n), density=0.2, stretch_compliance=1e-4,
                      bending_stiffness=1.0, bending_compliance=1.0)
    b.pin(inst.nearest([-size / 2, 0, -size / 2]))
    b.pin(inst.nearest([size / 2, 0, -size / 2]))
    return b.build()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--skip-cost", action="store_true", help="skip the 32 x 32 cloth (several minutes)")
    parser.add_argument("--quick", action="store_true", help="small scenes, short runs, no cost run (the tests' version)")
    args = parser.parse_args()
    if args.quick:
        args.skip_cost = True
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    rows = []
    print(f"{'scene':8s} {'rtol':>7s} {'spread (m)':>11s} {'/ PBD error':>11s} {'energy drift':>13s} {'steps':>9s} "
          f"{'wall (s)':>9s} solver")
    scenes = ((("chain", swinging_chain(links=5, compliance=1e-5), 0.5), ("cloth", pinned_cloth(4, 0.3), 0.25))
              if args.quick else
              (("chain", swinging_chain(links=10, compliance=1e-7), 2.0), ("cloth", pinned_cloth(8, 0.5), 1.0)))
    for name, model, duration in scenes:
        start = model.initial_state()
        times = np.arange(0, round(duration * 60) + 1) / 60
        runs = {rtol: csb.integrate_reference(model, start, times, gravity=G, rtol=rtol, atol=rtol / 100)
                for rtol in (1e-8, 1e-10, 1e-12)}
        smallest, _ = pbd_errors(model, start, times, runs[1e-12].x, G, dt=1 / 3840, iterations=50)
        for rtol, r in runs.items():
            spread = float(np.abs(r.x - runs[1e-12].x).max())
            drift = relative_energy_drift(model, list(r.states(model)), G)
            rows.append(dict(scene=name, rtol=rtol, atol=rtol / 100, spread_m=spread, smallest_pbd_error_m=smallest,
                             spread_over_error=spread / smallest, energy_drift=drift, steps=r.stats["steps"],
                             wall_time_s=r.stats["wall_time"], linear_solver=r.stats["linear_solver"]))
            print(f"{name:8s} {rtol:>7.0e} {spread:>11.2e} {spread / smallest:>11.2e} {drift:>13.2e} "
                  f"{r.stats['steps']:>9d} {r.stats['wall_time']:>9.2f} {r.stats['linear_solver']}")
        print(f"         smallest PBD error measured against it (dt = 1/3840 s, 50 iterations): {smallest:.3e} m")
    write_csv(out / "reference_self_convergence.csv", rows)
    print(f"  wrote {out / 'reference_self_convergence.csv'}")

    if args.skip_cost:
        return
    model = pinned_cloth(32, 1.0)
    r = csb.integrate_reference(model, model.initial_state(), np.arange(0, 121) / 60, gravity=G, rtol=1e-8, atol=1e-10)
    s = r.stats
    cost = dict(cloth="32x32", particles=model.num_particles, constraints=model.num_constraints, duration_s=2.0,
                rtol=1e-8, atol=1e-10, **{k: s[k] for k in ("steps", "newton_iters", "linear_iters", "jacobian_evals",
                                                            "rhs_evals", "wall_time", "linear_solver")})
    write_csv(out / "reference_cost.csv", [cost])
    print(f"reference cost, 32 x 32 cloth ({model.num_particles} particles, {model.num_constraints} constraints), "
          f"2 s: {s['steps']} steps, {s['newton_iters']} Newton iterations, {s['linear_iters']} GMRES iterations, "
          f"{s['jacobian_evals']} preconditioner set-ups, {s['wall_time']:.1f} s wall")
    print(f"  wrote {out / 'reference_cost.csv'}")


if __name__ == "__main__":
    main()
