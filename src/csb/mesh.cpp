#include "csb/mesh.hpp"
#include "csb/format.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <unordered_map>

namespace csb {

using detail::str;

namespace {


struct CellKey {
  std::int64_t x, y, z;
  bool operator==(const CellKey& o) const { return x == o.x && y == o.y && z == o.z; }
};
struct CellHash {
  std::size_t operator()(const CellKey& k) const {
    // Teschner et al. 2003 spatial hash primes.
    return static_cast<std::size_t>(k.x * 73856093LL ^ k.y * 19349663LL ^ k.z * 83492791LL);
  }
};

std::int64_t cell_coord(Real v, Real cell) {
  const Real c = std::floor(v / cell);
  constexpr Real limit = 4.0e18;
  return static_cast<std::int64_t>(std::clamp(c, -limit, limit));
}

// Representative (output) vertex for every input vertex; deterministic: vertices are visited in
// order and each joins the lowest-numbered representative within the tolerance.
std::vector<Index> weld_map(const Positions& x, Real tol, Index* num_reps) {
  const Index n = static_cast<Index>(x.cols());
  std::vector<Index> rep(n, -1);
  std::vector<Index> reps;  // input index of each representative
  if (tol <= 0) {
    // Exact weld: identical coordinates only.
    struct PosHash {
      std::size_t operator()(const Vec3& v) const {
        std::size_t h = 0;
        for (int k = 0; k < 3; ++k) h = h * 1000003u ^ std::hash<Real>()(v[k] + 0.0);
        return h;
      }
    };
    struct PosEq {
      bool operator()(const Vec3& a, const Vec3& b) const { return a == b; }
    };
    std::unordered_map<Vec3, Index, PosHash, PosEq> seen;
    for (Index i = 0; i < n; ++i) {
      auto [it, inserted] = seen.emplace(x.col(i), static_cast<Index>(reps.size()));
      if (inserted) reps.push_back(i);
      rep[i] = it->second;
    }
  } else {
    std::unordered_map<CellKey, std::vector<Index>, CellHash> grid;
    const Real tol2 = tol * tol;
    for (Index i = 0; i < n; ++i) {
      const Vec3 p = x.col(i);
      const CellKey c{cell_coord(p.x(), tol), cell_coord(p.y(), tol), cell_coord(p.z(), tol)};
      Index best = -1;
      for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dz = -1; dz <= 1; ++dz) {
            auto it = grid.find(CellKey{c.x + dx, c.y + dy, c.z + dz});
            if (it == grid.end()) continue;
            for (Index r : it->second)
              if ((x.col(reps[r]) - p).squaredNorm() <= tol2 && (best < 0 || r < best)) best = r;
          }
      if (best < 0) {
        best = static_cast<Index>(reps.size());
        reps.push_back(i);
        grid[c].push_back(best);
      }
      rep[i] = best;
    }
  }
  *num_reps = static_cast<Index>(reps.size());
  return rep;
}

std::string first_items(const std::vector<Index>& items, std::size_t max_items = 5) {
  std::ostringstream s;
  for (std::size_t k = 0; k < items.size() && k < max_items; ++k) s << (k ? ", " : "") << items[k];
  if (items.size() > max_items) s << ", ...";
  return s.str();
}

}  // namespace

Real bounding_box_diagonal(const Positions& x) {
  if (x.cols() == 0) return 0;
  return (x.rowwise().maxCoeff() - x.rowwise().minCoeff()).norm();
}

void validate(const Mesh& mesh) {
  const Index n = mesh.num_vertices();
  if (n == 0) throw MeshError(mesh.name + ": the mesh has no vertices");
  for (Index i = 0; i < n; ++i)
    if (!mesh.vertices.col(i).allFinite())
      throw MeshError(mesh.name + ": vertex " + std::to_string(i) + " has a non-finite coordinate " +
                      str(mesh.vertices.col(i)));
  if (mesh.triangles.empty() && mesh.lines.empty())
    throw MeshError(mesh.name + ": the mesh has no triangles (and no line segments)");
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    for (Index v : mesh.triangles[t])
      if (v < 0 || v >= n)
        throw MeshError(mesh.name + ": triangle " + std::to_string(t) + " refers to vertex " + std::to_string(v) +
                        ", but the mesh has " + std::to_string(n) + " vertices (0 to " + std::to_string(n - 1) + ")");
  for (std::size_t l = 0; l < mesh.lines.size(); ++l)
    for (Index v : mesh.lines[l])
      if (v < 0 || v >= n)
        throw MeshError(mesh.name + ": line " + std::to_string(l) + " refers to vertex " + std::to_string(v) +
                        ", but the mesh has " + std::to_string(n) + " vertices (0 to " + std::to_string(n - 1) + ")");
}

Mesh clean(const Mesh& mesh, const CleanOptions& options, MeshReport* report_out) {
  validate(mesh);
  if (!(options.weld_tolerance >= 0) || !std::isfinite(options.weld_tolerance))
    throw InvalidArgument(mesh.name + ": weld_tolerance must be a finite number >= 0, got " +
                          std::to_string(options.weld_tolerance));
  MeshReport report;
  const Index n = mesh.num_vertices();
  report.input_vertices = n;
  report.input_triangles = static_cast<Index>(mesh.triangles.size());
  report.input_lines = static_cast<Index>(mesh.lines.size());

  // 1. Weld.
  std::vector<Index> rep(n);
  Index num_reps = n;
  if (options.weld) {
    rep = weld_map(mesh.vertices, options.weld_tolerance * bounding_box_diagonal(mesh.vertices), &num_reps);
  } else {
    for (Index i = 0; i < n; ++i) rep[i] = i;
  }
  report.welded_vertices = n - num_reps;
  // Position of each representative: that of its first input vertex.
  std::vector<Index> rep_source(num_reps, -1);
  for (Index i = 0; i < n; ++i)
    if (rep_source[rep[i]] < 0) rep_source[rep[i]] = i;

  // 2. Drop degenerate triangles and lines.
  std::vector<Triangle> tris;
  std::vector<Index> dropped_tris;
  tris.reserve(mesh.triangles.size());
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const Triangle in = mesh.triangles[t];
    const Triangle r{rep[in[0]], rep[in[1]], rep[in[2]]};
    bool degenerate = r[0] == r[1] || r[1] == r[2] || r[0] == r[2];
    if (!degenerate) {
      const Vec3 a = mesh.vertices.col(rep_source[r[0]]), b = mesh.vertices.col(rep_source[r[1]]),
                 c = mesh.vertices.col(rep_source[r[2]]);
      const Real longest2 = std::max({(b - a).squaredNorm(), (c - b).squaredNorm(), (a - c).squaredNorm()});
      degenerate = (b - a).cross(c - a).norm() <= kDegenerateArea * longest2;
    }
    if (degenerate)
      dropped_tris.push_back(static_cast<Index>(t));
    else
      tris.push_back(r);
  }
  std::vector<Edge> lines;
  std::vector<Index> dropped_lines;
  for (std::size_t l = 0; l < mesh.lines.size(); ++l) {
    const Edge r{rep[mesh.lines[l][0]], rep[mesh.lines[l][1]]};
    if (r[0] == r[1])
      dropped_lines.push_back(static_cast<Index>(l));
    else
      lines.push_back(r);
  }
  report.degenerate_triangles = static_cast<Index>(dropped_tris.size());
  report.degenerate_lines = static_cast<Index>(dropped_lines.size());
  if (!dropped_tris.empty())
    report.warnings.push_back(mesh.name + ": dropped " + std::to_string(dropped_tris.size()) +
                              " degenerate triangle(s) (zero area or a repeated vertex after welding): " +
                              first_items(dropped_tris));
  if (!dropped_lines.empty())
    report.warnings.push_back(mesh.name + ": dropped " + std::to_string(dropped_lines.size()) +
                              " zero-length line segment(s): " + first_items(dropped_lines));
  if (tris.empty() && lines.empty())
    throw MeshError(mesh.name + ": no usable triangles are left: all " + std::to_string(mesh.triangles.size()) +
                    " triangles are degenerate (zero area or zero-length edges)");

  // 3. Number the output vertices in order of first appearance among the representatives.
  std::vector<char> used(num_reps, options.drop_unreferenced ? 0 : 1);
  for (const auto& t : tris)
    for (Index v : t) used[v] = 1;
  for (const auto& l : lines)
    for (Index v : l) used[v] = 1;
  std::vector<Index> out_index(num_reps, -1);
  Index m = 0;
  for (Index r = 0; r < num_reps; ++r)
    if (used[r]) out_index[r] = m++;
  report.unreferenced_vertices = num_reps - m;
  if (report.unreferenced_vertices > 0)
    report.warnings.push_back(mesh.name + ": dropped " + std::to_string(report.unreferenced_vertices) +
                              " vertex/vertices that no triangle or line uses");

  Mesh out;
  out.name = mesh.name;
  out.vertices.resize(3, m);
  for (Index r = 0; r < num_reps; ++r)
    if (out_index[r] >= 0) out.vertices.col(out_index[r]) = mesh.vertices.col(rep_source[r]);
  out.triangles.reserve(tris.size());
  for (const auto& t : tris) out.triangles.push_back({out_index[t[0]], out_index[t[1]], out_index[t[2]]});
  for (const auto& l : lines) out.lines.push_back({out_index[l[0]], out_index[l[1]]});
  report.vertex_map.resize(n);
  for (Index i = 0; i < n; ++i) report.vertex_map[i] = out_index[rep[i]];

  const Topology topo = topology(out);
  report.boundary_edges = topo.boundary_edges;
  report.non_manifold_edges = topo.non_manifold_edges;
  if (topo.non_manifold_edges > 0)
    report.warnings.push_back(mesh.name + ": " + std::to_string(topo.non_manifold_edges) +
                              " non-manifold edge(s) (shared by more than two triangles) get a distance "
                              "constraint but no bending constraint");
  if (report_out) *report_out = std::move(report);
  return out;
}

void vertex_normals(const Positions& x, const std::vector<Triangle>& triangles, Positions& normals) {
  normals.setZero(3, x.cols());
  for (const Triangle& t : triangles) {
    const Vec3 a = x.col(t[0]);
    const Vec3 n = (x.col(t[1]) - a).cross(x.col(t[2]) - a);
    for (const Index i : t) normals.col(i) += n;
  }
  for (Eigen::Index i = 0; i < normals.cols(); ++i) {
    const Real length = normals.col(i).norm();
    if (length > 0) normals.col(i) /= length;
  }
}

Topology topology(const Mesh& mesh) {
  struct HalfEdge {
    Index a, b, opposite;  // a < b; opposite = -1 for an explicit line
  };
  std::vector<HalfEdge> half;
  half.reserve(3 * mesh.triangles.size() + mesh.lines.size());
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) {
      const Index u = t[k], v = t[(k + 1) % 3];
      half.push_back({std::min(u, v), std::max(u, v), t[(k + 2) % 3]});
    }
  for (const auto& l : mesh.lines) half.push_back({std::min(l[0], l[1]), std::max(l[0], l[1]), -1});
  std::sort(half.begin(), half.end(), [](const HalfEdge& p, const HalfEdge& q) {
    return std::tie(p.a, p.b, p.opposite) < std::tie(q.a, q.b, q.opposite);
  });

  Topology topo;
  for (std::size_t i = 0; i < half.size();) {
    std::size_t j = i;
    std::vector<Index> opposite;
    while (j < half.size() && half[j].a == half[i].a && half[j].b == half[i].b) {
      if (half[j].opposite >= 0) opposite.push_back(half[j].opposite);
      ++j;
    }
    topo.edges.push_back({half[i].a, half[i].b});
    if (opposite.size() == 1) ++topo.boundary_edges;
    if (opposite.size() > 2) ++topo.non_manifold_edges;
    if (opposite.size() == 2 && opposite[0] != opposite[1])
      topo.bending.push_back({half[i].a, half[i].b, opposite[0], opposite[1]});
    i = j;
  }
  return topo;
}

std::vector<Edge> sweep_order(const std::vector<Edge>& edges) {
  Index n = 0;
  for (const Edge& e : edges) n = std::max(n, e[1] + 1);
  std::vector<std::vector<Index>> taken(static_cast<std::size_t>(n));  // colours at each vertex
  std::vector<Index> colour(edges.size());
  Index colours = 0;
  for (std::size_t k = 0; k < edges.size(); ++k) {
    const auto& ta = taken[edges[k][0]];
    const auto& tb = taken[edges[k][1]];
    Index c = 0;
    while (std::find(ta.begin(), ta.end(), c) != ta.end() || std::find(tb.begin(), tb.end(), c) != tb.end()) ++c;
    colour[k] = c;
    colours = std::max(colours, c + 1);
    taken[edges[k][0]].push_back(c);
    taken[edges[k][1]].push_back(c);
  }
  std::vector<Index> start(static_cast<std::size_t>(colours) + 1, 0);
  for (const Index c : colour) ++start[c + 1];
  for (Index c = 0; c < colours; ++c) start[c + 1] += start[c];
  std::vector<Edge> out(edges.size());
  for (std::size_t k = 0; k < edges.size(); ++k) out[start[colour[k]]++] = edges[k];
  return out;
}

std::vector<Real> lumped_measure(const Mesh& mesh) {
  std::vector<Real> w(mesh.num_vertices(), 0.0);
  if (!mesh.triangles.empty()) {
    for (const auto& t : mesh.triangles) {
      const Vec3 a = mesh.vertices.col(t[0]), b = mesh.vertices.col(t[1]), c = mesh.vertices.col(t[2]);
      const Real third = (b - a).cross(c - a).norm() / 6.0;
      for (Index v : t) w[v] += third;
    }
  } else {
    for (const auto& l : mesh.lines) {
      const Real half = (mesh.vertices.col(l[0]) - mesh.vertices.col(l[1])).norm() / 2.0;
      w[l[0]] += half;
      w[l[1]] += half;
    }
  }
  return w;
}

}  // namespace csb
