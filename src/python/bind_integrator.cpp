// csb._core: the step-level interface every method implements (csb.Integrator), open to Python
// through a trampoline, and the methods by name (csb.methods, csb.make_integrator).
//
// A Python subclass of csb.Integrator implements name(), dt() and step(model, state, steps=1,
// interrupt=None); csb's C++ (the viewer) then steps it like a built-in. The classes are held by
// pybind11's smart_holder, and the trampoline has trampoline_self_life_support, so that a
// std::shared_ptr<Integrator> that C++ keeps of a Python object keeps the Python object (its
// __dict__, its numpy arrays) alive with it.
#include "bindings.hpp"
#include "csb/methods/registry.hpp"

#include <pybind11/functional.h>

#include <cmath>

namespace csb::python {

namespace {

// A Python method's call from C++, as PYBIND11_OVERRIDE_PURE makes it (py::get_override, the
// GIL taken), with the errors a user can act on: a method the class does not define names the
// class and the method (NotImplementedError); a Python exception raised by it passes through as
// it was raised (py::error_already_set keeps its type, message and traceback).
class PyIntegrator : public Integrator, public py::trampoline_self_life_support {
 public:
  using Integrator::Integrator;

  std::string name() const override {
    py::gil_scoped_acquire gil;
    py::object r = override_of("name", "name()")();
    if (!py::isinstance<py::str>(r)) wrong_return("name()", "a str", r);
    return r.cast<std::string>();
  }

  Real dt() const override {
    py::gil_scoped_acquire gil;
    py::object r = override_of("dt", "dt()")();
    double v = 0;
    try {
      v = py::cast<double>(py::float_(r));
    } catch (const py::error_already_set&) {
      wrong_return("dt()", "a time step in s (a float > 0)", r);
    }
    return v;
  }

  void step(const Model& model, State& state, std::int64_t steps,
            const std::function<bool()>& interrupt) override {
    py::gil_scoped_acquire gil;
    py::function f = override_of("step", "step(model, state, steps=1, interrupt=None)");
    // Pointers, not references: pybind11 passes a reference argument to Python as a copy, and
    // the method must advance this state. The Model is shared (enable_shared_from_this), so a
    // method that keeps the model it was given keeps it alive.
    f(&model, &state, steps, interrupt ? py::cpp_function(interrupt) : py::object(py::none()));
  }

 private:
  py::handle self() const {
    return py::detail::get_object_handle(static_cast<const Integrator*>(this),
                                         py::detail::get_type_info(typeid(Integrator)));
  }

  std::string class_name() const {
    py::handle s = self();
    return s ? py::str(py::type::handle_of(s).attr("__qualname__")).cast<std::string>() : std::string("Integrator");
  }

  py::function override_of(const char* method, const char* signature) const {
    py::function f = py::get_override(static_cast<const Integrator*>(this), method);
    if (!f) {
      const std::string message = class_name() + " does not define " + signature +
                                  ", which a csb.Integrator implements (name(), dt() and step(model, state, steps=1, "
                                  "interrupt=None))";
      PyErr_SetString(PyExc_NotImplementedError, message.c_str());
      throw py::error_already_set();
    }
    return f;
  }

  [[noreturn]] void wrong_return(const char* method, const char* expected, const py::object& got) const {
    const std::string message = class_name() + "." + method + " must return " + expected + ", got " +
                                std::string(py::repr(got));
    PyErr_SetString(PyExc_TypeError, message.c_str());
    throw py::error_already_set();
  }
};

}  // namespace

void bind_integrator(py::module_& m) {
  py::class_<Integrator, PyIntegrator, py::smart_holder>(m, "Integrator",
      "The step-level interface every method implements: name(), dt() (s) and step(model, state, steps=1, "
      "interrupt=None), which advances the state in place by `steps` steps of dt (positions, velocities, state.t "
      "and state.step). PbdStepper and ForceStepper are Integrators; so is a Python subclass that implements the "
      "three methods (calling Integrator.__init__ in its own __init__), and it is then accepted wherever a "
      "built-in is: the scene runner, csb.render and csb.view, the studies. `interrupt`, when not None, is a "
      "callable a long step may ask between steps whether to stop.")
      .def(py::init<>())
      .def("name", &Integrator::name, "A short name of the method ('pbd', 'symplectic-euler', a user's own).")
      .def("dt", &Integrator::dt, "s, the time one step advances.")
      .def("step", [](Integrator& self, const Model& model, State& state, IntArg steps_arg, py::object interrupt) {
        const std::int64_t steps = in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64);
        if (!interrupt.is_none() && !PyCallable_Check(interrupt.ptr()))
          throw InvalidArgument("interrupt must be None or a callable returning whether to stop, got " +
                                std::string(py::repr(interrupt)));
        if (dynamic_cast<PyIntegrator*>(&self)) {
          // A Python method: called with the GIL held, the caller's interrupt passed as given.
          std::function<bool()> ask;
          if (!interrupt.is_none()) ask = [interrupt]() { return py::bool_(interrupt()).cast<bool>(); };
          self.step(model, state, steps, ask);
          return;
        }
        step_interruptibly(self, model, state, steps, interrupt);  // a C++ method: without the GIL
      }, py::arg("model"), py::arg("state"), py::arg("steps") = 1, py::arg("interrupt") = py::none(),
         "Advances state by `steps` steps of dt.")
      .def("__repr__", [](py::handle self) {
        const Integrator& s = self.cast<const Integrator&>();
        std::ostringstream o;
        o << "<" << py::str(py::type::handle_of(self).attr("__qualname__")).cast<std::string>() << " '" << s.name()
          << "', dt = " << s.dt() << " s>";
        return o.str();
      });

  py::class_<SettingInfo>(m, "SettingInfo", "One of a method's own settings: make_integrator's keyword, a scene's "
                                             "[solver.settings] key.")
      .def_readonly("name", &SettingInfo::name)
      .def_readonly("default", &SettingInfo::default_value, "as a scene file writes it")
      .def_readonly("description", &SettingInfo::description, "what it is, its unit and range")
      .def("__repr__", [](const SettingInfo& i) {
        return "SettingInfo(name='" + i.name + "', default=" + i.default_value + ")";
      });

  py::class_<MethodInfo>(m, "MethodInfo", "A method csb can step with, as listed by csb.methods().")
      .def_readonly("name", &MethodInfo::name, "how to ask for it: make_integrator(name, dt)")
      .def_readonly("label", &MethodInfo::label, "for tables and the viewer")
      .def_readonly("source", &MethodInfo::source, "where it comes from")
      .def_readonly("reads", &MethodInfo::reads, "what it reads of a constraint's material: 'stiffness' or 'compliance'")
      .def_readonly("iterates", &MethodInfo::iterates, "whether `iterations` means anything to it")
      .def_readonly("aliases", &MethodInfo::aliases, "other names it answers to")
      .def_readonly("settings", &MethodInfo::settings, "its own settings, beyond dt, substeps, iterations and gravity")
      .def_property_readonly("pbd_variant", [](const MethodInfo& i) { return i.pbd && method_info(*i.pbd).name == i.name; },
          "whether PbdStepper(method=name) and a scene's solver.method take this name (small steps is a set-up of "
          "XPBD, not a variant of its own)")
      .def("__repr__", [](const MethodInfo& i) {
        return "MethodInfo(name='" + i.name + "', label='" + i.label + "', source='" + i.source + "', reads='" +
               i.reads + "', iterates=" + (i.iterates ? "True" : "False") + ")";
      });

  m.def("method_info", [](const std::string& name) { return method_info(name); }, py::arg("name"),
        "The built-in method of that name or alias; a csb.ParameterError listing the known ones otherwise.");
  m.def("pbd_variant_names", [](bool aliases) {
          std::vector<std::string> names;
          for (const Method v : pbd_variants()) {
            const MethodInfo& i = method_info(v);
            names.push_back(i.name);
            if (aliases) names.insert(names.end(), i.aliases.begin(), i.aliases.end());
          }
          return names;
        }, py::kw_only(), py::arg("aliases") = false,
        "The names PbdStepper(method=...) and a scene's solver.method take, in csb's order (with their aliases).");
  m.def("methods", [] { return methods(); }, "The built-in methods, in csb's order: name, label, source, reads, iterates.");
  m.def("make_integrator", [](const std::string& name, double dt, IntArg substeps, IntArg iterations, py::handle gravity,
                              const py::kwargs& settings) {
    const MethodInfo& info = method_info(name);  // InvalidArgument naming the known methods
    MethodOptions o;
    o.dt = dt;
    o.substeps = in_range<int>(substeps, "substeps", 1, kMaxSubsteps);
    o.iterations = in_range<int>(iterations, "iterations", 1, kMaxIterations);
    o.gravity = to_vec3(gravity, "gravity");
    for (const auto& [k, v] : settings) {
      const std::string key = py::str(k);
      if (py::isinstance<py::bool_>(v)) o.settings.set(key, v.cast<bool>());
      else if (py::isinstance<py::int_>(v)) o.settings.set(key, v.cast<std::int64_t>());
      else if (py::isinstance<py::float_>(v)) o.settings.set(key, v.cast<double>());
      else if (py::isinstance<py::str>(v)) o.settings.set(key, v.cast<std::string>());
      else throw InvalidArgument("setting '" + key + "' must be a boolean, a number or a string, got " +
                                 py::str(py::type::handle_of(v).attr("__name__")).cast<std::string>());
    }
    return std::shared_ptr<Integrator>(make_method(info, o));
  }, py::arg("name"), py::arg("dt"), py::kw_only(), py::arg("substeps") = 1, py::arg("iterations") = 10,
     py::arg("gravity") = std::vector<double>{0, -9.81, 0},
     "The built-in method `name` (see csb.methods()) with step dt (s), `substeps` sub-steps per step, `iterations` "
     "constraint sweeps per sub-step (methods that iterate) and gravity (m/s²); a method's own settings as further "
     "keywords (csb.method_info(name).settings lists them), the others at their defaults. An unknown name or "
     "setting, or a setting out of range, is a csb.ParameterError (a ValueError) naming it.");
}

}  // namespace csb::python
