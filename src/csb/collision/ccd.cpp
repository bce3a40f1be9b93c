#include "csb/collision/ccd.hpp"
#include "csb/collision/collision.hpp"

#include <algorithm>
#include <cmath>

namespace csb {

Real segment_segment_distance2(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1, Real* s_out,
                               Real* t_out) {
  const Vec3 d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
  const Real a = d1.dot(d1), e = d2.dot(d2), f = d2.dot(r);
  const auto clamp01 = [](Real v) { return std::min(std::max(v, Real(0)), Real(1)); };
  Real s = 0, t = 0;
  if (a <= 0 && e <= 0) {
    s = t = 0;  // two points
  } else if (a <= 0) {
    t = clamp01(f / e);
  } else {
    const Real c = d1.dot(r);
    if (e <= 0) {
      s = clamp01(-c / a);
    } else {
      const Real b = d1.dot(d2), denom = a * e - b * b;
      // denom = |d1|²|d2|² sin²θ; below 1e-12 of a e (θ < 1e-6 rad) the segments are parallel
      // and the formula's round-off is larger than its answer: start from s = 0 instead.
      s = denom > 1e-12 * a * e ? clamp01((b * f - c * e) / denom) : 0;
      t = (b * s + f) / e;
      if (t < 0) {
        t = 0;
        s = clamp01(-c / a);
      } else if (t > 1) {
        t = 1;
        s = clamp01((b - c) / a);
      }
    }
  }
  if (s_out) *s_out = s;
  if (t_out) *t_out = t;
  return ((p0 + s * d1) - (q0 + t * d2)).squaredNorm();
}

Real point_triangle_distance2(const Vec3& x, const Vec3& a, const Vec3& b, const Vec3& c, Vec3* barycentric) {
  return (x - closest_point_on_triangle(x, a, b, c, barycentric)).squaredNorm();
}

Real pair_distance2(PairKind kind, const std::array<Vec3, 4>& x) {
  if (kind == PairKind::PointTriangle) return point_triangle_distance2(x[0], x[1], x[2], x[3], nullptr);
  return segment_segment_distance2(x[0], x[1], x[2], x[3], nullptr, nullptr);
}

Impact additive_ccd(PairKind kind, std::array<Vec3, 4> x, std::array<Vec3, 4> dx, Real s, Real xi, int max_steps) {
  const Vec3 mean = (dx[0] + dx[1] + dx[2] + dx[3]) / 4;
  for (Vec3& d : dx) d -= mean;
  Real lp;
  if (kind == PairKind::PointTriangle)
    lp = dx[0].norm() + std::max({dx[1].norm(), dx[2].norm(), dx[3].norm()});
  else
    lp = std::max(dx[0].norm(), dx[1].norm()) + std::max(dx[2].norm(), dx[3].norm());
  if (!(lp > 0)) return {};  // a rigid translation keeps every distance
  Real d2 = pair_distance2(kind, x);
  if (d2 <= xi * xi) return {true, 0};
  Real d = std::sqrt(d2);
  const Real gap = (d2 - xi * xi) / (d + xi);  // d - ξ, without cancellation
  const Real g = s * gap;
  Real tl = (1 - s) * gap / lp;
  if (tl >= 1) return {};  // the whole motion cannot close (1 - s) of the gap
  Real t = 0;
  for (int k = 0; k < max_steps; ++k) {
    for (int i = 0; i < 4; ++i) x[i] += tl * dx[i];
    d2 = pair_distance2(kind, x);
    d = std::sqrt(d2);
    const Real now = (d2 - xi * xi) / (d + xi);
    if (t > 0 && now < g) return {true, t};
    t += tl;
    if (t > 1) return {};
    tl = 0.9 * now / lp;
  }
  return {true, t};
}

}  // namespace csb
