"""Small measurement set-ups shared by the validation studies and their quick versions in the tests."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from . import _core
from .model import ModelBuilder
from .scene import Scene


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
