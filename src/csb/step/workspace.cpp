// csb — the stepper's per-model workspace: coefficients per constraint (PBD stiffness, XPBD α̃ and
// γ), predicted positions, Jacobi buffers, self-collision groups, the XPBD multipliers.
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/solver/coloured.hpp"

namespace csb {

using detail::str;
using namespace stepper_detail;


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
  family_terms_.resize(model.families.size());
  for (std::size_t f = 0; f < model.families.size(); ++f) stiffness(model.families[f]->stiffness, family_terms_[f].k);
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
    lambda_.family.resize(model.families.size());
    for (std::size_t f = 0; f < model.families.size(); ++f) {
      compliance(model.families[f]->compliance, family_terms_[f].alpha, family_terms_[f].gamma);
      lambda_.family[f].assign(model.families[f]->size(), 0);
    }
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
  // Collisions: the triangles and edges of each self-colliding group, their owners and their
  // hierarchy (self_contacts.cpp); hash cells, for the group's particles in no triangle, of about
  // a feature's widened box, 1.5 times the mean edge plus twice the thickness (Teschner et al.
  // 2003 find a cell near the mean primitive size best).
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
    sg.size = (hi - lo).norm();
    sg.cell = 1.5 * (edges / (3.0 * std::max<std::size_t>(sg.triangles.size(), 1)) + 2 * h_self);
    for (const Index t : sg.triangles)
      for (int e = 0; e < 3; ++e) {
        const Index a = model.triangles[t][e], b = model.triangles[t][(e + 1) % 3];
        sg.edges.push_back({std::min(a, b), std::max(a, b)});
      }
    std::sort(sg.edges.begin(), sg.edges.end());
    sg.edges.erase(std::unique(sg.edges.begin(), sg.edges.end()), sg.edges.end());
    // Owners (the first triangle holding a particle or an edge), for the candidate search.
    {
      const Index T = static_cast<Index>(sg.triangles.size());
      std::vector<Index> particle_owner(n, -1), edge_owner(sg.edges.size(), -1);
      for (Index t = 0; t < T; ++t)
        for (int e = 0; e < 3; ++e) {
          const Index a = model.triangles[sg.triangles[t]][e], b = model.triangles[sg.triangles[t]][(e + 1) % 3];
          if (particle_owner[a] < 0) particle_owner[a] = t;
          const std::array<Index, 2> key{std::min(a, b), std::max(a, b)};
          const auto k = std::lower_bound(sg.edges.begin(), sg.edges.end(), key) - sg.edges.begin();
          if (edge_owner[k] < 0) edge_owner[k] = t;
        }
      sg.owned_particle_start.assign(T + 1, 0);
      sg.owned_edge_start.assign(T + 1, 0);
      for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
        const Index i = model.group_particles[o];
        if (particle_owner[i] >= 0)
          ++sg.owned_particle_start[particle_owner[i] + 1];
        else
          sg.loose.push_back(i);
      }
      for (const Index t : edge_owner) ++sg.owned_edge_start[t + 1];
      for (Index t = 0; t < T; ++t) {
        sg.owned_particle_start[t + 1] += sg.owned_particle_start[t];
        sg.owned_edge_start[t + 1] += sg.owned_edge_start[t];
      }
      sg.owned_particles.resize(sg.owned_particle_start[T]);
      sg.owned_edges.resize(sg.owned_edge_start[T]);
      std::vector<Index> at(sg.owned_particle_start.begin(), sg.owned_particle_start.end() - 1);
      for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
        const Index i = model.group_particles[o];
        if (particle_owner[i] >= 0) sg.owned_particles[at[particle_owner[i]]++] = i;
      }
      at.assign(sg.owned_edge_start.begin(), sg.owned_edge_start.end() - 1);
      for (Index k = 0; k < static_cast<Index>(edge_owner.size()); ++k) sg.owned_edges[at[edge_owner[k]]++] = k;
      // The hierarchy: the triangles split at the median of their rest centroids along the
      // longest side of their box, recursively (ties by index: the same tree on every run).
      std::vector<Vec3> centroid(T);
      for (Index t = 0; t < T; ++t) {
        const Triangle& tri = model.triangles[sg.triangles[t]];
        centroid[t] = (model.rest_positions.col(tri[0]) + model.rest_positions.col(tri[1]) +
                       model.rest_positions.col(tri[2])) / 3;
      }
      std::vector<Index> order(T);
      for (Index t = 0; t < T; ++t) order[t] = t;
      sg.bvh_child.clear();
      sg.bvh_size.clear();
      const auto build = [&](auto&& self, Index begin, Index end) -> Index {
        const Index node = static_cast<Index>(sg.bvh_child.size());
        sg.bvh_child.push_back({-1 - order[begin], -1});
        sg.bvh_size.push_back(end - begin);
        if (end - begin == 1) return node;
        Vec3 lo = centroid[order[begin]], hi = lo;
        for (Index k = begin; k < end; ++k) lo = lo.cwiseMin(centroid[order[k]]), hi = hi.cwiseMax(centroid[order[k]]);
        int axis;
        (hi - lo).maxCoeff(&axis);
        const Index mid = begin + (end - begin) / 2;
        std::nth_element(order.begin() + begin, order.begin() + mid, order.begin() + end, [&](Index u, Index v) {
          return centroid[u][axis] < centroid[v][axis] || (centroid[u][axis] == centroid[v][axis] && u < v);
        });
        const Index left = self(self, begin, mid);
        const Index right = self(self, mid, end);
        sg.bvh_child[node] = {left, right};
        return node;
      };
      if (T > 0) build(build, 0, T);
    }
    most_triangles = std::max({most_triangles, sg.triangles.size(), sg.edges.size()});
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


void PbdStepper::zero_coloured_multipliers(int share, int shares) {
  const auto zero = [share, shares](std::vector<Real>& l) {
    const std::int64_t m = static_cast<std::int64_t>(l.size());
    std::fill(l.begin() + m * share / shares, l.begin() + m * (share + 1) / shares, 0.0);
  };
  for (std::vector<Real>* l : {&coloured_.distance.lambda, &coloured_.bending.lambda, &coloured_.volume.lambda,
                               &coloured_.attachments.lambda, &lambda_.balloon})
    zero(*l);
  for (std::vector<Real>& l : lambda_.family) zero(l);
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
  for (const auto& l : lambda_.family) s += capacity_bytes(l);
  for (const FamilyTerms& t : family_terms_) s += capacity_bytes(t.k) + capacity_bytes(t.alpha) + capacity_bytes(t.gamma);
  s += capacity_bytes(coloured_order_.distance) + capacity_bytes(coloured_order_.bending) +
       capacity_bytes(coloured_order_.volume) + capacity_bytes(coloured_order_.attachment);
  // Self-collision: the groups' features, owners, hierarchy and candidate pairs, the contacts and
  // the boxes.
  for (const SelfGroup& g : self_groups_)
    s += capacity_bytes(g.triangles) + capacity_bytes(g.edges) + capacity_bytes(g.pt) + capacity_bytes(g.ee) +
         capacity_bytes(g.owned_particle_start) + capacity_bytes(g.owned_particles) + capacity_bytes(g.owned_edge_start) +
         capacity_bytes(g.owned_edges) + capacity_bytes(g.loose) + capacity_bytes(g.bvh_child) + capacity_bytes(g.bvh_size);
  s += capacity_bytes(self_contacts_) + capacity_bytes(impacts_) + capacity_bytes(box_lo_) + capacity_bytes(box_hi_) +
       capacity_bytes(edge_lo_) + capacity_bytes(edge_hi_) + capacity_bytes(node_lo_) + capacity_bytes(node_hi_) +
       capacity_bytes(node_pairs_) + capacity_bytes(stopped_) + positions(particle_lo_) + positions(particle_hi_) +
       positions(sweep_lo_) + positions(sweep_hi_);
  for (const auto& v : impact_parts_) s += capacity_bytes(v);
  for (const auto& v : contact_parts_) s += capacity_bytes(v);
  return s + coloured_.bytes();
}

// XPBD: every multiplier set to zero at the start of a sub-step (Macklin 2016, Algorithm 1).
void PbdStepper::reset_multipliers() {
  if (settings_.method != Method::Xpbd) return;
  if (settings_.ordering == Ordering::Coloured) {
    zero_coloured_multipliers(0, 1);
    lambda_stale_ = true;
    return;
  }
  std::fill(lambda_.distance.begin(), lambda_.distance.end(), 0.0);
  std::fill(lambda_.bending.begin(), lambda_.bending.end(), 0.0);
  std::fill(lambda_.volume.begin(), lambda_.volume.end(), 0.0);
  std::fill(lambda_.balloon.begin(), lambda_.balloon.end(), 0.0);
  std::fill(lambda_.attachment.begin(), lambda_.attachment.end(), 0.0);
  for (std::vector<Real>& l : lambda_.family) std::fill(l.begin(), l.end(), 0.0);
}

}  // namespace csb
