// csb — the step-level interface every method implements: the built-in position-based steppers
// (PbdStepper: PBD, XPBD, Jakobsen), the force-based integrators (ForceStepper) and a user's own
// method, in C++ or, through the Python binding's trampoline, in Python. The scene runner, the
// viewer and the studies take an Integrator and nothing more specific.
//
// Like Newton's solvers it advances a State over an immutable Model; unlike them it advances the
// state in place (csb's State is the numpy-visible pool of positions and velocities).
#pragma once

#include "csb/model.hpp"

#include <cstdint>
#include <functional>
#include <string>

namespace csb {

class Integrator {
 public:
  virtual ~Integrator() = default;

  // A short name that says which method this is ("pbd", "xpbd", "symplectic_euler", a user's own).
  virtual std::string name() const = 0;
  // s: the time one step() advances (> 0).
  virtual Real dt() const = 0;
  // Advances `state` of `model` by `steps` steps of dt(): positions, velocities and state.t
  // (and state.step, the steps taken). `interrupt`, if given, may be asked between steps whether
  // to stop; a method that stops then throws Interrupted, the state left at the end of a step.
  virtual void step(const Model& model, State& state, std::int64_t steps = 1,
                    const std::function<bool()>& interrupt = {}) = 0;
};

}  // namespace csb
