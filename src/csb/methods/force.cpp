// csb — the force-based integrators of the spring network (csb/force.hpp): the classic methods PBD was
// made to avoid, kept to show where they fail. They read each constraint's compliance as a spring.
#include "csb/methods/registry.hpp"

namespace csb {

namespace {

MethodInfo force_method(const char* name, const char* label, const char* source, ForceIntegrator integrator) {
  MethodInfo m;
  m.name = name;
  m.label = label;
  m.source = source;
  m.reads = "compliance";
  m.force = integrator;
  m.make = [integrator](const MethodOptions& o) {
    ForceSettings s;
    s.method = integrator, s.dt = o.dt, s.substeps = o.substeps, s.gravity = o.gravity;
    return std::make_unique<ForceStepper>(s);
  };
  return m;
}

}  // namespace

MethodInfo explicit_euler_method() {
  return force_method("explicit-euler", "explicit Euler", "Hairer, Lubich and Wanner 2006", ForceIntegrator::ExplicitEuler);
}
MethodInfo symplectic_euler_method() {
  return force_method("symplectic-euler", "symplectic Euler", "Hairer, Lubich and Wanner 2006",
                      ForceIntegrator::SymplecticEuler);
}
MethodInfo velocity_verlet_method() {
  return force_method("velocity-verlet", "velocity Verlet", "Swope, Andersen, Berens and Wilson 1982",
                      ForceIntegrator::VelocityVerlet);
}

}  // namespace csb
