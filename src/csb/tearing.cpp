#include "csb/tearing.hpp"
#include "csb/format.hpp"

#include <algorithm>
#include <numeric>

namespace csb {

using detail::str;

namespace {

// Splits particle v of `m` (in place) against the direction towards u; returns false if the
// plane through v leaves all of v's triangles on one side (nothing to split).
bool split_vertex(Model& m, State& s, Index v, Index u) {
  const Vec3 xv = s.x.col(v), dir = s.x.col(u) - xv;
  std::vector<std::size_t> incident;
  std::vector<char> moves(m.triangles.size(), 0);
  for (std::size_t t = 0; t < m.triangles.size(); ++t) {
    const auto& tri = m.triangles[t];
    if (tri[0] != v && tri[1] != v && tri[2] != v) continue;
    incident.push_back(t);
    const Vec3 centroid = (s.x.col(tri[0]) + s.x.col(tri[1]) + s.x.col(tri[2])) / 3;
    moves[t] = (centroid - xv).dot(dir) > 0;
  }
  std::size_t moving = 0;
  for (std::size_t t : incident) moving += moves[t];
  if (moving == 0 || moving == incident.size()) return false;

  // The new particle: same place, motion and rest position; the mass shared equally.
  const Index w = m.num_particles();
  const auto grow = [](Positions& p, const Vec3& col) {
    p.conservativeResize(3, p.cols() + 1);
    p.col(p.cols() - 1) = col;
  };
  grow(m.rest_positions, Vec3(m.rest_positions.col(v)));
  grow(s.x, xv);
  grow(s.v, Vec3(s.v.col(v)));
  m.mass[v] /= 2;
  m.mass.push_back(m.mass[v]);
  m.inv_mass[v] = 1 / m.mass[v];
  m.inv_mass.push_back(m.inv_mass[v]);
  m.group.push_back(m.group[v]);
  m.thickness.push_back(m.thickness[v]);

  // Which side each edge (v, x) of v's triangles is on: bit 1 stays, bit 2 moves.
  const auto sides_of_edge = [&](Index a, Index b) {
    int sides = 0;
    for (std::size_t t : incident) {
      const auto& tri = m.triangles[t];
      const bool has_a = tri[0] == a || tri[1] == a || tri[2] == a;
      const bool has_b = tri[0] == b || tri[1] == b || tri[2] == b;
      if (has_a && has_b) sides |= moves[t] ? 2 : 1;
    }
    return sides;
  };
  // Distance constraints touching v.
  DistanceBatch& d = m.distance;
  const Index nd = d.size();
  for (Index c = 0; c < nd; ++c) {
    auto& e = d.particles[c];
    const int slot = e[0] == v ? 0 : e[1] == v ? 1 : -1;
    if (slot < 0) continue;
    const Index other = e[1 - slot];
    int sides = sides_of_edge(v, other);
    if (sides == 0) sides = (s.x.col(other) - xv).dot(dir) > 0 ? 2 : 1;  // a spring: by its other end
    if (sides == 2) {
      e[slot] = w;
    } else if (sides == 3) {  // on the crack: one copy per side
      auto copy = e;
      copy[slot] = w;
      d.particles.push_back(copy);
      d.rest_length.push_back(d.rest_length[c]);
      d.stiffness.push_back(d.stiffness[c]);
      d.compliance.push_back(d.compliance[c]);
      d.sense.push_back(d.sense[c]);
    }
  }
  // Bending constraints: (a, b) the hinge, c and d the wings of triangles (a, b, c), (a, b, d).
  BendingBatch& bend = m.bending;
  BendingBatch kept;
  const auto triangle_moves = [&](Index a, Index b, Index c) {
    for (std::size_t t : incident) {
      const auto& tri = m.triangles[t];
      int found = 0;
      for (Index q : tri) found += q == a || q == b || q == c;
      if (found == 3) return int(moves[t]);
    }
    return -1;  // not a triangle of v
  };
  for (Index c = 0; c < bend.size(); ++c) {
    auto q = bend.particles[c];
    if (q[0] == v || q[1] == v || q[2] == v || q[3] == v) {
      const int m1 = triangle_moves(q[0], q[1], q[2]), m2 = triangle_moves(q[0], q[1], q[3]);
      const bool on_hinge = q[0] == v || q[1] == v;
      if (on_hinge && m1 != m2) continue;  // the hinge is torn
      for (int k = 0; k < 4; ++k) {
        if (q[k] != v) continue;
        const int moved = k == 2 ? m1 : k == 3 ? m2 : m1;
        if (moved == 1) q[k] = w;
      }
    }
    kept.particles.push_back(q);
    kept.rest_angle.push_back(bend.rest_angle[c]);
    kept.stiffness.push_back(bend.stiffness[c]);
    kept.compliance.push_back(bend.compliance[c]);
  }
  bend = std::move(kept);
  for (std::size_t t : incident)
    if (moves[t])
      for (Index& q : m.triangles[t])
        if (q == v) q = w;
  return true;
}

void rebuild_groups(Model& m) {
  const Index n = m.num_particles(), g = m.num_groups();
  m.group_offsets.assign(g + 1, 0);
  for (Index i = 0; i < n; ++i) ++m.group_offsets[m.group[i] + 1];
  for (Index k = 0; k < g; ++k) m.group_offsets[k + 1] += m.group_offsets[k];
  m.group_particles.resize(n);
  std::vector<Index> cursor(m.group_offsets.begin(), m.group_offsets.end() - 1);
  for (Index i = 0; i < n; ++i) m.group_particles[cursor[m.group[i]]++] = i;
}

}  // namespace

TearResult tear(const Model& model, State& state, Real max_strain, Index max_tears) {
  if (!(max_strain > 0) || !std::isfinite(max_strain))
    throw InvalidArgument("tear: max_strain must be a finite strain > 0, got " + str(max_strain));
  if (max_tears < 1) throw InvalidArgument("tear: max_tears must be >= 1, got " + std::to_string(max_tears));
  if (state.x.cols() != model.num_particles() || state.v.cols() != model.num_particles())
    throw InvalidArgument("tear: the state does not belong to the model");
  // A NaN strain compares false with every threshold: a non-finite state would tear nothing, silently.
  for (Index i = 0; i < state.x.cols(); ++i)
    if (!state.x.col(i).allFinite() || !state.v.col(i).allFinite())
      throw InvalidArgument("tear: particle " + std::to_string(i) + " has a non-finite " +
                            (state.x.col(i).allFinite() ? "velocity" : "position") +
                            "; the state has diverged and cannot be torn (csb.SimulationError is raised by a stepper "
                            "before it gets there)");
  TearResult result;
  result.model = std::shared_ptr<const Model>(std::shared_ptr<const Model>(), &model);  // non-owning until torn
  const DistanceBatch& d = model.distance;
  std::vector<std::pair<Real, Index>> strained;
  for (Index c = 0; c < d.size(); ++c) {
    const Real len = (state.x.col(d.particles[c][0]) - state.x.col(d.particles[c][1])).norm();
    const Real strain = std::abs(len - d.rest_length[c]) / d.rest_length[c];
    if (strain > max_strain) strained.push_back({-strain, c});
  }
  if (strained.empty()) return result;
  std::sort(strained.begin(), strained.end());
  // Particles of tets and balloons cannot be split.
  std::vector<char> solid(model.num_particles(), 0);
  for (const auto& q : model.volume.particles)
    for (Index i : q) solid[i] = 1;
  for (Index i : model.balloons.particles) solid[i] = 1;

  auto torn = std::make_shared<Model>(model);
  std::vector<char> touched(model.num_particles(), 0);
  for (const auto& [negative_strain, c] : strained) {
    if (result.torn >= max_tears) break;
    const Index a = d.particles[c][0], b = d.particles[c][1];
    if (touched[a] || touched[b]) continue;
    // Split the free end with more triangles (the interior one); a pinned end never splits.
    std::vector<Index> ends;
    for (Index i : {a, b})
      if (model.inv_mass[i] > 0) ends.push_back(i);
    if (ends.empty()) continue;
    const auto count = [&](Index i) {
      return std::count_if(model.triangles.begin(), model.triangles.end(),
                           [i](const Triangle& t) { return t[0] == i || t[1] == i || t[2] == i; });
    };
    std::stable_sort(ends.begin(), ends.end(), [&](Index x, Index y) { return count(x) > count(y); });
    for (Index v : ends) {
      if (solid[v])
        throw InvalidArgument("tear: particle " + std::to_string(v) +
                              " belongs to a tetrahedron or a balloon; tearing splits cloth (triangle surfaces) only");
      const Index u = v == a ? b : a;
      if (split_vertex(*torn, state, v, u)) {
        touched[a] = touched[b] = 1;
        result.split.push_back(v);
        ++result.torn;
        break;
      }
    }
  }
  if (result.torn == 0) return result;
  rebuild_groups(*torn);
  colour_batches(*torn);  // constraints were added, dropped and renamed: colour them afresh
  torn->id = next_model_id();
  result.model = torn;
  return result;
}

}  // namespace csb
