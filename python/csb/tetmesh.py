"""Tetrahedral (volume) meshes: read with meshio, or generated (:func:`tet_box`)."""

from __future__ import annotations

import os
import sys

import numpy as np

from . import _core
from ._core import TetMesh, tet_box
from .mesh import warn_mesh

__all__ = ["TetMesh", "tet_box", "load_tet_mesh"]


DEFAULT_MAX_MEMORY = 2 * 1024**3
"""bytes: the memory meshio may allocate while reading one file (2 GiB)"""
DEFAULT_TIMEOUT = 60.0
"""s: how long meshio may take to read one file"""

_CHILD = os.path.join(os.path.dirname(os.path.abspath(__file__)), "_meshio_child.py")
_LOG_TAIL = 2000  # characters of meshio's own messages quoted in an error


def _positive(name: str, value: object, what: str) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        v = float("nan")
    if isinstance(value, bool) or not (np.isfinite(v) and v > 0):
        raise _core.ParameterError(f"{name} must be a finite number > 0 ({what}), got {value!r}")
    return v


def _meshio_said(log: str) -> str:
    """meshio's own messages (it prints why each reader refused the file), on one line."""
    try:
        with open(log, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - _LOG_TAIL))
            text = f.read().decode("utf-8", "replace")
    except OSError:
        return ""
    return " ".join(text.split())


def _read_in_child(name: str, max_memory: int, timeout: float) -> tuple[np.ndarray, np.ndarray, int, list[str]]:
    """Run meshio on ``name`` in a child process capped at ``max_memory`` bytes and ``timeout``
    seconds; its arrays come back as .npy files, its prints go to a file of ours."""
    import json
    import subprocess
    import tempfile

    raise_memory = "pass a larger max_memory= (bytes) to load_tet_mesh if the file really is that large"
    with tempfile.TemporaryDirectory(prefix="csb-meshio-") as out:
        log = os.path.join(out, "meshio.log")
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
        args = [sys.executable, "-I", _CHILD, json.dumps(sys.path), os.path.abspath(name), out, str(max_memory)]
        with open(log, "wb") as sink:
            try:
                done = subprocess.run(args, stdin=subprocess.DEVNULL, stdout=sink, stderr=sink, env=env,
                                      timeout=timeout, check=False)
            except subprocess.TimeoutExpired:
                raise _core.MeshError(
                    f"{name}: reading the file took longer than the timeout of {timeout:g} s and was stopped; the file "
                    "is probably corrupt (pass a larger timeout= (s) to load_tet_mesh if it really is that slow to read)") from None
        said = _meshio_said(log)
        try:
            with open(os.path.join(out, "result.json")) as f:
                result = json.load(f)
        except (OSError, ValueError):
            if done.returncode < 0:
                raise _core.MeshError(
                    f"{name}: the reading process was killed by signal {-done.returncode}, probably on reaching the "
                    f"max_memory limit of {max_memory} bytes; the file is probably corrupt ({raise_memory})"
                    + (f" (meshio: {said})" if said else "")) from None
            raise _core.MeshError(f"{name}: the reading process ended (exit status {done.returncode}) without a "
                                  "result" + (f" (meshio: {said})" if said else "")) from None
        if result["status"] == "memory":
            raise _core.MeshError(
                f"{name}: reading the file needed more than the max_memory limit of {max_memory} bytes and was "
                f"stopped; the file is probably corrupt ({raise_memory})")
        if result["status"] != "ok":
            raise _core.MeshError(f"{name}: {result['error']}" + (f" (meshio: {said})" if said else ""))
        arrays = []
        for part, dtype in (("points", np.float64), ("tets", np.int64)):
            path = os.path.join(out, f"{part}.npy")
            size = os.path.getsize(path)
            if size > max_memory:  # the parent holds no more than the child was allowed
                raise _core.MeshError(f"{name}: its {part} take {size} bytes, more than the max_memory limit of "
                                      f"{max_memory} bytes ({raise_memory})")
            a = np.load(path, allow_pickle=False)
            if a.dtype != dtype:
                raise _core.MeshError(f"{name}: the reading process sent {part} of type {a.dtype}")
            arrays.append(a)
        return arrays[0], arrays[1], int(result["tetra10"]), list(result["found"])


def load_tet_mesh(
    path: str | os.PathLike[str], *, max_memory: int = DEFAULT_MAX_MEMORY, timeout: float = DEFAULT_TIMEOUT
) -> TetMesh:
    """Read the tetrahedra of a volume mesh with meshio (Gmsh .msh 2.2/4.1, VTK .vtu/.vtk, Medit
    .mesh, Abaqus .inp, ... anything meshio reads that holds ``tetra`` cells).

    Every ``tetra`` block is kept, in file order; ``tetra10`` (quadratic) blocks are reduced to
    their corner nodes with a :class:`csb.MeshWarning`. Other cells (surface triangles, lines,
    points) are ignored, and points that no tet uses are dropped with a warning (they would be
    free-flying particles). Coordinates are taken as metres.

    meshio runs in a child process, so that a hostile file costs only that process: it may
    allocate at most ``max_memory`` bytes (default 2 GiB; on POSIX systems, beyond the ~0.1 GB
    that Python, numpy and meshio take) and run at most ``timeout`` seconds (default 60 s).
    meshio's own messages never reach the terminal; they are quoted in the error.

    Raises FileNotFoundError for a missing file, :class:`csb.ParameterError` for a non-positive
    ``max_memory`` or ``timeout``, and :class:`csb.MeshError` naming the file for one meshio
    cannot read, one that hits either limit (the message says which, and how to raise it), one
    without tetrahedra, non-finite coordinates or out-of-range indices.
    """
    name = os.fspath(path)
    max_memory = int(_positive("max_memory", max_memory, "bytes"))
    timeout = _positive("timeout", timeout, "s")
    if not os.path.isfile(name):
        raise FileNotFoundError(f"{name}: no such file")
    points, tets, tetra10, found = _read_in_child(name, max_memory, timeout)
    if points.ndim != 2 or points.shape[1] != 3:
        raise _core.MeshError(f"{name}: points must be 3-dimensional, got an array of shape {points.shape}")
    if tetra10:
        warn_mesh(f"{name}: {tetra10} quadratic tets (tetra10) reduced to their 4 corner nodes")
    if len(tets) == 0:
        raise _core.MeshError(f"{name}: no tetrahedra (tetra cells) in the file (it holds {', '.join(found) or 'no cells'})")
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
