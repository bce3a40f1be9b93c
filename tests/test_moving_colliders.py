"""Colliders that move (the position-based steppers own a rigid pose per collider, interpolated
over the sub-steps) and particles attached to them: contacts along the motion relative to the
collider, friction and restitution on the relative velocity (collision.hpp, contacts.cpp)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import csb

G = 9.81
EPS = np.finfo(float).eps
METHODS = ["pbd", "xpbd", "jakobsen"]


def rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def puck(mu: float, restitution: float = 0.0, y: float = 0.0):
    b = csb.ModelBuilder()
    g = b.add_group("puck")
    b.add_particle([0.0, y, 0.0], 0.1, g)
    b.add_plane(friction_static=mu, friction_kinetic=mu, restitution=restitution, name="floor")
    model = b.build()
    return model, model.initial_state()


@pytest.mark.parametrize("method", METHODS)
def test_a_particle_on_a_plane_sliding_sideways_is_carried_along_with_friction(method):
    """The floor moves along x at u = 0.5 m/s from t = 0, the particle at rest on it, μ = 0.5.
    Kinetic friction accelerates the particle at μ g until it moves with the floor, at
    t* = u/(μ g) = 0.10 s, lagging u²/(2 μ g) = 25.5 mm behind it; then static friction keeps the
    relative displacement at zero. The friction acts a sub-step late and the catch-up ends
    within a sub-step, so the lag is known to the floor's travel in two sub-steps, 2 u h =
    1.7 mm. Once caught up the particle's offset to the floor changes by round-off only
    (1e-12 m over 0.5 s, a thousand ulps of 0.5 m)."""
    model, state = puck(0.5)
    dt, substeps, u = 1 / 60, 10, 0.5
    stepper = csb.PbdStepper(method=method, dt=dt, substeps=substeps)
    offsets = []
    for k in range(60):
        stepper.move_collider(model, 0, np.eye(3), [u * (k + 1) * dt, 0.0, 0.0])
        stepper.step(model, state, 1)
        offsets.append(state.x[0, 0] - u * (k + 1) * dt)
    assert offsets[-1] == pytest.approx(-u * u / (2 * 0.5 * G), abs=2 * u * dt / substeps)
    assert max(offsets[30:]) - min(offsets[30:]) < 1e-12
    assert state.v[0, 0] == pytest.approx(u, abs=1e-9)
    assert state.x[0, 1] == pytest.approx(0.0, abs=1e-12)  # on the floor, which moves within itself


@pytest.mark.parametrize("method", METHODS)
def test_a_frictionless_particle_stays_where_it_is_while_the_floor_slides(method):
    model, state = puck(0.0)
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=10)
    for k in range(60):
        stepper.move_collider(model, 0, np.eye(3), [0.5 * (k + 1) / 60, 0.0, 0.0])
        stepper.step(model, state, 1)
    assert state.x[0, 0] == 0.0 and state.x[0, 2] == 0.0 and state.v[0, 0] == 0.0


@pytest.mark.parametrize("method", METHODS)
def test_a_turntable_carries_a_particle_round_at_omega_r(method):
    """A floor turning about its normal (the y axis) at ω = 2 rad/s, a particle 0.2 m from the
    axis moving with it (v = ω ρ along the circle), μ = 0.5. Each sub-step the particle's
    prediction differs from the floor point's chord by at most ω² ρ h² = 0.8 h², within the static
    cone μ g h² = 4.9 h² (the contact's normal correction is g h²), so friction puts it on the
    floor's material point: it stays on the circle of radius ρ and at the floor's angle to
    round-off (1e-12 over 600 sub-steps of ulp-size errors), and its speed is the chord over h,
    2 ρ sin(ω h/2)/h (ω ρ less (ω h)²/24 of it)."""
    b = csb.ModelBuilder()
    g = b.add_group("puck")
    rho, omega, dt, substeps = 0.2, 2.0, 1 / 60, 10
    b.add_particle([rho, 0.0, 0.0], 0.1, g)
    b.add_plane(friction_static=0.5, friction_kinetic=0.5)
    model = b.build()
    state = model.initial_state()
    state.v[0] = (0.0, 0.0, -omega * rho)  # rot_y turns +x towards -z
    stepper = csb.PbdStepper(method=method, dt=dt, substeps=substeps)
    lags = []
    for k in range(60):
        stepper.move_collider(model, 0, rot_y(omega * (k + 1) * dt), [0.0, 0.0, 0.0])
        stepper.step(model, state, 1)
        lags.append(omega * (k + 1) * dt - math.atan2(-state.x[0, 2], state.x[0, 0]))
    h = dt / substeps
    assert np.hypot(state.x[0, 0], state.x[0, 2]) == pytest.approx(rho, abs=1e-12)
    assert max(abs(a) for a in lags) < 1e-12
    assert np.linalg.norm(state.v[0]) == pytest.approx(2 * rho * math.sin(omega * h / 2) / h, rel=1e-9)


def draped_cloth(omega: float, mu: float = 0.5, n: int = 12, threads: int = 1, steps: int = 90,
                 method: str = "xpbd"):
    """A 0.5 m cloth dropped from 2 cm onto a 0.3 m sphere turning about the vertical at ω; its
    spin (rad/s) after each step, Σ (x × v)_y / Σ ρ²."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(0.5, 0.5, n, n, center=[0, 0.32, 0]), mass=0.1, thickness=0.01)
    b.add_sphere(center=[0, 0, 0], radius=0.3, friction_static=mu, friction_kinetic=mu, name="ball")
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=20, iterations=1, threads=threads)
    spins = []
    for k in range(steps):
        stepper.move_collider(model, 0, rot_y(omega * (k + 1) / 60), [0.0, 0.0, 0.0])
        stepper.step(model, state, 1)
        x, v = state.x, state.v
        spins.append(float(np.sum(x[:, 2] * v[:, 0] - x[:, 0] * v[:, 2]) / np.sum(x[:, 0] ** 2 + x[:, 2] ** 2)))
    assert stepper.threads_used == threads
    return state, np.array(spins)


def test_a_sphere_turning_under_a_cloth_turns_it_with_friction():
    """The sphere turns at ω = π/2 rad/s, μ = 0.5. The cap under the cloth slopes at most 57°
    (|x| <= 0.25 m) and the cloth rests on it by friction as on a static sphere; static friction
    moves each contact particle with the point of the sphere's frame where the contact holds it,
    so after 1.5 s the cloth turns rigidly at ω: its spin is ω within 1 % (what remains is the
    rim swinging and the chord of each sub-step's turn, (ω h)² ~ 2e-5; measured 4e-5).
    Without friction the sphere's surface moves within itself and does not turn the cloth, which
    slides off: its spin stays that of the same cloth on a static sphere (whose folding gives
    Σ x × v a few % of ω by itself: up to 0.054 rad/s) within 1 % of ω."""
    omega = math.pi / 2
    _, spins = draped_cloth(omega)
    assert spins[-1] == pytest.approx(omega, rel=0.01)
    _, free = draped_cloth(omega, mu=0.0)
    _, static = draped_cloth(0.0, mu=0.0)
    assert np.abs(free - static).max() < 0.01 * omega


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
def test_a_plane_moving_up_hits_a_ball_and_it_leaves_at_u_plus_e_times_the_closing_speed(method, e):
    """No gravity; the ball falls at v0 = 1 m/s, the floor rises at u = 2 m/s: the closing speed
    is u + v0 and the ball leaves at u + e (u + v0). The contact pushes the ball onto the floor's
    end-of-sub-step position (relative normal velocity 0), and restitution sets it to e times the
    closing speed, measured along the ray in the floor's frame, so the result is exact to
    round-off (1e-9 m/s: ulps of the positions divided by h)."""
    model, state = puck(0.0, restitution=e, y=0.05)
    state.v[0] = (0.0, -1.0, 0.0)
    dt, substeps, u = 1 / 60, 10, 2.0
    stepper = csb.PbdStepper(method=method, dt=dt, substeps=substeps, gravity=[0, 0, 0])
    for k in range(6):
        stepper.move_collider(model, 0, np.eye(3), [0.0, u * (k + 1) * dt, 0.0])
        stepper.step(model, state, 1)
    assert state.v[0, 1] == pytest.approx(u + e * (u + 1.0), abs=1e-9)
    assert state.x[0, 1] >= u * 6 * dt - 1e-12  # above the floor


def rise_through_cloth(method: str, dt: float, add_collider):
    """A 0.4 m cloth of 8 x 8 at y = 0 and a collider (added by add_collider(builder), the model's
    collider 0) that moves up by 100 m/s x dt in one step of one sub-step, without gravity: the
    model, the state after that step and the stepper."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(0.4, 0.4, 8, 8, center=[0, 0, 0]), mass=0.1)
    add_collider(b)
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, dt=dt, substeps=1, iterations=4, gravity=[0, 0, 0])
    stepper.move_collider(model, 0, np.eye(3), [0.0, 100.0 * dt, 0.0])
    stepper.step(model, state, 1)
    return model, state, stepper

@pytest.mark.parametrize("method", METHODS)
def test_a_thin_plate_at_100_m_s_does_not_pass_through_a_cloth(method):
    """A 1 cm thick, 1 m wide plate moves up at 100 m/s from 1 m below a 0.4 m cloth: 1.67 m in
    one step of one sub-step, so it starts below the cloth and ends above it. The ray in the
    plate's frame runs from above the plate to below it and enters the top face: every particle
    ends on the plate's top face (its thickness 0: C = (p - q)·n >= 0, the contacts projected
    last in each sweep), to round-off of the 0.67 m coordinate (1e-12 m)."""
    dt = 1 / 60
    _, state, _ = rise_through_cloth(method, dt, lambda b: b.add_box(center=[0, -1.0, 0], half_extents=[0.5, 0.005, 0.5],
                                                                        name="plate"))
    top = -1.0 + 100.0 * dt + 0.005
    assert state.x[:, 1].min() >= top - 1e-12


@pytest.mark.parametrize("method", METHODS)
def test_particles_attached_to_a_turning_collider_stay_at_its_pose(method):
    """Three corners of a cloth attached to a box that turns about y at 1 rad/s while moving
    along x: after every step an attached particle is at R(t) x0 + t(t), computed here with
    numpy. The stepper applies the same pose to the same x0 (the pose at attaching was the
    identity, so x0 is kept exactly); only the order of the three-term sums may differ: a few ulps
    of |R| |x0| + |t|, bounded by 8 ε (|x0| + |t|)."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(0.4, 0.4, 5, 5, center=[0, 1.0, 0]), mass=0.1)
    b.add_box(center=[0, 2.0, 0], half_extents=[0.1, 0.1, 0.1], name="torso")
    model = b.build()
    state = model.initial_state()
    x = state.x.copy()
    pinned = [0, 4, 20]
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=5)
    stepper.attach(model, state, 0, pinned)
    assert [a["particle"] for a in stepper.attachments] == pinned and stepper.grabs == []
    for k in range(30):
        t = (k + 1) / 60
        R, tr = rot_y(1.0 * t), np.array([0.3 * t, 0.0, 0.0])
        stepper.move_collider(model, 0, R, tr)
        stepper.step(model, state, 1)
        for i in pinned:
            expected = R @ x[i] + tr
            assert np.abs(state.x[i] - expected).max() <= 8 * EPS * (np.linalg.norm(x[i]) + np.linalg.norm(tr))
    stepper.detach(0, [4])
    assert [a["particle"] for a in stepper.attachments] == [0, 20]
    v4 = state.v[4].copy()
    stepper.step(model, state, 1)
    assert state.v[4, 1] < v4[1]  # falls once let go
    stepper.detach(0)
    assert stepper.attachments == []


def test_bad_poses_and_attachments_are_refused_naming_the_collider_and_parameter():
    model, state = puck(0.5)
    stepper = csb.PbdStepper(method="pbd", dt=1 / 60)
    cases = [
        (lambda: stepper.move_collider(model, 1, np.eye(3), [0, 0, 0]), "collider 1 is out of range"),
        (lambda: stepper.move_collider(model, 0, 2 * np.eye(3), [0, 0, 0]), "collider 0 ('floor'): rotation"),
        (lambda: stepper.move_collider(model, 0, np.diag([1.0, 1.0, -1.0]), [0, 0, 0]), "det R"),
        (lambda: stepper.move_collider(model, 0, np.full((3, 3), np.nan), [0, 0, 0]), "rotation must be finite"),
        (lambda: stepper.move_collider(model, 0, np.eye(3), [0, math.nan, 0]), "translation"),
        (lambda: stepper.move_collider(model, 0, np.eye(2), [0, 0, 0]), "rotation must be a 3 x 3"),
        (lambda: stepper.attach(model, state, 0, [3]), "particle 3 is out of range"),
        (lambda: stepper.attach(model, state, 2, [0]), "collider 2 is out of range"),
        (lambda: stepper.detach(0, [0]), "not attached"),
    ]
    for call, words in cases:
        with pytest.raises(csb.ParameterError, match=None) as info:
            call()
        assert words in str(info.value), str(info.value)
    # A rotation off by less than the tolerance (1e-6) is taken.
    stepper.move_collider(model, 0, rot_y(0.1) * (1 + 1e-8), [0, 0, 0])
    stepper.attach(model, state, 0, [0])
    with pytest.raises(csb.ParameterError, match="already held"):
        stepper.attach(model, state, 0, [0])
    with pytest.raises(csb.ParameterError, match="already held"):
        stepper.grab(model, state, 0, [0, 0, 0])


def test_moving_colliders_are_deterministic_across_runs_and_threads():
    """The contacts and friction of a moving collider run on the calling thread in particle
    order, so two runs, and one and two threads of the coloured sweep, give the same bits."""
    a, _ = draped_cloth(math.pi / 2, steps=30, threads=1)
    b, _ = draped_cloth(math.pi / 2, steps=30, threads=1)
    c, _ = draped_cloth(math.pi / 2, steps=30, threads=2)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.v, b.v)
    assert np.array_equal(a.x, c.x) and np.array_equal(a.v, c.v)


@pytest.mark.parametrize("method", METHODS)
def test_a_collider_left_at_the_identity_gives_the_static_bits(method):
    """A collider moved to the identity pose takes the static path: the same bits as a stepper
    that never heard of poses (scripts/state_hashes.py pins the static scenes themselves)."""
    a, _ = draped_cloth(0.0, steps=20, method=method)
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(0.5, 0.5, 12, 12, center=[0, 0.32, 0]), mass=0.1, thickness=0.01)
    b.add_sphere(center=[0, 0, 0], radius=0.3, friction_static=0.5, friction_kinetic=0.5, name="ball")
    model = b.build()
    state = model.initial_state()
    csb.PbdStepper(method=method, dt=1 / 60, substeps=20, iterations=1, threads=1).step(model, state, 20)
    assert np.array_equal(a.x, state.x) and np.array_equal(a.v, state.v)


# ---------------------------------------------------------------------------------------------
# Scene files: keyframed motion, callbacks, attachments to colliders

SCENE = """
[scene]
name = "moving"
duration = 0.5

[solver]
method = "{method}"
dt = 0.01
substeps = 2
iterations = 5

[[mesh]]
name = "cape"
shape = "cloth"
size = [0.4, 0.4]
resolution = [5, 5]
plane = "xz"
translate = [0.0, 1.0, 0.0]
mass = 0.1
stretch = {{ stiffness = 0.9, compliance = 1e-6 }}
{attach}

[[collider]]
type = "box"
name = "torso"
center = [0.0, 1.5, 0.0]
half_extents = [0.1, 0.1, 0.1]
{motion}
"""

MOTION = ('motion = { times = [0.0, 1.0, 2.0], translation = [[0, 0, 0], [0.5, 0, 0], [0, 0, 0]], '
          'rotation = [[0, 0, 0], [0, 1.5, 0], [0, 0, 0]] }')


def scene(tmp_path, method="pbd", motion=MOTION, attach=""):
    p = tmp_path / "moving.toml"
    p.write_text(SCENE.format(method=method, motion=motion, attach=attach))
    return p


def test_keyframes_are_interpolated_linearly_and_by_slerp_and_held_outside(tmp_path):
    """Halfway between keyframes 0 and 1: translation 0.25 m, rotation 0.75 rad about y (slerp
    between rotations about one axis turns at a constant rate); before 0 and after 2 s the end
    keyframes hold. Exact to round-off (1e-12)."""
    motion = csb.load_scene(scene(tmp_path)).colliders[0].motion
    R, t = motion.pose(0.5)
    np.testing.assert_allclose(t, [0.25, 0, 0], atol=1e-12)
    np.testing.assert_allclose(R, rot_y(0.75), atol=1e-12)
    R, t = motion.pose(1.75)  # 1.5 rad back to 0, three quarters of the way: 0.375 rad
    np.testing.assert_allclose(R, rot_y(0.375), atol=1e-12)
    np.testing.assert_allclose(t, [0.125, 0, 0], atol=1e-12)
    for before, after in ((-1.0, 0.0), (5.0, 2.0)):
        Rb, tb = motion.pose(before)
        Ra, ta = motion.pose(after)
        np.testing.assert_array_equal(Rb, Ra)
        np.testing.assert_array_equal(tb, ta)


def test_a_scene_moves_its_collider_and_the_attached_cape_follows(tmp_path):
    """The cape's corner vertices 0 and 4 are attached to the torso: after every step they are at
    the keyframed pose applied to where they started, as the stepper reports its pose."""
    attach = 'attach = { indices = [0, 4], collider = "torso" }'
    sim = csb.load_scene(scene(tmp_path, attach=attach)).build()
    x0 = sim.state.x.copy()
    motion = sim.scene.colliders[0].motion
    for _ in range(20):
        sim.step()
        R, t = motion.pose(sim.state.t)
        Rs, ts = sim.stepper.collider_pose(0)
        np.testing.assert_allclose(Rs, R, atol=1e-12)  # the same keyframe pose, to round-off
        for i in (0, 4):
            np.testing.assert_allclose(sim.state.x[i], Rs @ x0[i] + ts, atol=1e-12)
    # t = 0.2 s: 0.3 rad about y and 0.1 m along x.
    np.testing.assert_allclose(sim.state.x[0], rot_y(0.3) @ x0[0] + [0.1, 0.0, 0.0], atol=1e-12)


def test_a_python_callback_overrides_the_keyframes(tmp_path):
    sim = csb.load_scene(scene(tmp_path)).build()
    sim.collider_motion["torso"] = lambda t: (np.eye(3), [0.0, -t, 0.0])
    sim.step(3)
    R, t = sim.stepper.collider_pose(0)
    np.testing.assert_array_equal(R, np.eye(3))
    assert t[1] == pytest.approx(-0.03, abs=1e-15)
    sim.collider_motion["nobody"] = lambda t: (np.eye(3), [0, 0, 0])
    with pytest.raises(csb.ParameterError, match="no collider named 'nobody'"):
        sim.step()
    del sim.collider_motion["nobody"]
    sim.collider_motion["torso"] = lambda t: (2 * np.eye(3), [0, 0, 0])
    with pytest.raises(csb.ParameterError, match="collider 'torso' at t = 0.04 s: .*rotation"):
        sim.step()


def test_the_runner_steps_a_moving_scene_and_draws_the_collider_where_it_is(tmp_path):
    result = csb.load_scene(scene(tmp_path, attach='attach = { indices = [0], collider = "torso" }')).run(
        tmp_path / "out")
    assert (tmp_path / "out" / "snapshot.png").is_file()
    assert result.checks() == []  # driven by the torso: the energy may rise
    assert result.steps == 50
    sim = result.simulation
    R, t = sim.stepper.collider_pose(0)
    np.testing.assert_allclose(t, [0.25, 0, 0], atol=1e-12)


@pytest.mark.parametrize("method", ["implicit-euler", "vbd"])
def test_methods_without_moving_colliders_refuse_them_by_name(tmp_path, method):
    with pytest.raises(csb.SceneError, match=f"collider 'torso' has a motion, but method '{method}'"):
        csb.load_scene(scene(tmp_path, method=method)).build()
    with pytest.raises(csb.SceneError, match=f"attached to a collider, but method '{method}'"):
        csb.load_scene(scene(tmp_path, method=method, motion="",
                             attach='attach = { indices = [0], collider = "torso" }')).build()
    sim = csb.load_scene(scene(tmp_path, method=method, motion="")).build()
    sim.collider_motion["torso"] = lambda t: (np.eye(3), [0, 0, 0])
    with pytest.raises(csb.ParameterError, match=f"method '{method}' cannot move colliders"):
        sim.step()


@pytest.mark.parametrize("motion, key, words", [
    ("motion = { times = [0.0, 2.0, 1.0] }", "times", "strictly increasing"),
    ("motion = { times = [] }", "times", "non-empty"),
    ("motion = { times = [0.0, nan] }", "times", "finite"),
    ("motion = { times = [0.0, 1.0], translation = [[0, 0, 0]] }", "translation", "one [x, y, z] per time"),
    ("motion = { times = [0.0, 1.0], translation = [[0, 0], [0, 0]] }", "translation", "[x, y, z]"),
    ("motion = { times = [0.0, 1.0], rotation = [[0, 0, 0], [0, nan, 0]] }", "rotation", "[x, y, z]"),
    ("motion = { times = [0.0, 1.0], rotation = [[0, 0, 0], [0, 3.2, 0]] }", "rotation", "π rad or more"),
    ("motion = { times = [0.0], speed = 3 }", "speed", "unknown key"),
])
def test_bad_keyframes_are_scene_errors_naming_file_line_and_key(tmp_path, motion, key, words):
    path = scene(tmp_path, motion=motion)
    line = path.read_text().splitlines().index(motion) + 1
    with pytest.raises(csb.SceneError) as info:
        csb.load_scene(path)
    message = str(info.value)
    assert f"{path}:{line}" in message and f"collider[0] (torso).motion.{key}" in message and words in message, message


def test_bad_attachments_are_scene_errors(tmp_path):
    with pytest.raises(csb.SceneError, match="no collider named 'head'"):
        csb.load_scene(scene(tmp_path, attach='attach = { indices = [0], collider = "head" }')).build()
    with pytest.raises(csb.SceneError, match="attach.stiffness: an attachment to a collider"):
        csb.load_scene(scene(tmp_path, attach='attach = { indices = [0], collider = "torso", stiffness = 0.5 }'))


def test_the_bundled_rotating_sphere_scene_turns_its_cloth():
    """cloth_rotating_sphere: the sphere turns at π/2 rad/s (keyframes a quarter turn apart, so
    slerp gives a constant rate): after 1 s the ball's pose is a quarter turn, and the cloth on it
    has started to turn the same way (its spin about the axis is positive)."""
    sim = csb.load_scene("cloth_rotating_sphere").build()
    sim.step(60)
    R, _ = sim.stepper.collider_pose(sim.colliders["ball"])
    np.testing.assert_allclose(R, rot_y(math.pi / 2), atol=1e-9)
    x, v = sim.state.x, sim.state.v
    assert np.sum(x[:, 2] * v[:, 0] - x[:, 0] * v[:, 2]) > 0


def test_the_bundled_cape_follows_its_walking_waving_character():
    """cape_wave: the cape's top edge is attached to the torso, which walks 0.4 m/s along +z, so
    after 1.5 s every attached particle has moved exactly 0.6 m in z from its start (the torso's
    keyframed translation; 1e-9 m of round-off), the arm has turned to its keyframed angle about
    its shoulder, and the cape, which collides with the body and itself, has no edge crossing a
    triangle."""
    from csb.studies import collisions as cs

    sim = csb.load_scene("cape_wave").build()
    start = np.array(sim.state.x)
    top = sorted(a["particle"] for a in sim.stepper.attachments)
    assert len(top) == 16 and np.allclose(start[top, 1], 1.42)
    sim.step(90)
    x = np.asarray(sim.state.x)
    np.testing.assert_allclose(x[top] - start[top], np.broadcast_to([0.0, 0.0, 0.6], (len(top), 3)), atol=1e-9)
    R, _ = sim.stepper.collider_pose(sim.colliders["arm"])
    angle = 1.2 + 0.5 * math.sin(2 * math.pi * 1.5)
    np.testing.assert_allclose(R[:2, :2], [[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]],
                               atol=1e-9)
    triangles = np.asarray(sim.model.triangles)
    edges = np.unique(np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    assert cs.self_intersections(x, edges, triangles) == 0


@pytest.mark.parametrize("method", METHODS)
def test_a_mesh_sheet_at_100_m_s_does_not_pass_through_a_cloth(method):
    """A triangle-mesh collider (a two-sided 1 m sheet, its grid built in its model frame) moves
    up at 100 m/s through a 0.4 m cloth in one sub-step: the query is transformed, not the grid,
    and the ray in the sheet's frame crosses it, so every particle ends on the side it started
    on, the top, at least the sheet's skin (1e-9 of its size) above it, to round-off (1e-12 m)."""
    sheet = csb.Mesh(np.array([[-0.5, -1.0, -0.5], [0.5, -1.0, -0.5], [0.5, -1.0, 0.5], [-0.5, -1.0, 0.5]]),
                     np.array([[0, 2, 1], [0, 3, 2]]), name="sheet")
    dt = 1 / 60
    model, state, stepper = rise_through_cloth(method, dt, lambda b: b.add_collider_mesh(sheet, name="sheet"))
    assert state.x[:, 1].min() >= -1.0 + 100.0 * dt - 1e-12
    assert stepper.contacts()["count"] == model.num_particles


@pytest.mark.parametrize("method", METHODS)
def test_a_turning_paddle_sweeps_particles_without_passing_any(method):
    """A box paddle (1 m x 2 cm x 0.2 m) turns about the vertical at 2π rad/s through a ring of
    resting particles (no gravity, no friction). In the paddle's frame a particle's path over a
    sub-step is an arc, tested as its chord: off by at most ρ θ²/8 = 7e-6 m at ρ = 0.5 m and
    θ = ω h = 0.0105 rad, far less than the paddle's 2 cm, so no particle is missed: after every
    step each particle is outside the paddle (its distance in the paddle's frame >= -1e-12 m,
    round-off of the 0.5 m coordinates) and the particles ahead of it have been pushed along."""
    b = csb.ModelBuilder()
    g = b.add_group("dust")
    angles = np.linspace(0.2, 2 * math.pi - 0.2, 12)
    for a in angles:
        for rho in (0.15, 0.3, 0.45):
            b.add_particle([rho * math.cos(a), 0.0, -rho * math.sin(a)], 0.01, g)
    b.add_box(center=[0, 0, 0], half_extents=[0.5, 0.1, 0.01], name="paddle")
    model = b.build()
    state = model.initial_state()
    omega, dt = 2 * math.pi, 1 / 60
    stepper = csb.PbdStepper(method=method, dt=dt, substeps=10, gravity=[0, 0, 0])
    for k in range(30):
        R = rot_y(omega * (k + 1) * dt)
        stepper.move_collider(model, 0, R, [0.0, 0.0, 0.0])
        stepper.step(model, state, 1)
        local = state.x @ R  # R^T x per particle
        inside = np.all(np.abs(local) < np.array([0.5, 0.1, 0.01]) - 1e-12, axis=1)
        assert not inside.any(), (k, np.flatnonzero(inside))
    moved = np.linalg.norm(state.x - model.rest_positions, axis=1) > 1e-3
    assert moved.sum() >= 12  # half a turn: the paddle's two blades have swept the particles at 0.2 .. π rad


@pytest.mark.parametrize("method", METHODS)
def test_within_a_step_the_pose_is_interpolated_linearly_and_by_slerp(method):
    """A step of two sub-steps from the identity to a turn of 1 rad about y and 0.4 m along x,
    stopped after its first sub-step (interrupt): an attached particle is at the halfway pose,
    rot_y(0.5) x0 + (0.2, 0, 0) (the slerp of two turns about one axis is the turn by the mean
    angle), to round-off (1e-12 m)."""
    b = csb.ModelBuilder()
    g = b.add_group("p")
    b.add_particle([0.3, 0.0, 0.1], 0.1, g)
    b.add_sphere(center=[0.0, -1.0, 0.0], radius=0.1, name="hand")
    model = b.build()
    state = model.initial_state()
    x0 = state.x[0].copy()
    stepper = csb.PbdStepper(method=method, dt=0.01, substeps=2, gravity=[0, 0, 0])
    stepper.attach(model, state, 0, [0])
    stepper.move_collider(model, 0, rot_y(1.0), [0.4, 0.0, 0.0])
    with pytest.raises(csb.Error, match="after sub-step 0"):
        stepper.step(model, state, 1, interrupt=lambda: True)
    np.testing.assert_allclose(state.x[0], rot_y(0.5) @ x0 + [0.2, 0.0, 0.0], atol=1e-12)
