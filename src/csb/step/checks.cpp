// csb — what the stepper checks and says: non-finite positions, the divergence guard, settings that
// cannot solve a model accurately, a degenerate state.
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/memory_budget.hpp"
#include "csb/constraints/volume.hpp"
#include "csb/material.hpp"
#include <limits>
#include <sstream>

namespace csb {

using detail::str;
using namespace stepper_detail;


std::vector<std::string> PbdStepper::accuracy_notes_to_report(const Model& model) const {
  if (reported_models_.count(model.id)) return {};
  std::vector<std::string> notes;
  // A self-collision thickness above the smallest rest altitude of the group's triangles puts a
  // particle within the contact distance of triangles of its own neighbourhood lying flat beside
  // it: their contacts fight the cloth's shape (a 256 x 256 cape of 1 m, altitude 2.8 mm, steps
  // at h = 2 mm and diverges within 15 steps at 3 mm; xpbd, 2 x 5).
  for (Index g = 0; g < model.num_groups(); ++g) {
    const Real h = model.self_collision_thickness[g];
    if (!(h > 0)) continue;
    Real lowest = std::numeric_limits<Real>::infinity();
    Index at = -1;
    Vec3 lo = Vec3::Constant(lowest), hi = -lo;
    for (Index t = 0; t < static_cast<Index>(model.triangles.size()); ++t) {
      const Triangle& tri = model.triangles[t];
      if (model.group[tri[0]] != g) continue;
      const Vec3 a = model.rest_positions.col(tri[0]), b = model.rest_positions.col(tri[1]), c = model.rest_positions.col(tri[2]);
      const Real longest = std::max({(b - a).norm(), (c - b).norm(), (a - c).norm()});
      const Real altitude = longest > 0 ? (b - a).cross(c - a).norm() / longest : 0;
      if (altitude < lowest) lowest = altitude, at = t;
      lo = lo.cwiseMin(a.cwiseMin(b).cwiseMin(c)), hi = hi.cwiseMax(a.cwiseMax(b).cwiseMax(c));
    }
    // A thickness beyond the cloth's size is refused by the step itself (SelfCollision::prepare).
    if (at < 0 || !(h > lowest) || h > (hi - lo).norm()) continue;
    std::ostringstream msg;
    msg << "self-collision of group '" << model.group_names[g] << "': its thickness " << h
        << " m exceeds the smallest rest altitude of its triangles, " << lowest << " m (triangle " << at
        << "), so a particle lies within the contact distance of triangles of its own flat neighbourhood and their "
           "contacts fight the cloth's shape (a 256 x 256 cape of 1 m steps at 2 mm and diverges at 3 mm); give a "
           "thickness below the altitude, or a coarser mesh";
    notes.push_back(msg.str());
  }
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
  if (at < 0 || !(worst > allowed)) return notes;
  const Index i = d.particles[at][0], j = d.particles[at][1];
  std::ostringstream msg;
  msg << method_label(settings_.method) << " with " << settings_.substeps << " sub-step(s) x " << settings_.iterations
      << " iteration(s): distance constraint " << at << " joins particles " << i << " and " << j
      << " whose masses differ " << worst << " times (" << model.mass[i] << " and " << model.mass[j]
      << " kg), more than 10 x iterations x substeps² = " << allowed
      << "; Gauss-Seidel then moves the light particle almost alone and such links stretch (a hanging chain of "
         "alternating masses: 7-70 % of their length at that ratio, up to 15 times it ten times beyond). More "
         "sub-steps raise the limit fastest; or keep neighbours' masses closer";
  notes.push_back(msg.str());
  return notes;
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


namespace {

// Whether some moving particle's squared speed may exceed limit2: one branch-free pass that the
// compiler runs in SIMD lanes, so that a step far from the limit (nearly all) skips the search
// for the fastest particle below. Its sums may round apart from Eigen's squaredNorm, so it asks
// for a margin of 1e-9 below limit2 (far wider than a rounding); it skips only steps whose
// particles are all below that, where the search would find none. v: the velocities, or
// (Verlet) the previous positions, with x.
bool maybe_beyond(const Real* w, const Real* x, const Real* v, bool verlet, Real h, Real limit2, Index n) {
  const Real below = limit2 * (1 - 1e-9);
  int beyond = 0;
  if (verlet) {
    for (Index i = 0; i < n; ++i) {
      const Real a = (x[3 * i] - v[3 * i]) / h, b = (x[3 * i + 1] - v[3 * i + 1]) / h,
                 c = (x[3 * i + 2] - v[3 * i + 2]) / h;
      beyond |= (w[i] > 0) & (a * a + b * b + c * c > below);
    }
  } else {
    for (Index i = 0; i < n; ++i) {
      const Real a = v[3 * i], b = v[3 * i + 1], c = v[3 * i + 2];
      beyond |= (w[i] > 0) & (a * a + b * b + c * c > below);
    }
  }
  return beyond != 0;
}

}  // namespace

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
  if (!maybe_beyond(w, state.x.data(), verlet ? x_prev_.data() : state.v.data(), verlet, h, limit2, n)) return;
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


void PbdStepper::fail_non_finite(State& state, int sub, Index i, Real h) {
  if (settings_.front_end == FrontEnd::Verlet) state.v = (state.x - x_prev_) / h;
  std::ostringstream msg;
  msg << "step " << state.step << " (substep " << sub << ", t = " << state.t << " s): particle " << i
      << " got a non-finite position " << str(p_.col(i)) << "; the state is left at the end of the last finite substep";
  throw SimulationError(msg.str());
}

// Precision::Single covers the coloured Gauss-Seidel sweep of distance and bending constraints
// with pins and kinematic grabs, in a step without contacts, compliant grabs or moving colliders:
// what else the model or the stepper holds is named.
void PbdStepper::check_single(const Model& model) const {
  std::vector<std::string> what;
  const auto count = [&](Index k, const char* name) {
    if (k > 0) what.push_back(std::to_string(k) + " " + name);
  };
  count(model.volume.size(), "volume constraints");
  count(model.attachments.size(), "attachments");
  count(model.balloons.size(), "balloons");
  Index family = 0;
  for (const auto& f : model.families) family += f->size();
  count(family, "constraints of families (tethers, ...)");
  count(static_cast<Index>(model.colliders.size()), "colliders");
  if (!self_.empty()) what.push_back("self-collision");
  Index compliant = 0;
  for (const Grab& g : grabs_) compliant += g.compliance > 0;
  count(compliant, "compliant grabs (compliance > 0)");
  if (what.empty()) return;
  std::string list;
  for (std::size_t k = 0; k < what.size(); ++k) list += (k ? ", " : "") + what[k];
  throw InvalidArgument("precision 'float32' runs distance and bending constraints, pins and kinematic grabs "
                        "(compliance 0) without contacts; this model and stepper have " + list +
                        ": use precision 'float64'");
}

// The request before any work: the state matches the model, steps >= 0 and within a year's work
// (memory_budget.hpp), every position and velocity finite.
void PbdStepper::check_request(const Model& model, const State& state, std::int64_t steps) const {
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
}

}  // namespace csb
