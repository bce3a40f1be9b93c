// csb — the coloured dihedral bending projection in SIMD blocks.
//
// The kernel of constraints/bending.hpp (signed angle, Bridson et al.'s gradient, Müller 2007
// §3.3's projection, Macklin 2016's XPBD update), written out on scalars for a range of
// constraints that share no particle (one colour), in blocks of kBendingBlock (∇_a θ as minus
// the sum of the other three gradients and |∇_c θ|², |∇_d θ|² in closed form: the same values,
// about two dozen operations fewer a constraint, a few units in the last place from the
// reference):
//  1. gather: the four particles' positions (and, XPBD, their displacement since the sub-step's
//     start) into structure-of-arrays block buffers, one constraint at a time (the AVX2 copy in
//     coloured_bending.cpp four at a time, in registers);
//  2. compute: a branch-free loop over the block that the compiler runs in SIMD lanes (`omp
//     simd`; SSE2 in the portable build), the angle by atan2_rational (csb/atan2.hpp) instead of
//     libm's atan2; a degenerate pair (zero-length edge, zero-area triangle) is masked by
//     selects: its gradient and so its correction are zero. With Gauss-Seidel (PBD, Jakobsen,
//     XPBD) the distance constraint on the element's edge (a, b) is projected first, on the
//     block's copy of a and b (ColouredFour::pair_rest; PbdStepper::build_coloured);
//  3. scatter: Gauss-Seidel (o = r) writes the four new positions, the block's copy plus the
//     correction (the same sum as adding the correction to the particle, which no other
//     constraint of the colour has moved meanwhile); Jacobi adds the twelve corrections (the
//     AVX2 copy likewise).
// Every constraint goes through the same IEEE operations in the same order whatever its lane,
// block, range or thread (no FMA contraction), so results do not depend on the thread count.
// A range whose constraints may share particles (the overflow colour) is projected one
// constraint per block, in order: Gauss-Seidel, with the same bits per constraint.
//
// r: positions read, o: positions (Gauss-Seidel, o = r) or correction sums (Jacobi) written;
// x: positions at the sub-step's start (XPBD damping only).
#pragma once

#include "csb/atan2.hpp"
#include "csb/solver/coloured.hpp"
#include "csb/constraints/bending.hpp"

#include <algorithm>
#include <string>

namespace csb {

// XPBD's distance step on one constraint, distance_xpbd's operations in its order, for the blocked
// kernels (the distance blocks and the bending elements' edges): from d = p_i - p_j (and, Damped,
// the relative motion u = (p_i - x_i) - (p_j - x_j)) the unit n = d/|d| (0 for |d| = 0), |d| and
// Δλ = (-(|d| - rest) - α̃ λ - γ n·u) * inv_den, before any sign clamp. Without damping γ n·u is
// +0, whose subtraction changes no value, and is left out. Fresh: λ is +0 (a sub-step's first
// sweep), so α̃ λ is +0 (α̃ is finite and >= 0) and likewise left out: neither α̃ nor λ is read.
template <bool Damped, class T, bool Fresh = false>
CSB_ATAN2_INLINE T xpbd_distance_step(T dx, T dy, T dz, T ux, T uy, T uz, T rest, T alpha,
                                         T gamma, T inv_den, T lambda, T& nx, T& ny, T& nz,
                                         T& len) {
  len = std::sqrt(dx * dx + dy * dy + dz * dz);
  const T inv_len = T(len > 0 ? 1 : 0) / (len > 0 ? len : T(1));
  nx = dx * inv_len, ny = dy * inv_len, nz = dz * inv_len;
  const T cl = len - rest;
  T num = -cl;
  if constexpr (!Fresh) num = num - alpha * lambda;
  if constexpr (Damped) {
    const T along = nx * ux + ny * uy + nz * uz;
    const T moved = gamma == 0 ? T(0) : along;
    num = num - gamma * moved;
  }
  return num * inv_den;
}

// Constraints per block: a multiple of 8 (the AVX-512 copy's compute loops run 8 lanes, its
// gathers 4). On the Zen 4 this was measured on (32 KiB L1d), per-pair against 32: 48 took
// 0.95-0.98 from 32² to 128² and 0.98-1.01 at 256² (two threads); 64 took 0.94-0.96 at 64² but
// 1.05-1.10 at 256², 128 1.07-1.08 at 64². The SSE2 and AVX2 copies do not care (1.00). The
// block size changes no result: every constraint is computed alike in any lane and block.
constexpr Index kBendingBlock = 48;

// Where a block of constraints c0 + [0, kBendingBlock) reads a coefficient: the batch's shared
// copies when its elements all have the same (ColouredFourT::k_same and the others), else their
// own.
template <class T>
CSB_ATAN2_INLINE const T* coefficients(const std::vector<T>& same, const std::vector<T>& own, Index c0) {
  return same.empty() ? own.data() + c0 : same.data();
}

// A block's working arrays. P[3 s + e][k]: coordinate e of particle s (a, b, c, d) of constraint
// c0 + k (a and b moved by the edge's distance constraint, if projected with the element);
// G[3 s + e][k]: ∇_s C; W[s][k] its inverse mass; X: XPBD's x, the positions at the sub-step's
// start, for damping (the motion p - x is taken after the edge's projection); Theta: the angle;
// S: the multiplier step, Δp_s = S w_s ∇_s C. Damped: XPBD on a batch with damping
// (ColouredFour::damped); without, the damping term is zero and X is neither gathered nor read.
// T: the scalar, double or (the single-precision step) float. (Fresh, a template argument of the
// kernels below: XPBD's multipliers are +0, a sub-step's first sweep: they are written, not read,
// see bending_compute.)
template <bool Xpbd, bool Damped = Xpbd, class T = Real>
struct BendingBlock {
  static_assert(Xpbd || !Damped);
  static constexpr Index B = kBendingBlock;
  alignas(64) T P[12][B], G[12][B], W[4][B];
  alignas(64) T X[Damped ? 12 : 1][B];
  alignas(64) T Theta[B], Cos[B], Wgrad[B], S[B];
};

// 1. Gather constraints c0 + [k0, m) into t, one at a time.
template <bool Xpbd, bool Damped, class T>
CSB_ATAN2_INLINE void bending_gather(BendingBlock<Xpbd, Damped, T>& t, const ColouredFourT<T>& b, Index c0, Index k0, Index m,
                                     const T* r, const T* x) {
  for (Index k = k0; k < m; ++k) {
    const auto& q = b.q[c0 + k];
    const auto& w = b.w[c0 + k];
    for (int s = 0; s < 4; ++s) {
      const Index i = q[s];
      t.P[3 * s][k] = r[i];
      t.P[3 * s + 1][k] = r[i + 1];
      t.P[3 * s + 2][k] = r[i + 2];
      t.W[s][k] = w[s];
      if constexpr (Damped) {
        t.X[3 * s][k] = x[i];
        t.X[3 * s + 1][k] = x[i + 1];
        t.X[3 * s + 2][k] = x[i + 2];
      }
    }
  }
}

// 2. The arithmetic of constraints c0 + [0, m) in SIMD lanes: the gradient into P, the step into S.
// Three short loops rather than one long one: the angle hangs on a chain of sqrt, two divisions
// and the polynomials (~100 cycles of latency), and only a short loop body lets the processor
// overlap that chain across iterations (in a micro-benchmark one fused loop ran at 1.25x the old
// scalar kernel, the split one at 1.7x).
//
// Fresh (XPBD): every multiplier of these constraints is +0, as at a sub-step's first sweep
// (Macklin 2016, Algorithm 1, sets them to zero before it): λ is not read, α̃ λ is +0 (α̃ finite,
// >= 0) and its subtraction changes no value, and the new λ is +0 + Δλ: the same bits as reading
// the zeros, without streaming the multipliers in or setting them to zero beforehand.
// XPBD's edge shares its correction by its particles' inverse masses, W[0] and W[1], not read
// again (pair_ca and pair_cb are PBD's): an element without an edge has inv_den = 0, so its Δλ
// is ±0 and w Δλ the same ±0 as 0 Δλ.
template <bool Xpbd, bool Damped, class T, bool Fresh = false>
CSB_ATAN2_INLINE void bending_compute(BendingBlock<Xpbd, Damped, T>& t, ColouredFourT<T>& b, Index c0, Index m) {
  static_assert(Xpbd || !Fresh);
  auto& P = t.P;
  auto& G = t.G;
  const auto& W = t.W;
  const auto& X = t.X;
  if constexpr (Xpbd) {
    if (!b.pair_rest.empty()) {
      // The distance constraints on the elements' edges (a, b) first (XPBD, as distance_xpbd:
      // d = a - b, n = d/|d|, Δλ = (-(|d| - rest) - α̃ λ - γ n·((a - x_a) - (b - x_b))) / ((1 + γ)
      // Σw + α̃), Δa = +w_a Δλ n, Δb = -w_b Δλ n; an element without one has 1/denominator 0, so
      // Δλ = ±0 and no step), into the block's positions of a and b.
      const T* rest = b.pair_rest.data() + c0;
      const T* alpha = coefficients(b.pair_alpha_same, b.pair_alpha, c0);
      const T* gamma = b.pair_gamma.data() + c0;
      const T* inv_den = b.pair_inv_den.data() + c0;
      T* lambda = b.pair_lambda.data() + c0;
#pragma omp simd
      for (Index k = 0; k < m; ++k) {
        T ux = 0, uy = 0, uz = 0;
        if constexpr (Damped) {
          ux = (P[0][k] - X[0][k]) - (P[3][k] - X[3][k]);
          uy = (P[1][k] - X[1][k]) - (P[4][k] - X[4][k]);
          uz = (P[2][k] - X[2][k]) - (P[5][k] - X[5][k]);
        }
        const T l = Fresh ? T(0) : lambda[k];
        T nx, ny, nz, len;
        T dl = xpbd_distance_step<Damped, T, Fresh>(P[0][k] - P[3][k], P[1][k] - P[4][k], P[2][k] - P[5][k], ux, uy,
                                                    uz, rest[k], Fresh ? T(0) : alpha[k], gamma[k], inv_den[k], l, nx,
                                                    ny, nz, len);
        dl = len > 0 ? dl : T(0);
        lambda[k] = l + dl;
        const T da = W[0][k] * dl, db = W[1][k] * dl;
        P[0][k] += da * nx, P[1][k] += da * ny, P[2][k] += da * nz;
        P[3][k] -= db * nx, P[4][k] -= db * ny, P[5][k] -= db * nz;
      }
    }
  } else if (!b.pair_rest.empty()) {
    // The distance constraints on the elements' edges (a, b) first (PBD, as distance_pbd:
    // d = a - b, s = (|d| - rest)/|d|, Δa = -ca s d, Δb = +cb s d; ca = cb = 0 for an element
    // without one), into the block's positions of a and b.
    const T* rest = b.pair_rest.data() + c0;
    const T* ca = b.pair_ca.data() + c0;
    const T* cb = b.pair_cb.data() + c0;
#pragma omp simd
    for (Index k = 0; k < m; ++k) {
      const T dx = P[0][k] - P[3][k], dy = P[1][k] - P[4][k], dz = P[2][k] - P[5][k];
      const T len = std::sqrt(dx * dx + dy * dy + dz * dz);
      const T s = (len > 0 ? len - rest[k] : T(0)) / (len > 0 ? len : T(1));
      const T sa = ca[k] * s, sb = cb[k] * s;
      P[0][k] -= sa * dx, P[1][k] -= sa * dy, P[2][k] -= sa * dz;
      P[3][k] += sb * dx, P[4][k] += sb * dy, P[5][k] += sb * dz;
    }
  }
  // Geometry: the angle's two arguments, the gradient (over the positions) and Σ w |∇C|².
#pragma omp simd
  for (Index k = 0; k < m; ++k) {
    const T ax = P[0][k], ay = P[1][k], az = P[2][k];
    const T bx = P[3][k], by = P[4][k], bz = P[5][k];
    const T cx = P[6][k], cy = P[7][k], cz = P[8][k];
    const T dx = P[9][k], dy = P[10][k], dz = P[11][k];
    const T ex = bx - ax, ey = by - ay, ez = bz - az;
    const T cax = cx - ax, cay = cy - ay, caz = cz - az, cbx = cx - bx, cby = cy - by, cbz = cz - bz;
    const T dax = dx - ax, day = dy - ay, daz = dz - az, dbx = dx - bx, dby = dy - by, dbz = dz - bz;
    // N1 = (c - a) x (c - b), N2 = (d - b) x (d - a)
    const T n1x = cay * cbz - caz * cby, n1y = caz * cbx - cax * cbz, n1z = cax * cby - cay * cbx;
    const T n2x = dby * daz - dbz * day, n2y = dbz * dax - dbx * daz, n2z = dbx * day - dby * dax;
    const T e2 = ex * ex + ey * ey + ez * ez;
    const T n1 = n1x * n1x + n1y * n1y + n1z * n1z, n2 = n2x * n2x + n2y * n2y + n2z * n2z;
    const bool ok = e2 > 0 && n1 > 0 && n2 > 0;
    const T elen = std::sqrt(e2);
    t.Theta[k] = (n1y * n2z - n1z * n2y) * ex + (n1z * n2x - n1x * n2z) * ey + (n1x * n2y - n1y * n2x) * ez;
    t.Cos[k] = (n1x * n2x + n1y * n2y + n1z * n2z) * elen;
    const T one = ok ? T(1) : T(0);
    const T i1 = one / (ok ? n1 : T(1)), i2 = one / (ok ? n2 : T(1)), ie = one / (ok ? elen : T(1));
    const T g1x = n1x * i1, g1y = n1y * i1, g1z = n1z * i1, g2x = n2x * i2, g2y = n2y * i2, g2z = n2z * i2;
    const T tca = (cax * ex + cay * ey + caz * ez) * ie, tda = (dax * ex + day * ey + daz * ez) * ie;
    const T el = ok ? elen : T(0);
    const T gbx = tca * g1x + tda * g2x, gby = tca * g1y + tda * g2y, gbz = tca * g1z + tda * g2z;
    const T gcx = -el * g1x, gcy = -el * g1y, gcz = -el * g1z;
    const T gdx = -el * g2x, gdy = -el * g2y, gdz = -el * g2z;
    // θ is invariant under translation, so the gradients sum to zero: ∇_a θ = -(∇_b + ∇_c + ∇_d)
    // (Bridson's -((c - b)·e N1/|N1|² + (d - b)·e N2/|N2|²)/|e| in closed form), and
    // |∇_c θ|² = |e|² |N1|²/|N1|⁴ = |e|²/|N1|², |∇_d θ|² = |e|²/|N2|² (0 where degenerate:
    // i1 = i2 = 0).
    const T gax = -(gbx + gcx + gdx), gay = -(gby + gcy + gdy), gaz = -(gbz + gcz + gdz);
    t.Wgrad[k] = W[0][k] * (gax * gax + gay * gay + gaz * gaz) + W[1][k] * (gbx * gbx + gby * gby + gbz * gbz) +
                 (W[2][k] * i1 + W[3][k] * i2) * e2;
    G[0][k] = gax, G[1][k] = gay, G[2][k] = gaz, G[3][k] = gbx, G[4][k] = gby, G[5][k] = gbz;
    G[6][k] = gcx, G[7][k] = gcy, G[8][k] = gcz, G[9][k] = gdx, G[10][k] = gdy, G[11][k] = gdz;
  }
  // The angle, in a loop of its own (its latency chain is the longest), then the violation
  // and the multiplier: Δp_i = S w_i ∇_i C.
#pragma omp simd
  for (Index k = 0; k < m; ++k) t.Theta[k] = atan2_rational(t.Theta[k], t.Cos[k]);
  const T* rest = b.rest.data() + c0;
  if constexpr (Xpbd) {
    const T* alpha = coefficients(b.alpha_same, b.alpha, c0);
    const T* gamma = b.gamma.data() + c0;
    T* lambda = b.lambda.data() + c0;
#pragma omp simd
    for (Index k = 0; k < m; ++k) {
      const T violation = wrap_angle(t.Theta[k] - rest[k]);
      const T wgrad = t.Wgrad[k];
      const bool move = wgrad > 0;
      const T l = Fresh ? T(0) : lambda[k];
      // Without damping (every γ +0) (1 + γ) w|∇C|² is w|∇C|² and γ moved is +0, whose
      // subtraction changes no value: the damping terms are left out, with the same bits.
      T num = -violation, den = wgrad + alpha[k];
      if constexpr (!Fresh) num = num - alpha[k] * l;
      if constexpr (Damped) {
        const T g = gamma[k];
        // the motion since the sub-step's start, p - x, along the gradient
        T along = G[0][k] * (P[0][k] - X[0][k]);
        for (int e = 1; e < 12; ++e) along = along + G[e][k] * (P[e][k] - X[e][k]);
        const T moved = g == 0 ? T(0) : along;
        num = num - g * moved;
        den = (1 + g) * wgrad + alpha[k];
      }
      const T dl = num / (move ? den : T(1));
      t.S[k] = move ? dl : T(0);
      lambda[k] = l + t.S[k];
    }
  } else {
    const T* kk = coefficients(b.k_same, b.k, c0);
#pragma omp simd
    for (Index k = 0; k < m; ++k) {
      const T violation = wrap_angle(t.Theta[k] - rest[k]);
      const T wgrad = t.Wgrad[k];
      const bool move = wgrad > 0;
      const T stiffness = kk[k];  // loaded unconditionally: a conditional load is control flow
      t.S[k] = (move ? -stiffness * violation : T(0)) / (move ? wgrad : T(1));
    }
  }
}

// 3. Scatter constraints c0 + [k0, m), one at a time. In place (Gauss-Seidel, o = r): the new
// positions written, P + S w_s ∇_s C; else (Jacobi) the correction added to o.
template <bool Xpbd, bool Damped, class T>
CSB_ATAN2_INLINE void bending_scatter(const BendingBlock<Xpbd, Damped, T>& t, const ColouredFourT<T>& b, Index c0, Index k0, Index m,
                                      bool in_place, T* o) {
  for (Index k = k0; k < m; ++k) {
    const auto& q = b.q[c0 + k];
    for (int s = 0; s < 4; ++s) {
      const T ws = t.S[k] * t.W[s][k];
      const Index i = q[s];
      for (int e = 0; e < 3; ++e)
        o[i + e] = (in_place ? t.P[3 * s + e][k] : o[i + e]) + ws * t.G[3 * s + e][k];
    }
  }
}

// Constraints c0 + [0, m) as one block, gathered and scattered one constraint at a time.
template <bool Xpbd, bool Damped = Xpbd, class T, bool Fresh = false>
CSB_ATAN2_INLINE void bending_block(ColouredFourT<T>& b, Index c0, Index m, const T* r, T* o, const T* x) {
  BendingBlock<Xpbd, Damped, T> t;
  bending_gather(t, b, c0, 0, m, r, x);
  bending_compute<Xpbd, Damped, T, Fresh>(t, b, c0, m);
  bending_scatter(t, b, c0, 0, m, o == r, o);
}

// The blocks of constraints [begin, end) of one colour (they share no particle). Defined in
// coloured_bending.cpp: on x86-64 compiled for SSE2, AVX2 and AVX-512, the best the processor
// has taken (same bits: IEEE operations give the same results in any lane width, and no copy
// contracts to FMA). fresh (XPBD): the multipliers are +0 (a sub-step's first sweep; see
// bending_compute).
void bending_blocks(ColouredFour& b, bool xpbd, bool fresh, Index begin, Index end, const Real* r, Real* o,
                    const Real* x);
void bending_blocks(ColouredFourT<float>& b, bool xpbd, bool fresh, Index begin, Index end, const float* r, float* o,
                    const float* x);

// Constraints [begin, end) of one colour. independent: they share no particle (blocks);
// otherwise one at a time, in order. fresh: as bending_blocks'.
template <bool Xpbd, class T>
inline void project_bending_range(ColouredFourT<T>& b, Index begin, Index end, bool independent, bool fresh,
                                  const T* r, T* o, const T* x) {
  if (independent) {
    bending_blocks(b, Xpbd, fresh, begin, end, r, o, x);
  } else if (Xpbd && fresh) {
    for (Index c = begin; c < end; ++c) bending_block<Xpbd, Xpbd, T, Xpbd>(b, c, 1, r, o, x);
  } else {
    for (Index c = begin; c < end; ++c) bending_block<Xpbd>(b, c, 1, r, o, x);
  }
}

// The instruction set the blocked kernels (bending_blocks, and the coloured PBD distance blocks
// in pbd.cpp) run: "avx512", "avx2" or "sse2" in the portable x86-64 build ("avx512": bending in
// its AVX-512 copy, distance in its AVX2 one), "native" in a native build (compiled for its
// machine) or elsewhere. set_kernel_isa("sse2") makes an AVX2 machine run the SSE2 code (for
// measurements and tests), "auto" undoes it.
std::string kernel_isa();
void set_kernel_isa(const std::string& isa);
// Whether the blocked distance kernels take their AVX2 copies now ("avx2" or "avx512").
bool kernels_use_avx2();

// For tests (the Python `csb.kernels`): the same projection over all of `b` as one range, with
// positions p read and written in place (Gauss-Seidel); x: start positions (XPBD). Defined in
// pbd.cpp, compiled with the library's flags.
void project_bending_coloured(ColouredFour& b, bool xpbd, bool independent, Real* p, const Real* x);
// out[i] = atan2_rational(y[i], x[i]), in a loop that vectorises as the kernel does.
void atan2_rational_array(const Real* y, const Real* x, Real* out, Index n);

}  // namespace csb
