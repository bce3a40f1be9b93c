// csb — Position Based Dynamics, Müller, Heidelberger, Hennix, Ratcliff 2007, Algorithm 1.
//
// One call to step() advances the state by dt; it runs `substeps` sub-steps of h = dt/substeps,
// each the whole of Algorithm 1:
//
//   (5)  v <- v + h w f_ext          gravity, on particles with w > 0
//   (6)  dampVelocities(v)           §3.5, per group, leaves rigid motion untouched
//   (7)  p <- x + h v                explicit Euler prediction
//   (9-11) `iterations` Gauss-Seidel sweeps of projectConstraints: every distance, bending and
//          attachment constraint in turn, each seeing the corrections of those before it
//   (12-15) v <- (p - x)/h,  x <- p
//
// Time step, substeps and iterations are three different things and keep three names.
#pragma once

#include "csb/model.hpp"

#include <cstdint>

namespace csb {

struct PbdSettings {
  Real dt = 1.0 / 60.0;                 // s, the time one step() advances; > 0
  int substeps = 1;                     // sub-steps of dt/substeps per step; >= 1
  int iterations = 10;                  // Gauss-Seidel sweeps per sub-step; >= 1
  Vec3 gravity = Vec3(0, -9.81, 0);     // m/s^2
  // Müller 2007 §3.5 k_damping in [0, 1]: the fraction of each particle's velocity deviation
  // from its group's rigid motion removed per sub-step (0: undamped).
  Real damping = 0;
  // Müller 2007 §3.3: project with k' = 1 - (1 - k)^(1/iterations), so that the stiffness
  // felt after all iterations does not depend on their number.
  bool stiffness_correction = true;
};

// Throws InvalidArgument naming the first impossible setting.
void validate(const PbdSettings& settings);

class PbdStepper {
 public:
  explicit PbdStepper(const PbdSettings& settings);
  const PbdSettings& settings() const { return settings_; }

  // Advances `state` by `steps` steps of settings().dt. Throws SimulationError naming the step
  // and particle if a position becomes non-finite; the state is then left at the end of the
  // last sub-step whose positions were all finite.
  void step(const Model& model, State& state, std::int64_t steps = 1);

  // Constraint projections one step performs on this model.
  std::int64_t projections_per_step(const Model& model) const;

 private:
  void prepare(const Model& model);
  void substep(const Model& model, State& state, Real h);
  void damp_velocities(const Model& model, State& state) const;

  PbdSettings settings_;
  // Per-model workspace, rebuilt when the model changes.
  std::uint64_t model_id_ = 0;
  Positions p_;                          // predicted positions
  std::vector<Real> k_distance_, k_bending_, k_attachment_;  // stiffness used per iteration
};

// The stiffness used in each of n iterations so that n of them act like one of stiffness k:
// 1 - (1 - k)^(1/n) (Müller 2007 §3.3).
Real corrected_stiffness(Real k, int iterations);

}  // namespace csb
