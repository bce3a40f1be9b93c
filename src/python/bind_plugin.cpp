// csb._core: methods brought as plug-ins (csb/plugin/): csb.load_plugin(path) loads a shared
// library written against csb_plugin.h and returns a csb.Plugin, which makes csb.PluginIntegrator
// objects (csb.Integrator) from dt, substeps, iterations and gravity, the keywords a study's
// make_stepper passes to a callable.
#include "bindings.hpp"

namespace csb::python {

namespace {

// A str or an os.PathLike as a path; a csb.ParameterError naming `path` otherwise.
std::string path_arg(const py::handle& path) {
  py::object p;
  try {
    p = py::module_::import("os").attr("fspath")(path);
  } catch (const py::error_already_set&) {
    throw InvalidArgument("path must be a str or an os.PathLike naming a shared library, got " + std::string(py::repr(path)));
  }
  if (!py::isinstance<py::str>(p))
    throw InvalidArgument("path must be a str or an os.PathLike naming a shared library, got " + std::string(py::repr(path)));
  return p.cast<std::string>();
}

}  // namespace

void bind_plugin(py::module_& m) {
  // Both classes first, so that each one's signatures can name the other.
  py::class_<PluginLibrary, std::shared_ptr<PluginLibrary>> plugin(m, "Plugin",
      "A method brought as a plug-in: a shared library written against csb_plugin.h (in csb.plugin_include_dir()), "
      "loaded by csb.load_plugin(path). Calling it, plugin(dt=..., substeps=1, iterations=10, gravity=(0, -9.81, 0)), "
      "makes a csb.PluginIntegrator, a csb.Integrator that the runner, the viewer and the studies step like a "
      "built-in; so the Plugin itself can be passed wherever a callable making an Integrator is taken "
      "(csb.studies.make_stepper).");
  py::class_<PluginIntegrator, Integrator, py::smart_holder> integrator(m, "PluginIntegrator",
      "An integrator of a plug-in (csb.load_plugin(path)(dt=...)): a csb.Integrator. step() calls the plug-in one "
      "step at a time, checks that every position and velocity is finite and advances state.t and state.step; a "
      "step the plug-in reports as failed, or one that leaves a non-finite value, puts the state back at the end "
      "of the last completed step and raises csb.SimulationError (csb.ParameterError for a model or settings the "
      "plug-in refuses), naming the plug-in, its file, the step and the plug-in's message.");

  plugin.def_property_readonly("path", &PluginLibrary::path, "the file it was loaded from, as given")
      .def_property_readonly("name", &PluginLibrary::name, "the method's name, as csb_plugin_name() gives it")
      .def_property_readonly("abi_version", &PluginLibrary::abi_version, "the version of csb_plugin.h it was built for")
      .def("__call__", [](std::shared_ptr<PluginLibrary> self, double dt, IntArg substeps, IntArg iterations,
                          py::handle gravity) {
             MethodOptions o;
             o.dt = dt;
             o.substeps = in_range<int>(substeps, "substeps", 1, kMaxSubsteps);
             o.iterations = in_range<int>(iterations, "iterations", 1, kMaxIterations);
             o.gravity = to_vec3(gravity, "gravity");
             return std::make_shared<PluginIntegrator>(std::move(self), o);
           }, py::arg("dt"), py::kw_only(), py::arg("substeps") = 1, py::arg("iterations") = 10,
           py::arg("gravity") = std::vector<double>{0, -9.81, 0},
           "An integrator of this plug-in with step dt (s), `substeps` sub-steps per step, `iterations` constraint "
           "sweeps per sub-step and gravity (m/s²): a csb.PluginIntegrator. Settings out of range are a "
           "csb.ParameterError naming them, as are settings the plug-in refuses (with its message).")
      .def("__reduce__", [m](const PluginLibrary& self) -> py::tuple {
        // Pickled by its path: loaded again where it is unpickled (a study's worker process).
        return py::make_tuple(py::object(m.attr("load_plugin")), py::make_tuple(self.path()));
      })
      .def("__repr__", [](const PluginLibrary& self) {
        return "<csb.Plugin '" + self.name() + "' from " + self.path() + ">";
      });

  integrator
      .def_property_readonly("plugin", [](const PluginIntegrator& s) { return std::const_pointer_cast<PluginLibrary>(s.library()); },
                             "the csb.Plugin it was made from")
      .def_property_readonly("substeps", [](const PluginIntegrator& s) { return s.options().substeps; })
      .def_property_readonly("iterations", [](const PluginIntegrator& s) { return s.options().iterations; })
      .def_property_readonly("gravity", [](const PluginIntegrator& s) { return vec3_array(s.options().gravity); }, "m/s²");

  m.def("load_plugin", [](py::handle path) {
    return std::const_pointer_cast<PluginLibrary>(PluginLibrary::load(path_arg(path)));
  }, py::arg("path"),
     "Loads the method in the shared library at `path` (a str or os.PathLike; a name without a directory is taken "
     "in the working directory, not searched for) and returns a csb.Plugin, which makes integrators: "
     "csb.load_plugin(path)(dt=0.01, substeps=1, iterations=10, gravity=(0, -9.81, 0)). A missing file is a "
     "FileNotFoundError; a file that is not a shared library, lacks one of csb_plugin.h's entry points (named) or "
     "was built for another version of csb_plugin.h is a csb.ParameterError naming the file.");
}

}  // namespace csb::python
