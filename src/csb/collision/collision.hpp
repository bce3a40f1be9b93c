// csb — colliders and the contacts the PBD stepper generates against them (Müller,
// Heidelberger, Hennix, Ratcliff 2007, "Position Based Dynamics", §3.4 and §4.3).
//
// A collider is immutable and part of the Model: a half-space, a sphere, a capsule, an oriented
// box, or a triangle mesh treated as a two-sided sheet. Once per sub-step, after the prediction
// p = x + h v (Algorithm 1, line 8), every particle that can move is tested along the ray x -> p:
//
//   - the ray enters the collider: a contact at the entry point q with the surface normal n there
//     ("continuous collision handling", §4.3);
//   - x is already inside (continuous handling failed at some earlier point, or the user put the
//     particle there): the surface point q closest to p and its normal ("static" fallback, §4.3);
//   - neither, but p ends closer than r + margin to the surface, r the particle's thickness:
//     q closest to p. The margin (the largest distance a particle of the group moves in the
//     prediction) makes the contact speculative: it does nothing while satisfied, but catches a
//     particle whose prediction was outside and whom its neighbours' constraints drag inside
//     during the iterations (a cloth draped on a sphere, the rim of the contact patch).
//
// Each contact is the inequality constraint, with stiffness 1 (§4.3),
//
//   C(p) = (p - q)·n - r >= 0,     ∇C = n,     Δp = -C n  when C < 0,
//
// i.e. the tangent plane at q, pushed out by the thickness r. For a convex collider the
// half-space beyond a tangent plane lies outside the collider, so a satisfied contact keeps the
// particle out (and at least r away). A mesh sheet has no inside: a particle keeps the side it
// is on, and the normal of a contact is turned towards that side.
//
// Moving colliders. The shape above is the collider's model frame; the position-based stepper
// owns a rigid pose per collider, x_world = R x_model + t (identity until moved; the Model stays
// immutable), set for the end of the next step and interpolated over its sub-steps (t linearly,
// R by slerp of unit quaternions, as a kinematic grab's hand moves). A sub-step goes from pose A
// (its start) to pose B (its end); the ray is tested in the model frame, from A⁻¹ x to B⁻¹ p:
// the particle's motion relative to the collider, so a collider faster than the cloth is thin
// does not pass through it.
//   - Translation only (R_A = R_B): both the particle's prediction and the collider move on
//     straight lines at constant speed within the sub-step, so their relative path is exactly
//     that segment; the test is exact (as continuous as for a static collider).
//   - Rotation: in the model frame the relative path of a particle is an arc, replaced by its
//     chord. The chord is off the arc by at most ρ θ²/8 (ρ the distance to the rotation axis,
//     θ the angle turned in the sub-step): a feature thinner than that can be missed.
// The contact point q and normal n are carried to the world by pose B, so the constraint is the
// tangent plane where the surface is at the end of the sub-step. The contact also keeps the
// motion over the sub-step of the point of the collider's frame where it holds the particle,
// s = q_m + r n_m in the model frame (q_m, n_m: q and n there), B s - A s: friction acts on the
// particle's displacement relative to it and restitution on the relative normal velocity
// (contacts.cpp); a particle that does not slide moves with the collider as if fixed to it.
// For an unmoved collider that motion is zero and every operation is the static collider's.
//
// Deforming mesh colliders (a skinned character). The stepper can also be given a mesh
// collider's vertices, in its model frame, for the end of the next step (deform_collider). Each
// vertex goes to them from where it was on a straight line over the step's sub-steps, carried
// to the world by the sub-step's pose: within a sub-step every vertex moves on the segment from
// its world position at the start to the one at the end, at constant speed, and so does the
// particle's prediction. The contact test is then the point against the moving triangle:
//   - continuous: additive CCD (ccd.hpp; Li, Kaufman and Jiang 2021) of the particle against
//     each triangle near its path, swept from its start to its end positions, reports the first
//     time the distance falls to 1/10 of the start's; the earliest such triangle gives the
//     contact, its plane at the end of the sub-step facing the side the particle was on at that
//     time, q the point of the end triangle with the barycentric coordinates of the closest point
//     then. A particle cannot cross a triangle without this report, however fast the triangle;
//   - otherwise p ending within r + margin of the end triangles: the nearest end triangle's
//     closest point q, n from q to p (the particle did not cross: p is on its side).
// The surface motion of the contact is that of the point q + r n held by the triangle: the
// barycentric blend of its vertices' motions plus r times its oriented unit normal's change over
// the sub-step (for a triangle moved rigidly, the rigid collider's B s - A s). The triangles'
// grid covers their swept boxes: built once a step over the step's sweep (each vertex moves on
// one line over the step), or each sub-step over the sub-step's when the collider also turns.
#pragma once

#include "csb/mesh.hpp"
#include "csb/types.hpp"

#include <memory>
#include <string>
#include <vector>

namespace csb {

// Coulomb friction and restitution of a collider's surface (dimensionless).
struct ContactMaterial {
  Real friction_static = 0;   // μs >= μk
  Real friction_kinetic = 0;  // μk >= 0
  Real restitution = 0;       // e in [0, 1]: the normal speed after an impact over the one before
};

enum class ColliderKind { Plane, Sphere, Capsule, Box, Mesh };

// A uniform grid over the triangles of a mesh collider: each cell lists (CSR) the triangles
// whose bounding box overlaps it, so that a query touches the triangles near a segment only.
struct TriangleGrid {
  Vec3 origin = Vec3::Zero();       // m, corner of cell (0, 0, 0)
  Real cell = 1;                    // m, edge of a cubic cell
  std::array<Index, 3> dims{1, 1, 1};
  std::vector<Index> cell_start;    // size cells + 1
  std::vector<Index> items;         // triangle indices, ascending within a cell
};

struct ColliderMesh {
  Positions vertices;               // m, 3 x V
  std::vector<Triangle> triangles;
  std::vector<Vec3> normals;        // unit face normals, from the winding
  // m: the least clearance a contact keeps from the sheet, 1e-9 of the mesh's size (at least
  // 1 nm). A particle left exactly on a two-sided sheet would have no side; round-off (1e-16
  // of the size) cannot cross this.
  Real skin = 1e-9;
  TriangleGrid grid;
};

// One collider, in its model frame. Only the fields of its kind are used:
//   Plane    point (m), normal (unit, outward: the free side)
//   Sphere   center (m), radius (m)
//   Capsule  a, b (m): the ends of its axis; radius (m)
//   Box      center (m), half_extents (m), rotation: columns are the box's axes in the world
//   Mesh     mesh
struct Collider {
  ColliderKind kind = ColliderKind::Plane;
  std::string name;                 // used in every message about this collider
  ContactMaterial material;
  Vec3 point = Vec3::Zero();
  Vec3 normal = Vec3::UnitY();
  Vec3 center = Vec3::Zero();
  Real radius = 0;
  Vec3 a = Vec3::Zero(), b = Vec3::Zero();
  Vec3 half_extents = Vec3::Zero();
  Mat3 rotation = Mat3::Identity();
  std::shared_ptr<const ColliderMesh> mesh;
};

const char* kind_name(ColliderKind kind);

// The surface point nearest to x, for the analytic (convex) colliders.
struct SurfacePoint {
  Real distance = 0;                // m, signed: < 0 inside
  Vec3 point = Vec3::Zero();        // m, on the surface
  Vec3 normal = Vec3::UnitY();      // unit, outward
};
SurfacePoint closest_surface_point(const Collider& c, const Vec3& x);

// Signed distance of x to an analytic collider (m, < 0 inside); +infinity for a mesh sheet,
// which has no inside.
Real signed_distance(const Collider& c, const Vec3& x);

// A contact between a particle and a collider, generated once per sub-step and projected in every
// iteration; afterwards it carries what the velocity update needs (friction, restitution).
struct Contact {
  Index particle = 0;
  Index collider = 0;
  Vec3 point = Vec3::Zero();        // q, m
  Vec3 normal = Vec3::UnitY();      // n, unit
  Real thickness = 0;               // r, m
  Real approach_speed = 0;          // (p - x)/h · n at generation, m/s (< 0: approaching)
  bool started_inside = false;      // x was inside: the static fallback
  Real lambda = 0;                  // XPBD multiplier, kg m (the contact force is λ/h² along n)
  Real normal_correction = 0;       // m, what the contact pushed the particle along n this sub-step
  Real sweep_move = 0;              // m, PBD with averaged Jacobi: this sweep's push, before the averaging
  Vec3 surface_motion = Vec3::Zero();  // m, how far the collider carried the point q + r n in the sub-step
};

// A collider's rigid pose, x_world = rotation x_model + translation (rotation orthonormal with
// determinant +1; translation in m).
struct ColliderPose {
  Mat3 rotation = Mat3::Identity();
  Vec3 translation = Vec3::Zero();  // m
  Vec3 to_world(const Vec3& x) const { return rotation * x + translation; }
  Vec3 to_model(const Vec3& x) const { return rotation.transpose() * (x - translation); }
  bool identity() const { return rotation == Mat3::Identity() && translation == Vec3::Zero(); }
};

// The pose `fraction` in [0, 1] of the way from `from` to `to`: translation linear, rotation by
// slerp of unit quaternions (the shorter arc, so a step must turn less than π); exactly `from`
// at 0 and `to` at 1.
ColliderPose interpolate_pose(const ColliderPose& from, const ColliderPose& to, Real fraction);

// Throws InvalidArgument naming `what` unless `rotation` is a rotation (|RᵀR - I| and
// |det R - 1| at most kRotationTolerance, entries finite) and `translation` is finite.
constexpr Real kRotationTolerance = 1e-6;
void validate_pose(const Mat3& rotation, const Vec3& translation, const std::string& what);

// A particle attached to a collider: kinematic (inverse mass 0 in the projections, like a
// kinematic grab), its prediction the collider's pose applied to `local`, where it was in the
// collider's model frame when attached. On a mesh collider it is also held in the frame of its
// nearest triangle (a, b, c) with unit normal n when attached: local = a + u (b - a) + v (c - a)
// + w n, (u, v, w) = `frame`; while the mesh deforms it follows that triangle (the skin).
struct ColliderAttachment {
  Index collider = 0;
  Index particle = 0;
  Vec3 local = Vec3::Zero();        // m, model frame of the collider
  int handle = 0;                   // of the kinematic grab that holds it (< 0)
  Index triangle = -1;              // mesh colliders: the nearest triangle when attached
  Vec3 frame = Vec3::Zero();        // (u, v: dimensionless; w: m) in that triangle's frame
};

// A mesh collider's deformation held by the stepper: its vertices in the model frame at the end
// of the last step and of the next (m; both empty until deformed), and, for the current
// sub-step, in the world at its start and end with the grid over the swept triangles.
struct DeformingMesh {
  Positions from, to;               // m, model frame, 3 x V
  Positions start, end;             // m, world, 3 x V
  Positions step_end;               // m, world, 3 x V: at the end of the step (the grid's sweep)
  TriangleGrid grid;                // over the triangles swept over the sub-step, or the step (collider_motion.cpp)
  bool active() const { return to.cols() > 0; }
};

// Throws InvalidArgument naming `what` (the collider) and the first bad vertex unless `vertices`
// are as many as the mesh's and finite.
void validate_collider_vertices(const ColliderMesh& mesh, const Positions& vertices, const std::string& what);

// The grid over triangles given by their bounding boxes (m; one per triangle), as
// build_triangle_grid sizes it; `grid`'s storage is reused.
void build_box_grid(const std::vector<Vec3>& lo, const std::vector<Vec3>& hi, TriangleGrid& grid);

// The contact of particle i (x -> p over the sub-step, thickness r, margin in m) with mesh
// collider c deforming from d.start to d.end over the sub-step (see above); `h` (s) only serves
// approach_speed. Returns whether a contact was added.
bool generate_deforming_contact(const Collider& c, const DeformingMesh& d, Index collider_index, Index i,
                                const Vec3& x, const Vec3& p, Real r, Real margin, Real h, std::vector<Contact>& out,
                                std::vector<std::uint32_t>& stamps, std::uint32_t& stamp);

// The nearest triangle of a mesh with `vertices` to x, and x in that triangle's frame
// (ColliderAttachment::frame). Returns -1 if every triangle is degenerate.
Index triangle_frame(const Positions& vertices, const std::vector<Triangle>& triangles, const Vec3& x, Vec3& frame);

// The point with `frame` coordinates in triangle t of `vertices` (the inverse of triangle_frame).
Vec3 from_triangle_frame(const Positions& vertices, const Triangle& t, const Vec3& frame);

// generate_contact against collider c at pose A at the sub-step's start and B at its end: the
// ray A⁻¹ x -> B⁻¹ p in the model frame, the contact carried to the world by B (see above).
bool generate_moving_contact(const Collider& c, const ColliderPose& A, const ColliderPose& B, Index collider_index,
                             Index i, const Vec3& x, const Vec3& p, Real r, Real margin, Real h,
                             std::vector<Contact>& out, std::vector<std::uint32_t>& stamps, std::uint32_t& stamp);

// Appends the contact of particle i (at x, predicted at p, thickness r, speculative margin in m)
// with collider c if there is one; `stamps` holds candidate triangle marks for mesh colliders
// (sized by the caller). `h` (s) only serves approach_speed. Returns whether a contact was added.
bool generate_contact(const Collider& c, Index collider_index, Index i, const Vec3& x, const Vec3& p, Real r,
                      Real margin, Real h, std::vector<Contact>& out, std::vector<std::uint32_t>& stamps,
                      std::uint32_t& stamp);

// Builds the grid of a mesh collider: cell edge about the mean triangle bounding-box size, at
// most a few cells per triangle in total.
TriangleGrid build_triangle_grid(const Positions& vertices, const std::vector<Triangle>& triangles);

// Closest point on triangle (a, b, c) to x (Ericson 2005, "Real-Time Collision Detection",
// §5.1.5), with its barycentric coordinates.
Vec3 closest_point_on_triangle(const Vec3& x, const Vec3& a, const Vec3& b, const Vec3& c, Vec3* barycentric);

}  // namespace csb
