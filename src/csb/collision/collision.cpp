#include "csb/collision/collision.hpp"
#include "csb/collision/ccd.hpp"
#include "csb/format.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace csb {

const char* kind_name(ColliderKind kind) {
  switch (kind) {
    case ColliderKind::Plane: return "plane";
    case ColliderKind::Sphere: return "sphere";
    case ColliderKind::Capsule: return "capsule";
    case ColliderKind::Box: return "box";
    case ColliderKind::Mesh: return "mesh";
  }
  return "?";
}

namespace {

// Any unit vector perpendicular to v (v need not be unit).
Vec3 any_perpendicular(const Vec3& v) {
  const Vec3 axis = std::abs(v.x()) < 0.9 * v.norm() ? Vec3::UnitX() : Vec3::UnitY();
  return v.cross(axis).normalized();
}

// A point at distance `len` from a centre (or axis) along v, with the direction chosen for a
// point exactly on the centre.
Vec3 direction_or(const Vec3& v, Real len, const Vec3& fallback) { return len > 0 ? Vec3(v / len) : fallback; }

}  // namespace

SurfacePoint closest_surface_point(const Collider& c, const Vec3& x) {
  SurfacePoint s;
  switch (c.kind) {
    case ColliderKind::Plane: {
      s.distance = (x - c.point).dot(c.normal);
      s.point = x - s.distance * c.normal;
      s.normal = c.normal;
      break;
    }
    case ColliderKind::Sphere: {
      const Vec3 v = x - c.center;
      const Real len = v.norm();
      s.normal = direction_or(v, len, Vec3::UnitY());
      s.distance = len - c.radius;
      s.point = c.center + c.radius * s.normal;
      break;
    }
    case ColliderKind::Capsule: {
      const Vec3 axis = c.b - c.a;
      const Real t = std::clamp((x - c.a).dot(axis) / axis.squaredNorm(), Real(0), Real(1));
      const Vec3 on_axis = c.a + t * axis;
      const Vec3 v = x - on_axis;
      const Real len = v.norm();
      s.normal = direction_or(v, len, any_perpendicular(axis));
      s.distance = len - c.radius;
      s.point = on_axis + c.radius * s.normal;
      break;
    }
    case ColliderKind::Box: {
      const Vec3 l = c.rotation.transpose() * (x - c.center);
      const Vec3& e = c.half_extents;
      const Vec3 clamped = l.cwiseMax(-e).cwiseMin(e);
      const Vec3 outside = l - clamped;
      const Real len = outside.norm();
      Vec3 n_local, q_local;
      if (len > 0) {
        // Outside: the nearest point is the clamped one, the normal points from it to x (it is
        // the face normal off a face, and rounds over edges and corners).
        s.distance = len;
        n_local = outside / len;
        q_local = clamped;
      } else {
        // Inside or on the surface: the nearest face is the one with the smallest clearance.
        int k = 0;
        Real clearance = e[0] - std::abs(l[0]);
        for (int j = 1; j < 3; ++j)
          if (e[j] - std::abs(l[j]) < clearance) clearance = e[j] - std::abs(l[j]), k = j;
        const Real sign = l[k] < 0 ? -1 : 1;
        s.distance = -clearance;
        n_local = Vec3::Zero();
        n_local[k] = sign;
        q_local = l;
        q_local[k] = sign * e[k];
      }
      s.normal = c.rotation * n_local;
      s.point = c.center + c.rotation * q_local;
      break;
    }
    case ColliderKind::Mesh:
      s.distance = std::numeric_limits<Real>::infinity();
      s.point = x;
      break;
  }
  return s;
}

Real signed_distance(const Collider& c, const Vec3& x) { return closest_surface_point(c, x).distance; }

Vec3 closest_point_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, Vec3* bary) {
  // Ericson 2005, §5.1.5: the Voronoi region of p among the triangle's vertices, edges and face.
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const Real d1 = ab.dot(ap), d2 = ac.dot(ap);
  const auto result = [&](Real u, Real v, Real w) {
    if (bary) *bary = Vec3(u, v, w);
    return Vec3(u * a + v * b + w * c);
  };
  if (d1 <= 0 && d2 <= 0) return result(1, 0, 0);
  const Vec3 bp = p - b;
  const Real d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return result(0, 1, 0);
  const Real vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    const Real v = d1 / (d1 - d3);
    return result(1 - v, v, 0);
  }
  const Vec3 cp = p - c;
  const Real d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return result(0, 0, 1);
  const Real vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    const Real w = d2 / (d2 - d6);
    return result(1 - w, 0, w);
  }
  const Real va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    const Real w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return result(0, 1 - w, w);
  }
  const Real denom = 1 / (va + vb + vc);
  const Real v = vb * denom, w = vc * denom;
  return result(1 - v - w, v, w);
}

TriangleGrid build_triangle_grid(const Positions& x, const std::vector<Triangle>& triangles) {
  std::vector<Vec3> lo(triangles.size()), hi(triangles.size());
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    Vec3 tl = x.col(triangles[t][0]), th = tl;
    for (int k = 1; k < 3; ++k) tl = tl.cwiseMin(x.col(triangles[t][k])), th = th.cwiseMax(x.col(triangles[t][k]));
    lo[t] = tl;
    hi[t] = th;
  }
  TriangleGrid g;
  build_box_grid(lo, hi, g);
  return g;
}

void build_box_grid(const std::vector<Vec3>& boxes_lo, const std::vector<Vec3>& boxes_hi, TriangleGrid& g) {
  const Index T = static_cast<Index>(boxes_lo.size());
  Vec3 lo = Vec3::Constant(std::numeric_limits<Real>::infinity()), hi = -lo;
  Real mean_size = 0;
  for (Index t = 0; t < T; ++t) {
    lo = lo.cwiseMin(boxes_lo[t]);
    hi = hi.cwiseMax(boxes_hi[t]);
    mean_size += (boxes_hi[t] - boxes_lo[t]).maxCoeff();
  }
  mean_size /= std::max<Index>(T, 1);
  const Vec3 extent = hi - lo;
  Real cell = std::max(mean_size, 1e-9 * std::max(extent.maxCoeff(), Real(1)));
  // At most about 4 cells per triangle, so that an empty-looking flat mesh does not allocate a
  // huge grid.
  const double max_cells = 4.0 * T + 64;
  for (;;) {
    double cells = 1;
    for (int k = 0; k < 3; ++k) cells *= std::floor(extent[k] / cell) + 1;
    if (cells <= max_cells) break;
    cell *= 1.5;
  }
  g.origin = lo;
  g.cell = cell;
  for (int k = 0; k < 3; ++k) g.dims[k] = static_cast<Index>(std::floor(extent[k] / cell)) + 1;
  const auto cell_of = [&](Real v, int k) {
    return std::clamp(static_cast<Index>(std::floor((v - lo[k]) / cell)), Index(0), g.dims[k] - 1);
  };
  const Index cells = g.dims[0] * g.dims[1] * g.dims[2];
  g.cell_start.assign(cells + 1, 0);
  // Two passes (count, then fill), triangles in index order: each cell's list is ascending.
  std::vector<Index> cursor;
  for (int pass = 0; pass < 2; ++pass) {
    if (pass == 1) {
      for (Index k = 0; k < cells; ++k) g.cell_start[k + 1] += g.cell_start[k];
      g.items.resize(g.cell_start[cells]);
      cursor.assign(g.cell_start.begin(), g.cell_start.end() - 1);
    }
    for (Index t = 0; t < T; ++t) {
      const Vec3& tl = boxes_lo[t];
      const Vec3& th = boxes_hi[t];
      for (Index i = cell_of(tl[0], 0); i <= cell_of(th[0], 0); ++i)
        for (Index j = cell_of(tl[1], 1); j <= cell_of(th[1], 1); ++j)
          for (Index k = cell_of(tl[2], 2); k <= cell_of(th[2], 2); ++k) {
            const Index id = (k * g.dims[1] + j) * g.dims[0] + i;
            if (pass == 0)
              ++g.cell_start[id + 1];
            else
              g.items[cursor[id]++] = t;
          }
    }
  }
}

namespace {

// First parameter t in [0, 1] at which the segment x + t (p - x) enters a convex collider, given
// that x is not inside. The signed distance f(t) to a convex set is a convex function of t, so
// either f(1) < 0 (one crossing in [0, 1]) or the crossing, if any, lies before f's minimum,
// found by golden-section search; then bisection brackets the root to round-off.
bool convex_entry(const Collider& c, const Vec3& x, const Vec3& p, Real d0, Real d1, Vec3& q, Vec3& n) {
  const Vec3 d = p - x;
  const auto f = [&](Real t) { return signed_distance(c, x + t * d); };
  Real lo = 0, hi = 1;
  if (!(d1 < 0)) {
    // |∇f| <= |d| bounds f below by (d0 + d1 - |d|)/2 on [0, 1]: most segments stop here.
    if ((d0 + d1 - d.norm()) / 2 >= 0) return false;
    const Real r = (std::sqrt(5.0) - 1) / 2;
    Real a = 0, b = 1, t1 = b - r * (b - a), t2 = a + r * (b - a), f1 = f(t1), f2 = f(t2);
    for (int k = 0; k < 80 && b - a > 1e-12; ++k) {
      if (f1 < f2) {
        b = t2, t2 = t1, f2 = f1, t1 = b - r * (b - a), f1 = f(t1);
      } else {
        a = t1, t1 = t2, f1 = f2, t2 = a + r * (b - a), f2 = f(t2);
      }
      if (std::min(f1, f2) < 0) break;
    }
    const Real tm = f1 < f2 ? t1 : t2;
    if (!(std::min(f1, f2) < 0)) return false;
    hi = tm;
  }
  for (int k = 0; k < 200; ++k) {  // f(lo) >= 0 > f(hi)
    const Real mid = (lo + hi) / 2;
    if (mid <= lo || mid >= hi) break;
    (f(mid) < 0 ? hi : lo) = mid;
  }
  const SurfacePoint s = closest_surface_point(c, x + lo * d);
  q = s.point;
  n = s.normal;
  return true;
}

// Segment x -> p against triangle (a, b, c) (Möller and Trumbore 1997), t in [0, 1] up to a
// small tolerance on the edges so that a segment through a shared edge hits one of its triangles.
bool segment_triangle(const Vec3& x, const Vec3& d, const Vec3& a, const Vec3& b, const Vec3& c, Real& t) {
  constexpr Real tol = 1e-10;
  const Vec3 e1 = b - a, e2 = c - a;
  const Vec3 pv = d.cross(e2);
  const Real det = e1.dot(pv);
  if (det == 0) return false;
  const Real inv = 1 / det;
  const Vec3 tv = x - a;
  const Real u = tv.dot(pv) * inv;
  if (u < -tol || u > 1 + tol) return false;
  const Vec3 qv = tv.cross(e1);
  const Real v = d.dot(qv) * inv;
  if (v < -tol || u + v > 1 + tol) return false;
  t = e2.dot(qv) * inv;
  return t >= -tol && t <= 1 + tol;
}

// Calls visit(t) once for every triangle listed in a cell of grid g that the box [lo, hi]
// overlaps (every one of the T triangles, in index order, when the box spans more cells than
// there are triangles), in the cells' order. Returns false, visiting none, if the box misses the grid.
template <class Visit>
bool for_each_candidate(const TriangleGrid& g, Index T, const Vec3& lo, const Vec3& hi,
                        std::vector<std::uint32_t>& stamps, std::uint32_t& stamp, Visit&& visit) {
  std::array<Index, 3> c0, c1;
  for (int k = 0; k < 3; ++k) {
    const Real a = std::floor((lo[k] - g.origin[k]) / g.cell), b = std::floor((hi[k] - g.origin[k]) / g.cell);
    if (b < 0 || a > g.dims[k] - 1) return false;  // the segment's box misses the mesh's
    c0[k] = static_cast<Index>(std::max<Real>(a, 0));
    c1[k] = static_cast<Index>(std::min<Real>(b, g.dims[k] - 1));
  }
  if (++stamp == 0) std::fill(stamps.begin(), stamps.end(), 0), stamp = 1;
  const auto once = [&](Index t) {
    if (stamps[t] == stamp) return;
    stamps[t] = stamp;
    visit(t);
  };
  const double cells = double(c1[0] - c0[0] + 1) * (c1[1] - c0[1] + 1) * (c1[2] - c0[2] + 1);
  if (cells > static_cast<double>(T)) {
    // A segment longer than the mesh is wide: fewer tests visiting every triangle once.
    for (Index t = 0; t < T; ++t) once(t);
  } else {
    for (Index k = c0[2]; k <= c1[2]; ++k)
      for (Index j = c0[1]; j <= c1[1]; ++j)
        for (Index i = c0[0]; i <= c1[0]; ++i) {
          const Index id = (k * g.dims[1] + j) * g.dims[0] + i;
          for (Index e = g.cell_start[id]; e < g.cell_start[id + 1]; ++e) once(g.items[e]);
        }
  }
  return true;
}

bool mesh_contact(const ColliderMesh& m, const Vec3& x, const Vec3& p, Real r, Real reach,
                  std::vector<std::uint32_t>& stamps, std::uint32_t& stamp, Vec3& q, Vec3& n) {
  (void)r;
  const Vec3 lo = x.cwiseMin(p).array() - reach, hi = x.cwiseMax(p).array() + reach;
  const Vec3 d = p - x;
  Real best_t = std::numeric_limits<Real>::infinity(), best_dist = std::numeric_limits<Real>::infinity();
  Index hit = -1, near = -1;
  Vec3 near_point = Vec3::Zero();
  const auto visit = [&](Index t) {
    const Triangle& tri = m.triangles[t];
    const Vec3 a = m.vertices.col(tri[0]), b = m.vertices.col(tri[1]), c = m.vertices.col(tri[2]);
    Real s;
    if (segment_triangle(x, d, a, b, c, s) && s < best_t) best_t = s, hit = t;
    if (hit < 0) {
      const Vec3 cp = closest_point_on_triangle(p, a, b, c, nullptr);
      const Real dist = (p - cp).norm();
      if (dist < best_dist) best_dist = dist, near = t, near_point = cp;
    }
  };
  if (!for_each_candidate(m.grid, static_cast<Index>(m.triangles.size()), lo, hi, stamps, stamp, visit)) return false;
  if (hit >= 0) {
    // The ray crossed the sheet: the contact plane is the triangle's, facing the side x is on
    // (or, for x on the sheet, against the motion).
    const Vec3& nf = m.normals[hit];
    q = x + std::clamp(best_t, Real(0), Real(1)) * d;
    const Real side = (x - m.vertices.col(m.triangles[hit][0])).dot(nf);
    n = side > 0 ? nf : side < 0 ? Vec3(-nf) : (d.dot(nf) > 0 ? Vec3(-nf) : nf);
    return true;
  }
  if (near >= 0 && best_dist < reach) {
    q = near_point;
    const Vec3& nf = m.normals[near];
    if (best_dist > 1e-12 * m.grid.cell) {
      n = (p - q) / best_dist;  // no crossing: p is on x's side, and p - q points away from the sheet
    } else {
      const Real side = (x - q).dot(nf);
      n = side >= 0 ? nf : Vec3(-nf);
    }
    return true;
  }
  return false;
}

}  // namespace

bool generate_contact(const Collider& c, Index collider_index, Index i, const Vec3& x, const Vec3& p, Real r,
                      Real margin, Real h, std::vector<Contact>& out, std::vector<std::uint32_t>& stamps,
                      std::uint32_t& stamp) {
  Contact k;
  k.particle = i;
  k.collider = collider_index;
  k.thickness = r;
  if (c.kind == ColliderKind::Mesh) {
    k.thickness = std::max(r, c.mesh->skin);
    if (!mesh_contact(*c.mesh, x, p, k.thickness, k.thickness + margin, stamps, stamp, k.point, k.normal))
      return false;
  } else {
    const Real d0 = signed_distance(c, x);
    // The segment cannot come within r + margin of the surface: f is 1-Lipschitz in the point.
    const Real travel = (p - x).norm();
    if (d0 - travel >= r + margin) return false;
    const Real d1 = signed_distance(c, p);
    bool entered = false;
    if (d0 >= 0) {
      if (c.kind == ColliderKind::Plane) {
        if (d1 < 0) {
          // The plane's crossing in closed form, then put exactly on the plane.
          const Vec3 at = x + (d0 / (d0 - d1)) * (p - x);
          k.point = at - (at - c.point).dot(c.normal) * c.normal;
          k.normal = c.normal;
          entered = true;
        }
      } else {
        entered = convex_entry(c, x, p, d0, d1, k.point, k.normal);
      }
    }
    if (!entered) {
      // x inside (the static fallback), or p within the thickness and margin: the surface point
      // nearest p.
      if (!(d1 < r + margin)) return false;
      const SurfacePoint s = closest_surface_point(c, p);
      k.point = s.point;
      k.normal = s.normal;
      k.started_inside = d0 < 0;
    }
  }
  k.approach_speed = (p - x).dot(k.normal) / h;
  out.push_back(k);
  return true;
}

namespace {

// Unit normal of triangle (a, b, c) from its winding; zero for a degenerate one.
Vec3 face_normal(const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 n = (b - a).cross(c - a);
  const Real len = n.norm();
  return len > 0 ? Vec3(n / len) : Vec3::Zero();
}

Vec3 blend(const Positions& v, const Triangle& t, const Vec3& w) {
  return w[0] * v.col(t[0]) + w[1] * v.col(t[1]) + w[2] * v.col(t[2]);
}

// The separation the continuous test keeps: an impact is the distance falling to this fraction
// of the start's (self-collision's choice, self_collision.cpp).
constexpr Real kDeformingSeparation = 0.1;

}  // namespace

void validate_collider_vertices(const ColliderMesh& mesh, const Positions& vertices, const std::string& what) {
  if (vertices.cols() != mesh.vertices.cols())
    throw InvalidArgument(what + ": " + std::to_string(vertices.cols()) + " vertices given, but the mesh has " +
                          std::to_string(mesh.vertices.cols()));
  for (Index v = 0; v < vertices.cols(); ++v)
    if (!vertices.col(v).allFinite())
      throw InvalidArgument(what + ": vertex " + std::to_string(v) + " must be finite (m), got " +
                            detail::str(Vec3(vertices.col(v))));
}

bool generate_deforming_contact(const Collider& c, const DeformingMesh& d, Index collider_index, Index i,
                                const Vec3& x, const Vec3& p, Real r, Real margin, Real h, std::vector<Contact>& out,
                                std::vector<std::uint32_t>& stamps, std::uint32_t& stamp) {
  const ColliderMesh& m = *c.mesh;
  const Real thickness = std::max(r, m.skin);
  const Real reach = thickness + margin;
  const Vec3 lo = x.cwiseMin(p).array() - reach, hi = x.cwiseMax(p).array() + reach;
  const Vec3 dp = p - x;
  Real best_toi = std::numeric_limits<Real>::infinity(), best_dist = std::numeric_limits<Real>::infinity();
  Index hit = -1, near = -1;
  Vec3 hit_bary = Vec3::Zero(), hit_normal = Vec3::Zero(), near_bary = Vec3::Zero(), near_point = Vec3::Zero();
  const auto visit = [&](Index t) {
    const Triangle& tri = m.triangles[t];
    const std::array<Vec3, 4> x0{x, d.start.col(tri[0]), d.start.col(tri[1]), d.start.col(tri[2])};
    const std::array<Vec3, 4> dx{dp, d.end.col(tri[0]) - x0[1], d.end.col(tri[1]) - x0[2], d.end.col(tri[2]) - x0[3]};
    const Impact im = additive_ccd(PairKind::PointTriangle, x0, dx, kDeformingSeparation, 0);
    if (im.hit && im.toi < best_toi) {
      // Where the pair is at the reported time: the particle is still apart from the triangle
      // (at least 1/10 of its start distance, ccd.hpp), so its side there is defined.
      std::array<Vec3, 4> at;
      for (int k = 0; k < 4; ++k) at[k] = x0[k] + im.toi * dx[k];
      Vec3 bary;
      const Vec3 cp = closest_point_on_triangle(at[0], at[1], at[2], at[3], &bary);
      const Vec3 nt = face_normal(at[1], at[2], at[3]);
      if (nt != Vec3::Zero()) {  // a triangle collapsed then is left to its neighbours
        Real side = (at[0] - cp).dot(nt);
        if (side == 0) side = -(dx[0] - (bary[0] * dx[1] + bary[1] * dx[2] + bary[2] * dx[3])).dot(nt);
        best_toi = im.toi;
        hit = t;
        hit_bary = bary;
        hit_normal = side >= 0 ? nt : Vec3(-nt);
      }
    }
    if (hit < 0) {
      Vec3 bary;
      const Vec3 cp = closest_point_on_triangle(p, d.end.col(tri[0]), d.end.col(tri[1]), d.end.col(tri[2]), &bary);
      const Real dist = (p - cp).norm();
      if (dist < best_dist) best_dist = dist, near = t, near_point = cp, near_bary = bary;
    }
  };
  if (!for_each_candidate(d.grid, static_cast<Index>(m.triangles.size()), lo, hi, stamps, stamp, visit)) return false;
  Contact k;
  k.particle = i;
  k.collider = collider_index;
  k.thickness = thickness;
  Index t;
  Vec3 bary;
  if (hit >= 0) {
    // The end triangle's plane, facing the side the particle was on at the impact (a triangle
    // that turned over within the sub-step keeps that side).
    t = hit;
    bary = hit_bary;
    const Triangle& tri = m.triangles[t];
    Vec3 n1 = face_normal(d.end.col(tri[0]), d.end.col(tri[1]), d.end.col(tri[2]));
    if (n1 == Vec3::Zero()) n1 = hit_normal;
    k.normal = n1.dot(hit_normal) >= 0 ? n1 : Vec3(-n1);
    k.point = blend(d.end, tri, bary);
  } else if (near >= 0 && best_dist < reach) {
    t = near;
    bary = near_bary;
    k.point = near_point;
    const Triangle& tri = m.triangles[t];
    if (best_dist > 1e-12 * d.grid.cell) {
      k.normal = (p - k.point) / best_dist;  // no crossing: p is on x's side
    } else {
      Vec3 nf = face_normal(d.end.col(tri[0]), d.end.col(tri[1]), d.end.col(tri[2]));
      if (nf == Vec3::Zero()) return false;
      const Real side = (x - blend(d.start, tri, bary)).dot(nf);
      k.normal = side > 0 ? nf : side < 0 ? Vec3(-nf) : (dp.dot(nf) > 0 ? Vec3(-nf) : nf);
    }
  } else {
    return false;
  }
  // The motion of the point q + r n the triangle holds (see collision.hpp).
  const Triangle& tri = m.triangles[t];
  const Vec3 q0 = blend(d.start, tri, bary);
  const Vec3 f0 = face_normal(d.start.col(tri[0]), d.start.col(tri[1]), d.start.col(tri[2]));
  const Vec3 f1 = face_normal(d.end.col(tri[0]), d.end.col(tri[1]), d.end.col(tri[2]));
  const Real s1 = k.normal.dot(f1) >= 0 ? 1 : -1, s0 = f0.dot(f1) >= 0 ? s1 : -s1;
  k.surface_motion = (k.point - q0) + k.thickness * (s1 * f1 - s0 * f0);
  k.approach_speed = (dp - (k.point - q0)).dot(k.normal) / h;
  out.push_back(k);
  return true;
}

Index triangle_frame(const Positions& v, const std::vector<Triangle>& triangles, const Vec3& x, Vec3& frame) {
  Index best = -1;
  Real best_d2 = std::numeric_limits<Real>::infinity();
  for (Index t = 0; t < static_cast<Index>(triangles.size()); ++t) {
    const Triangle& tri = triangles[t];
    const Vec3 a = v.col(tri[0]), b = v.col(tri[1]), c = v.col(tri[2]);
    if (face_normal(a, b, c) == Vec3::Zero()) continue;
    const Real d2 = (x - closest_point_on_triangle(x, a, b, c, nullptr)).squaredNorm();
    if (d2 < best_d2) best_d2 = d2, best = t;
  }
  if (best < 0) return -1;
  const Triangle& tri = triangles[best];
  const Vec3 a = v.col(tri[0]), e1 = v.col(tri[1]) - a, e2 = v.col(tri[2]) - a;
  const Vec3 n = face_normal(a, v.col(tri[1]), v.col(tri[2]));
  const Real w = (x - a).dot(n);
  const Vec3 y = x - a - w * n;  // in the triangle's plane: u e1 + v e2 by the normal equations
  const Real g11 = e1.dot(e1), g12 = e1.dot(e2), g22 = e2.dot(e2), det = g11 * g22 - g12 * g12;
  const Real b1 = e1.dot(y), b2 = e2.dot(y);
  frame = Vec3((g22 * b1 - g12 * b2) / det, (g11 * b2 - g12 * b1) / det, w);
  return best;
}

Vec3 from_triangle_frame(const Positions& v, const Triangle& t, const Vec3& frame) {
  const Vec3 a = v.col(t[0]), b = v.col(t[1]), c = v.col(t[2]);
  return a + frame[0] * (b - a) + frame[1] * (c - a) + frame[2] * face_normal(a, b, c);
}

}  // namespace csb
