// csb — tethers: long range attachments of free particles to pinned ones (Kim, Chentanez and
// Müller 2012, "Long Range Attachments — A Method to Simulate Inextensible Clothing in Computer
// Games", SCA 2012; the LRA constraints of Jolt's soft bodies).
//
// A cloth held at a few pinned particles stretches under its own weight when a Gauss-Seidel sweep
// of its edges cannot carry the correction from the pins to the far end in the iterations it has:
// each sweep moves a correction about one edge along, so an n-edge-long cloth needs about n
// iterations. A tether joins every free particle i directly to a pinned particle a and bounds
// their distance by the farthest the cloth could take i from a at its rest lengths:
//
//   C(x_i, x_a) = |x_i - x_a| - L  <= 0                (unilateral: a slack tether is satisfied)
//   ∇_i C = n = (x_i - x_a)/|x_i - x_a|,   ∇_a C = -n
//   ∇²_ii C = ∇²_aa C = -∇²_ia C = (I - n nᵀ)/|x_i - x_a|
//
// With w_a = 0 the projection moves i alone, straight back within reach of its anchor: one
// projection of stiffness 1 satisfies it, whatever the length of the cloth between them.
//
// The rest length L = max_stretch × the rest distance of i from a:
//   Euclidean  |X_i - X_a| in the rest positions (the paper's), the tightest bound for a cloth
//              whose rest shape is flat or convex between i and a;
//   geodesic   the shortest path from a to i through the distance constraints (Dijkstra, each
//              edge weighted by its rest length): for a rest shape folded, curved around a body or
//              cut between i and a, where the Euclidean distance is shorter than the material
//              between them and a Euclidean tether would forbid the cloth unfolding. On a
//              triangulated grid this path is the grid's own metric, up to 8 % longer than the
//              straight line in directions between the grid's and its diagonals' (22.5°).
// Only distance constraints that bound a length (sense 0 or -1) are paths; particles not joined
// to any pinned particle by them get no tether.
//
// Which anchors: Kim et al. attach a particle to the attachment points; csb tethers each free
// particle to its `anchors` nearest pinned particles (in the mode's distance, among those its
// distance constraints reach). The default, 1, is Jolt's and Unreal's choice: the nearest anchor's
// tether is the one that binds first as the cloth falls away from its pins, and one tether a
// particle costs one projection a particle a sweep; more anchors bound sideways swings too
// (a large `anchors` is every reachable pinned particle) at anchors projections a particle.
#pragma once

#include "csb/constraints/family.hpp"
#include "csb/format.hpp"
#include "csb/memory_budget.hpp"
#include "csb/model.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <queue>
#include <tuple>

namespace csb {

struct Tether {
  static constexpr const char* name = "tethers";
  static constexpr const char* label = "tether";
  static constexpr int arity = 2;  // (the free particle i, its anchor a)
  static constexpr bool unilateral = true;
  static constexpr const char* compliance_unit = "m/N";
  struct Params {
    Real rest_length;  // L, m
  };
  static constexpr std::array<const char*, 1> param_names{{"rest_length"}};
  static constexpr std::array<const char*, 1> param_units{{"m"}};

  static std::string check(const Params& p) {
    if (!(p.rest_length >= 0) || !std::isfinite(p.rest_length))
      return "rest_length must be a finite length >= 0 m, got " + detail::str(p.rest_length);
    return "";
  }
  static bool evaluate(const Vec3 x[2], const Params& p, Real& c, Vec3 g[2]) {
    const Vec3 d = x[0] - x[1];
    const Real len = d.norm();
    c = len - p.rest_length;
    if (!(len > 0)) return false;  // coincident: no direction
    g[0] = d / len;
    g[1] = -g[0];
    return true;
  }
  static void hessian(const Vec3 x[2], const Params&, Mat3 h[2][2]) {
    const Vec3 d = x[0] - x[1];
    const Real len = d.norm();
    if (!(len > 0)) {
      for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) h[i][j].setZero();
      return;
    }
    const Vec3 n = d / len;
    const Mat3 p = (Mat3::Identity() - n * n.transpose()) / len;
    h[0][0] = h[1][1] = p;
    h[0][1] = h[1][0] = -p;
  }
};

enum class TetherMode { Euclidean, Geodesic };

struct TetherOptions {
  TetherMode mode = TetherMode::Geodesic;
  Real max_stretch = 1;  // L = max_stretch × the rest distance; a finite factor >= 1
  Real stiffness = 1;    // dimensionless, in [0, 1] (PBD, Jakobsen)
  Real compliance = 0;   // m/N, >= 0 (XPBD, the references); 0: hard
  Index anchors = 1;     // nearest pinned particles each free particle is tethered to; >= 1
};

// Tethers every free particle of the builder to its `anchors` nearest pinned particles (see the
// top of this file), with the pins and distance constraints added so far. Returns how many it
// added. Throws InvalidArgument naming the parameter for max_stretch < 1 or not finite, anchors
// < 1, a stiffness outside [0, 1] or a negative compliance; when no particle is pinned; and when
// no free particle is joined to a pinned one by distance constraints.
inline Index add_tethers(ModelBuilder& builder, const TetherOptions& o) {
  using detail::str;
  if (!(o.max_stretch >= 1) || !std::isfinite(o.max_stretch))
    throw InvalidArgument("add_tethers: max_stretch must be a finite factor >= 1 (1: the rest distance), got " +
                          str(o.max_stretch));
  if (o.anchors < 1) throw InvalidArgument("add_tethers: anchors must be >= 1, got " + std::to_string(o.anchors));
  if (!(o.stiffness >= 0 && o.stiffness <= 1))
    throw InvalidArgument("add_tethers: stiffness must be in [0, 1], got " + str(o.stiffness));
  if (!(o.compliance >= 0) || !std::isfinite(o.compliance))
    throw InvalidArgument("add_tethers: compliance must be a finite number >= 0 m/N (0: hard), got " + str(o.compliance));
  const Index n = builder.num_particles();
  std::vector<Index> pins;
  for (Index i = 0; i < n; ++i)
    if (builder.pinned(i)) pins.push_back(i);
  if (pins.empty())
    throw InvalidArgument("add_tethers: the model has no pinned particles; a tether holds a free particle within "
                          "reach of a pinned one (pin some first)");
  // The distance constraints that bound a length, as a graph (CSR, both directions).
  const DistanceBatch& d = builder.distance_constraints();
  std::vector<Index> start(static_cast<std::size_t>(n) + 1, 0);
  for (Index c = 0; c < d.size(); ++c)
    if (d.sense[c] <= 0) ++start[d.particles[c][0] + 1], ++start[d.particles[c][1] + 1];
  for (Index i = 0; i < n; ++i) start[i + 1] += start[i];
  std::vector<std::pair<Index, Real>> edges(static_cast<std::size_t>(start[n]));
  {
    std::vector<Index> at(start.begin(), start.end() - 1);
    for (Index c = 0; c < d.size(); ++c) {
      if (d.sense[c] > 0) continue;
      const Index i = d.particles[c][0], j = d.particles[c][1];
      edges[at[i]++] = {j, d.rest_length[c]};
      edges[at[j]++] = {i, d.rest_length[c]};
    }
  }
  const std::size_t k = static_cast<std::size_t>(std::min<Index>(o.anchors, static_cast<Index>(pins.size())));
  // nearest[i]: (distance, anchor) of particle i's k nearest pinned particles, nearest first.
  std::vector<std::vector<std::pair<Real, Index>>> nearest(static_cast<std::size_t>(n));
  if (o.mode == TetherMode::Geodesic) {
    // Dijkstra from every pin at once, each particle settled by at most k distinct pins: a pin
    // among a particle's k nearest is among the k nearest of every particle on the path between
    // them, so the search finds them all. Ties go to the lower pin index, then particle index.
    using Item = std::tuple<Real, Index, Index>;  // (distance, pin, particle)
    std::priority_queue<Item, std::vector<Item>, std::greater<Item>> queue;
    for (Index a : pins) queue.push({0, a, a});
    const auto has = [&](Index v, Index a) {
      for (const auto& e : nearest[v])
        if (e.second == a) return true;
      return false;
    };
    while (!queue.empty()) {
      const auto [dist, a, v] = queue.top();
      queue.pop();
      if (nearest[v].size() >= k || has(v, a)) continue;
      nearest[v].push_back({dist, a});
      for (Index e = start[v]; e < start[v + 1]; ++e) {
        const Index u = edges[e].first;
        if (nearest[u].size() < k && !has(u, a)) queue.push({dist + edges[e].second, a, u});
      }
    }
  } else {
    // The pins each particle's distance constraints reach (connected components), nearest by the
    // straight line in the rest positions.
    std::vector<Index> root(static_cast<std::size_t>(n));
    std::iota(root.begin(), root.end(), 0);
    const auto find = [&](Index i) {
      while (root[i] != i) i = root[i] = root[root[i]];
      return i;
    };
    for (Index i = 0; i < n; ++i)
      for (Index e = start[i]; e < start[i + 1]; ++e) root[find(i)] = find(edges[e].first);
    std::vector<std::vector<Index>> pins_of(static_cast<std::size_t>(n));
    for (Index a : pins) pins_of[find(a)].push_back(a);
    for (Index i = 0; i < n; ++i) {
      if (builder.pinned(i)) continue;
      auto& near = nearest[i];
      for (Index a : pins_of[find(i)]) near.push_back({(builder.position(i) - builder.position(a)).norm(), a});
      const std::size_t keep = std::min(k, near.size());
      std::partial_sort(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(keep), near.end());
      near.resize(keep);
    }
  }
  double count = 0;
  for (Index i = 0; i < n; ++i)
    if (!builder.pinned(i)) count += static_cast<double>(nearest[i].size());
  if (count == 0)
    throw InvalidArgument("add_tethers: no free particle is joined to a pinned particle by distance constraints "
                          "(tethers follow the stretch constraints: add the meshes with their stretch first)");
  // A tether holds about 64 B in the model and the stepper's workspace.
  const double have = physical_memory_bytes();
  if (have > 0 && count * 64 > have)
    throw InvalidArgument("add_tethers: " + str(count) + " tethers (anchors = " + std::to_string(o.anchors) +
                          ") would need about " + str(count * 64 / 1e9) + " GB, more than this machine's " +
                          str(have / 1e9) + " GB of memory; ask for fewer anchors");
  Index added = 0;
  for (Index i = 0; i < n; ++i) {
    if (builder.pinned(i)) continue;
    for (const auto& [dist, a] : nearest[i]) {
      const Real rest = o.max_stretch * dist;
      builder.add_constraint(Tether::name, {i, a}, {rest}, o.stiffness, o.compliance);
      ++added;
    }
  }
  return added;
}

}  // namespace csb
