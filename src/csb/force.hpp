// csb — force-based mass-spring integrators on the reference's spring network: the classic
// methods that PBD was made to avoid, kept to show where they fail.
//
// With a(x, v) = M⁻¹(-∇E(x) - D v) + g - β v from SpringNetwork (every constraint a spring of
// stiffness 1/α) and h = dt/substeps:
//   explicit Euler       x' = x + h v,          v' = v + h a(x, v)
//   symplectic Euler     v' = v + h a(x, v),    x' = x + h v'
//   velocity Verlet      x' = x + h v + h²/2 a,  v' = v + h/2 (a + a(x', v + h a))
// For an undamped spring of angular frequency ω, explicit Euler grows by sqrt(1 + (ωh)²) per
// step at any h; symplectic Euler and velocity (Störmer-)Verlet are stable for h < 2/ω, and a
// network for h < 2/ω_max, ω_max² the largest eigenvalue of M⁻¹K.
#pragma once

#include "csb/reference.hpp"

#include <memory>

namespace csb {

enum class ForceIntegrator { ExplicitEuler, SymplecticEuler, VelocityVerlet };

struct ForceSettings {
  ForceIntegrator method = ForceIntegrator::SymplecticEuler;
  Real dt = 1e-4;                    // s, per step; > 0
  int substeps = 1;                  // >= 1
  Vec3 gravity = Vec3(0, -9.81, 0);  // m/s²
  Real damping = 0;                  // N s/m, dashpot along each distance constraint
  Real drag = 0;                     // 1/s, force -drag m v on every particle
};

class ForceStepper {
 public:
  explicit ForceStepper(const ForceSettings& settings);
  const ForceSettings& settings() const { return settings_; }

  // Advances `state` by `steps` steps of dt. Pinned particles stay where `state` has them.
  // Throws InvalidArgument for a hard constraint (compliance 0), SimulationError naming the
  // step and particle when a position becomes non-finite (the state is then left at the last
  // finite sub-step).
  void step(const Model& model, State& state, std::int64_t steps = 1);

 private:
  ForceSettings settings_;
};

}  // namespace csb
