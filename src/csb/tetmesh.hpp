// csb — tetrahedral (volume) meshes: validation, the boundary surface, and a generated box.
#pragma once

#include "csb/types.hpp"

#include <limits>
#include <string>
#include <vector>

namespace csb {

using Tet = std::array<Index, 4>;

// A volume mesh before it enters the particle pool. Coordinates in metres.
struct TetMesh {
  std::string name;         // file path or label, used in every message about this mesh
  Positions points;         // 3 x N
  std::vector<Tet> tets;    // 4 point indices each; positive orientation: tet_volume > 0

  Index num_points() const { return static_cast<Index>(points.cols()); }
  Index num_tets() const { return static_cast<Index>(tets.size()); }
};

// A tet whose |signed volume| is below this times the mesh's bounding-box diagonal cubed is
// degenerate (flat or collapsed). A regular tet of edge a has V = a³/(6√2); 1e-12 allows cells down
// to ~1e-4 of the mesh size, while the round-off of V itself is ~1e-16 diag³.
constexpr Real kDegenerateTetVolume = 1e-12;

// Throws MeshError naming the mesh and the element if a coordinate is not finite, an index is out of
// range, a tet repeats a point, or there are no tets.
void validate(const TetMesh& mesh);

// Signed volume of every tet, m³.
std::vector<Real> tet_volumes(const TetMesh& mesh);

// The faces used by exactly one tet, wound outwards (for a positively oriented mesh), in the order
// of the tets and their faces. Throws MeshError naming a face shared by more than two tets.
std::vector<Triangle> tet_surface(const TetMesh& mesh);

// A box of size (m) centred on `center`, with nx x ny x nz cubic cells of 6 tets each (Kuhn /
// Freudenthal split along each cell's main diagonal, conforming between cells), every tet
// positively oriented. Point (i, j, k) is number (k (ny + 1) + j)(nx + 1) + i.
TetMesh tet_box(const Vec3& size, Index nx, Index ny, Index nz, const Vec3& center = Vec3::Zero());

}  // namespace csb
