"""The coloured bending projection in SIMD blocks (csb/solver/coloured_bending.hpp) and its
branch-free rational atan2 (csb/atan2.hpp), against std::atan2 (numpy's arctan2 calls the same
libm) and against the reference kernel of constraints/bending.hpp."""

from __future__ import annotations

import numpy as np
import pytest

import csb
from helpers import copies_here

K = csb.kernels
EPS = np.finfo(float).eps


def assert_atan2_close(y: np.ndarray, x: np.ndarray, ulps: float = 4) -> float:
    """atan2_rational within `ulps` units in the last place of libm's atan2, the same sign (also
    of zeros); returns the largest error in ulps."""
    got, want = K.atan2(y, x), np.arctan2(y, x)
    assert np.array_equal(np.signbit(got), np.signbit(want))
    err = np.abs(got - want) / np.spacing(np.abs(want))
    err[want == 0] = np.abs(got[want == 0]) / np.spacing(0.0)
    assert err.max() <= ulps, (y[err.argmax()], x[err.argmax()], got[err.argmax()], want[err.argmax()])
    return float(err.max())


def test_atan2_on_a_dense_sweep_of_angles():
    # 2·10⁶ + 1 angles through all four quadrants, both axes and ±π, at radii 1e-300 to 1e300
    t = np.linspace(-np.pi, np.pi, 2_000_001)
    worst = 0.0
    for r in (1e-300, 1e-8, 1.0, 3.7, 1e8, 1e300):
        worst = max(worst, assert_atan2_close(r * np.sin(t), r * np.cos(t)))
    # Measured: 2 ulp (about 4.4e-16 rad at ±π), against Cephes' 2.6e-18 relative for the
    # approximation itself: what remains is the rounding of the reduction and of the sums.
    assert worst <= 2


def test_atan2_on_random_arguments_of_every_scale(rng):
    n = 1_000_000
    mag = 10.0 ** rng.uniform(-200, 200, size=(2, n))
    y, x = rng.choice([-1.0, 1.0], size=(2, n)) * mag
    assert_atan2_close(y, x)
    y, x = rng.uniform(-1, 1, size=(2, n))
    assert_atan2_close(y, x)
    # the switch of the reduction at |y|/|x| = 0.66 and 1/0.66, and the diagonals
    s = rng.uniform(0.5, 2, size=n)
    for ratio in (0.66, 1 / 0.66, 1.0):
        for f in (1 - 4 * EPS, 1.0, 1 + 4 * EPS):
            for sy, sx in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                assert_atan2_close(sy * ratio * f * s, sx * s)


def test_atan2_near_pi_and_at_signed_zeros_and_the_axes():
    tiny = np.array([0.0, 5e-324, 1e-300, 1e-17, 1e-12, 1e-6])
    for y in (tiny, -tiny):
        for x in (-1.0, 1.0, -1e-300, 1e300):
            assert_atan2_close(y, np.full_like(y, x))
            assert_atan2_close(np.full_like(y, x), y)  # on the y axis: ±π/2
    z = np.array([0.0, -0.0, 0.0, -0.0])
    got = K.atan2(z, z[[0, 0, 1, 1]])
    want = np.arctan2(z, z[[0, 0, 1, 1]])
    assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))  # ±0, ±π
    assert np.isnan(K.atan2(np.array([np.nan, 1.0]), np.array([1.0, np.nan]))).all()


def test_atan2_is_a_pure_function_of_its_inputs(rng):
    # The same value whatever its position in the array (SIMD lane, epilogue) and its neighbours.
    y, x = rng.normal(size=(2, 1001))
    ref = K.atan2(y, x)
    for shift in range(1, 5):
        got = K.atan2(np.concatenate([rng.normal(size=shift), y]), np.concatenate([rng.normal(size=shift), x]))
        assert np.array_equal(got[shift:], ref)
    assert np.array_equal(np.array([K.atan2(y[i:i + 1], x[i:i + 1])[0] for i in range(50)]), ref[:50])


def random_quads(rng: np.random.Generator, m: int) -> np.ndarray:
    """m bending quads (a, b, c, d) of two well-shaped triangles across (a, b), each on its own
    four points: edge length > 0.2, triangle areas > 0.05 for points ~ N(0, 1)."""
    out = []
    while len(out) < m:
        P = rng.normal(size=(4, 3))
        e = np.linalg.norm(P[1] - P[0])
        a1 = np.linalg.norm(np.cross(P[2] - P[0], P[2] - P[1]))
        a2 = np.linalg.norm(np.cross(P[3] - P[1], P[3] - P[0]))
        if e > 0.2 and a1 > 0.05 and a2 > 0.05:
            out.append(P)
    return np.array(out)


def reference_pbd(P: np.ndarray, w: np.ndarray, rest: np.ndarray, k: np.ndarray) -> np.ndarray:
    out = np.empty_like(P)
    for c in range(len(P)):
        *pts, _ = K.project_bending(*P[c], w[c], rest[c], k[c])
        out[c] = pts
    return out


def reference_xpbd(P, X, w, rest, alpha, gamma, lam):
    """Macklin 2016 Eq. (18), (26) with the reference kernel's angle and gradient (what
    project_bending_xpbd in constraints/bending.hpp computes)."""
    out, lam_out = P.copy(), lam.copy()
    for c in range(len(P)):
        theta = K.dihedral_angle(*P[c])
        g = K.dihedral_angle_gradient(*P[c])
        C = (theta - rest[c] + np.pi) % (2 * np.pi) - np.pi
        wgrad = np.sum(w[c] * np.sum(g * g, axis=1))
        moved = np.sum(g * (P[c] - X[c]))
        dl = (-C - alpha[c] * lam[c] - gamma[c] * moved) / ((1 + gamma[c]) * wgrad + alpha[c])
        lam_out[c] += dl
        out[c] += w[c][:, None] * g * dl
    return out, lam_out


def tolerance(P: np.ndarray, Q: np.ndarray) -> float:
    """Both kernels compute the same formulas; they differ in atan2 (<= 2 ulp, tested above) and
    in how the dot and cross products are associated (Eigen's order against the written-out
    one): a few dozen roundings of half an ulp each. For the well-shaped quads of random_quads
    (edge > 0.2, areas > 0.05, points ~ N(0, 1)) the angle and the gradient are well
    conditioned, and over 10⁴ random quads the corrections agreed to 1.5 eps times the scale
    (largest coordinate plus largest correction). The bound allows 64 eps, 1.4e-14 at unit
    scale: far below anything physical, tight enough to catch any change of formula."""
    return 64 * EPS * (np.abs(P).max() + np.abs(Q - P).max())


@pytest.mark.parametrize("weights", ["random", "some pinned"])
def test_coloured_pbd_bending_matches_the_reference_kernel(rng, weights):
    m = 203  # 6 blocks of 32 and a remainder: full SIMD lanes and the epilogue
    P = random_quads(rng, m)
    w = rng.uniform(0.2, 5, size=(m, 4))
    if weights == "some pinned":
        w[rng.random(size=(m, 4)) < 0.3] = 0
        w[0] = 0  # all four pinned: nothing moves
    rest = rng.uniform(-np.pi, np.pi, size=m)
    rest[:8] = [np.pi, -np.pi + 1e-12, np.pi - 1e-12, 0, 3, -3, 1e-9, -1e-9]  # wrapping through ±π
    k = rng.uniform(0.1, 1, size=m)
    quads = np.arange(4 * m).reshape(m, 4)
    got, lam = K.project_bending_coloured(P.reshape(-1, 3), quads, w, rest, stiffness=k)
    assert lam is None
    want = reference_pbd(P, w, rest, k)
    got = got.reshape(m, 4, 3)
    assert np.abs(got - want).max() <= tolerance(P, want)
    if weights == "some pinned":
        assert np.array_equal(got[0], P[0])
    assert np.abs(got - P).max() > 0.01  # really projected


def test_coloured_xpbd_bending_matches_the_reference_kernel(rng):
    m = 77
    P = random_quads(rng, m)
    X = P + 0.01 * rng.normal(size=P.shape)
    w = rng.uniform(0.2, 5, size=(m, 4))
    rest = rng.uniform(-np.pi, np.pi, size=m)
    alpha = 10.0 ** rng.uniform(-6, 1, size=m)
    gamma = np.where(rng.random(m) < 0.5, 0.0, rng.uniform(0, 2, size=m))
    lam = rng.normal(size=m) * 0.1
    quads = np.arange(4 * m).reshape(m, 4)
    got, lam_got = K.project_bending_coloured(P.reshape(-1, 3), quads, w, rest, alpha_tilde=alpha, gamma=gamma,
                                              lambda_=lam, start=X.reshape(-1, 3))
    want, lam_want = reference_xpbd(P, X, w, rest, alpha, gamma, lam)
    assert np.abs(got.reshape(m, 4, 3) - want).max() <= tolerance(P, want)
    assert np.abs(lam_got - lam_want).max() <= 64 * EPS * (np.abs(lam_want).max() + 1)


def test_degenerate_quads_are_left_alone():
    P = np.array([
        [[0, 0, 0], [0, 0, 0], [0, 1, 0], [0, -1, 0.3]],  # zero-length edge
        [[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, -1, 0.3]],  # zero-area triangle
        [[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, 1, 0]],  # d on top of c: a valid fold of π
    ], float)
    w = np.ones((3, 4))
    got, _ = K.project_bending_coloured(P.reshape(-1, 3), np.arange(12).reshape(3, 4), w, np.zeros(3))
    got = got.reshape(3, 4, 3)
    assert np.array_equal(got[:2], P[:2])
    assert np.isfinite(got).all()
    assert np.allclose(got[2], reference_pbd(P[2:], w[2:], np.zeros(1), np.ones(1))[0], atol=1e-12)


def test_the_result_does_not_depend_on_lane_block_or_neighbours(rng):
    # The same constraint gives the same bits in any SIMD lane, in the epilogue, in a block of
    # one (the overflow colour's path) and next to any other constraints.
    m = 100
    P = random_quads(rng, m)
    w = rng.uniform(0.2, 5, size=(m, 4))
    rest = rng.uniform(-np.pi, np.pi, size=m)
    quads = np.arange(4 * m).reshape(m, 4)
    ref, _ = K.project_bending_coloured(P.reshape(-1, 3), quads, w, rest)
    one, _ = K.project_bending_coloured(P.reshape(-1, 3), quads, w, rest, independent=False)
    assert np.array_equal(one, ref)
    for shift in (1, 3, 31):
        E = random_quads(rng, shift)
        P2 = np.concatenate([E, P])
        q2 = np.arange(4 * (m + shift)).reshape(-1, 4)
        w2 = np.concatenate([rng.uniform(0.2, 5, size=(shift, 4)), w])
        r2 = np.concatenate([rng.uniform(-3, 3, size=shift), rest])
        got, _ = K.project_bending_coloured(P2.reshape(-1, 3), q2, w2, r2)
        assert np.array_equal(got[4 * shift:], ref)


def test_dependent_quads_are_projected_in_order_like_the_reference(rng):
    # Quads sharing points (not independent): one at a time, Gauss-Seidel, in order.
    X = rng.normal(size=(6, 3))
    quads = np.array([[0, 1, 2, 3], [1, 2, 4, 5], [0, 2, 3, 5]])
    w = rng.uniform(0.5, 2, size=(6,))
    rest = np.array([0.3, -0.2, 1.0])
    got, _ = K.project_bending_coloured(X, quads, w[quads], rest, independent=False)
    want = X.copy()
    for c, q in enumerate(quads):
        *pts, _ = K.project_bending(*want[q], w[q], rest[c], 1.0)
        want[q] = pts
    assert np.abs(got - want).max() <= tolerance(X, want)


@pytest.fixture
def all_isas():
    """The blocked kernels' copies of the portable x86-64 build that this processor runs (SSE2,
    AVX2, AVX-512); skips where there is one."""
    isas = copies_here()
    if len(isas) < 2:
        pytest.skip(f"the blocked kernels have one copy here ({K.kernel_isa()})")
    yield isas
    K.kernel_isa("auto")


def test_the_blocks_write_only_the_particles_of_their_quads(rng):
    """The AVX2 copy loads a particle as four doubles (the fourth masked off) and writes (x, y)
    and z back: the particles between and after the quads' particles, and the last particle of
    the array, must keep their bits (another thread may own them), and the result must be the
    same as with the quads' particles packed together."""
    m = 61  # blocks of 32 and 29: full groups of four lanes and a tail of one
    P = random_quads(rng, m)
    w = rng.uniform(0.2, 5, size=(m, 4))
    rest = rng.uniform(-np.pi, np.pi, size=m)
    packed, _ = K.project_bending_coloured(P.reshape(-1, 3), np.arange(4 * m).reshape(m, 4), w, rest)
    # particle j of the packed array at 2 j + 1 of a spread one (the last quad's d last of all),
    # the gaps filled with values the kernel must not touch
    x = rng.normal(size=(8 * m, 3))
    x[1::2] = P.reshape(-1, 3)
    try:
        for isa in copies_here():
            K.kernel_isa(isa)
            got, _ = K.project_bending_coloured(x, 2 * np.arange(4 * m).reshape(m, 4) + 1, w, rest)
            assert np.array_equal(got[0::2], x[0::2]), isa
            assert np.array_equal(got[1::2], packed), isa
    finally:
        K.kernel_isa("auto")


@pytest.mark.parametrize("method, solver", [("pbd", "gauss-seidel"), ("xpbd", "gauss-seidel"), ("pbd", "jacobi"),
                                            ("jakobsen", "gauss-seidel")])
def test_the_sse2_avx2_and_avx512_kernels_give_the_same_bits(all_isas, method, solver):
    """The portable build runs the blocked bending and distance kernels and a fused step's update
    and prediction in AVX2 lanes (bending in AVX-512 code) when the processor has them; IEEE
    operations without FMA give the same bits in two lanes as in four, so a falling, bending
    64x64 cloth (8 parts: interiors and interfaces) ends bit for bit the same, with Gauss-Seidel
    (positions read and written in place), with Jacobi (read from the sweep's start, corrections
    summed apart) and with Jakobsen's Verlet front end."""
    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, 64, 64), mass=0.5, bending_stiffness=0.5,
                       bending_compliance=1e-3 if method == "xpbd" else 0.0)
    b.pin(cloth.first_particle)
    model = b.build()
    out = {}
    for isa in all_isas:
        assert K.kernel_isa(isa) == isa
        state = model.initial_state()
        csb.PbdStepper(method=method, solver=solver, dt=1 / 60, substeps=5, iterations=2, threads=2).step(
            model, state, 30)
        assert np.isfinite(state.x).all()
        out[isa] = np.asarray(state.x).copy()
    for isa in all_isas[1:]:
        assert np.array_equal(out["sse2"], out[isa]), isa
    # The kernel alone, on one colour's quads (independent: SIMD blocks) of a crumpled cloth.
    c = model.colouring("bending")
    quads = np.asarray(model.bending["particles"])[np.asarray(c["order"])[c["colour_offsets"][0]:c["colour_offsets"][1]]]
    assert len(quads) > 100
    x = np.asarray(model.initial_state().x) + np.random.default_rng(3).normal(scale=0.01, size=(model.num_particles, 3))
    w = np.ones((len(quads), 4))
    got = {}
    for isa in all_isas:
        K.kernel_isa(isa)
        got[isa] = K.project_bending_coloured(x, quads, w, np.zeros(len(quads)), independent=True)[0]
    assert not np.array_equal(got["sse2"], x)
    for isa in all_isas[1:]:
        assert np.array_equal(got["sse2"], got[isa]), isa
    with pytest.raises(csb.ParameterError, match="isa must be"):
        K.kernel_isa("avx1024")
