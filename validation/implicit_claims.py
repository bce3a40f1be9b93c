#!/usr/bin/env python3
"""Study: the claims of the implicit methods, measured. Each part prints its table and writes a CSV.

1. Implicit Euler (Baraff and Witkin 1998).
   a. Numerical damping grows with the time step. On a linear oscillator (a 0.1 kg particle on a
      spring of 0.1 m/N, ω = 10 rad/s, no gravity) backward Euler keeps 1/(1 + ω²h²) of the
      energy per step: the measured fraction after 1 s beside that closed form. On the swinging
      10-link chain of the studies (links of 1e-6 m/N, released at 0.35 rad) the fraction of its
      swing's energy (its mechanical energy above hanging straight down at rest) kept after 1 s,
      at each dt, beside the continuous reference's (CVODE, rtol 1e-10).
   b. One Newton iteration per step against the converged step: a 12 x 12 hanging cloth (0.5 m,
      0.2 kg/m², stretch 1e-4 m/N, bending 1 1/(N m)) for 1 s at dt = 1/60 s; the largest
      distance to CVODE's trajectory at the end and the CPU time per step, for 1, 2 and 4 Newton
      iterations of PCG (the default budget of 100 iterations, and 20), 1 and 2 of the sparse
      direct solve, and Newton to convergence (with its mean Newton iterations per step).
   c. Stability: a chain of stiff links (1e-8 m/N, ω ~ 3e4 rad/s) at dt = 1/30 and 1/10 s for 3 s:
      whether the step stays finite and the mechanical energy ever rises above its start, for
      backward Euler (Newton to convergence, up to 5000 iterations: a stiff chain at 0.1 s takes
      up to about a hundred), one Newton iteration, and symplectic Euler for contrast.
2. Projective Dynamics (Bouaziz et al. 2014) and its Chebyshev acceleration (Wang 2015): one step
   of 1/60 s of the studies' hanging cloth (32 x 32; 0.5 m, 0.2 kg/m², stretch 1e-4 m/N, bending
   1 1/(N m)) in mid-swing (after 20 converged steps from rest): the backward-Euler residual after
   each of 500 iterations, plain and with Chebyshev (Wang's delay S = 10 and γ = 0.9, ρ measured
   on the plain iterations), the mean reduction per iteration over the first 10 and over the
   second half, the iterations to 1e-2 and 1e-3 of the start's residual; Newton's residuals on
   the same step; the prefactorisation's time against one iteration's, one thread.
3. Vertex Block Descent (Chen, Liu, Yang and Yuksel 2024) against XPBD.
   a. At equal budgets: one step of 1/60 s of the moving 32 x 32 cloth and of the studies' tet
      cube (0.2 m, 3³ cells of 6 tets; after 20 converged steps), 1 ... 100 iterations, one
      thread: the backward-Euler residual over the step's force scale and the ms per step.
   b. The accelerated variant (§3.8): the same step of the cloth at 4 ... 256 sweeps with
      ρ = 0, 0.5, 0.9, 0.95.
   c. On the chains of their stress tests (csb.studies.literature): stiffness_ratio_chain (links
      alternating α and α/ratio) and mass_ratio_chain (the end particle ratio times heavier),
      hanging at rest for 1 s at dt = 1/60 s, 10 iterations a step. Their exact answer is the
      static equilibrium (each link stretched by its compliance times the weight below it);
      reported, the largest distance of any particle from it over the second, at ratios 1 ... 1e4.

Writes implicit_damping.csv, implicit_newton.csv, implicit_stability.csv, pd_convergence.csv,
pd_cost.csv, vbd_xpbd.csv, vbd_acceleration.csv, ratio_chains.csv and implicit_claims.png.

    python validation/implicit_claims.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

import csb
from csb.reference import integrate_reference
from csb.studies import copy_state, write_csv
from csb.studies.literature import mass_ratio_chain, stiffness_ratio_chain
from csb.studies.soft_bodies import hanging_tet_cube
from csb.studies.study.schema import hanging_cloth
from csb.studies import swinging_chain

G = (0.0, -9.81, 0.0)


def mechanical_energy(model: csb.Model, state: csb.State, gravity=G) -> float:
    return float(csb.measure(model, state, gravity)["total_energy"])


# ------------------------------------------------------------------------------ implicit Euler


def oscillator() -> csb.Model:
    b = csb.ModelBuilder()
    g = b.add_group("oscillator")
    b.add_particle([0, 0, 0], 0.1, g)
    b.add_particle([1.05, 0, 0], 0.1, g)
    b.add_distance(0, 1, compliance=0.1, rest_length=1.0)
    b.pin(0)
    return b.build()


def damping(dts: tuple[float, ...]) -> list[dict]:
    rows = []
    model = oscillator()
    omega2 = 1 / (0.1 * 0.1)
    for dt in dts:
        s = model.initial_state()
        e0 = mechanical_energy(model, s, (0, 0, 0))
        steps = round(1.0 / dt)
        csb.make_integrator("backward-euler", dt, gravity=(0, 0, 0)).step(model, s, steps)
        rows.append(dict(scene="oscillator", dt=dt, kept=mechanical_energy(model, s, (0, 0, 0)) / e0,
                         closed_form=(1 + omega2 * dt * dt) ** -steps, reference_kept=1.0))
    chain = swinging_chain(links=10, compliance=1e-6)
    start = chain.initial_state()
    hanging = chain.initial_state()  # straight down from the pin, at rest length and at rest
    rest = np.asarray(chain.distance["rest_length"])
    x = np.asarray(start.x)
    hanging.x = x[0] - np.outer(np.concatenate([[0.0], np.cumsum(rest)]), [0.0, 1.0, 0.0])
    bottom = mechanical_energy(chain, hanging)
    swing = mechanical_energy(chain, start) - bottom
    ref = integrate_reference(chain, start, [0.0, 1.0], gravity=G, rtol=1e-10, atol=1e-12)
    ref_state = chain.initial_state()
    ref_state.x, ref_state.v = ref.x[-1], ref.v[-1]
    ref_kept = (mechanical_energy(chain, ref_state) - bottom) / swing
    for dt in dts:
        s = chain.initial_state()
        csb.make_integrator("backward-euler", dt).step(chain, s, round(1.0 / dt))
        rows.append(dict(scene="chain", dt=dt, kept=(mechanical_energy(chain, s) - bottom) / swing,
                         closed_form=float("nan"), reference_kept=ref_kept))
    return rows


def newton_budget(n: int, seconds: float) -> list[dict]:
    model = hanging_cloth(n=n, stretch_compliance=1e-4, bending_compliance=1.0)
    dt = 1 / 60
    steps = round(seconds / dt)
    ref = integrate_reference(model, model.initial_state(), [0.0, steps * dt], gravity=G, rtol=1e-10, atol=1e-12)
    rows = []
    for label, name, iterations, settings in (("1 Newton iteration", "implicit-euler", 1, {}),
                                              ("2 Newton iterations", "implicit-euler", 2, {}),
                                              ("4 Newton iterations", "implicit-euler", 4, {}),
                                              ("1 Newton iteration, 20 PCG", "implicit-euler", 1,
                                               dict(cg_iterations=20)),
                                              ("4 Newton iterations, 20 PCG", "implicit-euler", 4,
                                               dict(cg_iterations=20)),
                                              ("1 Newton iteration, direct solve", "implicit-euler", 1,
                                               dict(linear_solver="direct")),
                                              ("2 Newton iterations, direct solve", "implicit-euler", 2,
                                               dict(linear_solver="direct")),
                                              ("converged", "backward-euler", 1, {})):
        s = model.initial_state()
        stepper = csb.make_integrator(name, dt, iterations=iterations, **settings)
        c0 = time.process_time()
        stepper.step(model, s, steps)
        cpu = time.process_time() - c0
        rows.append(dict(method=label, error_m=float(np.max(np.linalg.norm(np.asarray(s.x) - ref.x[-1], axis=1))),
                         ms_per_step=1e3 * cpu / steps, newton_per_step=stepper.total_iterations / steps))
    return rows


def stiff_chain() -> csb.Model:
    b = csb.ModelBuilder()
    g = b.add_group("chain")
    for i in range(10):
        b.add_particle([0.1 * i, 0, 0], 0.1, g)
    for i in range(9):
        b.add_distance(i, i + 1, compliance=1e-8)
    b.pin(0)
    return b.build()


def stability(dts: tuple[float, ...]) -> list[dict]:
    model = stiff_chain()
    rows = []
    for dt in dts:
        for label, name, settings in (("backward Euler", "backward-euler", dict(max_iterations=5000)),
                                      ("1 Newton iteration", "implicit-euler", dict(iterations=1)),
                                      ("symplectic Euler", "symplectic-euler", {})):
            s = model.initial_state()
            e0 = mechanical_energy(model, s)
            stepper = csb.make_integrator(name, dt, **settings)
            rise, outcome, newton = 0.0, "stable", []
            try:
                for _ in range(round(3.0 / dt)):
                    stepper.step(model, s)
                    rise = max(rise, mechanical_energy(model, s) - e0)
                    if name != "symplectic-euler":
                        newton.append(stepper.newton_iterations)
            except csb.SimulationError:
                outcome = "blew up"
            rows.append(dict(dt=dt, method=label, outcome=outcome, largest_energy_rise_J=rise,
                             newton_per_step=f"{np.mean(newton):.3g} (most {max(newton)})" if newton else "-"))
    return rows


# ------------------------------------------------------------------------------ Projective Dynamics


def moving_cloth(n: int):
    """The studies' hanging cloth (0.5 m, 0.2 kg/m², stretch 1e-4 m/N, bending 1 1/(N m)) after
    20 converged backward Euler steps of 1/60 s from rest: a cloth in mid-swing."""
    model = hanging_cloth(n=n, stretch_compliance=1e-4, bending_compliance=1.0)
    s = model.initial_state()
    csb.make_integrator("backward-euler", 1 / 60).step(model, s, 20)
    return model, s


def pd_convergence(n: int, iterations: int) -> tuple[list[dict], list[dict]]:
    """One step of 1/60 s from the moving cloth: the backward-Euler residual after each iteration
    of PD, PD + Chebyshev (Wang's delay S = 10, γ = 0.9, ρ measured) and Newton (converged backward
    Euler, sparse LDLᵀ), and the costs: PD's prefactorisation against one iteration."""
    model, start = moving_cloth(n)
    curves = {}
    for label, settings in (("PD", {}), ("PD + Chebyshev", {"chebyshev": True})):
        pd = csb.make_integrator("projective-dynamics", 1 / 60, iterations=iterations, record_residuals=True,
                                 threads=1, **settings)
        pd.step(model, copy_state(model, start))
        curves[label] = list(pd.residual_history)
    be = csb.make_integrator("backward-euler", 1 / 60)
    be.step(model, copy_state(model, start))
    curves["Newton"] = list(be.history)
    rows = []
    for label, r in curves.items():
        for k, v in enumerate(r):
            rows.append(dict(method=label, iteration=k, residual_N=float(v)))
    # cost: a fresh stepper factors on its first step; later steps reuse it
    pd = csb.make_integrator("projective-dynamics", 1 / 60, iterations=iterations, threads=1)
    pd.step(model, copy_state(model, start))
    factor_ms = 1e3 * pd.last_factorization_time
    times = []
    for _ in range(5):
        s = copy_state(model, start)
        t0 = time.perf_counter()
        pd.step(model, s)
        times.append((time.perf_counter() - t0) / iterations * 1e3)
    be_times = []
    for _ in range(3):
        s = copy_state(model, start)
        t0 = time.perf_counter()
        be.step(model, s)
        be_times.append((time.perf_counter() - t0) * 1e3)
    cost = [dict(cloth=f"{n}x{n}", particles=model.num_particles, factorization_ms=factor_ms,
                 ms_per_iteration=float(np.median(times)), newton_ms_per_step=float(np.median(be_times)),
                 newton_iterations=be.newton_iterations)]
    return rows, cost


def reached(curve: list[float], fraction: float) -> int | None:
    """The first iteration at which the residual is within `fraction` of the start's."""
    for k, v in enumerate(curve):
        if v <= fraction * curve[0]:
            return k
    return None


# ------------------------------------------------------------------------------ ratio chains


def vbd_against_xpbd(n: int, budgets: tuple[int, ...], rounds: int) -> list[dict]:
    """One step of 1/60 s of the moving cloth and of the studies' tet cube (after 20 converged
    steps from rest), VBD and XPBD at equal iteration budgets, one thread: the backward-Euler
    residual over the step's force scale, and the median ms per step over `rounds` runs (the two
    methods taking turns)."""
    cube, _ = hanging_tet_cube()
    cube_start = cube.initial_state()
    csb.make_integrator("backward-euler", 1 / 60).step(cube, cube_start, 20)
    rows = []
    for scene, (model, start) in (("cloth", moving_cloth(n)), ("tet cube", (cube, cube_start))):
        for it in budgets:
            steppers = {"VBD": csb.make_integrator("vbd", 1 / 60, iterations=it, threads=1),
                        "XPBD": csb.PbdStepper(method="xpbd", dt=1 / 60, iterations=it, threads=1)}
            times = {k: [] for k in steppers}
            ends = {}
            for _ in range(rounds):
                for label, stepper in steppers.items():
                    s = copy_state(model, start)
                    t0 = time.perf_counter()
                    stepper.step(model, s)
                    times[label].append(1e3 * (time.perf_counter() - t0))
                    ends[label] = s
            for label in steppers:
                r = csb.backward_euler_residual(model, start, ends[label], 1 / 60, G)
                rows.append(dict(scene=scene, particles=model.num_particles, iterations=it, method=label,
                                 residual_over_scale=r.max / r.scale, ms_per_step=float(np.median(times[label]))))
    return rows


def vbd_acceleration(n: int, budgets: tuple[int, ...], rhos: tuple[float, ...]) -> list[dict]:
    """The accelerated variant (Chen et al. 2024 §3.8, Chebyshev over the sweeps): one step of the
    moving cloth, the backward-Euler residual over the force scale at each budget and ρ."""
    model, start = moving_cloth(n)
    rows = []
    for rho in rhos:
        for it in budgets:
            s = copy_state(model, start)
            csb.make_integrator("vbd", 1 / 60, iterations=it, acceleration=rho, threads=1).step(model, s)
            r = csb.backward_euler_residual(model, start, s, 1 / 60, G)
            rows.append(dict(acceleration=rho, iterations=it, residual_over_scale=r.max / r.scale))
    return rows


def equilibrium(model: csb.Model, gravity=G) -> np.ndarray:
    """The static equilibrium of a chain hanging straight down from particle 0: each link
    stretched by its compliance times the weight below it."""
    x = np.array(model.rest_positions)
    mass = np.asarray(model.mass)
    alpha = np.asarray(model.distance["compliance"])
    rest = np.asarray(model.distance["rest_length"])
    g = float(np.linalg.norm(gravity))
    for k in range(len(rest)):
        below = float(np.sum(mass[k + 1:]))
        x[k + 1] = x[k] - np.array([0.0, rest[k] + alpha[k] * below * g, 0.0])
    return x


def ratio_chains(ratios: tuple[float, ...], methods: tuple[str, ...]) -> list[dict]:
    rows = []
    for scene, make in (("stiffness_ratio_chain", stiffness_ratio_chain), ("mass_ratio_chain", mass_ratio_chain)):
        for ratio in ratios:
            model = make(ratio=ratio)
            target = equilibrium(model)
            for method in methods:
                s = model.initial_state()
                stepper = csb.make_integrator(method, 1 / 60, iterations=10)
                worst = 0.0
                with warnings.catch_warnings():  # XPBD warns of the mass ratio it cannot take: the table shows it
                    warnings.simplefilter("ignore", csb.AccuracyWarning)
                    stepper.step(model, s)
                worst = float(np.max(np.linalg.norm(np.asarray(s.x) - target, axis=1)))
                for _ in range(59):
                    stepper.step(model, s)
                    worst = max(worst, float(np.max(np.linalg.norm(np.asarray(s.x) - target, axis=1))))
                rows.append(dict(scene=scene, ratio=ratio, method=method, largest_distance_m=worst))
    return rows


def table(rows: list[dict], columns: list[str]) -> str:
    def cell(v):
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    lines = [" | ".join(columns), " | ".join("---" for _ in columns)]
    lines += [" | ".join(cell(r[c]) for c in columns) for r in rows]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="fewer time steps and ratios, an 8 x 8 cloth for 0.5 s")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    dts = (1 / 30, 1 / 120) if args.quick else (1 / 30, 1 / 60, 1 / 120, 1 / 240, 1 / 480)
    rows = damping(dts)
    write_csv(out / "implicit_damping.csv", rows)
    print("1a. backward Euler's numerical damping: energy kept after 1 s\n")
    print(table(rows, ["scene", "dt", "kept", "closed_form", "reference_kept"]), "\n")

    rows = newton_budget(8, 0.5) if args.quick else newton_budget(12, 1.0)
    write_csv(out / "implicit_newton.csv", rows)
    print("1b. one Newton iteration against the converged step: hanging cloth, dt = 1/60 s\n")
    print(table(rows, ["method", "error_m", "ms_per_step", "newton_per_step"]), "\n")

    rows = stability((1 / 30,) if args.quick else (1 / 30, 1 / 10))
    write_csv(out / "implicit_stability.csv", rows)
    print("1c. a chain of 1e-8 m/N links for 3 s\n")
    print(table(rows, ["dt", "method", "outcome", "largest_energy_rise_J", "newton_per_step"]), "\n")

    n, iterations = (12, 100) if args.quick else (32, 500)
    rows, cost = pd_convergence(n, iterations)
    write_csv(out / "pd_convergence.csv", rows)
    write_csv(out / "pd_cost.csv", cost)
    curves = {}
    for r in rows:
        curves.setdefault(r["method"], []).append(r["residual_N"])
    print(f"2. Projective Dynamics: one step of a moving {n} x {n} cloth, backward-Euler residual (N) per iteration\n")
    marks = [k for k in (0, 1, 2, 5, 10, 20, 50, 100, 200, 500) if k <= iterations]
    summary = []
    for label in ("PD", "PD + Chebyshev"):
        c = curves[label]
        early = (c[10] / c[0]) ** (1 / 10)
        late = (c[iterations] / c[iterations // 2]) ** (1 / (iterations - iterations // 2))
        summary.append(dict(method=label, **{f"r{k}": c[k] for k in marks}, rate_first_10=early,
                            rate_second_half=late, to_1e_2=reached(c, 1e-2), to_1e_3=reached(c, 1e-3)))
    print(table(summary, ["method", *[f"r{k}" for k in marks], "rate_first_10", "rate_second_half", "to_1e_2",
                          "to_1e_3"]), "\n")
    print("Newton (converged backward Euler) from the same state:",
          ", ".join(f"{v:.3g}" for v in curves["Newton"]), "N\n")
    print(table(cost, ["cloth", "particles", "factorization_ms", "ms_per_iteration", "newton_ms_per_step",
                       "newton_iterations"]), "\n")

    rows = vbd_against_xpbd(12, (1, 5, 20), 3) if args.quick else vbd_against_xpbd(32, (1, 2, 5, 10, 20, 50, 100), 7)
    write_csv(out / "vbd_xpbd.csv", rows)
    print("3a. VBD against XPBD at equal budgets: one step of 1/60 s, one thread\n")
    print(table(rows, ["scene", "particles", "iterations", "method", "residual_over_scale", "ms_per_step"]), "\n")

    rows = vbd_acceleration(12 if args.quick else 32, (4, 16, 64) if args.quick else (4, 16, 64, 256),
                            (0.0, 0.9) if args.quick else (0.0, 0.5, 0.9, 0.95))
    write_csv(out / "vbd_acceleration.csv", rows)
    print("3b. VBD's accelerated variant: residual over the force scale after one step, by ρ and sweeps\n")
    print(table(rows, ["acceleration", "iterations", "residual_over_scale"]), "\n")

    ratios = (1.0, 1e4) if args.quick else (1.0, 10.0, 100.0, 1e3, 2e3, 5e3, 1e4)
    rows = ratio_chains(ratios, ("vbd", "xpbd"))
    write_csv(out / "ratio_chains.csv", rows)
    print("3c. hanging chains at rest, dt = 1/60 s, 10 iterations: largest distance from equilibrium over 1 s\n")
    print(table(rows, ["scene", "ratio", "method", "largest_distance_m"]), "\n")
    chart(out)


def chart(out: Path) -> None:
    """implicit_claims.png from the CSVs: damping against dt, PD's and Newton's residual against
    iterations, VBD against XPBD at equal budgets, and the ratio chains."""
    import csv

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    def load(name):
        with open(out / name, newline="") as f:
            return list(csv.DictReader(f))

    fig, (a, b, c, d) = plt.subplots(1, 4, figsize=(19, 4.4), constrained_layout=True)
    rows = load("implicit_damping.csv")
    for scene, marker in (("oscillator", "o"), ("chain", "s")):
        pts = sorted((float(r["dt"]), float(r["kept"])) for r in rows if r["scene"] == scene)
        a.plot(*zip(*pts), marker + "-", label=f"backward Euler, {scene}")
    pts = sorted((float(r["dt"]), float(r["closed_form"])) for r in rows if r["scene"] == "oscillator")
    a.plot(*zip(*pts), "k:", label="1/(1 + ω²h²) per step")
    a.axhline(1.0, color="grey", lw=0.8, label="continuous reference")
    a.set_xscale("log")
    a.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    a.set_xlabel("dt (s)")
    a.set_ylabel("share of the energy kept after 1 s")
    a.set_title("implicit Euler's numerical damping", fontsize="medium")
    a.legend(fontsize="x-small")
    rows = load("pd_convergence.csv")
    for label in dict.fromkeys(r["method"] for r in rows):
        pts = [(int(r["iteration"]), float(r["residual_N"])) for r in rows if r["method"] == label]
        b.plot(*zip(*pts), "o-" if label == "Newton" else "-", label=label, ms=4)
    b.set_yscale("log")
    b.set_xscale("symlog", linthresh=1)
    b.set_xlim(left=0)
    b.set_xlabel("iteration (Newton: Newton iteration)")
    b.set_ylabel("backward-Euler residual (N)")
    b.set_title("Projective Dynamics on a moving cloth", fontsize="medium")
    b.legend(fontsize="x-small")
    rows = load("vbd_xpbd.csv")
    for scene, style in (("cloth", "-"), ("tet cube", "--")):
        for method, marker in (("VBD", "o"), ("XPBD", "s")):
            pts = sorted((int(r["iterations"]), float(r["residual_over_scale"])) for r in rows
                         if r["scene"] == scene and r["method"] == method)
            c.plot(*zip(*pts), marker + style, label=f"{method}, {scene}", ms=4)
    c.set_xscale("log")
    c.set_yscale("log")
    c.set_xlabel("iterations per step")
    c.set_ylabel("residual / force scale")
    c.set_title("VBD against XPBD at equal budgets", fontsize="medium")
    c.legend(fontsize="x-small")
    rows = load("ratio_chains.csv")
    for scene, style in (("stiffness_ratio_chain", "-"), ("mass_ratio_chain", "--")):
        for method, marker in (("vbd", "o"), ("xpbd", "s")):
            pts = sorted((float(r["ratio"]), float(r["largest_distance_m"])) for r in rows
                         if r["scene"] == scene and r["method"] == method)
            d.plot(*zip(*pts), marker + style, label=f"{method}, {scene.replace('_chain', '')}", ms=4)
    d.set_xscale("log")
    d.set_yscale("log")
    d.set_xlabel("ratio")
    d.set_ylabel("largest distance from equilibrium over 1 s (m)")
    d.set_title("hanging ratio chains, 10 iterations, dt = 1/60 s", fontsize="medium")
    d.legend(fontsize="x-small")
    fig.savefig(out / "implicit_claims.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
