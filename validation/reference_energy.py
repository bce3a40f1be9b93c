#!/usr/bin/env python3
"""Study: how well the reference (CVODE, BDF) keeps the energy of an undamped spring, as a
function of rtol, frequency, duration, BDF order and amplitude, and the rule rtol="auto" follows.

One particle of 1 kg on a spring of rest length 1 m to a pinned particle, no gravity, released at
rest stretched by A (0.1 m unless said): a harmonic oscillator of ω = sqrt(k/m), whose energy
½ v² + ½ ω² u² is exactly constant. The reference runs with atol = rtol/100; the relative energy
change after the run is ε, ε per period its rate. Sweeps: rtol 1e-6 .. 1e-12 x ω 1, 10, 100,
1000 rad/s x 10, 100, 1000 periods (BDF up to order 5, the default); the BDF order capped at
2 .. 5 (ω = 100 rad/s); the amplitude A from 0.5 m down to 1e-4 m. The law BDF5 gives,
ε ≈ c rtol^(5/6) per period (a loss), is checked (fitted exponent; c against
csb.reference.ENERGY_CONSTANT), then the default rtol="auto" (energy_tolerance 1e-6) against the
former default rtol 1e-8, on the oscillator and on a 10-link chain whose every mode was set
moving at random (no gravity). Writes reference_energy.csv, reference_energy_auto.csv and
reference_energy.png.

    python validation/reference_energy.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

import csb
from csb.reference import ENERGY_CONSTANT
from csb.studies import swinging_chain, write_csv

ZERO_G = (0.0, 0.0, 0.0)
SAMPLES_PER_PERIOD = 8


def oscillator(omega: float, amplitude: float, *, mass: float = 1.0, rest_length: float = 1.0) -> csb.Model:
    b = csb.ModelBuilder()
    g = b.add_group("oscillator")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([rest_length + amplitude, 0, 0], mass, g)
    b.add_distance(0, 1, rest_length=rest_length, compliance=1 / (mass * omega**2))
    b.pin(0)
    return b.build()


def energy_change(model: csb.Model, start: csb.State, times: np.ndarray, **settings) -> tuple[float, dict]:
    """(E(end) - E(0)) / E(0) of the reference run, and its stats."""
    r = csb.integrate_reference(model, start, times, gravity=ZERO_G, **settings)
    e = [csb.measure(model, s, ZERO_G)["total_energy"] for s in r.states(model)]
    return (e[-1] - e[0]) / e[0], r.stats


def oscillator_row(sweep: str, omega: float, rtol: float, periods: int, *, order: int = 5, amplitude: float = 0.1):
    model = oscillator(omega, amplitude)
    times = np.linspace(0, periods * 2 * math.pi / omega, periods * SAMPLES_PER_PERIOD + 1)
    eps, stats = energy_change(model, model.initial_state(), times, rtol=rtol, atol=rtol / 100, max_order=order)
    return dict(sweep=sweep, omega_rad_s=omega, rtol=rtol, atol=rtol / 100, max_order=order, periods=periods,
                amplitude_m=amplitude, energy_change=eps, per_period=eps / periods,
                c=abs(eps / periods) / rtol ** (5 / 6), steps=stats["steps"], steps_per_period=stats["steps"] / periods,
                wall_time_s=stats["wall_time"])


def fitted_exponent(rows: list[dict]) -> float:
    """Slope of log|ε per period| against log rtol."""
    return float(np.polyfit(np.log([r["rtol"] for r in rows]), np.log([abs(r["per_period"]) for r in rows]), 1)[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="a few points of each sweep (the tests' version)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    q = args.quick

    rtols = (1e-6, 1e-8, 1e-10) if q else (1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12)
    rows = []
    for omega in ((10.0, 1000.0) if q else (1.0, 10.0, 100.0, 1000.0)):
        for periods in ((10, 100) if q else (10, 100, 1000)):
            rows += [oscillator_row("rtol x omega x periods", omega, r, periods) for r in rtols]
    for order in ((3, 5) if q else (2, 3, 4, 5)):
        for r in ((1e-6, 1e-8) if q else (1e-6, 1e-8, 1e-10, 1e-12)):
            rows.append(oscillator_row("order", 100.0, r, 10 if order == 2 else 100, order=order))
    for amplitude in ((0.1, 1e-3) if q else (0.5, 0.1, 1e-2, 1e-3, 1e-4)):
        rows += [oscillator_row("amplitude", 100.0, r, 100, amplitude=amplitude)
                 for r in ((1e-6, 1e-8) if q else (1e-6, 1e-8, 1e-10, 1e-12))]
    write_csv(out / "reference_energy.csv", rows)

    print("Relative energy change of the oscillator per period, BDF up to order 5 (amplitude 0.1 m):")
    grid = [r for r in rows if r["sweep"] == "rtol x omega x periods"]
    omegas = list(dict.fromkeys(r["omega_rad_s"] for r in grid))
    periods_list = list(dict.fromkeys(r["periods"] for r in grid))
    print(f"{'rtol':>7s} " + " ".join(f"{f'w={w:g}, {p} per.':>17s}" for w in omegas for p in periods_list))
    for rtol in rtols:
        cells = [next(r for r in grid if r["rtol"] == rtol and r["omega_rad_s"] == w and r["periods"] == p)["per_period"]
                 for w in omegas for p in periods_list]
        print(f"{rtol:>7.0e} " + " ".join(f"{c:>17.2e}" for c in cells))
    # The exponent is fitted where atol (rtol/100) does not take over from rtol: rtol >= 1e-10.
    fit = [r for r in grid if r["rtol"] >= 1e-10]
    exponents = {w: fitted_exponent([r for r in fit if r["omega_rad_s"] == w]) for w in omegas}
    print("fitted exponent of the rate in rtol (BDF5's law: 5/6 = 0.833): "
          + ", ".join(f"w={w:g}: {e:.3f}" for w, e in exponents.items()))
    print("\nBy BDF order (w = 100 rad/s; order 2 over 10 periods): energy change per period, steps per period")
    for order in dict.fromkeys(r["max_order"] for r in rows if r["sweep"] == "order"):
        sel = [r for r in rows if r["sweep"] == "order" and r["max_order"] == order]
        print(f"  max_order {order}: " + ", ".join(f"rtol {r['rtol']:.0e}: {r['per_period']:+.2e} ({r['steps_per_period']:.0f})"
                                                  for r in sel) + f"; exponent {fitted_exponent(sel):.3f}")
    print("\nc = |rate| / rtol^(5/6) by amplitude (w = 100 rad/s, 100 periods):")
    for amplitude in dict.fromkeys(r["amplitude_m"] for r in rows if r["sweep"] == "amplitude"):
        sel = [r for r in rows if r["sweep"] == "amplitude" and r["amplitude_m"] == amplitude]
        print(f"  A = {amplitude:g} m: " + ", ".join(f"rtol {r['rtol']:.0e}: {r['c']:.1f}" for r in sel))
    lawful = [r for r in rows if r["max_order"] == 5 and r["amplitude_m"] >= 1e-3]
    c_max = max(r["c"] for r in lawful)
    print(f"largest c at order 5, amplitudes >= 1e-3 m: {c_max:.1f} (ENERGY_CONSTANT = {ENERGY_CONSTANT:g}); "
          f"every BDF5 run lost energy: {all(r['energy_change'] < 0 for r in rows if r['max_order'] == 5)}")

    # The default against the former default.
    auto = []
    cases = [(100.0, 100), (1000.0, 10)] if q else [(w, p) for w in (1.0, 100.0, 1000.0) for p in (10, 100, 1000)]
    for omega, periods in cases:
        model = oscillator(omega, 0.1)
        times = np.linspace(0, periods * 2 * math.pi / omega, periods * SAMPLES_PER_PERIOD + 1)
        for label, settings in (("rtol 1e-8, atol 1e-10", dict(rtol=1e-8, atol=1e-10)), ("auto (default)", {})):
            eps, stats = energy_change(model, model.initial_state(), times, **settings)
            auto.append(dict(scene=f"oscillator w={omega:g}, {periods} periods", settings=label, rtol=stats["rtol"],
                             frequency_rad_s=stats["frequency"], energy_bound=stats["energy_bound"],
                             energy_change=eps, steps=stats["steps"], wall_time_s=stats["wall_time"]))
    rng = np.random.default_rng(1)
    chain = swinging_chain(links=10, compliance=1e-5)
    start = chain.initial_state()
    v = rng.normal(scale=0.01, size=np.asarray(start.v).shape)
    v[0] = 0
    start.v = v
    times = np.linspace(0, 0.2, 41)
    for label, settings in (("rtol 1e-8, atol 1e-10", dict(rtol=1e-8, atol=1e-10)), ("auto (default)", {})):
        eps, stats = energy_change(chain, start, times, **settings)
        auto.append(dict(scene="10-link chain, random velocities, 0.2 s", settings=label, rtol=stats["rtol"],
                         frequency_rad_s=stats["frequency"], energy_bound=stats["energy_bound"], energy_change=eps,
                         steps=stats["steps"], wall_time_s=stats["wall_time"]))
    write_csv(out / "reference_energy_auto.csv", auto)
    print("\nThe default rtol='auto' (energy_tolerance 1e-6) against rtol 1e-8:")
    print(f"{'scene':42s} {'settings':22s} {'rtol':>8s} {'bound':>9s} {'change':>10s} {'steps':>9s} {'wall s':>7s}")
    for r in auto:
        print(f"{r['scene']:42s} {r['settings']:22s} {r['rtol']:>8.1e} {r['energy_bound']:>9.1e} "
              f"{r['energy_change']:>+10.2e} {r['steps']:>9d} {r['wall_time_s']:>7.2f}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), constrained_layout=True)
    ax = axes[0]
    for w in omegas:
        sel = [r for r in grid if r["omega_rad_s"] == w and r["periods"] == periods_list[-1]]
        ax.loglog([r["rtol"] for r in sel], [abs(r["per_period"]) for r in sel], "o-", label=f"ω = {w:g} rad/s")
    x = np.array(rtols)
    ax.loglog(x, ENERGY_CONSTANT * x ** (5 / 6), "k--", label=f"{ENERGY_CONSTANT:g} rtol^(5/6)")
    ax.set_xlabel("rtol")
    ax.set_ylabel("|energy change| per period")
    ax.set_title(f"BDF5, {periods_list[-1]} periods: the same for every ω", fontsize="medium")
    ax.legend(fontsize="small")
    ax = axes[1]
    for order in dict.fromkeys(r["max_order"] for r in rows if r["sweep"] == "order"):
        sel = [r for r in rows if r["sweep"] == "order" and r["max_order"] == order]
        gain = sel[0]["energy_change"] > 0
        ax.loglog([r["rtol"] for r in sel], [abs(r["per_period"]) for r in sel], "o-" if gain else "s--",
                  label=f"max order {order} ({'gains' if gain else 'loses'})")
    ax.set_xlabel("rtol")
    ax.set_title("by BDF order, ω = 100 rad/s", fontsize="medium")
    ax.legend(fontsize="small")
    ax = axes[2]
    for amplitude in dict.fromkeys(r["amplitude_m"] for r in rows if r["sweep"] == "amplitude"):
        sel = [r for r in rows if r["sweep"] == "amplitude" and r["amplitude_m"] == amplitude]
        ax.semilogx([r["rtol"] for r in sel], [r["c"] for r in sel], "o-", label=f"A = {amplitude:g} m")
    ax.axhline(ENERGY_CONSTANT, color="k", ls="--", lw=1)
    ax.set_xlabel("rtol")
    ax.set_ylabel("c = |rate| / rtol^(5/6)")
    ax.set_title("the constant against the amplitude (rest length 1 m)", fontsize="medium")
    ax.legend(fontsize="small")
    fig.suptitle("The reference's energy error on an undamped spring (CVODE BDF, atol = rtol/100)", fontsize="medium")
    fig.savefig(out / "reference_energy.png", dpi=120)
    print(f"  wrote {out / 'reference_energy.csv'}, {out / 'reference_energy_auto.csv'} and {out / 'reference_energy.png'}")


if __name__ == "__main__":
    main()
