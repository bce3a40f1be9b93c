// csb — the position-based steppers: Müller et al. 2007 PBD, Macklin et al. 2016 XPBD (and its
// small-steps use, Macklin et al. 2019) and Jakobsen 2001's Verlet with relaxation, as variants
// of one pipeline (Müller 2007, Algorithm 1):
//
//   (5)  v <- v + h w f_ext          gravity, on particles with w > 0         [Euler front end]
//   (6)  dampVelocities(v)           §3.5, per group, leaves rigid motion untouched
//   (7)  p <- x + h v                explicit Euler prediction
//        or p <- x + (1 - d)(x - x*) + h² g                                    [Verlet front end]
//   (8)  generate collision constraints: contacts with the colliders along x -> p (§4.3) and,
//        per self-colliding group, point-triangle contacts of its cloth (§4.4); see below
//   (9-11) `iterations` sweeps of projectConstraints over every distance, bending, volume, balloon,
//          attachment and constraint family's (tethers, constraints/families.hpp) constraint:
//          Gauss-Seidel (each sees the corrections before it) or Jacobi (all from
//          the positions at the start of the sweep, corrections averaged or summed)
//   (12-15) v <- (p - x)/h, x <- p      (Verlet: x* <- x, x <- p)
//   (16) velocityUpdate: friction (apply_friction, on p before (12)) and restitution
//        (apply_restitution) of the particles in contact
//
// The projection is the method's: PBD scales each correction by the stiffness k ∈ [0, 1] (with
// Müller's iteration correction if asked); XPBD solves for a multiplier per constraint with the
// compliance α, reset at each (sub)step; Jakobsen relaxes sticks, optionally without square
// roots. One call to step() advances by dt, as `substeps` sub-steps of h = dt/substeps. Time
// step, substeps and iterations are three different things and keep three names.
#pragma once

#include "csb/solver/coloured.hpp"
#include "csb/integrator.hpp"
#include "csb/material.hpp"
#include "csb/model.hpp"
#include "csb/collision/ccd.hpp"
#include "csb/collision/self_collision.hpp"
#include "csb/collision/spatial_hash.hpp"
#include "csb/solver/team.hpp"
#include "csb/use_guard.hpp"

#include <cstdint>
#include <functional>
#include <unordered_set>

namespace csb {

enum class Method { Pbd, Xpbd, Jakobsen };
enum class FrontEnd { Euler, Verlet };
enum class Solver { GaussSeidel, Jacobi, JacobiSummed };
enum class Ordering { Coloured, Sequential };
enum class Precision { Double, Single };

struct PbdSettings {
  Method method = Method::Pbd;
  Real dt = 1.0 / 60.0;                 // s, the time one step() advances; > 0
  int substeps = 1;                     // sub-steps of dt/substeps per step; >= 1
  int iterations = 10;                  // constraint sweeps per sub-step; >= 1
  Vec3 gravity = Vec3(0, -9.81, 0);     // m/s^2
  // Müller 2007 §3.5 k_damping in [0, 1]: the fraction of each particle's velocity deviation
  // from its group's rigid motion removed per sub-step (0: undamped). Euler front end only.
  Real damping = 0;
  // PBD: project with k' = 1 - (1 - k)^(1/iterations) (Müller 2007 §3.3), so that the
  // stiffness felt after all iterations does not depend on their number.
  bool stiffness_correction = true;
  // How positions are predicted: Euler keeps the velocity (Müller), Verlet the previous
  // position (Jakobsen). Jakobsen's method always uses Verlet.
  FrontEnd front_end = FrontEnd::Euler;
  // How each sweep visits the constraints. Jacobi averages the corrections a particle receives
  // (by their number); with XPBD, whose multipliers must stay consistent with the positions
  // (x - p = M⁻¹∇Cᵀλ), it instead scales each constraint's Δλ by 1/(the most projections that
  // reach any of its moving particles) and adds the corrections, which converges to the same
  // answer as Gauss-Seidel. JacobiSummed adds the full corrections: whether it converges depends
  // on the constraint graph, not the stiffness (a sweep's spectral radius is cos(π/2n) < 1 on a
  // chain of n links, about 2 on a cloth, where it diverges; validation/stability.py). Kept to
  // show it.
  Solver solver = Solver::GaussSeidel;
  // XPBD constraint damping β (Macklin 2016 Eq. 26), in N s/m for distance constraints and
  // attachments (J s for bending, J s/m⁶ for volumes and balloons); 0: none.
  Real xpbd_damping = 0;
  // Jakobsen's drag d in [0, 1): p = x + (1 - d)(x - x*) + h² g (his x' = 1.99x - 0.99x* is 0.01).
  Real verlet_drag = 0;
  // Jakobsen's stick relaxation without square roots (see constraints/distance.hpp).
  bool sqrt_approximation = false;
  // Coloured (default): the parts of the model and the interfaces between them as the threads'
  // tasks, each batch of a task colour by colour (Model's `colours`), the constraints of one
  // colour projected at once in SIMD lanes. Sequential: every batch in the order it
  // was built, one constraint after the other, on one thread (Müller's loop as written, for
  // teaching and comparison). A different order is a different Gauss-Seidel sweep: the two agree
  // to the solver's convergence, not to the bit.
  Ordering ordering = Ordering::Coloured;
  // Threads that share the sweep (csb/team.hpp); >= 0. 0: automatic, the cores that are free
  // (from /proc/loadavg's runnable count), at most the model's parts (one for a model of one
  // part: under 1024 particles). The result does not depend on the number: the parts and their
  // colouring fix the order of every update.
  int threads = 0;
  // The divergence guard, m/s: a step after which a particle that can move is faster than this
  // throws SimulationError naming the step, the particle, its speed, its most strained
  // constraint and what the limit is made of, with the state left at the end of that step.
  // 0 (default): automatic, D/h + 2 (v0 + |g| t + sqrt(2 |g| D)): D the model's size (its rest
  // bounding-box diagonal plus twice its thickest collision layer, m) and h the sub-step, v0 the fastest particle of the state the
  // stepper first stepped, t the time since. A stable simulation stays below it (the second
  // term bounds what the start, gravity and a swing over the model's size give, twice over; a
  // particle that crosses the whole model in one sub-step has left what the constraints and
  // contacts can follow); a runaway, which grows geometrically, trips it within a few steps,
  // long before positions reach 1e14 m or NaN. Infinity turns the guard off.
  Real max_speed = 0;
  // The scalar the solver runs in. Double (default): the state and every constraint in double
  // precision. Single: during a step, the particles' positions, velocities (Verlet: previous
  // positions) and predictions and the distance and bending constraints' data in float, twice
  // the SIMD lanes and half the bytes; the state is rounded to float at the step's start and
  // widened back at its end (deterministic within each precision). Single runs the coloured
  // Gauss-Seidel sweep of a step without contacts, compliant grabs or Müller damping, on models of
  // distance and bending constraints and pins, with kinematic grabs; other models and settings
  // are refused with what stands in the way.
  Precision precision = Precision::Double;
};

// Throws InvalidArgument naming the first impossible setting.
void validate(const PbdSettings& settings);

// Lagrange multipliers of the last XPBD (sub)step, one per constraint of each batch; the
// constraint force is λ/h² along ∇C (N for distance constraints and attachments; for volumes and
// balloons λ/h² is a pressure, Pa).
struct Multipliers {
  std::vector<Real> distance, bending, attachment;
  std::vector<Real> volume, balloon;
  std::vector<std::vector<Real>> family;  // per constraint family, as Model::families
};

// A particle held by the user's hand at a moving point (click and drag). The stepper owns its
// grabs, the Model stays immutable: a grab is interaction, not material.
//  - compliance 0: the particle follows the hand exactly (kinematic): while held its inverse
//    mass is 0 in every projection and its prediction is the hand's position, interpolated
//    linearly over the sub-steps of a step from where the hand was at the previous step, so a
//    fast drag does not arrive as one jump; the rest of the mesh follows through the constraints.
//    On release the particle keeps the velocity of the last sub-step (a throw).
//  - compliance α > 0 (m/N): an XPBD spring of stiffness 1/α to the hand, for every method;
//    the particle keeps its mass. A pinned particle (w = 0) cannot be pulled by a spring, but a
//    kinematic grab moves it, and it stays pinned where it is released.
struct Grab {
  int handle = 0;
  Index particle = 0;
  Vec3 target = Vec3::Zero();  // m, where the hand is
  Vec3 from = Vec3::Zero();    // m, where the hand was at the end of the previous step
  Real compliance = 0;         // m/N
  bool pinned = false;         // the model pins the particle: released, it stops where it is
  // Where the hand is `fraction` of the way through the step, on the straight line from `from`
  // (1 and beyond: exactly at `target`).
  Vec3 at(Real fraction) const { return fraction >= 1 ? target : Vec3(from + fraction * (target - from)); }
};

// What the collision detection of the last sub-step found.
struct ContactSummary {
  Index count = 0;            // particle-collider contacts, speculative ones included
  Index active = 0;           // those that pushed their particle this sub-step
  Index self_count = 0;       // self-contacts: proximity point-triangle, and continuous
  Index self_continuous = 0;  // of which found by the continuous test after the sweeps
  Index self_failsafe = 0;    // particles the self-collision fail-safe stopped (p = x) this sub-step
  Index self_unresolved = 0;  // impacts the fail-safe could not stop (only prescribed particles moved)
  std::int64_t self_searches = 0;  // candidate-pair searches since the stepper was made
  std::int64_t self_candidates = 0;  // point-triangle and edge-edge candidate pairs now kept
  std::int64_t self_tests = 0;  // continuous tests (additive CCD) run since the stepper was made
  std::int64_t self_culled = 0;  // candidate pairs left untested in certified patches, since made
  Index self_skipped = 0;     // triangles left out of self-collision: spread over more than the cloth's size in a step
  Real max_depth = 0;         // m, deepest violation r - (p - q)·n of a contact at the prediction
  Real max_penetration = 0;   // m, deepest violation left at the end of the sub-step (both below)
  Real collider_penetration = 0;  // m, of the collider contacts (projected last: round-off)
  Real self_penetration = 0;  // m, of the self-contacts' thickness (a collider's push may thin it)
};

class PbdStepper : public Integrator {
 public:
  explicit PbdStepper(const PbdSettings& settings);
  const PbdSettings& settings() const { return settings_; }
  std::string name() const override;  // "pbd", "xpbd" or "jakobsen"
  Real dt() const override { return settings_.dt; }
  Real substep_size() const { return settings_.dt / settings_.substeps; }

  // Advances `state` by `steps` steps of settings().dt. Throws SimulationError naming the step
  // and particle if a position becomes non-finite; the state is then left at the end of the
  // last sub-step whose positions were all finite. One thread at a time (use_guard.hpp): a
  // second thread's call while a step runs throws ConcurrentUse.
  // `interrupt`, if given, is asked between sub-steps (every kFusedSubsteps of a fused step) and
  // between steps whether to stop; when it returns true the step throws Interrupted, the state
  // left at the end of the last completed sub-step. Python's binding asks its signal handlers
  // (Ctrl-C) at most every 20 ms.
  void step(const Model& model, State& state, std::int64_t steps = 1,
            const std::function<bool()>& interrupt = {}) override;
  static constexpr int kFusedSubsteps = 64;

  // Held by the bindings while they copy out what a step writes (contacts, multipliers).
  const UseGuard& use_guard() const { return use_; }

  // Constraint projections one step performs on this model.
  std::int64_t projections_per_step(const Model& model) const;
  // What `steps` steps cost at the least, in constraint projections and particle updates: the
  // quantity step() refuses beyond a year's work (memory_budget.hpp, require_time_for).
  double operations(const Model& model, std::int64_t steps) const {
    return static_cast<double>(steps) * settings_.substeps *
           (static_cast<double>(settings_.iterations) * model.num_constraints() + model.num_particles());
  }

  // XPBD only: the multipliers of the last sub-step (empty for the other methods), indexed as
  // the model's batches.
  const Multipliers& multipliers() const;

  // Threads the last step() used (1 for the sequential ordering).
  int threads_used() const { return threads_used_; }
  // Bytes of the per-model workspace (from the vectors' capacities): predicted and previous
  // positions, Jacobi buffers, the coloured batches and per-constraint coefficients, multipliers,
  // self-collision (features, hierarchy, candidate pairs, contacts).
  std::size_t workspace_bytes() const;

  // Grabs particle `particle` of `model` with the hand at `target` (m); returns a handle. The
  // hand starts where the particle is in `state`, so the first step moves it from there to
  // `target`. Throws InvalidArgument for an index out of range, a non-finite target, a
  // compliance < 0 or a particle already held.
  int grab(const Model& model, const State& state, Index particle, const Vec3& target, Real compliance = 0);
  // Moves the hand of a grab (m); the next step() takes the particle there.
  void move_grab(int handle, const Vec3& target);
  // Lets go; unknown handles are an error.
  void release(int handle);
  const std::vector<Grab>& grabs() const { return grabs_; }
  // The contacts of the last sub-step (with their XPBD multipliers, normal corrections) and
  // a summary of them.
  const std::vector<Contact>& contacts() const { return contacts_; }
  const std::vector<SelfContact>& self_contacts() const { return self_.contacts(); }
  const ContactSummary& contact_summary() const { return contact_summary_; }
  // What this method cannot read of `model`'s material (material.hpp); empty once
  // material_reported(model) was called: the Python binding warns once per model and stepper.
  std::vector<MaterialNote> material_notes_to_report(const Model& model) const;  // material.cpp
  void material_reported(const Model& model) { reported_models_.insert(model.id); }
  // What the settings cannot solve accurately in `model` (reported with the material notes, once
  // per model): a distance constraint between particles whose masses differ more than
  // 10 x iterations x substeps² times. Gauss-Seidel then moves the light particle almost alone: a
  // hanging 10-particle chain of alternating masses (1 s at 1/60 s) stretched its 0.1 m links by
  // 7-70 % at that ratio and by up to 15 times their length ten times beyond it (1 x 1, 1 x 10,
  // 1 x 100, 10 x 1, 100 x 1 sub-steps x iterations; PBD and XPBD alike), while the 2-6 times of
  // a mesh's lumped masses stay quiet. Empty once material_reported(model) was called.
  std::vector<std::string> accuracy_notes_to_report(const Model& model) const;
  // What `state` holds that no constraint can resolve (once per model and stepper, like the notes
  // above). One pass over the distance and volume constraints, made on the first call for a model
  // and then once every kDegenerateCheckSteps steps of the state (a pass on every call made
  // single one-iteration steps of a 64 x 64 cloth 18 % slower): distance constraints whose particles coincide (closer than 1e-9 of the rest
  // length: the correction has no direction, so the kernels leave them alone) and tets collapsed
  // onto a line or a point (the volume gradient is zero, so nothing restores them). A state
  // squashed flat by the user, or particles placed on one another, stays so without a word
  // otherwise.
  std::vector<std::string> degenerate_notes_to_report(const Model& model, const State& state);
  static constexpr std::int64_t kDegenerateCheckSteps = 64;

  // Moving colliders and attachments (collision/collider_motion.cpp; collision.hpp for the
  // contacts). Each collider of the model has a rigid pose x_world = R x_model + t, the identity
  // until moved. move_collider sets the pose the collider reaches at the end of the next step();
  // over that step's sub-steps it goes there from its present pose (t linearly, R by quaternion
  // slerp: less than π a step). Throws InvalidArgument naming the collider for an index out of
  // range or a rotation that is not one (|RᵀR - I|, |det R - 1| > kRotationTolerance) or
  // non-finite values. translation in m. A step interrupted between sub-steps leaves the pose
  // of the step's start as the one to move from (as for a grab's hand): the next step() goes
  // from there again.
  void move_collider(const Model& model, Index collider, const Mat3& rotation, const Vec3& translation);
  // The pose of a collider at the end of the last step (what the state's positions saw).
  ColliderPose collider_pose(Index collider) const;
  // Attaches particles to a collider: kinematic (inverse mass 0 in the projections) and predicted
  // at the collider's interpolated pose applied to where they are in its frame now (so a cape
  // hangs from a moving character's shoulders). A particle held already (grab or attachment) is
  // an error. detach lets go of `particles` of that collider (all of them if empty); they keep
  // the velocity they had. Attached particles appear in grabs() with negative handles.
  void attach(const Model& model, const State& state, Index collider, const std::vector<Index>& particles);
  void detach(Index collider, const std::vector<Index>& particles = {});
  const std::vector<ColliderAttachment>& attachments() const { return attachments_; }
  // Deforming mesh colliders (collision.hpp): the vertices (m, 3 x V, the model frame, in the
  // mesh's order) mesh collider `collider` reaches at the end of the next step(), each moving
  // there on a straight line over the step's sub-steps (then carried by the collider's pose, if
  // moved too). Contacts test particles against the moving triangles continuously; particles
  // attached to the collider follow their triangle. Throws InvalidArgument naming the collider
  // (and the vertex) for a collider that is not a mesh, a wrong vertex count or a non-finite vertex.
  void deform_collider(const Model& model, Index collider, const Positions& vertices);
  // A mesh collider's vertices at the end of the last step (model frame, m): the model's until deformed.
  Positions collider_vertices(const Model& model, Index collider) const;
  // Whether deform_collider was called for collider `collider` (else its vertices are the model's):
  // what a renderer asks before copying a mesh's vertices each frame.
  bool collider_deforms(Index collider) const {
    return collider >= 0 && collider < static_cast<Index>(collider_motion_.size()) &&
           collider_motion_[collider].deform.active();
  }

 private:
  struct ColliderMotion {
    ColliderPose from, to;     // at the end of the last step, at the end of the next
    ColliderPose start, end;   // of the current sub-step
    bool moving = false;       // either pose is not the identity (else every operation is the static one)
    DeformingMesh deform;      // a mesh collider's vertices, once deform_collider was called
  };
  std::vector<ColliderMotion> collider_motion_;  // per collider of the model, empty until one is moved or attached to
  std::vector<ColliderAttachment> attachments_;
  int next_attachment_ = -1;
  void size_collider_motion(const Model& model, const char* what);
  void move_colliders(const Model& model, int sub);  // the sub-step's poses; attached particles' predictions
  void end_collider_motion(const Model& model, const State& state);
  void deform_substep(const Collider& c, ColliderMotion& m, int sub, Real s0, Real s1);  // vertices, swept grid
  std::vector<Vec3> deform_lo_, deform_hi_;  // m, the swept triangles' boxes

  void prepare(const Model& model);
  void predict(const Model& model, State& state, Real h);
  // (5) and (7) of Algorithm 1 for particles [begin, end), without Müller's damping (Euler) or
  // with the Verlet front end; (12)-(15) for particles [begin, end); a non-finite position of
  // sub-step `sub` as an error naming particle i (the state left at the last finite sub-step).
  void predict_range(const Model& model, State& state, Real h, Index begin, Index end);
  void commit(State& state, Real h, Index begin, Index end);
  // commit then predict_range for particles [begin, end) in one pass (the same operations), the
  // prediction's h g (Verlet: h² g) taken from accel_ (set_accel).
  void advance(State& state, Real h, Index begin, Index end);
  // accel_ for particles [begin, end).
  void set_accel(const Model& model, Real h, Index begin, Index end);
  [[noreturn]] void fail_non_finite(State& state, int sub, Index i, Real h);
  // The divergence guard (PbdSettings::max_speed) after a step; guard_size_ is the model's
  // rest bounding-box diagonal (m), guard_v0_ and guard_t0_ the fastest speed (m/s) and the time
  // (s) of the state the stepper first stepped on this model.
  void check_divergence(const Model& model, State& state, Real h);
  // The stages of step() (step/stepper.cpp lists them against Algorithm 1).
  void check_request(const Model& model, const State& state, std::int64_t steps) const;
  bool begin_steps(const Model& model, State& state);
  bool substep(const Model& model, State& state, Real h, int sub, bool after, bool predicted, bool next);
  // Whether a sub-step's update may also predict the next (advance): predict() is predict_range.
  bool advancing() const { return settings_.front_end == FrontEnd::Verlet || settings_.damping <= 0; }
  void substeps(const Model& model, State& state, Real h, int first, int count, const std::function<bool()>& interrupt);
  void substeps_fused(const Model& model, State& state, Real h, const std::function<bool()>& interrupt);
  void stop_if_asked(State& state, Real h, int sub, const std::function<bool()>& interrupt);
  void end_step(const Model& model, State& state, Real h);
  void finish_steps(State& state, Real h);
  void reset_multipliers();
  void hold_grabbed(const Model& model);
  UseGuard use_;
  Real guard_size_ = 0, guard_v0_ = 0, guard_t0_ = 0;
  bool guard_started_ = false;
  // XPBD: share `share` of `shares` (equal runs) of every coloured batch's multipliers, and the
  // balloons', set to zero (at the start of a sub-step); the distance and bending constraints'
  // only if `all` (a sub-step's first sweep writes them without reading them, but for the relaxed
  // Jacobi kernels, which read them).
  void zero_coloured_multipliers(int share, int shares, bool all);
  // The sub-steps of a step done entirely by the projection's threads, in one fork of the team
  // (no contacts, grabs or Müller damping): the prediction before the sweeps, the finiteness
  // check and the velocity update after them, the update and the next sub-step's prediction in
  // one pass. With several sub-steps, when every constraint lies in a part or an interface
  // (Gauss-Seidel, no balloons), each part's task instead updates and predicts its own particles
  // before its first sweep of the next sub-step, and the finiteness check runs once, after the
  // last sub-step.
  struct Fused {
    State* state;
    Real h;
    int substeps;
    Index bad = -1;    // a particle whose new position is not finite
    int bad_sub = -1;  // in this sub-step (the state then left at its start), or -1: after the
                       // last sub-step, checked once (the caller restores the step's start)
  };
  void project(const Model& model, const Positions& x_start, Fused* fused = nullptr);
  void project_sequential(const Model& model, const Positions& x_start);
  // One sweep of every constraint family (after the other batches, on the calling thread): the
  // positions read and moved (Gauss-Seidel: read = out = p; Jacobi: read = the sweep's start,
  // out = the corrections' sums, count the corrections per particle or null when counted
  // beforehand), the sub-step's start and XPBD's relaxation (or null).
  void project_families(const Model& model, const Real* w, const Real* read, Real* out, Real* count,
                        const Real* x_start, const Real* relax);
  template <Method M, bool Jacobi>
  void project_coloured(const Model& model, const Positions& x_start, Fused* fused);
  // Precision::Single: what in the model or the stepper's state stands in its way (throws
  // InvalidArgument), and `count` sub-steps of a step in float, sub-steps first .. first + count
  // - 1 (solver/coloured.cpp).
  void check_single(const Model& model) const;
  void substeps_single(const Model& model, State& state, Real h, int first, int count);
  template <Method M>
  void substeps_single(const Model& model, State& state, Real h, int first, int count);
  void build_coloured(const Model& model, const Real* w);
  int resolve_threads(const Model& model);
  void damp_velocities(const Model& model, State& state) const;
  // x_resolved: x is the p that the last sub-step's self-collision resolve left (SelfCollision::begin).
  void generate_contacts(const Model& model, const Positions& x, Real h, bool x_resolved = false);
  void set_relaxation(const Model& model);
  void project_contacts(const Model& model, bool jacobi);
  void project_self_contacts(const Model& model, bool jacobi);
  void resolve_self_collisions(const Model& model, const Positions& x, Real h);
  void settle_self_contact_velocities(const Model& model, State& state, Real h);
  void report_self_collision();
  void settle_contact_moves(bool average);
  void apply_friction(const Model& model, const Positions& x);
  void apply_restitution(const Model& model, State& state, Real h);

  PbdSettings settings_;
  // Per-model workspace, rebuilt when the model changes.
  std::uint64_t model_id_ = 0;
  Positions p_;                          // predicted positions
  Positions x_prev_;                     // Verlet: positions one sub-step back
  Positions x_step_, v_step_;            // a fused step checked once: x and v (Verlet: x_prev_) at its start
  std::vector<Real> accel_;              // advance: what a prediction adds, h g (Verlet h² g), 0 where w = 0
  Positions p_start_, delta_;            // Jacobi: positions at the sweep's start, summed corrections
  std::vector<Real> count_;              // Jacobi: corrections each particle received in the sweep
  // XPBD with averaged Jacobi: per particle 1/(projections that reach it in a sweep, contacts
  // included), 1 where it cannot move; a constraint's Δλ is scaled by the smallest over its
  // particles, and positions move by the sum (see set_relaxation). Empty otherwise.
  std::vector<Real> relax_;
  std::vector<Real> k_distance_, k_bending_, k_attachment_;  // PBD: stiffness used per iteration
  std::vector<Real> a_distance_, a_bending_, a_attachment_;  // XPBD: α̃ = α/h²
  std::vector<Real> g_distance_, g_bending_, g_attachment_;  // XPBD: γ = α β / h
  std::vector<Real> k_volume_, a_volume_, g_volume_;     // volume: PBD stiffness, XPBD α̃ and γ
  std::vector<Real> k_balloon_, a_balloon_, g_balloon_;  // balloons: the same
  std::vector<Vec3> balloon_grad_;                       // balloon gradient workspace (largest balloon)
  struct FamilyTerms {
    std::vector<Real> k, alpha, gamma;  // PBD stiffness as iterated; XPBD α̃ = α/h², γ = α β / h
  };
  std::vector<FamilyTerms> family_terms_;                // per constraint family, as Model::families
  // Multipliers in the model's order; in coloured ordering filled from coloured_ on request.
  mutable Multipliers lambda_;
  mutable bool lambda_stale_ = false;
  ColouredBatches coloured_;             // the batches in colour order (coloured ordering)
  // Precision::Single: the distance and bending batches rounded to float (coloured_'s own are
  // then released), and during a step the particles' positions x, velocities v (Verlet: previous
  // positions), predictions p and per-sub-step accelerations (h g; Verlet h² g) in float. w: each
  // particle's inverse mass as the bending batch has it, kept in the pads of x and p (and of
  // Verlet's previous positions; the velocities' and accelerations' pads are 0, so that every
  // prediction and update leaves them so): the bending kernels read it with the particle.
  struct {
    ColouredDistanceT<float> distance;
    ColouredFourT<float> bending;
    std::vector<float> x, v, p, accel, w;
  } single_;
  struct {
    std::vector<Index> distance, bending, volume, attachment;
    std::vector<Index> distance_paired;  // the distance constraint projected with each bending element, or -1
  } coloured_order_;                     // XPBD: the colourings' orders, to put multipliers back
  int threads_used_ = 1;
  std::vector<Index> bad_;               // per thread: first non-finite position of its range (Fused)
  bool spin_ = false;                    // the team's threads may spin while waiting (cores are free)
  TeamHandle team_;                      // the threads of the coloured projection
  // Interaction.
  std::vector<Grab> grabs_;
  int next_grab_ = 1;
  std::vector<Real> w_;                  // inverse masses with kinematic grabs at 0
  std::vector<Real> grab_lambda_;        // multipliers of compliant grabs, per sub-step
  Real grab_fraction_ = 1;               // how far through the step the hand is
  std::vector<Index> stop_;              // pinned particles released since the last step
  void apply_grab_targets(Real fraction);
  void project_grabs(const Positions& x_start);
  Grab& find_grab(int handle);
  // Collisions: per-sub-step contacts with the colliders, and self-collision.
  SelfCollision self_;
  std::vector<Contact> contacts_;
  ContactSummary contact_summary_;
  std::vector<Real> margin_;  // m, per group
  std::vector<std::uint32_t> stamps_;
  std::uint32_t stamp_ = 0;
  std::unordered_set<std::uint64_t> reported_models_;  // models whose material notes were reported
  std::unordered_set<std::uint64_t> degenerate_reported_;  // models whose degenerate state was reported
  std::uint64_t degenerate_model_ = 0;                     // the model last checked, and the state's step
  std::int64_t degenerate_next_ = 0;                       // at which it is checked again
};

// The stiffness used in each of n iterations so that n of them act like one of stiffness k:
// 1 - (1 - k)^(1/n) (Müller 2007 §3.3).
Real corrected_stiffness(Real k, int iterations);

}  // namespace csb
