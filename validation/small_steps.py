#!/usr/bin/env python3
"""Study: small steps (Macklin et al. 2019) — for equal work, n sub-steps of one XPBD iteration
against one step of n iterations.

Scenes, undamped, 2 s at 1/60 s per frame: a 10-link chain swinging from its top (5 cm links,
5 g nodes, link compliance 1e-6 m/N) and a 16 x 16 cloth (0.5 m, 0.2 kg/m², stretch 1e-4 m/N,
bending 1000 1/(N m)) hanging from two corners. For n = 1, 2, 5, 10, 20, 50 both splits do n
projections of every constraint per frame. Measured: the largest strain of any link over the
run, the change of kinetic + gravitational energy (as a fraction of the largest kinetic energy
the reference reaches; the springs' own energy is left out because an unconverged step leaves
links stretched far beyond what the material would, which is the strain column's business), and
the largest distance to the reference. Müller's velocity damping (§3.5, `damping`) is off, as is
XPBD's constraint damping: Müller's acts once per sub-step, so with it on, n sub-steps would damp
n times where one step of n iterations damps once, and the energy column would measure that
rather than the split. Writes small_steps.csv and small_steps.png.

    python validation/small_steps.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import csb
from csb.studies import swinging_chain, write_csv

G = (0.0, -9.81, 0.0)


def cloth(n: int) -> csb.Model:
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(0.5, 0.5, n, n), density=0.2, stretch_compliance=1e-4, bending_stiffness=1.0,
                      bending_compliance=1000.0)
    b.pin(inst.nearest([-0.25, 0, -0.25]))
    b.pin(inst.nearest([0.25, 0, -0.25]))
    return b.build()


def run(model, start, times, ref, *, substeps, iterations):
    state = start.copy()
    stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=substeps, iterations=iterations, gravity=G)
    rest = np.asarray(model.distance["rest_length"])
    strain, error = 0.0, 0.0
    mechanical = lambda: (lambda m: m["kinetic_energy"] + m["gravitational_energy"])(csb.measure(model, state, G))  # noqa: E731
    energy = [mechanical()]
    for k in range(1, len(times)):
        for _ in range(int(round((times[k] - times[k - 1]) * 60))):
            stepper.step(model, state)
            strain = max(strain, float(np.abs(csb.distance_violations(model, state) / rest).max()))
        energy.append(mechanical())
        error = max(error, float(np.linalg.norm(np.asarray(state.x) - ref.x[k], axis=1).max()))
    return strain, energy[-1] - energy[0], error


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="shorter, smaller (the tests' version)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scenes = {"chain": swinging_chain(links=5 if args.quick else 10, compliance=1e-6), "cloth": cloth(6 if args.quick else 16)}
    duration = 0.5 if args.quick else 2.0
    ns = (1, 5, 20) if args.quick else (1, 2, 5, 10, 20, 50)
    rows = []
    for name, model in scenes.items():
        start = model.initial_state()
        times = np.arange(0, round(duration * 10) + 1) / 10
        # Positions are compared (the energy column is XPBD's): rtol 1e-8, where the reference's
        # trajectories converge; rtol="auto" would bound its energy over the stiff links' modes.
        ref = csb.integrate_reference(model, start, times, gravity=G, rtol=1e-8, atol=1e-10)
        kinetic = max(csb.measure(model, s, G)["kinetic_energy"] for s in ref.states(model))
        for n in ns:
            for split, (sub, it) in (("n sub-steps x 1", (n, 1)), ("1 x n iterations", (1, n))):
                strain, lost, error = run(model, start, times, ref, substeps=sub, iterations=it)
                rows.append(dict(scene=name, n=n, split=split, max_strain=strain, energy_change=lost / kinetic,
                                 max_error_m=error))
    write_csv(out / "small_steps.csv", rows)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 7), constrained_layout=True)
    for r_, name in enumerate(scenes):
        for c_, (key, label, scale) in enumerate((("max_strain", "largest strain (%)", 100),
                                                  ("energy_change", "energy change (% of max kinetic)", 100),
                                                  ("max_error_m", "largest distance to the reference (m)", 1))):
            ax = axes[r_, c_]
            for split in ("n sub-steps x 1", "1 x n iterations"):
                pts = [r for r in rows if r["scene"] == name and r["split"] == split]
                y = [scale * (abs(r[key]) if key == "energy_change" else r[key]) for r in pts]
                ax.loglog([r["n"] for r in pts], y, "o-", label=split)
            ax.set_xlabel("n (projections per constraint per frame)")
            ax.set_ylabel(label if key != "energy_change" else "energy lost (% of max kinetic)")
            ax.set_title(name, fontsize="medium")
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize="x-small")
    fig.suptitle("Small steps: XPBD at 1/60 s per frame, equal work split into sub-steps or iterations",
                 fontsize="medium")
    fig.savefig(out / "small_steps.png", dpi=120)

    print(f"{'scene':6s} {'n':>3s} {'split':18s} {'max strain':>11s} {'energy change':>14s} {'max error (m)':>14s}")
    for r in rows:
        print(f"{r['scene']:6s} {r['n']:>3d} {r['split']:18s} {100 * r['max_strain']:>10.3f}% {100 * r['energy_change']:>13.2f}% "
              f"{r['max_error_m']:>14.3e}")
    print("  damping off (Müller's damping acts once per sub-step: with it on, n sub-steps would damp n times a frame, "
          "1 x n once)")
    print(f"  wrote {out}/small_steps.csv and small_steps.png")


if __name__ == "__main__":
    main()
