// csb — constraint families: a new kind of constraint is one header that states C(p) and its
// gradient, plus one line in constraints/families.cpp's list. From the family alone this header
// derives what every method and every reference needs, so the stepper, the reference, the
// force-based integrators, the metrics, the material notes, the bindings and the scene files pick
// the new kind up without an edit of their own.
//
// A family F provides (tether.hpp is the worked example):
//
//   static constexpr const char* name;             "tethers": the Model's key, Python's view, the scene's table
//   static constexpr const char* label;            "tether": one constraint, in messages
//   static constexpr int arity;                    particles per constraint
//   static constexpr bool unilateral;              true: C <= 0 is satisfied, only C > 0 violates (an
//                                                  inequality); false: C = 0
//   static constexpr const char* compliance_unit;  SI unit of α, the inverse stiffness of C²/(2α)
//   struct Params;                                 per constraint: Reals only (the rest value, m, rad, ...)
//   static constexpr std::array<const char*, P> param_names, param_units;   Params' fields, in order
//   static std::string check(const Params&);       why a constraint cannot be made ("" when it can)
//   static bool evaluate(const Vec3 x[arity], const Params&, Real& C, Vec3 grad[arity]);
//        C and ∂C/∂x_j; false where the gradient has no direction (the constraint is then left
//        alone, as every csb kernel leaves a degenerate constraint)
//   optionally
//   static void hessian(const Vec3 x[arity], const Params&, Mat3 H[arity][arity]);   ∂²C/∂x_i∂x_j
//
// Derived here, for one constraint with particles p_j of inverse mass w_j:
//
//   PBD (Müller et al. 2007 Eq. (4)-(5)): s = C / Σ_j w_j |∇_j C|²,  Δp_i = -k s w_i ∇_i C, with
//       k ∈ [0, 1] the stiffness, which the stepper corrects per iteration as it does every PBD
//       stiffness (1 - (1 - k)^(1/n), corrected_stiffness in methods/pbd.cpp); Jakobsen projects
//       the same way.
//   XPBD (Macklin et al. 2016 Eq. (18) and (26)): with α̃ = α/h², γ = α β / h and the multiplier
//       λ accumulated over the iterations of a sub-step (zeroed at its start with every other),
//       Δλ = (-C - α̃ λ - γ Σ_j ∇_j C·(p_j - x_j)) / ((1 + γ) Σ_j w_j |∇_j C|² + α̃),
//       Δp_i = w_i ∇_i C Δλ.
//   Unilateral families: PBD projects the violation C₊ = max(C, 0), so a slack constraint moves
//       nothing; XPBD clamps the accumulated λ to λ <= 0 (the constraint only pulls back), as the
//       distance kernel's sense -1 does (distance.hpp).
//   Gauss-Seidel moves the particles in place; Jacobi reads the positions at the sweep's start and
//       adds each correction to the particle's sum, and counts it, as every batch's Jacobi does;
//       XPBD's averaged Jacobi scales Δλ and the corrections by the constraint's relaxation
//       (PbdStepper::set_relaxation).
//   The potential of the references (csb's SpringNetwork, hence CVODE and the force-based
//       integrators), with α the compliance (a hard constraint, α = 0, has none):
//         E = C₊²/(2α)                      (C₊ = C for a bilateral family)
//         f_i = -∂E/∂x_i = -(C₊/α) ∇_i C
//         ∂f_i/∂x_j = -(1/α) (∇_i C ∇_j Cᵀ + C₊ ∇²_ij C)
//       the Gauss-Newton term and, when the family gives its Hessian, the curvature term; without
//       it the Jacobian is the Gauss-Newton term alone, so the reference takes its GMRES path
//       (the Jacobian then only preconditions). PBD's k is dimensionless and is no energy.
//
// The sweep runs over the family's plain arrays (one typed array per family, Jolt's layout), one
// virtual call per batch and sweep, none per constraint. It is the scalar path: the families
// project on one thread after the coloured batches (the same order on any thread count, so the
// bits do not depend on it). The distance, bending, volume, balloon and attachment kinds are not
// families: they are csb's tuned hot paths (coloured SIMD blocks, AVX2 copies, paired edges) and
// stay as they are; the family mechanism is for new kinds.
#pragma once

#include "csb/types.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <functional>
#include <memory>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace csb {

class FamilyBatch;

// What the rest of csb reads about a family (made from F by family_info<F>()).
struct FamilyInfo {
  std::string name;             // "tethers"
  std::string label;            // "tether"
  std::string compliance_unit;  // "m/N"
  int arity = 0;
  bool unilateral = false;
  bool has_hessian = false;     // the reference's Jacobian is exact (else Gauss-Newton)
  // Projected by the caller's thread alone: a family written in Python (csb.ConstraintFamily),
  // whose projections call back into the interpreter. A model holding one is stepped on one
  // thread, so that what the callback raises reaches the caller (and the bits are those of one).
  bool serial_only = false;
  std::vector<std::string> param_names, param_units;
  std::function<std::unique_ptr<FamilyBatch>()> make;  // an empty batch of the family
  int num_params() const { return static_cast<int>(param_names.size()); }
};

// One sweep of a family batch: what the stepper hands it.
struct FamilySweep {
  bool xpbd = false;              // XPBD's multipliers (else PBD's stiffness, also Jakobsen's)
  bool jacobi = false;            // read `read`, add the corrections to `out`; else move `out` in place
  const Real* w = nullptr;        // inverse masses, 1/kg (a kinematic grab's particle at 0)
  const Real* read = nullptr;     // positions the projections read, m (Gauss-Seidel: out)
  Real* out = nullptr;            // Gauss-Seidel: the positions; Jacobi: the corrections' sums
  Real* count = nullptr;          // Jacobi: corrections per particle, incremented (null: counted beforehand)
  const Real* x_start = nullptr;  // positions at the start of the sub-step (XPBD's damping)
  const Real* k = nullptr;        // PBD, Jakobsen: stiffness per constraint, as iterated
  const Real* alpha = nullptr;    // XPBD: α̃ = α/h² per constraint
  const Real* gamma = nullptr;    // XPBD: γ = α β / h per constraint
  Real* lambda = nullptr;         // XPBD: multipliers per constraint
  const Real* relax = nullptr;    // XPBD with averaged Jacobi: relaxation per particle, else null
};

// The type-erased batch a Model holds per family: the material of every constraint (the same two
// forms every csb constraint carries, model.hpp) and what the methods and references call, once
// per batch. FamilyBatchOf<F> holds the typed arrays.
class FamilyBatch {
 public:
  virtual ~FamilyBatch() = default;
  virtual const FamilyInfo& info() const = 0;
  Index size() const { return static_cast<Index>(stiffness.size()); }

  std::vector<Real> stiffness;   // dimensionless, in [0, 1] (PBD, Jakobsen)
  std::vector<Real> compliance;  // info().compliance_unit, >= 0 (XPBD, the references)

  // The particles (arity per constraint, in order) and parameters (num_params per constraint).
  virtual const Index* particle_data() const = 0;
  virtual const Real* param_data() const = 0;
  // Appends a constraint: particles[arity], params[num_params]; the builder checks them first.
  virtual void append(const Index* particles, const Real* params, Real stiffness, Real compliance) = 0;
  // The family's own check of one constraint's parameters ("" when they are possible).
  virtual std::string check(const Real* params) const = 0;
  virtual std::unique_ptr<FamilyBatch> clone() const = 0;
  virtual std::size_t bytes() const = 0;

  // One sweep over every constraint, in order.
  virtual void sweep(const FamilySweep& s) const = 0;
  // C (size()) and ∇C (size() x arity x 3) of every constraint at positions x (3 per particle).
  virtual void evaluate(const Real* x, Real* c, Real* grad) const = 0;
  // Violations: C₊ = max(C, 0) for a unilateral family, C otherwise.
  virtual void violations(const Real* x, Real* v) const = 0;
  // Σ C₊²/(2α) over the constraints with α > 0, J.
  virtual Real energy(const Real* x) const = 0;
  // f (3 per particle) += -(C₊/α) ∇C over the constraints with α > 0, N.
  virtual void add_forces(const Real* x, Real* f) const = 0;
  // Per constraint, arity x arity blocks ∂f_i/∂x_j (3 x 3, row-major), N/m; zero for α = 0 and
  // for a slack unilateral constraint.
  virtual void stiffness_blocks(const Real* x, Real* blocks) const = 0;
};

// ------------------------------------------------------------------------------ one constraint

template <class F, class = void>
struct family_has_hessian : std::false_type {};
template <class F>
struct family_has_hessian<F, std::void_t<decltype(F::hessian(std::declval<const Vec3*>(),
                                                             std::declval<const typename F::Params&>(),
                                                             std::declval<Mat3 (*)[F::arity]>()))>>
    : std::true_type {};

template <class F>
constexpr Real family_violation(Real c) {
  if constexpr (F::unilateral)
    return std::max(c, Real(0));
  else
    return c;
}

template <class F>
void family_load(Real* const p[F::arity], Vec3 x[F::arity]) {
  for (int j = 0; j < F::arity; ++j) x[j] = Vec3(p[j][0], p[j][1], p[j][2]);
}

// The corrections of one evaluated constraint of n particles (C, its violation v and gradient g
// at the positions p, moved in place), shared by the compiled families (n their arity, a
// constant) and the ones evaluated at run time (a family written in Python).
// PBD: Δp_j = -k v w_j g_j / Σ_i w_i |g_i|².
inline void family_correct_pbd(Real* const* p, const Real* w, const Vec3* g, int n, Real v, Real k) {
  Real wg = 0;
  for (int j = 0; j < n; ++j) wg += w[j] * g[j].squaredNorm();
  if (!(wg > 0)) return;
  const Real s = k * v / wg;
  for (int j = 0; j < n; ++j)
    for (int e = 0; e < 3; ++e) p[j][e] -= s * w[j] * g[j][e];
}

// XPBD: Δλ and Δp_j = w_j Δλ g_j, λ clamped to <= 0 for a unilateral family (x0: the positions
// at the start of the sub-step, for the damping).
inline void family_correct_xpbd(Real* const* p, const Real* const* x0, const Real* w, const Vec3* g, int n, Real c,
                                bool unilateral, Real alpha_tilde, Real gamma, Real& lambda) {
  Real wg = 0;
  for (int j = 0; j < n; ++j) wg += w[j] * g[j].squaredNorm();
  if (!(wg > 0)) return;
  Real moved = 0;
  if (gamma != 0)
    for (int j = 0; j < n; ++j)
      for (int e = 0; e < 3; ++e) moved += g[j][e] * (p[j][e] - x0[j][e]);
  Real dl = (-c - alpha_tilde * lambda - gamma * moved) / ((1 + gamma) * wg + alpha_tilde);
  if (unilateral) dl = std::min(lambda + dl, Real(0)) - lambda;
  lambda += dl;
  for (int j = 0; j < n; ++j)
    for (int e = 0; e < 3; ++e) p[j][e] += w[j] * dl * g[j][e];
}

// PBD: projects one constraint of F in place (positions p, inverse masses w); returns its
// violation before the projection.
template <class F>
Real project_family_pbd(Real* const p[F::arity], const Real w[F::arity], const typename F::Params& params, Real k) {
  Vec3 x[F::arity], g[F::arity];
  family_load<F>(p, x);
  Real c = 0;
  const bool ok = F::evaluate(x, params, c, g);
  const Real v = family_violation<F>(c);
  if (!ok || v == 0) return v;
  family_correct_pbd(p, w, g, F::arity, v, k);
  return v;
}

// XPBD: projects one constraint of F in place (x0: positions at the start of the sub-step);
// returns its violation before the projection.
template <class F>
Real project_family_xpbd(Real* const p[F::arity], const Real* const x0[F::arity], const Real w[F::arity],
                         const typename F::Params& params, Real alpha_tilde, Real gamma, Real& lambda) {
  Vec3 x[F::arity], g[F::arity];
  family_load<F>(p, x);
  Real c = 0;
  const bool ok = F::evaluate(x, params, c, g);
  const Real v = family_violation<F>(c);
  if (!ok) return v;
  if constexpr (F::unilateral)
    if (v == 0 && lambda == 0) return v;  // slack, and nothing to give back
  family_correct_xpbd(p, x0, w, g, F::arity, c, F::unilateral, alpha_tilde, gamma, lambda);
  return v;
}

// ------------------------------------------------------------------------------ a typed batch

template <class F>
class FamilyBatchOf final : public FamilyBatch {
 public:
  static constexpr int arity = F::arity;
  static constexpr int num_params = static_cast<int>(std::tuple_size<decltype(F::param_names)>::value);
  using Params = typename F::Params;
  static_assert(std::is_trivially_copyable<Params>::value && sizeof(Params) == sizeof(Real) * num_params,
                "a family's Params are its param_names' Reals, in order");
  static_assert(std::tuple_size<decltype(F::param_units)>::value == num_params, "a unit per parameter");

  std::vector<std::array<Index, arity>> particles;
  std::vector<Params> params;

  const FamilyInfo& info() const override;
  const Index* particle_data() const override { return particles.empty() ? nullptr : particles[0].data(); }
  const Real* param_data() const override { return reinterpret_cast<const Real*>(params.data()); }
  void append(const Index* ids, const Real* values, Real k, Real alpha) override {
    std::array<Index, arity> q;
    std::copy(ids, ids + arity, q.begin());
    Params p;
    std::memcpy(&p, values, sizeof(Params));
    particles.push_back(q);
    params.push_back(p);
    stiffness.push_back(k);
    compliance.push_back(alpha);
  }
  std::string check(const Real* values) const override {
    Params p;
    std::memcpy(&p, values, sizeof(Params));
    return F::check(p);
  }
  std::unique_ptr<FamilyBatch> clone() const override { return std::make_unique<FamilyBatchOf>(*this); }
  std::size_t bytes() const override {
    return particles.capacity() * sizeof(particles[0]) + params.capacity() * sizeof(Params) +
           (stiffness.capacity() + compliance.capacity()) * sizeof(Real);
  }

  void sweep(const FamilySweep& s) const override {
    if (s.xpbd)
      s.jacobi ? run<true, true>(s) : run<true, false>(s);
    else
      s.jacobi ? run<false, true>(s) : run<false, false>(s);
  }

  // g: ∇C of constraint c at x; returns C; `ok` false where ∇C has no direction.
  Real geometry(const Real* x, Index c, Vec3 p[arity], Vec3 g[arity], bool& ok) const {
    for (int j = 0; j < arity; ++j) {
      const Real* q = x + 3 * static_cast<std::size_t>(particles[c][j]);
      p[j] = Vec3(q[0], q[1], q[2]);
    }
    Real value = 0;
    ok = F::evaluate(p, params[c], value, g);
    if (!ok)
      for (int j = 0; j < arity; ++j) g[j].setZero();
    return value;
  }

  void evaluate(const Real* x, Real* c, Real* grad) const override {
    Vec3 p[arity], g[arity];
    bool ok = false;
    for (Index k = 0; k < size(); ++k) {
      c[k] = geometry(x, k, p, g, ok);
      for (int j = 0; j < arity; ++j)
        for (int e = 0; e < 3; ++e) grad[(static_cast<std::size_t>(k) * arity + j) * 3 + e] = g[j][e];
    }
  }
  void violations(const Real* x, Real* v) const override {
    Vec3 p[arity], g[arity];
    bool ok = false;
    for (Index k = 0; k < size(); ++k) v[k] = family_violation<F>(geometry(x, k, p, g, ok));
  }
  Real energy(const Real* x) const override {
    Vec3 p[arity], g[arity];
    bool ok = false;
    Real e = 0;
    for (Index k = 0; k < size(); ++k) {
      if (!(compliance[k] > 0)) continue;
      const Real v = family_violation<F>(geometry(x, k, p, g, ok));
      e += v * v / (2 * compliance[k]);
    }
    return e;
  }
  void add_forces(const Real* x, Real* f) const override {
    Vec3 p[arity], g[arity];
    bool ok = false;
    for (Index k = 0; k < size(); ++k) {
      if (!(compliance[k] > 0)) continue;
      const Real v = family_violation<F>(geometry(x, k, p, g, ok));
      if (v == 0 || !ok) continue;
      for (int j = 0; j < arity; ++j)
        for (int e = 0; e < 3; ++e) f[3 * static_cast<std::size_t>(particles[k][j]) + e] -= v / compliance[k] * g[j][e];
    }
  }
  void stiffness_blocks(const Real* x, Real* blocks) const override {
    constexpr std::size_t per = static_cast<std::size_t>(arity) * arity * 9;
    std::fill(blocks, blocks + per * static_cast<std::size_t>(size()), 0.0);
    Vec3 p[arity], g[arity];
    bool ok = false;
    for (Index k = 0; k < size(); ++k) {
      if (!(compliance[k] > 0)) continue;
      const Real c = geometry(x, k, p, g, ok);
      const Real v = family_violation<F>(c);
      if (!ok || (F::unilateral && !(c > 0))) continue;
      [[maybe_unused]] Mat3 H[arity][arity];
      if constexpr (family_has_hessian<F>::value) F::hessian(p, params[k], H);
      const Real s = -1 / compliance[k];
      Real* out = blocks + per * static_cast<std::size_t>(k);
      for (int i = 0; i < arity; ++i)
        for (int j = 0; j < arity; ++j) {
          Mat3 K = g[i] * g[j].transpose();
          if constexpr (family_has_hessian<F>::value) K += v * H[i][j];
          for (int r = 0; r < 3; ++r)
            for (int q = 0; q < 3; ++q) out[(i * arity + j) * 9 + 3 * r + q] = s * K(r, q);
        }
    }
  }

 private:
  template <bool Xpbd, bool Jacobi>
  void run(const FamilySweep& s) const {
    [[maybe_unused]] Real local[arity][3];
    Real* p[arity];
    const Real* x0[arity] = {};
    Real w[arity];
    for (Index c = 0; c < size(); ++c) {
      const auto& ids = particles[c];
      for (int j = 0; j < arity; ++j) {
        const std::size_t i = static_cast<std::size_t>(ids[j]);
        if constexpr (Jacobi) {
          for (int e = 0; e < 3; ++e) local[j][e] = s.read[3 * i + e];
          p[j] = local[j];
        } else {
          p[j] = s.out + 3 * i;
        }
        if constexpr (Xpbd) x0[j] = s.x_start + 3 * i;
        w[j] = s.w[i];
      }
      Real om = 1;  // the constraint's relaxation (XPBD with averaged Jacobi)
      if constexpr (Xpbd) {
        if (s.relax)
          for (int j = 0; j < arity; ++j) om = std::min(om, s.relax[ids[j]]);
        const Real before = s.lambda[c];
        project_family_xpbd<F>(p, x0, w, params[c], s.alpha[c], s.gamma[c], s.lambda[c]);
        if (s.relax) s.lambda[c] = before + om * (s.lambda[c] - before);
      } else {
        project_family_pbd<F>(p, w, params[c], s.k[c]);
      }
      if constexpr (Jacobi) {
        for (int j = 0; j < arity; ++j) {
          const std::size_t i = static_cast<std::size_t>(ids[j]);
          for (int e = 0; e < 3; ++e) s.out[3 * i + e] += om * (local[j][e] - s.read[3 * i + e]);
          if (s.count) s.count[i] += 1;
        }
      }
    }
  }
};

// The FamilyInfo of F (one per family, made on first use).
template <class F>
const FamilyInfo& family_info() {
  static const FamilyInfo info = [] {
    FamilyInfo i;
    i.name = F::name;
    i.label = F::label;
    i.compliance_unit = F::compliance_unit;
    i.arity = F::arity;
    i.unilateral = F::unilateral;
    i.has_hessian = family_has_hessian<F>::value;
    for (const char* p : F::param_names) i.param_names.emplace_back(p);
    for (const char* u : F::param_units) i.param_units.emplace_back(u);
    i.make = [] { return std::unique_ptr<FamilyBatch>(std::make_unique<FamilyBatchOf<F>>()); };
    return i;
  }();
  return info;
}

template <class F>
const FamilyInfo& FamilyBatchOf<F>::info() const {
  return family_info<F>();
}

}  // namespace csb
