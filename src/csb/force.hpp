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
// network for h < 2/ω_max, ω_max² the largest eigenvalue of M⁻¹K. They have no contacts: a model
// with colliders or self-collision is refused by name (InvalidArgument) rather than stepped as if
// it had none.
#pragma once

#include "csb/integrator.hpp"
#include "csb/reference.hpp"
#include "csb/use_guard.hpp"

#include <functional>
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

class ForceStepper : public Integrator {
 public:
  explicit ForceStepper(const ForceSettings& settings);
  const ForceSettings& settings() const { return settings_; }
  std::string name() const override;  // "explicit-euler", "symplectic-euler" or "velocity-verlet"
  Real dt() const override { return settings_.dt; }

  // Advances `state` by `steps` steps of dt. Pinned particles stay where `state` has them. One
  // thread at a time (use_guard.hpp).
  // Throws InvalidArgument for a hard constraint (compliance 0), SimulationError naming the
  // step and particle when a position becomes non-finite (the state is then left at the last
  // finite sub-step).
  // Advances `steps` steps of dt. A request beyond a year's work (memory_budget.hpp) is refused
  // before the first; `interrupt`, if given, is asked between steps whether to stop (then
  // Interrupted is thrown, the state left at the end of the last completed step).
  void step(const Model& model, State& state, std::int64_t steps = 1,
            const std::function<bool()>& interrupt = {}) override;

  // Evaluations of the network's right-hand side since construction: one per sub-step for every
  // method (undamped velocity Verlet reuses a(x') as the next sub-step's a(x)); two per sub-step
  // for velocity Verlet with damping or drag, whose a(x', v') cannot be a(x', v + h a).
  std::int64_t force_evaluations() const { return force_evaluations_; }

 private:
  ForceSettings settings_;
  std::int64_t force_evaluations_ = 0;
  // Velocity Verlet's last a(x') and what it was evaluated for: the model, the whole state it
  // belongs to (positions, velocities, time), bit for bit. Any other state misses.
  struct Cache {
    bool valid = false;
    std::uint64_t model_id = 0;
    Positions x, v;
    Real t = 0;
    std::vector<Real> accel;  // m/s², 3 per dynamic particle
  } cache_;
  UseGuard use_;  // one thread at a time (use_guard.hpp)
};

}  // namespace csb
