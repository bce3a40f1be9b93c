// csb — the sequential sweep (Müller's loop as written: every batch in model order, one constraint after
// the other, Gauss-Seidel or Jacobi), the constraint families' sweep (both orderings) and the
// relaxation of XPBD's averaged Jacobi.
#include "csb/solver/sequential.hpp"
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/constraints/attachment.hpp"
#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"

namespace csb {

using detail::str;
using namespace stepper_detail;


void PbdStepper::project_sequential(const Model& model, const Positions& x_start) {
  const Solver solver = settings_.solver;
  const bool jacobi = solver != Solver::GaussSeidel;
  const Index n = model.num_particles();
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  set_relaxation(model);
  const Real* relax = relax_.empty() ? nullptr : relax_.data();
  for (int it = 0; it < settings_.iterations; ++it) {
    if (jacobi) {
      p_start_ = p_;
      delta_.setZero();
      std::fill(count_.begin(), count_.end(), 0.0);
    }
    Real* p = p_.data();
    const Real* from = jacobi ? p_start_.data() : p;
    Real* delta = jacobi ? delta_.data() : nullptr;
    Real* count = jacobi ? count_.data() : nullptr;
    const VolumeTerms vt{k_volume_, a_volume_, g_volume_, k_balloon_, a_balloon_, g_balloon_, balloon_grad_.data()};
    const auto run = [&](auto method, auto jacobi_tag) {
      sweep_batches<decltype(method)::value, decltype(jacobi_tag)::value>(
          model, w, settings_, p, from, x_start.data(), delta, count, k_distance_, k_bending_, k_attachment_,
          a_distance_, a_bending_, a_attachment_, g_distance_, g_bending_, g_attachment_, lambda_, vt, relax);
    };
    using Pbd = std::integral_constant<Method, Method::Pbd>;
    using Xpbd = std::integral_constant<Method, Method::Xpbd>;
    using Jak = std::integral_constant<Method, Method::Jakobsen>;
    switch (settings_.method) {
      case Method::Pbd:
        jacobi ? run(Pbd{}, std::true_type{}) : run(Pbd{}, std::false_type{});
        break;
      case Method::Xpbd:
        jacobi ? run(Xpbd{}, std::true_type{}) : run(Xpbd{}, std::false_type{});
        break;
      case Method::Jakobsen:
        jacobi ? run(Jak{}, std::true_type{}) : run(Jak{}, std::false_type{});
        break;
    }
    project_families(model, w, from, jacobi ? delta : p, count, x_start.data(), relax);
    if (!contacts_.empty() || !self_.contacts().empty()) project_contacts(model, jacobi);
    if (jacobi) {
      // Averaged Jacobi moves each particle by the mean of the corrections it received (XPBD: by
      // the sum of its relaxed ones); summed Jacobi by their sum, which overshoots where
      // constraints pull the same way.
      const bool average = solver == Solver::Jacobi && !relax;
      for (Index i = 0; i < n; ++i) {
        const Real scale = average ? (count_[i] > 0 ? 1 / count_[i] : 0) : 1;
        p_.col(i) = p_start_.col(i) + scale * delta_.col(i);
      }
      if (!contacts_.empty() && settings_.method != Method::Xpbd) settle_contact_moves(average);
    }
    project_grabs(x_start);
  }
}


void PbdStepper::project_families(const Model& model, const Real* w, const Real* read, Real* out, Real* count,
                                  const Real* x_start, const Real* relax) {
  const bool xpbd = settings_.method == Method::Xpbd;
  for (std::size_t f = 0; f < model.families.size(); ++f) {
    const FamilyBatch& batch = *model.families[f];
    if (batch.size() == 0) continue;
    FamilySweep s;
    s.xpbd = xpbd;
    s.jacobi = read != out;
    s.w = w;
    s.read = read;
    s.out = out;
    s.count = count;
    s.x_start = x_start;
    s.k = family_terms_[f].k.data();
    if (xpbd) {
      s.alpha = family_terms_[f].alpha.data();
      s.gamma = family_terms_[f].gamma.data();
      s.lambda = lambda_.family[f].data();
      s.relax = relax;
    }
    batch.sweep(s);
  }
}


// XPBD with averaged Jacobi: relax_[i] = 1/n_i, n_i the projections that reach particle i in one
// sweep (contacts included), 1 where the particle cannot move. A constraint's Δλ is scaled by
// ω = min over its particles of relax_, and each particle moves by the sum of its scaled
// corrections, so λ and the positions move together and x - p = M⁻¹∇Cᵀλ holds as in
// Gauss-Seidel: the fixed point is XPBD's (C + α̃λ = 0 with that λ). Averaging the positions
// while λ took the whole Δλ kept a softer fixed point (a hanging chain stretched up to 5/3 of
// its static stretch and λ/h² over-read the load). The scaled sum converges: per particle
// (Σ_j y_j ∇_i C_j)² <= n_i Σ_j y_j² |∇_i C_j|² (Cauchy-Schwarz), so J M⁻¹ Jᵀ + α̃ <= Ω⁻¹ D,
// D the diagonal of the kernels' denominators, and the Jacobi iteration ΩD⁻¹ has eigenvalues
// in (0, 1] on the linearised system.
void PbdStepper::set_relaxation(const Model& model) {
  if (!(settings_.method == Method::Xpbd && settings_.solver == Solver::Jacobi)) {
    relax_.clear();
    return;
  }
  if (coloured_.model_id == model.id && !coloured_.count.empty())
    relax_ = coloured_.count;
  else
    jacobi_counts(model, relax_);
  for (const Contact& k : contacts_) relax_[k.particle] += 1;
  for (const SelfContact& k : self_.contacts())
    for (Index i : k.particles) relax_[i] += 1;
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  for (Index i = 0; i < model.num_particles(); ++i) relax_[i] = w[i] > 0 && relax_[i] > 0 ? 1 / relax_[i] : 1;
}

}  // namespace csb
