#!/usr/bin/env python3
"""Study: accuracy against speed, every method over its parameter range.

Two scenes, 1 s each: a 10-link chain (5 cm links, 5 g nodes, link compliance 1e-6 m/N) pinned at
its top and released at 20°, and a 12 x 12 cloth (0.5 m, 0.2 kg/m², stretch compliance 1e-4 m/N,
bending 1 1/(N m)) hanging from two corners. The error of a run is the largest distance of any
particle from the reference at any of ten output times, relative to the scene's size (0.5 m);
its cost is the CPU time per simulated second (the process's, time.process_time: stepping only, one
thread, so another process on a shared machine does not inflate it; the faster of two runs
for runs under 0.2 s). Methods and ranges:

  PBD, XPBD, Jakobsen   dt = 1/30 ... 1/960 s, 1, 5 or 20 iterations
  small steps           XPBD, one 1/60 s frame in 1 ... 128 sub-steps of one iteration
  symplectic Euler,     dt = 0.9, 0.5, 0.2, 0.1 x the stability limit 2/ω_max
  velocity Verlet
  explicit Euler        dt = 0.1, 0.01 x 2/ω_max (it is unstable at every dt for undamped springs)
  CVODE                 rtol = 1e-2 ... 1e-8 (atol = rtol/100), against itself at rtol 1e-11

Writes pareto_<scene>.csv, pareto.png and, per scene, the fastest method at 10 %, 1 % and 0.1 %.

    python validation/pareto.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

import csb
from csb.studies import hanging_cloth, make_stepper, omega_max, run_method, swinging_chain, write_csv

G = (0.0, -9.81, 0.0)
LEVELS = (0.1, 0.01, 0.001)
SIZE = 0.5  # m, both scenes


def timed(model, start, times, stepper, dt, ref_x):
    r = run_method(model, start, times, stepper, dt=dt, reference_x=ref_x)
    if r["cpu_time"] < 0.2 and not r["blew_up"]:
        r["cpu_time"] = min(r["cpu_time"], run_method(model, start, times, stepper, dt=dt, reference_x=ref_x)["cpu_time"])
    return r


def sweep(model: csb.Model, duration: float, quick: bool) -> list[dict]:
    start = model.initial_state()
    times = np.linspace(0, duration, 11)
    interval = times[1] - times[0]
    ref = csb.integrate_reference(model, start, times, gravity=G, rtol=1e-11, atol=1e-13)
    rows = []

    def add(method, settings, r):
        rows.append(dict(method=method, settings=settings, relative_error=r["error"] / SIZE,
                         cpu_per_simulated_s=r["cpu_time"] / duration, blew_up=r["blew_up"]))

    dts = (1 / 30, 1 / 120, 1 / 480) if quick else (1 / 30, 1 / 60, 1 / 120, 1 / 240, 1 / 480, 1 / 960)
    for method in ("pbd", "xpbd", "jakobsen"):
        for it in ((1, 20) if quick else (1, 5, 20)):
            for dt in dts:
                dt = interval / round(interval / dt)
                add(method, f"dt=1/{round(1 / dt)} it={it}", timed(model, start, times, make_stepper(method, dt=dt, iterations=it),
                                                                   dt, ref.x))
    frame = interval / round(interval * 60)
    for n in ((1, 8, 64) if quick else (1, 2, 4, 8, 16, 32, 64, 128)):
        add("small steps", f"1/60 s in {n} sub-steps",
            timed(model, start, times, make_stepper("small-steps", dt=frame, substeps=n), frame, ref.x))
    h_crit = 2 / omega_max(model, start, G)
    for method, factors in (("symplectic-euler", (0.9, 0.2) if quick else (0.9, 0.5, 0.2, 0.1)),
                            ("velocity-verlet", (0.9, 0.2) if quick else (0.9, 0.5, 0.2, 0.1)),
                            ("explicit-euler", (0.1,) if quick else (0.1, 0.01))):
        for f in factors:
            dt = interval / math.ceil(interval / (f * h_crit))
            if duration / dt > 3e6:
                continue
            add(method, f"dt={f:g} h_crit", timed(model, start, times, make_stepper(method, dt=dt), dt, ref.x))
    for rtol in ((1e-3, 1e-6) if quick else (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)):
        t0 = time.process_time()
        r = csb.integrate_reference(model, start, times, gravity=G, rtol=rtol, atol=rtol / 100)
        wall = time.process_time() - t0
        err = float(np.linalg.norm(r.x - ref.x, axis=2).max())
        rows.append(dict(method="CVODE", settings=f"rtol={rtol:g}", relative_error=err / SIZE,
                         cpu_per_simulated_s=wall / duration, blew_up=False))
    return rows


def fastest(rows: list[dict], level: float) -> dict | None:
    ok = [r for r in rows if not r["blew_up"] and r["relative_error"] <= level]
    return min(ok, key=lambda r: r["cpu_per_simulated_s"]) if ok else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="a 5-link chain and a 6 x 6 cloth, fewer settings")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scenes = {
        "chain": swinging_chain(links=5 if args.quick else 10, compliance=1e-6),
        "cloth": hanging_cloth(6 if args.quick else 12, size=SIZE),
    }
    duration = 0.3 if args.quick else 1.0
    results = {}
    for name, model in scenes.items():
        rows = sweep(model, duration, args.quick)
        results[name] = rows
        write_csv(out / f"pareto_{name}.csv", rows)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    markers = {"pbd": "o", "xpbd": "s", "jakobsen": "^", "small steps": "D", "symplectic-euler": "v",
               "velocity-verlet": "P", "explicit-euler": "X", "CVODE": "*"}
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), constrained_layout=True)
    for ax, (name, rows) in zip(axes, results.items()):
        for method, marker in markers.items():
            pts = [r for r in rows if r["method"] == method and not r["blew_up"]]
            if pts:
                ax.loglog([r["cpu_per_simulated_s"] for r in pts], [r["relative_error"] for r in pts], marker,
                          ls="none", label=method, ms=6, alpha=0.85)
        good = sorted((r for r in rows if not r["blew_up"]), key=lambda r: r["cpu_per_simulated_s"])
        front, best = [], math.inf
        for r in good:
            if r["relative_error"] < best:
                best = r["relative_error"]
                front.append(r)
        ax.step([r["cpu_per_simulated_s"] for r in front], [r["relative_error"] for r in front], "k-", lw=1,
                where="post", label="Pareto front")
        for level in LEVELS:
            ax.axhline(level, color="grey", lw=0.5, ls=":")
        ax.set_title(f"{name}: error against cost", fontsize="medium")
        ax.set_xlabel("CPU time per simulated second (s)")
        ax.set_ylabel("largest distance to the reference / size")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize="x-small", ncol=2)
    fig.savefig(out / "pareto.png", dpi=120)

    for name, rows in results.items():
        print(f"{name}: fastest within each error level (CPU seconds per simulated second)")
        for level in LEVELS:
            f = fastest(rows, level)
            if f is None:
                print(f"  {100 * level:g} %: none")
            else:
                print(f"  {100 * level:g} %: {f['method']} ({f['settings']}), {f['cpu_per_simulated_s']:.3g} s/s, "
                      f"error {100 * f['relative_error']:.3g} %")
        blown = [r for r in rows if r["blew_up"]]
        if blown:
            print("  blew up: " + ", ".join(f"{r['method']} {r['settings']}" for r in blown))
    print(f"  wrote {out}/pareto_chain.csv, pareto_cloth.csv and pareto.png")


if __name__ == "__main__":
    main()
