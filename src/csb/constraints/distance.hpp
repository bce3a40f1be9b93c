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

// p1 -= w1 s d, p2 += w2 s d: a correction along d = p1 - p2, shared by inverse mass.
inline void move_apart(Real* p1, Real* p2, Real w1, Real w2, Real s, Real dx, Real dy, Real dz) {
  p1[0] -= w1 * s * dx;
  p1[1] -= w1 * s * dy;
  p1[2] -= w1 * s * dz;
  p2[0] += w2 * s * dx;
  p2[1] += w2 * s * dy;
  p2[2] += w2 * s * dz;
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
  move_apart(p1, p2, w1, w2, stiffness * violation / (wsum * len), dx, dy, dz);
  return violation;
}

// XPBD (Macklin, Müller, Chentanez 2016): the same constraint with compliance α (m/N). With
// α̃ = α/h², the damping γ = α̃ β̃ / h = α β / h of their Eq. (26) (β in N s/m) and the
// multiplier λ accumulated over the iterations of one (sub)step, Eq. (18) and (26) give
//
//   Δλ = (-C - α̃ λ - γ ∇C·(p - x_n)) / ((1 + γ)(w1 + w2) + α̃),   Δp1 = w1 n Δλ,  Δp2 = -w2 n Δλ
//
// x_n are the positions at the start of the (sub)step. For an inequality the accumulated λ is
// clamped to its sign (λ >= 0 for C >= 0, λ <= 0 for C <= 0), so the constraint only pushes
// (or pulls) while it is violated. λ/h² is the constraint force (N). Returns the violation.
inline Real project_distance_xpbd(Real* p1, Real* p2, const Real* x1, const Real* x2, Real w1, Real w2,
                                  Real rest_length, Real alpha_tilde, Real gamma, Real& lambda, int sense) {
  const Real dx = p1[0] - p2[0], dy = p1[1] - p2[1], dz = p1[2] - p2[2];
  const Real len = std::sqrt(dx * dx + dy * dy + dz * dz);
  const Real c = len - rest_length;
  const Real violation = distance_violation(c, sense);
  const Real wsum = w1 + w2;
  if (wsum <= 0 || len <= 0) return violation;
  const Real nx = dx / len, ny = dy / len, nz = dz / len;
  // The damping term reads the start positions; without damping it is skipped.
  const Real moved = gamma == 0 ? Real(0)
                                : nx * ((p1[0] - x1[0]) - (p2[0] - x2[0])) + ny * ((p1[1] - x1[1]) - (p2[1] - x2[1])) +
                                      nz * ((p1[2] - x1[2]) - (p2[2] - x2[2]));
  Real dl = (-c - alpha_tilde * lambda - gamma * moved) / ((1 + gamma) * wsum + alpha_tilde);
  if (sense != 0) {
    const Real next = sense > 0 ? std::max(lambda + dl, Real(0)) : std::min(lambda + dl, Real(0));
    dl = next - lambda;
  }
  lambda += dl;
  p1[0] += w1 * dl * nx;
  p1[1] += w1 * dl * ny;
  p1[2] += w1 * dl * nz;
  p2[0] -= w2 * dl * nx;
  p2[1] -= w2 * dl * ny;
  p2[2] -= w2 * dl * nz;
  return violation;
}

// Jakobsen 2001, "Advanced Character Physics", §4 (stick constraints with his square-root
// approximation): |d| ≈ (d·d + r²)/(2r), the first-order expansion of sqrt(d·d) about r², so
// that the correction C n = (|d| - r) d/|d| becomes (d·d - r²)/(d·d + r²) d, with no square root.
// Accurate when the stick is near its rest length r, which relaxation keeps it. Scaled by the
// stiffness and shared by inverse mass as in project_distance. Returns the approximate violation
// (d·d - r²)/(2r).
inline Real project_distance_jakobsen(Real* p1, Real* p2, Real w1, Real w2, Real rest_length, Real stiffness,
                                      int sense) {
  const Real dx = p1[0] - p2[0], dy = p1[1] - p2[1], dz = p1[2] - p2[2];
  const Real dd = dx * dx + dy * dy + dz * dz, r2 = rest_length * rest_length;
  const Real violation = distance_violation((dd - r2) / (2 * rest_length), sense);
  const Real wsum = w1 + w2;
  if (wsum <= 0 || violation == 0) return violation;
  move_apart(p1, p2, w1, w2, stiffness * (dd - r2) / (dd + r2) / wsum, dx, dy, dz);
  return violation;
}

}  // namespace csb
