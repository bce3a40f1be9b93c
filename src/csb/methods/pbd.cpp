// csb — Position Based Dynamics (Müller, Heidelberger, Hennix and Ratcliff 2007): the pipeline of
// step/ with each constraint projected by its stiffness k ∈ [0, 1], corrected for the iterations.
#include "csb/methods/registry.hpp"

#include <cmath>

namespace csb {

// The stiffness used in each of n iterations so that n of them act like one of stiffness k
// (Müller 2007 §3.3): 1 - (1 - k)^(1/n).
Real corrected_stiffness(Real k, int iterations) {
  if (k >= 1) return 1;
  return 1 - std::pow(1 - k, 1.0 / iterations);
}

MethodInfo pbd_method() {
  MethodInfo m;
  m.name = "pbd";
  m.label = "PBD";
  m.source = "Müller, Heidelberger, Hennix and Ratcliff 2007";
  m.reads = "stiffness";
  m.iterates = true;
  m.pbd = Method::Pbd;
  m.make = [](const MethodOptions& o) {
    PbdSettings s;
    s.method = Method::Pbd, s.dt = o.dt, s.substeps = o.substeps, s.iterations = o.iterations, s.gravity = o.gravity;
    return std::make_unique<PbdStepper>(s);
  };
  return m;
}

}  // namespace csb
