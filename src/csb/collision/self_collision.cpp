// csb — cloth self-collision (self_collision.hpp): point–triangle proximity contacts of each
// self-colliding group generated at the start of a sub-step and projected with the constraints
// (Müller 2007 §4.4), then, after the sweeps, continuous collision detection of every
// point–triangle and edge–edge pair along the sub-step's motion x -> p, responses (after Bridson,
// Fedkiw, Anderson 2002), inelastic velocities, and a fail-safe.
//
// What is guaranteed. Let the cloth have no intersection at the start x of a sub-step. Every
// pair of features that share no particle (a particle and a triangle without it, two edges
// without a common end) whose swept boxes over x -> p touch is tested by additive CCD (ccd.hpp)
// along its straight motion, conservatively: a pair whose distance reaches 0 anywhere in the
// sub-step is always found. The one exception is a pair inside a patch of the hierarchy that is
// certified for the motion (certify_node: a disc whose projection along its mean normal stays one
// to one over the whole sub-step, after Volino and Magnenat-Thalmann 1994 and Schvartzman, Pérez
// and Otaduy 2010): no two of its points can meet, so its pairs need no test, and a patch
// certified when the candidates are searched is not even searched inside until a sub-step's
// motion stops certifying it; nor are two nodes whose union is such a patch (certify_union).
// A smooth cloth, however it swings, costs the certification of a few
// patches instead of tens of thousands of tests; only where it folds onto itself are pairs
// searched and tested. Found pairs get a contact along their normal at the time of impact;
// after kResponseRounds rounds of responses, what is still found is stopped: its particles that
// can move are put back where they started the sub-step (p = x), the fail-safe, repeated until the
// test finds nothing (a pair whose particles all stay cannot meet: x has no intersection). So the
// end of the sub-step has no new intersection, with two exceptions, counted and reported:
// `self_unresolved`, a pair that meets only because prescribed particles (pins moved by the
// user, kinematic grabs) drive it through, which no motion of the free particles can undo; and
// `self_skipped`, triangles left out because they spread over more than the cloth's rest size
// within a step (a runaway, which the divergence guard stops by default). Each
// particle the fail-safe stops is counted (`self_failsafe`): it loses its velocity for that
// sub-step, visibly, which is why the responses come first. The guarantee is the one of the
// pairs: a particle touching a triangle it belongs to, or two edges with a common end, are not
// tested (they meet only by a triangle collapsing).
#include "csb/collision/self_collision.hpp"

#include "csb/collision/collision.hpp"
#include "csb/format.hpp"
#include "csb/solver/coloured_bending.hpp"  // kernels_use_avx2

#include <algorithm>
#include <limits>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
// The portable x86-64 build (SSE2) carries AVX2 copies of the per-sub-step passes below, taken
// where the processor has AVX2 (kernels_use_avx2) and giving the same bits.
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__AVX2__)
#define CSB_SELF_AVX2 1
#include <immintrin.h>
#endif

namespace csb {

using detail::str;

namespace {

// Rounds of continuous contacts before the fail-safe, and Gauss-Seidel passes over the
// self-contacts in each. More do not stop the fail-safe firing where a cloth is wound tight:
// the 30 x 30 twist's first 3 s stopped 9,211 particles with 2 rounds of 2 passes, 7,251 with
// 4 of 2, 12,530 with 2 of 4 and 34,990 with 6 of 4 (validation/torture.py counts them).
constexpr int kResponseRounds = 2;
constexpr int kResponsePasses = 2;
// The additive CCD's separation s: an impact is a pair whose distance falls below s times its
// distance at the start of the sub-step; its contact then keeps at least that much.
constexpr Real kSeparation = 0.1;
// The candidates' boxes are widened by this many thicknesses on each side (find_candidates).
constexpr Real kSearchPad = 1.5;
// A particle's look-ahead (find_candidates) reaches at most this many of its group's mean rest
// edges, so that a box holds a bounded number of edges at any resolution: the pairs a particle
// keeps grow as the square of its box in edges. A shorter look-ahead searches more often. The
// cape's steps (XPBD, 10 x 1, frames 30-90, five alternating rounds) averaged, at 2 edges, 4
// and a whole step's look-ahead: 1.18, 1.14 and 1.15 ms at 40 x 40 (0.73 without
// self-collision), 3.31, 2.99 and 3.10 at 56 x 56 (1.46), 6.26, 5.85 and 5.90 at 80 x 80 (2.84).
constexpr Real kLookaheadEdges = 4;
// The widest a particle's or a feature's search box may be (m) for a group of rest size `size` and
// thickness h; a wider one is left out of the search (find_candidates).
inline Real search_reach(Real size, Real h) { return size + 2 * (kSearchPad * h); }

// Whether y[j] lies in [lo[j], hi[j]] for j < n (a NaN is not outside: as Eigen's comparisons
// in candidates_hold's loop over particles): the per-sub-step check of a whole cloth, one branch
// per run of kRun coordinates, the compares of a run vectorised (four lanes where AVX2 is).
inline __attribute__((always_inline)) bool within_body(const Real* __restrict y, const Real* __restrict lo,
                                                       const Real* __restrict hi, Index n) {
  constexpr Index kRun = 256;
  for (Index j = 0; j < n;) {
    std::uint64_t out = 0;  // as wide as a coordinate: the compares' masks are or-ed as they are
    for (const Index end = std::min(n, j + kRun); j < end; ++j)
      out |= std::uint64_t(y[j] < lo[j]) | std::uint64_t(y[j] > hi[j]);
    if (out) return false;
  }
  return true;
}
#if defined(CSB_SELF_AVX2)
__attribute__((target("avx2"))) bool within_avx2(const Real* y, const Real* lo, const Real* hi, Index n) {
  return within_body(y, lo, hi, n);
}
#endif
bool within(const Real* y, const Real* lo, const Real* hi, Index n) {
#if defined(CSB_SELF_AVX2)
  if (kernels_use_avx2()) return within_avx2(y, lo, hi, n);
#endif
  return within_body(y, lo, hi, n);
}

// For the n particles at x, p and e (3 x n, contiguous): whether x equals e coordinate for
// coordinate, each one's |p - x|² (move2, taken as (dx² + dy²) + dz²) and the largest (a NaN left
// out, as std::max leaves it). Two particles per step of SSE2 where there is SSE2, to the same
// bits as the plain loop.
void carry_check(const Real* x, const Real* p, const Real* e, Index n, bool& same, Real* move2, Real& step2) {
  Index i = 0;
  step2 = 0;
  same = true;
#if defined(__SSE2__)
  __m128d differ = _mm_setzero_pd(), most = _mm_setzero_pd();
  for (; i + 2 <= n; i += 2) {
    const Real *xi = x + 3 * i, *pi = p + 3 * i, *ei = e + 3 * i;
    const __m128d x0 = _mm_loadu_pd(xi), x1 = _mm_loadu_pd(xi + 2), x2 = _mm_loadu_pd(xi + 4);
    differ = _mm_or_pd(differ, _mm_or_pd(_mm_cmpneq_pd(x0, _mm_loadu_pd(ei)),
                                         _mm_or_pd(_mm_cmpneq_pd(x1, _mm_loadu_pd(ei + 2)), _mm_cmpneq_pd(x2, _mm_loadu_pd(ei + 4)))));
    const __m128d d0 = _mm_sub_pd(_mm_loadu_pd(pi), x0), d1 = _mm_sub_pd(_mm_loadu_pd(pi + 2), x1),
                  d2 = _mm_sub_pd(_mm_loadu_pd(pi + 4), x2);
    // Squares [x0² y0²], [z0² x1²], [y1² z1²]: particle 0 in the low lanes, particle 1 in the high.
    const __m128d s0 = _mm_mul_pd(d0, d0), s1 = _mm_mul_pd(d1, d1), s2 = _mm_mul_pd(d2, d2);
    const __m128d xs = _mm_shuffle_pd(s0, s1, 2), ys = _mm_shuffle_pd(s0, s2, 1), zs = _mm_shuffle_pd(s1, s2, 2);
    const __m128d sum = _mm_add_pd(_mm_add_pd(xs, ys), zs);
    _mm_storeu_pd(move2 + i, sum);
    most = _mm_max_pd(sum, most);  // the second operand where NaN
  }
  same = _mm_movemask_pd(differ) == 0;
  alignas(16) Real lanes[2];
  _mm_store_pd(lanes, most);
  step2 = std::max(lanes[0], lanes[1]);
#endif
  for (; i < n; ++i) {
    const Real dx = p[3 * i] - x[3 * i], dy = p[3 * i + 1] - x[3 * i + 1], dz = p[3 * i + 2] - x[3 * i + 2];
    same = same && x[3 * i] == e[3 * i] && x[3 * i + 1] == e[3 * i + 1] && x[3 * i + 2] == e[3 * i + 2];
    move2[i] = dx * dx + dy * dy + dz * dz;
    step2 = std::max(step2, move2[i]);
  }
}

// The n particles y (3 x n, contiguous) projected onto the plane across an axis, along the unit
// axes U and W of that plane: out[2 i] = U·y_i, out[2 i + 1] = W·y_i, each sum taken left to
// right. Four particles a trip where AVX2 is, to the same bits (no fused multiply-add).
inline __attribute__((always_inline)) void project_across_body(const Real* __restrict y, Index n, const Vec3& U,
                                                               const Vec3& W, Real* __restrict out) {
  for (Index i = 0; i < n; ++i, y += 3) {
    out[2 * i] = U.x() * y[0] + U.y() * y[1] + U.z() * y[2];
    out[2 * i + 1] = W.x() * y[0] + W.y() * y[1] + W.z() * y[2];
  }
}

// For the triangles across[0 .. size) (each corner's offset into P, two coordinates a particle):
// whether every one's 2D cross product (b - a) x (c - a), times scale, is above need (false for
// NaN); if so, least = the least cross product times scale. The verdicts are looked at every kRun
// triangles; four triangles a trip, each lane its own least (exact in any order).
inline __attribute__((always_inline)) bool areas_above_body(const std::array<Index, 3>* across, Index size,
                                                            const Real* P, Real scale, Real need, Real& least_out) {
  constexpr int L = 4;
  constexpr Index kRun = 256;
  Real least[L];
  unsigned char all[L];
  for (int l = 0; l < L; ++l) least[l] = std::numeric_limits<Real>::infinity(), all[l] = 1;
  const auto lane = [&](Index i, int l) {
    const std::array<Index, 3>& t = across[i];
    const Real *a = P + t[0], *b = P + t[1], *c = P + t[2];
    const Real end = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    all[l] &= end * scale > need;  // false for NaN
    least[l] = std::min(least[l], end);
  };
  Index i = 0;
  while (i + L <= size) {
    for (const Index end = std::min(size - L, i + kRun); i <= end; i += L)
      for (int l = 0; l < L; ++l) lane(i + l, l);
    if (!(all[0] & all[1] & all[2] & all[3])) return false;
  }
  for (; i < size; ++i) lane(i, 0);
  least_out = std::min(std::min(least[0], least[1]), std::min(least[2], least[3])) * scale;
  return all[0] != 0;
}

#if defined(CSB_SELF_AVX2)
// AVX2 forms of the two above, to the same bits. A root like the 40 x 40 cape's (1,600 particles,
// 3,042 triangles), certified on every sub-step, took 2.1 and 5.5 thousand cycles against 3.2 and
// 10.5 (a micro-benchmark of the two loops), and the cape's median step with self-collision went
// from 1.28 to 1.25 times the step without (10 x 1, three alternating runs of seven rounds).
__attribute__((target("avx2"))) void project_across_avx2(const Real* y, Index n, const Vec3& U, const Vec3& W,
                                                         Real* out) {
  const __m256d ux = _mm256_set1_pd(U.x()), uy = _mm256_set1_pd(U.y()), uz = _mm256_set1_pd(U.z());
  const __m256d wx = _mm256_set1_pd(W.x()), wy = _mm256_set1_pd(W.y()), wz = _mm256_set1_pd(W.z());
  Index i = 0;
  for (; i + 4 <= n; i += 4) {
    // [x0 y0 z0 x1] [y1 z1 x2 y2] [z2 x3 y3 z3] -> x, y and z of the four.
    const Real* c = y + 3 * i;
    const __m256d a = _mm256_loadu_pd(c), b = _mm256_loadu_pd(c + 4), d = _mm256_loadu_pd(c + 8);
    const __m256d p0 = _mm256_permute2f128_pd(a, b, 0x30);  // [x0 y0 | x2 y2]
    const __m256d p1 = _mm256_permute2f128_pd(a, d, 0x21);  // [z0 x1 | z2 x3]
    const __m256d p2 = _mm256_permute2f128_pd(b, d, 0x30);  // [y1 z1 | y3 z3]
    const __m256d xs = _mm256_shuffle_pd(p0, p1, 0b1010), ys = _mm256_shuffle_pd(p0, p2, 0b0101),
                  zs = _mm256_shuffle_pd(p1, p2, 0b1010);
    const __m256d u = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(ux, xs), _mm256_mul_pd(uy, ys)), _mm256_mul_pd(uz, zs));
    const __m256d w = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(wx, xs), _mm256_mul_pd(wy, ys)), _mm256_mul_pd(wz, zs));
    const __m256d lo = _mm256_unpacklo_pd(u, w), hi = _mm256_unpackhi_pd(u, w);  // [u0 w0 | u2 w2], [u1 w1 | u3 w3]
    _mm256_storeu_pd(out + 2 * i, _mm256_permute2f128_pd(lo, hi, 0x20));
    _mm256_storeu_pd(out + 2 * i + 4, _mm256_permute2f128_pd(lo, hi, 0x31));
  }
  project_across_body(y + 3 * i, n - i, U, W, out + 2 * i);
}

// Corner e of triangles k and k + 2 in one register: [x y | x y].
inline __attribute__((target("avx2"), always_inline)) __m256d corners_of_two(const Real* P,
                                                                             const std::array<Index, 3>* across,
                                                                             Index k, int e) {
  return _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(P + across[k][e])), _mm_loadu_pd(P + across[k + 2][e]), 1);
}

__attribute__((target("avx2"))) bool areas_above_avx2(const std::array<Index, 3>* across, Index size, const Real* P,
                                                      Real scale, Real need, Real& least_out) {
  constexpr Index kRun = 256;
  const __m256d s = _mm256_set1_pd(scale), floor = _mm256_set1_pd(need);
  __m256d least = _mm256_set1_pd(std::numeric_limits<Real>::infinity()), fail = _mm256_setzero_pd();
  Index i = 0;
  while (i + 4 <= size) {
    for (const Index last = std::min(size - 4, i + kRun); i <= last; i += 4) {
      const __m256d a02 = corners_of_two(P, across, i, 0), a13 = corners_of_two(P, across, i + 1, 0);
      const __m256d e02 = _mm256_sub_pd(corners_of_two(P, across, i, 1), a02),
                    e13 = _mm256_sub_pd(corners_of_two(P, across, i + 1, 1), a13);
      const __m256d f02 = _mm256_sub_pd(corners_of_two(P, across, i, 2), a02),
                    f13 = _mm256_sub_pd(corners_of_two(P, across, i + 1, 2), a13);
      // Lanes in the triangles' order i .. i + 3.
      const __m256d ex = _mm256_unpacklo_pd(e02, e13), ey = _mm256_unpackhi_pd(e02, e13);
      const __m256d fx = _mm256_unpacklo_pd(f02, f13), fy = _mm256_unpackhi_pd(f02, f13);
      const __m256d area = _mm256_sub_pd(_mm256_mul_pd(ex, fy), _mm256_mul_pd(ey, fx));
      fail = _mm256_or_pd(fail, _mm256_cmp_pd(_mm256_mul_pd(area, s), floor, _CMP_NGT_UQ));  // NaN fails
      least = _mm256_min_pd(area, least);  // least where area is NaN, as std::min
    }
    if (_mm256_movemask_pd(fail)) return false;
  }
  alignas(32) Real lanes[4];
  _mm256_store_pd(lanes, least);
  Real tail = std::numeric_limits<Real>::infinity();
  if (!areas_above_body(across + i, size - i, P, scale, need, tail)) return false;
  least_out = std::min(std::min(std::min(lanes[0], lanes[1]), std::min(lanes[2], lanes[3])) * scale, tail);
  return true;
}
#endif

void project_across(const Real* y, Index n, const Vec3& U, const Vec3& W, Real* out) {
#if defined(CSB_SELF_AVX2)
  if (kernels_use_avx2()) return project_across_avx2(y, n, U, W, out);
#endif
  project_across_body(y, n, U, W, out);
}

bool areas_above(const std::array<Index, 3>* across, Index size, const Real* P, Real scale, Real need, Real& least) {
#if defined(CSB_SELF_AVX2)
  if (kernels_use_avx2()) return areas_above_avx2(across, size, P, scale, need, least);
#endif
  return areas_above_body(across, size, P, scale, need, least);
}

inline bool boxes_overlap(const Vec3& lo_a, const Vec3& hi_a, const Vec3& lo_b, const Vec3& hi_b) {
  return !((lo_a.array() > hi_b.array()).any() || (hi_a.array() < lo_b.array()).any());
}

// Whether the boxes swept over x -> p by particles a and by particles b, each widened by pad (m),
// overlap: the same answer as boxes_overlap on the boxes sweep_boxes unites, computed for one pair.
template <std::size_t NA, std::size_t NB>
bool swept_boxes_overlap_body(const Positions& x, const Positions& p, const std::array<Index, NA>& a,
                              const std::array<Index, NB>& b, Real pad) {
  const auto box = [&](const auto& ids, Vec3& lo, Vec3& hi) {
    lo = x.col(ids[0]).cwiseMin(p.col(ids[0]));
    hi = x.col(ids[0]).cwiseMax(p.col(ids[0]));
    for (std::size_t k = 1; k < ids.size(); ++k) {
      lo = lo.cwiseMin(x.col(ids[k])).cwiseMin(p.col(ids[k]));
      hi = hi.cwiseMax(x.col(ids[k])).cwiseMax(p.col(ids[k]));
    }
    lo.array() -= pad;
    hi.array() += pad;
  };
  Vec3 lo_a, hi_a, lo_b, hi_b;
  box(a, lo_a, hi_a);
  box(b, lo_b, hi_b);
  return boxes_overlap(lo_a, hi_a, lo_b, hi_b);
}

#if defined(CSB_SELF_AVX2)
// The same in AVX2 lanes, a particle's three coordinates and a zero in one register: the same
// answer (each min and max taken as Eigen's, the operand order kept for NaN; the zero lanes never
// decide). The check runs on every candidate pair on every sub-step, 6,000-15,000 pairs where the
// 80 x 80 cape folds: there its samples fell from 583 to 255 per 1,000 of the constraint
// kernels', and the fifteen dearest of frames 30-90 went from 2.27-2.31 to 1.91-1.94 times the
// median step with the projected form below the root (which alone gave 2.25-2.28; three
// alternating runs).
inline __attribute__((target("avx2"), always_inline)) __m256d particle_row(const Real* y, Index i) {
  const Real* c = y + 3 * static_cast<std::size_t>(i);
  return _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(c)), _mm_load_sd(c + 2), 1);
}
template <std::size_t N>
inline __attribute__((target("avx2"), always_inline)) void swept_box_avx2(const Real* x, const Real* p,
                                                                            const std::array<Index, N>& ids,
                                                                            __m256d& lo, __m256d& hi) {
  __m256d xi = particle_row(x, ids[0]), pi = particle_row(p, ids[0]);
  lo = _mm256_min_pd(pi, xi);  // std::min(x, p): p where p < x, else x
  hi = _mm256_max_pd(pi, xi);  // std::max(x, p): p where x < p, else x
  for (std::size_t k = 1; k < N; ++k) {
    xi = particle_row(x, ids[k]), pi = particle_row(p, ids[k]);
    lo = _mm256_min_pd(pi, _mm256_min_pd(xi, lo));
    hi = _mm256_max_pd(pi, _mm256_max_pd(xi, hi));
  }
}
template <std::size_t NA, std::size_t NB>
__attribute__((target("avx2"))) bool swept_boxes_overlap_avx2(const Real* x, const Real* p,
                                                              const std::array<Index, NA>& a,
                                                              const std::array<Index, NB>& b, Real pad) {
  __m256d lo_a, hi_a, lo_b, hi_b;
  swept_box_avx2(x, p, a, lo_a, hi_a);
  swept_box_avx2(x, p, b, lo_b, hi_b);
  const __m256d w = _mm256_set1_pd(pad);
  lo_a = _mm256_sub_pd(lo_a, w), hi_a = _mm256_add_pd(hi_a, w);
  lo_b = _mm256_sub_pd(lo_b, w), hi_b = _mm256_add_pd(hi_b, w);
  const __m256d apart = _mm256_or_pd(_mm256_cmp_pd(lo_a, hi_b, _CMP_GT_OQ), _mm256_cmp_pd(hi_a, lo_b, _CMP_LT_OQ));
  return _mm256_movemask_pd(apart) == 0;
}
#endif

// avx2: kernels_use_avx2(), read once for a loop over pairs.
template <std::size_t NA, std::size_t NB>
bool swept_boxes_overlap(const Positions& x, const Positions& p, const std::array<Index, NA>& a,
                         const std::array<Index, NB>& b, Real pad, bool avx2) {
#if defined(CSB_SELF_AVX2)
  if (avx2) return swept_boxes_overlap_avx2(x.data(), p.data(), a, b, pad);
#endif
  (void)avx2;
  return swept_boxes_overlap_body(x, p, a, b, pad);
}

// Σ_k c_k y_k: the separation d of contact k's particles at positions y (m).
template <class Y>
Vec3 separation(const SelfContact& k, const Y& y) {
  const auto& c = k.weights;
  const auto& id = k.particles;
  return c[0] * y(id[0]) + c[1] * y(id[1]) + c[2] * y(id[2]) + c[3] * y(id[3]);
}

// Σ_k c_k² w_k: the inverse mass a contact's correction or impulse along its normal meets.
Real contact_inverse_mass(const SelfContact& k, const Real* w) {
  const auto& c = k.weights;
  const auto& id = k.particles;
  return c[0] * c[0] * w[id[0]] + c[1] * c[1] * w[id[1]] + c[2] * c[2] * w[id[2]] + c[3] * c[3] * w[id[3]];
}

// The approach speed of a contact along n in the motion x -> p over h, m/s.
Real approach_speed(const SelfContact& k, const Vec3& n, const Positions& x, const Positions& p, Real h) {
  return separation(k, [&](Index i) { return Vec3(p.col(i) - x.col(i)); }).dot(n) / h;
}

}  // namespace

void SelfCollision::prepare(const Model& model) {
  // The triangles and edges of each self-colliding group, their owners and their hierarchy; hash
  // cells, for the group's particles in no triangle, of about
  // a feature's widened box, 1.5 times the mean edge plus twice the thickness (Teschner et al.
  // 2003 find a cell near the mean primitive size best).
  groups_.clear();
  contacts_.clear();
  counts_ = {};
  const Index n = model.num_particles();
  std::size_t most_triangles = 0;
  for (Index g = 0; g < model.num_groups(); ++g) {
    const Real h_self = model.self_collision_thickness[g];
    if (!(h_self > 0)) continue;
    Group sg;
    sg.group = g;
    sg.thickness = h_self;
    sg.count = model.group_offsets[g + 1] - model.group_offsets[g];
    if (sg.count > 0) {
      sg.first = model.group_particles[model.group_offsets[g]];
      for (Index o = 0; o < sg.count; ++o)
        if (model.group_particles[model.group_offsets[g] + o] != sg.first + o) sg.first = -1;
    }
    Real edges = 0;
    Vec3 lo = Vec3::Constant(std::numeric_limits<Real>::infinity()), hi = -lo;
    for (Index t = 0; t < static_cast<Index>(model.triangles.size()); ++t) {
      const Triangle& tri = model.triangles[t];
      if (model.group[tri[0]] != g) continue;
      sg.triangles.push_back(t);
      for (int e = 0; e < 3; ++e) {
        edges += (model.rest_positions.col(tri[e]) - model.rest_positions.col(tri[(e + 1) % 3])).norm();
        lo = lo.cwiseMin(model.rest_positions.col(tri[e]));
        hi = hi.cwiseMax(model.rest_positions.col(tri[e]));
      }
    }
    // A layer thicker than the cloth is wide puts every triangle near every particle: the broad
    // phase's work would grow as their product each sub-step. Refused by name.
    if (!sg.triangles.empty() && h_self > (hi - lo).norm())
      throw InvalidArgument("the self-collision thickness " + str(h_self) + " m of group '" + model.group_names[g] +
                            "' exceeds the size of its cloth (" + str((hi - lo).norm()) +
                            " m, its rest bounding-box diagonal): give a thickness of the order of the cloth's "
                            "thickness, well under its edges");
    sg.size = (hi - lo).norm();
    sg.edge = edges / (3.0 * std::max<std::size_t>(sg.triangles.size(), 1));
    sg.cell = 1.5 * (sg.edge + 2 * h_self);
    for (const Index t : sg.triangles)
      for (int e = 0; e < 3; ++e) {
        const Index a = model.triangles[t][e], b = model.triangles[t][(e + 1) % 3];
        sg.edges.push_back({std::min(a, b), std::max(a, b)});
      }
    std::sort(sg.edges.begin(), sg.edges.end());
    sg.edges.erase(std::unique(sg.edges.begin(), sg.edges.end()), sg.edges.end());
    // Owners (the first triangle holding a particle or an edge), for the candidate search.
    {
      const Index T = static_cast<Index>(sg.triangles.size());
      std::vector<Index> particle_owner(n, -1), edge_owner(sg.edges.size(), -1);
      for (Index t = 0; t < T; ++t)
        for (int e = 0; e < 3; ++e) {
          const Index a = model.triangles[sg.triangles[t]][e], b = model.triangles[sg.triangles[t]][(e + 1) % 3];
          if (particle_owner[a] < 0) particle_owner[a] = t;
          const std::array<Index, 2> key{std::min(a, b), std::max(a, b)};
          const auto k = std::lower_bound(sg.edges.begin(), sg.edges.end(), key) - sg.edges.begin();
          if (edge_owner[k] < 0) edge_owner[k] = t;
        }
      sg.owned_particle_start.assign(T + 1, 0);
      sg.owned_edge_start.assign(T + 1, 0);
      for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
        const Index i = model.group_particles[o];
        if (particle_owner[i] >= 0)
          ++sg.owned_particle_start[particle_owner[i] + 1];
        else
          sg.loose.push_back(i);
      }
      for (const Index t : edge_owner) ++sg.owned_edge_start[t + 1];
      for (Index t = 0; t < T; ++t) {
        sg.owned_particle_start[t + 1] += sg.owned_particle_start[t];
        sg.owned_edge_start[t + 1] += sg.owned_edge_start[t];
      }
      sg.owned_particles.resize(sg.owned_particle_start[T]);
      sg.owned_edges.resize(sg.owned_edge_start[T]);
      std::vector<Index> at(sg.owned_particle_start.begin(), sg.owned_particle_start.end() - 1);
      for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
        const Index i = model.group_particles[o];
        if (particle_owner[i] >= 0) sg.owned_particles[at[particle_owner[i]]++] = i;
      }
      at.assign(sg.owned_edge_start.begin(), sg.owned_edge_start.end() - 1);
      for (Index k = 0; k < static_cast<Index>(edge_owner.size()); ++k) sg.owned_edges[at[edge_owner[k]]++] = k;
      // The hierarchy: the triangles split near the median of their rest centroids along the
      // longest side of their box, recursively (ties by index: the same tree on every run), at the
      // widest gap between consecutive centroids in the middle half. On a grid that is between two
      // rows or columns of quads: a cut through the quads, separating each quad's two triangles,
      // leaves a sawtooth boundary whose back steps no point sees from inside, and no node below
      // one that fails could then be certified (certify_node's star test). The 80 x 80 cape's
      // nodes below a failed root did not certify, down to three triangles, and their pairs were
      // searched and checked on every sub-step: its steps averaged 36.5 ms with the median cut
      // and 9.4-12.7 with this one (3.0 without self-collision; XPBD, 10 x 1, frames 30-90).
      std::vector<Vec3> centroid(T);
      for (Index t = 0; t < T; ++t) {
        const Triangle& tri = model.triangles[sg.triangles[t]];
        centroid[t] = (model.rest_positions.col(tri[0]) + model.rest_positions.col(tri[1]) +
                       model.rest_positions.col(tri[2])) / 3;
      }
      std::vector<Index> order(T);
      for (Index t = 0; t < T; ++t) order[t] = t;
      sg.bvh_child.clear();
      sg.bvh_size.clear();
      sg.bvh_begin.clear();
      const auto build = [&](auto&& self, Index begin, Index end) -> Index {
        const Index node = static_cast<Index>(sg.bvh_child.size());
        sg.bvh_child.push_back({-1 - order[begin], -1});
        sg.bvh_size.push_back(end - begin);
        sg.bvh_begin.push_back(begin);
        if (end - begin == 1) return node;
        Vec3 lo = centroid[order[begin]], hi = lo;
        for (Index k = begin; k < end; ++k) lo = lo.cwiseMin(centroid[order[k]]), hi = hi.cwiseMax(centroid[order[k]]);
        int axis;
        (hi - lo).maxCoeff(&axis);
        const auto less = [&](Index u, Index v) {
          return centroid[u][axis] < centroid[v][axis] || (centroid[u][axis] == centroid[v][axis] && u < v);
        };
        // The cut: among the middle half of the ranks, where the next centroid along the axis is
        // farthest; of the gaps within a millionth of the widest (equal but for rounding), the one
        // nearest the median, then the lower rank. Only the ranks around the window are ordered:
        // [from - 1, to] sorted, the rest partitioned about them.
        const Index count = end - begin, median = begin + count / 2;
        const Index from = begin + std::max<Index>(1, count / 4), to = begin + std::min<Index>(count - 1, count - count / 4);
        std::nth_element(order.begin() + begin, order.begin() + (from - 1), order.begin() + end, less);
        std::nth_element(order.begin() + from, order.begin() + to, order.begin() + end, less);
        std::sort(order.begin() + from, order.begin() + to, less);
        const auto gap = [&](Index k) { return centroid[order[k]][axis] - centroid[order[k - 1]][axis]; };
        Real widest = 0;
        for (Index k = from; k <= to; ++k) widest = std::max(widest, gap(k));
        Index mid = -1;  // set: the widest gap is within a millionth of itself
        for (Index k = from; k <= to; ++k)
          if (gap(k) >= (1 - 1e-6) * widest && (mid < 0 || std::abs(k - median) < std::abs(mid - median))) mid = k;
        const Index left = self(self, begin, mid);
        const Index right = self(self, mid, end);
        sg.bvh_child[node] = {left, right};
        return node;
      };
      if (T > 0) build(build, 0, T);
      sg.bvh_order = std::move(order);  // each node's triangles are a run of it
      sg.bvh_corners.resize(T);
      for (Index i = 0; i < T; ++i) sg.bvh_corners[i] = model.triangles[sg.triangles[sg.bvh_order[i]]];
      sg.bvh_across.clear();
      if (sg.first >= 0 && T >= sg.count) {  // a node may be large enough to project (certify_patch)
        sg.bvh_across.resize(T);
        for (Index i = 0; i < T; ++i)
          for (int e = 0; e < 3; ++e) sg.bvh_across[i][e] = 2 * (sg.bvh_corners[i][e] - sg.first);
      }
      find_patches(sg);
      sg.union_of.assign(sg.bvh_child.size(), {});
      // The nodes' rest boxes, children after their parent in preorder: refitted from the end.
      const Index nodes = static_cast<Index>(sg.bvh_child.size());
      sg.rest_lo.resize(nodes);
      sg.rest_hi.resize(nodes);
      for (Index k = nodes - 1; k >= 0; --k) {
        const auto& c = sg.bvh_child[k];
        if (c[0] < 0) {
          const Triangle& tri = model.triangles[sg.triangles[-1 - c[0]]];
          sg.rest_lo[k] = sg.rest_hi[k] = model.rest_positions.col(tri[0]);
          for (int e = 1; e < 3; ++e)
            sg.rest_lo[k] = sg.rest_lo[k].cwiseMin(model.rest_positions.col(tri[e])),
            sg.rest_hi[k] = sg.rest_hi[k].cwiseMax(model.rest_positions.col(tri[e]));
        } else {
          sg.rest_lo[k] = sg.rest_lo[c[0]].cwiseMin(sg.rest_lo[c[1]]);
          sg.rest_hi[k] = sg.rest_hi[c[0]].cwiseMax(sg.rest_hi[c[1]]);
        }
      }
    }
    most_triangles = std::max({most_triangles, sg.triangles.size(), sg.edges.size()});
    groups_.push_back(std::move(sg));
  }
  stamps_.assign(most_triangles, 0);
  stamp_ = 0;
  stopped_.assign(n, 0);
}

void SelfCollision::set_threads(int threads, Fork fork) {
  threads_ = threads;
  fork_ = std::move(fork);
}

std::size_t SelfCollision::bytes() const {
  const auto b = [](const auto& v) { return v.capacity() * sizeof(typename std::decay_t<decltype(v)>::value_type); };
  const auto positions = [](const Positions& m) { return static_cast<std::size_t>(m.size()) * sizeof(Real); };
  std::size_t s = 0;
  for (const Group& g : groups_)
    s += b(g.triangles) + b(g.edges) + b(g.pt) + b(g.ee) + b(g.owned_particle_start) + b(g.owned_particles) +
         b(g.owned_edge_start) + b(g.owned_edges) + b(g.loose) + b(g.bvh_child) + b(g.bvh_size) + b(g.bvh_order) +
         b(g.bvh_begin) + b(g.bvh_corners) + b(g.bvh_across) + b(g.patch_start) + b(g.patch_edges) + b(g.is_patch) + b(g.deferred) + b(g.failed) + b(g.axis) + b(g.carry) +
         b(g.tri_lo) + b(g.tri_hi) + b(g.node_lo) + b(g.node_hi) + b(g.unions) + b(g.deferred_unions) + b(g.union_of) + b(g.rest_lo) + b(g.rest_hi);
  for (const Group& g : groups_) {
    for (const Group::Union& u : g.unions) s += b(u.corners) + b(u.boundary);
    for (const auto& known : g.union_of) s += b(known);
  }
  s += b(contacts_) + b(impacts_) + b(box_lo_) + b(box_hi_) + b(edge_lo_) + b(edge_hi_) +
       b(node_pairs_) + b(stopped_) + b(stamps_) + b(tests_parts_) + b(culled_parts_) + b(certified_) + b(across_x_) + b(across_p_) +
       b(move2_) + positions(end_p_) + positions(hold_lo_) + positions(hold_hi_) + positions(particle_lo_) + positions(particle_hi_) +
       positions(sweep_lo_) + positions(sweep_hi_);
  for (const auto& v : impact_parts_) s += b(v);
  for (const auto& v : contact_parts_) s += b(v);
  return s;
}

// The patches of a group's hierarchy (static: the mesh's connectivity). Node k's triangles form a
// patch if they are a topological disc, consistently oriented: no directed edge twice (an
// inconsistent orientation or an edge of three triangles), the edges without their reverse (the
// boundary) forming one loop through distinct vertices, and V - E + F = 1. Its boundary loop is
// kept, each edge directed as in its triangle (counter-clockwise about the triangles' normals).
// Leaves (one triangle) hold no pair and are not patches.
void SelfCollision::find_patches(Group& g) {
  const Index nodes = static_cast<Index>(g.bvh_child.size());
  g.patch_start.assign(1, 0);
  g.patch_edges.clear();
  g.is_patch.assign(nodes, 0);
  DiscScratch scratch;
  for (Index k = 0; k < nodes; ++k) {
    if (g.bvh_size[k] >= 2)
      g.is_patch[k] = disc_boundary(g.bvh_corners.data() + g.bvh_begin[k], g.bvh_size[k], g.patch_edges, scratch);
    g.patch_start.push_back(static_cast<Index>(g.patch_edges.size()));
  }
}

// Whether the triangles tri[0 .. size) form a topological disc, consistently oriented (see
// find_patches); if so its boundary loop, each edge directed as in its triangle, is appended to
// loop (else loop is left as it was).
bool SelfCollision::disc_boundary(const Triangle* tri, Index size, std::vector<std::array<Index, 2>>& loop,
                                  DiscScratch& s) {
  // The vertices numbered locally, and each one's directed edges by counting: linear in the
  // triangles (a vertex has a few). Sorting the edges instead, the step where the 40 x 40 cape
  // first folds (the unions its search meets there each tested) took 5.1 ms against 0.8 for a
  // step without the fold; it now takes 1.7.
  auto& local = s.local;
  auto& vertices = s.vertices;
  vertices.clear();
  for (Index i = 0; i < size; ++i)
    for (const Index v : tri[i]) {
      if (static_cast<std::size_t>(v) >= local.size()) local.resize(static_cast<std::size_t>(v) + 1, -1);
      if (local[v] < 0) local[v] = static_cast<Index>(vertices.size()), vertices.push_back(v);
    }
  const Index V = static_cast<Index>(vertices.size());
  auto& start = s.start;
  auto& out = s.out;
  start.assign(static_cast<std::size_t>(V) + 2, 0);
  for (Index i = 0; i < size; ++i)
    for (const Index v : tri[i]) ++start[local[v] + 2];
  for (Index v = 0; v < V; ++v) start[v + 2] += start[v + 1];
  out.resize(3 * static_cast<std::size_t>(size));
  for (Index i = 0; i < size; ++i)
    for (int e = 0; e < 3; ++e) out[start[local[tri[i][e]] + 1]++] = local[tri[i][(e + 1) % 3]];
  // start[v] .. start[v + 1] now holds v's ends. No directed edge twice; a directed edge whose
  // reverse is in the set is interior (each interior edge counted twice), else on the boundary,
  // and each boundary vertex starts one boundary edge (next).
  auto& next = s.next;
  next.assign(V, -1);
  bool disc = true;
  Index interior = 0, boundary = 0;
  for (Index a = 0; a < V && disc; ++a)
    for (Index k = start[a]; k < start[a + 1]; ++k) {
      const Index b = out[k];
      for (Index j = start[a]; j < k; ++j) disc = disc && out[j] != b;
      bool reverse = false;
      for (Index j = start[b]; j < start[b + 1]; ++j) reverse = reverse || out[j] == a;
      if (reverse) {
        ++interior;
      } else {
        disc = disc && next[a] < 0;
        next[a] = b, ++boundary;
      }
    }
  for (const Index v : vertices) local[v] = -1;
  const Index E = interior / 2 + boundary;
  disc = disc && boundary > 0 && V - E + size == 1;
  if (!disc) return false;
  // One loop: following the boundary edges from the one whose start is the least particle returns
  // to it after visiting them all, not before (two loops of one length would otherwise pass).
  // Each edge is directed as in its triangle.
  Index first = -1;
  for (Index v = 0; v < V; ++v)
    if (next[v] >= 0 && (first < 0 || vertices[v] < vertices[first])) first = v;
  const std::size_t at_start = loop.size();
  Index at = first;
  for (Index n = 0; n < boundary; ++n) {
    loop.push_back({vertices[at], vertices[next[at]]});
    at = next[at];
    if (next[at] < 0 || (at == first && n + 1 < boundary)) {
      disc = false;
      break;
    }
  }
  disc = disc && at == first;
  if (!disc) loop.resize(at_start);
  return disc;
}

// Whether node k, a patch, has no self-intersection at any time of the motion x -> p (each
// particle on its straight line), after Volino and Magnenat-Thalmann (1994) with the star test of
// Schvartzman, Pérez and Otaduy (2010), both for a moving patch. With V an axis (the sum of the
// patch's normals when last computed) and O a point fixed over the motion (the centroid of the
// boundary's projected area at x, or of its vertices):
//  - every triangle's normal n(s) = (b - a) x (c - a), a quadratic in s over [0, 1], has
//    V·n(s) > 0: its three Bernstein coefficients are positive along V. The
//    projection along V onto a plane then keeps each triangle's orientation at every s;
//  - every boundary edge (a, b) keeps ((a - O) x (b - O))·V > 0, again a quadratic whose three
//    Bernstein coefficients are positive: the projected boundary turns monotonically about O;
//  - at s = 0 a ray from O crosses the projected boundary once: it winds once about O, and so
//    (its angle about O only increasing, no edge ever reaching O) at every s.
// The projected boundary is then a simple closed curve at every s and, every triangle keeping its
// orientation, each point inside it has exactly one preimage in the patch (the projection's
// degree): the projection is one-to-one and no two points of the patch meet. A pair of features
// inside a certified patch cannot meet during the motion, and neither can one inside any part of
// it. Each sign is taken with a margin of 1e-9 of its scale (the squared size of the node's box
// times |V|), far above the products' rounding, so that rounding never certifies.
bool SelfCollision::certify_node(Group& g, Index k, const Positions& x, const Positions& p, bool sub_step) {
  const PatchView view{g.bvh_corners.data() + g.bvh_begin[k],
                       g.bvh_size[k],
                       g.patch_edges.data() + g.patch_start[k],
                       g.patch_start[k + 1] - g.patch_start[k],
                       (g.node_hi[k] - g.node_lo[k]).squaredNorm(),
                       g.first >= 0 && 4 * g.bvh_size[k] >= g.count ? g.bvh_across.data() + g.bvh_begin[k] : nullptr,
                       g.axis[k],
                       g.carry[k]};
  return certify_patch(g, view, x, p, sub_step);
}

// The test above for any patch: a node, or the union of two (certify_union).
bool SelfCollision::certify_patch(Group& g, const PatchView& v, const Positions& x, const Positions& p, bool sub_step) {
  const Triangle* tri = v.tri;
  const Index size = v.size;
  const auto corners = [&](Index i, Vec3& e0, Vec3& f0, Vec3& e1, Vec3& f1) {
    const Triangle& t = tri[i];
    e0 = x.col(t[1]) - x.col(t[0]), f0 = x.col(t[2]) - x.col(t[0]);
    e1 = p.col(t[1]) - p.col(t[0]), f1 = p.col(t[2]) - p.col(t[0]);
  };
  // V: the axis kept from the node's last certification (any V serves the proof), else the sum
  // of its normals at x; a kept axis that fails is replaced by that sum and tried once more.
  Vec3& V = v.axis;
  bool fresh = false;
  const auto renew_axis = [&] {
    V.setZero();
    Vec3 e0, f0, e1, f1;
    for (Index i = 0; i < size; ++i) corners(i, e0, f0, e1, f1), V += e0.cross(f0);
    fresh = true;
    v.carry.at = 0;
  };
  if (V.isZero(0)) renew_axis();
  const Real box2 = v.box2;
  const auto* edges = v.edges;
  const Index m = v.m;
  // The boundary about O: every edge's signed area positive over the motion, and a ray from O
  // crossing it once at s = 0. Keeps O and the least signed area at the end for the next sub-step.
  Vec3 origin = Vec3::Zero();
  Real least_boundary = 0;
  const auto star_about = [&](const Vec3& O, Real margin) {
    const Vec3 u = (std::abs(V.x()) < std::abs(V.y()) ? Vec3::UnitX().cross(V) : Vec3::UnitY().cross(V)).normalized();
    const Vec3 w = V.cross(u);  // u, w: two axes of the plane across V, for the ray's crossings
    int crossings = 0;
    Real least = std::numeric_limits<Real>::infinity();
    for (Index i = 0; i < m; ++i) {
      const Vec3 a0 = x.col(edges[i][0]) - O, b0 = x.col(edges[i][1]) - O;
      const Vec3 a1 = p.col(edges[i][0]) - O, b1 = p.col(edges[i][1]) - O;
      const Real end = a1.cross(b1).dot(V);
      if (!(a0.cross(b0).dot(V) > margin && end > margin && (a0.cross(b1) + a1.cross(b0)).dot(V) > 2 * margin))
        return false;
      least = std::min(least, end);
      const Real ay = a0.dot(w), by = b0.dot(w);
      if ((ay > 0) != (by > 0)) {
        const Real ax = a0.dot(u), bx = b0.dot(u);
        if (ax + (0 - ay) * (bx - ax) / (by - ay) > 0) ++crossings;
      }
    }
    if (crossings != 1) return false;
    origin = O, least_boundary = least;
    return true;
  };
  // O: the centroid of the boundary's area projected along V at x (a notch of the boundary
  // near its vertices' centroid, common in the hierarchy's small nodes, turned most of the
  // tests down about that centroid), else the vertices' centroid.
  const auto star = [&](Real margin) {
    Vec3 R = Vec3::Zero();
    for (Index i = 0; i < m; ++i) R += x.col(edges[i][0]);
    R /= static_cast<Real>(m);
    Real area = 0;
    Vec3 moment = Vec3::Zero();
    for (Index i = 0; i < m; ++i) {
      const Vec3 a = x.col(edges[i][0]) - R, b = x.col(edges[i][1]) - R;
      const Real ai = a.cross(b).dot(V);
      area += ai;
      moment += ai * (a + b);
    }
    if (area > 0 && star_about(R + moment / (3 * area), margin)) return true;
    return star_about(R, margin);
  };
  // The tests carried from the last sub-step (below) bound how far the patch's particles moved
  // by step2, the largest |p - x|² of its own particles (the group's for a node the size of the
  // group). With the group's largest, the nodes and unions of a cape that folds, where a few
  // particles move fast, turned most of their carried tests down (481 of 663 on the 80 x 80
  // cape's frames 75-90) and took the full test instead, at twice the cost. With the patch's own,
  // the full tests' triangles on those frames fell from 1.8 to 1.1 million, and the nodes' and
  // unions' certifications from 86 to 52 million cycles.
  const bool carry = sub_step && g.carried && v.carry.at + 1 == g.serial;  // (re-read in the loop below)
  Real step2 = g.step2;
  if (carry && !(v.across && size >= g.count)) {
    // Six running maximums (two triangles' three corners), not one chain of dependent maximums: a
    // single chain was a quarter of the certifications' time on the 40 x 40 cape's folding steps.
    // A NaN is left out, as in certify.
    Real most[2][3] = {};
    Index i = 0;
    for (; i + 2 <= size; i += 2)
      for (int h = 0; h < 2; ++h)
        for (int e = 0; e < 3; ++e) most[h][e] = std::max(most[h][e], move2_[tri[i + h][e]]);
    for (; i < size; ++i)
      for (int e = 0; e < 3; ++e) most[0][e] = std::max(most[0][e], move2_[tri[i][e]]);
    step2 = 0;
    for (int h = 0; h < 2; ++h)
      for (int e = 0; e < 3; ++e) step2 = std::max(step2, most[h][e]);
  }
  // A sub-step that starts where the last one ended, the boundary certified then about O with
  // this axis: each edge's signed area about O at the start is its area at that sub-step's end, at
  // least end_boundary, and only the end's is computed. The middle coefficient, (a0 x b1 + a1 x
  // b0)·V = c0 + c2 - ((a1 - a0) x (b1 - b0))·V, with a1 - a0 and b1 - b0 the moves of two
  // particles of the patch (each at most √step2 long), stays above 2 margin when c0 and c2 are
  // above margin + |V| step2. No ray is needed: the areas stayed positive over the last sub-step,
  // so O never met the boundary and the boundary still winds once about it, every crossing of a
  // ray from O being in the same sense.
  const auto carried_star = [&](Real margin) {
    const Real need = margin + V.norm() * step2 * (1 + 1e-12);
    if (!(v.carry.end_boundary > need)) return false;
    const Vec3 O = v.carry.origin;
    Real least = std::numeric_limits<Real>::infinity();
    for (Index i = 0; i < m; ++i) {
      const Vec3 a1 = p.col(edges[i][0]) - O, b1 = p.col(edges[i][1]) - O;
      const Real end = a1.cross(b1).dot(V);
      if (!(end > need)) return false;  // false for NaN
      least = std::min(least, end);
    }
    origin = O, least_boundary = least;
    return true;
  };
  Real least_end = 0;  // the least V·(e x f) at p, for the next sub-step
  // A node of at least a quarter as many triangles as its group has particles (a cloth, with
  // about twice as many triangles as particles: the root and the two levels below it), the group
  // one run: the group's particles are projected once onto the plane across V, along unit axes U
  // and W with U x W = V/|V|, and a triangle's V·(e x f) is |V| times the 2D cross product of its
  // projected sides, two coordinates a corner and no cross product in 3D. (The rounding of either
  // form is some 1e-16 of |V| |e| |f|, far below the margin.) With the root alone taking it, the
  // cape's median step with self-collision went from 1.51 to 1.43 times the step without at
  // 40 x 40 and from 1.70 to 1.48 at 80 x 80 (XPBD, 10 x 1, frames 30-90, nine and three
  // alternating rounds). Below the root, the projection (some 1.3 cycles a particle in AVX2
  // lanes) costs less than the 3D form's 13 cycles a triangle save once a node has a quarter as
  // many triangles as the group has particles: the 40 x 40 cape's fifteen dearest steps of
  // frames 30-90, where it folds, went from 1.43-1.46 to 1.32-1.42 times its median step, the
  // 80 x 80 cape's from 2.29-2.35 to 2.25-2.28 (three alternating runs).
  const std::array<Index, 3>* across = v.across;
  const auto project = [&](const Positions& y, std::vector<Real>& out) {
    const Vec3 U = (std::abs(V.x()) < std::abs(V.y()) ? Vec3::UnitX().cross(V) : Vec3::UnitY().cross(V)).normalized();
    const Vec3 W = V.normalized().cross(U);
    out.resize(2 * static_cast<std::size_t>(g.count));
    project_across(y.data() + 3 * g.first, g.count, U, W, out.data());
    return static_cast<const Real*>(out.data());
  };
  // The sides e = b - a and f = c - a of the triangles [i0, i0 + n) at positions y, by coordinate,
  // for the blocks of B triangles below.
  constexpr Index B = 16;
  const auto sides = [&](const Positions& y, Index i0, Index n, Real (&e)[3][B], Real (&f)[3][B]) {
    for (Index j = 0; j < n; ++j) {
      const Triangle& t = tri[i0 + j];
      for (int d = 0; d < 3; ++d) e[d][j] = y(d, t[1]) - y(d, t[0]), f[d][j] = y(d, t[2]) - y(d, t[0]);
    }
  };
  // A sub-step that starts where the last one ended, the node certified then with this axis:
  // V·n(0) is that sub-step's V·n(1), at least carry.end_normal, and only V·n(1) = V·(e1 x f1) is
  // computed. The middle coefficient is (c0 + c2 - V·((e1 - e0) x (f1 - f0)))/2, and each of
  // e1 - e0 and f1 - f0 is at most 2 √step2 long: c0 and c2 above margin + 2 |V| step2 keep it
  // above the margin.
  const auto carried_normals = [&](Real margin) {
    const Real need = margin + 2 * V.norm() * step2 * (1 + 1e-12);
    if (!(v.carry.end_normal > need)) return false;
    if (across) return areas_above(across, size, project(p, across_p_), V.norm(), need, least_end);
    alignas(64) Real e[3][B], f[3][B];
    alignas(64) Real end[B];
    least_end = std::numeric_limits<Real>::infinity();
    for (Index i0 = 0; i0 < size; i0 += B) {
      const Index n = std::min(B, size - i0);
      sides(p, i0, n, e, f);
      const Real vx = V.x(), vy = V.y(), vz = V.z();
      for (Index j = 0; j < n; ++j) {
        const Real bx = vy * e[2][j] - vz * e[1][j], by = vz * e[0][j] - vx * e[2][j], bz = vx * e[1][j] - vy * e[0][j];
        end[j] = bx * f[0][j] + by * f[1][j] + bz * f[2][j];
      }
      unsigned char all = 1;
      for (Index j = 0; j < n; ++j) all &= end[j] > need, least_end = std::min(least_end, end[j]);
      if (!all) return false;  // false for NaN too
    }
    return true;
  };
  // V·n(s) over the motion, by its Bernstein coefficients: V·(e0 x f0), V·(e0 x f1 + e1 x f0)/2
  // and V·(e1 x f1), each V·(a x b) taken as (V x a)·b. In blocks: the corners gathered, then the
  // arithmetic, then the signs.
  const auto normals = [&](Real margin) {
    if (across) {
      const Real scale = V.norm();
      const Real *X = project(x, across_x_), *P = project(p, across_p_);
      Real least = std::numeric_limits<Real>::infinity();
      bool all = true;
      constexpr Index kRun = 256;  // the verdict looked at every kRun triangles
      for (Index i = 0; i < size && all;) {
        for (const Index last = std::min(size, i + kRun); i < last; ++i) {
          const auto [i0, i1, i2] = across[i];
          const Real ex0 = X[i1] - X[i0], ex1 = X[i1 + 1] - X[i0 + 1], fx0 = X[i2] - X[i0], fx1 = X[i2 + 1] - X[i0 + 1];
          const Real ep0 = P[i1] - P[i0], ep1 = P[i1 + 1] - P[i0 + 1], fp0 = P[i2] - P[i0], fp1 = P[i2 + 1] - P[i0 + 1];
          const Real c0 = (ex0 * fx1 - ex1 * fx0) * scale, c2 = (ep0 * fp1 - ep1 * fp0) * scale;
          const Real c1 = ((ex0 * fp1 - ex1 * fp0) + (ep0 * fx1 - ep1 * fx0)) * scale;
          all &= (c0 > margin) & (c1 > 2 * margin) & (c2 > margin);  // false for NaN
          least = std::min(least, c2);
        }
      }
      least_end = least;
      return all;
    }
    alignas(64) Real e[2][3][B], f[2][3][B];  // [at x, at p][coordinate][triangle of the block]
    alignas(64) unsigned char pass[B];
    alignas(64) Real end[B];
    least_end = std::numeric_limits<Real>::infinity();
    for (Index i0 = 0; i0 < size; i0 += B) {
      const Index n = std::min(B, size - i0);
      sides(x, i0, n, e[0], f[0]);
      sides(p, i0, n, e[1], f[1]);
      for (Index j = n; j < B; ++j)  // the block's tail: a triangle that passes
        for (int d = 0; d < 3; ++d) e[0][d][j] = e[1][d][j] = f[0][d][j] = f[1][d][j] = 0;
      const Real vx = V.x(), vy = V.y(), vz = V.z();
      for (Index j = 0; j < B; ++j) {
        // V x e at x and at p (Eigen's cross), then the three coefficients against their margins.
        const Real ax = vy * e[0][2][j] - vz * e[0][1][j], ay = vz * e[0][0][j] - vx * e[0][2][j],
                   az = vx * e[0][1][j] - vy * e[0][0][j];
        const Real bx = vy * e[1][2][j] - vz * e[1][1][j], by = vz * e[1][0][j] - vx * e[1][2][j],
                   bz = vx * e[1][1][j] - vy * e[1][0][j];
        const Real c0 = ax * f[0][0][j] + ay * f[0][1][j] + az * f[0][2][j];
        const Real c1 = (ax * f[1][0][j] + ay * f[1][1][j] + az * f[1][2][j]) +
                        (bx * f[0][0][j] + by * f[0][1][j] + bz * f[0][2][j]);
        const Real c2 = bx * f[1][0][j] + by * f[1][1][j] + bz * f[1][2][j];
        pass[j] = (c0 > margin) & (c1 > 2 * margin) & (c2 > margin);  // false for NaN
        end[j] = c2;
      }
      unsigned char all = 1;
      for (Index j = 0; j < n; ++j) all &= pass[j], least_end = std::min(least_end, end[j]);
      if (!all) return false;
    }
    return true;
  };
  // The boundary first: it is the cheaper test (a patch's boundary edges against its triangles),
  // and the one that fails most.
  for (;;) {
    const Real margin = 1e-9 * box2 * V.norm();
    if (!(margin > 0)) return false;  // NaN, or a collapsed patch
    // (A renewed axis clears carry.at: what was carried holds for the old axis only.)
    const bool carried = carry && v.carry.at + 1 == g.serial;
    if (((carried && carried_star(margin)) || star(margin)) &&
        ((carried && carried_normals(margin)) || normals(margin))) {
      if (sub_step) v.carry = {g.serial, least_end, least_boundary, origin};
      return true;
    }
    if (fresh) return false;
    renew_axis();
  }
}

// certified_[k]: node k or one of its ancestors is a patch certified for the motion x -> p
// (certify_node), top-down: a node below a certified one needs no test of its own.
// A certification does not try again, for a step's worth of sub-steps, a node that a sub-step
// turned down (g.failed): it would most likely fail again, at the cost of its triangles (two or
// three passes, with a fresh axis), and a certification only spares tests (a node searched because
// it failed stays searched). Tried again after every search instead, the nodes along a fold (the
// root, its children, theirs...) cost the 56 x 56 cape's folding steps some 9,000 triangles a
// sub-step. Deferred nodes are never turned down when searched: the first failure searches them.
void SelfCollision::certify(const Model& model, Group& g, const Positions& x, const Positions& p, bool sub_step) {
  const Index nodes = static_cast<Index>(g.bvh_child.size());
  if (g.axis.size() != static_cast<std::size_t>(nodes)) g.axis.assign(nodes, Vec3::Zero());
  if (g.failed.size() != static_cast<std::size_t>(nodes)) g.failed.assign(nodes, 0);
  if (g.carry.size() != static_cast<std::size_t>(nodes)) g.carry.assign(nodes, Group::Carried{});
  if (sub_step) {
    ++g.serial;
    if (move2_.size() != static_cast<std::size_t>(p.cols())) move2_.assign(p.cols(), 0);
    bool same = end_p_.cols() == x.cols();
    Real step2 = 0;
    if (same && g.first >= 0) {
      const Index at = 3 * g.first;
      carry_check(x.data() + at, p.data() + at, end_p_.data() + at, g.count, same, move2_.data() + g.first, step2);
    } else {
      for (Index o = model.group_offsets[g.group]; o < model.group_offsets[g.group + 1]; ++o) {
        const Index i = model.group_particles[o];
        same = same && x.col(i) == end_p_.col(i);
        move2_[i] = (p.col(i) - x.col(i)).squaredNorm();
        step2 = std::max(step2, move2_[i]);
      }
    }
    g.carried = same;
    g.step2 = step2;  // (a NaN in p fails the normals themselves)
  }
  // The nodes are in preorder: node k's subtree is the 2 bvh_size[k] - 1 nodes from k on, all
  // certified with it and skipped.
  certified_.assign(nodes, 0);
  for (Index k = 0; k < nodes;) {
    if (g.is_patch[k] && !(g.failed[k] > 0 && g.serial < g.failed[k] + static_cast<std::uint64_t>(g.substeps))) {
      // A search defers a node that the last sub-step certified without testing it again: the
      // sub-steps decide (resume_deferred), and its proximity contacts wait a sub-step, as
      // when a deferred node fails.
      const bool passed = !sub_step && g.serial > 0 && g.carry[k].at == g.serial;
      if (!passed && k > 0 && !g.boxes_ready) search_boxes(model, g);  // the margin's scale
      if (passed || certify_node(g, k, x, p, sub_step)) {
        const Index end = k + 2 * g.bvh_size[k] - 1;
        std::fill(certified_.begin() + k, certified_.begin() + end, std::uint8_t(1));
        k = end;
        continue;
      }
      if (sub_step) g.failed[k] = g.serial;
    }
    ++k;
  }
  if (sub_step) {
    if (end_p_.cols() != p.cols()) end_p_.resize(3, p.cols());
    if (g.first >= 0)
      std::copy_n(p.data() + 3 * g.first, 3 * g.count, end_p_.data() + 3 * g.first);
    else
      for (Index o = model.group_offsets[g.group]; o < model.group_offsets[g.group + 1]; ++o)
        end_p_.col(model.group_particles[o]) = p.col(model.group_particles[o]);
  }
}

// Runs chunk(t, T) for t = 0 .. T - 1 on the stepper's team, T its threads when the work (n
// pairs) is large enough to pay for a fork, else 1; impact_parts_, contact_parts_ and tests_parts_ are sized
// for T. Chunk t takes the t-th of T equal runs of each list and writes only its own part; the
// caller joins the parts in t's order, so the result is the same for any T. Returns T.
template <class F>
int SelfCollision::in_chunks(std::size_t n, F&& chunk) {
  const int T = threads_ > 1 && fork_ && n >= kParallelPairs ? threads_ : 1;
  if (impact_parts_.size() < 2 * static_cast<std::size_t>(T)) impact_parts_.resize(2 * T);
  if (contact_parts_.size() < static_cast<std::size_t>(T)) contact_parts_.resize(T);
  if (tests_parts_.size() < static_cast<std::size_t>(T)) tests_parts_.resize(T), culled_parts_.resize(T);
  const auto job = [&](int t) { chunk(t, T); };
  if (T == 1)
    job(0);
  else
    fork_(T, job);
  return T;
}

// The candidate pairs of a group, found once per step and kept while they hold. Each particle gets
// a box: over its start x, its prediction p and where the prediction leads in a step's time
// (x + k (p - x), k the sub-steps of a step, but no farther than kLookaheadEdges mean edges; not
// beyond the cloth's size), widened by 1.5 h on each side. A feature's box is the union of its
// particles'; a pair is kept if its boxes overlap, the features share no particle, and one of its
// particles can move.
//
// The pairs hold for a sub-step as long as every particle's x and p lie in its box shrunk by h
// (candidates_hold; h/2 of slack for the path to bend away from the straight line): then
// the features' swept boxes over x -> p, widened by h, lie in their boxes, so every pair that can
// touch during the sub-step (swept boxes overlapping) or is within 2h at the prediction (the
// proximity contacts) is a candidate. When a particle leaves its box (the cloth swung off the
// straight line, or a hard push by the constraints) the pairs are found again from where it is.
// One search a step instead of one a sub-step: the search, not the tests, was most of the cost
// (66 % of a 1,600-particle cape's step at 10 sub-steps); widened by 1.5 h rather than 2 h, the
// boxes overlap less and the cape's step took 7.0-7.7 ms instead of 9.2-11 (2 sub-steps of 5
// iterations, three alternating runs).
void SelfCollision::find_candidates(const Model& model, Group& g, const Positions& x, const Positions& p,
                                    const Real* w, int substeps) {
  const Real pad = kSearchPad * g.thickness;
  const Real ahead = static_cast<Real>(substeps);
  const Real reach = search_reach(g.size, g.thickness);
  const Vec3 inf = Vec3::Constant(std::numeric_limits<Real>::infinity());
  Vec3 all_lo = inf, all_hi = -inf;  // the union of the particles' boxes
  const Real budget = kLookaheadEdges * g.edge;
  for (Index o = model.group_offsets[g.group]; o < model.group_offsets[g.group + 1]; ++o) {
    const Index i = model.group_particles[o];
    const Vec3 xi = x.col(i), pi = p.col(i);
    // The look-ahead: a step's sub-steps of the prediction's motion, no farther than the budget
    // (but at least the sub-step), and only while it stays within the cloth's size (a fast particle
    // searches again).
    Real a = ahead;
    const Real len = (pi - xi).norm();
    if (len * a > budget) a = std::max(Real(1), budget / len);
    Vec3 end = xi + a * (pi - xi);
    if (!((end - xi).cwiseAbs().maxCoeff() <= g.size)) end = pi;
    particle_lo_.col(i) = xi.cwiseMin(pi).cwiseMin(end).array() - pad;
    particle_hi_.col(i) = xi.cwiseMax(pi).cwiseMax(end).array() + pad;
    all_lo = all_lo.cwiseMin(particle_lo_.col(i));
    all_hi = all_hi.cwiseMax(particle_hi_.col(i));
    // The box shrunk by h that x and p must stay in (candidates_hold); a particle left out of the
    // search (see search_boxes) holds anywhere.
    if ((particle_hi_.col(i) - particle_lo_.col(i)).maxCoeff() <= reach) {
      hold_lo_.col(i) = particle_lo_.col(i).array() + g.thickness;
      hold_hi_.col(i) = particle_hi_.col(i).array() - g.thickness;
    } else {
      hold_lo_.col(i) = -inf, hold_hi_.col(i) = inf;
    }
  }
  // The features' boxes and the hierarchy's, for this search and the deferred ones. A cloth within
  // its reach, all its particles in triangles (a smooth cloth's every search), leaves no triangle
  // out and the root's box is the particles': the rest waits until a node is opened (search_boxes).
  const Index nodes = static_cast<Index>(g.bvh_child.size());
  g.node_lo.resize(nodes);
  g.node_hi.resize(nodes);
  g.boxes_ready = false;
  if (nodes > 0 && g.loose.empty() && (all_hi - all_lo).maxCoeff() <= reach) {
    g.skipped = 0;
    g.node_lo[0] = all_lo, g.node_hi[0] = all_hi;
  } else {
    search_boxes(model, g);
  }
  // The patches that cannot meet themselves in the motion x -> p (certify), and the unions of two
  // nodes that are such patches, are not searched inside: their pairs are found when a sub-step's
  // motion no longer certifies them (resume_deferred, resume_unions), each sub-step's
  // certification deciding what is tested. A smooth cloth's search then costs little more than
  // the certification. (Certified for the look-ahead instead, the nodes a whip's longer, bent
  // motion failed were searched, and then culled by the sub-steps that certified them: at
  // 56 x 56 a step kept up to 15,225 pairs, 72 thousand culled in its sub-steps, against 6,929.)
  certify(model, g, x, p, false);
  g.pt.clear();
  g.ee.clear();
  g.deferred.clear();
  g.deferred_unions.clear();
  if (nodes > 0) search_node(model, g, {0, 0, 0}, w, x, p);
  if (!g.loose.empty()) hash_.build(g.cell, g.tri_lo, g.tri_hi);
  for (const Index q : g.loose) {  // particles of the group in no triangle
    if (!((particle_hi_.col(q) - particle_lo_.col(q)).maxCoeff() <= reach)) continue;
    if (++stamp_ == 0) std::fill(stamps_.begin(), stamps_.end(), 0), stamp_ = 1;
    hash_.query(particle_lo_.col(q), particle_hi_.col(q), [&](Index t) {
      if (stamps_[t] == stamp_) return;
      stamps_[t] = stamp_;
      add_point_triangle(model, g, q, t, -1, w);
    });
  }
  g.searched = true;
  ++counts_.searches;
}


// The search's boxes of group g (find_candidates): each triangle's, the union of its particles',
// and the hierarchy's, refitted to them (children come after their parent). A triangle whose box
// spans more than the cloth's rest size (plus the widening) has been torn across the cloth or
// flung beyond it within a step: no contact or continuous test can follow it (the divergence
// guard stops such a step by default). It is left out of this search (an empty box) and counted
// (self_skipped), so that a particle flung 1e12 m away costs one search, not one pair with every
// feature on every sub-step. (The edges' boxes are taken one pair at a time, in search_node.)
void SelfCollision::search_boxes(const Model& model, Group& g) {
  const Real reach = search_reach(g.size, g.thickness);
  const Vec3 inf = Vec3::Constant(std::numeric_limits<Real>::infinity());
  unite_boxes(model, g, particle_lo_, particle_hi_, g.tri_lo, g.tri_hi, nullptr, nullptr);
  g.skipped = 0;
  for (std::size_t t = 0; t < g.triangles.size(); ++t)
    if (!((g.tri_hi[t] - g.tri_lo[t]).maxCoeff() <= reach)) {  // NaN too
      g.tri_lo[t] = inf, g.tri_hi[t] = -inf;
      ++g.skipped;
    }
  const Index nodes = static_cast<Index>(g.bvh_child.size());
  for (Index k = nodes - 1; k >= 0; --k) {
    const auto& c = g.bvh_child[k];
    if (c[0] < 0) {
      g.node_lo[k] = g.tri_lo[-1 - c[0]], g.node_hi[k] = g.tri_hi[-1 - c[0]];
    } else {
      g.node_lo[k] = g.node_lo[c[0]].cwiseMin(g.node_lo[c[1]]);
      g.node_hi[k] = g.node_hi[c[0]].cwiseMax(g.node_hi[c[1]]);
    }
  }
  g.boxes_ready = true;
}

// The candidate pairs inside node `root` (all of them from the root): the hierarchy traversed
// against itself from (root, root) with the search's boxes; a node certified (certified_) is not
// entered but marked deferred. One search, of triangle pairs, gives both kinds: a particle's box
// lies in its owner triangle's, an edge's in its owner's (the first triangle of the group holding
// it), so a particle-triangle or edge-edge pair whose boxes overlap has owners whose boxes
// overlap; each pair is taken from its owners' pair only, so none comes twice. A node with itself
// gives its children with themselves and with each other; two nodes whose boxes overlap give the
// pairs of their children (the one holding more triangles is opened). Every overlapping pair of
// leaves comes once, in an order fixed by the tree.
void SelfCollision::search_node(const Model& model, Group& g, const std::array<Index, 3>& start, const Real* w,
                                const Positions& x, const Positions& q) {
  const auto point_triangle = [&](Index q, Index t, Index lca) { add_point_triangle(model, g, q, t, lca, w); };
  // An edge's search box, the union of its particles'; false for one left out of the search (see
  // find_candidates).
  const Real reach = search_reach(g.size, g.thickness);
  const auto edge_box = [&](const std::array<Index, 2>& e, Vec3& lo, Vec3& hi) {
    lo = particle_lo_.col(e[0]).cwiseMin(particle_lo_.col(e[1]));
    hi = particle_hi_.col(e[0]).cwiseMax(particle_hi_.col(e[1]));
    return (hi - lo).maxCoeff() <= reach;
  };
  const auto edge_edge = [&](Index a, Index b, Index lca) {
    const auto& ea = g.edges[a];
    const auto& eb = g.edges[b];
    if (ea[0] == eb[0] || ea[0] == eb[1] || ea[1] == eb[0] || ea[1] == eb[1]) return;
    Vec3 lo_a, hi_a, lo_b, hi_b;
    if (!edge_box(ea, lo_a, hi_a) || !edge_box(eb, lo_b, hi_b) || !boxes_overlap(lo_a, hi_a, lo_b, hi_b)) return;
    if (w[ea[0]] + w[ea[1]] + w[eb[0]] + w[eb[1]] <= 0) return;
    g.ee.push_back({std::min(a, b), std::max(a, b), lca});
  };
  // lca: the node whose self-pair the leaves' pair descends from, the smallest holding both.
  const auto leaf_pair = [&](Index t1, Index t2, Index lca) {
    for (Index k = g.owned_particle_start[t1]; k < g.owned_particle_start[t1 + 1]; ++k)
      point_triangle(g.owned_particles[k], t2, lca);
    for (Index k = g.owned_particle_start[t2]; k < g.owned_particle_start[t2 + 1]; ++k)
      point_triangle(g.owned_particles[k], t1, lca);
    for (Index i = g.owned_edge_start[t1]; i < g.owned_edge_start[t1 + 1]; ++i)
      for (Index j = g.owned_edge_start[t2]; j < g.owned_edge_start[t2 + 1]; ++j)
        edge_edge(g.owned_edges[i], g.owned_edges[j], lca);
  };
  if (!(start[0] == start[1] && certified_[start[0]]) && !g.boxes_ready) search_boxes(model, g);
  node_pairs_.clear();
  node_pairs_.push_back(start);
  while (!node_pairs_.empty()) {
    const auto [a, b, lca] = node_pairs_.back();
    node_pairs_.pop_back();
    const auto& ca = g.bvh_child[a];
    const auto& cb = g.bvh_child[b];
    if (a == b) {
      if (ca[0] < 0) continue;
      if (certified_[a]) {
        g.deferred.push_back(a);
        continue;
      }
      node_pairs_.push_back({ca[0], ca[1], a});
      node_pairs_.push_back({ca[1], ca[1], ca[1]});
      node_pairs_.push_back({ca[0], ca[0], ca[0]});
      continue;
    }
    if (!boxes_overlap(g.node_lo[a], g.node_hi[a], g.node_lo[b], g.node_hi[b])) continue;
    // (Two children of their patch are that patch, which failed: no union of them is tried; nor
    // is the pair the search starts from, a union that resume_unions just saw fail this motion.)
    const auto& cl = g.bvh_child[lca];
    const bool tried = (cl[0] == a && cl[1] == b) || (cl[0] == b && cl[1] == a) || (a == start[0] && b == start[1]);
    if (!tried && certify_union(g, a, b, x, q, false)) {
      g.deferred_unions.push_back({a, b, lca});
      continue;
    }
    if (ca[0] < 0 && cb[0] < 0) {
      leaf_pair(-1 - ca[0], -1 - cb[0], lca);
    } else if (ca[0] < 0 || (cb[0] >= 0 && g.bvh_size[b] > g.bvh_size[a])) {
      node_pairs_.push_back({a, cb[1], lca});
      node_pairs_.push_back({a, cb[0], lca});
    } else {
      node_pairs_.push_back({ca[1], b, lca});
      node_pairs_.push_back({ca[0], b, lca});
    }
  }
}

// Particle q and triangle t as a candidate pair of patch lca, if q is not one of t's corners, their
// search boxes overlap and one of them can move.
void SelfCollision::add_point_triangle(const Model& model, Group& g, Index q, Index t, Index lca, const Real* w) {
  const Triangle& tri = model.triangles[g.triangles[t]];
  if (tri[0] == q || tri[1] == q || tri[2] == q) return;
  if (!boxes_overlap(particle_lo_.col(q), particle_hi_.col(q), g.tri_lo[t], g.tri_hi[t])) return;
  if (w[q] + w[tri[0]] + w[tri[1]] + w[tri[2]] <= 0) return;
  g.pt.push_back({q, t, lca});
}

// After certify for a sub-step's motion: the deferred nodes it no longer certifies are searched
// now (with the search's boxes, which hold while the candidates do), in the tree's order, and the
// pairs they give join the candidates.
void SelfCollision::resume_deferred(const Model& model, Group& g, const Real* w, const Positions& x,
                                    const Positions& p) {
  // A node deferred by one of these searches lies inside the one searched and is certified: none
  // is searched in this call, and the list is put back in order at its end.
  const std::size_t before = g.deferred.size();
  std::size_t kept = 0;
  for (std::size_t j = 0; j < before; ++j) {
    const Index k = g.deferred[j];
    if (certified_[k])
      g.deferred[kept++] = k;
    else
      search_node(model, g, {k, k, k}, w, x, p);
  }
  if (kept == before) return;
  g.deferred.erase(std::copy(g.deferred.begin() + before, g.deferred.end(), g.deferred.begin() + kept), g.deferred.end());
  std::sort(g.deferred.begin(), g.deferred.end());
}

// Whether the union of nodes a and b (disjoint: two nodes the search meets across the cut of the
// node they descend from), a disc, is certified for the motion x -> p as a patch is (certify_patch):
// then no two of its features can meet, the pairs between a and b need no search, and none is
// kept. Where a cloth curves past what one patch can hold (a cape hanging past 90 degrees), the
// root and a few large nodes fail while their children certify, and the features near those
// cuts, mostly neighbours in the cloth's own plane, were pairs checked on every sub-step. Tried
// for two patches of at most kUnionMost triangles between them; the disc test is made once per
// pair of nodes and kept.
bool SelfCollision::certify_union(Group& g, Index a, Index b, const Positions& x, const Positions& p, bool sub_step) {
  // Nodes apart at rest share no particle (their union is not connected), and a search meets
  // many such pairs where the cloth folds onto itself: their rest boxes tell them apart at once.
  if (!g.is_patch[a] || !g.is_patch[b] || g.bvh_size[a] + g.bvh_size[b] > kUnionMost ||
      !boxes_overlap(g.rest_lo[a], g.rest_hi[a], g.rest_lo[b], g.rest_hi[b]))
    return false;
  if (b < a) std::swap(a, b);
  auto& known = g.union_of[a];
  Index index = -1;
  for (const auto& [other, i] : known)
    if (other == b) index = i;
  if (index < 0) {
    index = static_cast<Index>(g.unions.size());
    known.push_back({b, index});
    Group::Union u;
    const Triangle *ta = g.bvh_corners.data() + g.bvh_begin[a], *tb = g.bvh_corners.data() + g.bvh_begin[b];
    u.corners.assign(ta, ta + g.bvh_size[a]);
    u.corners.insert(u.corners.end(), tb, tb + g.bvh_size[b]);
    u.disc = disc_boundary(u.corners.data(), static_cast<Index>(u.corners.size()), u.boundary, disc_scratch_);
    if (!u.disc) u.corners = {};
    g.unions.push_back(std::move(u));
  }
  Group::Union& u = g.unions[index];
  if (!u.disc) return false;
  if (!sub_step && g.serial > 0 && u.carry.at == g.serial) return true;  // as certify does for a node
  const Vec3 lo = g.node_lo[a].cwiseMin(g.node_lo[b]), hi = g.node_hi[a].cwiseMax(g.node_hi[b]);
  const PatchView view{u.corners.data(), static_cast<Index>(u.corners.size()), u.boundary.data(),
                       static_cast<Index>(u.boundary.size()), (hi - lo).squaredNorm(), nullptr, u.axis, u.carry};
  return certify_patch(g, view, x, p, sub_step);
}

// After certify for a sub-step's motion: the deferred unions whose patch is not certified and
// that the motion does not certify are searched now, in their order, and the pairs they give join
// the candidates (a union deferred by one of these searches joins the list's end).
void SelfCollision::resume_unions(const Model& model, Group& g, const Positions& x, const Positions& p, const Real* w) {
  const std::size_t before = g.deferred_unions.size();
  std::size_t kept = 0;
  for (std::size_t j = 0; j < before; ++j) {
    const std::array<Index, 3> d = g.deferred_unions[j];
    if (certified_[d[2]] || certify_union(g, d[0], d[1], x, p, true))
      g.deferred_unions[kept++] = d;
    else
      search_node(model, g, d, w, x, p);
  }
  if (kept == before) return;
  g.deferred_unions.erase(
      std::copy(g.deferred_unions.begin() + before, g.deferred_unions.end(), g.deferred_unions.begin() + kept),
      g.deferred_unions.end());
}

// Whether the candidates of group g hold for the positions x and p now (see above). Without x:
// for p alone, x being known to hold (resolve: begin checked the same x against these boxes, or
// a search since made boxes that hold it).
bool SelfCollision::candidates_hold(const Model& model, const Group& g, const Positions* x, const Positions& p) const {
  if (g.first >= 0) {
    const Index at = 3 * g.first, n = 3 * g.count;
    const Real *lo = hold_lo_.data() + at, *hi = hold_hi_.data() + at;
    return within(p.data() + at, lo, hi, n) && (!x || within(x->data() + at, lo, hi, n));
  }
  for (Index o = model.group_offsets[g.group]; o < model.group_offsets[g.group + 1]; ++o) {
    const Index i = model.group_particles[o];
    const auto lo = hold_lo_.col(i).array(), hi = hold_hi_.col(i).array();
    const auto pi = p.col(i).array();
    if ((pi < lo).any() || (pi > hi).any()) return false;
    if (x && ((x->col(i).array() < lo).any() || (x->col(i).array() > hi).any())) return false;
  }
  return true;
}

// The features' swept boxes over x -> p (triangles in box_lo_/box_hi_, edges in edge_lo_/edge_hi_,
// particles in sweep_lo_/sweep_hi_), widened by `pad` (m).
void SelfCollision::sweep_boxes(const Model& model, const Group& g, const Positions& x, const Positions& p, Real pad) {
  for (Index o = model.group_offsets[g.group]; o < model.group_offsets[g.group + 1]; ++o) {
    const Index i = model.group_particles[o];
    sweep_lo_.col(i) = x.col(i).cwiseMin(p.col(i)).array() - pad;
    sweep_hi_.col(i) = x.col(i).cwiseMax(p.col(i)).array() + pad;
  }
  unite_boxes(model, g, sweep_lo_, sweep_hi_, box_lo_, box_hi_, &edge_lo_, &edge_hi_);
}

// Each triangle's and (given edge_lo) edge's box (tri_lo/tri_hi, edge_lo/edge_hi) as the union of
// its particles' boxes [lo, hi].
void SelfCollision::unite_boxes(const Model& model, const Group& g, const Positions& lo, const Positions& hi,
                                std::vector<Vec3>& tri_lo, std::vector<Vec3>& tri_hi, std::vector<Vec3>* edge_lo,
                                std::vector<Vec3>* edge_hi) {
  const Vec3 inf = Vec3::Constant(std::numeric_limits<Real>::infinity());
  const auto unite = [&](const auto& ids, Vec3& l, Vec3& u) {
    l = inf, u = -inf;
    for (const Index i : ids) l = l.cwiseMin(lo.col(i)), u = u.cwiseMax(hi.col(i));
  };
  tri_lo.resize(g.triangles.size());
  tri_hi.resize(g.triangles.size());
  for (std::size_t t = 0; t < g.triangles.size(); ++t) unite(model.triangles[g.triangles[t]], tri_lo[t], tri_hi[t]);
  if (!edge_lo) return;
  edge_lo->resize(g.edges.size());
  edge_hi->resize(g.edges.size());
  for (std::size_t e = 0; e < g.edges.size(); ++e) unite(g.edges[e], (*edge_lo)[e], (*edge_hi)[e]);
}

// Proximity contacts at the start of the sub-step, from the candidates, with two rules that keep
// them from adding energy. The projection moves a particle by a distance d in one sub-step, and
// the velocity update (12) turns that into a speed d/Δt (Δt = 1/1800 s in cloth_sphere: 1 cm is
// 18 m/s), so a contact may only take away approach, never push apart:
// - a pair that starts the sub-step closer than h (at a distance d0 in [0, h): it slid in
//   sideways, typically around a sharp crease) is held at d0, not pushed out to h; the same rule
//   as a collider's static fallback (started_inside), which keeps a particle from leaving faster
//   than it came.
// - a triangle whose normal turns by more than 90° within the sub-step is a sliver passing
//   through degeneracy (no real triangle turns over in 0.5 ms), its normal is meaningless and the
//   side carried over would push q through it by up to 2h plus the depth: no contact.
// A point–triangle contact (Müller 2007 §4.4) when, at the prediction, q is less than 2h from the
// triangle's plane on its side (or beyond it) and within h of the triangle sideways. (Edge–edge
// proximity contacts, tried too, only added energy to the soft drape's whip, 10 E0 against 4 E0,
// and cost a fifth more: edges are kept from crossing by the continuous test alone.)
void SelfCollision::begin(const Model& model, const Positions& x, const Positions& p, const Real* w, int substeps,
                          Real h, bool proximity, bool x_resolved) {
  contacts_.clear();
  counts_.continuous = counts_.failsafe = counts_.unresolved = 0;
  if (particle_lo_.cols() != p.cols())
    for (Positions* m : {&particle_lo_, &particle_hi_, &hold_lo_, &hold_hi_, &sweep_lo_, &sweep_hi_}) m->resize(3, p.cols());
  if (stopped_.size() != static_cast<std::size_t>(p.cols())) stopped_.assign(p.cols(), 0);
  for (Group& g : groups_) {
    g.substeps = std::max(substeps, 1);
    const Real hs = g.thickness;
    if (!g.searched || !candidates_hold(model, g, x_resolved ? nullptr : &x, p)) find_candidates(model, g, x, p, w, substeps);
    // The deferred nodes are searched when the continuous test's motion does not certify them
    // (find_impacts): a patch has proximity contacts from the sub-step after it stops being one.
    if (!proximity || g.pt.empty()) continue;
    // A pair within 2h at the prediction: its boxes widened by h overlap. Few pairs (a smooth
    // cloth's, its patches certified) take their boxes one pair at a time; many, from boxes
    // united once per feature.
    const bool per_pair = g.pt.size() < g.triangles.size() + g.edges.size();
    const bool avx2 = kernels_use_avx2();
    if (!per_pair) sweep_boxes(model, g, x, p, hs);
    const int parts = in_chunks(g.pt.size(), [&](int part, int parts_count) {
      auto& out = contact_parts_[part];
      out.clear();
      for (std::size_t k = g.pt.size() * part / parts_count; k < g.pt.size() * (part + 1) / parts_count; ++k) {
        const auto [q, t, patch] = g.pt[k];
        const Triangle& tri = model.triangles[g.triangles[t]];
        if (per_pair ? !swept_boxes_overlap(x, p, std::array<Index, 1>{q}, tri, hs, avx2)
                     : !boxes_overlap(sweep_lo_.col(q), sweep_hi_.col(q), box_lo_[t], box_hi_[t]))
          continue;
        const Vec3 xq = x.col(q), pq = p.col(q);
        const Vec3 x1 = x.col(tri[0]);
        Vec3 n0 = (x.col(tri[1]) - x1).cross(x.col(tri[2]) - x1);
        const Vec3 p1 = p.col(tri[0]);
        Vec3 np = (p.col(tri[1]) - p1).cross(p.col(tri[2]) - p1);
        const Real l0 = n0.norm(), lp = np.norm();
        if (!(l0 > 0) || !(lp > 0)) continue;  // a collapsed triangle has no side
        n0 /= l0;
        np /= lp;
        if (!(n0.dot(np) > 0)) continue;  // the triangle flipped: a sliver, no side
        const Real d0 = (xq - x1).dot(n0);
        const Real side = d0 >= 0 ? 1 : -1;
        if (side * (pq - p1).dot(np) >= 2 * hs) continue;
        Vec3 b;
        const Vec3 c = closest_point_on_triangle(pq, p1, p.col(tri[1]), p.col(tri[2]), &b);
        const Vec3 off = pq - c;
        if ((off - off.dot(np) * np).norm() > hs) continue;
        out.push_back({PairKind::PointTriangle, false, {q, tri[0], tri[1], tri[2]}, {1, -b[0], -b[1], -b[2]}, np, side,
                       std::min(hs, side * d0)});
        out.back().approach = approach_speed(out.back(), side * np, x, p, h);
      }
    });
    for (int part = 0; part < parts; ++part)
      contacts_.insert(contacts_.end(), contact_parts_[part].begin(), contact_parts_[part].end());
  }
  counts_.contacts = static_cast<Index>(contacts_.size());
  counts_.skipped = 0;
  counts_.candidates = 0;
  for (const Group& g : groups_) {
    counts_.skipped += g.skipped;
    counts_.candidates += static_cast<std::int64_t>(g.pt.size() + g.ee.size());
  }
}

// The self-contacts' projection (with the other contacts in a position-based stepper's sweep, after
// the constraints; and in resolve's passes). C = d·n - thickness with n as SelfContact says; its
// gradient is taken with n and the weights c fixed, ∇_k C = c_k n, so the correction is (Bridson,
// Fedkiw, Anderson 2002, §7.1)
//   Δp_k = -C w_k c_k n / Σ_j c_j² w_j,
// times `scale` (a relaxation; 1 changes no bit).
bool self_contact_step(const SelfContact& k, const Real* y, const Real* w, Real scale, Vec3& s) {
  const auto& id = k.particles;
  const auto& c = k.weights;
  const Eigen::Map<const Vec3> p0(y + 3 * id[0]), p1(y + 3 * id[1]), p2(y + 3 * id[2]), p3(y + 3 * id[3]);
  Vec3 n;
  if (!self_contact_normal(k, p1, p2, p3, n)) return false;
  const Real C = (c[0] * p0 + c[1] * p1 + c[2] * p2 + c[3] * p3).dot(n) - k.thickness;
  if (C >= 0) return false;
  const Real denom = contact_inverse_mass(k, w);
  if (!(denom > 0)) return false;
  s = (-C * scale / denom) * n;
  return true;
}

bool self_contact_normal(const SelfContact& k, const Vec3& y1, const Vec3& y2, const Vec3& y3, Vec3& n) {
  if (k.continuous) {
    n = k.normal;
    return true;
  }
  n = (y2 - y1).cross(y3 - y1);
  const Real len = n.norm();
  if (!(len > 0)) return false;
  n *= k.side / len;
  return true;
}

// One Gauss-Seidel pass over the contacts, in their order, on p.
void SelfCollision::project(Positions& p, const Real* w) {
  for (SelfContact& k : contacts_) {
    Vec3 s;
    if (!self_contact_step(k, p.data(), w, 1, s)) continue;
    k.pushed = true;
    for (int e = 0; e < 4; ++e) p.col(k.particles[e]) += (w[k.particles[e]] * k.weights[e]) * s;
  }
}

// The pairs of group g whose distance falls to kSeparation of its start along x -> p (additive
// CCD), in the candidates' order, into impacts_. The patches certified for the motion are found
// first (and those deferred at the search that are not, searched now); a pair inside one, or
// whose swept boxes do not overlap, cannot meet and is skipped before the test.
void SelfCollision::find_impacts(const Model& model, Group& g, const Positions& x, const Positions& p, const Real* w) {
  impacts_.clear();
  certify(model, g, x, p, true);
  resume_deferred(model, g, w, x, p);
  resume_unions(model, g, x, p, w);
  if (g.pt.empty() && g.ee.empty()) return;
  const bool per_pair = g.pt.size() + g.ee.size() < g.triangles.size() + g.edges.size();  // as in begin
  const bool avx2 = kernels_use_avx2();
  if (!per_pair) sweep_boxes(model, g, x, p, 0);
  const auto test = [&](PairKind kind, const std::array<Index, 4>& id, std::vector<Found>& out) {
    std::array<Vec3, 4> x0, dx;
    for (int k = 0; k < 4; ++k) x0[k] = x.col(id[k]), dx[k] = p.col(id[k]) - x.col(id[k]);
    const csb::Impact hit = additive_ccd(kind, x0, dx, kSeparation, 0);
    if (hit.hit) out.push_back({kind, id, hit.toi});
  };
  const int parts = in_chunks(g.pt.size() + g.ee.size(), [&](int t, int T) {
    auto& pt_out = impact_parts_[2 * t];
    auto& ee_out = impact_parts_[2 * t + 1];
    pt_out.clear();
    ee_out.clear();
    std::int64_t tests = 0, culled = 0;
    for (std::size_t k = g.pt.size() * t / T; k < g.pt.size() * (t + 1) / T; ++k) {
      const auto [q, tri_index, patch] = g.pt[k];
      if (patch >= 0 && certified_[patch]) {
        ++culled;
        continue;
      }
      const Triangle& tri = model.triangles[g.triangles[tri_index]];
      if (per_pair ? !swept_boxes_overlap(x, p, std::array<Index, 1>{q}, tri, 0, avx2)
                   : !boxes_overlap(sweep_lo_.col(q), sweep_hi_.col(q), box_lo_[tri_index], box_hi_[tri_index]))
        continue;
      test(PairKind::PointTriangle, {q, tri[0], tri[1], tri[2]}, pt_out);
      ++tests;
    }
    for (std::size_t k = g.ee.size() * t / T; k < g.ee.size() * (t + 1) / T; ++k) {
      const auto [a, b, patch] = g.ee[k];
      if (certified_[patch]) {
        ++culled;
        continue;
      }
      if (per_pair ? !swept_boxes_overlap(x, p, g.edges[a], g.edges[b], 0, avx2)
                   : !boxes_overlap(edge_lo_[a], edge_hi_[a], edge_lo_[b], edge_hi_[b]))
        continue;
      test(PairKind::EdgeEdge, {g.edges[a][0], g.edges[a][1], g.edges[b][0], g.edges[b][1]}, ee_out);
      ++tests;
    }
    tests_parts_[t] = tests;
    culled_parts_[t] = culled;
  });
  // In the candidates' order whatever the number of threads: point-triangle, then edge-edge.
  for (int kind = 0; kind < 2; ++kind)
    for (int t = 0; t < parts; ++t) impacts_.insert(impacts_.end(), impact_parts_[2 * t + kind].begin(), impact_parts_[2 * t + kind].end());
  for (int t = 0; t < parts; ++t) counts_.tests += tests_parts_[t], counts_.culled += culled_parts_[t];
}

// After the sweeps: the continuous test, up to kResponseRounds rounds of continuous contacts
// (each impact a contact along the pair's direction at the time of impact, kept at least at
// min(h, its start distance); then kResponsePasses Gauss-Seidel passes over all self-contacts),
// then the fail-safe for what is left (see the top of this file).
void SelfCollision::resolve(const Model& model, const Positions& x, Positions& p, const Real* w, int substeps, Real h) {
  for (Group& g : groups_) {
    for (int round = 0;; ++round) {
      if (!candidates_hold(model, g, nullptr, p)) find_candidates(model, g, x, p, w, substeps);
      find_impacts(model, g, x, p, w);
      if (impacts_.empty()) break;
      if (round == kResponseRounds) break;
      for (const Found& m : impacts_) {
        std::array<Vec3, 4> at;  // the pair at the time of impact
        for (int k = 0; k < 4; ++k) at[k] = x.col(m.particles[k]) + m.toi * (p.col(m.particles[k]) - x.col(m.particles[k]));
        std::array<Real, 4> c;
        if (m.kind == PairKind::PointTriangle) {
          Vec3 b;
          closest_point_on_triangle(at[0], at[1], at[2], at[3], &b);
          c = {1, -b[0], -b[1], -b[2]};
        } else {
          Real u, v;
          segment_segment_distance2(at[0], at[1], at[2], at[3], &u, &v);
          c = {1 - u, u, -(1 - v), -v};
        }
        const auto separation = [&](const std::array<Vec3, 4>& y) { return Vec3(c[0] * y[0] + c[1] * y[1] + c[2] * y[2] + c[3] * y[3]); };
        std::array<Vec3, 4> x0;
        for (int k = 0; k < 4; ++k) x0[k] = x.col(m.particles[k]);
        const Vec3 d_at = separation(at), d_start = separation(x0);
        const Real len = d_at.norm();
        const Vec3 n = len > 0 ? Vec3(d_at / len) : Vec3(d_start.normalized());
        if (!n.allFinite()) continue;  // the features coincide at both times: no direction to push
        contacts_.push_back({m.kind, true, m.particles, c, n, 1, std::min(g.thickness, std::sqrt(pair_distance2(m.kind, x0)))});
        contacts_.back().approach = approach_speed(contacts_.back(), n, x, p, h);
        ++counts_.continuous;
      }
      for (int pass = 0; pass < kResponsePasses; ++pass) project(p, w);
    }
    if (impacts_.empty()) continue;
    // The fail-safe: stop the free particles of every pair still found, until none is.
    std::vector<Index> stopped;
    while (!impacts_.empty()) {
      Index newly = 0;
      for (const Found& m : impacts_)
        for (const Index i : m.particles)
          if (w[i] > 0 && !stopped_[i]) {
            p.col(i) = x.col(i);
            stopped_[i] = 1;
            stopped.push_back(i);
            ++newly;
          }
      if (newly == 0) {
        counts_.unresolved += static_cast<Index>(impacts_.size());
        break;
      }
      counts_.failsafe += newly;
      find_impacts(model, g, x, p, w);  // p = x stays inside the swept boxes: the candidates hold
    }
    for (const Index i : stopped) stopped_[i] = 0;
  }
  counts_.contacts = static_cast<Index>(contacts_.size());
}

// The deepest violation left by the self-contacts at x (m), for the contact summary.
Real SelfCollision::penetration(const Positions& x) const {
  Real worst = 0;
  for (const SelfContact& k : contacts_) {
    const auto& id = k.particles;
    Vec3 n;
    if (!self_contact_normal(k, x.col(id[1]), x.col(id[2]), x.col(id[3]), n)) continue;
    worst = std::max(worst, k.thickness - separation(k, [&](Index i) { return Vec3(x.col(i)); }).dot(n));
  }
  return worst;
}

// Self-contacts are inelastic (16): a contact that pushed its pair this sub-step may take away
// its approach but not make it separate. The projection moved the pair by up to its depth, and
// the velocity update turned that into a separating speed depth/h; left so, a one-iteration
// Gauss-Seidel cloth whose hem whips into itself gained energy from its contacts (the soft drape
// of cloth_sphere, sequential sweep: 9.5 E0 at the whip against 3.1 E0 without self-collision).
// With v_n the pair's relative normal speed now (Σ_k c_k v_k · n) and a its approach speed in the
// motion the contact was made from, v_n is brought down to max(a, 0) if above it: the pair leaves
// no faster than it was separating before the contact acted. The change is an impulse along n
// shared by the weights, Δv_k = w_k c_k Δ / Σ_j c_j² w_j, one pass in the contacts' order.
void SelfCollision::settle_velocities(const Positions& x_end, const Real* w, const std::function<Vec3(Index)>& velocity,
                                      const std::function<void(Index, const Vec3&)>& add_velocity) const {
  for (const SelfContact& k : contacts_) {
    if (!k.pushed) continue;
    const auto& id = k.particles;
    const auto& c = k.weights;
    Vec3 n;
    if (!self_contact_normal(k, x_end.col(id[1]), x_end.col(id[2]), x_end.col(id[3]), n)) continue;
    Real vn = 0;
    for (int e = 0; e < 4; ++e) vn += c[e] * velocity(id[e]).dot(n);
    const Real target = std::max(k.approach, Real(0));
    if (!(vn > target)) continue;
    const Real denom = contact_inverse_mass(k, w);
    if (!(denom > 0)) continue;
    const Vec3 impulse = ((target - vn) / denom) * n;
    for (int e = 0; e < 4; ++e) add_velocity(id[e], (w[id[e]] * c[e]) * impulse);
  }
}

}  // namespace csb
