// csb — Small Steps (Macklin, Storey, Lu, Terdiman, Chentanez, Jeschke and Müller 2019): XPBD with
// many sub-steps of one iteration each; MethodOptions::iterations is not read.
#include "csb/methods/registry.hpp"

namespace csb {

MethodInfo small_steps_method() {
  MethodInfo m;
  m.name = "small-steps";
  m.label = "XPBD, small steps";
  m.source = "Macklin et al. 2019";
  m.reads = "compliance";
  m.iterates = false;
  m.pbd = Method::Xpbd;
  m.make = [](const MethodOptions& o) {
    PbdSettings s;
    s.method = Method::Xpbd, s.dt = o.dt, s.substeps = o.substeps, s.iterations = 1, s.gravity = o.gravity;
    return std::make_unique<PbdStepper>(s);
  };
  return m;
}

}  // namespace csb
