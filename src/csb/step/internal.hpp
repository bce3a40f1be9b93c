// csb — small helpers the stepper's files share (internal to the stepper's files).
#pragma once

#include "csb/model.hpp"

#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

namespace csb::stepper_detail {

// Index of the first particle of [begin, end) (default: all) whose column is not finite, or -1.
inline Index first_non_finite(const Positions& x, Index begin = 0, Index end = -1) {
  if (end < 0) end = static_cast<Index>(x.cols());
  for (Index i = begin; i < end; ++i)
    if (!x.col(i).allFinite()) return i;
  return -1;
}

// Jacobi: the kernels work on copies of their particles' positions at the sweep's start; the
// difference is added to the particles' correction sums.
struct Local {
  Real p[3];
  void load(const Real* from) { p[0] = from[0], p[1] = from[1], p[2] = from[2]; }
  // om: XPBD with averaged Jacobi, the constraint's relaxation (else 1, which changes no bit).
  void add_to(const Real* from, Real* delta, Real om = 1) const {
    delta[0] += om * (p[0] - from[0]);
    delta[1] += om * (p[1] - from[1]);
    delta[2] += om * (p[2] - from[2]);
  }
};

// Jacobi: how many projections reach each particle in one sweep of the model's batches
// (contacts aside).
inline void jacobi_counts(const Model& model, std::vector<Real>& count) {
  count.assign(model.num_particles(), 0);
  for (const auto& e : model.distance.particles)
    for (Index i : e) count[i] += 1;
  for (const auto& q : model.bending.particles)
    for (Index i : q) count[i] += 1;
  for (const auto& q : model.volume.particles)
    for (Index i : q) count[i] += 1;
  for (Index i : model.balloons.particles) count[i] += 1;
  for (Index i : model.attachments.particle) count[i] += 1;
  for (const auto& f : model.families) {
    const Index* q = f->particle_data();
    const std::size_t ids = static_cast<std::size_t>(f->size()) * static_cast<std::size_t>(f->info().arity);
    for (std::size_t k = 0; k < ids; ++k) count[q[k]] += 1;
  }
}

// XPBD with averaged Jacobi: the relaxation of a constraint on particles ids[0 .. count), the
// smallest of their 1/count (PbdStepper::set_relaxation); 1 without relaxation (relax null).
inline Real relaxation(const Real* relax, const Index* ids, Index count) {
  if (!relax) return 1;
  Real om = 1;
  for (Index k = 0; k < count; ++k) om = std::min(om, relax[ids[k]]);
  return om;
}
template <std::size_t N>
Real relaxation(const Real* relax, const std::array<Index, N>& ids) {
  return relaxation(relax, ids.data(), static_cast<Index>(N));
}

// A relaxed multiplier: λ moves by om times the kernel's Δλ (after its sign clamp), like the
// positions; `lambda` holds the kernel's result, `before` its value before the kernel.
inline void relax_multiplier(Real& lambda, Real before, Real om) { lambda = before + om * (lambda - before); }

// The volume and balloon coefficients of one sweep, in the roles the distance ones have: PBD
// stiffness (corrected or not), XPBD α̃ = α/h² and γ = α β / h; and the balloon gradient workspace.
struct VolumeTerms {
  const std::vector<Real>& k_volume;
  const std::vector<Real>& a_volume;
  const std::vector<Real>& g_volume;
  const std::vector<Real>& k_balloon;
  const std::vector<Real>& a_balloon;
  const std::vector<Real>& g_balloon;
  Vec3* grad;
};

// XPBD's multipliers set to zero: share `share` of `shares` (equal runs) of a batch's, as the
// threads split them; or those of group g of the batch's colouring (its colours' ranges; none
// where the batch is empty or the colouring has no group g).
template <class S>
void zero_share(std::vector<S>& lambda, int share, int shares) {
  const std::int64_t m = static_cast<std::int64_t>(lambda.size());
  std::fill(lambda.begin() + m * share / shares, lambda.begin() + m * (share + 1) / shares, S(0));
}
template <class S>
void zero_group(const Colouring& c, Index g, std::vector<S>& lambda) {
  if (lambda.empty() || static_cast<std::size_t>(g) + 1 >= c.group_colours.size()) return;
  std::fill(lambda.begin() + c.colour_offsets[c.group_colours[g]],
            lambda.begin() + c.colour_offsets[c.group_colours[g + 1]], S(0));
}

// The single-precision step's update of a sub-step and prediction of the next for coordinates
// [k0, k1) in one pass (PbdStepper::advance's operations in float; v: Verlet's previous
// positions), in AVX2 lanes where the processor has them (step/integrate.cpp).
void advance_single(float* x, float* v, float* p, const float* a, float h, float keep, bool verlet, Index k0,
                    Index k1);

// The single-precision step's start for particles [begin, end): the double positions xd and
// velocities vd (Verlet: previous positions) rounded to nearest into floats (x, y, z and a pad,
// 4 apart; the pads w[i], and 0 for Euler's velocities), the positions into x, and the first
// prediction into p (Euler p = x + h (v + a); Verlet p = x + keep (x - v) + a); in one pass where
// the processor has AVX2 (v, scratch, then left unwritten). Its end: the first of particles
// [begin, end) whose projected position p is not finite (the exponent all ones), or -1; then the
// last update (Euler v = (p - x)/h, x = p; Verlet v = x, x = p) in float, its results widened
// exactly straight into the double state xd, vd (step/integrate.cpp).
void start_single(const Real* xd, const Real* vd, const float* w, float* x, float* v, float* p, const float* a,
                  float h, float keep, bool verlet, Index begin, Index end);
Index first_non_finite_single(const float* p, Index begin, Index end);
void finish_single(const float* x, const float* p, float h, bool verlet, Real* xd, Real* vd, Index begin, Index end);

template <class T>
std::size_t capacity_bytes(const std::vector<T>& v) {
  return v.capacity() * sizeof(T);
}

}  // namespace csb::stepper_detail
