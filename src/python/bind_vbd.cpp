// csb._core: Vertex Block Descent (csb/methods/vbd/vbd.hpp), a built-in Integrator.
#include "bindings.hpp"
#include "csb/methods/vbd/vbd.hpp"

namespace csb::python {

void bind_vbd(py::module_& m) {
  py::class_<VbdStepper, Integrator, py::smart_holder>(m, "VertexBlockDescent",
      "Vertex Block Descent (Chen, Liu, Yang and Yuksel 2024): each sub-step minimises the backward Euler step's "
      "incremental potential over every compliant constraint by `iterations` sweeps of per-vertex Newton steps, "
      "colour by colour (a colour's vertices share no constraint and update in parallel). Reads compliance; "
      "takes contacts with colliders as a penalty and self-collision as a layer after each sub-step's solve; refuses hard constraints.")
      .def(py::init([](double dt, IntArg substeps, IntArg iterations, py::handle gravity,
                       const std::string& initialization, double acceleration, IntArg threads,
                       double contact_stiffness) {
             VbdSettings s;
             s.dt = dt;
             s.substeps = in_range<int>(substeps, "substeps", 1, kMaxSubsteps);
             s.iterations = in_range<int>(iterations, "iterations", 1, kMaxIterations);
             s.gravity = to_vec3(gravity, "gravity");
             s.initialization = parse_initialization(initialization);
             s.acceleration = acceleration;
             s.threads = in_range<int>(threads, "threads", 0, kMaxThreads);
             s.contact_stiffness = contact_stiffness;
             return VbdStepper(s);
           }),
           py::kw_only(), py::arg("dt") = 1.0 / 60.0, py::arg("substeps") = 1, py::arg("iterations") = 10,
           py::arg("gravity") = std::vector<double>{0, -9.81, 0}, py::arg("initialization") = "adaptive",
           py::arg("acceleration") = 0.0, py::arg("threads") = 0,
           py::arg("contact_stiffness") = 1e4,
           "dt: s, the time a step advances, in `substeps` sub-steps. iterations: VBD sweeps over all vertices per "
           "sub-step. gravity: m/s². initialization: 'adaptive', 'inertia' or 'previous'. acceleration: ρ of the "
           "Chebyshev acceleration in [0, 1), 0 off. threads: 0 automatic; the result does not depend on it. "
           "contact_stiffness: κ, contacts with colliders as a penalty of stiffness κ m/h² (N/m).")
      .def("step", [](VbdStepper& s, const Model& model, State& state, IntArg steps_arg, py::object interrupt) {
        step_interruptibly(s, model, state, in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64), interrupt);
      }, py::arg("model"), py::arg("state"), py::arg("steps") = 1, py::arg("interrupt") = py::none(),
         "Advances state by `steps` steps of dt (the GIL released meanwhile).")
      .def_property_readonly("substeps", [](const VbdStepper& s) { return s.settings().substeps; })
      .def_property_readonly("iterations", [](const VbdStepper& s) { return s.settings().iterations; })
      .def_property_readonly("gravity", [](const VbdStepper& s) { return vec3_array(s.settings().gravity); }, "m/s²")
      .def_property_readonly("initialization", [](const VbdStepper& s) {
        return std::string(initialization_name(s.settings().initialization));
      })
      .def_property_readonly("acceleration", [](const VbdStepper& s) { return s.settings().acceleration; })
      .def_property_readonly("threads", [](const VbdStepper& s) { return s.settings().threads; }, "as set (0: automatic)")
      .def_property_readonly("threads_used", &VbdStepper::threads_used, "threads of the last step")
      .def_property_readonly("num_colours", &VbdStepper::num_colours, "vertex colours of the last model stepped")
      .def_property_readonly("self_collision", [](const VbdStepper& s) { return self_collision_dict(s.self_collision()); },
           kSelfCollisionDoc)
      .def("residual", [](const VbdStepper& s, const Model& model) {
        py::gil_scoped_release release;
        return s.last_residual(model);
      }, py::arg("model"),
         "The backward-Euler residual (csb.BackwardEulerResidual, N) of the last sub-step taken on `model`: what "
         "the sweeps left of ∇E; computed when asked.");
}

}  // namespace csb::python
