"""Choosing particles by where they are: regions of space (a box, a sphere, a half-space, a
distance to a line), boolean masks, index arrays and Python predicates of position, for pins,
attachments and anything else that takes particles.

A region is tested against a mesh's vertices as they were added to the model (metres, after the
scene's scale, rotation and translation)::

    cape = builder.add_mesh(mesh, ...)
    builder.pin(cape.select(csb.Box([-1, 1.9, -1], [1, 2.1, 1])))      # the collar
    builder.pin(cape.select(lambda x: x[:, 1] > 1.95))                 # the same, by a predicate

A selection that catches no particle is an error that says so, with where the mesh lies: a pin
that silently holds nothing is the commonest way a scene goes wrong.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence, Union

import numpy as np

from . import _core

__all__ = ["Region", "Box", "Sphere", "HalfSpace", "NearLine", "Material", "select_vertices"]


def _point(value: Any, name: str) -> np.ndarray:
    p = np.asarray(value, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise _core.ParameterError(f"{name} must be 3 finite coordinates in m, got {value!r}")
    return p


def _length(value: Any, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise _core.ParameterError(f"{name} must be a distance > 0 m, got {value!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise _core.ParameterError(f"{name} must be a distance > 0 m, got {value!r}")
    return v


class Region:
    """A part of space; ``contains(points)`` says which of the (N, 3) points (m) lie in it, its
    boundary included."""

    def contains(self, points: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def __or__(self, other: Region) -> Region:
        return _Union((self, other))


@dataclass(frozen=True, init=False)
class Box(Region):
    """The axis-aligned box lo <= x <= hi (m)."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    def __init__(self, lo: Sequence[float], hi: Sequence[float]):
        a, b = _point(lo, "Box: lo"), _point(hi, "Box: hi")
        if np.any(a > b):
            raise _core.ParameterError(f"Box: lo {a.tolist()} must not exceed hi {b.tolist()} on any axis (m)")
        object.__setattr__(self, "lo", tuple(a.tolist()))
        object.__setattr__(self, "hi", tuple(b.tolist()))

    def contains(self, points: np.ndarray) -> np.ndarray:
        return np.all((points >= self.lo) & (points <= self.hi), axis=1)


@dataclass(frozen=True, init=False)
class Sphere(Region):
    """The points within `radius` (m) of `center` (m): a distance to a point."""

    center: tuple[float, float, float]
    radius: float

    def __init__(self, center: Sequence[float], radius: float):
        object.__setattr__(self, "center", tuple(_point(center, "Sphere: center").tolist()))
        object.__setattr__(self, "radius", _length(radius, "Sphere: radius"))

    def contains(self, points: np.ndarray) -> np.ndarray:
        return np.sum((points - self.center) ** 2, axis=1) <= self.radius**2


@dataclass(frozen=True, init=False)
class HalfSpace(Region):
    """The points on the side of the plane through `point` (m) that `normal` points to:
    (x - point)·normal >= 0."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]

    def __init__(self, point: Sequence[float], normal: Sequence[float]):
        n = _point(normal, "HalfSpace: normal")
        length = float(np.linalg.norm(n))
        if not length > 0:
            raise _core.ParameterError("HalfSpace: normal must not be zero")
        object.__setattr__(self, "point", tuple(_point(point, "HalfSpace: point").tolist()))
        object.__setattr__(self, "normal", tuple((n / length).tolist()))

    def contains(self, points: np.ndarray) -> np.ndarray:
        return (points - self.point) @ np.asarray(self.normal) >= 0


@dataclass(frozen=True, init=False)
class NearLine(Region):
    """The points within `distance` (m) of the line through `a` and `b` (m), or of the segment
    from a to b with ``segment=True`` (a capsule)."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    distance: float
    segment: bool = False

    def __init__(self, a: Sequence[float], b: Sequence[float], distance: float, *, segment: bool = False):
        pa, pb = _point(a, "NearLine: a"), _point(b, "NearLine: b")
        if not np.linalg.norm(pb - pa) > 0:
            raise _core.ParameterError(f"NearLine: a and b must differ, both are {pa.tolist()}")
        object.__setattr__(self, "a", tuple(pa.tolist()))
        object.__setattr__(self, "b", tuple(pb.tolist()))
        object.__setattr__(self, "distance", _length(distance, "NearLine: distance"))
        object.__setattr__(self, "segment", bool(segment))

    def contains(self, points: np.ndarray) -> np.ndarray:
        a, d = np.asarray(self.a), np.asarray(self.b) - np.asarray(self.a)
        s = (points - a) @ d / (d @ d)
        if self.segment:
            s = np.clip(s, 0.0, 1.0)
        return np.sum((points - a - s[:, None] * d) ** 2, axis=1) <= self.distance**2


@dataclass(frozen=True)
class _Union(Region):
    parts: tuple[Region, ...]

    def contains(self, points: np.ndarray) -> np.ndarray:
        out = np.zeros(len(points), dtype=bool)
        for r in self.parts:
            out |= r.contains(points)
        return out

    def __repr__(self) -> str:
        return " | ".join(repr(r) for r in self.parts)


@dataclass(frozen=True)
class Material:
    """The vertices of the file's meshes whose material is `name` (as the file names it: an OBJ's
    ``usemtl``, a glTF, FBX or Collada material), through the file's own mesh that
    :func:`csb.load_mesh` keeps; a vertex welded across two materials belongs to both. Assimp
    exposes no vertex groups for these formats, so materials are how a file marks a part."""

    name: str


Selector = Union[Material, Region, Callable[[np.ndarray], Any], Sequence[int], Sequence[bool], np.ndarray]


def select_vertices(vertices: np.ndarray, what: Selector, *, label: str = "the mesh") -> np.ndarray:
    """The indices (ascending, into `vertices`, (N, 3) m) of the vertices `what` chooses:
    - a Region (Box, Sphere, HalfSpace, NearLine, or several joined with ``|``);
    - a callable f(points) of the (N, 3) positions returning N booleans (one call for all
      vertices: write it with numpy, ``lambda x: x[:, 1] > 1.9``);
    - a boolean mask of N entries;
    - an array of vertex indices (each in [0, N), kept once, in ascending order).
    ParameterError, naming `label`, for anything else, a mask or result of the wrong length, an
    index out of range, and a selection that catches no vertex."""
    v = np.asarray(vertices, dtype=float)
    n = len(v)
    if isinstance(what, Region) or callable(what):
        if isinstance(what, Region):
            mask = what.contains(v)
            name = repr(what)
        else:
            mask = np.asarray(what(v.copy()))  # a copy: the predicate cannot alter the mesh
            name = f"the predicate {getattr(what, '__name__', type(what).__name__)}"
            if mask.shape != (n,) or mask.dtype != bool:
                raise _core.ParameterError(
                    f"{name} must return {n} booleans for the {n} vertices of {label} (called once with "
                    f"their (N, 3) positions), got an array of shape {mask.shape} and type {mask.dtype}")
        chosen = np.flatnonzero(mask)
    else:
        arr = np.asarray(what)
        if arr.dtype == bool:
            name = "the mask"
            if arr.shape != (n,):
                raise _core.ParameterError(f"a mask must have one entry per vertex of {label} ({n}), got shape {arr.shape}")
            chosen = np.flatnonzero(arr)
        elif arr.ndim == 1 and (arr.size == 0 or np.issubdtype(arr.dtype, np.integer)):
            name = "the index array"
            bad = arr[(arr < 0) | (arr >= n)]
            if bad.size:
                raise _core.ParameterError(f"vertex {int(bad[0])} is out of range: {label} has {n} vertices")
            chosen = np.unique(arr.astype(np.int64))
        else:
            raise _core.ParameterError(
                f"cannot select vertices of {label} with {what!r}: give a Region (Box, Sphere, HalfSpace, "
                "NearLine), a callable of the (N, 3) positions, a boolean mask or an array of vertex indices")
    if chosen.size == 0:
        lo, hi = (v.min(axis=0), v.max(axis=0)) if n else (np.zeros(3), np.zeros(3))
        raise _core.ParameterError(
            f"{name} caught 0 of the {n} vertices of {label}, which spans {np.round(lo, 6).tolist()} to "
            f"{np.round(hi, 6).tolist()} m (positions as added: after scale, rotation and translation)")
    return chosen
