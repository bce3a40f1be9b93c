#!/usr/bin/env python3
"""Study: what single precision costs in accuracy, against the reference, and gives in speed.

Accuracy, on the two scenes of the accuracy-against-cost study (pareto.py): a 10-link chain (5 cm
links, 5 g nodes, link compliance 1e-6 m/N) pinned at its top and released at 20°, and a 12 x 12
cloth (0.5 m, 0.2 kg/m², stretch compliance 1e-4 m/N, bending 1 1/(N m)) hanging from two corners,
1 s each, against CVODE at rtol 1e-11. PBD, XPBD and Jakobsen step each at dt = 1/60 s in 1 to 64
sub-steps of one iteration (the small-steps regime; dt rounded so that whole steps fill each of
the ten output intervals: 1/60 s over 1 s, 1/66.7 s over --quick's 0.3 s), once with
PbdStepper(precision="float64") and once with "float32". The error of a run is the largest
distance of any particle from the reference at any of ten output times, relative to the scene's
size (0.5 m); "rounding" is float32's own largest distance from float64 over the same times.

Speed, on cloths big enough for it to matter: the bundled cloth_grid at 64², 128² and 256², 10 x 1
and 1 x 10, two threads, PBD and XPBD each in float64 and float32 taking turns within each round
(csb.bench.precision_table); and the distance and bending kernels on one thread
(csb.bench.precision_rates).

Writes precision_<scene>.csv, precision_speed.csv, precision_kernels.csv and precision.png (error
against sub-steps per precision, and ms per frame per precision).

    python validation/precision.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import csb
from csb.bench import format_precision_rates, format_precision_table, precision_rates, precision_table
from csb.studies import hanging_cloth, run_method, swinging_chain, write_csv

G = (0.0, -9.81, 0.0)
SIZE = 0.5  # m, both scenes
METHODS = ("pbd", "xpbd", "jakobsen")


def sweep(model: csb.Model, duration: float, substeps: tuple[int, ...]) -> list[dict]:
    start = model.initial_state()
    times = np.linspace(0, duration, 11)
    ref = csb.integrate_reference(model, start, times, gravity=G, rtol=1e-11, atol=1e-13)
    interval = times[1] - times[0]
    dt = interval / max(1, round(interval * 60))  # about 1/60 s, a whole number of steps per output interval
    rows = []
    for method in METHODS:
        for n in substeps:
            row = dict(method=method, substeps=n)
            x = {}
            for precision in ("float64", "float32"):
                stepper = csb.PbdStepper(method=method, dt=dt, substeps=n, iterations=1, gravity=G, threads=1,
                                         precision=precision)
                r = run_method(model, start, times, stepper, dt=dt, reference_x=ref.x, positions=True)
                row[precision + "_error"] = r["error"] / SIZE
                row[precision + "_cpu_per_simulated_s"] = r["cpu_time"] / duration
                row[precision + "_blew_up"] = r["blew_up"]
                x[precision] = r["x"]
            row["rounding"] = (float(np.linalg.norm(x["float32"] - x["float64"], axis=2).max()) / SIZE
                               if x["float32"] is not None and x["float64"] is not None else float("nan"))
            rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true",
                        help="a 5-link chain and a 6 x 6 cloth for 0.3 s, fewer sub-steps; speed at 64² and 128², "
                             "3 rounds")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    scenes = {
        "chain": swinging_chain(links=5 if args.quick else 10, compliance=1e-6),
        "cloth": hanging_cloth(6 if args.quick else 12, size=SIZE),
    }
    duration = 0.3 if args.quick else 1.0
    substeps = (1, 4, 16, 64) if args.quick else (1, 2, 4, 8, 16, 32, 64)
    accuracy = {}
    for name, model in scenes.items():
        accuracy[name] = sweep(model, duration, substeps)
        write_csv(out / f"precision_{name}.csv", accuracy[name])
    speed = precision_table(sizes=(64, 128) if args.quick else (64, 128, 256), rounds=3 if args.quick else 7)
    write_csv(out / "precision_speed.csv", [{k: v for k, v in r.items() if not k.endswith("_spread")} for r in speed])
    kernels = precision_rates(sizes=(128,) if args.quick else (128, 256), rounds=3 if args.quick else 7)
    write_csv(out / "precision_kernels.csv", [{k: v for k, v in r.items() if not k.endswith("_spread")}
                                              for r in kernels])

    for name, rows in accuracy.items():
        print(f"{name}: largest distance to the reference / size, float64 and float32, and float32's own distance "
              f"from float64 (rounding)")
        print(f"  {'method':>8} {'sub-steps':>9} {'float64':>9} {'float32':>9} {'rounding':>9} {'32/64':>6}")
        for r in rows:
            e64, e32 = r["float64_error"], r["float32_error"]
            print(f"  {r['method']:>8} {r['substeps']:>9} {e64:>9.2e} {e32:>9.2e} {r['rounding']:>9.1e} "
                  f"{e32 / e64 if e64 > 0 else float('nan'):>6.3f}"
                  + ("  blew up" if r["float64_blew_up"] or r["float32_blew_up"] else ""))
        worst = max((r for r in rows if r["float64_error"] > 0), key=lambda r: r["rounding"] / r["float64_error"])
        print(f"  float32's rounding is at most {worst['rounding'] / worst['float64_error']:.2g} of the method's own "
              f"error ({worst['method']}, {worst['substeps']} sub-steps: {worst['rounding']:.1e} against "
              f"{worst['float64_error']:.1e})")
    print("\nWhole frames (cloth_grid, dt = 1/60 s, two threads), ms per frame:")
    print(format_precision_table(speed))
    print("\nThe kernels (one thread), ns per projection:")
    print(format_precision_rates(kernels))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"pbd": "C0", "xpbd": "C1", "jakobsen": "C2"}
    fig, axes = plt.subplots(1, 3, figsize=(16, 5), constrained_layout=True)
    for ax, (name, rows) in zip(axes[:2], accuracy.items()):
        for method in METHODS:
            pts = [r for r in rows if r["method"] == method]
            ax.loglog([r["substeps"] for r in pts], [r["float64_error"] for r in pts], "o-", color=colours[method],
                      label=f"{method} float64")
            ax.loglog([r["substeps"] for r in pts], [r["float32_error"] for r in pts], "x--", color=colours[method],
                      ms=9, label=f"{method} float32")
            ax.loglog([r["substeps"] for r in pts], [r["rounding"] for r in pts], ":", color=colours[method],
                      label=f"{method} float32 - float64")
        ax.set_title(f"{name}: error against the reference, dt ≈ 1/60 s", fontsize="medium")
        ax.set_xlabel("sub-steps of one iteration")
        ax.set_ylabel("largest distance / size")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize="x-small", ncol=2)
    ax = axes[2]
    for method, marker in (("pbd", "o"), ("xpbd", "s")):
        for substeps_, iterations in ((10, 1), (1, 10)):
            pts = [r for r in speed if r["substeps"] == substeps_ and r["iterations"] == iterations]
            label = f"{method} {substeps_} x {iterations}"
            ax.loglog([r["n"] ** 2 for r in pts], [r[f"{method}_float64"] for r in pts], marker + "-",
                      color=colours[method], alpha=0.5 + 0.5 * (substeps_ == 10), label=label + " float64")
            ax.loglog([r["n"] ** 2 for r in pts], [r[f"{method}_float32"] for r in pts], marker + "--",
                      color=colours[method], mfc="none", alpha=0.5 + 0.5 * (substeps_ == 10), label=label + " float32")
    ax.set_title("cloth_grid, two threads: ms per frame", fontsize="medium")
    ax.set_xlabel("particles")
    ax.set_ylabel("ms per frame (median)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize="x-small", ncol=2)
    fig.savefig(out / "precision.png", dpi=120)
    print(f"\n  wrote {out}/precision_chain.csv, precision_cloth.csv, precision_speed.csv, precision_kernels.csv "
          f"and precision.png ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
