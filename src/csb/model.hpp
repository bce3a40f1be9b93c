// csb — the immutable Model (particles at rest, masses, one batch per constraint type), the
// mutable State (positions, velocities, time) and the ModelBuilder that makes a Model.
//
// Particles of every mesh live in one pool, structure of arrays; a mesh keeps no identity in it
// except its group index, so that groups can differ in mass and be damped separately.
#pragma once

#include "csb/collision/collision.hpp"
#include "csb/constraints/family.hpp"
#include "csb/mesh.hpp"
#include "csb/tetmesh.hpp"
#include "csb/types.hpp"

#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace csb {

// Every constraint carries two material parameters:
//  - stiffness k in [0, 1], dimensionless: the fraction of the violation one PBD projection
//    removes (Müller 2007 §3.3); it is what the PBD stepper uses;
//  - compliance α >= 0 in SI units (m/N for lengths, 1/(N m) = rad²/J for angles): the inverse
//    of a physical stiffness, with potential energy C²/(2α); 0 is a hard constraint (m⁶/J for
//    volumes, whose C is in m³). It is what
//    the reference integrator (and XPBD) use, so that they model the same material.

// Graph colouring of one constraint batch: the constraints of one colour share no
// particle, so that a Gauss-Seidel sweep may project them in any order, or at once (SIMD lanes,
// threads), with the same result. Computed when the Model is built; the batch's arrays stay in
// the order the constraints were added (every index into a batch is that order's), `order`
// lists them colour by colour. Within a group (below), colours smaller than kMinColourSize (for
// the parts and interfaces of a model of several parts, kMinTaskColourSize) and constraints that
// find no free colour among the first kMaxColours go to a last, serial colour
// whose constraints may share particles and are projected one after the other, in `order`. A
// small model (a chain, a pendulum) is then a single serial colour: the sequential order as built.
//
// Groups (the sweep's schedule, see colour_batches): the colours are grouped, group g owning
// colours [group_colours[g], group_colours[g + 1]). A model's particles are split into
// `Model::num_parts` parts (colour_batches); for P parts every batch has 2P groups:
//   g in [0, P)       constraints whose particles all lie in part g (the part's interior);
//   g = P + i, i < P-1 constraints between parts i and i + 1 (interface i);
//   g = 2P - 1        the rest (particles in non-adjacent parts, or more than two parts).
// Interiors share no particle with each other, nor do interfaces of the same parity, so one
// thread can sweep a whole group (every batch's colours of it) while another sweeps another:
// three barriers per sweep instead of one per colour.
struct Colouring {
  std::vector<Index> order;                  // constraint indices, colour by colour, increasing within a colour
  std::vector<Index> colour_offsets{0};      // colour k is order[colour_offsets[k] .. [k+1])
  std::vector<std::uint8_t> serial_colours;  // 1: colour k's constraints may share particles (projected in order)
  std::vector<Index> group_colours{0, 0};    // group g's colours: [group_colours[g], group_colours[g + 1])
  Index num_colours() const { return static_cast<Index>(colour_offsets.size()) - 1; }
  Index num_groups() const { return static_cast<Index>(group_colours.size()) - 1; }
  bool serial(Index k) const { return serial_colours[static_cast<std::size_t>(k)] != 0; }
};

constexpr Index kMaxColours = 64;
constexpr Index kMinColourSize = 64;
constexpr Index kMinTaskColourSize = 8;  // in a part or an interface of a model of several parts
// Parts of a model: one per kParticlesPerPart particles, at most kMaxParts. Fixed by the model,
// never by the thread count, so that the projection order (and the result) is the same with
// any number of threads; 8 parts keep up to 8 threads busy on the interiors. (512: a 32x32
// cloth has two parts, and two threads sweep it in 0.59 ms a frame at 10 x 1 against 1.19 on one.)
constexpr Index kParticlesPerPart = 512;
constexpr Index kMaxParts = 8;

// Greedy first-fit colouring in constraint order (deterministic): constraint c of `count`, with
// particles particles[arity c .. arity c + arity), takes the lowest colour none of its particles
// has yet. Then colours under min_colour_size merge into the serial colour. One group.
Colouring colour_constraints(const Index* particles, int arity, Index count, Index num_particles,
                             Index min_colour_size = kMinColourSize);

// Distance constraints: mesh edges (stretch), springs, chain links. Plain arrays, one entry per
// constraint, in the order they were added; `colours` is the projection order.
struct DistanceBatch {
  std::vector<Edge> particles;      // (i, j)
  std::vector<Real> rest_length;    // m
  std::vector<Real> stiffness;      // dimensionless, in [0, 1] (Müller 2007 §3.3)
  std::vector<Real> compliance;     // m/N, >= 0
  std::vector<std::int8_t> sense;   // 0: C = 0, +1: C >= 0, -1: C <= 0 (see constraints/distance.hpp)
  Colouring colours;
  Index size() const { return static_cast<Index>(particles.size()); }
};

// Dihedral bending across the edge (a, b) with opposite vertices c and d.
struct BendingBatch {
  std::vector<std::array<Index, 4>> particles;  // (a, b, c, d)
  std::vector<Real> rest_angle;                 // rad, signed (see constraints/bending.hpp)
  std::vector<Real> stiffness;                  // dimensionless, in [0, 1]
  std::vector<Real> compliance;                 // rad²/J = 1/(N m), >= 0
  Colouring colours;
  Index size() const { return static_cast<Index>(particles.size()); }
};

// Tetrahedral volume constraints C = V - V0 (see constraints/volume.hpp).
struct VolumeBatch {
  std::vector<std::array<Index, 4>> particles;  // (p0, p1, p2, p3), positively oriented at rest
  std::vector<Real> rest_volume;                // m³, > 0
  std::vector<Real> stiffness;                  // dimensionless, in [0, 1]
  std::vector<Real> compliance;                 // m⁶/J, >= 0
  Colouring colours;
  Index size() const { return static_cast<Index>(particles.size()); }
};

// Overpressure constraints over closed surfaces (Müller 2007 §4.5), C = V - pressure V0, one
// constraint per balloon. Balloon b moves particles[particle_offsets[b] .. [b+1]) and has the
// triangles triangles[triangle_offsets[b] .. [b+1]), whose indices point into its own particle
// list (local numbering), wound outwards.
struct BalloonBatch {
  std::vector<Index> particle_offsets{0};
  std::vector<Index> particles;
  std::vector<Index> triangle_offsets{0};
  std::vector<Triangle> triangles;
  std::vector<Real> rest_volume;  // m³, V0 > 0, enclosed at build time
  std::vector<Real> pressure;     // dimensionless k_pressure >= 0: target volume k_pressure V0
  std::vector<Real> stiffness;    // dimensionless, in [0, 1]
  std::vector<Real> compliance;   // m⁶/J, >= 0
  Index size() const { return static_cast<Index>(rest_volume.size()); }
  Index num_particles(Index b) const { return particle_offsets[b + 1] - particle_offsets[b]; }
  Index num_triangles(Index b) const { return triangle_offsets[b + 1] - triangle_offsets[b]; }
};

// Particles held at points fixed in the world.
struct AttachmentBatch {
  std::vector<Index> particle;
  Positions target;                 // m, 3 x count
  std::vector<Real> stiffness;      // dimensionless, in [0, 1]
  std::vector<Real> compliance;     // m/N, >= 0
  Colouring colours;
  Index size() const { return static_cast<Index>(particle.size()); }
};

// Mutable simulation state; sized for one Model.
struct State {
  Positions x;            // m, 3 x N
  Positions v;            // m/s, 3 x N
  Real t = 0;             // s
  std::int64_t step = 0;  // number of completed steps
};

// Held by std::shared_ptr wherever it is shared (ModelBuilder::build, tear, the viewer, Python);
// enable_shared_from_this lets a reference handed to a user's method (a Python Integrator) keep
// the model alive if the method keeps it.
class Model : public std::enable_shared_from_this<Model> {
 public:
  Index num_particles() const { return static_cast<Index>(mass.size()); }
  Index num_constraints() const {
    Index n = distance.size() + bending.size() + volume.size() + balloons.size() + attachments.size();
    for (const auto& f : families) n += f->size();
    return n;
  }
  // The batch of the constraint family of that name (constraints/families.hpp), or null.
  const FamilyBatch* family(const std::string& name) const {
    for (const auto& f : families)
      if (f->info().name == name) return f.get();
    return nullptr;
  }
  // Whether a family must be projected by the caller's thread alone (FamilyInfo::serial_only):
  // the steppers then run on one thread.
  bool serial_families() const {
    for (const auto& f : families)
      if (f->info().serial_only && f->size() > 0) return true;
    return false;
  }
  Index num_groups() const { return static_cast<Index>(group_names.size()); }
  // Rest positions, zero velocities, t = 0.
  State initial_state() const;

  std::uint64_t id = 0;              // unique per built model; lets steppers cache per-model data
  Index num_parts = 1;               // parts of the particles the batches' colourings are grouped by (Colouring)
  std::vector<Index> part;           // part of each particle
  // The interfaces (i: between parts i and i + 1) in phases: no two interfaces of one phase
  // share a particle, so threads may sweep them at once (parts thicker than an element: one phase).
  std::vector<std::vector<Index>> interface_phases;
  Positions rest_positions;          // m, 3 x N
  std::vector<Real> mass;            // kg, > 0 (kept for pinned particles too)
  std::vector<Real> inv_mass;        // 1/kg; 0 for a pinned particle
  std::vector<Index> group;          // group of each particle
  std::vector<std::string> group_names;
  std::vector<Index> group_offsets;  // particles of group g: group_particles[group_offsets[g] .. [g+1])
  std::vector<Index> group_particles;
  std::vector<Triangle> triangles;   // surface triangles, for output and rendering
  DistanceBatch distance;
  BendingBatch bending;
  VolumeBatch volume;
  BalloonBatch balloons;
  AttachmentBatch attachments;
  // One batch per constraint family (constraints/families.cpp's list, in its order): the kinds
  // added through the family mechanism (tethers, ...), projected after the batches above.
  std::vector<std::shared_ptr<const FamilyBatch>> families;
  // Collisions (collision.hpp): static colliders, each particle's collision radius, and per group
  // the self-collision thickness h of its cloth (0: the group does not collide with itself).
  std::vector<Collider> colliders;
  std::vector<Real> thickness;                 // m, >= 0, per particle
  std::vector<Real> self_collision_thickness;  // m, per group
};

// A fresh Model::id, for every model built or derived (e.g. by tearing).
std::uint64_t next_model_id();

// (Re)computes the parts and the colouring of every batch of `model` (distance, bending, volume,
// attachments; balloons are one constraint each and stay serial). The parts are runs of equal
// particle count: of consecutive indices, or slabs along x, y or z of the rest positions (ties
// by index), whichever leaves the fewest constraints outside the parts' interiors.
// ModelBuilder::build and tear call it (solver/colouring.cpp, with colour_constraints).
void colour_batches(Model& model);

// Bytes the model's arrays hold (from their capacities), split into what belongs to the
// particles and to each constraint type (its colouring included).
struct ModelMemory {
  std::size_t particles = 0, distance = 0, bending = 0, volume = 0, balloons = 0, attachments = 0, families = 0,
              other = 0;
  std::size_t total() const {
    return particles + distance + bending + volume + balloons + attachments + families + other;
  }
};
ModelMemory model_memory(const Model& model);

// How a mesh's particles get their mass.
struct MassSpec {
  enum class Kind { Total, Density, PerParticle };
  Kind kind = Kind::Total;
  // Total: kg for the whole mesh, shared in proportion to each vertex's lumped area (or length).
  // Density: kg/m² for a surface (kg/m for a mesh of lines), times the lumped area (length).
  // PerParticle: kg for every particle.
  Real value = 1.0;
};

struct MeshOptions {
  Index group = -1;  // existing group, or -1 for a new group named after the mesh
  MassSpec mass;
  // Stiffness in [0, 1] of the distance constraint on every unique edge; none: no stretch.
  std::optional<Real> stretch_stiffness = Real(1);
  Real stretch_compliance = 0;   // m/N
  // Stiffness in [0, 1] of the bending constraint on every interior edge; none: no bending.
  std::optional<Real> bending_stiffness;
  Real bending_compliance = 0;   // 1/(N m)
  // Collision radius of the mesh's particles against colliders, m (>= 0).
  Real thickness = 0;
};

// How add_tet_mesh turns a tet mesh into particles and constraints.
struct TetMeshOptions {
  Index group = -1;  // existing group, or -1 for a new group named after the mesh
  // Total: kg for the whole mesh; Density: kg/m³; PerParticle: kg each. Total and Density share
  // by lumped volume (a quarter of each adjacent tet's volume per point).
  MassSpec mass;
  // Stiffness in [0, 1] of the distance constraint on every unique tet edge; none: no stretch.
  std::optional<Real> stretch_stiffness = Real(1);
  Real stretch_compliance = 0;  // m/N
  // Stiffness in [0, 1] of the volume constraint on every tet; none: no volume constraints.
  std::optional<Real> volume_stiffness = Real(1);
  Real volume_compliance = 0;   // m⁶/J
};

struct MeshInstance {
  Index first_particle = 0;  // vertex i of the mesh is particle first_particle + i
  Index num_particles = 0;
  Index group = 0;
  Index num_distance = 0;
  Index num_bending = 0;
  Index num_volume = 0;      // tet meshes: volume constraints (one per tet)
  Index flipped_tets = 0;    // tet meshes: inverted tets that were re-oriented
  std::vector<Triangle> triangles;  // the surface triangles it added to the model (particle indices)
  MeshReport report;         // degenerate triangles dropped, non-manifold edges, ...
};

class ModelBuilder {
 public:
  Index add_group(const std::string& name);

  // One particle at x (m) with the given mass (kg) in an existing group; returns its index.
  Index add_particle(const Vec3& x, Real mass, Index group);

  // All vertices of a mesh become particles (numbering kept), its unique edges distance
  // constraints and its interior edges bending constraints, as the options ask. Degenerate
  // triangles are dropped and reported, vertices are not welded (call clean() for that).
  MeshInstance add_mesh(const Mesh& mesh, const MeshOptions& options);

  // A distance constraint between particles i and j. rest_length < 0 takes the current distance.
  // compliance in m/N (0: hard).
  Index add_distance(Index i, Index j, Real stiffness = 1, Real rest_length = -1, int sense = 0, Real compliance = 0);
  // A bending constraint across edge (a, b) with wings c, d. No rest angle: the current one.
  // compliance in 1/(N m) (0: hard).
  Index add_bending(Index a, Index b, Index c, Index d, Real stiffness, std::optional<Real> rest_angle = {},
                    Real compliance = 0);
  // A tetrahedral volume constraint; compliance in m⁶/J (0: hard). No rest volume: the current
  // signed volume, which must be positive (orient (a, b, c, d) so that d lies on the side of
  // (b - a) x (c - a)) and not degenerate.
  Index add_tetrahedron(Index a, Index b, Index c, Index d, Real stiffness = 1, Real compliance = 0,
                        std::optional<Real> rest_volume = {});
  // Every point of a tet mesh becomes a particle (numbering kept), every unique tet edge a distance
  // constraint and every tet a volume constraint, as the options ask; the boundary faces (used by
  // one tet) go to the model's triangles, wound outwards. Inverted tets (negative signed volume)
  // are re-oriented by swapping their last two points, counted in flipped_tets and reported as a
  // warning; a degenerate tet (|V| below kDegenerateTetVolume times the bounding-box diagonal
  // cubed) is a MeshError naming the tet and its volume.
  MeshInstance add_tet_mesh(const TetMesh& mesh, const TetMeshOptions& options);
  // An overpressure constraint over a closed surface (particle indices, wound outwards): C = V -
  // pressure V0 with V0 the volume it encloses now. Throws InvalidArgument naming the count of
  // boundary, non-manifold and inconsistently wound edges and one example, or for a surface that
  // encloses a negative (inward winding) or vanishing volume. compliance in m⁶/J (0: hard).
  Index add_balloon(const std::vector<Triangle>& triangles, Real pressure = 1, Real stiffness = 1,
                    Real compliance = 0);
  // Fixes particle i where it is: inverse mass 0 (its mass is kept for reporting).
  void pin(Index i);
  // Holds particle i at a world point (m) with stiffness in [0, 1] and compliance in m/N.
  Index attach(Index i, const Vec3& target, Real stiffness = 1, Real compliance = 0);
  // A constraint of a registered family (constraints/families.cpp): its particles (the family's
  // arity, distinct), its parameters (the family's param_names, in their units), PBD stiffness in
  // [0, 1] and compliance in the family's unit (0: hard). Returns its index in the family's batch.
  // Throws InvalidArgument naming the family, the constraint and what is wrong.
  Index add_constraint(const std::string& family, const std::vector<Index>& particles, const std::vector<Real>& params,
                       Real stiffness = 1, Real compliance = 0);
  // A family defined at run time (csb.ConstraintFamily, a family written in Python), added empty;
  // add_constraint then takes its name. Its batch follows the registered families' in the model.
  // Throws InvalidArgument for a name a registered or earlier family has.
  void add_family(std::unique_ptr<FamilyBatch> batch);

  // Static colliders (collision.hpp), each with its ContactMaterial (μs >= μk >= 0, e in [0, 1]);
  // `name` labels it in messages (default: its kind and index). Each returns the collider's
  // index. Throws InvalidArgument naming the collider and the parameter on bad input.
  // The half-space (point - x)·normal <= 0 is solid; point in m, normal any non-zero vector
  // (normalised), pointing to the free side.
  Index add_plane(const Vec3& point, const Vec3& normal, const ContactMaterial& material = {},
                  const std::string& name = "");
  // center in m, radius > 0 m.
  Index add_sphere(const Vec3& center, Real radius, const ContactMaterial& material = {}, const std::string& name = "");
  // The points within radius (> 0 m) of the segment a-b (m, a != b).
  Index add_capsule(const Vec3& a, const Vec3& b, Real radius, const ContactMaterial& material = {},
                    const std::string& name = "");
  // center in m, half_extents > 0 m along the box's axes, which are the columns of the rotation
  // (orthonormal, determinant +1).
  Index add_box(const Vec3& center, const Vec3& half_extents, const Mat3& rotation = Mat3::Identity(),
                const ContactMaterial& material = {}, const std::string& name = "");
  // A static triangle mesh (any file load_mesh reads), treated as a two-sided sheet: a particle
  // keeps the side it is on. Degenerate triangles are dropped; none left is an error.
  Index add_collider_mesh(const Mesh& mesh, const ContactMaterial& material = {}, const std::string& name = "");
  // Collision radius (m, >= 0) of every particle of a group against the colliders.
  void set_thickness(Index group, Real thickness);
  // Point-triangle self-collision of a group's cloth with thickness h > 0 m (Müller 2007 §4.4).
  void enable_self_collision(Index group, Real thickness);
  Index num_colliders() const { return static_cast<Index>(colliders_.size()); }

  Index num_particles() const { return static_cast<Index>(mass_.size()); }
  const Vec3& position(Index i) const { return points_.at(i); }
  bool pinned(Index i) const { return pinned_.at(i) != 0; }
  const DistanceBatch& distance_constraints() const { return distance_; }

  // Checks what was added once more and returns the immutable model.
  std::shared_ptr<const Model> build() const;

 private:
  void require_particle(Index i, const std::string& what) const;
  void require_stiffness(Real k, const std::string& what) const;
  void require_compliance(Real alpha, const std::string& what) const;

  std::vector<Vec3> points_;
  std::vector<Real> mass_;
  std::vector<char> pinned_;
  std::vector<Index> group_;
  std::vector<std::string> group_names_;
  std::vector<Triangle> triangles_;
  DistanceBatch distance_;
  BendingBatch bending_;
  VolumeBatch volume_;
  BalloonBatch balloons_;
  std::vector<Index> attached_;
  std::vector<Vec3> attachment_targets_;
  std::vector<Real> attachment_stiffness_;
  std::vector<Real> attachment_compliance_;
  // The family batches, one per registered family once the first family constraint is added;
  // a copy of the builder copies them.
  struct Families {
    std::vector<std::unique_ptr<FamilyBatch>> batches;
    std::vector<std::unique_ptr<FamilyBatch>> runtime;  // add_family's, in order
    Families() = default;
    Families(const Families& o) {
      for (const auto& b : o.batches) batches.push_back(b->clone());
      for (const auto& b : o.runtime) runtime.push_back(b->clone());
    }
    Families& operator=(const Families& o) {
      if (this != &o) {
        Families copy(o);
        batches = std::move(copy.batches);
        runtime = std::move(copy.runtime);
      }
      return *this;
    }
    Families(Families&&) = default;
    Families& operator=(Families&&) = default;
  } families_;
  // collisions
  std::string collider_what(ColliderKind kind, const std::string& name) const;
  Index push_collider(Collider c, const std::string& what);
  std::vector<Collider> colliders_;
  std::vector<Real> thickness_;
  std::vector<Real> self_collision_;
};

}  // namespace csb
