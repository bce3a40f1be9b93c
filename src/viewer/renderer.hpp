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
  // Draws into the bound framebuffer of the given size; `held` are particles under the hand.
  void draw(const Model& model, const State& state, const Camera& camera, const DrawOptions& options,
            const std::vector<Index>& held);

  // The bounding box of the model at rest and of its bounded colliders (m), for framing.
  void bounds(Vec3& lo, Vec3& hi) const { lo = lo_; hi = hi_; }

 private:
  struct Geometry;
  std::unique_ptr<Geometry> g_;
  Vec3 lo_ = Vec3::Zero(), hi_ = Vec3::Zero();
};

}  // namespace csb::viewer
