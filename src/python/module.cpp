// csb._core — the pybind11 module. Arrays of the State are zero-copy, writable numpy views;
// arrays of the (immutable) Model are zero-copy, read-only views. Parameters are keyword
// arguments in SI units.
#include "bindings.hpp"

using namespace csb;
using namespace csb::python;

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
    // csb._viewer, a module of its own, says whether it loads (csb.viewer_missing()).
#ifdef CSB_VIEWER_MISSING
    d["viewer"] = std::string("not built: ") + CSB_VIEWER_MISSING;
#else
    d["viewer"] = "built";
#endif
    return d;
  }, "Versions of csb and of the libraries it was built against, and whether the viewer was built.");
  bind_mesh(m);
  bind_model(m);
  bind_family(m);
  bind_integrator(m);
  bind_methods(m, Warnings{material_warning, accuracy_warning});
  bind_plugin(m);
  bind_reference(m);
  bind_implicit(m);
  bind_vbd(m);
  bind_projective(m);
  bind_metrics(m);
  bind_kernels(m);
}
