"""Building a Model: particles from meshes, constraints, pins and attachments."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from . import _core
from .mesh import Mesh, MeshReport

__all__ = ["ModelBuilder", "MeshInstance"]


@dataclass(frozen=True)
class MeshInstance:
    """Where a mesh landed in the particle pool: vertex i is particle ``first_particle + i``."""

    first_particle: int
    num_particles: int
    group: int
    num_distance: int
    num_bending: int
    report: MeshReport
    vertices: np.ndarray
    """(N, 3) positions of the mesh's vertices as added, m"""

    @property
    def particles(self) -> np.ndarray:
        """Indices of the mesh's particles in the model."""
        return np.arange(self.first_particle, self.first_particle + self.num_particles)

    def nearest(self, point: Sequence[float]) -> int:
        """Index (in the model) of this mesh's particle nearest to a point (m); ties go to the lowest index."""
        p = np.asarray(point, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise _core.ParameterError(f"point must be 3 finite coordinates in m, got {point!r}")
        return self.first_particle + int(np.argmin(np.sum((self.vertices - p) ** 2, axis=1)))


class ModelBuilder(_core.ModelBuilder):
    """Collects particles and constraints; :meth:`build` returns the immutable :class:`csb.Model`.

    Only what is added is built and stepped: a mesh gets distance constraints on its edges only if
    ``stretch_stiffness`` is given, bending constraints only if ``bending_stiffness`` is given.
    """

    def add_mesh(
        self,
        mesh: Mesh,
        *,
        group: int = -1,
        mass: float | None = None,
        density: float | None = None,
        particle_mass: float | None = None,
        stretch_stiffness: float | None = 1.0,
        bending_stiffness: float | None = None,
        stretch_compliance: float = 0.0,
        bending_compliance: float = 0.0,
        thickness: float = 0.0,
    ) -> MeshInstance:
        """Add every vertex of ``mesh`` as a particle (numbering kept) with its constraints.

        Give exactly one of ``mass`` (kg, whole mesh, shared by lumped area or length),
        ``density`` (kg/m² for a surface, kg/m for lines) or ``particle_mass`` (kg each).
        ``stretch_stiffness`` in [0, 1] puts a distance constraint on every unique edge (None: none);
        ``bending_stiffness`` in [0, 1] a dihedral bending constraint on every interior edge
        (None: none). Stiffness is what PBD projects with; ``stretch_compliance`` (m/N) and
        ``bending_compliance`` (1/(N m)) are the material's inverse stiffness, which the reference
        integrator (and XPBD) use; 0 is hard. ``group`` is an existing group or -1 for a new one
        named after the mesh. ``thickness`` (m, >= 0) is the particles' collision radius against
        the colliders.
        Degenerate triangles are dropped with a :class:`csb.MeshWarning`.
        """
        d = self._add_mesh(
            mesh,
            group=group,
            mass=mass,
            density=density,
            particle_mass=particle_mass,
            stretch_stiffness=stretch_stiffness,
            bending_stiffness=bending_stiffness,
            stretch_compliance=stretch_compliance,
            bending_compliance=bending_compliance,
            thickness=thickness,
        )
        report = MeshReport._from_core(d.pop("report"))
        report._emit()
        return MeshInstance(**d, report=report, vertices=mesh.vertices)
