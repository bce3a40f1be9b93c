// csb — Projective Dynamics (Bouaziz, Martin, Liu, Kavan and Pauly 2014, "Projective Dynamics:
// Fusing Constraint Projections for Fast Simulation"), optionally accelerated by the Chebyshev
// semi-iterative method (Wang 2015, "A Chebyshev Semi-Iterative Approach for Accelerating
// Projective and Position-based Dynamics").
//
// Each sub-step h = dt/substeps minimises the incremental potential of backward Euler
// (csb/implicit_euler.hpp) with every constraint's potential replaced by a projective one
// (Bouaziz et al. 2014, Eq. 6-9):
//
//   E(x) = Σ_i m_i |x_i - x̃_i|²/(2h²) + Σ_j (w_j/2) |A_j S_j x - p_j|²,   x̃ = xⁿ + h vⁿ + h² g,
//
// p_j the projection of A_j S_j x onto constraint j's set. Local/global alternation: the local
// step projects every constraint at the current positions (independent, in parallel), the global
// step solves (M/h² + Σ w_j S_jᵀA_jᵀA_jS_j) x = M x̃/h² + Σ w_j S_jᵀA_jᵀ p_j. Every A_j here acts
// on each coordinate alike (A_j ⊗ I₃), so the matrix is L ⊗ I₃ with L scalar over the dynamic
// particles: L is factored once per model and sub-step length (sparse Cholesky, Eigen's
// SimplicialLLT) and each iteration solves it for three right-hand sides. Pinned particles
// (inverse mass 0) are not unknowns: their terms move to the right-hand side. vⁿ⁺¹ = (x - xⁿ)/h.
//
// The materials, from each constraint's compliance α (the same as every other method's):
//   distance (stretch, springs): A x = x_a - x_b, p = L (x_a - x_b)/|x_a - x_b|, w = 1/α, so that
//     (w/2)|e - p|² = (|e| - L)²/(2α): backward Euler's spring exactly. An inequality (sense +1:
//     |e| >= L, -1: |e| <= L) projects to p = e while satisfied (no force at that iterate).
//   attachment: A = the particle's selection, p = the target, w = 1/α: exact.
//   bending (C = θ - θ0), tet volume (C = V - V0), balloons and the constraint families: A =
//     the centring operator on the constraint's particles (y_i = x_i - mean x, translation
//     invariant, AᵀA = A), p = a point of {C = 0} near the centred positions y, reached by
//     Gauss-Newton steps with equal weights, y ← y - C ∇C/|∇C|² (at most kProjectionSteps, until
//     |C| <= 1e-9 of its start; a unilateral family only while violated), and w = |∇C|²/α with
//     ∇C at the rest positions. Near the set, |y - p| ≈ |C|/|∇C|, so (w/2)|y - p|² ≈ C²/(2α):
//     this is first order only. The projective energy differs from C²/(2α) by the factor
//     |∇C(rest)|²/|∇C(x)|² and by terms of higher order in C, so PD's converged step is close to,
//     not equal to, backward Euler's on models with bending, volumes or families.
//   balloons (C = V - pressure V0 over a closed surface): the generic form over the surface's
//     particles. Its AᵀA = I - 11ᵀ/n is dense over the surface, but the dense part is rank one per
//     balloon: L = L_s + U D Uᵀ, L_s sparse and factored, L⁻¹ applied by the Woodbury identity.
// Contacts with the colliders are generated once per sub-step as the implicit methods' are
// (collision/penalty.hpp) and held by projection: after each global solve a particle past its
// contact's plane is moved onto it, and one inside an analytic collider that no contact foresaw
// (dragged there by its neighbours) out to its surface, so the constant matrix stays factored;
// friction and restitution follow the step (PenaltyContacts::finish_projected). Hard constraints (α = 0: no
// finite weight) are refused, as BackwardEulerStepper does; self-collision is the layer after each
// sub-step's solve (ImplicitSelfCollision, implicit_euler.hpp).
//
// Chebyshev (Wang 2015, Eq. 11-12 and his Algorithm 1 for PD with a direct global solve): with
// q̂ the plain iteration's result from q⁽ᵏ⁾,
//
//   ω = 1 (k < S),   2/(2 - ρ²) (k = S),   4/(4 - ρ² ω_prev) (k > S),
//   q⁽ᵏ⁺¹⁾ = ω (γ (q̂ - q⁽ᵏ⁾) + q⁽ᵏ⁾ - q⁽ᵏ⁻¹⁾) + q⁽ᵏ⁻¹⁾,
//
// S the delay, γ the under-relaxation, ρ the spectral radius of the plain iteration. ρ is a setting
// or, when it is 0 (the default), measured each sub-step from the S plain (relaxed) iterations
// before the acceleration starts: their updates d_k = q⁽ᵏ⁺¹⁾ - q⁽ᵏ⁾ follow d_{k+1} ≈ G d_k with G
// the relaxed iteration's linearisation, self-adjoint in the inner product of L; the largest Ritz
// value μ < 1 of G on the updates' Krylov space (Rayleigh-Ritz, as Lanczos estimates an extreme
// eigenvalue) approaches G's spectral radius from below, much faster than the ratio of update
// norms (the power method) does, and ρ = 1 - (1 - μ)/γ undoes the relaxation. Below the true
// value (where the iteration is linear) is the side Wang finds safe: too large a ρ makes the
// iteration oscillate. A measurement
// outside (0, 1) leaves that sub-step unaccelerated (ω = 1).
//
// Threads: the local step's constraints are split in fixed chunks that the threads take; each
// constraint writes its own slots of the right-hand side, which each particle then gathers in a
// fixed order (a CSR built with the factorisation). The global solve is serial. The result does
// not depend on the thread count.
#pragma once

#include "csb/collision/penalty.hpp"
#include "csb/implicit_euler.hpp"

#include "csb/integrator.hpp"
#include "csb/solver/team.hpp"
#include "csb/use_guard.hpp"

#include <cstdint>
#include <memory>
#include <vector>

namespace csb {

struct ProjectiveDynamicsSettings {
  Real dt = 1.0 / 60.0;              // s, > 0
  int substeps = 1;                  // sub-steps of dt/substeps per step, >= 1
  int iterations = 10;               // local/global iterations per sub-step, >= 1
  Vec3 gravity = Vec3(0, -9.81, 0);  // m/s²
  bool chebyshev = false;            // Wang 2015's acceleration
  // Dimensionless, the plain iteration's spectral radius ρ in (0, 1); 0: measured each sub-step.
  Real spectral_radius = 0;
  int chebyshev_delay = 10;          // S, plain iterations before the acceleration; Wang's PD value, >= 0
  Real relaxation = 0.9;             // γ in (0, 1], Wang's under-relaxation for PD
  int threads = 0;                   // threads of the local step, >= 0; 0: automatic
  bool record_residuals = false;     // record the backward-Euler residual after each iteration
};

struct ProjectiveDynamicsStats {
  std::int64_t factorizations = 0;  // factorisations of L so far (one per model and sub-step length)
  double factorization_time = 0;    // s, wall time of all of them
  double last_factorization_time = 0;  // s, wall time of the latest
  Real spectral_radius = 0;         // ρ the last sub-step used (0: not accelerated)
  Real measured_spectral_radius = 0;  // the last measurement of ρ, used or not (spectral_radius 0)
  int threads_used = 1;             // of the last step's local steps
  // N, the largest backward-Euler residual component of the last sub-step: at its start
  // (x = xⁿ + h vⁿ + h² g, before any iteration) and after each iteration (record_residuals only).
  std::vector<Real> residual_history;
};

class ProjectiveDynamicsStepper final : public Integrator {
 public:
  // Throws InvalidArgument naming a setting out of range.
  explicit ProjectiveDynamicsStepper(const ProjectiveDynamicsSettings& settings);
  ~ProjectiveDynamicsStepper() override;
  ProjectiveDynamicsStepper(const ProjectiveDynamicsStepper&);
  ProjectiveDynamicsStepper& operator=(const ProjectiveDynamicsStepper&);

  std::string name() const override { return "projective-dynamics"; }
  Real dt() const override { return settings_.dt; }
  const ProjectiveDynamicsSettings& settings() const { return settings_; }
  const UseGuard& use_guard() const { return use_; }
  // InvalidArgument for a model PD cannot step (hard constraints, nothing that moves) or a state of another size or not finite; SimulationError
  // naming the step when a position becomes non-finite, the state left at the end of the last
  // completed step. One thread at a time (use_guard.hpp).
  void step(const Model& model, State& state, std::int64_t steps = 1,
            const std::function<bool()>& interrupt = {}) override;

  const ProjectiveDynamicsStats& stats() const { return stats_; }
  // What self-collision did in the last sub-step (ImplicitSelfCollision).
  const SelfCollisionCounts& self_collision() const { return self_collision_.counts(); }

 private:
  struct Cache;  // the terms, L's factorisation and the gather CSR of one model and sub-step length
  void solve_one(const Model& model, State& state, Real h, int sub);

  ProjectiveDynamicsSettings settings_;
  std::unique_ptr<Cache> cache_;
  TeamHandle team_;  // the local step's threads
  UseGuard use_;
  ProjectiveDynamicsStats stats_;
  PenaltyContacts contacts_;  // the sub-step's contacts with the colliders
  ImplicitSelfCollision self_collision_;
};

}  // namespace csb
