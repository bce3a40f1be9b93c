// csb — Vertex Block Descent (Chen, Liu, Yang and Yuksel 2024, "Vertex Block Descent", ACM TOG
// 43(4)): each sub-step of h = dt/substeps approximates the backward Euler step of
// csb/implicit_euler.hpp by block coordinate descent on its incremental potential
//
//   E(x) = Σ_i m_i |x_i - x̃_i|² / (2h²) + Σ_j C_j(x)² / (2α_j),   x̃ = xⁿ + h vⁿ + h² g,
//
// over every compliant constraint csb models (distance springs, their inequalities only while
// violated, dihedral bending, tet volumes, balloons, attachments, the constraint families), the
// same E as IncrementalPotential. One block is one vertex: with the other vertices held, vertex i
// takes one Newton step on E,
//
//   f_i = -m_i/h² (x_i - x̃_i) - Σ_{j∋i} (C_j/α_j) ∇_i C_j,   H_i = m_i/h² I + Σ_{j∋i} H_ij,
//   x_i += H_i⁻¹ f_i,
//
// H_ij positive semi-definite: a spring's exact 3x3 block with its geometric term clamped at 0,
// k (n nᵀ + max(0, C/l)(I - n nᵀ)); every other constraint's Gauss-Newton block ∇_iC ∇_iCᵀ/α,
// which is the exact block for tet volumes and balloons (V is linear in any single vertex, so
// ∂²V/∂x_i² = 0) and for bending its positive semi-definite part (the curvature term C ∇²θ
// dropped). A vertex whose det(H_i) is below 1e-30 of its diagonal's cube is skipped (the
// paper's safeguard; H_i ⪰ m_i/h² I makes it unreachable for finite positions); a non-finite
// f_i or H_i (constraint values that overflow) is a SimulationError. `iterations` sweeps over
// all vertices per sub-step.
//
// Vertices are swept colour by colour, as the paper's parallel sweep: no two vertices of a colour
// share a constraint (greedy first-fit on the vertex graph of every batch, deterministic), so a
// colour's vertices update at once on the team's threads, each writing only itself and reading
// only vertices of other colours: the bits do not depend on the thread count.
//
// Balloons (one constraint over a whole surface) are not in the colouring's graph, only their
// triangles' edges are: the vertices of one colour are then never in one triangle, so V is affine
// in their joint positions, V(x + Δ) = V(x) + Σ_{i in colour} ∇_iV·Δ_i exactly, and the colour's
// block problem couples them through the rank-one term k ∇V ∇Vᵀ alone. It is solved exactly by
// Sherman-Morrison: with D the block diagonal of the other terms, u = D⁻¹f and w = D⁻¹∇V over the
// colour's vertices of the balloon, Δ = u - w k (∇V·u)/(1 + k ∇V·w), the two sums taken in vertex
// order (deterministic). A particle may belong to one balloon.
//
// Constraint families (constraints/family.hpp) are evaluated batch-wide (FamilyBatch::evaluate,
// one virtual call per family and colour: the interface has no per-constraint call), at the start
// of each colour that has a vertex in the family; within a colour no vertex moves another's
// constraint, so these values are those of the vertex's own update.
//
// Initialisation (§3.6): "adaptive" x = xⁿ + h vⁿ + h² ã, ã = ĝ clamp(aⁿ·ĝ, 0, |g|) with aⁿ the
// vertex's acceleration over the previous sub-step ((vⁿ - vⁿ⁻¹)/h; without one, a stepper's
// first step or a state it did not leave, ã = g); "inertia" x = x̃; "previous" x = xⁿ.
// Acceleration (§3.8, Chebyshev semi-iteration after Wang 2015): after sweep n,
// x⁽ⁿ⁾ = ω_n (x̄⁽ⁿ⁾ - x⁽ⁿ⁻²⁾) + x⁽ⁿ⁻²⁾, ω_1 = 1, ω_2 = 2/(2 - ρ²), ω_n = 4/(4 - ρ² ω_{n-1}),
// with ρ the estimated spectral radius (`acceleration`; 0: off).
//
// vⁿ⁺¹ = (x - xⁿ)/h; pinned particles (inverse mass 0) stay where the state has them, at zero
// velocity. Contacts with the colliders are the implicit methods' penalty (collision/penalty.hpp),
// generated once per sub-step from xⁿ towards x̃: each adds (k/2) min(C, 0)² to its vertex's block,
// k n nᵀ to its Hessian while active (the paper's penalty contact), with friction and restitution
// after the sub-step. Self-collision is the layer after each sub-step's solve
// (ImplicitSelfCollision, implicit_euler.hpp).
#pragma once

#include "csb/collision/penalty.hpp"
#include "csb/integrator.hpp"
#include "csb/implicit_euler.hpp"
#include "csb/solver/team.hpp"
#include "csb/use_guard.hpp"

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace csb {

struct VbdSettings {
  enum class Initialization { Adaptive, Inertia, Previous };
  Real dt = 1.0 / 60.0;              // s, > 0
  int substeps = 1;                  // sub-steps of dt/substeps per step, >= 1
  int iterations = 10;               // VBD sweeps over all vertices per sub-step, >= 1
  Vec3 gravity = Vec3(0, -9.81, 0);  // m/s²
  Initialization initialization = Initialization::Adaptive;
  Real acceleration = 0;             // ρ of the Chebyshev acceleration, dimensionless, in [0, 1); 0: off
  int threads = 0;                   // threads of a colour's updates, >= 0; 0: automatic (free cores, at most Model::num_parts)
  // κ: contacts with colliders as a penalty of stiffness κ m/h² (collision/penalty.hpp), > 0.
  Real contact_stiffness = PenaltyContacts::kDefaultStiffness;
};

const char* initialization_name(VbdSettings::Initialization i);
// "adaptive", "inertia" or "previous"; InvalidArgument naming `initialization` otherwise.
VbdSettings::Initialization parse_initialization(const std::string& name);

class VbdStepper final : public Integrator {
 public:
  // Throws InvalidArgument naming a setting out of range.
  explicit VbdStepper(const VbdSettings& settings);
  ~VbdStepper() override;
  // A copy has the settings and starts without per-model data (nor the adaptive history).
  VbdStepper(const VbdStepper&);
  VbdStepper& operator=(const VbdStepper&);

  std::string name() const override { return "vbd"; }
  Real dt() const override { return settings_.dt; }
  const VbdSettings& settings() const { return settings_; }
  const UseGuard& use_guard() const { return use_; }
  // Throws InvalidArgument for a hard constraint, a particle in two
  // balloons, states of the wrong size or non-finite; SimulationError naming the step and the
  // particle when a position becomes non-finite (the state left at the end of the last step).
  void step(const Model& model, State& state, std::int64_t steps = 1,
            const std::function<bool()>& interrupt = {}) override;

  // The backward-Euler residual (N) of the last sub-step this stepper took on `model`
  // (backward_euler_residual from its start to its end). InvalidArgument before a step on it.
  Residual last_residual(const Model& model) const;
  int threads_used() const { return threads_used_; }
  Index num_colours() const;  // of the last model stepped (0 before a step)
  // What self-collision did in the last sub-step (ImplicitSelfCollision).
  const SelfCollisionCounts& self_collision() const { return self_collision_.counts(); }

  struct Plan;  // per model: colouring, each particle's constraints, scratch (vbd.cpp)

 private:
  void substep(const Model& model, State& state, Plan& plan, Real h);

  VbdSettings settings_;
  std::unique_ptr<Plan> plan_;
  TeamHandle team_;
  UseGuard use_;
  int threads_used_ = 1;
  bool spin_ = false;  // the team's threads may spin at the barriers (free cores for each)
  ImplicitSelfCollision self_collision_;
};

}  // namespace csb
