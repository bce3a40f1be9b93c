// csb._core — what every part of the bindings shares: numpy views of csb's arrays, conversions
// from Python objects with errors that name the argument, and the interruptible step.
#pragma once

#include "csb/csb.hpp"
#include "csb/constraints/attachment.hpp"
#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"
#include "csb/solver/coloured_bending.hpp"
#include "csb/memory_budget.hpp"
#include "int_arg.hpp"

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <chrono>
#include <cstring>
#include <functional>
#include <sstream>

namespace py = pybind11;

namespace csb::python {

using namespace csb;

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
inline py::array_t<bool> serial_flags(const Colouring& c) {
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

inline std::string shape_str(const py::array& a) {
  std::ostringstream s;
  s << "(";
  for (py::ssize_t k = 0; k < a.ndim(); ++k) s << (k ? ", " : "") << a.shape(k);
  s << (a.ndim() == 1 ? ",)" : ")");
  return s.str();
}

inline Positions to_positions(const py::handle& obj, const std::string& what) {
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
inline Index index_arg(const IntArg& v, const std::string& name, long long lo = 0) { return in_range(v, name, lo, kMaxIndex); }

inline int parse_sense(const std::string& s) {
  if (s == "==") return 0;
  if (s == ">=") return 1;
  if (s == "<=") return -1;
  throw InvalidArgument("sense must be '==' (distance equals rest length), '>=' or '<=', got '" + s + "'");
}

inline Plane parse_plane(const std::string& s) {
  if (s == "xy") return Plane::XY;
  if (s == "xz") return Plane::XZ;
  if (s == "yz") return Plane::YZ;
  throw InvalidArgument("plane must be 'xy', 'xz' or 'yz', got '" + s + "'");
}

// A step's interrupt (PbdStepper::step): at most every 20 ms, the GIL taken back to run Python's
// signal handlers; true once one raised (Ctrl-C: KeyboardInterrupt), which stays set for the
// binding to re-raise when the step has stopped.
inline std::function<bool()> python_interrupt() {
  return [last = std::chrono::steady_clock::now()]() mutable {
    const auto now = std::chrono::steady_clock::now();
    if (now - last < std::chrono::milliseconds(20)) return false;
    last = now;
    py::gil_scoped_acquire gil;
    return PyErr_CheckSignals() != 0;
  };
}

// The interrupt of a C++ method's step called from Python: Ctrl-C (python_interrupt) and, if
// given, the caller's own callable (Integrator.step's `interrupt`), asked with the GIL held. It
// holds the callable by handle (the caller's argument outlives the step), so that copying the
// function needs no GIL.
inline std::function<bool()> with_callers(py::handle interrupt) {
  if (!interrupt.is_none() && !PyCallable_Check(interrupt.ptr()))
    throw InvalidArgument("interrupt must be None or a callable returning whether to stop, got " +
                          std::string(py::repr(interrupt)));
  std::function<bool()> signals = python_interrupt();
  if (interrupt.is_none()) return signals;
  return [signals, interrupt]() mutable {
    if (signals()) return true;
    py::gil_scoped_acquire gil;
    return py::bool_(interrupt()).cast<bool>();
  };
}

// Steps without the GIL, asking Python's signal handlers (and the caller's `interrupt`) between
// (sub-)steps; what a handler raised (KeyboardInterrupt for Ctrl-C) is raised here, the state
// left where the stepper stopped; a stop the caller's interrupt asked for is a csb.Error saying
// where.
template <class Stepper>
void step_interruptibly(Stepper& stepper, const Model& model, State& state, std::int64_t steps,
                        py::handle interrupt = py::none()) {
  const std::function<bool()> ask = with_callers(interrupt);
  try {
    py::gil_scoped_release release;
    stepper.step(model, state, steps, ask);
  } catch (const Interrupted&) {
    if (PyErr_Occurred()) throw py::error_already_set();
    throw;
  }
}

inline Vec3 to_vec3(const py::handle& obj, const std::string& what) {
  py::array_t<double, py::array::forcecast> a;
  try {
    a = py::array_t<double, py::array::forcecast>::ensure(obj);
  } catch (const py::error_already_set&) {
  }
  if (!a || a.ndim() != 1 || a.shape(0) != 3) throw InvalidArgument(what + " must be a sequence of 3 numbers");
  return Vec3(a.at(0), a.at(1), a.at(2));
}

inline ContactMaterial material(double friction_static, double friction_kinetic, double restitution) {
  ContactMaterial m;
  m.friction_static = friction_static;
  m.friction_kinetic = friction_kinetic;
  m.restitution = restitution;
  return m;
}

inline Mat3 to_mat3(const py::handle& obj, const std::string& what) {
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

inline py::dict report_dict(const MeshReport& r) {
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
inline MassSpec mass_spec(const std::string& name, const py::object& mass, const py::object& density,
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
inline py::dict instance_dict(const MeshInstance& inst) {
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

inline py::dict violation_dict(const Violation& v) {
  py::dict d;
  d["count"] = v.count;
  d["max"] = v.max;
  d["rms"] = v.rms;
  return d;
}

// What self-collision did in an implicit method's last sub-step (the keys of PbdStepper.contacts()'
// self_* entries, without the prefix).
inline constexpr const char* kSelfCollisionDoc =
    "what self-collision did in the last sub-step: contacts, continuous, failsafe, unresolved, skipped and "
    "candidates there; searches, tests and culled (pairs left untested in certified patches) since the model "
    "was first stepped";
inline py::dict self_collision_dict(const SelfCollisionCounts& c) {
  py::dict d;
  d["contacts"] = c.contacts;
  d["continuous"] = c.continuous;
  d["failsafe"] = c.failsafe;
  d["unresolved"] = c.unresolved;
  d["skipped"] = c.skipped;
  d["candidates"] = c.candidates;
  d["searches"] = c.searches;
  d["tests"] = c.tests;
  d["culled"] = c.culled;
  return d;
}

inline py::array vec3_array(const Vec3& v) {
  py::array_t<double> a(3);
  for (int k = 0; k < 3; ++k) a.mutable_at(k) = v[k];
  return a;
}


// The parts of the module, one per area (bind_*.cpp).
struct Warnings {
  PyObject* material;  // csb.MaterialWarning
  PyObject* accuracy;  // csb.AccuracyWarning
};
void bind_mesh(py::module_& m);
void bind_model(py::module_& m);
void bind_family(py::module_& m);  // after bind_model (the builder it extends)
void bind_integrator(py::module_& m);  // before bind_methods: the steppers derive from Integrator
void bind_methods(py::module_& m, const Warnings& warnings);
void bind_plugin(py::module_& m);  // after bind_integrator
void bind_reference(py::module_& m);
void bind_implicit(py::module_& m);  // after bind_integrator and bind_reference
void bind_vbd(py::module_& m);  // after bind_implicit (its residual type)
void bind_projective(py::module_& m);  // after bind_implicit
void bind_metrics(py::module_& m);
void bind_kernels(py::module_& m);

}  // namespace csb::python
