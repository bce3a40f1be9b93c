// csb — implicit (backward) Euler with Newton's method (csb/implicit_euler.hpp), after Baraff and
// Witkin 1998, in its two practices. It reads each constraint's compliance as the potential
// C²/(2α) and refuses hard constraints.
//   backward-euler   each step solved to convergence (sparse LDLᵀ, line search): the same-step
//                    reference every method's solver error is measured against;
//   implicit-euler   the budgeted form: `iterations` Newton iterations per step, each a linear solve
//                    by block-Jacobi preconditioned conjugate gradients on a fixed budget (or the
//                    sparse LDLᵀ), a method on the accuracy-versus-cost chart. Its CG budget, 100
//                    iterations (stopping once the residual has fallen by 1e-4): on the studies'
//                    12 x 12 hanging cloth one Newton iteration a step ended 0.77 m from the
//                    continuous reference after 1 s with 20 and 50 CG iterations, 0.052 m with 100
//                    and 0.051 m with a direct solve (validation/implicit_claims.py). Newton starts from
//                    whichever of the inertial prediction x̃ and xⁿ has the lower incremental
//                    potential. A truncated CG resolves the stiff, local part of a step first: from
//                    xⁿ, 20 CG iterations left an 8 x 8 cloth (springs of 0.01 m/N) 0.95 m behind its
//                    swing after 0.5 s, where from x̃, which holds the slow, global motion, it was
//                    8 mm off; but x̃ stretches a stiff chain's links along their tangents (1e-8 m/N:
//                    kinetic energy spikes of 6e5 J at dt = 0.1 s from x̃, none from xⁿ). The lower
//                    E picks x̃ for the first and xⁿ for the second.
#include "csb/implicit_euler.hpp"
#include "csb/methods/registry.hpp"

namespace csb {

MethodInfo backward_euler_method() {
  MethodInfo m;
  m.name = "backward-euler";
  m.label = "backward Euler (Newton, converged)";
  m.source = "Baraff and Witkin 1998; Martin et al. 2011";
  m.reads = "compliance";
  m.settings = {
      {"rtol", "1e-9", "the largest residual component at which a step stops, relative to the step's force scale, > 0"},
      {"max_iterations", "100", "Newton iterations per step before a SimulationError, >= 1"},
      {"contact_stiffness", "1e4", "κ: contacts with colliders as a penalty of stiffness κ m/h² (N/m), > 0"},
  };
  m.make = [](const MethodOptions& o) -> std::unique_ptr<Integrator> {
    BackwardEulerSettings s;
    s.dt = o.dt, s.substeps = o.substeps, s.gravity = o.gravity;
    s.rtol = o.settings.number("rtol", s.rtol, 0, 1);
    s.max_iterations = static_cast<int>(o.settings.integer("max_iterations", s.max_iterations, 1, 1'000'000));
    s.contact_stiffness = o.settings.number("contact_stiffness", s.contact_stiffness, 1e-300, 1e300);
    return std::make_unique<BackwardEulerStepper>(s);
  };
  return m;
}

MethodInfo implicit_euler_method() {
  MethodInfo m;
  m.name = "implicit-euler";
  m.label = "implicit Euler (Newton-PCG)";
  m.source = "Baraff and Witkin 1998";
  m.reads = "compliance";
  m.iterates = true;  // iterations: Newton iterations per step
  m.settings = {
      {"linear_solver", "'cg'", "'cg' (block-Jacobi preconditioned conjugate gradients) or 'direct' (sparse LDLᵀ)"},
      {"cg_iterations", "100", "conjugate-gradient iterations per Newton iteration at most, >= 1"},
      {"cg_tolerance", "1e-4", "CG stops once its residual has fallen by this factor, in [0, 1)"},
      {"line_search", "true", "Armijo backtracking on the incremental potential; false: full Newton steps"},
      {"initial_guess", "'lower'", "where Newton starts: 'inertia' (x̃ = xⁿ + h vⁿ + h² g), 'previous' (xⁿ, "
                                   "Baraff and Witkin's linearisation; a particle whose prediction is past a "
                                   "contact plane starts at x̃) or 'lower' (the one of the two with the lower "
                                   "incremental potential)"},
      {"rtol", "1e-9", "a step stops before its budget once the residual is below rtol times its force scale, > 0"},
      {"contact_stiffness", "1e4", "κ: contacts with colliders as a penalty of stiffness κ m/h² (N/m), > 0"},
  };
  m.make = [](const MethodOptions& o) -> std::unique_ptr<Integrator> {
    BackwardEulerSettings s;
    s.dt = o.dt, s.substeps = o.substeps, s.gravity = o.gravity;
    s.newton_iterations = o.iterations;
    s.linear_solver = o.settings.choice("linear_solver", "cg", {"cg", "direct"}) == "cg"
                          ? BackwardEulerSettings::Linear::ConjugateGradient
                          : BackwardEulerSettings::Linear::Direct;
    s.cg_iterations = static_cast<int>(o.settings.integer("cg_iterations", s.cg_iterations, 1, 1'000'000));
    s.cg_tolerance = o.settings.number("cg_tolerance", s.cg_tolerance, 0, 0.999999);
    s.line_search = o.settings.boolean("line_search", true);
    const std::string guess = o.settings.choice("initial_guess", "lower", {"lower", "inertia", "previous"});
    s.initial_guess = guess == "previous" ? BackwardEulerSettings::Guess::Previous
                      : guess == "inertia" ? BackwardEulerSettings::Guess::Inertia
                                           : BackwardEulerSettings::Guess::Lower;
    s.rtol = o.settings.number("rtol", s.rtol, 0, 1);
    s.contact_stiffness = o.settings.number("contact_stiffness", s.contact_stiffness, 1e-300, 1e300);
    return std::make_unique<BackwardEulerStepper>(s);
  };
  return m;
}

}  // namespace csb
