#include "csb/interaction/pick.hpp"
#include "csb/format.hpp"

#include <cmath>
#include <limits>

namespace csb {

using detail::str;

Pick pick_particle(const Model& model, const State& state, const Vec3& origin, const Vec3& direction,
                   Real max_distance) {
  if (!origin.allFinite()) throw InvalidArgument("pick: origin must be finite, got " + str(origin));
  if (!direction.allFinite() || !(direction.norm() > 0))
    throw InvalidArgument("pick: direction must be finite and non-zero, got " + str(direction));
  if (!(max_distance >= 0)) throw InvalidArgument("pick: max_distance must be >= 0 m, got " + str(max_distance));
  if (state.x.cols() != model.num_particles()) throw InvalidArgument("pick: the state does not belong to the model");
  const Vec3 d = direction.normalized();
  const auto& x = state.x;
  Pick best;
  Real t_best = std::numeric_limits<Real>::infinity();
  // Möller & Trumbore 1997: solve origin + t d = a + u (b - a) + v (c - a).
  for (Index f = 0; f < static_cast<Index>(model.triangles.size()); ++f) {
    const auto& tri = model.triangles[f];
    const Vec3 a = x.col(tri[0]), e1 = x.col(tri[1]) - a, e2 = x.col(tri[2]) - a;
    const Vec3 q = d.cross(e2);
    const Real det = e1.dot(q);
    if (std::abs(det) <= 1e-14 * e1.norm() * e2.norm()) continue;  // ray in the triangle's plane
    const Vec3 s = origin - a;
    const Real u = s.dot(q) / det;
    if (u < 0 || u > 1) continue;
    const Vec3 r = s.cross(e1);
    const Real v = d.dot(r) / det;
    if (v < 0 || u + v > 1) continue;
    const Real t = e2.dot(r) / det;
    if (t >= 0 && t < t_best) {
      t_best = t;
      best.triangle = f;
    }
  }
  if (best.triangle >= 0) {
    const Vec3 hit = origin + t_best * d;
    Real nearest = std::numeric_limits<Real>::infinity();
    for (Index i : model.triangles[best.triangle]) {
      const Real r = (x.col(i) - hit).squaredNorm();
      if (r < nearest || (r == nearest && i < best.particle)) nearest = r, best.particle = i;
    }
    best.distance = t_best;
    return best;
  }
  Real off_best = std::numeric_limits<Real>::infinity();
  for (Index i = 0; i < model.num_particles(); ++i) {
    const Vec3 r = x.col(i) - origin;
    const Real t = r.dot(d);
    if (t < 0) continue;
    const Real off = (r - t * d).norm();
    if (off > max_distance) continue;
    if (off < off_best || (off == off_best && t < t_best)) off_best = off, t_best = t, best.particle = i;
  }
  if (best.particle >= 0) best.distance = t_best;
  return best;
}

}  // namespace csb
