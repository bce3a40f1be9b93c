// csb — tearing (Müller et al. 2007, §4.6): a cloth edge strained past a threshold splits one
// of its vertices, so that a crack opens there.
//
// The Model is immutable, so a tear makes a new Model (a new id; steppers rebuild their
// per-model data) and grows the State by the new particles. Tearing is for triangle surfaces:
// the split vertex's triangles are divided by the plane through it perpendicular to the
// strained edge; those on the side of the edge's other end move to a new particle (same
// position, velocity and rest position, half the mass each), and every constraint follows its
// triangles:
//   - a distance constraint on an edge whose triangles all moved moves with them; one whose
//     triangles are on both sides (the edges where the crack opens) is kept on both particles;
//     one with no triangles (a spring) follows the side its other end is on;
//   - a bending constraint whose two triangles end up on different particles is dropped (the
//     hinge is torn); otherwise its particles are renamed with its triangles;
//   - attachments stay on the original particle.
// A pinned vertex is never split (its edge's other end is, if free). Particles in a tet or a
// balloon cannot be split: an InvalidArgument names them.
#pragma once

#include "csb/model.hpp"

#include <memory>

namespace csb {

struct TearResult {
  // The torn model (owned); if nothing tore, a non-owning pointer to the model given, valid as
  // long as that model is.
  std::shared_ptr<const Model> model;
  Index torn = 0;                      // vertices split in this call
  std::vector<Index> split;            // the particles that were split (new ones are appended)
};

// Splits, in order of decreasing strain, up to `max_tears` vertices of distance constraints
// whose strain |ℓ − ℓ0|/ℓ0 exceeds `max_strain` (> 0), at most one per constraint and none of
// a particle already split in this call; `state` gains the new particles. Deterministic: ties
// go to the lower constraint index.
TearResult tear(const Model& model, State& state, Real max_strain, Index max_tears = 1);

}  // namespace csb
