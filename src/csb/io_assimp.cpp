#include "csb/io.hpp"

#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <memory>
#include <sstream>

namespace csb {
namespace fs = std::filesystem;

namespace {

std::string lower_extension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char ch) { return std::tolower(ch); });
  return ext;
}

std::string joined(const std::vector<std::string>& items) {
  std::ostringstream s;
  for (std::size_t k = 0; k < items.size(); ++k) s << (k ? " " : "") << items[k];
  return s.str();
}

}  // namespace

std::vector<std::string> readable_extensions() {
  Assimp::Importer importer;
  std::string list;  // "*.3ds;*.obj;..."
  importer.GetExtensionList(list);
  std::vector<std::string> out;
  std::stringstream s(list);
  for (std::string item; std::getline(s, item, ';');) {
    if (item.rfind("*.", 0) == 0) item = item.substr(1);
    std::transform(item.begin(), item.end(), item.begin(), [](unsigned char ch) { return std::tolower(ch); });
    if (!item.empty()) out.push_back(item);
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

Mesh load_mesh(const std::string& path, const CleanOptions& options, MeshReport* report) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw FileNotFound(path + ": no such file");
  if (fs::is_directory(path, ec)) throw MeshError(path + ": is a directory, not a mesh file");
  if (fs::file_size(path, ec) == 0) throw MeshError(path + ": the file is empty");
  const std::string ext = lower_extension(path);

  Assimp::Importer importer;
  if (ext.empty() || !importer.IsExtensionSupported(ext))
    throw MeshError(path + ": unsupported format '" + ext + "'; csb reads " + joined(readable_extensions()));
  if (ext == ".obj") check_obj(path);
  if (ext == ".ply") check_ply(path);
  if (ext == ".stl") check_stl(path);
  if (ext == ".off") check_off(path);

  // Triangulate polygons, bake node transforms so that all meshes share world space, split
  // primitive types so that points and lines can be told apart, and let Assimp check its output.
  const unsigned flags = aiProcess_Triangulate | aiProcess_PreTransformVertices | aiProcess_SortByPType |
                         aiProcess_ValidateDataStructure;
  const aiScene* scene = importer.ReadFile(path, flags);
  if (!scene) throw MeshError(path + ": cannot read the file: " + importer.GetErrorString());
  if (scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE)
    throw MeshError(path + ": the file holds no complete mesh (Assimp marked the scene incomplete)");

  Mesh mesh;
  mesh.name = path;
  std::size_t num_vertices = 0;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) num_vertices += scene->mMeshes[m]->mNumVertices;
  mesh.vertices.resize(3, static_cast<Eigen::Index>(num_vertices));
  std::size_t points = 0, lines = 0, polygons = 0, offset = 0;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* am = scene->mMeshes[m];
    for (unsigned i = 0; i < am->mNumVertices; ++i)
      mesh.vertices.col(static_cast<Eigen::Index>(offset + i)) =
          Vec3(am->mVertices[i].x, am->mVertices[i].y, am->mVertices[i].z);
    for (unsigned f = 0; f < am->mNumFaces; ++f) {
      const aiFace& face = am->mFaces[f];
      if (face.mNumIndices == 3) {
        mesh.triangles.push_back({static_cast<Index>(offset + face.mIndices[0]),
                                  static_cast<Index>(offset + face.mIndices[1]),
                                  static_cast<Index>(offset + face.mIndices[2])});
      } else if (face.mNumIndices == 2) {
        ++lines;
      } else if (face.mNumIndices == 1) {
        ++points;
      } else {
        ++polygons;  // cannot happen after aiProcess_Triangulate; counted to be safe
      }
    }
    offset += am->mNumVertices;
  }
  if (mesh.triangles.empty())
    throw MeshError(path + ": the file has no triangles (" + std::to_string(num_vertices) + " vertices, " +
                    std::to_string(points) + " points, " + std::to_string(lines) +
                    " line segments); csb needs a surface mesh");
  MeshReport local;
  Mesh out = clean(mesh, options, &local);
  if (points + lines + polygons > 0)
    local.warnings.insert(local.warnings.begin(),
                          path + ": ignored " + std::to_string(points) + " point(s) and " + std::to_string(lines) +
                              " line segment(s) beside the triangles");
  if (report) *report = std::move(local);
  return out;
}

void save_mesh(const Mesh& mesh, const std::string& path) {
  validate(mesh);
  const std::string ext = lower_extension(path);
  // Extension -> Assimp exporter id; binary variants where a format has both.
  static const std::pair<const char*, const char*> ids[] = {
      {".obj", "obj"},   {".stl", "stlb"},     {".ply", "plyb"},  {".gltf", "gltf2"}, {".glb", "glb2"},
      {".dae", "collada"}, {".3ds", "3ds"},    {".fbx", "fbxa"},   {".x", "x"},        {".3mf", "3mf"},
      {".x3d", "x3d"},   {".assbin", "assbin"}};
  const char* id = nullptr;
  for (const auto& [e, i] : ids)
    if (ext == e) id = i;
  if (!id) throw MeshError(path + ": csb cannot write '" + ext + "' files");
  if (mesh.triangles.empty()) throw MeshError(mesh.name + ": cannot write a mesh without triangles to " + path);

  // aiScene owns (and deletes) everything attached to it.
  auto scene = std::make_unique<aiScene>();
  scene->mRootNode = new aiNode();
  scene->mRootNode->mNumMeshes = 1;
  scene->mRootNode->mMeshes = new unsigned[1]{0};
  scene->mNumMaterials = 1;
  scene->mMaterials = new aiMaterial*[1]{new aiMaterial()};
  auto* am = new aiMesh();
  scene->mNumMeshes = 1;
  scene->mMeshes = new aiMesh*[1]{am};
  am->mMaterialIndex = 0;
  am->mPrimitiveTypes = aiPrimitiveType_TRIANGLE;
  am->mNumVertices = static_cast<unsigned>(mesh.num_vertices());
  am->mVertices = new aiVector3D[am->mNumVertices];
  for (unsigned i = 0; i < am->mNumVertices; ++i) {
    const Vec3 p = mesh.vertices.col(i);
    am->mVertices[i] = aiVector3D(static_cast<ai_real>(p.x()), static_cast<ai_real>(p.y()), static_cast<ai_real>(p.z()));
  }
  am->mNumFaces = static_cast<unsigned>(mesh.triangles.size());
  am->mFaces = new aiFace[am->mNumFaces];
  for (unsigned f = 0; f < am->mNumFaces; ++f) {
    am->mFaces[f].mNumIndices = 3;
    am->mFaces[f].mIndices = new unsigned[3];
    for (int k = 0; k < 3; ++k) am->mFaces[f].mIndices[k] = static_cast<unsigned>(mesh.triangles[f][k]);
  }
  Assimp::Exporter exporter;
  if (exporter.Export(scene.get(), id, path) != aiReturn_SUCCESS)
    throw MeshError(path + ": cannot write the file: " + exporter.GetErrorString());
}

}  // namespace csb
