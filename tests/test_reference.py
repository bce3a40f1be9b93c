"""The reference integrator (CVODE on the model's springs) against closed forms, its Jacobian,
its self-convergence, and the analytic scenes it and PBD are measured on."""

from __future__ import annotations

import math

import numpy as np
import pytest

import csb
import csb.studies
from csb.studies import catenary, hanging_chain, pendulum_model, pendulum_period, relative_energy_drift

G = (0.0, -9.81, 0.0)


def elliptic_k(m: float) -> float:
    """Complete elliptic integral of the first kind K(m) by the arithmetic-geometric mean."""
    a, b = 1.0, math.sqrt(1 - m)
    for _ in range(60):
        a, b = (a + b) / 2, math.sqrt(a * b)
    return math.pi / (2 * a)


# ------------------------------------------------------------------------------ the system itself


def random_network(rng, damping: float, drag: float):
    b = csb.ModelBuilder()
    g = b.add_group("net")
    for _ in range(8):
        b.add_particle(rng.normal(size=3), rng.uniform(0.2, 2.0), g)
    b.pin(7)
    pairs = [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (4, 5), (5, 6), (6, 7), (4, 7), (1, 5)]
    for k, (i, j) in enumerate(pairs):
        d = float(np.linalg.norm(b.position(i) - b.position(j)))
        # equalities, and inequalities both active (stretched '<=', compressed '>=') and not
        sense = ["==", "<=", ">=", "<="][k % 4]
        rest = d * (0.8 if sense == "<=" else 1.2 if sense == ">=" else 1.1) if k % 5 else d * 1.3
        b.add_distance(i, j, rest_length=rest, sense=sense, compliance=rng.uniform(1e-3, 1e-2))
    b.attach(3, [0.5, 0.5, 0.5], compliance=2e-3)
    model = b.build()
    return model, csb.SpringNetwork(model, model.initial_state(), gravity=G, damping=damping, drag=drag)


@pytest.mark.parametrize("damping, drag", [(0.0, 0.0), (0.7, 0.3)])
def test_analytic_jacobian_matches_finite_differences(rng, damping, drag):
    model, net = random_network(rng, damping, drag)
    assert net.has_analytic_jacobian and net.num_dynamic == 7 and net.size == 42
    y = net.pack(model.initial_state()) + rng.normal(scale=0.05, size=net.size)
    indptr, indices, data = net.jacobian(y)
    J = np.zeros((net.size, net.size))
    for col in range(net.size):
        J[indices[indptr[col]:indptr[col + 1]], col] = data[indptr[col]:indptr[col + 1]]
    assert all(J[r, r] == J[r, r] for r in range(net.size))  # the diagonal is stored
    assert np.all(np.diff(indptr) >= 1)
    h = 1e-6
    F = np.zeros_like(J)
    for col in range(net.size):
        e = np.zeros(net.size)
        e[col] = h
        F[:, col] = (net.rhs(y + e) - net.rhs(y - e)) / (2 * h)
    # Central differences: truncation O(h² f''') and round-off O(eps |f| / h), both below
    # 1e-7 of the largest entry for these forces (|J| up to ~1e4).
    np.testing.assert_allclose(J, F, atol=1e-7 * np.abs(J).max())


def test_elastic_energy_is_c_squared_over_two_alpha():
    b = csb.ModelBuilder()
    g = b.add_group("s")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([1.3, 0, 0], 1.0, g)
    b.add_distance(0, 1, rest_length=1.0, compliance=0.01)
    b.add_distance(0, 1, rest_length=1.3)  # hard: no energy, only a violation (0 here)
    model = b.build()
    m = csb.measure(model, model.initial_state(), G)
    assert m["elastic_energy"] == pytest.approx(0.3**2 / (2 * 0.01), rel=1e-14)
    assert m["total_energy"] == pytest.approx(m["kinetic_energy"] + m["gravitational_energy"] + m["elastic_energy"])
    assert csb.elastic_energy(model, model.initial_state()) == m["elastic_energy"]


# ------------------------------------------------------------------------------ closed forms


def test_harmonic_oscillator_matches_the_exact_solution_over_fifty_periods():
    m, k, L, A = 0.5, 200.0, 1.0, 0.1
    b = csb.ModelBuilder()
    g = b.add_group("oscillator")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([L + A, 0, 0], m, g)
    b.add_distance(0, 1, rest_length=L, compliance=1 / k)
    b.pin(0)
    model = b.build()
    w = math.sqrt(k / m)
    times = np.linspace(0, 50 * 2 * math.pi / w, 2001)
    r = csb.integrate_reference(model, model.initial_state(), times, gravity=(0, 0, 0), rtol=1e-10, atol=1e-12)
    u, v = r.x[:, 1, 0] - L, r.v[:, 1, 0]
    amplitude = np.sqrt(u**2 + (v / w) ** 2)
    phase = np.angle(np.exp(1j * (np.arctan2(-v / w, u) - w * times)))
    # rtol = 1e-10 per step, about 10^4 steps: the global error stays near 1e-6 of the amplitude.
    assert np.abs(amplitude / A - 1).max() < 1e-5
    assert np.abs(phase).max() < 1e-5
    assert r.stats["linear_solver"] == "klu" and r.stats["steps"] > 0


def fast_oscillator(omega: float = 100.0, amplitude: float = 0.1) -> csb.Model:
    b = csb.ModelBuilder()
    g = b.add_group("oscillator")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_particle([1.0 + amplitude, 0, 0], 1.0, g)
    b.add_distance(0, 1, rest_length=1.0, compliance=1 / omega**2)
    b.pin(0)
    return b.build()


def test_the_default_keeps_a_fast_oscillators_energy_within_its_bound():
    """100 rad/s for 100 periods: rtol 1e-8 (BDF up to order 5) loses ~3e-4 of the energy (BDF5
    loses ~13 rtol^(5/6) a period, validation/reference_energy.py); the default rtol="auto" takes
    the tolerance that bounds the loss by energy_tolerance = 1e-6 and keeps it."""
    omega = 100.0
    model = fast_oscillator(omega)
    times = np.linspace(0, 100 * 2 * math.pi / omega, 801)

    def change(**kwargs):
        r = csb.integrate_reference(model, model.initial_state(), times, gravity=(0, 0, 0), **kwargs)
        e = [csb.measure(model, s, (0, 0, 0))["total_energy"] for s in r.states(model)]
        return abs(e[-1] / e[0] - 1), r.stats

    former, _ = change(rtol=1e-8, atol=1e-10)
    assert former > 1e-4
    now, stats = change()
    assert stats["energy_bound"] == pytest.approx(1e-6) and stats["frequency"] == pytest.approx(omega)
    assert stats["rtol"] < 1e-11 and stats["atol"] == stats["rtol"] / 100
    assert now <= 1e-6
    tighter, stats = change(energy_tolerance=1e-8)  # the bound follows the setting
    assert tighter <= 1e-8 and stats["energy_bound"] == pytest.approx(1e-8)


def test_energy_rule_and_frequency_bound():
    from csb.reference import ENERGY_CONSTANT, energy_bound, energy_rtol, frequency_bound

    model = fast_oscillator(100.0)
    assert frequency_bound(model, model.initial_state(), (0, 0, 0)) == pytest.approx(100.0, rel=1e-12)
    chain = csb.studies.swinging_chain(links=5, compliance=1e-5)
    w_max = csb.studies.omega_max(chain, chain.initial_state())
    assert w_max <= frequency_bound(chain, chain.initial_state()) <= 2 * w_max  # an upper bound, not a loose one
    rtol = energy_rtol(100.0, 2 * math.pi, 1e-6)  # 100 periods
    assert energy_bound(rtol, 100.0, 2 * math.pi) == pytest.approx(1e-6)
    assert rtol == pytest.approx((1e-6 / (ENERGY_CONSTANT * 100)) ** 1.2)
    assert energy_rtol(1.0, 1e-3, 1e-6) == 1e-8  # never looser than the trajectories' tolerance
    assert energy_rtol(0.0, 10.0) == 1e-8


@pytest.mark.parametrize("degrees, exact", [(30, 1.017409), (90, 1.180341), (120, 1.372881)])
def test_reference_pendulum_period_is_the_elliptic_integral(degrees, exact):
    """T/T0 = (2/π) K(sin²(θ0/2)). The rod is a spring of compliance 1e-8 m/N: with m = 1 kg and
    L = 1 m its stretch m g α / L ≈ 1e-7 changes the period by that order, two orders below the
    1e-5 asked for, and its radial mode (3e3 rad/s) is far above the swing (3 rad/s)."""
    theta = math.radians(degrees)
    ratio = 2 / math.pi * elliptic_k(math.sin(theta / 2) ** 2)
    assert ratio == pytest.approx(exact, abs=5e-7)
    model = pendulum_model(theta, compliance=1e-8)
    T0 = 2 * math.pi * math.sqrt(1.0 / 9.81)
    times = np.arange(0, 2.2 * ratio * T0, 1e-3)
    r = csb.integrate_reference(model, model.initial_state(), times, rtol=1e-10, atol=1e-12)
    assert pendulum_period(times, r.x[:, 1, 0]) / T0 == pytest.approx(ratio, rel=1e-5)


def test_pbd_pendulum_period_converges_at_first_order_in_the_substep():
    theta = math.radians(30)
    exact = 2 / math.pi * elliptic_k(math.sin(theta / 2) ** 2) * 2 * math.pi * math.sqrt(1 / 9.81)
    model = pendulum_model(theta, compliance=0.0)
    errors = []
    for substeps in (8, 16, 32, 64):
        state = model.initial_state()
        stepper = csb.PbdStepper(dt=1 / 60, substeps=substeps, iterations=1)
        t, x = [0.0], [state.x[1, 0]]
        for _ in range(int(2.5 * exact * 60)):
            stepper.step(model, state)
            t.append(state.t)
            x.append(state.x[1, 0])
        errors.append(abs(pendulum_period(np.array(t), np.array(x)) / exact - 1))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[-1] < 1e-3
    assert np.all((orders > 0.9) & (orders < 1.1)), orders


def test_single_pbd_spring_step_is_backward_euler():
    """One step of n projections of one spring to a fixed anchor is exactly a backward Euler step
    of a Hooke spring of k_eff = m((1 - k)^(-n) - 1)/Δt², in 3D: m(x⁺ - p)/Δt² = -k_eff C(x⁺) n(x⁺)."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        m, k, n, dt, L = rng.uniform(0.1, 2), rng.uniform(0.05, 0.9), int(rng.integers(1, 6)), 0.01, 1.0
        b = csb.ModelBuilder()
        g = b.add_group("s")
        b.add_particle([0, 0, 0], 1.0, g)
        b.add_particle(rng.normal(size=3) * 0.5 + [0, -1.2, 0], m, g)
        b.add_distance(0, 1, stiffness=k, rest_length=L)
        b.pin(0)
        model = b.build()
        state = model.initial_state()
        state.v[1] = rng.normal(size=3)
        p = state.x[1] + dt * state.v[1]
        csb.PbdStepper(dt=dt, iterations=n, gravity=(0, 0, 0), stiffness_correction=False).step(model, state)
        x = state.x[1]
        k_eff = m * ((1 - k) ** -n - 1) / dt**2
        residual = m * (x - p) / dt**2 + k_eff * (np.linalg.norm(x) - L) * x / np.linalg.norm(x)
        scale = m * np.linalg.norm(x - p) / dt**2
        assert np.abs(residual).max() <= 1e-11 * max(scale, 1.0)


def test_hanging_chain_rest_states_match_the_discrete_catenary():
    """N = 10 links of 0.1 m, 5 g nodes, supports 0.8 m apart. PBD (hard links) converges to a
    rest state that is off the catenary by O(h²): Gauss-Seidel lands on the constraint manifold,
    but not at the mass-orthogonal projection that statics needs, so each step's gravity
    prediction h²g leaves a bias. The reference (elastic links, k = 1000 N/m, brought to rest by
    drag and a dashpot) matches the elastic catenary."""
    N, l0, span, mass = 10, 0.1, 0.8, 0.005
    hard = catenary(N, l0, span, mass)
    model = hanging_chain(N, l0, span, mass)
    bias = []
    for substeps in (1, 4, 16):
        state = model.initial_state()
        csb.PbdStepper(dt=1 / 60, substeps=substeps, iterations=300, damping=0.05).step(model, state, 900)
        assert np.abs(state.v).max() < 1e-8  # at rest
        assert np.abs(csb.distance_violations(model, state)).max() < 1e-8  # converged
        bias.append(np.abs(state.x[:, :2] - hard).max())
    assert bias[-1] < 2e-6
    orders = np.log2(np.array(bias[:-1]) / np.array(bias[1:])) / 2  # per halving of h
    assert np.all((orders > 1.8) & (orders < 2.2)), orders

    k = 1000.0
    elastic = catenary(N, l0, span, mass, stiffness=k)
    model = hanging_chain(N, l0, span, mass, compliance=1 / k)
    r = csb.integrate_reference(model, model.initial_state(), [30.0], drag=2.0, damping=0.05)
    assert np.abs(r.x[0][:, :2] - elastic).max() < 1e-8
    assert np.abs(r.x[0][:, :2] - hard).max() > 1e-4  # the links did stretch


# ------------------------------------------------------------------------------ self-convergence


def quick_chain() -> csb.Model:
    """A 5-link hanging chain released at 20°; stiff links (α = 1e-5 m/N, stretch ≤ 1e-5 m)."""
    return csb.studies.swinging_chain(links=5, compliance=1e-5)


def quick_cloth() -> csb.Model:
    """A 4 x 4 cloth pinned at two corners with compliant stretch and bending (GMRES path)."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(0.3, 0.3, 4, 4), density=0.2, stretch_compliance=1e-4,
                      bending_stiffness=1.0, bending_compliance=0.1)
    b.pin(inst.nearest([-0.15, 0, -0.15]))
    b.pin(inst.nearest([0.15, 0, -0.15]))
    return b.build()


@pytest.mark.parametrize("make, duration, solver", [(quick_chain, 1.0, "klu"), (quick_cloth, 0.5, "gmres")])
def test_reference_self_convergence(make, duration, solver):
    """A tolerance sweep moves the trajectory by less than 1% of the smallest PBD error measured
    against it (PBD at 1/960 s here, whose constraints are hard: the models declare only
    compliances), and the undamped energy drifts by less than 1e-6."""
    model = make()
    start = model.initial_state()
    times = np.linspace(0, duration, 11)
    runs = {rtol: csb.integrate_reference(model, start, times, rtol=rtol, atol=rtol * 1e-2) for rtol in (1e-8, 1e-10, 1e-12)}
    assert runs[1e-10].stats["linear_solver"] == solver
    spread = max(np.abs(runs[r].x - runs[1e-12].x).max() for r in (1e-8, 1e-10))
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=duration / 10 / 96, iterations=20)
    smallest = np.inf
    with pytest.warns(csb.MaterialWarning, match="PBD reads stiffness, not compliance: .* so PBD makes them rigid"):
        stepper.step(model, state, 96)
    smallest = np.linalg.norm(state.x - runs[1e-12].x[1], axis=1).max()
    for k in range(2, len(times)):
        stepper.step(model, state, 96)
        smallest = min(smallest, np.linalg.norm(state.x - runs[1e-12].x[k], axis=1).max())
    assert spread < 0.01 * smallest
    default = csb.integrate_reference(model, start, times)
    assert relative_energy_drift(model, list(default.states(model)), G) < 1e-6


# ------------------------------------------------------------------------------ bad input


def small_model(compliance: float = 1e-3) -> csb.Model:
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(3, 0.1), particle_mass=0.01, stretch_compliance=compliance)
    b.pin(0)
    return b.build()


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(rtol=0.0), r"rtol must be a finite tolerance > 0, got 0"),
        (dict(rtol=-1e-8), r"rtol must be"),
        (dict(atol=0.0), r"atol must be a finite tolerance > 0, got 0"),
        (dict(atol=float("nan")), r"atol must be"),
        (dict(damping=-1.0), r"damping must be a finite coefficient >= 0"),
        (dict(drag=-1.0), r"drag must be a finite rate >= 0"),
        (dict(max_order=6), r"max_order must be an integer in \[1, 5\], got 6"),
        (dict(linear_solver="lu"), r"linear_solver must be 'auto', 'klu' or 'gmres', got 'lu'"),
        (dict(max_steps=0), r"max_steps must be an integer in \[1, 9223372036854775807\], got 0"),
        (dict(times=[0.1, 0.1]), r"output times must increase: time 1 \(0\.1 s\) is not after time 0"),
        (dict(times=[0.2, 0.1]), r"output times must increase"),
        (dict(times=[-0.1, 0.1]), r"output time 0 \(-0\.1 s\) is before the start time 0 s"),
        (dict(times=[float("inf")]), r"output time 0 is not finite"),
        (dict(rtol="fast"), r"rtol must be 'auto' or a finite tolerance > 0, got 'fast'"),
        (dict(atol="small"), r"atol must be 'auto' or a finite tolerance > 0"),
        (dict(energy_tolerance=0.0), r"energy_tolerance must be a finite number > 0"),
        (dict(energy_tolerance=float("nan")), r"energy_tolerance must be a finite number > 0"),
        (dict(energy_tolerance=1.5), r"energy_tolerance must be below 1"),
        (dict(energy_tolerance=0.0, rtol=1e-8), r"energy_tolerance must be a finite number > 0"),
        (dict(frequency=-1.0), r"frequency must be a finite angular frequency > 0 rad/s, got -1"),
        (dict(frequency="fast"), r"frequency must be a finite angular frequency > 0 rad/s"),
        (dict(max_order=3), r"rtol='auto' follows BDF5's energy law and needs max_order=5"),
        (dict(times=[1e4], frequency=1e3), r"rtol='auto' cannot keep the energy within energy_tolerance=1e-06 over "
                                           r".* periods of frequency=1000 rad/s .*needs rtol=.*below 1e-14"),
    ],
)
def test_bad_reference_input(kwargs, message):
    times = kwargs.pop("times", [0.1])
    with pytest.raises(csb.ParameterError, match=message):
        csb.integrate_reference(small_model(), small_model().initial_state(), times, **kwargs)


def test_hard_constraints_and_frozen_models_are_refused():
    model = small_model(compliance=0.0)
    with pytest.raises(csb.ParameterError, match=r"distance constraint 0 is hard \(compliance 0\).*needs a compliance"):
        csb.integrate_reference(model, model.initial_state(), [0.1])
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(2, 0.1), particle_mass=0.01, stretch_compliance=1e-3)
    for i in range(3):
        b.pin(i)
    frozen = b.build()
    with pytest.raises(csb.ParameterError, match=r"no dynamic particles"):
        csb.integrate_reference(frozen, frozen.initial_state(), [0.1])
    cloth = quick_cloth()
    with pytest.raises(csb.ParameterError, match=r"'klu' needs an analytic Jacobian"):
        csb.integrate_reference(cloth, cloth.initial_state(), [0.1], linear_solver="klu")


def test_a_run_that_cannot_finish_stops_with_an_error_not_a_hang():
    model = small_model()
    with pytest.raises(csb.SimulationError, match=r"CVODE stopped at t = .* s on the way to 10 s: max_steps = 50"):
        csb.integrate_reference(model, model.initial_state(), [10.0], max_steps=50)
    with pytest.raises(csb.SimulationError, match=r"max_wall_time = 0\.2 s ran out"):
        csb.integrate_reference(model, model.initial_state(), [1e4], max_wall_time=0.2, rtol=1e-12)
    state = model.initial_state()
    r = csb.integrate_reference(model, state, [0.0, 0.05])  # the start time itself is allowed
    np.testing.assert_array_equal(r.x[0], state.x)
