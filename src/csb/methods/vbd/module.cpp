// csb — Vertex Block Descent (Chen, Liu, Yang and Yuksel 2024; csb/methods/vbd/vbd.hpp): block
// coordinate descent, vertex by vertex and colour by colour, on the backward Euler step's
// incremental potential. It reads each constraint's compliance as the potential C²/(2α), takes
// contacts with the colliders as a penalty, runs self-collision as the layer after each
// sub-step's solve, and refuses hard constraints.
#include "csb/methods/registry.hpp"
#include "csb/methods/vbd/vbd.hpp"

namespace csb {

MethodInfo vbd_method() {
  MethodInfo m;
  m.name = "vbd";
  m.aliases = {"vertex-block-descent"};
  m.label = "VBD";
  m.source = "Chen, Liu, Yang and Yuksel 2024";
  m.reads = "compliance";
  m.iterates = true;
  m.settings = {
      {"initialization", "'adaptive'",
       "the sub-step's first guess: 'adaptive' (xⁿ + h vⁿ + h² ã, ã the previous sub-step's acceleration along "
       "gravity clamped to [0, |g|]), 'inertia' (x̃ = xⁿ + h vⁿ + h² g) or 'previous' (xⁿ)"},
      {"acceleration", "0.0",
       "ρ of the Chebyshev acceleration over the sweeps, dimensionless, in [0, 1); 0: off"},
      {"threads", "0", "threads of a colour's vertex updates, >= 0; 0: automatic; the result does not depend on it"},
      {"contact_stiffness", "1e4", "κ: contacts with colliders as a penalty of stiffness κ m/h² (N/m), > 0"},
  };
  m.make = [](const MethodOptions& o) -> std::unique_ptr<Integrator> {
    VbdSettings s;
    s.dt = o.dt, s.substeps = o.substeps, s.iterations = o.iterations, s.gravity = o.gravity;
    // Every key read, so that finish() lists them all.
    s.initialization = parse_initialization(o.settings.choice("initialization", "adaptive",
                                                              {"adaptive", "inertia", "previous"}));
    s.acceleration = o.settings.number("acceleration", 0.0, 0.0, 1.0);
    s.threads = static_cast<int>(o.settings.integer("threads", 0, 0, 1024));
    s.contact_stiffness = o.settings.number("contact_stiffness", s.contact_stiffness, 1e-300, 1e300);
    return std::make_unique<VbdStepper>(s);  // refuses acceleration 1 (ρ < 1)
  };
  return m;
}

}  // namespace csb
