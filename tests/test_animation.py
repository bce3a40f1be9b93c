"""Animated mesh files (glTF node animations and skins, Collada): load_mesh loads the rest pose and
says so with a csb.AnimationWarning; csb.load_animation reads the animation."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

import csb
from csb.export import GltfBuilder

HERE = Path(__file__).resolve()


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
    g = GltfBuilder()
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
    g = GltfBuilder()
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


# ---------------------------------------------------------------- load_animation reads it


def f32(values) -> np.ndarray:
    """The values as the file stores them (float32), in double."""
    return np.asarray(values, np.float32).astype(float)


def lerp_keys(times, values, t) -> np.ndarray:
    values = f32(values)
    return np.array([np.interp(t, f32(times), values[:, c]) for c in range(values.shape[1])])


def slerp(a: np.ndarray, b: np.ndarray, f: float) -> np.ndarray:
    """Shoemake's (1985) slerp of unit quaternions along the shorter arc."""
    d = float(np.dot(a, b))
    if d < 0:
        b, d = -b, -d
    theta = math.acos(min(d, 1.0))
    if theta == 0:
        return a
    return (math.sin((1 - f) * theta) * a + math.sin(f * theta) * b) / math.sin(theta)


def slerp_keys(times, quats, t) -> np.ndarray:
    times, q = f32(times), f32(quats)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    k = min(int(np.searchsorted(times, t, side="right")) - 1, len(times) - 2)
    return slerp(q[k], q[k + 1], (t - times[k]) / (times[k + 1] - times[k]))


def matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def rodrigues(v) -> np.ndarray:
    angle = float(np.linalg.norm(v))
    if angle == 0:
        return np.eye(3)
    k = np.asarray(v) / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


# The evaluation repeats, in double, the reference's operations on the same float32 keys by other
# formulas (Eigen's slerp, matrix products): coordinates of order 1 agree to a few ulps, and 1e-12 m
# leaves a margin of about 10^3 ulps while catching any interpolation error (a wrong key or
# fraction moves a vertex by 1e-2 m or more here).
EXACT = 1e-12


def test_a_rigid_node_animation_follows_its_keys(rigid_gltf):
    times = [0.0, 0.25, 0.5, 1.0, 1.3, 1.7, 2.0]
    anim = csb.load_animation(rigid_gltf, times)
    assert (anim.name, anim.duration) == ("slide", 2.0)
    np.testing.assert_array_equal(anim.times, times)
    (m,) = anim.meshes
    assert (m.name, m.node, m.skinned) == ("plate", "plate", False)
    np.testing.assert_array_equal(m.triangles, [[0, 1, 2]])
    assert m.vertices.shape == (len(times), 3, 3)
    x0 = f32(TRIANGLE)
    for k, t in enumerate(times):
        R, p = matrix(slerp_keys(R_TIMES, R_VALUES, t)), lerp_keys(T_TIMES, T_VALUES, t)
        np.testing.assert_allclose(m.vertices[k], x0 @ R.T + p, rtol=0, atol=EXACT, err_msg=f"t = {t} s")
    # The keyframes take the rest pose load_mesh reads to the animated one, as move_collider does.
    kf = m.keyframes
    assert kf is not None
    with pytest.warns(csb.AnimationWarning):
        rest = csb.load_mesh(rigid_gltf).vertices
    for k in range(len(times)):
        np.testing.assert_allclose(rest @ kf.matrices[k].T + kf.translation[k], m.vertices[k], rtol=0, atol=EXACT)
        np.testing.assert_allclose(rodrigues(kf.rotation[k]), kf.matrices[k], rtol=0, atol=EXACT)
    motion = kf.motion()
    assert motion["times"] == times and len(motion["translation"]) == len(motion["rotation"]) == len(times)


def test_a_mesh_under_an_animated_parent_and_a_unit_scale(tmp_path):
    """A root scaling centimetres to metres, an arm at 100 cm turning a quarter turn about z in
    1 s, and the mesh on a hand 50 cm along the arm: x(t) = 0.01 (a + Rz(θ(t)) (h + x0)). The
    keyframes take the rest pose load_mesh reads (θ = 0) there: the unit scale applies to the
    vertices as load_mesh applies it."""
    g = GltfBuilder()
    pos = g.accessor(TRIANGLE, "VEC3")
    idx = g.accessor([0, 1, 2], "SCALAR", np.uint32)
    rt, rv = g.accessor([0.0, 1.0], "SCALAR"), g.accessor([[0, 0, 0, 1], quat_z(math.pi / 2)], "VEC4")
    arm, hand = np.array([100.0, 0, 0]), np.array([50.0, 0, 0])
    path = g.write(tmp_path / "arm.gltf", {
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "units", "scale": [0.01, 0.01, 0.01], "children": [1]},
                  {"name": "arm", "translation": arm.tolist(), "children": [2]},
                  {"name": "hand", "translation": hand.tolist(), "mesh": 0}],
        "meshes": [{"name": "palm", "primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}],
        "animations": [{"name": "wave", "samplers": [{"input": rt, "output": rv, "interpolation": "LINEAR"}],
                        "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}}]}],
    })
    times = [0.0, 0.4, 1.0]
    m = csb.load_animation(path, times).mesh("hand")
    with pytest.warns(csb.AnimationWarning):
        rest = csb.load_mesh(path).vertices
    # load_mesh returns Assimp's float32 coordinates: 1e-6 m is about 8 float32 ulps at 1.5 m.
    np.testing.assert_allclose(rest, 0.01 * (arm + hand + TRIANGLE), rtol=0, atol=1e-6)
    for k, t in enumerate(times):
        R = matrix(slerp_keys([0.0, 1.0], [[0, 0, 0, 1], quat_z(math.pi / 2)], t))
        expected = float(np.float32(0.01)) * (arm + (hand + f32(TRIANGLE)) @ R.T)  # Assimp's nodes hold float32
        np.testing.assert_allclose(m.vertices[k], expected, rtol=0, atol=EXACT, err_msg=f"t = {t} s")
        kf = m.keyframes
        np.testing.assert_allclose(kf.matrices[k], R, rtol=0, atol=EXACT)
        # Applied to load_mesh's float32 rest pose, the keyframes agree to its rounding (as above).
        np.testing.assert_allclose(rest @ kf.matrices[k].T + kf.translation[k], expected, rtol=0, atol=1e-6)


def test_default_times_are_the_keys(rigid_gltf):
    anim = csb.load_animation(rigid_gltf)
    np.testing.assert_array_equal(anim.times, [0.0, 1.0, 2.0])
    assert csb.load_animation(rigid_gltf, animation="slide").meshes[0].vertices.shape == (3, 3, 3)


def test_an_animation_is_chosen_by_index_or_name(tmp_path):
    g = GltfBuilder()
    pos = g.accessor(TRIANGLE, "VEC3")
    idx = g.accessor([0, 1, 2], "SCALAR", np.uint32)
    times = g.accessor([0.0, 1.0], "SCALAR")
    up, side = g.accessor([[0, 0, 0], [0, 1, 0]], "VEC3"), g.accessor([[0, 0, 0], [1, 0, 0]], "VEC3")
    path = g.write(tmp_path / "two.gltf", {
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "plate", "mesh": 0}],
        "meshes": [{"name": "plate", "primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}],
        "animations": [{"name": name, "samplers": [{"input": times, "output": out, "interpolation": "LINEAR"}],
                        "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}]}
                       for name, out in (("up", up), ("side", side))],
    })
    with pytest.warns(csb.AnimationWarning, match=r"2 animation\(s\) \('up': 1 s, 1 animated node\(s\); 'side'"):
        csb.load_mesh(path)
    for choice in (1, "side"):
        anim = csb.load_animation(path, [1.0], animation=choice)
        assert anim.name == "side"
        np.testing.assert_array_equal(anim.meshes[0].vertices[0], f32(TRIANGLE) + [1, 0, 0])
    np.testing.assert_array_equal(csb.load_animation(path, [1.0]).meshes[0].vertices[0], f32(TRIANGLE) + [0, 1, 0])


def test_a_skinned_column_follows_its_bones(skinned_gltf):
    times = [0.0, 0.3, 0.75, 1.2, 1.5]
    anim = csb.load_animation(skinned_gltf, times)
    (m,) = anim.meshes
    assert m.skinned and m.keyframes is None and m.name == "column"
    np.testing.assert_array_equal(m.vertices[0], COLUMN.astype(np.float32))  # the bind pose at t = 0
    x0 = f32(COLUMN)
    for k, t in enumerate(times):
        slide = lerp_keys(ROOT_TIMES, ROOT_VALUES, t)
        turn = matrix(slerp_keys(TIP_TIMES, TIP_VALUES, t))
        root = x0 + slide                                      # weight 1 on root
        tip = slide + TIP_OFFSET + (x0 - TIP_OFFSET) @ turn.T  # weight 1 on tip: turned about its joint
        np.testing.assert_allclose(m.vertices[k, :4], root[:4], rtol=0, atol=EXACT, err_msg=f"t = {t} s")
        np.testing.assert_allclose(m.vertices[k, 8:], tip[8:], rtol=0, atol=EXACT, err_msg=f"t = {t} s")
        np.testing.assert_allclose(m.vertices[k, 4:8], 0.5 * (root[4:8] + tip[4:8]), rtol=0, atol=EXACT,
                                   err_msg=f"t = {t} s")
    # Halfway the tip has turned by π/4 exactly (slerp about a fixed axis is linear in the angle).
    np.testing.assert_allclose(matrix(slerp_keys(TIP_TIMES, TIP_VALUES, 0.75)), matrix(quat_z(math.pi / 4)),
                               atol=1e-7)  # float32 keys


def test_a_collada_animation(collada):
    anim = csb.load_animation(collada, [0.0, 1.0, 4.0])
    assert anim.duration == 4.0
    (m,) = anim.meshes
    for k, lift in enumerate([0.0, 0.5, 2.0]):
        np.testing.assert_allclose(m.vertices[k], TRIANGLE + [0, lift, 0], rtol=0, atol=EXACT)
    np.testing.assert_allclose(m.keyframes.translation, [[0, 0, 0], [0, 0.5, 0], [0, 2, 0]], rtol=0, atol=EXACT)


def test_bad_requests_are_named(rigid_gltf, tmp_path):
    with pytest.raises(FileNotFoundError):
        csb.load_animation(tmp_path / "nowhere.gltf")
    still = tmp_path / "still.gltf"
    csb.save_mesh(csb.Mesh(TRIANGLE, [[0, 1, 2]], name="still"), str(still))
    with pytest.raises(csb.ParameterError, match="holds no animation"):
        csb.load_animation(still)
    with pytest.raises(csb.ParameterError, match=r"times\[1\] = 2.5 s is outside the animation 'slide' \(0 to 2 s\)"):
        csb.load_animation(rigid_gltf, [0.0, 2.5])
    with pytest.raises(csb.ParameterError, match="outside"):
        csb.load_animation(rigid_gltf, [-0.1])
    with pytest.raises(csb.ParameterError, match=r"times\[0\] is not finite"):
        csb.load_animation(rigid_gltf, [math.nan])
    with pytest.raises(csb.ParameterError, match="non-empty"):
        csb.load_animation(rigid_gltf, [])
    with pytest.raises(csb.ParameterError, match="no animation named 'walk'.*0 'slide'"):
        csb.load_animation(rigid_gltf, animation="walk")
    with pytest.raises(csb.ParameterError, match=r"animation must be an index in \[0, 0\], got 1"):
        csb.load_animation(rigid_gltf, animation=1)
    with pytest.raises(csb.ParameterError, match="no mesh or node named 'x'"):
        csb.load_animation(rigid_gltf).mesh("x")


# ---------------------------------------------------------------- a scene's collider follows it

SCENE = """
[scene]
name = "animated collider"
duration = 0.2

[solver]
method = "pbd"
dt = 0.01
substeps = 2
iterations = 5

[[mesh]]
name = "sheet"
shape = "cloth"
size = [0.4, 0.4]
resolution = [5, 5]
plane = "xz"
translate = [0.0, 3.0, 0.0]
mass = 0.1

[[collider]]
type = "mesh"
name = "plate"
file = "{file}"
scale = {scale}
rotate = [0.0, 0.3, 0.0]
translate = [0.1, 0.2, 0.3]
{extra}
"""


def scene_file(tmp_path, file: Path, extra: str = "animation = true", scale: str = "2.0") -> Path:
    p = tmp_path / "animated.toml"
    p.write_text(SCENE.format(file=file.name, extra=extra, scale=scale))
    return p


def test_a_mesh_collider_follows_its_files_rigid_animation(rigid_gltf, tmp_path):
    scene = csb.load_scene(scene_file(tmp_path, rigid_gltf))
    motion = scene.colliders[0].motion
    times = np.asarray(motion.times)
    assert {0.0, 1.0, 2.0} <= set(times) and len(times) == 61  # the keys and 30 per second over 2 s
    # At every keyframe the declared shape is where the file's animation puts it, declared the
    # same way: x_d(t) = A x(t) + b.
    anim = csb.load_animation(rigid_gltf, times)
    A = csb.mesh._rotation([0.0, 0.3, 0.0]) * 2.0
    b = np.array([0.1, 0.2, 0.3])
    with pytest.warns(csb.AnimationWarning):
        declared = csb.transformed(csb.load_mesh(rigid_gltf), scale=2.0, rotate=[0.0, 0.3, 0.0],
                                   translate=b).vertices
    for k, t in enumerate(times):
        R, p = motion.pose(t)
        np.testing.assert_allclose(declared @ R.T + p, anim.meshes[0].vertices[k] @ A.T + b, rtol=0, atol=EXACT,
                                   err_msg=f"t = {t} s")
    # The stepper puts the collider there (built without an AnimationWarning: the animation is used).
    sim = scene.build()
    for _ in range(5):
        sim.step()
        R, p = motion.pose(sim.state.t)
        Rs, ps = sim.stepper.collider_pose(sim.colliders["plate"])
        np.testing.assert_allclose(Rs, R, rtol=0, atol=EXACT)
        np.testing.assert_allclose(ps, p, rtol=0, atol=EXACT)


def test_a_mesh_collider_deforms_with_its_files_skin(skinned_gltf, tmp_path):
    """A skinned file drives a deforming collider: the scene samples the skinning at the keys and
    30 per second, declared as the collider is (x_d = A x + b), and the stepper's vertices are
    those samples at t = 0.1, 0.2 and 0.3 s, sample times to the round-off of the steps' summed
    time (1e-12 m)."""
    scene = csb.load_scene(scene_file(tmp_path, skinned_gltf))
    c = scene.colliders[0]
    assert c.motion is None and c.deformation is not None
    times = c.deformation.times
    assert {0.0, 1.5} <= set(times) and len(times) == 46  # the keys and 30 per second over 1.5 s
    A = csb.mesh._rotation([0.0, 0.3, 0.0]) * 2.0
    b = np.array([0.1, 0.2, 0.3])
    anim = csb.load_animation(skinned_gltf, times)
    np.testing.assert_allclose(c.deformation.vertices, anim.meshes[0].vertices @ A.T + b, rtol=0, atol=EXACT)
    sim = scene.build()
    body = sim.colliders["plate"]
    rest = anim.meshes[0].vertices[0] @ A.T + b
    model_vertices = sim.model.colliders[body]["vertices"]
    source = [int(np.argmin(np.linalg.norm(rest - v, axis=1))) for v in model_vertices]
    for _ in range(3):
        sim.step(10)  # 0.1 s: three samples of 1/30 s
        k = int(np.argmin(np.abs(times - sim.state.t)))
        np.testing.assert_allclose(sim.stepper.collider_vertices(sim.model, body),
                                   anim.meshes[0].vertices[k][source] @ A.T + b, rtol=0, atol=EXACT)


def test_an_animated_collider_that_cannot_follow_is_named(rigid_gltf, skinned_gltf, tmp_path):
    with pytest.raises(csb.SceneError, match=r"collider\[0\] \(plate\)\.animation: a collider follows either its motion table"):
        csb.load_scene(scene_file(tmp_path, rigid_gltf, "animation = true\nmotion = { times = [0.0] }"))
    with pytest.raises(csb.SceneError, match="no animation named 'walk'"):
        csb.load_scene(scene_file(tmp_path, rigid_gltf, 'animation = "walk"'))
    with pytest.raises(csb.SceneError, match=r"animation: must be true, false or an animation's name, got 3"):
        csb.load_scene(scene_file(tmp_path, rigid_gltf, "animation = 3"))
    with pytest.raises(csb.SceneError, match=r"\.scale: a non-uniform scale"):
        csb.load_scene(scene_file(tmp_path, rigid_gltf, scale="[1.0, 2.0, 1.0]"))
    still = tmp_path / "still.gltf"
    csb.save_mesh(csb.Mesh(TRIANGLE, [[0, 1, 2]], name="still"), str(still))
    with pytest.raises(csb.SceneError, match="holds no animation"):
        csb.load_scene(scene_file(tmp_path, still))
