"""Mesh import through Assimp: formats, welding, triangulation, and every kind of bad input."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

import csb

SCENES = Path(csb.__file__).parent / "scenes"


def reference_mesh() -> csb.Mesh:
    """A small cloth with alternating diagonals (7 x 5 vertices, 48 triangles)."""
    return csb.cloth_grid(1.2, 0.8, 7, 5, plane="xy")


def invariants(mesh: csb.Mesh) -> dict:
    """Counts and rotation-invariant geometry, to compare imports of the same mesh."""
    topo = csb.topology(mesh)
    v, e, t = mesh.vertices, topo["edges"], mesh.triangles
    lengths = np.sort(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1))
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1).sum()
    return dict(vertices=mesh.num_vertices, triangles=len(t), edges=len(e), bending=len(topo["bending"]),
                lengths=lengths, area=area)


WRITERS = {
    # meshio writes these four; Assimp's exporter (csb.save_mesh) the other five.
    "obj": "meshio", "off": "meshio", "ply": "meshio", "stl": "meshio",
    "gltf": "assimp", "glb": "assimp", "dae": "assimp", "3ds": "assimp", "fbx": "assimp",
}


def write(mesh: csb.Mesh, path: Path) -> Path:
    if WRITERS[path.suffix[1:]] == "meshio":
        meshio.write(path, meshio.Mesh(mesh.vertices, [("triangle", mesh.triangles)]))
    else:
        csb.save_mesh(mesh, str(path))
    return path


def test_the_same_mesh_in_nine_formats_imports_identically(tmp_path):
    ref = invariants(reference_mesh())
    assert (ref["vertices"], ref["triangles"], ref["edges"], ref["bending"]) == (35, 48, 82, 62)  # 82 edges, 20 of them on the boundary
    for ext in WRITERS:
        got = invariants(csb.load_mesh(write(reference_mesh(), tmp_path / f"cloth.{ext}")))
        for key in ("vertices", "triangles", "edges", "bending"):
            assert got[key] == ref[key], f".{ext}: {key} {got[key]} != {ref[key]}"
        # Assimp stores coordinates as 32-bit floats: lengths and area agree to float precision.
        np.testing.assert_allclose(got["lengths"], ref["lengths"], rtol=1e-6, err_msg=ext)
        assert got["area"] == pytest.approx(ref["area"], rel=1e-6), ext


def test_seams_are_welded_so_the_bundled_cloth_holds_together():
    path = SCENES / "meshes" / "cloth_panels.obj"
    mesh = csb.load_mesh(path)
    assert mesh.num_vertices == 33 * 33 and len(mesh.triangles) == 2 * 32 * 32
    topo = csb.topology(mesh)
    assert topo["boundary_edges"] == 4 * 32 and topo["non_manifold_edges"] == 0
    # Assimp gives every face corner its own vertex; the weld joins them, seam included.
    assert mesh.report.welded_vertices == mesh.report.input_vertices - 33 * 33
    apart = csb.load_mesh(path, weld=False)
    assert apart.num_vertices == 4 * 32 * 32
    # Unwelded, every quad is an island: only its own diagonal is shared. It would fall apart.
    assert csb.topology(apart)["boundary_edges"] == 4 * 32 * 32


def test_weld_tolerance_is_relative_to_the_mesh_size(tmp_path):
    # Two triangles whose shared edge is off by 3e-6 and 4e-6 of the bounding-box diagonal
    # (sqrt 2): welded at a relative tolerance of 1e-5, not at 1e-6, whatever the scale.
    # (Offsets well above float32 resolution: Assimp stores coordinates as 32-bit floats.)
    d = np.sqrt(2)
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1 + 3e-6 * d, 0, 0], [1, 1, 0], [0, 1 + 4e-6 * d, 0]])
    for scale in (1e-3, 1.0, 1e3):
        path = tmp_path / "near.ply"
        meshio.write(path, meshio.Mesh(v * scale, [("triangle", np.array([[0, 1, 2], [3, 4, 5]]))]))
        assert csb.load_mesh(path, weld_tolerance=1e-5).num_vertices == 4
        assert csb.load_mesh(path, weld_tolerance=1e-6).num_vertices == 6


def test_obj_negative_indices_and_polygons(tmp_path):
    relative = tmp_path / "relative.obj"
    relative.write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\n"
        "f -4/-1 -3/-1 -2/-1 -1/-1\n"          # a quad, relative indices
        "v 2 0 0\nv 3 1 0\nv 2.5 2 0\nv 1.5 1.5 0\n"
        "f -7 -4 -3 -2 -1\n"                    # a pentagon sharing vertex 2 (-7 of 8)
    )
    absolute = tmp_path / "absolute.obj"
    absolute.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n"
                        "v 2 0 0\nv 3 1 0\nv 2.5 2 0\nv 1.5 1.5 0\nf 2 5 6\nf 2 6 7\nf 2 7 8\n")
    a, b = invariants(csb.load_mesh(relative)), invariants(csb.load_mesh(absolute))
    assert a["triangles"] == 2 + 3  # n - 2 triangles per polygon, not truncated to one
    for key in ("vertices", "triangles", "edges", "bending"):
        assert a[key] == b[key]
    # (Assimp may pick other diagonals for the pentagon than we did: compare the area.)
    assert a["area"] == pytest.approx(b["area"], rel=1e-7)


def test_non_manifold_edges_are_reported_not_crashed_on():
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]], float)
    fan = csb.Mesh(v, np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]), name="fan")
    b = csb.ModelBuilder()
    with pytest.warns(csb.MeshWarning, match=r"fan: 1 non-manifold edge"):
        inst = b.add_mesh(fan, particle_mass=1.0, bending_stiffness=0.5)
    assert inst.num_distance == 7 and inst.num_bending == 0 and inst.report.non_manifold_edges == 1
    b.build()


def test_degenerate_triangles_are_dropped_with_a_warning(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 0, 0]], float)
    tris = np.array([[0, 1, 2], [0, 1, 3], [1, 4, 2]])  # collinear; zero-length edge (1 and 4 coincide)
    b = csb.ModelBuilder()
    with pytest.warns(csb.MeshWarning, match=r"dropped 2 degenerate triangle\(s\) .*: 1, 2"):
        inst = b.add_mesh(csb.Mesh(v, tris, name="slivers"), particle_mass=1.0)
    assert inst.num_distance == 3 and inst.num_particles == 5  # numbering kept, triangle 0 only
    path = tmp_path / "slivers.ply"
    meshio.write(path, meshio.Mesh(v, [("triangle", tris)]))
    with pytest.warns(csb.MeshWarning) as record:
        mesh = csb.load_mesh(path)
    assert mesh.num_vertices == 3 and len(mesh.triangles) == 1
    assert any("degenerate" in str(w.message) for w in record)


# ------------------------------------------------------------------------------ bad input


def obj(tmp_path: Path, text: str, name: str = "bad.obj") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "text, message",
    [
        ("v 0 0 0\nv 1 0 0\nv 1 2\nf 1 2 3\n", r"bad\.obj:3: vertex 3 has 2 coordinate\(s\)"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2\n", r"bad\.obj:4: face has 2 vertex/vertices; a face needs at least 3"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9\n", r"bad\.obj:4: face refers to vertex 9, but only 3 vertices"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf -1 -2 -4\n", r"bad\.obj:4: face refers to vertex -4, but only 3 vertices"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 0 1 2\n", r"bad\.obj:4: face reference '0' uses index 0"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nf 1/4 2/4 3/4\n",
         r"bad\.obj:5: face refers to texture coordinate 4, but only 1 texture coordinate is defined"),
        ("v 0 0 0\nv nan 0 0\nv 1 1 0\nf 1 2 3\n", r"bad\.obj:2: vertex 2 has a non-finite coordinate 'nan'"),
        ("v 0 0 0\nv 1e999 0 0\nv 1 1 0\nf 1 2 3\n", r"bad\.obj:2: vertex 2 has a non-finite coordinate"),
        ("v 0 0 0\nv 1 0 x\nv 1 1 0\nf 1 2 3\n", r"bad\.obj:2: vertex coordinate 'x' is not a number"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\n", r"bad\.obj: the file has no faces \(3 vertices, 0 line elements\)"),
        ("v 0 0 0\nv 1 0 0\nv 1 1 0\nl 1 2 3\n", r"the file has no faces \(3 vertices, 1 line elements\)"),
        ("# only a comment\n", r"the file has no faces"),
    ],
)
def test_bad_obj_files_name_the_line(tmp_path, text, message):
    with pytest.raises(csb.MeshError, match=message):
        csb.load_mesh(obj(tmp_path, text))


def test_missing_empty_directory_and_unsupported(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothere\.obj: no such file"):
        csb.load_mesh(tmp_path / "nothere.obj")
    for ext in ("obj", "stl", "glb", "fbx"):
        (tmp_path / f"empty.{ext}").write_bytes(b"")
        with pytest.raises(csb.MeshError, match=rf"empty\.{ext}: the file is empty"):
            csb.load_mesh(tmp_path / f"empty.{ext}")
    (tmp_path / "dir.obj").mkdir()
    with pytest.raises(csb.MeshError, match=r"dir\.obj: is a directory"):
        csb.load_mesh(tmp_path / "dir.obj")
    (tmp_path / "cloth.xyz").write_text("1 2 3\n")
    with pytest.raises(csb.MeshError, match=r"cloth\.xyz: unsupported format '\.xyz'; csb reads .*\.obj"):
        csb.load_mesh(tmp_path / "cloth.xyz")


@pytest.mark.parametrize("ext", ["glb", "gltf", "fbx", "dae", "3ds", "ply", "stl", "off"])
def test_corrupt_files_raise_mesh_error(tmp_path, ext):
    rng = np.random.default_rng(7)
    path = tmp_path / f"noise.{ext}"
    path.write_bytes(rng.integers(0, 256, 3000).astype(np.uint8).tobytes())
    with pytest.raises(csb.MeshError, match=rf"noise\.{ext}: "):
        csb.load_mesh(path)


def test_truncated_files_raise_mesh_error(tmp_path):
    good = write(reference_mesh(), tmp_path / "good.ply")
    data = good.read_bytes()
    header_end = data.index(b"end_header")
    last_property = data.rindex(b"\n", 0, header_end - 1) + 1
    # A PLY header cut in a property line made Assimp 5.2 loop forever; csb checks it first.
    for cut, message in [(header_end, "no 'end_header'"), (last_property + 11, "PLY header: unknown property type"),
                         (header_end + 40, r"needs at least \d+ bytes")]:
        (tmp_path / "cut.ply").write_bytes(data[:cut])
        with pytest.raises(csb.MeshError, match=rf"cut\.ply: .*{message}"):
            csb.load_mesh(tmp_path / "cut.ply")
    csb.save_mesh(reference_mesh(), str(tmp_path / "binary.stl"))
    stl = (tmp_path / "binary.stl").read_bytes()
    (tmp_path / "cut.stl").write_bytes(stl[:84 + 50 * 10 + 7])
    with pytest.raises(csb.MeshError, match=r"cut\.stl: the binary STL header declares 48 triangles"):
        csb.load_mesh(tmp_path / "cut.stl")
    text = write(reference_mesh(), tmp_path / "ascii.stl").read_bytes()  # meshio writes ASCII STL
    (tmp_path / "cut.stl").write_bytes(text[: len(text) // 2])
    with pytest.raises(csb.MeshError, match=r"cut\.stl: cannot read the file: "):
        csb.load_mesh(tmp_path / "cut.stl")
    off = write(reference_mesh(), tmp_path / "good.off").read_text().splitlines()
    (tmp_path / "cut.off").write_text("\n".join(off[:20]) + "\n")
    with pytest.raises(csb.MeshError, match=r"cut\.off: the OFF header declares 35 vertices and 48 faces"):
        csb.load_mesh(tmp_path / "cut.off")


def test_files_without_triangles(tmp_path):
    points = tmp_path / "points.ply"
    meshio.write(points, meshio.Mesh(np.eye(3), [("vertex", np.arange(3)[:, None])]), binary=False)
    with pytest.raises(csb.MeshError, match=r"points\.ply: the file has no triangles"):
        csb.load_mesh(points)
    lines = tmp_path / "lines.ply"
    lines.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                     "property float z\nelement edge 2\nproperty int vertex1\nproperty int vertex2\nend_header\n"
                     "0 0 0\n1 0 0\n1 1 0\n0 1\n1 2\n")
    with pytest.raises(csb.MeshError, match=r"lines\.ply: the file has no triangles"):
        csb.load_mesh(lines)


def test_non_finite_coordinates_in_other_formats(tmp_path):
    v = reference_mesh().vertices
    v[4] = [np.nan, 0, 0]
    path = tmp_path / "nan.ply"
    meshio.write(path, meshio.Mesh(v, [("triangle", reference_mesh().triangles)]), binary=False)
    with pytest.raises(csb.MeshError, match=r"nan\.ply: vertex \d+ has a non-finite coordinate \(nan"):
        csb.load_mesh(path)


def test_bad_arrays(tmp_path):
    v = reference_mesh().vertices
    t = reference_mesh().triangles
    with pytest.raises(csb.ParameterError, match=r"vertices must have shape \(N, 3\), got \(35, 2\)"):
        csb.Mesh(v[:, :2], t)
    with pytest.raises(csb.ParameterError, match=r"triangles must hold integer indices"):
        csb.Mesh(v, t.astype(float))
    with pytest.raises(csb.ParameterError, match=r"triangles must have shape \(M, 3\), got \(48, 2\)"):
        csb.Mesh(v, t[:, :2])
    bad = v.copy()
    bad[7, 2] = np.inf
    with pytest.raises(csb.MeshError, match=r"mesh: vertex 7 has a non-finite coordinate \(.*inf\)"):
        csb.Mesh(bad, t)
    with pytest.raises(csb.MeshError, match=r"triangle 3 refers to vertex 35, but the mesh has 35 vertices"):
        csb.Mesh(v, np.vstack([t[:3], [[0, 1, 35]]]))
    with pytest.raises(csb.MeshError, match=r"index 4294967296, which is out of range"):
        csb.Mesh(v, np.array([[0, 1, 2**32]]))
    with pytest.raises(csb.MeshError, match=r"the mesh has no triangles \(and no line segments\)"):
        csb.Mesh(v)


def test_corrupted_files_never_crash_or_hang(tmp_path):
    """A quick fuzz: truncations and byte flips of every promised format, each loaded in a child
    process so that a crash or a hang would show here instead of killing the test run."""
    rng = np.random.default_rng(11)
    cases = []
    for ext in WRITERS:
        data = write(reference_mesh(), tmp_path / f"base.{ext}").read_bytes()
        for k in range(4):
            b = bytearray(data)
            if k % 2 == 0:
                b = b[: int(rng.integers(1, len(b)))]
            else:
                for _ in range(int(rng.integers(1, 20))):
                    b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
            path = tmp_path / f"fuzz{k}.{ext}"
            path.write_bytes(bytes(b))
            cases.append(str(path))
    script = (
        "import sys, warnings, csb\n"
        "warnings.simplefilter('ignore')\n"
        "try:\n    csb.load_mesh(sys.argv[1])\n"
        "except (csb.Error, FileNotFoundError):\n    pass\n"
    )
    for path in cases:
        r = subprocess.run([sys.executable, "-c", script, path], capture_output=True, timeout=60)
        assert r.returncode == 0, f"{os.path.basename(path)}: exit {r.returncode}\n{r.stderr.decode()[-500:]}"


def test_a_file_assimp_loops_on_gives_an_error_not_a_hang(tmp_path):
    """Assimp 5.2 loops forever on a Collada index list with a stray byte in it; csb runs Assimp
    in a child process and stops it at the deadline."""
    path = csb.save_mesh(reference_mesh(), str(tmp_path / "good.dae")) or tmp_path / "good.dae"
    data = path.read_bytes()
    start = data.index(b"<p>") + 3
    space = data.index(b" ", start + 4)
    (tmp_path / "stray.dae").write_bytes(data[:space] + b"\xbf" + data[space + 1:])
    with pytest.raises(csb.MeshError, match=r"stray\.dae: reading the file took longer than 1 s and was stopped"):
        csb.load_mesh(tmp_path / "stray.dae", timeout=1.0)
    with pytest.raises(csb.ParameterError, match=r"timeout must be >= 0 s"):
        csb.load_mesh(path, timeout=-1.0)


def test_save_mesh_refuses_what_it_cannot_write(tmp_path):
    with pytest.raises(csb.MeshError, match=r"cannot write '\.off' files"):
        csb.save_mesh(reference_mesh(), str(tmp_path / "x.off"))
