// csb._core: the same-step reference: backward Euler solved by Newton's method each step
// (csb/implicit_euler.hpp), its incremental potential, and the backward-Euler residual of a step
// taken by any method.
#include "bindings.hpp"
#include "csb/implicit_euler.hpp"

namespace csb::python {

namespace {

// The dynamic particles' rows of an (N, 3) array, flattened (m).
std::vector<Real> dynamic_rows(const IncrementalPotential& p, const Model& model, py::handle x_arg) {
  const Positions x = to_positions(x_arg, "x");
  if (x.cols() != model.num_particles())
    throw InvalidArgument("x must have shape (" + std::to_string(model.num_particles()) + ", 3), got " +
                          std::to_string(x.cols()) + " rows");
  if (!x.allFinite()) throw InvalidArgument("x must be finite");
  const auto& dyn = p.network().dynamic_particles();
  std::vector<Real> out(3 * dyn.size());
  for (std::size_t s = 0; s < dyn.size(); ++s)
    for (int k = 0; k < 3; ++k) out[3 * s + k] = x(k, dyn[s]);
  return out;
}

struct BoundPotential {
  std::shared_ptr<const Model> model;
  IncrementalPotential potential;
};

}  // namespace

void bind_implicit(py::module_& m) {
  py::class_<Residual>(m, "BackwardEulerResidual",
      "The backward-Euler residual ∇E of a step (N): its 2-norm, its largest component and the step's force scale "
      "(the largest of m|g|, the constraint forces and the inertia m|x - x̃|/h²).")
      .def_readonly("norm", &Residual::norm, "N, 2-norm over the dynamic particles' coordinates")
      .def_readonly("max", &Residual::max, "N, largest component")
      .def_readonly("scale", &Residual::scale, "N, the step's force scale")
      .def("__repr__", [](const Residual& r) {
        std::ostringstream o;
        o << "BackwardEulerResidual(norm=" << r.norm << ", max=" << r.max << ", scale=" << r.scale << ")";
        return o.str();
      });

  m.def("backward_euler_residual", [](const Model& model, const State& previous, const State& next, double dt,
                                      py::handle gravity) {
    const Vec3 g = to_vec3(gravity, "gravity");
    py::gil_scoped_release release;
    return backward_euler_residual(model, previous, next, dt, g);
  }, py::arg("model"), py::arg("previous"), py::arg("next"), py::arg("dt"),
     py::arg("gravity") = std::vector<double>{0, -9.81, 0},
     "The backward-Euler residual |∇E(x_next)| (N) of a step of dt (s) from `previous` to `next` taken by any "
     "method: E(x) = Σ m|x - x̃|²/(2h²) + Σ C²/(2α), x̃ = x_prev + h v_prev + h² g (gravity, m/s²), the pinned "
     "particles where `next` has them. Zero for a converged backward Euler step; the solver error of an iterative "
     "method's step. A hard constraint (α = 0) is a csb.ParameterError naming it.");

  py::class_<BoundPotential>(m, "IncrementalPotential",
      "The incremental potential of one backward Euler step, E(x) = Σ m|x - x̃|²/(2h²) + U(x), from the state "
      "before the step: for tests and studies. Positions are (N, 3) arrays of all particles; the pinned ones stay "
      "where `pinned_at` (default: `previous`) has them and carry no gradient.")
      .def(py::init([](std::shared_ptr<const Model> model, const State& previous, double dt, py::handle gravity,
                       py::object pinned_at) {
             const Vec3 g = to_vec3(gravity, "gravity");
             const State& pin = pinned_at.is_none() ? previous : pinned_at.cast<const State&>();
             return BoundPotential{model, IncrementalPotential(*model, previous, pin, dt, g)};
           }),
           py::arg("model"), py::arg("previous"), py::arg("dt"), py::kw_only(),
           py::arg("gravity") = std::vector<double>{0, -9.81, 0}, py::arg("pinned_at") = py::none())
      .def_property_readonly("dynamic_particles", [](const BoundPotential& b) {
        const auto& d = b.potential.network().dynamic_particles();
        return py::array_t<Index>(static_cast<py::ssize_t>(d.size()), d.data());
      }, "the particles that move, in the order of the Hessian's rows (3 each)")
      .def_property_readonly("inertial_positions", [](const BoundPotential& b) {
        const auto& x = b.potential.inertial_positions();
        return py::array_t<double>({static_cast<py::ssize_t>(x.size() / 3), py::ssize_t(3)}, x.data());
      }, "x̃ = x + h v + h² g of the dynamic particles, m, (n, 3)")
      .def("energy", [](const BoundPotential& b, py::handle x) {
        const auto y = dynamic_rows(b.potential, *b.model, x);
        return b.potential.energy(y.data());
      }, py::arg("x"), "E(x), J")
      .def("gradient", [](const BoundPotential& b, py::handle x) {
        const auto y = dynamic_rows(b.potential, *b.model, x);
        std::vector<Real> r(y.size());
        b.potential.gradient(y.data(), r.data());
        py::array_t<double> out({static_cast<py::ssize_t>(b.model->num_particles()), py::ssize_t(3)});
        std::fill(out.mutable_data(), out.mutable_data() + out.size(), 0.0);
        const auto& dyn = b.potential.network().dynamic_particles();
        for (std::size_t s = 0; s < dyn.size(); ++s)
          for (int k = 0; k < 3; ++k) out.mutable_data()[3 * dyn[s] + k] = r[3 * s + k];
        return out;
      }, py::arg("x"), "∇E(x), N, (N, 3), zero on the pinned particles")
      .def("hessian", [](const BoundPotential& b, py::handle x, bool definite) {
        const auto y = dynamic_rows(b.potential, *b.model, x);
        Eigen::SparseMatrix<Real> H;
        SpringNetwork::Stiffness work;
        b.potential.hessian(y.data(), definite, H, work);
        Eigen::MatrixXd D = Eigen::MatrixXd(H);
        for (std::size_t k = 0; k < work.rank_one_weight.size(); ++k) {
          const Eigen::Map<const Eigen::VectorXd> u(work.rank_one_vector[k].data(), D.rows());
          D += work.rank_one_weight[k] * u * u.transpose();
        }
        return D;
      }, py::arg("x"), py::kw_only(), py::arg("definite") = false,
         "∇²E(x), N/m, dense (3n, 3n) over the dynamic particles (rows in dynamic_particles' order); with "
         "definite=True the Gauss-Newton form Newton's method falls back to");

  py::class_<BackwardEulerStepper, Integrator, py::smart_holder>(m, "BackwardEuler",
      "Implicit (backward) Euler over every compliant constraint (distance, bending, volume, balloons, attachments, "
      "tethers and the other families), each step's incremental potential minimised by Newton's method (Baraff and "
      "Witkin 1998). newton_iterations = 0 (the default, method 'backward-euler'): to convergence (sparse LDLᵀ, "
      "Armijo line search, Gauss-Newton where the Hessian is indefinite), the same-step reference. "
      "newton_iterations = n > 0 (method 'implicit-euler'): the budgeted form, at most n Newton iterations per step, "
      "each solved by block-Jacobi preconditioned conjugate gradients on a fixed budget (the Gauss-Newton Hessian) or "
      "by the sparse LDLᵀ.")
      .def(py::init([](double dt, IntArg substeps, py::handle gravity, double rtol, IntArg max_iterations,
                       IntArg newton_iterations, const std::string& linear_solver, IntArg cg_iterations,
                       double cg_tolerance, bool line_search, const std::string& initial_guess,
                       double contact_stiffness) {
             BackwardEulerSettings s;
             s.dt = dt;
             s.substeps = in_range<int>(substeps, "substeps", 1, kMaxSubsteps);
             s.gravity = to_vec3(gravity, "gravity");
             s.rtol = rtol;
             s.max_iterations = in_range<int>(max_iterations, "max_iterations", 1, kMaxIterations);
             s.newton_iterations = in_range<int>(newton_iterations, "newton_iterations", 0, kMaxIterations);
             if (linear_solver == "direct") s.linear_solver = BackwardEulerSettings::Linear::Direct;
             else if (linear_solver == "cg") s.linear_solver = BackwardEulerSettings::Linear::ConjugateGradient;
             else throw InvalidArgument("linear_solver must be 'direct' or 'cg', got '" + linear_solver + "'");
             s.cg_iterations = in_range<int>(cg_iterations, "cg_iterations", 1, kMaxIterations);
             s.cg_tolerance = cg_tolerance;
             s.line_search = line_search;
             if (initial_guess == "inertia") s.initial_guess = BackwardEulerSettings::Guess::Inertia;
             else if (initial_guess == "previous") s.initial_guess = BackwardEulerSettings::Guess::Previous;
             else if (initial_guess == "lower") s.initial_guess = BackwardEulerSettings::Guess::Lower;
             else throw InvalidArgument("initial_guess must be 'inertia', 'previous' or 'lower', got '" + initial_guess + "'");
             s.contact_stiffness = contact_stiffness;
             return BackwardEulerStepper(s);
           }),
           py::kw_only(), py::arg("dt") = 1.0 / 60.0, py::arg("substeps") = 1, py::arg("gravity") = std::vector<double>{0, -9.81, 0},
           py::arg("rtol") = 1e-9, py::arg("max_iterations") = 100, py::arg("newton_iterations") = 0,
           py::arg("linear_solver") = "direct", py::arg("cg_iterations") = 100, py::arg("cg_tolerance") = 1e-4,
           py::arg("line_search") = true, py::arg("initial_guess") = "inertia", py::arg("contact_stiffness") = 1e4,
           "dt: s, the time a step advances, in `substeps` backward Euler steps of dt/substeps. gravity: m/s². rtol: "
           "the largest residual component at which a step stops, relative to the step's force scale, on top of the "
           "rounding floor. max_iterations: Newton iterations per step of the converged form. newton_iterations: 0 "
           "to convergence, n > 0 the budgeted form. linear_solver: 'direct' or 'cg' (budgeted form). cg_iterations, "
           "cg_tolerance: CG's budget per Newton iteration and its relative residual for stopping early. line_search: "
           "Armijo backtracking (the converged form needs it). initial_guess: 'inertia' (x̃), 'previous' (xⁿ) or 'lower' (the "
           "one with the lower incremental potential). "
           "contact_stiffness: κ, contacts with colliders as a penalty of stiffness κ m/h² (N/m).")
      .def("step", [](BackwardEulerStepper& s, const Model& model, State& state, IntArg steps_arg, py::object interrupt) {
        step_interruptibly(s, model, state, in_range<std::int64_t>(steps_arg, "steps", 0, kMaxInt64), interrupt);
      }, py::arg("model"), py::arg("state"), py::arg("steps") = 1, py::arg("interrupt") = py::none(),
         "Advances state by `steps` steps of dt (the GIL released meanwhile; `interrupt`, a callable asked between "
         "steps, returning True stops it, the state left at the end of the last completed step).")
      .def_property_readonly("substeps", [](const BackwardEulerStepper& s) { return s.settings().substeps; })
      .def_property_readonly("rtol", [](const BackwardEulerStepper& s) { return s.settings().rtol; })
      .def_property_readonly("max_iterations", [](const BackwardEulerStepper& s) { return s.settings().max_iterations; })
      .def_property_readonly("linear_solver", [](const BackwardEulerStepper& s) {
        return s.settings().linear_solver == BackwardEulerSettings::Linear::Direct ? "direct" : "cg";
      })
      .def_property_readonly("cg_iterations", [](const BackwardEulerStepper& s) { return s.last().cg_iterations; },
           "conjugate-gradient iterations of the last step, in all (budgeted form with linear_solver 'cg')")
      .def_property_readonly("gravity", [](const BackwardEulerStepper& s) { return vec3_array(s.settings().gravity); }, "m/s²")
      .def_property_readonly("newton_iterations", [](const BackwardEulerStepper& s) { return s.last().newton_iterations; },
           "Newton iterations of the last step")
      .def_property_readonly("residual", [](const BackwardEulerStepper& s) { return s.last().residual; },
           "N, the last step's largest residual component at the end")
      .def_property_readonly("residual_norm", [](const BackwardEulerStepper& s) { return s.last().residual_norm; },
           "N, its 2-norm")
      .def_property_readonly("tolerance", [](const BackwardEulerStepper& s) { return s.last().tolerance; },
           "N, the bound the last step's residual met")
      .def_property_readonly("definiteness_fixes", [](const BackwardEulerStepper& s) { return s.last().definiteness_fixes; },
           "Newton steps of the last step that took the Gauss-Newton form or a shift")
      .def_property_readonly("line_search_halvings", [](const BackwardEulerStepper& s) { return s.last().line_search_halvings; })
      .def_property_readonly("history", [](const BackwardEulerStepper& s) {
        const auto& h = s.last().history;
        return py::array_t<double>(static_cast<py::ssize_t>(h.size()), h.data());
      }, "N, the last step's largest residual component before each Newton step and at the end")
      .def_property_readonly("max_residual", &BackwardEulerStepper::max_residual, "N, over all steps so far")
      .def_property_readonly("total_iterations", &BackwardEulerStepper::total_iterations, "Newton iterations, all steps")
      .def_property_readonly("self_collision", [](const BackwardEulerStepper& s) { return self_collision_dict(s.self_collision()); },
           kSelfCollisionDoc);
}

}  // namespace csb::python
