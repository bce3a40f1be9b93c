// csb — picking a particle under the cursor: the ray cast behind click and drag.
//
// The grab itself lives in the stepper (PbdStepper::grab, move_grab, release); this finds what
// to grab.
#pragma once

#include "csb/model.hpp"

namespace csb {

struct Pick {
  Index particle = -1;   // -1: nothing under the ray
  Real distance = 0;     // m, along the ray to the hit point (or to the particle's foot point)
  Index triangle = -1;   // the surface triangle hit, or -1 if the particle was found by proximity
};

// The particle a ray from `origin` along `direction` (need not be unit) points at, in `state`:
// the first surface triangle of the model it crosses (Möller–Trumbore), then that triangle's
// vertex nearest to the hit point. If the ray crosses no triangle (a chain, a point cloud, a
// miss near a silhouette), the particle nearest to the ray, in front of the origin and within
// `max_distance` (m) of it; ties go to the nearer along the ray, then to the lower index.
// Throws InvalidArgument for a zero or non-finite direction, a non-finite origin or a negative
// max_distance.
Pick pick_particle(const Model& model, const State& state, const Vec3& origin, const Vec3& direction,
                   Real max_distance);

}  // namespace csb
