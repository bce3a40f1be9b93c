// csb — continuous collision detection of a cloth's point–triangle and edge–edge pairs over a
// sub-step: the distances between the features and a conservative time of impact along straight
// motions.
//
// The time of impact is Li, Kaufman and Jiang's additive CCD (2021, "Codimensional Incremental
// Potential Contact", §5 and Algorithm 1; ACCD). Subtract the pair's mean displacement; then l_p,
// the sum of the largest displacements of the two features, bounds how fast their distance d can
// fall (|ḋ| <= l_p over the unit interval). From d(t) the pair can move on by
//     Δt = c (d(t) - ξ) / l_p
// without d falling below ξ + (1 - c)(d(t) - ξ). Stepping so from t = 0 (c = 1 - s at first,
// then 0.9) either passes t = 1 (no impact) or reaches a time where d has fallen below
// ξ + s (d(0) - ξ): the impact, reported at the last time before it. Every step is taken from a
// lower bound on the time the distance needs, so the report is conservative: a pair whose
// distance falls to ξ anywhere in [0, 1] is always reported, at a time when it is still at least
// about s (d(0) - ξ) + ξ apart, never after it touched. It needs no root finding and no
// polynomial: only the distance of the pair, computed at each step.
#pragma once

#include "csb/types.hpp"

#include <array>

namespace csb {

// Squared distance between segments [p0, p1] and [q0, q1], with the parameters s, t in [0, 1] of
// their closest points p0 + s (p1 - p0) and q0 + t (q1 - q0) (Ericson 2005, "Real-Time Collision
// Detection", §5.1.9; parallel segments take s from the clamped projection of the other's end).
Real segment_segment_distance2(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1, Real* s, Real* t);

// Squared distance from point x to triangle (a, b, c), with the barycentric coordinates of the
// closest point (Ericson 2005, §5.1.5).
Real point_triangle_distance2(const Vec3& x, const Vec3& a, const Vec3& b, const Vec3& c, Vec3* barycentric);

enum class PairKind { PointTriangle, EdgeEdge };

// The distance of a pair of features (point–triangle: x[0] and triangle x[1..3]; edge–edge:
// [x[0], x[1]] and [x[2], x[3]]), m, squared.
Real pair_distance2(PairKind kind, const std::array<Vec3, 4>& x);

struct Impact {
  bool hit = false;
  Real toi = 1;  // fraction of the motion before which the pair keeps its distance (hit), else 1
};

// Additive CCD of a pair moving from x to x + dx over the unit interval: the first time its
// distance falls below ξ + s (d(0) - ξ) (s in (0, 1), the separation kept; ξ >= 0 m the
// thickness of the contact). A pair already closer than ξ at the start is an impact at 0. After
// `max_steps` steps without a decision (a pair that grazes at almost its speed bound) the impact is
// reported at the time reached, the conservative answer.
Impact additive_ccd(PairKind kind, std::array<Vec3, 4> x, std::array<Vec3, 4> dx, Real s, Real xi,
                    int max_steps = 1000);

}  // namespace csb
