"""A csb.MeshWarning points at the user's line, the call into csb, not at the csb source line
that found the problem (however deep in csb that was: a loader, the builder, a scene's build)."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import meshio
import numpy as np
import pytest

import csb

HERE = Path(__file__).resolve()


def line() -> int:
    """The caller's current line number."""
    return sys._getframe(1).f_lineno


def assert_points_here(record: pytest.WarningsRecorder, lineno: int) -> None:
    got = [(w.category, Path(w.filename).resolve(), w.lineno) for w in record]
    assert got and all(g == (csb.MeshWarning, HERE, lineno) for g in got), got


def slivers() -> tuple[np.ndarray, np.ndarray]:
    """A triangle and two degenerate ones (collinear; a zero-length edge): two MeshWarnings' worth."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 0, 0]], float)
    return v, np.array([[0, 1, 2], [0, 1, 3], [1, 4, 2]], np.int32)


@pytest.fixture
def slivers_ply(tmp_path) -> Path:
    v, tris = slivers()
    path = tmp_path / "slivers.ply"
    meshio.write(path, meshio.Mesh(v, [("triangle", tris)]))
    return path


def test_load_mesh_and_clean_warn_at_the_call(slivers_ply):
    with pytest.warns(csb.MeshWarning) as record:  # the degenerate triangles, then the vertex they alone used
        at, _ = line(), csb.load_mesh(slivers_ply)
    assert_points_here(record, at)
    assert any("degenerate" in str(w.message) for w in record)
    with pytest.warns(csb.MeshWarning) as record:
        at, _ = line(), csb.clean(csb.Mesh(*slivers(), name="slivers"))
    assert_points_here(record, at)
    assert any("degenerate" in str(w.message) for w in record)


def test_the_builder_warns_at_the_call():
    b = csb.ModelBuilder()
    with pytest.warns(csb.MeshWarning, match="degenerate") as record:
        at, _ = line(), b.add_mesh(csb.Mesh(*slivers(), name="slivers"), particle_mass=1.0)
    assert_points_here(record, at)
    m = csb.tet_box([1.0, 1.0, 1.0], [1, 1, 1])
    tets = m.tets.copy()
    tets[1] = tets[1][[0, 1, 3, 2]]
    with pytest.warns(csb.MeshWarning, match="inverted") as record:
        at, _ = line(), b.add_tet_mesh(csb.TetMesh(m.points, tets, name="inside_out"), mass=1.0)
    assert_points_here(record, at)


def test_load_tet_mesh_warns_at_the_call(tmp_path):
    m = csb.tet_box([1.0, 1.0, 1.0], [1, 1, 1])
    path = tmp_path / "extra_point.vtu"
    meshio.write(path, meshio.Mesh(np.vstack([m.points, [[5.0, 5.0, 5.0]]]), [("tetra", m.tets)]))
    with pytest.warns(csb.MeshWarning, match="1 points that no tet uses") as record:
        at, _ = line(), csb.load_tet_mesh(path)
    assert_points_here(record, at)


def test_a_scene_build_warns_at_the_call(tmp_path, slivers_ply):
    path = tmp_path / "scene.toml"
    path.write_text(textwrap.dedent("""\
        [scene]
        name = "slivers"
        duration = 0.1

        [solver]
        dt = 0.01

        [[mesh]]
        name = "slivers"
        file = "slivers.ply"
        particle_mass = 0.01
        stretch = { stiffness = 1.0 }
        """))
    scene = csb.load_scene(path)
    with pytest.warns(csb.MeshWarning) as record:
        at, _ = line(), scene.build()
    assert_points_here(record, at)
    assert any("degenerate" in str(w.message) for w in record)
