// csb — the coloured sweep's kernels: one constraint per SIMD lane within a colour (distance in
// gathered blocks with an AVX2 copy, tet volumes, attachments); included by solver/coloured.cpp only.
#pragma once

#include "csb/pbd.hpp"
#include "csb/solver/avx2_rows.hpp"
#include "csb/solver/coloured_bending.hpp"
#include "csb/constraints/attachment.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"
#include "csb/step/internal.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <type_traits>
#include <utility>

#if defined(__GNUC__)
#define CSB_INLINE inline __attribute__((always_inline))
#else
#define CSB_INLINE inline
#endif

namespace csb::coloured_kernels {

using namespace stepper_detail;

// PBD (Müller 2007 §3.3) and Jakobsen: Δp_i = -c_i s d, Δp_j = +c_j s d, d = p_i - p_j, with
// s = C/|d| (C the violation, see constraints/distance.hpp) or, with Jakobsen's square-root
// approximation, s = (d·d - r²)/(d·d + r²); c = k w/(w_i + w_j) precomputed.
template <bool Approx, class S>
CSB_INLINE void distance_pbd(const ColouredDistanceT<S>& b, Index c, const S* r, S* o) {
  const Index i = b.i[c], j = b.j[c];
  const S dx = r[i] - r[j], dy = r[i + 1] - r[j + 1], dz = r[i + 2] - r[j + 2];
  const S dd = dx * dx + dy * dy + dz * dz;
  const S rest = b.rest[c];
  const S sense = b.sense[c];
  S s;
  if constexpr (Approx) {
    const S r2 = rest * rest;
    const S cj = (dd - r2) / (2 * rest);
    const S violation = cj - sense * std::max(sense * cj, S(0));
    const S den = dd + r2;  // selects on values, then an unconditional division: no branch
    s = (violation != 0 ? dd - r2 : S(0)) / (den > 0 ? den : S(1));
  } else {
    const S len = std::sqrt(dd);
    const S cl = len - rest;
    const S violation = cl - sense * std::max(sense * cl, S(0));
    s = (len > 0 ? violation : S(0)) / (len > 0 ? len : S(1));
  }
  const S si = b.ci[c] * s, sj = b.cj[c] * s;
  o[i] -= si * dx;
  o[i + 1] -= si * dy;
  o[i + 2] -= si * dz;
  o[j] += sj * dx;
  o[j + 1] += sj * dy;
  o[j + 2] += sj * dz;
}

// The same over the independent constraints [begin, end) of one colour, in blocks of kDistanceBlock:
// positions gathered into small arrays one constraint at a time, the arithmetic in a loop the
// compiler runs in SIMD lanes (distance_pbd_block_s), the corrections scattered back. (SSE2 has
// no gather instruction to vectorise the plain loop with; with AVX-512's, in a native build, the
// plain loop ran at 7.9 ns per projection against these blocks' 5.8 in AVX2:
// papers/benchmarks.md.) Per constraint the same operations in the same order as distance_pbd,
// so the same bits.
constexpr Index kDistanceBlock = 32;

// The senses of constraints c0 + [0, m) as S, in a loop of their own: a loop that mixes the int8
// senses with the doubles runs as many lanes as the int8 fill a register (16 or 32, unrolled in
// 128-bit registers for XPBD's, spilling), where one of doubles alone runs four.
template <class S>
CSB_INLINE void senses(const ColouredDistanceT<S>& b, Index c0, Index m, S* out) {
  const std::int8_t* sense = b.sense.data() + c0;
  for (Index k = 0; k < m; ++k) out[k] = sense[k];
}

// The violation C of a constraint of sense sn from its bilateral value c (constraints/distance.hpp):
// c - sn max(sn c, 0). Bilateral: the batch's constraints are all bilateral (sn = 0,
// ColouredDistanceT::bilateral), and C is c itself: the same value, since c - 0 max(0 c, 0) is c
// for every finite c but -0, which c (a length less a rest length, or Jakobsen's
// (d·d - r²)/(2 r)) never is; a non-finite c gives a non-finite s either way.
template <bool Bilateral, class S>
CSB_INLINE S violation_of(S c, S sn) {
  if constexpr (Bilateral)
    return c;
  else
    return c - sn * std::max(sn * c, S(0));
}

// s of constraints c0 + [0, m) from their d = p_i - p_j (Bilateral: see violation_of; the senses
// are not read).
template <bool Approx, bool Bilateral, class S>
CSB_INLINE void distance_pbd_block_s(const ColouredDistanceT<S>& b, Index c0, Index m, const S* dx, const S* dy,
                                     const S* dz, S* s) {
  const S* rest = b.rest.data() + c0;
  alignas(64) S sense[Bilateral ? 1 : kDistanceBlock];
  if constexpr (!Bilateral) senses(b, c0, m, sense);
#pragma omp simd
  for (Index k = 0; k < m; ++k) {
    const S dd = dx[k] * dx[k] + dy[k] * dy[k] + dz[k] * dz[k];
    const S sn = Bilateral ? S(0) : sense[k];
    if constexpr (Approx) {
      const S r2 = rest[k] * rest[k];
      const S cj = (dd - r2) / (2 * rest[k]);
      const S violation = violation_of<Bilateral>(cj, sn);
      const S den = dd + r2;
      s[k] = (violation != 0 ? dd - r2 : S(0)) / (den > 0 ? den : S(1));
    } else {
      const S len = std::sqrt(dd);
      const S cl = len - rest[k];
      const S violation = violation_of<Bilateral>(cl, sn);
      s[k] = (len > 0 ? violation : S(0)) / (len > 0 ? len : S(1));
    }
  }
}

// d = p_i - p_j of constraints c0 + [k0, m), one at a time.
template <class S>
CSB_INLINE void distance_gather(const ColouredDistanceT<S>& b, Index c0, Index k0, Index m, const S* r, S* dx,
                                S* dy, S* dz) {
  for (Index k = k0; k < m; ++k) {
    const Index i = b.i[c0 + k], j = b.j[c0 + k];
    dx[k] = r[i] - r[j];
    dy[k] = r[i + 1] - r[j + 1];
    dz[k] = r[i + 2] - r[j + 2];
  }
}

// The corrections of constraints c0 + [k0, m), one at a time: PBD's -c_i s d and +c_j s d (s the
// violation over |d|), XPBD's +w_i Δλ n and -w_j Δλ n (s = Δλ, (vx, vy, vz) = n, c = w).
template <bool Xpbd, class S>
CSB_INLINE void distance_scatter(const ColouredDistanceT<S>& b, Index c0, Index k0, Index m, const S* s,
                                 const S* vx, const S* vy, const S* vz, S* o) {
  for (Index k = k0; k < m; ++k) {
    const Index i = b.i[c0 + k], j = b.j[c0 + k];
    const S si = b.ci[c0 + k] * s[k], sj = b.cj[c0 + k] * s[k];
    if constexpr (Xpbd) {
      o[i] += si * vx[k], o[i + 1] += si * vy[k], o[i + 2] += si * vz[k];
      o[j] -= sj * vx[k], o[j + 1] -= sj * vy[k], o[j + 2] -= sj * vz[k];
    } else {
      o[i] -= si * vx[k], o[i + 1] -= si * vy[k], o[i + 2] -= si * vz[k];
      o[j] += sj * vx[k], o[j + 1] += sj * vy[k], o[j + 2] += sj * vz[k];
    }
  }
}

template <bool Approx, bool Bilateral, class S>
CSB_INLINE void distance_pbd_blocks(const ColouredDistanceT<S>& b, Index begin, Index end, const S* r, S* o) {
  constexpr Index B = kDistanceBlock;
  alignas(64) S dx[B], dy[B], dz[B], s[B];
  for (Index c0 = begin; c0 < end; c0 += B) {
    const Index m = std::min(B, end - c0);
    distance_gather(b, c0, 0, m, r, dx, dy, dz);
    distance_pbd_block_s<Approx, Bilateral>(b, c0, m, dx, dy, dz, s);
    distance_scatter<false>(b, c0, 0, m, s, dx, dy, dz, o);
  }
}

#if CSB_HAS_AVX2_ROWS
// distance_scatter of constraints c0 + [0, m4), m4 a multiple of 4, four at a time in AVX2
// registers (the same operations, so the same bits); their shares c_i, c_j at ci, cj.
template <bool Xpbd>
CSB_AVX2_INLINE void distance_scatter_rows(const ColouredDistance& b, Index c0, Index m4, const Real* s,
                                           const Real* vx, const Real* vy, const Real* vz, Real* o, const Real* ci,
                                           const Real* cj) {
  using namespace avx2;
  const Offset* bi = as_offsets(b.i.data()) + c0;
  const Offset* bj = as_offsets(b.j.data()) + c0;
  for (Index k = 0; k < m4; k += 4) {
    const __m256d sk = _mm256_load_pd(s + k);
    const __m256d x = _mm256_load_pd(vx + k), y = _mm256_load_pd(vy + k), z = _mm256_load_pd(vz + k);
    const __m256d si = _mm256_mul_pd(_mm256_loadu_pd(ci + k), sk), sj = _mm256_mul_pd(_mm256_loadu_pd(cj + k), sk);
    const Offset* at_i = bi + k;
    const Offset* at_j = bj + k;
    add_rows<!Xpbd>(o, at_i, _mm256_mul_pd(si, x), _mm256_mul_pd(si, y), _mm256_mul_pd(si, z));
    add_rows<Xpbd>(o, at_j, _mm256_mul_pd(sj, x), _mm256_mul_pd(sj, y), _mm256_mul_pd(sj, z));
  }
}

// d = p_i - p_j (and, Damped, u = (p_i - x_i) - (p_j - x_j)) of constraints c0 + [0, m4) as rows,
// four at a time in AVX2 registers (csb/avx2_rows.hpp). (Pads: the float copy's; double positions
// have none, so wi and wj are not written.)
template <bool Damped, bool Pads = false>
CSB_AVX2_INLINE void distance_gather_rows(const ColouredDistance& b, Index c0, Index m4, const Real* r, const Real* x,
                                          Real* dx, Real* dy, Real* dz, Real* ux, Real* uy, Real* uz,
                                          Real* /*wi*/ = nullptr, Real* /*wj*/ = nullptr) {
  static_assert(!Pads, "double positions have no pads");
  using namespace avx2;
  const Offset* bi = as_offsets(b.i.data()) + c0;
  const Offset* bj = as_offsets(b.j.data()) + c0;
  for (Index k = 0; k < m4; k += 4) {
    __m256d d[4], u[4];
    for (int l = 0; l < 4; ++l) {
      const __m256d pi = load_xyz(r + bi[k + l]), pj = load_xyz(r + bj[k + l]);
      d[l] = _mm256_sub_pd(pi, pj);
      if constexpr (Damped)
        u[l] = _mm256_sub_pd(_mm256_sub_pd(pi, load_xyz(x + bi[k + l])),
                             _mm256_sub_pd(pj, load_xyz(x + bj[k + l])));
    }
    __m256d rx, ry, rz;
    rows(d[0], d[1], d[2], d[3], rx, ry, rz);
    _mm256_store_pd(dx + k, rx);
    _mm256_store_pd(dy + k, ry);
    _mm256_store_pd(dz + k, rz);
    if constexpr (Damped) {
      rows(u[0], u[1], u[2], u[3], rx, ry, rz);
      _mm256_store_pd(ux + k, rx);
      _mm256_store_pd(uy + k, ry);
      _mm256_store_pd(uz + k, rz);
    }
  }
}
#endif
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__AVX2__)
#define CSB_DISTANCE_AVX2 1
#endif

// XPBD (Macklin 2016 Eq. (18), (26)); see project_distance_xpbd. x: positions at the sub-step's start.
// Relaxed (averaged Jacobi): Δλ, after its sign clamp, scaled by the constraint's relaxation
// min(relax_i, relax_j) (PbdStepper::set_relaxation). Fresh: the multiplier is +0 (a sub-step's
// first sweep): not read, α̃ λ (+0) not subtracted, the same bits (as bending_compute's).
template <bool Relaxed = false, class S, bool Fresh = false>
CSB_INLINE void distance_xpbd(ColouredDistanceT<S>& b, Index c, const S* r, S* o, const S* x,
                              const Real* relax = nullptr) {
  static_assert(!(Relaxed && Fresh));
  const Index i = b.i[c], j = b.j[c];
  const S dx = r[i] - r[j], dy = r[i + 1] - r[j + 1], dz = r[i + 2] - r[j + 2];
  const S len = std::sqrt(dx * dx + dy * dy + dz * dz);
  const S inv_len = S(len > 0 ? 1 : 0) / (len > 0 ? len : S(1));
  const S nx = dx * inv_len, ny = dy * inv_len, nz = dz * inv_len;
  const S cl = len - b.rest[c];
  const S g = b.gamma[c];
  const S along = nx * ((r[i] - x[i]) - (r[j] - x[j])) + ny * ((r[i + 1] - x[i + 1]) - (r[j + 1] - x[j + 1])) +
                     nz * ((r[i + 2] - x[i + 2]) - (r[j + 2] - x[j + 2]));
  const S moved = g == 0 ? S(0) : along;
  const S lambda = Fresh ? S(0) : b.lambda[c];
  S num = -cl;
  if constexpr (!Fresh) num = num - b.alpha[c] * lambda;
  S dl = (num - g * moved) * b.inv_den[c];
  const S sense = b.sense[c];
  const S next = lambda + dl;
  const S clamped = sense > 0 ? std::max(next, S(0)) : std::min(next, S(0));
  dl = sense == 0 ? dl : clamped - lambda;
  dl = len > 0 ? dl : S(0);
  if constexpr (Relaxed) dl *= std::min(relax[i / kStride<S>], relax[j / kStride<S>]);
  b.lambda[c] = lambda + dl;
  const S di = b.ci[c] * dl, dj = b.cj[c] * dl;
  o[i] += di * nx;
  o[i + 1] += di * ny;
  o[i + 2] += di * nz;
  o[j] -= dj * nx;
  o[j + 1] -= dj * ny;
  o[j + 2] -= dj * nz;
}

// XPBD over the independent constraints [begin, end) of one colour in gathered blocks, as
// distance_pbd_blocks: per constraint the operations of distance_xpbd in its order, so the same
// bits. Damped: the batch has damping (ColouredDistance::damped), and the gather also takes the
// motion since the sub-step's start, u = (p_i - x_i) - (p_j - x_j); without it every γ is +0,
// γ moved is +0, and its subtraction changes no value. Fresh: the multipliers are +0 (see
// distance_xpbd).
template <bool Damped, bool Fresh, bool Bilateral, class S>
CSB_INLINE void distance_xpbd_block_s(ColouredDistanceT<S>& b, Index c0, Index m, S* dx, S* dy, S* dz,
                                      const S* ux, const S* uy, const S* uz, S* s) {
  const S* rest = b.rest.data() + c0;
  alignas(64) S sense[Bilateral ? 1 : kDistanceBlock];
  if constexpr (!Bilateral) senses(b, c0, m, sense);
  const S* alpha = b.alpha.data() + c0;
  const S* gamma = b.gamma.data() + c0;
  const S* inv_den = b.inv_den.data() + c0;
  S* lambda = b.lambda.data() + c0;
#pragma omp simd
  for (Index k = 0; k < m; ++k) {
    const S l = Fresh ? S(0) : lambda[k];
    S nx, ny, nz, len;
    S dl = xpbd_distance_step<Damped, S, Fresh>(dx[k], dy[k], dz[k], Damped ? ux[k] : S(0), Damped ? uy[k] : S(0),
                                                Damped ? uz[k] : S(0), rest[k], Fresh ? S(0) : alpha[k], gamma[k],
                                                inv_den[k], l, nx, ny, nz, len);
    if constexpr (!Bilateral) {  // a bilateral constraint's Δλ is not clamped
      const S sn = sense[k];
      const S next = l + dl;
      const S clamped = sn > 0 ? std::max(next, S(0)) : std::min(next, S(0));
      dl = sn == 0 ? dl : clamped - l;
    }
    dl = len > 0 ? dl : S(0);
    lambda[k] = l + dl;
    s[k] = dl;
    dx[k] = nx, dy[k] = ny, dz[k] = nz;
  }
}

// u = (p_i - x_i) - (p_j - x_j) of constraints c0 + [k0, m), one at a time.
template <class S>
CSB_INLINE void distance_motion_gather(const ColouredDistanceT<S>& b, Index c0, Index k0, Index m, const S* r,
                                       const S* x, S* ux, S* uy, S* uz) {
  for (Index k = k0; k < m; ++k) {
    const Index i = b.i[c0 + k], j = b.j[c0 + k];
    ux[k] = (r[i] - x[i]) - (r[j] - x[j]);
    uy[k] = (r[i + 1] - x[i + 1]) - (r[j + 1] - x[j + 1]);
    uz[k] = (r[i + 2] - x[i + 2]) - (r[j + 2] - x[j + 2]);
  }
}

template <bool Damped, bool Fresh, bool Bilateral, class S>
CSB_INLINE void distance_xpbd_blocks(ColouredDistanceT<S>& b, Index begin, Index end, const S* r, S* o,
                                     const S* x) {
  constexpr Index B = kDistanceBlock;
  alignas(64) S dx[B], dy[B], dz[B], s[B];
  alignas(64) S ux[Damped ? B : 1], uy[Damped ? B : 1], uz[Damped ? B : 1];
  for (Index c0 = begin; c0 < end; c0 += B) {
    const Index m = std::min(B, end - c0);
    distance_gather(b, c0, 0, m, r, dx, dy, dz);
    if constexpr (Damped) distance_motion_gather(b, c0, 0, m, r, x, ux, uy, uz);
    distance_xpbd_block_s<Damped, Fresh, Bilateral>(b, c0, m, dx, dy, dz, ux, uy, uz, s);
    distance_scatter<true>(b, c0, 0, m, s, dx, dy, dz, o);
  }
}

#if CSB_HAS_AVX2_ROWS
// Single precision: distance_scatter_rows and distance_gather_rows eight constraints at a time in
// 256-bit registers, then four in 128-bit ones (csb/avx2_rows.hpp). The shares c_i, c_j of
// constraints c0 + [0, m4) at ci, cj: the batch's, or (XPBD, whose shares are w_i and w_j) the
// inverse masses the gather took from the particles' pads.
template <bool Xpbd>
CSB_AVX2_INLINE void distance_scatter_rows(const ColouredDistanceT<float>& b, Index c0, Index m4, const float* s,
                                           const float* vx, const float* vy, const float* vz, float* o,
                                           const float* ci, const float* cj) {
  using namespace avx2;
  const Offset* bi = as_offsets(b.i.data()) + c0;
  const Offset* bj = as_offsets(b.j.data()) + c0;
  const Index m8 = m4 - m4 % 8;
  for (Index k = 0; k < m8; k += 8) {
    const __m256 sk = _mm256_load_ps(s + k);
    const __m256 x = _mm256_load_ps(vx + k), y = _mm256_load_ps(vy + k), z = _mm256_load_ps(vz + k);
    const __m256 si = _mm256_mul_ps(_mm256_loadu_ps(ci + k), sk);
    const __m256 sj = _mm256_mul_ps(_mm256_loadu_ps(cj + k), sk);
    const Offset* at_i = bi + k;
    const Offset* at_j = bj + k;
    add8<!Xpbd>(o, at_i, _mm256_mul_ps(si, x), _mm256_mul_ps(si, y), _mm256_mul_ps(si, z));
    add8<Xpbd>(o, at_j, _mm256_mul_ps(sj, x), _mm256_mul_ps(sj, y), _mm256_mul_ps(sj, z));
  }
  for (Index k = m8; k < m4; k += 4) {
    const __m128 sk = _mm_load_ps(s + k);
    const __m128 x = _mm_load_ps(vx + k), y = _mm_load_ps(vy + k), z = _mm_load_ps(vz + k);
    const __m128 si = _mm_mul_ps(_mm_loadu_ps(ci + k), sk);
    const __m128 sj = _mm_mul_ps(_mm_loadu_ps(cj + k), sk);
    const Offset* at_i = bi + k;
    const Offset* at_j = bj + k;
    add_rows<!Xpbd>(o, at_i, _mm_mul_ps(si, x), _mm_mul_ps(si, y), _mm_mul_ps(si, z));
    add_rows<Xpbd>(o, at_j, _mm_mul_ps(sj, x), _mm_mul_ps(sj, y), _mm_mul_ps(sj, z));
  }
}

// d = p_i - p_j (and, Damped, u = (p_i - x_i) - (p_j - x_j)) of constraints c0 + [0, m4) as rows,
// eight at a time, then four; Pads: also the particles' pads (the single-precision step keeps
// their inverse masses there) into wi, wj.
template <bool Damped, bool Pads = false>
CSB_AVX2_INLINE void distance_gather_rows(const ColouredDistanceT<float>& b, Index c0, Index m4, const float* r,
                                          const float* x, float* dx, float* dy, float* dz, float* ux, float* uy,
                                          float* uz, float* wi = nullptr, float* wj = nullptr) {
  using namespace avx2;
  const Offset* bi = as_offsets(b.i.data()) + c0;
  const Offset* bj = as_offsets(b.j.data()) + c0;
  const Index m8 = m4 - m4 % 8;
  for (Index k = 0; k < m8; k += 8) {
    const Offset* at_i = bi + k;
    const Offset* at_j = bj + k;
    __m256 ix, iy, iz, iw, jx, jy, jz, jw;
    gather8(r, at_i, ix, iy, iz, iw);
    gather8(r, at_j, jx, jy, jz, jw);
    if constexpr (Pads) {
      _mm256_store_ps(wi + k, iw);
      _mm256_store_ps(wj + k, jw);
    }
    _mm256_store_ps(dx + k, _mm256_sub_ps(ix, jx));
    _mm256_store_ps(dy + k, _mm256_sub_ps(iy, jy));
    _mm256_store_ps(dz + k, _mm256_sub_ps(iz, jz));
    if constexpr (Damped) {
      __m256 sx, sy, sz, tx, ty, tz;
      gather8(x, at_i, sx, sy, sz);
      gather8(x, at_j, tx, ty, tz);
      _mm256_store_ps(ux + k, _mm256_sub_ps(_mm256_sub_ps(ix, sx), _mm256_sub_ps(jx, tx)));
      _mm256_store_ps(uy + k, _mm256_sub_ps(_mm256_sub_ps(iy, sy), _mm256_sub_ps(jy, ty)));
      _mm256_store_ps(uz + k, _mm256_sub_ps(_mm256_sub_ps(iz, sz), _mm256_sub_ps(jz, tz)));
    }
  }
  for (Index k = m8; k < m4; k += 4) {
    __m128 d[4], u[4];
    for (int l = 0; l < 4; ++l) {
      const __m128 pi = load_xyz(r + bi[k + l]), pj = load_xyz(r + bj[k + l]);
      d[l] = _mm_sub_ps(pi, pj);
      if constexpr (Damped)
        u[l] = _mm_sub_ps(_mm_sub_ps(pi, load_xyz(x + bi[k + l])), _mm_sub_ps(pj, load_xyz(x + bj[k + l])));
    }
    __m128 rx, ry, rz;
    rows(d[0], d[1], d[2], d[3], rx, ry, rz);
    _mm_store_ps(dx + k, rx), _mm_store_ps(dy + k, ry), _mm_store_ps(dz + k, rz);
    if constexpr (Pads)
      for (int l = 0; l < 4; ++l) wi[k + l] = r[bi[k + l] + 3], wj[k + l] = r[bj[k + l] + 3];
    if constexpr (Damped) {
      rows(u[0], u[1], u[2], u[3], rx, ry, rz);
      _mm_store_ps(ux + k, rx), _mm_store_ps(uy + k, ry), _mm_store_ps(uz + k, rz);
    }
  }
}

// The blocks with AVX2 gathers and scatters (distance_gather_rows, distance_scatter_rows: four
// doubles or eight floats at a time), the rest of a block one at a time; the arithmetic in SIMD
// lanes. Per constraint the operations of the portable blocks, so the same bits.
template <bool Approx, bool Bilateral, class S>
CSB_AVX2_INLINE void distance_pbd_blocks_rows(const ColouredDistanceT<S>& b, Index begin, Index end, const S* r,
                                              S* o) {
  constexpr Index B = kDistanceBlock;
  alignas(64) S dx[B], dy[B], dz[B], s[B];
  for (Index c0 = begin; c0 < end; c0 += B) {
    const Index m = std::min(B, end - c0), m4 = m - m % 4;
    distance_gather_rows<false>(b, c0, m4, r, static_cast<const S*>(nullptr), dx, dy, dz, static_cast<S*>(nullptr),
                                static_cast<S*>(nullptr), static_cast<S*>(nullptr));
    distance_gather(b, c0, m4, m, r, dx, dy, dz);
    distance_pbd_block_s<Approx, Bilateral>(b, c0, m, dx, dy, dz, s);
    distance_scatter_rows<false>(b, c0, m4, s, dx, dy, dz, o, b.ci.data() + c0, b.cj.data() + c0);
    distance_scatter<false>(b, c0, m4, m, s, dx, dy, dz, o);
  }
}

template <bool Damped, bool Fresh, bool Bilateral, class S>
CSB_AVX2_INLINE void distance_xpbd_blocks_rows(ColouredDistanceT<S>& b, Index begin, Index end, const S* r, S* o,
                                               const S* x) {
  constexpr Index B = kDistanceBlock;
  constexpr bool single = std::is_same_v<S, float>;  // XPBD's shares w_i, w_j from the pads
  alignas(64) S dx[B], dy[B], dz[B], s[B];
  alignas(64) S ux[Damped ? B : 1], uy[Damped ? B : 1], uz[Damped ? B : 1];
  alignas(64) S wi[single ? B : 1], wj[single ? B : 1];
  for (Index c0 = begin; c0 < end; c0 += B) {
    const Index m = std::min(B, end - c0), m4 = m - m % 4;
    distance_gather_rows<Damped, single>(b, c0, m4, r, x, dx, dy, dz, ux, uy, uz, wi, wj);
    distance_gather(b, c0, m4, m, r, dx, dy, dz);
    if constexpr (Damped) distance_motion_gather(b, c0, m4, m, r, x, ux, uy, uz);
    distance_xpbd_block_s<Damped, Fresh, Bilateral>(b, c0, m, dx, dy, dz, ux, uy, uz, s);
    distance_scatter_rows<true>(b, c0, m4, s, dx, dy, dz, o, single ? wi : b.ci.data() + c0,
                                single ? wj : b.cj.data() + c0);
    distance_scatter<true>(b, c0, m4, m, s, dx, dy, dz, o);
  }
}
#endif
#if defined(CSB_DISTANCE_AVX2)
// The row blocks compiled for AVX2 in the portable build, taken when the processor has it (see
// coloured_bending.cpp).
template <bool Approx, bool Bilateral, class S>
__attribute__((target("avx2"))) void distance_pbd_blocks_avx2(const ColouredDistanceT<S>& b, Index begin, Index end,
                                                               const S* r, S* o) {
  distance_pbd_blocks_rows<Approx, Bilateral>(b, begin, end, r, o);
}
template <bool Damped, bool Fresh, bool Bilateral, class S>
__attribute__((target("avx2"))) void distance_xpbd_blocks_avx2(ColouredDistanceT<S>& b, Index begin, Index end,
                                                                const S* r, S* o, const S* x) {
  distance_xpbd_blocks_rows<Damped, Fresh, Bilateral>(b, begin, end, r, o, x);
}
#endif

// PBD and Jakobsen over the independent constraints [begin, end) of one colour: the blocks, with
// AVX2 gathers and scatters where the processor has them; in double, Jakobsen's square-root
// approximation one constraint per SIMD lane.
template <bool Approx, class S>
inline void distance_pbd_range(const ColouredDistanceT<S>& b, Index begin, Index end, const S* r, S* o) {
  if constexpr (Approx && std::is_same_v<S, Real>) {
#pragma omp simd
    for (Index c = begin; c < end; ++c) distance_pbd<true>(b, c, r, o);
  } else {
    const auto run = [&](auto bilateral) {
      constexpr bool L = decltype(bilateral)::value;
#if defined(CSB_DISTANCE_AVX2)
      if (kernels_use_avx2()) return distance_pbd_blocks_avx2<Approx, L>(b, begin, end, r, o);
#elif CSB_HAS_AVX2_ROWS && defined(__AVX2__)  // a native build for a processor with AVX2
      return distance_pbd_blocks_rows<Approx, L>(b, begin, end, r, o);
#endif
      distance_pbd_blocks<Approx, L>(b, begin, end, r, o);
    };
    b.bilateral ? run(std::true_type{}) : run(std::false_type{});
  }
}

// XPBD over the independent constraints [begin, end) of one colour: the blocks, with AVX2 gathers
// and scatters where the processor has them. Fresh: the multipliers are +0 (see distance_xpbd).
template <bool Fresh, class S>
inline void distance_xpbd_range(ColouredDistanceT<S>& b, Index begin, Index end, const S* r, S* o, const S* x) {
  const auto run = [&](auto damped, auto bilateral) {
    constexpr bool D = decltype(damped)::value, L = decltype(bilateral)::value;
#if defined(CSB_DISTANCE_AVX2)
    if (kernels_use_avx2()) return distance_xpbd_blocks_avx2<D, Fresh, L>(b, begin, end, r, o, x);
#elif CSB_HAS_AVX2_ROWS && defined(__AVX2__)  // a native build for a processor with AVX2
    return distance_xpbd_blocks_rows<D, Fresh, L>(b, begin, end, r, o, x);
#endif
    distance_xpbd_blocks<D, Fresh, L>(b, begin, end, r, o, x);
  };
  using Yes = std::true_type;
  using No = std::false_type;
  if (b.damped)
    b.bilateral ? run(Yes{}, Yes{}) : run(Yes{}, No{});
  else
    b.bilateral ? run(No{}, Yes{}) : run(No{}, No{});
}

// Dihedral bending: csb/solver/coloured_bending.hpp (SIMD blocks, polynomial atan2).

// A scalar kernel of constraints/ called as one out-of-line function with every call in it
// inlined. Left to itself GCC inlines the XPBD tet volume and dihedral bending kernels into the
// sweeps below and then, past its growth limits, keeps their geometry and Eigen 3-vector updates
// out of line (a call per particle): XPBD on a soft cube stepped 7 % slower, XPBD's averaged
// Jacobi on a cloth 3-4 % (scripts/compare_builds.py, against the build before the stepper was
// split into files, whose one larger file led GCC to other choices). PBD's volume kernel is left
// to GCC: through flat it made XPBD on a cloth 3.5 % slower. The same operations, the same bits.
template <auto Kernel, class... Args>
[[gnu::noinline, gnu::flatten]] Real flat(Args&&... args) {
  return Kernel(std::forward<Args>(args)...);
}

// The particles of a double batch's element from their offsets (ColouredFourT::q).
inline std::array<Index, 4> particles_of(const std::array<Index, 4>& q) {
  return {q[0] / kStride<Real>, q[1] / kStride<Real>, q[2] / kStride<Real>, q[3] / kStride<Real>};
}

// Tet volume: the kernels of constraints/volume.hpp, on local copies for Jacobi.
// relax (XPBD with averaged Jacobi, else null): Δλ and the corrections scaled by the
// constraint's relaxation (PbdStepper::set_relaxation).
template <Method M, bool Jacobi>
CSB_INLINE void volume_one(ColouredFour& b, Index k, const Real* r, Real* o, const Real* x, const Real* relax) {
  const auto& q = b.q[k];
  const auto& w = b.w[k];
  Real local[4][3];
  Real* at[4];
  for (int s = 0; s < 4; ++s) {
    if constexpr (Jacobi) {
      for (int e = 0; e < 3; ++e) local[s][e] = r[q[s] + e];
      at[s] = local[s];
    } else {
      at[s] = o + q[s];
    }
  }
  Real om = 1;
  if constexpr (M == Method::Xpbd) {
    const Real before = b.lambda[k];
    flat<project_volume_xpbd>(at[0], at[1], at[2], at[3], x + q[0], x + q[1], x + q[2], x + q[3], w[0], w[1], w[2],
                              w[3], b.rest[k], b.alpha[k], b.gamma[k], b.lambda[k]);
    if (Jacobi && relax) {
      om = relaxation(relax, particles_of(q));
      relax_multiplier(b.lambda[k], before, om);
    }
  } else {
    project_volume(at[0], at[1], at[2], at[3], w[0], w[1], w[2], w[3], b.rest[k], b.k[k]);
  }
  if constexpr (Jacobi)
    for (int s = 0; s < 4; ++s)
      for (int e = 0; e < 3; ++e) o[q[s] + e] += om * (local[s][e] - r[q[s] + e]);
}

// Dihedral bending with XPBD and averaged Jacobi: the scalar kernel of constraints/bending.hpp
// on local copies, relaxed like volume_one (the blocks of coloured_bending.hpp serve every other
// case).
CSB_INLINE void bending_xpbd_relaxed(ColouredFour& b, Index k, const Real* r, Real* o, const Real* x,
                                     const Real* relax) {
  const auto& q = b.q[k];
  const auto& w = b.w[k];
  Real local[4][3];
  for (int s = 0; s < 4; ++s)
    for (int e = 0; e < 3; ++e) local[s][e] = r[q[s] + e];
  const Real before = b.lambda[k];
  flat<project_bending_xpbd>(local[0], local[1], local[2], local[3], x + q[0], x + q[1], x + q[2], x + q[3], w[0],
                            w[1], w[2], w[3], b.rest[k], b.alpha[k], b.gamma[k], b.lambda[k]);
  const Real om = relaxation(relax, particles_of(q));
  relax_multiplier(b.lambda[k], before, om);
  for (int s = 0; s < 4; ++s)
    for (int e = 0; e < 3; ++e) o[q[s] + e] += om * (local[s][e] - r[q[s] + e]);
}

template <Method M, bool Jacobi>
CSB_INLINE void attachment_one(ColouredAttachments& b, Index k, const Real* r, Real* o, const Real* x,
                               const Real* relax) {
  const Index i = b.i[k];
  Real local[3];
  Real* at = o + 3 * i;
  if constexpr (Jacobi) {
    for (int e = 0; e < 3; ++e) local[e] = r[3 * i + e];
    at = local;
  }
  Real om = 1;
  if constexpr (M == Method::Xpbd) {
    const Real before = b.lambda[k];
    project_attachment_xpbd(at, x + 3 * i, b.w[k], b.target[k].data(), b.alpha[k], b.gamma[k], b.lambda[k]);
    if (Jacobi && relax) {
      om = relax[i];
      relax_multiplier(b.lambda[k], before, om);
    }
  } else {
    project_attachment(at, b.w[k], b.target[k].data(), b.k[k]);
  }
  if constexpr (Jacobi)
    for (int e = 0; e < 3; ++e) o[3 * i + e] += om * (local[e] - r[3 * i + e]);
}

}  // namespace csb::coloured_kernels
