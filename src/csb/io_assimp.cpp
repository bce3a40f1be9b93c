#include "csb/io.hpp"
#include "csb/memory_budget.hpp"

#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <new>
#include <sstream>

#if defined(__unix__) || defined(__APPLE__)
#define CSB_ISOLATED_IMPORT 1
#include <csignal>
#include <fcntl.h>
#include <poll.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>
#else
#define CSB_ISOLATED_IMPORT 0
#endif

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

namespace {

// What load_mesh needs from Assimp's scene: float32 coordinates (Assimp's ai_real) and
// triangles, plus counts of what is not a triangle, or Assimp's error message.
struct RawScene {
  bool ok = false;
  std::string error;
  std::vector<float> vertices;        // x, y, z per vertex, all meshes concatenated
  std::vector<std::uint32_t> triangles;
  std::uint64_t points = 0, lines = 0, polygons = 0;
  std::string animation;  // encode_summary() of what the file animates
  // The file's polygons before triangulation (SourceMesh), over the same vertices; empty when the
  // triangulated scene's vertices are not those (a mesh of mixed primitives split by type).
  std::vector<std::uint32_t> face_sizes, face_indices;
  std::vector<float> uv, normals;  // 2 and 3 per vertex, or none
  std::string materials;           // "name\tbegin\tend\n" per mesh: its material and vertex range
};

// Ticks per second of an animation: Assimp leaves 0 where the file gives none, and its own
// viewer then plays 25.
double ticks_per_second(const aiAnimation* a) { return a->mTicksPerSecond > 0 ? a->mTicksPerSecond : 25.0; }

std::string printable(const aiString& name) {
  std::string s(name.C_Str());
  for (char& c : s)
    if (c == '\t' || c == '\n' || c == '\r') c = ' ';
  return s;
}

// The animations and skinned meshes of a scene as read, before post-processing (which drops them
// when it bakes the node transforms).
AnimationSummary summarize(const aiScene* scene) {
  AnimationSummary out;
  for (unsigned k = 0; k < scene->mNumAnimations; ++k) {
    const aiAnimation* a = scene->mAnimations[k];
    out.animations.push_back({printable(a->mName), a->mDuration / ticks_per_second(a), a->mNumChannels});
  }
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* am = scene->mMeshes[m];
    if (am->mNumBones > 0) out.skinned.push_back({printable(am->mName), am->mNumBones, am->mNumVertices});
  }
  return out;
}

// One line per item, tab-separated: "a name duration channels" or "s name bones vertices"; it
// crosses the pipe from the import process.
std::string encode_summary(const AnimationSummary& summary) {
  std::ostringstream s;
  s.precision(17);
  for (const AnimationInfo& a : summary.animations) s << "a\t" << a.name << '\t' << a.duration << '\t' << a.channels << '\n';
  for (const SkinnedMeshInfo& m : summary.skinned) s << "s\t" << m.name << '\t' << m.bones << '\t' << m.vertices << '\n';
  return s.str();
}

AnimationSummary decode_summary(const std::string& text) {
  AnimationSummary out;
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);) {
    std::vector<std::string> f;
    std::istringstream fields(line);
    for (std::string item; std::getline(fields, item, '\t');) f.push_back(item);
    if (f.size() != 4) continue;
    if (f[0] == "a") out.animations.push_back({f[1], std::strtod(f[2].c_str(), nullptr),
                                               static_cast<unsigned>(std::strtoul(f[3].c_str(), nullptr, 10))});
    if (f[0] == "s") out.skinned.push_back({f[1], static_cast<unsigned>(std::strtoul(f[2].c_str(), nullptr, 10)),
                                            static_cast<unsigned>(std::strtoul(f[3].c_str(), nullptr, 10))});
  }
  return out;
}

// The polygons (3 or more corners; points and lines are not kept), first UV set and normals of
// every mesh of a scene whose node transforms are baked, over its vertices concatenated (into
// `vertices`, as read_in_process concatenates them), and each mesh's material: SourceMesh.
void keep_polygons(const aiScene* scene, RawScene& raw, std::vector<float>& vertices) {
  bool uv = true, normals = true;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    uv = uv && scene->mMeshes[m]->HasTextureCoords(0);
    normals = normals && scene->mMeshes[m]->HasNormals();
  }
  std::uint32_t offset = 0;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* am = scene->mMeshes[m];
    for (unsigned i = 0; i < am->mNumVertices; ++i) {
      vertices.insert(vertices.end(), {static_cast<float>(am->mVertices[i].x), static_cast<float>(am->mVertices[i].y),
                                       static_cast<float>(am->mVertices[i].z)});
      if (uv) raw.uv.insert(raw.uv.end(), {am->mTextureCoords[0][i].x, am->mTextureCoords[0][i].y});
      if (normals) raw.normals.insert(raw.normals.end(), {am->mNormals[i].x, am->mNormals[i].y, am->mNormals[i].z});
    }
    for (unsigned f = 0; f < am->mNumFaces; ++f) {
      const aiFace& face = am->mFaces[f];
      if (face.mNumIndices < 3) continue;
      raw.face_sizes.push_back(face.mNumIndices);
      for (unsigned k = 0; k < face.mNumIndices; ++k) raw.face_indices.push_back(offset + face.mIndices[k]);
    }
    aiString name;
    const std::string material = am->mMaterialIndex < scene->mNumMaterials &&
                                         scene->mMaterials[am->mMaterialIndex]->Get(AI_MATKEY_NAME, name) == aiReturn_SUCCESS
                                     ? printable(name)
                                     : std::string();
    raw.materials += material + "\t" + std::to_string(offset) + "\t" + std::to_string(offset + am->mNumVertices) + "\n";
    offset += am->mNumVertices;
  }
}

RawScene read_in_process(const std::string& path) {
  RawScene raw;
  Assimp::Importer importer;
  // Triangulate polygons, bake node transforms so that all meshes share world space, split
  // primitive types so that points and lines can be told apart, and let Assimp check its output.
  const unsigned flags = aiProcess_Triangulate | aiProcess_PreTransformVertices | aiProcess_SortByPType |
                         aiProcess_ValidateDataStructure;
  // Assimp's ReadFile validates, then post-processes; split in two, the same steps run in the same
  // order, and the animations can be listed in between.
  // The node transforms are baked first, then the polygons triangulated and the primitives
  // sorted: the order Assimp runs these steps in when given together, so the result is the same,
  // and in between the file's own polygons, UVs, normals and materials are kept (SourceMesh).
  const aiScene* scene = importer.ReadFile(path, aiProcess_ValidateDataStructure);
  std::vector<float> baked;
  if (scene) {
    raw.animation = encode_summary(summarize(scene));
    scene = importer.ApplyPostProcessing(aiProcess_PreTransformVertices);
  }
  if (scene) {
    keep_polygons(scene, raw, baked);
    scene = importer.ApplyPostProcessing(flags & ~(aiProcess_ValidateDataStructure | aiProcess_PreTransformVertices));
  }
  if (!scene) {
    // Assimp turns the std::bad_alloc of an exhausted memory limit into an error string.
    if (std::strstr(importer.GetErrorString(), "bad_alloc")) throw std::bad_alloc();
    raw.error = std::string("cannot read the file: ") + importer.GetErrorString();
    // Assimp's post-processing fails on a point cloud ("all meshes are orphaned"): read the file
    // again as it is, and if it holds no polygon, say so with what it holds.
    if (const aiScene* bare = importer.ReadFile(path, 0)) {
      std::uint64_t points = 0, segments = 0, polygons = 0;
      for (unsigned m = 0; m < bare->mNumMeshes; ++m) {
        const aiMesh* am = bare->mMeshes[m];
        if (am->mNumFaces == 0) points += am->mNumVertices;
        for (unsigned f = 0; f < am->mNumFaces; ++f) {
          const unsigned n = am->mFaces[f].mNumIndices;
          (n >= 3 ? polygons : n == 2 ? segments : points) += 1;
        }
      }
      if (polygons == 0)
        raw.error = "the file has no triangles (" + std::to_string(points) + " points" +
                    (segments ? ", " + std::to_string(segments) + " line segments" : std::string()) +
                    "); csb needs a surface mesh";
    }
    return raw;
  }
  // Assimp draws placeholder bones (material "SkeletonMaterial") for a file that holds a skeleton
  // and no surface, such as motion capture; as a cloth they would be a meaningless surface.
  for (unsigned k = 0; k < scene->mNumMaterials; ++k) {
    aiString name;
    if (scene->mMaterials[k]->Get(AI_MATKEY_NAME, name) == aiReturn_SUCCESS &&
        std::strcmp(name.C_Str(), "SkeletonMaterial") == 0) {
      raw.error = "the file holds a skeleton and no surface (Assimp drew placeholder bones for it)";
      return raw;
    }
  }
  if (scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE) {
    raw.error = "the file holds no complete mesh (Assimp marked the scene incomplete)";
    return raw;
  }
  std::uint32_t offset = 0;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* am = scene->mMeshes[m];
    for (unsigned i = 0; i < am->mNumVertices; ++i)
      raw.vertices.insert(raw.vertices.end(), {static_cast<float>(am->mVertices[i].x),
                                               static_cast<float>(am->mVertices[i].y),
                                               static_cast<float>(am->mVertices[i].z)});
    for (unsigned f = 0; f < am->mNumFaces; ++f) {
      const aiFace& face = am->mFaces[f];
      if (face.mNumIndices == 3) {
        for (int k = 0; k < 3; ++k) raw.triangles.push_back(offset + face.mIndices[k]);
      } else if (face.mNumIndices == 2) {
        ++raw.lines;
      } else if (face.mNumIndices == 1) {
        ++raw.points;
      } else {
        ++raw.polygons;  // cannot happen after aiProcess_Triangulate; counted to be safe
      }
    }
    offset += am->mNumVertices;
  }
  if (raw.vertices != baked) {  // triangulation or the split by type changed the vertices
    raw.face_sizes.clear(), raw.face_indices.clear(), raw.uv.clear(), raw.normals.clear(), raw.materials.clear();
  }
  raw.ok = true;
  return raw;
}

#if CSB_ISOLATED_IMPORT
// Assimp's parsers can loop forever or crash on corrupt input (Assimp 5.2 hangs on some damaged
// Collada index lists and PLY headers). The import therefore runs in a forked child that sends
// the scene back through a pipe; the parent gives up at a deadline and reports a crash as an
// error instead of dying with it. glibc's fork() keeps malloc usable in the child, which only
// runs Assimp and then _exit()s. The child's address space is capped (RLIMIT_AS) at what it
// inherited plus max_memory: a header that declares 10^9 vertices makes Assimp allocate
// gigabytes before it finds the data missing, and the cap turns that into std::bad_alloc.

// Bytes of address space this process has mapped (0 where /proc is absent). Plain syscalls:
// this runs in the forked child.
std::uint64_t mapped_bytes() {
  const int fd = ::open("/proc/self/statm", O_RDONLY);
  if (fd < 0) return 0;
  char text[64] = {};
  const ssize_t n = ::read(fd, text, sizeof text - 1);
  ::close(fd);
  if (n <= 0) return 0;
  std::uint64_t pages = 0;
  for (const char* c = text; *c >= '0' && *c <= '9'; ++c) pages = 10 * pages + static_cast<std::uint64_t>(*c - '0');
  return pages * static_cast<std::uint64_t>(::sysconf(_SC_PAGESIZE));
}

void limit_memory(double max_memory) {
  rlimit lim{};
  if (::getrlimit(RLIMIT_AS, &lim) != 0) return;
  rlim_t cap = static_cast<rlim_t>(mapped_bytes() + static_cast<std::uint64_t>(max_memory));
  if (lim.rlim_max != RLIM_INFINITY) cap = std::min(cap, lim.rlim_max);
  lim.rlim_cur = cap;
  ::setrlimit(RLIMIT_AS, &lim);
}

constexpr std::uint64_t kOutOfMemory = 2;  // the result header's status when the cap was hit
constexpr std::size_t kHeader = 13;           // the result header's fields (child_import)

bool write_all(int fd, const void* data, std::size_t n) {
  const char* p = static_cast<const char*>(data);
  while (n > 0) {
    const ssize_t w = ::write(fd, p, n);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return false;
    p += w;
    n -= static_cast<std::size_t>(w);
  }
  return true;
}

void child_import(const std::string& path, int fd, double max_memory) {
  limit_memory(max_memory);
  RawScene raw;
  bool out_of_memory = false;
  try {
    raw = read_in_process(path);
  } catch (const std::bad_alloc&) {
    out_of_memory = true;
  } catch (const std::exception& e) {
    raw.error = std::string("cannot read the file: ") + e.what();
  } catch (...) {
    raw.error = "cannot read the file: Assimp failed with an unknown exception";
  }
  const std::uint64_t header[kHeader] = {out_of_memory ? kOutOfMemory : raw.ok ? 1u : 0u, raw.error.size(), raw.vertices.size(),
                                         raw.triangles.size(), raw.points, raw.lines, raw.polygons, raw.animation.size(),
                                         raw.face_sizes.size(), raw.face_indices.size(), raw.uv.size(), raw.normals.size(),
                                         raw.materials.size()};
  const bool sent = write_all(fd, header, sizeof header) && write_all(fd, raw.error.data(), raw.error.size()) &&
                    write_all(fd, raw.animation.data(), raw.animation.size()) &&
                    write_all(fd, raw.vertices.data(), raw.vertices.size() * sizeof(float)) &&
                    write_all(fd, raw.triangles.data(), raw.triangles.size() * sizeof(std::uint32_t)) &&
                    write_all(fd, raw.face_sizes.data(), raw.face_sizes.size() * sizeof(std::uint32_t)) &&
                    write_all(fd, raw.face_indices.data(), raw.face_indices.size() * sizeof(std::uint32_t)) &&
                    write_all(fd, raw.uv.data(), raw.uv.size() * sizeof(float)) &&
                    write_all(fd, raw.normals.data(), raw.normals.size() * sizeof(float)) &&
                    write_all(fd, raw.materials.data(), raw.materials.size());
  ::close(fd);
  ::_exit(sent ? 0 : 3);
}

RawScene receive(pid_t pid, int fd, double timeout, double max_memory);

// What the child printed (Assimp's assertion messages go to stderr): its last line, trimmed, or "".
std::string last_printed_line(int fd) {
  char text[4096];
  const off_t size = ::lseek(fd, 0, SEEK_END);
  if (size <= 0) return {};
  const off_t from = std::max<off_t>(0, size - static_cast<off_t>(sizeof text));
  const ssize_t n = ::pread(fd, text, sizeof text, from);
  if (n <= 0) return {};
  std::string s(text, static_cast<std::size_t>(n));
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.pop_back();
  const std::size_t nl = s.find_last_of('\n');
  if (nl != std::string::npos) s.erase(0, nl + 1);
  for (char& c : s)
    if (!std::isprint(static_cast<unsigned char>(c))) c = '?';
  return s.size() > 300 ? s.substr(0, 300) + "..." : s;
}

RawScene read_isolated(const std::string& path, double timeout, double max_memory) {
  int fds[2];
  if (::pipe(fds) != 0) return read_in_process(path);
  // The child's stdout and stderr go to an unlinked temporary file, never to the user's terminal;
  // on failure its last line is quoted in the error.
  std::FILE* printed = std::tmpfile();
  const pid_t pid = ::fork();
  if (pid < 0) {
    ::close(fds[0]);
    ::close(fds[1]);
    if (printed) std::fclose(printed);
    return read_in_process(path);
  }
  if (pid == 0) {
    ::close(fds[0]);
    const int sink = printed ? ::fileno(printed) : ::open("/dev/null", O_WRONLY);
    if (sink >= 0) {
      ::dup2(sink, STDOUT_FILENO);
      ::dup2(sink, STDERR_FILENO);
    }
    child_import(path, fds[1], max_memory);
  }
  ::close(fds[1]);
  RawScene raw = receive(pid, fds[0], timeout, max_memory);
  if (printed) {
    if (!raw.ok && !raw.error.empty()) {
      const std::string said = last_printed_line(::fileno(printed));
      if (!said.empty()) raw.error += " (Assimp printed: " + said + ")";
    }
    std::fclose(printed);
  }
  return raw;
}

// The parent's side: read the child's result until the deadline, then reap the child.
RawScene receive(pid_t pid, int fd, double timeout, double max_memory) {
  std::string bytes;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout);
  bool timed_out = false;
  char buffer[1 << 16];
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      timed_out = true;
      break;
    }
    pollfd pfd{fd, POLLIN, 0};
    const int r = ::poll(&pfd, 1, static_cast<int>(std::min<long long>(left.count(), 1000)));
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) continue;
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;  // EOF: the child is done (or died)
    bytes.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fd);
  if (timed_out) ::kill(pid, SIGKILL);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  RawScene raw;
  std::ostringstream why;
  const auto raise_memory = [&] {
    why << " and was stopped; the file is probably corrupt (pass a larger max_memory (bytes) to load_mesh if it "
           "really is that large)";
  };
  if (timed_out) {
    why << "reading the file took longer than " << timeout
        << " s and was stopped; the file is probably corrupt (Assimp can loop forever on damaged input)";
    raw.error = why.str();
    return raw;
  }
  if (WIFSIGNALED(status)) {
    why << "Assimp crashed (signal " << WTERMSIG(status) << ") while reading the file; it is probably corrupt (a "
        << "crash can also come from reaching the max_memory limit of " << static_cast<std::uint64_t>(max_memory)
        << " bytes: pass a larger max_memory (bytes) to load_mesh if the file really is that large)";
    raw.error = why.str();
    return raw;
  }
  std::uint64_t header[kHeader];
  if (bytes.size() < sizeof header) {
    raw.error = "the import process ended without a result";
    return raw;
  }
  std::memcpy(header, bytes.data(), sizeof header);
  if (header[0] == kOutOfMemory) {
    why << "reading the file needed more than the max_memory limit of " << static_cast<std::uint64_t>(max_memory)
        << " bytes";
    raise_memory();
    raw.error = why.str();
    return raw;
  }
  const std::size_t need = sizeof header + header[1] + header[7] + header[2] * sizeof(float) +
                           (header[3] + header[8] + header[9]) * sizeof(std::uint32_t) +
                           (header[10] + header[11]) * sizeof(float) + header[12];
  if (bytes.size() != need) {
    raw.error = "the import process sent an incomplete result";
    return raw;
  }
  const char* p = bytes.data() + sizeof header;
  raw.ok = header[0] == 1;
  raw.error.assign(p, header[1]);
  p += header[1];
  raw.animation.assign(p, header[7]);
  p += header[7];
  // An empty vector's data() may be null, and memcpy from or to null is undefined even for
  // 0 bytes (UBSan reports it): a refused file sends no vertices.
  raw.vertices.resize(header[2]);
  if (header[2] > 0) std::memcpy(raw.vertices.data(), p, header[2] * sizeof(float));
  p += header[2] * sizeof(float);
  const auto take = [&p](auto& v, std::uint64_t n) {
    v.resize(n);
    if (n > 0) std::memcpy(v.data(), p, n * sizeof(v[0]));
    p += n * sizeof(v[0]);
  };
  take(raw.triangles, header[3]);
  take(raw.face_sizes, header[8]);
  take(raw.face_indices, header[9]);
  take(raw.uv, header[10]);
  take(raw.normals, header[11]);
  raw.materials.assign(p, header[12]);
  raw.points = header[4];
  raw.lines = header[5];
  raw.polygons = header[6];
  return raw;
}
#endif

// A symbolic link to `target` named with `ext`, in a fresh temporary directory, removed with
// both when this goes out of scope; `path` is empty when target is empty or no link could be
// made (then the file is read as it is).
struct NamedLink {
  std::string path;
  fs::path dir;
  NamedLink(const std::string& target, const std::string& ext) {
#if CSB_ISOLATED_IMPORT  // POSIX: mkdtemp
    if (target.empty()) return;
    std::error_code ec;
    const fs::path absolute = fs::absolute(target, ec);
    if (ec) return;
    std::string pattern = (fs::temp_directory_path(ec) / "csb-mesh-XXXXXX").string();
    if (ec || ::mkdtemp(pattern.data()) == nullptr) return;
    dir = pattern;
    const fs::path link = dir / ("mesh" + ext);
    fs::create_symlink(absolute, link, ec);
    if (!ec) path = link.string();
#else
    (void)target;
    (void)ext;
#endif
  }
  ~NamedLink() {
    std::error_code ec;
    if (!dir.empty()) fs::remove_all(dir, ec);
  }
  NamedLink(const NamedLink&) = delete;
  NamedLink& operator=(const NamedLink&) = delete;
};

}  // namespace

Mesh load_mesh(const std::string& path, const CleanOptions& options, MeshReport* report, double timeout,
               double max_memory, AnimationSummary* animations, SourceMesh* file_mesh) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw FileNotFound(path + ": no such file");
  if (fs::is_directory(path, ec)) throw MeshError(path + ": is a directory, not a mesh file");
  const std::uintmax_t bytes = fs::file_size(path, ec);
  if (bytes == 0) throw MeshError(path + ": the file is empty");
  std::string ext = lower_extension(path);
  const bool named = !ext.empty();
  if (named && !Assimp::Importer().IsExtensionSupported(ext))
    throw MeshError(path + ": unsupported format '" + ext + "'; csb reads " + joined(readable_extensions()));
  if (!(timeout >= 0)) throw InvalidArgument(path + ": timeout must be >= 0 s (0: automatic)");
  if (!(max_memory > 0 && max_memory < 1.8e19))
    throw InvalidArgument(path + ": max_memory must be > 0 bytes, got " + std::to_string(max_memory));
  // A file without an extension: the formats whose pre-checks need one are recognised by their
  // first word; for the others Assimp detects the format from the content.
  if (!named) ext = sniff_format(path);
  // Motion capture: Assimp reads the skeleton and draws placeholder bones, no surface.
  static const std::pair<const char*, const char*> motion[] = {{".bvh", "BVH"}, {".csm", "CSM"}};
  for (const auto& [e, name] : motion)
    if (ext == e)
      throw MeshError(path + ": is a motion-capture file (" + name + "): it holds a skeleton and no surface");
  // A binary STL header may start with any bytes; check_stl looks at an STL's encoding itself.
  if (ext != ".stl") check_encoding(path);
  if (ext == ".obj") check_obj(path);
  if (ext == ".ply") check_ply(path);
  if (ext == ".stl") check_stl(path);
  if (ext == ".off") check_off(path);

  // Assimp 5.2 knows these self-contained formats by their extension only: an unnamed one is read
  // through a link that has it.
  const NamedLink link(named || !(ext == ".stl" || ext == ".glb" || ext == ".x3d" || ext == ".3mf") ? "" : path, ext);
  const std::string& source = link.path.empty() ? path : link.path;
#if CSB_ISOLATED_IMPORT
  // Automatic deadline: generous for real files (Assimp reads tens of MB/s).
  if (timeout == 0) timeout = 10.0 + 2.0 * static_cast<double>(bytes) / 1e6;
  const RawScene raw = read_isolated(source, timeout, max_memory);
#else
  const RawScene raw = read_in_process(source);
#endif
  if (!raw.ok && !named && raw.error.rfind("cannot read the file: ", 0) == 0)
    throw MeshError(path + ": the file has no extension and Assimp did not recognise its content (" +
                    raw.error.substr(22) + "); name it with its format's extension" +
                    (ext.empty() ? " (csb reads " + joined(readable_extensions()) + ")"
                                 : " (it looks like a '" + ext + "' file)"));
  if (!raw.ok) throw MeshError(path + ": " + raw.error);

  Mesh mesh;
  mesh.name = path;
  const std::size_t num_vertices = raw.vertices.size() / 3;
  mesh.vertices.resize(3, static_cast<Eigen::Index>(num_vertices));
  for (std::size_t i = 0; i < raw.vertices.size(); ++i) mesh.vertices.data()[i] = raw.vertices[i];
  mesh.triangles.resize(raw.triangles.size() / 3);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k) mesh.triangles[t][k] = static_cast<Index>(raw.triangles[3 * t + k]);
  if (mesh.triangles.empty())
    throw MeshError(path + ": the file has no triangles (" +
                    (raw.points + raw.lines == 0
                         ? std::to_string(num_vertices) + " vertices and no faces"
                         : (raw.points ? std::to_string(raw.points) + " points" : std::string()) +
                               (raw.points && raw.lines ? ", " : "") +
                               (raw.lines ? std::to_string(raw.lines) + " line segments" : std::string())) +
                    "); csb needs a surface mesh");
  MeshReport local;
  Mesh out = clean(mesh, options, &local);
  if (raw.points + raw.lines + raw.polygons > 0)
    local.warnings.insert(local.warnings.begin(), path + ": ignored " + std::to_string(raw.points) +
                                                      " point(s) and " + std::to_string(raw.lines) +
                                                      " line segment(s) beside the triangles");
  if (file_mesh) {
    *file_mesh = SourceMesh{};
    if (!raw.face_sizes.empty()) {
      file_mesh->vertices = mesh.vertices;
      file_mesh->face_sizes.assign(raw.face_sizes.begin(), raw.face_sizes.end());
      file_mesh->face_vertices.assign(raw.face_indices.begin(), raw.face_indices.end());
      if (raw.uv.size() == 2 * num_vertices) {
        file_mesh->uv.resize(2, static_cast<Eigen::Index>(num_vertices));
        for (std::size_t i = 0; i < raw.uv.size(); ++i) file_mesh->uv.data()[i] = raw.uv[i];
      }
      if (raw.normals.size() == 3 * num_vertices) {
        file_mesh->normals.resize(3, static_cast<Eigen::Index>(num_vertices));
        for (std::size_t i = 0; i < raw.normals.size(); ++i) file_mesh->normals.data()[i] = raw.normals[i];
      }
      file_mesh->weld_map = local.vertex_map;
      std::istringstream lines(raw.materials);
      for (std::string line; std::getline(lines, line);) {
        const std::size_t a = line.find('\t'), b = line.find('\t', a + 1);
        if (a == std::string::npos || b == std::string::npos) continue;
        file_mesh->materials.push_back({line.substr(0, a), static_cast<Index>(std::stoul(line.substr(a + 1, b - a - 1))),
                                     static_cast<Index>(std::stoul(line.substr(b + 1)))});
      }
    }
  }
  if (report) *report = std::move(local);
  if (animations) *animations = decode_summary(raw.animation);
  return out;
}

namespace {

using Mat4 = Eigen::Matrix<double, 4, 4>;

Mat4 to_eigen(const aiMatrix4x4& m) {
  Mat4 e;
  e << m.a1, m.a2, m.a3, m.a4, m.b1, m.b2, m.b3, m.b4, m.c1, m.c2, m.c3, m.c4, m.d1, m.d2, m.d3, m.d4;
  return e;
}

Vec3 to_eigen(const aiVector3D& v) { return Vec3(v.x, v.y, v.z); }

// The key at or before `tick` and the fraction of the way to the next one; the first key before
// it, the last after it (Assimp's keys are sorted by time).
template <class Key>
std::pair<unsigned, double> bracket(const Key* keys, unsigned n, double tick) {
  if (n == 1 || tick <= keys[0].mTime) return {0, 0.0};
  if (tick >= keys[n - 1].mTime) return {n - 1, 0.0};
  unsigned lo = 0, hi = n - 1;  // keys[lo].mTime <= tick < keys[hi].mTime
  while (hi - lo > 1) {
    const unsigned mid = lo + (hi - lo) / 2;
    (keys[mid].mTime <= tick ? lo : hi) = mid;
  }
  const double span = keys[hi].mTime - keys[lo].mTime;
  return {lo, span > 0 ? (tick - keys[lo].mTime) / span : 0.0};
}

Vec3 interpolate(const aiVectorKey* keys, unsigned n, double tick) {
  const auto [k, f] = bracket(keys, n, tick);
  const Vec3 a = to_eigen(keys[k].mValue);
  return f == 0.0 ? a : Vec3(a + f * (to_eigen(keys[k + 1].mValue) - a));
}

Eigen::Quaterniond to_eigen(const aiQuaternion& q) { return Eigen::Quaterniond(q.w, q.x, q.y, q.z).normalized(); }

// Shoemake's (1985) slerp along the shorter arc (Eigen's slerp flips the sign of a negative dot).
Eigen::Quaterniond interpolate(const aiQuatKey* keys, unsigned n, double tick) {
  const auto [k, f] = bracket(keys, n, tick);
  const Eigen::Quaterniond a = to_eigen(keys[k].mValue);
  return f == 0.0 ? a : a.slerp(f, to_eigen(keys[k + 1].mValue));
}

// A node's transform relative to its parent at `tick`: T R S from its channel's keys, each part
// without keys taken from the node's static transform.
Mat4 local_transform(const aiNode* node, const aiNodeAnim* channel, double tick) {
  if (!channel) return to_eigen(node->mTransformation);
  aiVector3D s0, p0;
  aiQuaternion r0;
  node->mTransformation.Decompose(s0, r0, p0);
  const Vec3 p = channel->mNumPositionKeys ? interpolate(channel->mPositionKeys, channel->mNumPositionKeys, tick)
                                           : to_eigen(p0);
  const Eigen::Quaterniond r = channel->mNumRotationKeys
                                   ? interpolate(channel->mRotationKeys, channel->mNumRotationKeys, tick)
                                   : to_eigen(r0);
  const Vec3 s = channel->mNumScalingKeys ? interpolate(channel->mScalingKeys, channel->mNumScalingKeys, tick)
                                          : to_eigen(s0);
  Mat4 m = Mat4::Identity();
  m.topLeftCorner<3, 3>() = r.toRotationMatrix() * s.asDiagonal();
  m.topRightCorner<3, 1>() = p;
  return m;
}

// Every node's global transform (its ancestors' transforms and its own), animated by `anim` at
// `tick`, or static (the rest pose load_mesh reads) when anim is null.
std::map<const aiNode*, Mat4> global_transforms(const aiScene* scene, const aiAnimation* anim, double tick) {
  std::map<std::string, const aiNodeAnim*> channels;
  if (anim)
    for (unsigned c = 0; c < anim->mNumChannels; ++c) channels[anim->mChannels[c]->mNodeName.C_Str()] = anim->mChannels[c];
  std::map<const aiNode*, Mat4> out;
  std::vector<std::pair<const aiNode*, Mat4>> stack{{scene->mRootNode, Mat4::Identity()}};
  while (!stack.empty()) {
    const auto [node, parent] = stack.back();
    stack.pop_back();
    const auto found = channels.find(node->mName.C_Str());
    const Mat4 global = parent * local_transform(node, found == channels.end() ? nullptr : found->second, tick);
    out[node] = global;
    for (unsigned c = 0; c < node->mNumChildren; ++c) stack.push_back({node->mChildren[c], global});
  }
  return out;
}

// The placements of the scene's triangle meshes, depth first as the nodes are stored.
std::vector<std::pair<const aiNode*, unsigned>> mesh_placements(const aiScene* scene) {
  std::vector<std::pair<const aiNode*, unsigned>> out;
  std::vector<const aiNode*> stack{scene->mRootNode};
  while (!stack.empty()) {
    const aiNode* node = stack.back();
    stack.pop_back();
    for (unsigned k = 0; k < node->mNumMeshes; ++k)
      if (scene->mMeshes[node->mMeshes[k]]->mPrimitiveTypes & aiPrimitiveType_TRIANGLE) out.push_back({node, node->mMeshes[k]});
    for (unsigned c = node->mNumChildren; c-- > 0;) stack.push_back(node->mChildren[c]);
  }
  return out;
}

}  // namespace

Animation load_animation(const std::string& path, const std::vector<Real>* times, int animation,
                         const std::string& animation_name, double timeout, double max_memory) {
  // The isolated read checks the file (and that Assimp neither crashes nor loops on it) and lists
  // its animations; reading it again in this process is then safe.
  AnimationSummary summary;
  load_mesh(path, {}, nullptr, timeout, max_memory, &summary);
  if (summary.animations.empty())
    throw InvalidArgument(path + ": the file holds no animation" +
                          (summary.skinned.empty() ? std::string()
                                                   : " (it has skinned meshes, but nothing moves their bones)") +
                          "; load_mesh reads it as it is");
  Assimp::Importer importer;
  const aiScene* scene =
      importer.ReadFile(path, aiProcess_Triangulate | aiProcess_SortByPType | aiProcess_ValidateDataStructure);
  if (!scene || !scene->mRootNode) throw MeshError(path + ": cannot read the file: " + importer.GetErrorString());
  if (scene->mNumAnimations == 0) throw InvalidArgument(path + ": the file holds no animation");

  std::string names;
  for (unsigned k = 0; k < scene->mNumAnimations; ++k)
    names += (k ? ", " : "") + std::to_string(k) + " '" + printable(scene->mAnimations[k]->mName) + "'";
  const aiAnimation* anim = nullptr;
  if (!animation_name.empty()) {
    for (unsigned k = 0; k < scene->mNumAnimations && !anim; ++k)
      if (animation_name == scene->mAnimations[k]->mName.C_Str()) anim = scene->mAnimations[k];
    if (!anim) throw InvalidArgument(path + ": animation: no animation named '" + animation_name + "' (the file has " + names + ")");
  } else {
    if (animation < 0 || static_cast<unsigned>(animation) >= scene->mNumAnimations)
      throw InvalidArgument(path + ": animation must be an index in [0, " + std::to_string(scene->mNumAnimations - 1) +
                            "], got " + std::to_string(animation) + " (the file has " + names + ")");
    anim = scene->mAnimations[animation];
  }
  const double tps = ticks_per_second(anim);
  Animation out;
  out.name = anim->mName.C_Str();
  out.duration = anim->mDuration / tps;

  if (times) {
    for (std::size_t k = 0; k < times->size(); ++k) {
      const double t = (*times)[k];
      if (!std::isfinite(t)) throw InvalidArgument(path + ": times[" + std::to_string(k) + "] is not finite");
      if (t < 0 || t > out.duration) {
        std::ostringstream why;
        why.precision(17);
        why << path << ": times[" << k << "] = " << t << " s is outside the animation '" << out.name << "' (0 to "
            << out.duration << " s)";
        throw InvalidArgument(why.str());
      }
    }
    out.times = *times;
  } else {
    for (unsigned c = 0; c < anim->mNumChannels; ++c) {
      const aiNodeAnim* ch = anim->mChannels[c];
      for (unsigned k = 0; k < ch->mNumPositionKeys; ++k) out.times.push_back(ch->mPositionKeys[k].mTime / tps);
      for (unsigned k = 0; k < ch->mNumRotationKeys; ++k) out.times.push_back(ch->mRotationKeys[k].mTime / tps);
      for (unsigned k = 0; k < ch->mNumScalingKeys; ++k) out.times.push_back(ch->mScalingKeys[k].mTime / tps);
    }
    std::sort(out.times.begin(), out.times.end());
    out.times.erase(std::unique(out.times.begin(), out.times.end()), out.times.end());
    out.times.erase(std::remove_if(out.times.begin(), out.times.end(),
                                   [&](double t) { return !(t >= 0 && t <= out.duration); }),
                    out.times.end());
    if (out.times.size() < 2) {
      constexpr double rate = 30.0;  // Hz
      out.times.clear();
      const auto frames = static_cast<std::size_t>(std::floor(out.duration * rate));
      for (std::size_t k = 0; k <= frames; ++k) out.times.push_back(static_cast<double>(k) / rate);
      if (out.times.back() < out.duration) out.times.push_back(out.duration);
    }
  }

  const auto placements = mesh_placements(scene);
  const std::size_t T = out.times.size();
  // The vertices at every time are held twice at the peak (here and in the caller's copy).
  double vertices = 0;
  for (const auto& placement : placements) vertices += scene->mMeshes[placement.second]->mNumVertices;
  const double need = 2.0 * static_cast<double>(T) * vertices * 3 * sizeof(Real), have = physical_memory_bytes();
  if (have > 0 && need > have)
    throw InvalidArgument(path + ": times: " + std::to_string(T) + " times of " + detail::str(vertices) +
                          " vertices would need about " + detail::str(need / 1e9) + " GB, more than this machine's " +
                          detail::str(have / 1e9) + " GB of memory; ask for fewer times");
  const auto rest = global_transforms(scene, nullptr, 0.0);
  std::vector<std::map<const aiNode*, Mat4>> posed(T);
  for (std::size_t k = 0; k < T; ++k) posed[k] = global_transforms(scene, anim, out.times[k] * tps);

  for (const auto& [node, index] : placements) {
    const aiMesh* am = scene->mMeshes[index];
    AnimatedMesh m;
    m.name = am->mName.length ? am->mName.C_Str() : node->mName.C_Str();
    m.node = node->mName.C_Str();
    m.num_vertices = static_cast<Index>(am->mNumVertices);
    for (unsigned f = 0; f < am->mNumFaces; ++f)
      if (am->mFaces[f].mNumIndices == 3)
        m.triangles.push_back({static_cast<Index>(am->mFaces[f].mIndices[0]), static_cast<Index>(am->mFaces[f].mIndices[1]),
                               static_cast<Index>(am->mFaces[f].mIndices[2])});
    m.skinned = am->mNumBones > 0;
    // Influences per vertex: (bone, weight).
    std::vector<std::vector<std::pair<unsigned, double>>> influences(m.skinned ? am->mNumVertices : 0);
    std::vector<const aiNode*> bone_nodes;
    for (unsigned b = 0; b < am->mNumBones; ++b) {
      const aiBone* bone = am->mBones[b];
      const aiNode* bone_node = scene->mRootNode->FindNode(bone->mName);
      if (!bone_node)
        throw MeshError(path + ": mesh '" + m.name + "': bone '" + bone->mName.C_Str() + "' has no node in the scene");
      bone_nodes.push_back(bone_node);
      for (unsigned w = 0; w < bone->mNumWeights; ++w)
        if (bone->mWeights[w].mVertexId < am->mNumVertices && bone->mWeights[w].mWeight != 0)
          influences[bone->mWeights[w].mVertexId].push_back({b, bone->mWeights[w].mWeight});
    }
    m.vertices.resize(T * am->mNumVertices * 3);
    m.rigid = !m.skinned;
    const Mat4 rest_inverse = rest.at(node).inverse();
    for (std::size_t k = 0; k < T; ++k) {
      const Mat4& placed = posed[k].at(node);
      std::vector<Mat4> skin(am->mNumBones);
      for (unsigned b = 0; b < am->mNumBones; ++b) skin[b] = posed[k].at(bone_nodes[b]) * to_eigen(am->mBones[b]->mOffsetMatrix);
      Real* x = m.vertices.data() + k * am->mNumVertices * 3;
      for (unsigned i = 0; i < am->mNumVertices; ++i) {
        const Eigen::Vector4d v(am->mVertices[i].x, am->mVertices[i].y, am->mVertices[i].z, 1.0);
        Eigen::Vector4d p = placed * v;
        if (m.skinned && !influences[i].empty()) {
          Eigen::Vector4d sum = Eigen::Vector4d::Zero();
          double total = 0;
          for (const auto& [b, w] : influences[i]) {
            sum += w * (skin[b] * v);
            total += w;
          }
          if (total > 0) p = sum / total;
        }
        for (int c = 0; c < 3; ++c) x[3 * i + c] = p[c];
      }
      if (m.rigid) {
        // The motion from the rest pose: placed * rest^-1; rigid if its linear part is a rotation
        // to the tolerance move_collider accepts (1e-6).
        const Mat4 motion = placed * rest_inverse;
        const Mat3 r = motion.topLeftCorner<3, 3>();
        if ((r.transpose() * r - Mat3::Identity()).cwiseAbs().maxCoeff() > 1e-6 || std::abs(r.determinant() - 1) > 1e-6) {
          m.rigid = false;
          m.rotation.clear();
          m.translation.clear();
        } else {
          m.rotation.push_back(r);
          m.translation.push_back(motion.topRightCorner<3, 1>());
        }
      }
    }
    out.meshes.push_back(std::move(m));
  }
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
