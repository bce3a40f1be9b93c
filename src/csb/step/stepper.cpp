// csb — PbdStepper::step: one step of Algorithm 1 (Müller et al. 2007) as named stages, with
// sub-steps and iterations; the stages themselves live in step/, solver/, collision/ and interaction/.
#include "csb/pbd.hpp"
#include "csb/methods/registry.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/memory_budget.hpp"

namespace csb {

using detail::str;
using namespace stepper_detail;


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
  if (s.precision == Precision::Single) {
    if (s.ordering != Ordering::Coloured || s.solver != Solver::GaussSeidel)
      throw InvalidArgument("precision 'float32' runs the coloured Gauss-Seidel sweep only (ordering 'coloured', "
                            "solver 'gauss-seidel')");
    if (s.damping > 0)
      throw InvalidArgument("precision 'float32' does not run Müller's damping (damping > 0); use xpbd_damping, "
                            "verlet_drag or precision 'float64'");
  }
  if (!(s.max_speed >= 0))
    throw InvalidArgument("max_speed must be a speed >= 0 m/s (0: automatic, inf: no divergence guard), got " +
                          str(s.max_speed));
}


std::string PbdStepper::name() const { return method_info(settings_.method).name; }

PbdStepper::PbdStepper(const PbdSettings& settings) : settings_(settings) {
  validate(settings_);
  if (settings_.method == Method::Jakobsen) settings_.front_end = FrontEnd::Verlet;
}


std::int64_t PbdStepper::projections_per_step(const Model& model) const {
  return static_cast<std::int64_t>(settings_.substeps) * settings_.iterations * model.num_constraints();
}


// ---------------------------------------------------------------------------------- the step
//
// One call advances `steps` steps of dt, each `substeps` sub-steps of h = dt/substeps, each with
// `iterations` sweeps of the constraints (Müller et al. 2007, Algorithm 1, line by line):
//
//   stage                          Algorithm 1           where
//   check the request              -                     check_request (step/checks.cpp)
//   per-model workspace            -                     prepare (step/workspace.cpp)
//   start of the steps             -                     begin_steps (here)
//   per sub-step:
//     predict                      (5)-(7)               predict, damp_velocities (step/integrate.cpp)
//     move the hands               -                     apply_grab_targets (interaction/grabs.cpp)
//     move the colliders           -                     move_colliders (collision/collider_motion.cpp)
//     zero XPBD's multipliers      -                     reset_multipliers (step/workspace.cpp)
//     generate contacts            (8)                   generate_contacts (collision/contacts.cpp)
//     project, `iterations` sweeps (9)-(11)              project (solver/sequential.cpp, solver/coloured.cpp)
//     check finite                 -                     fail_non_finite (step/checks.cpp)
//     friction                     (16), on p            apply_friction (collision/contacts.cpp)
//     continuous self-collision    -                     resolve_self_collisions (collision/contacts.cpp)
//     velocities and positions     (12)-(15)             commit (step/integrate.cpp)
//     inelastic self-contacts      (16)                  settle_self_contact_velocities (collision/contacts.cpp)
//     restitution                  (16)                  apply_restitution (collision/contacts.cpp)
//   end of a step                  -                     end_step: time, hands, divergence guard
//
// A fused step (no contacts, grabs or Müller damping, coloured ordering) runs the same stages
// inside the projection's threads, all sub-steps in one fork of the team (substeps_fused).
void PbdStepper::step(const Model& model, State& state, std::int64_t steps,
                      const std::function<bool()>& interrupt) {
  const UseGuard::Scope in_use(use_, "PbdStepper.step");
  check_request(model, state, steps);
  prepare(model);
  const bool single = settings_.precision == Precision::Single;
  if (single) check_single(model);
  const bool fused = begin_steps(model, state);
  const Real h = substep_size();
  for (std::int64_t s = 0; s < steps; ++s) {
    if (single)
      for (int first = 0; first < settings_.substeps; first += kFusedSubsteps) {  // interruptible between forks
        const int count = std::min(kFusedSubsteps, settings_.substeps - first);
        substeps_single(model, state, h, first, count);
        if (first + count < settings_.substeps) stop_if_asked(state, h, first + count - 1, interrupt);
      }
    else if (fused)
      substeps_fused(model, state, h, interrupt);
    else
      substeps(model, state, h, 0, settings_.substeps, interrupt);
    end_step(model, state, h);
    if (s + 1 < steps && interrupt && interrupt()) {
      finish_steps(state, h);
      throw Interrupted("interrupted after step " + std::to_string(state.step) + " (t = " + str(state.t) +
                        " s): the state is left at the end of that step");
    }
  }
  finish_steps(state, h);
}

// One sub-step of Algorithm 1 outside a fused fork. `after`: it follows a sub-step of the same
// call to substeps, so its start x is what that one's stages left as p (only p is changed between
// them); `predicted`: that sub-step's update already made this one's prediction. With `next`
// (another sub-step of the step follows) and nothing to change the velocities after the update
// (no contact of either kind this sub-step; no Müller damping), the update and the next
// prediction are one pass (advance, the same operations): returns whether it made the next
// prediction.
bool PbdStepper::substep(const Model& model, State& state, Real h, int sub, bool after, bool predicted, bool next) {
  if (!predicted) predict(model, state, h);                                 // (5)-(7)
  if (!grabs_.empty()) apply_grab_targets(Real(sub + 1) / settings_.substeps);
  if (!collider_motion_.empty()) move_colliders(model, sub);             // poses, attached particles
  reset_multipliers();
  generate_contacts(model, state.x, h, after);                              // (8)
  project(model, state.x);                                                  // (9)-(11)
  if (const Index i = first_non_finite(p_); i >= 0) fail_non_finite(state, sub, i, h);
  if (!contacts_.empty()) apply_friction(model, state.x);                   // (16), on p
  if (!self_.empty()) resolve_self_collisions(model, state.x, h);          // the last word on p
  const bool settle = !contacts_.empty() || !self_.contacts().empty();
  if (next && !settle && advancing()) {
    advance(state, h, 0, model.num_particles());                            // (12)-(15), then (5)-(7)
    return true;
  }
  commit(state, h, 0, model.num_particles());                               // (12)-(15)
  if (!self_.contacts().empty()) settle_self_contact_velocities(model, state, h);  // (16), inelastic
  if (settle) apply_restitution(model, state, h);                           // (16)
  return false;
}

// Sub-steps first .. first + count - 1 of a step, one at a time (each checked for finiteness),
// asking between them whether to stop (the state is then at the end of a sub-step: an update
// that also predicted the next leaves x and v as commit does).
void PbdStepper::substeps(const Model& model, State& state, Real h, int first, int count,
                          const std::function<bool()>& interrupt) {
  if (advancing()) {
    accel_.resize(3 * static_cast<std::size_t>(model.num_particles()));
    set_accel(model, h, 0, model.num_particles());
  }
  bool predicted = false;
  for (int sub = first; sub < first + count; ++sub) {
    predicted = substep(model, state, h, sub, sub > first, predicted, sub + 1 < first + count);
    if (sub + 1 < settings_.substeps) stop_if_asked(state, h, sub, interrupt);
  }
}

// The sub-steps of a step in forks of the projection's team, at most kFusedSubsteps a fork, so
// that a step of very many sub-steps can be interrupted between forks; a fork's last sub-step
// commits what the next would have updated in the same pass (the same operations), so the bits
// do not depend on the cut.
void PbdStepper::substeps_fused(const Model& model, State& state, Real h, const std::function<bool()>& interrupt) {
  generate_contacts(model, state.x, h);  // (8): none, but the last step's are cleared
  if (settings_.method == Method::Xpbd) lambda_stale_ = true;
  for (int first = 0; first < settings_.substeps; first += kFusedSubsteps) {
    const int count = std::min(kFusedSubsteps, settings_.substeps - first);
    Fused f{&state, h, count};
    project(model, state.x, &f);
    if (f.bad >= 0 && f.bad_sub >= 0) fail_non_finite(state, first + f.bad_sub, f.bad, h);
    // Checked once, after the fork's last sub-step, and found non-finite: back to the fork's
    // start, then its sub-steps again one at a time, each checked (the same operations, so the
    // same positions), which stop at the first non-finite one and leave the state at its start.
    // (A non-finite position stays so to the fork's end: every later operation that writes it
    // has it as an operand; so the check once misses none.)
    if (f.bad >= 0) {
      state.x = x_step_;
      (settings_.front_end == FrontEnd::Verlet ? x_prev_ : state.v) = v_step_;
      substeps(model, state, h, first, count, interrupt);
    }
    if (first + count < settings_.substeps) stop_if_asked(state, h, first + count - 1, interrupt);
  }
}

// Between sub-steps, whether the caller asked to stop: the state is then left at the end of
// sub-step `sub` of the current step (its time included, its step count not).
void PbdStepper::stop_if_asked(State& state, Real h, int sub, const std::function<bool()>& interrupt) {
  if (!interrupt || !interrupt()) return;
  state.t += (sub + 1) * h;
  finish_steps(state, h);
  throw Interrupted("interrupted during step " + std::to_string(state.step) + " after sub-step " +
                    std::to_string(sub) + " (t = " + str(state.t) + " s): the state is left at the end of that sub-step");
}

// What a call's steps start from: the divergence guard's baseline, pins let go, the hands'
// particles' masses, the coloured batches and the threads, Verlet's previous positions. Returns
// whether the steps are fused.
bool PbdStepper::begin_steps(const Model& model, State& state) {
  const Index n = model.num_particles();
  const Real h = substep_size();
  const bool verlet = settings_.front_end == FrontEnd::Verlet;
  if (!guard_started_ || state.t < guard_t0_) {  // the divergence guard's baseline: the first state stepped
    guard_v0_ = 0;
    for (Index i = 0; i < n; ++i) guard_v0_ = std::max(guard_v0_, state.v.col(i).norm());
    guard_t0_ = state.t;
    guard_started_ = true;
  }
  for (Index i : stop_)  // a pin let go stays where it was put
    if (i < n) state.v.col(i).setZero();
  stop_.clear();
  hold_grabbed(model);
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
    const Real* x = state.x.data();
    const Real* v = state.v.data();
    Real* xp = x_prev_.data();
    for (Index k = 0; k < 3 * n; ++k) xp[k] = x[k] - h * v[k];
  }
  // Without contacts, grabs or Müller damping a sub-step is element-wise but for the sweeps: the
  // projection's threads then also predict and update (the same operations, split by particle),
  // all sub-steps of a step in one fork of the team; otherwise the sub-steps run here, the team
  // forked for each projection.
  return settings_.ordering == Ordering::Coloured && grabs_.empty() && model.colliders.empty() && collider_motion_.empty() &&
         self_.empty() && (verlet || settings_.damping <= 0);
}

// The end of a step: its count and time, the hands' starting points for the next, the
// divergence guard.
void PbdStepper::end_step(const Model& model, State& state, Real h) {
  ++state.step;
  state.t += settings_.dt;
  for (Grab& g : grabs_) g.from = g.target;
  end_collider_motion(model, state);
  if (settings_.max_speed != std::numeric_limits<Real>::infinity()) check_divergence(model, state, h);
}

// The Verlet front end keeps its velocity in the previous positions: the state's velocities
// are made from them when a call ends (or stops).
void PbdStepper::finish_steps(State& state, Real h) {
  if (settings_.front_end == FrontEnd::Verlet) state.v = (state.x - x_prev_) / h;
}

}  // namespace csb
