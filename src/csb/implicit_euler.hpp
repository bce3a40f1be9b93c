// csb — the same-step reference: backward (implicit) Euler at the study's time step, each step
// solved to convergence by Newton's method, over the spring network of every compliant constraint
// (csb/reference.hpp: distance springs and inequalities, bending, tet volumes, balloons,
// attachments and the constraint families such as tethers).
//
// With the inertial positions x̃ = xⁿ + h vⁿ + h² g, a step's positions minimise the incremental
// potential (Macklin, Müller and Chentanez 2016, Eq. 4-9; Martin et al. 2011)
//
//   E(x) = Σ_i m_i |x_i - x̃_i|² / (2h²) + U(x),   U = Σ_j C_j(x)² / (2α_j),
//
// and vⁿ⁺¹ = (x - xⁿ)/h. Its gradient, the backward-Euler residual (N),
//
//   r_i = m_i (x_i - x̃_i)/h² - f_i(x),   f = -∇U,
//
// vanishes at the solution. XPBD, PBD and the other methods approximate this step; the residual of
// the positions they reach (backward_euler_residual) is their solver error at that step, the
// convergence measure of Macklin et al. 2016 and its successors.
//
// Newton's method: H = M/h² + ∇²U (the network's analytic stiffness, bending's curvature by central
// differences of its gradient, balloons' dense rank-one term through the Woodbury identity),
// factored by a sparse LDLᵀ (Eigen's SimplicialLDLT, AMD order); where H is not positive definite
// (a compressed spring, a volume's or a bending's curvature) the step is retried with those terms
// dropped (Gauss-Newton, always positive definite), and then with a shift of the mass term.
// A backtracking line search on E (Armijo, c = 1e-4) accepts the first step that decreases E
// enough or, where E's decrease is below its rounding, shrinks the largest residual component.
// A step stops when the largest residual component is below rtol times the step's force scale
// (the largest of max m|g|, the constraint forces |C/α||∇C| and the inertia m|x - x̃|/h²) plus the
// rounding floor of the forces and of the inertia term: the rule of python/csb/backward_euler.py.
//
// The budgeted form (method "implicit-euler", Baraff and Witkin 1998's real-time practice): a
// fixed number of Newton iterations per step (newton_iterations > 0; one is Baraff and Witkin's
// linearised step when started from xⁿ, initial_guess = Previous, and solved directly; the method
// starts from the lower of x̃ and xⁿ by default, methods/backward_euler.cpp says why), each a
// linear solve by conjugate gradients preconditioned by the inverse 3x3 diagonal blocks of H, with
// a fixed budget of cg_iterations (stopping early once the CG residual has fallen by
// cg_tolerance), or by the sparse LDLᵀ. CG needs H positive definite: it takes the Gauss-Newton form (the projection to
// positive semi-definite: a compressed spring's geometric term clamped at 0, the volumes',
// bending's, balloons' and the families' curvature dropped; plus M/h², which makes it definite).
// The line search is the same, and may be switched off (a full Newton step, as in real-time
// codes). The step then ends after its budget, converged or not: no SimulationError for an
// unconverged step, only for a non-finite one.
//
// Both forms take the contacts with colliders as a penalty in E (collision/penalty.hpp: the
// position-based pipeline's contacts, (k/2) min(C, 0)² each, k = κ m/h²), with friction and
// restitution after the step; self-collision is the layer after each sub-step's solve
// (ImplicitSelfCollision, below).
#pragma once

#include "csb/collision/penalty.hpp"
#include "csb/collision/self_collision.hpp"
#include "csb/integrator.hpp"
#include "csb/reference.hpp"
#include "csb/use_guard.hpp"

#include <memory>
#include <vector>

namespace csb {

struct BackwardEulerSettings {
  Real dt = 1.0 / 60.0;              // s, > 0
  int substeps = 1;                  // backward Euler steps of dt/substeps per step, >= 1
  Vec3 gravity = Vec3(0, -9.81, 0);  // m/s²
  Real rtol = 1e-9;                  // residual relative to the step's force scale, > 0
  int max_iterations = 100;          // Newton iterations per step before SimulationError, >= 1
  // The budgeted form: 0 solves each step to rtol (the converged form, the same-step reference);
  // n > 0 takes at most n Newton iterations per step (fewer once the residual meets rtol).
  int newton_iterations = 0;         // >= 0
  enum class Linear { Direct, ConjugateGradient };
  Linear linear_solver = Linear::Direct;  // the converged form always solves directly
  int cg_iterations = 100;           // ConjugateGradient: iterations per Newton step, >= 1
  Real cg_tolerance = 1e-4;          // ConjugateGradient: stop once |residual| <= this |r0|, in [0, 1)
  bool line_search = true;           // Armijo backtracking on E; false: full Newton steps (budgeted form only)
  // Where Newton starts: x̃, xⁿ (Baraff and Witkin 1998; a particle whose prediction is past a
  // contact plane starts at x̃), or the one of the two with the lower E.
  enum class Guess { Inertia, Previous, Lower };
  Guess initial_guess = Guess::Inertia;
  // Contacts with the colliders as a penalty (collision/penalty.hpp): κ, the contact stiffness in
  // units of each particle's m/h² (dimensionless), > 0.
  Real contact_stiffness = PenaltyContacts::kDefaultStiffness;
};

// What the last step's Newton solve did.
struct BackwardEulerStats {
  int newton_iterations = 0;     // Newton steps taken (0: x̃ already solved it)
  Real residual = 0;             // N, the largest residual component at the end
  Real residual_norm = 0;        // N, its 2-norm
  Real tolerance = 0;            // N, the bound the largest component met
  int definiteness_fixes = 0;    // Newton steps whose Hessian needed the Gauss-Newton form or a shift
  int line_search_halvings = 0;  // halvings of the step length, in all
  int cg_iterations = 0;         // conjugate-gradient iterations, in all (budgeted form)
  std::vector<Real> history;     // N, the largest residual component before each Newton step and at the end
};

// The incremental potential of one step: from the state before it (positions, velocities; the
// pinned particles fixed where `pinned_at` has them), the time step and gravity.
class IncrementalPotential {
 public:
  // Throws InvalidArgument for a hard constraint (naming it), non-finite states, dt <= 0, a model
  // with nothing that moves, or states of another size than the model.
  IncrementalPotential(const Model& model, const State& previous, const State& pinned_at, Real dt, const Vec3& gravity);

  const SpringNetwork& network() const { return net_; }
  Index num_dynamic() const { return net_.num_dynamic(); }
  Real dt() const { return dt_; }
  const std::vector<Real>& inertial_positions() const { return x_tilde_; }  // x̃, m, 3 num_dynamic()
  // Adds the contacts' penalty to E (kept by pointer: `contacts` must outlive the potential's use).
  void set_contacts(const PenaltyContacts* contacts);

  Real energy(const Real* x) const;                  // J
  void gradient(const Real* x, Real* r) const;       // N, 3 num_dynamic()
  // The Newton matrix H = M/h² + ∇²U (N/m), `definite` as SpringNetwork::stiffness.
  void hessian(const Real* x, bool definite, Eigen::SparseMatrix<Real>& H, SpringNetwork::Stiffness& work) const;
  // H's entries before assembly: work.entries (duplicates summed in their order by
  // Eigen's setFromTriplets, the mass diagonal last) and the balloons' rank-one terms.
  void hessian_entries(const Real* x, bool definite, SpringNetwork::Stiffness& work) const;
  // The step's force scale (N) and the residual's rounding floor (N).
  void scales(const Real* x, Real& force_scale, Real& rounding) const;

 private:
  SpringNetwork net_;
  Real dt_;
  Vec3 gravity_;
  std::vector<Real> x_tilde_;
  const PenaltyContacts* contacts_ = nullptr;
  std::vector<Index> contact_slot_;  // the slot of each contact's particle
};

// The checks every implicit method's step (implicit Euler, Projective Dynamics, VBD) makes before
// it touches the state: steps >= 0, a state of the model's size and finite. InvalidArgument
// naming what is wrong.
void check_implicit_step(const Model& model, const State& state, std::int64_t steps);

// Self-collision in an implicit method: the collision-processing layer of Bridson, Fedkiw and
// Anderson (2002) after each sub-step's solve. The solve's positions are the end of the sub-step's
// motion x -> p; the continuous test, its responses and the fail-safe (SelfCollision,
// collision/self_collision.hpp, which says exactly what is guaranteed) move p until it has no new
// intersection, the particles they move change velocity by the move over h, and the contacts that
// pushed are made inelastic, as in the position-based steppers. The incremental potential itself
// has no self-contact term: the layer acts on the solve's result, not inside it. The candidate
// pairs are found afresh at each step's start, so a step's bits do not depend on the steps before.
class ImplicitSelfCollision {
 public:
  bool active(const Model& model);  // the model has self-collision (prepared for it on first use)
  // Around sub-step `sub` of `substeps` (h seconds each): before() keeps its start, after() runs
  // the layer on the state the solve left (positions and velocities).
  void before(const State& state, int sub);
  void after(const Model& model, State& state, int substeps, Real h);
  const SelfCollisionCounts& counts() const { return self_.counts(); }

 private:
  SelfCollision self_;
  std::uint64_t model_id_ = 0;
  bool fresh_ = true;  // find the candidates again: a step's first sub-step
  Positions start_, end_;
};

// `steps` steps of dt, each `substeps` calls of substep(sub), with the self-collision layer after
// each when the model has self-collision (self may be null: none); `interrupt`, asked between
// steps, stops them with Interrupted (the state at the end of the last step); a step that throws
// leaves the state where the step started.
void run_implicit_steps(const Model& model, State& state, std::int64_t steps, int substeps, Real dt,
                        const std::function<bool()>& interrupt, const std::function<void(int)>& substep,
                        ImplicitSelfCollision* self);

struct Residual {
  Real norm = 0;     // N, 2-norm of the residual over the dynamic particles
  Real max = 0;      // N, its largest component
  Real scale = 0;    // N, the step's force scale (as the backward Euler stepper's stopping rule)
};

// The backward-Euler residual of a step from `previous` to `next` taken by any method at time step
// dt (s) under gravity (m/s²): |∇E(x_next)| with x̃ from `previous`. The pinned particles are
// fixed where `next` has them. Contact forces are not part of E: where a method's step touched a
// collider, the residual includes the contact force.
Residual backward_euler_residual(const Model& model, const State& previous, const State& next, Real dt,
                                 const Vec3& gravity);

class BackwardEulerStepper final : public Integrator {
 public:
  // Throws InvalidArgument naming a setting out of range.
  explicit BackwardEulerStepper(const BackwardEulerSettings& settings);

  // "backward-euler" (converged) or "implicit-euler" (budgeted: newton_iterations > 0).
  std::string name() const override { return settings_.newton_iterations > 0 ? "implicit-euler" : "backward-euler"; }
  Real dt() const override { return settings_.dt; }
  const BackwardEulerSettings& settings() const { return settings_; }
  const UseGuard& use_guard() const { return use_; }
  // Each step solved to convergence; SimulationError if Newton does not converge in
  // max_iterations, the state left at the end of the last completed step (budgeted form: each
  // step ends after its budget; SimulationError only for a non-finite residual). Contacts with
  // colliders are a penalty in E (collision/penalty.hpp); self-collision is the layer after each
  // sub-step's solve (ImplicitSelfCollision). One thread at a time
  // (use_guard.hpp): a second thread stepping the same stepper meanwhile gets ConcurrentUse.
  //
  // What a step keeps for the next (the workspace below) changes its cost, never its bits: each
  // step's positions are those of a fresh stepper given the same state.
  void step(const Model& model, State& state, std::int64_t steps = 1,
            const std::function<bool()>& interrupt = {}) override;

  // The last backward Euler step's (of dt/substeps) Newton solve.
  const BackwardEulerStats& last() const { return last_; }
  Real max_residual() const { return max_residual_; }  // N, over all steps so far
  // What self-collision did in the last sub-step (ImplicitSelfCollision).
  const SelfCollisionCounts& self_collision() const { return self_collision_.counts(); }
  std::int64_t total_iterations() const { return total_iterations_; }

 private:
  void solve_one(const Model& model, State& state, Real h);
  PenaltyContacts contacts_;
  ImplicitSelfCollision self_collision_;

  // The Newton matrix's storage and assembly, and the sparse LDLᵀ's symbolic analysis (AMD
  // order, elimination tree) of each sparsity pattern it has had, kept across Newton iterations
  // and steps: a new pattern is analysed once, the same pattern only refactored. Eigen's
  // analysis depends on the pattern alone and its factorisation on the analysis and the values
  // alone, so reusing them gives the bits of SimplicialLDLT::compute. A copy starts empty.
  struct Workspace;
  class WorkspaceHolder {
   public:
    WorkspaceHolder();
    ~WorkspaceHolder();
    WorkspaceHolder(const WorkspaceHolder&);
    WorkspaceHolder& operator=(const WorkspaceHolder&);
    Workspace& operator*() const { return *p_; }

   private:
    std::unique_ptr<Workspace> p_;
  };

  BackwardEulerSettings settings_;
  WorkspaceHolder workspace_;
  UseGuard use_;
  BackwardEulerStats last_;
  Real max_residual_ = 0;
  std::int64_t total_iterations_ = 0;
};

}  // namespace csb
