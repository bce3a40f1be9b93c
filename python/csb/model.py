"""Building a Model: particles from meshes, constraints, pins and attachments."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from . import _core
from .mesh import Mesh, MeshReport, SourceMesh, warn_element_quality
from .select import Material, Selector, select_vertices
from .tetmesh import TetMesh

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
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.int32))
    """(T, 3) the surface triangles it added to the model, particle indices (a tet mesh's boundary, wound outwards)"""
    num_volume: int = 0
    """tet meshes: volume constraints added (one per tet)"""
    flipped_tets: int = 0
    """tet meshes: inverted tets (negative signed volume) that were re-oriented"""
    name: str = ""
    """the mesh's name (its file, or the label it was given), for messages"""
    source: SourceMesh | None = None
    """the file's own mesh (:func:`csb.load_mesh`'s ``mesh.source``): its polygons, UVs and
    normals, and the weld map from its vertices to this mesh's particles"""

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

    def select(self, what: Selector) -> np.ndarray:
        """Indices (in the model, ascending) of this mesh's particles that `what` chooses: a region
        (:class:`csb.Box`, :class:`csb.Sphere`, :class:`csb.HalfSpace`, :class:`csb.NearLine`,
        joined with ``|``) or a callable of the (N, 3) vertex positions returning N booleans, both
        tested against the vertices as added (m); a boolean mask over the vertices; or an array of
        vertex indices; or :class:`csb.Material` (the file's meshes of that material). A selection
        that catches nothing is a ParameterError saying so (see :func:`csb.select.select_vertices`)."""
        label = f"mesh '{self.name}'" if self.name else "the mesh"
        if isinstance(what, Material):
            if self.source is None:
                raise _core.ParameterError(f"{label} has no file's mesh to find material {what.name!r} in: it was "
                                           "not read by csb.load_mesh, or its file mixes points and lines with polygons")
            try:
                return self.first_particle + self.source.material_vertices(what.name)
            except _core.ParameterError as e:
                raise _core.ParameterError(f"{label}: {e}") from None
        return self.first_particle + select_vertices(self.vertices, what, label=label)


class ModelBuilder(_core.ModelBuilder):
    """Collects particles and constraints; :meth:`build` returns the immutable :class:`csb.Model`.

    Only what is added is built and stepped: a mesh gets distance constraints on its edges only if
    ``stretch_stiffness`` is given, bending constraints only if ``bending_stiffness`` is given.
    """

    def add_family(self, family) -> str:
        """Adds a constraint family written in Python (a :class:`csb.ConstraintFamily`): its
        constraints are then added with :meth:`add_constraint` by its name, and every stepper
        projects them in its sweeps with the built-in ones (slow: see :mod:`csb.family`)."""
        from .family import add_family

        return add_family(self, family)

    def add_constraint(self, family, particles, params=(), stiffness: float = 1.0, compliance: float = 0.0) -> int:
        """A constraint of a family, by name or object (``tethers``, or one added with
        :meth:`add_family`): its particles (the family's arity), its parameters (the family's, in
        order, in their units), PBD stiffness in [0, 1], compliance in the family's unit (0: hard).
        Returns its index in the family's batch."""
        from .family import add_constraint

        return add_constraint(self, family, particles, params, stiffness, compliance)

    def pin(self, i: int | Sequence[int] | np.ndarray) -> None:
        """Fixes particle i (inverse mass 0), or each particle of an index array (what
        :meth:`MeshInstance.select` returns): ``builder.pin(cape.select(csb.Box(lo, hi)))``."""
        arr = np.asarray(i)
        if arr.ndim == 0:
            super().pin(i)
            return
        if arr.ndim != 1 or not (arr.size == 0 or np.issubdtype(arr.dtype, np.integer)):
            raise _core.ParameterError(f"pin: give a particle index or a 1-D array of them, got {i!r}")
        for k in arr.tolist():
            super().pin(k)

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
        warn_element_quality(mesh.name or "mesh", mesh.vertices, mesh.triangles)
        return _instance(d, mesh.vertices, mesh.name, getattr(mesh, "source", None))

    def add_tet_mesh(
        self,
        mesh: TetMesh,
        *,
        group: int = -1,
        mass: float | None = None,
        density: float | None = None,
        particle_mass: float | None = None,
        stretch_stiffness: float | None = 1.0,
        stretch_compliance: float = 0.0,
        volume_stiffness: float | None = 1.0,
        volume_compliance: float = 0.0,
    ) -> MeshInstance:
        """Add every point of a tet mesh as a particle (numbering kept) with its constraints.

        Give exactly one of ``mass`` (kg, whole mesh, shared by lumped volume: a quarter of each
        adjacent tet per point), ``density`` (kg/m³) or ``particle_mass`` (kg each).
        ``stretch_stiffness`` in [0, 1] puts a distance constraint on every unique tet edge
        (None: none), with ``stretch_compliance`` in m/N; ``volume_stiffness`` in [0, 1] a volume
        constraint C = V - V0 on every tet (None: none), with ``volume_compliance`` in m⁶/J (the
        potential is C²/(2α) with C in m³; a material of bulk modulus K in Pa gives a tet of rest
        volume V0 the compliance V0/K, from its strain energy K/2 (ΔV/V0)² V0). 0 is hard. The boundary faces become the model's
        triangles (``instance.triangles``, wound outwards), for output and for :meth:`add_balloon`.

        Inverted tets (negative signed volume) are re-oriented by swapping their last two points,
        counted in ``flipped_tets`` and reported as a :class:`csb.MeshWarning`; a degenerate tet
        (|V| below 1e-12 x the bounding-box diagonal cubed) raises :class:`csb.MeshError` naming the
        tet and its volume.
        """
        d = self._add_tet_mesh(
            mesh,
            group=group,
            mass=mass,
            density=density,
            particle_mass=particle_mass,
            stretch_stiffness=stretch_stiffness,
            stretch_compliance=stretch_compliance,
            volume_stiffness=volume_stiffness,
            volume_compliance=volume_compliance,
        )
        return _instance(d, mesh.points, getattr(mesh, "name", ""))

    def add_balloon(
        self,
        surface: MeshInstance | np.ndarray | Sequence[Sequence[int]],
        *,
        pressure: float = 1.0,
        stiffness: float = 1.0,
        compliance: float = 0.0,
    ) -> int:
        """An overpressure constraint (Müller 2007 §4.5) over a closed surface: C = V - pressure V0.

        ``surface`` is a :class:`MeshInstance` (its ``triangles``: a closed mesh from
        :meth:`add_mesh`, or a tet mesh's boundary) or a (T, 3) array of particle indices, wound
        outwards. V0 is the volume it encloses now (m³), ``pressure`` >= 0 the dimensionless factor
        k_pressure on it, ``stiffness`` in [0, 1] the PBD stiffness, ``compliance`` in m⁶/J
        (0: hard). Raises :class:`csb.ParameterError` for an open or inconsistently wound surface
        (naming the count of boundary, non-manifold and misoriented edges and one example) and
        for one wound inwards (negative enclosed volume). Returns the balloon's index.
        """
        triangles = surface.triangles if isinstance(surface, MeshInstance) else surface
        return int(self._add_balloon(np.asarray(triangles), pressure=pressure, stiffness=stiffness, compliance=compliance))


def _instance(d: dict, vertices: np.ndarray, name: str, source: SourceMesh | None = None) -> MeshInstance:
    """A MeshInstance from the builder's result dict, its report's warnings emitted."""
    report = MeshReport._from_core(d.pop("report"))
    report._emit()
    return MeshInstance(**d, report=report, vertices=vertices, name=name, source=source)
