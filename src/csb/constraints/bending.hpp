// csb — dihedral bending constraint kernel.
//
// Müller et al. 2007, §4.2 and Appendix A: two triangles (c, a, b) and (d, b, a) share the edge
// (a, b); the constraint keeps the dihedral angle across that edge at its rest value,
//
//   C(a, b, c, d) = θ(a, b, c, d) - θ0.
//
// The paper writes θ = acos(n1 · n2). That angle is unsigned, so a fold up and a fold down look
// the same, and its gradient, -1/sqrt(1 - d²) times grad(n1 · n2), is 0/0 at a flat rest state,
// which is where cloth starts. We use the signed angle instead,
//
//   N1 = (c - a) x (c - b),   N2 = (d - b) x (d - a),   e = b - a,
//   θ  = atan2((n1 x n2) · e/|e|, n1 · n2),   n = N / |N|,
//
// which is 0 for a flat pair and smooth through it, with the closed-form gradient of Bridson,
// Marino, Fedkiw 2003 ("Simulation of clothing with folds and wrinkles", §4):
//
//   grad_c θ = -|e| N1 / |N1|²
//   grad_d θ = -|e| N2 / |N2|²
//   grad_a θ = -( (c - b)·e/|e| N1/|N1|² + (d - b)·e/|e| N2/|N2|² )
//   grad_b θ =  ( (c - a)·e/|e| N1/|N1|² + (d - a)·e/|e| N2/|N2|² )
//
// Where both are defined (θ and θ0 of one sign, not flat), the paper's angle is φ = π - |θ| and
// the projection below equals the appendix's Δp_i = -w_i sqrt(1 - d²)(acos d - φ0) q_i /
// Σ_j w_j |q_j|² with φ0 = π - |θ0| (tests/test_kernels.py checks this to 1e-13, and the
// gradient by finite differences). The projection is the general one of
// §3.3: s = k C / Σ_j w_j |grad_j C|², Δp_i = -s w_i grad_i C. θ is invariant under
// translation and rotation, so the gradients sum to zero and have no moment: momentum is kept.
#pragma once

#include "csb/types.hpp"

#include <cmath>

namespace csb {

constexpr Real kPi = 3.14159265358979323846;

// Signed dihedral angle across the edge (a, b) in (-π, π]; 0 for a flat pair (rad). atan2 does
// not care for a common positive factor, so the normals need no normalising:
// θ = atan2((N1 x N2) · e, (N1 · N2) |e|).
inline Real dihedral_angle(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const Vec3 e = b - a;
  const Vec3 N1 = (c - a).cross(c - b);
  const Vec3 N2 = (d - b).cross(d - a);
  return std::atan2(N1.cross(N2).dot(e), N1.dot(N2) * e.norm());
}

// Wraps an angle difference into (-π, π]. Selects, not branches: the coloured bending kernel
// calls it inside its SIMD loops (csb/solver/coloured_bending.hpp).
inline Real wrap_angle(Real x) {
  x = x > kPi ? x - 2 * kPi : x;
  return x <= -kPi ? x + 2 * kPi : x;
}
// The same in single precision, about π rounded to float (the single-precision solver).
inline float wrap_angle(float x) {
  constexpr float pi = static_cast<float>(kPi);
  x = x > pi ? x - 2 * pi : x;
  return x <= -pi ? x + 2 * pi : x;
}

namespace detail {
template <bool Angle>
inline bool dihedral_terms(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, Real* theta, Vec3 grad[4]) {
  const Vec3 e = b - a;
  const Vec3 N1 = (c - a).cross(c - b);
  const Vec3 N2 = (d - b).cross(d - a);
  const Real e2 = e.squaredNorm(), n1 = N1.squaredNorm(), n2 = N2.squaredNorm();
  if (!(e2 > 0 && n1 > 0 && n2 > 0)) return false;
  const Real elen = std::sqrt(e2);
  if constexpr (Angle) *theta = std::atan2(N1.cross(N2).dot(e), N1.dot(N2) * elen);
  const Vec3 g1 = N1 / n1, g2 = N2 / n2;
  grad[0] = -((c - b).dot(e) / elen * g1 + (d - b).dot(e) / elen * g2);
  grad[1] = (c - a).dot(e) / elen * g1 + (d - a).dot(e) / elen * g2;
  grad[2] = -elen * g1;
  grad[3] = -elen * g2;
  return true;
}
}  // namespace detail

// The signed dihedral angle (rad) and its gradient with respect to a, b, c, d (rad/m). Returns
// false for a degenerate configuration (zero-length edge or zero-area triangle), where θ is
// undefined.
inline bool dihedral_angle_and_gradient(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, Real& theta,
                                        Vec3 grad[4]) {
  return detail::dihedral_terms<true>(a, b, c, d, &theta, grad);
}

// The gradient alone, the same bits as dihedral_angle_and_gradient's (its angle is not needed
// for a finite difference of the gradient, and atan2 is most of the cost).
inline bool dihedral_gradient(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, Vec3 grad[4]) {
  return detail::dihedral_terms<false>(a, b, c, d, nullptr, grad);
}

// What both projections need: the violation θ - θ0, the gradient and Σ w |∇C|². ok = false for a
// degenerate pair, which is left alone.
struct BendingGeometry {
  bool ok = false;
  Real violation = 0;
  Vec3 grad[4];
  Real wgrad = 0;
};

inline BendingGeometry bending_geometry(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, Real wa, Real wb,
                                        Real wc, Real wd, Real rest_angle) {
  BendingGeometry g;
  Real theta = 0;
  if (!dihedral_angle_and_gradient(a, b, c, d, theta, g.grad)) return g;
  g.ok = true;
  g.violation = wrap_angle(theta - rest_angle);
  g.wgrad = wa * g.grad[0].squaredNorm() + wb * g.grad[1].squaredNorm() + wc * g.grad[2].squaredNorm() +
            wd * g.grad[3].squaredNorm();
  return g;
}

// Projects one bending constraint in place (positions as 3-vectors of a, b, c, d); returns the
// violation before the projection (rad).
inline Real project_bending(Real* pa, Real* pb, Real* pc, Real* pd, Real wa, Real wb, Real wc, Real wd,
                            Real rest_angle, Real stiffness) {
  Eigen::Map<Vec3> a(pa), b(pb), c(pc), d(pd);
  const BendingGeometry g = bending_geometry(a, b, c, d, wa, wb, wc, wd, rest_angle);
  if (!(g.ok && g.wgrad > 0)) return g.violation;
  const Real s = stiffness * g.violation / g.wgrad;
  a -= (s * wa) * g.grad[0];
  b -= (s * wb) * g.grad[1];
  c -= (s * wc) * g.grad[2];
  d -= (s * wd) * g.grad[3];
  return g.violation;
}

// XPBD form (Macklin et al. 2016, Eq. (18) and (26)) of the same constraint, compliance α in
// rad²/J = 1/(N m): Δλ = (-C - α̃ λ - γ Σ_j ∇_j C·(p_j - x_j)) / ((1 + γ) Σ_j w_j |∇_j C|² + α̃),
// Δp_i = w_i ∇_i C Δλ; x are the positions at the start of the (sub)step. Returns the violation.
inline Real project_bending_xpbd(Real* pa, Real* pb, Real* pc, Real* pd, const Real* xa, const Real* xb,
                                 const Real* xc, const Real* xd, Real wa, Real wb, Real wc, Real wd, Real rest_angle,
                                 Real alpha_tilde, Real gamma, Real& lambda) {
  Eigen::Map<Vec3> a(pa), b(pb), c(pc), d(pd);
  const BendingGeometry g = bending_geometry(a, b, c, d, wa, wb, wc, wd, rest_angle);
  if (!(g.ok && g.wgrad > 0)) return g.violation;
  const Real moved = gamma == 0 ? Real(0)
                                : g.grad[0].dot(a - Eigen::Map<const Vec3>(xa)) + g.grad[1].dot(b - Eigen::Map<const Vec3>(xb)) +
                                      g.grad[2].dot(c - Eigen::Map<const Vec3>(xc)) +
                                      g.grad[3].dot(d - Eigen::Map<const Vec3>(xd));
  const Real dl = (-g.violation - alpha_tilde * lambda - gamma * moved) / ((1 + gamma) * g.wgrad + alpha_tilde);
  lambda += dl;
  a += (wa * dl) * g.grad[0];
  b += (wb * dl) * g.grad[1];
  c += (wc * dl) * g.grad[2];
  d += (wd * dl) * g.grad[3];
  return g.violation;
}

}  // namespace csb
