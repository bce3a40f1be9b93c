// csb._core: meshes and tet meshes, reading and writing them, the generated shapes.
#include "bindings.hpp"

namespace csb::python {

namespace {

// What a file animates, for csb.load_mesh's AnimationWarning: {"animations": [(name, duration s,
// channels)], "skinned": [(mesh name, bones, vertices)]}.
py::dict animation_summary_dict(const AnimationSummary& summary) {
  py::list animations, skinned;
  for (const AnimationInfo& a : summary.animations) animations.append(py::make_tuple(a.name, a.duration, a.channels));
  for (const SkinnedMeshInfo& s : summary.skinned) skinned.append(py::make_tuple(s.name, s.bones, s.vertices));
  py::dict d;
  d["animations"] = animations;
  d["skinned"] = skinned;
  return d;
}

// The file's own mesh (SourceMesh) for csb.load_mesh's `source`, as copies: None when the file
// gave none.
py::object source_dict(const SourceMesh& s) {
  if (s.empty()) return py::none();
  const auto M = static_cast<py::ssize_t>(s.vertices.cols());
  const auto copy = [](const Real* data, py::ssize_t rows, py::ssize_t cols) {
    py::array_t<double> a({rows, cols});
    if (rows * cols) std::memcpy(a.mutable_data(), data, sizeof(double) * rows * cols);
    return a;
  };
  const auto indices = [](const std::vector<Index>& v) {
    py::array_t<Index> a(static_cast<py::ssize_t>(v.size()));
    if (!v.empty()) std::memcpy(a.mutable_data(), v.data(), sizeof(Index) * v.size());
    return a;
  };
  py::dict d;
  d["vertices"] = copy(s.vertices.data(), M, 3);
  d["face_sizes"] = indices(s.face_sizes);
  d["face_vertices"] = indices(s.face_vertices);
  d["uv"] = s.uv.cols() ? py::object(copy(s.uv.data(), M, 2)) : py::none();
  d["normals"] = s.normals.cols() ? py::object(copy(s.normals.data(), M, 3)) : py::none();
  d["weld_map"] = indices(s.weld_map);
  py::list materials;
  for (const SourceMesh::Material& m : s.materials) materials.append(py::make_tuple(m.name, m.begin, m.end));
  d["materials"] = materials;
  return d;
}

}  // namespace

void bind_mesh(py::module_& m) {
  // ---------------------------------------------------------------- meshes
  py::class_<Mesh>(m, "Mesh", "A triangle (and/or line) mesh before it enters the particle pool; metres.", py::dynamic_attr())
      .def(py::init([](py::handle vertices, py::handle triangles, py::handle lines, const std::string& name) {
             Mesh mesh;
             mesh.name = name;
             mesh.vertices = to_positions(vertices, name + ": vertices");
             mesh.triangles = to_index_rows<3>(triangles, name + ": triangles");
             mesh.lines = to_index_rows<2>(lines, name + ": lines");
             validate(mesh);
             return mesh;
           }),
           py::arg("vertices"), py::arg("triangles") = py::none(), py::arg("lines") = py::none(),
           py::arg("name") = "mesh",
           "vertices: (N, 3) float, m. triangles: (T, 3) int. lines: (L, 2) int (ropes, chains).")
      .def_readonly("name", &Mesh::name)
      .def_property_readonly("num_vertices", &Mesh::num_vertices)
      .def_property_readonly("vertices", [](const Mesh& s) {
        py::array_t<double> a({static_cast<py::ssize_t>(s.num_vertices()), py::ssize_t(3)});
        if (s.num_vertices()) std::memcpy(a.mutable_data(), s.vertices.data(), sizeof(double) * 3 * s.num_vertices());
        return a;
      }, "(N, 3) vertex positions, m (a copy)")
      .def_property_readonly("triangles", [](const Mesh& s) { return index_rows(s.triangles); },
                             "(T, 3) vertex indices (a copy)")
      .def_property_readonly("lines", [](const Mesh& s) { return index_rows(s.lines); },
                             "(L, 2) vertex indices of explicit segments (a copy)")
      .def("__repr__", [](const Mesh& s) {
        return "<csb.Mesh '" + s.name + "': " + std::to_string(s.num_vertices()) + " vertices, " +
               std::to_string(s.triangles.size()) + " triangles, " + std::to_string(s.lines.size()) + " lines>";
      });

  m.def("_clean", [](const Mesh& mesh, bool weld, double weld_tolerance, bool drop_unreferenced) {
    CleanOptions o;
    o.weld = weld;
    o.weld_tolerance = weld_tolerance;
    o.drop_unreferenced = drop_unreferenced;
    MeshReport r;
    Mesh out = clean(mesh, o, &r);
    return py::make_tuple(out, report_dict(r));
  }, py::arg("mesh"), py::arg("weld") = true, py::arg("weld_tolerance") = 1e-6, py::arg("drop_unreferenced") = true);

  m.def("_load_mesh", [](const std::string& path, bool weld, double weld_tolerance, double timeout, double max_memory) {
    CleanOptions o;
    o.weld = weld;
    o.weld_tolerance = weld_tolerance;
    MeshReport r;
    Mesh out;
    AnimationSummary summary;
    SourceMesh source;
    {
      py::gil_scoped_release release;
      out = load_mesh(path, o, &r, timeout, max_memory, &summary, &source);
    }
    return py::make_tuple(out, report_dict(r), animation_summary_dict(summary), source_dict(source));
  }, py::arg("path"), py::arg("weld") = true, py::arg("weld_tolerance") = 1e-6, py::arg("timeout") = 0.0,
     py::arg("max_memory") = kDefaultMaxMemory);

  // ---------------------------------------------------------------- animated files
  m.def("_load_animation", [](const std::string& path, py::object times, int animation, const std::string& animation_name,
                              double timeout, double max_memory) {
    std::vector<Real> t;
    if (!times.is_none()) {
      const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(times);
      if (!a || a.ndim() != 1) throw InvalidArgument(path + ": times must be a 1-D sequence of times (s)");
      t.assign(a.data(), a.data() + a.size());
    }
    Animation out;
    {
      py::gil_scoped_release release;
      out = load_animation(path, times.is_none() ? nullptr : &t, animation, animation_name, timeout, max_memory);
    }
    const auto T = static_cast<py::ssize_t>(out.times.size());
    py::list meshes;
    for (const AnimatedMesh& a : out.meshes) {
      py::dict d;
      d["name"] = a.name;
      d["node"] = a.node;
      const auto V = static_cast<py::ssize_t>(a.num_vertices);
      py::array_t<double> x({T, V, py::ssize_t(3)});
      if (!a.vertices.empty()) std::memcpy(x.mutable_data(), a.vertices.data(), sizeof(double) * a.vertices.size());
      d["vertices"] = x;
      d["triangles"] = index_rows(a.triangles);
      d["skinned"] = a.skinned;
      d["rigid"] = a.rigid;
      py::array_t<double> r({a.rigid ? T : 0, py::ssize_t(3), py::ssize_t(3)}), p({a.rigid ? T : 0, py::ssize_t(3)});
      for (py::ssize_t k = 0; k < static_cast<py::ssize_t>(a.rotation.size()); ++k)
        for (py::ssize_t i = 0; i < 3; ++i) {
          p.mutable_at(k, i) = a.translation[static_cast<std::size_t>(k)][i];
          for (py::ssize_t j = 0; j < 3; ++j) r.mutable_at(k, i, j) = a.rotation[static_cast<std::size_t>(k)](i, j);
        }
      d["rotation"] = r;
      d["translation"] = p;
      meshes.append(d);
    }
    py::dict d;
    d["name"] = out.name;
    d["duration"] = out.duration;
    d["times"] = py::array_t<double>(T, out.times.data());
    d["meshes"] = meshes;
    return d;
  }, py::arg("path"), py::arg("times") = py::none(), py::arg("animation") = 0, py::arg("animation_name") = "",
     py::arg("timeout") = 0.0, py::arg("max_memory") = kDefaultMaxMemory);

  m.def("save_mesh", &save_mesh, py::arg("mesh"), py::arg("path"),
        "Writes the mesh's triangles; the format follows the extension (.obj .stl .ply .gltf .glb .dae .3ds .fbx ...).");
  m.def("_require_time_for", &require_time_for, py::arg("what"), py::arg("operations"));
  m.def("readable_extensions", &readable_extensions, "Extensions (with the dot) that load_mesh reads.");
  m.def("check_obj", &check_obj, py::arg("path"), "Strict OBJ syntax check naming the line of the first problem.");

  m.def("topology", [](const Mesh& mesh) {
    const Topology t = topology(mesh);
    py::dict d;
    d["edges"] = index_rows(t.edges);
    d["bending"] = index_rows(t.bending);
    d["boundary_edges"] = t.boundary_edges;
    d["non_manifold_edges"] = t.non_manifold_edges;
    return d;
  }, py::arg("mesh"), "Unique edges, bending quads (a, b, c, d), boundary and non-manifold edge counts.");

  m.def("lumped_measure", [](const Mesh& mesh) {
    std::vector<Real> w = lumped_measure(mesh);
    return py::array_t<Real>(static_cast<py::ssize_t>(w.size()), w.data());
  }, py::arg("mesh"), "Per vertex: a third of the adjacent triangle area (m²), or half the adjacent segment length (m).");

  m.def("cloth_grid", [](double width, double height, IntArg nx, IntArg ny, const std::string& plane, py::handle center) {
    const Index x = in_range(nx, "cloth_grid: nx", 2, kMaxIndex), y = in_range(ny, "cloth_grid: ny", 2, kMaxIndex);
    return cloth_grid(width, height, x, y, parse_plane(plane), to_vec3(center, "center"));
  }, py::arg("width"), py::arg("height"), py::arg("nx"), py::arg("ny"), py::arg("plane") = "xz",
        py::arg("center") = std::vector<double>{0, 0, 0},
        "Rectangular cloth of nx x ny particles spanning width x height m in `plane`, centred on `center` (m).");
  m.def("chain", [](IntArg links, double link_length, py::handle start, py::handle direction) {
    return chain(in_range(links, "chain: links", 1, kMaxIndex), link_length, to_vec3(start, "start"), to_vec3(direction, "direction"));
  }, py::arg("links"), py::arg("link_length"), py::arg("start") = std::vector<double>{0, 0, 0},
        py::arg("direction") = std::vector<double>{1, 0, 0},
        "A chain of `links` segments of link_length m from start (m) along direction.");
  m.def("pendulum", [](double length, double angle, py::handle anchor) {
    return pendulum(length, angle, to_vec3(anchor, "anchor"));
  }, py::arg("length"), py::arg("angle"), py::arg("anchor") = std::vector<double>{0, 0, 0},
        "Anchor (vertex 0) and bob (vertex 1) at `length` m, `angle` rad from the downward vertical towards +x.");

  // ---------------------------------------------------------------- tet meshes
  py::class_<TetMesh>(m, "TetMesh", "A tetrahedral volume mesh before it enters the particle pool; metres.",
                      py::dynamic_attr())
      .def(py::init([](py::handle points, py::handle tets, const std::string& name) {
             TetMesh mesh;
             mesh.name = name;
             mesh.points = to_positions(points, name + ": points");
             mesh.tets = to_index_rows<4>(tets, name + ": tets");
             validate(mesh);
             return mesh;
           }),
           py::arg("points"), py::arg("tets"), py::arg("name") = "tet mesh",
           "points: (N, 3) float, m. tets: (M, 4) int point indices. Raises MeshError naming the mesh and the "
           "element for non-finite points, out-of-range or repeated indices, or no tets.")
      .def_readonly("name", &TetMesh::name)
      .def_property_readonly("num_points", &TetMesh::num_points)
      .def_property_readonly("num_tets", &TetMesh::num_tets)
      .def_property_readonly("points", [](const TetMesh& s) {
        py::array_t<double> a({static_cast<py::ssize_t>(s.num_points()), py::ssize_t(3)});
        if (s.num_points()) std::memcpy(a.mutable_data(), s.points.data(), sizeof(double) * 3 * s.num_points());
        return a;
      }, "(N, 3) point positions, m (a copy)")
      .def_property_readonly("tets", [](const TetMesh& s) { return index_rows(s.tets); }, "(M, 4) point indices (a copy)")
      .def("volumes", [](const TetMesh& s) {
        const std::vector<Real> v = tet_volumes(s);
        return py::array_t<Real>(static_cast<py::ssize_t>(v.size()), v.data());
      }, "(M,) signed volume of every tet, m³ (positive: (p1 - p0) x (p2 - p0) points towards p3)")
      .def("surface", [](const TetMesh& s) { return index_rows(tet_surface(s)); },
           "(T, 3) the faces used by one tet, wound outwards for positively oriented tets")
      .def("__repr__", [](const TetMesh& s) {
        return "<csb.TetMesh '" + s.name + "': " + std::to_string(s.num_points()) + " points, " +
               std::to_string(s.num_tets()) + " tets>";
      });
  m.def("tet_box", [](py::handle size, std::array<IntArg, 3> divisions, py::handle center) {
    const Index nx = in_range(divisions[0], "tet_box: divisions[0]", 1, kMaxIndex);
    const Index ny = in_range(divisions[1], "tet_box: divisions[1]", 1, kMaxIndex);
    const Index nz = in_range(divisions[2], "tet_box: divisions[2]", 1, kMaxIndex);
    return tet_box(to_vec3(size, "size"), nx, ny, nz, to_vec3(center, "center"));
  }, py::arg("size"), py::arg("divisions"), py::arg("center") = std::vector<double>{0, 0, 0},
        "A box of size (3 lengths, m) centred on `center` (m) with divisions (nx, ny, nz) cells of 6 positively "
        "oriented tets each (Kuhn split, conforming).");

}

}  // namespace csb::python
