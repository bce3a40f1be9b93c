#include "csb/tetmesh.hpp"
#include "csb/format.hpp"
#include "csb/memory_budget.hpp"
#include "csb/mesh.hpp"

#include "csb/constraints/volume.hpp"

#include <algorithm>
#include <map>

namespace csb {

using detail::str;

void validate(const TetMesh& mesh) {
  const std::string& name = mesh.name;
  const Index n = mesh.num_points();
  if (mesh.tets.empty()) throw MeshError(name + ": the mesh has no tetrahedra");
  for (Index i = 0; i < n; ++i)
    if (!mesh.points.col(i).allFinite())
      throw MeshError(name + ": point " + std::to_string(i) + " has a non-finite coordinate " + str(Vec3(mesh.points.col(i))));
  for (Index t = 0; t < mesh.num_tets(); ++t) {
    const Tet& q = mesh.tets[t];
    for (Index p : q)
      if (p < 0 || p >= n)
        throw MeshError(name + ": tet " + std::to_string(t) + " uses point " + std::to_string(p) +
                        ", out of range (the mesh has " + std::to_string(n) + " points)");
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b)
        if (q[a] == q[b])
          throw MeshError(name + ": tet " + std::to_string(t) + " uses point " + std::to_string(q[a]) + " twice");
  }
}

std::vector<Real> tet_volumes(const TetMesh& mesh) {
  std::vector<Real> v(mesh.tets.size());
  for (std::size_t t = 0; t < mesh.tets.size(); ++t) {
    const Tet& q = mesh.tets[t];
    v[t] = tet_volume(mesh.points.col(q[0]), mesh.points.col(q[1]), mesh.points.col(q[2]), mesh.points.col(q[3]));
  }
  return v;
}

std::vector<Triangle> tet_surface(const TetMesh& mesh) {
  // Outward faces of a positively oriented tet (p3 on the side of (p1 - p0) x (p2 - p0)): each
  // face's normal points away from the fourth point.
  static constexpr int kFaces[4][3] = {{0, 2, 1}, {0, 1, 3}, {1, 2, 3}, {0, 3, 2}};
  std::map<std::array<Index, 3>, std::pair<int, Triangle>> faces;  // sorted face -> (uses, first winding)
  std::vector<std::array<Index, 3>> order;
  for (Index t = 0; t < mesh.num_tets(); ++t) {
    const Tet& q = mesh.tets[t];
    for (const auto& f : kFaces) {
      const Triangle tri{q[f[0]], q[f[1]], q[f[2]]};
      std::array<Index, 3> key = tri;
      std::sort(key.begin(), key.end());
      auto [it, inserted] = faces.try_emplace(key, 0, tri);
      if (inserted) order.push_back(key);
      if (++it->second.first > 2)
        throw MeshError(mesh.name + ": the face (" + std::to_string(key[0]) + ", " + std::to_string(key[1]) + ", " +
                        std::to_string(key[2]) + ") is shared by more than two tets (tet " + std::to_string(t) +
                        " is the third)");
    }
  }
  std::vector<Triangle> out;
  for (const auto& key : order) {
    const auto& [uses, tri] = faces.at(key);
    if (uses == 1) out.push_back(tri);
  }
  return out;
}

TetMesh tet_box(const Vec3& size, Index nx, Index ny, Index nz, const Vec3& center) {
  if (!(size.array() > 0).all() || !size.allFinite())
    throw InvalidArgument("tet_box: size must be three finite lengths > 0 m, got " + str(size));
  if (nx < 1 || ny < 1 || nz < 1)
    throw InvalidArgument("tet_box: divisions must be >= 1 along every axis, got (" + std::to_string(nx) + ", " +
                          std::to_string(ny) + ", " + std::to_string(nz) + ")");
  if (!center.allFinite()) throw InvalidArgument("tet_box: center must be finite");
  const double points = (static_cast<double>(nx) + 1) * (static_cast<double>(ny) + 1) * (static_cast<double>(nz) + 1);
  require_memory_for("tet_box(" + std::to_string(nx) + ", " + std::to_string(ny) + ", " + std::to_string(nz) + ")",
                     points);
  if (6.0 * nx * ny * nz >= double(1 << 30))
    throw InvalidArgument("tet_box: 6 nx ny nz must be below 2^30 tetrahedra, got " + detail::str(6.0 * nx * ny * nz));
  TetMesh m;
  m.name = "tet_box";
  const auto id = [&](Index i, Index j, Index k) { return (k * (ny + 1) + j) * (nx + 1) + i; };
  m.points.resize(3, static_cast<Eigen::Index>(nx + 1) * (ny + 1) * (nz + 1));
  const Vec3 lo = center - size / 2;
  for (Index k = 0; k <= nz; ++k)
    for (Index j = 0; j <= ny; ++j)
      for (Index i = 0; i <= nx; ++i)
        m.points.col(id(i, j, k)) =
            lo + Vec3(size.x() * i / nx, size.y() * j / ny, size.z() * k / nz);
  // Kuhn split: for each ordering of the axes, the path (0,0,0) -> +e_a -> +e_b -> (1,1,1). Every
  // cell uses the same split, so the face diagonals of neighbouring cells match.
  static constexpr int kPerm[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  for (Index k = 0; k < nz; ++k)
    for (Index j = 0; j < ny; ++j)
      for (Index i = 0; i < nx; ++i)
        for (const auto& perm : kPerm) {
          std::array<Index, 3> c{i, j, k};
          Tet q;
          q[0] = id(c[0], c[1], c[2]);
          for (int s = 0; s < 3; ++s) {
            ++c[perm[s]];
            q[s + 1] = id(c[0], c[1], c[2]);
          }
          if (tet_volume(m.points.col(q[0]), m.points.col(q[1]), m.points.col(q[2]), m.points.col(q[3])) < 0)
            std::swap(q[2], q[3]);  // odd permutations come out negative
          m.tets.push_back(q);
        }
  return m;
}

}  // namespace csb
