#!/usr/bin/env python3
"""Study: the claims of XPBD (Macklin, Müller, Chentanez 2016), measured.

1. Stiffness independent of the iteration count and the time step. A 64 x 64 cloth (1 m,
   0.2 kg/m²) hangs from its top edge until at rest (Müller damping 0.1 per sub-step); its sag
   (how far the bottom edge's middle ends up below where an inextensible cloth would) measures
   how stiff it behaves. PBD with k = 0.01 (no correction, as in the paper) and XPBD with
   α = 0.05 m/N per edge (a static sag of about 5 cm) run at 20, 40, 80, 160 and 320 iterations
   (dt = 1/60 s), and at the most iterations with dt = 1/30 and 1/120 s.
2. Constraint forces, under the paper's protocol (its §6.2): a chain of 20 particles (1 kg each,
   links of compliance α = 1e-8 m/N) pinned at one end, released straight and horizontal at rest
   length, falls for 100 frames of 1/60 s. XPBD (one sub-step, 50, 100, 1000 and 3000
   Gauss-Seidel iterations) and backward Euler solved by Newton's method to convergence
   (csb.backward_euler) each run their own trajectory from that state; the support force (the
   link at the pin: XPBD's |λ|/h², backward Euler's |C|/α) is compared frame by frame. The paper
   gives no link length: links of 0.1, 0.5, 1 and 2 m. Reported: the largest relative error over
   all frames, in the first frame, from frame 10 on (the first 0.15 s left out), over frames
   75-100 (the window the paper's Figure 3a plots) and over all links; and the largest error of
   one converged XPBD step (3000 iterations) against a backward Euler step from the same state,
   which is XPBD's own distance from the implicit step.
3. The cost of XPBD over PBD: ms per step on the bundled cloth_grid scene (stretch and
   bending, whose compliance XPBD uses) at 64 x 64 and 128 x 128, 10 iterations, median of 7
   rounds.

Writes xpbd_stiffness.csv, xpbd_chain.csv (per link length and iteration count),
xpbd_chain_frames.csv (the support force per frame), xpbd_cost.csv and xpbd.png.

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
from csb.studies.literature import xpbd_chain
from csb.backward_euler import BackwardEulerStepper
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


CHAIN_FRAMES = 100
CHAIN_DT = 1 / 60  # s
PAPER_WINDOW = (75, 100)  # frames on the abscissa of the paper's Figure 3a


def xpbd_chain_forces(model: csb.Model, iterations: int) -> np.ndarray:
    """(frames, links) constraint force magnitudes |λ|/h² (N) along XPBD's own trajectory."""
    stepper = csb.PbdStepper(method="xpbd", dt=CHAIN_DT, iterations=iterations)
    state = model.initial_state()
    forces = []
    for _ in range(CHAIN_FRAMES):
        stepper.step(model, state)
        forces.append(np.abs(stepper.multipliers()["distance"]) / stepper.substep_size**2)
    return np.array(forces)


def chain_errors(link: float, iterations: tuple[int, ...]) -> tuple[list[dict], list[dict]]:
    """The chain experiment for one link length: a summary row per iteration count and the
    support force per frame."""
    model = xpbd_chain(link=link)  # the paper's chain: 20 x 1 kg, α = 1e-8 m/N, horizontal start
    reference = BackwardEulerStepper(dt=CHAIN_DT, gravity=G)
    state = model.initial_state()
    ref, newton = [], []
    for _ in range(CHAIN_FRAMES):
        reference.step(model, state)
        ref.append(np.abs(reference.forces))
        newton.append(reference.newton_iterations)
    ref = np.array(ref)
    # One converged XPBD step against one backward Euler step from the same (XPBD's) state.
    converged = csb.PbdStepper(method="xpbd", dt=CHAIN_DT, iterations=iterations[-1])
    one_step = BackwardEulerStepper(dt=CHAIN_DT, gravity=G)
    state = model.initial_state()
    same_state = 0.0
    for _ in range(CHAIN_FRAMES):
        start = state.copy()
        one_step.step(model, start)
        converged.step(model, state)
        xpbd = abs(converged.multipliers()["distance"][0]) / converged.substep_size**2
        same_state = max(same_state, abs(xpbd / abs(one_step.forces[0]) - 1))
    first, last = PAPER_WINDOW
    rows, frames = [], [dict(link_m=link, frame=k + 1, method="backward Euler", support_force_N=ref[k, 0])
                        for k in range(CHAIN_FRAMES)]
    for it in iterations:
        forces = xpbd_chain_forces(model, it)
        error = np.abs(forces - ref) / ref
        frames += [dict(link_m=link, frame=k + 1, method=f"XPBD {it}", support_force_N=forces[k, 0])
                   for k in range(CHAIN_FRAMES)]
        rows.append(dict(
            link_m=link, iterations=it, support_error=error[:, 0].max(), frame_of_max=int(error[:, 0].argmax()) + 1,
            support_error_frame_1=error[0, 0], support_error_frames_10_100=error[9:, 0].max(),
            support_error_frames_75_100=error[first - 1:last, 0].max(),
            error_all_links=error.max(), reference_support_N_frame_1=ref[0, 0],
            reference_support_N_min_75_100=ref[first - 1:last, 0].min(),
            reference_support_N_max_75_100=ref[first - 1:last, 0].max(),
            converged_one_step_error=same_state if it == iterations[-1] else "",
            newton_residual_max_N=max(reference.max_residual, one_step.max_residual),
            newton_iterations_max=max(newton)))
    return rows, frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true",
                        help="a 16 x 16 cloth, the chain with 1 m links only, fewer settings (the tests' version)")
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

    links = (1.0,) if args.quick else (0.1, 0.5, 1.0, 2.0)
    chain, chain_frames = [], []
    for link in links:
        rows_link, frames_link = chain_errors(link, (50, 100, 1000, 3000))
        chain += rows_link
        chain_frames += frames_link
    write_csv(out / "xpbd_chain.csv", chain)
    write_csv(out / "xpbd_chain_frames.csv", chain_frames)

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

    fig, (a, b2, c, d) = plt.subplots(1, 4, figsize=(18, 4.2), constrained_layout=True)
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
    shown = 0.5 if 0.5 in links else links[0]  # 0.5 m: in frames 75-100 its force spans the paper's plot
    for label in dict.fromkeys(r["method"] for r in chain_frames):
        pts = [r for r in chain_frames if r["method"] == label and r["link_m"] == shown]
        c.plot([r["frame"] for r in pts], [r["support_force_N"] for r in pts],
               "k--" if label == "backward Euler" else "-", label=label, lw=1)
    c.set_xlabel(f"frame (1/60 s), links of {shown:g} m")
    c.set_ylabel("support force (N)")
    c.set_title("falling 20-particle chain, α = 1e-8 m/N", fontsize="medium")
    c.legend(fontsize="x-small")
    for it in dict.fromkeys(r["iterations"] for r in chain):
        pts = [r for r in chain if r["iterations"] == it]
        line, = d.loglog([r["link_m"] for r in pts], [100 * r["support_error"] for r in pts], "o-", label=f"XPBD {it}")
        d.loglog([r["link_m"] for r in pts], [100 * r["support_error_frames_75_100"] for r in pts], "s:",
                 color=line.get_color())
    d.set_xlabel("link length (m)")
    d.set_ylabel("support force error (%)")
    d.set_title("largest error: all 100 frames (o), frames 75-100 (s)", fontsize="medium")
    d.legend(fontsize="x-small")
    for ax in (a, b2, c, d):
        ax.grid(alpha=0.3, which="both")
    fig.savefig(out / "xpbd.png", dpi=120)

    print(f"hanging {n} x {n} cloth, sag after {seconds:g} s (cm; XPBD is at rest by then, PBD at k = 0.01 still sinking):")
    for label in dict.fromkeys(r["method"] for r in rows):
        pts = [r for r in rows if r["method"] == label]
        print(f"  {label:24s} " + "  ".join(
            f"{r['iterations']} it, 1/{round(1 / r['dt'])} s: {100 * r['sag_m']:.3f}" for r in pts))
    print("falling chain (20 x 1 kg, α = 1e-8 m/N, horizontal start, 100 frames of 1/60 s), XPBD's support force "
          "against backward Euler solved by Newton (largest residual "
          f"{max(r['newton_residual_max_N'] for r in chain):.2g} N), largest relative error:")
    print("  link    iterations   all frames (frame)    frame 1   frames 10-100   frames 75-100   all links   "
          "converged one step")
    for r in chain:
        one = f"{100 * r['converged_one_step_error']:.3g} %" if r["converged_one_step_error"] != "" else ""
        print(f"  {r['link_m']:4g} m  {r['iterations']:10d}"
              f"   {100 * r['support_error']:9.3g} % ({r['frame_of_max']:3d})"
              f"   {100 * r['support_error_frame_1']:7.3g} %   {100 * r['support_error_frames_10_100']:11.3g} %"
              f"   {100 * r['support_error_frames_75_100']:11.3g} %   {100 * r['error_all_links']:7.3g} %   {one}")
    print("  backward Euler support force: " + ", ".join(
        f"{link:g} m: {r['reference_support_N_frame_1']:.3g} N in frame 1, {r['reference_support_N_min_75_100']:.0f}-"
        f"{r['reference_support_N_max_75_100']:.0f} N in frames 75-100"
        for link in links for r in chain if r["link_m"] == link and r["iterations"] == 50))
    print("  the paper: 6 %, 2 %, 0.5 % at 50, 100, 1000 iterations; its Figure 3a plots 350-600 N over frames 75-100")
    print("cost: " + ", ".join(f"{r['cloth']} PBD {r['pbd_ms']:.2f} ms, XPBD {r['xpbd_ms']:.2f} ms "
                               f"(x{r['xpbd_over_pbd']:.3f})" for r in cost))
    print(f"  wrote {out}/xpbd_stiffness.csv, xpbd_chain.csv, xpbd_chain_frames.csv, xpbd_cost.csv and xpbd.png")


if __name__ == "__main__":
    main()
