"""Animated mesh files (glTF node animations and skins, Collada): load_mesh loads the rest pose and
says so with a csb.AnimationWarning; csb.load_animation reads the animation."""

from __future__ import annotations

import base64
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import csb

HERE = Path(__file__).resolve()


class Gltf:
    """A glTF 2.0 JSON file with its one buffer embedded as base64, built accessor by accessor."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def accessor(self, array, kind: str, dtype=np.float32) -> int:
        a = np.ascontiguousarray(np.asarray(array, dtype=dtype))
        component = {np.float32: 5126, np.uint32: 5125, np.uint16: 5123, np.uint8: 5121}[a.dtype.type]
        while len(self.blob) % 4:
            self.blob.append(0)
        self.views.append({"buffer": 0, "byteOffset": len(self.blob), "byteLength": a.nbytes})
        self.blob += a.tobytes()
        acc = {"bufferView": len(self.views) - 1, "componentType": component, "count": len(a), "type": kind}
        if kind in ("SCALAR", "VEC3") and a.dtype == np.float32:  # glTF requires bounds on positions and times
            flat = a.reshape(len(a), -1)
            acc["min"], acc["max"] = flat.min(0).tolist(), flat.max(0).tolist()
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def write(self, path: Path, document: dict) -> Path:
        document = dict(document, asset={"version": "2.0"}, scene=0, bufferViews=self.views,
                        accessors=self.accessors,
                        buffers=[{"byteLength": len(self.blob), "uri": "data:application/octet-stream;base64,"
                                  + base64.b64encode(bytes(self.blob)).decode()}])
        path.write_text(json.dumps(document))
        return path


def quat_z(angle: float) -> list[float]:
    """glTF quaternion (x, y, z, w) of a turn of `angle` rad about z."""
    return [0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)]


def quat_x(angle: float) -> list[float]:
    return [math.sin(angle / 2), 0.0, 0.0, math.cos(angle / 2)]


def qmul(a, b) -> list[float]:
    """Hamilton product of (x, y, z, w) quaternions: the turn b, then a."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]


# The rigid file: one triangle whose node rests at REST_TRANSLATION and is animated by translation
# keys (linear) and rotation keys (slerp): a quarter turn about z, then a third of a turn more
# about the turned x axis, so that the second arc is about no coordinate axis.
TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
REST_TRANSLATION = np.array([0.0, 0.0, 0.5])
T_TIMES, T_VALUES = [0.0, 1.0, 2.0], [[0, 0, 0], [1, 0, 0], [1, 2, 0]]
R_TIMES = [0.0, 1.0, 2.0]
R_VALUES = [[0.0, 0.0, 0.0, 1.0], quat_z(math.pi / 2), qmul(quat_z(math.pi / 2), quat_x(math.pi / 3))]


@pytest.fixture
def rigid_gltf(tmp_path) -> Path:
    g = Gltf()
    pos = g.accessor(TRIANGLE, "VEC3")
    idx = g.accessor([0, 1, 2], "SCALAR", np.uint32)
    tt, tv = g.accessor(T_TIMES, "SCALAR"), g.accessor(T_VALUES, "VEC3")
    rt, rv = g.accessor(R_TIMES, "SCALAR"), g.accessor(R_VALUES, "VEC4")
    return g.write(tmp_path / "rigid.gltf", {
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "plate", "mesh": 0, "translation": REST_TRANSLATION.tolist()}],
        "meshes": [{"name": "plate", "primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}],
        "animations": [{"name": "slide", "samplers": [
            {"input": tt, "output": tv, "interpolation": "LINEAR"},
            {"input": rt, "output": rv, "interpolation": "LINEAR"}],
            "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}},
                         {"sampler": 1, "target": {"node": 0, "path": "rotation"}}]}],
    })


# The skinned file: a column of three rings of four vertices at y = 0, 1, 2 (triangles between
# them), two joints: "root" at the origin, "tip" at y = 1 under it. The bottom ring follows root
# alone (weight 1), the top ring tip alone, the middle ring both (0.5, 0.5). Root slides along x,
# tip turns a quarter turn about z.
RING = np.array([[-0.2, 0, -0.2], [0.2, 0, -0.2], [0.2, 0, 0.2], [-0.2, 0, 0.2]])
COLUMN = np.concatenate([RING + [0, y, 0] for y in (0.0, 1.0, 2.0)])
WEIGHTS = np.array([[1, 0]] * 4 + [[0.5, 0.5]] * 4 + [[0, 1]] * 4, float)
ROOT_TIMES, ROOT_VALUES = [0.0, 1.5], [[0, 0, 0], [3, 0, 0]]
TIP_TIMES, TIP_VALUES = [0.0, 1.5], [[0, 0, 0, 1], quat_z(math.pi / 2)]
TIP_OFFSET = np.array([0.0, 1.0, 0.0])


def _column_triangles() -> np.ndarray:
    tris = []
    for layer in (0, 1):
        for k in range(4):
            a, b = 4 * layer + k, 4 * layer + (k + 1) % 4
            tris += [[a, b, b + 4], [a, b + 4, a + 4]]
    return np.array(tris)


@pytest.fixture
def skinned_gltf(tmp_path) -> Path:
    g = Gltf()
    pos = g.accessor(COLUMN, "VEC3")
    idx = g.accessor(_column_triangles().ravel(), "SCALAR", np.uint32)
    joints = g.accessor([[0, 1, 0, 0]] * 12, "VEC4", np.uint16)
    weights = g.accessor(np.concatenate([WEIGHTS, np.zeros((12, 2))], 1), "VEC4")
    # Inverse bind matrices (column-major): root's bind pose is the identity, tip's a shift by +1 in y.
    ibm = g.accessor(np.stack([np.eye(4), np.array([[1, 0, 0, 0], [0, 1, 0, -1], [0, 0, 1, 0], [0, 0, 0, 1]])])
                     .transpose(0, 2, 1).reshape(2, 16), "MAT4")
    rt, rv = g.accessor(ROOT_TIMES, "SCALAR"), g.accessor(ROOT_VALUES, "VEC3")
    tt, tv = g.accessor(TIP_TIMES, "SCALAR"), g.accessor(TIP_VALUES, "VEC4")
    return g.write(tmp_path / "skinned.gltf", {
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"name": "body", "mesh": 0, "skin": 0},
                  {"name": "root", "children": [2]},
                  {"name": "tip", "translation": TIP_OFFSET.tolist()}],
        "meshes": [{"name": "column", "primitives": [{"attributes": {"POSITION": pos, "JOINTS_0": joints,
                                                                     "WEIGHTS_0": weights}, "indices": idx}]}],
        "skins": [{"joints": [1, 2], "inverseBindMatrices": ibm, "skeleton": 1}],
        "animations": [{"name": "bend", "samplers": [
            {"input": rt, "output": rv, "interpolation": "LINEAR"},
            {"input": tt, "output": tv, "interpolation": "LINEAR"}],
            "channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}},
                         {"sampler": 1, "target": {"node": 2, "path": "rotation"}}]}],
    })


COLLADA = """<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="meter" meter="1"/><up_axis>Y_UP</up_axis></asset>
  <library_geometries>
    <geometry id="tri" name="tri"><mesh>
      <source id="tri-pos"><float_array id="tri-pos-array" count="9">0 0 0 1 0 0 0 1 0</float_array>
        <technique_common><accessor source="#tri-pos-array" count="3" stride="3">
          <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
        </accessor></technique_common></source>
      <vertices id="tri-vtx"><input semantic="POSITION" source="#tri-pos"/></vertices>
      <triangles count="1"><input semantic="VERTEX" source="#tri-vtx" offset="0"/><p>0 1 2</p></triangles>
    </mesh></geometry>
  </library_geometries>
  <library_animations>
    <animation id="lift">
      <source id="lift-in"><float_array id="lift-in-array" count="2">0 4</float_array>
        <technique_common><accessor source="#lift-in-array" count="2"><param name="TIME" type="float"/></accessor>
        </technique_common></source>
      <source id="lift-out"><float_array id="lift-out-array" count="6">0 0 0 0 2 0</float_array>
        <technique_common><accessor source="#lift-out-array" count="2" stride="3">
          <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
        </accessor></technique_common></source>
      <sampler id="lift-sampler"><input semantic="INPUT" source="#lift-in"/><input semantic="OUTPUT" source="#lift-out"/></sampler>
      <channel source="#lift-sampler" target="plate/location"/>
    </animation>
  </library_animations>
  <library_visual_scenes>
    <visual_scene id="scene">
      <node id="plate" name="plate">
        <translate sid="location">0 0 0</translate>
        <instance_geometry url="#tri"/>
      </node>
    </visual_scene>
  </library_visual_scenes>
  <scene><instance_visual_scene url="#scene"/></scene>
</COLLADA>
"""


@pytest.fixture
def collada(tmp_path) -> Path:
    path = tmp_path / "lift.dae"
    path.write_text(COLLADA)
    return path


# ---------------------------------------------------------------- load_mesh says so


def test_load_mesh_warns_of_a_node_animation(rigid_gltf):
    with pytest.warns(csb.AnimationWarning) as record:
        at, mesh = sys._getframe().f_lineno, csb.load_mesh(rigid_gltf)
    message = str(record[0].message)
    assert str(rigid_gltf) in message and "'slide'" in message and "2 s" in message
    assert "rest pose" in message and "csb.load_animation" in message
    assert (Path(record[0].filename).resolve(), record[0].lineno) == (HERE, at)  # at the user's call
    assert issubclass(csb.AnimationWarning, csb.MeshWarning)
    # The rest pose: the node's static translation, not the animation's first key.
    np.testing.assert_array_equal(mesh.vertices, TRIANGLE + REST_TRANSLATION)


def test_load_mesh_warns_of_a_skin(skinned_gltf):
    with pytest.warns(csb.AnimationWarning) as record:
        mesh = csb.load_mesh(skinned_gltf)
    message = str(record[0].message)
    assert "'bend'" in message and "1.5 s" in message
    assert "1 skinned mesh(es) ('column': 2 bone(s), 12 vertices)" in message, message
    np.testing.assert_array_equal(mesh.vertices, COLUMN.astype(np.float32))  # the bind pose (float32 in the file)


def test_load_mesh_warns_of_a_collada_animation(collada):
    with pytest.warns(csb.AnimationWarning, match=r"4 s") as record:
        csb.load_mesh(collada)
    assert str(collada) in str(record[0].message)


def test_a_file_without_animation_loads_silently(tmp_path):
    path = tmp_path / "still.gltf"
    csb.save_mesh(csb.Mesh(TRIANGLE, [[0, 1, 2]], name="still"), str(path))
    csb.load_mesh(path)  # warnings are errors in this suite
