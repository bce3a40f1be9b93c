"""csb.studies: the study framework. This module holds the small measurement set-ups shared by the
validation studies (validation/) and their quick versions in the tests; csb.studies.collisions and
csb.studies.soft_bodies the collision and soft-body set-ups, csb.studies.literature the
literature's test scenes (XPBD's oscillator, chain and cantilever, the ratio chains, the twisting
cloth) as study set-ups, csb.studies.report the main job's report, csb.studies.study the study
files that `csb study run` reads and runs on Dask (run_study). They use the library (csb), never
the benchmarks."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import inspect
import math
import time
import warnings

import numpy as np

from .. import _core
from ..model import ModelBuilder
from ..scene import Scene


def copy_state(model: _core.Model, state: _core.State) -> _core.State:
    """An independent copy of `state` (positions, velocities, time, step count) for `model`."""
    s = model.initial_state()
    s.x, s.v, s.t, s.step = np.array(state.x), np.array(state.v), state.t, state.step
    return s


def write_csv(path, rows: list[dict]) -> None:
    """Rows of a study as a CSV file, the first row's keys as the header."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def spring_k_eff(stiffness: float, iterations: int, *, correction: bool, mass: float = 0.3,
                 rest_length: float = 1.0, stretch: float = 0.2, dt: float = 0.01) -> float:
    """Effective stiffness (N/m) of one PBD spring, measured through the stepper.

    A particle of ``mass`` (kg) hangs on a spring of PBD ``stiffness`` in [0, 1] and
    ``rest_length`` (m) from a pinned anchor, stretched by ``stretch`` (m) and at rest, gravity
    off. One step of ``dt`` (s) with ``iterations`` leaves the stretch s1; the backward Euler
    spring that would leave the same has k_eff = m (s0/s1 - 1)/dt² (Müller 2007 §3.3).
    """
    b = ModelBuilder()
    g = b.add_group("spring")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([0, -(rest_length + stretch), 0], mass, g)
    b.add_distance(0, 1, stiffness=stiffness, rest_length=rest_length)
    b.pin(0)
    model = b.build()
    state = model.initial_state()
    _core.PbdStepper(dt=dt, iterations=iterations, gravity=(0, 0, 0),
                     stiffness_correction=correction).step(model, state)
    s1 = float(np.linalg.norm(state.x[1])) - rest_length
    return mass * (stretch / s1 - 1) / dt**2


def strain_history(scene: Scene, *, substeps: int, iterations: int, damping: float = 0.0,
                   steps: int | None = None) -> dict:
    """Runs ``scene`` with the given split of sub-steps and iterations (and damping), measuring
    after every step the largest and the RMS |strain| of its distance constraints.

    Returns max_strain (over all steps), mean_rms_strain, wall_time_s (stepping only) and the
    per-step series of the largest strain.
    """
    solver = dataclasses.replace(scene.solver, substeps=substeps, iterations=iterations, damping=damping)
    sim = dataclasses.replace(scene, solver=solver).build()
    rest = np.asarray(sim.model.distance["rest_length"])
    worst, rms, wall = [], [], 0.0
    for _ in range(scene.steps if steps is None else steps):
        t0 = time.perf_counter()
        sim.stepper.step(sim.model, sim.state)
        wall += time.perf_counter() - t0
        strain = np.abs(_core.distance_violations(sim.model, sim.state)) / rest
        worst.append(float(strain.max()))
        rms.append(float(np.sqrt(np.mean(strain**2))))
    return dict(substeps=substeps, iterations=iterations, max_strain=max(worst), mean_rms_strain=float(np.mean(rms)),
                wall_time_s=wall, series=np.array(worst))


# --------------------------------------------------------------------------------- analytic scenes


def pendulum_model(theta: float, *, compliance: float, length: float = 1.0, mass: float = 1.0,
                   gravity: float = 9.81) -> _core.Model:
    """A simple pendulum of ``length`` (m) and bob ``mass`` (kg) released at rest at ``theta`` (rad)
    from the downward vertical. With a compliant rod (α > 0, m/N) the bob starts at the rod's
    static stretch m g cos θ α, so that the rod's fast radial mode is not set ringing."""
    b = ModelBuilder()
    g = b.add_group("pendulum")
    r = length + mass * gravity * math.cos(theta) * compliance
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([r * math.sin(theta), -r * math.cos(theta), 0], mass, g)
    b.add_distance(0, 1, rest_length=length, compliance=compliance)
    b.pin(0)
    return b.build()


def pendulum_period(t: np.ndarray, x: np.ndarray) -> float:
    """Mean time between successive downward zero crossings of x(t) (s), located by linear
    interpolation (accurate: the swing's acceleration vanishes at the bottom)."""
    i = np.where((x[:-1] > 0) & (x[1:] <= 0))[0]
    if len(i) < 2:
        raise ValueError("fewer than two downward zero crossings: run longer")
    crossings = t[i] + x[i] / (x[i] - x[i + 1]) * (t[i + 1] - t[i])
    return float(np.diff(crossings).mean())


def catenary(links: int, link_length: float, span: float, mass: float, *, stiffness: float | None = None,
             gravity: float = 9.81) -> np.ndarray:
    """The exact discrete catenary: ``links`` links of ``link_length`` (m) between supports at
    (0, 0) and (span, 0), a point mass ``mass`` (kg) at every inner node, y up. Link i has slope
    s_i = (m g / H)(i - (N + 1)/2); the horizontal tension H solves Σ l_i / sqrt(1 + s_i²) = span,
    with l_i = l0 for inextensible links or l0 + H sqrt(1 + s_i²)/k for links of ``stiffness`` k
    (N/m). Returns the (N + 1, 2) node positions."""
    i = np.arange(1, links + 1)

    def shape(H: float) -> tuple[float, np.ndarray, np.ndarray]:
        s = (mass * gravity / H) * (i - (links + 1) / 2)
        lengths = link_length + (0.0 if stiffness is None else H * np.sqrt(1 + s * s) / stiffness)
        return float(np.sum(lengths / np.sqrt(1 + s * s))) - span, s, lengths

    if not links * link_length > span > 0:
        raise ValueError("the chain must be longer than the span between its supports")
    lo, hi = 1e-12, 1e12  # the span grows with H: bisect in log space
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if shape(mid)[0] > 0 else (mid, hi)
    _, s, lengths = shape(math.sqrt(lo * hi))
    dx, dy = lengths / np.sqrt(1 + s * s), lengths * s / np.sqrt(1 + s * s)
    return np.column_stack([np.concatenate([[0.0], np.cumsum(dx)]), np.concatenate([[0.0], np.cumsum(dy)])])


def hanging_chain(links: int, link_length: float, span: float, mass: float, *, compliance: float = 0.0) -> _core.Model:
    """A chain between two pinned supports ``span`` (m) apart, starting slack on the straight
    line between them: ``links`` links of rest length ``link_length`` (m), inner nodes of ``mass``
    (kg), link compliance in m/N (0: hard)."""
    b = ModelBuilder()
    g = b.add_group("chain")
    for k in range(links + 1):
        b.add_particle([span * k / links, 0, 0], mass, g)
    for k in range(links):
        b.add_distance(k, k + 1, rest_length=link_length, compliance=compliance)
    b.pin(0)
    b.pin(links)
    return b.build()


def swinging_chain(*, links: int = 10, compliance: float = 1e-7, link_length: float = 0.05, density: float = 0.1,
                   angle: float = 0.35) -> _core.Model:
    """A chain pinned at its top, released straight at ``angle`` (rad) from the vertical: a
    smooth, non-chaotic motion over a few seconds (a chain released horizontally whips and is
    chaotic, so no trajectory of it is reproducible to a tolerance). Links of compliance in m/N."""
    b = ModelBuilder()
    b.add_mesh(_core.chain(links, link_length, direction=(math.sin(angle), -math.cos(angle), 0)), density=density,
               stretch_compliance=compliance)
    b.pin(0)
    return b.build()


def hanging_cloth(n: int, *, size: float = 0.5) -> _core.Model:
    """A square cloth of n x n particles and `size` m a side (0.2 kg/m², stretch compliance 1e-4
    m/N, bending stiffness 1 and compliance 1 1/(N m)), flat and pinned at its two corners at -z:
    released, it falls and swings on them. The accuracy studies' cloth (validation/pareto.py,
    validation/precision.py)."""
    b = ModelBuilder()
    inst = b.add_mesh(_core.cloth_grid(size, size, n, n), density=0.2, stretch_compliance=1e-4, bending_stiffness=1.0,
                      bending_compliance=1.0)
    b.pin(inst.nearest([-size / 2, 0, -size / 2]))
    b.pin(inst.nearest([size / 2, 0, -size / 2]))
    return b.build()


def relative_energy_drift(model: _core.Model, states: list, gravity) -> float:
    """|E(end) - E(start)| of the total (kinetic + gravitational + elastic) energy, relative to
    the larger of |E(start)| and the largest kinetic energy seen, so that the figure does not
    depend on where the height origin is."""
    m = [_core.measure(model, s, gravity) for s in states]
    scale = max(abs(m[0]["total_energy"]), max(x["kinetic_energy"] for x in m))
    return abs(m[-1]["total_energy"] - m[0]["total_energy"]) / scale


def spinning_cloth(*, n: int = 8, size: float = 0.5, omega: float = 2.0, stretch_compliance: float = 1e-4,
                   bending_compliance: float = 1.0) -> tuple[_core.Model, _core.State]:
    """A free, flat sheet (no pins, 0.2 kg/m², stretch and bending constraints) spinning in its
    own plane at ``omega`` (rad/s) about its centre: with gravity off its kinetic energy is all
    the energy there is, and it stays flat, so the bending constraints store nothing in any
    method. Compliance for the reference: 1e-4 m/N stretch (woven cloth), 1 1/(N m) bending.
    Returns the model and the start state."""
    b = ModelBuilder()
    b.add_mesh(_core.cloth_grid(size, size, n, n), density=0.2, stretch_compliance=stretch_compliance,
               bending_stiffness=1.0, bending_compliance=bending_compliance)
    model = b.build()
    state = model.initial_state()
    r = np.asarray(model.rest_positions)
    state.v = np.cross([0.0, omega, 0.0], r)
    return model, state


def spin_energy_factor(omega_h: float) -> float:
    """Kinetic energy kept by one PBD step of a rigid body spinning at ω, if the projection
    shrinks the prediction x + hv (the body rotated by φ = atan(ωh) and scaled by
    sqrt(1 + (ωh)²)) back uniformly: |v_new|² / |v|² = 2(1 - cos φ)/(ωh)²."""
    phi = math.atan(omega_h)
    return 2 * (1 - math.cos(phi)) / omega_h**2


@contextlib.contextmanager
def hard_under_pbd():
    """The studies step one Model, whose constraints carry only a compliance (stiffness 1), with
    PBD and Jakobsen beside XPBD and the reference: PBD's and Jakobsen's hard constraints against
    the compliant system is what they measure. The csb.MaterialWarning saying that PBD or
    Jakobsen ignores the compliance is expected there and not shown; any other warning is."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"(PBD|Jakobsen) reads stiffness, not compliance",
                                category=_core.MaterialWarning)
        yield


def method_energy(model: _core.Model, state: _core.State, gravity, *, reference: bool) -> float:
    """The energy a method conserves: kinetic + gravitational + elastic (Σ C²/(2α)) for the
    reference; kinetic + gravitational for PBD, whose hard constraints store no energy (their
    violation is reported separately)."""
    m = _core.measure(model, state, gravity)
    return m["total_energy"] if reference else m["kinetic_energy"] + m["gravitational_energy"]


def energy_series(model: _core.Model, start: _core.State, times: np.ndarray, gravity, *,
                  method: str, dt: float = 1 / 60, substeps: int = 1, iterations: int = 10,
                  reference: dict | None = None) -> np.ndarray:
    """Energy at ``times`` (multiples of dt) for ``method`` "reference" (with the settings of
    ``reference``, e.g. its ``frequency``) or "pbd" (undamped)."""
    if method == "reference":
        from ..reference import integrate_reference

        r = integrate_reference(model, start, times, gravity=gravity, **(reference or {}))
        return np.array([method_energy(model, s, gravity, reference=True) for s in r.states(model)])
    state = start.copy()
    stepper = _core.PbdStepper(dt=dt, substeps=substeps, iterations=iterations, gravity=gravity)
    out = [method_energy(model, state, gravity, reference=False)]
    with hard_under_pbd():
        for k in range(1, len(times)):
            stepper.step(model, state, int(round((times[k] - times[k - 1]) / dt)))
            out.append(method_energy(model, state, gravity, reference=False))
    return np.array(out)


def drift_per_second(times: np.ndarray, energy: np.ndarray, scale: float) -> float:
    """Least-squares slope of the energy over time, relative to ``scale`` (1/s)."""
    return float(np.polyfit(times, energy, 1)[0] / scale)


def pbd_errors(model: _core.Model, start: _core.State, times: np.ndarray, reference_x: np.ndarray, gravity, *,
               dt: float, iterations: int, substeps: int = 1) -> tuple[float, float]:
    """Max over ``times`` of the max particle distance to the reference (m), and the mean over
    steps of the largest distance-constraint violation after the step (m)."""
    state = start.copy()
    stepper = _core.PbdStepper(dt=dt, substeps=substeps, iterations=iterations, gravity=gravity)
    error, residual, steps = 0.0, 0.0, 0
    with hard_under_pbd():
        for k in range(1, len(times)):
            for _ in range(int(round((times[k] - times[k - 1]) / dt))):
                stepper.step(model, state)
                residual += float(np.abs(_core.distance_violations(model, state)).max())
                steps += 1
            error = max(error, float(np.linalg.norm(np.asarray(state.x) - reference_x[k], axis=1).max()))
    return error, residual / steps


def observed_order(h: np.ndarray, error: np.ndarray) -> float:
    """Slope of log(error) against log(h), least squares."""
    return float(np.polyfit(np.log(h), np.log(error), 1)[0])


# --------------------------------------------------------------------------------- methods


def make_stepper(method, *, dt: float, iterations: int = 10, substeps: int = 1,
                 gravity=(0.0, -9.81, 0.0)) -> _core.Integrator:
    """The stepper a study runs, an Integrator. `method` is one of:

    - a built-in method's name (csb.methods(): "pbd", "xpbd", "jakobsen" with `iterations` per
      sub-step, "small-steps" (XPBD, `substeps` of one iteration), "explicit-euler",
      "symplectic-euler", "velocity-verlet"), made by csb.make_integrator;
    - a csb.Integrator (a user's own method), used as it is: its dt() must be `dt` (s);
    - a callable (a user's Integrator subclass, say) that makes one from those of the keyword
      arguments dt, iterations, substeps and gravity it takes, for a study that sweeps them."""
    if isinstance(method, str):
        return _core.make_integrator(method, dt, substeps=substeps, iterations=iterations, gravity=gravity)
    if isinstance(method, _core.Integrator):
        if method.dt() != dt:
            raise _core.ParameterError(f"the study steps with dt = {dt:g} s, but the method {method.name()!r} has "
                                       f"dt() = {method.dt():g} s: pass a callable that makes it for a dt")
        return method
    if callable(method):
        given = dict(dt=dt, iterations=iterations, substeps=substeps, gravity=gravity)
        try:
            params = inspect.signature(method).parameters
        except (TypeError, ValueError):  # no signature to read: all of them
            params = None
        if params is not None and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
            given = {k: v for k, v in given.items() if k in params}
        stepper = method(**given)
        if not isinstance(stepper, _core.Integrator):
            raise _core.ParameterError(f"method {method!r} made a {type(stepper).__name__}, not a csb.Integrator")
        return stepper
    raise _core.ParameterError(f"method must be a method's name, a csb.Integrator or a callable making one, "
                               f"got {method!r}")


def omega_max(model: _core.Model, state: _core.State, gravity=(0.0, -9.81, 0.0)) -> float:
    """The largest angular frequency of the spring network at `state` (rad/s): ω_max² is the
    largest eigenvalue of M⁻¹K, K the Hessian of the spring energy (read from the analytic
    Jacobian's ∂v̇/∂x block, which is -M⁻¹K)."""
    from ..reference import SpringNetwork

    net = SpringNetwork(model, state, gravity=gravity)
    n3 = net.size // 2
    indptr, indices, data = net.jacobian(net.pack(state))
    A = np.zeros((n3, n3))
    for col in range(n3):
        for e in range(indptr[col], indptr[col + 1]):
            if indices[e] >= n3:
                A[indices[e] - n3, col] = data[e]
    return float(math.sqrt(max(np.linalg.eigvals(-A).real.max(), 0.0)))


def run_method(model: _core.Model, start: _core.State, times: np.ndarray, stepper: _core.Integrator, *,
               dt: float | None = None, reference_x: np.ndarray | None = None, blow_up: float = 100.0,
               positions: bool = False) -> dict:
    """Steps `start` with `stepper`, any csb.Integrator (a built-in or a user's own), through
    `times` (multiples of its dt, s; `dt` defaults to stepper.dt()). Returns the wall time and the
    process's CPU time of stepping (s), whether it blew up (csb.SimulationError, non-finite, or a
    particle farther than `blow_up` times the model's size from where it started) and, with
    `reference_x` (T, N, 3), the largest distance to it (m); with `positions`, also the positions
    at `times` as "x" (T, N, 3; None if it blew up). Any other exception the method raises passes
    through."""
    if not isinstance(stepper, _core.Integrator):
        raise _core.ParameterError(f"stepper must be a csb.Integrator, got {type(stepper).__name__}")
    if dt is None:
        dt = stepper.dt()
    state = start.copy()
    x0 = np.asarray(start.x).copy()
    size = float(np.linalg.norm(x0.max(axis=0) - x0.min(axis=0)))
    wall, cpu, error, blew = 0.0, 0.0, 0.0, False
    xs = [x0]
    with hard_under_pbd():
        for k in range(1, len(times)):
            n = int(round((times[k] - times[k - 1]) / dt))
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                stepper.step(model, state, n)
            except _core.SimulationError:
                blew = True
            wall += time.perf_counter() - t0
            cpu += time.process_time() - c0
            if blew or not np.all(np.isfinite(state.x)) or np.abs(np.asarray(state.x) - x0).max() > blow_up * size:
                blew = True
                break
            if reference_x is not None:
                error = max(error, float(np.linalg.norm(np.asarray(state.x) - reference_x[k], axis=1).max()))
            if positions:
                xs.append(np.asarray(state.x).copy())
    result = dict(wall_time=wall, cpu_time=cpu, blew_up=blew, error=error if not blew else float("inf"))
    if positions:
        result["x"] = None if blew else np.array(xs)
    return result
