// csb — Projective Dynamics (Bouaziz et al. 2014) with Wang 2015's optional Chebyshev
// acceleration (projective_dynamics.hpp): backward Euler's step with every constraint's potential
// replaced by a projective one, solved by local projections and a prefactored global solve. It
// reads each constraint's compliance (exactly a spring's potential for distance constraints and
// attachments, to first order for bending, volumes, balloons and the families), holds contacts with
// the colliders by projection, runs self-collision as the layer after each sub-step's solve, and
// refuses hard constraints.
#include "csb/methods/projective_dynamics/projective_dynamics.hpp"
#include "csb/methods/registry.hpp"

namespace csb {

MethodInfo projective_dynamics_method() {
  MethodInfo m;
  m.name = "projective-dynamics";
  m.aliases = {"pd"};
  m.label = "Projective Dynamics";
  m.source = "Bouaziz et al. 2014; Wang 2015";
  m.reads = "compliance";
  m.iterates = true;  // local/global iterations per sub-step
  m.settings = {
      {"chebyshev", "false", "Wang 2015's Chebyshev semi-iterative acceleration"},
      {"spectral_radius", "0", "the plain iteration's spectral radius ρ in (0, 1) for Chebyshev; 0: measured each "
                               "sub-step from the iterations before chebyshev_delay"},
      {"chebyshev_delay", "10", "S, plain iterations before the acceleration starts (Wang's value for PD), >= 0"},
      {"relaxation", "0.9", "γ in (0, 1], Chebyshev's under-relaxation (Wang's value for PD)"},
      {"threads", "0", "threads of the local step, >= 0; 0: automatic"},
      {"record_residuals", "false", "record the backward-Euler residual (N) after each iteration of a sub-step"},
  };
  m.make = [](const MethodOptions& o) -> std::unique_ptr<Integrator> {
    ProjectiveDynamicsSettings s;
    s.dt = o.dt, s.substeps = o.substeps, s.iterations = o.iterations, s.gravity = o.gravity;
    const MethodSettings& k = o.settings;
    s.chebyshev = k.boolean("chebyshev", s.chebyshev);
    s.spectral_radius = k.number("spectral_radius", s.spectral_radius, 0, 1);
    s.chebyshev_delay = static_cast<int>(k.integer("chebyshev_delay", s.chebyshev_delay, 0, 1'000'000));
    s.relaxation = k.number("relaxation", s.relaxation, 0, 1);
    s.threads = static_cast<int>(k.integer("threads", s.threads, 0, 1024));
    s.record_residuals = k.boolean("record_residuals", s.record_residuals);
    return std::make_unique<ProjectiveDynamicsStepper>(s);  // its constructor refuses ρ = 1 and γ = 0
  };
  return m;
}

}  // namespace csb
