// csb — Extended Position Based Dynamics (Macklin, Müller and Chentanez 2016): the pipeline of step/
// with a Lagrange multiplier per constraint and its compliance α (SI), set to zero each sub-step.
#include "csb/methods/registry.hpp"

namespace csb {

MethodInfo xpbd_method() {
  MethodInfo m;
  m.name = "xpbd";
  m.label = "XPBD";
  m.source = "Macklin, Müller and Chentanez 2016";
  m.reads = "compliance";
  m.iterates = true;
  m.pbd = Method::Xpbd;
  m.make = [](const MethodOptions& o) {
    PbdSettings s;
    s.method = Method::Xpbd, s.dt = o.dt, s.substeps = o.substeps, s.iterations = o.iterations, s.gravity = o.gravity;
    return std::make_unique<PbdStepper>(s);
  };
  return m;
}

}  // namespace csb
