// csb — a branch-free, deterministic atan2 for SIMD kernels.
//
// libm's atan2 is a call the compiler cannot put in SIMD lanes (no vector variant without
// -ffast-math), and it was 22 % of a cloth frame. This one is a pure function of its two inputs
// built from IEEE +, -, *, /, comparisons and selects only, so it gives the same bits in a
// scalar register and in any SIMD lane, whatever the thread count (no FMA: the library is built
// with -ffp-contract=off).
//
// Reduction (Cephes atan, S. L. Moshier): with m = max(|x|, |y|), n = min(|x|, |y|),
//   u = n / m                     if n <= 0.66 m,   atan(n/m) = atan(u)
//   u = (n - m) / (n + m) ∈ (-0.205, 0]  otherwise,   atan(n/m) = π/4 + atan(u)
// (one division either way; n - m is exact there by Sterbenz's lemma), then Cephes' degree 4/5
// rational approximation atan(u) = u + u z P(z)/Q(z), z = u², whose peak relative error on
// |u| <= 0.66 is 2.6e-18, far below the rounding of the operations themselves. The octant is
// undone with selects: π/2 - r if |y| > |x|, π - r if x is negative (or -0), and the sign of y.
// π/4, π/2 and π are added as a double plus its rounding error, as Cephes does. In float (the
// single-precision solver) the same formula runs on the constants rounded to float: a few units
// in float's last place.
//
// Accuracy against std::atan2 (tests/test_kernels.py, dense sweeps over all quadrants, ±0,
// near ±π, tiny and huge ratios): a few units in the last place (max |error| ~4e-16 rad), so the
// physics is unchanged. Conventions of std::atan2 for ±0 are kept (atan2(±0, +0) = ±0,
// atan2(±0, -0) = ±π); NaN in, NaN out; both arguments infinite gives NaN (std: ±π/4, ±3π/4).
#pragma once

#include "csb/types.hpp"

#include <cmath>

namespace csb {

#if defined(__GNUC__)
#define CSB_ATAN2_INLINE inline __attribute__((always_inline))
#else
#define CSB_ATAN2_INLINE inline
#endif

template <class S>
CSB_ATAN2_INLINE S atan2_rational(S y, S x) {
  constexpr S P0 = -8.750608600031904122785e-1, P1 = -1.615753718733365076637e1,
                 P2 = -7.500855792314704667340e1, P3 = -1.228866684490136173410e2,
                 P4 = -6.485021904942025371773e1;
  constexpr S Q0 = 2.485846490142306297962e1, Q1 = 1.650270098316988542046e2, Q2 = 4.328810604912902668951e2,
                 Q3 = 4.853903996359136964868e2, Q4 = 1.945506571482613964425e2;
  constexpr S pi = 3.14159265358979323846, pi_lo = 1.2246467991473531772e-16;  // π = pi + pi_lo
  constexpr S pi_2 = 1.57079632679489661923, pi_2_lo = 6.123233995736765886130e-17;
  constexpr S pi_4 = 7.85398163397448309616e-1, pi_4_lo = 3.061616997868382943065e-17;
  const S ax = std::fabs(x), ay = std::fabs(y);
  const bool swap = ay > ax;
  const S m = swap ? ay : ax, n = swap ? ax : ay;
  const bool mid = n > S(0.66) * m;
  const S num = mid ? n - m : n;
  const S den0 = mid ? n + m : m;
  const S den = den0 == 0 ? S(1) : den0;  // x = y = 0: u = 0 (NaN still propagates)
  const S u = num / den;
  const S z = u * u;
  const S p = (((P0 * z + P1) * z + P2) * z + P3) * z + P4;
  const S q = ((((z + Q0) * z + Q1) * z + Q2) * z + Q3) * z + Q4;
  S r = u + u * (z * p / q);
  r = mid ? pi_4 + (r + pi_4_lo) : r;
  r = swap ? (pi_2 - r) + pi_2_lo : r;
  r = std::copysign(S(1), x) < 0 ? (pi - r) + pi_lo : r;
  return std::copysign(r, y);
}

}  // namespace csb
