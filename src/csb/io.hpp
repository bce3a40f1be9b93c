// csb — reading and writing meshes through Assimp (OBJ, glTF/GLB, FBX, Collada, PLY, STL, 3DS,
// OFF and the other formats of the installed Assimp).
#pragma once

#include "csb/mesh.hpp"

#include <string>
#include <vector>

namespace csb {

// Reads every mesh of the file into one Mesh (node transforms applied, polygons triangulated),
// then clean()s it: seams are welded and degenerate triangles dropped, each reported.
// Coordinates arrive as Assimp stores them, in 32-bit floats, and are taken as metres.
// Throws FileNotFound for a missing path and MeshError (naming the file, and the line for OBJ)
// for an empty, corrupt or unsupported file, one without triangles (a point cloud, motion
// capture or another skeleton without a surface) or UTF-16/32 text. A path without an
// extension is read by its content (sniff_format, else Assimp's detection); the formats Assimp
// 5.2 knows by extension only are read through a temporary link that has it.
//
// On POSIX systems Assimp runs in a child process: a file on which it crashes or loops gives a
// MeshError, after at most `timeout` seconds (0: 10 s + 2 s per MB of file), and one on which it
// would allocate more than `max_memory` bytes (beyond what the calling process already has
// mapped; Linux enforces it) gives a MeshError naming that limit. Throws InvalidArgument for a
// negative timeout or a max_memory that is not > 0.
//
// load_mesh reads the rest pose: the static transforms of the file's nodes, bones not applied.
// What the file animates is listed in `animations` (when given) so that the caller can say so.
struct AnimationInfo {
  std::string name;           // as the file names it ("" if unnamed)
  double duration = 0;        // s (Assimp's ticks over its ticks per second, 25 where the file gives none)
  unsigned channels = 0;      // animated nodes
};
struct SkinnedMeshInfo {
  std::string name;           // the mesh's name in the file ("" if unnamed)
  unsigned bones = 0;
  unsigned vertices = 0;
};
struct AnimationSummary {
  std::vector<AnimationInfo> animations;
  std::vector<SkinnedMeshInfo> skinned;
  bool empty() const { return animations.empty() && skinned.empty(); }
};
// The file's own mesh as its tools wrote it, for writing results back onto it: its vertices
// before welding (the triangulated mesh's, in load_mesh's frame, m), its polygons as the file has
// them (quads and n-gons kept; points and lines left out), its first UV set and its normals where
// every mesh of the file has them, each mesh's material with its vertices, and the weld map. Empty
// (no faces) when the file's vertices change with triangulation (a mesh of mixed primitives).
struct SourceMesh {
  Positions vertices;                          // 3 x M, m
  std::vector<Index> face_sizes;               // corners per polygon (>= 3)
  std::vector<Index> face_vertices;            // the polygons' corners, concatenated, into vertices
  Eigen::Matrix<Real, 2, Eigen::Dynamic> uv;   // 2 x M, or no columns
  Positions normals;                           // 3 x M, as the file gives them, or no columns
  std::vector<Index> weld_map;                 // M: the vertex of the welded mesh, -1 where dropped
  struct Material {
    std::string name;                          // "" where the file names none
    Index begin = 0, end = 0;                  // its vertices: [begin, end)
  };
  std::vector<Material> materials;             // one per mesh of the file, in order
  bool empty() const { return face_sizes.empty(); }
};

inline constexpr double kDefaultMaxMemory = 2.0 * 1024 * 1024 * 1024;  // bytes (2 GiB)
Mesh load_mesh(const std::string& path, const CleanOptions& options = {}, MeshReport* report = nullptr,
               double timeout = 0, double max_memory = kDefaultMaxMemory, AnimationSummary* animations = nullptr,
               SourceMesh* file_mesh = nullptr);

// One mesh of an animated file, evaluated at the times of an Animation. Vertices are in the frame
// load_mesh reads (the nodes' transforms applied, the file's unit scale with them), m; they are
// the file's own vertices, before load_mesh's welding.
struct AnimatedMesh {
  std::string name;                  // the mesh's name in the file, else its node's
  std::string node;                  // the node that places it
  Index num_vertices = 0;
  std::vector<Real> vertices;        // times x num_vertices x 3, m
  std::vector<Triangle> triangles;
  bool skinned = false;              // bones deform it (linear blend skinning)
  // Without bones, and when the nodes above it neither scale nor shear it beyond its rest pose,
  // the mesh moves rigidly: x(t) = rotation[k] x_rest + translation[k] takes the rest pose
  // load_mesh reads to the pose at times[k] (what PbdStepper.move_collider takes).
  bool rigid = false;
  std::vector<Mat3> rotation;        // per time
  std::vector<Vec3> translation;     // m, per time
};

struct Animation {
  std::string name;                  // as the file names it
  double duration = 0;               // s
  std::vector<Real> times;           // s, where the meshes were evaluated
  std::vector<AnimatedMesh> meshes;  // one per placement of a triangle mesh in the node tree
};

// Evaluates the file's animation number `animation` (or the one named `animation_name`, if not
// empty) at `times` (s, each in [0, duration]; nullptr: the times of its keys, or 30 per second
// of its duration where it has fewer than two). Node animations interpolate their keys as Assimp
// gives them (position and scaling linearly, rotation by quaternion slerp; held before the first
// key and after the last); skinned meshes follow their bones by linear blend skinning, x = sum_b
// w_b G_b(t) O_b x_bind / sum_b w_b (G_b the bone node's global transform, O_b its offset
// matrix; a vertex no bone weighs follows its mesh's node). The file is first read as load_mesh
// reads it (same checks, timeout and max_memory, in a child process), then again in this one.
// Throws FileNotFound and MeshError as load_mesh does, and InvalidArgument for a file without
// animation, an unknown animation, and a time that is not finite or outside [0, duration].
Animation load_animation(const std::string& path, const std::vector<Real>* times = nullptr, int animation = 0,
                         const std::string& animation_name = "", double timeout = 0,
                         double max_memory = kDefaultMaxMemory);

// Writes the triangles of a mesh; the format follows the extension (.obj .stl .ply .gltf .glb
// .dae .3ds .fbx .x .3mf ...). Throws MeshError if Assimp cannot write it.
void save_mesh(const Mesh& mesh, const std::string& path);

// Lower-case extensions (with the dot) that load_mesh reads, as reported by Assimp.
std::vector<std::string> readable_extensions();

// Checks an OBJ file's syntax more strictly than Assimp does, naming the line of the first
// problem: vertices with fewer than three or non-finite coordinates, faces with fewer than three
// vertices, zero or out-of-range (including relative, negative) indices. Throws MeshError.
void check_obj(const std::string& path);

// Refuses a file that starts with a UTF-16 or UTF-32 byte-order mark, naming the encoding (the
// text readers take ASCII or UTF-8; a UTF-8 mark is skipped), or with UTF-16 text without one
// (eight printable characters each beside a zero byte). Throws MeshError.
void check_encoding(const std::string& path);

// The extension of a file named without one, from its first word where that is unambiguous
// (".ply", ".off", ".bvh", ".stl" for "solid"), from its first 4 kB (".x3d" for an <X3D element),
// or from a binary signature (".glb"; ".stl" when the size matches a binary STL's triangle count;
// ".3mf" for a zip holding 3D/3dmodel.model); "" otherwise (Assimp then detects the format from
// the content).
std::string sniff_format(const std::string& path);

// Header consistency checks run before Assimp sees the file (Assimp 5.2 loops forever on some
// truncated PLY headers): declared element counts must fit the file. Throw MeshError.
void check_ply(const std::string& path);
void check_stl(const std::string& path);
void check_off(const std::string& path);

}  // namespace csb
