// csb — one sequential sweep over every constraint of a model, one batch at a time in model order
// (Müller's loop as written), for the stepper's sequential ordering and the dispatch benchmark.
#pragma once

#include "csb/pbd.hpp"
#include "csb/constraints/attachment.hpp"
#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"
#include "csb/step/internal.hpp"

namespace csb::stepper_detail {


// One sweep over all constraints, one batch at a time in model order. M picks the projection,
// Jacobi whether the kernels see the positions at the sweep's start (corrections collected in
// delta_ and count_) or each other's corrections as they come (Gauss-Seidel). relax (XPBD with
// averaged Jacobi, else null): each constraint's Δλ and correction scaled by its relaxation.
template <Method M, bool Jacobi>
void sweep_batches(const Model& model, const Real* w, const PbdSettings& settings, Real* p, const Real* from,
                          const Real* x_start, Real* delta, Real* count, const std::vector<Real>& k_dist,
                          const std::vector<Real>& k_bend, const std::vector<Real>& k_att,
                          const std::vector<Real>& a_dist, const std::vector<Real>& a_bend,
                          const std::vector<Real>& a_att, const std::vector<Real>& g_dist,
                          const std::vector<Real>& g_bend, const std::vector<Real>& g_att, Multipliers& lambda,
                          const VolumeTerms& vt, const Real* relax) {
  const auto& dist = model.distance;
  const auto& bend = model.bending;
  const auto& att = model.attachments;
  Local local[4];
  Real om = 1;  // the relaxation of the constraint being projected
  const auto relax_lambda = [&](Real& l, Real before) {
    if (relax) relax_multiplier(l, before, om);
  };
  // Where the kernel works on particle `slot`'s position: in place, or a local copy.
  const auto at = [&](int slot, Index i) -> Real* {
    if constexpr (Jacobi) {
      local[slot].load(from + 3 * i);
      return local[slot].p;
    } else {
      return p + 3 * i;
    }
  };
  const auto collect = [&](int slot, Index i) {
    if constexpr (Jacobi) {
      local[slot].add_to(from + 3 * i, delta + 3 * i, om);
      count[i] += 1;
    }
  };
  for (Index c = 0; c < dist.size(); ++c) {
    const Index i = dist.particles[c][0], j = dist.particles[c][1];
    Real* a = at(0, i);
    Real* b = at(1, j);
    if constexpr (M == Method::Xpbd) {
      om = relaxation(relax, dist.particles[c]);
      const Real before = lambda.distance[c];
      project_distance_xpbd(a, b, x_start + 3 * i, x_start + 3 * j, w[i], w[j], dist.rest_length[c], a_dist[c],
                            g_dist[c], lambda.distance[c], dist.sense[c]);
      relax_lambda(lambda.distance[c], before);
    } else if constexpr (M == Method::Jakobsen) {
      if (settings.sqrt_approximation)
        project_distance_jakobsen(a, b, w[i], w[j], dist.rest_length[c], k_dist[c], dist.sense[c]);
      else
        project_distance(a, b, w[i], w[j], dist.rest_length[c], k_dist[c], dist.sense[c]);
    } else {
      project_distance(a, b, w[i], w[j], dist.rest_length[c], k_dist[c], dist.sense[c]);
    }
    collect(0, i);
    collect(1, j);
  }
  for (Index c = 0; c < bend.size(); ++c) {
    const auto& q = bend.particles[c];
    Real* r[4] = {at(0, q[0]), at(1, q[1]), at(2, q[2]), at(3, q[3])};
    if constexpr (M == Method::Xpbd) {
      om = relaxation(relax, q);
      const Real before = lambda.bending[c];
      project_bending_xpbd(r[0], r[1], r[2], r[3], x_start + 3 * q[0], x_start + 3 * q[1], x_start + 3 * q[2],
                           x_start + 3 * q[3], w[q[0]], w[q[1]], w[q[2]], w[q[3]], bend.rest_angle[c], a_bend[c],
                           g_bend[c], lambda.bending[c]);
      relax_lambda(lambda.bending[c], before);
    } else {
      project_bending(r[0], r[1], r[2], r[3], w[q[0]], w[q[1]], w[q[2]], w[q[3]], bend.rest_angle[c], k_bend[c]);
    }
    for (int s = 0; s < 4; ++s) collect(s, q[s]);
  }
  const auto& vol = model.volume;
  for (Index c = 0; c < vol.size(); ++c) {
    const auto& q = vol.particles[c];
    Real* r[4] = {at(0, q[0]), at(1, q[1]), at(2, q[2]), at(3, q[3])};
    if constexpr (M == Method::Xpbd) {
      om = relaxation(relax, q);
      const Real before = lambda.volume[c];
      project_volume_xpbd(r[0], r[1], r[2], r[3], x_start + 3 * q[0], x_start + 3 * q[1], x_start + 3 * q[2],
                          x_start + 3 * q[3], w[q[0]], w[q[1]], w[q[2]], w[q[3]], vol.rest_volume[c], vt.a_volume[c],
                          vt.g_volume[c], lambda.volume[c]);
      relax_lambda(lambda.volume[c], before);
    } else {
      project_volume(r[0], r[1], r[2], r[3], w[q[0]], w[q[1]], w[q[2]], w[q[3]], vol.rest_volume[c], vt.k_volume[c]);
    }
    for (int s = 0; s < 4; ++s) collect(s, q[s]);
  }
  // A balloon couples all its particles; Gauss-Seidel moves them in place, Jacobi reads the
  // sweep's start and adds to the correction sums (and counts), like collect() does.
  const auto& bal = model.balloons;
  for (Index c = 0; c < bal.size(); ++c) {
    const Index* ids = bal.particles.data() + bal.particle_offsets[c];
    const Triangle* tris = bal.triangles.data() + bal.triangle_offsets[c];
    const Real target = bal.pressure[c] * bal.rest_volume[c];
    const Real* read = Jacobi ? from : p;
    Real* out = Jacobi ? delta : p;
    Real* counts = Jacobi ? count : nullptr;
    if constexpr (M == Method::Xpbd)
      project_balloon(read, out, counts, w, ids, bal.num_particles(c), tris, bal.num_triangles(c), target, 0, x_start,
                      vt.a_balloon[c], vt.g_balloon[c], &lambda.balloon[c], vt.grad,
                      relaxation(relax, ids, bal.num_particles(c)));
    else
      project_balloon(read, out, counts, w, ids, bal.num_particles(c), tris, bal.num_triangles(c), target,
                      vt.k_balloon[c], nullptr, 0, 0, nullptr, vt.grad);
  }
  om = 1;
  for (Index c = 0; c < att.size(); ++c) {
    const Index i = att.particle[c];
    Real* a = at(0, i);
    if constexpr (M == Method::Xpbd) {
      om = relaxation(relax, std::array<Index, 1>{i});
      const Real before = lambda.attachment[c];
      project_attachment_xpbd(a, x_start + 3 * i, w[i], att.target.col(c).data(), a_att[c], g_att[c],
                              lambda.attachment[c]);
      relax_lambda(lambda.attachment[c], before);
    } else {
      project_attachment(a, w[i], att.target.col(c).data(), k_att[c]);
    }
    collect(0, i);
  }
}

}  // namespace csb::stepper_detail
