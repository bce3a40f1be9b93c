"""Static colliders: contacts generated along x -> p after the prediction (Müller 2007 §4.3),
checked against exact signed distances written in numpy (csb.studies.collisions), not the
library's own geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

import csb
from csb.studies import collisions as cs

METHODS = ("pbd", "xpbd", "jakobsen")
# A contact leaves the particle on the collider's tangent plane (outside a convex collider) up to
# the round-off of the projection, a few ulps of coordinates of about 1 m: 1e-12 m is 4500 ulps.
ROUND_OFF = 1e-12


def test_exact_signed_distances_of_the_checks_themselves():
    """The numpy distances the other tests trust, on points whose distance is known by hand."""
    sphere = dict(kind="sphere", center=np.zeros(3), radius=0.5)
    assert cs.signed_distance(sphere, [[0, 2, 0], [0.1, 0, 0]]) == pytest.approx([1.5, -0.4])
    capsule = dict(kind="capsule", a=np.zeros(3), b=np.array([1.0, 0, 0]), radius=0.2)
    assert cs.signed_distance(capsule, [[0.5, 1, 0], [2, 0, 0], [0.5, 0.1, 0]]) == pytest.approx([0.8, 0.8, -0.1])
    c, s = math.cos(0.3), math.sin(0.3)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    box = dict(kind="box", center=np.ones(3), half_extents=np.array([0.5, 0.2, 0.1]), rotation=rot)
    corner = np.ones(3) + rot @ np.array([0.5, 0.2, 0.1])
    assert cs.signed_distance(box, [corner + rot @ np.array([0.3, 0.4, 0.0])]) == pytest.approx([0.5])
    assert cs.signed_distance(box, [np.ones(3)]) == pytest.approx([-0.1])
    plane = dict(kind="plane", point=np.zeros(3), normal=np.array([0, 1.0, 0]))
    assert cs.signed_distance(plane, [[3, -2, 1]]) == pytest.approx([-2])


@pytest.mark.parametrize("kind", cs.KINDS)
@pytest.mark.parametrize("method", METHODS)
def test_particles_thrown_at_a_collider_never_end_a_step_inside(kind, method):
    penetration, touched = cs.max_penetration_history(kind, method, friction_static=0.5, friction_kinetic=0.4,
                                                      restitution=0.3)
    # They did reach it: on the plane and the mesh's flat lid all 36 come to rest; on the curved
    # and tilted tops (sphere 23, capsule and box 20) the others slide or bounce off the steep sides.
    assert touched >= (36 if kind in ("plane", "mesh") else 18)
    assert penetration.max() <= ROUND_OFF


@pytest.mark.parametrize("solver", ["jacobi", "jacobi-summed"])
def test_jacobi_keeps_free_particles_out(solver):
    # A free particle has only its contact: averaged or summed, the correction is the contact's.
    penetration, touched = cs.max_penetration_history("sphere", "pbd", solver=solver, friction_static=0.5,
                                                      friction_kinetic=0.4)
    assert touched >= 18 and penetration.max() <= ROUND_OFF


@pytest.mark.parametrize("method", METHODS)
def test_a_cloth_draped_on_a_sphere_stays_outside(method):
    """Gauss-Seidel projects the contacts after the cloth's constraints: they have the last word."""
    b = csb.ModelBuilder()
    # Both forms of the bending material: PBD and Jakobsen read the stiffness, XPBD the compliance
    # (1/(N m), the cloth_sphere scene's).
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 12, 12, center=[0, 0.6, 0]), mass=0.2, bending_stiffness=0.2,
               bending_compliance=10.0)
    b.add_sphere(center=(0, 0, 0), radius=0.5, friction_static=0.3, friction_kinetic=0.2)
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=2, iterations=10)
    sphere = model.colliders[0]
    for frame in range(90):
        stepper.step(model, state)
        assert cs.signed_distance(sphere, state.x).min() >= -ROUND_OFF
        if frame >= 30:  # draped over the last second: always touching (XPBD's stiff cloth bounces on it)
            assert stepper.contacts()["active"] >= 1
    # the middle of the cloth rests on top of the sphere
    middle = np.argmin(np.linalg.norm(np.asarray(model.rest_positions)[:, [0, 2]], axis=1))
    assert abs(cs.signed_distance(sphere, state.x[middle:middle + 1])[0]) <= 1e-6 and state.x[middle, 1] > 0.49
    assert stepper.contacts()["max_penetration"] <= ROUND_OFF


@pytest.mark.parametrize("kind", ["box", "mesh"])
@pytest.mark.parametrize("method", METHODS)
def test_a_fast_particle_does_not_tunnel_through_a_thin_wall(kind, method):
    # 120 m/s at dt = 1/60 s: 2 m per step, the particle would cross the 1 mm wall (or the sheet)
    # and be 1.7 m past it after one step.
    reached = cs.thin_wall(kind, method)
    wall_front = -0.0005 if kind == "box" else 0.0
    assert reached <= wall_front + ROUND_OFF
    assert reached > wall_front - 1e-6  # it did reach the wall and stopped there


def test_a_collider_mesh_from_a_file(tmp_path):
    path = tmp_path / "crate.stl"
    csb.save_mesh(cs.box_mesh((0, -0.5, 0), (0.5, 0.5, 0.5)), str(path))
    mesh = csb.load_mesh(path)
    b = csb.ModelBuilder()
    g = b.add_group("drops")
    for u in np.linspace(-0.45, 0.45, 5):
        b.add_particle([u, 0.5, 0.3 * u], 0.01, g)
    index = b.add_collider_mesh(mesh, name="crate")
    model = b.build()
    assert model.colliders[index]["kind"] == "mesh" and model.colliders[index]["name"] == "crate"
    assert len(model.colliders[index]["triangles"]) == 12
    state = model.initial_state()
    csb.PbdStepper(dt=1 / 60, substeps=2).step(model, state, 60)
    # at rest on the lid, within the sheet's 1e-9 m skin
    assert np.all(np.abs(state.x[:, 1]) <= 2e-9) and np.all(state.x[:, 1] >= 0)


def test_a_large_collider_mesh_uses_its_grid():
    """A 20 000-triangle sheet and 400 particles resting on it: every particle finds its contact
    through the grid's cells (without the grid this is 5e8 triangle tests; no timing is asserted
    here — timings are for benchmarks)."""
    sheet = csb.cloth_grid(2.0, 2.0, 101, 101)
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 20, 20, center=[0, 0.01, 0]), mass=0.2, thickness=0.005)
    b.add_collider_mesh(sheet)
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=1 / 60, substeps=2)
    stepper.step(model, state, 30)
    assert np.all(state.x[:, 1] >= 0.005 - ROUND_OFF)
    assert stepper.contacts()["count"] == 400


def test_thickness_keeps_particles_away_and_is_per_mesh_and_group():
    b = csb.ModelBuilder()
    a = b.add_mesh(csb.cloth_grid(0.5, 0.5, 4, 4, center=[0, 0.1, 0]), mass=0.1, thickness=0.02)
    c = b.add_mesh(csb.cloth_grid(0.5, 0.5, 4, 4, center=[2, 0.1, 0]), mass=0.1)
    b.set_thickness(c.group, 0.05)
    b.add_plane()
    model = b.build()
    assert np.all(model.thickness[a.particles] == 0.02) and np.all(model.thickness[c.particles] == 0.05)
    assert not model.thickness.flags.writeable
    state = model.initial_state()
    csb.PbdStepper(dt=1 / 60, substeps=2).step(model, state, 60)
    assert np.allclose(state.x[a.particles, 1], 0.02, atol=ROUND_OFF)
    assert np.allclose(state.x[c.particles, 1], 0.05, atol=ROUND_OFF)


def test_colliders_view():
    b = csb.ModelBuilder()
    b.add_group("g")
    b.add_particle([0, 5, 0], 1.0, 0)
    b.add_plane(point=(0, 0, 0), normal=(0, 2, 0), friction_static=0.5, friction_kinetic=0.4, restitution=0.3,
                name="ground")
    b.add_sphere(center=(3, 0, 0), radius=0.5)
    b.add_capsule(a=(0, 0, 3), b=(1, 0, 3), radius=0.1)
    b.add_box(center=(0, 0, -3), half_extents=(1, 2, 3))
    model = b.build()
    plane, sphere, capsule, box = model.colliders
    assert plane["name"] == "ground" and sphere["name"] == "sphere 1"
    assert np.array_equal(plane["normal"], [0, 1, 0])  # normalised
    assert (plane["friction_static"], plane["friction_kinetic"], plane["restitution"]) == (0.5, 0.4, 0.3)
    assert capsule["radius"] == 0.1 and np.array_equal(box["rotation"], np.eye(3))


def bad(call, *words):
    with pytest.raises(csb.ParameterError) as e:
        call()
    for w in words:
        assert w in str(e.value), str(e.value)


def test_bad_colliders_name_the_collider_and_the_parameter():
    b = csb.ModelBuilder()
    bad(lambda: b.add_plane(normal=(0, 0, 0)), "collider 0 (plane)", "normal", "non-zero")
    bad(lambda: b.add_plane(point=(0, math.nan, 0)), "collider 0 (plane)", "point", "finite")
    bad(lambda: b.add_sphere(center=(0, 0, 0), radius=0.0, name="ball"), "collider 0 (sphere 'ball')", "radius")
    bad(lambda: b.add_sphere(center=(0, 0, 0), radius=math.inf), "radius", "finite")
    bad(lambda: b.add_capsule(a=(0, 0, 0), b=(0, 0, 0), radius=0.1), "capsule", "coincide")
    bad(lambda: b.add_capsule(a=(0, 0, 0), b=(1, 0, 0), radius=-1), "capsule", "radius")
    bad(lambda: b.add_box(center=(0, 0, 0), half_extents=(1, 0, 1)), "box", "half_extents[1]")
    bad(lambda: b.add_box(center=(0, 0, 0), half_extents=(1, 1, 1), rotation=np.diag([1.0, 1, -1])), "box", "rotation")
    bad(lambda: b.add_box(center=(0, 0, 0), half_extents=(1, 1, 1), rotation=2 * np.eye(3)), "rotation")
    bad(lambda: b.add_sphere(center=(0, 0, 0), radius=1, friction_static=0.2, friction_kinetic=0.5),
        "sphere", "friction_static (0.2) must be >= friction_kinetic (0.5)")
    bad(lambda: b.add_plane(friction_kinetic=-0.1, friction_static=0.1), "plane", "friction_kinetic", ">= 0")
    bad(lambda: b.add_plane(restitution=1.5), "plane", "restitution", "[0, 1]")
    bad(lambda: b.add_plane(restitution=math.nan), "plane", "restitution", "finite")
    lines = csb.Mesh(np.array([[0.0, 0, 0], [1, 0, 0]]), lines=np.array([[0, 1]]), name="rope.obj")
    bad(lambda: b.add_collider_mesh(lines), "collider 0 (mesh 'rope.obj')", "no (non-degenerate) triangles")
    flat = csb.Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), np.array([[0, 1, 2]]), name="flat.obj")
    bad(lambda: b.add_collider_mesh(flat), "collider 0 (mesh 'flat.obj')")
    with pytest.raises(TypeError):
        b.add_plane((0, 0, 0), (0, 1, 0))  # keyword arguments only
    assert b.num_colliders == 0  # nothing half-added
    g = b.add_group("g")
    bad(lambda: b.set_thickness(g, -0.1), "set_thickness", "thickness", ">= 0")
    bad(lambda: b.set_thickness(7, 0.1), "group 7")
    cloth = csb.cloth_grid(1, 1, 3, 3)
    bad(lambda: b.add_mesh(cloth, mass=1.0, thickness=math.nan), "thickness")


def test_a_particle_starting_inside_a_collider_is_an_error_naming_both():
    b = csb.ModelBuilder()
    g = b.add_group("g")
    b.add_particle([0, 1, 0], 1.0, g)
    b.add_particle([0, 0.2, 0], 1.0, g)
    b.add_sphere(center=(0, 0, 0), radius=0.5, name="ball")
    bad(b.build, "particle 1 starts inside collider 0 (sphere 'ball')", "0.3 m below its surface")
    b.pin(1)  # a pinned particle never moves, and may sit inside
    b.build()


def test_starting_within_the_thickness_is_corrected_by_the_first_step_without_launching():
    b = csb.ModelBuilder()
    g = b.add_group("g")
    b.add_particle([0, 0.004, 0], 1.0, g)
    b.set_thickness(g, 0.01)
    b.add_plane()
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=1 / 60, substeps=1)
    stepper.step(model, state)
    assert state.x[0, 1] == pytest.approx(0.01, abs=ROUND_OFF)
    stepper.step(model, state, 10)
    assert state.x[0, 1] == pytest.approx(0.01, abs=ROUND_OFF)  # rests there


def test_a_particle_moved_inside_during_the_run_is_pushed_out_without_launching():
    """The static fallback (Müller 2007 §4.3): x inside, the contact is at the surface point
    nearest the prediction; the push out gives no normal velocity."""
    b = csb.ModelBuilder()
    g = b.add_group("g")
    b.add_particle([0, 2, 0], 1.0, g)
    b.add_sphere(center=(0, 0, 0), radius=0.5)
    model = b.build()
    state = model.initial_state()
    state.x[0] = (0.0, 0.3, 0.0)  # 0.2 m inside
    stepper = csb.PbdStepper(dt=1 / 60)
    stepper.step(model, state)
    assert np.linalg.norm(state.x[0]) == pytest.approx(0.5, abs=ROUND_OFF)
    assert state.v[0, 1] <= 0  # not thrown up at 0.2 m / (1/60 s) = 12 m/s
    assert stepper.contacts()["count"] == 1 and stepper.contacts()["max_depth"] == pytest.approx(0.2 + 9.81 / 3600)


def test_contacts_report_the_last_substep():
    b = csb.ModelBuilder()
    g = b.add_group("g")
    for k in range(3):
        b.add_particle([k, 0.5 + k, 0], 1.0, g)
    b.add_plane()
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=1 / 60, substeps=4, method="xpbd")
    stepper.step(model, state, 30)  # particle 0 has landed, 1 and 2 have not
    c = stepper.contacts()
    assert c["count"] == 1 and c["active"] == 1 and list(c["particle"]) == [0] and list(c["collider"]) == [0]
    assert np.array_equal(c["normal"][0], [0, 1, 0])
    h = stepper.substep_size
    # resting: the contact holds the particle's weight, λ/h² = m g
    assert c["lambda"][0] / h**2 == pytest.approx(9.81, rel=1e-9)
    assert c["max_penetration"] <= ROUND_OFF and c["self_count"] == 0


def scene_state(method: str) -> tuple[np.ndarray, np.ndarray]:
    model, state = cs.particle_rain("mesh", friction_static=0.4, friction_kinetic=0.3, restitution=0.5)
    cloth, _ = cs.folded_cloth(n=8)
    s2 = cloth.initial_state()
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=2)
    stepper.step(model, state, 40)
    csb.PbdStepper(method=method, dt=1 / 60, substeps=2).step(cloth, s2, 40)
    return np.concatenate([state.x, s2.x]), np.concatenate([state.v, s2.v])


@pytest.mark.parametrize("method", METHODS)
def test_collisions_are_deterministic(method):
    x1, v1 = scene_state(method)
    x2, v2 = scene_state(method)
    assert x1.tobytes() == x2.tobytes() and v1.tobytes() == v2.tobytes()
