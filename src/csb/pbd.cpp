#include "csb/pbd.hpp"
#include "csb/avx2_rows.hpp"
#include "csb/coloured_bending.hpp"
#include "csb/dispatch.hpp"
#include "csb/format.hpp"
#include "csb/team.hpp"

#include "csb/constraints/attachment.hpp"
#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"
#include "csb/memory_budget.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>

#include <thread>
#include <unordered_map>
#include <sstream>

namespace csb {

using detail::str;

namespace {

// Index of the first particle of [begin, end) (default: all) whose column is not finite, or -1.
Index first_non_finite(const Positions& x, Index begin = 0, Index end = -1) {
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
void jacobi_counts(const Model& model, std::vector<Real>& count) {
  count.assign(model.num_particles(), 0);
  for (const auto& e : model.distance.particles)
    for (Index i : e) count[i] += 1;
  for (const auto& q : model.bending.particles)
    for (Index i : q) count[i] += 1;
  for (const auto& q : model.volume.particles)
    for (Index i : q) count[i] += 1;
  for (Index i : model.balloons.particles) count[i] += 1;
  for (Index i : model.attachments.particle) count[i] += 1;
}

// XPBD with averaged Jacobi: the relaxation of a constraint on particles ids[0 .. count), the
// smallest of their 1/count (PbdStepper::set_relaxation); 1 without relaxation (relax null).
Real relaxation(const Real* relax, const Index* ids, Index count) {
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
void relax_multiplier(Real& lambda, Real before, Real om) { lambda = before + om * (lambda - before); }

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

}  // namespace

void validate(const PbdSettings& s) {
  if (!(s.dt > 0) || !std::isfinite(s.dt)) throw InvalidArgument("dt must be a finite time step > 0 s, got " + str(s.dt));
  if (s.substeps < 1) throw InvalidArgument("substeps must be >= 1, got " + std::to_string(s.substeps));
  if (s.iterations < 1) throw InvalidArgument("iterations must be >= 1, got " + std::to_string(s.iterations));
  if (!s.gravity.allFinite()) throw InvalidArgument("gravity must be finite, got " + str(s.gravity));
  if (!(s.damping >= 0 && s.damping <= 1)) throw InvalidArgument("damping must be in [0, 1], got " + str(s.damping));
  if (!(s.xpbd_damping >= 0) || !std::isfinite(s.xpbd_damping))
    throw InvalidArgument("xpbd_damping must be a finite coefficient >= 0, got " + str(s.xpbd_damping));
  if (!(s.verlet_drag >= 0 && s.verlet_drag < 1))
    throw InvalidArgument("verlet_drag must be in [0, 1), got " + str(s.verlet_drag));
  const bool verlet = s.front_end == FrontEnd::Verlet || s.method == Method::Jakobsen;
  if (verlet && s.damping > 0)
    throw InvalidArgument("damping (Müller 2007 §3.5) acts on stored velocities and needs the Euler front end; "
                          "with Verlet use verlet_drag");
  if (!verlet && s.verlet_drag > 0) throw InvalidArgument("verlet_drag applies to the Verlet front end only");
  if (s.method != Method::Xpbd && s.xpbd_damping > 0) throw InvalidArgument("xpbd_damping applies to XPBD only");
  if (s.method != Method::Jakobsen && s.sqrt_approximation)
    throw InvalidArgument("sqrt_approximation is part of Jakobsen's method only");
  if (s.threads < 0)
    throw InvalidArgument("threads must be >= 0 (0: automatic, from the free cores), got " + std::to_string(s.threads));
  if (!(s.max_speed >= 0))
    throw InvalidArgument("max_speed must be a speed >= 0 m/s (0: automatic, inf: no divergence guard), got " +
                          str(s.max_speed));
}

Real corrected_stiffness(Real k, int iterations) {
  if (k >= 1) return 1;
  return 1 - std::pow(1 - k, 1.0 / iterations);
}

std::string PbdStepper::name() const {
  return settings_.method == Method::Pbd ? "pbd" : settings_.method == Method::Xpbd ? "xpbd" : "jakobsen";
}

PbdStepper::PbdStepper(const PbdSettings& settings) : settings_(settings) {
  validate(settings_);
  if (settings_.method == Method::Jakobsen) settings_.front_end = FrontEnd::Verlet;
}

std::int64_t PbdStepper::projections_per_step(const Model& model) const {
  return static_cast<std::int64_t>(settings_.substeps) * settings_.iterations * model.num_constraints();
}

void PbdStepper::prepare(const Model& model) {
  if (model_id_ == model.id) return;
  const Real h = substep_size();
  const auto stiffness = [this](const std::vector<Real>& k, std::vector<Real>& out) {
    out.resize(k.size());
    const bool correct = settings_.method == Method::Pbd && settings_.stiffness_correction;
    for (std::size_t c = 0; c < k.size(); ++c) out[c] = correct ? corrected_stiffness(k[c], settings_.iterations) : k[c];
  };
  const auto compliance = [this, h](const std::vector<Real>& alpha, std::vector<Real>& a, std::vector<Real>& g) {
    a.resize(alpha.size());
    g.resize(alpha.size());
    for (std::size_t c = 0; c < alpha.size(); ++c) {
      a[c] = alpha[c] / (h * h);                     // α̃ = α/h²
      g[c] = alpha[c] * settings_.xpbd_damping / h;  // γ = α̃ β̃ / h = α β / h
    }
  };
  stiffness(model.distance.stiffness, k_distance_);
  stiffness(model.bending.stiffness, k_bending_);
  stiffness(model.volume.stiffness, k_volume_);
  stiffness(model.balloons.stiffness, k_balloon_);
  stiffness(model.attachments.stiffness, k_attachment_);
  if (settings_.method == Method::Xpbd) {
    compliance(model.distance.compliance, a_distance_, g_distance_);
    compliance(model.bending.compliance, a_bending_, g_bending_);
    compliance(model.volume.compliance, a_volume_, g_volume_);
    compliance(model.balloons.compliance, a_balloon_, g_balloon_);
    compliance(model.attachments.compliance, a_attachment_, g_attachment_);
    lambda_.distance.assign(model.distance.size(), 0);
    lambda_.bending.assign(model.bending.size(), 0);
    lambda_.volume.assign(model.volume.size(), 0);
    lambda_.balloon.assign(model.balloons.size(), 0);
    lambda_.attachment.assign(model.attachments.size(), 0);
  }
  const Index n = model.num_particles();
  p_.resize(3, n);
  if (settings_.front_end == FrontEnd::Verlet) x_prev_.resize(3, n);
  Index largest_balloon = 0;
  for (Index b = 0; b < model.balloons.size(); ++b) largest_balloon = std::max(largest_balloon, model.balloons.num_particles(b));
  balloon_grad_.resize(largest_balloon);
  if (settings_.solver != Solver::GaussSeidel) {
    p_start_.resize(3, n);
    delta_.resize(3, n);
    count_.resize(n);
  }
  // Collisions: the triangles of each self-colliding group; hash cells of about a triangle's
  // size plus the thickness on each side (Teschner et al. 2003 find a cell near the mean
  // primitive size best).
  self_groups_.clear();
  std::size_t most_triangles = 0;
  for (Index g = 0; g < model.num_groups(); ++g) {
    const Real h_self = model.self_collision_thickness[g];
    if (!(h_self > 0)) continue;
    SelfGroup sg;
    sg.group = g;
    sg.thickness = h_self;
    Real edges = 0;
    Vec3 lo = Vec3::Constant(std::numeric_limits<Real>::infinity()), hi = -lo;
    for (Index t = 0; t < static_cast<Index>(model.triangles.size()); ++t) {
      const Triangle& tri = model.triangles[t];
      if (model.group[tri[0]] != g) continue;
      sg.triangles.push_back(t);
      for (int e = 0; e < 3; ++e) {
        edges += (model.rest_positions.col(tri[e]) - model.rest_positions.col(tri[(e + 1) % 3])).norm();
        lo = lo.cwiseMin(model.rest_positions.col(tri[e]));
        hi = hi.cwiseMax(model.rest_positions.col(tri[e]));
      }
    }
    // A layer thicker than the cloth is wide puts every triangle near every particle: the broad
    // phase's work would grow as their product each sub-step. Refused by name.
    if (!sg.triangles.empty() && h_self > (hi - lo).norm())
      throw InvalidArgument("the self-collision thickness " + str(h_self) + " m of group '" + model.group_names[g] +
                            "' exceeds the size of its cloth (" + str((hi - lo).norm()) +
                            " m, its rest bounding-box diagonal): give a thickness of the order of the cloth's "
                            "thickness, well under its edges");
    sg.cell = edges / (3.0 * std::max<std::size_t>(sg.triangles.size(), 1)) + 2 * h_self;
    most_triangles = std::max(most_triangles, sg.triangles.size());
    self_groups_.push_back(std::move(sg));
  }
  for (const Collider& c : model.colliders)
    if (c.mesh) most_triangles = std::max(most_triangles, c.mesh->triangles.size());
  stamps_.assign(most_triangles, 0);
  stamp_ = 0;
  contacts_.clear();
  self_contacts_.clear();
  contact_summary_ = {};
  coloured_.model_id = 0;  // the coloured batches follow in step()
  lambda_stale_ = false;
  // The divergence guard's size: the rest bounding box's diagonal, plus the thickest collision
  // layer on either side (contacts push a particle out of it within a sub-step).
  guard_size_ = n > 0 ? (model.rest_positions.rowwise().maxCoeff() - model.rest_positions.rowwise().minCoeff()).norm() : 0;
  Real thickest = 0;
  for (const Real t : model.thickness) thickest = std::max(thickest, t);
  for (const Real t : model.self_collision_thickness) thickest = std::max(thickest, t);
  guard_size_ += 2 * thickest;
  guard_started_ = false;
  model_id_ = model.id;
}

void PbdStepper::step(const Model& model, State& state, std::int64_t steps,
                      const std::function<bool()>& interrupt) {
  const UseGuard::Scope in_use(use_, "PbdStepper.step");
  const Index n = model.num_particles();
  if (state.x.cols() != n || state.v.cols() != n)
    throw InvalidArgument("the state has " + std::to_string(state.x.cols()) + " positions and " +
                          std::to_string(state.v.cols()) + " velocities, but the model has " + std::to_string(n) +
                          " particles");
  if (steps < 0) throw InvalidArgument("steps must be >= 0, got " + std::to_string(steps));
  require_time_for("steps = " + std::to_string(steps), operations(model, steps));
  for (const Positions* q : {&state.x, &state.v})
    if (const Index i = first_non_finite(*q); i >= 0)
      throw SimulationError("before step " + std::to_string(state.step) + ": particle " + std::to_string(i) +
                            " has a non-finite " + (q == &state.x ? "position " : "velocity ") + str(q->col(i)));
  prepare(model);
  const Real h = substep_size();
  const bool verlet = settings_.front_end == FrontEnd::Verlet;
  const Index n3 = 3 * n;
  if (!guard_started_ || state.t < guard_t0_) {  // the divergence guard's baseline: the first state stepped
    guard_v0_ = 0;
    for (Index i = 0; i < n; ++i) guard_v0_ = std::max(guard_v0_, state.v.col(i).norm());
    guard_t0_ = state.t;
    guard_started_ = true;
  }
  Real* x = state.x.data();
  Real* v = state.v.data();
  for (Index i : stop_)  // a pin let go stays where it was put
    if (i < n) state.v.col(i).setZero();
  stop_.clear();
  if (!grabs_.empty()) {  // kinematic grabs: infinite mass while held
    w_ = model.inv_mass;
    for (const Grab& g : grabs_) {
      if (g.particle >= n)
        throw InvalidArgument("grab " + std::to_string(g.handle) + " holds particle " + std::to_string(g.particle) +
                              ", but this model has " + std::to_string(n) + " particles");
      if (g.compliance == 0) w_[g.particle] = 0;
    }
    grab_lambda_.assign(grabs_.size(), 0);
  }
  if (settings_.ordering == Ordering::Coloured) {
    // The coloured batches carry the inverse masses: rebuilt for a new model or when the
    // particles held kinematically (w = 0 while held) change.
    std::vector<Index> kinematic;
    for (const Grab& g : grabs_)
      if (g.compliance == 0) kinematic.push_back(g.particle);
    std::sort(kinematic.begin(), kinematic.end());
    if (coloured_.model_id != model.id || kinematic != coloured_.kinematic) {
      build_coloured(model, grabs_.empty() ? model.inv_mass.data() : w_.data());
      coloured_.kinematic = std::move(kinematic);
    }
    threads_used_ = resolve_threads(model);
  } else {
    threads_used_ = 1;
  }
  if (verlet) {  // the Verlet front end keeps the previous positions instead of the velocity
    Real* xp = x_prev_.data();
    for (Index k = 0; k < n3; ++k) xp[k] = x[k] - h * v[k];
  }
  // Without contacts, grabs or Müller damping a sub-step is element-wise but for the sweeps: the
  // projection's threads then also predict and update (the same operations, split by particle),
  // all sub-steps of a step in one fork of the team; otherwise the sub-steps run here, the team
  // forked for each projection.
  const bool fused = settings_.ordering == Ordering::Coloured && grabs_.empty() && model.colliders.empty() &&
                     self_groups_.empty() && (verlet || settings_.damping <= 0);
  // Between sub-steps, whether the caller asked to stop (set_interrupt): the state is then left
  // at the end of sub-step `sub` of the current step (its time included, its step count not).
  const auto stop_if_asked = [&](int sub) {
    if (!interrupt || !interrupt()) return;
    state.t += (sub + 1) * h;
    if (verlet) state.v = (state.x - x_prev_) / h;
    throw Interrupted("interrupted during step " + std::to_string(state.step) + " after sub-step " +
                      std::to_string(sub) + " (t = " + str(state.t) +
                      " s): the state is left at the end of that sub-step");
  };
  // Sub-steps first .. first + count - 1 of a step, one at a time (each checked for finiteness).
  const auto one_at_a_time = [&](int first, int count) {
    for (int sub = first; sub < first + count; ++sub) {
      one_substep(model, state, h, sub);
      if (sub + 1 < settings_.substeps) stop_if_asked(sub);
    }
  };
  for (std::int64_t s = 0; s < steps; ++s) {
    if (fused) {
      generate_contacts(model, state.x, h);  // (8): none, but the last step's are cleared
      if (settings_.method == Method::Xpbd) lambda_stale_ = true;
      // At most kFusedSubsteps sub-steps a fork, so that a step of very many sub-steps can be
      // interrupted between forks; a fork's last sub-step commits what the next would have
      // updated in the same pass (the same operations), so the bits do not depend on the cut.
      for (int first = 0; first < settings_.substeps; first += kFusedSubsteps) {
        const int count = std::min(kFusedSubsteps, settings_.substeps - first);
        Fused f{&state, h, count};
        project(model, state.x, &f);
        if (f.bad >= 0 && f.bad_sub >= 0) fail_non_finite(state, first + f.bad_sub, f.bad, h);
        // Checked once, after the fork's last sub-step, and found non-finite: back to the fork's
        // start, then its sub-steps again one at a time, each checked (the same operations, so
        // the same positions), which stop at the first non-finite one and leave the state at its
        // start. (A non-finite position stays so to the fork's end: every later operation that
        // writes it has it as an operand; so the check once misses none.)
        if (f.bad >= 0) {
          state.x = x_step_;
          (verlet ? x_prev_ : state.v) = v_step_;
          one_at_a_time(first, count);
        }
        if (first + count < settings_.substeps) stop_if_asked(first + count - 1);
      }
    } else {
      one_at_a_time(0, settings_.substeps);
    }
    ++state.step;
    state.t += settings_.dt;
    for (Grab& g : grabs_) g.from = g.target;
    if (settings_.max_speed != std::numeric_limits<Real>::infinity()) check_divergence(model, state, h);
    if (s + 1 < steps && interrupt && interrupt()) {
      if (verlet) state.v = (state.x - x_prev_) / h;
      throw Interrupted("interrupted after step " + std::to_string(state.step) + " (t = " + str(state.t) +
                        " s): the state is left at the end of that step");
    }
  }
  if (verlet) state.v = (state.x - x_prev_) / h;
}

// One sub-step of Algorithm 1 outside a fused fork: (5)-(7) prediction, grabs, XPBD's multipliers
// set to zero, (8) contacts, the projection, friction, (12)-(15) and restitution (16).
void PbdStepper::one_substep(const Model& model, State& state, Real h, int sub) {
  const Index n = model.num_particles();
  predict(model, state, h);
  if (!grabs_.empty()) apply_grab_targets(Real(sub + 1) / settings_.substeps);
  if (settings_.method == Method::Xpbd && settings_.ordering == Ordering::Coloured) {
    zero_coloured_multipliers(0, 1);
    lambda_stale_ = true;
  } else if (settings_.method == Method::Xpbd) {
    std::fill(lambda_.distance.begin(), lambda_.distance.end(), 0.0);
    std::fill(lambda_.bending.begin(), lambda_.bending.end(), 0.0);
    std::fill(lambda_.volume.begin(), lambda_.volume.end(), 0.0);
    std::fill(lambda_.balloon.begin(), lambda_.balloon.end(), 0.0);
    std::fill(lambda_.attachment.begin(), lambda_.attachment.end(), 0.0);
  }
  generate_contacts(model, state.x, h);  // (8)
  project(model, state.x);
  if (const Index i = first_non_finite(p_); i >= 0) fail_non_finite(state, sub, i, h);
  if (!contacts_.empty()) apply_friction(model, state.x);
  commit(state, h, 0, n);  // (12)-(15) of Algorithm 1
  if (!contacts_.empty() || !self_contacts_.empty()) apply_restitution(model, state, h);  // (16)
}

std::vector<std::string> PbdStepper::accuracy_notes_to_report(const Model& model) const {
  if (reported_models_.count(model.id)) return {};
  const auto& d = model.distance;
  const Real* w = model.inv_mass.data();
  Real worst = 1;
  Index at = -1;
  for (Index c = 0; c < d.size(); ++c) {
    const Real wi = w[d.particles[c][0]], wj = w[d.particles[c][1]];
    if (!(wi > 0) || !(wj > 0)) continue;
    const Real ratio = std::max(wi / wj, wj / wi);
    if (ratio > worst) worst = ratio, at = c;
  }
  const Real allowed = 10 * Real(settings_.iterations) * settings_.substeps * settings_.substeps;
  if (at < 0 || !(worst > allowed)) return {};
  const Index i = d.particles[at][0], j = d.particles[at][1];
  std::ostringstream msg;
  msg << method_label(settings_.method) << " with " << settings_.substeps << " sub-step(s) x " << settings_.iterations
      << " iteration(s): distance constraint " << at << " joins particles " << i << " and " << j
      << " whose masses differ " << worst << " times (" << model.mass[i] << " and " << model.mass[j]
      << " kg), more than 10 x iterations x substeps² = " << allowed
      << "; Gauss-Seidel then moves the light particle almost alone and such links stretch (a hanging chain of "
         "alternating masses: 7-70 % of their length at that ratio, up to 15 times it ten times beyond). More "
         "sub-steps raise the limit fastest; or keep neighbours' masses closer";
  return {msg.str()};
}

std::vector<std::string> PbdStepper::degenerate_notes_to_report(const Model& model, const State& state) {
  if (degenerate_reported_.count(model.id) || state.x.cols() != model.num_particles()) return {};
  // A new model, the next check's step reached, or a state from further back (another state).
  const bool due = model.id != degenerate_model_ || state.step >= degenerate_next_ ||
                   state.step + kDegenerateCheckSteps < degenerate_next_;
  if (!due) return {};
  degenerate_model_ = model.id;
  degenerate_next_ = state.step + kDegenerateCheckSteps;
  const Real* w = model.inv_mass.data();
  const auto& d = model.distance;
  Index coincident = 0, first_distance = -1;
  for (Index c = 0; c < d.size(); ++c) {
    const auto [i, j] = d.particles[c];
    const Real tiny = 1e-9 * d.rest_length[c];
    if ((state.x.col(i) - state.x.col(j)).squaredNorm() < tiny * tiny && w[i] + w[j] > 0) {
      if (first_distance < 0) first_distance = c;
      ++coincident;
    }
  }
  const auto& v = model.volume;
  Index collapsed = 0, first_tet = -1;
  for (Index t = 0; t < v.size(); ++t) {
    const auto& q = v.particles[t];
    Vec3 grad[4];
    tet_volume_gradient(state.x.col(q[0]), state.x.col(q[1]), state.x.col(q[2]), state.x.col(q[3]), grad);
    if (!volume_gradient_usable(grad, state.x.col(q[0]), state.x.col(q[1]), state.x.col(q[2]), state.x.col(q[3])) &&
        w[q[0]] + w[q[1]] + w[q[2]] + w[q[3]] > 0) {
      if (first_tet < 0) first_tet = t;
      ++collapsed;
    }
  }
  if (coincident == 0 && collapsed == 0) return {};
  degenerate_reported_.insert(model.id);
  std::ostringstream msg;
  msg << "the state is degenerate at t = " << state.t << " s:";
  if (coincident > 0) {
    const auto [i, j] = d.particles[first_distance];
    msg << " " << coincident << " distance constraint(s) join coincident particles (first: constraint "
        << first_distance << ", particles " << i << " and " << j << ", rest length " << d.rest_length[first_distance]
        << " m)" << (collapsed > 0 ? ";" : "");
  }
  if (collapsed > 0)
    msg << " " << collapsed << " tet(s) are collapsed onto a line or a point (first: volume constraint " << first_tet
        << ")";
  msg << ". Their gradient has no direction, so " << method_label(settings_.method)
      << " leaves them alone and they stay collapsed; separate the particles (state.x) before stepping";
  return {msg.str()};
}

void PbdStepper::check_divergence(const Model& model, State& state, Real h) {
  const Index n = model.num_particles();
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  const bool verlet = settings_.front_end == FrontEnd::Verlet;
  const Real elapsed = std::max(state.t - guard_t0_, Real(0));
  const Real g = settings_.gravity.norm();
  // What a stable run can reach: the start's fastest speed, what gravity adds since, and a swing
  // over the model's size (sqrt(2 g D), a pendulum's lowest point), twice over; plus a crossing
  // of the whole model in one sub-step, which the constraints and contacts cannot follow.
  const Real natural = guard_v0_ + g * elapsed + std::sqrt(2 * g * guard_size_);
  const Real limit = settings_.max_speed > 0 ? settings_.max_speed : 2 * natural + guard_size_ / h;
  // Squared speeds (Verlet: from the last sub-step's displacement), no square root per particle.
  const Real limit2 = limit * limit;
  Index worst = -1;
  Real worst2 = limit2;
  for (Index i = 0; i < n; ++i) {
    if (!(w[i] > 0)) continue;
    const Vec3 v = verlet ? Vec3((state.x.col(i) - x_prev_.col(i)) / h) : Vec3(state.v.col(i));
    const Real v2 = v.squaredNorm();
    if (v2 > worst2) worst2 = v2, worst = i;
  }
  if (worst < 0) return;
  // The particle's most strained distance constraint, for the message (the error path only).
  Real strain = 0;
  const auto& d = model.distance;
  for (Index c = 0; c < d.size(); ++c) {
    const auto& e = d.particles[c];
    if (e[0] != worst && e[1] != worst) continue;
    const Real len = (state.x.col(e[0]) - state.x.col(e[1])).norm();
    if (d.rest_length[c] > 0) strain = std::max(strain, len / d.rest_length[c]);
  }
  std::ostringstream msg;
  msg << "step " << state.step << " (t = " << state.t << " s): particle " << worst << " moves at "
      << std::sqrt(worst2) << " m/s, beyond the divergence guard's " << limit << " m/s (";
  if (settings_.max_speed > 0)
    msg << "max_speed";
  else
    msg << "automatic: the model's size " << guard_size_ << " m per sub-step of " << h << " s, plus twice "
        << natural << " m/s, the start's fastest " << guard_v0_ << " m/s, |g| t = " << g * elapsed
        << " m/s and sqrt(2 |g| size) = " << std::sqrt(2 * g * guard_size_) << " m/s";
  msg << "): the simulation is diverging";
  if (strain > 0) msg << "; its most stretched distance constraint is at " << strain << " times its rest length";
  msg << ". Usual causes: a time step or sub-step too large for the stiffness, too few iterations for sliver "
         "triangles or vertices of very high valence (csb warns of them when the mesh is added), or summed Jacobi. "
         "The state is left at the end of this step; max_speed sets the guard (inf turns it off).";
  if (verlet) state.v = (state.x - x_prev_) / h;
  throw SimulationError(msg.str());
}

void PbdStepper::predict(const Model& model, State& state, Real h) {
  const Index n = model.num_particles();
  if (settings_.front_end == FrontEnd::Euler && settings_.damping > 0) {
    // (5), then (6), which needs every velocity updated, then (7).
    const Real* w = model.inv_mass.data();
    for (Index i = 0; i < n; ++i)
      if (w[i] > 0) state.v.col(i) += h * settings_.gravity;
    damp_velocities(model, state);
    const Real* x = state.x.data();
    const Real* v = state.v.data();
    Real* p = p_.data();
    for (Index k = 0; k < 3 * n; ++k) p[k] = x[k] + h * v[k];
    return;
  }
  predict_range(model, state, h, 0, n);
}

void PbdStepper::predict_range(const Model& model, State& state, Real h, Index begin, Index end) {
  const Real* w = model.inv_mass.data();
  const Vec3& g = settings_.gravity;
  const Real* x = state.x.data();
  Real* v = state.v.data();
  Real* p = p_.data();
  if (settings_.front_end == FrontEnd::Verlet) {
    // p = x + (1 - d)(x - x*) + h² g: the velocity lives in the previous positions.
    const Real keep = 1 - settings_.verlet_drag;
    const Real* xp = x_prev_.data();
    for (Index i = begin; i < end; ++i) {
      const Real a = w[i] > 0 ? h * h : 0;
      for (int k = 0; k < 3; ++k) p[3 * i + k] = x[3 * i + k] + keep * (x[3 * i + k] - xp[3 * i + k]) + a * g[k];
    }
    return;
  }
  // (5) and (7) in one pass.
  for (Index i = begin; i < end; ++i) {
    const Real a = w[i] > 0 ? h : 0;
    for (int k = 0; k < 3; ++k) {
      v[3 * i + k] += a * g[k];
      p[3 * i + k] = x[3 * i + k] + h * v[3 * i + k];
    }
  }
}

namespace {

// The update of a sub-step and the prediction of the next for coordinates [k0, k1) in one pass:
// Euler v = (p - x)/h + a, x = p, p = x + h v; Verlet x* = x, x = p, p = x + keep (x - x*) + a
// (a = accel_). The operations of commit and predict_range, in their order: the same bits.
inline __attribute__((always_inline)) void advance_euler_body(Real* __restrict x, Real* __restrict v,
                                                              Real* __restrict p, const Real* __restrict a, Real h,
                                                              Index k0, Index k1) {
  for (Index k = k0; k < k1; ++k) {
    const Real pk = p[k];
    const Real vk = (pk - x[k]) / h + a[k];
    x[k] = pk;
    v[k] = vk;
    p[k] = pk + h * vk;
  }
}
inline __attribute__((always_inline)) void advance_verlet_body(Real* __restrict x, Real* __restrict xp,
                                                               Real* __restrict p, const Real* __restrict a, Real keep,
                                                               Index k0, Index k1) {
  for (Index k = k0; k < k1; ++k) {
    const Real pk = p[k], xk = x[k];
    xp[k] = xk;
    x[k] = pk;
    p[k] = pk + keep * (pk - xk) + a[k];
  }
}
void advance_euler_base(Real* x, Real* v, Real* p, const Real* a, Real h, Index k0, Index k1) {
  advance_euler_body(x, v, p, a, h, k0, k1);
}
void advance_verlet_base(Real* x, Real* xp, Real* p, const Real* a, Real keep, Index k0, Index k1) {
  advance_verlet_body(x, xp, p, a, keep, k0, k1);
}
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__AVX2__)
// Four lanes instead of SSE2's two (the division dominates): taken with the AVX2 kernels.
#define CSB_ADVANCE_AVX2 1
__attribute__((target("avx2"))) void advance_euler_avx2(Real* x, Real* v, Real* p, const Real* a, Real h, Index k0,
                                                         Index k1) {
  advance_euler_body(x, v, p, a, h, k0, k1);
}
__attribute__((target("avx2"))) void advance_verlet_avx2(Real* x, Real* xp, Real* p, const Real* a, Real keep,
                                                          Index k0, Index k1) {
  advance_verlet_body(x, xp, p, a, keep, k0, k1);
}
#endif

}  // namespace

void PbdStepper::set_accel(const Model& model, Real h, Index begin, Index end) {
  const Real* w = model.inv_mass.data();
  const Vec3& g = settings_.gravity;
  const Real step = settings_.front_end == FrontEnd::Verlet ? h * h : h;
  for (Index i = begin; i < end; ++i) {
    const Real a = w[i] > 0 ? step : 0;
    for (int k = 0; k < 3; ++k) accel_[3 * i + k] = a * g[k];
  }
}

void PbdStepper::advance(State& state, Real h, Index begin, Index end) {
  const bool verlet = settings_.front_end == FrontEnd::Verlet;
  Real* x = state.x.data();
  Real* v = verlet ? x_prev_.data() : state.v.data();
  const Real keep = 1 - settings_.verlet_drag;
#if defined(CSB_ADVANCE_AVX2)
  if (kernels_use_avx2()) {
    if (verlet)
      advance_verlet_avx2(x, v, p_.data(), accel_.data(), keep, 3 * begin, 3 * end);
    else
      advance_euler_avx2(x, v, p_.data(), accel_.data(), h, 3 * begin, 3 * end);
    return;
  }
#endif
  if (verlet)
    advance_verlet_base(x, v, p_.data(), accel_.data(), keep, 3 * begin, 3 * end);
  else
    advance_euler_base(x, v, p_.data(), accel_.data(), h, 3 * begin, 3 * end);
}

void PbdStepper::commit(State& state, Real h, Index begin, Index end) {
  Real* x = state.x.data();
  Real* v = state.v.data();
  const Real* p = p_.data();
  if (settings_.front_end == FrontEnd::Verlet) {
    Real* xp = x_prev_.data();
    for (Index k = 3 * begin; k < 3 * end; ++k) {
      xp[k] = x[k];
      x[k] = p[k];
    }
  } else {
    for (Index k = 3 * begin; k < 3 * end; ++k) {
      v[k] = (p[k] - x[k]) / h;
      x[k] = p[k];
    }
  }
}

void PbdStepper::zero_coloured_multipliers(int share, int shares) {
  for (std::vector<Real>* l : {&coloured_.distance.lambda, &coloured_.bending.lambda, &coloured_.volume.lambda,
                               &coloured_.attachments.lambda, &lambda_.balloon}) {
    const std::int64_t m = static_cast<std::int64_t>(l->size());
    std::fill(l->begin() + m * share / shares, l->begin() + m * (share + 1) / shares, 0.0);
  }
}

void PbdStepper::fail_non_finite(State& state, int sub, Index i, Real h) {
  if (settings_.front_end == FrontEnd::Verlet) state.v = (state.x - x_prev_) / h;
  std::ostringstream msg;
  msg << "step " << state.step << " (substep " << sub << ", t = " << state.t << " s): particle " << i
      << " got a non-finite position " << str(p_.col(i)) << "; the state is left at the end of the last finite substep";
  throw SimulationError(msg.str());
}

// One sweep over all constraints, one batch at a time in model order. M picks the projection,
// Jacobi whether the kernels see the positions at the sweep's start (corrections collected in
// delta_ and count_) or each other's corrections as they come (Gauss-Seidel). relax (XPBD with
// averaged Jacobi, else null): each constraint's Δλ and correction scaled by its relaxation.
template <Method M, bool Jacobi>
static void sweep_batches(const Model& model, const Real* w, const PbdSettings& settings, Real* p, const Real* from,
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

void PbdStepper::project_sequential(const Model& model, const Positions& x_start) {
  const Solver solver = settings_.solver;
  const bool jacobi = solver != Solver::GaussSeidel;
  const Index n = model.num_particles();
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  set_relaxation(model);
  const Real* relax = relax_.empty() ? nullptr : relax_.data();
  for (int it = 0; it < settings_.iterations; ++it) {
    if (jacobi) {
      p_start_ = p_;
      delta_.setZero();
      std::fill(count_.begin(), count_.end(), 0.0);
    }
    Real* p = p_.data();
    const Real* from = jacobi ? p_start_.data() : p;
    Real* delta = jacobi ? delta_.data() : nullptr;
    Real* count = jacobi ? count_.data() : nullptr;
    const VolumeTerms vt{k_volume_, a_volume_, g_volume_, k_balloon_, a_balloon_, g_balloon_, balloon_grad_.data()};
    const auto run = [&](auto method, auto jacobi_tag) {
      sweep_batches<decltype(method)::value, decltype(jacobi_tag)::value>(
          model, w, settings_, p, from, x_start.data(), delta, count, k_distance_, k_bending_, k_attachment_,
          a_distance_, a_bending_, a_attachment_, g_distance_, g_bending_, g_attachment_, lambda_, vt, relax);
    };
    using Pbd = std::integral_constant<Method, Method::Pbd>;
    using Xpbd = std::integral_constant<Method, Method::Xpbd>;
    using Jak = std::integral_constant<Method, Method::Jakobsen>;
    switch (settings_.method) {
      case Method::Pbd:
        jacobi ? run(Pbd{}, std::true_type{}) : run(Pbd{}, std::false_type{});
        break;
      case Method::Xpbd:
        jacobi ? run(Xpbd{}, std::true_type{}) : run(Xpbd{}, std::false_type{});
        break;
      case Method::Jakobsen:
        jacobi ? run(Jak{}, std::true_type{}) : run(Jak{}, std::false_type{});
        break;
    }
    if (!contacts_.empty() || !self_contacts_.empty()) project_contacts(model, jacobi);
    if (jacobi) {
      // Averaged Jacobi moves each particle by the mean of the corrections it received (XPBD: by
      // the sum of its relaxed ones); summed Jacobi by their sum, which overshoots where
      // constraints pull the same way.
      const bool average = solver == Solver::Jacobi && !relax;
      for (Index i = 0; i < n; ++i) {
        const Real scale = average ? (count_[i] > 0 ? 1 / count_[i] : 0) : 1;
        p_.col(i) = p_start_.col(i) + scale * delta_.col(i);
      }
      if (!contacts_.empty() && settings_.method != Method::Xpbd) settle_contact_moves(average);
    }
    project_grabs(x_start);
  }
}

// ------------------------------------------------------------------------------ coloured sweep
//
// Each batch is projected colour by colour (Model's `colours`); the constraints of one
// colour share no particle, so within a colour a range of constraints is a loop whose iterations
// are independent: `omp simd` lets the compiler put one constraint in each SIMD lane (the kernels
// below are branch-free in the common case: masks instead of early returns, coefficients
// precomputed in ColouredBatches).
//
// Threads share the work by groups (see Colouring): a sweep is
//  1. the parts' interiors, each part a task: one thread projects every batch's colours of that
//     part (distance, then bending, volume, attachments; with PBD or Jakobsen Gauss-Seidel a
//     bending element also projects the distance constraint on its edge, just before itself,
//     see build_coloured), no barrier between colours;
//  2. the interfaces (constraints between parts i and i + 1), each a task, in the model's
//     interface phases, whose interfaces share no particle (one phase for a cloth);
//  3. the rest, colour by colour, threads sharing ranges of a colour (`kChunk`) with a barrier
//     after each (constraints across non-adjacent parts; usually none).
// The tasks of one phase share no particle, and threads take them dynamically, so a thread
// slowed by a busy core takes fewer. A cloth's sweep thus has two barriers where colour by
// colour it had one per colour, 26; and a part's particles stay in the core's cache while all of
// its colours are projected.
//
// Every constraint is computed by the same instructions whatever the thread count or the range
// it falls in (IEEE +, -, *, / and sqrt give the same bits in a SIMD lane and in a scalar
// register; no FMA contraction), every task runs its colours in a fixed order, and no two tasks
// of a phase touch the same particle, so the result does not depend on the number of threads.
// A serial colour (constraints that may share particles) is projected in its order. Jacobi reads
// the sweep's start and adds each correction to the particle's sum: each particle receives its
// corrections in a fixed order (no atomics on floats).
//
// Kernels read positions from r and apply corrections to o: Gauss-Seidel r = o = p, Jacobi
// r = the positions at the sweep's start, o = the correction sums.

#if defined(__GNUC__)
#define CSB_INLINE inline __attribute__((always_inline))
#else
#define CSB_INLINE inline
#endif

namespace {

// PBD (Müller 2007 §3.3) and Jakobsen: Δp_i = -c_i s d, Δp_j = +c_j s d, d = p_i - p_j, with
// s = C/|d| (C the violation, see constraints/distance.hpp) or, with Jakobsen's square-root
// approximation, s = (d·d - r²)/(d·d + r²); c = k w/(w_i + w_j) precomputed.
template <bool Approx>
CSB_INLINE void distance_pbd(const ColouredDistance& b, Index c, const Real* r, Real* o) {
  const Index i = 3 * b.i[c], j = 3 * b.j[c];
  const Real dx = r[i] - r[j], dy = r[i + 1] - r[j + 1], dz = r[i + 2] - r[j + 2];
  const Real dd = dx * dx + dy * dy + dz * dz;
  const Real rest = b.rest[c];
  const Real sense = b.sense[c];
  Real s;
  if constexpr (Approx) {
    const Real r2 = rest * rest;
    const Real cj = (dd - r2) / (2 * rest);
    const Real violation = cj - sense * std::max(sense * cj, Real(0));
    const Real den = dd + r2;  // selects on values, then an unconditional division: no branch
    s = (violation != 0 ? dd - r2 : Real(0)) / (den > 0 ? den : Real(1));
  } else {
    const Real len = std::sqrt(dd);
    const Real cl = len - rest;
    const Real violation = cl - sense * std::max(sense * cl, Real(0));
    s = (len > 0 ? violation : Real(0)) / (len > 0 ? len : Real(1));
  }
  const Real si = b.ci[c] * s, sj = b.cj[c] * s;
  o[i] -= si * dx;
  o[i + 1] -= si * dy;
  o[i + 2] -= si * dz;
  o[j] += sj * dx;
  o[j + 1] += sj * dy;
  o[j + 2] += sj * dz;
}

// The same over the independent constraints [begin, end) of one colour, in blocks of kDistanceBlock:
// positions gathered into small arrays one constraint at a time, the arithmetic in a loop the
// compiler runs in SIMD lanes (distance_pbd_block_s), the corrections scattered back. (SSE2 has
// no gather instruction to vectorise the plain loop with; with AVX-512's, in a native build, the
// plain loop ran at 7.9 ns per projection against these blocks' 5.8 in AVX2:
// papers/benchmarks.md.) Per constraint the same operations in the same order as distance_pbd,
// so the same bits.
constexpr Index kDistanceBlock = 32;

// s of constraints c0 + [0, m) from their d = p_i - p_j.
template <bool Approx>
CSB_INLINE void distance_pbd_block_s(const ColouredDistance& b, Index c0, Index m, const Real* dx, const Real* dy,
                                     const Real* dz, Real* s) {
  const Real* rest = b.rest.data() + c0;
  const std::int8_t* sense = b.sense.data() + c0;
#pragma omp simd
  for (Index k = 0; k < m; ++k) {
    const Real dd = dx[k] * dx[k] + dy[k] * dy[k] + dz[k] * dz[k];
    const Real sn = sense[k];
    if constexpr (Approx) {
      const Real r2 = rest[k] * rest[k];
      const Real cj = (dd - r2) / (2 * rest[k]);
      const Real violation = cj - sn * std::max(sn * cj, Real(0));
      const Real den = dd + r2;
      s[k] = (violation != 0 ? dd - r2 : Real(0)) / (den > 0 ? den : Real(1));
    } else {
      const Real len = std::sqrt(dd);
      const Real cl = len - rest[k];
      const Real violation = cl - sn * std::max(sn * cl, Real(0));
      s[k] = (len > 0 ? violation : Real(0)) / (len > 0 ? len : Real(1));
    }
  }
}

// d = p_i - p_j of constraints c0 + [k0, m), one at a time.
CSB_INLINE void distance_gather(const ColouredDistance& b, Index c0, Index k0, Index m, const Real* r, Real* dx,
                                Real* dy, Real* dz) {
  for (Index k = k0; k < m; ++k) {
    const Index i = 3 * b.i[c0 + k], j = 3 * b.j[c0 + k];
    dx[k] = r[i] - r[j];
    dy[k] = r[i + 1] - r[j + 1];
    dz[k] = r[i + 2] - r[j + 2];
  }
}

// The corrections -c_i s d and +c_j s d of constraints c0 + [k0, m), one at a time.
CSB_INLINE void distance_scatter(const ColouredDistance& b, Index c0, Index k0, Index m, const Real* s,
                                 const Real* dx, const Real* dy, const Real* dz, Real* o) {
  for (Index k = k0; k < m; ++k) {
    const Index i = 3 * b.i[c0 + k], j = 3 * b.j[c0 + k];
    const Real si = b.ci[c0 + k] * s[k], sj = b.cj[c0 + k] * s[k];
    o[i] -= si * dx[k];
    o[i + 1] -= si * dy[k];
    o[i + 2] -= si * dz[k];
    o[j] += sj * dx[k];
    o[j + 1] += sj * dy[k];
    o[j + 2] += sj * dz[k];
  }
}

template <bool Approx>
CSB_INLINE void distance_pbd_blocks(const ColouredDistance& b, Index begin, Index end, const Real* r, Real* o) {
  constexpr Index B = kDistanceBlock;
  alignas(64) Real dx[B], dy[B], dz[B], s[B];
  for (Index c0 = begin; c0 < end; c0 += B) {
    const Index m = std::min(B, end - c0);
    distance_gather(b, c0, 0, m, r, dx, dy, dz);
    distance_pbd_block_s<Approx>(b, c0, m, dx, dy, dz, s);
    distance_scatter(b, c0, 0, m, s, dx, dy, dz, o);
  }
}

#if CSB_HAS_AVX2_ROWS
// The blocks again with AVX2 lanes, four constraints gathered and scattered at a time in AVX2
// registers (csb/avx2_rows.hpp), the rest of a block one at a time; taken when the processor has
// AVX2 (see coloured_bending.cpp).
__attribute__((target("avx2"))) void distance_pbd_blocks_avx2(const ColouredDistance& b, Index begin, Index end,
                                                               const Real* r, Real* o) {
  using namespace avx2;
  constexpr Index B = kDistanceBlock;
  alignas(64) Real dx[B], dy[B], dz[B], s[B];
  for (Index c0 = begin; c0 < end; c0 += B) {
    const Index m = std::min(B, end - c0), m4 = m - m % 4;
    const Index* bi = b.i.data() + c0;
    const Index* bj = b.j.data() + c0;
    for (Index k = 0; k < m4; k += 4) {
      __m256d d[4];
      for (int l = 0; l < 4; ++l) d[l] = _mm256_sub_pd(load_xyz(r + 3 * bi[k + l]), load_xyz(r + 3 * bj[k + l]));
      __m256d x, y, z;
      rows(d[0], d[1], d[2], d[3], x, y, z);
      _mm256_store_pd(dx + k, x);
      _mm256_store_pd(dy + k, y);
      _mm256_store_pd(dz + k, z);
    }
    distance_gather(b, c0, m4, m, r, dx, dy, dz);
    distance_pbd_block_s<false>(b, c0, m, dx, dy, dz, s);
    const Real* ci = b.ci.data() + c0;
    const Real* cj = b.cj.data() + c0;
    for (Index k = 0; k < m4; k += 4) {
      const __m256d sk = _mm256_load_pd(s + k);
      const __m256d x = _mm256_load_pd(dx + k), y = _mm256_load_pd(dy + k), z = _mm256_load_pd(dz + k);
      const __m256d si = _mm256_mul_pd(_mm256_loadu_pd(ci + k), sk), sj = _mm256_mul_pd(_mm256_loadu_pd(cj + k), sk);
      const Index at_i[4] = {3 * bi[k], 3 * bi[k + 1], 3 * bi[k + 2], 3 * bi[k + 3]};
      const Index at_j[4] = {3 * bj[k], 3 * bj[k + 1], 3 * bj[k + 2], 3 * bj[k + 3]};
      add_rows<true>(o, at_i, _mm256_mul_pd(si, x), _mm256_mul_pd(si, y), _mm256_mul_pd(si, z));
      add_rows(o, at_j, _mm256_mul_pd(sj, x), _mm256_mul_pd(sj, y), _mm256_mul_pd(sj, z));
    }
    distance_scatter(b, c0, m4, m, s, dx, dy, dz, o);
  }
}
#endif
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__AVX2__)
#define CSB_DISTANCE_AVX2 1
#endif

// XPBD (Macklin 2016 Eq. (18), (26)); see project_distance_xpbd. x: positions at the sub-step's start.
// Relaxed (averaged Jacobi): Δλ, after its sign clamp, scaled by the constraint's relaxation
// min(relax_i, relax_j) (PbdStepper::set_relaxation).
template <bool Relaxed = false>
CSB_INLINE void distance_xpbd(ColouredDistance& b, Index c, const Real* r, Real* o, const Real* x,
                              const Real* relax = nullptr) {
  const Index i = 3 * b.i[c], j = 3 * b.j[c];
  const Real dx = r[i] - r[j], dy = r[i + 1] - r[j + 1], dz = r[i + 2] - r[j + 2];
  const Real len = std::sqrt(dx * dx + dy * dy + dz * dz);
  const Real inv_len = Real(len > 0 ? 1 : 0) / (len > 0 ? len : Real(1));
  const Real nx = dx * inv_len, ny = dy * inv_len, nz = dz * inv_len;
  const Real cl = len - b.rest[c];
  const Real g = b.gamma[c];
  const Real along = nx * ((r[i] - x[i]) - (r[j] - x[j])) + ny * ((r[i + 1] - x[i + 1]) - (r[j + 1] - x[j + 1])) +
                     nz * ((r[i + 2] - x[i + 2]) - (r[j + 2] - x[j + 2]));
  const Real moved = g == 0 ? Real(0) : along;
  const Real lambda = b.lambda[c];
  Real dl = (-cl - b.alpha[c] * lambda - g * moved) * b.inv_den[c];
  const Real sense = b.sense[c];
  const Real next = lambda + dl;
  const Real clamped = sense > 0 ? std::max(next, Real(0)) : std::min(next, Real(0));
  dl = sense == 0 ? dl : clamped - lambda;
  dl = len > 0 ? dl : Real(0);
  if constexpr (Relaxed) dl *= std::min(relax[b.i[c]], relax[b.j[c]]);
  b.lambda[c] = lambda + dl;
  const Real di = b.ci[c] * dl, dj = b.cj[c] * dl;
  o[i] += di * nx;
  o[i + 1] += di * ny;
  o[i + 2] += di * nz;
  o[j] -= dj * nx;
  o[j + 1] -= dj * ny;
  o[j + 2] -= dj * nz;
}

// Dihedral bending: csb/coloured_bending.hpp (SIMD blocks, polynomial atan2).

// Tet volume: the kernels of constraints/volume.hpp, on local copies for Jacobi.
// relax (XPBD with averaged Jacobi, else null): Δλ and the corrections scaled by the
// constraint's relaxation (PbdStepper::set_relaxation).
template <Method M, bool Jacobi>
CSB_INLINE void volume_one(ColouredFour& b, Index k, const Real* r, Real* o, const Real* x, const Real* relax) {
  const auto& q = b.q[k];
  const auto& w = b.w[k];
  Real local[4][3];
  Real* at[4];
  for (int s = 0; s < 4; ++s) {
    if constexpr (Jacobi) {
      for (int e = 0; e < 3; ++e) local[s][e] = r[3 * q[s] + e];
      at[s] = local[s];
    } else {
      at[s] = o + 3 * q[s];
    }
  }
  Real om = 1;
  if constexpr (M == Method::Xpbd) {
    const Real before = b.lambda[k];
    project_volume_xpbd(at[0], at[1], at[2], at[3], x + 3 * q[0], x + 3 * q[1], x + 3 * q[2], x + 3 * q[3], w[0], w[1],
                        w[2], w[3], b.rest[k], b.alpha[k], b.gamma[k], b.lambda[k]);
    if (Jacobi && relax) {
      om = relaxation(relax, q);
      relax_multiplier(b.lambda[k], before, om);
    }
  } else {
    project_volume(at[0], at[1], at[2], at[3], w[0], w[1], w[2], w[3], b.rest[k], b.k[k]);
  }
  if constexpr (Jacobi)
    for (int s = 0; s < 4; ++s)
      for (int e = 0; e < 3; ++e) o[3 * q[s] + e] += om * (local[s][e] - r[3 * q[s] + e]);
}

// Dihedral bending with XPBD and averaged Jacobi: the scalar kernel of constraints/bending.hpp
// on local copies, relaxed like volume_one (the blocks of coloured_bending.hpp serve every other
// case).
CSB_INLINE void bending_xpbd_relaxed(ColouredFour& b, Index k, const Real* r, Real* o, const Real* x,
                                     const Real* relax) {
  const auto& q = b.q[k];
  const auto& w = b.w[k];
  Real local[4][3];
  for (int s = 0; s < 4; ++s)
    for (int e = 0; e < 3; ++e) local[s][e] = r[3 * q[s] + e];
  const Real before = b.lambda[k];
  project_bending_xpbd(local[0], local[1], local[2], local[3], x + 3 * q[0], x + 3 * q[1], x + 3 * q[2], x + 3 * q[3],
                       w[0], w[1], w[2], w[3], b.rest[k], b.alpha[k], b.gamma[k], b.lambda[k]);
  const Real om = relaxation(relax, q);
  relax_multiplier(b.lambda[k], before, om);
  for (int s = 0; s < 4; ++s)
    for (int e = 0; e < 3; ++e) o[3 * q[s] + e] += om * (local[s][e] - r[3 * q[s] + e]);
}

template <Method M, bool Jacobi>
CSB_INLINE void attachment_one(ColouredAttachments& b, Index k, const Real* r, Real* o, const Real* x,
                               const Real* relax) {
  const Index i = b.i[k];
  Real local[3];
  Real* at = o + 3 * i;
  if constexpr (Jacobi) {
    for (int e = 0; e < 3; ++e) local[e] = r[3 * i + e];
    at = local;
  }
  Real om = 1;
  if constexpr (M == Method::Xpbd) {
    const Real before = b.lambda[k];
    project_attachment_xpbd(at, x + 3 * i, b.w[k], b.target[k].data(), b.alpha[k], b.gamma[k], b.lambda[k]);
    if (Jacobi && relax) {
      om = relax[i];
      relax_multiplier(b.lambda[k], before, om);
    }
  } else {
    project_attachment(at, b.w[k], b.target[k].data(), b.k[k]);
  }
  if constexpr (Jacobi)
    for (int e = 0; e < 3; ++e) o[3 * i + e] += om * (local[e] - r[3 * i + e]);
}

// Constraints per dynamically scheduled range: a few microseconds of work, so that taking a
// range costs little beside it; fixed, so that ranges do not depend on the thread count.
constexpr Index kChunkDistance = 256, kChunkFour = 64, kChunkAttachment = 256;

// Runs `kernel(begin, end, independent)` over the colours of group g of `colours`, in order,
// on the calling thread.
template <class Kernel>
void group_colours(const Colouring& colours, Index g, Kernel&& kernel) {
  for (Index k = colours.group_colours[g]; k < colours.group_colours[g + 1]; ++k)
    kernel(colours.colour_offsets[k], colours.colour_offsets[k + 1], !colours.serial(k));
}

// One thread's view of the team during a projection: every thread makes the same calls in the
// same order (the phases are counted alike on each).
struct Share {
  Team& team;
  int t;                   // this thread
  std::int64_t phase = 0;  // phases begun

  // Tasks 0 .. count - 1 shared dynamically, then a barrier. The tasks are cut into one range per
  // thread (up to Team::kRanges), each with its own counter: a thread takes the tasks of its own
  // range first, then those left in the others'. So a part stays on one core from sweep to sweep
  // (its particles and constraints in that core's cache: 2-5 % of a 64x64 frame), and a thread
  // slowed by a busy core still leaves its tasks to the others.
  template <class F>
  void tasks(Index count, F&& f) {
    if (count <= 0) return;
    const int ranges = std::min(team.size(), Team::kRanges);
    for (int i = 0; i < ranges; ++i) {
      const int r = (t + i) % ranges;
      const Index begin = static_cast<Index>(static_cast<std::int64_t>(count) * r / ranges);
      const Index end = static_cast<Index>(static_cast<std::int64_t>(count) * (r + 1) / ranges);
      for (int k; (k = team.take(phase, r)) < end - begin;) f(begin + static_cast<Index>(k));
    }
    team.barrier();
    if (t == 0) team.reset(phase);
    ++phase;
  }
  // f on thread 0 only, then a barrier.
  template <class F>
  void single(F&& f) {
    if (t == 0) f();
    team.barrier();
  }
  // f(begin, end) on this thread's share of [0, n) (fixed ranges), then a barrier.
  template <class F>
  void split(Index n, F&& f) {
    const int threads = team.size();
    f(static_cast<Index>(static_cast<std::int64_t>(n) * t / threads),
      static_cast<Index>(static_cast<std::int64_t>(n) * (t + 1) / threads));
    team.barrier();
  }
};

// Runs `kernel(begin, end, independent)` over the colours of group g, in order, the team sharing
// ranges of `chunk` constraints of a colour (a serial colour on one thread); a barrier after each.
template <class Kernel>
void shared_colours(Share& share, const Colouring& colours, Index g, Index chunk, Kernel&& kernel) {
  for (Index k = colours.group_colours[g]; k < colours.group_colours[g + 1]; ++k) {
    const Index begin = colours.colour_offsets[k], end = colours.colour_offsets[k + 1];
    if (colours.serial(k))
      share.single([&] { kernel(begin, end, false); });
    else
      share.tasks((end - begin + chunk - 1) / chunk,
                  [&](Index r) { kernel(begin + r * chunk, std::min(end, begin + (r + 1) * chunk), true); });
  }
}

// One coloured sweep over distance, bending, volume and attachment constraints.
// start(g): called at the start of group g's task (a part's interior or an interface).
// relax: XPBD with averaged Jacobi (else null), see PbdStepper::set_relaxation.
template <Method M, bool Jacobi, class Start>
void sweep_coloured(Share& share, const Model& model, ColouredBatches& cb, bool approx, const Real* r, Real* o,
                    const Real* x, const Real* relax, Start&& start) {
  ColouredDistance& d = cb.distance;
  const auto distance = [&](Index begin, Index end, bool independent) {
    if constexpr (M == Method::Xpbd && Jacobi) {
      if (relax) {
        for (Index c = begin; c < end; ++c) distance_xpbd<true>(d, c, r, o, x, relax);
        return;
      }
    }
    if constexpr (M == Method::Xpbd) {
      if (independent) {
#pragma omp simd
        for (Index c = begin; c < end; ++c) distance_xpbd(d, c, r, o, x);
      } else {
        for (Index c = begin; c < end; ++c) distance_xpbd(d, c, r, o, x);
      }
    } else if (approx) {
      if (independent) {
#pragma omp simd
        for (Index c = begin; c < end; ++c) distance_pbd<true>(d, c, r, o);
      } else {
        for (Index c = begin; c < end; ++c) distance_pbd<true>(d, c, r, o);
      }
    } else {
      if (independent) {
#if defined(CSB_DISTANCE_AVX2)
        if (kernels_use_avx2())
          distance_pbd_blocks_avx2(d, begin, end, r, o);
        else
          distance_pbd_blocks<false>(d, begin, end, r, o);
#elif CSB_HAS_AVX2_ROWS && defined(__AVX2__)  // a native build for a processor with AVX2
        distance_pbd_blocks_avx2(d, begin, end, r, o);
#else
        distance_pbd_blocks<false>(d, begin, end, r, o);
#endif
      } else {
        for (Index c = begin; c < end; ++c) distance_pbd<false>(d, c, r, o);
      }
    }
  };
  ColouredFour& bend = cb.bending;
  const auto bending = [&](Index begin, Index end, bool independent) {
    if constexpr (M == Method::Xpbd && Jacobi) {
      if (relax) {
        for (Index c = begin; c < end; ++c) bending_xpbd_relaxed(bend, c, r, o, x, relax);
        return;
      }
    }
    project_bending_range<M == Method::Xpbd>(bend, begin, end, independent, r, o, x);
  };
  ColouredFour& vol = cb.volume;
  const auto volume = [&](Index begin, Index end, bool) {
    for (Index c = begin; c < end; ++c) volume_one<M, Jacobi>(vol, c, r, o, x, relax);
  };
  ColouredAttachments& att = cb.attachments;
  const auto attachment = [&](Index begin, Index end, bool) {
    for (Index c = begin; c < end; ++c) attachment_one<M, Jacobi>(att, c, r, o, x, relax);
  };
  const auto group = [&](Index g) {
    start(g);
    group_colours(cb.distance_colours, g, distance);
    group_colours(model.bending.colours, g, bending);
    group_colours(model.volume.colours, g, volume);
    group_colours(model.attachments.colours, g, attachment);
  };
  const Index parts = model.num_parts;
  // 1. The interiors.
  share.tasks(parts, group);
  // 2. The interfaces, in phases whose interfaces share no particle (usually one).
  for (const std::vector<Index>& phase : model.interface_phases)
    share.tasks(static_cast<Index>(phase.size()), [&](Index k) { group(parts + phase[k]); });
  // 3. The rest, colour by colour.
  const Index rest = 2 * parts - 1;
  shared_colours(share, cb.distance_colours, rest, kChunkDistance, distance);
  shared_colours(share, model.bending.colours, rest, kChunkFour, bending);
  shared_colours(share, model.volume.colours, rest, kChunkFour, volume);
  shared_colours(share, model.attachments.colours, rest, kChunkAttachment, attachment);
}

// Cores free for the team: `decided` sets the thread count, `now` (<= decided) whether its
// threads may spin while they wait.
struct FreeCores {
  int decided, now;
};

#if defined(__linux__)
// Cores not busy with other runnable tasks: /proc/loadavg's fourth field is "runnable/total"
// scheduling entities now, the caller's thread included. Reading it costs ~10 µs on a virtual
// machine, a few per cent of a small cloth's step: a step within 5 ms of the last reading (of
// any stepper in the process) takes that reading again.
// A reading is one instant: one that lands on a task runnable for a few microseconds would
// halve a small cloth's speed for the next 5 ms (a 32x32 cloth stepped on one thread in 6-29 %
// of its frames on an idle machine, in runs of ~10 frames, one reading each). So fewer free
// cores count only once a second reading 1.3 ms later (not a multiple of the 5 ms, so a task
// with a period near it is not seen twice) agrees; until then the team keeps its threads but
// waits by sleeping, not spinning. More free cores count at once.
FreeCores free_cores(int cores) {
  static std::atomic<std::int64_t> read_at{std::numeric_limits<std::int64_t>::min() / 2};  // ns
  static std::atomic<std::int64_t> valid_for{5'000'000};  // ns
  static std::atomic<int> decided{1}, seen{1};
  const std::int64_t now =
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
          .count();
  if (now - read_at.load(std::memory_order_relaxed) < valid_for.load(std::memory_order_relaxed)) {
    const int d = std::min(cores, decided.load(std::memory_order_relaxed));
    return {d, std::min(d, seen.load(std::memory_order_relaxed))};
  }
  std::FILE* f = std::fopen("/proc/loadavg", "r");
  if (!f) return {cores, cores};
  double l1, l5, l15;
  int running = 1, total = 0;
  const int got = std::fscanf(f, "%lf %lf %lf %d/%d", &l1, &l5, &l15, &running, &total);
  std::fclose(f);
  if (got != 5) return {cores, cores};
  running -= Team::idle_spinning();  // csb's own threads about to sleep
  const int free = std::max(1, std::min(cores, cores - (running - 1)));
  const int before = seen.exchange(free, std::memory_order_relaxed);
  int d = decided.load(std::memory_order_relaxed);
  if (free >= d || before <= free) {  // more free cores, or confirmed by the reading before
    d = free;
    decided.store(d, std::memory_order_relaxed);
    valid_for.store(5'000'000, std::memory_order_relaxed);
  } else {
    valid_for.store(1'300'000, std::memory_order_relaxed);  // confirm soon
  }
  read_at.store(now, std::memory_order_relaxed);
  d = std::min(cores, d);
  return {d, std::min(d, free)};
}
#else
FreeCores free_cores(int cores) { return {cores, cores}; }
#endif

template <class T>
std::size_t capacity_bytes(const std::vector<T>& v) {
  return v.capacity() * sizeof(T);
}

}  // namespace

std::size_t ColouredBatches::bytes() const {
  const auto& d = distance;
  std::size_t s = capacity_bytes(kinematic) + capacity_bytes(count) + capacity_bytes(d.i) + capacity_bytes(d.j) +
                  capacity_bytes(d.rest) + capacity_bytes(d.sense) + capacity_bytes(d.ci) + capacity_bytes(d.cj) +
                  capacity_bytes(d.alpha) + capacity_bytes(d.gamma) + capacity_bytes(d.inv_den) +
                  capacity_bytes(d.lambda) + capacity_bytes(part_run_offsets) + capacity_bytes(part_runs);
  for (const ColouredFour* f : {&bending, &volume})
    s += capacity_bytes(f->q) + capacity_bytes(f->rest) + capacity_bytes(f->w) + capacity_bytes(f->k) +
         capacity_bytes(f->alpha) + capacity_bytes(f->gamma) + capacity_bytes(f->lambda) +
         capacity_bytes(f->pair_rest) + capacity_bytes(f->pair_ca) + capacity_bytes(f->pair_cb);
  const Colouring& dc = distance_colours;
  s += capacity_bytes(dc.order) + capacity_bytes(dc.colour_offsets) + capacity_bytes(dc.serial_colours) +
       capacity_bytes(dc.group_colours);
  const auto& a = attachments;
  s += capacity_bytes(a.i) + capacity_bytes(a.target) + capacity_bytes(a.w) + capacity_bytes(a.k) +
       capacity_bytes(a.alpha) + capacity_bytes(a.gamma) + capacity_bytes(a.lambda);
  return s;
}

void PbdStepper::build_coloured(const Model& model, const Real* w) {
  ColouredBatches& cb = coloured_;
  const bool xpbd = settings_.method == Method::Xpbd;
  const auto fill = [xpbd](std::vector<Real>& out, const std::vector<Real>& from, const std::vector<Index>& order) {
    out.clear();
    if (!xpbd) return;
    out.resize(order.size());
    for (std::size_t c = 0; c < order.size(); ++c) out[c] = from[order[c]];
  };
  // PBD and Jakobsen Gauss-Seidel (exact square root): each bending element (a, b, c, d) takes the
  // distance constraint on its edge (a, b), when there is one (bilateral, not yet taken by
  // another element; elements in colour order): one kernel projects it and then the bending
  // constraint, four particles moved in and out once instead of six. (Another Gauss-Seidel
  // order: within a bending colour, its elements' edges, then its bending constraints.)
  const DistanceBatch& db = model.distance;
  const BendingBatch& bb = model.bending;
  // PBD's shares of distance constraint o's correction for its particles i and j: k w / Σw.
  const auto pbd_shares = [&](Index o) -> std::array<Real, 2> {
    const Index i = db.particles[o][0], j = db.particles[o][1];
    const Real wsum = w[i] + w[j];
    return {wsum > 0 ? k_distance_[o] * w[i] / wsum : 0, wsum > 0 ? k_distance_[o] * w[j] / wsum : 0};
  };
  const bool pairs = !xpbd && settings_.solver == Solver::GaussSeidel && !settings_.sqrt_approximation &&
                     bb.size() > 0 && db.size() > 0;
  // pair_of[c]: the distance constraint (model index) of the element at bending colour position c, or -1
  std::vector<Index> pair_of(pairs ? static_cast<std::size_t>(bb.size()) : 0, -1);
  std::vector<std::uint8_t> paired(pairs ? static_cast<std::size_t>(db.size()) : 0, 0);
  if (pairs) {
    std::unordered_map<std::uint64_t, Index> edges;
    edges.reserve(static_cast<std::size_t>(db.size()));
    const auto key = [](Index i, Index j) {
      return (static_cast<std::uint64_t>(std::min(i, j)) << 32) | static_cast<std::uint32_t>(std::max(i, j));
    };
    for (Index o = 0; o < db.size(); ++o)
      if (db.sense[o] == 0) edges.emplace(key(db.particles[o][0], db.particles[o][1]), o);
    const auto& order = bb.colours.order;
    for (std::size_t c = 0; c < order.size(); ++c) {
      const auto& q = bb.particles[order[c]];
      const auto it = edges.find(key(q[0], q[1]));
      if (it == edges.end() || paired[it->second]) continue;
      paired[it->second] = 1;
      pair_of[c] = it->second;
    }
  }
  cb.distance_colours = db.colours;
  if (pairs) {  // the model's colouring less the paired constraints
    Colouring& dc = cb.distance_colours;
    std::vector<Index> order;
    std::vector<Index> offsets{0};
    for (Index k = 0; k < dc.num_colours(); ++k) {
      for (Index c = dc.colour_offsets[k]; c < dc.colour_offsets[k + 1]; ++c)
        if (!paired[dc.order[c]]) order.push_back(dc.order[c]);
      offsets.push_back(static_cast<Index>(order.size()));
    }
    dc.order = std::move(order);
    dc.colour_offsets = std::move(offsets);
  }
  {
    const DistanceBatch& b = model.distance;
    const auto& order = cb.distance_colours.order;
    ColouredDistance& d = cb.distance;
    const std::size_t m = order.size();
    d.i.resize(m);
    d.j.resize(m);
    d.rest.resize(m);
    d.sense.resize(m);
    d.ci.resize(m);
    d.cj.resize(m);
    d.inv_den.assign(xpbd ? m : 0, 0);
    fill(d.alpha, a_distance_, order);
    fill(d.gamma, g_distance_, order);
    d.lambda.assign(xpbd ? m : 0, 0);
    for (std::size_t c = 0; c < m; ++c) {
      const Index o = order[c], i = b.particles[o][0], j = b.particles[o][1];
      const Real wsum = w[i] + w[j];
      d.i[c] = i;
      d.j[c] = j;
      d.rest[c] = b.rest_length[o];
      d.sense[c] = b.sense[o];
      if (xpbd) {
        d.ci[c] = w[i];
        d.cj[c] = w[j];
        d.inv_den[c] = wsum > 0 ? 1 / ((1 + d.gamma[c]) * wsum + d.alpha[c]) : 0;
      } else {
        const auto [ci, cj] = pbd_shares(o);
        d.ci[c] = ci;
        d.cj[c] = cj;
      }
    }
  }
  const auto four = [&](ColouredFour& f, const std::vector<std::array<Index, 4>>& particles, const std::vector<Real>& rest,
                        const Colouring& colours, const std::vector<Real>& k, const std::vector<Real>& a,
                        const std::vector<Real>& g) {
    const auto& order = colours.order;
    const std::size_t m = order.size();
    f.q.resize(m);
    f.rest.resize(m);
    f.w.resize(m);
    f.k.resize(xpbd ? 0 : m);
    fill(f.alpha, a, order);
    fill(f.gamma, g, order);
    f.lambda.assign(xpbd ? m : 0, 0);
    for (std::size_t c = 0; c < m; ++c) {
      const Index o = order[c];
      f.q[c] = particles[o];
      f.rest[c] = rest[o];
      for (int s = 0; s < 4; ++s) f.w[c][s] = w[particles[o][s]];
      if (!xpbd) f.k[c] = k[o];
    }
  };
  four(cb.bending, model.bending.particles, model.bending.rest_angle, model.bending.colours, k_bending_, a_bending_,
       g_bending_);
  {
    ColouredFour& f = cb.bending;
    const std::size_t m = pair_of.size();
    f.pair_rest.assign(m, 0);
    f.pair_ca.assign(m, 0);
    f.pair_cb.assign(m, 0);
    for (std::size_t c = 0; c < m; ++c) {
      const Index o = pair_of[c];
      if (o < 0) continue;
      const auto [ci, cj] = pbd_shares(o);
      // the kernel takes d = a - b: Δa = -ca s d, Δb = +cb s d (the constraint's own
      // orientation, d = p_i - p_j, gives the same values)
      const bool forward = db.particles[o][0] == f.q[c][0];
      f.pair_rest[c] = db.rest_length[o];
      f.pair_ca[c] = forward ? ci : cj;
      f.pair_cb[c] = forward ? cj : ci;
    }
  }
  four(cb.volume, model.volume.particles, model.volume.rest_volume, model.volume.colours, k_volume_, a_volume_, g_volume_);
  {
    const AttachmentBatch& b = model.attachments;
    const auto& order = b.colours.order;
    ColouredAttachments& a = cb.attachments;
    const std::size_t m = order.size();
    a.i.resize(m);
    a.target.resize(m);
    a.w.resize(m);
    a.k.resize(xpbd ? 0 : m);
    fill(a.alpha, a_attachment_, order);
    fill(a.gamma, g_attachment_, order);
    a.lambda.assign(xpbd ? m : 0, 0);
    for (std::size_t c = 0; c < m; ++c) {
      const Index o = order[c];
      a.i[c] = b.particle[o];
      for (int e = 0; e < 3; ++e) a.target[c][e] = b.target(e, o);
      a.w[c] = w[b.particle[o]];
      if (!xpbd) a.k[c] = k_attachment_[o];
    }
  }
  // Jacobi: how many projections reach each particle in one sweep (the averaging's divisor);
  // contacts add theirs as they are projected.
  cb.count.clear();
  if (settings_.solver != Solver::GaussSeidel) jacobi_counts(model, cb.count);
  if (xpbd) {
    coloured_order_.distance = cb.distance_colours.order;
    coloured_order_.bending = model.bending.colours.order;
    coloured_order_.volume = model.volume.colours.order;
    coloured_order_.attachment = model.attachments.colours.order;
  }
  // The parts' particles as runs (a fused step's part tasks update and predict them).
  const Index parts = model.num_parts, n = model.num_particles();
  std::vector<std::vector<std::array<Index, 2>>> runs(static_cast<std::size_t>(parts));
  for (Index i = 0; i < n; ++i) {
    auto& r = runs[static_cast<std::size_t>(model.part[i])];
    if (!r.empty() && r.back()[1] == i)
      r.back()[1] = i + 1;
    else
      r.push_back({i, i + 1});
  }
  cb.part_run_offsets.assign(1, 0);
  cb.part_runs.clear();
  for (const auto& r : runs) {
    cb.part_runs.insert(cb.part_runs.end(), r.begin(), r.end());
    cb.part_run_offsets.push_back(static_cast<Index>(cb.part_runs.size()));
  }
  const Index rest = 2 * parts - 1;
  cb.rest_empty = true;
  const Colouring* const batches[] = {&cb.distance_colours, &model.bending.colours, &model.volume.colours,
                                      &model.attachments.colours};
  for (const Colouring* c : batches)
    cb.rest_empty = cb.rest_empty && (c->num_groups() <= rest || c->colour_offsets[c->group_colours[rest + 1]] ==
                                                                      c->colour_offsets[c->group_colours[rest]]);
  cb.model_id = model.id;
}

int PbdStepper::resolve_threads(const Model& model) {
  spin_ = false;
  if (settings_.ordering == Ordering::Sequential) return 1;
  if (settings_.threads == 1 || (settings_.threads == 0 && model.num_parts == 1))
    return 1;  // (automatic: a model of one part has one task per phase)
  // hardware_concurrency reads /sys on every call (glibc): once per process is enough.
  static const int cores = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  const FreeCores free = free_cores(cores);
  const int threads =
      settings_.threads > 0 ? settings_.threads : std::min<int>(free.decided, static_cast<int>(model.num_parts));
  // Waiting threads may spin when every one has a core to itself (csb/team.hpp). CSB_WAIT=spin
  // or sleep fixes the choice (for measurements, papers/benchmarks.md).
  static const std::string wait = [] {
    const char* v = std::getenv("CSB_WAIT");
    return std::string(v ? v : "");
  }();
  spin_ = wait == "spin" || (wait != "sleep" && threads <= free.now);
  return threads;
}

const Multipliers& PbdStepper::multipliers() const {
  if (lambda_stale_) {
    // The coloured batches keep their multipliers in colour order; put them in the model's.
    const auto scatter = [](std::vector<Real>& out, const std::vector<Real>& in, const std::vector<Index>& order) {
      out.resize(in.size());
      for (std::size_t c = 0; c < in.size(); ++c) out[order[c]] = in[c];
    };
    scatter(lambda_.distance, coloured_.distance.lambda, coloured_order_.distance);
    scatter(lambda_.bending, coloured_.bending.lambda, coloured_order_.bending);
    scatter(lambda_.volume, coloured_.volume.lambda, coloured_order_.volume);
    scatter(lambda_.attachment, coloured_.attachments.lambda, coloured_order_.attachment);
    lambda_stale_ = false;
  }
  return lambda_;
}

template <Method M, bool Jacobi>
void PbdStepper::project_coloured(const Model& model, const Positions& x_start, Fused* fused) {
  const Index n = model.num_particles();
  const int threads = threads_used_;
  Real* p = p_.data();
  Real* ps = Jacobi ? p_start_.data() : nullptr;
  Real* delta = Jacobi ? delta_.data() : nullptr;
  Real* count = Jacobi ? count_.data() : nullptr;
  const Real* count0 = Jacobi ? coloured_.count.data() : nullptr;
  const Real* r = Jacobi ? ps : p;
  Real* o = Jacobi ? delta : p;
  const Real* x = x_start.data();
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  const bool contacts = !contacts_.empty() || !self_contacts_.empty();
  const bool tail = model.balloons.size() > 0 || contacts;
  bool compliant_grabs = false;
  for (const Grab& g : grabs_) compliant_grabs = compliant_grabs || g.compliance > 0;
  set_relaxation(model);
  const Real* relax = relax_.empty() ? nullptr : relax_.data();
  const bool average = settings_.solver == Solver::Jacobi && !relax;
  const bool approx = settings_.sqrt_approximation;
  const auto& bal = model.balloons;
  const int iterations = settings_.iterations;
  bad_.assign(static_cast<std::size_t>(std::max(threads, 1)), -1);
  // A fused step of several sub-steps whose constraints all lie in parts and interfaces (no rest
  // group, no serial tail, Gauss-Seidel): part g's task of a sub-step's first sweep first
  // updates its particles from the last sub-step and predicts them (the last sub-step's
  // interfaces, the only other constraints on them, are done: a barrier ends their phase), and
  // each group's task sets its XPBD multipliers to zero; the finiteness check runs once, after
  // the last sub-step, the step's start kept to go back to. Two barriers a sub-step instead of
  // four (a cloth).
  const bool in_tasks = fused && fused->substeps > 1 && !Jacobi && !tail && !compliant_grabs && coloured_.rest_empty;
  const bool advancing = fused && fused->substeps > 1;  // a sub-step's update is followed by a prediction
  if (in_tasks) {
    x_step_.resize(3, n);
    v_step_.resize(3, n);
  }
  if (advancing) accel_.resize(3 * static_cast<std::size_t>(n));
  const Index parts = model.num_parts;
  // XPBD: group g's multipliers (of every batch) set to zero.
  const auto zero_group_multipliers = [&](Index g) {
    const auto zero = [g](const Colouring& c, std::vector<Real>& lambda) {
      if (static_cast<std::size_t>(g) + 1 >= c.group_colours.size()) return;
      std::fill(lambda.begin() + c.colour_offsets[c.group_colours[g]],
                lambda.begin() + c.colour_offsets[c.group_colours[g + 1]], 0.0);
    };
    zero(coloured_.distance_colours, coloured_.distance.lambda);
    zero(model.bending.colours, coloured_.bending.lambda);
    zero(model.volume.colours, coloured_.volume.lambda);
    zero(model.attachments.colours, coloured_.attachments.lambda);
  };
  team_.get().run(threads, spin_, [&](int t) {
    Share share{team_.get(), t};
    // (5)-(7) of Algorithm 1, and XPBD's multipliers set to zero.
    const auto predict = [&](Index begin, Index end) {
      predict_range(model, *fused->state, fused->h, begin, end);
      if constexpr (M == Method::Xpbd) zero_coloured_multipliers(t, share.team.size());
    };
    if (in_tasks) {
      // Keep the step's start, then predict (the multipliers are zeroed by the group tasks).
      const Real* v = settings_.front_end == FrontEnd::Verlet ? x_prev_.data() : fused->state->v.data();
      share.split(n, [&](Index begin, Index end) {
        const Real* x0 = fused->state->x.data();
        std::memcpy(x_step_.data() + 3 * begin, x0 + 3 * begin, sizeof(Real) * 3 * (end - begin));
        std::memcpy(v_step_.data() + 3 * begin, v + 3 * begin, sizeof(Real) * 3 * (end - begin));
        predict_range(model, *fused->state, fused->h, begin, end);
        set_accel(model, fused->h, begin, end);
      });
    } else if (fused) {
      share.split(n, [&](Index begin, Index end) {
        predict(begin, end);
        if (advancing) set_accel(model, fused->h, begin, end);
      });
    }
    for (int sub = 0; sub < (fused ? fused->substeps : 1); ++sub) {
      for (int it = 0; it < iterations; ++it) {
        // What a group's task does before its constraints (in_tasks only).
        const bool update = in_tasks && it == 0 && sub > 0;
        const auto start = [&](Index g) {
          if (!in_tasks) return;
          if constexpr (M == Method::Xpbd)
            if (it == 0) zero_group_multipliers(g);
          if (update && g < parts) {
            for (Index k = coloured_.part_run_offsets[g]; k < coloured_.part_run_offsets[g + 1]; ++k) {
              const auto [begin, end] = coloured_.part_runs[k];
              advance(*fused->state, fused->h, begin, end);
            }
          }
        };
        if constexpr (Jacobi) {
          share.split(n, [&](Index begin, Index end) {
            for (Index i = begin; i < end; ++i) {
              for (int e = 0; e < 3; ++e) {
                ps[3 * i + e] = p[3 * i + e];
                delta[3 * i + e] = 0;
              }
              count[i] = count0[i];
            }
          });
        }
        sweep_coloured<M, Jacobi>(share, model, coloured_, approx, r, o, x, relax, start);
        if (tail) {
          share.single([&] {
            // Balloons: one constraint over many particles each, serial (see sweep_batches).
            for (Index c = 0; c < bal.size(); ++c) {
              const Index* ids = bal.particles.data() + bal.particle_offsets[c];
              const Triangle* tris = bal.triangles.data() + bal.triangle_offsets[c];
              const Real target = bal.pressure[c] * bal.rest_volume[c];
              if constexpr (M == Method::Xpbd)
                project_balloon(r, o, nullptr, w, ids, bal.num_particles(c), tris, bal.num_triangles(c), target, 0,
                                x, a_balloon_[c], g_balloon_[c], &lambda_.balloon[c], balloon_grad_.data(),
                                relaxation(relax, ids, bal.num_particles(c)));
              else
                project_balloon(r, o, nullptr, w, ids, bal.num_particles(c), tris, bal.num_triangles(c), target,
                                k_balloon_[c], nullptr, 0, 0, nullptr, balloon_grad_.data());
            }
            if (contacts) project_contacts(model, Jacobi);
          });
        }
        if constexpr (Jacobi) {
          // Averaged Jacobi moves each particle by the mean of its corrections (XPBD: by the sum
          // of its relaxed ones), summed Jacobi by their sum.
          share.split(n, [&](Index begin, Index end) {
            for (Index i = begin; i < end; ++i) {
              const Real scale = average ? (count[i] > 0 ? 1 / count[i] : 0) : 1;
              for (int e = 0; e < 3; ++e) p[3 * i + e] = ps[3 * i + e] + scale * delta[3 * i + e];
            }
          });
          if (contacts && M != Method::Xpbd) share.single([&] { settle_contact_moves(average); });
        }
        if (compliant_grabs) share.single([&] { project_grabs(x_start); });
      }
      if (fused) {
        const bool last = sub + 1 == fused->substeps;
        if (in_tasks && !last) continue;  // updated and predicted by the part tasks
        // The new positions must all be finite before any is taken (else the state stays).
        share.split(n, [&](Index begin, Index end) { bad_[t] = first_non_finite(p_, begin, end); });
        Index bad = -1;
        for (const Index b : bad_)
          if (b >= 0) bad = bad < 0 ? b : std::min(bad, b);
        if (bad >= 0) {
          if (t == 0) fused->bad = bad, fused->bad_sub = in_tasks ? -1 : sub;
          return;
        }
        // (12)-(15) of Algorithm 1, then the next sub-step's prediction of the same particles.
        const bool next = sub + 1 < fused->substeps;
        share.split(n, [&](Index begin, Index end) {
          if (!next) {
            commit(*fused->state, fused->h, begin, end);
            return;
          }
          advance(*fused->state, fused->h, begin, end);
          if constexpr (M == Method::Xpbd) zero_coloured_multipliers(t, share.team.size());
        });
      }
    }
  });
}

void PbdStepper::project(const Model& model, const Positions& x_start, Fused* fused) {
  if (settings_.ordering == Ordering::Sequential) {
    project_sequential(model, x_start);
    return;
  }
  const bool jacobi = settings_.solver != Solver::GaussSeidel;
  switch (settings_.method) {
    case Method::Pbd:
      jacobi ? project_coloured<Method::Pbd, true>(model, x_start, fused)
             : project_coloured<Method::Pbd, false>(model, x_start, fused);
      break;
    case Method::Xpbd:
      jacobi ? project_coloured<Method::Xpbd, true>(model, x_start, fused)
             : project_coloured<Method::Xpbd, false>(model, x_start, fused);
      break;
    case Method::Jakobsen:
      jacobi ? project_coloured<Method::Jakobsen, true>(model, x_start, fused)
             : project_coloured<Method::Jakobsen, false>(model, x_start, fused);
      break;
  }
}

std::size_t PbdStepper::workspace_bytes() const {
  const auto positions = [](const Positions& q) { return sizeof(Real) * static_cast<std::size_t>(q.size()); };
  std::size_t s = positions(p_) + positions(x_prev_) + positions(x_step_) + positions(v_step_) + positions(p_start_) +
                  positions(delta_) + capacity_bytes(accel_) +
                  capacity_bytes(count_) + capacity_bytes(w_) + capacity_bytes(balloon_grad_);
  for (const auto* v : {&k_distance_, &k_bending_, &k_attachment_, &a_distance_, &a_bending_, &a_attachment_,
                        &g_distance_, &g_bending_, &g_attachment_, &k_volume_, &a_volume_, &g_volume_, &k_balloon_,
                        &a_balloon_, &g_balloon_})
    s += capacity_bytes(*v);
  for (const auto* v : {&lambda_.distance, &lambda_.bending, &lambda_.attachment, &lambda_.volume, &lambda_.balloon})
    s += capacity_bytes(*v);
  s += capacity_bytes(coloured_order_.distance) + capacity_bytes(coloured_order_.bending) +
       capacity_bytes(coloured_order_.volume) + capacity_bytes(coloured_order_.attachment);
  return s + coloured_.bytes();
}

// ---------------------------------------------------------------------------------- interaction

int PbdStepper::grab(const Model& model, const State& state, Index particle, const Vec3& target, Real compliance) {
  const UseGuard::Scope in_use(use_, "PbdStepper.grab");
  if (particle < 0 || particle >= model.num_particles())
    throw InvalidArgument("grab: particle " + std::to_string(particle) + " is out of range (the model has " +
                          std::to_string(model.num_particles()) + " particles)");
  if (state.x.cols() != model.num_particles()) throw InvalidArgument("grab: the state does not belong to the model");
  if (!target.allFinite()) throw InvalidArgument("grab: target must be finite, got " + str(target));
  if (!(compliance >= 0) || !std::isfinite(compliance))
    throw InvalidArgument("grab: compliance must be a finite value >= 0 m/N, got " + str(compliance));
  for (const Grab& g : grabs_)
    if (g.particle == particle)
      throw InvalidArgument("grab: particle " + std::to_string(particle) + " is already held (handle " +
                            std::to_string(g.handle) + ")");
  Grab g;
  g.handle = next_grab_++;
  g.particle = particle;
  g.target = target;
  g.from = state.x.col(particle);
  g.compliance = compliance;
  g.pinned = model.inv_mass[particle] == 0;
  grabs_.push_back(g);
  return g.handle;
}

Grab& PbdStepper::find_grab(int handle) {
  for (Grab& g : grabs_)
    if (g.handle == handle) return g;
  throw InvalidArgument("no grab with handle " + std::to_string(handle) + " (released already?)");
}

void PbdStepper::move_grab(int handle, const Vec3& target) {
  const UseGuard::Scope in_use(use_, "PbdStepper.move_grab");
  if (!target.allFinite()) throw InvalidArgument("move_grab: target must be finite, got " + str(target));
  find_grab(handle).target = target;
}

void PbdStepper::release(int handle) {
  const UseGuard::Scope in_use(use_, "PbdStepper.release");
  const Grab& g = find_grab(handle);
  if (g.pinned) stop_.push_back(g.particle);
  grabs_.erase(grabs_.begin() + (&g - grabs_.data()));
}

// The hand's position `fraction` of the way through this step: kinematic grabs are put there,
// compliant ones pull towards it.
void PbdStepper::apply_grab_targets(Real fraction) {
  grab_fraction_ = fraction;
  for (const Grab& g : grabs_)
    if (g.compliance == 0) p_.col(g.particle) = fraction >= 1 ? g.target : Vec3(g.from + fraction * (g.target - g.from));
  std::fill(grab_lambda_.begin(), grab_lambda_.end(), 0.0);
}

// Compliant grabs: XPBD attachments to the hand (Macklin 2016 Eq. 18), after each sweep.
void PbdStepper::project_grabs(const Positions& x_start) {
  const Real h = substep_size();
  for (std::size_t k = 0; k < grabs_.size(); ++k) {
    const Grab& g = grabs_[k];
    if (g.compliance == 0) continue;
    const Index i = g.particle;
    const Vec3 target = g.from + grab_fraction_ * (g.target - g.from);
    project_attachment_xpbd(p_.col(i).data(), x_start.col(i).data(), w_[i], target.data(),
                            g.compliance / (h * h), 0, grab_lambda_[k]);
  }
}

// ------------------------------------------------------------------------------------ collisions

// Algorithm 1 line (8): the collision constraints of this sub-step, from the positions x at its
// start and the prediction p (see collision.hpp for the rule). Particles that cannot move get none.
void PbdStepper::generate_contacts(const Model& model, const Positions& x, Real h) {
  contacts_.clear();
  contact_summary_ = {};
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();  // a held particle follows the hand
  if (!model.colliders.empty()) {
    // Speculative margin per group: the farthest any of its particles moves in the prediction,
    // about as far as the group's constraints can drag a neighbour during the iterations.
    margin_.assign(model.num_groups(), 0);
    for (Index i = 0; i < model.num_particles(); ++i)
      if (w[i] > 0) margin_[model.group[i]] = std::max(margin_[model.group[i]], (p_.col(i) - x.col(i)).norm());
    for (Index i = 0; i < model.num_particles(); ++i) {
      if (w[i] <= 0) continue;
      const Vec3 xi = x.col(i), pi = p_.col(i);
      for (Index c = 0; c < static_cast<Index>(model.colliders.size()); ++c)
        generate_contact(model.colliders[c], c, i, xi, pi, model.thickness[i], margin_[model.group[i]], h, contacts_,
                         stamps_, stamp_);
    }
  }
  for (const Contact& k : contacts_)
    contact_summary_.max_depth =
        std::max(contact_summary_.max_depth, k.thickness - (p_.col(k.particle) - k.point).dot(k.normal));
  contact_summary_.count = static_cast<Index>(contacts_.size());
  if (!self_groups_.empty()) generate_self_contacts(model, x);
}

// Müller 2007 §4.4: for each particle q of a self-colliding group and each triangle (p1, p2, p3)
// of the group without q, C = (q - p1)·n - h >= 0 with n the triangle's unit normal, on the side
// q was on at the start of the sub-step, so that a cloth folding onto itself cannot pass through
// between two sub-steps. Broad phase: the triangles' swept boxes (start and prediction, widened
// by h) in a spatial hash, rebuilt every sub-step, queried with each particle's swept box.
// Narrow phase: a contact when, at the prediction, q is less than 2h from the triangle's plane on
// its side (or beyond it) and within h of the triangle sideways.
//
// Two rules keep the contacts from adding energy. The projection moves q by a distance d in one
// sub-step, and the velocity update (12) turns that into a speed d/Δt (Δt = 1/1800 s in
// cloth_sphere: 1 cm is 18 m/s), so a contact may only take away approach, never push apart:
// - q that starts the sub-step closer than h to the triangle (at a distance d0 in [0, h): it slid
//   in sideways, typically around a sharp crease, or the last sub-step's single Gauss-Seidel pass
//   left it there) is held at d0, C = s (q - p1)·n - d0, not pushed out to h; the same rule as a
//   collider's static fallback (started_inside), which keeps q from leaving faster than it came.
// - a triangle whose normal turns by more than 90° within the sub-step is a sliver passing
//   through degeneracy (no real triangle turns over in 0.5 ms), its normal is meaningless and the
//   side carried over would push q through it by up to 2h plus the depth: no contact.
void PbdStepper::generate_self_contacts(const Model& model, const Positions& x) {
  self_contacts_.clear();
  const Real* w = model.inv_mass.data();
  for (const SelfGroup& g : self_groups_) {
    const Real hs = g.thickness;
    const std::size_t T = g.triangles.size();
    box_lo_.resize(T);
    box_hi_.resize(T);
    for (std::size_t t = 0; t < T; ++t) {
      const Triangle& tri = model.triangles[g.triangles[t]];
      Vec3 lo = x.col(tri[0]).cwiseMin(p_.col(tri[0])), hi = x.col(tri[0]).cwiseMax(p_.col(tri[0]));
      for (int e = 1; e < 3; ++e) {
        lo = lo.cwiseMin(x.col(tri[e])).cwiseMin(p_.col(tri[e]));
        hi = hi.cwiseMax(x.col(tri[e])).cwiseMax(p_.col(tri[e]));
      }
      box_lo_[t] = lo.array() - hs;
      box_hi_[t] = hi.array() + hs;
    }
    hash_.build(g.cell, box_lo_, box_hi_);
    for (Index o = model.group_offsets[g.group]; o < model.group_offsets[g.group + 1]; ++o) {
      const Index q = model.group_particles[o];
      const Vec3 xq = x.col(q), pq = p_.col(q);
      const Vec3 lo = xq.cwiseMin(pq), hi = xq.cwiseMax(pq);
      if (++stamp_ == 0) std::fill(stamps_.begin(), stamps_.end(), 0), stamp_ = 1;
      hash_.query(lo, hi, [&](Index t) {
        if (stamps_[t] == stamp_) return;
        stamps_[t] = stamp_;
        const Triangle& tri = model.triangles[g.triangles[t]];
        if (tri[0] == q || tri[1] == q || tri[2] == q) return;
        if ((lo.array() > box_hi_[t].array()).any() || (hi.array() < box_lo_[t].array()).any()) return;
        if (w[q] + w[tri[0]] + w[tri[1]] + w[tri[2]] <= 0) return;
        const Vec3 x1 = x.col(tri[0]);
        Vec3 n0 = (x.col(tri[1]) - x1).cross(x.col(tri[2]) - x1);
        const Vec3 p1 = p_.col(tri[0]);
        Vec3 np = (p_.col(tri[1]) - p1).cross(p_.col(tri[2]) - p1);
        const Real l0 = n0.norm(), lp = np.norm();
        if (!(l0 > 0) || !(lp > 0)) return;  // a collapsed triangle has no side
        n0 /= l0;
        np /= lp;
        if (!(n0.dot(np) > 0)) return;  // the triangle flipped: a sliver, no side
        const Real d0 = (xq - x1).dot(n0);
        const Real side = d0 >= 0 ? 1 : -1;
        if (side * (pq - p1).dot(np) >= 2 * hs) return;
        Vec3 b;
        const Vec3 c = closest_point_on_triangle(pq, p1, p_.col(tri[1]), p_.col(tri[2]), &b);
        const Vec3 off = pq - c;
        if ((off - off.dot(np) * np).norm() > hs) return;
        self_contacts_.push_back({q, tri, b, side, std::min(hs, side * d0)});
      });
    }
  }
  contact_summary_.self_count = static_cast<Index>(self_contacts_.size());
}

// The contacts' projections in one sweep, after the other constraints so that non-penetration
// has the last word in Gauss-Seidel: self-contacts, then collider contacts. Each is hard
// (stiffness 1, Müller 2007 §4.3; XPBD with α = 0).
//
// Self-contact (Müller 2007 §4.4): C = s (q - p1)·n - d, n the unit normal of the current
// triangle; its gradient is taken with n fixed and the correction shared by the barycentric
// weights b of q's nearest point (the distribution of Bridson, Fedkiw, Anderson 2002, §7.1):
//   ∇_q C = s n,  ∇_pi C = -b_i s n,  Δ = -C / (w_q + Σ b_i² w_i).
// Collider contact: C = (p - q)·n - r, ∇C = n, Δp = -C n (PBD, Jakobsen); XPBD tracks the
// multiplier, Δλ = -C/w, clamped to λ >= 0 (a contact only pushes), Δp = w Δλ n.
void PbdStepper::project_contacts(const Model& model, bool jacobi) {
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  const Real* from = jacobi ? p_start_.data() : p_.data();
  const Real* relax = relax_.empty() ? nullptr : relax_.data();  // XPBD, averaged Jacobi
  const auto apply = [&](Index i, const Vec3& dp) {
    if (jacobi) {
      delta_.col(i) += dp;
      count_[i] += 1;
    } else {
      p_.col(i) += dp;
    }
  };
  for (const SelfContact& k : self_contacts_) {
    const Index q = k.particle;
    const auto& t = k.triangle;
    const Eigen::Map<const Vec3> xq(from + 3 * q), a(from + 3 * t[0]), b(from + 3 * t[1]), c(from + 3 * t[2]);
    Vec3 n = (b - a).cross(c - a);
    const Real len = n.norm();
    if (!(len > 0)) continue;
    n *= k.side / len;
    const Real C = (xq - a).dot(n) - k.thickness;
    if (C >= 0) continue;
    const Vec3& bc = k.barycentric;
    const Real denom = w[q] + bc[0] * bc[0] * w[t[0]] + bc[1] * bc[1] * w[t[1]] + bc[2] * bc[2] * w[t[2]];
    if (!(denom > 0)) continue;
    const Vec3 step = (-C * relaxation(relax, std::array<Index, 4>{q, t[0], t[1], t[2]}) / denom) * n;
    apply(q, w[q] * step);
    for (int e = 0; e < 3; ++e) apply(t[e], -(w[t[e]] * bc[e]) * step);
  }
  const bool xpbd = settings_.method == Method::Xpbd;
  for (Contact& k : contacts_) {
    const Index i = k.particle;
    const Real C = (Eigen::Map<const Vec3>(from + 3 * i) - k.point).dot(k.normal) - k.thickness;
    Real move;  // along n, m
    if (xpbd) {
      const Real next = std::max(k.lambda - C / w[i], Real(0));
      const Real dl = relax ? relax[i] * (next - k.lambda) : next - k.lambda;
      move = w[i] * dl;
      k.lambda = relax ? k.lambda + dl : next;
      k.normal_correction = w[i] * k.lambda;
    } else {
      if (C >= 0) continue;
      move = -C;
      // Jacobi: the push counts once the sweep's corrections are combined (settle_contact_moves).
      if (jacobi)
        k.sweep_move = move;
      else
        k.normal_correction += move;
    }
    if (move != 0) apply(i, move * k.normal);
  }
}

// PBD and Jakobsen with Jacobi: a contact's push counts towards its normal correction (which
// bounds friction) as the particle received it: averaged Jacobi moves a particle by the mean of
// its corrections, so a contact's share is its push over the particle's count. (Counting the
// whole push made the friction cone as many times too wide as there are constraints on the
// particle.)
void PbdStepper::settle_contact_moves(bool average) {
  for (Contact& k : contacts_) {
    const Real count = count_[k.particle];
    k.normal_correction += average ? (count > 0 ? k.sweep_move / count : 0) : k.sweep_move;
    k.sweep_move = 0;
  }
}

// XPBD with averaged Jacobi: relax_[i] = 1/n_i, n_i the projections that reach particle i in one
// sweep (contacts included), 1 where the particle cannot move. A constraint's Δλ is scaled by
// ω = min over its particles of relax_, and each particle moves by the sum of its scaled
// corrections, so λ and the positions move together and x - p = M⁻¹∇Cᵀλ holds as in
// Gauss-Seidel: the fixed point is XPBD's (C + α̃λ = 0 with that λ). Averaging the positions
// while λ took the whole Δλ kept a softer fixed point (a hanging chain stretched up to 5/3 of
// its static stretch and λ/h² over-read the load). The scaled sum converges: per particle
// (Σ_j y_j ∇_i C_j)² <= n_i Σ_j y_j² |∇_i C_j|² (Cauchy-Schwarz), so J M⁻¹ Jᵀ + α̃ <= Ω⁻¹ D,
// D the diagonal of the kernels' denominators, and the Jacobi iteration ΩD⁻¹ has eigenvalues
// in (0, 1] on the linearised system.
void PbdStepper::set_relaxation(const Model& model) {
  if (!(settings_.method == Method::Xpbd && settings_.solver == Solver::Jacobi)) {
    relax_.clear();
    return;
  }
  if (coloured_.model_id == model.id && !coloured_.count.empty())
    relax_ = coloured_.count;
  else
    jacobi_counts(model, relax_);
  for (const Contact& k : contacts_) relax_[k.particle] += 1;
  for (const SelfContact& k : self_contacts_) {
    relax_[k.particle] += 1;
    for (Index i : k.triangle) relax_[i] += 1;
  }
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  for (Index i = 0; i < model.num_particles(); ++i) relax_[i] = w[i] > 0 && relax_[i] > 0 ? 1 / relax_[i] : 1;
}

// Friction, before the velocity update (Müller 2007 §3.5 leaves its form open). Coulomb's law
// at the position level (Macklin, Müller, Chentanez, Kim 2014, "Unified Particle Physics for
// Real-Time Applications", Eq. 24): with d the normal correction the contact made this sub-step
// (m; for XPBD w λ) and Δx_t the tangential part of the particle's displacement p - x,
//   |Δx_t| <= μs d:  p <- p - Δx_t                     (static: the particle does not slide)
//   otherwise:       p <- p - Δx_t μk d / |Δx_t|       (kinetic: slides, slowed by μk d)
// Divided by h this is the velocity-level rule |Δv_t| <= μ |f_n| h / m with f_n = m d / h²
// the contact force (Müller et al. 2020, "Detailed Rigid Body Simulation with XPBD", Eq. 30).
// The velocity (p - x)/h, or Verlet's x - x*, inherits the change.
void PbdStepper::apply_friction(const Model& model, const Positions& x) {
  for (const Contact& k : contacts_) {
    const Real d = k.normal_correction;
    const ContactMaterial& m = model.colliders[k.collider].material;
    if (!(d > 0) || !(m.friction_static > 0)) continue;
    const Index i = k.particle;
    const Vec3 dx = p_.col(i) - x.col(i);
    const Vec3 dt = dx - dx.dot(k.normal) * k.normal;
    const Real len = dt.norm();
    if (len <= m.friction_static * d)
      p_.col(i) -= dt;
    else
      p_.col(i) -= (m.friction_kinetic * d / len) * dt;
  }
}

// Restitution, in the velocity update (16). With v_n the normal velocity after (12) and ṽ_n the
// predicted one, (p - x)/h · n, at the contact's generation (< 0 approaching):
//   ṽ_n < -v_rest:  v_n <- max(v_n, -e ṽ_n)   (the impact is reflected with e)
//   otherwise:      v_n unchanged             (resting contact does not bounce)
// with v_rest = 2 |g| h, the normal speed gravity gives in two sub-steps (the threshold of Müller
// et al. 2020, §3.6), so a particle at rest, whose ṽ_n is -|g| h, never bounces and does not
// jitter. A particle that started the sub-step inside (the static fallback) leaves with
// v_n <- min(v_n, 0): being pushed out does not launch it. Verlet: x* <- x - h v.
void PbdStepper::apply_restitution(const Model& model, State& state, Real h) {
  const Real v_rest = 2 * settings_.gravity.norm() * h;
  const bool verlet = settings_.front_end == FrontEnd::Verlet;
  for (const Contact& k : contacts_) {
    if (!(k.normal_correction > 0)) continue;
    const Index i = k.particle;
    Vec3 v = verlet ? Vec3((state.x.col(i) - x_prev_.col(i)) / h) : Vec3(state.v.col(i));
    const Real vn = v.dot(k.normal);
    Real target = vn;
    if (k.started_inside)
      target = std::min(vn, Real(0));
    else if (k.approach_speed < -v_rest)
      target = std::max(vn, -model.colliders[k.collider].material.restitution * k.approach_speed);
    if (target == vn) continue;
    v += (target - vn) * k.normal;
    if (verlet)
      x_prev_.col(i) = state.x.col(i) - h * v;
    else
      state.v.col(i) = v;
  }
  // What is left of the contacts at the end of the sub-step.
  Real worst = 0;
  contact_summary_.active = 0;
  for (const Contact& k : contacts_) {
    worst = std::max(worst, k.thickness - (state.x.col(k.particle) - k.point).dot(k.normal));
    contact_summary_.active += k.normal_correction > 0;
  }
  for (const SelfContact& k : self_contacts_) {
    const auto& t = k.triangle;
    const Vec3 a = state.x.col(t[0]);
    const Vec3 n = (state.x.col(t[1]) - a).cross(state.x.col(t[2]) - a);
    if (n.norm() > 0) worst = std::max(worst, k.thickness - k.side * (state.x.col(k.particle) - a).dot(n.normalized()));
  }
  contact_summary_.max_penetration = worst;
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

// ------------------------------------------------------------------------------------ dispatch

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
  t.projections = static_cast<std::int64_t>(sweeps) * model.num_constraints();
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
