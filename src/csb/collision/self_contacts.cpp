// csb — cloth self-collision in the position-based steppers: point–triangle proximity contacts of
// each self-colliding group generated at the start of a sub-step and projected with the
// constraints (Müller 2007 §4.4), then, after the sweeps, continuous collision detection of every
// point–triangle and edge–edge pair along the sub-step's motion x -> p, responses (after Bridson,
// Fedkiw, Anderson 2002), inelastic velocities, and a fail-safe.
//
// What is guaranteed. Let the cloth have no intersection at the start x of a sub-step. Every
// pair of features that share no particle (a particle and a triangle without it, two edges
// without a common end) whose swept boxes over x -> p touch is tested by additive CCD (ccd.hpp)
// along its straight motion, conservatively: a pair whose distance reaches 0 anywhere in the
// sub-step is always found. Found pairs get a contact along their normal at the time of impact;
// after kResponseRounds rounds of responses, what is still found is stopped: its particles that
// can move are put back where they started the sub-step (p = x), the fail-safe, repeated until the
// test finds nothing (a pair whose particles all stay cannot meet: x has no intersection). So the
// end of the sub-step has no new intersection, with two exceptions, counted and reported:
// `self_unresolved`, a pair that meets only because prescribed particles (pins moved by the
// user, kinematic grabs) drive it through, which no motion of the free particles can undo; and
// `self_skipped`, triangles left out because they spread over more than the cloth's rest size
// within a step (a runaway, which the divergence guard stops by default). Each
// particle the fail-safe stops is counted (`self_failsafe`): it loses its velocity for that
// sub-step, visibly, which is why the responses come first. The guarantee is the one of the
// pairs: a particle touching a triangle it belongs to, or two edges with a common end, are not
// tested (they meet only by a triangle collapsing).
#include "csb/pbd.hpp"
#include "csb/collision/collision.hpp"
#include "csb/step/internal.hpp"

#include <algorithm>

namespace csb {

using namespace stepper_detail;

namespace {

// Rounds of continuous contacts before the fail-safe, and Gauss-Seidel passes over the
// self-contacts in each. More do not stop the fail-safe firing where a cloth is wound tight:
// the 30 x 30 twist's first 3 s stopped 9,211 particles with 2 rounds of 2 passes, 7,251 with
// 4 of 2, 12,530 with 2 of 4 and 34,990 with 6 of 4 (validation/torture.py counts them).
constexpr int kResponseRounds = 2;
constexpr int kResponsePasses = 2;
// The additive CCD's separation s: an impact is a pair whose distance falls below s times its
// distance at the start of the sub-step; its contact then keeps at least that much.
constexpr Real kSeparation = 0.1;

inline bool boxes_overlap(const Vec3& lo_a, const Vec3& hi_a, const Vec3& lo_b, const Vec3& hi_b) {
  return !((lo_a.array() > hi_b.array()).any() || (hi_a.array() < lo_b.array()).any());
}

// The normal n of contact k at positions y0..y3 (as SelfContact says); false if it has none there
// (a collapsed triangle).
bool contact_normal(const SelfContact& k, const Vec3& y1, const Vec3& y2, const Vec3& y3, Vec3& n) {
  if (k.continuous) {
    n = k.normal;
    return true;
  }
  n = (y2 - y1).cross(y3 - y1);
  const Real len = n.norm();
  if (!(len > 0)) return false;
  n *= k.side / len;
  return true;
}

// Σ_k c_k y_k: the separation d of contact k's particles at positions y (m).
template <class Y>
Vec3 separation(const SelfContact& k, const Y& y) {
  const auto& c = k.weights;
  const auto& id = k.particles;
  return c[0] * y(id[0]) + c[1] * y(id[1]) + c[2] * y(id[2]) + c[3] * y(id[3]);
}

// Σ_k c_k² w_k: the inverse mass a contact's correction or impulse along its normal meets.
Real contact_inverse_mass(const SelfContact& k, const Real* w) {
  const auto& c = k.weights;
  const auto& id = k.particles;
  return c[0] * c[0] * w[id[0]] + c[1] * c[1] * w[id[1]] + c[2] * c[2] * w[id[2]] + c[3] * c[3] * w[id[3]];
}

// The approach speed of a contact along n in the motion x -> p over h, m/s.
Real approach_speed(const SelfContact& k, const Vec3& n, const Positions& x, const Positions& p, Real h) {
  return separation(k, [&](Index i) { return Vec3(p.col(i) - x.col(i)); }).dot(n) / h;
}

}  // namespace

// Runs chunk(t, T) for t = 0 .. T - 1 on the stepper's team, T its threads when the work (n
// pairs) is large enough to pay for a fork, else 1; impact_parts_ and contact_parts_ are sized
// for T. Chunk t takes the t-th of T equal runs of each list and writes only its own part; the
// caller joins the parts in t's order, so the result is the same for any T. Returns T.
template <class F>
int PbdStepper::in_chunks(std::size_t n, F&& chunk) {
  const int T = threads_used_ > 1 && n >= kParallelPairs ? threads_used_ : 1;
  if (impact_parts_.size() < 2 * static_cast<std::size_t>(T)) impact_parts_.resize(2 * T);
  if (contact_parts_.size() < static_cast<std::size_t>(T)) contact_parts_.resize(T);
  const auto job = [&](int t) { chunk(t, T); };
  if (T == 1)
    job(0);
  else
    team_.get().run(T, spin_, job);
  return T;
}

// The candidate pairs of a group, found once per step and kept while they hold. Each particle gets
// a box: over its start x, its prediction p and where the prediction leads in a step's time
// (x + k (p - x), k the sub-steps of a step; not beyond the cloth's size), widened by 1.5 h on
// each side. A feature's box is the union of its particles'; a pair is kept if its boxes overlap,
// the features share no particle, and one of its particles can move.
//
// The pairs hold for a sub-step as long as every particle's x and p lie in its box shrunk by h
// (self_candidates_hold; h/2 of slack for the path to bend away from the straight line): then
// the features' swept boxes over x -> p, widened by h, lie in their boxes, so every pair that can
// touch during the sub-step (swept boxes overlapping) or is within 2h at the prediction (the
// proximity contacts) is a candidate. When a particle leaves its box (the cloth swung off the
// straight line, or a hard push by the constraints) the pairs are found again from where it is.
// One search a step instead of one a sub-step: the search, not the tests, was most of the cost
// (66 % of a 1,600-particle cape's step at 10 sub-steps); widened by 1.5 h rather than 2 h, the
// boxes overlap less and the cape's step took 7.0-7.7 ms instead of 9.2-11 (2 sub-steps of 5
// iterations, three alternating runs).
void PbdStepper::find_self_candidates(const Model& model, SelfGroup& g, const Positions& x) {
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  const Real pad = 1.5 * g.thickness;
  const Real ahead = static_cast<Real>(settings_.substeps);
  const Vec3 inf = Vec3::Constant(std::numeric_limits<Real>::infinity());
  for (Index o = model.group_offsets[g.group]; o < model.group_offsets[g.group + 1]; ++o) {
    const Index i = model.group_particles[o];
    const Vec3 xi = x.col(i), pi = p_.col(i);
    // The look-ahead only while it stays within the cloth's size (a fast particle searches again).
    Vec3 end = xi + ahead * (pi - xi);
    if (!((end - xi).cwiseAbs().maxCoeff() <= g.size)) end = pi;
    particle_lo_.col(i) = xi.cwiseMin(pi).cwiseMin(end).array() - pad;
    particle_hi_.col(i) = xi.cwiseMax(pi).cwiseMax(end).array() + pad;
  }
  // A feature whose box spans more than the cloth's rest size (plus the widening) has been torn
  // across the cloth or flung beyond it within a step: no contact or continuous test can follow
  // it (the divergence guard stops such a step by default). It is left out of this search (an
  // empty box) and counted (self_skipped), so that a particle flung 1e12 m away costs one search,
  // not one pair with every feature on every sub-step.
  const Real reach = g.size + 2 * pad;
  const auto keep = [&](Vec3& lo, Vec3& hi) {
    if ((hi - lo).maxCoeff() <= reach) return true;  // false for NaN too
    lo = inf, hi = -inf;
    return false;
  };
  unite_self_boxes(model, g, particle_lo_, particle_hi_);
  g.skipped = 0;
  for (std::size_t t = 0; t < g.triangles.size(); ++t) g.skipped += !keep(box_lo_[t], box_hi_[t]);
  for (std::size_t e = 0; e < g.edges.size(); ++e) keep(edge_lo_[e], edge_hi_[e]);
  g.pt.clear();
  g.ee.clear();
  // One search, of triangle pairs, gives both kinds: a particle's box lies in its owner
  // triangle's, an edge's in its owner's (the first triangle of the group holding it), so a
  // particle-triangle or edge-edge pair whose boxes overlap has owners whose boxes overlap; each
  // pair is taken from its owners' pair only, so none comes twice.
  const auto point_triangle = [&](Index q, Index t) {
    const Triangle& tri = model.triangles[g.triangles[t]];
    if (tri[0] == q || tri[1] == q || tri[2] == q) return;
    if (!boxes_overlap(particle_lo_.col(q), particle_hi_.col(q), box_lo_[t], box_hi_[t])) return;
    if (w[q] + w[tri[0]] + w[tri[1]] + w[tri[2]] <= 0) return;
    g.pt.push_back({q, t});
  };
  const auto edge_edge = [&](Index a, Index b) {
    const auto& ea = g.edges[a];
    const auto& eb = g.edges[b];
    if (ea[0] == eb[0] || ea[0] == eb[1] || ea[1] == eb[0] || ea[1] == eb[1]) return;
    if (!boxes_overlap(edge_lo_[a], edge_hi_[a], edge_lo_[b], edge_hi_[b])) return;
    if (w[ea[0]] + w[ea[1]] + w[eb[0]] + w[eb[1]] <= 0) return;
    g.ee.push_back({std::min(a, b), std::max(a, b)});
  };
  // The pairs of triangles whose boxes overlap: the group's bounding-volume hierarchy (built once
  // from the rest shape, see workspace.cpp) refitted to the boxes, and traversed against itself
  // from the root: a node with itself gives its children with themselves and with each other; two
  // nodes whose boxes overlap give the pairs of their children (the one holding more triangles
  // is opened). Every overlapping pair of leaves comes once, in an order fixed by the tree.
  const Index nodes = static_cast<Index>(g.bvh_child.size());
  node_lo_.resize(nodes);
  node_hi_.resize(nodes);
  for (Index k = nodes - 1; k >= 0; --k) {  // children come after their parent
    const auto& c = g.bvh_child[k];
    if (c[0] < 0) {
      node_lo_[k] = box_lo_[-1 - c[0]], node_hi_[k] = box_hi_[-1 - c[0]];
    } else {
      node_lo_[k] = node_lo_[c[0]].cwiseMin(node_lo_[c[1]]);
      node_hi_[k] = node_hi_[c[0]].cwiseMax(node_hi_[c[1]]);
    }
  }
  const auto leaf_pair = [&](Index t1, Index t2) {
    for (Index k = g.owned_particle_start[t1]; k < g.owned_particle_start[t1 + 1]; ++k)
      point_triangle(g.owned_particles[k], t2);
    for (Index k = g.owned_particle_start[t2]; k < g.owned_particle_start[t2 + 1]; ++k)
      point_triangle(g.owned_particles[k], t1);
    for (Index i = g.owned_edge_start[t1]; i < g.owned_edge_start[t1 + 1]; ++i)
      for (Index j = g.owned_edge_start[t2]; j < g.owned_edge_start[t2 + 1]; ++j)
        edge_edge(g.owned_edges[i], g.owned_edges[j]);
  };
  node_pairs_.clear();
  if (nodes > 0) node_pairs_.push_back({0, 0});
  while (!node_pairs_.empty()) {
    const auto [a, b] = node_pairs_.back();
    node_pairs_.pop_back();
    const auto& ca = g.bvh_child[a];
    const auto& cb = g.bvh_child[b];
    if (a == b) {
      if (ca[0] < 0) continue;
      node_pairs_.push_back({ca[0], ca[1]});
      node_pairs_.push_back({ca[1], ca[1]});
      node_pairs_.push_back({ca[0], ca[0]});
      continue;
    }
    if (!boxes_overlap(node_lo_[a], node_hi_[a], node_lo_[b], node_hi_[b])) continue;
    if (ca[0] < 0 && cb[0] < 0) {
      leaf_pair(-1 - ca[0], -1 - cb[0]);
    } else if (ca[0] < 0 || (cb[0] >= 0 && g.bvh_size[b] > g.bvh_size[a])) {
      node_pairs_.push_back({a, cb[1]});
      node_pairs_.push_back({a, cb[0]});
    } else {
      node_pairs_.push_back({ca[1], b});
      node_pairs_.push_back({ca[0], b});
    }
  }
  if (!g.loose.empty()) hash_.build(g.cell, box_lo_, box_hi_);
  for (const Index q : g.loose) {  // particles of the group in no triangle
    if (!((particle_hi_.col(q) - particle_lo_.col(q)).maxCoeff() <= reach)) continue;
    if (++stamp_ == 0) std::fill(stamps_.begin(), stamps_.end(), 0), stamp_ = 1;
    hash_.query(particle_lo_.col(q), particle_hi_.col(q), [&](Index t) {
      if (stamps_[t] == stamp_) return;
      stamps_[t] = stamp_;
      point_triangle(q, t);
    });
  }
  g.searched = true;
  ++self_searches_;
}

// Whether the candidates of group g hold for the positions x and p_ now (see above).
bool PbdStepper::self_candidates_hold(const Model& model, const SelfGroup& g, const Positions& x) const {
  const Real h = g.thickness;
  for (Index o = model.group_offsets[g.group]; o < model.group_offsets[g.group + 1]; ++o) {
    const Index i = model.group_particles[o];
    if (!((particle_hi_.col(i) - particle_lo_.col(i)).maxCoeff() <= g.size + 3 * h)) continue;  // left out
    const Vec3 lo = particle_lo_.col(i).array() + h, hi = particle_hi_.col(i).array() - h;
    const Vec3 xi = x.col(i), pi = p_.col(i);
    if ((xi.array() < lo.array()).any() || (xi.array() > hi.array()).any() || (pi.array() < lo.array()).any() ||
        (pi.array() > hi.array()).any())
      return false;
  }
  return true;
}

// The features' swept boxes over x -> p_ (triangles in box_lo_/box_hi_, edges in edge_lo_/edge_hi_,
// particles in sweep_lo_/sweep_hi_), widened by `pad` (m).
void PbdStepper::sweep_self_boxes(const Model& model, const SelfGroup& g, const Positions& x, Real pad) {
  for (Index o = model.group_offsets[g.group]; o < model.group_offsets[g.group + 1]; ++o) {
    const Index i = model.group_particles[o];
    sweep_lo_.col(i) = x.col(i).cwiseMin(p_.col(i)).array() - pad;
    sweep_hi_.col(i) = x.col(i).cwiseMax(p_.col(i)).array() + pad;
  }
  unite_self_boxes(model, g, sweep_lo_, sweep_hi_);
}

// Each triangle's and edge's box (box_lo_/box_hi_, edge_lo_/edge_hi_) as the union of its
// particles' boxes [lo, hi].
void PbdStepper::unite_self_boxes(const Model& model, const SelfGroup& g, const Positions& lo, const Positions& hi) {
  const Vec3 inf = Vec3::Constant(std::numeric_limits<Real>::infinity());
  const auto unite = [&](const auto& ids, Vec3& l, Vec3& u) {
    l = inf, u = -inf;
    for (const Index i : ids) l = l.cwiseMin(lo.col(i)), u = u.cwiseMax(hi.col(i));
  };
  box_lo_.resize(g.triangles.size());
  box_hi_.resize(g.triangles.size());
  for (std::size_t t = 0; t < g.triangles.size(); ++t) unite(model.triangles[g.triangles[t]], box_lo_[t], box_hi_[t]);
  edge_lo_.resize(g.edges.size());
  edge_hi_.resize(g.edges.size());
  for (std::size_t e = 0; e < g.edges.size(); ++e) unite(g.edges[e], edge_lo_[e], edge_hi_[e]);
}

// Proximity contacts at the start of the sub-step, from the candidates, with two rules that keep
// them from adding energy. The projection moves a particle by a distance d in one sub-step, and
// the velocity update (12) turns that into a speed d/Δt (Δt = 1/1800 s in cloth_sphere: 1 cm is
// 18 m/s), so a contact may only take away approach, never push apart:
// - a pair that starts the sub-step closer than h (at a distance d0 in [0, h): it slid in
//   sideways, typically around a sharp crease) is held at d0, not pushed out to h; the same rule
//   as a collider's static fallback (started_inside), which keeps a particle from leaving faster
//   than it came.
// - a triangle whose normal turns by more than 90° within the sub-step is a sliver passing
//   through degeneracy (no real triangle turns over in 0.5 ms), its normal is meaningless and the
//   side carried over would push q through it by up to 2h plus the depth: no contact.
// A point–triangle contact (Müller 2007 §4.4) when, at the prediction, q is less than 2h from the
// triangle's plane on its side (or beyond it) and within h of the triangle sideways. (Edge–edge
// proximity contacts, tried too, only added energy to the soft drape's whip, 10 E0 against 4 E0,
// and cost a fifth more: edges are kept from crossing by the continuous test alone.)
void PbdStepper::generate_self_contacts(const Model& model, const Positions& x, Real h) {
  self_contacts_.clear();
  contact_summary_.self_continuous = 0;
  contact_summary_.self_failsafe = contact_summary_.self_unresolved = 0;
  if (particle_lo_.cols() != p_.cols())
    for (Positions* m : {&particle_lo_, &particle_hi_, &sweep_lo_, &sweep_hi_}) m->resize(3, p_.cols());
  for (SelfGroup& g : self_groups_) {
    const Real hs = g.thickness;
    if (!g.searched || !self_candidates_hold(model, g, x)) find_self_candidates(model, g, x);
    sweep_self_boxes(model, g, x, hs);  // a pair within 2h at the prediction: its widened boxes overlap
    const int parts = in_chunks(g.pt.size(), [&](int part, int parts_count) {
      auto& out = contact_parts_[part];
      out.clear();
      for (std::size_t k = g.pt.size() * part / parts_count; k < g.pt.size() * (part + 1) / parts_count; ++k) {
        const auto [q, t] = g.pt[k];
        if (!boxes_overlap(sweep_lo_.col(q), sweep_hi_.col(q), box_lo_[t], box_hi_[t])) continue;
        const Triangle& tri = model.triangles[g.triangles[t]];
        const Vec3 xq = x.col(q), pq = p_.col(q);
        const Vec3 x1 = x.col(tri[0]);
        Vec3 n0 = (x.col(tri[1]) - x1).cross(x.col(tri[2]) - x1);
        const Vec3 p1 = p_.col(tri[0]);
        Vec3 np = (p_.col(tri[1]) - p1).cross(p_.col(tri[2]) - p1);
        const Real l0 = n0.norm(), lp = np.norm();
        if (!(l0 > 0) || !(lp > 0)) continue;  // a collapsed triangle has no side
        n0 /= l0;
        np /= lp;
        if (!(n0.dot(np) > 0)) continue;  // the triangle flipped: a sliver, no side
        const Real d0 = (xq - x1).dot(n0);
        const Real side = d0 >= 0 ? 1 : -1;
        if (side * (pq - p1).dot(np) >= 2 * hs) continue;
        Vec3 b;
        const Vec3 c = closest_point_on_triangle(pq, p1, p_.col(tri[1]), p_.col(tri[2]), &b);
        const Vec3 off = pq - c;
        if ((off - off.dot(np) * np).norm() > hs) continue;
        out.push_back({PairKind::PointTriangle, false, {q, tri[0], tri[1], tri[2]}, {1, -b[0], -b[1], -b[2]}, np, side,
                       std::min(hs, side * d0)});
        out.back().approach = approach_speed(out.back(), side * np, x, p_, h);
      }
    });
    for (int part = 0; part < parts; ++part)
      self_contacts_.insert(self_contacts_.end(), contact_parts_[part].begin(), contact_parts_[part].end());
  }
  contact_summary_.self_count = static_cast<Index>(self_contacts_.size());
  contact_summary_.self_searches = self_searches_;
  contact_summary_.self_skipped = 0;
  for (const SelfGroup& g : self_groups_) contact_summary_.self_skipped += g.skipped;
}

// The self-contacts' projections in one sweep (with the other contacts, after the constraints).
// C = d·n - thickness with n as SelfContact says; its gradient is taken with n and the weights c
// fixed, ∇_k C = c_k n, so the correction is (Bridson, Fedkiw, Anderson 2002, §7.1)
//   Δp_k = -C w_k c_k n / Σ_j c_j² w_j.
void PbdStepper::project_self_contacts(const Model& model, bool jacobi) {
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  const Real* from = jacobi ? p_start_.data() : p_.data();
  const Real* relax = jacobi && !relax_.empty() ? relax_.data() : nullptr;  // XPBD, averaged Jacobi
  for (SelfContact& k : self_contacts_) {
    const auto& id = k.particles;
    const auto& c = k.weights;
    const Eigen::Map<const Vec3> p0(from + 3 * id[0]), p1(from + 3 * id[1]), p2(from + 3 * id[2]), p3(from + 3 * id[3]);
    Vec3 n;
    if (!contact_normal(k, p1, p2, p3, n)) continue;
    const Real C = (c[0] * p0 + c[1] * p1 + c[2] * p2 + c[3] * p3).dot(n) - k.thickness;
    if (C >= 0) continue;
    const Real denom = contact_inverse_mass(k, w);
    if (!(denom > 0)) continue;
    const Vec3 step = (-C * relaxation(relax, id) / denom) * n;
    k.pushed = true;
    for (int e = 0; e < 4; ++e) {
      const Vec3 dp = (w[id[e]] * c[e]) * step;
      if (jacobi) {
        delta_.col(id[e]) += dp;
        count_[id[e]] += 1;
      } else {
        p_.col(id[e]) += dp;
      }
    }
  }
}

// The pairs of group g whose distance falls to kSeparation of its start along x -> p (additive
// CCD), in the candidates' order, into impacts_. A pair whose swept boxes do not overlap cannot
// meet and is skipped before the test.
void PbdStepper::find_self_impacts(const Model& model, const SelfGroup& g, const Positions& x) {
  impacts_.clear();
  sweep_self_boxes(model, g, x, 0);
  const auto test = [&](PairKind kind, const std::array<Index, 4>& id, std::vector<SelfImpact>& out) {
    std::array<Vec3, 4> x0, dx;
    for (int k = 0; k < 4; ++k) x0[k] = x.col(id[k]), dx[k] = p_.col(id[k]) - x.col(id[k]);
    const Impact hit = additive_ccd(kind, x0, dx, kSeparation, 0);
    if (hit.hit) out.push_back({kind, id, hit.toi});
  };
  const int parts = in_chunks(g.pt.size() + g.ee.size(), [&](int t, int T) {
    auto& pt_out = impact_parts_[2 * t];
    auto& ee_out = impact_parts_[2 * t + 1];
    pt_out.clear();
    ee_out.clear();
    for (std::size_t k = g.pt.size() * t / T; k < g.pt.size() * (t + 1) / T; ++k) {
      const auto [q, tri_index] = g.pt[k];
      if (!boxes_overlap(sweep_lo_.col(q), sweep_hi_.col(q), box_lo_[tri_index], box_hi_[tri_index])) continue;
      const Triangle& tri = model.triangles[g.triangles[tri_index]];
      test(PairKind::PointTriangle, {q, tri[0], tri[1], tri[2]}, pt_out);
    }
    for (std::size_t k = g.ee.size() * t / T; k < g.ee.size() * (t + 1) / T; ++k) {
      const auto [a, b] = g.ee[k];
      if (!boxes_overlap(edge_lo_[a], edge_hi_[a], edge_lo_[b], edge_hi_[b])) continue;
      test(PairKind::EdgeEdge, {g.edges[a][0], g.edges[a][1], g.edges[b][0], g.edges[b][1]}, ee_out);
    }
  });
  // In the candidates' order whatever the number of threads: point-triangle, then edge-edge.
  for (int kind = 0; kind < 2; ++kind)
    for (int t = 0; t < parts; ++t) impacts_.insert(impacts_.end(), impact_parts_[2 * t + kind].begin(), impact_parts_[2 * t + kind].end());
}

// After the sweeps: the continuous test, up to kResponseRounds rounds of continuous contacts
// (each impact a contact along the pair's direction at the time of impact, kept at least at
// min(h, its start distance); then kResponsePasses Gauss-Seidel passes over all self-contacts),
// then the fail-safe for what is left (see the top of this file).
void PbdStepper::resolve_self_collisions(const Model& model, const Positions& x, Real h) {
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  if (stopped_.size() != static_cast<std::size_t>(model.num_particles())) stopped_.assign(model.num_particles(), 0);
  for (SelfGroup& g : self_groups_) {
    for (int round = 0;; ++round) {
      if (!self_candidates_hold(model, g, x)) find_self_candidates(model, g, x);
      find_self_impacts(model, g, x);
      if (impacts_.empty()) break;
      if (round == kResponseRounds) break;
      for (const SelfImpact& m : impacts_) {
        std::array<Vec3, 4> at;  // the pair at the time of impact
        for (int k = 0; k < 4; ++k) at[k] = x.col(m.particles[k]) + m.toi * (p_.col(m.particles[k]) - x.col(m.particles[k]));
        std::array<Real, 4> c;
        if (m.kind == PairKind::PointTriangle) {
          Vec3 b;
          closest_point_on_triangle(at[0], at[1], at[2], at[3], &b);
          c = {1, -b[0], -b[1], -b[2]};
        } else {
          Real u, v;
          segment_segment_distance2(at[0], at[1], at[2], at[3], &u, &v);
          c = {1 - u, u, -(1 - v), -v};
        }
        const auto separation = [&](const std::array<Vec3, 4>& y) { return Vec3(c[0] * y[0] + c[1] * y[1] + c[2] * y[2] + c[3] * y[3]); };
        std::array<Vec3, 4> x0;
        for (int k = 0; k < 4; ++k) x0[k] = x.col(m.particles[k]);
        const Vec3 d_at = separation(at), d_start = separation(x0);
        const Real len = d_at.norm();
        const Vec3 n = len > 0 ? Vec3(d_at / len) : Vec3(d_start.normalized());
        if (!n.allFinite()) continue;  // the features coincide at both times: no direction to push
        self_contacts_.push_back({m.kind, true, m.particles, c, n, 1, std::min(g.thickness, std::sqrt(pair_distance2(m.kind, x0)))});
        self_contacts_.back().approach = approach_speed(self_contacts_.back(), n, x, p_, h);
        ++contact_summary_.self_continuous;
      }
      for (int pass = 0; pass < kResponsePasses; ++pass) project_self_contacts(model, false);
    }
    if (impacts_.empty()) continue;
    // The fail-safe: stop the free particles of every pair still found, until none is.
    std::vector<Index> stopped;
    while (!impacts_.empty()) {
      Index newly = 0;
      for (const SelfImpact& m : impacts_)
        for (const Index i : m.particles)
          if (w[i] > 0 && !stopped_[i]) {
            p_.col(i) = x.col(i);
            stopped_[i] = 1;
            stopped.push_back(i);
            ++newly;
          }
      if (newly == 0) {
        contact_summary_.self_unresolved += static_cast<Index>(impacts_.size());
        break;
      }
      contact_summary_.self_failsafe += newly;
      find_self_impacts(model, g, x);  // p = x stays inside the swept boxes: the candidates hold
    }
    for (const Index i : stopped) stopped_[i] = 0;
  }
  contact_summary_.self_count = static_cast<Index>(self_contacts_.size());
}

// The deepest violation left by the self-contacts at x (m), for the contact summary.
Real PbdStepper::self_penetration(const Positions& x) const {
  Real worst = 0;
  for (const SelfContact& k : self_contacts_) {
    const auto& id = k.particles;
    Vec3 n;
    if (!contact_normal(k, x.col(id[1]), x.col(id[2]), x.col(id[3]), n)) continue;
    worst = std::max(worst, k.thickness - separation(k, [&](Index i) { return Vec3(x.col(i)); }).dot(n));
  }
  return worst;
}

// Self-contacts are inelastic (16): a contact that pushed its pair this sub-step may take away
// its approach but not make it separate. The projection moved the pair by up to its depth, and
// the velocity update turned that into a separating speed depth/h; left so, a one-iteration
// Gauss-Seidel cloth whose hem whips into itself gained energy from its contacts (the soft drape
// of cloth_sphere, sequential sweep: 9.5 E0 at the whip against 3.1 E0 without self-collision).
// With v_n the pair's relative normal speed now (Σ_k c_k v_k · n) and a its approach speed in the
// motion the contact was made from, v_n is brought down to max(a, 0) if above it: the pair leaves
// no faster than it was separating before the contact acted. The change is an impulse along n
// shared by the weights, Δv_k = w_k c_k Δ / Σ_j c_j² w_j, one pass in the contacts' order.
void PbdStepper::settle_self_contact_velocities(const Model& model, State& state, Real h) {
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  const bool verlet = settings_.front_end == FrontEnd::Verlet;
  const auto velocity = [&](Index i) { return verlet ? Vec3((state.x.col(i) - x_prev_.col(i)) / h) : Vec3(state.v.col(i)); };
  for (const SelfContact& k : self_contacts_) {
    if (!k.pushed) continue;
    const auto& id = k.particles;
    const auto& c = k.weights;
    Vec3 n;
    if (!contact_normal(k, state.x.col(id[1]), state.x.col(id[2]), state.x.col(id[3]), n)) continue;
    Real vn = 0;
    for (int e = 0; e < 4; ++e) vn += c[e] * velocity(id[e]).dot(n);
    const Real target = std::max(k.approach, Real(0));
    if (!(vn > target)) continue;
    const Real denom = contact_inverse_mass(k, w);
    if (!(denom > 0)) continue;
    const Vec3 impulse = ((target - vn) / denom) * n;
    for (int e = 0; e < 4; ++e) {
      const Vec3 dv = (w[id[e]] * c[e]) * impulse;
      if (verlet)
        x_prev_.col(id[e]) -= h * dv;
      else
        state.v.col(id[e]) += dv;
    }
  }
}

}  // namespace csb
