"""Choosing particles by region (box, sphere, half-space, distance to a line), by mask, index array
or Python predicate, in Python and in scene files; a selection that catches nothing is an error
that says so."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

import csb

ROOT = Path(__file__).resolve().parents[1]


def grid():
    """An 11 x 11 cloth of 1 m in the xz plane at y = 0: vertices on a 0.1 m lattice from -0.5 to
    0.5, vertex i at x = -0.5 + 0.1 (i % 11), z = -0.5 + 0.1 (i // 11)."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, 11, 11), density=0.2)
    return b, inst


def lattice(inst):
    """Each vertex's (column, row) on the 0.1 m lattice."""
    v = inst.vertices
    return np.rint((v[:, 0] + 0.5) / 0.1).astype(int), np.rint((v[:, 2] + 0.5) / 0.1).astype(int)


def test_each_region_catches_exactly_the_vertices_inside_it():
    b, inst = grid()
    col, row = lattice(inst)
    first = inst.first_particle
    # The row at z = -0.5 (boundary included) and nothing else.
    got = inst.select(csb.Box([-1, -0.01, -0.5], [1, 0.01, -0.45]))
    assert got.tolist() == (first + np.flatnonzero(row == 0)).tolist()
    # The centre and its four neighbours at 0.1 m (the diagonals at 0.141 m are out).
    got = inst.select(csb.Sphere([0, 0, 0], 0.11))
    assert sorted(got - first) == sorted(np.flatnonzero((col - 5) ** 2 + (row - 5) ** 2 <= 1))
    # x >= 0.3 (columns 8, 9, 10), the plane through a vertex column included.
    got = inst.select(csb.HalfSpace([0.3, 0, 0], [2, 0, 0]))
    assert sorted(got - first) == sorted(np.flatnonzero(col >= 8))
    # Within 0.05 m of the diagonal line x = z: the diagonal's 11 vertices (the next at 0.0707 m).
    got = inst.select(csb.NearLine([0, 0, 0], [1, 0, 1], 0.05))
    assert sorted(got - first) == sorted(np.flatnonzero(col == row))
    # The segment from the centre towards the far corner only: 6 of them.
    got = inst.select(csb.NearLine([0, 0, 0], [0.5, 0, 0.5], 0.05, segment=True))
    assert sorted(got - first) == sorted(np.flatnonzero((col == row) & (col >= 5)))
    # A union, each vertex once.
    got = inst.select(csb.Sphere([-0.5, 0, -0.5], 0.01) | csb.Sphere([0.5, 0, -0.5], 0.01) | csb.Sphere([-0.5, 0, -0.5], 0.01))
    assert sorted(got - first) == sorted(np.flatnonzero(((col == 0) | (col == 10)) & (row == 0)))


def test_masks_index_arrays_and_predicates_select_too():
    b, inst = grid()
    col, row = lattice(inst)
    first = inst.first_particle
    assert inst.select(lambda x: x[:, 0] > 0.35).tolist() == (first + np.flatnonzero(col >= 9)).tolist()
    assert inst.select(row == 10).tolist() == (first + np.flatnonzero(row == 10)).tolist()
    assert inst.select([7, 3, 3]).tolist() == [first + 3, first + 7]
    # The predicate gets a copy: it cannot move the mesh's vertices.
    before = inst.vertices.copy()

    def meddle(x):
        x += 1.0
        return x[:, 0] > 0

    inst.select(meddle)
    assert np.array_equal(inst.vertices, before)


def test_pinning_a_selection_fixes_those_particles_and_no_others():
    b, inst = grid()
    col, row = lattice(inst)
    b.pin(inst.select(csb.Box([-1, -1, 0.45], [1, 1, 1])))
    model = b.build()
    fixed = np.asarray(model.inv_mass) == 0
    assert np.array_equal(fixed, row == 10)
    state = model.initial_state()
    csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=4, iterations=2).step(model, state, 10)
    x = np.asarray(state.x)
    assert np.array_equal(x[fixed], inst.vertices[row == 10])  # held where they were
    assert np.all(x[~fixed, 1] < 0)  # the rest fell


@pytest.mark.parametrize("what,message", [
    (csb.Box([2, 2, 2], [3, 3, 3]), r"Box\(lo=\(2.0, 2.0, 2.0\), hi=\(3.0, 3.0, 3.0\)\) caught 0 of the 121 vertices of mesh 'cloth_grid\(11x11\)', which spans \[-0.5, 0.0, -0.5\] to \[0.5, 0.0, 0.5\] m"),
    (lambda x: x[:, 1] > 1, r"the predicate <lambda> caught 0 of the 121 vertices"),
    (np.zeros(121, bool), r"the mask caught 0 of the 121 vertices"),
    ([], r"the index array caught 0 of the 121 vertices"),
])
def test_a_selection_that_catches_nothing_says_so(what, message):
    b, inst = grid()
    with pytest.raises(csb.ParameterError, match=message):
        inst.select(what)


@pytest.mark.parametrize("make,message", [
    (lambda: csb.Box([0, 0, 0], [1, -1, 1]), r"Box: lo \[0.0, 0.0, 0.0\] must not exceed hi \[1.0, -1.0, 1.0\]"),
    (lambda: csb.Box([0, 0, float("nan")], [1, 1, 1]), r"Box: lo must be 3 finite coordinates in m"),
    (lambda: csb.Sphere([0, 0, 0], 0.0), r"Sphere: radius must be a distance > 0 m, got 0.0"),
    (lambda: csb.Sphere([0, 0, 0], float("inf")), r"Sphere: radius must be a distance > 0 m"),
    (lambda: csb.Sphere([0, 0], 1.0), r"Sphere: center must be 3 finite coordinates"),
    (lambda: csb.HalfSpace([0, 0, 0], [0, 0, 0]), r"HalfSpace: normal must not be zero"),
    (lambda: csb.NearLine([1, 2, 3], [1, 2, 3], 0.1), r"NearLine: a and b must differ"),
    (lambda: csb.NearLine([0, 0, 0], [1, 0, 0], -1), r"NearLine: distance must be a distance > 0 m"),
])
def test_impossible_regions_are_refused_by_name(make, message):
    with pytest.raises(csb.ParameterError, match=message):
        make()


@pytest.mark.parametrize("what,message", [
    (lambda x: x[:, 0], r"must return 121 booleans for the 121 vertices"),
    (lambda x: True, r"must return 121 booleans"),
    (np.ones(5, bool), r"a mask must have one entry per vertex of mesh 'cloth_grid\(11x11\)' \(121\), got shape \(5,\)"),
    ([0, 121], r"vertex 121 is out of range: mesh 'cloth_grid\(11x11\)' has 121 vertices"),
    ([-1], r"vertex -1 is out of range"),
    ([0.5, 1.5], r"cannot select vertices"),
    ("collar", r"cannot select vertices"),
])
def test_malformed_selections_are_refused_by_name(what, message):
    b, inst = grid()
    with pytest.raises(csb.ParameterError, match=message):
        inst.select(what)


def test_pin_takes_an_index_array_and_refuses_anything_else():
    b, inst = grid()
    b.pin(np.array([0, 5], dtype=np.int64))
    b.pin(7)
    with pytest.raises(csb.ParameterError, match="pin: give a particle index or a 1-D array"):
        b.pin(np.zeros((2, 2), dtype=int))
    with pytest.raises(csb.ParameterError, match="pin"):
        b.pin(10**6)
    assert np.flatnonzero(np.asarray(b.build().inv_mass) == 0).tolist() == [0, 5, 7]


SCENE = """\
[scene]
name = "regions"
duration = 0.1

[solver]
dt = 0.01
substeps = 2
iterations = 2

[[mesh]]
name = "cloth"
shape = "cloth"
size = [1.0, 1.0]
resolution = [11, 11]
density = 0.2
translate = [0.0, 1.0, 0.0]
stretch = { stiffness = 1.0 }
{pin}
"""


def scene(tmp_path: Path, pin: str) -> Path:
    path = tmp_path / "regions.toml"
    path.write_text(SCENE.replace("{pin}", pin))
    return path


@pytest.mark.parametrize("pin,rows", [
    ('pin = { box = { min = [-1.0, 0.9, -0.51], max = [1.0, 1.1, -0.49] } }', [0]),
    ('pin = { half_space = { point = [0.0, 0.0, 0.45], normal = [0.0, 0.0, 1.0] } }', [10]),
    ('pin = { near_line = { a = [-0.5, 1.0, -0.5], b = [0.5, 1.0, -0.5], distance = 0.01 } }', [0]),
    # A union with indices: row 0 by a box, row 10 by a sphere about each of its ends and the indices between.
    ('pin = { box = { min = [-1.0, 0.9, -0.51], max = [1.0, 1.1, -0.49] }, indices = [111, 112, 113, 114, 115, 116, 117, 118, 119], '
     'sphere = { center = [-0.5, 1.0, 0.5], radius = 0.01 }, near = [[0.5, 1.0, 0.5]] }', [0, 10]),
])
def test_a_scene_pins_by_region(tmp_path, pin, rows):
    sim = csb.load_scene(scene(tmp_path, pin)).build()
    fixed = np.asarray(sim.model.inv_mass) == 0
    row = np.rint((np.asarray(sim.state.x)[:, 2] + 0.5) / 0.1).astype(int)
    assert np.array_equal(fixed, np.isin(row, rows))


@pytest.mark.parametrize("pin,message", [
    ('pin = { box = { min = [2.0, 2.0, 2.0], max = [3.0, 3.0, 3.0] } }',
     r"regions.toml: mesh 'cloth' pin.box: Box\(.*\) caught 0 of the 121 vertices of mesh 'cloth', which spans "
     r"\[-0.5, 1.0, -0.5\] to \[0.5, 1.0, 0.5\] m"),
    ('pin = { sphere = { center = [0.0, 1.0, 0.0], radius = -1.0 } }',
     r"regions.toml:\d+: mesh\[0\] \(cloth\).pin.sphere: Sphere: radius must be a distance > 0 m, got -1.0"),
    ('pin = { box = { min = [0.0, 0.0, 0.0], max = [1.0, 1.0, 1.0], centre = [0.0, 0.0, 0.0] } }',
     r"pin.box.centre: unknown key; expected one of: max, min"),
    ('pin = { half_space = { point = [0.0, 0.0, 0.0] } }', r"pin.half_space: missing key 'normal'"),
    ('pin = { cylinder = { a = [0.0, 0.0, 0.0] } }',
     r"mesh\[0\] \(cloth\).pin: give 'indices' \(vertex numbers\), 'near' \(points in m\), 'material' \(a material's "
     r"name in the file\) or a region: 'box', 'sphere', 'half_space' or 'near_line'"),
    ('pin = { indices = [0], cylinder = { a = [0.0, 0.0, 0.0] } }', r"pin.cylinder: unknown key"),
])
def test_a_scene_region_that_is_wrong_or_catches_nothing_is_an_error_naming_it(tmp_path, pin, message):
    with pytest.raises(csb.SceneError, match=message):
        csb.load_scene(scene(tmp_path, pin)).build()


def test_the_readme_pin_examples_run_as_written(tmp_path, capsys):
    """The README's Python example pins what its comment says, and each of its scene lines pins
    particles of the scene above."""
    text = (ROOT / "README.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "csb.Box(" in b]
    exec(compile(block, "README.md", "exec"), {})
    assert capsys.readouterr().out == "26 pinned\n"
    (toml,) = [b for b in re.findall(r"```toml\n(.*?)```", text, re.S) if "box = {" in b]
    lines = [line for line in toml.splitlines() if line.startswith("pin = ")]
    assert len(lines) == 4
    for line in lines:
        sim = csb.load_scene(scene(tmp_path, line)).build()
        assert (np.asarray(sim.model.inv_mass) == 0).sum() > 0
