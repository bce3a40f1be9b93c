"""Animated mesh files (glTF, FBX, Collada, ... through Assimp): every mesh's vertices at given
times, from the file's node animations (keys interpolated linearly, rotations by slerp) and skins
(linear blend skinning), and, for a mesh its nodes move rigidly, keyframes that drive a collider;
a skinned mesh's vertices drive a deforming collider (PbdStepper.deform_collider)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _core

__all__ = ["Animation", "AnimatedMesh", "RigidKeyframes", "load_animation"]


def _rotation_vectors(matrices: np.ndarray) -> np.ndarray:
    """Rotation vectors (rad, axis times angle) of rotation matrices, each chosen among its
    equivalents (the angle plus a multiple of 2π) nearest the previous one, so that a turning
    collider's keyframes do not jump from π to -π."""
    out = np.zeros((len(matrices), 3))
    for k, r in enumerate(matrices):
        # Quaternion of R (Shepperd 1978: from the largest of w², x², y², z² for accuracy).
        t = np.trace(r)
        d = np.array([t, r[0, 0], r[1, 1], r[2, 2]])
        i = int(np.argmax(d))
        if i == 0:
            w = math.sqrt(1 + t) / 2
            q = np.array([w, (r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w)])
        else:
            j, l = (i % 3) + 1, ((i + 1) % 3) + 1  # the other two axes, cyclically (1-based in q)
            a, b, c = i - 1, j - 1, l - 1
            s = math.sqrt(1 + r[a, a] - r[b, b] - r[c, c]) / 2
            q = np.zeros(4)
            q[i] = s
            q[0] = (r[c, b] - r[b, c]) / (4 * s)
            q[j] = (r[b, a] + r[a, b]) / (4 * s)
            q[l] = (r[c, a] + r[a, c]) / (4 * s)
        if q[0] < 0:
            q = -q
        sin_half = float(np.linalg.norm(q[1:]))
        if sin_half == 0.0:
            v = np.zeros(3)
        else:
            axis = q[1:] / sin_half
            angle = 2 * math.atan2(sin_half, q[0])  # in [0, π]
            v = axis * angle
            if k > 0:
                candidates = [axis * (angle + 2 * math.pi * m) for m in (-1, 0, 1)]
                v = min(candidates, key=lambda c: float(np.linalg.norm(c - out[k - 1])))
        out[k] = v
    return out


@dataclass(frozen=True)
class RigidKeyframes:
    """The rigid motion of a mesh its nodes move without deforming it: at ``times[k]`` (s) the
    mesh as :func:`csb.load_mesh` reads it (the rest pose) is at x = R_k x_rest + translation[k],
    R_k = ``matrices[k]``, the rotation whose rotation vector is ``rotation[k]``. These are what
    ``PbdStepper.move_collider(model, collider, R, translation)`` takes and what a scene file's
    ``motion = { times, translation, rotation }`` holds (:meth:`motion`). Between keyframes a
    motion table interpolates translation linearly and rotation by slerp: that is the file's own
    interpolation only where one node is animated, about its own origin, with its keys at these
    times; sample more times (``load_animation(path, times=...)``) to follow the file closer."""

    times: np.ndarray        # (T,) s
    translation: np.ndarray  # (T, 3) m
    rotation: np.ndarray     # (T, 3) rad, rotation vectors, each nearest the previous one
    matrices: np.ndarray     # (T, 3, 3) rotation matrices

    def motion(self) -> dict[str, list]:
        """The keyframes as a scene file's ``motion`` table: {"times", "translation", "rotation"}."""
        return {"times": self.times.tolist(), "translation": self.translation.tolist(),
                "rotation": self.rotation.tolist()}


@dataclass(frozen=True)
class AnimatedMesh:
    """One placement of a triangle mesh of the file, evaluated at the animation's times."""

    name: str                 # the mesh's name in the file, else its node's
    node: str                 # the node that places it
    vertices: np.ndarray      # (T, V, 3) m: the file's vertices (not welded) at each time
    triangles: np.ndarray     # (F, 3) indices into the V vertices
    skinned: bool             # bones deform it (linear blend skinning)
    keyframes: RigidKeyframes | None  # its rigid motion from the rest pose; None if it deforms


@dataclass(frozen=True)
class Animation:
    """An animation of a file, evaluated at ``times``."""

    path: str
    name: str                          # as the file names it
    duration: float                    # s
    times: np.ndarray                  # (T,) s
    meshes: tuple[AnimatedMesh, ...]

    def mesh(self, name: str) -> AnimatedMesh:
        """The first mesh named ``name`` (or placed by the node ``name``)."""
        for m in self.meshes:
            if name in (m.name, m.node):
                return m
        raise _core.ParameterError(f"{self.path}: no mesh or node named {name!r} (the animation moves: "
                                   f"{', '.join(repr(m.name) for m in self.meshes) or 'no mesh'})")


def load_animation(
    path: str | os.PathLike[str],
    times: Any = None,
    *,
    animation: int | str = 0,
    timeout: float = 0.0,
    max_memory: int = 2 * 1024**3,
) -> Animation:
    """Read an animation of a file (glTF/GLB, FBX, Collada, ... any format Assimp reads) and
    evaluate every triangle mesh of it at ``times`` (s).

    ``animation`` is the animation's index in the file or its name (default: the first).
    ``times`` (s) default to the times of its keys, or to 30 per second of its duration (and the
    duration itself) where it has fewer than two. A time outside [0, duration] is an error, not
    clamped (before its first key and after its last the file holds the pose, which the caller can
    ask for at 0 or at ``duration``), and so is a time that is not finite.

    Node animations interpolate their keys as Assimp reads them: translation and scaling
    linearly, rotation by quaternion slerp along the shorter arc (Assimp 5.2 keeps no
    interpolation mode: a glTF STEP or CUBICSPLINE sampler arrives as its key values, interpolated
    so); a skinned mesh follows its bones
    by linear blend skinning, x = Σ w_b G_b(t) O_b x_bind / Σ w_b (G_b the bone's node transform at
    t, O_b its offset, or inverse bind, matrix). Vertices are in metres in the frame
    :func:`csb.load_mesh` reads (the nodes' transforms applied, the file's unit scale among them),
    one array per placement of a mesh, not welded. A mesh its nodes move rigidly carries
    :class:`RigidKeyframes` for ``PbdStepper.move_collider`` or a scene's collider ``motion``; a
    skinned (deforming) mesh's vertices drive a deforming collider, ``PbdStepper.deform_collider``
    (in the collider's vertex order: the model welds the file's split vertices), which a scene's
    ``[[collider]] type = "mesh"`` with ``animation = true`` does by itself.

    Raises FileNotFoundError and :class:`csb.MeshError` as :func:`csb.load_mesh` does, and
    :class:`csb.ParameterError` for a file without animation, an unknown animation, and bad times.
    """
    p = os.fspath(path)
    if isinstance(animation, bool) or not isinstance(animation, (int, np.integer, str)):
        raise _core.ParameterError(f"{p}: animation must be an index or a name, got {animation!r}")
    if times is not None:
        try:
            times = np.atleast_1d(np.asarray(times, dtype=float))
        except (TypeError, ValueError):
            raise _core.ParameterError(f"{p}: times must be a sequence of times (s), got {times!r}") from None
        if times.ndim != 1 or len(times) == 0:
            raise _core.ParameterError(f"{p}: times must be a non-empty 1-D sequence of times (s), got shape {times.shape}")
    if isinstance(max_memory, bool) or not isinstance(max_memory, (int, float, np.integer, np.floating)):
        raise _core.ParameterError(f"max_memory must be a number of bytes > 0, got {max_memory!r}")
    by_name = isinstance(animation, str)
    d = _core._load_animation(p, times, animation=0 if by_name else int(animation),
                              animation_name=animation if by_name else "", timeout=timeout,
                              max_memory=float(max_memory))
    t = np.asarray(d["times"])
    meshes = []
    for m in d["meshes"]:
        keyframes = None
        if m["rigid"]:
            keyframes = RigidKeyframes(times=t.copy(), translation=np.asarray(m["translation"]),
                                       rotation=_rotation_vectors(np.asarray(m["rotation"])),
                                       matrices=np.asarray(m["rotation"]))
        meshes.append(AnimatedMesh(name=m["name"], node=m["node"], vertices=np.asarray(m["vertices"]),
                                   triangles=np.asarray(m["triangles"]), skinned=bool(m["skinned"]),
                                   keyframes=keyframes))
    return Animation(path=p, name=d["name"], duration=float(d["duration"]), times=t, meshes=tuple(meshes))
