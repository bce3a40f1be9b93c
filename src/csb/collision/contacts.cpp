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

}  // namespace csb
