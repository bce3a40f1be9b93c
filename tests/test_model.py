"""Building models: particles from meshes, masses, groups, constraints and their bad input."""

from __future__ import annotations

import numpy as np
import pytest

import csb
from helpers import cloth_model


def test_cloth_grid_topology_and_rest_values():
    n = 9
    model = cloth_model(n)
    edges = 2 * n * (n - 1) + (n - 1) ** 2  # rows, columns, one diagonal per quad
    interior = edges - 4 * (n - 1)
    assert model.num_particles == n * n
    assert len(model.distance["rest_length"]) == edges
    assert len(model.bending["rest_angle"]) == interior
    x = model.rest_positions
    pairs = model.distance["particles"]
    np.testing.assert_allclose(model.distance["rest_length"], np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1))
    assert np.all(model.bending["rest_angle"] == 0.0)  # flat at rest
    assert np.all(model.distance["sense"] == 0)
    assert np.count_nonzero(model.inv_mass == 0) == 2


def test_mass_by_total_density_and_particle():
    mesh = csb.cloth_grid(2.0, 0.5, 11, 6)
    for kwargs, total in [(dict(mass=0.3), 0.3), (dict(density=0.2), 0.2 * 2.0 * 0.5), (dict(particle_mass=0.01), 0.66)]:
        b = csb.ModelBuilder()
        b.add_mesh(mesh, **kwargs)
        m = b.build().mass
        assert m.sum() == pytest.approx(total, rel=1e-12)
    # Lumped area, a third of each adjacent triangle: with alternating diagonals the corner
    # vertex 0 touches the two triangles of its quad, the interior vertex (1, 1) eight.
    b = csb.ModelBuilder()
    b.add_mesh(mesh, density=1.0)
    m = b.build().mass
    cell = (2.0 / 10) * (0.5 / 5)
    assert m[0] == pytest.approx(2 * cell / 2 / 3, rel=1e-12) and m[12] == pytest.approx(8 * cell / 2 / 3, rel=1e-12)


def test_line_meshes_lump_length():
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(4, 0.25), density=2.0)  # kg/m
    m = b.build().mass
    np.testing.assert_allclose(m, [0.25, 0.5, 0.5, 0.5, 0.25])


def test_groups_let_meshes_differ_in_mass():
    b = csb.ModelBuilder()
    heavy = b.add_mesh(csb.cloth_grid(1, 1, 3, 3), particle_mass=2.0)
    light = b.add_mesh(csb.cloth_grid(1, 1, 3, 3, center=(0, 1, 0)), particle_mass=0.5)
    shared = b.add_group("shared")
    extra = b.add_mesh(csb.chain(2, 0.1), group=shared, particle_mass=0.1)
    model = b.build()
    assert model.group_names == ["cloth_grid(3x3)", "cloth_grid(3x3)", "shared"]
    assert np.array_equal(model.group[heavy.particles], [0] * 9)
    assert np.array_equal(model.group[light.particles], [1] * 9)
    assert np.array_equal(model.group[extra.particles], [2] * 3)
    assert np.all(model.mass[heavy.particles] == 2.0) and np.all(model.mass[light.particles] == 0.5)
    assert light.first_particle == 9 and extra.first_particle == 18


def test_only_declared_constraints_are_built():
    mesh = csb.cloth_grid(1, 1, 4, 4)
    b = csb.ModelBuilder()
    inst = b.add_mesh(mesh, mass=1.0, stretch_stiffness=None)
    model = b.build()
    assert model.num_constraints == 0 and inst.num_distance == 0 and inst.num_bending == 0


def test_compliance_is_stored_per_constraint():
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1, 1, 3, 3), mass=1.0, stretch_compliance=1e-4, bending_stiffness=0.5,
               bending_compliance=0.2)
    model = b.build()
    assert np.all(model.distance["compliance"] == 1e-4) and np.all(model.bending["compliance"] == 0.2)
    assert np.all(model.distance["stiffness"] == 1.0) and np.all(model.bending["stiffness"] == 0.5)


def test_springs_pins_and_attachments():
    b = csb.ModelBuilder()
    g = b.add_group("g")
    for x in ([0, 0, 0], [1, 0, 0], [2, 0, 0]):
        b.add_particle(x, 1.0, g)
    assert b.add_distance(0, 1, stiffness=0.3) == 0
    assert b.add_distance(1, 2, stiffness=1.0, rest_length=0.5, sense="<=") == 1
    b.pin(0)
    assert b.attach(2, [2, 1, 0], stiffness=0.5) == 0
    model = b.build()
    np.testing.assert_array_equal(model.distance["sense"], [0, -1])
    np.testing.assert_array_equal(model.distance["stiffness"], [0.3, 1.0])
    np.testing.assert_array_equal(model.attachments["target"], [[2, 1, 0]])
    np.testing.assert_array_equal(model.inv_mass, [0, 1, 1])
    np.testing.assert_array_equal(model.mass, [1, 1, 1])  # a pin keeps the mass it was given
    # The attachment pulls particle 2 towards its target, the pin holds particle 0.
    state = model.initial_state()
    csb.PbdStepper(dt=0.01, gravity=(0, 0, 0), iterations=20).step(model, state, 200)
    assert np.array_equal(state.x[0], [0, 0, 0])
    assert state.x[2, 1] > 0.5


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda b: b.add_particle([0, 0, 0], 0.0, 0), r"particle 3: mass must be > 0 kg, got 0"),
        (lambda b: b.add_particle([0, 0, 0], -1.0, 0), r"mass must be > 0 kg, got -1"),
        (lambda b: b.add_particle([0, 0, 0], float("nan"), 0), r"mass must be > 0 kg"),
        (lambda b: b.add_particle([0, np.nan, 0], 1.0, 0), r"particle 3: position must be finite"),
        (lambda b: b.add_particle([0, 0, 0], 1.0, 5), r"group 5 does not exist"),
        (lambda b: b.add_distance(0, 7), r"distance constraint 0 \(particles 0, 7\): particle index 7 is out of range"),
        (lambda b: b.add_distance(0, 0), r"needs two different particles"),
        (lambda b: b.add_distance(0, 1, stiffness=1.5), r"stiffness must be in \[0, 1\], got 1.5"),
        (lambda b: b.add_distance(0, 1, stiffness=-0.1), r"stiffness must be in \[0, 1\], got -0.1"),
        (lambda b: b.add_distance(0, 1, sense="<"), r"sense must be '=='"),
        (lambda b: b.add_distance(0, 1, rest_length=0.0), r"zero rest length"),
        (lambda b: b.add_distance(0, 1, compliance=-1e-3), r"compliance must be a finite number >= 0 \(0: hard\), got -0.001"),
        (lambda b: b.attach(0, [0, 0, 0], compliance=float("nan")), r"compliance must be a finite number >= 0"),
        (lambda b: b.add_bending(0, 1, 2, 2, stiffness=0.5), r"needs four different particles"),
        (lambda b: b.pin(3), r"pin: particle index 3 is out of range \(the model has 3 particles\)"),
        (lambda b: b.pin(-1), r"pin: i must be an integer in \[0, 2147483647\], got -1"),
        (lambda b: b.attach(0, [0, np.inf, 0]), r"attachment 0 \(particle 0\): target must be finite"),
        (lambda b: b.attach(0, [0, 0, 0], stiffness=2.0), r"stiffness must be in \[0, 1\], got 2"),
    ],
)
def test_bad_parameters_name_what_is_wrong(call, message):
    b = csb.ModelBuilder()
    g = b.add_group("g")
    for x in ([0, 0, 0], [1, 0, 0], [0, 1, 0]):
        b.add_particle(x, 1.0, g)
    with pytest.raises(csb.ParameterError, match=message):
        call(b)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(), r"give exactly one of mass \(kg\), density \(kg/m\^2\) or particle_mass \(kg\)"),
        (dict(mass=1.0, density=1.0), r"give exactly one of"),
        (dict(mass=0.0), r"cloth_grid\(3x3\): mass must be > 0 kg, got 0"),
        (dict(density=-1.0), r"density must be > 0 kg/m\^2, got -1"),
        (dict(particle_mass=float("inf")), r"particle mass must be > 0 kg, got inf"),
        (dict(mass=1.0, stretch_stiffness=1.2), r"cloth_grid\(3x3\) stretch: stiffness must be in \[0, 1\], got 1.2"),
        (dict(mass=1.0, bending_stiffness=-1.0), r"bending: stiffness must be in \[0, 1\], got -1"),
        (dict(mass=1.0, stretch_compliance=-1.0), r"stretch: compliance must be a finite number >= 0"),
    ],
)
def test_bad_mesh_options(kwargs, message):
    with pytest.raises(csb.ParameterError, match=message):
        csb.ModelBuilder().add_mesh(csb.cloth_grid(1, 1, 3, 3), **kwargs)


def test_a_vertex_without_area_gets_no_mass_from_mass_or_density():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], float)
    mesh = csb.Mesh(v, np.array([[0, 1, 2]]), name="stray")
    with pytest.raises(csb.MeshError, match=r"stray: vertex 3 belongs to no triangle"):
        csb.ModelBuilder().add_mesh(mesh, mass=1.0)
    b = csb.ModelBuilder()
    assert b.add_mesh(mesh, particle_mass=1.0).num_particles == 4  # kept: the user asked for it


def test_empty_model_is_refused():
    with pytest.raises(csb.ParameterError, match="the model has no particles"):
        csb.ModelBuilder().build()


def test_shapes_refuse_impossible_sizes():
    with pytest.raises(csb.ParameterError, match=r"cloth_grid: width must be > 0 m, got -1"):
        csb.cloth_grid(-1, 1, 4, 4)
    with pytest.raises(csb.ParameterError, match=r"cloth_grid: nx must be an integer in \[2, 2147483647\], got 1"):
        csb.cloth_grid(1, 1, 1, 4)
    with pytest.raises(csb.ParameterError, match=r"chain: link_length must be > 0 m"):
        csb.chain(3, 0.0)
    with pytest.raises(csb.ParameterError, match=r"plane must be 'xy', 'xz' or 'yz', got 'xx'"):
        csb.cloth_grid(1, 1, 4, 4, plane="xx")
    with pytest.raises(csb.ParameterError, match=r"rotate must be 3 finite angles in rad"):
        csb.transformed(csb.chain(2, 1.0), rotate=(0, np.nan, 0))
