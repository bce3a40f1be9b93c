"""XPBD with Jacobi sweeps converges to XPBD's answer (Macklin, Müller, Chentanez 2016), the one
Gauss-Seidel finds, for every constraint type.

Averaged Jacobi moves a particle by the mean of the corrections it receives; XPBD's multiplier λ
must move with the positions (x - p = M⁻¹∇Cᵀλ), so csb's averaged Jacobi XPBD scales each
constraint's Δλ by 1/(the most projections on any of its moving particles) and adds the
corrections (``PbdStepper::set_relaxation``). When λ took the whole Δλ while the particles moved
by the mean, the fixed point was softer than the compliance: the chain below stretched 5/3, 3/2
and 1 times its static stretch and λ/h² read 49.05 N for a 29.43 N load.
"""

from __future__ import annotations

import numpy as np
import pytest

import csb
from csb.mesh import icosphere

G = 9.81
DT = 1 / 60


def hanging_chain(alpha: float = 1e-3, links: int = 3, length: float = 1.0, mass: float = 1.0):
    """A vertical chain of links + 1 particles (mass kg each) hanging from its pinned top, placed
    at its exact static shape: link j carries the (links - j) particles below it, tension
    T_j = (links - j) m g and stretch α T_j."""
    tension = np.array([(links - j) * mass * G for j in range(links)])
    y = np.concatenate([[0.0], -np.cumsum(length + alpha * tension)])
    b = csb.ModelBuilder()
    g = b.add_group("chain")
    for yi in y:
        b.add_particle([0.0, yi, 0.0], mass, g)
    for j in range(links):
        b.add_distance(j, j + 1, rest_length=length, compliance=alpha)
    b.pin(0)
    return b.build(), tension, alpha * tension


def link_stretch(x: np.ndarray, length: float = 1.0) -> np.ndarray:
    return np.linalg.norm(np.diff(x, axis=0), axis=1) - length


@pytest.mark.parametrize("ordering", ["coloured", "sequential"])
@pytest.mark.parametrize("solver", ["gauss-seidel", "jacobi"])
def test_a_hanging_chain_keeps_its_static_stretch_and_force(solver, ordering):
    """4 particles of 1 kg, α = 1e-3 m/N, 200 iterations. From the static shape at rest, backward
    Euler's step (which XPBD converges to) is the static shape itself, with λ_j/h² = T_j. 200
    Jacobi iterations contract the error by about 0.68 each (the chain's relaxed Jacobi
    iteration matrix at α̃ = α/h² = 3.6 kg⁻¹), far below round-off, so 1e-6 relative is the
    issue's bound with six orders of margin; all the chain's gradients are vertical, so XPBD's
    linearisation is exact here."""
    model, tension, stretch = hanging_chain()
    state = model.initial_state()
    stepper = csb.PbdStepper(method="xpbd", dt=DT, substeps=1, iterations=200, solver=solver, ordering=ordering,
                             gravity=(0, -G, 0))
    stepper.step(model, state, 1)
    assert link_stretch(np.asarray(state.x)) == pytest.approx(stretch, rel=1e-6)
    force = -np.asarray(stepper.multipliers()["distance"]) / DT**2
    assert force == pytest.approx(tension, rel=1e-6)


@pytest.mark.parametrize("solver", ["gauss-seidel", "jacobi"])
def test_a_chain_falling_into_place_settles_at_the_static_stretch(solver):
    """Released unstretched, the chain oscillates and XPBD's backward-Euler damping settles it:
    its stiffest mode (ω h ≈ 0.9) loses ~25 % a step and its slowest (ω h ≈ 0.2) ~2 %,
    so after 1200 steps (20 s) what is left is far below the 1e-6 asked."""
    model, tension, stretch = hanging_chain()
    state = model.initial_state()
    x = np.asarray(state.x)
    x[:, 1] = -np.arange(4.0)  # rest lengths, not stretched
    stepper = csb.PbdStepper(method="xpbd", dt=DT, iterations=200, solver=solver, gravity=(0, -G, 0))
    stepper.step(model, state, 1200)
    assert link_stretch(np.asarray(state.x)) == pytest.approx(stretch, rel=1e-6)
    assert -np.asarray(stepper.multipliers()["distance"]) / DT**2 == pytest.approx(tension, rel=1e-6)


def _model(kind: str):
    """A small body of one constraint family held so that it has no free swinging mode, and
    compliant enough that its stiff modes die out in a few hundred backward-Euler steps."""
    b = csb.ModelBuilder()
    if kind == "distance and bending":  # a cloth hanging in its plane from its whole top edge
        cloth = b.add_mesh(csb.cloth_grid(0.3, 0.3, 4, 4, "xy", (0, 0, 0)), mass=0.2, stretch_stiffness=1.0,
                           bending_stiffness=1.0, stretch_compliance=1e-3, bending_compliance=1.0)
        for i in cloth.particles:
            if cloth.vertices[i - cloth.first_particle][1] > 0.14:
                b.pin(int(i))
    elif kind == "volume":  # a tet cube hanging from its pinned top face
        cube = b.add_tet_mesh(csb.tet_box((0.1, 0.1, 0.1), (1, 1, 1), (0, 0, 0)), mass=0.5, stretch_stiffness=1.0,
                              stretch_compliance=1e-3, volume_stiffness=1.0, volume_compliance=1e-6)
        for i in cube.particles:
            if cube.vertices[i - cube.first_particle][1] > 0.04:
                b.pin(int(i))
    elif kind == "attachment":  # two particles on soft springs to points above them, linked by a third
        g = b.add_group("bobs")
        bobs = [b.add_particle([x, 0.0, 0.0], 0.2, g) for x in (0.0, 0.5)]
        for p, x in zip(bobs, (0.0, 0.5)):
            b.attach(p, [x - 0.1, 0.1, 0.0], compliance=1e-2)
        b.add_distance(bobs[0], bobs[1], rest_length=0.4, compliance=1e-2)
    elif kind == "balloon":  # a closed surface with a compliant overpressure, hanging from its top cap
        body = b.add_mesh(icosphere(0.2, 1), mass=0.3, stretch_stiffness=1.0, stretch_compliance=1e-3)
        b.add_balloon(body, pressure=1.2, stiffness=1.0, compliance=1e-4)
        for i in body.particles:
            if body.vertices[i - body.first_particle][1] > 0.15:
                b.pin(int(i))
    elif kind == "contact":  # a cloth lying on the ground
        b.add_mesh(csb.cloth_grid(0.3, 0.3, 4, 4, "xz", (0, 0.0, 0)), mass=0.2, stretch_stiffness=1.0,
                   stretch_compliance=1e-3)
        b.add_plane(point=(0, 0, 0), normal=(0, 1, 0))
    return b.build()


@pytest.mark.parametrize("kind", ["distance and bending", "volume", "attachment", "balloon", "contact"])
@pytest.mark.parametrize("ordering", ["coloured", "sequential"])
def test_converged_jacobi_equals_gauss_seidel_for_every_constraint_type(kind, ordering):
    """One step from a loaded state (the body hanging, or lying on the ground, after 600 frames),
    solved to convergence with each solver: the multipliers and the corrections x - p agree.

    XPBD's converged step depends a little on the path its iterates take (it adds up
    ∇C(x_k) Δλ_k along the way; Macklin et al. 2016 drop the geometric stiffness, Eq. 11), so two
    orders that converge along different paths differ by a share that falls as the square of the
    travel h² g. Measured here at h = 1/60, 1/600, 1e-3 and 1e-4 s: in the corrections 2e-3,
    3e-4, 1e-4 and 1e-6 of their size for the cloth, 4e-2 down to 1e-4 for the balloon (its
    pressure and its skin push against each other at every iteration); in the multipliers under
    2e-8 at 1e-4 s for every type. So at h = 1e-4 s this test asks 1e-6 of the multipliers and
    1e-3 of the corrections: the old averaged Jacobi was off by a factor of order one in both
    (its particles moved by the mean of the corrections its multipliers implied)."""
    model = _model(kind)
    gravity = (0, -G, 0)
    start = model.initial_state()
    csb.PbdStepper(method="xpbd", dt=DT, iterations=50, gravity=gravity).step(model, start, 600)
    x0 = np.array(start.x)
    h = 1e-4
    free = np.asarray(model.inv_mass) > 0
    p = x0 + np.where(free[:, None], h * h * np.array(gravity), 0.0)
    results = {}
    for solver in ("gauss-seidel", "jacobi"):
        state = model.initial_state()
        state.x[:] = x0
        stepper = csb.PbdStepper(method="xpbd", dt=h, iterations=500, solver=solver, ordering=ordering,
                                 gravity=gravity)
        stepper.step(model, state, 1)
        lam = {k: np.asarray(v) for k, v in stepper.multipliers().items() if len(v)}
        if kind == "contact":
            lam["contact"] = np.asarray(stepper.contacts()["lambda"])
        results[solver] = (np.array(state.x) - p, lam)
    (c_gs, l_gs), (c_j, l_j) = results["gauss-seidel"], results["jacobi"]
    assert np.abs(c_gs).max() > 0.1 * h * h * G  # the step is loaded: its corrections are of order h² g
    assert np.abs(c_j - c_gs).max() <= 1e-3 * np.abs(c_gs).max()
    largest = max(np.abs(v).max() for v in l_gs.values())
    for name in set(l_gs) | set(l_j):
        gs, jac = l_gs.get(name, np.zeros(1)), l_j.get(name, np.zeros(1))
        scale = np.abs(gs).max()
        if scale <= 1e-9 * largest:  # an unloaded family (the flat cloth's edges on the ground): round-off
            assert np.abs(jac).max() <= 1e-9 * largest, name
        else:
            assert np.abs(jac - gs).max() <= 1e-6 * scale, name
