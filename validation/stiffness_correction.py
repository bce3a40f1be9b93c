#!/usr/bin/env python3
"""Study: the effective stiffness of a PBD spring against the iteration count (Müller 2007 §3.3).

One particle of mass m hangs on a spring of PBD stiffness k from a fixed anchor, stretched by s0
and at rest; gravity is off. A single step of n Gauss-Seidel iterations leaves s1 = (1 - k')^n s0,
which is one backward Euler step of a Hooke spring with

    k_eff = m (s0/s1 - 1) / Δt²   (N/m).

Without the correction (k' = k), k_eff = m((1 - k)^(-n) - 1)/Δt² grows without bound in n; with
k' = 1 - (1 - k)^(1/n), k_eff = m((1 - k)^(-1) - 1)/Δt² for every n. The study measures k_eff
through csb's stepper, compares it with both closed forms and writes
stiffness_correction.csv and stiffness_correction.png.

The correction is exact for that one constraint only. Beside it, a chain of 10 particles of the
same mass (9 links of the same rest length, pinned at the top, hanging straight), every link
stretched by s0 and at rest, gravity off, gets one step of n Gauss-Seidel iterations: the total
stretch left S1 (the tip's distance from the pin less 9 rest lengths) is measured through the
stepper and computed in closed form (the sweeps keep the chain straight, so each projection is a
linear map of the link stretches). Its effective stiffness is measured the same way: the Hooke
stiffness k_eff whose backward Euler step of the same chain from the same state leaves the same
S1 (for one link this is the formula above). With the correction k_eff still moves with n: the
projections of neighbouring links undo part of each other, by an amount that depends on how
many sweeps share the work. Writes stiffness_correction_chain.csv and a second panel.

    python validation/stiffness_correction.py [--out out/validation]

Its quick version is tests/test_pbd.py::test_stiffness_correction_makes_the_effective_stiffness_
independent_of_iterations.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

import csb
from csb.studies import spring_k_eff, write_csv

M, L0, S0, DT = 0.3, 1.0, 0.2, 0.01   # kg, m, m, s
CHAIN_PARTICLES = 10
KS = (0.05, 0.2, 0.5, 0.9)
CHAIN_ITERATIONS = (1, 2, 3, 5, 7, 10, 15, 20, 30, 50, 70, 100)


def chain_stretch_left(k: float, n: int, *, correction: bool) -> float:
    """S1 (m) of the chain after one step of n iterations, through csb's stepper."""
    b = csb.ModelBuilder()
    g = b.add_group("chain")
    for i in range(CHAIN_PARTICLES):
        b.add_particle([0, -i * (L0 + S0), 0], M, g)
    for i in range(CHAIN_PARTICLES - 1):
        b.add_distance(i, i + 1, stiffness=k, rest_length=L0)
    b.pin(0)
    model = b.build()
    state = model.initial_state()
    csb.PbdStepper(dt=DT, iterations=n, gravity=(0, 0, 0), stiffness_correction=correction).step(model, state)
    x = np.asarray(state.x)
    return float(np.linalg.norm(x[-1] - x[0])) - (CHAIN_PARTICLES - 1) * L0


def chain_stretch_left_closed_form(k: float, n: int, *, correction: bool) -> float:
    """S1 (m) in closed form: n Gauss-Seidel sweeps, top link first, over the link stretches s.
    Projecting link i by k' moves its two ends towards each other by k' s_i in all, split by
    inverse mass: the top link's upper end is pinned, so its lower end moves k' s_0 and the link
    below gets longer by as much; any other link's ends move k' s_i / 2 each, lengthening both
    neighbours by that."""
    kp = 1 - (1 - k) ** (1 / n) if correction else k
    s = np.full(CHAIN_PARTICLES - 1, S0)
    for _ in range(n):
        for i in range(len(s)):
            c = kp * s[i]
            s[i] -= c
            share = c if i == 0 else c / 2
            if i > 0:
                s[i - 1] += share
            if i + 1 < len(s):
                s[i + 1] += share
    return float(s.sum())


def backward_euler_stretch_left(stiffness: float) -> float:
    """S1 (m) after one backward Euler step of dt from the stretched chain at rest, every link a
    Hooke spring of `stiffness` (N/m): (M + dt² K DᵀD) u = -dt² K Dᵀ s0 for the displacements u
    along the chain, D the links' difference operator (the top particle pinned)."""
    links = CHAIN_PARTICLES - 1
    D = np.eye(links) - np.eye(links, k=-1)
    s0 = np.full(links, S0)
    u = np.linalg.solve(M * np.eye(links) + DT**2 * stiffness * D.T @ D, -DT**2 * stiffness * D.T @ s0)
    return float((s0 + D @ u).sum())


def chain_k_eff(stretch_left: float) -> float:
    """The Hooke stiffness (N/m) whose backward Euler step leaves `stretch_left`: bisection in
    log k_eff (S1 falls from the whole stretch at k_eff = 0 to 0 as k_eff grows), to round-off."""
    lo, hi = 1e-9, 1e15
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if backward_euler_stretch_left(mid) > stretch_left else (lo, mid)
    return math.sqrt(lo * hi)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    ks = KS
    ns = range(1, 31)
    rows = []
    for k in ks:
        for n in ns:
            if (1 - k) ** n < 1e-4:  # the stretch left would be round-off, not stiffness
                continue
            for correction in (False, True):
                expect = M * (((1 - k) ** -1 if correction else (1 - k) ** -n) - 1) / DT**2
                got = spring_k_eff(k, n, correction=correction, mass=M, rest_length=L0, stretch=S0, dt=DT)
                rows.append(dict(k=k, iterations=n, correction=int(correction), k_eff=got, closed_form=expect,
                                 rel_error=abs(got / expect - 1)))
    write_csv(out / "stiffness_correction.csv", rows)
    chain = []
    for k in ks:
        for n in CHAIN_ITERATIONS:
            for correction in (False, True):
                if not correction and (1 - k) ** n < 1e-4:  # as above: left out of the spring's rows too
                    continue
                got = chain_stretch_left(k, n, correction=correction)
                expect = chain_stretch_left_closed_form(k, n, correction=correction)
                chain.append(dict(k=k, iterations=n, correction=int(correction), stretch_left_m=got,
                                  closed_form_m=expect, k_eff=chain_k_eff(got), k_eff_closed_form=chain_k_eff(expect)))
    for r in chain:
        first = [c for c in chain if c["k"] == r["k"] and c["correction"] == r["correction"] and c["iterations"] == 1][0]
        r["k_eff_over_one_iteration"] = r["k_eff"] / first["k_eff"]
    write_csv(out / "stiffness_correction_chain.csv", chain)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 4.5), constrained_layout=True)
    for i, k in enumerate(ks):
        for correction, style in ((False, "--"), (True, "-")):
            sel = [r for r in rows if r["k"] == k and r["correction"] == correction]
            ax.semilogy([r["iterations"] for r in sel], [r["k_eff"] for r in sel], style, color=f"C{i}",
                        marker="o" if correction else "x", ms=3,
                        label=f"k = {k}" + (" corrected" if correction else ""))
    ax.set_xlabel("iterations n")
    ax.set_ylabel("effective stiffness k_eff (N/m)")
    ax.set_title(f"PBD spring, m = {M} kg, Δt = {DT} s: dashed k' = k, solid k' = 1-(1-k)^(1/n)", fontsize="medium")
    ax.legend(fontsize="x-small", ncol=2)
    ax.grid(alpha=0.3, which="both")
    for i, k in enumerate(ks):
        for correction, style in ((False, "--"), (True, "-")):
            sel = [r for r in chain if r["k"] == k and r["correction"] == correction]
            ax2.loglog([r["iterations"] for r in sel], [r["k_eff_over_one_iteration"] for r in sel], style,
                       color=f"C{i}", marker="o" if correction else "x", ms=3,
                       label=f"k = {k}" + (" corrected" if correction else ""))
    ax2.set_xlabel("iterations n")
    ax2.set_ylabel("k_eff(n) / k_eff(1)")
    ax2.set_title(f"chain of {CHAIN_PARTICLES} particles, same m, Δt: the correction is exact for one link only",
                  fontsize="medium")
    ax2.legend(fontsize="x-small", ncol=2)
    ax2.grid(alpha=0.3, which="both")
    fig.savefig(out / "stiffness_correction.png", dpi=120)

    worst = max(r["rel_error"] for r in rows)
    corrected = [r["k_eff"] for r in rows if r["correction"] and r["k"] == 0.5]
    plain = [r for r in rows if not r["correction"] and r["k"] == 0.5]
    print(f"stiffness correction: {len(rows)} measurements, largest relative deviation from the closed forms "
          f"{worst:.2e}")
    print(f"  k = 0.5: corrected k_eff = {min(corrected):.6g} .. {max(corrected):.6g} N/m over n = 1..{len(corrected)}; "
          f"uncorrected {plain[0]['k_eff']:.6g} N/m at n = 1, {plain[-1]['k_eff']:.6g} N/m at n = {plain[-1]['iterations']}")
    worst_chain = max(abs(r["stretch_left_m"] / r["closed_form_m"] - 1) for r in chain)
    print(f"chain of {CHAIN_PARTICLES} particles: {len(chain)} measurements, stretch left within {worst_chain:.1e} of the "
          f"closed form; with the correction, k_eff from 1 to {CHAIN_ITERATIONS[-1]} iterations:")
    for k in ks:
        sel = [r for r in chain if r["k"] == k and r["correction"]]
        print(f"  k = {k}: {sel[0]['k_eff']:.6g} -> {sel[-1]['k_eff']:.6g} N/m "
              f"({100 * (sel[-1]['k_eff_over_one_iteration'] - 1):+.2f} %; the single spring: "
              f"{M * ((1 - k) ** -1 - 1) / DT**2:.6g} N/m at every n)")
    print(f"  wrote {out / 'stiffness_correction.csv'}, stiffness_correction_chain.csv and "
          f"{out / 'stiffness_correction.png'}")


if __name__ == "__main__":
    main()
