// csb — backward Euler solved to convergence each step (csb/implicit_euler.hpp): the same-step
// reference every method's solver error is measured against. It reads each constraint's compliance
// as the potential C²/(2α) and refuses hard constraints.
#include "csb/implicit_euler.hpp"
#include "csb/methods/registry.hpp"

namespace csb {

MethodInfo backward_euler_method() {
  MethodInfo m;
  m.name = "backward-euler";
  m.aliases = {"implicit-euler"};
  m.label = "backward Euler (Newton)";
  m.source = "Baraff and Witkin 1998; Martin et al. 2011";
  m.reads = "compliance";
  m.make = [](const MethodOptions& o) -> std::unique_ptr<Integrator> {
    BackwardEulerSettings s;
    s.dt = o.dt, s.substeps = o.substeps, s.gravity = o.gravity;
    return std::make_unique<BackwardEulerStepper>(s);
  };
  return m;
}

}  // namespace csb
