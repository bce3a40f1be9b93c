#include "csb/metrics.hpp"

#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"

#include <cmath>

namespace csb {
namespace {

Violation summarise(const std::vector<Real>& values) {
  Violation v;
  v.count = static_cast<Index>(values.size());
  Real sum2 = 0;
  for (Real x : values) {
    v.max = std::max(v.max, std::abs(x));
    sum2 += x * x;
  }
  if (!values.empty()) v.rms = std::sqrt(sum2 / values.size());
  return v;
}

}  // namespace

std::vector<Real> distance_violations(const Model& model, const State& state) {
  const auto& d = model.distance;
  std::vector<Real> out(d.size());
  for (Index c = 0; c < d.size(); ++c) {
    const Real len = (state.x.col(d.particles[c][0]) - state.x.col(d.particles[c][1])).norm();
    out[c] = distance_violation(len - d.rest_length[c], d.sense[c]);
  }
  return out;
}

std::vector<Real> bending_violations(const Model& model, const State& state) {
  const auto& b = model.bending;
  std::vector<Real> out(b.size());
  for (Index c = 0; c < b.size(); ++c) {
    const auto& q = b.particles[c];
    out[c] = wrap_angle(dihedral_angle(state.x.col(q[0]), state.x.col(q[1]), state.x.col(q[2]), state.x.col(q[3])) -
                        b.rest_angle[c]);
  }
  return out;
}

std::vector<Real> volume_violations(const Model& model, const State& state) {
  const auto& b = model.volume;
  std::vector<Real> out(b.size());
  for (Index c = 0; c < b.size(); ++c) {
    const auto& q = b.particles[c];
    out[c] = tet_volume(state.x.col(q[0]), state.x.col(q[1]), state.x.col(q[2]), state.x.col(q[3])) - b.rest_volume[c];
  }
  return out;
}

std::vector<Real> balloon_volumes(const Model& model, const State& state) {
  const auto& b = model.balloons;
  std::vector<Real> out(b.size());
  for (Index c = 0; c < b.size(); ++c)
    out[c] = enclosed_volume(state.x.data(), b.particles.data() + b.particle_offsets[c],
                             b.triangles.data() + b.triangle_offsets[c], b.num_triangles(c));
  return out;
}

std::vector<Real> balloon_violations(const Model& model, const State& state) {
  std::vector<Real> out = balloon_volumes(model, state);
  for (std::size_t c = 0; c < out.size(); ++c) out[c] -= model.balloons.pressure[c] * model.balloons.rest_volume[c];
  return out;
}

namespace {

std::vector<Real> attachment_violations(const Model& model, const State& state) {
  const auto& a = model.attachments;
  std::vector<Real> out(a.size());
  for (Index c = 0; c < a.size(); ++c) out[c] = (state.x.col(a.particle[c]) - a.target.col(c)).norm();
  return out;
}

// Σ C²/(2α) over the entries with α > 0.
Real potential(const std::vector<Real>& violation, const std::vector<Real>& compliance) {
  Real e = 0;
  for (std::size_t c = 0; c < violation.size(); ++c)
    if (compliance[c] > 0) e += violation[c] * violation[c] / (2 * compliance[c]);
  return e;
}

}  // namespace

Real elastic_energy(const Model& model, const State& state) {
  Real e = potential(distance_violations(model, state), model.distance.compliance) +
           potential(bending_violations(model, state), model.bending.compliance) +
           potential(volume_violations(model, state), model.volume.compliance) +
           potential(balloon_violations(model, state), model.balloons.compliance) +
           potential(attachment_violations(model, state), model.attachments.compliance);
  for (const auto& f : model.families) e += f->energy(state.x.data());
  return e;
}

Metrics measure(const Model& model, const State& state, const Vec3& gravity) {
  if (state.x.cols() != model.num_particles() || state.v.cols() != model.num_particles())
    throw InvalidArgument("the state does not belong to this model (particle counts differ)");
  Metrics m;
  m.t = state.t;
  for (Index i = 0; i < model.num_particles(); ++i) {
    const Real mi = model.mass[i];
    const Vec3 x = state.x.col(i), v = state.v.col(i);
    m.kinetic_energy += 0.5 * mi * v.squaredNorm();
    m.gravitational_energy -= mi * gravity.dot(x);
    m.linear_momentum += mi * v;
    m.angular_momentum += mi * x.cross(v);
  }
  const std::vector<Real> dv = distance_violations(model, state);
  const std::vector<Real> bv = bending_violations(model, state);
  m.distance = summarise(dv);
  m.bending = summarise(bv);
  const std::vector<Real> av = attachment_violations(model, state);
  m.attachment = summarise(av);
  const std::vector<Real> vv = volume_violations(model, state);
  const std::vector<Real> pv = balloon_violations(model, state);
  m.volume = summarise(vv);
  m.balloon = summarise(pv);
  m.elastic_energy = potential(dv, model.distance.compliance) + potential(bv, model.bending.compliance) +
                     potential(av, model.attachments.compliance) + potential(vv, model.volume.compliance) +
                     potential(pv, model.balloons.compliance);
  for (const auto& f : model.families) {
    std::vector<Real> fv(static_cast<std::size_t>(f->size()));
    f->violations(state.x.data(), fv.data());
    m.families.push_back({f->info().name, summarise(fv)});
    m.elastic_energy += f->energy(state.x.data());
  }
  std::vector<Real> strain(dv.size());
  for (std::size_t c = 0; c < dv.size(); ++c) strain[c] = dv[c] / model.distance.rest_length[c];
  const Violation s = summarise(strain);
  m.max_strain = s.max;
  m.rms_strain = s.rms;
  return m;
}

}  // namespace csb
