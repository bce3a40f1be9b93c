#!/usr/bin/env python3
"""Harness: energy drift of each method on conservative scenes, against the reference.

Three undamped scenes: a pendulum released at 30° (4 s), a 10-link chain swinging from its top
(2 s) and a free 8 x 8 cloth spinning in its plane at 2 rad/s without gravity (2 s). Each runs with Müller PBD at
dt = 1/60 s (split into 1 or 10 sub-steps) and with the reference; the energy each conserves
(kinetic + gravitational for PBD, whose hard constraints store none; plus the springs' C²/(2α)
for the reference) is sampled every 1/60 s. The drift per simulated second is the least-squares
slope of the energy, relative to the largest kinetic energy of the reference run.

The reference runs at rtol="auto" with energy_tolerance 1e-6 (reference_energy.py), counting the
periods of the fastest motion that carries the energy: the swing, sqrt(g/L) for the pendulum (its
rod's 1e4 rad/s mode is not rung: the bob starts at the rod's static stretch) and 2 sqrt(n g/l) for
the chain (the top of the swing frequencies of n nodes hanging on links of length l; the links'
own modes are rung only by their static stretch), and the spin, 2 rad/s, for the cloth. Its
relative energy change over the run is checked against that bound. Writes energy_drift.csv (one
row per scene and method), energy_drift_series.csv and energy_drift.png.

    python validation/energy_drift.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

import csb
from csb.studies import (drift_per_second, energy_series, method_energy, pendulum_model, spinning_cloth, swinging_chain,
                         write_csv)

G = (0.0, -9.81, 0.0)
DT = 1 / 60


ENERGY_TOLERANCE = 1e-6
LINK = 0.05  # m, swinging_chain's link length


def scenes(quick: bool):
    """(name, model, start, gravity, duration, PBD splits, frequency of the energy-carrying motion in rad/s)"""
    scale = 0.25 if quick else 1.0
    yield ("pendulum", pendulum_model(math.radians(30), compliance=1e-8), None, G, 4.0 * scale, [(1, 1), (10, 1)],
           math.sqrt(9.81 / 1.0))
    links = 5 if quick else 10
    chain = swinging_chain(links=links, compliance=1e-5 if quick else 1e-7)
    yield "chain", chain, None, G, 2.0 * scale, [(1, 20), (10, 2)], 2 * math.sqrt(links * 9.81 / LINK)
    model, start = spinning_cloth(n=4 if quick else 8, omega=2.0)
    yield "free cloth", model, start, (0.0, 0.0, 0.0), 2.0 * scale, [(1, 10), (10, 1)], 2.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="short runs of smaller scenes (the tests' version)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows, series = [], []
    for name, model, start, gravity, duration, splits, frequency in scenes(args.quick):
        start = start if start is not None else model.initial_state()
        times = np.arange(0, round(duration / DT) + 1) * DT
        ref = csb.integrate_reference(model, start, times, gravity=gravity, energy_tolerance=ENERGY_TOLERANCE,
                                      frequency=frequency)
        kinetic = max(csb.measure(model, s, gravity)["kinetic_energy"] for s in ref.states(model))
        runs = {"reference": np.array([method_energy(model, s, gravity, reference=True) for s in ref.states(model)])}
        for substeps, iterations in splits:
            runs[f"PBD {substeps}x{iterations}"] = energy_series(model, start, times, gravity, method="pbd", dt=DT,
                                                                   substeps=substeps, iterations=iterations)
        for method, energy in runs.items():
            is_ref = method == "reference"
            rows.append(dict(scene=name, method=method, duration_s=duration,
                             drift_per_second=drift_per_second(times, energy, kinetic),
                             final_change=(energy[-1] - energy[0]) / kinetic,
                             frequency_rad_s=frequency if is_ref else "", rtol=ref.stats["rtol"] if is_ref else "",
                             energy_bound=ref.stats["energy_bound"] if is_ref else "",
                             steps=ref.stats["steps"] if is_ref else ""))
            series += [dict(scene=name, method=method, t=t, relative_energy=(e - energy[0]) / kinetic)
                       for t, e in zip(times, energy)]
    write_csv(out / "energy_drift.csv", rows)
    write_csv(out / "energy_drift_series.csv", series)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.8), constrained_layout=True)
    for ax, name in zip(axes, names):
        for method in dict.fromkeys(s["method"] for s in series if s["scene"] == name):
            pts = [s for s in series if s["scene"] == name and s["method"] == method]
            ax.plot([p["t"] for p in pts], [100 * p["relative_energy"] for p in pts], label=method,
                    lw=2 if method == "reference" else 1.2, color="k" if method == "reference" else None)
        ax.set_title(name, fontsize="medium")
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    axes[0].set_ylabel("energy change (% of the largest kinetic energy)")
    fig.suptitle("Energy drift, undamped: PBD at dt = 1/60 s (sub-steps x iterations per step) and the CVODE reference",
                 fontsize="medium")
    fig.savefig(out / "energy_drift.png", dpi=120)

    print(f"{'scene':12s} {'method':14s} {'drift per s':>12s} {'change over run':>16s}")
    for r in rows:
        print(f"{r['scene']:12s} {r['method']:14s} {r['drift_per_second']:>12.3e} {r['final_change']:>16.3e}")
    print("The reference (rtol='auto', energy_tolerance 1e-6, periods of the energy-carrying frequency):")
    for r in rows:
        if r["method"] == "reference":
            print(f"  {r['scene']:12s} frequency {r['frequency_rad_s']:6.2f} rad/s  rtol {r['rtol']:.2e}  "
                  f"bound {r['energy_bound']:.1e}  measured {abs(r['final_change']):.1e}  {r['steps']} steps")
    print(f"  wrote {out / 'energy_drift.csv'}, {out / 'energy_drift_series.csv'} and {out / 'energy_drift.png'}")


if __name__ == "__main__":
    main()
