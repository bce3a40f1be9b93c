// csb — attachment of a particle to a point fixed in the world.
//
// A one-particle distance constraint with rest length 0 (Müller et al. 2007, §3.3 with a single
// particle): C(p) = |p - t|, grad C = (p - t)/|p - t|, s = C / (w |grad C|²), so
//
//   Δp = -k (p - t)
//
// whatever the particle's (non-zero) inverse mass. A particle with w = 0 is not moved.
#pragma once

#include "csb/types.hpp"

#include <cmath>

namespace csb {

// Projects one attachment in place; returns its violation |p - t| before the projection (m).
inline Real project_attachment(Real* p, Real w, const Real* target, Real stiffness) {
  const Real dx = p[0] - target[0], dy = p[1] - target[1], dz = p[2] - target[2];
  const Real violation = std::sqrt(dx * dx + dy * dy + dz * dz);
  if (w <= 0) return violation;
  p[0] -= stiffness * dx;
  p[1] -= stiffness * dy;
  p[2] -= stiffness * dz;
  return violation;
}

// XPBD form (Macklin et al. 2016): C = |p - t|, ∇C = n = (p - t)/|p - t|, compliance α in m/N:
// Δλ = (-C - α̃ λ - γ n·(p - x_n)) / ((1 + γ) w + α̃), Δp = w n Δλ. Returns the violation.
inline Real project_attachment_xpbd(Real* p, const Real* x, Real w, const Real* target, Real alpha_tilde, Real gamma,
                                    Real& lambda) {
  const Real dx = p[0] - target[0], dy = p[1] - target[1], dz = p[2] - target[2];
  const Real c = std::sqrt(dx * dx + dy * dy + dz * dz);
  if (w <= 0 || c <= 0) return c;
  const Real nx = dx / c, ny = dy / c, nz = dz / c;
  const Real moved = gamma == 0 ? Real(0) : nx * (p[0] - x[0]) + ny * (p[1] - x[1]) + nz * (p[2] - x[2]);
  const Real dl = (-c - alpha_tilde * lambda - gamma * moved) / ((1 + gamma) * w + alpha_tilde);
  lambda += dl;
  p[0] += w * dl * nx;
  p[1] += w * dl * ny;
  p[2] += w * dl * nz;
  return c;
}

}  // namespace csb
