"""csb.backward_euler: backward Euler of the distance springs (energy C²/(2α)) solved by Newton's
method, the same-step reference XPBD's constraint forces are measured against."""

from __future__ import annotations

import numpy as np
import pytest

import csb
from csb.backward_euler import BackwardEulerStepper

H = 0.01  # s


def hanging_spring(*, m: float, alpha: float, rest: float, start: float, sense: str = "=="):
    """A particle of mass m (kg) hanging at y = -start (m) on a spring (compliance alpha, m/N,
    rest length rest, m) from a pin at the origin."""
    b = csb.ModelBuilder()
    g = b.add_group("spring")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([0, -start, 0], m, g)
    b.add_distance(0, 1, rest_length=rest, compliance=alpha, sense=sense)
    b.pin(0)
    return b.build()


@pytest.mark.parametrize("sense, start", [("==", 1.05), ("<=", 1.05), ("<=", 0.7)])
def test_backward_euler_of_a_linear_spring_is_the_closed_form_step(sense, start):
    """Along its axis the spring is linear: with ỹ = yⁿ + h vⁿ - h² g, the step's y solves
    m (y - ỹ)/h² + (-y - L)/α (-1) = 0, i.e. y = (m ỹ/h² - L/α)/(m/h² + 1/α), while a slack
    tether ('<=' shorter than L) falls freely (y = ỹ). A quadratic energy: one Newton step is
    exact. Each step's residual is below the stepper's tolerance τ (N), so its position is within
    τ/(m/h² + 1/α) of the closed form; backward Euler does not amplify errors, so after 20 steps
    the bound is 20 times that."""
    m, alpha, L, g = 0.5, 1e-4, 1.0, 9.81
    model = hanging_spring(m=m, alpha=alpha, rest=L, start=start, sense=sense)
    state = model.initial_state()
    stepper = BackwardEulerStepper(dt=H, gravity=(0, -g, 0))
    y, v = -start, 0.0
    for _ in range(20):
        y_tilde = y + H * v - H * H * g
        taut = sense == "==" or -y_tilde > L
        y_new = (m * y_tilde / H**2 - L / alpha) / (m / H**2 + 1 / alpha) if taut else y_tilde
        y, v = y_new, (y_new - y) / H
        stepper.step(model, state)
        assert stepper.newton_iterations == (1 if taut else 0)
        assert stepper.residual <= stepper.tolerance
        bound = 20 * stepper.tolerance / (m / H**2 + 1 / alpha) + 1e-15
        assert abs(state.x[1, 1] - y) <= bound
        assert state.x[1, 0] == 0.0 and state.x[1, 2] == 0.0 and np.all(state.x[0] == 0.0)
        # The spring force C/α (N), with C as the step leaves it.
        force = (-y - L) / alpha if taut else 0.0
        assert abs(stepper.forces[0] - force) <= bound / alpha
    assert state.t == pytest.approx(20 * H) and state.step == 20
    if sense == "<=" and start < L:
        assert stepper.forces[0] == 0.0  # still slack after 0.2 s: it falls 0.2 m of its 0.3 m


def permuted_cloth(n: int, order: np.ndarray, alpha: float) -> tuple[csb.Model, np.ndarray]:
    """An n x n cloth of 1 kg (structural and shear springs of compliance alpha, two corners
    pinned) whose particles are added in ``order``: returns it and each original particle's index."""
    plain = csb.ModelBuilder()
    inst = plain.add_mesh(csb.cloth_grid(1.0, 1.0, n, n, plane="xy"), mass=1.0, stretch_compliance=alpha)
    grid = plain.build()
    index = np.empty(len(order), dtype=int)
    index[order] = np.arange(len(order))
    b = csb.ModelBuilder()
    g = b.add_group("cloth")
    for i in order:
        b.add_particle(grid.rest_positions[i], float(grid.mass[i]), g)
    for i, j in np.asarray(grid.distance["particles"]):
        b.add_distance(int(index[i]), int(index[j]), compliance=alpha)
    for corner in (inst.first_particle + (n - 1) * n, inst.first_particle + n * n - 1):  # the top row's ends
        b.pin(int(index[corner]))
    return b.build(), index


def test_newton_converges_on_a_tumbling_cloth_in_any_particle_order(rng):
    """A 7 x 7 cloth pinned at two corners, thrown with random velocities so that springs
    compress (negative geometric stiffness: the Hessian is indefinite): every step's residual,
    recomputed here from its definition, is below the stepper's tolerance, which is 1e-9 of the
    step's largest force plus the rounding floor; and the particles' order (a random permutation
    against the grid's, so that the band comes from the reverse Cuthill-McKee order) changes the
    result only by rounding."""
    n, alpha, h, g = 7, 1e-6, 1 / 60, np.array([0.0, -9.81, 0.0])
    identity = np.arange(n * n)
    grid, _ = permuted_cloth(n, identity, alpha)
    shuffled, index = permuted_cloth(n, rng.permutation(n * n), alpha)
    velocities = rng.normal(scale=2.0, size=(n * n, 3))
    runs = {}
    for name, model, where in (("grid", grid, identity), ("shuffled", shuffled, index)):
        state = model.initial_state()
        free = np.asarray(model.inv_mass) > 0
        v0 = np.zeros((n * n, 3))
        v0[where] = velocities
        state.v = v0 * free[:, None]
        stepper = BackwardEulerStepper(dt=h)
        pairs = np.asarray(model.distance["particles"])
        rest = np.asarray(model.distance["rest_length"])
        m = np.asarray(model.mass)[:, None]
        compressed = 0
        for _ in range(30):
            x_tilde = state.x + (h * state.v + h * h * g) * free[:, None]
            stepper.step(model, state)
            e = state.x[pairs[:, 1]] - state.x[pairs[:, 0]]
            length = np.linalg.norm(e, axis=1)
            c = length - rest
            f = (c / alpha)[:, None] * (e / length[:, None])
            r = m * (state.x - x_tilde) / h**2
            np.add.at(r, pairs[:, 1], f)
            np.add.at(r, pairs[:, 0], -f)
            largest = np.abs(c / alpha).max()
            # The sums of forces of ~1e3 N here round at ~1e-13 N, far below the tolerance.
            assert np.abs(r[free]).max() <= stepper.tolerance + 1e-15 * largest
            # rtol 1e-9 of the step's force scale (at most a particle's 8 springs' forces) plus the
            # rounding floor 4 eps (|x_a| + |x_b|)/α, under 1e-8 N for a cloth within 5 m of the origin.
            assert stepper.tolerance <= 8e-9 * largest + 1e-8
            np.testing.assert_allclose(stepper.forces, c / alpha, rtol=0, atol=1e-12 * largest)
            compressed += int((c < 0).sum())
        assert compressed > 0
        runs[name] = state.x[where]
    # Positions agree to the Newton tolerance over the springs' stiffness, a few nm here.
    assert np.abs(runs["grid"] - runs["shuffled"]).max() < 1e-8


def test_bad_input_is_refused_by_name():
    model = hanging_spring(m=1.0, alpha=1e-4, rest=1.0, start=1.0)
    for kwargs, word in ((dict(dt=0.0), "dt"), (dict(dt=float("nan")), "dt"), (dict(rtol=0.0), "rtol"),
                         (dict(max_iterations=0), "max_iterations"), (dict(gravity=(0, 1)), "gravity")):
        with pytest.raises(csb.ParameterError, match=word):
            BackwardEulerStepper(**kwargs)
    with pytest.raises(csb.ParameterError, match="steps"):
        BackwardEulerStepper().step(model, model.initial_state(), -1)
    hard = hanging_spring(m=1.0, alpha=0.0, rest=1.0, start=1.0)
    with pytest.raises(csb.ParameterError, match="compliance"):
        BackwardEulerStepper().step(hard, hard.initial_state())
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 3, 3), mass=0.1, stretch_compliance=1e-6, bending_stiffness=0.5)
    cloth = b.build()
    with pytest.raises(csb.ParameterError, match="bending"):
        BackwardEulerStepper().step(cloth, cloth.initial_state())
    with pytest.raises(csb.ParameterError, match="particles"):
        BackwardEulerStepper().step(model, cloth.initial_state())
