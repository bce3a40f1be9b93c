"""Meshes: import through Assimp, build from arrays, clean (weld, drop degenerate triangles), transform; the icosphere."""

from __future__ import annotations

import os
import sys
import warnings
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from . import _core
from ._core import Mesh

__all__ = ["Mesh", "MeshReport", "SourceMesh", "MeshWarning", "AnimationWarning", "load_mesh", "clean", "transformed",
           "icosphere"]


class MeshWarning(UserWarning):
    """Something in a mesh was dropped or skipped (degenerate triangles, non-manifold edges, ...)."""


class AnimationWarning(MeshWarning):
    """A mesh file animates its meshes (node animations or skinning) and csb loaded its rest pose;
    :func:`csb.load_animation` reads the animation."""


_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn_mesh(message: str, category: type[Warning] = MeshWarning) -> None:
    """Issue a :class:`MeshWarning` (or ``category``) that points at the user's line: the first
    caller outside the csb package (``load_mesh``, ``add_mesh``, a scene's ``build``, ...),
    however deep in csb it was found."""
    if sys.version_info >= (3, 12):
        warnings.warn(message, category, skip_file_prefixes=(_PACKAGE,))
        return
    level, frame = 1, sys._getframe(0)  # stacklevel 1 is this function
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        level, frame = level + 1, frame.f_back
    warnings.warn(message, category, stacklevel=level)


def _animation_message(path: str, summary: dict[str, Any]) -> str | None:
    """The :class:`AnimationWarning` for a file whose scene has animations or skinned meshes, or None."""
    animations, skinned = summary["animations"], summary["skinned"]
    if not animations and not skinned:
        return None
    parts = []
    if animations:
        listed = "; ".join(f"{(name or f'animation {k}')!r}: {duration:.4g} s, {channels} animated node(s)"
                           for k, (name, duration, channels) in enumerate(animations))
        parts.append(f"{len(animations)} animation(s) ({listed})")
    if skinned:
        listed = "; ".join(f"{(name or 'unnamed')!r}: {bones} bone(s), {vertices} vertices"
                           for name, bones, vertices in skinned)
        parts.append(f"{len(skinned)} skinned mesh(es) ({listed})")
    uses = []
    if skinned:
        uses.append("a skinned mesh as a mesh collider deforms with its skeleton (a scene file's [[collider]] "
                    "type = \"mesh\", animation = true; or csb.load_animation's vertices given to "
                    "PbdStepper.deform_collider every step)")
    if animations:
        uses.append("a mesh its node moves rigidly moves as a collider by keyframes (PbdStepper.move_collider, "
                    "a scene file's collider motion or animation = true)")
    return (f"{path}: the file holds " + " and ".join(parts) + "; csb loaded the rest pose (the nodes' static "
            "transforms, no bone applied) and does not play the animation on a mesh loaded so (a cloth or soft "
            "body stays in that pose). What csb does use of it: " + "; ".join(uses) + ". csb.load_animation(path) "
            "reads the animated vertices at given times (s)")


# Elements that make a Gauss-Seidel sweep with few iterations unstable: a sliver's altitude is so
# short beside its longest edge that its bending gradient (~1/altitude) throws its apex far in one
# projection; a vertex with very many neighbours receives that many corrections in a row, each
# undoing the last. Ratios past these are warned of when a mesh is added (csb's regular meshes
# have ratios under 2 and at most 8 neighbours).
SLIVER_RATIO = 100.0     # longest edge over its altitude
HIGH_VALENCE = 32        # neighbours of a vertex


def element_quality(vertices: np.ndarray, triangles: np.ndarray) -> dict:
    """Per mesh: the triangles' largest ratio of longest edge to its altitude (zero-area triangles
    aside), how many exceed :data:`SLIVER_RATIO` and the worst; the vertices' largest valence
    (distinct neighbours), how many exceed :data:`HIGH_VALENCE` and the worst."""
    v = np.asarray(vertices, dtype=float)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    out = {"slivers": 0, "worst_ratio": 0.0, "worst_triangle": -1,
           "high_valence": 0, "worst_valence": 0, "worst_vertex": -1}
    if len(t) == 0:
        return out
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    longest2 = np.max(np.stack([np.sum((b - a) ** 2, 1), np.sum((c - b) ** 2, 1), np.sum((a - c) ** 2, 1)]), axis=0)
    twice_area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    ok = twice_area > 0
    ratio = np.zeros(len(t))
    ratio[ok] = longest2[ok] / twice_area[ok]  # L / altitude, altitude = 2 A / L
    if ok.any():
        out["worst_triangle"] = int(np.argmax(ratio))
        out["worst_ratio"] = float(ratio[out["worst_triangle"]])
        out["slivers"] = int(np.count_nonzero(ratio > SLIVER_RATIO))
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    edges = np.unique(edges, axis=0)
    valence = np.bincount(edges.ravel(), minlength=len(v))
    out["worst_vertex"] = int(np.argmax(valence))
    out["worst_valence"] = int(valence[out["worst_vertex"]])
    out["high_valence"] = int(np.count_nonzero(valence > HIGH_VALENCE))
    return out


def warn_element_quality(name: str, vertices: np.ndarray, triangles: np.ndarray) -> dict:
    """A :class:`MeshWarning` naming the mesh's slivers and high-valence vertices, if any."""
    q = element_quality(vertices, triangles)
    parts = []
    if q["slivers"]:
        parts.append(f"{q['slivers']} sliver triangle(s) whose longest edge exceeds {SLIVER_RATIO:g} times its "
                     f"altitude (worst: triangle {q['worst_triangle']}, {q['worst_ratio']:.3g} times)")
    if q["high_valence"]:
        parts.append(f"{q['high_valence']} vertex(es) with more than {HIGH_VALENCE} neighbours (worst: vertex "
                     f"{q['worst_vertex']}, {q['worst_valence']})")
    if parts:
        warn_mesh(f"mesh {name!r} has " + " and ".join(parts) + ": Gauss-Seidel with few iterations per sub-step "
                  "can blow up on such elements (more sub-steps or iterations, or remeshing, keep it stable; the "
                  "stepper's divergence guard stops a run that runs away)")
    return q


@dataclass(frozen=True)
class MeshReport:
    """What clean-up did to a mesh, so that nothing the user gave disappears silently."""

    input_vertices: int = 0
    input_triangles: int = 0
    input_lines: int = 0
    welded_vertices: int = 0
    unreferenced_vertices: int = 0
    degenerate_triangles: int = 0
    degenerate_lines: int = 0
    boundary_edges: int = 0
    non_manifold_edges: int = 0
    vertex_map: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    """input vertex -> output vertex, -1 where dropped"""
    warnings: tuple[str, ...] = ()

    @classmethod
    def _from_core(cls, d: dict[str, Any]) -> "MeshReport":
        d = dict(d)
        d["warnings"] = tuple(d["warnings"])
        return cls(**d)

    def _emit(self) -> None:
        for message in self.warnings:
            warn_mesh(message)


@dataclass(frozen=True)
class SourceMesh:
    """A file's own mesh, as its tools wrote it (``mesh.source`` of :func:`load_mesh`), so that
    results go back onto it: its vertices before welding, its polygons as the file has them (quads
    and n-gons kept), its first UV set and its normals where every mesh of the file has them, each
    of its meshes' material with its vertices, and the weld map from its vertices to the welded
    mesh that csb simulates. Positions in m, in the frame of the mesh it belongs to (the scene's
    scale, rotation and translation applied with the mesh's)."""

    vertices: np.ndarray
    """(M, 3) the file's vertices, m (as Assimp reads them: glTF's own; an OBJ's, one per distinct
    position, UV and normal corner)"""
    face_sizes: np.ndarray
    """(F,) corners per polygon"""
    face_vertices: np.ndarray
    """(sum of face_sizes,) the polygons' corners, into vertices"""
    uv: np.ndarray | None
    """(M, 2) the first UV set, or None"""
    normals: np.ndarray | None
    """(M, 3) the file's normals (unit), or None"""
    weld_map: np.ndarray
    """(M,) each vertex's vertex in the welded mesh (its particle, from a MeshInstance's
    first_particle on), -1 where it was dropped (used by no polygon)"""
    materials: tuple[tuple[str, int, int], ...] = ()
    """per mesh of the file: its material's name ("" for none) and its vertices [begin, end)"""

    @classmethod
    def _from_core(cls, d: dict[str, Any]) -> "SourceMesh":
        return cls(vertices=d["vertices"], face_sizes=d["face_sizes"], face_vertices=d["face_vertices"], uv=d["uv"],
                   normals=d["normals"], weld_map=d["weld_map"], materials=tuple(tuple(m) for m in d["materials"]))

    def positions(self, welded: np.ndarray) -> np.ndarray:
        """(M, 3) the file's vertices where the welded mesh's vertices `welded` ((N, 3), m) are:
        each takes its weld_map vertex's position; a dropped one keeps its own."""
        out = np.array(self.vertices, dtype=float)
        kept = self.weld_map >= 0
        out[kept] = np.asarray(welded)[self.weld_map[kept]]
        return out

    def distinct_vertices(self) -> tuple[np.ndarray, np.ndarray]:
        """(keep, index): the vertices that differ in position, UV or normal, each once, in the
        order the polygons first use them (`keep`, into vertices), and each vertex's place among
        them (`index`, (M,)). Assimp gives an OBJ one vertex per polygon corner; its distinct ones
        are the file's own (position, UV, normal) corners (the bundled cloth: 4,096 corners, 1,122
        distinct, as its 1,122 'v' lines). A glTF's vertices are distinct already."""
        columns = [np.asarray(self.vertices, dtype=float)]
        columns += [np.asarray(a, dtype=float) for a in (self.uv, self.normals) if a is not None]
        _, first, inverse = np.unique(np.hstack(columns), axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        # np.unique sorts the rows: renumber them by first use.
        order = np.argsort(first, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        return first[order], rank[inverse]

    def material_vertices(self, name: str) -> np.ndarray:
        """The welded mesh's vertices (ascending) of the file's meshes whose material is `name`;
        ParameterError naming the materials there are if none is."""
        ranges = [(b, e) for n, b, e in self.materials if n == name]
        if not ranges:
            names = sorted({n for n, _, _ in self.materials if n})
            raise _core.ParameterError(
                f"no material {name!r} in the file; it has " + (", ".join(repr(n) for n in names) if names else "none named"))
        source = np.concatenate([np.arange(b, e) for b, e in ranges])
        welded = self.weld_map[source]
        return np.unique(welded[welded >= 0])

    def _transformed(self, s: np.ndarray, R: np.ndarray, t: np.ndarray, mirror: bool) -> "SourceMesh":
        faces = np.asarray(self.face_vertices)
        if mirror:  # each polygon's corners in reverse order, so that outward stays outward
            starts = np.concatenate([[0], np.cumsum(self.face_sizes)[:-1]])
            order = np.concatenate([start + np.arange(n)[::-1] for start, n in zip(starts, self.face_sizes)]) \
                if len(starts) else np.zeros(0, dtype=np.int64)
            faces = faces[order]
        normals = None
        if self.normals is not None:  # normals take the inverse transpose: divided by the scale
            n = (np.asarray(self.normals) / s) @ R.T
            length = np.linalg.norm(n, axis=1, keepdims=True)
            normals = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        return SourceMesh(vertices=(np.asarray(self.vertices) * s) @ R.T + t, face_sizes=self.face_sizes,
                          face_vertices=faces, uv=self.uv, normals=normals, weld_map=self.weld_map,
                          materials=self.materials)

    def _rewelded(self, vertex_map: np.ndarray) -> "SourceMesh":
        """The same file's mesh after the welded mesh was cleaned again (vertex_map: its old
        vertices to the new, -1 dropped)."""
        kept = self.weld_map >= 0
        weld = np.full_like(self.weld_map, -1)
        weld[kept] = np.asarray(vertex_map)[self.weld_map[kept]]
        return SourceMesh(self.vertices, self.face_sizes, self.face_vertices, self.uv, self.normals, weld, self.materials)


def load_mesh(
    path: str | os.PathLike[str],
    *,
    weld: bool = True,
    weld_tolerance: float = 1e-6,
    timeout: float = 0.0,
    max_memory: int = 2 * 1024**3,
) -> Mesh:
    """Read every mesh in a file (any format Assimp reads: OBJ, glTF/GLB, FBX, DAE, PLY, STL, 3DS, OFF, ...).

    Node transforms are applied and polygons triangulated; coordinates are taken as metres. The
    file's own mesh (polygons, UVs, normals, materials and the weld map to the vertices csb
    simulates) is kept as ``mesh.source`` (a :class:`SourceMesh`, None for a file of mixed
    primitives), for writing results back onto it (:class:`csb.export.UsdWriter`).
    Vertices closer than ``weld_tolerance`` times the bounding-box diagonal are welded (UV and
    normal seams), degenerate triangles and unused vertices dropped; each is reported as a
    :class:`MeshWarning` and in ``mesh.report`` (a :class:`MeshReport`).

    Raises FileNotFoundError for a missing file and :class:`csb.MeshError`, naming the file (and
    the line, for OBJ and OFF), for an empty, corrupt or unsupported file or one without triangles
    (a point cloud says how many points it holds; motion capture, such as BVH, holds a skeleton and
    no surface), and for UTF-16 or UTF-32 text (naming the encoding, with or without a byte-order
    mark). A file without an extension is read by its content: Assimp recognises most formats so,
    and csb recognises the ones Assimp 5.2 knows by extension only (GLB, STL, X3D, 3MF).
    Assimp runs in a child process (on POSIX systems): a file on which it would crash or loop
    gives a MeshError after at most ``timeout`` seconds (0: 10 s + 2 s per MB of file), and one
    on which it would allocate more than ``max_memory`` bytes (default 2 GiB, beyond what this
    process already has mapped; enforced on Linux) a MeshError naming that limit. Both errors say
    how to raise the limit; a non-positive ``max_memory`` is a :class:`csb.ParameterError`.

    A file whose scene has animations or skinned meshes (glTF, FBX, Collada, ...) loads in its
    rest pose (the nodes' static transforms, no bone applied) with an :class:`AnimationWarning`
    naming the animations (and their durations, s) and the skinned meshes; :func:`csb.load_animation`
    reads the animation itself.
    """
    if isinstance(max_memory, bool) or not isinstance(max_memory, (int, float, np.integer, np.floating)):
        raise _core.ParameterError(f"max_memory must be a number of bytes > 0, got {max_memory!r}")
    mesh, report, animation, source = _core._load_mesh(os.fspath(path), weld=weld, weld_tolerance=weld_tolerance,
                                                       timeout=timeout, max_memory=float(max_memory))
    mesh.report = MeshReport._from_core(report)
    mesh.source = SourceMesh._from_core(source) if source is not None else None
    mesh.report._emit()
    message = _animation_message(os.fspath(path), animation)
    if message is not None:
        warn_mesh(message, AnimationWarning)
    return mesh


def clean(mesh: Mesh, *, weld: bool = True, weld_tolerance: float = 1e-6, drop_unreferenced: bool = True) -> Mesh:
    """Weld coincident vertices, drop degenerate triangles and (optionally) unused vertices.

    The result carries ``report`` (a :class:`MeshReport`, with ``vertex_map`` from input to
    output vertices); everything dropped is also reported as a :class:`MeshWarning`.
    """
    out, report = _core._clean(mesh, weld=weld, weld_tolerance=weld_tolerance, drop_unreferenced=drop_unreferenced)
    out.report = MeshReport._from_core(report)
    out.report._emit()
    source = getattr(mesh, "source", None)
    out.source = source._rewelded(out.report.vertex_map) if source is not None else None
    return out


def _rotation(angles: Sequence[float]) -> np.ndarray:
    """Rotation matrix for XYZ Euler angles in radians (about x first, then y, then z)."""
    rx, ry, rz = (float(a) for a in angles)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def transformed(
    mesh: Mesh | _core.TetMesh,
    *,
    scale: float | Sequence[float] = 1.0,
    rotate: Sequence[float] = (0.0, 0.0, 0.0),
    translate: Sequence[float] = (0.0, 0.0, 0.0),
) -> Mesh | _core.TetMesh:
    """A copy of ``mesh`` (a surface :class:`Mesh` or a :class:`csb.TetMesh`) scaled
    (dimensionless, per axis or uniform), then rotated (XYZ Euler angles, rad), then translated
    (m). The vertex numbering is unchanged. A mirroring scale (an odd number of negative factors)
    turns every triangle and tet inside out; their orientation is restored (two indices swapped)
    so that outward stays outward."""
    s = np.broadcast_to(np.asarray(scale, dtype=float), (3,))
    if not np.all(np.isfinite(s)) or np.any(s == 0):
        raise _core.ParameterError(f"{mesh.name}: scale must be finite and non-zero, got {scale!r}")
    r = np.asarray(rotate, dtype=float)
    t = np.asarray(translate, dtype=float)
    if r.shape != (3,) or not np.all(np.isfinite(r)):
        raise _core.ParameterError(f"{mesh.name}: rotate must be 3 finite angles in rad, got {rotate!r}")
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise _core.ParameterError(f"{mesh.name}: translate must be 3 finite numbers in m, got {translate!r}")
    mirror = bool(np.prod(np.sign(s)) < 0)
    if isinstance(mesh, _core.TetMesh):
        tets = np.array(mesh.tets)
        if mirror:
            tets[:, [2, 3]] = tets[:, [3, 2]]
        return _core.TetMesh((mesh.points * s) @ _rotation(r).T + t, tets, mesh.name)
    v = (mesh.vertices * s) @ _rotation(r).T + t
    tris = mesh.triangles if len(mesh.triangles) else None
    if tris is not None and mirror:
        tris = np.array(tris)[:, [0, 2, 1]]
    lines = mesh.lines if len(mesh.lines) else None
    out = Mesh(v, tris, lines, name=mesh.name)
    source = getattr(mesh, "source", None)
    out.source = source._transformed(s, _rotation(r), t, mirror) if source is not None else None
    return out


def icosphere(radius: float = 0.5, subdivisions: int = 2, center=(0.0, 0.0, 0.0)) -> Mesh:
    """A closed triangle sphere of ``radius`` (m): an icosahedron whose faces are split in four
    ``subdivisions`` times, vertices pushed onto the sphere, every triangle wound outwards."""
    if not radius > 0:
        raise _core.ParameterError(f"icosphere: radius must be > 0 m, got {radius}")
    # 10·4^s + 2 vertices and 20·4^s triangles: s = 13 is the last whose triangles an Index counts.
    if isinstance(subdivisions, bool) or not isinstance(subdivisions, (int, np.integer)) or not 0 <= subdivisions <= 13:
        raise _core.ParameterError(f"icosphere: subdivisions must be an integer in [0, 13], got {subdivisions!r}")
    t = (1 + 5**0.5) / 2
    v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
         [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    verts = [np.array(p, dtype=float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        midpoint: dict[tuple[int, int], int] = {}

        def mid(a: int, b: int) -> int:
            key = (min(a, b), max(a, b))
            if key not in midpoint:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                midpoint[key] = len(verts) - 1
            return midpoint[key]

        f = [g for a, b, c in f for g in ([a, mid(a, b), mid(c, a)], [b, mid(b, c), mid(a, b)],
                                          [c, mid(c, a), mid(b, c)], [mid(a, b), mid(b, c), mid(c, a)])]
    x = np.array(verts) * radius + np.asarray(center, dtype=float)
    tris = np.array(f, dtype=np.int32)
    if _core.kernels.enclosed_volume(x, tris) < 0:
        tris = tris[:, ::-1].copy()
    return Mesh(x, tris, name="icosphere")
