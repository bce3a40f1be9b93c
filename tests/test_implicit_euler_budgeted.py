"""Implicit Euler in its real-time practice (method "implicit-euler", Baraff and Witkin 1998): a fixed
number of Newton iterations per step, each a linear solve by block-Jacobi preconditioned conjugate
gradients on a fixed budget (or the sparse LDLᵀ), against its converged form, the same-step reference
(method "backward-euler")."""

from __future__ import annotations

import numpy as np
import pytest

import csb

from helpers import cloth_over_sphere
from test_implicit_euler import G, chain, copy_state, every_type, spring_cloth


def cloth(n: int = 8) -> csb.Model:
    """An n x n cloth, 1 m x 1 m, 0.2 kg, stretch springs (α = 1e-5 m/N) and dihedral bending
    (α = 0.1 1/(N m)), two corners pinned."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.2, stretch_compliance=1e-5, bending_stiffness=1.0,
                      bending_compliance=0.1)
    b.pin(inst.first_particle)
    b.pin(inst.first_particle + n - 1)
    return b.build()


def falling(model: csb.Model, steps: int, dt: float) -> csb.State:
    """The state after `steps` converged backward Euler steps from rest: a cloth in motion."""
    s = model.initial_state()
    csb.BackwardEuler(dt=dt).step(model, s, steps)
    return s


def test_the_registered_method():
    info = csb.method_info("implicit-euler")
    assert info.reads == "compliance" and info.iterates and info.aliases == []
    assert [k.name for k in info.settings] == ["linear_solver", "cg_iterations", "cg_tolerance", "line_search",
                                               "initial_guess", "rtol", "contact_stiffness"]
    made = csb.make_integrator("implicit-euler", 0.01, iterations=2, cg_iterations=40, cg_tolerance=0.0)
    assert isinstance(made, csb.BackwardEuler) and made.name() == "implicit-euler" and made.linear_solver == "cg"
    direct = csb.BackwardEuler(dt=0.01, newton_iterations=2, linear_solver="cg", cg_iterations=40, cg_tolerance=0.0,
                               initial_guess="lower")
    model = every_type()
    s1, s2 = model.initial_state(), model.initial_state()
    made.step(model, s1, 5)
    direct.step(model, s2, 5)
    assert np.array_equal(s1.x, s2.x) and np.array_equal(s1.v, s2.v)
    assert made.newton_iterations <= 2 and 0 < made.cg_iterations <= 2 * 40


def test_more_newton_iterations_reach_the_converged_step():
    """From one moving state, the budgeted step's residual falls with the Newton budget, and a budget
    of direct solves large enough reaches the converged step: both minimise the same E, whose
    Newton iteration converges quadratically, so at 30 iterations the two agree to the converged
    form's tolerance (rtol 1e-9 of the force scale over a stiffness of order 1/α = 1e5 N/m: positions
    within 1e-9 m)."""
    model, dt = cloth(), 1 / 60
    start = falling(model, 20, dt)
    ref = copy_state(model, start)
    csb.BackwardEuler(dt=dt).step(model, ref)
    residuals = []
    for n in (1, 2, 4, 8):
        s = copy_state(model, start)
        ie = csb.make_integrator("implicit-euler", dt, iterations=n, cg_iterations=200, cg_tolerance=1e-10)
        ie.step(model, s)
        residuals.append(csb.backward_euler_residual(model, start, s, dt, G).max)
    assert all(b < a for a, b in zip(residuals, residuals[1:])), residuals
    s = copy_state(model, start)
    csb.make_integrator("implicit-euler", dt, iterations=30, linear_solver="direct").step(model, s)
    assert np.max(np.abs(s.x - ref.x)) < 1e-9


def test_conjugate_gradients_solve_the_gauss_newton_system():
    """One Newton iteration from xⁿ with CG run to a tight tolerance is the step dx = -H⁻¹∇E of the
    Gauss-Newton Hessian H (csb.IncrementalPotential's, solved densely here) to 1e-8 of its size;
    with a budget of 3 iterations its residual is larger."""
    model, dt = cloth(6), 1 / 60
    start = falling(model, 10, dt)
    P = csb.IncrementalPotential(model, start, dt, gravity=G)
    dyn = np.asarray(P.dynamic_particles)
    x0 = np.asarray(start.x)
    dx = -np.linalg.solve(P.hessian(x0, definite=True), P.gradient(x0)[dyn].ravel()).reshape(-1, 3)
    out = {}
    for name, settings in {"tight": dict(cg_iterations=2000, cg_tolerance=1e-14),
                           "three": dict(cg_iterations=3, cg_tolerance=0.0)}.items():
        s = copy_state(model, start)
        csb.make_integrator("implicit-euler", dt, iterations=1, line_search=False, initial_guess="previous",
                            **settings).step(model, s)
        out[name] = s
    step = np.asarray(out["tight"].x)[dyn] - x0[dyn]
    assert np.max(np.abs(step - dx)) < 1e-8 * np.max(np.abs(dx))
    r = {k: csb.backward_euler_residual(model, start, v, dt, G).max for k, v in out.items()}
    assert r["three"] > r["tight"]


def test_stable_where_explicit_methods_fail():
    """Unconditional stability: a stiff chain (α = 1e-8 m/N, 0.1 kg links: ω ~ 3e4 rad/s) at
    dt = 1/30 s, 300 steps, one Newton iteration per step; symplectic Euler diverges within a step
    at this dt (its limit is 2/ω ~ 7e-5 s). The chain's energy never grows above its start (backward
    Euler only dissipates), and it stays finite and near its links' rest length."""
    model, dt = chain(10, alpha=1e-8), 1 / 30
    s = model.initial_state()
    ie = csb.make_integrator("implicit-euler", dt, iterations=1)
    e0 = csb.measure(model, s, G)["total_energy"]
    for _ in range(300):
        ie.step(model, s)
        assert csb.measure(model, s, G)["total_energy"] <= e0 + 1e-9
    links = np.linalg.norm(np.diff(np.asarray(s.x), axis=0), axis=1)
    assert np.max(np.abs(links - 0.1)) < 0.01
    with pytest.raises(csb.SimulationError):
        csb.make_integrator("symplectic-euler", dt).step(model, model.initial_state(), 300)


def test_deterministic():
    model = every_type()
    runs = []
    for _ in range(2):
        s = model.initial_state()
        csb.make_integrator("implicit-euler", 1 / 60, iterations=3).step(model, s, 10)
        runs.append((np.array(s.x), np.array(s.v)))
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])


@pytest.mark.parametrize("settings, match", [
    (dict(cg_iterations=0), "setting 'cg_iterations' must be an integer in \\[1,"),
    (dict(cg_tolerance=1.5), "setting 'cg_tolerance' must be a number in \\[0,"),
    (dict(linear_solver="lu"), "setting 'linear_solver' must be 'cg' or 'direct', got 'lu'"),
    (dict(line_search="yes"), "setting 'line_search' must be true or false, got a string"),
    (dict(cg_iteration=5), "method 'implicit-euler' has no setting 'cg_iteration'; its settings are .*'cg_iterations'"),
])
def test_bad_settings_are_named(settings, match):
    with pytest.raises(csb.ParameterError, match=match):
        csb.make_integrator("implicit-euler", 0.01, **settings)


def test_the_converged_form_refuses_a_budget_setting():
    with pytest.raises(csb.ParameterError, match="method 'backward-euler' has no setting 'cg_iterations'"):
        csb.make_integrator("backward-euler", 0.01, cg_iterations=5)
    with pytest.raises(csb.ParameterError, match="converged form .* solves directly"):
        csb.BackwardEuler(dt=0.01, linear_solver="cg")
    with pytest.raises(csb.ParameterError, match="method 'pbd' has no setting 'chebyshev'; it takes none"):
        csb.make_integrator("pbd", 0.01, chebyshev=True)


# ------------------------------------------------------------------------------ contacts


def test_a_cloth_drapes_over_a_sphere_without_passing_through():
    """A 16 x 16 cloth (1 cm thick) dropped on a sphere, 2 s: the deepest any particle goes past the
    sphere's surface plus the thickness stays under the thickness with one Newton iteration per
    step (2.1 mm measured: the 1.3 m/s landing is resolved by a single truncated CG solve) and
    under 1 mm with three (0.27 mm measured)."""
    model = cloth_over_sphere(16)
    for iterations, bound in ((1, 0.01), (3, 1e-3)):
        s = model.initial_state()
        stepper = csb.make_integrator("implicit-euler", 1 / 60, iterations=iterations)
        worst = 0.0
        for _ in range(120):
            stepper.step(model, s)
            worst = max(worst, -np.min(np.linalg.norm(np.asarray(s.x) - [0, -0.4, 0], axis=1) - 0.31))
        assert np.all(np.isfinite(s.x)) and worst < bound, (iterations, worst)


def test_self_collision_runs_after_each_solve():
    """Self-collision is the layer after each sub-step's solve (its crossings are tested in
    test_continuous_self_collision.py): each step searches its candidates afresh."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, 4, 4), mass=0.2, stretch_compliance=1e-5)
    b.enable_self_collision(inst.group, 0.005)
    model = b.build()
    state = model.initial_state()
    stepper = csb.make_integrator("implicit-euler", 0.01)
    stepper.step(model, state, 3)
    assert stepper.self_collision["searches"] >= 3 and np.all(np.isfinite(state.x))


# ------------------------------------------------------------------------------ the claims


def oscillator(alpha: float = 1e-3, mass: float = 0.1, amplitude: float = 0.05):
    """A particle on a spring along x from a pinned one (rest length 1 m, compliance α m/N), pulled
    out by `amplitude` m, no gravity: a linear oscillator of ω = 1/sqrt(α m) while the spring stays
    along x."""
    b = csb.ModelBuilder()
    g = b.add_group("o")
    b.add_particle([0, 0, 0], mass, g)
    b.add_particle([1 + amplitude, 0, 0], mass, g)
    b.add_distance(0, 1, compliance=alpha, rest_length=1.0)
    b.pin(0)
    return b.build()


@pytest.mark.parametrize("dt", [1e-3, 1e-2, 1e-1])
def test_numerical_damping_is_the_closed_form(dt):
    """Backward Euler's numerical damping (Baraff and Witkin 1998 §4's price of stability): on a
    linear oscillator each step multiplies the energy by 1/(1 + ω²h²) exactly (its amplification
    matrix is a rotation scaled by (1 + ω²h²)^(-1/2)), so the damping grows with the time step:
    after 3 steps at ω = 100 rad/s, 3 % of the energy is lost at h = 1 ms, 87.5 % at 10 ms and all
    but 1e-6 at 0.1 s. Newton solves the linear problem in one iteration: the measured ratio agrees
    with the closed form to 1e-9 (the round-off of a 0.05 mm stretch, the smallest here, on 1 m
    coordinates is 2e-12 of it, 4e-12 of the energy)."""
    model, mass, alpha = oscillator(), 0.1, 1e-3
    omega2 = 1 / (alpha * mass)
    s = model.initial_state()
    e0 = csb.measure(model, s, (0, 0, 0))["total_energy"]
    csb.make_integrator("backward-euler", dt, gravity=(0, 0, 0)).step(model, s, 3)
    ratio = csb.measure(model, s, (0, 0, 0))["total_energy"] / e0
    expected = (1 + omega2 * dt * dt) ** -3
    assert ratio == pytest.approx(expected, rel=1e-9)
