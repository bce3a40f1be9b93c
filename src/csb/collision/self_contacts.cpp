// csb — cloth self-collision in the position-based steppers (Müller 2007 §4.4): the self-contacts
// of each self-colliding group, generated each sub-step and projected with the constraints.
#include "csb/pbd.hpp"
#include "csb/step/internal.hpp"

namespace csb {

using namespace stepper_detail;

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

// Self-contact (Müller 2007 §4.4): C = s (q - p1)·n - d, n the unit normal of the current
// triangle; its gradient is taken with n fixed and the correction shared by the barycentric
// weights b of q's nearest point (the distribution of Bridson, Fedkiw, Anderson 2002, §7.1):
//   ∇_q C = s n,  ∇_pi C = -b_i s n,  Δ = -C / (w_q + Σ b_i² w_i).
void PbdStepper::project_self_contacts(const Model& model, bool jacobi) {
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
}

}  // namespace csb
