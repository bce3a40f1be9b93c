// csb — moving particle positions into and out of AVX2 lanes.
//
// Positions are stored x, y, z per particle; the blocked kernels want them as rows (x of four
// constraints in one register, then y, then z). Done one coordinate at a time that is twelve
// scalar loads and stores per particle of a bending block, half of the kernel's time
// (papers/benchmarks.md). Here a particle is one masked 256-bit load ([x, y, z, 0]; the fourth
// double is never read, so the last particle of an array is safe), four of them become three
// rows in seven shuffles, and a correction goes back as a 128-bit (x, y) and a scalar (z)
// read-modify-write (add_rows), or a new position as a 128-bit and a scalar store (store_rows):
// the constraints of a colour share no particle, and nothing outside a particle's three doubles
// is written, so another thread's particles next to it are untouched.
// Only data moves here; every sum is the same IEEE operation on the same operands as in the
// scalar loops, so the results keep their bits.
//
// Single precision has the same functions on four floats in 128-bit registers, a particle one
// load or store (the kernels' arithmetic still runs eight lanes in 256-bit ones).
// These functions are compiled for AVX2 (target attribute) and inlined into the kernels' AVX2
// copies, which run only when the processor has AVX2 (coloured_bending.cpp).
#pragma once

#include "csb/types.hpp"

#if defined(__GNUC__) && defined(__x86_64__)
#define CSB_HAS_AVX2_ROWS 1
#include <immintrin.h>

#define CSB_AVX2_INLINE inline __attribute__((target("avx2"), always_inline))

namespace csb::avx2 {

// A batch's particle offsets (ColouredDistanceT::i and j, ColouredFourT::q) as the copies here
// address with them: they are >= 0 and fit 31 bits (build_coloured refuses larger models), so
// read as unsigned 32-bit numbers they widen to 64-bit addresses with no sign extension, an
// instruction fewer a particle loaded or stored. (An integer type and its unsigned counterpart
// may alias: the batches' Index arrays are read in place.)
using Offset = std::uint32_t;
CSB_AVX2_INLINE const Offset* as_offsets(const Index* p) { return reinterpret_cast<const Offset*>(p); }

// The particle at p as [x, y, z, 0], reading p[0..2] only.
CSB_AVX2_INLINE __m256d load_xyz(const Real* p) {
  return _mm256_maskload_pd(p, _mm256_setr_epi64x(-1, -1, -1, 0));
}

// Rows x, y, z of four [x, y, z, ·] vectors (lane l from v_l).
CSB_AVX2_INLINE void rows(__m256d v0, __m256d v1, __m256d v2, __m256d v3, __m256d& x, __m256d& y, __m256d& z) {
  const __m256d t0 = _mm256_unpacklo_pd(v0, v1);  // x0 x1 z0 z1
  const __m256d t1 = _mm256_unpackhi_pd(v0, v1);  // y0 y1 ·  ·
  const __m256d t2 = _mm256_unpacklo_pd(v2, v3);  // x2 x3 z2 z3
  const __m256d t3 = _mm256_unpackhi_pd(v2, v3);  // y2 y3 ·  ·
  x = _mm256_permute2f128_pd(t0, t2, 0x20);
  y = _mm256_permute2f128_pd(t1, t3, 0x20);
  z = _mm256_permute2f128_pd(t0, t2, 0x31);
}

// Rows of four consecutive [a, b, c, d] quadruples at q (16 doubles): a, b, c, d of each.
CSB_AVX2_INLINE void rows4(const Real* q, __m256d& a, __m256d& b, __m256d& c, __m256d& d) {
  const __m256d v0 = _mm256_loadu_pd(q), v1 = _mm256_loadu_pd(q + 4), v2 = _mm256_loadu_pd(q + 8),
                v3 = _mm256_loadu_pd(q + 12);
  const __m256d t0 = _mm256_unpacklo_pd(v0, v1), t1 = _mm256_unpackhi_pd(v0, v1);
  const __m256d t2 = _mm256_unpacklo_pd(v2, v3), t3 = _mm256_unpackhi_pd(v2, v3);
  a = _mm256_permute2f128_pd(t0, t2, 0x20);
  b = _mm256_permute2f128_pd(t1, t3, 0x20);
  c = _mm256_permute2f128_pd(t0, t2, 0x31);
  d = _mm256_permute2f128_pd(t1, t3, 0x31);
}

// o + d (Subtract: o - d), lane by lane: a scalar, or a vector of GCC's vector types (__m128d,
// __m128, __m256, whose + and - are the lanes' IEEE addition and subtraction).
template <bool Subtract, class V>
CSB_AVX2_INLINE V update(V o, V d) {
  if constexpr (Subtract)
    return o - d;
  else
    return o + d;
}

// Lane l of the rows (dx, dy, dz) added to (Subtract: taken from) the particle at o + at[l].
template <bool Subtract = false, class Off>
CSB_AVX2_INLINE void add_rows(Real* o, const Off at[4], __m256d dx, __m256d dy, __m256d dz) {
  const __m256d t0 = _mm256_unpacklo_pd(dx, dy);  // x0 y0 x2 y2
  const __m256d t1 = _mm256_unpackhi_pd(dx, dy);  // x1 y1 x3 y3
  const __m128d xy[4] = {_mm256_castpd256_pd128(t0), _mm256_castpd256_pd128(t1), _mm256_extractf128_pd(t0, 1),
                         _mm256_extractf128_pd(t1, 1)};
  alignas(32) Real z[4];
  _mm256_store_pd(z, dz);
  for (int l = 0; l < 4; ++l) {
    Real* p = o + at[l];
    _mm_storeu_pd(p, update<Subtract>(_mm_loadu_pd(p), xy[l]));
    p[2] = update<Subtract>(p[2], z[l]);
  }
}

// Lane l of the rows (x, y, z) written to the particle at o + at[l] (its three doubles only).
template <class Off>
CSB_AVX2_INLINE void store_rows(Real* o, const Off at[4], __m256d x, __m256d y, __m256d z) {
  const __m256d t0 = _mm256_unpacklo_pd(x, y);  // x0 y0 x2 y2
  const __m256d t1 = _mm256_unpackhi_pd(x, y);  // x1 y1 x3 y3
  _mm_storeu_pd(o + at[0], _mm256_castpd256_pd128(t0));
  _mm_storeu_pd(o + at[1], _mm256_castpd256_pd128(t1));
  _mm_storeu_pd(o + at[2], _mm256_extractf128_pd(t0, 1));
  _mm_storeu_pd(o + at[3], _mm256_extractf128_pd(t1, 1));
  const __m128d z01 = _mm256_castpd256_pd128(z), z23 = _mm256_extractf128_pd(z, 1);
  _mm_store_sd(o + at[0] + 2, z01);
  _mm_storeh_pd(o + at[1] + 2, z01);
  _mm_store_sd(o + at[2] + 2, z23);
  _mm_storeh_pd(o + at[3] + 2, z23);
}

// Single precision, four particles in 128-bit registers. Positions are x, y, z and a pad per
// particle (kStride<float> = 4, solver/coloured.hpp; the single-precision step keeps the
// particle's inverse mass there): a particle is one 128-bit load, and one 128-bit store writes it
// back with its pad.
CSB_AVX2_INLINE __m128 load_xyz(const float* p) { return _mm_loadu_ps(p); }

// Rows x, y, z and pads w of four [x, y, z, w] vectors (lane l from v_l).
CSB_AVX2_INLINE void rows(__m128 v0, __m128 v1, __m128 v2, __m128 v3, __m128& x, __m128& y, __m128& z, __m128& w) {
  const __m128 t0 = _mm_unpacklo_ps(v0, v1);  // x0 x1 y0 y1
  const __m128 t1 = _mm_unpacklo_ps(v2, v3);  // x2 x3 y2 y3
  const __m128 t2 = _mm_unpackhi_ps(v0, v1);  // z0 z1 w0 w1
  const __m128 t3 = _mm_unpackhi_ps(v2, v3);  // z2 z3 w2 w3
  x = _mm_movelh_ps(t0, t1);
  y = _mm_movehl_ps(t1, t0);
  z = _mm_movelh_ps(t2, t3);
  w = _mm_movehl_ps(t3, t2);
}

// The same without the pads (the compiler drops their shuffle).
CSB_AVX2_INLINE void rows(__m128 v0, __m128 v1, __m128 v2, __m128 v3, __m128& x, __m128& y, __m128& z) {
  __m128 w;
  rows(v0, v1, v2, v3, x, y, z, w);
}

// The four [x, y, z, w] vectors of rows x, y, z and w (the pads).
CSB_AVX2_INLINE void particles(__m128 x, __m128 y, __m128 z, __m128 w, __m128 v[4]) {
  v[0] = x, v[1] = y, v[2] = z, v[3] = w;
  _MM_TRANSPOSE4_PS(v[0], v[1], v[2], v[3]);
}

// Lane l of the rows (dx, dy, dz) added to (Subtract: taken from) the particle at o + at[l].
template <bool Subtract = false, class Off>
CSB_AVX2_INLINE void add_rows(float* o, const Off at[4], __m128 dx, __m128 dy, __m128 dz) {
  __m128 d[4];
  particles(dx, dy, dz, _mm_setzero_ps(), d);  // the pad + 0: unchanged
  for (int l = 0; l < 4; ++l) _mm_storeu_ps(o + at[l], update<Subtract>(_mm_loadu_ps(o + at[l]), d[l]));
}

// Lane l of the rows (x, y, z, pad) written to the particle at o + at[l].
template <class Off>
CSB_AVX2_INLINE void store_rows(float* o, const Off at[4], __m128 x, __m128 y, __m128 z, __m128 w) {
  __m128 v[4];
  particles(x, y, z, w, v);
  for (int l = 0; l < 4; ++l) _mm_storeu_ps(o + at[l], v[l]);
}

// Eight particles at a time in 256-bit registers (lane l from the particle at o + at[l]; lanes
// 0-3 and 4-7 are two 128-bit halves, so particles l and l + 4 share a register before the
// transpose): six shuffles and four inserts for eight particles where two groups of four take
// twelve shuffles, and the way back likewise.
CSB_AVX2_INLINE __m256 load_pair(const float* a, const float* b) {
  return _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(a)), _mm_loadu_ps(b), 1);
}

// Rows x, y, z and the pads w of the four [x, y, z, w] register pairs (lane l from v_l); a caller
// that does not use w leaves its shuffle to the compiler to drop.
CSB_AVX2_INLINE void rows8(__m256 v0, __m256 v1, __m256 v2, __m256 v3, __m256& x, __m256& y, __m256& z,
                           __m256& w) {
  const __m256 t0 = _mm256_unpacklo_ps(v0, v1);  // x0 x1 y0 y1 | x4 x5 y4 y5
  const __m256 t1 = _mm256_unpacklo_ps(v2, v3);  // x2 x3 y2 y3 | x6 x7 y6 y7
  const __m256 t2 = _mm256_unpackhi_ps(v0, v1);  // z0 z1 w0 w1 | z4 z5 w4 w5
  const __m256 t3 = _mm256_unpackhi_ps(v2, v3);  // z2 z3 w2 w3 | z6 z7 w6 w7
  x = _mm256_shuffle_ps(t0, t1, _MM_SHUFFLE(1, 0, 1, 0));
  y = _mm256_shuffle_ps(t0, t1, _MM_SHUFFLE(3, 2, 3, 2));
  z = _mm256_shuffle_ps(t2, t3, _MM_SHUFFLE(1, 0, 1, 0));
  w = _mm256_shuffle_ps(t2, t3, _MM_SHUFFLE(3, 2, 3, 2));
}

// Rows x, y, z and pads w of the eight particles at o + at[l].
template <class Off>
CSB_AVX2_INLINE void gather8(const float* o, const Off at[8], __m256& x, __m256& y, __m256& z, __m256& w) {
  rows8(load_pair(o + at[0], o + at[4]), load_pair(o + at[1], o + at[5]), load_pair(o + at[2], o + at[6]),
        load_pair(o + at[3], o + at[7]), x, y, z, w);
}
// The same without the pads.
template <class Off>
CSB_AVX2_INLINE void gather8(const float* o, const Off at[8], __m256& x, __m256& y, __m256& z) {
  __m256 w;
  gather8(o, at, x, y, z, w);
}

// The [x, y, z, w] vectors of rows x, y, z and pads w: v[l] holds particles l and l + 4.
CSB_AVX2_INLINE void particles8(__m256 x, __m256 y, __m256 z, __m256 w, __m256 v[4]) {
  const __m256 t0 = _mm256_unpacklo_ps(x, y);  // x0 y0 x1 y1 | x4 y4 x5 y5
  const __m256 t1 = _mm256_unpackhi_ps(x, y);  // x2 y2 x3 y3 | x6 y6 x7 y7
  const __m256 t2 = _mm256_unpacklo_ps(z, w);  // z0 w0 z1 w1 | z4 w4 z5 w5
  const __m256 t3 = _mm256_unpackhi_ps(z, w);  // z2 w2 z3 w3 | z6 w6 z7 w7
  v[0] = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(1, 0, 1, 0));
  v[1] = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(3, 2, 3, 2));
  v[2] = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(1, 0, 1, 0));
  v[3] = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(3, 2, 3, 2));
}

// Lane l of the rows (x, y, z, pad) written to the particle at o + at[l].
template <class Off>
CSB_AVX2_INLINE void store8(float* o, const Off at[8], __m256 x, __m256 y, __m256 z, __m256 w) {
  __m256 v[4];
  particles8(x, y, z, w, v);
  for (int l = 0; l < 4; ++l) {
    _mm_storeu_ps(o + at[l], _mm256_castps256_ps128(v[l]));
    _mm_storeu_ps(o + at[l + 4], _mm256_extractf128_ps(v[l], 1));
  }
}

// Lane l of the rows (dx, dy, dz) added to (Subtract: taken from) the particle at o + at[l].
template <bool Subtract = false, class Off>
CSB_AVX2_INLINE void add8(float* o, const Off at[8], __m256 dx, __m256 dy, __m256 dz) {
  __m256 d[4];
  particles8(dx, dy, dz, _mm256_setzero_ps(), d);  // the pad + 0: unchanged
  for (int l = 0; l < 4; ++l) {
    const __m256 sum = update<Subtract>(load_pair(o + at[l], o + at[l + 4]), d[l]);
    _mm_storeu_ps(o + at[l], _mm256_castps256_ps128(sum));
    _mm_storeu_ps(o + at[l + 4], _mm256_extractf128_ps(sum, 1));
  }
}

}  // namespace csb::avx2

#else
#define CSB_HAS_AVX2_ROWS 0
#endif
