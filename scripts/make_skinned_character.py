#!/usr/bin/env python3
"""Writes python/csb/scenes/meshes/waving_character.gltf, the skinned body of the bundled
cape_skinned scene: a low-poly torso and a right arm, three joints, a 3 s animation.

The body (m, y up, facing +z) is two closed surfaces: a torso, an octagonal prism of elliptic
section (half-widths 0.13-0.17 m by 0.09-0.13 m) from the hips (y = 0.75) to the shoulders (1.38), closed by a vertex
below and one above; and an arm, a hexagonal prism of radius 0.05 m along +x at the shoulder's
height (1.30) from inside the torso (x = 0.08) to the hand (0.62), closed at both ends. Joints:
"hips" at the origin, walking along +z at 0.4 m/s; "spine" at y = 1.0 under it, bowing forward
(about x) by 0.15 (1 - cos(2π t / 1.5)) rad, then swaying about the vertical by
0.2 sin(2π t / 1.5) rad, so that the hips push into a cape hung from the shoulders; "shoulder" at (0.17, 1.30, 0) under the spine, the arm
raised and waving about z by 1.2 + 0.5 sin(2π t) rad. The torso's rings below y = 0.9 follow the
hips, the ring at 0.95 both (0.5, 0.5), those above the spine; the arm's rings inside the torso
follow the spine, the ring at x = 0.2 the spine and the shoulder equally, the rest the shoulder
(linear blend skinning). Keys every 0.1 s (glTF LINEAR: positions linearly, rotations by slerp).
Needs numpy only. Run it again only to change the asset; the file is committed.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from csb.export import GltfBuilder

TORSO_RINGS = [(0.75, 0.15, 0.10), (0.95, 0.16, 0.11), (1.15, 0.17, 0.13), (1.30, 0.17, 0.12), (1.38, 0.13, 0.09)]
# (y, half-width in x, half-depth in z) of each ring, m: the chest deeper than the hips
TORSO_SIDES = 8
TORSO_BOTTOM, TORSO_TOP = 0.72, 1.44  # m, the closing vertices
ARM_Y, ARM_RADIUS, ARM_SIDES = 1.30, 0.05, 6
ARM_RINGS = [0.08, 0.20, 0.32, 0.47, 0.62]  # m, x of each ring
SHOULDER = np.array([0.17, 1.30, 0.0])
SPINE = np.array([0.0, 1.0, 0.0])
DURATION, KEY_STEP = 3.0, 0.1        # s
WALK = 0.4                            # m/s along +z


def closed_prism(rings: list[np.ndarray], first_cap: np.ndarray, last_cap: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward-wound triangles of a closed tube: rings of n vertices (in order round
    the tube) joined by quads, closed by a fan to a cap vertex at each end; wound so that the
    enclosed signed volume is positive."""
    n = len(rings[0])
    v = np.concatenate(rings + [first_cap[None], last_cap[None]])
    a_cap, b_cap = len(v) - 2, len(v) - 1
    tris = []
    for r in range(len(rings) - 1):
        for k in range(n):
            a, b = r * n + k, r * n + (k + 1) % n
            tris += [[a, b + n, b], [a, a + n, b + n]]
    last = (len(rings) - 1) * n
    for k in range(n):
        tris += [[a_cap, k, (k + 1) % n], [b_cap, last + (k + 1) % n, last + k]]
    t = np.array(tris)
    p = v[t]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
    return v, (t if volume > 0 else t[:, [0, 2, 1]])


def body() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, triangles (outward) and per-vertex weights on (hips, spine, shoulder)."""
    angles = 2 * np.pi * np.arange(TORSO_SIDES) / TORSO_SIDES
    torso_rings = [np.stack([rx * np.cos(angles), np.full(TORSO_SIDES, y), rz * np.sin(angles)], 1)
                   for y, rx, rz in TORSO_RINGS]
    tv, tt = closed_prism(torso_rings, np.array([0.0, TORSO_BOTTOM, 0.0]), np.array([0.0, TORSO_TOP, 0.0]))
    tw = np.zeros((len(tv), 3))
    for i, y in enumerate(tv[:, 1]):
        tw[i] = [1, 0, 0] if y < 0.9 else ([0.5, 0.5, 0] if y < 1.0 else [0, 1, 0])
    a = 2 * np.pi * np.arange(ARM_SIDES) / ARM_SIDES
    arm_rings = [np.stack([np.full(ARM_SIDES, x), ARM_Y + ARM_RADIUS * np.cos(a), ARM_RADIUS * np.sin(a)], 1)
                 for x in ARM_RINGS]
    av, at = closed_prism(arm_rings, np.array([ARM_RINGS[0] - 0.03, ARM_Y, 0.0]),
                          np.array([ARM_RINGS[-1] + 0.04, ARM_Y, 0.0]))
    aw = np.zeros((len(av), 3))
    for i, x in enumerate(av[:, 0]):
        aw[i] = [0, 1, 0] if x < 0.15 else ([0, 0.5, 0.5] if x < 0.25 else [0, 0, 1])
    v = np.concatenate([tv, av])
    t = np.concatenate([tt, at + len(tv)])
    return v, t, np.concatenate([tw, aw])


def quat(axis: str, angle: float) -> list[float]:
    """glTF quaternion (x, y, z, w) of a turn of `angle` rad about a coordinate axis."""
    q = [0.0, 0.0, 0.0, math.cos(angle / 2)]
    q["xyz".index(axis)] = math.sin(angle / 2)
    return q


def qmul(a: list[float], b: list[float]) -> list[float]:
    """Hamilton product of (x, y, z, w) quaternions: the turn b, then a."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]


def main() -> None:
    v, t, w = body()
    g = GltfBuilder()
    pos = g.accessor(v, "VEC3")
    idx = g.accessor(t.ravel(), "SCALAR", np.uint32)
    joints = g.accessor([[0, 1, 2, 0]] * len(v), "VEC4", np.uint16)
    weights = g.accessor(np.concatenate([w, np.zeros((len(v), 1))], 1), "VEC4")
    # Inverse bind matrices (column-major): each joint's bind pose is a translation to where it is.
    ibm = []
    for at in (np.zeros(3), SPINE, SHOULDER):
        m = np.eye(4)
        m[:3, 3] = -at
        ibm.append(m.T.reshape(16))
    ibm_acc = g.accessor(ibm, "MAT4")
    times = np.round(np.arange(0.0, DURATION + KEY_STEP / 2, KEY_STEP), 10)
    keys = g.accessor(times, "SCALAR")
    walk = g.accessor([[0.0, 0.0, WALK * s] for s in times], "VEC3")
    sway = g.accessor([qmul(quat("y", 0.2 * math.sin(2 * math.pi * s / 1.5)),
                            quat("x", 0.15 * (1 - math.cos(2 * math.pi * s / 1.5)))) for s in times], "VEC4")
    wave = g.accessor([quat("z", 1.2 + 0.5 * math.sin(2 * math.pi * s)) for s in times], "VEC4")
    document = {
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"name": "body", "mesh": 0, "skin": 0},
                  {"name": "hips", "children": [2]},
                  {"name": "spine", "translation": SPINE.tolist(), "children": [3]},
                  {"name": "shoulder", "translation": (SHOULDER - SPINE).tolist()}],
        "meshes": [{"name": "body", "primitives": [{"attributes": {"POSITION": pos, "JOINTS_0": joints,
                                                                   "WEIGHTS_0": weights}, "indices": idx}]}],
        "skins": [{"joints": [1, 2, 3], "inverseBindMatrices": ibm_acc, "skeleton": 1}],
        "animations": [{"name": "walk_wave", "samplers": [
            {"input": keys, "output": walk, "interpolation": "LINEAR"},
            {"input": keys, "output": sway, "interpolation": "LINEAR"},
            {"input": keys, "output": wave, "interpolation": "LINEAR"}],
            "channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}},
                         {"sampler": 1, "target": {"node": 2, "path": "rotation"}},
                         {"sampler": 2, "target": {"node": 3, "path": "rotation"}}]}],
    }
    out = g.write(Path(__file__).resolve().parents[1] / "python/csb/scenes/meshes/waving_character.gltf", document)
    print(f"{out}: {len(v)} vertices, {len(t)} triangles, {len(times)} keys over {DURATION} s")


if __name__ == "__main__":
    main()
