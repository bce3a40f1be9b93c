"""The methods beside Müller's PBD: XPBD (Macklin et al. 2016), Jakobsen's Verlet (2001), the
Verlet front end, Jacobi sweeps, and the force-based integrators that fail."""

from __future__ import annotations

import math

import numpy as np
import pytest

import csb
from csb.studies import pendulum_model, swinging_chain

EPS = np.finfo(float).eps


def spring(m=0.3, L=1.0, stretch=0.2, compliance=1e-3, velocity=(0.0, 0.0, 0.0)):
    """A particle of mass m on a spring from a pinned anchor, stretched along -y."""
    b = csb.ModelBuilder()
    g = b.add_group("spring")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([0, -(L + stretch), 0], m, g)
    b.add_distance(0, 1, rest_length=L, compliance=compliance)
    b.pin(0)
    model = b.build()
    state = model.initial_state()
    state.v[1] = velocity
    return model, state


# ------------------------------------------------------------------------------ XPBD


def test_xpbd_with_zero_compliance_is_pbd():
    model = swinging_chain(links=6, compliance=0.0)
    a, b = model.initial_state(), model.initial_state()
    csb.PbdStepper(method="pbd", dt=1 / 120, iterations=8).step(model, a, 120)
    csb.PbdStepper(method="xpbd", dt=1 / 120, iterations=8).step(model, b, 120)
    # The same projection written two ways (s = C/(w|d|) against Δλ = -C/w): round-off apart.
    assert np.abs(a.x - b.x).max() < 1e-12


def test_converged_xpbd_step_is_backward_euler_with_stiffness_one_over_alpha():
    """XPBD solves the implicit Euler step of the spring energy C²/(2α): with the multiplier
    converged, m(x⁺ - p)/h² = -(1/α) C(x⁺) n(x⁺), in 3D, whatever the iteration count needed."""
    rng = np.random.default_rng(3)
    for _ in range(10):
        m, alpha, h = rng.uniform(0.1, 2), 10 ** rng.uniform(-5, -1), 0.01
        model, state = spring(m=m, compliance=alpha, velocity=rng.normal(size=3))
        p = state.x[1] + h * state.v[1]
        stepper = csb.PbdStepper(method="xpbd", dt=h, iterations=50, gravity=(0, 0, 0))
        stepper.step(model, state)
        x = state.x[1]
        C = np.linalg.norm(x) - 1.0
        residual = m * (x - p) / h**2 + C / alpha * x / np.linalg.norm(x)
        assert np.abs(residual).max() <= 1e-8 * max(m * np.linalg.norm(x - p) / h**2, 1.0)
        # λ/h² is the spring force k C (N) along -n.
        force = -stepper.multipliers()["distance"][0] / h**2
        assert force == pytest.approx(C / alpha, rel=1e-8)


def test_xpbd_stiffness_is_independent_of_the_iteration_count():
    """A chain of compliant links (α = 1e-3 m/N) and PBD stiffness 0.01: once XPBD's multipliers
    have converged the step no longer depends on the iterations, while PBD's stretch keeps
    shrinking as the iterations (uncorrected) stiffen it."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(8, 0.05, direction=(0.3, -1, 0)), density=0.1, stretch_stiffness=0.01, stretch_compliance=1e-3)
    b.pin(0)
    model = b.build()
    final = {}
    for method in ("xpbd", "pbd"):
        for it in (100, 400, 800):
            s = model.initial_state()
            csb.PbdStepper(method=method, dt=1 / 60, iterations=it, stiffness_correction=False).step(model, s, 10)
            final[method, it] = s
    stretch = {key: np.abs(csb.distance_violations(model, s)).max() for key, s in final.items()}
    assert np.abs(final["xpbd", 400].x - final["xpbd", 800].x).max() < 1e-6 * stretch["xpbd", 800]
    assert stretch["xpbd", 800] > 1e-4  # the links are compliant: they do stretch
    assert stretch["pbd", 800] < 0.5 * stretch["pbd", 100]


@pytest.mark.parametrize("sense, start, acts", [(">=", 0.8, True), (">=", 1.2, False), ("<=", 1.2, True), ("<=", 0.8, False)])
def test_xpbd_inequalities_only_act_when_violated(sense, start, acts):
    b = csb.ModelBuilder()
    g = b.add_group("pair")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([start, 0, 0], 1.0, g)
    b.add_distance(0, 1, rest_length=1.0, sense=sense, compliance=1e-6)
    b.pin(0)
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(method="xpbd", dt=0.01, iterations=20, gravity=(0, 0, 0))
    stepper.step(model, state)
    lam = stepper.multipliers()["distance"][0]
    if acts:
        # A compliant constraint leaves C α̃/(w + α̃) of its violation (α̃ = α/h², w = 1/kg).
        alpha_tilde = 1e-6 / 0.01**2
        assert state.x[1, 0] - 1.0 == pytest.approx((start - 1.0) * alpha_tilde / (1 + alpha_tilde), rel=1e-9)
        assert lam > 0 if sense == ">=" else lam < 0
    else:
        assert state.x[1, 0] == start and lam == 0.0


def test_xpbd_damping_dissipates_a_spring_oscillation():
    energies = []
    for beta in (0.0, 5.0):
        model, state = spring(m=0.2, compliance=1e-3, stretch=0.05)
        stepper = csb.PbdStepper(method="xpbd", dt=1 / 600, iterations=5, gravity=(0, 0, 0), xpbd_damping=beta)
        stepper.step(model, state, 600)
        energies.append(csb.measure(model, state, (0, 0, 0))["total_energy"])
    assert energies[1] < 0.2 * energies[0]


# ------------------------------------------------------------------------------ Jakobsen, front ends


def test_verlet_front_end_and_jakobsen_match_pbd_to_round_off():
    model = swinging_chain(links=6, compliance=0.0)
    runs = {}
    for name, kw in {"pbd": dict(method="pbd"), "pbd-verlet": dict(method="pbd", front_end="verlet"),
                     "jakobsen": dict(method="jakobsen")}.items():
        s = model.initial_state()
        csb.PbdStepper(dt=1 / 120, iterations=5, stiffness_correction=False, **kw).step(model, s, 120)
        runs[name] = s
    for other in ("pbd-verlet", "jakobsen"):
        # p = x + (x - x*) + h²g against v += hg, p = x + hv: the same prediction, rounded apart.
        assert np.abs(runs[other].x - runs["pbd"].x).max() < 1e-10
        assert np.abs(runs[other].v - runs["pbd"].v).max() < 1e-7


def test_jakobsen_square_root_approximation_is_second_order_near_rest_length():
    K = csb.kernels
    for eps in (1e-2, 1e-3):
        p1, p2 = np.zeros(3), np.array([1.0 + eps, 0.0, 0.0])
        exact = K.project_distance(p1, p2, 1.0, 1.0, 1.0)[1]
        b = csb.ModelBuilder()
        g = b.add_group("stick")
        b.add_particle(p1, 1.0, g)
        b.add_particle(p2, 1.0, g)
        b.add_distance(0, 1, rest_length=1.0)
        model = b.build()
        s = model.initial_state()
        csb.PbdStepper(method="jakobsen", dt=1.0, iterations=1, gravity=(0, 0, 0), sqrt_approximation=True).step(model, s)
        # A single projection leaves (d·d - r²)/(d·d + r²) vs (|d| - r)/|d|: O(eps²) apart.
        assert abs(s.x[1, 0] - exact[0]) < eps**2


def test_jakobsen_drag_slows_a_free_particle():
    b = csb.ModelBuilder()
    b.add_particle([0, 0, 0], 1.0, b.add_group("p"))
    model = b.build()
    s = model.initial_state()
    s.v[0] = [1.0, 0, 0]
    csb.PbdStepper(method="jakobsen", dt=0.01, gravity=(0, 0, 0), verlet_drag=0.01).step(model, s, 10)
    assert s.v[0, 0] == pytest.approx(0.99**10, rel=1e-9)


# ------------------------------------------------------------------------------ Jacobi


def test_summed_jacobi_diverges_while_gauss_seidel_and_averaged_jacobi_converge():
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1, 1, 10, 10), density=0.2)
    model = b.build()
    residual = {}
    for solver in ("gauss-seidel", "jacobi", "jacobi-summed"):
        for it in (5, 200):
            s = model.initial_state()
            s.x = s.x * 1.2  # every edge 20 % too long
            try:
                csb.PbdStepper(dt=1 / 60, iterations=it, gravity=(0, 0, 0), solver=solver).step(model, s)
                residual[solver, it] = np.abs(csb.distance_violations(model, s)).max()
            except csb.SimulationError:
                residual[solver, it] = np.inf
    assert residual["gauss-seidel", 200] < 1e-9 < residual["gauss-seidel", 5]
    assert residual["jacobi", 200] < 0.05 * residual["jacobi", 5]  # converges, slowly
    assert residual["jacobi-summed", 200] > 1e6 * residual["jacobi-summed", 5]


# ------------------------------------------------------------------------------ force-based


def test_explicit_euler_gains_exactly_one_plus_omega_h_squared_per_step():
    m, k, h = 0.5, 200.0, 0.01
    model, state = spring(m=m, compliance=1 / k, stretch=0.1)
    e = lambda s: csb.measure(model, s, (0, 0, 0))["total_energy"]  # noqa: E731
    e0 = e(state)
    csb.ForceStepper(method="explicit-euler", dt=h, gravity=(0, 0, 0)).step(model, state)
    # A 1D undamped oscillator: |1 + iωh|² = 1 + (ωh)².
    assert e(state) / e0 == pytest.approx(1 + k / m * h**2, rel=1e-12)


@pytest.mark.parametrize("method", ["symplectic-euler", "velocity-verlet"])
def test_stability_limit_is_two_over_omega(method):
    m, k = 0.5, 200.0
    h_crit = 2 / math.sqrt(k / m)
    for factor, stable in ((0.98, True), (1.02, False)):
        model, state = spring(m=m, compliance=1 / k, stretch=0.1)
        stepper = csb.ForceStepper(method=method, dt=factor * h_crit, gravity=(0, 0, 0))
        if stable:
            stepper.step(model, state, 2000)
            assert abs(np.linalg.norm(state.x[1]) - 1.0) < 0.5  # bounded
        else:
            with pytest.raises(csb.SimulationError, match="non-finite"):
                stepper.step(model, state, 20000)


def test_force_based_methods_converge_to_the_reference():
    """Well below the stability limit (ω_max h ≤ 0.23 here), symplectic Euler is first order
    and velocity Verlet second."""
    model = swinging_chain(links=4, compliance=1e-3)
    ref = csb.integrate_reference(model, model.initial_state(), [0.3], rtol=1e-12, atol=1e-14)
    for method, order in (("symplectic-euler", 1), ("velocity-verlet", 2)):
        errors = []
        for dt in (2.5e-4, 1.25e-4, 6.25e-5):
            s = model.initial_state()
            csb.ForceStepper(method=method, dt=dt).step(model, s, round(0.3 / dt))
            errors.append(np.abs(s.x - ref.x[0]).max())
        observed = np.log2(errors[-2] / errors[-1])
        assert abs(observed - order) < 0.15, (method, errors)


def verlet_two_evaluations(model, state, *, dt, substeps, steps, gravity, damping=0.0, drag=0.0):
    """Velocity Verlet as written in force.hpp, evaluating a(x) afresh at the start of every
    sub-step: y = [x; v] of the dynamic particles after `steps` steps, the same operations in
    the same order as the C++ loop (numpy's element-wise IEEE arithmetic, no contraction)."""
    net = csb.SpringNetwork(model, state, gravity=gravity, damping=damping, drag=drag)
    y = net.pack(state)
    n3, h = y.size // 2, dt / substeps
    for _ in range(steps * substeps):
        a = net.rhs(y)[n3:]
        y2 = np.concatenate([y[:n3] + h * y[n3:] + 0.5 * h * h * a, y[n3:] + h * a])
        a2 = net.rhs(y2)[n3:]
        y2[n3:] = y[n3:] + 0.5 * h * (a + a2)
        y = y2
    return y


def same_bits(a, b) -> bool:
    return np.asarray(a).tobytes() == np.asarray(b).tobytes()


def test_velocity_verlet_evaluates_the_forces_once_per_substep_with_the_same_bits():
    """a(x') at the end of a sub-step is a(x) of the next: reusing it is the same arithmetic as
    evaluating it again, so the state must match the two-evaluation loop bit for bit, across
    calls too, and one call of n steps must equal n calls of one."""
    model = swinging_chain(links=4, compliance=1e-3)
    dt, sub, g = 2e-4, 3, (0.0, -9.81, 0.0)
    net = csb.SpringNetwork(model, model.initial_state(), gravity=g)
    stepper = csb.ForceStepper(method="velocity-verlet", dt=dt, substeps=sub, gravity=g)
    one_call, many_calls = model.initial_state(), model.initial_state()
    stepper.step(model, one_call, 40)
    assert stepper.force_evaluations == 1 + 40 * sub  # the first a(x), then one per sub-step
    other = csb.ForceStepper(method="velocity-verlet", dt=dt, substeps=sub, gravity=g)
    other.step(model, many_calls)
    for k in range(39):
        before = other.force_evaluations
        other.step(model, many_calls)
        assert other.force_evaluations - before == sub  # the cache holds between calls
    expected = verlet_two_evaluations(model, model.initial_state(), dt=dt, substeps=sub, steps=40, gravity=g)
    assert same_bits(net.pack(one_call), expected)
    assert same_bits(net.pack(many_calls), expected)
    assert same_bits(one_call.x, many_calls.x) and same_bits(one_call.v, many_calls.v)


def test_force_stepper_cache_misses_when_the_state_or_the_model_changes():
    """A state written between calls (positions, velocities, time), or another model, must get
    its own a(x): the result then equals a fresh stepper's, and it cost a second evaluation."""
    model = swinging_chain(links=4, compliance=1e-3)
    stiffer = swinging_chain(links=4, compliance=1e-4)  # same particles, other springs
    dt, g = 2e-4, (0.0, -9.81, 0.0)
    stepper = csb.ForceStepper(method="velocity-verlet", dt=dt, gravity=g)
    state = model.initial_state()
    stepper.step(model, state, 10)

    def edit_x(s):
        s.x[3, 0] += 1e-4

    def edit_v(s):
        s.v[2, 1] += 1e-3

    def edit_t(s):
        s.t += 1.0

    for m, edit in ((model, edit_x), (model, edit_v), (model, edit_t), (stiffer, lambda s: None)):
        edit(state)
        fresh = state.copy()
        csb.ForceStepper(method="velocity-verlet", dt=dt, gravity=g).step(m, fresh, 5)
        before = stepper.force_evaluations
        stepper.step(m, state, 5)
        assert stepper.force_evaluations - before == 1 + 5
        assert same_bits(state.x, fresh.x) and same_bits(state.v, fresh.v)
        assert state.t == fresh.t


@pytest.mark.parametrize("method", ["explicit-euler", "symplectic-euler"])
def test_euler_methods_evaluate_the_forces_once_per_substep(method):
    model = swinging_chain(links=4, compliance=1e-3)
    stepper = csb.ForceStepper(method=method, dt=1e-4, substeps=2)
    state = model.initial_state()
    stepper.step(model, state, 30)
    stepper.step(model, state, 20)
    assert stepper.force_evaluations == 2 * 50


def test_damped_velocity_verlet_evaluates_twice_and_keeps_its_bits():
    """With damping or drag a(x', v') is not a(x', v + h a): two evaluations a sub-step."""
    model = swinging_chain(links=4, compliance=1e-3)
    dt, g = 2e-4, (0.0, -9.81, 0.0)
    for damping, drag in ((0.05, 0.0), (0.0, 0.5)):
        stepper = csb.ForceStepper(method="velocity-verlet", dt=dt, gravity=g, damping=damping, drag=drag)
        state = model.initial_state()
        stepper.step(model, state, 20)
        stepper.step(model, state, 20)
        assert stepper.force_evaluations == 2 * 40
        expected = verlet_two_evaluations(model, model.initial_state(), dt=dt, substeps=1, steps=40, gravity=g,
                                          damping=damping, drag=drag)
        assert same_bits(csb.SpringNetwork(model, state, gravity=g).pack(state), expected)


# ------------------------------------------------------------------------------ bad settings


# ------------------------------------------------------------------------------ bad settings


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(method="xpb"), r"method must be 'pbd', 'xpbd' or 'jakobsen', got 'xpb'"),
        (dict(front_end="leapfrog"), r"front_end must be 'euler', 'verlet' or 'auto'"),
        (dict(solver="sor"), r"solver must be 'gauss-seidel', 'jacobi' or 'jacobi-summed'"),
        (dict(front_end="verlet", damping=0.1), r"damping \(Müller 2007 §3\.5\) acts on stored velocities"),
        (dict(method="jakobsen", damping=0.1), r"needs the Euler front end"),
        (dict(verlet_drag=0.1), r"verlet_drag applies to the Verlet front end only"),
        (dict(method="jakobsen", verlet_drag=1.0), r"verlet_drag must be in \[0, 1\), got 1"),
        (dict(xpbd_damping=1.0), r"xpbd_damping applies to XPBD only"),
        (dict(method="xpbd", xpbd_damping=-1.0), r"xpbd_damping must be a finite coefficient >= 0"),
        (dict(sqrt_approximation=True), r"sqrt_approximation is part of Jakobsen's method only"),
    ],
)
def test_impossible_method_settings(kwargs, message):
    with pytest.raises(csb.ParameterError, match=message):
        csb.PbdStepper(**kwargs)


def test_force_stepper_bad_input():
    with pytest.raises(csb.ParameterError, match=r"method must be 'explicit-euler'"):
        csb.ForceStepper(method="rk4")
    with pytest.raises(csb.ParameterError, match=r"dt must be a finite time step > 0 s"):
        csb.ForceStepper(dt=0.0)
    model = pendulum_model(0.3, compliance=0.0)
    with pytest.raises(csb.ParameterError, match=r"distance constraint 0 is hard"):
        csb.ForceStepper().step(model, model.initial_state())


def test_force_steppers_refuse_contacts_they_would_ignore():
    """The force-based integrators have no contact term: a model with a collider or with
    self-collision is refused by name (it used to be stepped as if they were not there, a pair of
    particles falling through the floor) and the state is left as it was."""
    b = csb.ModelBuilder()
    g = b.add_group("pair")
    b.add_particle([0.0, 0.1, 0.0], 1.0, g)
    b.add_particle([0.1, 0.1, 0.0], 1.0, g)
    b.add_distance(0, 1, compliance=1e-3)
    b.add_plane(name="floor")
    model = b.build()
    state = model.initial_state()
    for method in ("explicit-euler", "symplectic-euler", "velocity-verlet"):
        with pytest.raises(csb.ParameterError, match=r"has no contacts.*1 collider\(s\) \('floor'\)"):
            csb.ForceStepper(method=method, dt=1e-3).step(model, state, 10)
    assert np.array_equal(np.asarray(state.x)[:, 1], [0.1, 0.1]) and state.step == 0
    b = csb.ModelBuilder()
    sheet = b.add_mesh(csb.cloth_grid(0.3, 0.3, 3, 3), mass=0.1, stretch_compliance=1e-4)
    b.enable_self_collision(sheet.group, 0.005)
    folding = b.build()
    with pytest.raises(csb.ParameterError, match=r"group 'cloth_grid\(3x3\)' has self-collision"):
        csb.ForceStepper(dt=1e-4).step(folding, folding.initial_state())
