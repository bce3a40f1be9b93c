"""Contacts with the colliders in the implicit methods (collision/penalty.hpp): implicit Euler,
budgeted and converged, and VBD take them as a penalty of stiffness κ m/h² in the incremental
potential; Projective Dynamics projects onto the contacts' planes after each global solve. All
four rub by Coulomb's law and bounce with the collider's restitution after the step, as the
position-based pipeline does."""

from __future__ import annotations

import numpy as np
import pytest

import csb

# (method, Newton iterations or sweeps a step): two are enough for a lone particle to feel its
# contact in every method (the converged form iterates to its tolerance).
METHODS = [("implicit-euler", 2), ("backward-euler", 1), ("vbd", 2), ("projective-dynamics", 2)]
G, H = 9.81, 1 / 60
KAPPA = 1e4  # the default contact_stiffness


def particle_on_plane(x0, v0=(0.0, 0.0, 0.0), *, mu: float = 0.0, e: float = 0.0):
    """A 0.1 kg particle above the ground plane y = 0 (friction μs = μk = mu, restitution e)."""
    b = csb.ModelBuilder()
    g = b.add_group("p")
    b.add_particle(x0, 0.1, g)
    b.add_plane(point=[0, 0, 0], normal=[0, 1, 0], friction_static=mu, friction_kinetic=mu, restitution=e)
    model = b.build()
    s = model.initial_state()
    s.v = np.array([v0], float)
    return model, s


@pytest.mark.parametrize("method, iterations", METHODS)
def test_a_particle_rests_on_the_ground(method, iterations):
    """At rest on the ground the penalty κ m/h² holds the weight m g: the particle sinks g h²/κ,
    2.725e-7 m at h = 1/60 s and κ = 1e4; Projective Dynamics projects it onto the plane: 0.
    Either way it does not move."""
    model, s = particle_on_plane([0, 0.5, 0])
    stepper = csb.make_integrator(method, H, iterations=iterations)
    for _ in range(120):
        stepper.step(model, s)
    depth = 0.0 if method == "projective-dynamics" else -G * H * H / KAPPA
    assert s.x[0, 1] == pytest.approx(depth, rel=1e-6, abs=1e-300) and np.all(s.v == 0)


@pytest.mark.parametrize("method, iterations", METHODS)
def test_coulomb_friction_stops_a_slide(method, iterations):
    """A particle sliding at 2 m/s on ground of μk = 0.5 stops after v²/(2 μk g) = 0.4077 m. The
    position-level friction removes μk g h² of the slide per sub-step of h = 1/600 s, so the
    discrete stop lies within a sub-step's slide, v h = 3.3 mm (0.8 %), of the closed form."""
    model, s = particle_on_plane([0, 0, 0], [2, 0, 0], mu=0.5)
    stepper = csb.make_integrator(method, H, substeps=10, iterations=iterations)
    for _ in range(120):
        stepper.step(model, s)
    assert s.x[0, 0] == pytest.approx(4 / (2 * 0.5 * G), abs=2 / 600) and np.all(s.v == 0)


@pytest.mark.parametrize("method, iterations", METHODS)
def test_restitution_reflects_an_impact(method, iterations):
    """Dropped from 1 m on ground of restitution e = 0.5, the particle bounces to e² = 0.25 m;
    backward Euler's free flight loses g h t to the discretisation (h = 1/600 s): within 1 %."""
    model, s = particle_on_plane([0, 1, 0], e=0.5)
    stepper = csb.make_integrator(method, H, substeps=10, iterations=iterations)
    ys = []
    for _ in range(90):
        stepper.step(model, s)
        ys.append(s.x[0, 1])
    landed = int(np.argmin(ys[:40]))
    assert max(ys[landed:]) == pytest.approx(0.25, rel=0.01)
