// csb — the stepper's per-model workspace: coefficients per constraint (PBD stiffness, XPBD α̃ and
// γ), predicted positions, Jacobi buffers, self-collision groups, the XPBD multipliers.
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/solver/coloured.hpp"

#include <algorithm>

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
  // The predictions in the solver's precision: the double p_, or (float32) the float rows the
  // single-precision sub-steps project; the other is empty.
  const bool single = settings_.precision == Precision::Single;
  p_.resize(3, single ? 0 : n);
  for (std::vector<float>* b : {&single_.x, &single_.v, &single_.p, &single_.accel})
    b->assign(single ? kStride<float> * static_cast<std::size_t>(n) : 0, 0.0f);
  if (settings_.front_end == FrontEnd::Verlet) x_prev_.resize(3, n);
  Index largest_balloon = 0;
  for (Index b = 0; b < model.balloons.size(); ++b) largest_balloon = std::max(largest_balloon, model.balloons.num_particles(b));
  balloon_grad_.resize(largest_balloon);
  if (settings_.solver != Solver::GaussSeidel) {
    p_start_.resize(3, n);
    delta_.resize(3, n);
    count_.resize(n);
  }
  self_.prepare(model);
  std::size_t most_triangles = 0;
  for (const Collider& c : model.colliders)
    if (c.mesh) most_triangles = std::max(most_triangles, c.mesh->triangles.size());
  stamps_.assign(most_triangles, 0);
  stamp_ = 0;
  contacts_.clear();
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


void PbdStepper::zero_coloured_multipliers(int share, int shares, bool all) {
  for (std::vector<Real>* l : {&coloured_.volume.lambda, &coloured_.attachments.lambda, &lambda_.balloon})
    zero_share(*l, share, shares);
  if (all)
    for (std::vector<Real>* l : {&coloured_.distance.lambda, &coloured_.bending.lambda, &coloured_.bending.pair_lambda})
      zero_share(*l, share, shares);
  for (std::vector<Real>& l : lambda_.family) zero_share(l, share, shares);
}


const Multipliers& PbdStepper::multipliers() const {
  if (lambda_stale_) {
    // The coloured batches keep their multipliers in colour order; put them in the model's.
    // (Precision::Single: the distance and bending batches' are floats, widened.)
    const auto scatter = [](std::vector<Real>& out, std::size_t size, const auto& in, const std::vector<Index>& order) {
      out.resize(size);
      for (std::size_t c = 0; c < in.size(); ++c)
        if (order[c] >= 0) out[order[c]] = in[c];
    };
    // The distance constraints projected on their own, and those projected with a bending
    // element (at the element's position; -1 where it has none).
    const auto distance_bending = [&](const auto& distance, const auto& bending) {
      const std::vector<Index>& paired = coloured_order_.distance_paired;
      const std::size_t distances = distance.lambda.size() +
          static_cast<std::size_t>(std::count_if(paired.begin(), paired.end(), [](Index o) { return o >= 0; }));
      scatter(lambda_.distance, distances, distance.lambda, coloured_order_.distance);
      if (!paired.empty()) scatter(lambda_.distance, distances, bending.pair_lambda, paired);
      scatter(lambda_.bending, bending.lambda.size(), bending.lambda, coloured_order_.bending);
    };
    if (settings_.precision == Precision::Single)
      distance_bending(single_.distance, single_.bending);
    else
      distance_bending(coloured_.distance, coloured_.bending);
    scatter(lambda_.volume, coloured_.volume.lambda.size(), coloured_.volume.lambda, coloured_order_.volume);
    scatter(lambda_.attachment, coloured_.attachments.lambda.size(), coloured_.attachments.lambda,
            coloured_order_.attachment);
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
  s += capacity_bytes(coloured_order_.distance) + capacity_bytes(coloured_order_.distance_paired) +
       capacity_bytes(coloured_order_.bending) + capacity_bytes(coloured_order_.volume) +
       capacity_bytes(coloured_order_.attachment);
  const auto& sd = single_.distance;
  const auto& sb = single_.bending;
  for (const auto* v : {&single_.x, &single_.v, &single_.p, &single_.accel, &sd.rest, &sd.ci, &sd.cj, &sd.alpha,
                        &sd.gamma, &sd.inv_den, &sd.lambda, &sb.rest, &sb.k, &sb.alpha, &sb.gamma, &sb.lambda,
                        &sb.pair_rest, &sb.pair_ca, &sb.pair_cb, &sb.pair_alpha, &sb.pair_gamma, &sb.pair_inv_den,
                        &sb.pair_lambda})
    s += capacity_bytes(*v);
  s += capacity_bytes(sd.i) + capacity_bytes(sd.j) + capacity_bytes(sd.sense) + capacity_bytes(sb.q) +
       capacity_bytes(sb.w);
  s += self_.bytes();  // self-collision's groups, candidate pairs, contacts and boxes
  // Deforming mesh colliders: each one's vertices (last, next, sub-step, step end) and swept grid.
  for (const ColliderMotion& m : collider_motion_) {
    const DeformingMesh& d = m.deform;
    s += positions(d.from) + positions(d.to) + positions(d.start) + positions(d.end) + positions(d.step_end) +
         capacity_bytes(d.grid.cell_start) + capacity_bytes(d.grid.items);
  }
  s += capacity_bytes(deform_lo_) + capacity_bytes(deform_hi_);
  return s + coloured_.bytes();
}

// XPBD: every multiplier set to zero at the start of a sub-step (Macklin 2016, Algorithm 1).
void PbdStepper::reset_multipliers() {
  if (settings_.method != Method::Xpbd) return;
  if (settings_.ordering == Ordering::Coloured) {
    zero_coloured_multipliers(0, 1, true);
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
