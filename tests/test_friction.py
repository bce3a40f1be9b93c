"""Coulomb friction and restitution in the velocity update (Müller 2007 §3.5, line 16): the
slope angle where a rigid box starts to slide against atan μ, sliding deceleration, the bounce
height against e², and a cloth at rest on the ground."""

from __future__ import annotations

import math

import numpy as np
import pytest

import csb
from csb.studies import collisions as cs

G = 9.81


# Averaged Jacobi moves a particle by the mean of its corrections, so a contact's push bounds
# friction by its share of that mean; counting the whole push made the cone as many times too
# wide as there are constraints on the particle (μ = 0.3 acted as 2.4 on this box: it stuck up to
# 67.4°). Summed Jacobi is not here: it diverges on the box's stiff all-pairs links
# (tests/test_methods.py).
SOLVERS = ["gauss-seidel", "jacobi"]


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("mu", [0.2, 0.5, 1.0])
def test_a_box_sticks_below_atan_mu_and_slides_above(mu, solver):
    """Bisection on the slope angle (14 halvings of [0, 80°]: 0.005°). A box 2 mrad past the
    threshold slides ½ g (sin θ - μ cos θ) t² ≈ 1 cm in 1 s, well above the 1 mm that counts as
    sliding, so the detection moves the found angle by < 0.01°. What remains is the sub-step's lag
    of the friction rule (the bottom corners are stopped after the projection, the box's top half
    follows a sub-step later): at h = 1/600 s it measured -0.009°, -0.044°, -0.110° for
    μ = 0.2, 0.5, 1.0, and it shrinks with h (next test). 0.2° bounds it."""
    found = cs.friction_threshold(mu, solver=solver)
    assert abs(math.degrees(found - math.atan(mu))) < 0.2
    assert cs.slope_slide(mu, math.atan(mu) - math.radians(2), solver=solver) < 1e-4  # sticks (creeps < 0.1 mm)


def test_the_threshold_converges_to_atan_mu_with_the_substep():
    coarse = abs(cs.friction_threshold(1.0, substeps=10) - math.pi / 4)
    fine = abs(cs.friction_threshold(1.0, substeps=40) - math.pi / 4)
    assert fine < coarse / 3  # measured 0.110° -> 0.012°: first order in h


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("method", ["xpbd", "jakobsen"])
def test_the_friction_threshold_holds_for_xpbd_and_verlet(method, solver):
    found = cs.friction_threshold(0.5, method=method, solver=solver)
    assert abs(math.degrees(found - math.atan(0.5))) < 0.2


@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("mu, theta_deg", [(0.5, 35.0), (0.5, 50.0), (0.3, 40.0)])
def test_a_sliding_box_accelerates_at_g_sin_minus_mu_cos(mu, theta_deg, solver, method):
    """Kinetic friction: distance ½ g (sin θ - μ cos θ) t² after 1 s. The box starts at rest on
    the slope, so the only error is the friction's one-sub-step lag (about a h/t = 1/600 share)."""
    theta = math.radians(theta_deg)
    expected = 0.5 * G * (math.sin(theta) - mu * math.cos(theta))
    assert cs.slope_slide(mu, theta, solver=solver, method=method) == pytest.approx(expected, rel=0.01)


@pytest.mark.parametrize("solver", [*SOLVERS, "jacobi-summed"])  # one particle: no network to diverge
@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
def test_a_particle_sliding_on_the_ground_stops_after_v2_over_2_mu_g(method, solver):
    """v0 = 2 m/s, μk = 0.3 (μs = 0.3): deceleration μ g, stopping distance v0²/(2 μ g) = 0.680 m.
    The sub-steps move the stop by at most a sub-step's travel, v0 h = 3.3 mm."""
    b = csb.ModelBuilder()
    g = b.add_group("puck")
    b.add_particle([0, 0, 0], 0.1, g)
    b.add_plane(friction_static=0.3, friction_kinetic=0.3)
    model = b.build()
    state = model.initial_state()
    state.v[0] = (2.0, 0.0, 0.0)
    stepper = csb.PbdStepper(method=method, solver=solver, dt=1 / 60, substeps=10)
    stepper.step(model, state, 60)
    assert state.x[0, 0] == pytest.approx(4 / (2 * 0.3 * G), abs=2 / 600)
    assert abs(state.v[0, 0]) < 1e-12 and state.x[0, 1] == 0  # stopped, on the ground


def test_frictionless_sliding_keeps_its_speed():
    b = csb.ModelBuilder()
    g = b.add_group("puck")
    b.add_particle([0, 0, 0], 0.1, g)
    b.add_plane()
    model = b.build()
    state = model.initial_state()
    state.v[0] = (2.0, 0.0, 1.0)
    csb.PbdStepper(dt=1 / 60, substeps=4).step(model, state, 60)
    assert np.allclose(state.v[0], (2.0, 0.0, 1.0), atol=1e-12)


@pytest.mark.parametrize("e", [0.0, 0.5, 0.8, 1.0])
@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
def test_a_ball_bounces_to_e_squared_of_its_height(e, method):
    """Dropped from H = 1 m at h = 1/600 s. The discrete impact speed (the predicted (p - x)/h)
    differs from sqrt(2 g H) by at most g h, and the contact stops the particle at the surface
    instead of reflecting the rest of that sub-step's travel, at most v h: the bounce height is
    e² H within 2 e² H g h / v + e v h (0.0055 m at e = 0.5, 0.0108 m at e = 1)."""
    H, h = 1.0, 1 / 600
    v = math.sqrt(2 * G * H)
    top = cs.bounce_height(e, height=H, method=method)
    assert abs(top - e * e * H) <= 2 * e * e * H * G * h / v + e * v * h + 1e-12


def test_resting_contact_does_not_bounce():
    """Below the threshold 2 |g| h of approach speed a contact does not bounce, even with e = 1: a
    particle at rest on the ground stays exactly there."""
    b = csb.ModelBuilder()
    g = b.add_group("g")
    b.add_particle([0, 0, 0], 1.0, g)
    b.add_plane(restitution=1.0)
    model = b.build()
    state = model.initial_state()
    csb.PbdStepper(dt=1 / 60, substeps=3).step(model, state, 120)
    assert state.x[0, 1] == 0 and state.v[0, 1] == 0


@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
def test_a_cloth_at_rest_on_the_ground_stays_at_rest(method):
    """A 16 x 16 cloth dropped 1 cm, settled for 2 s, then watched for 10 s (600 steps). Static
    friction stops every tangential displacement and a resting contact removes exactly the
    prediction's g h² sink, so the cloth is still to round-off: measured 0 m/s and 0 m. The
    bounds are those of the brief (1e-3 m/s, 1e-4 m), far above what is measured."""
    r = cs.rest_jitter(method)
    assert r["max_speed"] < 1e-3 and r["max_drift"] < 1e-4
    assert r["max_below_thickness"] <= 1e-12


def _box_table_energy(substeps: int, iterations: int, ordering: str = "coloured") -> tuple[float, float]:
    """The bundled cloth_table scene with its sub-steps, iterations and ordering replaced: (E0, max E)
    over 3 s of kinetic + gravitational energy."""
    import dataclasses

    scene = csb.load_scene("cloth_table")
    solver = dataclasses.replace(scene.solver, substeps=substeps, iterations=iterations, ordering=ordering)
    sim = dataclasses.replace(scene, solver=solver).build()
    m = sim.measure()
    e0 = m["kinetic_energy"] + m["gravitational_energy"]
    energy = []
    for _ in range(180):  # 3 s
        sim.stepper.step(sim.model, sim.state)
        m = sim.measure()
        energy.append(m["kinetic_energy"] + m["gravitational_energy"])
    return e0, max(energy)


@pytest.mark.parametrize("substeps, iterations, ordering", [
    (20, 2, "coloured"),  # the bundled setting
    (40, 1, "coloured"),
    # Müller's loop over the constraints in build order. Built in index order (each particle's
    # edges together, row after row) the cloth gained 4.33 J -> 9.3 J over 3 s here: see
    # test_the_sequential_sweep_in_index_order_gains_energy below and sweep_order (mesh.hpp).
    (40, 1, "sequential"),
])
def test_a_cloth_dropped_on_a_box_table_does_not_gain_energy(substeps, iterations, ordering):
    """The cloth starts at rest and only gravity does work on it, so kinetic + gravitational energy
    can only fall (contacts and friction dissipate, the stretch and bending constraints store
    E >= 0 and start unstrained). On a box wider than the cloth (nothing hangs over an edge) the
    maximum over 3 s is the initial value to 1 mJ; 1 % of E0 (43 mJ) leaves room for the
    integrator and stays far below the instability's gain."""
    e0, worst = _box_table_energy(substeps, iterations, ordering)
    assert worst <= 1.01 * e0, f"max {worst:.3f} J against {e0:.3f} J at the start"


def _sheet_hanging_from_its_last_row(order: str = "built") -> csb.Model:
    """The cloth_table tablecloth (1.4 m, 30 x 30 particles, 0.25 kg/m², stretch compliance
    1e-6 m/N, bending 500 1/(N m)) flat in the xz plane with its last row (largest z) pinned.
    order: its stretch constraints as add_mesh builds them ("built", colour order), or the same
    constraints re-added in index order ("index": each particle's edges together, row after row)
    or with the row and column edges before the diagonals ("rows")."""
    b = csb.ModelBuilder()
    group = b.add_group("sheet")
    b.add_mesh(csb.cloth_grid(1.4, 1.4, 30, 30), group=group, density=0.25, stretch_compliance=1e-6,
               bending_compliance=500.0)
    built = b.build()
    x = np.asarray(built.initial_state().x)
    if order != "built":
        pairs = np.asarray(built.distance["particles"])
        rest = np.asarray(built.distance["rest_length"])
        if order == "index":
            sequence = np.lexsort((pairs[:, 1], pairs[:, 0]))
        else:
            d = x[pairs[:, 0]] - x[pairs[:, 1]]
            straight = (np.abs(d[:, 0]) < 1e-12) | (np.abs(d[:, 2]) < 1e-12)  # along a row or a column
            sequence = np.r_[np.flatnonzero(straight), np.flatnonzero(~straight)]
        b = csb.ModelBuilder()
        group = b.add_group("sheet")
        for i, m in enumerate(np.asarray(built.mass)):
            b.add_particle(x[i], float(m), group)
        for c in sequence:
            b.add_distance(int(pairs[c, 0]), int(pairs[c, 1]), 1.0, float(rest[c]), compliance=1e-6)
        bend = built.bending
        for q, angle, k in zip(np.asarray(bend["particles"]), np.asarray(bend["rest_angle"]),
                               np.asarray(bend["stiffness"])):
            b.add_bending(*map(int, q), float(k), float(angle), compliance=500.0)
    for i in np.flatnonzero(x[:, 2] == x[:, 2].max()):
        b.pin(int(i))
    return b.build()


def _hanging_energy_gain(order: str, ordering: str) -> float:
    """max E - E0 (J) of kinetic + gravitational energy over 1 s of the hanging sheet, 40 sub-steps
    x 1 iteration of XPBD."""
    model = _sheet_hanging_from_its_last_row(order)
    state = model.initial_state()
    mass = np.asarray(model.mass)
    free = np.asarray(model.inv_mass) > 0
    stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=40, iterations=1, ordering=ordering,
                             gravity=[0.0, 0.0, -G])

    def energy() -> float:
        v, x = np.asarray(state.v)[free], np.asarray(state.x)[free]
        return float((0.5 * mass[free] * (v * v).sum(axis=1) + mass[free] * G * x[:, 2]).sum())

    e0 = energy()
    worst = e0
    for _ in range(60):
        stepper.step(model, state)
        worst = max(worst, energy())
    return worst - e0


@pytest.mark.parametrize("order, ordering", [
    ("built", "coloured"),
    ("built", "sequential"),  # Müller's loop in the order add_mesh builds the edges
    ("rows", "sequential"),
    ("index", "coloured"),  # the colours do not depend on the build order
])
def test_a_sheet_hanging_in_its_plane_from_its_last_row_does_not_gain_energy(order, ordering):
    """No collider: gravity along -z, in the sheet's plane, so the pinned row's pull reaches the
    rest of the sheet against the index order (the particles are numbered from the free edge to
    the pinned one). Only gravity does work, so kinetic + gravitational energy can only fall;
    40 sub-steps x 1 iteration for 1 s. Measured: E never rises above E0 in these orders; 1 mJ
    is about 1 % of the index order's gain (below) and 0.03 % of the sheet's potential energy
    below its pinned row (3.36 J)."""
    gain = _hanging_energy_gain(order, ordering)
    assert gain <= 1e-3, f"max E - E0 = {gain:.3e} J"


def test_the_sequential_sweep_in_index_order_gains_energy():
    """Why add_mesh builds a mesh's edges in colour order (sweep_order, mesh.hpp): Müller's loop
    over the same constraints in index order amplifies the pinned row's pull as it travels against
    the sweep, one row per sub-step, ~1.3x per row: measured +88.6 mJ within 1 s and speeds up to
    5.07 m/s, against no gain and 0.067 m/s in the orders above. 10 mJ is nine times below the
    measured gain and ten times above the stable orders' bound."""
    gain = _hanging_energy_gain("index", "sequential")
    assert gain > 1e-2, f"max E - E0 = {gain:.3e} J"
