"""Hostile mesh files: whatever a file holds, the loaders raise csb.MeshError naming it, print
nothing, and stay within their memory and time limits (meshio and Assimp both read in a bounded
child process)."""

from __future__ import annotations

import re
import struct
import time

import pytest

import csb
from helpers import reaches_memory_cap

MiB = 1024**2
# A limit small enough to be reached at once by a file that declares 10^9 vertices (8-24 GB of
# coordinates), and large enough for every well-formed test mesh (a few kB).
SMALL_MEMORY = 256 * MiB
# Generous beside the ~0.3 s a child takes to start Python, numpy and meshio on this machine,
# and far below what reading 10^9 vertices would take without a limit.
FAST = 5.0


def garbage(path, n=19):
    """A corrupt file of n bytes (not UTF-8, no format's magic)."""
    path.write_bytes((b"\x00\xff\xfe corrupt mesh \x01\x02" * 4)[:n])
    return path


def assert_silent(capfd):
    out, err = capfd.readouterr()
    assert out == "" and err == "", f"something reached the terminal: {out!r} {err!r}"


def cube_off(path):
    """A valid OFF surface (a cube of quads): meshio reads triangles only and exits on quads."""
    path.write_text("OFF\n8 6 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n1 0 1\n1 1 1\n0 1 1\n"
                    "4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 1 2 6 5\n4 2 3 7 6\n4 3 0 4 7\n")
    return path


def surface_ply(path):
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    return path


# ------------------------------------------------------------------------------ meshio


@pytest.mark.parametrize("ext", ["vtu", "msh", "mesh", "inp"])
def test_a_corrupt_volume_file_is_a_mesh_error_not_an_exit(tmp_path, capfd, ext):
    path = garbage(tmp_path / f"corrupt.{ext}")
    with pytest.raises(csb.MeshError, match=re.escape(str(path)) + ": meshio could not read it as a mesh"):
        csb.load_tet_mesh(path)
    assert_silent(capfd)


@pytest.mark.parametrize("make, message", [
    (lambda d: cube_off(d / "cube.off"), r"cube\.off: meshio could not read it as a mesh.*triangular faces"),
    (lambda d: surface_ply(d / "surface.ply"), r"surface\.ply: no tetrahedra .*triangle x 1"),
    (lambda d: (d / "empty.off").write_bytes(b"") or d / "empty.off", r"empty\.off: meshio could not read it.*OFF"),
    (lambda d: (d / "empty.ply").write_bytes(b"") or d / "empty.ply", r"empty\.ply: meshio could not read it.*ply"),
])
def test_surface_and_empty_files_are_mesh_errors_that_quote_meshio(tmp_path, capfd, make, message):
    """meshio's reasons (printed by meshio) end up in the error, not on the terminal."""
    path = make(tmp_path)
    with pytest.raises(csb.MeshError, match=message):
        csb.load_tet_mesh(path)
    assert_silent(capfd)


@reaches_memory_cap
def test_a_file_that_declares_a_billion_nodes_hits_the_memory_limit(tmp_path, capfd):
    """A 71-byte Gmsh file declaring 10^9 nodes: meshio would allocate 24 GB for them."""
    path = tmp_path / "huge.msh"
    path.write_text("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1000000000\n1 0 0 0\n$EndNodes\n")
    start = time.perf_counter()
    with pytest.raises(csb.MeshError, match=re.escape(str(path)) + r": reading the file needed more than the "
                       rf"max_memory limit of {SMALL_MEMORY} bytes .*pass a larger max_memory= \(bytes\)"):
        csb.load_tet_mesh(path, max_memory=SMALL_MEMORY)
    assert time.perf_counter() - start < FAST
    assert_silent(capfd)


def test_a_slow_read_hits_the_timeout(tmp_path, capfd):
    """A deadline shorter than the child's start-up stops it like a hanging reader would be."""
    path = csb.tet_box([1.0, 1.0, 1.0], [1, 1, 1])
    import meshio
    file = tmp_path / "box.vtu"
    meshio.write(file, meshio.Mesh(path.points, [("tetra", path.tets)]))
    with pytest.raises(csb.MeshError, match=re.escape(str(file)) + r": reading the file took longer than the "
                       r"timeout of 0.001 s and was stopped.*pass a larger timeout= \(s\)"):
        csb.load_tet_mesh(file, timeout=0.001)
    assert csb.load_tet_mesh(file).num_tets == 6  # the default limits read it
    assert_silent(capfd)


@pytest.mark.parametrize("kwargs, message", [
    ({"max_memory": 0}, r"max_memory must be a finite number > 0 \(bytes\), got 0"),
    ({"max_memory": -1}, r"max_memory must be a finite number > 0 \(bytes\), got -1"),
    ({"max_memory": "2GB"}, r"max_memory must be a finite number > 0 \(bytes\), got '2GB'"),
    ({"timeout": 0}, r"timeout must be a finite number > 0 \(s\), got 0"),
    ({"timeout": float("inf")}, r"timeout must be a finite number > 0 \(s\), got inf"),
    ({"timeout": True}, r"timeout must be a finite number > 0 \(s\), got True"),
])
def test_load_tet_mesh_limits_are_validated_by_name(tmp_path, kwargs, message):
    with pytest.raises(csb.ParameterError, match=message):
        csb.load_tet_mesh(tmp_path / "any.vtu", **kwargs)


# ------------------------------------------------------------------------------ Assimp


def huge_collada(path):
    """A Collada triangle whose float array declares 10^9 values: Assimp reserves 4 GB for them
    before it finds the three it holds."""
    path.write_text(
        '<?xml version="1.0"?>\n<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">\n'
        '<library_geometries><geometry id="g"><mesh>\n'
        '<source id="p"><float_array id="pa" count="1000000000">0 0 0 1 0 0 0 1 0</float_array>\n'
        '<technique_common><accessor source="#pa" count="3" stride="3"><param name="X" type="float"/>'
        '<param name="Y" type="float"/><param name="Z" type="float"/></accessor></technique_common></source>\n'
        '<vertices id="v"><input semantic="POSITION" source="#p"/></vertices>\n'
        '<triangles count="1"><input semantic="VERTEX" source="#v" offset="0"/><p>0 1 2</p></triangles>\n'
        '</mesh></geometry></library_geometries>\n'
        '<library_visual_scenes><visual_scene id="s"><node><instance_geometry url="#g"/></node></visual_scene>'
        '</library_visual_scenes><scene><instance_visual_scene url="#s"/></scene>\n</COLLADA>\n')
    return path


@reaches_memory_cap
def test_assimp_hits_the_memory_limit_with_a_clear_error(tmp_path, capfd):
    path = huge_collada(tmp_path / "huge.dae")
    start = time.perf_counter()
    with pytest.raises(csb.MeshError, match=re.escape(str(path)) + r": reading the file needed more than the "
                       rf"max_memory limit of {SMALL_MEMORY} bytes .*pass a larger max_memory \(bytes\) to load_mesh"):
        csb.load_mesh(path, max_memory=SMALL_MEMORY)
    assert time.perf_counter() - start < FAST
    assert_silent(capfd)


@pytest.mark.parametrize("value, message", [
    (0, r"max_memory must be > 0 bytes"), (-5, r"max_memory must be > 0 bytes"),
    (float("nan"), r"max_memory must be > 0 bytes"), ("1G", r"max_memory must be a number of bytes > 0, got '1G'"),
])
def test_load_mesh_memory_limit_is_validated_by_name(tmp_path, value, message):
    path = surface_ply(tmp_path / "tri.ply")
    with pytest.raises(csb.ParameterError, match=message):
        csb.load_mesh(path, max_memory=value)
    assert len(csb.load_mesh(path, max_memory=SMALL_MEMORY).triangles) == 1


@reaches_memory_cap
@pytest.mark.parametrize("binary", [False, True])
def test_a_ply_face_declaring_a_billion_indices_hits_the_memory_limit(tmp_path, capfd, binary):
    """A 3-vertex PLY whose one face declares 10^9 indices (int counts): Assimp reserves 4 GB
    for them. The header is consistent, so only the limit stops it; the default 2 GiB does too."""
    header = ("ply\nformat {} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list int int vertex_indices\nend_header\n")
    path = tmp_path / "billion.ply"
    if binary:
        path.write_bytes(header.format("binary_little_endian").encode() + struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
                         + struct.pack("<4i", 10**9, 0, 1, 2))
    else:
        path.write_text(header.format("ascii") + "0 0 0\n1 0 0\n0 1 0\n1000000000 0 1 2\n")
    for limit in (SMALL_MEMORY, 2 * 1024**3):
        start = time.perf_counter()
        with pytest.raises(csb.MeshError, match=re.escape(str(path)) + r": reading the file needed more than the "
                           rf"max_memory limit of {limit} bytes"):
            csb.load_mesh(path, max_memory=limit)
        assert time.perf_counter() - start < FAST
    assert_silent(capfd)
