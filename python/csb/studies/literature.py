"""The literature's test scenes as study set-ups, with the published parameters where the papers
give them (papers/ holds one note per paper; where a paper leaves a parameter out, the set-up's
docstring says so and which value csb takes).

SETUPS maps a name to a function of keyword-only arguments in SI units that returns a csb Model,
or (Model, State) when the scene starts from a state other than the model's rest. Gravity is not
part of a Model: a study gives it per scene (``gravity``, default (0, -9.81, 0) m/s²), and each
docstring says which gravity the paper's scene has.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from .. import _core
from ..model import ModelBuilder
from .soft_bodies import tet_cantilever

__all__ = ["SETUPS", "xpbd_oscillator", "xpbd_chain", "cantilever", "mass_ratio_chain", "stiffness_ratio_chain",
           "twisting_cloth", "oscillator_period"]


# ------------------------------------------------------------------------------------ argument checks


def _number(name: str, value: Any, *, low: float | None = None, high: float | None = None,
            strict_low: bool = True, unit: str = "") -> float:
    """``value`` as a finite float in (low, high] (or [low, high] with strict_low=False), else a
    csb.ParameterError naming ``name``."""
    ok = not isinstance(value, bool) and isinstance(value, (int, float, np.floating, np.integer))
    x = float(value) if ok else math.nan
    if ok and math.isfinite(x):
        ok = (low is None or (x > low if strict_low else x >= low)) and (high is None or x <= high)
    else:
        ok = False
    if not ok:
        lo = "" if low is None else (f"> {low:g}" if strict_low else f">= {low:g}")
        hi = "" if high is None else f"<= {high:g}"
        want = " and ".join(s for s in (lo, hi) if s) or "finite"
        raise _core.ParameterError(f"{name} must be a finite number {want}{(' ' + unit) if unit else ''}, "
                                   f"got {value!r}")
    return x


def _count(name: str, value: Any, *, low: int, high: int = 100_000) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= int(value) <= high:
        raise _core.ParameterError(f"{name} must be an integer in [{low}, {high}], got {value!r}")
    return int(value)


def _choice(name: str, value: Any, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise _core.ParameterError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


# ------------------------------------------------------------------------------------ XPBD (Macklin 2016)


def oscillator_period(*, mass: float = 1.0, compliance: float = 1e-3) -> float:
    """The period 2π sqrt(m α) (s) of a particle of ``mass`` (kg) on a spring of ``compliance``
    α (m/N), stiffness 1/α."""
    return 2 * math.pi * math.sqrt(_number("mass", mass, low=0, unit="kg")
                                   * _number("compliance", compliance, low=0, unit="m/N"))


def xpbd_oscillator(*, mass: float = 1.0, rest_length: float = 1.0, start_length: float = 1.5,
                    compliance: float = 1e-3) -> _core.Model:
    """A particle on a spring, released stretched: the one-constraint case of XPBD's update
    (Macklin, Müller and Chentanez 2016, §4, Eq. 18; papers/macklin2016-xpbd.md).

    The anchor is pinned at the origin and the particle of ``mass`` (kg, default 1) hangs below it
    on a distance constraint of ``rest_length`` (m, default 1) and ``compliance`` α (m/N, default
    1e-3, a stiffness of 1000 N/m), released at rest at ``start_length`` (m, default 1.5) from the
    anchor. Our note of the paper records no single-spring scene in it, so no published values:
    these are the ones csb takes (a spring of 1 m pulled to 1.5 m, α = 1e-3 m/N).

    What to see: a harmonic oscillation along the spring of amplitude start_length - rest_length
    (0.5 m) and period 2π sqrt(m α) = 0.1987 s (oscillator_period) — exactly, as the motion stays
    on the spring's line where C = |x| - L is linear. Without gravity (study: ``gravity = [0, 0,
    0]``) it oscillates about the rest length; under gravity along the spring (the study's
    default, -y) only the centre moves, down by m g α (9.81 mm), the period is the same. XPBD, backward Euler in
    disguise, damps the amplitude by sqrt(1 + (ωh)²) a step (ω = 31.6 rad/s: 12 % a step at
    dt = 1/60 s) and lengthens the period; sub-steps take both away.
    """
    mass = _number("mass", mass, low=0, unit="kg")
    rest_length = _number("rest_length", rest_length, low=0, unit="m")
    start_length = _number("start_length", start_length, low=0, unit="m")
    compliance = _number("compliance", compliance, low=0, unit="m/N")
    b = ModelBuilder()
    g = b.add_group("oscillator")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([0, -start_length, 0], mass, g)
    b.add_distance(0, 1, rest_length=rest_length, compliance=compliance)
    b.pin(0)
    return b.build()


def xpbd_chain(*, particles: int = 20, mass: float = 1.0, link: float = 1.0, compliance: float = 1e-8,
               start: str = "horizontal") -> _core.Model:
    """XPBD's chain (Macklin, Müller and Chentanez 2016, §6.2, Figures 3a and 4;
    papers/macklin2016-xpbd.md, "The chain under the paper's protocol").

    ``particles`` (20) of ``mass`` (kg, 1) joined by links of compliance α (m/N, 1e-8), the first
    particle pinned: the paper's values. The paper gives no link length, time step or gravity; csb
    takes ``link`` = 1 m (the length at which our trajectory errors after the start-up match the
    paper's 6 %, 2 %, 0.5 %), dt = 1/60 s and g = 9.81 m/s² (-y, the study's default gravity).

    ``start``: "horizontal" (the paper's), straight along +x at rest length, at rest; or
    "hanging", straight down from the pin at its static stretch under g = 9.81 m/s² (link k from
    the top stretched by α (particles - 1 - k) m g), at rest.

    What to see, under gravity (-y): from "horizontal" the chain falls and swings about its pin,
    and the support force (the first link's |λ|/h² under XPBD) rises from 0.25 N in the first
    frame to a few hundred N (python validation/xpbd_claims.py; the same chain, to the bit, as
    validation/residual.py's); from "hanging" it stays where it is, and the tension at the top
    is the weight of the particles below the pin, (particles - 1) m g = 186.39 N at the defaults.
    The paper measures against backward Euler at the method's step (csb.BackwardEuler,
    csb.studies.same_step); the CVODE reference is slow on links this stiff: 93 s of wall time
    for 1 s of the horizontal chain here.
    """
    particles = _count("particles", particles, low=2)
    mass = _number("mass", mass, low=0, unit="kg")
    link = _number("link", link, low=0, unit="m")
    compliance = _number("compliance", compliance, low=0, strict_low=False, unit="m/N")
    _choice("start", start, ("horizontal", "hanging"))
    b = ModelBuilder()
    g = b.add_group("chain")
    if start == "horizontal":
        for i in range(particles):
            b.add_particle([link * i, 0, 0], mass, g)
        for i in range(particles - 1):
            b.add_distance(i, i + 1, compliance=compliance)
    else:
        y = 0.0
        b.add_particle([0, 0, 0], mass, g)
        for k in range(particles - 1):
            y -= link + compliance * (particles - 1 - k) * mass * 9.81
            b.add_particle([0, y, 0], mass, g)
        for k in range(particles - 1):
            b.add_distance(k, k + 1, rest_length=link, compliance=compliance)
    b.pin(0)
    return b.build()


def cantilever(*, length: float = 0.4, width: float = 0.1, cells: int = 8, cross_cells: int = 2,
               density: float = 1000.0, stretch_compliance: float = 1e-4,
               bulk_modulus: float = 1e6) -> _core.Model:
    """A tet-mesh beam clamped at one end, sagging under gravity: the soft-body scene of XPBD
    (Macklin, Müller and Chentanez 2016, §5-6, Figure 1: soft bodies whose stretch, shear and
    volume compliances are varied independently).

    A ``length`` x ``width`` x ``width`` (m; 0.4 x 0.1 x 0.1) box along +x from x = 0, of
    ``cells`` x ``cross_cells`` x ``cross_cells`` cubes of 6 tets (8 x 2 x 2: 81 particles, 192
    tets, 344 edges), ``density`` (kg/m³, 1000: 4 kg), its x = 0 face (9 particles) pinned. csb models a tet mesh as a
    distance constraint on every tet edge (``stretch_compliance``, m/N, 1e-4) and a volume
    constraint on every tet of compliance V0/K (m⁶/J) from ``bulk_modulus`` K (Pa, 1e6), not as
    the finite elements of a Young's modulus, so the paper's material cannot be entered as such;
    the paper gives no beam dimensions or material either. These are the values of
    csb.studies.soft_bodies.tet_cantilever, whose reference solution tests/test_volume.py checks
    (tip y -0.0298 m at 0.5 s in CVODE).

    What to see, under gravity (-y, the study's default): the free end falls, overshoots and
    bounces about a sagged rest a few centimetres down; the clamped face does not move. XPBD's
    sag converges with sub-steps (1 iteration: an error ~ tenfold smaller per fourfold more;
    the tip's mean y after 1 s: -0.206, -0.060, -0.017 m at 1 x 10, 10 x 1, 100 x 1). PBD reads
    the constraints as hard, yet at 1 x 10 sags about as far (-0.197 m): its iteration count,
    not the material, sets its stiffness. The CVODE reference takes about 4 s for 1 s here.
    """
    length = _number("length", length, low=0, unit="m")
    width = _number("width", width, low=0, unit="m")
    cells = _count("cells", cells, low=1, high=200)
    cross_cells = _count("cross_cells", cross_cells, low=1, high=50)
    density = _number("density", density, low=0, unit="kg/m³")
    stretch_compliance = _number("stretch_compliance", stretch_compliance, low=0, strict_low=False, unit="m/N")
    bulk_modulus = _number("bulk_modulus", bulk_modulus, low=0, unit="Pa")
    model, _ = tet_cantilever(length=length, width=width, cells=(cells, cross_cells, cross_cells), density=density,
                              stretch_compliance=stretch_compliance, bulk_modulus=bulk_modulus)
    return model


# ------------------------------------------------------------------------------------ ratio chains


def _hanging_chain(masses: np.ndarray, compliances: np.ndarray, link: float, name: str) -> _core.Model:
    """Particles of ``masses`` (kg; the first pinned at the origin) straight down the -y axis at
    rest length ``link`` (m), link k of compliance ``compliances[k]`` (m/N)."""
    b = ModelBuilder()
    g = b.add_group(name)
    for k, m in enumerate(masses):
        b.add_particle([0, -link * k, 0], float(m), g)
    for k, a in enumerate(compliances):
        b.add_distance(k, k + 1, rest_length=link, compliance=float(a))
    b.pin(0)
    return b.build()


def mass_ratio_chain(*, links: int = 10, link: float = 0.1, mass: float = 0.1, ratio: float = 1000.0,
                     compliance: float = 1e-6, heavy: str = "end") -> _core.Model:
    """A chain whose masses differ by ``ratio``: the mass-ratio stress test of Vertex Block
    Descent (Chen, Liu, Yang and Yuksel 2024, §7, their comparison with XPBD on large mass and
    stiffness ratios), where iterative solvers that sweep constraint by constraint (Gauss-Seidel
    PBD/XPBD) converge slowly or not at all.

    ``links`` (10) links of rest length ``link`` (m, 0.1) and ``compliance`` α (m/N, 1e-6) hang
    straight down from a pinned particle, at rest length and at rest. The particles below the
    pin weigh ``mass`` (kg, 0.1), except, with ``heavy`` = "end", the last, which weighs ratio x
    mass; with "alternating", every second one (the 2nd, 4th, ... below the pin). ``ratio``
    (1000) may go to 1e4 and beyond. Our notes hold no page of the paper with its chain's
    parameters: link count, masses and compliance are csb's, chosen so that the exact answer is
    plain.

    What to see, under gravity (-y): the chain hangs still, each link stretched by α times the
    weight below it (the top link by α g times the mass below the pin, 0.99 mm at the defaults);
    the total mass is (links + 1) x mass + (ratio - 1) x mass x (number of heavy particles). A
    solver that cannot carry the ratio stretches the chain far more and lets the heavy mass sink
    or bounce: at ratio 1e4 the 1 m chain averages 7.16 m long over 2 s under XPBD with 10
    Gauss-Seidel iterations at dt = 1/60 s (csb warns of the ratio, csb.AccuracyWarning), 1.128 m
    with 100 sub-steps of one, against 1.098 m static (python -m csb.studies.literature).
    """
    links = _count("links", links, low=1, high=10_000)
    link = _number("link", link, low=0, unit="m")
    mass = _number("mass", mass, low=0, unit="kg")
    ratio = _number("ratio", ratio, low=0)
    compliance = _number("compliance", compliance, low=0, strict_low=False, unit="m/N")
    _choice("heavy", heavy, ("end", "alternating"))
    masses = np.full(links + 1, mass)
    if heavy == "end":
        masses[-1] *= ratio
    else:
        masses[2::2] *= ratio
    return _hanging_chain(masses, np.full(links, compliance), link, "mass ratio chain")


def stiffness_ratio_chain(*, links: int = 10, link: float = 0.1, mass: float = 0.1, ratio: float = 1000.0,
                          compliance: float = 1e-4) -> _core.Model:
    """A chain whose links alternate between soft and stiff, their stiffnesses ``ratio`` apart:
    the stiffness-ratio stress test of Vertex Block Descent (Chen, Liu, Yang and Yuksel 2024, §7),
    where Gauss-Seidel sweeps of the stiff links undo the soft links' progress.

    ``links`` (10) links of rest length ``link`` (m, 0.1) hang straight down from a pinned
    particle, at rest length and at rest, with particles of ``mass`` (kg, 0.1) below the pin. Links
    0, 2, 4, ... (from the top) have ``compliance`` α (m/N, 1e-4: 1e4 N/m), links 1, 3, 5, ...
    α / ``ratio`` (1000: 1e7 N/m), ``ratio`` up to 1e4 and beyond. As for the mass-ratio chain,
    the paper's own chain parameters are not in our notes: these are csb's.

    What to see, under gravity (-y): the chain hangs still, link k stretched by its compliance
    times the weight below it, (links - k) mass g α_k: the soft links stretch ``ratio`` times more
    than the stiff ones at the same load. The chain's total stretch is the sum, 2.94 mm at ratio
    1e4; XPBD with 10 iterations at dt = 1/60 s averages 12.9 mm over 2 s at every ratio (its
    iterations have not converged on the soft links), 100 sub-steps of one 2.96 mm.
    """
    links = _count("links", links, low=1, high=10_000)
    link = _number("link", link, low=0, unit="m")
    mass = _number("mass", mass, low=0, unit="kg")
    ratio = _number("ratio", ratio, low=0)
    compliance = _number("compliance", compliance, low=0, unit="m/N")
    alphas = np.where(np.arange(links) % 2 == 0, compliance, compliance / ratio)
    return _hanging_chain(np.full(links + 1, mass), alphas, link, "stiffness ratio chain")


# ------------------------------------------------------------------------------------ cloth


def twisting_cloth(*, n: int = 16, size: float = 1.0, density: float = 0.2, angle: float = math.pi,
                   stretch_compliance: float = 1e-4,
                   bending_compliance: float = 1.0) -> tuple[_core.Model, _core.State]:
    """A square cloth held along two opposite edges, one of them turned about the cloth's axis:
    the twisting test of the cloth papers (Li et al. 2021, codimensional IPC, and Vertex Block
    Descent, Chen et al. 2024, which turn the held edges for seconds, several turns, with
    self-contact).

    An ``n`` x ``n`` (16) grid of ``size`` (m, 1) side in the x-z plane, ``density`` (kg/m², 0.2),
    stretch constraints on its edges (``stretch_compliance``, m/N, 1e-4) and bending on its
    hinges (``bending_compliance``, 1/(N m), 1); the rows at x = -size/2 and x = +size/2 are
    pinned. The papers turn the edge over time; a csb Model holds no prescribed motion (the
    stepper's grabs move particles, but a study's methods and the reference are made from the
    Model alone), so here the twist is the start state: the edge at x = +size/2 already turned by
    ``angle`` (rad, π: half a turn) about the x axis, the cloth between on the helicoid whose
    turn grows linearly in x from 0 at the other edge, at rest, then released. The papers give
    turns, not a start shape; n, size, density and compliances are csb's (the hanging cloth's).

    What to see: the pinned edges stay where the start puts them (the turned one at ``angle``);
    the cloth between, stretched by the helicoid (its free edges by sqrt(1 + (angle/2)²) - 1, 86 %
    at π), pulls in towards the axis into a narrow twisted band, each free edge a helix (at π its
    middle row narrows from 1 m to 0.42 m within a second under XPBD, 1 x 10 at dt = 1/60 s).
    The held edges stay ``size`` apart, so the band cannot shorten and settles stretched, most
    next to the held edges: 136 % at π, 67 % at π/2 (python -m csb.studies.literature). Without
    self-collision it may pass through itself. The CVODE reference did not finish 1 s of this
    scene in 400 s of wall time here, neither at n = 16 nor at n = 8 (the stretched start rings
    every stiff mode): study it by the metrics that need no reference (max_strain, stability).
    """
    n = _count("n", n, low=2, high=1024)
    size = _number("size", size, low=0, unit="m")
    density = _number("density", density, low=0, unit="kg/m²")
    angle = _number("angle", angle, low=-8 * math.pi, high=8 * math.pi, strict_low=False, unit="rad")
    stretch_compliance = _number("stretch_compliance", stretch_compliance, low=0, strict_low=False, unit="m/N")
    bending_compliance = _number("bending_compliance", bending_compliance, low=0, strict_low=False, unit="1/(N m)")
    b = ModelBuilder()
    inst = b.add_mesh(_core.cloth_grid(size, size, n, n), density=density, stretch_compliance=stretch_compliance,
                      bending_stiffness=1.0, bending_compliance=bending_compliance)
    x = inst.vertices
    held = np.where(np.isclose(np.abs(x[:, 0]), size / 2, rtol=0, atol=1e-9 * size))[0]
    for i in held:
        b.pin(inst.first_particle + int(i))
    model = b.build()
    state = model.initial_state()
    turn = angle * (x[:, 0] + size / 2) / size
    twisted = np.column_stack([x[:, 0], x[:, 1] * np.cos(turn) - x[:, 2] * np.sin(turn),
                               x[:, 1] * np.sin(turn) + x[:, 2] * np.cos(turn)])
    xs = np.array(state.x)
    xs[inst.particles] = twisted
    state.x = xs
    return model, state


# The set-ups, by name: a function of keyword-only arguments returning a Model or (Model, State).
SETUPS: dict[str, Callable[..., Any]] = {
    "xpbd_oscillator": xpbd_oscillator,
    "xpbd_chain": xpbd_chain,
    "cantilever": cantilever,
    "mass_ratio_chain": mass_ratio_chain,
    "stiffness_ratio_chain": stiffness_ratio_chain,
    "twisting_cloth": twisting_cloth,
}


# ------------------------------------------------------------------------------------ what they do


def _xpbd(model: _core.Model, state: _core.State, seconds: float, *, substeps: int = 1, iterations: int = 10,
          gravity=(0.0, -9.81, 0.0), method: str = "xpbd") -> _core.State:
    import warnings

    state = state.copy()
    stepper = _core.make_integrator(method, 1 / 60, substeps=substeps, iterations=iterations, gravity=gravity)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", _core.AccuracyWarning)  # the ratio chains' ratios are their point
        # PBD reads the compliant constraints as hard: that is what the comparison shows
        warnings.filterwarnings("ignore", message=r"PBD reads stiffness, not compliance",
                                category=_core.MaterialWarning)
        stepper.step(model, state, int(round(seconds * 60)))
    return state


def main() -> None:
    """Prints each set-up at its defaults (sizes, build time, one second of XPBD at dt = 1/60 s)
    and the closed forms the scenes have: ``python -m csb.studies.literature``."""
    import time

    from . import pendulum_period

    print("set-up                 particles  constraints  pins  mass (kg)  build (ms)  largest move after 1 s of "
          "XPBD, 1 x 10 at 1/60 s (m)")
    for name, f in SETUPS.items():
        t0 = time.perf_counter()
        made = f()
        build = time.perf_counter() - t0
        model, state = made if isinstance(made, tuple) else (made, made.initial_state())
        end = _xpbd(model, state, 1.0)
        move = float(np.abs(np.asarray(end.x) - np.asarray(state.x)).max())
        pins = int(np.sum(np.asarray(model.inv_mass) == 0))
        print(f"{name:22s} {model.num_particles:9d}  {model.num_constraints:11d}  {pins:4d}  "
              f"{float(np.sum(model.mass)):9.4g}  {1e3 * build:10.2f}  {move:.4g}")

    model = xpbd_oscillator()
    stepper = _core.make_integrator("xpbd", 1e-4, iterations=1, gravity=(0, 0, 0))
    state, t, y = model.initial_state(), [], []
    for _ in range(10_000):
        stepper.step(model, state)
        t.append(state.t)
        y.append(-(state.x[1][1] + 1.0))
    period = pendulum_period(np.array(t), np.array(y))
    print(f"xpbd_oscillator: period at dt = 1e-4 s, no gravity {period:.6f} s; 2π sqrt(m α) = "
          f"{oscillator_period():.6f} s")

    model = xpbd_chain(start="hanging")
    state = model.initial_state()
    pbd = _core.PbdStepper(method="xpbd", dt=1 / 60, iterations=200)
    pbd.step(model, state, 10)
    top = abs(float(pbd.multipliers()["distance"][0])) / pbd.substep_size**2
    print(f"xpbd_chain, hanging: tension at the top after 10 steps of 200 iterations {top:.2f} N; "
          f"19 x 1 kg x 9.81 m/s² = {19 * 9.81:.2f} N")

    model = cantilever()
    x0 = np.asarray(model.rest_positions)
    tip = np.abs(x0[:, 0] - x0[:, 0].max()) < 1e-12
    for substeps, iterations in ((1, 10), (10, 1), (100, 1)):
        x = np.asarray(_xpbd(model, model.initial_state(), 1.0, substeps=substeps, iterations=iterations).x)
        print(f"cantilever: tip's mean y after 1 s, XPBD {substeps} x {iterations}: "
              f"{float(np.mean(x[tip, 1] - x0[tip, 1])):+.4f} m")
    x = np.asarray(_xpbd(model, model.initial_state(), 1.0, method="pbd").x)
    print(f"cantilever: tip's mean y after 1 s, PBD 1 x 10: {float(np.mean(x[tip, 1] - x0[tip, 1])):+.4f} m")

    print("ratio chains, their length below the pin averaged over 2 s (rest 1 m; the static length is the mean "
          "of an undamped oscillation about it):")
    for name, f in (("mass_ratio_chain", mass_ratio_chain), ("stiffness_ratio_chain", stiffness_ratio_chain)):
        for ratio in (1.0, 1e2, 1e4):
            model = f(ratio=ratio)
            alpha = np.asarray(model.distance["compliance"])
            below = np.cumsum(np.asarray(model.mass)[::-1])[::-1][1:]
            static = 1.0 + float(np.sum(alpha * 9.81 * below))
            means = []
            for substeps, iterations in ((1, 10), (100, 1), (100, 10)):
                state, length = model.initial_state(), 0.0
                for _ in range(120):
                    state = _xpbd(model, state, 1 / 60, substeps=substeps, iterations=iterations)
                    length += -float(state.x[-1][1]) / 120
                means.append(f"{substeps} x {iterations}: {length:.5f} m")
            print(f"  {name}, ratio {ratio:g}: static {static:.5f} m; XPBD " + ", ".join(means))

    for angle in (math.pi, math.pi / 2):
        model, state = twisting_cloth(angle=angle)
        rest = np.asarray(model.distance["rest_length"])
        r = np.asarray(model.rest_positions)
        middle = np.isclose(r[:, 0], r[np.argmin(np.abs(r[:, 0])), 0], rtol=0, atol=1e-9)
        for label, s in (("start", state), ("end of 1 s of XPBD 1 x 10", _xpbd(model, state, 1.0))):
            strain = np.abs(_core.distance_violations(model, s)) / rest
            x = np.asarray(s.x)[middle]
            print(f"twisting_cloth, angle {angle:.4f} rad: at the {label} largest strain {float(strain.max()):.3f}, "
                  f"middle row {2 * float(np.hypot(x[:, 1], x[:, 2]).max()):.3f} m wide")


if __name__ == "__main__":
    main()
