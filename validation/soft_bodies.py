#!/usr/bin/env python3
"""Study: soft bodies with tetrahedral volume constraints and a balloon (Müller 2007 §4.3, §4.5).

1. Volume over time. A 0.2 m soft tet cube (3³ cells of 6 tets, 500 kg/m³, stretch 1e-4 m/N,
   bulk modulus 1e5 Pa) falls and swings from one pinned corner for 2 s (dt = 1/60 s, 4
   substeps, 10 iterations): relative total-volume error and worst per-tet |V - V0|/V0, for PBD
   (hard constraints) and XPBD (compliant). A 162-vertex icosphere balloon (hard stretch, hard
   overpressure at pressure 1) hangs from its top vertex: V/V0 - 1 over time, PBD and XPBD.
2. Tet cantilever against the reference. A 0.4 x 0.1 x 0.1 m beam of 192 tets (stretch 1e-4 m/N,
   bulk modulus 1e6 Pa, 4 kg), its x = 0 face pinned, swings under gravity for 0.5 s; XPBD with
   one iteration and n substeps of dt = 1/60 s against CVODE (KLU, analytic volume Jacobian):
   largest particle distance over t = 0.1 .. 0.5 s and the tip deflection at 0.5 s.

Writes soft_volume.csv, soft_cantilever.csv and soft_bodies.png.

    python validation/soft_bodies.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import csb
from csb.studies.soft_bodies import (hanging_balloon, hanging_tet_cube, tet_cantilever, total_volume,
                             xpbd_error_against_reference)
from csb.studies import hard_under_pbd, write_csv


def volume_series(scene: str, method: str, seconds: float) -> list[dict]:
    if scene == "tet cube":
        model, _ = hanging_tet_cube()
        stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=4, iterations=10)
    else:
        model, _ = hanging_balloon(pressure=1.0)
        stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=2, iterations=10)
    state = model.initial_state()
    v0 = total_volume(model, state) if scene == "tet cube" else model.balloons["rest_volume"][0]
    rows = []
    for _ in range(int(round(seconds * 60))):
        with hard_under_pbd():  # the scenes declare compliances: PBD's constraints are hard, and compared so
            stepper.step(model, state)
        if scene == "tet cube":
            err = total_volume(model, state) / v0 - 1
            per_tet = float(np.abs(csb.volume_violations(model, state) / model.volume["rest_volume"]).max())
        else:
            err = csb.balloon_volumes(model, state)[0] / v0 - 1
            per_tet = float("nan")
        rows.append({"scene": scene, "method": method, "t": round(state.t, 6), "volume_error": err,
                     "max_tet_error": per_tet, "lowest_y": float(state.x[:, 1].min())})
    return rows


def cantilever_rows(substeps: list[int]) -> list[dict]:
    model, tip = tet_cantilever()
    times = [0.1, 0.2, 0.3, 0.4, 0.5]
    # Positions are compared: rtol 1e-8, the tolerance at which the reference's trajectories converge.
    ref = csb.integrate_reference(model, model.initial_state(), times, rtol=1e-8, atol=1e-10)
    ref_tip = float(ref.x[-1, tip, 1].mean())
    rows = []
    for n in substeps:
        err, state = xpbd_error_against_reference(model, ref, times, n)
        rows.append({"substeps": n, "h": 1 / 60 / n, "max_error_m": err, "tip_y_m": float(state.x[tip, 1].mean()),
                     "reference_tip_y_m": ref_tip, "reference_steps": ref.stats["steps"],
                     "reference_solver": ref.stats["linear_solver"]})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="1 s instead of 2 and fewer substep counts (the tests' version)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seconds = 1.0 if args.quick else 2.0
    volume = [r for scene in ("tet cube", "balloon") for m in ("pbd", "xpbd") for r in volume_series(scene, m, seconds)]
    write_csv(out / "soft_volume.csv", volume)
    cantilever = cantilever_rows([4, 16, 64] if args.quick else [4, 16, 64, 256, 1024])
    write_csv(out / "soft_cantilever.csv", cantilever)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for scene in ("tet cube", "balloon"):
        for m in ("pbd", "xpbd"):
            rs = [r for r in volume if r["scene"] == scene and r["method"] == m]
            a.semilogy([r["t"] for r in rs], [max(abs(r["volume_error"]), 1e-17) for r in rs], label=f"{scene}, {m.upper()}")
    a.set_xlabel("t (s)")
    a.set_ylabel("|V/V0 - 1|")
    a.set_title("volume error over time")
    a.legend()
    b.loglog([r["h"] for r in cantilever], [r["max_error_m"] for r in cantilever], "o-", label="XPBD, 1 iteration")
    b.set_xlabel("sub-step h (s)")
    b.set_ylabel("max |x - x_ref| over 0.1..0.5 s (m)")
    b.set_title("tet cantilever vs CVODE reference")
    b.legend()
    fig.tight_layout()
    fig.savefig(out / "soft_bodies.png", dpi=120)

    print(f"volume error over {seconds:g} s (max |V/V0 - 1|; tet cube also the worst tet):")
    for scene in ("tet cube", "balloon"):
        for m in ("pbd", "xpbd"):
            rs = [r for r in volume if r["scene"] == scene and r["method"] == m]
            worst = max(abs(r["volume_error"]) for r in rs)
            tet = max(r["max_tet_error"] for r in rs) if scene == "tet cube" else None
            print(f"  {scene:9s} {m.upper():5s} total {worst:.2e}" + (f", worst tet {tet:.2e}" if tet is not None else ""))
    print(f"tet cantilever, tip y at 0.5 s: reference {cantilever[0]['reference_tip_y_m']:.5f} m "
          f"({cantilever[0]['reference_steps']} CVODE steps, {cantilever[0]['reference_solver']})")
    for r in cantilever:
        print(f"  XPBD {r['substeps']:5d} substeps (h = {r['h']:.2e} s): max error {r['max_error_m']:.2e} m, "
              f"tip y {r['tip_y_m']:.5f} m")
    print(f"  wrote {out}/soft_volume.csv, soft_cantilever.csv and soft_bodies.png")


if __name__ == "__main__":
    main()
