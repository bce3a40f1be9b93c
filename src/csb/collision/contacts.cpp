// csb — the stepper's collision stages: contacts with the colliders and cloth self-contacts (Müller
// 2007 §4.3-4.4) generated each sub-step, projected with the constraints, then friction and restitution.
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/constraints/attachment.hpp"

namespace csb {

using detail::str;
using namespace stepper_detail;


// Algorithm 1 line (8): the collision constraints of this sub-step, from the positions x at its
// start and the prediction p (see collision.hpp for the rule). Particles that cannot move get none.
void PbdStepper::generate_contacts(const Model& model, const Positions& x, Real h, bool x_resolved) {
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
      for (Index c = 0; c < static_cast<Index>(model.colliders.size()); ++c) {
        if (!collider_motion_.empty() && collider_motion_[c].deform.active()) {  // against the moving triangles
          generate_deforming_contact(model.colliders[c], collider_motion_[c].deform, c, i, xi, pi, model.thickness[i],
                                     margin_[model.group[i]], h, contacts_, stamps_, stamp_);
          continue;
        }
        if (!collider_motion_.empty() && collider_motion_[c].moving) {  // along the motion relative to it
          const ColliderMotion& m = collider_motion_[c];
          generate_moving_contact(model.colliders[c], m.start, m.end, c, i, xi, pi, model.thickness[i],
                                  margin_[model.group[i]], h, contacts_, stamps_, stamp_);
          continue;
        }
        generate_contact(model.colliders[c], c, i, xi, pi, model.thickness[i], margin_[model.group[i]], h, contacts_,
                         stamps_, stamp_);
      }
    }
  }
  for (const Contact& k : contacts_)
    contact_summary_.max_depth =
        std::max(contact_summary_.max_depth, k.thickness - (p_.col(k.particle) - k.point).dot(k.normal));
  contact_summary_.count = static_cast<Index>(contacts_.size());
  if (!self_.empty()) {
    const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
    self_.set_threads(threads_used_, [this](int threads, const std::function<void(int)>& job) {
      team_.get().run(threads, spin_, job);
    });
    self_.begin(model, x, p_, w, settings_.substeps, h, true, x_resolved);
    report_self_collision();
  }
}

// The self-collision's counts in the contact summary.
void PbdStepper::report_self_collision() {
  const SelfCollisionCounts& c = self_.counts();
  contact_summary_.self_count = c.contacts;
  contact_summary_.self_continuous = c.continuous;
  contact_summary_.self_failsafe = c.failsafe;
  contact_summary_.self_unresolved = c.unresolved;
  contact_summary_.self_searches = c.searches;
  contact_summary_.self_candidates = c.candidates;
  contact_summary_.self_tests = c.tests;
  contact_summary_.self_culled = c.culled;
  contact_summary_.self_skipped = c.skipped;
}

// After the sweeps and friction: self-collision's continuous test, responses and fail-safe
// (collision/self_collision.cpp), the last word on p.
void PbdStepper::resolve_self_collisions(const Model& model, const Positions& x, Real h) {
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  self_.resolve(model, x, p_, w, settings_.substeps, h);
  report_self_collision();
}

// After the velocity update: self-contacts are inelastic (16), see SelfCollision::settle_velocities;
// the Verlet front end's velocity is (x - x_prev)/h, changed through x_prev.
void PbdStepper::settle_self_contact_velocities(const Model& model, State& state, Real h) {
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  if (settings_.front_end == FrontEnd::Verlet)
    self_.settle_velocities(
        state.x, w, [&](Index i) { return Vec3((state.x.col(i) - x_prev_.col(i)) / h); },
        [&](Index i, const Vec3& dv) { x_prev_.col(i) -= h * dv; });
  else
    self_.settle_velocities(
        state.x, w, [&](Index i) { return Vec3(state.v.col(i)); }, [&](Index i, const Vec3& dv) { state.v.col(i) += dv; });
}

// The self-contacts' projections in one sweep (self_contact_step, collision/self_collision.cpp),
// Gauss-Seidel on p or, with Jacobi, from the sweep's start into the averaged moves.
void PbdStepper::project_self_contacts(const Model& model, bool jacobi) {
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  const Real* from = jacobi ? p_start_.data() : p_.data();
  const Real* relax = jacobi && !relax_.empty() ? relax_.data() : nullptr;  // XPBD, averaged Jacobi
  for (SelfContact& k : self_.contacts()) {
    Vec3 step;
    if (!self_contact_step(k, from, w, relaxation(relax, k.particles), step)) continue;
    k.pushed = true;
    for (int e = 0; e < 4; ++e) {
      const Index i = k.particles[e];
      const Vec3 dp = (w[i] * k.weights[e]) * step;
      if (jacobi) {
        delta_.col(i) += dp;
        count_[i] += 1;
      } else {
        p_.col(i) += dp;
      }
    }
  }
}

// The contacts' projections in one sweep, after the other constraints so that non-penetration
// has the last word in Gauss-Seidel: self-contacts, then collider contacts. Each is hard
// (stiffness 1, Müller 2007 §4.3; XPBD with α = 0).
// Self-contacts: project_self_contacts (above).
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
  if (!self_.contacts().empty()) project_self_contacts(model, jacobi);
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


// Friction, before the velocity update (Müller 2007 §3.5 leaves its form open). Coulomb's law
// at the position level (Macklin, Müller, Chentanez, Kim 2014, "Unified Particle Physics for
// Real-Time Applications", Eq. 24): with d the normal correction the contact made this sub-step
// (m; for XPBD w λ) and Δx_t the tangential part of the particle's displacement p - x,
//   |Δx_t| <= μs d:  p <- p - Δx_t                     (static: the particle does not slide)
//   otherwise:       p <- p - Δx_t μk d / |Δx_t|       (kinetic: slides, slowed by μk d)
// Divided by h this is the velocity-level rule |Δv_t| <= μ |f_n| h / m with f_n = m d / h²
// the contact force (Müller et al. 2020, "Detailed Rigid Body Simulation with XPBD", Eq. 30).
// The velocity (p - x)/h, or Verlet's x - x*, inherits the change. Against a moving collider
// Δx_t is relative: the particle's displacement minus that of the collider's material point at
// the contact over the sub-step (Contact::surface_motion, zero for an unmoved collider), so a
// static contact is carried along by the surface (a rotating sphere turns the cloth on it).
void PbdStepper::apply_friction(const Model& model, const Positions& x) {
  for (const Contact& k : contacts_) {
    const Real d = k.normal_correction;
    const ContactMaterial& m = model.colliders[k.collider].material;
    if (!(d > 0) || !(m.friction_static > 0)) continue;
    const Index i = k.particle;
    const Vec3 dx = p_.col(i) - x.col(i) - k.surface_motion;
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
// v_n <- min(v_n, 0): being pushed out does not launch it. Verlet: x* <- x - h v. Against a
// moving collider v_n and ṽ_n are relative to the surface (ṽ_n from the ray in the collider's
// frame, v_n minus the normal velocity of the collider's material point at the contact,
// surface_motion/h): a plane moving up at u into a ball falling at v leaves it at
// u + e (u + v).
void PbdStepper::apply_restitution(const Model& model, State& state, Real h) {
  const Real v_rest = 2 * settings_.gravity.norm() * h;
  const bool verlet = settings_.front_end == FrontEnd::Verlet;
  for (const Contact& k : contacts_) {
    if (!(k.normal_correction > 0)) continue;
    const Index i = k.particle;
    Vec3 v = verlet ? Vec3((state.x.col(i) - x_prev_.col(i)) / h) : Vec3(state.v.col(i));
    const Real vn = (v - k.surface_motion / h).dot(k.normal);
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
  contact_summary_.collider_penetration = worst;
  contact_summary_.self_penetration = self_.penetration(state.x);
  contact_summary_.max_penetration = std::max(worst, contact_summary_.self_penetration);
}

}  // namespace csb
