"""Deforming mesh colliders (PbdStepper.deform_collider; collision.hpp): the vertices of a mesh
collider set per step and moved linearly over its sub-steps, particles tested continuously against
the moving triangles, friction and restitution relative to the surface, particles attached to the
skin; and the bundled skinned character with a cape (cape_skinned)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import csb

G = 9.81
METHODS = ["pbd", "xpbd", "jakobsen"]
SHEET = np.array([[-2.0, 0.0, -2.0], [2.0, 0.0, -2.0], [2.0, 0.0, 2.0], [-2.0, 0.0, 2.0]])
SHEET_TRIANGLES = np.array([[0, 2, 1], [0, 3, 2]])


def on_sheet(y: float, thickness: float = 0.0, mu: float = 0.0, restitution: float = 0.0):
    """One particle at (0, y, 0) over a 4 m square sheet at y = 0 (a mesh collider)."""
    b = csb.ModelBuilder()
    g = b.add_group("puck")
    b.add_particle([0.0, y, 0.0], 0.1, g)
    if thickness > 0:
        b.set_thickness(g, thickness)
    b.add_collider_mesh(csb.Mesh(SHEET, SHEET_TRIANGLES, name="sheet"), friction_static=mu, friction_kinetic=mu,
                        restitution=restitution, name="sheet")
    model = b.build()
    return model, model.initial_state()


@pytest.mark.parametrize("method", METHODS)
def test_a_fast_flap_does_not_pass_through_a_particle(method):
    """A triangle hinged on the z axis (vertices (0, 0, ±1)) whose third vertex goes from
    (2, -2, 0) to (2, 2, 0) in one step of one sub-step: at x = 0.5 its plane sweeps from
    y = -0.5 to y = 0.5, through the particle resting at (0.5, 0, 0) halfway. A test at the end
    positions alone would find the particle 0.35 m below the flap's end plane and push it down
    through; the continuous test finds the flap reaching it, so the contact is the end plane
    y = x facing the side the particle was on (up, n = (-1, 1, 0)/√2) and the particle ends
    r = 1 mm above it: x + (r + 0.5/√2) n, in closed form, to round-off (1e-12 m)."""
    r = 1e-3
    flap = csb.Mesh(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [2.0, -2.0, 0.0]]), np.array([[0, 1, 2]]), name="flap")
    b = csb.ModelBuilder()
    g = b.add_group("dust")
    b.add_particle([0.5, 0.0, 0.0], 0.1, g)
    b.set_thickness(g, r)
    b.add_collider_mesh(flap, name="flap")
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, dt=0.01, substeps=1, iterations=1, gravity=[0, 0, 0])
    stepper.deform_collider(model, 0, [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [2.0, 2.0, 0.0]])
    stepper.step(model, state, 1)
    n = np.array([-1.0, 1.0, 0.0]) / math.sqrt(2)
    np.testing.assert_allclose(state.x[0], np.array([0.5, 0.0, 0.0]) + (r + 0.5 / math.sqrt(2)) * n, rtol=0, atol=1e-12)
    assert (state.x[0] @ n) == pytest.approx(r, abs=1e-12)  # r above the end plane, on the side it started
    np.testing.assert_array_equal(stepper.collider_vertices(model, 0), [[0, 0, -1], [0, 0, 1], [2, 2, 0]])


@pytest.mark.parametrize("method", METHODS)
def test_a_particle_on_a_deforming_sheet_is_carried_along_with_friction(method):
    """The sheet's vertices move along x at u = 0.5 m/s (deform_collider every step), the
    particle at rest on it, μ = 0.5: the surface motion at the contact is the blend of its
    vertices' motions, so, as on a rigidly moved plane (test_moving_colliders), kinetic friction
    accelerates the particle at μ g until it moves with the sheet at t* = u/(μ g), lagging
    u²/(2 μ g) = 25.5 mm, known to the sheet's travel in two sub-steps (2 u h = 1.7 mm); then static
    friction holds it: its offset changes by round-off only (1e-12 m) and it moves at u."""
    r = 0.01
    model, state = on_sheet(r, thickness=r, mu=0.5)
    dt, substeps, u = 1 / 60, 10, 0.5
    stepper = csb.PbdStepper(method=method, dt=dt, substeps=substeps)
    offsets = []
    for k in range(60):
        stepper.deform_collider(model, 0, SHEET + [u * (k + 1) * dt, 0.0, 0.0])
        stepper.step(model, state, 1)
        offsets.append(state.x[0, 0] - u * (k + 1) * dt)
    assert offsets[-1] == pytest.approx(-u * u / (2 * 0.5 * G), abs=2 * u * dt / substeps)
    assert max(offsets[30:]) - min(offsets[30:]) < 1e-12
    assert state.v[0, 0] == pytest.approx(u, abs=1e-9)
    assert state.x[0, 1] == pytest.approx(r, abs=1e-12)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
def test_a_sheet_deformed_upwards_hits_a_ball_and_it_leaves_at_u_plus_e_times_the_closing_speed(method, e):
    """No gravity; the ball falls at v0 = 1 m/s, the sheet's vertices rise at u = 2 m/s: the
    closing speed is u + v0 and the ball leaves at u + e (u + v0), restitution acting on the
    velocity relative to the surface (the blend of its vertices' velocities); exact to round-off
    (1e-9 m/s: ulps of the positions divided by h), as for a rigidly moved plane."""
    model, state = on_sheet(0.05, restitution=e)
    state.v[0] = (0.0, -1.0, 0.0)
    dt, substeps, u = 1 / 60, 10, 2.0
    stepper = csb.PbdStepper(method=method, dt=dt, substeps=substeps, gravity=[0, 0, 0])
    for k in range(6):
        stepper.deform_collider(model, 0, SHEET + [0.0, u * (k + 1) * dt, 0.0])
        stepper.step(model, state, 1)
    assert state.v[0, 1] == pytest.approx(u + e * (u + 1.0), abs=1e-9)
    assert state.x[0, 1] >= u * 6 * dt - 1e-12  # above the sheet


@pytest.mark.parametrize("method", METHODS)
def test_particles_attached_to_a_deforming_mesh_follow_their_triangle(method):
    """Particles attached to a mesh collider are held in the frame of their nearest triangle
    (a + u (b - a) + v (c - a) + w n); when the sheet is stretched, sheared and lifted they are
    at that point of the deformed triangle after every step, to round-off (1e-12 m)."""
    b = csb.ModelBuilder()
    g = b.add_group("tag")
    for p in ([0.3, 0.1, 0.2], [-1.0, 0.05, 0.5], [1.5, -0.2, -1.5]):
        b.add_particle(p, 0.1, g)
    b.add_collider_mesh(csb.Mesh(SHEET, SHEET_TRIANGLES, name="sheet"), name="sheet")
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=4)
    stepper.attach(model, state, 0, [0, 1, 2])
    held = stepper.attachments
    assert [a["triangle"] for a in held] == [0, 1, 0]
    for k in range(1, 11):
        s = 0.1 * k
        v = SHEET * [1 + s, 1, 1] + np.outer(SHEET[:, 0], [0, 0.3 * s, 0.2 * s]) + [0, s, 0]
        stepper.deform_collider(model, 0, v)
        stepper.step(model, state, 1)
        for a in held:
            ta, tb, tc = v[SHEET_TRIANGLES[a["triangle"]]]
            n = np.cross(tb - ta, tc - ta)
            u, w, h = a["frame"]
            expected = ta + u * (tb - ta) + w * (tc - ta) + h * n / np.linalg.norm(n)
            np.testing.assert_allclose(state.x[a["particle"]], expected, rtol=0, atol=1e-12)


def rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@pytest.mark.parametrize("method", METHODS)
def test_a_mesh_deformed_and_turned_at_once_holds_and_carries_its_particles(method):
    """The sheet is stretched in its model frame (deform_collider) and turned about y
    (move_collider) in the same steps, so its grid is rebuilt every sub-step over the sub-step's
    sweep. A particle attached to it is at the pose applied to its frame point in the deformed
    triangle (1e-12 m of round-off); a particle dropped on it (r = 1 cm) lands and stays r above
    the plane y = 0, which the turn about y keeps, to round-off (1e-12 m)."""
    r = 0.01
    b = csb.ModelBuilder()
    g = b.add_group("dust")
    b.add_particle([0.5, 0.3, 0.2], 0.1, g)   # falls on the sheet
    b.add_particle([-1.0, 0.1, 0.5], 0.1, g)  # attached
    b.set_thickness(g, r)
    b.add_collider_mesh(csb.Mesh(SHEET, SHEET_TRIANGLES, name="sheet"), friction_static=0.5, name="sheet")
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=5)
    stepper.attach(model, state, 0, [1])
    (held,) = stepper.attachments
    for k in range(1, 31):
        v = SHEET * [1 + 0.01 * k, 1, 1 - 0.005 * k]
        R = rot_y(0.05 * k)
        stepper.deform_collider(model, 0, v)
        stepper.move_collider(model, 0, R, [0.0, 0.0, 0.0])
        stepper.step(model, state, 1)
        ta, tb, tc = v[SHEET_TRIANGLES[held["triangle"]]]
        n = np.cross(tb - ta, tc - ta)
        fu, fv, fw = held["frame"]
        local = ta + fu * (tb - ta) + fv * (tc - ta) + fw * n / np.linalg.norm(n)
        np.testing.assert_allclose(state.x[1], R @ local, rtol=0, atol=1e-12)
        assert state.x[0, 1] >= r - 1e-12
    assert state.x[0, 1] == pytest.approx(r, abs=1e-12)  # landed (0.3 m falls in 0.25 s)


def test_bad_deformations_are_refused_naming_the_collider_and_vertex():
    b = csb.ModelBuilder()
    g = b.add_group("dust")
    b.add_particle([0.0, 1.0, 0.0], 0.1, g)
    b.add_plane(name="floor")
    b.add_collider_mesh(csb.Mesh(SHEET, SHEET_TRIANGLES, name="sheet"), name="sheet")
    model = b.build()
    stepper = csb.PbdStepper(dt=1 / 60)
    bad = SHEET.copy()
    bad[2, 1] = math.nan
    for call, message in [
        (lambda: stepper.deform_collider(model, 1, SHEET[:3]), r"collider 1 \('sheet'\): 3 vertices given, but the mesh has 4"),
        (lambda: stepper.deform_collider(model, 1, bad), r"collider 1 \('sheet'\): vertex 2 must be finite"),
        (lambda: stepper.deform_collider(model, 0, SHEET), r"collider 0 \('floor'\) is a plane: only a mesh collider deforms"),
        (lambda: stepper.deform_collider(model, 2, SHEET), "collider 2 is out of range"),
        (lambda: stepper.deform_collider(model, 1, SHEET[:, :2]), r"vertices must have shape \(N, 3\)"),
        (lambda: stepper.collider_vertices(model, 0), r"collider 0 \('floor'\) is a plane, not a mesh"),
    ]:
        with pytest.raises(csb.ParameterError, match=message):
            call()
    np.testing.assert_array_equal(stepper.collider_vertices(model, 1), SHEET)  # unchanged by the refusals


def test_deforming_colliders_are_deterministic_across_runs_and_threads():
    """The skinned cape scene, 20 steps: the same bits on 1 and 2 threads and on a second run."""
    def run(threads: int) -> bytes:
        sim = csb.load_scene("cape_skinned").build(csb.PbdStepper(
            method="xpbd", dt=1 / 60, substeps=20, iterations=1, threads=threads))
        # the scene's own solver, but with a thread count; attach as the scene does
        sim.step(20)
        return np.asarray(sim.state.x).tobytes() + np.asarray(sim.state.v).tobytes()

    one = run(1)
    assert run(2) == one and run(1) == one


# ---------------------------------------------------------------------------------------------
# The bundled skinned character and its cape


def distances_to_mesh(points: np.ndarray, v: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Unsigned distance (m) of each point to a triangle mesh: the plane distance where the
    projection falls inside a triangle, else the nearest point of its edges."""
    a, b, c = v[tris[:, 0]], v[tris[:, 1]], v[tris[:, 2]]
    p = points[:, None, :]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    h = np.einsum("pfk,fk->pf", p - a, n)
    q = p - h[..., None] * n
    inside = np.ones(h.shape, dtype=bool)
    for u, w in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("pfk,fk->pf", np.cross(w - u, q - u), n) >= 0
    best = np.where(inside, np.abs(h), np.inf)
    for u, w in ((a, b), (b, c), (c, a)):
        e = w - u
        s = np.clip(np.einsum("pfk,fk->pf", p - u, e) / np.einsum("fk,fk->f", e, e), 0, 1)
        best = np.minimum(best, np.linalg.norm(p - (u + s[..., None] * e), axis=2))
    return best.min(axis=1)


def winding_numbers(points: np.ndarray, v: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """The winding number of a closed outward-wound mesh about each point: the sum of its
    triangles' solid angles over 4π (Van Oosterom and Strackee 1983), 1 inside, 0 outside."""
    a = v[tris[:, 0]][None] - points[:, None]
    b = v[tris[:, 1]][None] - points[:, None]
    c = v[tris[:, 2]][None] - points[:, None]
    la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
    num = np.einsum("pfk,pfk->pf", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("pfk,pfk->pf", a, b) * lc + np.einsum("pfk,pfk->pf", a, c) * lb \
        + np.einsum("pfk,pfk->pf", b, c) * la
    return (2 * np.arctan2(num, den)).sum(axis=1) / (4 * math.pi)


def test_the_bundled_cape_stays_outside_its_skinned_character_and_follows_the_skin():
    """cape_skinned for 1 s (60 steps of 20 sub-steps): the body (torso and arm, two closed
    surfaces in one mesh collider) walks, bows, sways and waves by linear blend skinning; the
    bow brings the hips against the cape. After every step:
      - the stepper's vertices are the scene's (the file's skinning sampled and interpolated) at t;
      - every attached particle is at its triangle's frame point on the deformed body, to
        round-off (1e-12 m);
      - no cape particle is inside the body (winding number < 1/2) or closer to its surface
        than the contact thickness r = 5 mm allows: the contacts push each particle to r from
        the triangle's plane, and what the iterations leave is at most the stepper's reported
        max_penetration, so the distance is at least r minus that, less 1e-9 m of round-off;
      - the positions are finite.
    The cape does touch the body: some step has active contacts with it."""
    sim = csb.load_scene("cape_skinned").build()
    body = sim.colliders["body"]
    tris = np.asarray(sim.model.colliders[body]["triangles"])
    deform = sim.collider_deformation["body"]
    held = sim.stepper.attachments
    assert len(held) == 16
    attached = np.array([a["particle"] for a in held])
    free = np.setdiff1d(np.arange(sim.model.num_particles), attached)
    r = float(np.asarray(sim.model.thickness)[free].max())
    assert r == 0.005
    v0 = sim.stepper.collider_vertices(sim.model, body)
    assert winding_numbers(np.array([[0.0, 1.1, 0.0], [0.4, 1.3, 0.0]]), v0, tris) == pytest.approx([1.0, 0.0])
    touched = 0
    closest = math.inf
    for _ in range(60):
        sim.step(1)
        x = np.asarray(sim.state.x)
        assert np.isfinite(x).all()
        v = sim.stepper.collider_vertices(sim.model, body)
        np.testing.assert_array_equal(v, deform(sim.state.t))
        for a in held:
            ta, tb, tc = v[tris[a["triangle"]]]
            n = np.cross(tb - ta, tc - ta)
            fu, fv, fw = a["frame"]
            np.testing.assert_allclose(x[a["particle"]], ta + fu * (tb - ta) + fv * (tc - ta) + fw * n / np.linalg.norm(n),
                                       rtol=0, atol=1e-12)
        assert (winding_numbers(x[free], v, tris) < 0.5).all()
        d = distances_to_mesh(x[free], v, tris)
        left = sim.stepper.contacts()["max_penetration"]
        assert d.min() >= r - left - 1e-9
        closest = min(closest, d.min())
        touched += sim.stepper.contacts()["active"] > 0
    assert touched > 0
    assert closest < 2 * r  # the cape did come against the body


def test_a_skinned_collider_is_refused_by_methods_that_cannot_deform_colliders(tmp_path):
    """The implicit methods take colliders from the Model and cannot deform them: a scene with a
    skinned collider refuses to build for them, and a deformation given to Simulation.step is
    refused, naming the method, rather than left static silently."""
    scene = csb.load_scene("cape_skinned")
    with pytest.raises(csb.SceneError, match=r"collider 'body' has a motion, but method '.*' cannot move or deform"):
        scene.build(csb.BackwardEuler(dt=1 / 60))
    csb.save_mesh(csb.Mesh(SHEET, SHEET_TRIANGLES, name="sheet"), str(tmp_path / "sheet.obj"))
    (tmp_path / "sheet.toml").write_text(
        '[scene]\nname = "sheet"\nduration = 0.1\n[solver]\nmethod = "pbd"\ndt = 0.01\nsubsteps = 1\niterations = 1\n'
        '[[mesh]]\nname = "dot"\nshape = "chain"\nlinks = 1\nlink_length = 0.1\ntranslate = [0.0, 1.0, 0.0]\nmass = 0.1\n'
        '[[collider]]\ntype = "mesh"\nname = "sheet"\nfile = "sheet.obj"\n')
    sim = csb.load_scene(tmp_path / "sheet.toml").build(csb.BackwardEuler(dt=1 / 60))
    sim.collider_deformation["sheet"] = lambda t: SHEET
    with pytest.raises(csb.ParameterError, match=r"method '.*' cannot deform colliders"):
        sim.step()
