// csb._core — the pybind11 module. Arrays of the State are zero-copy, writable numpy views;
// arrays of the (immutable) Model are zero-copy, read-only views. Parameters are keyword
// arguments in SI units.
#include "csb/csb.hpp"
#include "csb/constraints/attachment.hpp"
#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"
#include "csb/coloured_bending.hpp"
#include "csb/memory_budget.hpp"
#include "int_arg.hpp"
#ifdef CSB_HAS_VIEWER
#include "viewer.hpp"
#endif

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cstring>
#include <chrono>
#include <functional>
#include <sstream>

namespace py = pybind11;
using namespace csb;
using namespace csb::python;

namespace {

// A numpy array over memory owned by `base` (kept alive by the array).
template <class T>
py::array view(const T* data, std::vector<py::ssize_t> shape, py::handle base, bool writeable) {
  std::vector<py::ssize_t> strides(shape.size());
  py::ssize_t stride = sizeof(T);
  for (std::size_t k = shape.size(); k-- > 0;) {
    strides[k] = stride;
    stride *= shape[k];
  }
  py::array a(py::dtype::of<T>(), shape, strides, data, base);
  if (!writeable) a.attr("setflags")(py::arg("write") = false);
  return a;
}

// A colouring's serial flags (one byte per colour) as a bool array (a copy).
py::array_t<bool> serial_flags(const Colouring& c) {
  return py::array_t<bool>(static_cast<py::ssize_t>(c.serial_colours.size()),
                           reinterpret_cast<const bool*>(c.serial_colours.data()));
}

// A copy of rows of indices (triangles, edges, ...) as an (M, K) int32 array.
template <std::size_t K>
py::array_t<Index> index_rows(const std::vector<std::array<Index, K>>& rows) {
  py::array_t<Index> a({static_cast<py::ssize_t>(rows.size()), static_cast<py::ssize_t>(K)});
  if (!rows.empty()) std::memcpy(a.mutable_data(), rows.data(), sizeof(Index) * K * rows.size());
  return a;
}

// Getter of a per-particle array of the Model as a read-only view.
template <class T>
auto particle_array(const std::vector<T> Model::*member) {
  return [member](py::object self) {
    const Model& s = self.cast<const Model&>();
    return view((s.*member).data(), {s.num_particles()}, self, false);
  };
}

std::string shape_str(const py::array& a) {
  std::ostringstream s;
  s << "(";
  for (py::ssize_t k = 0; k < a.ndim(); ++k) s << (k ? ", " : "") << a.shape(k);
  s << (a.ndim() == 1 ? ",)" : ")");
  return s.str();
}

Positions to_positions(const py::handle& obj, const std::string& what) {
  py::array arr = py::array::ensure(obj);
  if (!arr) throw InvalidArgument(what + " must be an array of shape (N, 3)");
  if (arr.dtype().kind() != 'f' && arr.dtype().kind() != 'i' && arr.dtype().kind() != 'u')
    throw InvalidArgument(what + " must be numeric, got dtype " + std::string(py::str(arr.dtype())));
  if (arr.ndim() != 2 || arr.shape(1) != 3)
    throw InvalidArgument(what + " must have shape (N, 3), got " + shape_str(arr));
  auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(arr);
  Positions x(3, a.shape(0));
  if (a.shape(0) > 0) std::memcpy(x.data(), a.data(), sizeof(double) * 3 * a.shape(0));
  return x;
}

template <std::size_t K>
std::vector<std::array<Index, K>> to_index_rows(const py::handle& obj, const std::string& what) {
  std::vector<std::array<Index, K>> out;
  if (obj.is_none()) return out;
  py::array arr = py::array::ensure(obj);
  if (!arr) throw InvalidArgument(what + " must be an integer array of shape (M, " + std::to_string(K) + ")");
  if (arr.size() == 0) return out;
  if (arr.dtype().kind() != 'i' && arr.dtype().kind() != 'u')
    throw InvalidArgument(what + " must hold integer indices, got dtype " + std::string(py::str(arr.dtype())));
  if (arr.ndim() != 2 || arr.shape(1) != static_cast<py::ssize_t>(K))
    throw InvalidArgument(what + " must have shape (M, " + std::to_string(K) + "), got " + shape_str(arr));
  auto a = py::array_t<long long, py::array::c_style | py::array::forcecast>::ensure(arr);
  const long long* d = a.data();
  out.resize(a.shape(0));
  for (py::ssize_t r = 0; r < a.shape(0); ++r)
    for (std::size_t k = 0; k < K; ++k) {
      const long long v = d[r * K + k];
      if (v < -1 || v > std::numeric_limits<Index>::max())
        throw MeshError(what + " row " + std::to_string(r) + " has index " + std::to_string(v) + ", which is out of range");
      out[r][k] = static_cast<Index>(v);
    }
  return out;
}

// Bounds of the stepper's integer settings tighter than their C++ types': a million sub-steps or
// sweeps per step is already 10^12 projections of a single constraint per step (hours), and no
// machine shares one sweep among more than 1024 threads.
constexpr long long kMaxSubsteps = 1'000'000;
constexpr long long kMaxIterations = 1'000'000;
constexpr long long kMaxThreads = 1024;

// A particle, group or grab index: an integer in [lo, the largest Index].
Index index_arg(const IntArg& v, const std::string& name, long long lo = 0) { return in_range(v, name, lo, kMaxIndex); }

int parse_sense(const std::string& s) {
  if (s == "==") return 0;
  if (s == ">=") return 1;
  if (s == "<=") return -1;
  throw InvalidArgument("sense must be '==' (distance equals rest length), '>=' or '<=', got '" + s + "'");
}

Plane parse_plane(const std::string& s) {
  if (s == "xy") return Plane::XY;
  if (s == "xz") return Plane::XZ;
  if (s == "yz") return Plane::YZ;
  throw InvalidArgument("plane must be 'xy', 'xz' or 'yz', got '" + s + "'");
}

// A step's interrupt (PbdStepper::step): at most every 20 ms, the GIL taken back to run Python's
// signal handlers; true once one raised (Ctrl-C: KeyboardInterrupt), which stays set for the
// binding to re-raise when the step has stopped.
std::function<bool()> python_interrupt() {
  return [last = std::chrono::steady_clock::now()]() mutable {
    const auto now = std::chrono::steady_clock::now();
    if (now - last < std::chrono::milliseconds(20)) return false;
    last = now;
    py::gil_scoped_acquire gil;
    return PyErr_CheckSignals() != 0;
  };
}

// Steps without the GIL, asking Python's signal handlers between (sub-)steps; what a handler
// raised (KeyboardInterrupt for Ctrl-C) is raised here, the state left where the stepper stopped.
template <class Stepper>
void step_interruptibly(Stepper& stepper, const Model& model, State& state, std::int64_t steps) {
  try {
    py::gil_scoped_release release;
    stepper.step(model, state, steps, python_interrupt());
  } catch (const Interrupted&) {
    throw py::error_already_set();
  }
}

Vec3 to_vec3(const py::handle& obj, const std::string& what) {
  py::array_t<double, py::array::forcecast> a;
  try {
    a = py::array_t<double, py::array::forcecast>::ensure(obj);
  } catch (const py::error_already_set&) {
  }
  if (!a || a.ndim() != 1 || a.shape(0) != 3) throw InvalidArgument(what + " must be a sequence of 3 numbers");
  return Vec3(a.at(0), a.at(1), a.at(2));
}

ContactMaterial material(double friction_static, double friction_kinetic, double restitution) {
  ContactMaterial m;
  m.friction_static = friction_static;
  m.friction_kinetic = friction_kinetic;
  m.restitution = restitution;
  return m;
}

Mat3 to_mat3(const py::handle& obj, const std::string& what) {
  py::array_t<double, py::array::forcecast | py::array::c_style> a;
  try {
    a = py::array_t<double, py::array::forcecast | py::array::c_style>::ensure(obj);
  } catch (const py::error_already_set&) {
  }
  if (!a || a.ndim() != 2 || a.shape(0) != 3 || a.shape(1) != 3) throw InvalidArgument(what + " must be a 3 x 3 matrix");
  Mat3 r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r(i, j) = a.at(i, j);
  return r;
}

py::dict report_dict(const MeshReport& r) {
  py::dict d;
  d["input_vertices"] = r.input_vertices;
  d["input_triangles"] = r.input_triangles;
  d["input_lines"] = r.input_lines;
  d["welded_vertices"] = r.welded_vertices;
  d["unreferenced_vertices"] = r.unreferenced_vertices;
  d["degenerate_triangles"] = r.degenerate_triangles;
  d["degenerate_lines"] = r.degenerate_lines;
  d["boundary_edges"] = r.boundary_edges;
  d["non_manifold_edges"] = r.non_manifold_edges;
  d["vertex_map"] = py::array_t<Index>(static_cast<py::ssize_t>(r.vertex_map.size()), r.vertex_map.data());
  d["warnings"] = r.warnings;
  return d;
}

// Exactly one of mass (kg), density (per unit of `measure`) or particle_mass (kg), as a MassSpec.
MassSpec mass_spec(const std::string& name, const py::object& mass, const py::object& density,
                   const py::object& particle_mass, const char* density_unit) {
  const int given = !mass.is_none() + !density.is_none() + !particle_mass.is_none();
  if (given != 1)
    throw InvalidArgument(name + ": give exactly one of mass (kg), density (" + density_unit +
                          ") or particle_mass (kg)");
  if (!mass.is_none()) return {MassSpec::Kind::Total, mass.cast<double>()};
  if (!density.is_none()) return {MassSpec::Kind::Density, density.cast<double>()};
  return {MassSpec::Kind::PerParticle, particle_mass.cast<double>()};
}

// Where a mesh landed, as the keyword arguments of Python's MeshInstance (without its vertices).
py::dict instance_dict(const MeshInstance& inst) {
  py::dict d;
  d["first_particle"] = inst.first_particle;
  d["num_particles"] = inst.num_particles;
  d["group"] = inst.group;
  d["num_distance"] = inst.num_distance;
  d["num_bending"] = inst.num_bending;
  d["num_volume"] = inst.num_volume;
  d["flipped_tets"] = inst.flipped_tets;
  d["triangles"] = index_rows(inst.triangles);
  d["report"] = report_dict(inst.report);
  return d;
}

py::dict violation_dict(const Violation& v) {
  py::dict d;
  d["count"] = v.count;
  d["max"] = v.max;
  d["rms"] = v.rms;
  return d;
}

py::array vec3_array(const Vec3& v) {
  py::array_t<double> a(3);
  for (int k = 0; k < 3; ++k) a.mutable_at(k) = v[k];
  return a;
}

}  // namespace

PYBIND11_MODULE(_core, m) {
  m.doc() = "csb compiled core: meshes, models, states and the PBD stepper";

  // Exceptions: csb.Error is the base of all; each also derives from the built-in exception a
  // Python user would catch (ValueError for bad input, RuntimeError for a failed simulation).
  const auto new_exception = [&m](const char* name, py::handle bases) {
    PyObject* type = PyErr_NewException((std::string("csb.") + name).c_str(), bases.ptr(), nullptr);
    if (!type) throw py::error_already_set();
    m.add_object(name, py::handle(type));
    return type;
  };
  static PyObject* error_base = new_exception("Error", PyExc_Exception);
  static PyObject* param_error = new_exception("ParameterError", py::make_tuple(py::handle(error_base), py::handle(PyExc_ValueError)));
  static PyObject* mesh_error = new_exception("MeshError", py::make_tuple(py::handle(error_base), py::handle(PyExc_ValueError)));
  static PyObject* sim_error = new_exception("SimulationError", py::make_tuple(py::handle(error_base), py::handle(PyExc_RuntimeError)));
  static PyObject* concurrent_error = new_exception("ConcurrentUseError", py::make_tuple(py::handle(error_base), py::handle(PyExc_RuntimeError)));
  // A method that cannot read the form a constraint's material was declared in (material.hpp):
  // a UserWarning, which the warnings filter can turn into an error.
  static PyObject* material_warning = new_exception("MaterialWarning", PyExc_UserWarning);
  // Settings known to give wrong results on a model (PbdStepper::accuracy_notes_to_report).
  static PyObject* accuracy_warning = new_exception("AccuracyWarning", PyExc_UserWarning);
  py::register_exception_translator([](std::exception_ptr p) {
    // Messages may quote bytes of a corrupt file: decode them leniently.
    const auto raise = [](PyObject* type, const char* what) {
      PyObject* msg = PyUnicode_DecodeUTF8(what, static_cast<Py_ssize_t>(std::strlen(what)), "replace");
      PyErr_SetObject(type, msg);
      Py_XDECREF(msg);
    };
    try {
      if (p) std::rethrow_exception(p);
    } catch (const FileNotFound& e) {
      raise(PyExc_FileNotFoundError, e.what());
    } catch (const SimulationError& e) {
      raise(sim_error, e.what());
    } catch (const ConcurrentUse& e) {
      raise(concurrent_error, e.what());
    } catch (const MeshError& e) {
      raise(mesh_error, e.what());
    } catch (const InvalidArgument& e) {
      raise(param_error, e.what());
    } catch (const Error& e) {
      raise(error_base, e.what());
    }
  });

  m.def("build_info", [] {
    const BuildInfo b = build_info();
    py::dict d;
    d["csb"] = b.csb_version;
    d["eigen"] = b.eigen_version;
    d["assimp"] = b.assimp_version;
    d["sundials"] = b.sundials_version;
    d["sundials_klu"] = b.sundials_klu;
    d["compiler"] = b.compiler;
    d["simd"] = b.simd;
#ifdef CSB_HAS_VIEWER
    d["viewer"] = "built";
#else
    d["viewer"] = std::string("not built: ") + CSB_VIEWER_MISSING;
#endif
    return d;
  }, "Versions of csb and of the libraries it was built against, and whether the viewer was built.");
#ifdef CSB_HAS_VIEWER
  bind_viewer(m);
#endif

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
    {
      py::gil_scoped_release release;
      out = load_mesh(path, o, &r, timeout, max_memory);
    }
    return py::make_tuple(out, report_dict(r));
  }, py::arg("path"), py::arg("weld") = true, py::arg("weld_tolerance") = 1e-6, py::arg("timeout") = 0.0,
     py::arg("max_memory") = kDefaultMaxMemory);

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

  // ---------------------------------------------------------------- model
  py::class_<State, std::shared_ptr<State>>(m, "State", "Positions (m), velocities (m/s) and time (s) of every particle.")
      .def_property("x", [](py::object self) {
        State& s = self.cast<State&>();
        return view(s.x.data(), {s.x.cols(), 3}, self, true);
      }, [](State& s, py::handle value) {
        Positions x = to_positions(value, "State.x");
        if (x.cols() != s.x.cols()) throw InvalidArgument("State.x must have shape (" + std::to_string(s.x.cols()) + ", 3)");
        s.x = x;
      }, "(N, 3) positions, m: a writable view, no copy")
      .def_property("v", [](py::object self) {
        State& s = self.cast<State&>();
        return view(s.v.data(), {s.v.cols(), 3}, self, true);
      }, [](State& s, py::handle value) {
        Positions v = to_positions(value, "State.v");
        if (v.cols() != s.v.cols()) throw InvalidArgument("State.v must have shape (" + std::to_string(s.v.cols()) + ", 3)");
        s.v = v;
      }, "(N, 3) velocities, m/s: a writable view, no copy")
      .def_readwrite("t", &State::t, "time, s")
      .def_property("step", [](const State& s) { return s.step; },
                    [](State& s, IntArg step) { s.step = in_range<std::int64_t>(step, "State.step", 0, kMaxInt64); },
                    "number of completed steps")
      .def_property_readonly("num_particles", [](const State& s) { return s.x.cols(); })
      .def("copy", [](const State& s) { return std::make_shared<State>(s); }, "A deep copy (a checkpoint).")
      .def("__repr__", [](const State& s) {
        std::ostringstream o;
        o << "<csb.State " << s.x.cols() << " particles, t = " << s.t << " s, step " << s.step << ">";
        return o.str();
      });

  py::class_<Model, std::shared_ptr<Model>>(m, "Model",
      "Immutable: rest positions, masses, and one batch per constraint type. Arrays are read-only views.")
      .def_property_readonly("num_particles", &Model::num_particles)
      .def_property_readonly("num_constraints", &Model::num_constraints)
      .def_readonly("group_names", &Model::group_names)
      .def_property_readonly("rest_positions", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        return view(s.rest_positions.data(), {s.num_particles(), 3}, self, false);
      }, "(N, 3) rest positions, m")
      .def_property_readonly("mass", particle_array(&Model::mass), "(N,) masses, kg (kept for pinned particles)")
      .def_property_readonly("inv_mass", particle_array(&Model::inv_mass), "(N,) inverse masses, 1/kg; 0 for pinned particles")
      .def_property_readonly("group", particle_array(&Model::group), "(N,) group index of each particle")
      .def_property_readonly("triangles", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        return view(reinterpret_cast<const Index*>(s.triangles.data()), {static_cast<py::ssize_t>(s.triangles.size()), 3}, self, false);
      }, "(T, 3) surface triangles (particle indices)")
      .def_property_readonly("distance", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.distance;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particles"] = view(reinterpret_cast<const Index*>(b.particles.data()), {c, 2}, self, false);
        d["rest_length"] = view(b.rest_length.data(), {c}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        d["sense"] = view(b.sense.data(), {c}, self, false);
        return d;
      }, "distance batch: particles (M, 2), rest_length (m), stiffness, compliance (m/N), sense (0: ==, +1: >=, -1: <=)")
      .def("colouring", [](py::object self, const std::string& batch) {
        const Model& s = self.cast<const Model&>();
        const Colouring* c = batch == "distance" ? &s.distance.colours
                             : batch == "bending" ? &s.bending.colours
                             : batch == "volume" ? &s.volume.colours
                             : batch == "attachments" ? &s.attachments.colours : nullptr;
        if (!c) throw InvalidArgument("batch must be 'distance', 'bending', 'volume' or 'attachments', got '" + batch + "'");
        py::dict d;
        d["order"] = view(c->order.data(), {static_cast<py::ssize_t>(c->order.size())}, self, false);
        d["colour_offsets"] = view(c->colour_offsets.data(), {static_cast<py::ssize_t>(c->colour_offsets.size())}, self, false);
        d["serial"] = serial_flags(*c);
        d["group_colours"] = view(c->group_colours.data(), {static_cast<py::ssize_t>(c->group_colours.size())}, self, false);
        return d;
      }, py::arg("batch"),
         "The batch's graph colouring: order (constraint indices colour by colour), colour_offsets (colour k is "
         "order[offsets[k]:offsets[k+1]]), serial (per colour: its constraints may share particles and are "
         "projected in order), group_colours (group g owns colours group_colours[g]:group_colours[g+1]; with P = "
         "num_parts, groups 0..P-1 are the parts' interiors, P+i the interface of parts i and i+1, 2P-1 the rest)")
      .def_property_readonly("num_parts", [](const Model& s) { return s.num_parts; },
         "Parts of the particles (runs of indices or slabs along an axis) that group the colourings for the threads")
      .def_property_readonly("particle_parts", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        return view(s.part.data(), {static_cast<py::ssize_t>(s.part.size())}, self, false);
      }, "The part of each particle (see num_parts)")
      .def_property_readonly("interface_phases", [](const Model& s) { return s.interface_phases; },
         "The interfaces between parts (i: parts i and i+1) in phases whose interfaces share no particle")
      .def_property_readonly("memory", [](const Model& s) {
        const ModelMemory r = model_memory(s);
        py::dict d;
        d["particles"] = r.particles;
        d["distance"] = r.distance;
        d["bending"] = r.bending;
        d["volume"] = r.volume;
        d["balloons"] = r.balloons;
        d["attachments"] = r.attachments;
        d["other"] = r.other;
        d["total"] = r.total();
        return d;
      }, "Bytes the model's arrays hold (from their capacities), per part. Not counted: what stepping adds "
         "(PbdStepper.workspace_bytes, about as much again under PBD and twice under XPBD, and 48 B a particle "
         "per State) and the peak of building, when the builder's arrays, the mesh and the model coexist (about "
         "5 x this total for a cloth). csb run reports the process's peak resident memory.")
      .def_property_readonly("bending", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.bending;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particles"] = view(reinterpret_cast<const Index*>(b.particles.data()), {c, 4}, self, false);
        d["rest_angle"] = view(b.rest_angle.data(), {c}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        return d;
      }, "bending batch: particles (M, 4) = edge (a, b) and wings (c, d), rest_angle (rad), stiffness, compliance (1/(N m))")
      .def_property_readonly("volume", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.volume;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particles"] = view(reinterpret_cast<const Index*>(b.particles.data()), {c, 4}, self, false);
        d["rest_volume"] = view(b.rest_volume.data(), {c}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        return d;
      }, "volume batch: particles (M, 4) of each tet, rest_volume (m³), stiffness, compliance (m⁶/J)")
      .def_property_readonly("balloons", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.balloons;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particle_offsets"] = view(b.particle_offsets.data(), {c + 1}, self, false);
        d["particles"] = view(b.particles.data(), {static_cast<py::ssize_t>(b.particles.size())}, self, false);
        d["triangle_offsets"] = view(b.triangle_offsets.data(), {c + 1}, self, false);
        d["triangles"] = view(reinterpret_cast<const Index*>(b.triangles.data()),
                              {static_cast<py::ssize_t>(b.triangles.size()), 3}, self, false);
        d["rest_volume"] = view(b.rest_volume.data(), {c}, self, false);
        d["pressure"] = view(b.pressure.data(), {c}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        return d;
      }, "balloon batch: balloon b moves particles[particle_offsets[b]:particle_offsets[b+1]] and has "
         "triangles[triangle_offsets[b]:triangle_offsets[b+1]] (indices into its own particle list); rest_volume "
         "(m³), pressure (k_pressure: target volume pressure x rest_volume), stiffness, compliance (m⁶/J)")
      .def_property_readonly("attachments", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        const auto& b = s.attachments;
        const py::ssize_t c = b.size();
        py::dict d;
        d["particle"] = view(b.particle.data(), {c}, self, false);
        d["target"] = view(b.target.data(), {c, 3}, self, false);
        d["stiffness"] = view(b.stiffness.data(), {c}, self, false);
        d["compliance"] = view(b.compliance.data(), {c}, self, false);
        return d;
      }, "attachment batch: particle (M,), target (M, 3) m, stiffness, compliance (m/N)")
      .def_property_readonly("thickness", particle_array(&Model::thickness),
                             "(N,) collision radius of each particle against the colliders, m")
      .def_property_readonly("self_collision_thickness", [](py::object self) {
        const Model& s = self.cast<const Model&>();
        return view(s.self_collision_thickness.data(), {s.num_groups()}, self, false);
      }, "(G,) self-collision thickness h of each group, m (0: off)")
      .def_property_readonly("colliders", [](const Model& s) {
        py::list out;
        for (const Collider& c : s.colliders) {
          py::dict d;
          d["kind"] = kind_name(c.kind);
          d["name"] = c.name;
          d["friction_static"] = c.material.friction_static;
          d["friction_kinetic"] = c.material.friction_kinetic;
          d["restitution"] = c.material.restitution;
          switch (c.kind) {
            case ColliderKind::Plane:
              d["point"] = vec3_array(c.point);
              d["normal"] = vec3_array(c.normal);
              break;
            case ColliderKind::Sphere:
              d["center"] = vec3_array(c.center);
              d["radius"] = c.radius;
              break;
            case ColliderKind::Capsule:
              d["a"] = vec3_array(c.a);
              d["b"] = vec3_array(c.b);
              d["radius"] = c.radius;
              break;
            case ColliderKind::Box: {
              d["center"] = vec3_array(c.center);
              d["half_extents"] = vec3_array(c.half_extents);
              py::array_t<double> r({3, 3});
              for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) r.mutable_at(i, j) = c.rotation(i, j);
              d["rotation"] = r;
              break;
            }
            case ColliderKind::Mesh: {
              const auto& m = *c.mesh;
              py::array_t<double> v({static_cast<py::ssize_t>(m.vertices.cols()), py::ssize_t(3)});
              if (m.vertices.cols()) std::memcpy(v.mutable_data(), m.vertices.data(), sizeof(double) * m.vertices.size());
              d["vertices"] = v;
              d["triangles"] = index_rows(m.triangles);
              break;
            }
          }
          out.append(d);
        }
        return out;
      }, "The static colliders, one dict each (copies): kind, name, material (friction_static, friction_kinetic, "
         "restitution) and the geometry of its kind, in m.")
      .def("initial_state", [](const Model& s) { return std::make_shared<State>(s.initial_state()); },
           "A new State at the rest positions with zero velocities and t = 0.")
      .def("__repr__", [](const Model& s) {
        return "<csb.Model " + std::to_string(s.num_particles()) + " particles, " + std::to_string(s.distance.size()) +
               " distance, " + std::to_string(s.bending.size()) + " bending, " + std::to_string(s.volume.size()) +
               " volume, " + std::to_string(s.balloons.size()) + " balloon, " + std::to_string(s.attachments.size()) +
               " attachment constraints>";
      });

  py::class_<ModelBuilder>(m, "ModelBuilder", "Collects particles and constraints; build() returns the immutable Model.")
      .def(py::init<>())
      .def("add_group", &ModelBuilder::add_group, py::arg("name"), "Adds a particle group; returns its index.")
      .def("add_particle", [](ModelBuilder& b, py::handle x, double mass, IntArg group) {
        return b.add_particle(to_vec3(x, "x"), mass, index_arg(group, "add_particle: group"));
      }, py::arg("x"), py::arg("mass"), py::arg("group"), "One particle at x (m) of mass (kg) in a group; returns its index.")
      .def("_add_mesh", [](ModelBuilder& b, const Mesh& mesh, IntArg group, py::object mass, py::object density,
                           py::object particle_mass, std::optional<double> stretch_stiffness,
                           std::optional<double> bending_stiffness, double stretch_compliance,
                           double bending_compliance, double thickness) {
        MeshOptions o;
        o.thickness = thickness;
        o.group = index_arg(group, "add_mesh: group", -1);
        o.mass = mass_spec(mesh.name, mass, density, particle_mass, "kg/m^2");
        o.stretch_stiffness = stretch_stiffness;
        o.bending_stiffness = bending_stiffness;
        o.stretch_compliance = stretch_compliance;
        o.bending_compliance = bending_compliance;
        return instance_dict(b.add_mesh(mesh, o));
      }, py::arg("mesh"), py::arg("group") = -1, py::arg("mass") = py::none(), py::arg("density") = py::none(),
         py::arg("particle_mass") = py::none(), py::arg("stretch_stiffness") = 1.0,
         py::arg("bending_stiffness") = py::none(), py::arg("stretch_compliance") = 0.0,
         py::arg("bending_compliance") = 0.0, py::arg("thickness") = 0.0)
      .def("add_distance", [](ModelBuilder& b, IntArg i, IntArg j, double stiffness, std::optional<double> rest_length,
                              const std::string& sense, double compliance) {
        const Index pi = index_arg(i, "add_distance: i"), pj = index_arg(j, "add_distance: j");
        return b.add_distance(pi, pj, stiffness, rest_length ? *rest_length : -1.0, parse_sense(sense), compliance);
      }, py::arg("i"), py::arg("j"), py::arg("stiffness") = 1.0, py::arg("rest_length") = py::none(),
         py::arg("sense") = "==", py::arg("compliance") = 0.0,
         "Distance constraint: PBD stiffness in [0, 1], compliance in m/N (0: hard); rest_length in m, default the "
         "current distance; sense '==', '>=' (at least) or '<=' (at most, a tether). Returns its index.")
      .def("add_bending", [](ModelBuilder& b, IntArg a, IntArg b_, IntArg c, IntArg d, double stiffness,
                             std::optional<double> rest_angle, double compliance) {
        const Index pa = index_arg(a, "add_bending: a"), pb = index_arg(b_, "add_bending: b");
        const Index pc = index_arg(c, "add_bending: c"), pd = index_arg(d, "add_bending: d");
        return b.add_bending(pa, pb, pc, pd, stiffness, rest_angle, compliance);
      }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"),
           py::arg("stiffness"), py::arg("rest_angle") = py::none(), py::arg("compliance") = 0.0,
           "Dihedral bending across edge (a, b) with wings c, d: PBD stiffness in [0, 1], rest_angle in rad "
           "(default the current angle), compliance in 1/(N m) (0: hard).")
      .def("_add_tet_mesh", [](ModelBuilder& b, const TetMesh& mesh, IntArg group, py::object mass, py::object density,
                               py::object particle_mass, std::optional<double> stretch_stiffness,
                               double stretch_compliance, std::optional<double> volume_stiffness,
                               double volume_compliance) {
        TetMeshOptions o;
        o.group = index_arg(group, "add_tet_mesh: group", -1);
        o.mass = mass_spec(mesh.name, mass, density, particle_mass, "kg/m^3");
        o.stretch_stiffness = stretch_stiffness;
        o.stretch_compliance = stretch_compliance;
        o.volume_stiffness = volume_stiffness;
        o.volume_compliance = volume_compliance;
        return instance_dict(b.add_tet_mesh(mesh, o));
      }, py::arg("mesh"), py::arg("group") = -1, py::arg("mass") = py::none(), py::arg("density") = py::none(),
         py::arg("particle_mass") = py::none(), py::arg("stretch_stiffness") = 1.0, py::arg("stretch_compliance") = 0.0,
         py::arg("volume_stiffness") = 1.0, py::arg("volume_compliance") = 0.0)
      .def("add_tetrahedron", [](ModelBuilder& b, IntArg a, IntArg b_, IntArg c, IntArg d, double stiffness,
                                 double compliance, std::optional<double> rest_volume) {
        const Index pa = index_arg(a, "add_tetrahedron: a"), pb = index_arg(b_, "add_tetrahedron: b");
        const Index pc = index_arg(c, "add_tetrahedron: c"), pd = index_arg(d, "add_tetrahedron: d");
        return b.add_tetrahedron(pa, pb, pc, pd, stiffness, compliance, rest_volume);
      }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"),
           py::arg("stiffness") = 1.0, py::arg("compliance") = 0.0, py::arg("rest_volume") = py::none(),
           "Tetrahedral volume constraint C = V - V0: PBD stiffness in [0, 1], compliance in m⁶/J (0: hard), "
           "rest_volume in m³ (default the current signed volume, which must be > 0: d on the side of "
           "(b - a) x (c - a)). Returns its index.")
      .def("_add_balloon", [](ModelBuilder& b, py::handle triangles, double pressure, double stiffness,
                              double compliance) {
        return b.add_balloon(to_index_rows<3>(triangles, "balloon triangles"), pressure, stiffness, compliance);
      }, py::arg("triangles"), py::arg("pressure") = 1.0, py::arg("stiffness") = 1.0, py::arg("compliance") = 0.0)
      .def("pin", [](ModelBuilder& b, IntArg i) { b.pin(index_arg(i, "pin: i")); }, py::arg("i"), "Fixes particle i (inverse mass 0).")
      .def("attach", [](ModelBuilder& b, IntArg i, py::handle target, double stiffness, double compliance) {
        return b.attach(index_arg(i, "attach: i"), to_vec3(target, "target"), stiffness, compliance);
      }, py::arg("i"), py::arg("target"), py::arg("stiffness") = 1.0, py::arg("compliance") = 0.0,
         "Holds particle i at a world point (m): PBD stiffness in [0, 1], compliance in m/N (0: hard).")
      .def("position", [](const ModelBuilder& b, IntArg particle) {
        const Index i = index_arg(particle, "position: i");
        if (i < 0 || i >= b.num_particles()) throw InvalidArgument("particle index " + std::to_string(i) + " is out of range");
        return vec3_array(b.position(i));
      }, py::arg("i"))
      .def("add_plane", [](ModelBuilder& b, py::handle point, py::handle normal, double mus, double muk, double e,
                           const std::string& name) {
        return b.add_plane(to_vec3(point, "point"), to_vec3(normal, "normal"), material(mus, muk, e), name);
      }, py::kw_only(), py::arg("point") = std::vector<double>{0, 0, 0}, py::arg("normal") = std::vector<double>{0, 1, 0},
         py::arg("friction_static") = 0.0, py::arg("friction_kinetic") = 0.0, py::arg("restitution") = 0.0,
         py::arg("name") = "",
         "Static half-space collider: solid where (x - point)·normal < 0. point in m; normal any non-zero vector "
         "towards the free side. friction_static μs >= friction_kinetic μk >= 0 (Coulomb), restitution e in [0, 1]. "
         "Returns the collider's index.")
      .def("add_sphere", [](ModelBuilder& b, py::handle center, double radius, double mus, double muk, double e,
                            const std::string& name) {
        return b.add_sphere(to_vec3(center, "center"), radius, material(mus, muk, e), name);
      }, py::kw_only(), py::arg("center"), py::arg("radius"), py::arg("friction_static") = 0.0,
         py::arg("friction_kinetic") = 0.0, py::arg("restitution") = 0.0, py::arg("name") = "",
         "Static sphere collider: center in m, radius > 0 m; material as add_plane.")
      .def("add_capsule", [](ModelBuilder& b, py::handle a, py::handle end, double radius, double mus, double muk,
                             double e, const std::string& name) {
        return b.add_capsule(to_vec3(a, "a"), to_vec3(end, "b"), radius, material(mus, muk, e), name);
      }, py::kw_only(), py::arg("a"), py::arg("b"), py::arg("radius"), py::arg("friction_static") = 0.0,
         py::arg("friction_kinetic") = 0.0, py::arg("restitution") = 0.0, py::arg("name") = "",
         "Static capsule collider: the points within radius (> 0 m) of the segment a-b (m); material as add_plane.")
      .def("add_box", [](ModelBuilder& b, py::handle center, py::handle half_extents, py::handle rotation, double mus,
                         double muk, double e, const std::string& name) {
        const Mat3 r = rotation.is_none() ? Mat3::Identity() : to_mat3(rotation, "rotation");
        return b.add_box(to_vec3(center, "center"), to_vec3(half_extents, "half_extents"), r, material(mus, muk, e), name);
      }, py::kw_only(), py::arg("center"), py::arg("half_extents"), py::arg("rotation") = py::none(),
         py::arg("friction_static") = 0.0, py::arg("friction_kinetic") = 0.0, py::arg("restitution") = 0.0,
         py::arg("name") = "",
         "Static oriented box collider: center in m, half_extents > 0 m along the box's axes, rotation a 3 x 3 "
         "rotation matrix whose columns are those axes in the world (default identity); material as add_plane.")
      .def("add_collider_mesh", [](ModelBuilder& b, const Mesh& mesh, double mus, double muk, double e,
                                   const std::string& name) {
        return b.add_collider_mesh(mesh, material(mus, muk, e), name);
      }, py::arg("mesh"), py::kw_only(), py::arg("friction_static") = 0.0, py::arg("friction_kinetic") = 0.0,
         py::arg("restitution") = 0.0, py::arg("name") = "",
         "Static triangle-mesh collider (any mesh csb.load_mesh reads), a two-sided sheet: a particle keeps the side "
         "it is on. Material as add_plane.")
      .def("set_thickness", [](ModelBuilder& b, IntArg group, double thickness) {
        b.set_thickness(index_arg(group, "set_thickness: group"), thickness);
      }, py::arg("group"), py::arg("thickness"),
           "Collision radius (m, >= 0) of every particle of a group against the colliders.")
      .def("enable_self_collision", [](ModelBuilder& b, IntArg group, double thickness) {
        b.enable_self_collision(index_arg(group, "enable_self_collision: group"), thickness);
      }, py::arg("group"), py::arg("thickness"),
           "Point-triangle self-collision of a group's cloth (Müller 2007 §4.4) with thickness h > 0 m; keep h "
           "below the cloth's edge length.")
      .def_property_readonly("num_colliders", &ModelBuilder::num_colliders)
      .def_property_readonly("num_particles", &ModelBuilder::num_particles)
      .def("build", [](const ModelBuilder& b) { return std::const_pointer_cast<Model>(b.build()); });

  // ---------------------------------------------------------------- PBD
  py::class_<PbdSettings>(m, "PbdSettings", "Settings of a position-based stepper (SI units).")
      .def_property_readonly("method", [](const PbdSettings& s) {
        return s.method == Method::Pbd ? "pbd" : s.method == Method::Xpbd ? "xpbd" : "jakobsen";
      })
      .def_readonly("dt", &PbdSettings::dt, "s, time advanced by one step")
      .def_readonly("substeps", &PbdSettings::substeps)
      .def_readonly("iterations", &PbdSettings::iterations)
      .def_property_readonly("gravity", [](const PbdSettings& s) { return vec3_array(s.gravity); }, "m/s²")
      .def_readonly("damping", &PbdSettings::damping, "Müller 2007 §3.5 k_damping per substep, [0, 1]")
      .def_readonly("stiffness_correction", &PbdSettings::stiffness_correction)
      .def_readonly("max_speed", &PbdSettings::max_speed, "m/s, the divergence guard (0: automatic, inf: off)")
      .def_property_readonly("front_end", [](const PbdSettings& s) { return s.front_end == FrontEnd::Euler ? "euler" : "verlet"; })
      .def_property_readonly("solver", [](const PbdSettings& s) {
        return s.solver == Solver::GaussSeidel ? "gauss-seidel" : s.solver == Solver::Jacobi ? "jacobi" : "jacobi-summed";
      })
      .def_readonly("xpbd_damping", &PbdSettings::xpbd_damping, "XPBD constraint damping β, N s/m")
      .def_readonly("verlet_drag", &PbdSettings::verlet_drag, "Jakobsen's drag d in [0, 1)")
      .def_readonly("sqrt_approximation", &PbdSettings::sqrt_approximation)
      .def_property_readonly("ordering", [](const PbdSettings& s) {
        return s.ordering == Ordering::Coloured ? "coloured" : "sequential";
      })
      .def_readonly("threads", &PbdSettings::threads, "threads that share a sweep (parts and interfaces as tasks); 0: automatic")
      .def("__repr__", [](const PbdSettings& s) {
        std::ostringstream o;
        o << "PbdSettings(method=" << (s.method == Method::Pbd ? "'pbd'" : s.method == Method::Xpbd ? "'xpbd'" : "'jakobsen'")
          << ", dt=" << s.dt << ", substeps=" << s.substeps << ", iterations=" << s.iterations << ", gravity=("
          << s.gravity.x() << ", " << s.gravity.y() << ", " << s.gravity.z() << "), damping=" << s.damping
          << ", stiffness_correction=" << (s.stiffness_correction ? "True" : "False") << ", front_end='"
          << (s.front_end == FrontEnd::Euler ? "euler" : "verlet") << "', solver='"
          << (s.solver == Solver::GaussSeidel ? "gauss-seidel" : s.solver == Solver::Jacobi ? "jacobi" : "jacobi-summed")
          << "', xpbd_damping=" << s.xpbd_damping << ", verlet_drag=" << s.verlet_drag
          << ", sqrt_approximation=" << (s.sqrt_approximation ? "True" : "False") << ", ordering='"
          << (s.ordering == Ordering::Coloured ? "coloured" : "sequential") << "', threads=" << s.threads
          << ", max_speed=" << s.max_speed << ")";
        return o.str();
      });

  py::class_<PbdStepper>(m, "PbdStepper",
      "Position-based stepper: Müller et al. 2007 PBD, Macklin et al. 2016 XPBD, or Jakobsen 2001 Verlet with relaxation.")
      .def(py::init([](const std::string& method, double dt, IntArg substeps, IntArg iterations, py::handle gravity,
                       double damping, bool stiffness_correction, const std::string& front_end,
                       const std::string& solver, double xpbd_damping, double verlet_drag, bool sqrt_approximation,
                       const std::string& ordering, IntArg threads, double max_speed) {
             PbdSettings s;
             if (method == "pbd") s.method = Method::Pbd;
             else if (method == "xpbd") s.method = Method::Xpbd;
             else if (method == "jakobsen") s.method = Method::Jakobsen;
             else throw InvalidArgument("method must be 'pbd', 'xpbd' or 'jakobsen', got '" + method + "'");
             s.dt = dt;
             s.substeps = in_range<int>(substeps, "substeps", 1, kMaxSubsteps);
             s.iterations = in_range<int>(iterations, "iterations", 1, kMaxIterations);
             s.gravity = to_vec3(gravity, "gravity");
             s.damping = damping;
             s.stiffness_correction = stiffness_correction;
             if (front_end == "euler") s.front_end = FrontEnd::Euler;
             else if (front_end == "verlet") s.front_end = FrontEnd::Verlet;
             else if (front_end == "auto") s.front_end = s.method == Method::Jakobsen ? FrontEnd::Verlet : FrontEnd::Euler;
             else throw InvalidArgument("front_end must be 'euler', 'verlet' or 'auto', got '" + front_end + "'");
             if (solver == "gauss-seidel") s.solver = Solver::GaussSeidel;
             else if (solver == "jacobi") s.solver = Solver::Jacobi;
             else if (solver == "jacobi-summed") s.solver = Solver::JacobiSummed;
             else throw InvalidArgument("solver must be 'gauss-seidel', 'jacobi' or 'jacobi-summed', got '" + solver + "'");
             s.xpbd_damping = xpbd_damping;
             s.verlet_drag = verlet_drag;
             s.sqrt_approximation = sqrt_approximation;
             if (ordering == "coloured") s.ordering = Ordering::Coloured;
             else if (ordering == "sequential") s.ordering = Ordering::Sequential;
             else throw InvalidArgument("ordering must be 'coloured' or 'sequential', got '" + ordering + "'");
             s.threads = in_range<int>(threads, "threads", 0, kMaxThreads);
             s.max_speed = max_speed;
             return PbdStepper(s);
           }),
           py::kw_only(), py::arg("method") = "pbd", py::arg("dt") = 1.0 / 60.0, py::arg("substeps") = 1,
           py::arg("iterations") = 10, py::arg("gravity") = std::vector<double>{0, -9.81, 0},
           py::arg("damping") = 0.0, py::arg("stiffness_correction") = true, py::arg("front_end") = "auto",
           py::arg("solver") = "gauss-seidel", py::arg("xpbd_damping") = 0.0, py::arg("verlet_drag") = 0.0,
           py::arg("sqrt_approximation") = false, py::arg("ordering") = "coloured", py::arg("threads") = 0,
           py::arg("max_speed") = 0.0,
           "method: 'pbd' (stiffness k), 'xpbd' (compliance α) or 'jakobsen'. dt: time step, s (> 0). substeps: "
           "sub-steps per step, in [1, 10^6]. iterations: constraint sweeps per sub-step, in [1, 10^6]. gravity: m/s². damping: "
           "Müller §3.5 k_damping in [0, 1] per sub-step (Euler front end). stiffness_correction: PBD's "
           "k' = 1 - (1 - k)^(1/iterations). front_end: 'euler' (velocity), 'verlet' (previous position) or 'auto' "
           "(Verlet for Jakobsen). solver: 'gauss-seidel', 'jacobi' (averaged) or 'jacobi-summed'. xpbd_damping: "
           "β, N s/m (XPBD). verlet_drag: Jakobsen's d in [0, 1). sqrt_approximation: Jakobsen's stick relaxation "
           "without square roots. ordering: 'coloured' (the model's parts and interfaces as the "
           "threads' tasks, each batch of a task colour by colour in SIMD lanes) or 'sequential' (as built, one "
           "thread). threads: threads that share a sweep, in [0, 1024] (0: the free cores, at most the model's parts; the "
           "result does not depend on it). max_speed: the divergence guard, m/s: a step after which a movable "
           "particle is faster raises SimulationError naming it (0: automatic, D/h + 2 (v0 + |g| t + sqrt(2 |g| D)) "
           "with D the model's size and v0 the fastest start speed; inf: off).")
      .def_property_readonly("settings", &PbdStepper::settings)
      .def_property_readonly("threads_used", &PbdStepper::threads_used, "threads the last step used")
      .def_property_readonly("workspace_bytes", &PbdStepper::workspace_bytes,
                             "bytes of the stepper's per-model workspace (from the vectors' capacities)")
      .def_property_readonly("substep_size", &PbdStepper::substep_size, "h = dt/substeps, s")
      .def("step", [](PbdStepper& s, const Model& model, State& state, IntArg steps_arg) {
        const std::int64_t steps = in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64);
        {
          // Once per model and stepper, at the caller's line: what the method ignores of the material.
          const UseGuard::Scope in_use(s.use_guard(), "PbdStepper.step");
          for (const MaterialNote& note : s.material_notes_to_report(model))
            if (PyErr_WarnEx(material_warning, note.message.c_str(), 1) < 0) throw py::error_already_set();
          for (const std::string& note : s.accuracy_notes_to_report(model))
            if (PyErr_WarnEx(accuracy_warning, note.c_str(), 1) < 0) throw py::error_already_set();
          s.material_reported(model);
          for (const std::string& note : s.degenerate_notes_to_report(model, state))
            if (PyErr_WarnEx(accuracy_warning, note.c_str(), 1) < 0) throw py::error_already_set();
        }
        step_interruptibly(s, model, state, steps);
      }, py::arg("model"), py::arg("state"), py::arg("steps") = 1,
         "Advances state by `steps` steps of dt (the GIL is released meanwhile; Ctrl-C stops it between "
         "sub-steps, the state left at the end of the last completed one; a second thread stepping the same "
         "stepper meanwhile gets csb.ConcurrentUseError). The first time this stepper "
         "steps a model, a csb.MaterialWarning per constraint family whose declared material the method cannot "
         "read: PBD and Jakobsen read the stiffness k, XPBD the compliance α, so constraints with only α > 0 "
         "(k = 1) are rigid under PBD and Jakobsen, those with only k < 1 (α = 0) rigid under XPBD.")
      .def("projections_per_step", &PbdStepper::projections_per_step, py::arg("model"))
      .def("operations", [](const PbdStepper& s, const Model& model, IntArg steps_arg) {
        return s.operations(model, in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64));
      }, py::arg("model"), py::arg("steps"),
         "Constraint projections and particle updates of `steps` steps of the model: step() refuses "
         "(csb.ParameterError, with the estimate) a request that would take more than a year at 1e9 a second")
      .def("multipliers", [](const PbdStepper& s) {
        const UseGuard::Scope in_use(s.use_guard(), "PbdStepper.multipliers");
        const Multipliers& l = s.multipliers();
        py::dict d;
        d["distance"] = py::array_t<Real>(static_cast<py::ssize_t>(l.distance.size()), l.distance.data());
        d["bending"] = py::array_t<Real>(static_cast<py::ssize_t>(l.bending.size()), l.bending.data());
        d["attachment"] = py::array_t<Real>(static_cast<py::ssize_t>(l.attachment.size()), l.attachment.data());
        d["volume"] = py::array_t<Real>(static_cast<py::ssize_t>(l.volume.size()), l.volume.data());
        d["balloon"] = py::array_t<Real>(static_cast<py::ssize_t>(l.balloon.size()), l.balloon.data());
        return d;
      }, "XPBD: the Lagrange multipliers λ of the last sub-step per batch (empty otherwise); "
         "the constraint force is λ/h² along ∇C (N for distance constraints; for volume and balloon λ/h² is a "
         "pressure, Pa).")
      .def("contacts", [](const PbdStepper& s) {
        const UseGuard::Scope in_use(s.use_guard(), "PbdStepper.contacts");
        const ContactSummary& sum = s.contact_summary();
        const auto& c = s.contacts();
        const py::ssize_t m = static_cast<py::ssize_t>(c.size());
        py::array_t<Index> particle(m), collider(m);
        py::array_t<double> point({m, py::ssize_t(3)}), normal({m, py::ssize_t(3)}), correction(m), lambda(m);
        for (py::ssize_t k = 0; k < m; ++k) {
          particle.mutable_at(k) = c[k].particle;
          collider.mutable_at(k) = c[k].collider;
          for (int j = 0; j < 3; ++j) point.mutable_at(k, j) = c[k].point[j], normal.mutable_at(k, j) = c[k].normal[j];
          correction.mutable_at(k) = c[k].normal_correction;
          lambda.mutable_at(k) = c[k].lambda;
        }
        py::dict d;
        d["count"] = sum.count;
        d["active"] = sum.active;
        d["self_count"] = sum.self_count;
        d["max_depth"] = sum.max_depth;
        d["max_penetration"] = sum.max_penetration;
        d["particle"] = particle;
        d["collider"] = collider;
        d["point"] = point;
        d["normal"] = normal;
        d["normal_correction"] = correction;
        d["lambda"] = lambda;
        return d;
      }, "The contacts of the last sub-step: count (particle-collider, speculative ones included), active (those "
         "that pushed their particle), self_count (point-triangle), max_depth "
         "(m, deepest violation r - (p - q)·n at the prediction), max_penetration (m, deepest violation left at the "
         "end of the sub-step, thickness included), and per contact: particle, collider, point q (m), normal n, "
         "normal_correction (m) and lambda (XPBD multiplier, kg m; force λ/h² N).")
      .def("grab", [](PbdStepper& s, const Model& model, const State& state, IntArg particle, py::handle target,
                      double compliance) {
        return s.grab(model, state, index_arg(particle, "grab: particle"), to_vec3(target, "target"), compliance);
      }, py::arg("model"), py::arg("state"), py::arg("particle"), py::arg("target"), py::kw_only(),
         py::arg("compliance") = 0.0,
         "Holds `particle` with the hand at `target` (m) and returns a handle (click and drag). compliance 0: the "
         "particle follows the hand exactly, moved along a straight line over the sub-steps of the next step; "
         "compliance > 0 (m/N): an XPBD spring to the hand. The hand starts where the particle is now.")
      .def("move_grab", [](PbdStepper& s, IntArg handle, py::handle target) {
        s.move_grab(index_arg(handle, "move_grab: handle"), to_vec3(target, "target"));
      },
           py::arg("handle"), py::arg("target"), "Moves the hand of a grab (m); the next step takes the particle there.")
      .def("release", [](PbdStepper& s, IntArg handle) { s.release(index_arg(handle, "release: handle")); }, py::arg("handle"),
           "Lets go of a grab; the particle keeps the velocity it had.")
      .def_property_readonly("grabs", [](const PbdStepper& s) {
        py::list out;
        for (const Grab& g : s.grabs()) {
          py::dict d;
          d["handle"] = g.handle;
          d["particle"] = g.particle;
          d["target"] = std::vector<double>{g.target.x(), g.target.y(), g.target.z()};
          d["compliance"] = g.compliance;
          out.append(d);
        }
        return out;
      }, "The grabs held now: handle, particle, target (m), compliance (m/N).");

  m.def("tear", [](py::object model_obj, py::object state_obj, double max_strain, IntArg max_tears_arg) {
    const Model& model = model_obj.cast<const Model&>();
    const Index max_tears = in_range(max_tears_arg, "tear: max_tears", 1, kMaxIndex);
    // The given state is left as it is (numpy views of it stay valid); a torn one is a copy.
    auto torn_state = std::make_shared<State>(state_obj.cast<const State&>());
    TearResult r;
    {
      py::gil_scoped_release release;
      r = tear(model, *torn_state, max_strain, max_tears);
    }
    py::dict d;
    d["torn"] = r.torn;
    d["split"] = py::array_t<Index>(static_cast<py::ssize_t>(r.split.size()), r.split.data());
    d["model"] = r.torn ? py::cast(std::const_pointer_cast<Model>(r.model)) : model_obj;
    d["state"] = r.torn ? py::cast(torn_state) : state_obj;
    return d;
  }, py::arg("model"), py::arg("state"), py::kw_only(), py::arg("max_strain"), py::arg("max_tears") = 1,
     "Tearing (Müller 2007 §4.6): splits up to max_tears vertices of distance constraints strained past max_strain "
     "(|l - l0|/l0 > 0), most strained first. Returns a dict: torn (how many), split (the particles split), model "
     "and state — new ones if anything tore (the new particles are appended), else the ones given.");

  py::class_<Pick>(m, "Pick", "What a ray cast found: the particle (-1: none), the distance along the ray (m) and "
                               "the surface triangle hit (-1: found by proximity to the ray).")
      .def_readonly("particle", &Pick::particle)
      .def_readonly("distance", &Pick::distance)
      .def_readonly("triangle", &Pick::triangle)
      .def("__repr__", [](const Pick& p) {
        return "Pick(particle=" + std::to_string(p.particle) + ", distance=" + std::to_string(p.distance) +
               ", triangle=" + std::to_string(p.triangle) + ")";
      });
  m.def("pick_particle", [](const Model& model, const State& state, py::handle origin, py::handle direction,
                            double max_distance) {
    return pick_particle(model, state, to_vec3(origin, "origin"), to_vec3(direction, "direction"), max_distance);
  }, py::arg("model"), py::arg("state"), py::arg("origin"), py::arg("direction"), py::kw_only(),
     py::arg("max_distance") = 0.05,
     "The particle under a ray (the cursor): the first surface triangle it crosses, then that triangle's vertex "
     "nearest the hit; without a hit, the particle nearest the ray within max_distance (m).");

  py::class_<ForceStepper>(m, "ForceStepper",
      "Force-based mass-spring integrators on the reference's spring network (every constraint a spring of "
      "stiffness 1/α): the methods that fail, for the stability studies.")
      .def(py::init([](const std::string& method, double dt, IntArg substeps, py::handle gravity, double damping,
                       double drag) {
             ForceSettings s;
             if (method == "explicit-euler") s.method = ForceIntegrator::ExplicitEuler;
             else if (method == "symplectic-euler") s.method = ForceIntegrator::SymplecticEuler;
             else if (method == "velocity-verlet") s.method = ForceIntegrator::VelocityVerlet;
             else throw InvalidArgument("method must be 'explicit-euler', 'symplectic-euler' or 'velocity-verlet', got '" +
                                        method + "'");
             s.dt = dt;
             s.substeps = in_range<int>(substeps, "substeps", 1, kMaxSubsteps);
             s.gravity = to_vec3(gravity, "gravity");
             s.damping = damping;
             s.drag = drag;
             return ForceStepper(s);
           }),
           py::kw_only(), py::arg("method") = "symplectic-euler", py::arg("dt") = 1e-4, py::arg("substeps") = 1,
           py::arg("gravity") = std::vector<double>{0, -9.81, 0}, py::arg("damping") = 0.0, py::arg("drag") = 0.0,
           "method: 'explicit-euler', 'symplectic-euler' or 'velocity-verlet'. dt: s. damping: N s/m along springs. "
           "drag: 1/s.")
      .def("step", [](ForceStepper& s, const Model& model, State& state, IntArg steps_arg) {
        step_interruptibly(s, model, state, in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64));
      }, py::arg("model"), py::arg("state"), py::arg("steps") = 1,
         "Advances state by `steps` steps of dt (the GIL is released meanwhile; Ctrl-C stops it between steps, "
         "the state left at the end of the last completed one). A request that would take more than a year "
         "at 1e9 spring and particle updates a second is refused (csb.ParameterError, with the estimate).")
      .def_property_readonly("force_evaluations", &ForceStepper::force_evaluations,
           "Evaluations of the spring network's forces since construction: one per sub-step (velocity Verlet "
           "reuses the end of a sub-step's forces at the start of the next, unless damping or drag make them "
           "depend on the velocity: then two).");

  m.def("benchmark_dispatch", [](const Model& model, py::handle positions, IntArg sweeps_arg, IntArg repeats_arg) {
    const int sweeps = in_range<int>(sweeps_arg, "sweeps", 1, kMaxIndex), repeats = in_range<int>(repeats_arg, "repeats", 1, kMaxIndex);
    const Positions x = to_positions(positions, "positions");
    DispatchTiming t;
    {
      py::gil_scoped_release release;
      t = benchmark_dispatch(model, x, sweeps, repeats);
    }
    py::dict d;
    d["projections"] = t.projections;
    d["batched_ns"] = t.batched_ns;
    d["virtual_ns"] = t.virtual_ns;
    d["identical"] = t.identical;
    return d;
  }, py::arg("model"), py::arg("positions"), py::arg("sweeps"), py::arg("repeats"),
     "Gauss-Seidel sweeps through the batched kernels and through one virtual Constraint object per constraint: "
     "ns per projection of each repeat, and whether the results agree bit for bit.");

  m.def("colour_constraints", [](py::array_t<Index, py::array::c_style | py::array::forcecast> particles,
                                 IntArg num_particles_arg, IntArg min_colour_size_arg) {
    const Index num_particles = index_arg(num_particles_arg, "num_particles");
    const Index min_colour_size = index_arg(min_colour_size_arg, "min_colour_size");
    if (particles.ndim() != 2 || particles.shape(1) < 1)
      throw InvalidArgument("particles must have shape (M, k), k >= 1");
    for (py::ssize_t e = 0; e < particles.size(); ++e)
      if (particles.data()[e] < 0 || particles.data()[e] >= num_particles)
        throw InvalidArgument("particle index " + std::to_string(particles.data()[e]) + " out of range");
    const Colouring c = colour_constraints(particles.data(), static_cast<int>(particles.shape(1)),
                                           static_cast<Index>(particles.shape(0)), num_particles, min_colour_size);
    py::dict d;
    d["order"] = py::array_t<Index>(static_cast<py::ssize_t>(c.order.size()), c.order.data());
    d["colour_offsets"] = py::array_t<Index>(static_cast<py::ssize_t>(c.colour_offsets.size()), c.colour_offsets.data());
    d["serial"] = serial_flags(c);
    return d;
  }, py::arg("particles"), py::arg("num_particles"), py::arg("min_colour_size") = kMinColourSize,
     "The greedy colouring a Model gives a batch whose constraint c has particles[c] (see Model.colouring).");
  m.attr("MAX_COLOURS") = kMaxColours;
  // The largest value of an integer parameter: an index or count (Index), the stepper's sub-steps,
  // iterations and threads.
  m.attr("MAX_INDEX") = kMaxIndex;
  m.attr("MAX_SUBSTEPS") = kMaxSubsteps;
  m.attr("MAX_ITERATIONS") = kMaxIterations;
  m.attr("MAX_THREADS") = kMaxThreads;
  m.attr("MIN_COLOUR_SIZE") = kMinColourSize;
  m.attr("MIN_TASK_COLOUR_SIZE") = kMinTaskColourSize;

  m.def("benchmark_plain_distance", [](const Model& model, py::handle positions, IntArg sweeps_arg, IntArg repeats_arg) {
    const int sweeps = in_range<int>(sweeps_arg, "sweeps", 1, kMaxIndex), repeats = in_range<int>(repeats_arg, "repeats", 1, kMaxIndex);
    const Positions x = to_positions(positions, "positions");
    std::vector<double> ns;
    {
      py::gil_scoped_release release;
      ns = benchmark_plain_distance(model, x, sweeps, repeats);
    }
    return ns;
  }, py::arg("model"), py::arg("positions"), py::arg("sweeps"), py::arg("repeats"),
     "The baseline the coloured sweep is measured against: a plain sequential loop over the model's distance constraints in build order, in "
     "double precision (Müller's projection, stiffness 1), one thread; ns per projection of each repeat.");
  m.def("benchmark_jacobian", [](const SpringNetwork& net, const State& state, IntArg repeats_arg) {
    const int repeats = in_range<int>(repeats_arg, "repeats", 1, kMaxIndex);
    std::vector<double> y(net.size()), values(net.jacobian_row_indices().size());
    net.pack(state, y.data());
    std::vector<double> ms;
    py::gil_scoped_release release;
    for (int r = 0; r < repeats; ++r) {
      const auto t0 = std::chrono::steady_clock::now();
      net.jacobian(y.data(), values.data());
      ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
    return ms;
  }, py::arg("network"), py::arg("state"), py::arg("repeats"),
     "ms per assembly of the reference's sparse Jacobian (the values into its fixed CSC pattern), per repeat.");

  m.def("corrected_stiffness", [](double k, IntArg iterations) {
    return corrected_stiffness(k, in_range<int>(iterations, "iterations", 1, kMaxIterations));
  }, py::arg("stiffness"), py::arg("iterations"),
        "1 - (1 - k)^(1/iterations), Müller 2007 §3.3.");

  // ---------------------------------------------------------------- reference
  const auto reference_settings = [](py::handle gravity, double rtol, double atol, double damping, double drag,
                                     int max_order, bool stald, const std::string& linear, long long max_steps,
                                     double max_wall_time) {
    ReferenceSettings s;
    s.gravity = to_vec3(gravity, "gravity");
    s.rtol = rtol;
    s.atol = atol;
    s.damping = damping;
    s.drag = drag;
    s.max_order = max_order;
    s.stability_limit_detection = stald;
    if (linear == "auto")
      s.linear_solver = ReferenceSettings::Linear::Automatic;
    else if (linear == "klu")
      s.linear_solver = ReferenceSettings::Linear::Klu;
    else if (linear == "gmres")
      s.linear_solver = ReferenceSettings::Linear::Gmres;
    else
      throw InvalidArgument("linear_solver must be 'auto', 'klu' or 'gmres', got '" + linear + "'");
    s.max_steps = max_steps;
    s.max_wall_time = max_wall_time;
    return s;
  };

  m.def("_integrate_reference", [reference_settings](const Model& model, const State& start, std::vector<double> times,
                                                     py::handle gravity, double rtol, double atol, double damping,
                                                     double drag, IntArg max_order, bool stald, const std::string& linear,
                                                     IntArg max_steps, double max_wall_time) {
    const int order = in_range<int>(max_order, "max_order", 1, 5);
    const long long steps = in_range<long long>(max_steps, "max_steps", 1, kMaxInt64);
    const ReferenceSettings s =
        reference_settings(gravity, rtol, atol, damping, drag, order, stald, linear, steps, max_wall_time);
    ReferenceResult r;
    {
      py::gil_scoped_release release;
      r = integrate_reference(model, start, times, s);
    }
    const py::ssize_t T = static_cast<py::ssize_t>(r.times.size()), N = model.num_particles();
    py::array_t<double> x({T, N, py::ssize_t(3)}), v({T, N, py::ssize_t(3)});
    for (py::ssize_t k = 0; k < T; ++k) {
      std::memcpy(x.mutable_data(k), r.x[k].data(), sizeof(double) * 3 * N);
      std::memcpy(v.mutable_data(k), r.v[k].data(), sizeof(double) * 3 * N);
    }
    py::dict stats;
    stats["steps"] = r.stats.steps;
    stats["rhs_evals"] = r.stats.rhs_evals;
    stats["newton_iters"] = r.stats.newton_iters;
    stats["newton_failures"] = r.stats.newton_failures;
    stats["error_test_failures"] = r.stats.error_test_failures;
    stats["jacobian_evals"] = r.stats.jacobian_evals;
    stats["linear_iters"] = r.stats.linear_iters;
    stats["last_order"] = r.stats.last_order;
    stats["last_step"] = r.stats.last_step;
    stats["wall_time"] = r.stats.wall_time;
    stats["linear_solver"] = r.stats.linear_solver;
    return py::make_tuple(py::array_t<double>(T, r.times.data()), x, v, stats);
  }, py::arg("model"), py::arg("start"), py::arg("times"), py::arg("gravity"), py::arg("rtol"), py::arg("atol"),
     py::arg("damping"), py::arg("drag"), py::arg("max_order"), py::arg("stability_limit_detection"), py::arg("linear_solver"),
     py::arg("max_steps"), py::arg("max_wall_time"));

  py::class_<SpringNetwork>(m, "SpringNetwork",
      "The reference's first-order system y' = f(y), y = [x; v] of the dynamic particles: for tests and studies.")
      .def(py::init([reference_settings](const Model& model, const State& start, py::handle gravity, double damping,
                                         double drag) {
             return SpringNetwork(model, start,
                                  reference_settings(gravity, 1e-8, 1e-10, damping, drag, 5, false, "auto", 1, 0.0));
           }),
           py::arg("model"), py::arg("start"), py::kw_only(), py::arg("gravity") = std::vector<double>{0, -9.81, 0},
           py::arg("damping") = 0.0, py::arg("drag") = 0.0)
      .def_property_readonly("size", &SpringNetwork::size)
      .def_property_readonly("num_dynamic", &SpringNetwork::num_dynamic)
      .def_property_readonly("has_analytic_jacobian", &SpringNetwork::has_analytic_jacobian)
      .def("pack", [](const SpringNetwork& net, const State& state) {
        py::array_t<double> y(static_cast<py::ssize_t>(net.size()));
        net.pack(state, y.mutable_data());
        return y;
      }, py::arg("state"), "y = [x; v] of the dynamic particles")
      .def("rhs", [](const SpringNetwork& net, py::array_t<double, py::array::c_style | py::array::forcecast> y) {
        if (y.ndim() != 1 || static_cast<std::size_t>(y.shape(0)) != net.size())
          throw InvalidArgument("y must have shape (" + std::to_string(net.size()) + ",)");
        py::array_t<double> out(static_cast<py::ssize_t>(net.size()));
        net.rhs(y.data(), out.mutable_data());
        return out;
      }, py::arg("y"))
      .def("jacobian", [](const SpringNetwork& net, py::array_t<double, py::array::c_style | py::array::forcecast> y) {
        if (y.ndim() != 1 || static_cast<std::size_t>(y.shape(0)) != net.size())
          throw InvalidArgument("y must have shape (" + std::to_string(net.size()) + ",)");
        const auto& cs = net.jacobian_column_starts();
        const auto& ri = net.jacobian_row_indices();
        py::array_t<double> values(static_cast<py::ssize_t>(ri.size()));
        net.jacobian(y.data(), values.mutable_data());
        return py::make_tuple(py::array_t<std::int64_t>(static_cast<py::ssize_t>(cs.size()), cs.data()),
                              py::array_t<std::int64_t>(static_cast<py::ssize_t>(ri.size()), ri.data()), values);
      }, py::arg("y"),
         "(indptr, indices, data) of ∂f/∂y in compressed sparse columns (scipy.sparse.csc_matrix order); "
         "with bending, only the spring and attachment part");

  // ---------------------------------------------------------------- metrics
  m.def("measure", [](const Model& model, const State& state, py::handle gravity) {
    const Metrics r = measure(model, state, to_vec3(gravity, "gravity"));
    py::dict d;
    d["t"] = r.t;
    d["kinetic_energy"] = r.kinetic_energy;
    d["gravitational_energy"] = r.gravitational_energy;
    d["elastic_energy"] = r.elastic_energy;
    d["total_energy"] = r.total_energy();
    d["linear_momentum"] = vec3_array(r.linear_momentum);
    d["angular_momentum"] = vec3_array(r.angular_momentum);
    d["distance"] = violation_dict(r.distance);
    d["bending"] = violation_dict(r.bending);
    d["attachment"] = violation_dict(r.attachment);
    d["volume"] = violation_dict(r.volume);
    d["balloon"] = violation_dict(r.balloon);
    d["max_strain"] = r.max_strain;
    d["rms_strain"] = r.rms_strain;
    return d;
  }, py::arg("model"), py::arg("state"), py::arg("gravity"));
  m.def("elastic_energy", &elastic_energy, py::arg("model"), py::arg("state"),
        "Σ C²/(2α) over the constraints with compliance α > 0, J.");
  m.def("distance_violations", [](const Model& model, const State& state) {
    std::vector<Real> v = distance_violations(model, state);
    return py::array_t<Real>(static_cast<py::ssize_t>(v.size()), v.data());
  }, py::arg("model"), py::arg("state"), "Violation |xi - xj| - rest of every distance constraint, m.");
  m.def("bending_violations", [](const Model& model, const State& state) {
    std::vector<Real> v = bending_violations(model, state);
    return py::array_t<Real>(static_cast<py::ssize_t>(v.size()), v.data());
  }, py::arg("model"), py::arg("state"), "Violation θ - θ0 of every bending constraint, rad.");
  m.def("volume_violations", [](const Model& model, const State& state) {
    std::vector<Real> v = volume_violations(model, state);
    return py::array_t<Real>(static_cast<py::ssize_t>(v.size()), v.data());
  }, py::arg("model"), py::arg("state"), "Violation V - V0 of every tetrahedral volume constraint, m³.");
  m.def("balloon_volumes", [](const Model& model, const State& state) {
    std::vector<Real> v = balloon_volumes(model, state);
    return py::array_t<Real>(static_cast<py::ssize_t>(v.size()), v.data());
  }, py::arg("model"), py::arg("state"), "Volume enclosed by every balloon's surface, m³.");

  // ---------------------------------------------------------------- kernels, one constraint at a time
  py::module_ k = m.def_submodule("kernels", "The constraint kernels on single constraints (for tests and teaching).");
  k.def("project_distance", [](py::handle p1, py::handle p2, double w1, double w2, double rest_length,
                               double stiffness, const std::string& sense) {
    Vec3 a = to_vec3(p1, "p1"), b = to_vec3(p2, "p2");
    const Real c = project_distance(a.data(), b.data(), w1, w2, rest_length, stiffness, parse_sense(sense));
    return py::make_tuple(vec3_array(a), vec3_array(b), c);
  }, py::arg("p1"), py::arg("p2"), py::arg("w1"), py::arg("w2"), py::arg("rest_length"), py::arg("stiffness") = 1.0,
     py::arg("sense") = "==", "Returns (p1', p2', violation before projection).");
  k.def("project_bending", [](py::handle a, py::handle b, py::handle c, py::handle d, std::array<double, 4> w,
                              double rest_angle, double stiffness) {
    Vec3 p[4] = {to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d")};
    const Real v = project_bending(p[0].data(), p[1].data(), p[2].data(), p[3].data(), w[0], w[1], w[2], w[3],
                                   rest_angle, stiffness);
    return py::make_tuple(vec3_array(p[0]), vec3_array(p[1]), vec3_array(p[2]), vec3_array(p[3]), v);
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), py::arg("inv_mass"), py::arg("rest_angle"),
     py::arg("stiffness") = 1.0, "Returns (a', b', c', d', violation before projection).");
  k.def("project_attachment", [](py::handle p, double w, py::handle target, double stiffness) {
    Vec3 x = to_vec3(p, "p");
    const Vec3 t = to_vec3(target, "target");
    const Real v = project_attachment(x.data(), w, t.data(), stiffness);
    return py::make_tuple(vec3_array(x), v);
  }, py::arg("p"), py::arg("w"), py::arg("target"), py::arg("stiffness") = 1.0);
  k.def("tet_volume", [](py::handle a, py::handle b, py::handle c, py::handle d) {
    return tet_volume(to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d"));
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), "Signed volume (1/6)(b - a) x (c - a)·(d - a), m³.");
  k.def("tet_volume_gradient", [](py::handle a, py::handle b, py::handle c, py::handle d) {
    Vec3 g[4];
    tet_volume_gradient(to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d"), g);
    py::array_t<double> out({4, 3});
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 3; ++j) out.mutable_at(i, j) = g[i][j];
    return out;
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), "(4, 3) gradient of the signed volume, m².");
  k.def("project_volume", [](py::handle a, py::handle b, py::handle c, py::handle d, std::array<double, 4> w,
                             double rest_volume, double stiffness) {
    Vec3 p[4] = {to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d")};
    const Real v = project_volume(p[0].data(), p[1].data(), p[2].data(), p[3].data(), w[0], w[1], w[2], w[3],
                                  rest_volume, stiffness);
    return py::make_tuple(vec3_array(p[0]), vec3_array(p[1]), vec3_array(p[2]), vec3_array(p[3]), v);
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), py::arg("inv_mass"), py::arg("rest_volume"),
     py::arg("stiffness") = 1.0, "PBD: returns (a', b', c', d', violation V - V0 before projection, m³).");
  k.def("project_volume_xpbd", [](py::handle a, py::handle b, py::handle c, py::handle d, std::array<double, 4> w,
                                  double rest_volume, double alpha_tilde, double lambda) {
    Vec3 p[4] = {to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d")};
    const Real v = project_volume_xpbd(p[0].data(), p[1].data(), p[2].data(), p[3].data(), p[0].data(), p[1].data(),
                                       p[2].data(), p[3].data(), w[0], w[1], w[2], w[3], rest_volume, alpha_tilde, 0,
                                       lambda);
    return py::make_tuple(vec3_array(p[0]), vec3_array(p[1]), vec3_array(p[2]), vec3_array(p[3]), v, lambda);
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), py::arg("inv_mass"), py::arg("rest_volume"),
     py::arg("alpha_tilde"), py::arg("lambda_") = 0.0,
     "XPBD (no damping), α̃ = α/h² in m⁴/kg (α in m⁶/J): returns (a', b', c', d', violation, λ + Δλ).");
  k.def("enclosed_volume", [](py::handle points, py::handle triangles) {
    const Positions x = to_positions(points, "points");
    const auto tris = to_index_rows<3>(triangles, "triangles");
    std::vector<Index> ids(x.cols());
    for (Index i = 0; i < x.cols(); ++i) ids[i] = i;
    for (const auto& t : tris)
      for (Index i : t)
        if (i < 0 || i >= x.cols()) throw InvalidArgument("triangles: index " + std::to_string(i) + " out of range");
    return enclosed_volume(x.data(), ids.data(), tris.data(), static_cast<Index>(tris.size()));
  }, py::arg("points"), py::arg("triangles"), "(1/6) Σ (p_a x p_b)·p_c over the triangles, m³.");
  k.def("project_balloon", [](py::handle points, py::handle triangles, py::handle inv_mass, double target_volume,
                              double stiffness) {
    Positions x = to_positions(points, "points");
    const auto tris = to_index_rows<3>(triangles, "triangles");
    const auto wa = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(inv_mass);
    if (!wa || wa.ndim() != 1 || wa.shape(0) != x.cols())
      throw InvalidArgument("inv_mass must have shape (" + std::to_string(x.cols()) + ",), one entry (1/kg) per point");
    std::vector<Real> w(wa.data(), wa.data() + x.cols());
    std::vector<Index> ids(x.cols());
    for (Index i = 0; i < x.cols(); ++i) ids[i] = i;
    for (const auto& t : tris)
      for (Index i : t)
        if (i < 0 || i >= x.cols()) throw InvalidArgument("triangles: index " + std::to_string(i) + " out of range");
    std::vector<Vec3> grad(x.cols());
    const Index n = static_cast<Index>(x.cols());
    const Real v = project_balloon(x.data(), x.data(), nullptr, w.data(), ids.data(), n, tris.data(),
                                   static_cast<Index>(tris.size()), target_volume, stiffness, nullptr, 0, 0, nullptr,
                                   grad.data());
    py::array_t<double> out({static_cast<py::ssize_t>(n), py::ssize_t(3)});
    if (n) std::memcpy(out.mutable_data(), x.data(), sizeof(double) * 3 * n);
    return py::make_tuple(out, v);
  }, py::arg("points"), py::arg("triangles"), py::arg("inv_mass"), py::arg("target_volume"), py::arg("stiffness") = 1.0,
     "PBD balloon projection of a closed surface: returns (points', violation V - target before projection, m³).");
  k.def("atan2", [](py::handle y, py::handle x) {
    using A = py::array_t<double, py::array::c_style | py::array::forcecast>;
    const A ya = A::ensure(y), xa = A::ensure(x);
    if (!ya || !xa || ya.ndim() != 1 || xa.ndim() != 1 || ya.shape(0) != xa.shape(0))
      throw InvalidArgument("y and x must be 1-D arrays of one length");
    py::array_t<double> out(ya.shape(0));
    atan2_rational_array(ya.data(), xa.data(), out.mutable_data(), static_cast<Index>(ya.shape(0)));
    return out;
  }, py::arg("y"), py::arg("x"),
     "The coloured bending kernel's branch-free rational atan2 (csb/atan2.hpp), elementwise, rad.");
  k.def("kernel_isa", [](std::optional<std::string> isa) {
    if (isa) set_kernel_isa(*isa);
    return kernel_isa();
  }, py::arg("isa") = py::none(),
     "The instruction set of the blocked coloured kernels (bending; PBD distance): 'avx512', 'avx2' or 'sse2' (x86-64 "
     "portable build, the best the processor has; 'avx512' runs bending in AVX-512 and distance in AVX2), 'native' (a "
     "CSB_NATIVE build, or not x86-64). isa='sse2', 'avx2' or 'avx512' forces that copy (an error if the processor "
     "lacks it), 'auto' the processor's choice; returns the one in use.");
  k.def("project_bending_coloured", [](py::handle points, py::handle quads, py::handle inv_mass, py::handle rest_angle,
                                       py::handle stiffness, py::handle alpha_tilde, py::handle gamma, py::handle lambda_,
                                       py::handle start, bool independent) -> py::tuple {
    using A = py::array_t<double, py::array::c_style | py::array::forcecast>;
    Positions x = to_positions(points, "points");
    const Index n = static_cast<Index>(x.cols());
    ColouredFour b;
    b.q = to_index_rows<4>(quads, "quads");
    const std::size_t m = b.q.size();
    for (const auto& q : b.q)
      for (Index i : q)
        if (i < 0 || i >= n) throw InvalidArgument("quads: index " + std::to_string(i) + " out of range");
    const auto column = [m](py::handle h, const char* what) {
      const A a = A::ensure(h);
      if (!a || a.ndim() != 1 || static_cast<std::size_t>(a.shape(0)) != m)
        throw InvalidArgument(std::string(what) + " must have shape (" + std::to_string(m) + ",)");
      return std::vector<Real>(a.data(), a.data() + m);
    };
    const A w = A::ensure(inv_mass);
    if (!w || w.ndim() != 2 || static_cast<std::size_t>(w.shape(0)) != m || w.shape(1) != 4)
      throw InvalidArgument("inv_mass must have shape (" + std::to_string(m) + ", 4)");
    b.w.resize(m);
    for (std::size_t c = 0; c < m; ++c)
      for (int s = 0; s < 4; ++s) b.w[c][s] = w.at(c, s);
    b.rest = column(rest_angle, "rest_angle");
    const bool xpbd = !alpha_tilde.is_none();
    Positions x0 = x;
    if (xpbd) {
      b.alpha = column(alpha_tilde, "alpha_tilde");
      b.gamma = gamma.is_none() ? std::vector<Real>(m, 0) : column(gamma, "gamma");
      b.lambda = lambda_.is_none() ? std::vector<Real>(m, 0) : column(lambda_, "lambda_");
      if (!start.is_none()) {
        x0 = to_positions(start, "start");
        if (x0.cols() != x.cols()) throw InvalidArgument("start must have the shape of points");
      }
    } else {
      b.k = stiffness.is_none() ? std::vector<Real>(m, 1) : column(stiffness, "stiffness");
    }
    project_bending_coloured(b, xpbd, independent, x.data(), x0.data());
    py::array_t<double> out({static_cast<py::ssize_t>(n), py::ssize_t(3)});
    if (n) std::memcpy(out.mutable_data(), x.data(), sizeof(double) * 3 * n);
    if (!xpbd) return py::make_tuple(out, py::none());
    return py::make_tuple(out, py::array_t<double>(static_cast<py::ssize_t>(m), b.lambda.data()));
  }, py::arg("points"), py::arg("quads"), py::arg("inv_mass"), py::arg("rest_angle"), py::arg("stiffness") = py::none(),
     py::arg("alpha_tilde") = py::none(), py::arg("gamma") = py::none(), py::arg("lambda_") = py::none(),
     py::arg("start") = py::none(), py::arg("independent") = true,
     "The stepper's coloured bending projection (csb/coloured_bending.hpp) over quads (a, b, c, d) in order, "
     "Gauss-Seidel in place: SIMD blocks if independent (the quads must then share no point), else one at a time. "
     "PBD with stiffness (default 1), or XPBD if alpha_tilde is given (gamma, lambda_, start: damping, multipliers, "
     "sub-step start positions). Returns (points', lambda' or None).");
  k.def("dihedral_angle", [](py::handle a, py::handle b, py::handle c, py::handle d) {
    return dihedral_angle(to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d"));
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), "Signed dihedral angle across edge (a, b), rad.");
  k.def("dihedral_angle_gradient", [](py::handle a, py::handle b, py::handle c, py::handle d) -> py::object {
    Vec3 g[4];
    Real theta = 0;
    if (!dihedral_angle_and_gradient(to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d"), theta, g))
      return py::none();
    py::array_t<double> out({4, 3});
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 3; ++j) out.mutable_at(i, j) = g[i][j];
    return std::move(out);
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), "(4, 3) gradient, rad/m; None if degenerate.");
}
