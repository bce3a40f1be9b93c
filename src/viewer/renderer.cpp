#include "viewer/renderer.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace csb::viewer {

namespace {

using Rgb = std::array<float, 3>;
using Rgba = std::array<float, 4>;

// Linear RGB front colours of the groups, in turn.
constexpr std::array<Rgb, 6> kGroupColors = {{
    {0.10f, 0.32f, 0.70f},  // blue
    {0.80f, 0.30f, 0.08f},  // orange
    {0.12f, 0.50f, 0.20f},  // green
    {0.50f, 0.16f, 0.55f},  // purple
    {0.70f, 0.55f, 0.08f},  // ochre
    {0.08f, 0.50f, 0.52f},  // teal
}};
constexpr Rgb kColliderColor = {0.42f, 0.42f, 0.40f};
constexpr Rgba kGridColor = {0.30f, 0.32f, 0.36f, 0.55f};
constexpr Rgba kGridAxisColor = {0.20f, 0.22f, 0.26f, 0.9f};
constexpr Rgba kWireColor = {0.05f, 0.05f, 0.08f, 0.8f};
constexpr Rgba kChainColor = {0.10f, 0.10f, 0.12f, 1.0f};
constexpr Rgba kParticleColor = {0.95f, 0.95f, 0.95f, 1.0f};
constexpr Rgba kPinnedColor = {0.85f, 0.10f, 0.10f, 1.0f};
constexpr Rgba kHeldColor = {1.00f, 0.85f, 0.10f, 1.0f};

// A "nice" grid spacing (1, 2 or 5 times a power of ten) giving about `lines` lines over `size`.
double nice_spacing(double size, int lines) {
  const double raw = std::max(size / lines, 1e-6);
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0})
    if (m * p >= raw) return m * p;
  return 10 * p;
}

void push(std::vector<float>& v, const Vec3& p) {
  v.push_back(static_cast<float>(p.x()));
  v.push_back(static_cast<float>(p.y()));
  v.push_back(static_cast<float>(p.z()));
}

template <std::size_t K>
void push(std::vector<float>& v, const std::array<float, K>& c) {
  v.insert(v.end(), c.begin(), c.end());
}

// Triangle soup with per-vertex normals, for the colliders.
struct Soup {
  std::vector<float> position, normal, color;
  void vertex(const Vec3& p, const Vec3& n) {
    push(position, p);
    push(normal, n);
    push(color, kColliderColor);
  }
  void triangle(const Vec3& a, const Vec3& b, const Vec3& c) {  // flat
    const Vec3 n = (b - a).cross(c - a);
    vertex(a, n);
    vertex(b, n);
    vertex(c, n);
  }
  // A grid of quads over (u, v) in [0, 1]², mapped by f to points with normals.
  template <class F>
  void surface(int nu, int nv, F f) {
    for (int i = 0; i < nu; ++i)
      for (int j = 0; j < nv; ++j) {
        Vec3 p[4], n[4];
        f(double(i) / nu, double(j) / nv, p[0], n[0]);
        f(double(i + 1) / nu, double(j) / nv, p[1], n[1]);
        f(double(i + 1) / nu, double(j + 1) / nv, p[2], n[2]);
        f(double(i) / nu, double(j + 1) / nv, p[3], n[3]);
        for (int k : {0, 1, 2, 0, 2, 3}) vertex(p[k], n[k]);
      }
  }
};

// Any two unit vectors completing n to an orthonormal basis.
void basis(const Vec3& n, Vec3& u, Vec3& w) {
  u = (std::abs(n.x()) < 0.9 ? Vec3::UnitX() : Vec3::UnitY()).cross(n).normalized();
  w = n.cross(u);
}

// A triangle mesh, flat-shaded: 3 vertices a triangle, in the triangles' order (so that a
// deforming mesh collider's range of the soup is rewritten in place from new positions).
void add_mesh(Soup& s, const Positions& x, const std::vector<Triangle>& triangles) {
  for (const Triangle& t : triangles) s.triangle(x.col(t[0]), x.col(t[1]), x.col(t[2]));
}

// Every collider in its own frame (the model's, as declared).
void add_collider(Soup& s, const Collider& c) {
  switch (c.kind) {
    case ColliderKind::Plane:
      break;  // drawn as a grid
    case ColliderKind::Sphere:
      s.surface(48, 24, [&](double u, double v, Vec3& p, Vec3& n) {
        const double phi = 2 * M_PI * u, theta = M_PI * v;
        n = Vec3(std::sin(theta) * std::cos(phi), std::cos(theta), std::sin(theta) * std::sin(phi));
        p = c.center + c.radius * n;
      });
      break;
    case ColliderKind::Capsule: {
      const Vec3 axis = c.b - c.a;
      const Vec3 z = axis.normalized();
      Vec3 x, y;
      basis(z, x, y);
      // One sweep over the meridian: a hemisphere at a, the cylinder, a hemisphere at b.
      s.surface(48, 26, [&](double u, double v, Vec3& p, Vec3& n) {
        const double phi = 2 * M_PI * u;
        const Vec3 radial = std::cos(phi) * x + std::sin(phi) * y;
        const double t = v * 26;  // 0..12 cap at a, 12..14 cylinder, 14..26 cap at b
        if (t <= 12) {
          const double theta = M_PI / 2 * (t / 12);  // from the pole at a to the equator
          n = -std::cos(theta) * z + std::sin(theta) * radial;
          p = c.a + c.radius * n;
        } else if (t <= 14) {
          n = radial;
          p = c.a + (t - 12) / 2 * axis + c.radius * n;
        } else {
          const double theta = M_PI / 2 * ((t - 14) / 12);  // from the equator to the pole at b
          n = std::sin(theta) * z + std::cos(theta) * radial;
          p = c.b + c.radius * n;
        }
      });
      break;
    }
    case ColliderKind::Box: {
      const Mat3 r = c.rotation;
      const Vec3 e = c.half_extents;
      for (int axis = 0; axis < 3; ++axis)
        for (int sign : {-1, 1}) {
          const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
          const Vec3 n = sign * r.col(axis);
          const Vec3 du = e[a1] * r.col(a1), dv = e[a2] * r.col(a2);
          const Vec3 o = c.center + e[axis] * n;
          Vec3 q[4] = {o - du - dv, o + du - dv, o + du + dv, o - du + dv};
          if (sign < 0) std::swap(q[1], q[3]);  // wind outwards
          s.triangle(q[0], q[1], q[2]);
          s.triangle(q[0], q[2], q[3]);
        }
      break;
    }
    case ColliderKind::Mesh:
      add_mesh(s, c.mesh->vertices, c.mesh->triangles);
      break;
  }
}

void extend(Vec3& lo, Vec3& hi, const Vec3& p) {
  lo = lo.cwiseMin(p);
  hi = hi.cwiseMax(p);
}

}  // namespace

void vertex_normals(const Positions& x, const std::vector<Triangle>& triangles, std::vector<float>& normals) {
  std::vector<Vec3> acc(static_cast<std::size_t>(x.cols()), Vec3::Zero());
  for (const Triangle& t : triangles) {
    const Vec3 a = x.col(t[0]), b = x.col(t[1]), c = x.col(t[2]);
    const Vec3 n = (b - a).cross(c - a);  // twice the area, along the normal
    acc[t[0]] += n;
    acc[t[1]] += n;
    acc[t[2]] += n;
  }
  normals.resize(3 * acc.size());
  for (std::size_t i = 0; i < acc.size(); ++i)
    for (int k = 0; k < 3; ++k) normals[3 * i + k] = static_cast<float>(acc[i][k]);
}

struct Renderer::Geometry {
  Program surface{"surface.vert", "surface.frag"};
  Program lines{"lines.vert", "lines.frag"};
  Program points{"points.vert", "points.frag"};
  Mesh cloth, wire, chain, dots, colliders, grid;
  std::vector<float> position, normal, color, dot_color;
  // The colliders' soup (model frame) and each collider's vertices in it: [first, first + count).
  std::vector<float> collider_position, collider_normal;
  std::vector<std::size_t> collider_first, collider_count;
  std::vector<char> collider_deformed;  // per collider: its range on the GPU holds deformed vertices
  std::vector<Triangle> triangles;
  std::vector<char> in_triangle;
  std::vector<unsigned> chain_edges;
  bool has_chain = false;
};

Renderer::Renderer() : g_(std::make_unique<Geometry>()) {}

Renderer::~Renderer() = default;

void Renderer::set_model(const Model& model) {
  Geometry& g = *g_;
  const Index n = model.num_particles();
  g.triangles = model.triangles;

  // Colours per vertex from its group.
  g.color.resize(3 * static_cast<std::size_t>(n));
  for (Index i = 0; i < n; ++i) {
    const Rgb& c = kGroupColors[static_cast<std::size_t>(model.group[i]) % kGroupColors.size()];
    std::copy(c.begin(), c.end(), g.color.begin() + 3 * i);
  }
  g.cloth.attribute(2, 3, g.color.data(), n, GL_STATIC_DRAW);
  // The positions live in the surface's buffer, uploaded once per frame; the wireframe, the
  // chains and the particles read them from there.
  g.position.assign(3 * static_cast<std::size_t>(n), 0.0f);
  g.cloth.attribute(0, 3, g.position.data(), n);
  g.wire.share(0, g.cloth, 0, 3);
  g.chain.share(0, g.cloth, 0, 3);
  g.dots.share(0, g.cloth, 0, 3);
  std::vector<unsigned> tri;
  tri.reserve(3 * g.triangles.size());
  g.in_triangle.assign(static_cast<std::size_t>(n), 0);
  for (const Triangle& t : g.triangles)
    for (Index i : t) {
      tri.push_back(static_cast<unsigned>(i));
      g.in_triangle[i] = 1;
    }
  g.cloth.indices(tri.data(), tri.size());

  // Every distance constraint for the wireframe; those between particles of no triangle (chains,
  // springs of a point cloud) always, as lines.
  std::vector<unsigned> edges, chain;
  for (const Edge& e : model.distance.particles) {
    edges.push_back(static_cast<unsigned>(e[0]));
    edges.push_back(static_cast<unsigned>(e[1]));
    if (!g.in_triangle[e[0]] || !g.in_triangle[e[1]]) {
      chain.push_back(static_cast<unsigned>(e[0]));
      chain.push_back(static_cast<unsigned>(e[1]));
    }
  }
  std::vector<float> wire_color, chain_color;
  for (Index i = 0; i < n; ++i) {
    push(wire_color, kWireColor);
    push(chain_color, kChainColor);
  }
  g.wire.attribute(1, 4, wire_color.data(), n, GL_STATIC_DRAW);
  g.wire.indices(edges.data(), edges.size());
  g.has_chain = !chain.empty();
  g.chain.attribute(1, 4, chain_color.data(), n, GL_STATIC_DRAW);
  g.chain.indices(chain.data(), chain.size());

  // Bounds: the model at rest and the bounded colliders.
  lo_ = Vec3::Constant(std::numeric_limits<double>::infinity());
  hi_ = -lo_;
  for (Index i = 0; i < n; ++i) extend(lo_, hi_, model.rest_positions.col(i));
  Soup soup;
  g.collider_first.clear();
  g.collider_count.clear();
  for (const Collider& c : model.colliders) {
    g.collider_first.push_back(soup.position.size() / 3);
    add_collider(soup, c);
    g.collider_count.push_back(soup.position.size() / 3 - g.collider_first.back());
  }
  for (std::size_t k = 0; k + 2 < soup.position.size(); k += 3)
    extend(lo_, hi_, Vec3(soup.position[k], soup.position[k + 1], soup.position[k + 2]));
  if (!(lo_.array() <= hi_.array()).all()) lo_ = hi_ = Vec3::Zero();  // nothing at all
  // What falls lands on the ground: frame down to the highest floor below the model.
  double floor = -std::numeric_limits<double>::infinity();
  for (const Collider& c : model.colliders)
    if (c.kind == ColliderKind::Plane && c.normal.y() > 0.9 && c.point.y() < lo_.y()) floor = std::max(floor, c.point.y());
  if (std::isfinite(floor)) lo_.y() = floor;
  g.colliders.attribute(0, 3, soup.position.data(), soup.position.size() / 3, GL_STATIC_DRAW);
  g.colliders.attribute(1, 3, soup.normal.data(), soup.normal.size() / 3, GL_STATIC_DRAW);
  g.collider_position = std::move(soup.position);
  g.collider_normal = std::move(soup.normal);
  g.collider_deformed.assign(g.collider_first.size(), 0);
  g.colliders.attribute(2, 3, soup.color.data(), soup.color.size() / 3, GL_STATIC_DRAW);

  // Grids: one on every plane collider; with none facing up, a ground grid just below the model.
  const Vec3 centre = 0.5 * (lo_ + hi_);
  const double size = std::max(2.5 * (hi_ - lo_).norm(), 1.0);
  const double spacing = nice_spacing(size, 20);
  const int half = static_cast<int>(std::ceil(0.5 * size / spacing));
  std::vector<float> grid, grid_color;
  auto add_grid = [&](const Vec3& point, const Vec3& normal) {
    Vec3 u, w;
    if (std::abs(normal.y()) > 0.9) {  // align with the world axes
      u = Vec3::UnitX();
      w = normal.cross(u).normalized();
      u = w.cross(normal);
    } else {
      basis(normal, u, w);
    }
    // The grid's origin: the model's centre dropped onto the plane, snapped to the spacing.
    Vec3 o = centre - (centre - point).dot(normal) * normal;
    const double su = std::round((o - point).dot(u) / spacing), sw = std::round((o - point).dot(w) / spacing);
    o = point + 1e-4 * size * normal + su * spacing * u + sw * spacing * w;
    for (int k = -half; k <= half; ++k) {
      const Rgba& col = (k + static_cast<int>(su)) == 0 ? kGridAxisColor : kGridColor;
      push(grid, o + k * spacing * u - half * spacing * w);
      push(grid, o + k * spacing * u + half * spacing * w);
      const Rgba& col2 = (k + static_cast<int>(sw)) == 0 ? kGridAxisColor : kGridColor;
      push(grid, o - half * spacing * u + k * spacing * w);
      push(grid, o + half * spacing * u + k * spacing * w);
      push(grid_color, col);
      push(grid_color, col);
      push(grid_color, col2);
      push(grid_color, col2);
    }
  };
  bool ground = false;
  for (const Collider& c : model.colliders)
    if (c.kind == ColliderKind::Plane) {
      add_grid(c.point, c.normal);
      ground = ground || c.normal.y() > 0.9;
    }
  if (!ground) add_grid(Vec3(centre.x(), lo_.y() - 0.05 * (hi_ - lo_).norm(), centre.z()), Vec3::UnitY());
  g.grid.attribute(0, 3, grid.data(), grid.size() / 3, GL_STATIC_DRAW);
  g.grid.attribute(1, 4, grid_color.data(), grid_color.size() / 4, GL_STATIC_DRAW);
}

namespace {

// A rigid pose as a column-major 4 x 4 matrix for glUniformMatrix4fv.
Eigen::Matrix4f pose_matrix(const ColliderPose& pose) {
  Eigen::Matrix4f m = Eigen::Matrix4f::Identity();
  m.topLeftCorner<3, 3>() = pose.rotation.cast<float>();
  m.topRightCorner<3, 1>() = pose.translation.cast<float>();
  return m;
}

}  // namespace

void Renderer::draw(const Model& model, const State& state, const Camera& camera, const DrawOptions& options,
                    const std::vector<Index>& held, const std::vector<ColliderFrame>& colliders) {
  Geometry& g = *g_;
  const Index n = model.num_particles();
  const Eigen::Matrix4f vp = camera.view_projection().cast<float>();
  const Eigen::Matrix4f view = camera.view().cast<float>();

  glClearColor(0.86f, 0.88f, 0.91f, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDisable(GL_CULL_FACE);  // cloth has two sides
  glEnable(GL_BLEND);
  glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
  glEnable(GL_PROGRAM_POINT_SIZE);

  // Positions as floats, normals from them: every frame.
  g.position.resize(3 * static_cast<std::size_t>(n));
  for (Index i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) g.position[3 * i + k] = static_cast<float>(state.x(k, i));
  vertex_normals(state.x, g.triangles, g.normal);
  g.cloth.attribute(0, 3, g.position.data(), n);

  g.surface.use();
  const Eigen::Matrix4f identity = Eigen::Matrix4f::Identity();
  glUniformMatrix4fv(g.surface.uniform("model"), 1, GL_FALSE, identity.data());
  glUniformMatrix4fv(g.surface.uniform("view"), 1, GL_FALSE, view.data());
  glUniformMatrix4fv(g.surface.uniform("view_projection"), 1, GL_FALSE, vp.data());
  if (!g.triangles.empty()) {
    g.cloth.attribute(1, 3, g.normal.data(), n);
    glUniform3f(g.surface.uniform("back_tint"), 0.55f, 0.62f, 0.70f);
    glUniform1f(g.surface.uniform("specular"), 0.12f);
    // Pushed back a little so that the wireframe and particles on it stay visible.
    glEnable(GL_POLYGON_OFFSET_FILL);
    glPolygonOffset(1.0f, 1.0f);
    g.cloth.draw(GL_TRIANGLES);
    glDisable(GL_POLYGON_OFFSET_FILL);
  }
  if (options.colliders && g.colliders.vertices()) {
    glUniform3f(g.surface.uniform("back_tint"), 1.0f, 1.0f, 1.0f);
    glUniform1f(g.surface.uniform("specular"), 0.05f);
    // A deforming mesh collider's range of the soup is rewritten on the GPU from its vertices
    // (model frame) every frame; every other range stays as uploaded (a static mesh is not sent
    // again), and a range goes back to the mesh as declared once its collider no longer deforms.
    g.collider_deformed.resize(g.collider_first.size(), 0);
    for (std::size_t i = 0; i < g.collider_first.size(); ++i) {
      const Collider& c = model.colliders[i];
      const Positions* x = i < colliders.size() ? &colliders[i].vertices : nullptr;
      const bool deforms =
          x && x->cols() > 0 && c.kind == ColliderKind::Mesh && x->cols() == c.mesh->vertices.cols();
      const std::size_t first = g.collider_first[i], count = g.collider_count[i];
      if (deforms) {
        Soup part;
        add_mesh(part, *x, c.mesh->triangles);
        g.colliders.update(0, 3, part.position.data(), first, count);
        g.colliders.update(1, 3, part.normal.data(), first, count);
      } else if (g.collider_deformed[i]) {
        g.colliders.update(0, 3, g.collider_position.data() + 3 * first, first, count);
        g.colliders.update(1, 3, g.collider_normal.data() + 3 * first, first, count);
      }
      g.collider_deformed[i] = deforms;
    }
    for (std::size_t i = 0; i < g.collider_first.size(); ++i) {
      const Eigen::Matrix4f m = i < colliders.size() ? pose_matrix(colliders[i].pose) : identity;
      glUniformMatrix4fv(g.surface.uniform("model"), 1, GL_FALSE, m.data());
      g.colliders.draw_range(GL_TRIANGLES, g.collider_first[i], g.collider_count[i]);
    }
    glUniformMatrix4fv(g.surface.uniform("model"), 1, GL_FALSE, identity.data());
  }

  g.lines.use();
  glUniformMatrix4fv(g.lines.uniform("view_projection"), 1, GL_FALSE, vp.data());
  glUniform1f(g.lines.uniform("depth_bias"), 0.0f);
  if (options.grid) g.grid.draw(GL_LINES);
  glUniform1f(g.lines.uniform("depth_bias"), 2e-5f);
  if (options.wireframe && g.wire.index_count()) {
    g.wire.draw(GL_LINES);
  } else if (g.has_chain) {
    g.chain.draw(GL_LINES);
  }

  // Particles: all of them on request; particles of no triangle, pinned and held ones always.
  g.dot_color.resize(4 * static_cast<std::size_t>(n));
  bool any = false;
  for (Index i = 0; i < n; ++i) {
    Rgba c = kParticleColor;
    bool show = options.particles || !g.in_triangle[i];
    if (model.inv_mass[i] == 0) {
      c = kPinnedColor;
      show = true;
    }
    if (!show) c[3] = 0;
    std::copy(c.begin(), c.end(), g.dot_color.begin() + 4 * i);
    any = any || show;
  }
  for (Index i : held)
    if (i >= 0 && i < n) {
      std::copy(kHeldColor.begin(), kHeldColor.end(), g.dot_color.begin() + 4 * i);
      any = true;
    }
  if (any) {
    g.points.use();
    glUniformMatrix4fv(g.points.uniform("view_projection"), 1, GL_FALSE, vp.data());
    const double particles_on_screen = std::sqrt(static_cast<double>(std::max<Index>(n, 1)));
    glUniform1f(g.points.uniform("point_size"),
                static_cast<float>(std::clamp(0.25 * camera.height / particles_on_screen, 3.0, 9.0)));
    g.dots.attribute(1, 4, g.dot_color.data(), n);
    glDepthMask(GL_FALSE);
    g.dots.draw(GL_POINTS);
    glDepthMask(GL_TRUE);
  }
  glUseProgram(0);
}

}  // namespace csb::viewer
