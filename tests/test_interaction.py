"""Click and drag without a window: grabbing, moving and releasing particles through the stepper,
and picking the particle under a ray. The viewer's mouse handling calls exactly these."""

from __future__ import annotations

import numpy as np
import pytest

import csb
from helpers import cloth_model

G = (0.0, -9.81, 0.0)


def free_particle(mass: float = 1.0) -> csb.Model:
    b = csb.ModelBuilder()
    g = b.add_group("p")
    b.add_particle([0, 0, 0], mass, g)
    return b.build()


@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
def test_kinematic_grab_puts_the_particle_on_the_hand_and_the_cloth_follows(method):
    n = 8
    model = cloth_model(n, bending=None)
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=4, iterations=20, gravity=G)
    corner = n * n - 1  # a free corner
    start = state.x[corner].copy()
    target = start + np.array([0.0, 0.3, 0.1])
    h = stepper.grab(model, state, corner, target)
    stepper.step(model, state)
    # The particle is exactly where the hand is, whatever the constraints wanted.
    assert np.array_equal(state.x[corner], target)
    # Its velocity is the hand's: the last sub-step moved it a quarter of the way in dt/4.
    np.testing.assert_allclose(state.v[corner], (target - start) / (1 / 60), rtol=1e-9)
    # Its neighbour along the edge was pulled after it (it would have fallen otherwise).
    assert state.x[corner - 1][1] > 0.05
    stepper.release(h)
    assert stepper.grabs == []


def test_hand_moves_along_a_straight_line_over_the_substeps():
    model = free_particle()
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=0.1, substeps=5, iterations=1, gravity=G)
    stepper.grab(model, state, 0, [1.0, 0.0, 0.0])
    stepper.step(model, state)
    # Gravity does not pull a held particle, and each sub-step moved it a fifth of the way.
    assert np.array_equal(state.x[0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(state.v[0], [10.0, 0.0, 0.0], rtol=1e-12)


def test_release_throws_the_particle_with_the_hands_velocity():
    model = free_particle()
    state = model.initial_state()
    dt = 0.01
    stepper = csb.PbdStepper(dt=dt, iterations=1, gravity=G)
    h = stepper.grab(model, state, 0, [0.0, 0.0, 0.0])
    for k in range(1, 11):  # the hand moves at 2 m/s along x
        stepper.move_grab(h, [0.02 * k, 0.0, 0.0])
        stepper.step(model, state)
    stepper.release(h)
    v0 = state.v[0].copy()
    x0 = state.x[0].copy()
    np.testing.assert_allclose(v0, [2.0, 0.0, 0.0], rtol=1e-9)
    stepper.step(model, state, 10)
    # Free flight again: symplectic Euler from the release, x_n = x0 + n dt v0 + n(n+1)/2 dt² g.
    expected = x0 + 10 * dt * v0 + 55 * dt * dt * np.array(G)
    np.testing.assert_allclose(state.x[0], expected, rtol=0, atol=1e-12)


def test_compliant_grab_is_a_spring_of_stiffness_one_over_alpha():
    # XPBD's step is backward Euler on C²/(2α) (Macklin 2016): a 1 kg particle hanging from the
    # hand settles where the spring carries its weight, m g α below the hand.
    mass, alpha = 1.0, 1e-3
    model = free_particle(mass)
    state = model.initial_state()
    stepper = csb.PbdStepper(method="pbd", dt=1 / 60, iterations=1, gravity=G)
    stepper.grab(model, state, 0, [0.0, 0.0, 0.0], compliance=alpha)
    stepper.step(model, state, 600)
    # Backward Euler damps the spring's oscillation (ω h = 0.53) by ~0.2 per step: settled to round-off.
    np.testing.assert_allclose(state.x[0], [0.0, -mass * 9.81 * alpha, 0.0], rtol=0, atol=1e-12)


def test_grabs_are_deterministic_and_do_not_touch_the_model():
    def run():
        model = cloth_model(10, bending_compliance=10.0)  # XPBD's bending: 1/(N m), as the cloth_sphere scene
        state = model.initial_state()
        stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=2, iterations=5, gravity=G)
        h = stepper.grab(model, state, 55, state.x[55])
        for k in range(30):
            stepper.move_grab(h, model.rest_positions[55] + [0.01 * k, 0.02 * k, 0.0])
            stepper.step(model, state)
        stepper.release(h)
        stepper.step(model, state, 10)
        return model, state.x.copy()

    m1, x1 = run()
    _, x2 = run()
    assert np.array_equal(x1, x2)
    assert m1.inv_mass[55] > 0  # the grab changed nothing in the (immutable) model


def test_grabbing_a_pinned_particle_moves_the_pin():
    model = cloth_model(6)
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=1 / 60, iterations=10, gravity=G)
    target = state.x[0] + [0.0, 0.2, 0.0]
    h = stepper.grab(model, state, 0, target)
    stepper.step(model, state)
    stepper.release(h)
    stepper.step(model, state, 5)
    assert np.array_equal(state.x[0], target)  # pinned again, where it was let go


def test_grab_errors_name_the_problem():
    model = free_particle()
    state = model.initial_state()
    stepper = csb.PbdStepper()
    with pytest.raises(csb.ParameterError, match="particle 3 is out of range"):
        stepper.grab(model, state, 3, [0, 0, 0])
    with pytest.raises(csb.ParameterError, match="target must be finite"):
        stepper.grab(model, state, 0, [0, np.nan, 0])
    with pytest.raises(csb.ParameterError, match="compliance must be"):
        stepper.grab(model, state, 0, [0, 0, 0], compliance=-1)
    h = stepper.grab(model, state, 0, [0, 0, 0])
    with pytest.raises(csb.ParameterError, match="already held"):
        stepper.grab(model, state, 0, [0, 0, 0])
    with pytest.raises(csb.ParameterError, match="target must be finite"):
        stepper.move_grab(h, [np.inf, 0, 0])
    stepper.release(h)
    with pytest.raises(csb.ParameterError, match=f"no grab with handle {h}"):
        stepper.release(h)
    # A grab that outlives its model is caught at the next step, not read out of bounds.
    big = cloth_model(4)
    stepper.grab(big, big.initial_state(), 10, [0, 0, 0])
    with pytest.raises(csb.ParameterError, match="holds particle 10"):
        stepper.step(model, state)


def test_pick_finds_the_vertex_of_the_triangle_under_the_ray():
    n = 5
    model = cloth_model(n)  # 1 m x 1 m in the xz plane at y = 0; vertex (i, j) at x, z = -0.5 + 0.25 (i, j)
    state = model.initial_state()
    x = state.x
    # Straight down onto a point nearest to particle 7 (column 2, row 1, say): whatever its
    # numbering, the pick is the particle nearest the hit point.
    point = x[7] + [0.03, 0.0, -0.02]
    pick = csb.pick_particle(model, state, point + [0, 2.0, 0], [0, -1, 0])
    assert pick.particle == 7 and pick.triangle >= 0
    assert pick.distance == pytest.approx(2.0, abs=1e-12)
    # From below, too (cloth is two-sided), and the first hit wins over a farther one.
    assert csb.pick_particle(model, state, point - [0, 1.0, 0], [0, 3.0, 0]).particle == 7
    # Missing the cloth: by proximity within max_distance, else nothing.
    outside = x[n - 1] + [0.04, 1.0, 0.0]
    assert csb.pick_particle(model, state, outside, [0, -1, 0], max_distance=0.05).particle == n - 1
    miss = csb.pick_particle(model, state, outside, [0, -1, 0], max_distance=0.01)
    assert miss.particle == -1 and miss.triangle == -1
    # Behind the origin does not count.
    assert csb.pick_particle(model, state, point + [0, 2.0, 0], [0, 1, 0]).particle == -1


def test_pick_on_a_chain_uses_proximity():
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(4, 0.1), particle_mass=0.1)
    model = b.build()
    state = model.initial_state()
    target = state.x[2]
    pick = csb.pick_particle(model, state, target + [0.01, 0, 1.0], [0, 0, -1], max_distance=0.02)
    assert pick.particle == 2 and pick.triangle == -1 and pick.distance == pytest.approx(1.0)


def test_pick_rejects_bad_rays():
    model = cloth_model(3)
    state = model.initial_state()
    with pytest.raises(csb.ParameterError, match="direction must be finite and non-zero"):
        csb.pick_particle(model, state, [0, 1, 0], [0, 0, 0])
    with pytest.raises(csb.ParameterError, match="origin must be finite"):
        csb.pick_particle(model, state, [np.nan, 1, 0], [0, -1, 0])
    with pytest.raises(csb.ParameterError, match="max_distance"):
        csb.pick_particle(model, state, [0, 1, 0], [0, -1, 0], max_distance=-1)
