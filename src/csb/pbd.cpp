#include "csb/pbd.hpp"
#include "csb/format.hpp"

#include "csb/constraints/attachment.hpp"
#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"

#include <Eigen/Eigenvalues>

#include <cmath>
#include <sstream>

namespace csb {

using detail::str;

namespace {



// Index of the first particle whose column is not finite, or -1.
Index first_non_finite(const Positions& x) {
  for (Index i = 0; i < x.cols(); ++i)
    if (!x.col(i).allFinite()) return i;
  return -1;
}

}  // namespace

void validate(const PbdSettings& s) {
  if (!(s.dt > 0) || !std::isfinite(s.dt)) throw InvalidArgument("dt must be a finite time step > 0 s, got " + str(s.dt));
  if (s.substeps < 1) throw InvalidArgument("substeps must be >= 1, got " + std::to_string(s.substeps));
  if (s.iterations < 1) throw InvalidArgument("iterations must be >= 1, got " + std::to_string(s.iterations));
  if (!s.gravity.allFinite()) throw InvalidArgument("gravity must be finite, got " + str(s.gravity));
  if (!(s.damping >= 0 && s.damping <= 1)) throw InvalidArgument("damping must be in [0, 1], got " + str(s.damping));
}

Real corrected_stiffness(Real k, int iterations) {
  if (k >= 1) return 1;
  return 1 - std::pow(1 - k, 1.0 / iterations);
}

PbdStepper::PbdStepper(const PbdSettings& settings) : settings_(settings) { validate(settings_); }

std::int64_t PbdStepper::projections_per_step(const Model& model) const {
  return static_cast<std::int64_t>(settings_.substeps) * settings_.iterations * model.num_constraints();
}

void PbdStepper::prepare(const Model& model) {
  if (model_id_ == model.id) return;
  const auto effective = [this](const std::vector<Real>& k, std::vector<Real>& out) {
    out.resize(k.size());
    for (std::size_t c = 0; c < k.size(); ++c)
      out[c] = settings_.stiffness_correction ? corrected_stiffness(k[c], settings_.iterations) : k[c];
  };
  effective(model.distance.stiffness, k_distance_);
  effective(model.bending.stiffness, k_bending_);
  effective(model.attachments.stiffness, k_attachment_);
  p_.resize(3, model.num_particles());
  model_id_ = model.id;
}

void PbdStepper::step(const Model& model, State& state, std::int64_t steps) {
  const Index n = model.num_particles();
  if (state.x.cols() != n || state.v.cols() != n)
    throw InvalidArgument("the state has " + std::to_string(state.x.cols()) + " positions and " +
                          std::to_string(state.v.cols()) + " velocities, but the model has " + std::to_string(n) +
                          " particles");
  if (steps < 0) throw InvalidArgument("steps must be >= 0, got " + std::to_string(steps));
  for (const Positions* q : {&state.x, &state.v})
    if (const Index i = first_non_finite(*q); i >= 0)
      throw SimulationError("before step " + std::to_string(state.step) + ": particle " + std::to_string(i) +
                            " has a non-finite " + (q == &state.x ? "position " : "velocity ") +
                            str(q->col(i)));
  prepare(model);
  const Real h = settings_.dt / settings_.substeps;
  for (std::int64_t s = 0; s < steps; ++s) {
    for (int k = 0; k < settings_.substeps; ++k) {
      substep(model, state, h);
      if (const Index i = first_non_finite(p_); i >= 0) {
        std::ostringstream msg;
        msg << "step " << state.step << " (substep " << k << ", t = " << state.t << " s): particle " << i
            << " got a non-finite position " << str(p_.col(i))
            << "; the state is left at the end of the last finite substep";
        throw SimulationError(msg.str());
      }
      // (12)-(15) of Algorithm 1.
      state.v = (p_ - state.x) / h;
      state.x = p_;
    }
    ++state.step;
    state.t += settings_.dt;
  }
}

void PbdStepper::substep(const Model& model, State& state, Real h) {
  const Index n = model.num_particles();
  const Real* w = model.inv_mass.data();
  // (5) external forces: gravity accelerates every particle that can move.
  for (Index i = 0; i < n; ++i)
    if (w[i] > 0) state.v.col(i) += h * settings_.gravity;
  // (6)
  if (settings_.damping > 0) damp_velocities(model, state);
  // (7) predict.
  p_ = state.x + h * state.v;

  // (9)-(11) Gauss-Seidel: one constraint type at a time, in model order.
  Real* p = p_.data();
  const auto& dist = model.distance;
  const auto& bend = model.bending;
  const auto& att = model.attachments;
  for (int it = 0; it < settings_.iterations; ++it) {
    for (Index c = 0; c < dist.size(); ++c) {
      const Index i = dist.particles[c][0], j = dist.particles[c][1];
      project_distance(p + 3 * i, p + 3 * j, w[i], w[j], dist.rest_length[c], k_distance_[c], dist.sense[c]);
    }
    for (Index c = 0; c < bend.size(); ++c) {
      const auto& q = bend.particles[c];
      project_bending(p + 3 * q[0], p + 3 * q[1], p + 3 * q[2], p + 3 * q[3], w[q[0]], w[q[1]], w[q[2]], w[q[3]],
                      bend.rest_angle[c], k_bending_[c]);
    }
    for (Index c = 0; c < att.size(); ++c) {
      const Index i = att.particle[c];
      project_attachment(p + 3 * i, w[i], att.target.col(c).data(), k_attachment_[c]);
    }
  }
}

// Müller 2007 §3.5, per group over its particles that can move:
//   x_cm = Σ m_i x_i / Σ m_i,  v_cm = Σ m_i v_i / Σ m_i,  r_i = x_i - x_cm
//   L = Σ r_i x m_i v_i,  I = Σ m_i (|r_i|² 1 - r_i r_iᵀ)  (= Σ r̃_i r̃_iᵀ m_i),  ω = I⁻¹ L
//   Δv_i = v_cm + ω x r_i - v_i,  v_i <- v_i + k_damping Δv_i
// I is singular for collinear particles (a chain): the pseudo-inverse gives the ω of least norm,
// which still reproduces every rigid motion the particles can have.
void PbdStepper::damp_velocities(const Model& model, State& state) const {
  const Real k = settings_.damping;
  for (Index g = 0; g < model.num_groups(); ++g) {
    Real m_total = 0;
    Vec3 x_cm = Vec3::Zero(), v_cm = Vec3::Zero();
    for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
      const Index i = model.group_particles[o];
      if (model.inv_mass[i] <= 0) continue;
      m_total += model.mass[i];
      x_cm += model.mass[i] * state.x.col(i);
      v_cm += model.mass[i] * state.v.col(i);
    }
    if (m_total <= 0) continue;
    x_cm /= m_total;
    v_cm /= m_total;
    Vec3 L = Vec3::Zero();
    Mat3 I = Mat3::Zero();
    for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
      const Index i = model.group_particles[o];
      if (model.inv_mass[i] <= 0) continue;
      const Vec3 r = state.x.col(i) - x_cm;
      L += r.cross(model.mass[i] * state.v.col(i));
      I += model.mass[i] * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
    }
    Eigen::SelfAdjointEigenSolver<Mat3> eig(I);
    const Vec3 lambda = eig.eigenvalues();
    const Real cutoff = 1e-12 * lambda.cwiseAbs().maxCoeff();
    Vec3 inv = Vec3::Zero();
    for (int a = 0; a < 3; ++a)
      if (lambda[a] > cutoff) inv[a] = 1 / lambda[a];
    const Vec3 omega = eig.eigenvectors() * inv.asDiagonal() * eig.eigenvectors().transpose() * L;
    for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
      const Index i = model.group_particles[o];
      if (model.inv_mass[i] <= 0) continue;
      const Vec3 r = state.x.col(i) - x_cm;
      state.v.col(i) += k * (v_cm + omega.cross(r) - state.v.col(i));
    }
  }
}

}  // namespace csb
