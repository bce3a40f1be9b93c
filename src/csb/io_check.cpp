#include "csb/io.hpp"

#include <cctype>
#include <cerrno>
#include <cstdint>
#include <filesystem>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <cstring>
#include <sstream>
#include <vector>

namespace csb {
namespace {

std::uintmax_t size_of(const std::string& path) {
  std::error_code ec;
  const auto n = std::filesystem::file_size(path, ec);
  return ec ? 0 : n;
}

// Printable form of a token from a possibly binary file, for messages.
std::string printable(const std::string& s, std::size_t max_len = 40) {
  std::string out;
  for (unsigned char ch : s.substr(0, max_len)) out += std::isprint(ch) ? static_cast<char>(ch) : '?';
  if (s.size() > max_len) out += "...";
  return out;
}

// A UTF-8 byte-order mark before the first line is not part of its text.
void skip_utf8_bom(std::string& line) {
  if (line.rfind("\xEF\xBB\xBF", 0) == 0) line.erase(0, 3);
}

struct Counts {
  long long v = 0, vt = 0, vn = 0;
};

[[noreturn]] void fail(const std::string& path, long long line, const std::string& what) {
  throw MeshError(path + ":" + std::to_string(line) + ": " + what);
}

// Parses one reference of a face ("7", "7/2", "7//3", "-1/-1/-1") and checks each index against
// the elements defined so far (OBJ allows no forward references; negative ones are relative).
void check_reference(const std::string& path, long long line, const std::string& token, const Counts& c) {
  const long long count[3] = {c.v, c.vt, c.vn};
  const char* kind[3] = {"vertex", "texture coordinate", "normal"};
  const char* kinds[3] = {"vertices", "texture coordinates", "normals"};
  std::size_t start = 0;
  for (int slot = 0; slot < 3 && start <= token.size(); ++slot) {
    const std::size_t slash = token.find('/', start);
    const std::string part = token.substr(start, slash == std::string::npos ? std::string::npos : slash - start);
    if (!part.empty()) {
      char* end = nullptr;
      errno = 0;
      const long long idx = std::strtoll(part.c_str(), &end, 10);
      if (*end != '\0' || errno != 0)
        fail(path, line, "face reference '" + printable(token) + "' is not an integer index");
      if (idx == 0) fail(path, line, "face reference '" + printable(token) + "' uses index 0; OBJ indices start at 1");
      const long long resolved = idx > 0 ? idx : count[slot] + idx + 1;
      if (resolved < 1 || resolved > count[slot])
        fail(path, line,
             "face refers to " + std::string(kind[slot]) + " " + std::to_string(idx) + ", but only " +
                 std::to_string(count[slot]) + " " + (count[slot] == 1 ? kind[slot] : kinds[slot]) +
                 (count[slot] == 1 ? " is" : " are") + " defined before this line");
    } else if (slot == 0) {
      fail(path, line, "face reference '" + printable(token) + "' has no vertex index");
    }
    if (slash == std::string::npos) break;
    start = slash + 1;
  }
}

}  // namespace

void check_encoding(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw MeshError(path + ": cannot open the file");
  unsigned char b[4] = {1, 1, 1, 1};
  in.read(reinterpret_cast<char*>(b), 4);
  const char* encoding = nullptr;
  if (b[0] == 0xFF && b[1] == 0xFE && b[2] == 0 && b[3] == 0) encoding = "UTF-32 (little-endian)";
  else if (b[0] == 0 && b[1] == 0 && b[2] == 0xFE && b[3] == 0xFF) encoding = "UTF-32 (big-endian)";
  else if (b[0] == 0xFF && b[1] == 0xFE) encoding = "UTF-16 (little-endian)";
  else if (b[0] == 0xFE && b[1] == 0xFF) encoding = "UTF-16 (big-endian)";
  if (encoding)
    throw MeshError(path + ": the file is " + encoding +
                    " text (it starts with that byte-order mark); csb reads text mesh files in ASCII or UTF-8: "
                    "save it as UTF-8");
  // Without a mark: ASCII text in UTF-16 has a zero in every other byte. Eight printable
  // characters each paired with a zero are taken as such (no binary mesh format starts so).
  in.clear();
  in.seekg(0);
  unsigned char head[16];
  in.read(reinterpret_cast<char*>(head), sizeof head);
  if (in.gcount() == static_cast<std::streamsize>(sizeof head)) {
    const auto text = [](unsigned char c) { return (c >= 0x20 && c < 0x7F) || c == '\t' || c == '\n' || c == '\r'; };
    bool le = true, be = true;
    for (std::size_t k = 0; k < sizeof head; k += 2) {
      le = le && text(head[k]) && head[k + 1] == 0;
      be = be && head[k] == 0 && text(head[k + 1]);
    }
    if (le || be)
      throw MeshError(path + ": the file looks like UTF-16 (" + (le ? "little" : "big") +
                      "-endian) text without a byte-order mark (a zero byte beside each character); csb reads text "
                      "mesh files in ASCII or UTF-8: save it as UTF-8");
  }
}

std::string sniff_format(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  char head[84] = {};
  in.read(head, sizeof head);
  const std::size_t got = static_cast<std::size_t>(in.gcount());
  if (got >= 4 && std::memcmp(head, "glTF", 4) == 0) return ".glb";
  std::uint32_t triangles = 0;
  if (got == 84) std::memcpy(&triangles, head + 80, 4);
  if (got == 84 && triangles > 0 && size_of(path) == 84 + 50ull * triangles) return ".stl";  // binary STL
  in.clear();
  in.seekg(0);
  std::string first;
  if (!in || !(in >> first)) return "";
  skip_utf8_bom(first);
  if (first == "ply") return ".ply";
  if (first == "solid") return ".stl";  // ASCII STL
  // XML: X3D (Assimp 5.2 knows it by its extension only); 3MF: a zip holding 3D/3dmodel.model
  // (any case).
  std::string start(4096, '\0');
  in.clear();
  in.seekg(0);
  in.read(start.data(), static_cast<std::streamsize>(start.size()));
  start.resize(static_cast<std::size_t>(in.gcount()));
  if (start.find("<X3D") != std::string::npos) return ".x3d";
  if (start.rfind("PK\x03\x04", 0) == 0) {
    const std::uintmax_t size = size_of(path);
    const std::uintmax_t tail = std::min<std::uintmax_t>(size, 1 << 16);  // the central directory is at the end
    std::string end(static_cast<std::size_t>(tail), '\0');
    in.clear();
    in.seekg(static_cast<std::streamoff>(size - tail));
    in.read(end.data(), static_cast<std::streamsize>(end.size()));
    const auto holds_model = [](std::string text) {  // 3D/3dmodel.model, in any case
      for (char& c : text) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
      return text.find("3d/3dmodel.model") != std::string::npos;
    };
    if (holds_model(start) || holds_model(end)) return ".3mf";
  }
  if (first == "HIERARCHY") return ".bvh";
  if (first.size() >= 3 && first.size() <= 5 && first.find("OFF") != std::string::npos) return ".off";  // OFF, COFF, NOFF, STOFF
  return "";
}

void check_obj(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw MeshError(path + ": cannot open the file");
  Counts c;
  long long faces = 0, lines = 0, line_no = 0;
  std::string line;
  while (std::getline(in, line)) {
    ++line_no;
    if (line_no == 1 && line.rfind("\xEF\xBB\xBF", 0) == 0) {
      // Assimp's OBJ reader keeps the mark as part of the first line: harmless before a comment
      // or a blank line, but a vertex or face there would be lost or misread.
      skip_utf8_bom(line);
      const auto first = line.find_first_not_of(" \t\r");
      if (first != std::string::npos && line[first] != '#')
        fail(path, 1, "the file starts with a UTF-8 byte-order mark, which Assimp's OBJ reader takes as part of "
                      "this line's first word: remove the mark (save as UTF-8 without BOM)");
    }
    if (const auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream s(line);
    std::string key;
    if (!(s >> key)) continue;
    std::vector<std::string> args;
    for (std::string a; s >> a;) args.push_back(a);
    if (key == "v") {
      if (args.size() < 3)
        fail(path, line_no, "vertex " + std::to_string(c.v + 1) + " has " + std::to_string(args.size()) +
                                " coordinate(s); a vertex needs x, y and z");
      for (int k = 0; k < 3; ++k) {
        char* end = nullptr;
        const double value = std::strtod(args[k].c_str(), &end);
        if (*end != '\0') fail(path, line_no, "vertex coordinate '" + printable(args[k]) + "' is not a number");
        if (!std::isfinite(value))
          fail(path, line_no, "vertex " + std::to_string(c.v + 1) + " has a non-finite coordinate '" + printable(args[k]) + "'");
      }
      ++c.v;
    } else if (key == "vt") {
      ++c.vt;
    } else if (key == "vn") {
      ++c.vn;
    } else if (key == "f") {
      if (args.size() < 3)
        fail(path, line_no, "face has " + std::to_string(args.size()) + " vertex/vertices; a face needs at least 3");
      for (const auto& a : args) check_reference(path, line_no, a, c);
      ++faces;
    } else if (key == "l") {
      ++lines;
    }
  }
  if (line_no == 0) throw MeshError(path + ": the file is empty");
  if (faces == 0)
    throw MeshError(path + ": the file has no faces (" + std::to_string(c.v) + " vertices, " + std::to_string(lines) +
                    " line elements); csb needs a surface mesh with triangles");
}

void check_ply(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw MeshError(path + ": cannot open the file");
  const std::uintmax_t file_size = size_of(path);
  std::string line;
  if (std::getline(in, line) && line.rfind("\xEF\xBB\xBFply", 0) == 0)
    throw MeshError(path + ": the file starts with a UTF-8 byte-order mark before 'ply', which Assimp's PLY reader "
                           "refuses: remove the mark (save as UTF-8 without BOM)");
  if (!in || line.substr(0, 3) != "ply")
    throw MeshError(path + ": not a PLY file (it does not start with 'ply')");
  struct Element {
    std::string name;
    long long count = 0;
    long long fixed_bytes = 0;  // per instance, excluding list contents
  };
  const auto type_size = [&](const std::string& t) -> int {
    if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
    if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
    if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
    if (t == "double" || t == "float64") return 8;
    throw MeshError(path + ": PLY header: unknown property type '" + printable(t) + "'");
  };
  std::vector<Element> elements;
  std::string format;
  bool ended = false;
  for (long long n = 1; n < 10000 && std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream s(line);
    std::string key;
    s >> key;
    if (key == "end_header") {
      ended = true;
      break;
    }
    if (key == "format") {
      s >> format;
      if (format != "ascii" && format != "binary_little_endian" && format != "binary_big_endian")
        throw MeshError(path + ": PLY header: unknown format '" + printable(format) + "'");
    } else if (key == "element") {
      Element e;
      if (!(s >> e.name >> e.count) || e.count < 0 || e.count > (1LL << 31))
        throw MeshError(path + ": PLY header: bad element line '" + printable(line) + "'");
      elements.push_back(e);
    } else if (key == "property") {
      if (elements.empty()) throw MeshError(path + ": PLY header: property before any element");
      std::string type;
      s >> type;
      if (type == "list") {
        std::string count_type, item_type;
        if (!(s >> count_type >> item_type)) throw MeshError(path + ": PLY header: bad list property '" + printable(line) + "'");
        elements.back().fixed_bytes += type_size(count_type);
        type_size(item_type);
      } else {
        elements.back().fixed_bytes += type_size(type);
      }
    }
    // Other lines are skipped, as Assimp's reader skips them: old exporters wrote free text into
    // the header without 'comment' (Blender 2.4's "Created by Blender3D 247 - www.blender.org, ...").
  }
  if (!ended) throw MeshError(path + ": PLY header is truncated or too long (no 'end_header' line)");
  long long faces = 0, vertices = 0;
  for (const auto& e : elements) {
    if (e.name == "face") faces += e.count;
    if (e.name == "vertex") vertices += e.count;
  }
  if (faces == 0)
    throw MeshError(path + ": the file has no triangles (" + std::to_string(vertices) +
                    " points, no faces); csb needs a surface mesh");
  if (format.empty()) throw MeshError(path + ": PLY header has no 'format' line");
  const std::uintmax_t header_bytes = static_cast<std::uintmax_t>(in.tellg());
  const std::uintmax_t body = file_size > header_bytes ? file_size - header_bytes : 0;
  long long needed = 0, instances = 0;
  std::string declared;
  for (const auto& e : elements) {
    needed += e.count * e.fixed_bytes;
    instances += e.count;
    declared += (declared.empty() ? "" : ", ") + std::to_string(e.count) + " " + printable(e.name);
  }
  if (format == "ascii") {
    // Every instance takes at least one line.
    long long lines = 0;
    for (std::string rest; std::getline(in, rest) && lines < instances;)
      if (rest.find_first_not_of(" \t\r") != std::string::npos) ++lines;
    if (lines < instances)
      throw MeshError(path + ": the PLY header declares " + declared + " but the file holds only " +
                      std::to_string(lines) + " data lines (truncated?)");
  } else if (static_cast<std::uintmax_t>(needed) > body) {
    throw MeshError(path + ": the PLY header declares " + declared + ", which needs at least " +
                    std::to_string(needed) + " bytes, but the file has " + std::to_string(body) +
                    " bytes after the header (truncated?)");
  }
}

void check_stl(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw MeshError(path + ": cannot open the file");
  const std::uintmax_t file_size = size_of(path);
  char head[84] = {};
  in.read(head, sizeof head);
  const std::size_t got = static_cast<std::size_t>(in.gcount());
  std::uint32_t count = 0;
  if (got == 84) std::memcpy(&count, head + 80, 4);
  const bool binary_consistent = got == 84 && file_size == 84 + 50ull * count;
  // An ASCII file starts with "solid" and holds only text; binary writers sometimes put "solid"
  // in their 80-byte header too, so look at the first bytes as well.
  const std::size_t bom = got >= 3 && std::memcmp(head, "\xEF\xBB\xBF", 3) == 0 ? 3 : 0;  // UTF-8 mark: Assimp skips it
  bool text = got >= bom + 5 && std::string(head + bom, head + bom + 5) == "solid";
  for (std::size_t k = bom; text && k < got; ++k) {
    const unsigned char ch = static_cast<unsigned char>(head[k]);
    text = std::isprint(ch) || std::isspace(ch);
  }
  if (!binary_consistent) check_encoding(path);
  if (text && !binary_consistent) return;
  if (got < 84)
    throw MeshError(path + ": a binary STL file needs an 84-byte header, the file has " + std::to_string(file_size) + " bytes");
  if (!binary_consistent)
    throw MeshError(path + ": the binary STL header declares " + std::to_string(count) + " triangles (" +
                    std::to_string(84 + 50ull * count) + " bytes) but the file has " + std::to_string(file_size) +
                    " bytes (truncated or corrupt)");
}

void check_off(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw MeshError(path + ": cannot open the file");
  const std::uintmax_t file_size = size_of(path);
  std::vector<std::string> tokens;
  std::vector<long long> token_line;  // the line each header token came from
  std::string line;
  long long data_lines = 0, line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (line_no == 1) skip_utf8_bom(line);
    if (const auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    if (tokens.size() < 4) {
      std::istringstream s(line);
      for (std::string t; s >> t;) {
        tokens.push_back(t);
        token_line.push_back(line_no);
      }
    } else {
      ++data_lines;
    }
  }
  if (tokens.empty() || tokens[0].find("OFF") == std::string::npos)
    throw MeshError(path + ": not an OFF file (no 'OFF' header)");
  // Each count is checked on its own before any arithmetic: strtoll saturates at LLONG_MAX, and a
  // count no larger than the file's size in bytes (every vertex and face takes at least one
  // character of its own) keeps the sum below compared free of overflow.
  const char* what[2] = {"vertex", "face"};
  long long counts[2] = {0, 0};
  for (int k = 0; k < 2; ++k) {
    if (tokens.size() <= std::size_t(k + 1))
      throw MeshError(path + ": OFF header: expected vertex and face counts after 'OFF'");
    const std::string& token = tokens[k + 1];
    const long long at = token_line[k + 1];
    char* end = nullptr;
    errno = 0;
    const long long value = std::strtoll(token.c_str(), &end, 10);
    if (end == token.c_str() || *end != '\0')
      fail(path, at, std::string("OFF header: the ") + what[k] + " count '" + printable(token) + "' is not an integer");
    if (value < 0)
      fail(path, at, std::string("OFF header: the ") + what[k] + " count is " + printable(token) + "; a count must be >= 0");
    if (errno == ERANGE)
      fail(path, at, std::string("OFF header: the ") + what[k] + " count " + printable(token) +
                         " is out of range (a count is at most 9223372036854775807)");
    if (static_cast<std::uintmax_t>(value) > file_size)
      fail(path, at, std::string("OFF header: the ") + what[k] + " count " + token + " is more than a file of " +
                         std::to_string(file_size) + " bytes can hold");
    counts[k] = value;
  }
  if (counts[1] == 0)
    throw MeshError(path + ": the file has no triangles (" + std::to_string(counts[0]) +
                    " points, no faces); csb needs a surface mesh");
  // The counts line may share the header's line; every vertex and face needs a line of its own.
  if (data_lines + 1 < counts[0] + counts[1])
    throw MeshError(path + ": the OFF header declares " + std::to_string(counts[0]) + " vertices and " +
                    std::to_string(counts[1]) + " faces but the file holds only " + std::to_string(data_lines) +
                    " data lines (truncated?)");
}

}  // namespace csb
