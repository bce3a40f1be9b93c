"""Small measurement set-ups shared by the validation studies and their quick versions in the tests."""

from __future__ import annotations

import numpy as np

from . import _core
from .model import ModelBuilder


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
