// csb — the stepper's coloured batches: the model's batches copied in colour order with their
// per-constraint coefficients precomputed (structure of arrays, solver/coloured.hpp).
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/solver/coloured_bending.hpp"

#include <limits>
#include <string>

namespace csb {

using detail::str;
using namespace stepper_detail;


std::size_t ColouredBatches::bytes() const {
  const auto& d = distance;
  std::size_t s = capacity_bytes(kinematic) + capacity_bytes(count) + capacity_bytes(d.i) + capacity_bytes(d.j) +
                  capacity_bytes(d.rest) + capacity_bytes(d.sense) + capacity_bytes(d.ci) + capacity_bytes(d.cj) +
                  capacity_bytes(d.alpha) + capacity_bytes(d.gamma) + capacity_bytes(d.inv_den) +
                  capacity_bytes(d.lambda) + capacity_bytes(part_run_offsets) + capacity_bytes(part_runs);
  for (const ColouredFour* f : {&bending, &volume})
    s += capacity_bytes(f->q) + capacity_bytes(f->rest) + capacity_bytes(f->w) + capacity_bytes(f->k) +
         capacity_bytes(f->alpha) + capacity_bytes(f->gamma) + capacity_bytes(f->lambda) +
         capacity_bytes(f->pair_rest) + capacity_bytes(f->pair_ca) + capacity_bytes(f->pair_cb) +
         capacity_bytes(f->pair_alpha) + capacity_bytes(f->pair_gamma) + capacity_bytes(f->pair_inv_den) +
         capacity_bytes(f->pair_lambda);
  const Colouring& dc = distance_colours;
  s += capacity_bytes(dc.order) + capacity_bytes(dc.colour_offsets) + capacity_bytes(dc.serial_colours) +
       capacity_bytes(dc.group_colours);
  const auto& a = attachments;
  s += capacity_bytes(a.i) + capacity_bytes(a.target) + capacity_bytes(a.w) + capacity_bytes(a.k) +
       capacity_bytes(a.alpha) + capacity_bytes(a.gamma) + capacity_bytes(a.lambda);
  return s;
}


void PbdStepper::build_coloured(const Model& model, const Real* w) {
  // The batches hold particle offsets (ColouredDistanceT::i), kStride<float> = 4 times an index.
  if (model.num_particles() > kMostColouredParticles)
    throw InvalidArgument("the model has " + std::to_string(model.num_particles()) +
                          " particles; the coloured solver addresses at most " +
                          std::to_string(kMostColouredParticles));
  ColouredBatches& cb = coloured_;
  const bool xpbd = settings_.method == Method::Xpbd;
  const auto fill = [xpbd](std::vector<Real>& out, const std::vector<Real>& from, const std::vector<Index>& order) {
    out.clear();
    if (!xpbd) return;
    out.resize(order.size());
    for (std::size_t c = 0; c < order.size(); ++c) out[c] = from[order[c]];
  };
  // Gauss-Seidel (PBD and Jakobsen with the exact square root, and XPBD): each bending element
  // (a, b, c, d) takes the distance constraint on its edge (a, b), when there is one (bilateral,
  // not yet taken by another element; elements in colour order): one kernel projects it and then
  // the bending constraint, four particles moved in and out once instead of six. (Another
  // Gauss-Seidel order: within a bending colour, its elements' edges, then its bending
  // constraints.)
  const DistanceBatch& db = model.distance;
  const BendingBatch& bb = model.bending;
  // PBD's shares of distance constraint o's correction for its particles i and j: k w / Σw.
  const auto pbd_shares = [&](Index o) -> std::array<Real, 2> {
    const Index i = db.particles[o][0], j = db.particles[o][1];
    const Real wsum = w[i] + w[j];
    return {wsum > 0 ? k_distance_[o] * w[i] / wsum : 0, wsum > 0 ? k_distance_[o] * w[j] / wsum : 0};
  };
  const bool pairs = settings_.solver == Solver::GaussSeidel && (xpbd || !settings_.sqrt_approximation) &&
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
    d.damped = any_damping(d.gamma);
    d.lambda.assign(xpbd ? m : 0, 0);
    d.bilateral = true;
    for (std::size_t c = 0; c < m; ++c) {
      const Index o = order[c], i = b.particles[o][0], j = b.particles[o][1];
      const Real wsum = w[i] + w[j];
      d.i[c] = kStride<Real> * i;
      d.j[c] = kStride<Real> * j;
      d.rest[c] = b.rest_length[o];
      d.sense[c] = b.sense[o];
      d.bilateral = d.bilateral && b.sense[o] == 0;
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
    f.damped = any_damping(f.gamma);
    f.lambda.assign(xpbd ? m : 0, 0);
    for (std::size_t c = 0; c < m; ++c) {
      const Index o = order[c];
      for (int s = 0; s < 4; ++s) f.q[c][s] = kStride<Real> * particles[o][s];
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
    // XPBD's shares are the inverse masses of a and b, which the kernel has (ColouredFour::w)
    f.pair_ca.assign(xpbd ? 0 : m, 0);
    f.pair_cb.assign(xpbd ? 0 : m, 0);
    f.pair_alpha.assign(xpbd ? m : 0, 0);
    f.pair_gamma.assign(xpbd ? m : 0, 0);
    f.pair_inv_den.assign(xpbd ? m : 0, 0);
    f.pair_lambda.assign(xpbd ? m : 0, 0);
    for (std::size_t c = 0; c < m; ++c) {
      const Index o = pair_of[c];
      if (o < 0) continue;
      const Index i = db.particles[o][0], j = db.particles[o][1];
      const auto [ci, cj] = xpbd ? std::array<Real, 2>{w[i], w[j]} : pbd_shares(o);
      if (xpbd) {
        const Real wsum = w[i] + w[j];
        f.pair_alpha[c] = a_distance_[o];
        f.pair_gamma[c] = g_distance_[o];
        f.pair_inv_den[c] = wsum > 0 ? 1 / ((1 + f.pair_gamma[c]) * wsum + f.pair_alpha[c]) : 0;
      }
      // the kernel takes d = a - b: PBD Δa = -ca s d, Δb = +cb s d, XPBD Δa = +ca Δλ n,
      // Δb = -cb Δλ n with n = d/|d| (the constraint's own orientation, d = p_i - p_j, gives
      // the same values: d, n and the damping's relative motion change sign exactly)
      const bool forward = kStride<Real> * db.particles[o][0] == f.q[c][0];
      f.pair_rest[c] = db.rest_length[o];
      if (!xpbd) {
        f.pair_ca[c] = forward ? ci : cj;
        f.pair_cb[c] = forward ? cj : ci;
      }
    }
    f.damped = f.damped || any_damping(f.pair_gamma);
    f.k_same = same_copies(f.k, kBendingBlock);  // a block's worth: the kernels read them per block
    f.alpha_same = same_copies(f.alpha, kBendingBlock);
    f.pair_alpha_same = same_copies(f.pair_alpha, kBendingBlock);
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
    coloured_order_.distance_paired = pairs ? pair_of : std::vector<Index>{};
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
  if (settings_.precision == Precision::Single) {  // the float batches; the double ones are not projected
    single_.distance = narrowed<float>(cb.distance);
    single_.bending = narrowed<float>(cb.bending);
    cb.distance = {};
    cb.bending = {};
    // What a prediction adds, h g (Verlet: h² g), 0 where w = 0: fixed for the model.
    const Real h = substep_size(), step = settings_.front_end == FrontEnd::Verlet ? h * h : h;
    single_.w.resize(static_cast<std::size_t>(model.num_particles()));
    for (Index i = 0; i < model.num_particles(); ++i) {
      for (int e = 0; e < 3; ++e)
        single_.accel[kStride<float> * i + e] = static_cast<float>(w[i] > 0 ? step * settings_.gravity[e] : 0);
      single_.w[i] = static_cast<float>(w[i]);  // as narrowed rounds the bending batch's w
    }
  }
  cb.model_id = model.id;
}

}  // namespace csb
