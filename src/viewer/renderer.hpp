// csb viewer — draws a Model in a State with OpenGL 3.3: the surface triangles smooth-shaded with
// vertex normals recomputed from the positions every frame (two-sided lighting, a colour per
// group), the colliders, a ground grid, and optionally the distance constraints as a wireframe
// and the particles as dots (pinned red, held yellow). Meshes without triangles (chains) are
// drawn as their constraints and particles.
#pragma once

#include "csb/model.hpp"
#include "viewer/camera.hpp"
#include "viewer/gl.hpp"

#include <memory>
#include <vector>

namespace csb::viewer {

struct DrawOptions {
  bool wireframe = false;
  bool particles = false;
  bool grid = true;
  bool colliders = true;
};

// Where a collider is drawn in a frame: at its rigid pose (x_world = R x_model + t, what
// PbdStepper::collider_pose reports; the identity until it is moved) and, for a triangle-mesh
// collider whose mesh deforms, from its vertices this frame (m, 3 x V, its model frame, in the
// mesh's vertex order: what PbdStepper::collider_vertices reports), the pose applied to them.
// Empty vertices: the mesh as declared. A plane's grid stays where the plane was declared.
struct ColliderFrame {
  ColliderPose pose;
  Positions vertices;  // a deforming mesh collider's vertices (model frame), or empty
};

// Area-weighted vertex normals of the triangles at positions x (3 x N), not normalised (the
// shader does it): a vertex's normal is the sum of its triangles' (b - a) x (c - a). Vertices
// of no triangle get zero.
void vertex_normals(const Positions& x, const std::vector<Triangle>& triangles, std::vector<float>& normals);

class Renderer {
 public:
  Renderer();  // needs a current OpenGL 3.3 core context
  ~Renderer();

  // Takes the model's topology, colours and colliders; call again when the model changes (a
  // tear). The ground grid goes on the first collider plane facing up, else below the model.
  void set_model(const Model& model);
  // Draws into the bound framebuffer of the given size; `held` are particles under the hand;
  // `colliders` places model.colliders[i] (empty, or fewer than the model has: the rest as declared).
  void draw(const Model& model, const State& state, const Camera& camera, const DrawOptions& options,
            const std::vector<Index>& held, const std::vector<ColliderFrame>& colliders = {});

  // The bounding box of the model at rest and of its bounded colliders as declared (m), for framing.
  void bounds(Vec3& lo, Vec3& hi) const { lo = lo_; hi = hi_; }

 private:
  struct Geometry;
  std::unique_ptr<Geometry> g_;
  Vec3 lo_ = Vec3::Zero(), hi_ = Vec3::Zero();
};

}  // namespace csb::viewer
