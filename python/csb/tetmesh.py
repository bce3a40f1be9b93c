"""Tetrahedral (volume) meshes: read with meshio, or generated (:func:`tet_box`)."""

from __future__ import annotations

import os

import numpy as np

from . import _core
from ._core import TetMesh, tet_box
from .mesh import warn_mesh

__all__ = ["TetMesh", "tet_box", "load_tet_mesh"]


def load_tet_mesh(path: str | os.PathLike[str]) -> TetMesh:
    """Read the tetrahedra of a volume mesh with meshio (Gmsh .msh 2.2/4.1, VTK .vtu/.vtk, Medit
    .mesh, Abaqus .inp, ... anything meshio reads that holds ``tetra`` cells).

    Every ``tetra`` block is kept, in file order; ``tetra10`` (quadratic) blocks are reduced to
    their corner nodes with a :class:`csb.MeshWarning`. Other cells (surface triangles, lines,
    points) are ignored, and points that no tet uses are dropped with a warning (they would be
    free-flying particles). Coordinates are taken as metres.

    Raises FileNotFoundError for a missing file, and :class:`csb.MeshError` naming the file for
    one meshio cannot read, one without tetrahedra, non-finite coordinates or out-of-range
    indices.
    """
    name = os.fspath(path)
    if not os.path.isfile(name):
        raise FileNotFoundError(f"{name}: no such file")
    import meshio  # only needed here; keeps `import csb` light

    try:
        m = meshio.read(name)
    except Exception as e:  # meshio raises many types (ReadError, ValueError, KeyError, ...) for bad files
        raise _core.MeshError(f"{name}: meshio could not read it as a mesh: {type(e).__name__}: {e}") from e
    points = np.asarray(m.points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise _core.MeshError(f"{name}: points must be 3-dimensional, got an array of shape {points.shape}")
    blocks = []
    for block in m.cells:
        data = np.asarray(block.data)
        if block.type == "tetra":
            blocks.append(data)
        elif block.type == "tetra10":
            warn_mesh(f"{name}: {len(data)} quadratic tets (tetra10) reduced to their 4 corner nodes")
            blocks.append(data[:, :4])
    if not blocks:
        found = ", ".join(f"{b.type} x {len(b.data)}" for b in m.cells) or "no cells"
        raise _core.MeshError(f"{name}: no tetrahedra (tetra cells) in the file (it holds {found})")
    tets = np.concatenate(blocks).astype(np.int64)
    if tets.size and (tets.min() < 0 or tets.max() >= len(points)):
        bad = int(np.argmax((tets < 0).any(axis=1) | (tets >= len(points)).any(axis=1)))
        raise _core.MeshError(
            f"{name}: tet {bad} uses point indices {tets[bad].tolist()}, out of range (the file has {len(points)} points)"
        )
    used = np.zeros(len(points), dtype=bool)
    used[tets.ravel()] = True
    if not used.all():
        # Renumber so that only the points the tets use become particles.
        new_index = np.cumsum(used) - 1
        warn_mesh(f"{name}: {int((~used).sum())} points that no tet uses were dropped")
        points = points[used]
        tets = new_index[tets]
    return TetMesh(points, tets, name=name)
