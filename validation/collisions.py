#!/usr/bin/env python3
"""Study: collisions as constraints generated after the prediction (Müller et al. 2007 §4.3-4.4).

1. Penetration. 36 particles thrown at each collider type (plane, sphere, capsule, rotated box,
   box-shaped triangle mesh) for 1 s with PBD, XPBD and Jakobsen: the deepest penetration below
   the collider's exact surface (numpy signed distance) at the end of each step. Also a particle
   fired at 120 m/s at a 1 mm box wall and a one-sheet mesh (2 m per step): how far it got.
2. Rest jitter. A 16 x 16 cloth dropped 1 cm onto a plane with friction, settled 2 s, then
   watched 10 s: the largest particle speed and drift.
3. Friction threshold. A rigid 8-particle box on a slope with μs = μk = μ: the angle where it
   starts sliding, by bisection, against atan μ, at h = 1/600 s and 1/2400 s.
4. Restitution and self-collision: the bounce height against e² H, and the edge-triangle
   crossings of a cloth folded over itself, with and without self-collision.

Writes collisions_penetration.csv, collisions_rest.csv, collisions_friction.csv,
collisions_bounce.csv, collisions_self.csv and collisions.png.

    python validation/collisions.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

import csb
from csb.studies import collisions as cs
from csb.studies import write_csv

METHODS = ("pbd", "xpbd", "jakobsen")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="fewer settings (the tests' version)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    history = {}
    pen = []
    for kind in cs.KINDS:
        for method in METHODS:
            h, touched = cs.max_penetration_history(kind, method, friction_static=0.5, friction_kinetic=0.4,
                                                    restitution=0.3)
            history[kind, method] = h
            pen.append(dict(test="rain", collider=kind, method=method, max_penetration_m=float(h.max()),
                            particles_reaching=touched))
    for kind in ("box", "mesh"):
        for method in METHODS:
            front = -0.0005 if kind == "box" else 0.0
            reached = cs.thin_wall(kind, method)
            pen.append(dict(test="thin wall 120 m/s", collider=kind, method=method,
                            max_penetration_m=max(0.0, reached - front), particles_reaching=1))
    write_csv(out / "collisions_penetration.csv", pen)

    rest = []
    for method in (("pbd",) if args.quick else METHODS):
        r = cs.rest_jitter(method)
        rest.append(dict(method=method, seconds=10.0, max_speed_m_per_s=r["max_speed"], max_drift_m=r["max_drift"],
                         max_below_thickness_m=r["max_below_thickness"]))
    write_csv(out / "collisions_rest.csv", rest)

    friction = []
    mus = (0.2, 0.5, 1.0) if args.quick else (0.1, 0.2, 0.3, 0.5, 0.7, 1.0)
    for substeps in ((10,) if args.quick else (10, 40)):
        for mu in mus:
            found = cs.friction_threshold(mu, substeps=substeps)
            friction.append(dict(mu=mu, substeps=substeps, h_s=1 / 60 / substeps, threshold_deg=math.degrees(found),
                                 atan_mu_deg=math.degrees(math.atan(mu)),
                                 error_deg=math.degrees(found - math.atan(mu))))
    write_csv(out / "collisions_friction.csv", friction)

    bounce = []
    for e in (0.0, 0.5, 0.8, 1.0):
        top = cs.bounce_height(e)
        bounce.append(dict(restitution=e, height_m=1.0, bounce_m=top, e2_height_m=e * e, error_m=top - e * e))
    write_csv(out / "collisions_bounce.csv", bounce)

    selfc = []
    steps = 60 if args.quick else 120
    for label, h in (("self-collision h = 8 mm", 0.008), ("no self-collision", None)):
        model, edges = cs.folded_cloth(self_collision=h)
        triangles = np.asarray(model.triangles)
        state = model.initial_state()
        stepper = csb.PbdStepper(dt=1 / 60, substeps=4, iterations=10)
        for k in range(steps):
            stepper.step(model, state)
            selfc.append(dict(case=label, step=k + 1, crossings=cs.self_intersections(state.x, edges, triangles),
                              self_contacts=stepper.contacts()["self_count"]))
    write_csv(out / "collisions_self.csv", selfc)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b, c) = plt.subplots(1, 3, figsize=(14, 4.2), constrained_layout=True)
    for kind in cs.KINDS:
        h = history[kind, "pbd"]
        a.plot(np.arange(1, len(h) + 1) / 60, np.maximum(h, 1e-18), label=kind)
    a.set_yscale("log")
    a.set_xlabel("t (s)")
    a.set_ylabel("max penetration at step end (m; 1e-18 = none)")
    a.set_title("36 particles thrown at each collider (PBD)", fontsize="medium")
    a.legend(fontsize="x-small")
    for substeps in dict.fromkeys(r["substeps"] for r in friction):
        pts = [r for r in friction if r["substeps"] == substeps]
        b.plot([r["mu"] for r in pts], [r["threshold_deg"] for r in pts], "o", label=f"found, h = 1/{60 * substeps} s")
    grid = np.linspace(0, max(mus), 50)
    b.plot(grid, np.degrees(np.arctan(grid)), "k-", lw=0.8, label="atan μ")
    b.set_xlabel("μs = μk")
    b.set_ylabel("slope angle where the box slides (°)")
    b.set_title("friction threshold", fontsize="medium")
    b.legend(fontsize="x-small")
    for label in dict.fromkeys(r["case"] for r in selfc):
        pts = [r for r in selfc if r["case"] == label]
        c.plot([r["step"] / 60 for r in pts], [r["crossings"] for r in pts], label=label)
    c.set_xlabel("t (s)")
    c.set_ylabel("edge-triangle crossings")
    c.set_title("cloth folded over itself, dropped on the ground", fontsize="medium")
    c.legend(fontsize="x-small")
    for ax in (a, b, c):
        ax.grid(alpha=0.3, which="both")
    fig.savefig(out / "collisions.png", dpi=120)

    print("max penetration at the end of a step (m), 36 particles thrown for 1 s:")
    for kind in cs.KINDS:
        print(f"  {kind:8s} " + "  ".join(
            f"{r['method']} {r['max_penetration_m']:.2e}" for r in pen if r["collider"] == kind and r["test"] == "rain"))
    print("thin wall, 120 m/s (2 m per step), depth past the front face (m): " + ", ".join(
        f"{r['collider']} {r['method']} {r['max_penetration_m']:.2e}" for r in pen if r["test"] != "rain"))
    print("cloth at rest on a plane for 10 s: " + ", ".join(
        f"{r['method']} max speed {r['max_speed_m_per_s']:.2e} m/s, drift {r['max_drift_m']:.2e} m" for r in rest))
    print("friction threshold (found vs atan μ, °): " + ", ".join(
        f"μ={r['mu']:g} h=1/{60 * r['substeps']}: {r['threshold_deg']:.3f} vs {r['atan_mu_deg']:.3f}" for r in friction))
    print("bounce from 1 m (m): " + ", ".join(f"e={r['restitution']:g}: {r['bounce_m']:.4f} vs e² {r['e2_height_m']:.4f}"
                                              for r in bounce))
    for label in dict.fromkeys(r["case"] for r in selfc):
        pts = [r for r in selfc if r["case"] == label]
        print(f"folded cloth, {label}: max edge-triangle crossings {max(r['crossings'] for r in pts)} over "
              f"{len(pts)} steps, at the end {pts[-1]['crossings']}")
    print(f"  wrote {out}/collisions_*.csv and collisions.png")


if __name__ == "__main__":
    main()
