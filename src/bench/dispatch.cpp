// csb — the benchmarks of the projection kernels: the proposal's virtual Constraint::project against
// the batches, and the plain distance loop the coloured sweep is measured against.
#include "bench/dispatch.hpp"
#include "csb/solver/sequential.hpp"
#include "csb/constraints/attachment.hpp"
#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"

#include <chrono>
#include <cstring>

namespace csb {

using stepper_detail::VolumeTerms;
using stepper_detail::sweep_batches;

namespace {

class DistanceObject final : public Constraint {
 public:
  DistanceObject(Index i, Index j, Real rest, int sense) : i_(i), j_(j), rest_(rest), sense_(sense) {}
  Real project(bool equality, Real stiffness, const Real* w, Real* p) const override {
    return project_distance(p + 3 * i_, p + 3 * j_, w[i_], w[j_], rest_, stiffness, equality ? 0 : sense_);
  }

 private:
  Index i_, j_;
  Real rest_;
  int sense_;
};

// A four-particle constraint with one rest value (dihedral bending, tet volume) and its kernel.
using FourParticleKernel = Real (*)(Real*, Real*, Real*, Real*, Real, Real, Real, Real, Real, Real);

template <FourParticleKernel Kernel>
class FourParticleObject final : public Constraint {
 public:
  FourParticleObject(const std::array<Index, 4>& q, Real rest) : q_(q), rest_(rest) {}
  Real project(bool, Real stiffness, const Real* w, Real* p) const override {
    return Kernel(p + 3 * q_[0], p + 3 * q_[1], p + 3 * q_[2], p + 3 * q_[3], w[q_[0]], w[q_[1]], w[q_[2]], w[q_[3]],
                  rest_, stiffness);
  }

 private:
  std::array<Index, 4> q_;
  Real rest_;
};

using BendingObject = FourParticleObject<project_bending>;
using VolumeObject = FourParticleObject<project_volume>;

// One balloon as an object: its own copies of the index lists and a gradient workspace (mutable:
// scratch, not state).
class BalloonObject final : public Constraint {
 public:
  BalloonObject(const BalloonBatch& b, Index c)
      : ids_(b.particles.begin() + b.particle_offsets[c], b.particles.begin() + b.particle_offsets[c + 1]),
        tris_(b.triangles.begin() + b.triangle_offsets[c], b.triangles.begin() + b.triangle_offsets[c + 1]),
        target_(b.pressure[c] * b.rest_volume[c]),
        grad_(ids_.size()) {}
  Real project(bool, Real stiffness, const Real* w, Real* p) const override {
    return project_balloon(p, p, nullptr, w, ids_.data(), static_cast<Index>(ids_.size()), tris_.data(),
                           static_cast<Index>(tris_.size()), target_, stiffness, nullptr, 0, 0, nullptr, grad_.data());
  }

 private:
  std::vector<Index> ids_;
  std::vector<Triangle> tris_;
  Real target_;
  mutable std::vector<Vec3> grad_;
};

class AttachmentObject final : public Constraint {
 public:
  AttachmentObject(Index i, const Vec3& target) : i_(i), target_(target) {}
  Real project(bool, Real stiffness, const Real* w, Real* p) const override {
    return project_attachment(p + 3 * i_, w[i_], target_.data(), stiffness);
  }

 private:
  Index i_;
  Vec3 target_;
};

}  // namespace

std::vector<std::unique_ptr<Constraint>> polymorphic_constraints(const Model& model) {
  std::vector<std::unique_ptr<Constraint>> out;
  out.reserve(model.num_constraints());
  const auto& d = model.distance;
  for (Index c = 0; c < d.size(); ++c)
    out.push_back(std::make_unique<DistanceObject>(d.particles[c][0], d.particles[c][1], d.rest_length[c], d.sense[c]));
  for (Index c = 0; c < model.bending.size(); ++c)
    out.push_back(std::make_unique<BendingObject>(model.bending.particles[c], model.bending.rest_angle[c]));
  for (Index c = 0; c < model.volume.size(); ++c)
    out.push_back(std::make_unique<VolumeObject>(model.volume.particles[c], model.volume.rest_volume[c]));
  for (Index c = 0; c < model.balloons.size(); ++c) out.push_back(std::make_unique<BalloonObject>(model.balloons, c));
  for (Index c = 0; c < model.attachments.size(); ++c)
    out.push_back(std::make_unique<AttachmentObject>(model.attachments.particle[c], model.attachments.target.col(c)));
  return out;
}

DispatchTiming benchmark_dispatch(const Model& model, const Positions& positions, int sweeps, int repeats) {
  if (positions.cols() != model.num_particles()) throw InvalidArgument("positions do not match the model");
  if (sweeps < 1 || repeats < 1) throw InvalidArgument("sweeps and repeats must be >= 1");
  // The stepper's own Gauss-Seidel sweep (PBD, stiffness corrected for `sweeps` iterations).
  PbdSettings settings;
  settings.iterations = sweeps;
  std::vector<Real> kd, kb, ka, kv, kp, none;
  for (Real k : model.distance.stiffness) kd.push_back(corrected_stiffness(k, sweeps));
  for (Real k : model.bending.stiffness) kb.push_back(corrected_stiffness(k, sweeps));
  for (Real k : model.volume.stiffness) kv.push_back(corrected_stiffness(k, sweeps));
  for (Real k : model.balloons.stiffness) kp.push_back(corrected_stiffness(k, sweeps));
  for (Real k : model.attachments.stiffness) ka.push_back(corrected_stiffness(k, sweeps));
  Multipliers unused;
  // The same stiffness, one per object, in the objects' order.
  std::vector<Real> k_all(kd);
  k_all.insert(k_all.end(), kb.begin(), kb.end());
  k_all.insert(k_all.end(), kv.begin(), kv.end());
  k_all.insert(k_all.end(), kp.begin(), kp.end());
  k_all.insert(k_all.end(), ka.begin(), ka.end());
  std::vector<char> equality;
  for (Index c = 0; c < model.distance.size(); ++c) equality.push_back(model.distance.sense[c] == 0);
  equality.resize(k_all.size(), 1);
  const auto objects = polymorphic_constraints(model);
  Index largest_balloon = 0;
  for (Index c = 0; c < model.balloons.size(); ++c) largest_balloon = std::max(largest_balloon, model.balloons.num_particles(c));
  std::vector<Vec3> grad(largest_balloon);
  const VolumeTerms vt{kv, none, none, kp, none, none, grad.data()};

  DispatchTiming t;
  // The batches both sides project (a model's constraint families are not among the objects).
  t.projections = static_cast<std::int64_t>(sweeps) * static_cast<std::int64_t>(objects.size());
  Positions a, b;
  const Real* w = model.inv_mass.data();
  for (int r = 0; r < repeats; ++r) {
    a = positions;
    auto t0 = std::chrono::steady_clock::now();
    for (int s = 0; s < sweeps; ++s)
      sweep_batches<Method::Pbd, false>(model, w, settings, a.data(), a.data(), a.data(), nullptr, nullptr, kd, kb, ka,
                                        none, none, none, none, none, none, unused, vt, nullptr);
    auto t1 = std::chrono::steady_clock::now();
    t.batched_ns.push_back(std::chrono::duration<double, std::nano>(t1 - t0).count() / t.projections);
    b = positions;
    t0 = std::chrono::steady_clock::now();
    Real* p = b.data();
    for (int s = 0; s < sweeps; ++s)
      for (std::size_t c = 0; c < objects.size(); ++c) objects[c]->project(equality[c], k_all[c], w, p);
    t1 = std::chrono::steady_clock::now();
    t.virtual_ns.push_back(std::chrono::duration<double, std::nano>(t1 - t0).count() / t.projections);
  }
  t.identical = a.size() == b.size() && std::memcmp(a.data(), b.data(), sizeof(Real) * a.size()) == 0;
  return t;
}

std::vector<double> benchmark_plain_distance(const Model& model, const Positions& positions, int sweeps, int repeats) {
  if (positions.cols() != model.num_particles()) throw InvalidArgument("positions do not match the model");
  if (sweeps < 1 || repeats < 1) throw InvalidArgument("sweeps and repeats must be >= 1");
  const auto& d = model.distance;
  const Index m = d.size();
  if (m == 0) throw InvalidArgument("the model has no distance constraints");
  const Real* w = model.inv_mass.data();
  std::vector<double> ns;
  Positions a;
  for (int r = 0; r < repeats; ++r) {
    a = positions;
    Real* p = a.data();
    const auto t0 = std::chrono::steady_clock::now();
    for (int s = 0; s < sweeps; ++s)
      for (Index c = 0; c < m; ++c) {
        const Index i = d.particles[c][0], j = d.particles[c][1];
        Real* pi = p + 3 * i;
        Real* pj = p + 3 * j;
        const Real dx = pi[0] - pj[0], dy = pi[1] - pj[1], dz = pi[2] - pj[2];
        const Real len = std::sqrt(dx * dx + dy * dy + dz * dz);
        const Real wsum = w[i] + w[j];
        if (wsum <= 0 || len <= 0) continue;
        const Real f = (len - d.rest_length[c]) / (wsum * len);
        pi[0] -= w[i] * f * dx;
        pi[1] -= w[i] * f * dy;
        pi[2] -= w[i] * f * dz;
        pj[0] += w[j] * f * dx;
        pj[1] += w[j] * f * dy;
        pj[2] += w[j] * f * dz;
      }
    const auto t1 = std::chrono::steady_clock::now();
    ns.push_back(std::chrono::duration<double, std::nano>(t1 - t0).count() / (static_cast<double>(sweeps) * m));
  }
  return ns;
}

}  // namespace csb
