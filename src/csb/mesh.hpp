// csb — surface and line meshes as they arrive from files, arrays or generators, and the
// clean-up that turns them into simulation topology: welding seams, dropping degenerate
// triangles, unique edges and bending pairs.
#pragma once

#include "csb/types.hpp"

#include <limits>
#include <string>
#include <vector>

namespace csb {

// A mesh before it enters the particle pool. Coordinates are in metres.
struct Mesh {
  std::string name;                  // file path or label, used in every message about this mesh
  Positions vertices;                // 3 x N
  std::vector<Triangle> triangles;   // faces, any winding
  std::vector<Edge> lines;           // explicit segments (ropes, chains), besides triangle edges

  Index num_vertices() const { return static_cast<Index>(vertices.cols()); }
};

struct CleanOptions {
  // Weld vertices that share a position (UV and normal seams split them in most exporters).
  bool weld = true;
  // Two vertices closer than weld_tolerance * (bounding-box diagonal) become one. Dimensionless.
  Real weld_tolerance = 1e-6;
  // Drop vertices that no triangle or line uses (they would be free-flying particles).
  bool drop_unreferenced = true;
};

// What clean() did, so that nothing the user gave disappears silently.
struct MeshReport {
  Index input_vertices = 0;
  Index input_triangles = 0;
  Index input_lines = 0;
  Index welded_vertices = 0;          // input vertices merged into an earlier one
  Index unreferenced_vertices = 0;    // dropped because nothing used them
  Index degenerate_triangles = 0;     // dropped: repeated vertex or zero area
  Index degenerate_lines = 0;         // dropped: both ends welded into one vertex
  Index boundary_edges = 0;
  Index non_manifold_edges = 0;       // shared by more than two triangles: no bending pair
  std::vector<Index> vertex_map;      // input vertex -> output vertex, -1 if dropped
  std::vector<std::string> warnings;  // one line each, already naming the mesh
};

// The constraint topology of a cleaned mesh.
struct Topology {
  std::vector<Edge> edges;                    // unique, (min, max), sorted
  std::vector<std::array<Index, 4>> bending;  // (a, b) shared edge, c and d the opposite vertices
  Index boundary_edges = 0;
  Index non_manifold_edges = 0;
};

// Throws MeshError naming the mesh and the element if a coordinate is not finite, an index is
// out of range, or the mesh has neither triangles nor lines.
void validate(const Mesh& mesh);

// Welds, drops degenerate triangles and lines and, if asked, unreferenced vertices. Validates
// first. Throws MeshError if nothing usable is left.
Mesh clean(const Mesh& mesh, const CleanOptions& options, MeshReport* report = nullptr);

Topology topology(const Mesh& mesh);

// Unit vertex normals of triangles over positions x (3 x N, m): each vertex sums the area-weighted
// normals of its triangles ((b - a) x (c - a), counterclockwise in front), then is normalised; a
// vertex in no triangle, or whose triangles cancel, gets 0. What a renderer takes with the
// positions each frame (examples/cpp/own_loop.cpp). `normals` is resized to 3 x N.
void vertex_normals(const Positions& x, const std::vector<Triangle>& triangles, Positions& normals);

// The order a mesh's edges become distance constraints in: first-fit colour classes (edges that
// share no vertex), class after class, in (min, max) order within a class. One Gauss-Seidel sweep
// in index order (each vertex's edges together, row after row on a grid) carries a pull against
// the sweep one row per sweep and amplifies it, ~1.3x per row on a hard cloth: the sequential
// sweep then gains energy. In colour order it does not, and it is the order the coloured sweep
// visits them in (the distance batch is coloured in particle order, so the colours stay those of
// the index order). `edges`: unique, (min, max), sorted, as Topology::edges. A rope (a mesh of
// lines only) keeps index order: along a path, one sweep carries a pin's pull in either
// direction without gaining energy, and leaves about half the stretch of the colour order.
std::vector<Edge> sweep_order(const std::vector<Edge>& edges);

// Lumped measure per vertex: a third of each adjacent triangle's area (m^2) for a surface, or
// half of each adjacent segment's length (m) for a mesh of lines only.
std::vector<Real> lumped_measure(const Mesh& mesh);

Real bounding_box_diagonal(const Positions& x);

// Twice the area of a triangle below which it counts as degenerate, relative to its longest
// edge squared: a few ulps of the cross product.
constexpr Real kDegenerateArea = 64 * std::numeric_limits<Real>::epsilon();

}  // namespace csb
