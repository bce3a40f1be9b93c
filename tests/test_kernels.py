"""The constraint kernels one constraint at a time: the equations of Müller et al. 2007 and the
momentum conservation of §3.3, on random configurations."""

from __future__ import annotations

import numpy as np
import pytest

import csb

K = csb.kernels
EPS = np.finfo(float).eps


def assert_momentum_free(P: np.ndarray, Q: np.ndarray, w: np.ndarray) -> None:
    """Σ m_i Δp_i = 0 and Σ m_i p_i × Δp_i = 0 for the correction Δp = Q - P (§3.3).

    Round-off: Δp is only observable as Q - P, which is exact up to one ulp of |p_i| per
    component; so the sums can differ from zero by about eps Σ m_i |p_i| and (the cross product
    doubling it) 2 eps Σ m_i |p_i|². The bounds allow twice that.
    """
    m = 1 / w
    dp = Q - P
    R = np.abs(P).max(axis=1)
    assert np.abs((m[:, None] * dp).sum(axis=0)).max() <= 4 * EPS * np.sum(m * R)
    assert np.abs((m[:, None] * np.cross(P, dp)).sum(axis=0)).max() <= 8 * EPS * np.sum(m * R * R)


def random_quad(rng: np.random.Generator) -> np.ndarray:
    """Four points forming two non-degenerate triangles across the edge (p0, p1)."""
    while True:
        P = rng.normal(size=(4, 3))
        if K.dihedral_angle_gradient(*P) is not None:
            e = np.linalg.norm(P[1] - P[0])
            a1 = np.linalg.norm(np.cross(P[2] - P[0], P[2] - P[1]))
            a2 = np.linalg.norm(np.cross(P[3] - P[1], P[3] - P[0]))
            if e > 0.2 and a1 > 0.05 and a2 > 0.05:
                return P


# ------------------------------------------------------------------------------ distance


def test_distance_projection_is_the_papers_distance_example(rng):
    for _ in range(200):
        p1, p2 = rng.normal(size=(2, 3))
        w1, w2 = rng.uniform(0.1, 3.0, 2)
        d = rng.uniform(0.1, 2.0)
        q1, q2, c = K.project_distance(p1, p2, w1, w2, d)
        n = (p1 - p2) / np.linalg.norm(p1 - p2)
        C = np.linalg.norm(p1 - p2) - d
        assert c == pytest.approx(C, abs=1e-15)
        np.testing.assert_allclose(q1, p1 - w1 / (w1 + w2) * C * n, atol=1e-14)
        np.testing.assert_allclose(q2, p2 + w2 / (w1 + w2) * C * n, atol=1e-14)
        # With k = 1 one projection satisfies the constraint exactly, up to round-off.
        assert abs(np.linalg.norm(q1 - q2) - d) < 16 * EPS * max(1.0, d)


def test_distance_stiffness_scales_the_correction(rng):
    p1, p2 = rng.normal(size=(2, 3))
    full = K.project_distance(p1, p2, 1.0, 2.0, 0.3, 1.0)
    part = K.project_distance(p1, p2, 1.0, 2.0, 0.3, 0.25)
    np.testing.assert_allclose(part[0] - p1, 0.25 * (full[0] - p1), atol=1e-15)
    np.testing.assert_allclose(part[1] - p2, 0.25 * (full[1] - p2), atol=1e-15)


@pytest.mark.parametrize(
    "sense, length, moves",
    [(">=", 0.5, True), (">=", 2.0, False), ("<=", 0.5, False), ("<=", 2.0, True), ("==", 0.5, True)],
)
def test_distance_inequalities_act_only_when_violated(sense, length, moves):
    p1, p2 = np.array([0.0, 0, 0]), np.array([length, 0, 0])
    q1, q2, c = K.project_distance(p1, p2, 1.0, 1.0, 1.0, 1.0, sense)
    assert (c != 0) == moves
    if moves:
        assert np.linalg.norm(q2 - q1) == pytest.approx(1.0, abs=1e-15)
    else:
        assert np.array_equal(q1, p1) and np.array_equal(q2, p2)


def test_distance_leaves_fixed_and_coincident_particles_alone():
    p = np.array([1.0, 2.0, 3.0])
    q1, q2, c = K.project_distance(p, p, 1.0, 1.0, 0.5)
    assert np.array_equal(q1, p) and np.array_equal(q2, p) and c == -0.5
    q1, q2, _ = K.project_distance(p, p + 1, 0.0, 0.0, 0.5)
    assert np.array_equal(q1, p) and np.array_equal(q2, p + 1)


def test_distance_projection_conserves_linear_and_angular_momentum(rng):
    """§3.3: Σ m_i Δp_i = 0 and Σ m_i p_i × Δp_i = 0 for the correction."""
    for _ in range(500):
        P = rng.normal(size=(2, 3)) * rng.uniform(0.1, 10)
        w = rng.uniform(0.01, 10.0, 2)
        q1, q2, _ = K.project_distance(P[0], P[1], w[0], w[1], rng.uniform(0.1, 3.0), rng.uniform(0, 1))
        assert_momentum_free(P, np.array([q1, q2]), w)


# ------------------------------------------------------------------------------ bending


def test_dihedral_angle_is_signed_and_zero_when_flat():
    a, b = np.array([0.0, 0, 0]), np.array([1.0, 0, 0])
    c, d = np.array([0.5, 1.0, 0]), np.array([0.5, -1.0, 0])
    assert K.dihedral_angle(a, b, c, d) == 0.0
    up = K.dihedral_angle(a, b, c + [0, 0, 0.3], d)
    down = K.dihedral_angle(a, b, c - [0, 0, 0.3], d)
    assert up == pytest.approx(-down, abs=1e-15) and abs(up) == pytest.approx(np.arctan(0.3), abs=1e-15)


def test_dihedral_gradient_matches_finite_differences(rng):
    h = 1e-6
    for _ in range(50):
        P = random_quad(rng)
        G = K.dihedral_angle_gradient(*P)
        F = np.zeros_like(P)
        for i in range(4):
            for j in range(3):
                Pp, Pm = P.copy(), P.copy()
                Pp[i, j] += h
                Pm[i, j] -= h
                F[i, j] = np.angle(np.exp(1j * (K.dihedral_angle(*Pp) - K.dihedral_angle(*Pm)))) / (2 * h)
        # Central differences: truncation O(h²) and round-off O(eps/h) both below 1e-8 here.
        np.testing.assert_allclose(G, F, atol=1e-7 * (1 + np.abs(G).max()))


def muller_appendix(P: np.ndarray, w: np.ndarray, phi0: float) -> np.ndarray:
    """Δp of Müller et al. 2007, Appendix A, written as in the paper (p1 moved to the origin)."""
    p2, p3, p4 = P[1] - P[0], P[2] - P[0], P[3] - P[0]
    l1, l2 = np.linalg.norm(np.cross(p2, p3)), np.linalg.norm(np.cross(p2, p4))
    n1, n2 = np.cross(p2, p3) / l1, np.cross(p2, p4) / l2
    d = n1 @ n2
    q3 = (np.cross(p2, n2) + np.cross(n1, p2) * d) / l1
    q4 = (np.cross(p2, n1) + np.cross(n2, p2) * d) / l2
    q2 = -(np.cross(p3, n2) + np.cross(n1, p3) * d) / l1 - (np.cross(p4, n1) + np.cross(n2, p4) * d) / l2
    q = np.array([-q2 - q3 - q4, q2, q3, q4])
    denom = np.sum(w * np.sum(q * q, axis=1))
    return -(w[:, None] * np.sqrt(1 - d * d) * (np.arccos(d) - phi0) * q) / denom


def test_bending_projection_equals_the_papers_appendix(rng):
    """Where the paper's unsigned angle is defined (θ and θ0 of one sign, away from flat), our
    signed-angle projection is the appendix's, with φ = π - |θ|."""
    for _ in range(100):
        P = random_quad(rng)
        theta = K.dihedral_angle(*P)
        if not 0.2 < abs(theta) < np.pi - 0.2:
            continue
        theta0 = theta - np.sign(theta) * rng.uniform(-0.15, 0.15)
        w = rng.uniform(0.2, 3.0, 4)
        out = K.project_bending(*P, list(w), theta0, 1.0)
        ours = np.array(out[:4]) - P
        np.testing.assert_allclose(ours, muller_appendix(P, w, np.pi - abs(theta0)), atol=1e-13)


def test_bending_is_finite_at_the_flat_rest_state():
    """The paper's acos form is 0/0 here; the signed angle is not."""
    P = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.5, 1.0, 0], [0.5, -1.0, 0]])
    out = K.project_bending(*P, [1, 1, 1, 1], 0.0, 1.0)
    assert np.array_equal(np.array(out[:4]), P) and out[4] == 0.0
    P[2, 2] = 1e-9  # almost flat: a finite, tiny correction
    out = K.project_bending(*P, [1, 1, 1, 1], 0.0, 1.0)
    assert np.all(np.isfinite(out[:4])) and abs(out[4]) < 2e-9


def test_bending_projection_reduces_the_violation(rng):
    for _ in range(100):
        P = random_quad(rng)
        theta0 = K.dihedral_angle(*P) + rng.uniform(-0.2, 0.2)
        out = K.project_bending(*P, list(rng.uniform(0.2, 3, 4)), theta0, 1.0)
        after = np.angle(np.exp(1j * (K.dihedral_angle(*out[:4]) - theta0)))
        # One Newton step on a smooth C: the residual is second order in the initial one.
        assert abs(after) <= max(0.5 * abs(out[4]), 1e-12)


def test_bending_projection_conserves_linear_and_angular_momentum(rng):
    for _ in range(500):
        P = random_quad(rng) * rng.uniform(0.1, 5)
        w = rng.uniform(0.01, 10.0, 4)
        theta0 = rng.uniform(-np.pi, np.pi)
        out = K.project_bending(*P, list(w), theta0, rng.uniform(0, 1))
        assert_momentum_free(P, np.array(out[:4]), w)


# ------------------------------------------------------------------------------ attachment


def test_attachment_moves_the_particle_towards_its_target():
    p, t = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 1.0])
    q, c = K.project_attachment(p, 2.0, t, 0.25)
    assert c == pytest.approx(np.linalg.norm(p - t))
    np.testing.assert_allclose(q, p - 0.25 * (p - t), atol=1e-15)
    q, _ = K.project_attachment(p, 0.0, t, 1.0)
    assert np.array_equal(q, p)


def test_every_projection_is_in_kernels_with_its_docstring():
    """csb.kernels covers each built-in projection: PBD, XPBD and Jakobsen's stick for distances,
    PBD and XPBD for bending, attachments and volumes, and balloons; each says what it computes."""
    names = ["project_distance", "project_distance_xpbd", "project_distance_jakobsen", "project_bending",
             "project_bending_xpbd", "project_attachment", "project_attachment_xpbd", "project_volume",
             "project_volume_xpbd", "project_balloon"]
    for name in names:
        doc = getattr(csb.kernels, name).__doc__
        assert doc and len(doc.split("\n", 2)[-1].strip()) > 40, name


def test_xpbd_distance_kernel_against_its_closed_form():
    """One XPBD iteration from λ = 0 on a stretched link: Δλ = -C/(w1 + w2 + α̃), Δp1 = w1 n Δλ;
    with damping γ and start positions x, the move since x enters as -γ n·(Δp1 - Δp2) in the
    numerator and (1 + γ) on the inverse masses."""
    p1, p2, w1, w2, rest, at = np.array([0.0, 0, 0]), np.array([1.2, 0, 0]), 2.0, 1.0, 1.0, 0.5
    a, b, c, lam = csb.kernels.project_distance_xpbd(p1, p2, w1, w2, rest, at)
    dl = -0.2 / (w1 + w2 + at)
    n = np.array([-1.0, 0, 0])
    assert c == pytest.approx(0.2) and lam == pytest.approx(dl)
    assert np.allclose(a, p1 + w1 * n * dl) and np.allclose(b, p2 - w2 * n * dl)
    x1, x2, gamma = np.array([0.05, 0, 0]), np.array([1.2, 0, 0]), 0.3
    a, b, c, lam = csb.kernels.project_distance_xpbd(p1, p2, w1, w2, rest, at, 0.0, gamma, x1, x2)
    moved = n @ ((p1 - x1) - (p2 - x2))
    assert lam == pytest.approx((-0.2 - gamma * moved) / ((1 + gamma) * (w1 + w2) + at))
    # An inequality C >= 0 (a rope that may not be shorter, i.e. a strut): compressed, it pushes apart
    # (λ = 0.2/2 >= 0); stretched, it is satisfied and λ stays clamped at 0.
    _, _, _, lam = csb.kernels.project_distance_xpbd([0, 0, 0], [0.8, 0, 0], 1.0, 1.0, 1.0, 0.0, sense=">=")
    assert lam == pytest.approx(0.1)
    a, b, _, lam = csb.kernels.project_distance_xpbd([0, 0, 0], [1.2, 0, 0], 1.0, 1.0, 1.0, 0.0, sense=">=")
    assert lam == 0.0 and np.allclose(b, [1.2, 0, 0])


def test_jakobsen_stick_kernel_without_square_roots():
    """Jakobsen's approximation: the correction (d·d - L²)/(d·d + L²) d, shared by inverse mass;
    near the rest length it agrees with the exact projection to second order in the strain."""
    p1, p2 = np.array([0.0, 0, 0]), np.array([1.01, 0, 0])
    a, b, v = csb.kernels.project_distance_jakobsen(p1, p2, 1.0, 1.0, 1.0)
    dd = 1.01**2
    assert v == pytest.approx((dd - 1) / 2)
    assert np.allclose(a, p1 + 0.5 * (dd - 1) / (dd + 1) * (p2 - p1))
    exact, _, _ = csb.kernels.project_distance(p1, p2, 1.0, 1.0, 1.0)
    assert abs(a[0] - exact[0]) < 0.01**2


def test_xpbd_attachment_and_bending_kernels():
    p, v, lam = csb.kernels.project_attachment_xpbd([0.0, 0.3, 0.0], 4.0, [0.0, 0.0, 0.0], 1.0)
    assert v == pytest.approx(0.3) and lam == pytest.approx(-0.3 / 5.0) and np.allclose(p, [0, 0.3 - 4 * 0.06, 0])
    # A hinge bent to 90 degrees, rest 0: hard (α̃ = 0) XPBD closes the angle as PBD with k = 1 does.
    a, b, c, d = [0, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0]
    w = [1.0, 1.0, 1.0, 1.0]
    xpbd = csb.kernels.project_bending_xpbd(a, b, c, d, w, 0.0, 0.0)
    pbd = csb.kernels.project_bending(a, b, c, d, w, 0.0, 1.0)
    assert abs(xpbd[4]) == pytest.approx(np.pi / 2)
    for k in range(4):
        assert np.allclose(xpbd[k], pbd[k], atol=1e-12)
