// csb — volume constraint kernels: one tetrahedron, and the overpressure (balloon) constraint of
// a closed triangle surface.
//
// Tetrahedron (Müller et al. 2007 §4.3, Eq. for general constraints in §3.3): with e_i = p_i - p0,
//
//   C(p0, p1, p2, p3) = V - V0,   V = (1/6) (e1 x e2) · e3            (signed volume, m³)
//   grad_p1 C = (1/6) e2 x e3,  grad_p2 C = (1/6) e3 x e1,  grad_p3 C = (1/6) e1 x e2,
//   grad_p0 C = -(grad_p1 C + grad_p2 C + grad_p3 C)                  (m²)
//
// PBD: s = k C / Σ_j w_j |grad_j C|²,  Δp_i = -s w_i grad_i C  (§3.3, k in [0, 1]).
// XPBD (Macklin et al. 2016, Eq. (18) and (26)): compliance α in m⁶/J (C is in m³ and the
// potential C²/(2α) in J, so α = m⁶/J = m⁵/N; for a material of bulk modulus K (Pa) a tet of rest
// volume V0 has α = V0/K, from the strain energy K/2 (ΔV/V0)² V0), α̃ = α/h², γ = α β / h,
//
//   Δλ = (-C - α̃ λ - γ Σ_j grad_j C · (p_j - x_j)) / ((1 + γ) Σ_j w_j |grad_j C|² + α̃),
//   Δp_i = w_i grad_i C Δλ.
//
// V is invariant under translation and rotation, so the gradients sum to zero and have zero
// moment (Σ p_i x grad_i C = 0): both projections conserve linear and angular momentum.
// V is cubic in the positions, so one projection with k = 1 removes C only to first order; the
// residual after one step is O(C²) (tests/test_volume.py measures it).
//
// Balloon (Müller 2007 §4.5, overpressure): over a closed, outward-wound triangle surface,
//
//   C(p) = V(p) - k_pressure V0,   V = (1/6) Σ_triangles (p_a x p_b) · p_c
//   grad_i C = (1/6) Σ_{triangles (a, b, c) with i = a} p_b x p_c      (each triangle rotated so
//                                                                      that i comes first)
//
// one constraint over all the surface's particles, projected with the same two formulas. On a
// closed surface V is translation invariant (Σ_i grad_i C = 0) and rotation invariant, so momentum
// is kept here too. The balloon kernels take index lists: the surface's particles, and its
// triangles as indices into that list.
#pragma once

#include "csb/types.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace csb {

// Signed volume (m³) of the tetrahedron (p0, p1, p2, p3); positive when p3 lies on the side of
// (p1 - p0) x (p2 - p0).
inline Real tet_volume(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& p3) {
  return (p1 - p0).cross(p2 - p0).dot(p3 - p0) / 6;
}

// grad[i] = ∂V/∂p_i (m²); returns V (m³).
inline Real tet_volume_gradient(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& p3, Vec3 grad[4]) {
  const Vec3 e1 = p1 - p0, e2 = p2 - p0, e3 = p3 - p0;
  grad[1] = e2.cross(e3) / 6;
  grad[2] = e3.cross(e1) / 6;
  grad[3] = e1.cross(e2) / 6;
  grad[0] = -(grad[1] + grad[2] + grad[3]);
  return e3.dot(grad[3]);
}

// A gradient below round-off of the tet's size carries no direction (all four particles on a
// line or at a point): such a constraint is left alone. Σ_j |grad_j V|² ~ L⁴; this is its
// round-off floor, relative to the longest edge L.
inline bool volume_gradient_usable(const Vec3 grad[4], const Vec3& p0, const Vec3& p1, const Vec3& p2,
                                   const Vec3& p3) {
  const Real l2 = std::max({(p1 - p0).squaredNorm(), (p2 - p0).squaredNorm(), (p3 - p0).squaredNorm(),
                            (p2 - p1).squaredNorm(), (p3 - p1).squaredNorm(), (p3 - p2).squaredNorm()});
  const Real g2 = grad[0].squaredNorm() + grad[1].squaredNorm() + grad[2].squaredNorm() + grad[3].squaredNorm();
  constexpr Real eps = std::numeric_limits<Real>::epsilon();
  return g2 > (eps * l2) * (eps * l2);
}

struct VolumeGeometry {
  bool ok = false;
  Real violation = 0;  // V - V0, m³
  Vec3 grad[4];
  Real wgrad = 0;      // Σ w |∇C|², m⁴/kg
};

inline VolumeGeometry volume_geometry(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& p3, Real w0, Real w1,
                                      Real w2, Real w3, Real rest_volume) {
  VolumeGeometry g;
  g.violation = tet_volume_gradient(p0, p1, p2, p3, g.grad) - rest_volume;
  g.wgrad = w0 * g.grad[0].squaredNorm() + w1 * g.grad[1].squaredNorm() + w2 * g.grad[2].squaredNorm() +
            w3 * g.grad[3].squaredNorm();
  g.ok = g.wgrad > 0 && volume_gradient_usable(g.grad, p0, p1, p2, p3);
  return g;
}

// Projects one tetrahedral volume constraint in place (PBD, stiffness k in [0, 1]); returns the
// violation V - V0 before the projection (m³).
inline Real project_volume(Real* p0, Real* p1, Real* p2, Real* p3, Real w0, Real w1, Real w2, Real w3,
                           Real rest_volume, Real stiffness) {
  Eigen::Map<Vec3> a(p0), b(p1), c(p2), d(p3);
  const VolumeGeometry g = volume_geometry(a, b, c, d, w0, w1, w2, w3, rest_volume);
  if (!g.ok) return g.violation;
  const Real s = stiffness * g.violation / g.wgrad;
  a -= (s * w0) * g.grad[0];
  b -= (s * w1) * g.grad[1];
  c -= (s * w2) * g.grad[2];
  d -= (s * w3) * g.grad[3];
  return g.violation;
}

// XPBD form, compliance α in m⁶/J passed as α̃ = α/h² and γ = α β / h (β in J s/m⁶); x are the
// positions at the start of the (sub)step; λ (kg/m) is accumulated over the iterations of one
// (sub)step, and λ/h² is the pressure (Pa) the constraint exerts: force λ/h² grad_i C (N) on
// particle i. Returns the violation before the projection (m³).
inline Real project_volume_xpbd(Real* p0, Real* p1, Real* p2, Real* p3, const Real* x0, const Real* x1,
                                const Real* x2, const Real* x3, Real w0, Real w1, Real w2, Real w3, Real rest_volume,
                                Real alpha_tilde, Real gamma, Real& lambda) {
  Eigen::Map<Vec3> a(p0), b(p1), c(p2), d(p3);
  const VolumeGeometry g = volume_geometry(a, b, c, d, w0, w1, w2, w3, rest_volume);
  if (!g.ok) return g.violation;
  const Real moved = gamma == 0 ? Real(0)
                                : g.grad[0].dot(a - Eigen::Map<const Vec3>(x0)) +
                                      g.grad[1].dot(b - Eigen::Map<const Vec3>(x1)) +
                                      g.grad[2].dot(c - Eigen::Map<const Vec3>(x2)) +
                                      g.grad[3].dot(d - Eigen::Map<const Vec3>(x3));
  const Real dl = (-g.violation - alpha_tilde * lambda - gamma * moved) / ((1 + gamma) * g.wgrad + alpha_tilde);
  lambda += dl;
  a += (w0 * dl) * g.grad[0];
  b += (w1 * dl) * g.grad[1];
  c += (w2 * dl) * g.grad[2];
  d += (w3 * dl) * g.grad[3];
  return g.violation;
}

// ------------------------------------------------------------------------------ balloon

// Volume (m³) enclosed by the triangles (indices into `particles`, which index the 3 x N array x).
inline Real enclosed_volume(const Real* x, const Index* particles, const Triangle* triangles, Index num_triangles) {
  Real v = 0;
  for (Index t = 0; t < num_triangles; ++t) {
    const Eigen::Map<const Vec3> a(x + 3 * particles[triangles[t][0]]), b(x + 3 * particles[triangles[t][1]]),
        c(x + 3 * particles[triangles[t][2]]);
    v += a.cross(b).dot(c);
  }
  return v / 6;
}

// grad[k] = ∂V/∂p_{particles[k]} (m²) for k < num_particles; returns V (m³).
inline Real enclosed_volume_gradient(const Real* x, const Index* particles, Index num_particles,
                                     const Triangle* triangles, Index num_triangles, Vec3* grad) {
  for (Index k = 0; k < num_particles; ++k) grad[k].setZero();
  Real v = 0;
  for (Index t = 0; t < num_triangles; ++t) {
    const Triangle& tri = triangles[t];
    const Eigen::Map<const Vec3> a(x + 3 * particles[tri[0]]), b(x + 3 * particles[tri[1]]),
        c(x + 3 * particles[tri[2]]);
    const Vec3 bc = b.cross(c);
    v += a.dot(bc);
    grad[tri[0]] += bc;
    grad[tri[1]] += c.cross(a);
    grad[tri[2]] += a.cross(b);
  }
  for (Index k = 0; k < num_particles; ++k) grad[k] /= 6;
  return v / 6;
}

// One balloon projection. Reads the positions from `x`, and adds each particle's correction to
// `out` (x itself for Gauss-Seidel; a correction sum for Jacobi, which then counts the particle in
// `count` if given). XPBD when `lambda` is given (α̃, γ, x_start used), PBD with `stiffness`
// otherwise. grad: workspace of num_particles vectors. relax scales XPBD's Δλ (and so the
// corrections: averaged Jacobi, see PbdSettings::solver; 1 changes nothing). Returns the
// violation V - k V0 before the projection (m³). A surface whose gradient has vanished
// (collapsed) is left alone.
inline Real project_balloon(const Real* x, Real* out, Real* count, const Real* w, const Index* particles,
                            Index num_particles, const Triangle* triangles, Index num_triangles, Real target_volume,
                            Real stiffness, const Real* x_start, Real alpha_tilde, Real gamma, Real* lambda,
                            Vec3* grad, Real relax = 1) {
  const Real c = enclosed_volume_gradient(x, particles, num_particles, triangles, num_triangles, grad) - target_volume;
  Real wgrad = 0, g2 = 0, moved = 0;
  for (Index k = 0; k < num_particles; ++k) {
    const Index i = particles[k];
    const Real n2 = grad[k].squaredNorm();
    g2 += n2;
    wgrad += w[i] * n2;
    if (lambda && gamma != 0) moved += grad[k].dot(Eigen::Map<const Vec3>(x + 3 * i) - Eigen::Map<const Vec3>(x_start + 3 * i));
  }
  // Round-off floor of Σ |grad|² as in volume_gradient_usable, with |V|^(4/3) standing in for L⁴.
  constexpr Real eps = std::numeric_limits<Real>::epsilon();
  const Real l4 = std::pow(std::abs(c + target_volume), Real(4) / 3);
  if (!(wgrad > 0) || !(g2 > eps * eps * l4)) return c;
  Real scale;  // Δp_i = scale w_i grad_i
  if (lambda) {
    const Real dl = relax * (-c - alpha_tilde * *lambda - gamma * moved) / ((1 + gamma) * wgrad + alpha_tilde);
    *lambda += dl;
    scale = dl;
  } else {
    scale = -stiffness * c / wgrad;
  }
  for (Index k = 0; k < num_particles; ++k) {
    const Index i = particles[k];
    Eigen::Map<Vec3>(out + 3 * i) += (scale * w[i]) * grad[k];
    if (count) count[i] += 1;
  }
  return c;
}

}  // namespace csb
