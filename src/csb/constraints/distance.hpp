// csb — distance constraint kernel (stretch, springs, links of a chain).
//
// Müller, Heidelberger, Hennix, Ratcliff 2007, "Position Based Dynamics", §3.3, the worked
// example of a distance constraint:
//
//   C(p1, p2)  = |p1 - p2| - d
//   grad_p1 C  =  n,   grad_p2 C = -n,   n = (p1 - p2) / |p1 - p2|
//   Δp1 = -k  w1 / (w1 + w2) C n
//   Δp2 = +k  w2 / (w1 + w2) C n
//
// with w = 1/m the inverse masses and k in [0, 1] the (possibly iteration-corrected) stiffness.
// Since m1 Δp1 + m2 Δp2 = 0 and both are parallel to p1 - p2, the correction conserves
// linear and angular momentum (§3.3).
//
// `sense` makes the same kernel an equality or an inequality constraint, the proposal's
// project(equality, stiffness, inverse_mass):
//    0  C  = 0   (a rod or stretch edge)
//   +1  C >= 0   (keep at least d apart: only pushes)
//   -1  C <= 0   (keep at most d apart, a tether or rope: only pulls)
// The violation of an inequality is the part of C outside its half line; it is computed without
// a branch: violation = C - sense * max(sense * C, 0).
#pragma once

#include "csb/types.hpp"

#include <algorithm>
#include <cmath>

namespace csb {

inline Real distance_violation(Real c, int sense) {
  return c - sense * std::max(sense * c, Real(0));
}

// Projects one distance constraint in place; returns its violation before the projection (m).
// Coincident particles have no gradient direction and are left alone.
inline Real project_distance(Real* p1, Real* p2, Real w1, Real w2, Real rest_length, Real stiffness, int sense) {
  const Real dx = p1[0] - p2[0], dy = p1[1] - p2[1], dz = p1[2] - p2[2];
  const Real len = std::sqrt(dx * dx + dy * dy + dz * dz);
  const Real violation = distance_violation(len - rest_length, sense);
  const Real wsum = w1 + w2;
  if (wsum <= 0 || len <= 0) return violation;
  // s = k C / ((w1 + w2) |p1 - p2|): the 1/|p1 - p2| normalises n.
  const Real s = stiffness * violation / (wsum * len);
  p1[0] -= w1 * s * dx;
  p1[1] -= w1 * s * dy;
  p1[2] -= w1 * s * dz;
  p2[0] += w2 * s * dx;
  p2[1] += w2 * s * dy;
  p2[2] += w2 * s * dz;
  return violation;
}

}  // namespace csb
