// csb — the reference every method is measured against: the continuous system the PBD
// solvers approximate, integrated with SUNDIALS CVODE.
//
// From a Model, every constraint with compliance α > 0 becomes the potential E = C(x)²/(2α)
// (a Hooke spring of stiffness k = 1/α for a distance constraint), pinned particles stay where
// the start state has them, and gravity acts on the others:
//
//   M ẍ = -∇E(x) + M g - D(x) ẋ - β M ẋ,      y = [x; v],   ẏ = [v; M⁻¹(-∇E + M g - D v) - β v]
//
// with D an optional dashpot along every distance constraint (and an isotropic one on every
// attachment) and β an optional drag rate on every particle, both off by default. (A dashpot
// along a spring does not damp a pendulum's swing; the drag does, and brings a hanging chain to
// rest.) Only the constraint types present in the model are evaluated. The constraint families
// (tethers, ...; constraints/family.hpp) give their own potential C₊²/(2α), forces and Jacobian
// blocks; they are not damped.
//
// CVODE integrates it with BDF and Newton iterations. For springs, attachments and tetrahedral
// volume constraints the Jacobian is analytic and sparse and the Newton systems are solved by
// KLU; a model with compliant bending constraints (whose Hessian csb does not write out) or with
// balloons (one constraint coupling every particle of a surface: its Jacobian C/α ∇²V + ∇V ∇Vᵀ/α
// is dense over the surface) uses GMRES with CVODE's difference-quotient Jacobian-vector
// products, preconditioned by KLU on the spring, attachment and volume part.
#pragma once

#include "csb/model.hpp"

#include <Eigen/SparseCore>

#include <string>
#include <vector>

namespace csb {

struct ReferenceSettings {
  Vec3 gravity = Vec3(0, -9.81, 0);  // m/s²
  // Tolerances of CVODE's local error test. At the defaults a chain's and a cloth's trajectories
  // are within 1e-8 m of those at rtol 1e-12 (papers/reference.md), far below any error a study
  // measures; analytic tests ask for tighter ones. The energy is another matter: BDF5 loses about
  // c rtol^(5/6) (c <= 40 measured) of a spring mode's energy per period of that mode, 2.8e-4 of a
  // 100 rad/s spring's in 100 periods at rtol 1e-8; Python's rtol="auto" chooses rtol from a
  // stated energy tolerance, the fastest mode and the duration (validation/reference_energy.py).
  Real rtol = 1e-8;                  // relative tolerance, > 0
  Real atol = 1e-10;                 // absolute tolerance on positions (m) and velocities (m/s), > 0
  // N s/m: dashpot along each distance constraint and an isotropic one on each attachment; bending,
  // volume and balloon constraints are not damped (XPBD's damping, Macklin 2016 Eq. 26, acts along
  // every constraint's gradient: the two agree on distance constraints only).
  Real damping = 0;
  Real drag = 0;                     // 1/s: force -drag m v on every particle
  int max_order = 5;                 // BDF order cap, 1..5
  // CVODE's BDF stability limit detection (STALD): lowers the order when a mode near the
  // imaginary axis (an undamped spring) would make orders 3-5 unstable. Off by default: at the
  // default tolerances CVODE resolves the spring modes, so |hλ| stays where BDF5 is stable, and
  // the self-convergence check passes without it; with it a falling chain took 3x the steps and
  // a cloth at rtol 1e-12 stalled at order 3 (papers/reference.md).
  bool stability_limit_detection = false;
  enum class Linear { Automatic, Klu, Gmres };
  Linear linear_solver = Linear::Automatic;  // Automatic: KLU unless compliant bending is present
  std::int64_t max_steps = 10'000'000;       // internal steps in all before giving up
  Real max_wall_time = 0;                    // s; 0: no limit
};

struct ReferenceStats {
  long steps = 0;
  long rhs_evals = 0;
  long newton_iters = 0;
  long newton_failures = 0;
  long error_test_failures = 0;
  long jacobian_evals = 0;   // KLU: Jacobian evaluations; GMRES: preconditioner set-ups
  long linear_iters = 0;     // GMRES iterations (0 with KLU)
  int last_order = 0;
  double last_step = 0;      // s
  double wall_time = 0;      // s
  std::string linear_solver; // "klu" or "gmres"
};

struct ReferenceResult {
  std::vector<Real> times;     // s, as requested
  std::vector<Positions> x;    // m, one 3 x N block per time (pinned particles included)
  std::vector<Positions> v;    // m/s
  ReferenceStats stats;
};

// The first-order system ẏ = f(y) of a model: state layout, right-hand side and Jacobian.
class SpringNetwork {
 public:
  // Pinned particles are fixed at their positions in `start`. Throws InvalidArgument if a
  // constraint is hard (compliance 0: the reference needs a spring), if no particle can move,
  // or for impossible settings. Without `with_jacobian` the sparse structure is not built
  // (the force-based steppers need only rhs()).
  SpringNetwork(const Model& model, const State& start, const ReferenceSettings& settings, bool with_jacobian = true);

  Index num_dynamic() const { return static_cast<Index>(dynamic_.size()); }
  std::size_t size() const { return 6 * dynamic_.size(); }  // length of y
  // True when every force has an analytic sparse Jacobian (no compliant bending constraints, no
  // balloons, no constraint family without its Hessian).
  bool has_analytic_jacobian() const;

  const std::vector<Index>& dynamic_particles() const { return dynamic_; }
  void pack(const State& state, Real* y) const;             // y = [x_dyn; v_dyn]
  void unpack(const Real* y, Positions& x, Positions& v) const;  // all particles
  void rhs(const Real* y, Real* ydot) const;

  // Compressed sparse column structure of ∂f/∂y (size() x size()), every diagonal entry
  // present; values filled by jacobian(). Without bending and balloons: the whole Jacobian;
  // with them: the part of the springs, attachments and volumes only (the preconditioner's).
  const std::vector<std::int64_t>& jacobian_column_starts() const { return col_start_; }
  const std::vector<std::int64_t>& jacobian_row_indices() const { return row_index_; }
  void jacobian(const Real* y, Real* values) const;

  // The position-level network, for implicit steps (csb/implicit_euler.hpp). x holds the dynamic
  // particles' positions (3 num_dynamic(), m: the first half of y); pinned ones stay where the
  // start state has them. The potential U(x) = Σ C²/(2α) (J; inequalities and unilateral families
  // only while violated); the forces -∇U (N, added to f: no gravity, no damping).
  Real potential(const Real* x) const;
  void add_potential_forces(const Real* x, Real* f) const { add_forces(x, nullptr, 0, f); }
  // ∇²U (N/m) over 3 num_dynamic() rows: sparse entries (duplicates to be summed) and, for each
  // balloon, the dense rank-one part k ∇V ∇Vᵀ as (k, ∇V). Bending's curvature is the central
  // difference of its analytic gradient (within 2e-10 of the largest entry in the tests). With
  // `definite`, the terms that can make it indefinite are dropped (a compressed spring's geometric
  // term, the volumes', bending's, balloons' and the families' curvature): what remains is
  // Gauss-Newton, positive semi-definite.
  struct Stiffness {
    std::vector<Eigen::Triplet<Real>> entries;
    std::vector<Real> rank_one_weight;               // J/m⁶
    std::vector<std::vector<Real>> rank_one_vector;  // m², 3 num_dynamic() each
  };
  void stiffness(const Real* x, bool definite, Stiffness& out) const;
  // The largest constraint force |C/α| |∇C| (N) and the forces' rounding floor (N): the error of
  // C (~ 4 eps |x| Σ|∇C|, from coordinates of size |x|) times |∇C|/α, largest over constraints.
  void force_scale(const Real* x, Real& largest, Real& rounding) const;
  Real mass(Index slot) const { return mass_[static_cast<std::size_t>(slot)]; }  // kg

 private:
  struct Spring {
    Index a, b;        // slots, or -1 for a fixed end
    Vec3 fixed_a, fixed_b;
    Real k, rest;
    int sense;
  };
  struct Bend {
    Index slot[4];
    Vec3 fixed[4];
    Real k, rest;
  };
  struct Volume {     // a tet: C = V - V0, potential C²/(2α), k = 1/α (J/m⁶)
    Index slot[4];
    Vec3 fixed[4];
    Real k, rest;
  };
  struct Balloon {    // C = V_enclosed - pressure V0 over the surface's particles
    std::vector<Index> slot;
    std::vector<Vec3> fixed;
    std::vector<Triangle> triangles;  // indices into slot
    Real k, target;
  };
  struct Anchor {
    Index slot;
    Vec3 target;
    Real k;
  };
  void build_structure();
  // Adds the forces at positions y (and, with a dashpot c > 0, velocities v) to a (3 num_dynamic()).
  void add_forces(const Real* y, const Real* v, Real c, Real* a) const;
  Vec3 position(const Real* y, Index slot, const Vec3& fixed) const {
    return slot >= 0 ? Vec3(y[3 * slot], y[3 * slot + 1], y[3 * slot + 2]) : fixed;
  }
  // A balloon at positions y: its surface's positions p (3 x its particles, in its own order),
  // ∇V there, and C = V - target.
  Real balloon_constraint(const Real* y, const Balloon& b, Positions& p, std::vector<Vec3>& grad) const;

  ReferenceSettings settings_;
  std::vector<Index> dynamic_;   // particle of each slot
  std::vector<Index> slot_of_;   // slot of each particle, -1 if pinned
  std::vector<Real> mass_;       // per slot, kg
  Positions pinned_x_;           // all particles' start positions (used for the pinned ones)
  std::vector<Spring> springs_;
  std::vector<Bend> bending_;
  std::vector<Volume> volumes_;
  std::vector<Balloon> balloons_;
  std::vector<Anchor> anchors_;
  // A constraint family's batch and, per constraint, the value positions of its arity x arity
  // blocks ∂(force on i)/∂x_j (9 each, -1 where i or j is pinned).
  struct FamilyTerm {
    std::shared_ptr<const FamilyBatch> batch;
    std::vector<std::int64_t> blocks;
  };
  std::vector<FamilyTerm> families_;
  // All particles' positions (pinned ones from the start state, the others from y), for the families.
  void full_positions(const Real* y, std::vector<Real>& x) const;
  std::vector<std::int64_t> col_start_, row_index_;
  // For each spring: value positions of the 3x3 blocks (aa, ab, ba, bb) in the x- and the
  // v-columns; -1 where an end is fixed. For each anchor: its aa blocks.
  struct Blocks {
    std::int64_t x[4][9];
    std::int64_t v[4][9];
  };
  std::vector<Blocks> spring_blocks_;
  std::vector<Blocks> anchor_blocks_;
  // For each tet: value positions of its 16 blocks (i, j) = ∂(force on i)/∂x_j at 4 i + j.
  struct VolumeBlocks {
    std::int64_t x[16][9];
  };
  std::vector<VolumeBlocks> volume_blocks_;
  std::vector<std::int64_t> identity_;       // positions of the ∂ẋ/∂v = I entries
  std::vector<std::int64_t> drag_diagonal_;  // positions of the ∂v̇/∂v diagonal
};

// Integrates the model from `start` (time start.t) and returns positions and velocities at the
// requested times, which must be increasing and not before start.t. Throws InvalidArgument for
// bad settings or times, SimulationError if CVODE fails (with its message, the time reached and
// the statistics), if max_steps is exceeded, or if max_wall_time runs out.
ReferenceResult integrate_reference(const Model& model, const State& start, const std::vector<Real>& times,
                                    const ReferenceSettings& settings);

}  // namespace csb
