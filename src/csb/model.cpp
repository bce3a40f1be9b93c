#include "csb/model.hpp"
#include "csb/format.hpp"

#include "csb/constraints/bending.hpp"
#include "csb/constraints/families.hpp"
#include "csb/constraints/volume.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <map>
#include <sstream>

namespace csb {

using detail::str;

std::uint64_t next_model_id() {
  static std::atomic<std::uint64_t> counter{0};
  return ++counter;
}

namespace {

// Masses (kg) of the particles of a mesh from their lumped measure (m, m² or m³): the total
// shared in proportion to it (MassSpec::Total), or the density times it (Density). A particle
// with no measure gets no mass: an error naming it.
std::vector<Real> lumped_masses(const MassSpec& spec, const std::vector<Real>& measure, const std::string& name,
                                const char* element, const char* holder) {
  Real total = 0;
  for (Real m : measure) total += m;
  std::vector<Real> mass(measure.size());
  for (std::size_t i = 0; i < measure.size(); ++i) {
    if (!(measure[i] > 0))
      throw MeshError(name + ": " + element + " " + std::to_string(i) + " belongs to no " + holder +
                      ", so mass and density give it no mass; give a per-particle mass or remove the " + element);
    mass[i] = spec.kind == MassSpec::Kind::Total ? spec.value * measure[i] / total : spec.value * measure[i];
  }
  return mass;
}

}  // namespace

State Model::initial_state() const {
  State s;
  s.x = rest_positions;
  s.v = Positions::Zero(3, num_particles());
  return s;
}

void ModelBuilder::require_particle(Index i, const std::string& what) const {
  if (i < 0 || i >= num_particles())
    throw InvalidArgument(what + ": particle index " + std::to_string(i) + " is out of range (the model has " +
                          std::to_string(num_particles()) + " particles)");
}

void ModelBuilder::require_stiffness(Real k, const std::string& what) const {
  if (!(k >= 0 && k <= 1))
    throw InvalidArgument(what + ": stiffness must be in [0, 1], got " + str(k));
}

void ModelBuilder::require_compliance(Real alpha, const std::string& what) const {
  if (!(alpha >= 0) || !std::isfinite(alpha))
    throw InvalidArgument(what + ": compliance must be a finite number >= 0 (0: hard), got " + str(alpha));
}

Index ModelBuilder::add_group(const std::string& name) {
  group_names_.push_back(name);
  self_collision_.push_back(0);
  return static_cast<Index>(group_names_.size() - 1);
}

Index ModelBuilder::add_particle(const Vec3& x, Real mass, Index group) {
  const std::string what = "particle " + std::to_string(num_particles());
  if (!x.allFinite()) throw InvalidArgument(what + ": position must be finite");
  if (!(mass > 0) || !std::isfinite(mass)) throw InvalidArgument(what + ": mass must be > 0 kg, got " + str(mass));
  if (group < 0 || group >= static_cast<Index>(group_names_.size()))
    throw InvalidArgument(what + ": group " + std::to_string(group) + " does not exist (add_group first)");
  points_.push_back(x);
  mass_.push_back(mass);
  pinned_.push_back(0);
  group_.push_back(group);
  thickness_.push_back(0);
  return num_particles() - 1;
}

MeshInstance ModelBuilder::add_mesh(const Mesh& input, const MeshOptions& options) {
  const std::string& name = input.name;
  if (options.stretch_stiffness) require_stiffness(*options.stretch_stiffness, name + " stretch");
  if (options.bending_stiffness) require_stiffness(*options.bending_stiffness, name + " bending");
  require_compliance(options.stretch_compliance, name + " stretch");
  require_compliance(options.bending_compliance, name + " bending");
  if (!(options.thickness >= 0) || !std::isfinite(options.thickness))
    throw InvalidArgument(name + ": thickness must be a finite collision radius >= 0 m, got " + str(options.thickness));
  if (!(options.mass.value > 0) || !std::isfinite(options.mass.value))
    throw InvalidArgument(name + ": " +
                          (options.mass.kind == MassSpec::Kind::Total     ? "mass must be > 0 kg"
                           : options.mass.kind == MassSpec::Kind::Density ? "density must be > 0 kg/m^2"
                                                                          : "particle mass must be > 0 kg") +
                          ", got " + str(options.mass.value));
  if (options.group >= static_cast<Index>(group_names_.size()))
    throw InvalidArgument(name + ": group " + std::to_string(options.group) + " does not exist");

  MeshInstance inst;
  CleanOptions keep_numbering;
  keep_numbering.weld = false;
  keep_numbering.drop_unreferenced = false;
  const Mesh mesh = clean(input, keep_numbering, &inst.report);
  const Index n = mesh.num_vertices();

  // Masses: lumped area (or length) for Total and Density.
  const std::vector<Real> mass =
      options.mass.kind == MassSpec::Kind::PerParticle
          ? std::vector<Real>(n, options.mass.value)
          : lumped_masses(options.mass, lumped_measure(mesh), name, "vertex", "triangle (or segment)");
  inst.group = options.group >= 0 ? options.group : add_group(name);
  inst.first_particle = num_particles();
  inst.num_particles = n;
  for (Index i = 0; i < n; ++i) add_particle(mesh.vertices.col(i), mass[i], inst.group);
  std::fill(thickness_.begin() + inst.first_particle, thickness_.end(), options.thickness);

  const Index f = inst.first_particle;
  for (const auto& t : mesh.triangles) triangles_.push_back({f + t[0], f + t[1], f + t[2]});
  inst.triangles.assign(triangles_.end() - static_cast<std::ptrdiff_t>(mesh.triangles.size()), triangles_.end());
  const Topology topo = topology(mesh);
  if (options.stretch_stiffness) {
    for (const auto& e : mesh.triangles.empty() ? topo.edges : sweep_order(topo.edges))
      add_distance(f + e[0], f + e[1], *options.stretch_stiffness, -1, 0, options.stretch_compliance);
    inst.num_distance = static_cast<Index>(topo.edges.size());
  }
  if (options.bending_stiffness) {
    for (const auto& q : topo.bending)
      add_bending(f + q[0], f + q[1], f + q[2], f + q[3], *options.bending_stiffness, {}, options.bending_compliance);
    inst.num_bending = static_cast<Index>(topo.bending.size());
  }
  return inst;
}

Index ModelBuilder::add_distance(Index i, Index j, Real stiffness, Real rest_length, int sense, Real compliance) {
  const std::string what = "distance constraint " + std::to_string(distance_.size()) + " (particles " +
                           std::to_string(i) + ", " + std::to_string(j) + ")";
  require_particle(i, what);
  require_particle(j, what);
  if (i == j) throw InvalidArgument(what + ": a distance constraint needs two different particles");
  require_stiffness(stiffness, what);
  require_compliance(compliance, what);
  if (sense < -1 || sense > 1) throw InvalidArgument(what + ": sense must be -1, 0 or +1, got " + std::to_string(sense));
  if (!std::isfinite(rest_length)) throw InvalidArgument(what + ": rest length must be finite");
  if (rest_length < 0) rest_length = (position(i) - position(j)).norm();
  if (!(rest_length > 0))
    throw InvalidArgument(what + ": zero rest length (coincident particles); a distance constraint needs a length > 0 m");
  distance_.particles.push_back({i, j});
  distance_.rest_length.push_back(rest_length);
  distance_.stiffness.push_back(stiffness);
  distance_.compliance.push_back(compliance);
  distance_.sense.push_back(static_cast<std::int8_t>(sense));
  return distance_.size() - 1;
}

Index ModelBuilder::add_bending(Index a, Index b, Index c, Index d, Real stiffness, std::optional<Real> rest_angle,
                                Real compliance) {
  const std::string what = "bending constraint " + std::to_string(bending_.size()) + " (particles " +
                           std::to_string(a) + ", " + std::to_string(b) + ", " + std::to_string(c) + ", " +
                           std::to_string(d) + ")";
  for (Index p : {a, b, c, d}) require_particle(p, what);
  if (a == b || a == c || a == d || b == c || b == d || c == d)
    throw InvalidArgument(what + ": needs four different particles");
  require_stiffness(stiffness, what);
  require_compliance(compliance, what);
  Vec3 grad[4];
  Real angle = 0;
  if (!dihedral_angle_and_gradient(position(a), position(b), position(c), position(d), angle, grad))
    throw InvalidArgument(what + ": degenerate at rest (zero-length edge or zero-area triangle)");
  if (rest_angle) {
    if (!std::isfinite(*rest_angle)) throw InvalidArgument(what + ": rest angle must be finite");
    angle = wrap_angle(*rest_angle);
  }
  bending_.particles.push_back({a, b, c, d});
  bending_.rest_angle.push_back(angle);
  bending_.stiffness.push_back(stiffness);
  bending_.compliance.push_back(compliance);
  return bending_.size() - 1;
}

Index ModelBuilder::add_tetrahedron(Index a, Index b, Index c, Index d, Real stiffness, Real compliance,
                                    std::optional<Real> rest_volume) {
  const std::string what = "volume constraint " + std::to_string(volume_.size()) + " (particles " +
                           std::to_string(a) + ", " + std::to_string(b) + ", " + std::to_string(c) + ", " +
                           std::to_string(d) + ")";
  for (Index p : {a, b, c, d}) require_particle(p, what);
  if (a == b || a == c || a == d || b == c || b == d || c == d)
    throw InvalidArgument(what + ": needs four different particles");
  require_stiffness(stiffness, what);
  require_compliance(compliance, what);
  const Real v = tet_volume(position(a), position(b), position(c), position(d));
  Real diag2 = 0;
  for (Index p : {b, c, d}) diag2 = std::max(diag2, (position(p) - position(a)).squaredNorm());
  // Relative to the tet's own size: its longest edge from a, cubed.
  if (!(std::abs(v) > kDegenerateTetVolume * diag2 * std::sqrt(diag2)))
    throw InvalidArgument(what + ": degenerate at rest (signed volume " + str(v) + " m³; flat or collapsed)");
  if (v < 0)
    throw InvalidArgument(what + ": negative signed volume " + str(v) +
                          " m³ (inverted): swap two of its particles so that d lies on the side of (b - a) x (c - a)");
  if (rest_volume && !(*rest_volume > 0 && std::isfinite(*rest_volume)))
    throw InvalidArgument(what + ": rest volume must be a finite volume > 0 m³, got " + str(*rest_volume));
  volume_.particles.push_back({a, b, c, d});
  volume_.rest_volume.push_back(rest_volume ? *rest_volume : v);
  volume_.stiffness.push_back(stiffness);
  volume_.compliance.push_back(compliance);
  return volume_.size() - 1;
}

MeshInstance ModelBuilder::add_tet_mesh(const TetMesh& input, const TetMeshOptions& options) {
  const std::string& name = input.name;
  if (options.stretch_stiffness) require_stiffness(*options.stretch_stiffness, name + " stretch");
  if (options.volume_stiffness) require_stiffness(*options.volume_stiffness, name + " volume");
  require_compliance(options.stretch_compliance, name + " stretch");
  require_compliance(options.volume_compliance, name + " volume");
  if (!(options.mass.value > 0) || !std::isfinite(options.mass.value))
    throw InvalidArgument(name + ": " +
                          (options.mass.kind == MassSpec::Kind::Total     ? "mass must be > 0 kg"
                           : options.mass.kind == MassSpec::Kind::Density ? "density must be > 0 kg/m^3"
                                                                          : "particle mass must be > 0 kg") +
                          ", got " + str(options.mass.value));
  if (options.group >= static_cast<Index>(group_names_.size()))
    throw InvalidArgument(name + ": group " + std::to_string(options.group) + " does not exist");
  validate(input);

  MeshInstance inst;
  TetMesh mesh = input;
  const Index n = mesh.num_points();
  std::vector<Real> vol = tet_volumes(mesh);
  const Real diag = bounding_box_diagonal(mesh.points);
  const Real tiny = kDegenerateTetVolume * diag * diag * diag;
  Index first_flipped = -1;
  for (Index t = 0; t < mesh.num_tets(); ++t) {
    if (!(std::abs(vol[t]) > tiny))
      throw MeshError(name + ": tet " + std::to_string(t) + " is degenerate (flat or collapsed): signed volume " +
                      str(vol[t]) + " m³, below " + str(kDegenerateTetVolume) +
                      " x the bounding-box diagonal cubed (" + str(tiny) + " m³)");
    if (vol[t] < 0) {
      // Inverted (the file's convention or a mistake): re-orient rather than simulate a tet that
      // the volume constraint would try to keep inside out.
      std::swap(mesh.tets[t][2], mesh.tets[t][3]);
      vol[t] = -vol[t];
      if (first_flipped < 0) first_flipped = t;
      ++inst.flipped_tets;
    }
  }
  inst.report.input_vertices = n;
  if (inst.flipped_tets > 0)
    inst.report.warnings.push_back(name + ": " + std::to_string(inst.flipped_tets) +
                                   " inverted tets (negative signed volume, first: tet " + std::to_string(first_flipped) +
                                   ") were re-oriented by swapping their last two points");

  std::vector<Real> mass(n, options.mass.value);
  if (options.mass.kind != MassSpec::Kind::PerParticle) {
    std::vector<Real> measure(n, 0.0);  // a quarter of each adjacent tet's volume
    for (Index t = 0; t < mesh.num_tets(); ++t)
      for (Index p : mesh.tets[t]) measure[p] += vol[t] / 4;
    mass = lumped_masses(options.mass, measure, name, "point", "tet");
  }
  inst.group = options.group >= 0 ? options.group : add_group(name);
  inst.first_particle = num_particles();
  inst.num_particles = n;
  for (Index i = 0; i < n; ++i) add_particle(mesh.points.col(i), mass[i], inst.group);
  const Index f = inst.first_particle;

  for (const Triangle& t : tet_surface(mesh)) {
    triangles_.push_back({f + t[0], f + t[1], f + t[2]});
    inst.triangles.push_back(triangles_.back());
  }
  if (options.stretch_stiffness) {
    std::vector<Edge> edges;
    for (const Tet& q : mesh.tets)
      for (int a = 0; a < 4; ++a)
        for (int b = a + 1; b < 4; ++b) edges.push_back({std::min(q[a], q[b]), std::max(q[a], q[b])});
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    for (const Edge& e : sweep_order(edges))
      add_distance(f + e[0], f + e[1], *options.stretch_stiffness, -1, 0, options.stretch_compliance);
    inst.num_distance = static_cast<Index>(edges.size());
  }
  if (options.volume_stiffness) {
    for (const Tet& q : mesh.tets)
      add_tetrahedron(f + q[0], f + q[1], f + q[2], f + q[3], *options.volume_stiffness, options.volume_compliance);
    inst.num_volume = mesh.num_tets();
  }
  return inst;
}

Index ModelBuilder::add_balloon(const std::vector<Triangle>& triangles, Real pressure, Real stiffness,
                                Real compliance) {
  const std::string what = "balloon " + std::to_string(balloons_.size());
  if (triangles.empty()) throw InvalidArgument(what + ": needs the triangles of a closed surface, got none");
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    const Triangle& tri = triangles[t];
    for (Index p : tri) require_particle(p, what + " triangle " + std::to_string(t));
    if (tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2])
      throw InvalidArgument(what + ": triangle " + std::to_string(t) + " repeats a particle");
  }
  if (!(pressure >= 0) || !std::isfinite(pressure))
    throw InvalidArgument(what + ": pressure (the factor k_pressure on the rest volume) must be finite and >= 0, got " +
                          str(pressure));
  require_stiffness(stiffness, what);
  require_compliance(compliance, what);
  // Closed and consistently wound: every edge used once in each direction.
  std::map<Edge, std::pair<int, int>> uses;  // (min, max) -> (times a->b with a < b, times b->a)
  for (const Triangle& tri : triangles)
    for (int k = 0; k < 3; ++k) {
      const Index a = tri[k], b = tri[(k + 1) % 3];
      auto& u = uses[{std::min(a, b), std::max(a, b)}];
      (a < b ? u.first : u.second) += 1;
    }
  Index boundary = 0, non_manifold = 0, misoriented = 0;
  std::string example;
  for (const auto& [e, u] : uses) {
    const int total = u.first + u.second;
    const std::string edge = "(" + std::to_string(e[0]) + ", " + std::to_string(e[1]) + ")";
    if (total == 1) {
      if (!boundary++ && example.empty()) example = "boundary edge " + edge;
    } else if (total > 2) {
      if (!non_manifold++ && example.empty()) example = "edge " + edge + " shared by " + std::to_string(total) + " triangles";
    } else if (u.first != 1) {
      if (!misoriented++ && example.empty()) example = "edge " + edge + " used twice in the same direction";
    }
  }
  if (boundary + non_manifold + misoriented > 0)
    throw InvalidArgument(what + ": the surface is not closed and consistently wound: " + std::to_string(boundary) +
                          " boundary edges, " + std::to_string(non_manifold) + " non-manifold edges, " +
                          std::to_string(misoriented) + " edges with inconsistent winding (e.g. " + example + ")");
  // Local numbering: the balloon's particles in increasing order.
  std::vector<Index> particles;
  for (const Triangle& tri : triangles) particles.insert(particles.end(), tri.begin(), tri.end());
  std::sort(particles.begin(), particles.end());
  particles.erase(std::unique(particles.begin(), particles.end()), particles.end());
  std::vector<Triangle> local;
  for (const Triangle& tri : triangles) {
    Triangle l;
    for (int k = 0; k < 3; ++k)
      l[k] = static_cast<Index>(std::lower_bound(particles.begin(), particles.end(), tri[k]) - particles.begin());
    local.push_back(l);
  }
  Positions x(3, static_cast<Eigen::Index>(particles.size()));
  std::vector<Index> identity(particles.size());
  for (std::size_t k = 0; k < particles.size(); ++k) {
    x.col(static_cast<Eigen::Index>(k)) = position(particles[k]);
    identity[k] = static_cast<Index>(k);
  }
  const Real v0 = enclosed_volume(x.data(), identity.data(), local.data(), static_cast<Index>(local.size()));
  const Real diag = bounding_box_diagonal(x);
  if (!(std::abs(v0) > kDegenerateTetVolume * diag * diag * diag))
    throw InvalidArgument(what + ": the surface encloses no volume (" + str(v0) + " m³): it is flat or collapsed");
  if (v0 < 0)
    throw InvalidArgument(what + ": the surface encloses a negative volume (" + str(v0) +
                          " m³): its triangles are wound inwards; reverse the winding of every triangle");
  balloons_.particles.insert(balloons_.particles.end(), particles.begin(), particles.end());
  balloons_.particle_offsets.push_back(static_cast<Index>(balloons_.particles.size()));
  balloons_.triangles.insert(balloons_.triangles.end(), local.begin(), local.end());
  balloons_.triangle_offsets.push_back(static_cast<Index>(balloons_.triangles.size()));
  balloons_.rest_volume.push_back(v0);
  balloons_.pressure.push_back(pressure);
  balloons_.stiffness.push_back(stiffness);
  balloons_.compliance.push_back(compliance);
  return balloons_.size() - 1;
}

void ModelBuilder::pin(Index i) {
  require_particle(i, "pin");
  pinned_[i] = 1;
}

Index ModelBuilder::attach(Index i, const Vec3& target, Real stiffness, Real compliance) {
  const std::string what = "attachment " + std::to_string(attached_.size()) + " (particle " + std::to_string(i) + ")";
  require_particle(i, what);
  if (!target.allFinite()) throw InvalidArgument(what + ": target must be finite");
  require_stiffness(stiffness, what);
  require_compliance(compliance, what);
  attached_.push_back(i);
  attachment_targets_.push_back(target);
  attachment_stiffness_.push_back(stiffness);
  attachment_compliance_.push_back(compliance);
  return static_cast<Index>(attached_.size() - 1);
}

void ModelBuilder::add_family(std::unique_ptr<FamilyBatch> batch) {
  if (!batch) throw InvalidArgument("add_family: no family given");
  const std::string& name = batch->info().name;
  bool taken = false;
  for (const FamilyInfo* i : families()) taken = taken || i->name == name;
  for (const auto& b : families_.runtime) taken = taken || b->info().name == name;
  if (name.empty() || taken)
    throw InvalidArgument("add_family: a constraint family needs a name of its own, and '" + name +
                          "' is " + (name.empty() ? "empty" : "taken"));
  if (batch->size() != 0) throw InvalidArgument("add_family: family '" + name + "' must be added empty");
  families_.runtime.push_back(std::move(batch));
}

Index ModelBuilder::add_constraint(const std::string& family, const std::vector<Index>& particles,
                                   const std::vector<Real>& params, Real stiffness, Real compliance) {
  FamilyBatch* found = nullptr;
  for (const auto& b : families_.runtime)
    if (b->info().name == family) found = b.get();
  if (!found) {
    const Index f = family_index(family);  // an unknown name: the error lists the known ones
    if (families_.batches.empty())
      for (const FamilyInfo* i : families()) families_.batches.push_back(i->make());
    found = families_.batches[f].get();
  }
  FamilyBatch& batch = *found;
  const FamilyInfo& info = batch.info();
  std::string what = info.label + " " + std::to_string(batch.size()) + " (particles";
  for (std::size_t k = 0; k < particles.size(); ++k) what += (k ? ", " : " ") + std::to_string(particles[k]);
  what += ")";
  if (static_cast<int>(particles.size()) != info.arity)
    throw InvalidArgument(what + ": a " + info.label + " joins " + std::to_string(info.arity) + " particles, got " +
                          std::to_string(particles.size()));
  for (std::size_t k = 0; k < particles.size(); ++k) {
    require_particle(particles[k], what);
    for (std::size_t j = 0; j < k; ++j)
      if (particles[j] == particles[k]) throw InvalidArgument(what + ": repeats particle " + std::to_string(particles[k]));
  }
  if (static_cast<int>(params.size()) != info.num_params()) {
    std::string names;
    for (const std::string& n : info.param_names) names += (names.empty() ? "" : ", ") + n;
    throw InvalidArgument(what + ": needs " + std::to_string(info.num_params()) + " parameters (" + names + "), got " +
                          std::to_string(params.size()));
  }
  const std::string wrong = batch.check(params.data());
  if (!wrong.empty()) throw InvalidArgument(what + ": " + wrong);
  require_stiffness(stiffness, what);
  if (!(compliance >= 0) || !std::isfinite(compliance))
    throw InvalidArgument(what + ": compliance must be a finite number >= 0 " + info.compliance_unit + " (0: hard), got " +
                          str(compliance));
  batch.append(particles.data(), params.data(), stiffness, compliance);
  return batch.size() - 1;
}

// ------------------------------------------------------------------------------------ collisions

std::string ModelBuilder::collider_what(ColliderKind kind, const std::string& name) const {
  return "collider " + std::to_string(colliders_.size()) + " (" + kind_name(kind) + (name.empty() ? "" : " '" + name + "'") +
         ")";
}

Index ModelBuilder::push_collider(Collider c, const std::string& what) {
  const ContactMaterial& m = c.material;
  for (const auto& [value, label] : {std::pair{m.friction_static, "friction_static"},
                                     std::pair{m.friction_kinetic, "friction_kinetic"},
                                     std::pair{m.restitution, "restitution"}})
    if (!std::isfinite(value)) throw InvalidArgument(what + ": " + label + " must be finite, got " + str(value));
  if (!(m.friction_kinetic >= 0))
    throw InvalidArgument(what + ": friction_kinetic must be >= 0, got " + str(m.friction_kinetic));
  if (!(m.friction_static >= m.friction_kinetic))
    throw InvalidArgument(what + ": friction_static (" + str(m.friction_static) +
                          ") must be >= friction_kinetic (" + str(m.friction_kinetic) + ")");
  if (!(m.restitution >= 0 && m.restitution <= 1))
    throw InvalidArgument(what + ": restitution must be in [0, 1], got " + str(m.restitution));
  if (c.name.empty()) c.name = std::string(kind_name(c.kind)) + " " + std::to_string(colliders_.size());
  colliders_.push_back(std::move(c));
  return static_cast<Index>(colliders_.size() - 1);
}

namespace {

void require_point(const Vec3& x, const std::string& what, const char* label) {
  if (!x.allFinite()) throw InvalidArgument(what + ": " + label + " must be finite (m), got " + str(x));
}

void require_size(Real r, const std::string& what, const char* label) {
  if (!(r > 0) || !std::isfinite(r)) throw InvalidArgument(what + ": " + label + " must be a finite length > 0 m, got " + str(r));
}

}  // namespace

Index ModelBuilder::add_plane(const Vec3& point, const Vec3& normal, const ContactMaterial& material,
                              const std::string& name) {
  const std::string what = collider_what(ColliderKind::Plane, name);
  require_point(point, what, "point");
  if (!normal.allFinite()) throw InvalidArgument(what + ": normal must be finite, got " + str(normal));
  if (!(normal.norm() > 0)) throw InvalidArgument(what + ": normal must be a non-zero vector, got " + str(normal));
  Collider c;
  c.kind = ColliderKind::Plane;
  c.name = name;
  c.material = material;
  c.point = point;
  c.normal = normal.normalized();
  return push_collider(std::move(c), what);
}

Index ModelBuilder::add_sphere(const Vec3& center, Real radius, const ContactMaterial& material,
                               const std::string& name) {
  const std::string what = collider_what(ColliderKind::Sphere, name);
  require_point(center, what, "center");
  require_size(radius, what, "radius");
  Collider c;
  c.kind = ColliderKind::Sphere;
  c.name = name;
  c.material = material;
  c.center = center;
  c.radius = radius;
  return push_collider(std::move(c), what);
}

Index ModelBuilder::add_capsule(const Vec3& a, const Vec3& b, Real radius, const ContactMaterial& material,
                                const std::string& name) {
  const std::string what = collider_what(ColliderKind::Capsule, name);
  require_point(a, what, "a");
  require_point(b, what, "b");
  require_size(radius, what, "radius");
  if (!((b - a).norm() > 0))
    throw InvalidArgument(what + ": the ends a and b coincide (axis length 0 m); use add_sphere for a ball");
  Collider c;
  c.kind = ColliderKind::Capsule;
  c.name = name;
  c.material = material;
  c.a = a;
  c.b = b;
  c.radius = radius;
  return push_collider(std::move(c), what);
}

Index ModelBuilder::add_box(const Vec3& center, const Vec3& half_extents, const Mat3& rotation,
                            const ContactMaterial& material, const std::string& name) {
  const std::string what = collider_what(ColliderKind::Box, name);
  require_point(center, what, "center");
  static const char* axes[3] = {"half_extents[0]", "half_extents[1]", "half_extents[2]"};
  for (int k = 0; k < 3; ++k) require_size(half_extents[k], what, axes[k]);
  if (!rotation.allFinite()) throw InvalidArgument(what + ": rotation must be finite");
  // A rotation up to round-off: orthonormal columns and no reflection.
  if ((rotation.transpose() * rotation - Mat3::Identity()).cwiseAbs().maxCoeff() > 1e-9 || !(rotation.determinant() > 0))
    throw InvalidArgument(what + ": rotation must be a rotation matrix (orthonormal columns, determinant +1)");
  Collider c;
  c.kind = ColliderKind::Box;
  c.name = name;
  c.material = material;
  c.center = center;
  c.half_extents = half_extents;
  c.rotation = rotation;
  return push_collider(std::move(c), what);
}

Index ModelBuilder::add_collider_mesh(const Mesh& input, const ContactMaterial& material, const std::string& name) {
  const std::string label = name.empty() ? input.name : name;
  const std::string what = collider_what(ColliderKind::Mesh, label);
  Mesh mesh;
  try {
    mesh = clean(input, CleanOptions{});
  } catch (const MeshError& e) {
    throw InvalidArgument(what + ": " + e.what());
  }
  if (mesh.triangles.empty())
    throw InvalidArgument(what + ": the mesh has no (non-degenerate) triangles to collide with");
  auto m = std::make_shared<ColliderMesh>();
  m->vertices = mesh.vertices;
  m->triangles = mesh.triangles;
  for (const auto& t : m->triangles) {
    const Vec3 a = m->vertices.col(t[0]), b = m->vertices.col(t[1]), c = m->vertices.col(t[2]);
    m->normals.push_back((b - a).cross(c - a).normalized());
  }
  m->grid = build_triangle_grid(m->vertices, m->triangles);
  m->skin = 1e-9 * std::max(Real(1), bounding_box_diagonal(m->vertices));
  Collider c;
  c.kind = ColliderKind::Mesh;
  c.name = label;
  c.material = material;
  c.mesh = std::move(m);
  return push_collider(std::move(c), what);
}

void ModelBuilder::set_thickness(Index group, Real thickness) {
  if (group < 0 || group >= static_cast<Index>(group_names_.size()))
    throw InvalidArgument("set_thickness: group " + std::to_string(group) + " does not exist");
  if (!(thickness >= 0) || !std::isfinite(thickness))
    throw InvalidArgument("set_thickness: group " + std::to_string(group) + " ('" + group_names_[group] +
                          "'): thickness must be a finite collision radius >= 0 m, got " + str(thickness));
  for (Index i = 0; i < num_particles(); ++i)
    if (group_[i] == group) thickness_[i] = thickness;
}

void ModelBuilder::enable_self_collision(Index group, Real thickness) {
  if (group < 0 || group >= static_cast<Index>(group_names_.size()))
    throw InvalidArgument("enable_self_collision: group " + std::to_string(group) + " does not exist");
  const std::string what = "enable_self_collision: group " + std::to_string(group) + " ('" + group_names_[group] + "')";
  if (!(thickness > 0) || !std::isfinite(thickness))
    throw InvalidArgument(what + ": thickness must be a finite distance > 0 m, got " + str(thickness));
  bool any = false;
  for (const auto& t : triangles_) any = any || group_[t[0]] == group;
  if (!any) throw InvalidArgument(what + ": the group has no triangles (add its mesh first)");
  self_collision_[group] = thickness;
}

std::shared_ptr<const Model> ModelBuilder::build() const {
  if (num_particles() == 0) throw InvalidArgument("the model has no particles");
  // A particle that can move may not start inside a solid collider: the first step would have
  // to throw it out (a mesh sheet has no inside; starting closer than the thickness is allowed
  // and corrected by the first step's contacts).
  for (std::size_t c = 0; c < colliders_.size(); ++c) {
    if (colliders_[c].kind == ColliderKind::Mesh) continue;
    for (Index i = 0; i < num_particles(); ++i) {
      if (pinned_[i]) continue;
      const Real d = signed_distance(colliders_[c], points_[i]);
      if (d < 0)
        throw InvalidArgument("particle " + std::to_string(i) + " starts inside collider " + std::to_string(c) + " (" +
                              kind_name(colliders_[c].kind) + " '" + colliders_[c].name + "'), " + str(-d) +
                              " m below its surface; move it out or pin it");
    }
  }
  auto model = std::make_shared<Model>();
  const Index n = num_particles();
  model->id = next_model_id();
  model->rest_positions.resize(3, n);
  for (Index i = 0; i < n; ++i) model->rest_positions.col(i) = points_[i];
  model->mass = mass_;
  model->inv_mass.resize(n);
  for (Index i = 0; i < n; ++i) model->inv_mass[i] = pinned_[i] ? 0.0 : 1.0 / mass_[i];
  model->group = group_;
  model->group_names = group_names_;
  // Particles of each group, in index order (CSR).
  const Index g = static_cast<Index>(group_names_.size());
  model->group_offsets.assign(g + 1, 0);
  for (Index i = 0; i < n; ++i) ++model->group_offsets[group_[i] + 1];
  for (Index k = 0; k < g; ++k) model->group_offsets[k + 1] += model->group_offsets[k];
  model->group_particles.resize(n);
  std::vector<Index> cursor(model->group_offsets.begin(), model->group_offsets.end() - 1);
  for (Index i = 0; i < n; ++i) model->group_particles[cursor[group_[i]]++] = i;
  model->triangles = triangles_;
  model->distance = distance_;
  model->bending = bending_;
  model->volume = volume_;
  model->balloons = balloons_;
  model->colliders = colliders_;
  model->thickness = thickness_;
  model->self_collision_thickness = self_collision_;
  model->attachments.particle = attached_;
  model->attachments.stiffness = attachment_stiffness_;
  model->attachments.compliance = attachment_compliance_;
  model->attachments.target.resize(3, static_cast<Eigen::Index>(attached_.size()));
  for (std::size_t k = 0; k < attached_.size(); ++k)
    model->attachments.target.col(static_cast<Eigen::Index>(k)) = attachment_targets_[k];
  for (std::size_t f = 0; f < families().size(); ++f)
    model->families.push_back(families_.batches.empty() ? families()[f]->make() : families_.batches[f]->clone());
  for (const auto& b : families_.runtime) model->families.push_back(b->clone());
  colour_batches(*model);
  return model;
}

namespace {

template <class T>
std::size_t bytes(const std::vector<T>& v) {
  return v.capacity() * sizeof(T);
}

std::size_t bytes(const Colouring& c) {
  return bytes(c.order) + bytes(c.colour_offsets) + bytes(c.serial_colours) + bytes(c.group_colours);
}

}  // namespace

ModelMemory model_memory(const Model& m) {
  ModelMemory r;
  r.particles = sizeof(Real) * static_cast<std::size_t>(m.rest_positions.size()) + bytes(m.mass) + bytes(m.inv_mass) +
                bytes(m.group) + bytes(m.group_particles) + bytes(m.thickness) + bytes(m.part);
  const auto& d = m.distance;
  r.distance = bytes(d.particles) + bytes(d.rest_length) + bytes(d.stiffness) + bytes(d.compliance) + bytes(d.sense) +
               bytes(d.colours);
  const auto& b = m.bending;
  r.bending = bytes(b.particles) + bytes(b.rest_angle) + bytes(b.stiffness) + bytes(b.compliance) + bytes(b.colours);
  const auto& v = m.volume;
  r.volume = bytes(v.particles) + bytes(v.rest_volume) + bytes(v.stiffness) + bytes(v.compliance) + bytes(v.colours);
  const auto& p = m.balloons;
  r.balloons = bytes(p.particle_offsets) + bytes(p.particles) + bytes(p.triangle_offsets) + bytes(p.triangles) +
               bytes(p.rest_volume) + bytes(p.pressure) + bytes(p.stiffness) + bytes(p.compliance);
  const auto& a = m.attachments;
  r.attachments = bytes(a.particle) + sizeof(Real) * static_cast<std::size_t>(a.target.size()) + bytes(a.stiffness) +
                  bytes(a.compliance) + bytes(a.colours);
  for (const auto& f : m.families) r.families += f->bytes();
  r.other = bytes(m.triangles) + bytes(m.group_offsets) + bytes(m.self_collision_thickness) +
            m.colliders.capacity() * sizeof(Collider);
  return r;
}

}  // namespace csb
