"""Soft-body scenes shared by the tests and validation/soft_bodies.py: a tet cube held by one
corner, a tet cantilever, and an icosphere balloon."""

from __future__ import annotations

import numpy as np

from .. import _core
from ..mesh import icosphere
from ..model import ModelBuilder
from ..tetmesh import tet_box

__all__ = ["icosphere", "hanging_tet_cube", "tet_cantilever", "hanging_balloon", "total_volume",
           "xpbd_error_against_reference"]


def hanging_tet_cube(*, size: float = 0.2, cells: int = 3, density: float = 500.0, stretch_compliance: float = 1e-4,
                     volume_compliance: float | None = None, bulk_modulus: float = 1e5, stretch_stiffness: float = 1.0,
                     volume_stiffness: float | None = 1.0):
    """A soft tet cube (``size`` m, ``cells``³ cells of 6 tets, ``density`` kg/m³) whose corner
    (-size/2, size/2, -size/2) is pinned at the origin's side: released at rest, it falls and swings
    from that corner. Volume compliance V0/K per tet from ``bulk_modulus`` K (Pa) unless given
    (m⁶/J). Returns (model, instance)."""
    mesh = tet_box([size] * 3, [cells] * 3)
    if volume_compliance is None:
        volume_compliance = float(mesh.volumes()[0]) / bulk_modulus
    b = ModelBuilder()
    inst = b.add_tet_mesh(mesh, density=density, stretch_stiffness=stretch_stiffness,
                          stretch_compliance=stretch_compliance, volume_stiffness=volume_stiffness,
                          volume_compliance=volume_compliance)
    b.pin(inst.nearest([-size / 2, size / 2, -size / 2]))
    return b.build(), inst


def tet_cantilever(*, length: float = 0.4, width: float = 0.1, cells=(8, 2, 2), density: float = 1000.0,
                   stretch_compliance: float = 1e-4, bulk_modulus: float = 1e6):
    """A beam of tets along +x from x = 0 (``length`` x ``width`` x ``width`` m, ``cells`` cells of 6
    tets), its x = 0 face pinned, compliant stretch (m/N) on every edge and volume compliance
    V0/K (m⁶/J) from ``bulk_modulus`` K (Pa) on every tet. Returns (model, tip particle indices)."""
    mesh = tet_box([length, width, width], list(cells), center=[length / 2, 0, 0])
    b = ModelBuilder()
    inst = b.add_tet_mesh(mesh, density=density, stretch_compliance=stretch_compliance,
                          volume_compliance=float(mesh.volumes()[0]) / bulk_modulus)
    x = inst.vertices
    for i in np.where(x[:, 0] < 1e-9 * length)[0]:
        b.pin(inst.first_particle + int(i))
    tip = inst.first_particle + np.where(np.abs(x[:, 0] - length) < 1e-9 * length)[0]
    return b.build(), tip


def hanging_balloon(*, pressure: float = 1.0, radius: float = 0.2, subdivisions: int = 2, mass: float = 0.1,
                    stretch_stiffness: float = 1.0, stretch_compliance: float = 0.0, balloon_stiffness: float = 1.0,
                    balloon_compliance: float = 0.0, pin_top: bool = True):
    """An icosphere cloth (``mass`` kg, stretch on every edge) with an overpressure constraint of
    ``pressure`` times its initial volume, hanging from its top vertex. Returns (model, instance)."""
    b = ModelBuilder()
    inst = b.add_mesh(icosphere(radius, subdivisions), mass=mass, stretch_stiffness=stretch_stiffness,
                      stretch_compliance=stretch_compliance)
    b.add_balloon(inst, pressure=pressure, stiffness=balloon_stiffness, compliance=balloon_compliance)
    if pin_top:
        b.pin(inst.nearest([0, radius, 0]))
    return b.build(), inst


def total_volume(model: _core.Model, state: _core.State) -> float:
    """Σ of the signed volumes of the model's volume constraints (m³)."""
    return float(np.sum(_core.volume_violations(model, state) + np.asarray(model.volume["rest_volume"])))


def xpbd_error_against_reference(model: _core.Model, reference, times, substeps: int,
                                 frame: float = 1 / 60) -> tuple[float, _core.State]:
    """Steps ``model`` from rest with XPBD, one iteration and ``substeps`` sub-steps per ``frame``
    (s), and returns the largest distance (m) of any particle to the reference at ``times`` (the
    reference's output times, multiples of ``frame``), with the final state."""
    state = model.initial_state()
    stepper = _core.PbdStepper(method="xpbd", dt=frame, substeps=substeps, iterations=1)
    err = 0.0
    for k, t in enumerate(times):
        stepper.step(model, state, int(round((t - state.t) / frame)))
        err = max(err, float(np.max(np.linalg.norm(np.asarray(state.x) - reference.x[k], axis=1))))
    return err, state
