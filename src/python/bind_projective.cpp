// csb._core: Projective Dynamics with optional Chebyshev acceleration
// (csb/methods/projective_dynamics/projective_dynamics.hpp), a built-in Integrator.
#include "bindings.hpp"
#include "csb/methods/projective_dynamics/projective_dynamics.hpp"

namespace csb::python {

void bind_projective(py::module_& m) {
  using PD = ProjectiveDynamicsStepper;
  py::class_<PD, Integrator, py::smart_holder>(m, "ProjectiveDynamics",
      "Projective Dynamics (Bouaziz et al. 2014) with optional Chebyshev acceleration (Wang 2015): each sub-step "
      "minimises backward Euler's incremental potential with every constraint's potential made projective, by "
      "`iterations` local projections and global solves with a matrix factored once per model and sub-step length. "
      "Reads compliance: exact for distance constraints and attachments, first order for bending, volumes, "
      "balloons and tethers. Holds contacts with colliders by projection after each global solve and runs "
      "self-collision as a layer after each sub-step's solve; refuses hard constraints.")
      .def(py::init([](double dt, IntArg substeps, IntArg iterations, py::handle gravity, bool chebyshev,
                       double spectral_radius, IntArg chebyshev_delay, double relaxation, IntArg threads,
                       bool record_residuals) {
             ProjectiveDynamicsSettings s;
             s.dt = dt;
             s.substeps = in_range<int>(substeps, "substeps", 1, kMaxSubsteps);
             s.iterations = in_range<int>(iterations, "iterations", 1, kMaxIterations);
             s.gravity = to_vec3(gravity, "gravity");
             s.chebyshev = chebyshev;
             s.spectral_radius = spectral_radius;
             s.chebyshev_delay = in_range<int>(chebyshev_delay, "chebyshev_delay", 0, kMaxIterations);
             s.relaxation = relaxation;
             s.threads = in_range<int>(threads, "threads", 0, kMaxThreads);
             s.record_residuals = record_residuals;
             return PD(s);
           }),
           py::kw_only(), py::arg("dt") = 1.0 / 60.0, py::arg("substeps") = 1, py::arg("iterations") = 10,
           py::arg("gravity") = std::vector<double>{0, -9.81, 0}, py::arg("chebyshev") = false,
           py::arg("spectral_radius") = 0.0, py::arg("chebyshev_delay") = 10, py::arg("relaxation") = 0.9,
           py::arg("threads") = 0, py::arg("record_residuals") = false,
           "dt: s, the time a step advances, in `substeps` sub-steps. iterations: local/global iterations per "
           "sub-step. gravity: m/s². chebyshev: Wang 2015's acceleration, with spectral_radius ρ in (0, 1) (0: "
           "measured each sub-step), chebyshev_delay S plain iterations first and the under-relaxation "
           "`relaxation` γ in (0, 1]. threads: of the local step, 0 automatic; the result does not depend on it. "
           "record_residuals: keep the backward-Euler residual after each iteration of the last sub-step.")
      .def("step", [](PD& s, const Model& model, State& state, IntArg steps_arg, py::object interrupt) {
        step_interruptibly(s, model, state, in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64), interrupt);
      }, py::arg("model"), py::arg("state"), py::arg("steps") = 1, py::arg("interrupt") = py::none(),
         "Advances state by `steps` steps of dt (the GIL released meanwhile).")
      .def_property_readonly("substeps", [](const PD& s) { return s.settings().substeps; })
      .def_property_readonly("iterations", [](const PD& s) { return s.settings().iterations; })
      .def_property_readonly("gravity", [](const PD& s) { return vec3_array(s.settings().gravity); }, "m/s²")
      .def_property_readonly("chebyshev", [](const PD& s) { return s.settings().chebyshev; })
      .def_property_readonly("spectral_radius", [](const PD& s) { return s.settings().spectral_radius; },
           "as set (0: measured each sub-step)")
      .def_property_readonly("chebyshev_delay", [](const PD& s) { return s.settings().chebyshev_delay; })
      .def_property_readonly("relaxation", [](const PD& s) { return s.settings().relaxation; })
      .def_property_readonly("threads", [](const PD& s) { return s.settings().threads; }, "as set (0: automatic)")
      .def_property_readonly("record_residuals", [](const PD& s) { return s.settings().record_residuals; })
      .def_property_readonly("threads_used", [](const PD& s) { return s.stats().threads_used; },
           "threads of the last sub-step's local steps")
      .def_property_readonly("factorizations", [](const PD& s) { return s.stats().factorizations; },
           "factorisations of the global matrix so far (one per model and sub-step length)")
      .def_property_readonly("factorization_time", [](const PD& s) { return s.stats().factorization_time; },
           "s, wall time of all factorisations (the terms' set-up included)")
      .def_property_readonly("last_factorization_time", [](const PD& s) { return s.stats().last_factorization_time; },
           "s, wall time of the latest factorisation")
      .def_property_readonly("spectral_radius_used", [](const PD& s) { return s.stats().spectral_radius; },
           "ρ the last sub-step's Chebyshev acceleration used (0: none)")
      .def_property_readonly("measured_spectral_radius", [](const PD& s) { return s.stats().measured_spectral_radius; },
           "the last measurement of ρ (spectral_radius 0), also when outside (0, 1) and so not used")
      .def_property_readonly("residual_history", [](const PD& s) {
        const auto& h = s.stats().residual_history;
        return std::vector<double>(h.begin(), h.end());
      }, "N, with record_residuals: the largest backward-Euler residual component of the last sub-step at its "
         "start (x̃) and after each iteration (iterations + 1 values); empty otherwise")
      .def_property_readonly("self_collision", [](const PD& s) { return self_collision_dict(s.self_collision()); },
           kSelfCollisionDoc);
}

}  // namespace csb::python
