#!/usr/bin/env python3
"""Study: XPBD measured against the same-step reference (backward Euler at XPBD's own time step,
solved by Newton's method from XPBD's own state: csb.BackwardEuler).

1. The backward-Euler residual |∇E| (N) of one XPBD step against its iteration count and its CPU
   time, Gauss-Seidel and Jacobi, on XPBD's §6.2 chain (20 x 1 kg, 1 m links of α = 1e-8 m/N,
   after 30 steps of falling) and on a hanging cloth (n x n, 0.2 kg, stretch α = 1e-4 m/N,
   bending 0.1 1/(N m), after 30 steps), dt = 1/60 s; the Newton solve's own point for scale.
2. The §6.2 chain claim (XPBD's support force 6 %, 2 %, 0.5 % off at 50, 100, 1000 iterations)
   measured two ways: against backward Euler solved from XPBD's state at every frame (the solver
   error alone) and against backward Euler's own trajectory (the paper's reading), with links of
   0.5, 1 and 2 m.

Writes residual.csv, chain_same_step.csv and residual.png.

    python validation/residual.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import csb  # noqa: F401  (the package, for csb.studies' imports)
from csb.studies import write_csv
from csb.studies.same_step import falling_chain, hanging_cloth, residual_curve, xpbd_chain_same_step


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="out/validation", help="output directory")
    p.add_argument("--quick", action="store_true", help="a 12 x 12 cloth, fewer iteration counts, the 1 m chain only")
    a = p.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)

    iterations = (1, 3, 10, 30, 100) if a.quick else (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)
    scenes = {"chain": falling_chain(1.0), "cloth": hanging_cloth(12 if a.quick else 32)}
    rows = []
    for scene, model in scenes.items():
        for solver in ("gauss-seidel", "jacobi"):
            for r in residual_curve(model, solver=solver, iterations=iterations, repeats=1 if a.quick else 3):
                if r["method"] == "backward-euler" and solver != "gauss-seidel":
                    continue
                rows.append(dict(scene=scene, **r))
    write_csv(out / "residual.csv", rows)

    links = (1.0,) if a.quick else (0.5, 1.0, 2.0)
    chain = [r for link in links for r in xpbd_chain_same_step(link=link, frames=30 if a.quick else 100)]
    write_csv(out / "chain_same_step.csv", chain)

    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    fig, axes = plt.subplots(2, 2, figsize=(10, 8))
    for row, scene in enumerate(scenes):
        for solver, marker in (("gauss-seidel", "o-"), ("jacobi", "s--")):
            pts = [r for r in rows if r["scene"] == scene and r["solver"] == solver]
            label = f"XPBD {solver}"
            axes[row, 0].loglog([r["iterations"] for r in pts], [r["residual_norm_N"] for r in pts], marker, label=label)
            axes[row, 1].loglog([r["cpu_s"] * 1e3 for r in pts], [r["residual_norm_N"] for r in pts], marker, label=label)
        be = [r for r in rows if r["scene"] == scene and r["method"] == "backward-euler"][0]
        axes[row, 1].loglog([be["cpu_s"] * 1e3], [max(be["residual_norm_N"], 1e-12)], "k*", ms=12,
                            label=f"backward Euler, Newton ({be['iterations']} it.)")
        axes[row, 0].set_xlabel("iterations per step")
        axes[row, 1].set_xlabel("CPU time per step (ms)")
        for c in range(2):
            axes[row, c].set_ylabel("backward-Euler residual |∇E| (N)")
            axes[row, c].set_title(f"{scene}: {scenes[scene].num_particles} particles, dt = 1/60 s", fontsize="medium")
            axes[row, c].grid(True, which="both", alpha=0.3)
            axes[row, c].legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(out / "residual.png", dpi=110)

    print("backward-Euler residual of one XPBD step (2-norm, N), dt = 1/60 s:")
    for scene in scenes:
        for solver in ("gauss-seidel", "jacobi"):
            pts = [r for r in rows if r["scene"] == scene and r["solver"] == solver]
            print(f"  {scene:5s} {solver:12s} " + ", ".join(f"{r['iterations']}: {r['residual_norm_N']:.3g}" for r in pts))
    print("XPBD's support force on the §6.2 chain (20 x 1 kg, α = 1e-8 m/N, dt = 1/60 s), largest relative error:")
    print("  link  iterations  same step (all frames)  trajectory (all; from frame 10)  residual max/scale")
    for r in chain:
        print(f"  {r['link_m']:4g}  {r['iterations']:10d}  {100 * r['same_step_error']:20.3g} %  "
              f"{100 * r['trajectory_error']:10.3g} %; {100 * r['trajectory_error_from_frame_10']:.3g} %"
              f"  {r['residual_relative_max']:.3g}")
    print("  the paper: 6 %, 2 %, 0.5 % at 50, 100, 1000 iterations")
    print(f"  wrote {out}/residual.csv, chain_same_step.csv and residual.png")


if __name__ == "__main__":
    main()
