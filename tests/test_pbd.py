"""The PBD stepper (Müller et al. 2007, Algorithm 1) against closed forms."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

import csb
from csb.studies import spring_k_eff, strain_history
from helpers import cloth_model

EPS = np.finfo(float).eps
G = np.array([0.0, -9.81, 0.0])


def particles_model(x: np.ndarray, m: np.ndarray) -> csb.Model:
    b = csb.ModelBuilder()
    g = b.add_group("free")
    for xi, mi in zip(x, m):
        b.add_particle(xi, mi, g)
    return b.build()


@pytest.mark.parametrize("substeps", [1, 3])
def test_free_fall_is_symplectic_euler_to_round_off(rng, substeps):
    x0 = rng.uniform(-1, 1, (20, 3))
    v0 = rng.uniform(-2, 2, (20, 3))
    model = particles_model(x0, rng.uniform(0.1, 2.0, 20))
    state = model.initial_state()
    state.v[:] = v0
    dt, steps = 0.01, 500
    csb.PbdStepper(dt=dt, substeps=substeps, iterations=5, gravity=G).step(model, state, steps)

    h = dt / substeps
    n = steps * substeps
    x, v = x0.copy(), v0.copy()  # symplectic Euler
    xa, va = x0.copy(), v0.copy()  # Algorithm 1 without constraints, in numpy
    for _ in range(n):
        v = v + h * G
        x = x + h * v
        va = va + h * G
        p = xa + h * va
        va = (p - xa) / h
        xa = p
    # Algorithm 1 is symplectic Euler whose velocity is recovered as (p - x)/h; done in the same
    # order in numpy it agrees to the last bit.
    assert np.array_equal(state.x, xa) and np.array_equal(state.v, va)
    # That recovery rounds v by about eps|x|/h per sub-step; in the worst case these add up
    # to n eps max|x|/h in v and n²/2 eps max|x| in x.
    scale = EPS * np.abs(x).max()
    assert np.abs(state.v - v).max() <= n * scale / h
    assert np.abs(state.x - x).max() <= n * n / 2 * scale
    assert state.t == pytest.approx(steps * dt) and state.step == steps


def test_pinned_pendulum_keeps_its_length():
    b = csb.ModelBuilder()
    b.add_mesh(csb.pendulum(1.0, 1.2), particle_mass=1.0)
    b.pin(0)
    model = b.build()
    state = model.initial_state()
    # One hard constraint to a fixed anchor is satisfied by a single projection.
    csb.PbdStepper(dt=1e-3, iterations=1, gravity=G).step(model, state, 1000)
    assert abs(np.linalg.norm(state.x[1] - state.x[0]) - 1.0) < 1e-10
    assert np.array_equal(state.x[0], model.rest_positions[0])
    # It swung: the bob is far from where it started.
    assert np.linalg.norm(state.x[1] - model.rest_positions[1]) > 0.1


def test_pinned_chain_keeps_its_links_with_enough_iterations():
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(5, 0.1), particle_mass=0.1)
    b.pin(0)
    model = b.build()
    state = model.initial_state()
    stepper = csb.PbdStepper(dt=1e-3, iterations=200, gravity=G)
    worst = 0.0
    for _ in range(10):
        stepper.step(model, state, 100)
        worst = max(worst, np.abs(csb.distance_violations(model, state)).max())
    assert worst < 1e-10


def random_free_model(rng, n_particles=60, disjoint=False):
    """Random particles with random distance and bending constraints (no pins)."""
    b = csb.ModelBuilder()
    g = b.add_group("random")
    for _ in range(n_particles):
        b.add_particle(rng.normal(size=3), rng.uniform(0.1, 3.0), g)
    order = rng.permutation(n_particles)
    if disjoint:  # every particle in at most one constraint
        k = 0
        while k + 4 <= n_particles:
            a, c, d, e = order[k:k + 4]
            b.add_bending(int(a), int(c), int(d), int(e), stiffness=rng.uniform(0.2, 1), rest_angle=rng.uniform(-3, 3))
            k += 4
            if k + 2 <= n_particles:
                b.add_distance(int(order[k]), int(order[k + 1]), stiffness=rng.uniform(0.2, 1),
                               rest_length=rng.uniform(0.2, 2))
                k += 2
    else:
        for _ in range(3 * n_particles):
            i, j = rng.choice(n_particles, 2, replace=False)
            b.add_distance(int(i), int(j), stiffness=rng.uniform(0.2, 1), rest_length=rng.uniform(0.2, 2))
        for _ in range(n_particles):
            a, c, d, e = rng.choice(n_particles, 4, replace=False)
            b.add_bending(int(a), int(c), int(d), int(e), stiffness=rng.uniform(0.2, 1), rest_angle=rng.uniform(-3, 3))
    return b.build()


def momenta(model, state):
    m = np.asarray(model.mass)[:, None]
    return (m * state.v).sum(axis=0), (m * np.cross(state.x, state.v)).sum(axis=0)


def test_internal_constraints_conserve_linear_momentum_over_many_steps(rng):
    """Σ m v is exactly invariant under Algorithm 1 without external forces: each projection has
    Σ m Δp = 0 and v = (p - x)/h is linear in p."""
    model = random_free_model(rng)
    state = model.initial_state()
    state.v[:] = rng.normal(size=state.v.shape)
    P0, _ = momenta(model, state)
    h = 0.01
    csb.PbdStepper(dt=h, iterations=4, gravity=(0, 0, 0)).step(model, state, 200)
    P1, _ = momenta(model, state)
    # Round-off: each step's v = (p - x)/h carries ~eps|x|/h per particle.
    bound = 4 * 200 * EPS * np.sum(np.asarray(model.mass) * np.abs(state.x).max(axis=1)) / h
    assert np.abs(P1 - P0).max() <= bound
    assert np.linalg.norm(P0) > 1  # the test moves something


# Random masses put some neighbours more than 10 times apart (12 in one draw), past what one iteration solves accurately
# (csb.AccuracyWarning); momentum conservation holds whatever the accuracy.
@pytest.mark.filterwarnings("ignore::csb.AccuracyWarning")
def test_internal_constraints_conserve_angular_momentum_from_rest(rng):
    """From rest (p = x), one step's new momenta are Σ m Δp / h and Σ m x × Δp / h: zero for
    every constraint's correction (§3.3), here on random distance and bending constraints on
    disjoint particle sets."""
    for _ in range(5):
        model = random_free_model(rng, 60, disjoint=True)
        state = model.initial_state()
        h = 0.01
        x0 = np.array(state.x)
        csb.PbdStepper(dt=h, iterations=1, gravity=(0, 0, 0)).step(model, state, 1)
        P, L = momenta(model, state)
        m, R = np.asarray(model.mass), np.abs(x0).max(axis=1)
        assert np.abs(state.x - x0).max() > 1e-3  # the constraints did act
        assert np.abs(P).max() <= 4 * EPS * np.sum(m * R) / h
        assert np.abs(L).max() <= 16 * EPS * np.sum(m * R * R) / h


@pytest.mark.parametrize("omega_h", [0.01, 0.1, 0.5])
def test_a_spinning_rod_loses_angular_momentum_by_the_closed_form_factor(omega_h):
    """Algorithm 1 is not angular-momentum-exact in time: the prediction x + hv leaves the rod,
    the projection pulls it back along the chord. For a rigid rod of half-length r spinning at ω,
    the first step keeps exactly 1/sqrt(1 + (ωh)²) of L."""
    r, h = 0.5, 0.01
    omega = omega_h / h
    b = csb.ModelBuilder()
    g = b.add_group("rod")
    b.add_particle([-r, 0, 0], 1.0, g)
    b.add_particle([r, 0, 0], 1.0, g)
    b.add_distance(0, 1)
    model = b.build()
    state = model.initial_state()
    state.v[:] = [[0, -omega * r, 0], [0, omega * r, 0]]
    _, L0 = momenta(model, state)
    csb.PbdStepper(dt=h, iterations=1, gravity=(0, 0, 0)).step(model, state, 1)
    _, L1 = momenta(model, state)
    assert L1[2] / L0[2] == pytest.approx(1 / math.sqrt(1 + omega_h**2), rel=1e-12)


@pytest.mark.parametrize("k", [0.1, 0.5, 0.9])
def test_stiffness_correction_makes_the_effective_stiffness_independent_of_iterations(k):
    """One spring from a fixed anchor to a particle of mass m, stretched and at rest. n projections
    of stiffness k' leave (1 - k')^n of the stretch, which is a backward Euler step with
    k_eff = m((1 - k')^(-n) - 1)/Δt² (Müller 2007 §3.3). Without the correction k' = k and k_eff
    grows with n; with k' = 1 - (1 - k)^(1/n) it is m((1 - k)^(-1) - 1)/Δt² for every n."""
    m, dt = 0.3, 0.01

    def k_eff(iterations, correction):
        return spring_k_eff(k, iterations, correction=correction, mass=m, dt=dt)

    # The stretch left, (1 - k)^n s0, is measured as |x| - L0 with an error of a few ulps of |x|:
    # iteration counts that leave less than 1e-4 of it would measure round-off, not stiffness.
    for n in (n for n in (1, 2, 3, 5, 10, 20) if (1 - k) ** n >= 1e-4):
        assert k_eff(n, False) == pytest.approx(m * ((1 - k) ** -n - 1) / dt**2, rel=1e-9)
        assert k_eff(n, True) == pytest.approx(m * ((1 - k) ** -1 - 1) / dt**2, rel=1e-9)
    assert csb.corrected_stiffness(k, 7) == pytest.approx(1 - (1 - k) ** (1 / 7), rel=1e-15)


def test_sub_steps_stretch_a_hanging_cloth_less_than_iterations():
    """Quick version of validation/substeps_vs_iterations.py: the first second of cloth_drop,
    40 projections per constraint per step, as 4 x 10 and as 40 x 1."""
    scene = csb.load_scene("cloth_drop")
    few = strain_history(scene, substeps=4, iterations=10, steps=60)
    many = strain_history(scene, substeps=40, iterations=1, steps=60)
    assert many["max_strain"] < 0.5 * few["max_strain"]
    assert many["mean_rms_strain"] < 0.5 * few["mean_rms_strain"]


def test_damping_leaves_rigid_motion_untouched_and_removes_the_rest(rng):
    """Müller 2007 §3.5 with k_damping = 1 keeps exactly the rigid part (v_cm + ω × r) of the
    velocity field; a velocity field that is rigid already is left as it is."""
    x0 = rng.normal(size=(30, 3))
    m = rng.uniform(0.1, 2, 30)
    model = particles_model(x0, m)
    omega, vcm = np.array([0.3, -1.2, 0.7]), np.array([1.0, 2.0, -0.5])
    rigid = vcm + np.cross(omega, x0 - (m[:, None] * x0).sum(0) / m.sum())
    state = model.initial_state()
    state.v[:] = rigid
    csb.PbdStepper(dt=1e-3, gravity=(0, 0, 0), damping=1.0).step(model, state, 1)
    np.testing.assert_allclose(state.v, rigid, atol=1e-12)

    state = model.initial_state()
    state.v[:] = rigid + rng.normal(size=rigid.shape)
    P0, L0 = momenta(model, state)
    csb.PbdStepper(dt=1e-3, gravity=(0, 0, 0), damping=1.0).step(model, state, 1)
    # What is left is rigid: fit v = a + w × x by least squares and check the residual.
    A = np.zeros((90, 6))
    for i, xi in enumerate(np.asarray(model.rest_positions)):
        A[3 * i:3 * i + 3, :3] = np.eye(3)
        A[3 * i:3 * i + 3, 3:] = -np.array([[0, -xi[2], xi[1]], [xi[2], 0, -xi[0]], [-xi[1], xi[0], 0]])
    coef, *_ = np.linalg.lstsq(A, np.asarray(state.v).ravel(), rcond=None)
    assert np.abs(A @ coef - np.asarray(state.v).ravel()).max() < 1e-12
    P1, _ = momenta(model, state)
    np.testing.assert_allclose(P1, P0, atol=1e-12)


def test_damping_is_per_group():
    """Two particles in different groups moving apart: each group is rigid by itself, so
    damping removes nothing; in one group the separation velocity is damped."""
    for same_group in (False, True):
        b = csb.ModelBuilder()
        g0 = b.add_group("a")
        g1 = g0 if same_group else b.add_group("b")
        b.add_particle([-1, 0, 0], 1.0, g0)
        b.add_particle([1, 0, 0], 1.0, g1)
        model = b.build()
        state = model.initial_state()
        state.v[:] = [[-1, 0, 0], [1, 0, 0]]
        csb.PbdStepper(dt=0.01, gravity=(0, 0, 0), damping=0.5).step(model, state, 1)
        expected = 0.5 if same_group else 1.0
        # v comes back as (p - x)/h: a few ulps of |x| = 1 divided by h.
        assert state.v[1, 0] == pytest.approx(expected, abs=4 * EPS / 0.01)


def test_substeps_are_steps_of_dt_over_substeps():
    model = cloth_model(10)
    a, b = model.initial_state(), model.initial_state()
    csb.PbdStepper(dt=0.02, substeps=4, iterations=3, damping=0.01).step(model, a, 25)
    csb.PbdStepper(dt=0.005, substeps=1, iterations=3, damping=0.01).step(model, b, 100)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.v, b.v)


def state_hash(state) -> str:
    return hashlib.sha256(np.ascontiguousarray(state.x).tobytes() + np.ascontiguousarray(state.v).tobytes()).hexdigest()


def test_same_scene_same_bits():
    scene = csb.load_scene("cloth_grid")
    hashes = []
    for _ in range(2):
        sim = scene.build()
        sim.stepper.step(sim.model, sim.state, 60)
        hashes.append(state_hash(sim.state))
    assert hashes[0] == hashes[1]


def test_positions_are_a_writable_zero_copy_view():
    model = cloth_model(4, bending=None, pins=False)
    state = model.initial_state()
    x = state.x
    assert x.shape == (16, 3) and x.flags.writeable and np.shares_memory(x, state.x)
    x[0] += [0, 0.5, 0]  # the user moves a particle; the stepper sees it
    assert state.x[0, 1] == 0.5
    state.v = np.ones((16, 3))
    assert np.array_equal(state.v, np.ones((16, 3)))
    with pytest.raises(csb.ParameterError, match=r"shape \(16, 3\)"):
        state.x = np.zeros((15, 3))
    assert not model.rest_positions.flags.writeable
    assert not model.distance["rest_length"].flags.writeable
    with pytest.raises(ValueError):
        model.mass[0] = 2.0


def test_a_non_finite_position_stops_the_run_naming_step_and_particle():
    model = cloth_model(4, pins=False)
    state = model.initial_state()
    state.x[5, 1] = np.nan
    with pytest.raises(csb.SimulationError, match=r"before step 0: particle 5 has a non-finite position"):
        csb.PbdStepper().step(model, state, 1)

    state = model.initial_state()
    stepper = csb.PbdStepper(dt=0.1, gravity=(0, -1e307, 0))
    with pytest.raises(csb.SimulationError, match=r"step \d+ \(substep 0, t = .* s\): particle \d+ got a non-finite"):
        stepper.step(model, state, 100)
    assert np.all(np.isfinite(state.x)) and state.step >= 1  # left at the last finite step


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(dt=0.0), "dt must be"),
        (dict(dt=-0.01), "dt must be"),
        (dict(dt=float("nan")), "dt must be"),
        (dict(dt=float("inf")), "dt must be"),
        (dict(iterations=0), r"iterations must be an integer in \[1, 1000000\], got 0"),
        (dict(substeps=0), r"substeps must be an integer in \[1, 1000000\], got 0"),
        (dict(damping=1.5), r"damping must be in \[0, 1\]"),
        (dict(damping=-0.1), r"damping must be in \[0, 1\]"),
        (dict(gravity=(0, float("nan"), 0)), "gravity must be finite"),
    ],
)
def test_impossible_settings_are_refused(kwargs, message):
    with pytest.raises(csb.ParameterError, match=message):
        csb.PbdStepper(**kwargs)


def test_a_state_of_another_model_is_refused():
    with pytest.raises(csb.ParameterError, match="the state has 16 positions"):
        csb.PbdStepper().step(cloth_model(8), cloth_model(4).initial_state())
