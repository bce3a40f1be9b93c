// csb — generated meshes for tests, validation and examples.
#pragma once

#include "csb/mesh.hpp"

namespace csb {

enum class Plane { XY, XZ, YZ };

// A rectangular cloth of nx x ny particles spanning width x height metres, centred on `center`
// and lying in `plane` (the first axis of the plane runs along nx). Quads are split along
// alternating diagonals so that the cloth has no preferred shear direction. Vertex (i, j) is
// number j * nx + i.
Mesh cloth_grid(Real width, Real height, Index nx, Index ny, Plane plane = Plane::XZ,
                const Vec3& center = Vec3::Zero());

// A chain of `links` segments of link_length metres from `start` along `direction`
// (normalised here): links + 1 vertices joined by line segments.
Mesh chain(Index links, Real link_length, const Vec3& start = Vec3::Zero(),
           const Vec3& direction = Vec3(1, 0, 0));

// A simple pendulum: an anchor vertex (0) and a bob (1) at `length` metres, displaced by
// `angle` radians from the downward vertical (-y) towards +x.
Mesh pendulum(Real length, Real angle, const Vec3& anchor = Vec3::Zero());

}  // namespace csb
