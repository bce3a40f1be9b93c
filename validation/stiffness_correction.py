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

    python validation/stiffness_correction.py [--out out/validation]

Its quick version is tests/test_pbd.py::test_stiffness_correction_makes_the_effective_stiffness_
independent_of_iterations.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from csb.studies import spring_k_eff, write_csv

M, L0, S0, DT = 0.3, 1.0, 0.2, 0.01   # kg, m, m, s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    ks = (0.05, 0.2, 0.5, 0.9)
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

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
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
    fig.savefig(out / "stiffness_correction.png", dpi=120)

    worst = max(r["rel_error"] for r in rows)
    corrected = [r["k_eff"] for r in rows if r["correction"] and r["k"] == 0.5]
    plain = [r for r in rows if not r["correction"] and r["k"] == 0.5]
    print(f"stiffness correction: {len(rows)} measurements, largest relative deviation from the closed forms "
          f"{worst:.2e}")
    print(f"  k = 0.5: corrected k_eff = {min(corrected):.6g} .. {max(corrected):.6g} N/m over n = 1..{len(corrected)}; "
          f"uncorrected {plain[0]['k_eff']:.6g} N/m at n = 1, {plain[-1]['k_eff']:.6g} N/m at n = {plain[-1]['iterations']}")
    print(f"  wrote {out / 'stiffness_correction.csv'} and {out / 'stiffness_correction.png'}")


if __name__ == "__main__":
    main()
