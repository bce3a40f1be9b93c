"""Results back into the user's tools: the file's own mesh kept by load_mesh (polygons, UVs,
normals, materials, the weld map), and the simulation written as USD on it, read back with Pixar's
USD and compared with the simulation at every frame."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import csb
from csb.export import UsdWriter, polygon_normals

ROOT = Path(__file__).resolve().parents[1]
PANELS = ROOT / "python" / "csb" / "scenes" / "meshes" / "cloth_panels.obj"

pxr = pytest.importorskip("pxr", reason="USD export needs usd-core (the test extra installs it)")
from pxr import Usd, UsdGeom  # noqa: E402


def test_load_mesh_keeps_the_files_quads_uvs_and_weld_map():
    """The bundled cloth: two OBJ panels of 16 x 32 quads with texture seams; csb welds them into
    33 x 33 vertices and triangulates. Its source keeps 1,024 quads over the file's vertices, their
    UVs, and maps each to the welded vertex at its position."""
    mesh = csb.load_mesh(PANELS)
    src = mesh.source
    assert mesh.num_vertices == 33 * 33
    assert len(src.face_sizes) == 1024 and np.all(src.face_sizes == 4)
    assert len(src.face_vertices) == 4 * 1024 and src.face_vertices.max() < len(src.vertices)
    assert src.uv is not None and src.uv.shape == (len(src.vertices), 2)
    assert np.array_equal(src.weld_map, mesh.report.vertex_map)  # the public weld map is the report's
    assert np.all(src.weld_map >= 0)
    assert np.allclose(mesh.vertices[src.weld_map], src.vertices, atol=1e-6)
    assert np.array_equal(src.positions(mesh.vertices), mesh.vertices[src.weld_map])
    # Every quad's corners are four distinct welded vertices (the triangulation's).
    corners = src.weld_map[src.face_vertices].reshape(-1, 4)
    assert all(len(set(q)) == 4 for q in corners.tolist())


def test_transforms_carry_the_source_and_a_mirror_keeps_polygons_outward():
    mesh = csb.load_mesh(PANELS)
    moved = csb.transformed(mesh, scale=2.0, rotate=(0.0, np.pi / 2, 0.0), translate=(1.0, 2.0, 3.0))
    assert np.allclose(moved.vertices[moved.source.weld_map], moved.source.vertices, atol=1e-5)
    flipped = csb.transformed(mesh, scale=(-1.0, 1.0, 1.0))
    n0 = polygon_normals(mesh.source.vertices, mesh.source.face_sizes, mesh.source.face_vertices)
    n1 = polygon_normals(flipped.source.vertices, flipped.source.face_sizes, flipped.source.face_vertices)
    used = np.linalg.norm(n0, axis=1) > 0
    assert np.allclose(n1[used], n0[used], atol=1e-9)  # a flat cloth in y = 0 mirrored in x faces the same way


def test_polygon_normals_of_a_unit_square_and_a_bent_pair():
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    assert np.allclose(polygon_normals(square, np.array([4]), np.arange(4)), [[0, 0, 1]] * 4)
    # Two triangles folded by 90 degrees along x = 0: the shared vertices get the bisector.
    pts = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1]], float)
    n = polygon_normals(pts, np.array([3, 3]), np.array([0, 2, 1, 0, 1, 3]))
    assert np.allclose(n[2], [0, 0, 1]) and np.allclose(n[3], [1, 0, 0])
    assert np.allclose(n[0], np.array([1, 0, 1]) / np.sqrt(2))


SCENE = """\
[scene]
name = "drop"
duration = 0.2

[solver]
method = "xpbd"
dt = 0.016666666666666666
substeps = 4
iterations = 2

[[mesh]]
name = "cloth"
file = "{panels}"
mass = 0.2
translate = [0.0, 1.0, 0.0]
stretch = {{ stiffness = 1.0, compliance = 1e-7 }}
bending = {{ stiffness = 0.1, compliance = 1.0 }}
pin = {{ near = [[-0.5, 1.0, -0.5], [0.5, 1.0, -0.5]] }}

[[collider]]
name = "ball"
type = "sphere"
center = [0.0, 0.3, 0.0]
radius = 0.3
motion = {{ times = [0.0, 0.2], translation = [[0.0, 0.0, 0.0], [0.0, 0.2, 0.0]] }}

[output]
fps = 30
xdmf = false
vtu = false
csv = false
plot = false
usd = true
"""


def test_a_scene_written_as_usd_reads_back_frame_for_frame(tmp_path):
    """The scene's USD holds the file's quads with its UVs, and at each frame's time code the
    file's vertices where the simulation's particles are (float32, as USD stores points): compared
    with the same scene stepped here frame by frame. The moving ball's transform follows its
    keyframes; the stage is in metres, y up, at the frames' rate."""
    path = tmp_path / "drop.toml"
    path.write_text(SCENE.format(panels=PANELS.as_posix()))
    scene = csb.load_scene(path)
    result = scene.run(tmp_path / "out")
    usd_path = tmp_path / "out" / "drop.usd"
    assert usd_path in result.files

    sim = scene.build()
    src = sim.meshes["cloth"].source
    expected = [src.positions(np.asarray(sim.state.x))]
    for _ in range(6):  # 0.2 s at 30 frames per second: 2 steps of 1/60 s per frame
        sim.step(2)
        expected.append(src.positions(np.asarray(sim.state.x)))

    stage = Usd.Stage.Open(str(usd_path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert stage.GetTimeCodesPerSecond() == pytest.approx(30.0)
    assert stage.GetEndTimeCode() == pytest.approx(6.0)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/cloth"))
    keep, index = src.distinct_vertices()
    assert len(keep) == 1122  # the OBJ's 1,122 vertices, each once (Assimp gave one per quad corner: 4,096)
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [4] * 1024
    faces = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
    assert np.array_equal(keep[faces], keep[index[src.face_vertices]])
    assert np.array_equal(src.vertices[keep][faces], src.vertices[src.face_vertices])  # the same quads
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert np.array_equal(np.asarray(st.Get())[faces], src.uv[src.face_vertices].astype(np.float32))
    points = mesh.GetPointsAttr()
    assert points.GetTimeSamples() == [float(k) for k in range(7)]
    for k, want in enumerate(expected):
        got = np.asarray(points.Get(Usd.TimeCode(k)))
        assert np.array_equal(got, want[keep].astype(np.float32)), f"frame {k}"
        assert np.array_equal(got[faces], want[src.face_vertices].astype(np.float32))
    normals = np.asarray(mesh.GetNormalsAttr().Get(Usd.TimeCode(6)))
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-6)
    ball = UsdGeom.Xformable(stage.GetPrimAtPath("/World/colliders/ball"))
    for k in range(7):
        m = np.asarray(ball.ComputeLocalToWorldTransform(Usd.TimeCode(k)))
        assert np.allclose(m[3, :3], [0.0, 0.2 * (k / 30) / 0.2, 0.0], atol=1e-9)


def test_csb_run_format_usd_writes_the_usd_alone(tmp_path):
    path = tmp_path / "drop.toml"
    path.write_text(SCENE.format(panels=PANELS.as_posix()).replace("usd = true", "usd = false"))
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "csb.cli", "run", str(path), "--out", str(out), "--format", "usd", "--quiet"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["drop.usd"]
    assert f"wrote {out / 'drop.usd'}" in r.stdout


def test_a_mesh_built_in_code_is_written_as_simulated_and_a_rope_as_points(tmp_path):
    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, 5, 5), density=0.2)
    rope = b.add_mesh(csb.chain(4, 0.1), density=0.01)
    b.pin(cloth.first_particle)
    model = b.build()
    state = model.initial_state()
    w = UsdWriter(tmp_path / "a.usda", {"cloth": cloth, "rope": rope}, model, fps=60)
    stepper = csb.PbdStepper(dt=1 / 60, substeps=2, iterations=2)
    for _ in range(3):
        w.write(state)
        stepper.step(model, state)
    w.close()
    stage = Usd.Stage.Open(str(tmp_path / "a.usda"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/cloth"))
    tris = np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    assert np.array_equal(tris, np.asarray(cloth.triangles) - cloth.first_particle)
    assert np.array_equal(np.asarray(mesh.GetPointsAttr().Get(Usd.TimeCode(0))), cloth.vertices.astype(np.float32))
    assert stage.GetPrimAtPath("/World/rope").IsA(UsdGeom.Points)


def test_bad_frames_are_refused_by_name(tmp_path):
    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, 3, 3), density=0.2)
    model = b.build()
    state = model.initial_state()
    w = UsdWriter(tmp_path / "b.usda", {"cloth": cloth}, model, fps=30)
    w.write(state)
    with pytest.raises(csb.ParameterError, match=r"frame at t = 0.0 s does not come after the last"):
        w.write(state)
    x = np.asarray(state.x)
    x[0, 0] = np.nan
    state.t = 1.0
    with pytest.raises(csb.SimulationError, match=r"non-finite positions; not written"):
        w.write(state)
    with pytest.raises(csb.ParameterError, match="fps must be > 0"):
        UsdWriter(tmp_path / "c.usda", {"cloth": cloth}, model, fps=0)


def test_without_usd_core_the_writer_says_how_to_get_it(tmp_path):
    code = textwrap.dedent(f"""
        import sys
        sys.modules["pxr"] = None  # as if usd-core were not installed
        import csb
        from csb.export import UsdWriter, usd_available
        assert not usd_available()
        b = csb.ModelBuilder(); c = b.add_mesh(csb.cloth_grid(1.0, 1.0, 3, 3), density=0.2)
        try:
            UsdWriter({str(tmp_path / 'x.usd')!r}, {{"c": c}}, b.build())
        except ImportError as e:
            print(e)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert "writing USD needs Pixar's usd-core, the 'usd' extra: pip install 'csb[usd]'" in r.stdout, r.stderr
    # The command line says so in one line, without a traceback.
    cli = ('import sys; sys.modules["pxr"] = None; from csb.cli import main; '
           f'sys.exit(main(["run", "cloth_drop", "--duration", "0.1", "--quiet", "--format", "usd", "--out", {str(tmp_path)!r}]))')
    r = subprocess.run([sys.executable, "-c", cli], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.startswith("csb: error: writing USD needs Pixar's usd-core"), r.stderr


def test_a_material_of_the_file_selects_its_vertices(tmp_path):
    """Two squares side by side in one OBJ, 'body' and 'collar' materials, sharing their seam:
    Material('collar') catches the collar's vertices, the seam's included (welded to both)."""
    (tmp_path / "two.mtl").write_text("newmtl body\nKd 0.5 0.5 0.5\nnewmtl collar\nKd 0.8 0.1 0.1\n")
    (tmp_path / "two.obj").write_text(textwrap.dedent("""\
        mtllib two.mtl
        v 0 0 0
        v 1 0 0
        v 1 0 1
        v 0 0 1
        v 2 0 0
        v 2 0 1
        usemtl body
        f 1 2 3 4
        usemtl collar
        f 2 5 6 3
        """))
    mesh = csb.load_mesh(tmp_path / "two.obj")
    b = csb.ModelBuilder()
    inst = b.add_mesh(mesh, density=0.2)
    got = inst.select(csb.Material("collar")) - inst.first_particle
    assert sorted(np.asarray(mesh.vertices)[got, 0].tolist()) == [1.0, 1.0, 2.0, 2.0]
    with pytest.raises(csb.ParameterError, match=r"no material 'cuff' in the file; it has 'body', 'collar'"):
        inst.select(csb.Material("cuff"))
    shape = b.add_mesh(csb.cloth_grid(1.0, 1.0, 3, 3), density=0.2)
    with pytest.raises(csb.ParameterError, match="has no file's mesh to find material 'collar' in"):
        shape.select(csb.Material("collar"))


def test_the_usd_study_reads_cloth_drop_back_to_float32_rounding(tmp_path):
    """validation/usd_export.py (the main job's study), quick: cloth_drop's USD read back equals
    the simulation at every frame to float32 rounding, and its still is drawn from the USD."""
    r = subprocess.run([sys.executable, str(ROOT / "validation" / "usd_export.py"), "--quick", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "cloth_drop.usd: 16 frames (time codes 0-15 at 30 per second), metersPerUnit 1, up axis Y" in r.stdout
    assert "1122 points (4096 corners as Assimp read the OBJ, welded into 1089 particles), 1024 polygons of [4] corners" in r.stdout
    assert (tmp_path / "usd_still.png").stat().st_size > 10_000


def _read_glb(path: Path) -> tuple[dict, bytes]:
    """A GLB's JSON and binary chunks, parsed here from the bytes (independently of the writer)."""
    import json
    import struct

    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    n, kind = struct.unpack_from("<I4s", data, 12)
    assert kind == b"JSON"
    doc = json.loads(data[20:20 + n])
    m, kind = struct.unpack_from("<I4s", data, 20 + n)
    assert kind == b"BIN\0"
    return doc, data[28 + n:28 + n + m]


def _accessor(doc: dict, blob: bytes, k: int) -> np.ndarray:
    a = doc["accessors"][k]
    view = doc["bufferViews"][a["bufferView"]]
    dtype = {5126: np.float32, 5125: np.uint32, 5123: np.uint16}[a["componentType"]]
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[a["type"]]
    out = np.frombuffer(blob, dtype=dtype, count=a["count"] * width, offset=view["byteOffset"])
    return out.reshape(a["count"], width) if width > 1 else out


def _run_formats(tmp_path: Path, formats: list[str]):
    path = tmp_path / "drop.toml"
    path.write_text(SCENE.format(panels=PANELS.as_posix()).replace("usd = true", "usd = false"))
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "csb.cli", "run", str(path), "--out", str(out), "--format", *formats,
                        "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    sim = csb.load_scene(path).build()
    src = sim.meshes["cloth"].source
    keep, index = src.distinct_vertices()
    frames = [src.positions(np.asarray(sim.state.x))[keep]]
    for _ in range(6):
        sim.step(2)
        frames.append(src.positions(np.asarray(sim.state.x))[keep])
    return out, r.stdout, src, keep, index, frames


def test_the_gltf_plays_the_simulation_as_morph_targets(tmp_path):
    """The .glb, parsed here: the file's 1,122 vertices with its UVs (v flipped, as glTF's runs
    down), its quads as two triangles each, and one morph target per frame after the first whose
    weights animation (linear, at the frames' times) puts every vertex where the simulation had it.
    Assimp reads it as a valid glTF too."""
    out, stdout, src, keep, index, frames = _run_formats(tmp_path, ["gltf"])
    doc, blob = _read_glb(out / "drop.glb")
    prim = doc["meshes"][0]["primitives"][0]
    base = _accessor(doc, blob, prim["attributes"]["POSITION"])
    assert np.array_equal(base, frames[0].astype(np.float32))
    uv = _accessor(doc, blob, prim["attributes"]["TEXCOORD_0"])
    assert np.allclose(uv[:, 0], src.uv[keep, 0]) and np.allclose(uv[:, 1], 1 - src.uv[keep, 1])
    tris = _accessor(doc, blob, prim["indices"]).reshape(-1, 3)
    assert len(tris) == 2 * 1024
    anim = doc["animations"][0]
    sampler = anim["samplers"][anim["channels"][0]["sampler"]]
    times = _accessor(doc, blob, sampler["input"])
    assert np.allclose(times, np.arange(7) / 30)
    weights = _accessor(doc, blob, sampler["output"]).reshape(7, 6)
    targets = [_accessor(doc, blob, t["POSITION"]) for t in prim["targets"]]
    for k in range(7):
        shown = base + sum(w * d for w, d in zip(weights[k], targets))
        assert np.allclose(shown, frames[k], atol=3e-7), f"frame {k}"
    with pytest.warns(csb.AnimationWarning, match=r"1 animation\(s\) \('simulation': 0.2 s"):
        mesh = csb.load_mesh(out / "drop.glb")  # Assimp reads and validates it, and sees the animation
    assert mesh.num_vertices == 33 * 33


def test_obj_and_ply_sequences_hold_every_frame(tmp_path):
    import meshio

    out, stdout, src, keep, index, frames = _run_formats(tmp_path, ["obj", "ply"])
    objs = sorted((out / "obj").glob("*.obj"))
    plys = sorted((out / "ply").glob("*.ply"))
    assert [p.name for p in objs] == [f"drop_{k:05d}.obj" for k in range(7)]
    assert [p.name for p in plys] == [f"cloth_{k:05d}.ply" for k in range(7)]
    assert f"wrote {out / 'obj'}/ (7 files)" in stdout
    for k in range(7):
        text = objs[k].read_text().splitlines()
        v = np.array([[float(a) for a in line.split()[1:]] for line in text if line.startswith("v ")])
        assert np.allclose(v, frames[k], rtol=0, atol=1e-8)
        faces = [line for line in text if line.startswith("f ")]
        assert len(faces) == 1024 and all(len(f.split()) == 5 and f.count("/") == 8 for f in faces)
        ply = meshio.read(plys[k])
        assert np.allclose(ply.points, frames[k], rtol=0, atol=1e-6)
        assert ply.cells_dict["quad"].shape == (1024, 4)
    assert any(line.startswith("vt ") for line in objs[0].read_text().splitlines())
