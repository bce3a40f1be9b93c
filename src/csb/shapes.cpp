#include "csb/shapes.hpp"
#include "csb/format.hpp"
#include "csb/memory_budget.hpp"

#include <cmath>
#include <sstream>

namespace csb {

using detail::str;

namespace {

void require(bool ok, const std::string& message) {
  if (!ok) throw InvalidArgument(message);
}


}  // namespace

Mesh cloth_grid(Real width, Real height, Index nx, Index ny, Plane plane, const Vec3& center) {
  require(std::isfinite(width) && width > 0, "cloth_grid: width must be > 0 m, got " + str(width));
  require(std::isfinite(height) && height > 0, "cloth_grid: height must be > 0 m, got " + str(height));
  require(nx >= 2 && ny >= 2, "cloth_grid: nx and ny must be >= 2 particles, got " + std::to_string(nx) + " x " +
                                  std::to_string(ny));
  require_memory_for("cloth_grid(" + std::to_string(nx) + ", " + std::to_string(ny) + ")",
                     static_cast<double>(nx) * static_cast<double>(ny));
  require(static_cast<long long>(nx) * ny < (1LL << 30), "cloth_grid: nx x ny must be below 2^30 particles, got " +
                                                            std::to_string(static_cast<long long>(nx) * ny));
  require(center.allFinite(), "cloth_grid: center must be finite");
  Mesh m;
  m.name = "cloth_grid(" + std::to_string(nx) + "x" + std::to_string(ny) + ")";
  m.vertices.resize(3, static_cast<Eigen::Index>(nx) * ny);
  const int u_axis = plane == Plane::YZ ? 1 : 0;
  const int v_axis = plane == Plane::XY ? 1 : 2;
  for (Index j = 0; j < ny; ++j)
    for (Index i = 0; i < nx; ++i) {
      Vec3 p = center;
      p[u_axis] += width * (static_cast<Real>(i) / (nx - 1) - 0.5);
      p[v_axis] += height * (static_cast<Real>(j) / (ny - 1) - 0.5);
      m.vertices.col(j * nx + i) = p;
    }
  m.triangles.reserve(2 * static_cast<std::size_t>(nx - 1) * (ny - 1));
  for (Index j = 0; j + 1 < ny; ++j)
    for (Index i = 0; i + 1 < nx; ++i) {
      const Index a = j * nx + i, b = a + 1, c = a + nx, d = c + 1;
      if ((i + j) % 2 == 0) {
        m.triangles.push_back({a, b, d});
        m.triangles.push_back({a, d, c});
      } else {
        m.triangles.push_back({a, b, c});
        m.triangles.push_back({b, d, c});
      }
    }
  return m;
}

Mesh chain(Index links, Real link_length, const Vec3& start, const Vec3& direction) {
  require(links >= 1, "chain: links must be >= 1, got " + std::to_string(links));
  require_memory_for("chain(" + std::to_string(links) + ")", static_cast<double>(links) + 1);
  require(links < (1 << 30), "chain: links must be below 2^30, got " + std::to_string(links));
  require(std::isfinite(link_length) && link_length > 0, "chain: link_length must be > 0 m, got " + str(link_length));
  require(start.allFinite(), "chain: start must be finite");
  require(direction.allFinite() && direction.norm() > 0, "chain: direction must be a finite non-zero vector");
  const Vec3 d = direction.normalized();
  Mesh m;
  m.name = "chain(" + std::to_string(links) + ")";
  m.vertices.resize(3, links + 1);
  for (Index i = 0; i <= links; ++i) m.vertices.col(i) = start + (link_length * i) * d;
  for (Index i = 0; i < links; ++i) m.lines.push_back({i, i + 1});
  return m;
}

Mesh pendulum(Real length, Real angle, const Vec3& anchor) {
  require(std::isfinite(length) && length > 0, "pendulum: length must be > 0 m, got " + str(length));
  require(std::isfinite(angle), "pendulum: angle must be finite");
  require(anchor.allFinite(), "pendulum: anchor must be finite");
  Mesh m = chain(1, length, anchor, Vec3(std::sin(angle), -std::cos(angle), 0));
  m.name = "pendulum";
  return m;
}

}  // namespace csb
