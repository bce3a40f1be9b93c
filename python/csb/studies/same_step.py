"""Measurements against the same-step reference: backward Euler at the method's own time step,
solved by Newton's method to convergence from the method's own state (csb.BackwardEuler). Against
it a method's error is its solver error alone (against the continuous reference, CVODE, its total
error); its measure is the backward-Euler residual |∇E| (N) of the method's step
(csb.backward_euler_residual), plotted against iterations and against CPU time."""

from __future__ import annotations

import time

import numpy as np

from .. import _core
from ..model import ModelBuilder
from . import copy_state
from .literature import xpbd_chain

G = (0.0, -9.81, 0.0)


def falling_chain(link: float = 1.0, *, particles: int = 20, mass: float = 1.0,
                  compliance: float = 1e-8) -> _core.Model:
    """XPBD's §6.2 chain: ``particles`` of ``mass`` kg, straight and horizontal at rest length
    ``link`` (m), links of compliance α (m/N), the first particle pinned
    (csb.studies.literature.xpbd_chain, start "horizontal")."""
    return xpbd_chain(particles=particles, mass=mass, link=link, compliance=compliance, start="horizontal")


def hanging_cloth(n: int = 16, *, compliance: float = 1e-4, bending_compliance: float = 0.1) -> _core.Model:
    """An n x n cloth of 1 m and 0.2 kg (stretch springs of α m/N, bending of 1/(N m)), the two
    corners of one edge pinned."""
    b = ModelBuilder()
    inst = b.add_mesh(_core.cloth_grid(1.0, 1.0, n, n), mass=0.2, stretch_compliance=compliance, bending_stiffness=1.0,
                      bending_compliance=bending_compliance)
    b.pin(inst.first_particle)
    b.pin(inst.first_particle + n - 1)
    return b.build()


def _support_force(model: _core.Model, state: _core.State) -> float:
    """|C|/α of distance constraint 0 (the link at the pin), N."""
    i, j = np.asarray(model.distance["particles"])[0]
    x = np.asarray(state.x)
    c = np.linalg.norm(x[j] - x[i]) - float(model.distance["rest_length"][0])
    return abs(c) / float(model.distance["compliance"][0])


def xpbd_chain_same_step(*, link: float = 1.0, iterations: tuple[int, ...] = (50, 100, 1000), frames: int = 100,
                         dt: float = 1.0 / 60.0, skip: int = 9) -> list[dict]:
    """XPBD's support force on the §6.2 chain against the same-step reference and against the
    backward Euler trajectory. For each iteration count XPBD (Gauss-Seidel, one sub-step) runs its
    own trajectory; at every frame backward Euler solved to convergence from XPBD's state gives
    the same-step force (|C|/α) and the residual |∇E| of XPBD's step; backward Euler run on its own
    from the start gives the trajectory force. Rows: the largest relative error of XPBD's |λ|/h²
    at the support over all frames and from frame skip + 1 on, against either reference, and the
    residual's largest and median 2-norm (N) and largest component relative to the step's force
    scale."""
    model = falling_chain(link)
    reference = _core.BackwardEuler(dt=dt, gravity=G)
    state = model.initial_state()
    trajectory = []
    for _ in range(frames):
        reference.step(model, state)
        trajectory.append(_support_force(model, state))
    trajectory = np.array(trajectory)
    rows = []
    for it in iterations:
        xpbd = _core.PbdStepper(method="xpbd", dt=dt, iterations=it, gravity=G)
        same = _core.BackwardEuler(dt=dt, gravity=G)
        state = model.initial_state()
        f_xpbd, f_same, res_norm, res_rel, newton = [], [], [], [], 0
        for _ in range(frames):
            before = copy_state(model, state)
            target = copy_state(model, state)
            same.step(model, target)
            newton = max(newton, same.newton_iterations)
            f_same.append(_support_force(model, target))
            xpbd.step(model, state)
            f_xpbd.append(abs(float(xpbd.multipliers()["distance"][0])) / xpbd.substep_size**2)
            r = _core.backward_euler_residual(model, before, state, dt, G)
            res_norm.append(r.norm)
            res_rel.append(r.max / r.scale)
        f_xpbd, f_same = np.array(f_xpbd), np.array(f_same)
        e_same = np.abs(f_xpbd - f_same) / f_same
        e_traj = np.abs(f_xpbd - trajectory) / trajectory
        rows.append(dict(
            link_m=link, iterations=it,
            same_step_error=float(e_same.max()), same_step_frame_of_max=int(e_same.argmax()) + 1,
            same_step_error_from_frame_10=float(e_same[skip:].max()),
            trajectory_error=float(e_traj.max()), trajectory_frame_of_max=int(e_traj.argmax()) + 1,
            trajectory_error_from_frame_10=float(e_traj[skip:].max()),
            residual_norm_max_N=float(max(res_norm)), residual_norm_median_N=float(np.median(res_norm)),
            residual_relative_max=float(max(res_rel)),
            newton_iterations_max=newton, newton_residual_max_N=max(same.max_residual, reference.max_residual)))
    return rows


def residual_curve(model: _core.Model, *, method: str = "xpbd", solver: str = "gauss-seidel",
                   iterations: tuple[int, ...] = (1, 2, 5, 10, 20, 50, 100, 200), dt: float = 1.0 / 60.0,
                   warmup: int = 30, repeats: int = 3) -> list[dict]:
    """The backward-Euler residual of one step of a position-based method against its iteration
    count and its CPU time. The model first runs ``warmup`` converged backward Euler steps (so the
    step starts in motion, not at rest); from that state each iteration count takes one step
    (timed: the smallest of ``repeats`` runs, process CPU time, s) and its residual |∇E| (2-norm and
    largest component, N) is measured."""
    state = model.initial_state()
    _core.BackwardEuler(dt=dt, gravity=G).step(model, state, warmup)
    rows = []
    for it in iterations:
        stepper = _core.PbdStepper(method=method, dt=dt, iterations=it, gravity=G, solver=solver, threads=1)
        cpu, after = _timed_step(model, state, stepper, repeats)
        r = _core.backward_euler_residual(model, state, after, dt, G)
        rows.append(dict(method=method, solver=solver, iterations=it, cpu_s=cpu, residual_norm_N=r.norm,
                         residual_max_N=r.max, force_scale_N=r.scale))
    ref = _core.BackwardEuler(dt=dt, gravity=G)
    cpu, after = _timed_step(model, state, ref, repeats)
    r = _core.backward_euler_residual(model, state, after, dt, G)
    rows.append(dict(method="backward-euler", solver="newton", iterations=ref.newton_iterations, cpu_s=cpu,
                     residual_norm_N=r.norm, residual_max_N=r.max, force_scale_N=r.scale))
    return rows


def _timed_step(model: _core.Model, state: _core.State, stepper, repeats: int,
                least: float = 2e-3) -> tuple[float, _core.State]:
    """Process CPU time (s) of one step of ``stepper`` from ``state``: the smallest over ``repeats``
    rounds of the mean over enough steps (each from a copy of ``state``) to take ``least`` s; and
    the state one step leaves."""
    count, best, after = 1, np.inf, None
    for _ in range(repeats):
        while True:
            copies = [copy_state(model, state) for _ in range(count)]
            t0 = time.process_time()
            for c in copies:
                stepper.step(model, c)
            spent = time.process_time() - t0
            after = copies[0]
            if spent >= least or count >= 1 << 16:
                break
            count *= 2
        best = min(best, spent / count)
    return best, after
