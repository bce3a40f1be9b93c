// csb — cloth self-collision as a layer any stepper can run on its sub-step's motion x -> p:
// the candidate pairs of each self-colliding group, point–triangle proximity contacts at the
// prediction (the position-based steppers project them in their sweeps), and after the stepper's
// solve the continuous test, responses, fail-safe and inelastic velocities that leave the
// sub-step's end without a new intersection (self_collision.cpp says exactly what is claimed).
// The position-based steppers (pbd, xpbd, jakobsen) run all of it; the implicit methods
// (backward Euler, projective dynamics, VBD) run the continuous part on their solve's result, the
// collision-processing layer of Bridson, Fedkiw and Anderson (2002) over any internal dynamics.
#pragma once

#include "csb/collision/ccd.hpp"
#include "csb/collision/spatial_hash.hpp"
#include "csb/model.hpp"
#include "csb/types.hpp"

#include <array>
#include <cstdint>
#include <functional>
#include <vector>

namespace csb {

// A self-contact of a cloth (Müller 2007 §4.4; continuous contacts after Bridson, Fedkiw,
// Anderson 2002): two features of its own group, a point and a triangle or two edges, kept apart
// along a normal. The separation is d = Σ_k c_k p_k over the four particles (point–triangle: q,
// t0, t1, t2 with c = (1, -b0, -b1, -b2), b the barycentric coordinates of q's nearest point;
// edge–edge: a0, a1, b0, b1 with c = (1 - u, u, -(1 - v), -v) at the closest points' parameters),
// and the inequality C = d·n - thickness >= 0 with n:
//  - a proximity contact (point–triangle, made at the start of the sub-step): the triangle's
//    current unit normal times `side`, the side q was on at the start of the sub-step;
//  - a continuous contact (found by the continuous test after the sweeps): `normal`, fixed, d's
//    direction at the time of impact.
struct SelfContact {
  PairKind kind = PairKind::PointTriangle;
  bool continuous = false;
  std::array<Index, 4> particles{};
  std::array<Real, 4> weights{};    // c
  Vec3 normal = Vec3::UnitY();      // unit
  Real side = 1;                    // proximity: ±1 along the triangle's normal
  Real thickness = 0;               // m: the group's, or the pair's distance at the start of the sub-step if less
  Real approach = 0;                // m/s, d's normal speed in the motion x -> p when made (< 0: approaching)
  bool pushed = false;              // the contact moved its particles this sub-step
};

// The normal n of contact k with its triangle at y1, y2, y3 (as SelfContact says); false if it has
// none there (a collapsed triangle).
bool self_contact_normal(const SelfContact& k, const Vec3& y1, const Vec3& y2, const Vec3& y3, Vec3& n);

// Contact k's projection at positions y (3 x n, column-major) with inverse masses w: the step s
// along the normal such that Δp_k = w_k c_k s (Bridson, Fedkiw, Anderson 2002, §7.1), times
// `scale` (a relaxation); false if the contact holds or cannot move.
bool self_contact_step(const SelfContact& k, const Real* y, const Real* w, Real scale, Vec3& s);

// What self-collision did in the last sub-step, and since it was prepared.
struct SelfCollisionCounts {
  Index contacts = 0;             // self-contacts: proximity point-triangle, and continuous
  Index continuous = 0;           // of which found by the continuous test
  Index failsafe = 0;             // particles the fail-safe stopped (p = x) this sub-step
  Index unresolved = 0;           // impacts the fail-safe could not stop (only prescribed particles moved)
  Index skipped = 0;              // triangles left out: spread over more than the cloth's size in a step
  std::int64_t candidates = 0;    // point-triangle and edge-edge candidate pairs now kept
  std::int64_t searches = 0;      // candidate-pair searches since prepared
  std::int64_t tests = 0;         // continuous tests (additive CCD) run since prepared
  std::int64_t culled = 0;        // candidate pairs left untested in certified patches, since prepared
};

class SelfCollision {
 public:
  // Runs job(t) for t = 0 .. threads - 1, in parallel: the stepper's thread team.
  using Fork = std::function<void(int threads, const std::function<void(int)>& job)>;

  // The groups of the model with a self-collision thickness > 0: their triangles, edges, owners and
  // hierarchies. InvalidArgument for a thickness larger than its cloth.
  void prepare(const Model& model);
  bool empty() const { return groups_.empty(); }
  // The next begin() finds the candidate pairs afresh instead of keeping them while they hold, and
  // the patches' axes afresh: what follows depends on the positions alone.
  void forget_candidates() {
    for (Group& g : groups_) {
      g.searched = false, g.axis.clear(), g.failed.clear(), g.carry.clear();
      for (Group::Union& u : g.unions) u.axis.setZero(), u.carry.at = 0;
    }
  }
  // The threads the per-sub-step tests may use (1: the caller's); the results do not depend on it.
  void set_threads(int threads, Fork fork);

  // The start of a sub-step of h seconds, one of `substeps` in a step, with the motion x -> p (the
  // prediction) and inverse masses w: the candidate pairs kept or found again, the contacts
  // cleared, and with `proximity` the point–triangle proximity contacts made. `x_resolved`: x is
  // the p the last resolve left (which it found the candidates to hold), so only p is checked.
  void begin(const Model& model, const Positions& x, const Positions& p, const Real* w, int substeps, Real h,
             bool proximity, bool x_resolved = false);
  // After the stepper's solve: the continuous test along x -> p, responses and fail-safe, which
  // move p (see self_collision.cpp). Follows the sub-step's begin, with the same x.
  void resolve(const Model& model, const Positions& x, Positions& p, const Real* w, int substeps, Real h);
  // After the velocity update: the contacts that pushed take away their pair's approach but do not
  // make it separate. velocity(i) gives particle i's velocity, add_velocity(i, dv) changes it.
  void settle_velocities(const Positions& x_end, const Real* w, const std::function<Vec3(Index)>& velocity,
                         const std::function<void(Index, const Vec3&)>& add_velocity) const;
  // The deepest violation left by the contacts at x (m).
  Real penetration(const Positions& x) const;

  std::vector<SelfContact>& contacts() { return contacts_; }
  const std::vector<SelfContact>& contacts() const { return contacts_; }
  const SelfCollisionCounts& counts() const { return counts_; }
  std::size_t bytes() const;  // the workspace held, for memory reports

 private:
  struct Group {
    Index group = 0;
    Real thickness = 0;                  // h, m
    // The group's particles are first, first + 1, ..., first + count - 1 (first = -1: not one run);
    // the per-sub-step checks then run over their coordinates as flat arrays.
    Index first = -1, count = 0;
    Real cell = 1;                       // m, hash cell edge
    Real edge = 0;                       // m, the mean rest edge of its triangles
    std::vector<Index> triangles;        // into model.triangles
    std::vector<std::array<Index, 2>> edges;  // the triangles' edges, particle pairs, ascending
    // The candidate pairs (find_candidates): point-triangle (particle, triangle index into
    // `triangles`, the patch holding both) and edge-edge (indices into `edges`, first < second,
    // the patch), the patch being the smallest node of the hierarchy that holds both features'
    // owner triangles (-1: none, a particle in no triangle).
    std::vector<std::array<Index, 3>> pt, ee;
    bool searched = false;               // pt and ee were found for this model
    Real size = 0;                       // m, the group's rest bounding-box diagonal
    Index skipped = 0;                   // triangles left out of the last search (beyond `size`)
    // The triangles' and the hierarchy's boxes at the last search (m), built when a search or a
    // certification first needs them (search_boxes); until then only the root's is known.
    std::vector<Vec3> tri_lo, tri_hi, node_lo, node_hi;
    bool boxes_ready = false;
    // Owners: each particle and edge belongs to the first triangle (in `triangles`) holding it;
    // per triangle the particles and edges it owns (CSR), and the group's particles in no triangle.
    std::vector<Index> owned_particle_start, owned_particles, owned_edge_start, owned_edges, loose;
    // The triangles' bounding-volume hierarchy, built once from the rest shape: per node its two
    // children (a leaf: {-1 - triangle, -1}), in preorder (a node, then its first subtree, then its
    // second: a subtree is a run of 2 bvh_size - 1 nodes); and its triangles' count.
    std::vector<std::array<Index, 2>> bvh_child;
    std::vector<Index> bvh_size;
    // Each node's triangles are bvh_order[bvh_begin[k] .. bvh_begin[k] + bvh_size[k]). A node
    // whose triangles form a disc (connected, one boundary loop, Euler
    // characteristic 1, consistently oriented) is a patch (certify): its boundary loop's edges,
    // directed as in their triangles, are patch_edges[patch_start[k] .. patch_start[k + 1]);
    // other nodes have none.
    std::vector<Index> bvh_order, bvh_begin, patch_start;
    std::vector<Triangle> bvh_corners;  // the particles of bvh_order's triangles, in that order
    // Their corners as offsets 2 (i - first) into the group's particles projected across an axis
    // (certify_patch's large nodes), where the group is one run and may have such a node.
    std::vector<std::array<Index, 3>> bvh_across;
    std::vector<std::array<Index, 2>> patch_edges;
    std::vector<std::uint8_t> is_patch;
    std::vector<Index> deferred;         // nodes not searched inside, certified when searched, ascending
    // Per node: the serial of the sub-step certification that last turned it down (0: none), and the
    // sub-steps of a step (certify tries it again a step later).
    std::vector<std::uint64_t> failed;
    int substeps = 1;
    std::vector<Vec3> axis;              // per node: the axis V of its last certification (zero: none yet)
    // What a patch's certification by a sub-step leaves for the next (certify_patch): the
    // sub-step's serial, the least V·(e x f) over its triangles at the end (m² times |V|), and the
    // boundary's centre O with the least signed area of its edges about O at the end (the same
    // units). The next sub-step starts where this one ended, so these are its least coefficients
    // at the start, and only the end's are computed. A new axis forgets them.
    struct Carried {
      std::uint64_t at = 0;
      Real end_normal = 0;
      Real end_boundary = 0;
      Vec3 origin = Vec3::Zero();
    };
    std::vector<Carried> carry;  // per node
    // Unions of two nodes across the cut of a node that failed (certify_union), by the pair of
    // nodes (a < b; union_of[a]: its pairs b and their index in unions): whether their triangles form a disc and, if so,
    // its corners (a's, then b's) and boundary loop, kept once made (the mesh's connectivity),
    // and the axis and carried end of its certifications, as a node keeps them.
    struct Union {
      bool disc = false;
      std::vector<Triangle> corners;
      std::vector<std::array<Index, 2>> boundary;
      Vec3 axis = Vec3::Zero();
      Carried carry;
    };
    std::vector<Union> unions;
    std::vector<Vec3> rest_lo, rest_hi;  // m, per node: its triangles' box in the rest shape
    std::vector<std::vector<std::array<Index, 2>>> union_of;
    // Pairs of nodes (a, b, and the patch whose self-pair they descend from) that the search did
    // not enter, their union certified: searched when a sub-step's motion does not certify it.
    std::vector<std::array<Index, 3>> deferred_unions;
    std::uint64_t serial = 0;            // the sub-step certifications so far
    bool carried = false;                // this sub-step starts where the last one ended
    Real step2 = 0;                      // m², the largest |p - x|² of this sub-step
  };
  struct Found {
    PairKind kind;
    std::array<Index, 4> particles;
    Real toi;
  };

  // What certify_patch needs of a patch: its triangles' corners, its boundary loop, the squared
  // size of its box (the margin's scale), where it is as large as its group's particles (the
  // projection across the axis pays) its corners' offsets into that projection (else null), and
  // where its axis and what a sub-step carries are kept.
  struct PatchView {
    const Triangle* tri;
    Index size;
    const std::array<Index, 2>* edges;
    Index m;
    Real box2;
    const std::array<Index, 3>* across;
    Vec3& axis;
    Group::Carried& carry;
  };
  // disc_boundary's working arrays: local, by particle, its index among the patch's vertices (-1
  // outside a call); by local vertex, its particle, its directed edges' ends (out[start[v] ..
  // start[v + 1])) and its boundary edge's end.
  struct DiscScratch {
    std::vector<Index> local, vertices, start, out, next;
  };
  void find_candidates(const Model& model, Group& g, const Positions& x, const Positions& p, const Real* w,
                       int substeps);
  void search_boxes(const Model& model, Group& g);
  bool candidates_hold(const Model& model, const Group& g, const Positions* x, const Positions& p) const;
  void sweep_boxes(const Model& model, const Group& g, const Positions& x, const Positions& p, Real pad);
  void unite_boxes(const Model& model, const Group& g, const Positions& lo, const Positions& hi, std::vector<Vec3>& tri_lo,
                   std::vector<Vec3>& tri_hi, std::vector<Vec3>* edge_lo, std::vector<Vec3>* edge_hi);
  void find_impacts(const Model& model, Group& g, const Positions& x, const Positions& p, const Real* w);
  void search_node(const Model& model, Group& g, const std::array<Index, 3>& start, const Real* w, const Positions& x,
                   const Positions& q);
  bool certify_union(Group& g, Index a, Index b, const Positions& x, const Positions& p, bool sub_step);
  void resume_unions(const Model& model, Group& g, const Positions& x, const Positions& p, const Real* w);
  void add_point_triangle(const Model& model, Group& g, Index q, Index t, Index lca, const Real* w);
  void resume_deferred(const Model& model, Group& g, const Real* w, const Positions& x, const Positions& p);
  static void find_patches(Group& g);
  static bool disc_boundary(const Triangle* tri, Index size, std::vector<std::array<Index, 2>>& loop, DiscScratch& s);
  void certify(const Model& model, Group& g, const Positions& x, const Positions& p, bool sub_step);
  bool certify_node(Group& g, Index k, const Positions& x, const Positions& p, bool sub_step);
  bool certify_patch(Group& g, const PatchView& v, const Positions& x, const Positions& p, bool sub_step);
  void project(Positions& p, const Real* w);
  template <class F>
  int in_chunks(std::size_t n, F&& chunk);

  static constexpr std::size_t kParallelPairs = 8192;  // candidate pairs worth a fork of the team
  // The largest union of two nodes tried (certify_union), in triangles: a union is tested on
  // each sub-step while it is deferred, at the cost of its triangles.
  static constexpr Index kUnionMost = 256;
  std::vector<Group> groups_;
  std::vector<SelfContact> contacts_;
  SelfCollisionCounts counts_;
  int threads_ = 1;
  Fork fork_;
  std::vector<Found> impacts_;
  std::vector<std::vector<Found>> impact_parts_;        // per thread: point-triangle, edge-edge
  std::vector<std::vector<SelfContact>> contact_parts_;  // per thread: proximity contacts
  std::vector<std::int64_t> tests_parts_, culled_parts_;  // per thread: continuous tests run, pairs culled
  Positions particle_lo_, particle_hi_;  // m, each particle's box when the candidates were found
  Positions hold_lo_, hold_hi_;          // m, that box shrunk by h (candidates_hold)
  Positions sweep_lo_, sweep_hi_;        // m, each particle's swept box over x -> p this sub-step
  std::vector<Vec3> box_lo_, box_hi_;    // m, the triangles' boxes
  std::vector<Vec3> edge_lo_, edge_hi_;  // m, the edges' boxes
  Positions end_p_;                      // m, the last sub-step certification's end positions
  std::vector<Real> move2_;              // m², by particle, |p - x|² of the sub-step being certified
  std::vector<Real> across_x_, across_p_;  // m, a large node's particles across its axis (certify_node)
  std::vector<std::array<Index, 3>> node_pairs_;  // the traversal's stack: two nodes and their pair's patch
  std::vector<std::uint8_t> stopped_;    // per particle: stopped by the fail-safe this sub-step
  // The continuous test's culling (certify): per node whether it or an ancestor is certified
  // free of self-intersection over the motion.
  std::vector<std::uint8_t> certified_;
  DiscScratch disc_scratch_;             // for certify_union's disc test
  SpatialHash hash_;                     // triangles, for the particles in no triangle
  std::vector<std::uint32_t> stamps_;    // per triangle: queried for the current particle
  std::uint32_t stamp_ = 0;
};

}  // namespace csb
