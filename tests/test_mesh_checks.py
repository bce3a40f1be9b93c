"""What load_mesh refuses before or after Assimp reads a file, and that each refusal says why:
OFF header counts, free text in a PLY header, motion capture, point clouds, text encodings and
files named without an extension."""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np
import pytest

import csb

TRIANGLE_OBJ = "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n"
TRIANGLE_PLY = ("ply\nformat ascii 1.0\n{extra}element vertex 3\nproperty float x\nproperty float y\n"
                "property float z\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n"
                "0 0 0\n1 0 0\n1 1 0\n3 0 1 2\n")
TRIANGLE_OFF = "OFF\n3 1 0\n0 0 0\n1 0 0\n1 1 0\n3 0 1 2\n"
TRIANGLE_STL = ("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 1 1 0\nendloop\n"
                "endfacet\nendsolid t\n")
BVH = ("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xposition Yposition Zposition\n  JOINT Chest\n  {\n"
       "    OFFSET 0 1 0\n    CHANNELS 3 Zrotation Xrotation Yrotation\n    End Site\n    {\n      OFFSET 0 1 0\n"
       "    }\n  }\n}\nMOTION\nFrames: 1\nFrame Time: 0.033333\n0 0 0 0 0 0\n")


def is_the_triangle(mesh: csb.Mesh) -> bool:
    return (mesh.num_vertices, len(mesh.triangles)) == (3, 1) and np.allclose(
        np.sort(mesh.vertices, axis=0), [[0, 0, 0], [1, 0, 0], [1, 1, 0]])


# --- OFF header counts -------------------------------------------------------------------------
# A count beyond the file's size (each vertex and face takes at least one byte of its own) cannot
# be true; strtoll saturates at 2^63 - 1, and the sum of two such counts overflowed before.


@pytest.mark.parametrize(
    "text, message",
    [
        ("OFF\n9223372036854775807 9223372036854775807 0\n0 0 0\n",
         r"huge\.off:2: OFF header: the vertex count 9223372036854775807 is more than a file of 52 bytes can hold"),
        ("OFF\n99999999999999999999 1 0\n0 0 0\n",
         r"huge\.off:2: OFF header: the vertex count 99999999999999999999 is out of range"),
        ("OFF\n-1 1 0\n0 0 0\n", r"huge\.off:2: OFF header: the vertex count is -1; a count must be >= 0"),
        ("OFF\n-99999999999999999999 1 0\n0 0 0\n", r"huge\.off:2: OFF header: the vertex count is -9+; a count"),
        ("# a comment\nOFF 3 9223372036854775807 0\n0 0 0\n",
         r"huge\.off:2: OFF header: the face count 9223372036854775807 is more than a file of 46 bytes"),
        ("OFF\n3 x 0\n", r"huge\.off:2: OFF header: the face count 'x' is not an integer"),
        ("OFF\n", r"huge\.off: OFF header: expected vertex and face counts after 'OFF'"),
    ],
)
def test_off_header_counts_out_of_range_name_the_line_and_the_count(tmp_path, text, message):
    path = tmp_path / "huge.off"
    path.write_text(text)
    with pytest.raises(csb.MeshError, match=message):
        csb.load_mesh(path)


def test_off_counts_on_the_header_line_still_load(tmp_path):
    path = tmp_path / "one.off"
    path.write_text("OFF 3 1 0\n0 0 0\n1 0 0\n1 1 0\n3 0 1 2\n")
    assert is_the_triangle(csb.load_mesh(path))


# --- PLY header --------------------------------------------------------------------------------


def test_a_ply_header_with_a_bare_text_line_loads(tmp_path):
    # Blender 2.4's exporter wrote this line into the header without 'comment'; Assimp skips it.
    path = tmp_path / "blender.ply"
    path.write_text(TRIANGLE_PLY.format(extra="Created by Blender3D 247 - www.blender.org, source file: ''\n"))
    assert is_the_triangle(csb.load_mesh(path))


# --- motion capture and other skeletons --------------------------------------------------------


def test_motion_capture_files_are_refused_by_name(tmp_path):
    (tmp_path / "walk.bvh").write_text(BVH)
    with pytest.raises(csb.MeshError, match=r"walk\.bvh: is a motion-capture file \(BVH\): it holds a skeleton "
                                            r"and no surface"):
        csb.load_mesh(tmp_path / "walk.bvh")
    (tmp_path / "walk").write_text(BVH)  # no extension: recognised by its first word
    with pytest.raises(csb.MeshError, match=r"walk: is a motion-capture file \(BVH\)"):
        csb.load_mesh(tmp_path / "walk")
    (tmp_path / "walk.csm").write_text("$Filename walk.csm\n$Firstframe 1\n$Lastframe 1\n$Order\nA B\n$Points\n"
                                       "1 0 0 0 1 0 0\n")
    with pytest.raises(csb.MeshError, match=r"walk\.csm: is a motion-capture file \(CSM\)"):
        csb.load_mesh(tmp_path / "walk.csm")


def test_a_skeleton_without_a_surface_in_another_format_is_refused(tmp_path):
    # A Valve SMD with bones and an animation frame but no triangles: Assimp draws 12 placeholder
    # bone faces for it, which are no cloth.
    path = tmp_path / "anim.smd"
    path.write_text('version 1\nnodes\n0 "root" -1\n1 "arm" 0\nend\nskeleton\ntime 0\n0 0 0 0 0 0 0\n'
                    "1 0 1 0 0 0 0\nend\n")
    with pytest.raises(csb.MeshError, match=r"anim\.smd: the file holds a skeleton and no surface"):
        csb.load_mesh(path)


# --- point clouds ------------------------------------------------------------------------------


def gltf_points(path: Path) -> Path:
    """A glTF whose only primitive draws three points (mode 0)."""
    data = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 1, 1, 0)
    path.write_text(json.dumps({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 0}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
        "bufferViews": [{"buffer": 0, "byteLength": len(data)}],
        "buffers": [{"byteLength": len(data),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}]}))
    return path


def test_point_clouds_say_no_triangles_and_how_many_points(tmp_path):
    ply = tmp_path / "cloud.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                   "end_header\n0 0 0\n1 0 0\n1 1 0\n")
    off = tmp_path / "cloud.off"
    off.write_text("OFF\n3 0 0\n0 0 0\n1 0 0\n1 1 0\n")
    # A vertex-only OBJ without an extension: Assimp's own checks fail on it with "Mesh contains
    # no faces"; csb reads it again unprocessed to say what it holds.
    bare = tmp_path / "cloud"
    bare.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\n")
    for path, held in [(ply, "3 points, no faces"), (off, "3 points, no faces"), (bare, "3 points"),
                       (gltf_points(tmp_path / "cloud.gltf"), "3 points")]:
        with pytest.raises(csb.MeshError, match=rf"{path.name}: the file has no triangles \({held}\); csb needs a "
                                                r"surface mesh"):
            csb.load_mesh(path)


# --- text encodings ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, data, encoding",
    [
        ("le.obj", TRIANGLE_OBJ.encode("utf-16"), r"UTF-16 \(little-endian\)"),  # Python writes the LE mark
        ("be.obj", b"\xfe\xff" + TRIANGLE_OBJ.encode("utf-16-be"), r"UTF-16 \(big-endian\)"),
        ("le32.obj", b"\xff\xfe\x00\x00" + TRIANGLE_OBJ.encode("utf-32-le"), r"UTF-32 \(little-endian\)"),
        ("le.off", b"\xff\xfe" + TRIANGLE_OFF.encode("utf-16-le"), r"UTF-16 \(little-endian\)"),
        ("le.stl", b"\xff\xfe" + TRIANGLE_STL.encode("utf-16-le"), r"UTF-16 \(little-endian\)"),
        ("le", b"\xff\xfe" + TRIANGLE_OBJ.encode("utf-16-le"), r"UTF-16 \(little-endian\)"),
    ],
)
def test_utf16_and_utf32_files_name_their_encoding(tmp_path, name, data, encoding):
    (tmp_path / name).write_bytes(data)
    with pytest.raises(csb.MeshError, match=rf"{name}: the file is {encoding} text .*save it as UTF-8"):
        csb.load_mesh(tmp_path / name)


def test_a_utf8_mark_is_read_past_or_refused_where_assimp_misreads_it(tmp_path):
    bom = b"\xef\xbb\xbf"
    for name, text in [("c.obj", "# exported\n" + TRIANGLE_OBJ), ("t.off", TRIANGLE_OFF), ("t.stl", TRIANGLE_STL)]:
        (tmp_path / name).write_bytes(bom + text.encode())
        assert is_the_triangle(csb.load_mesh(tmp_path / name)), name
    # Assimp's OBJ reader keeps the mark in the first word (the first vertex would be lost) and
    # its PLY reader refuses it.
    (tmp_path / "v.obj").write_bytes(bom + TRIANGLE_OBJ.encode())
    with pytest.raises(csb.MeshError, match=r"v\.obj:1: the file starts with a UTF-8 byte-order mark, which "
                                            r"Assimp's OBJ reader takes as part of this line's first word"):
        csb.load_mesh(tmp_path / "v.obj")
    (tmp_path / "m.ply").write_bytes(bom + TRIANGLE_PLY.format(extra="").encode())
    with pytest.raises(csb.MeshError, match=r"m\.ply: the file starts with a UTF-8 byte-order mark before 'ply'"):
        csb.load_mesh(tmp_path / "m.ply")


# --- files named without an extension ----------------------------------------------------------


def test_files_without_an_extension_are_read_by_their_content(tmp_path):
    for name, text in [("obj", TRIANGLE_OBJ), ("ply", TRIANGLE_PLY.format(extra="")), ("off", TRIANGLE_OFF)]:
        (tmp_path / f"{name}_cloth").write_text(text)
        assert is_the_triangle(csb.load_mesh(tmp_path / f"{name}_cloth")), name
    csb.save_mesh(csb.cloth_grid(1.0, 1.0, 3, 3, plane="xy"), str(tmp_path / "cloth.3ds"))  # binary
    (tmp_path / "cloth.3ds").rename(tmp_path / "3ds_cloth")
    mesh = csb.load_mesh(tmp_path / "3ds_cloth")
    assert (mesh.num_vertices, len(mesh.triangles)) == (9, 8)
    # The pre-checks run on what the first word names: a truncated PLY is caught as with '.ply'.
    (tmp_path / "cut").write_text(TRIANGLE_PLY.format(extra="")[:60])
    with pytest.raises(csb.MeshError, match=r"cut: PLY header is truncated"):
        csb.load_mesh(tmp_path / "cut")


def test_a_file_without_an_extension_that_assimp_does_not_recognise(tmp_path):
    (tmp_path / "noise").write_bytes(bytes(range(256)) * 4)
    with pytest.raises(csb.MeshError, match=r"noise: the file has no extension and Assimp did not recognise its "
                                            r"content \(.*\); name it with its format's extension \(csb reads "
                                            r".*\.glb .*\.obj"):
        csb.load_mesh(tmp_path / "noise")


THREE_MF_MODEL = """<?xml version="1.0" encoding="UTF-8"?>
<model unit="meter" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02">
 <resources><object id="1" type="model"><mesh>
  <vertices><vertex x="0" y="0" z="0"/><vertex x="1" y="0" z="0"/><vertex x="1" y="1" z="0"/></vertices>
  <triangles><triangle v1="0" v2="1" v3="2"/></triangles>
 </mesh></object></resources>
 <build><item objectid="1"/></build>
</model>
"""


def write_3mf(path):
    """A minimal 3MF package (Assimp 5.2 does not read back the 3MF its own exporter writes)."""
    import zipfile

    with zipfile.ZipFile(path, "w") as z:
        z.writestr("[Content_Types].xml", '<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.'
                   'openxmlformats.org/package/2006/content-types"><Default Extension="rels" ContentType="application/'
                   'vnd.openxmlformats-package.relationships+xml"/><Default Extension="model" ContentType="application/'
                   'vnd.ms-package.3dmanufacturing-3dmodel+xml"/></Types>')
        z.writestr("_rels/.rels", '<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.'
                   'openxmlformats.org/package/2006/relationships"><Relationship Target="/3D/3dmodel.model" Id="r0" '
                   'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>')
        z.writestr("3D/3dmodel.model", THREE_MF_MODEL)


def test_formats_assimp_knows_by_extension_only_are_read_by_their_signature(tmp_path):
    """Assimp 5.2 recognises GLB, STL, X3D and 3MF by their extensions only; csb knows them by
    their content (GLB's magic, a binary STL's size matching its triangle count or an ASCII STL's
    'solid', an <X3D element, a zip holding 3D/3dmodel.model) and reads them through a link that
    has the extension, removed afterwards."""
    import tempfile

    before = set(Path(tempfile.gettempdir()).glob("csb-mesh-*"))
    grid = csb.cloth_grid(1.0, 1.0, 3, 3, plane="xy")
    for ext in ("glb", "stl", "x3d"):
        csb.save_mesh(grid, str(tmp_path / f"cloth.{ext}"))
        (tmp_path / f"cloth.{ext}").rename(tmp_path / f"{ext}_cloth")
        mesh = csb.load_mesh(tmp_path / f"{ext}_cloth")
        assert (mesh.num_vertices, len(mesh.triangles)) == (9, 8), ext
    (tmp_path / "ascii_stl").write_text(TRIANGLE_STL)
    assert is_the_triangle(csb.load_mesh(tmp_path / "ascii_stl"))
    write_3mf(tmp_path / "print.3mf")
    assert is_the_triangle(csb.load_mesh(tmp_path / "print.3mf"))
    (tmp_path / "print.3mf").rename(tmp_path / "print")
    assert is_the_triangle(csb.load_mesh(tmp_path / "print"))
    assert set(Path(tempfile.gettempdir()).glob("csb-mesh-*")) == before
    # What the link reads is still checked: a damaged GLB without an extension is an error naming the file.
    (tmp_path / "broken").write_bytes((tmp_path / "glb_cloth").read_bytes()[:40])
    with pytest.raises(csb.MeshError, match=r"broken: "):
        csb.load_mesh(tmp_path / "broken")


@pytest.mark.parametrize("name, codec, order", [("le.obj", "utf-16-le", "little"), ("be.off", "utf-16-be", "big"),
                                                ("le", "utf-16-le", "little")])
def test_utf16_without_a_byte_order_mark_is_named(tmp_path, name, codec, order):
    text = TRIANGLE_OFF if name.endswith(".off") else TRIANGLE_OBJ
    (tmp_path / name).write_bytes(text.encode(codec))
    with pytest.raises(csb.MeshError, match=rf"{name}: the file looks like UTF-16 \({order}-endian\) text without a "
                                            r"byte-order mark .*save it as UTF-8"):
        csb.load_mesh(tmp_path / name)
