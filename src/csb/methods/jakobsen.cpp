// csb — Jakobsen's "Advanced Character Physics" (2001): Verlet integration (the velocity kept in the
// previous positions) with relaxation of stiff sticks, read by their stiffness k.
#include "csb/methods/registry.hpp"

namespace csb {

MethodInfo jakobsen_method() {
  MethodInfo m;
  m.name = "jakobsen";
  m.aliases = {"verlet"};  // by its integrator's name
  m.label = "Jakobsen";
  m.source = "Jakobsen 2001";
  m.reads = "stiffness";
  m.iterates = true;
  m.pbd = Method::Jakobsen;
  m.make = [](const MethodOptions& o) {
    PbdSettings s;
    s.method = Method::Jakobsen, s.front_end = FrontEnd::Verlet, s.dt = o.dt, s.substeps = o.substeps,
    s.iterations = o.iterations, s.gravity = o.gravity;
    return std::make_unique<PbdStepper>(s);
  };
  return m;
}

}  // namespace csb
