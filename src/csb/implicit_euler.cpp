#include "csb/implicit_euler.hpp"
#include "csb/format.hpp"

#include <Eigen/SparseCholesky>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>

namespace csb {

using detail::str;

namespace {

ReferenceSettings network_settings(const Vec3& gravity) {
  ReferenceSettings s;
  s.gravity = gravity;  // unused by the position-level network; checked finite
  return s;
}

Real max_abs(const std::vector<Real>& r) {
  Real m = 0;
  for (Real v : r) m = std::max(m, std::abs(v));
  return m;
}

Real norm2(const std::vector<Real>& r) {
  Real s = 0;
  for (Real v : r) s += v * v;
  return std::sqrt(s);
}

Vec3 slot_position(const Real* x, Index slot) { return Vec3(x[3 * slot], x[3 * slot + 1], x[3 * slot + 2]); }

void check_dt(Real dt) {
  if (!(dt > 0) || !std::isfinite(dt)) throw InvalidArgument("dt must be a finite time step > 0 s, got " + str(dt));
}

}  // namespace

// ------------------------------------------------------------------------------ the potential

IncrementalPotential::IncrementalPotential(const Model& model, const State& previous, const State& pinned_at, Real dt,
                                           const Vec3& gravity)
    : net_((check_dt(dt), model), pinned_at, network_settings(gravity), /*with_jacobian=*/false),
      dt_(dt),
      gravity_(gravity) {
  const Index n = model.num_particles();
  if (previous.x.cols() != n || previous.v.cols() != n)
    throw InvalidArgument("the previous state has " + std::to_string(previous.x.cols()) + " particles, the model " +
                          std::to_string(n));
  if (!previous.x.allFinite() || !previous.v.allFinite())
    throw InvalidArgument("the previous state has non-finite positions or velocities");
  const auto& dyn = net_.dynamic_particles();
  x_tilde_.resize(3 * dyn.size());
  for (std::size_t s = 0; s < dyn.size(); ++s)
    for (int k = 0; k < 3; ++k)
      x_tilde_[3 * s + k] = previous.x(k, dyn[s]) + dt * previous.v(k, dyn[s]) + dt * dt * gravity[k];
}

Real IncrementalPotential::energy(const Real* x) const {
  const std::size_t n = x_tilde_.size() / 3;
  Real inertia = 0;
  for (std::size_t s = 0; s < n; ++s) {
    Real d2 = 0;
    for (int k = 0; k < 3; ++k) d2 += (x[3 * s + k] - x_tilde_[3 * s + k]) * (x[3 * s + k] - x_tilde_[3 * s + k]);
    inertia += net_.mass(static_cast<Index>(s)) * d2;
  }
  Real contact = 0;
  for (std::size_t c = 0; contacts_ && c < contact_slot_.size(); ++c) {
    const Real C = contacts_->violation(c, slot_position(x, contact_slot_[c]));
    contact += contacts_->stiffness(c) * C * C;
  }
  return inertia / (2 * dt_ * dt_) + net_.potential(x) + contact / 2;
}

void IncrementalPotential::set_contacts(const PenaltyContacts* contacts) {
  contacts_ = contacts;
  contact_slot_.clear();
  if (!contacts) return;
  const auto& dyn = net_.dynamic_particles();
  std::vector<Index> slot_of(static_cast<std::size_t>(*std::max_element(dyn.begin(), dyn.end()) + 1), -1);
  for (std::size_t s = 0; s < dyn.size(); ++s) slot_of[static_cast<std::size_t>(dyn[s])] = static_cast<Index>(s);
  for (const Contact& k : contacts->contacts()) contact_slot_.push_back(slot_of[static_cast<std::size_t>(k.particle)]);
}

void IncrementalPotential::gradient(const Real* x, Real* r) const {
  const std::size_t n3 = x_tilde_.size();
  std::vector<Real> f(n3, 0.0);
  net_.add_potential_forces(x, f.data());
  const Real ih2 = 1 / (dt_ * dt_);
  for (std::size_t i = 0; i < n3; ++i) r[i] = net_.mass(static_cast<Index>(i / 3)) * (x[i] - x_tilde_[i]) * ih2 - f[i];
  for (std::size_t c = 0; contacts_ && c < contact_slot_.size(); ++c) {  // + k min(C, 0) n
    const Index s = contact_slot_[c];
    const Real kc = contacts_->stiffness(c) * contacts_->violation(c, slot_position(x, s));
    for (int k = 0; k < 3; ++k) r[3 * s + k] += kc * contacts_->contacts()[c].normal[k];
  }
}

void IncrementalPotential::hessian_entries(const Real* x, bool definite, SpringNetwork::Stiffness& work) const {
  const auto n3 = static_cast<Eigen::Index>(x_tilde_.size());
  net_.stiffness(x, definite, work);
  const Real ih2 = 1 / (dt_ * dt_);
  for (std::size_t c = 0; contacts_ && c < contact_slot_.size(); ++c) {  // k n nᵀ while C < 0
    const Index s = contact_slot_[c];
    if (!(contacts_->violation(c, slot_position(x, s)) < 0)) continue;
    const Vec3& n = contacts_->contacts()[c].normal;
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b)
        if (n[a] * n[b] != 0) work.entries.emplace_back(3 * s + a, 3 * s + b, contacts_->stiffness(c) * n[a] * n[b]);
  }
  for (Eigen::Index i = 0; i < n3; ++i) work.entries.emplace_back(i, i, net_.mass(static_cast<Index>(i / 3)) * ih2);
}

void IncrementalPotential::hessian(const Real* x, bool definite, Eigen::SparseMatrix<Real>& H,
                                   SpringNetwork::Stiffness& work) const {
  const auto n3 = static_cast<Eigen::Index>(x_tilde_.size());
  hessian_entries(x, definite, work);
  H.resize(n3, n3);
  H.setFromTriplets(work.entries.begin(), work.entries.end());
}

void IncrementalPotential::scales(const Real* x, Real& force_scale, Real& rounding) const {
  constexpr Real eps = std::numeric_limits<Real>::epsilon();
  net_.force_scale(x, force_scale, rounding);
  for (std::size_t c = 0; contacts_ && c < contact_slot_.size(); ++c)
    force_scale = std::max(force_scale, -contacts_->stiffness(c) * contacts_->violation(c, slot_position(x, contact_slot_[c])));
  const Real g = gravity_.norm(), ih2 = 1 / (dt_ * dt_);
  const std::size_t n = x_tilde_.size() / 3;
  for (std::size_t s = 0; s < n; ++s) {
    const Real m = net_.mass(static_cast<Index>(s));
    Real d2 = 0, size = 0;
    for (int k = 0; k < 3; ++k) {
      d2 += (x[3 * s + k] - x_tilde_[3 * s + k]) * (x[3 * s + k] - x_tilde_[3 * s + k]);
      size = std::max({size, std::abs(x[3 * s + k]), std::abs(x_tilde_[3 * s + k])});
    }
    force_scale = std::max({force_scale, m * g, m * std::sqrt(d2) * ih2});
    rounding = std::max(rounding, 4 * eps * m * size * ih2);
  }
}

void check_implicit_step(const Model& model, const State& state, std::int64_t steps) {
  if (steps < 0) throw InvalidArgument("steps must be >= 0, got " + std::to_string(steps));
  const Index np = model.num_particles();
  if (state.x.cols() != np || state.v.cols() != np)
    throw InvalidArgument("the state has " + std::to_string(state.x.cols()) + " particles, the model " +
                          std::to_string(np));
  if (!state.x.allFinite() || !state.v.allFinite())
    throw InvalidArgument("state.x and state.v must be finite (the state has non-finite positions or velocities)");
}

bool ImplicitSelfCollision::active(const Model& model) {
  if (model_id_ != model.id) {
    self_.prepare(model);
    model_id_ = model.id;
  }
  return !self_.empty();
}

void ImplicitSelfCollision::before(const State& state, int sub) {
  start_ = state.x;
  if (sub == 0) fresh_ = true;
}

void ImplicitSelfCollision::after(const Model& model, State& state, int substeps, Real h) {
  const Real* w = model.inv_mass.data();
  end_ = state.x;
  if (fresh_) self_.forget_candidates();  // the last step's candidates: not its bits
  fresh_ = false;
  self_.begin(model, start_, end_, w, substeps, h, false);
  self_.resolve(model, start_, end_, w, substeps, h);
  for (Index i = 0; i < model.num_particles(); ++i)
    if (!(end_.col(i) == state.x.col(i))) {
      state.v.col(i) += (end_.col(i) - state.x.col(i)) / h;
      state.x.col(i) = end_.col(i);
    }
  if (!self_.contacts().empty())
    self_.settle_velocities(
        state.x, w, [&](Index i) { return Vec3(state.v.col(i)); }, [&](Index i, const Vec3& dv) { state.v.col(i) += dv; });
}

void run_implicit_steps(const Model& model, State& state, std::int64_t steps, int substeps, Real dt,
                        const std::function<bool()>& interrupt, const std::function<void(int)>& substep,
                        ImplicitSelfCollision* self) {
  if (self && !self->active(model)) self = nullptr;
  for (std::int64_t step = 0; step < steps; ++step) {
    if (step > 0 && interrupt && interrupt())
      throw Interrupted("interrupted after " + std::to_string(step) + " of " + std::to_string(steps) +
                        " steps (t = " + str(state.t) + " s): the state is left at the end of that step");
    State start = state;
    try {
      for (int sub = 0; sub < substeps; ++sub) {
        if (self) self->before(state, sub);
        substep(sub);
        if (self) self->after(model, state, substeps, dt / substeps);
      }
    } catch (...) {
      state = std::move(start);
      throw;
    }
    state.t = start.t + dt;
    state.step = start.step + 1;
  }
}

Residual backward_euler_residual(const Model& model, const State& previous, const State& next, Real dt,
                                 const Vec3& gravity) {
  const Index n = model.num_particles();
  if (next.x.cols() != n || next.v.cols() != n)
    throw InvalidArgument("the next state has " + std::to_string(next.x.cols()) + " particles, the model " +
                          std::to_string(n));
  if (!next.x.allFinite()) throw InvalidArgument("the next state has non-finite positions");
  const IncrementalPotential P(model, previous, next, dt, gravity);
  const auto& dyn = P.network().dynamic_particles();
  std::vector<Real> x(3 * dyn.size()), r(x.size());
  for (std::size_t s = 0; s < dyn.size(); ++s)
    for (int k = 0; k < 3; ++k) x[3 * s + k] = next.x(k, dyn[s]);
  P.gradient(x.data(), r.data());
  Residual out;
  out.norm = norm2(r);
  out.max = max_abs(r);
  Real rounding = 0;
  P.scales(x.data(), out.scale, rounding);
  return out;
}

// ------------------------------------------------------------------------------ the stepper

using Ldlt = Eigen::SimplicialLDLT<Eigen::SparseMatrix<Real>>;

struct BackwardEulerStepper::Workspace {
  SpringNetwork::Stiffness work;
  Eigen::SparseMatrix<Real> H;  // compressed, as setFromTriplets leaves it
  // Per entry of work.entries, where it went in H's values the last time (a hint, checked).
  std::vector<Eigen::Index> slot;
  // Which of H's values an assembly has written (== generation), so that the first entry of a
  // position is stored and the later ones added, as setFromTriplets sums duplicates.
  std::vector<std::uint32_t> stamp;
  std::uint32_t generation = 0;
  struct Analysis {
    std::vector<Eigen::SparseMatrix<Real>::StorageIndex> outer, inner;  // the pattern it was made for
    std::unique_ptr<Ldlt> ldlt;
    std::uint64_t used = 0;
  };
  std::vector<Analysis> analyses;  // the few latest patterns (exact Hessian, Gauss-Newton, ...)
  std::uint64_t clock = 0;

  // H from `entries` (n3 x n3): bit for bit H.setFromTriplets(entries), which sums an entry's
  // duplicates in their order. While the entries' positions fill H's previous pattern exactly,
  // the values are written in place; otherwise setFromTriplets builds it afresh.
  void assemble(Eigen::Index n3) {
    const auto& entries = work.entries;
    if (slot.size() < entries.size()) slot.resize(entries.size(), -1);
    if (H.rows() == n3 && H.cols() == n3 && H.isCompressed() && H.nonZeros() > 0 && refill(entries)) return;
    H.resize(n3, n3);
    H.setFromTriplets(entries.begin(), entries.end());
    const auto* outer = H.outerIndexPtr();
    const auto* inner = H.innerIndexPtr();
    for (std::size_t t = 0; t < entries.size(); ++t) {
      const auto c = entries[t].col(), r = entries[t].row();
      slot[t] = std::lower_bound(inner + outer[c], inner + outer[c + 1], r) - inner;
    }
    stamp.assign(static_cast<std::size_t>(H.nonZeros()), 0);
    generation = 0;
  }

  bool refill(const std::vector<Eigen::Triplet<Real>>& entries) {
    const auto nnz = static_cast<std::size_t>(H.nonZeros());
    if (stamp.size() != nnz) {
      stamp.assign(nnz, 0);
      generation = 0;
    }
    if (++generation == 0) {
      std::fill(stamp.begin(), stamp.end(), 0);
      generation = 1;
    }
    const auto* outer = H.outerIndexPtr();
    const auto* inner = H.innerIndexPtr();
    Real* value = H.valuePtr();
    const Eigen::Index n = H.cols();
    std::size_t filled = 0;
    for (std::size_t t = 0; t < entries.size(); ++t) {
      const auto r = entries[t].row(), c = entries[t].col();
      if (c < 0 || c >= n) return false;
      Eigen::Index s = slot[t];
      if (!(s >= outer[c] && s < outer[c + 1] && inner[s] == r)) {
        const auto* end = inner + outer[c + 1];
        const auto* at = std::lower_bound(inner + outer[c], end, r);
        if (at == end || *at != r) return false;  // a position outside the pattern
        s = at - inner;
        slot[t] = s;
      }
      auto& mark = stamp[static_cast<std::size_t>(s)];
      if (mark != generation) {
        mark = generation;
        value[s] = entries[t].value();
        ++filled;
      } else {
        value[s] += entries[t].value();
      }
    }
    return filled == nnz;  // else a position of the pattern got no entry
  }

  // Conjugate gradients on (H + Σ w u uᵀ) dx = b, preconditioned by the inverse 3x3 diagonal
  // blocks of H (block Jacobi), from dx = 0, for at most `budget` iterations or until
  // |residual| <= tolerance |b|. Sequential sums in a fixed order: the same bits on any machine
  // thread count. Returns the iterations taken.
  int conjugate_gradients(const SpringNetwork::Stiffness& rank_one, const Real* b, Real* dx, int budget,
                          Real tolerance) {
    const Eigen::Index n3 = H.rows(), nb = n3 / 3;
    const auto* outer = H.outerIndexPtr();
    const auto* inner = H.innerIndexPtr();
    const Real* value = H.valuePtr();
    block_inverse.resize(static_cast<std::size_t>(nb));
    for (Eigen::Index s = 0; s < nb; ++s) {
      Mat3 B = Mat3::Zero();
      for (int c = 0; c < 3; ++c)
        for (auto e = outer[3 * s + c]; e < outer[3 * s + c + 1]; ++e)
          if (inner[e] >= 3 * s && inner[e] < 3 * s + 3) B(inner[e] - 3 * s, c) = value[e];
      block_inverse[static_cast<std::size_t>(s)] = B.inverse();
    }
    const auto n = static_cast<std::size_t>(n3);
    res.assign(b, b + n);
    z.resize(n), p.resize(n), q.resize(n);
    std::fill(dx, dx + n, 0.0);
    const auto precondition = [&] {
      for (Eigen::Index s = 0; s < nb; ++s) {
        const Vec3 r3(res[3 * s], res[3 * s + 1], res[3 * s + 2]);
        const Vec3 z3 = block_inverse[static_cast<std::size_t>(s)] * r3;
        for (int k = 0; k < 3; ++k) z[3 * s + k] = z3[k];
      }
    };
    const auto dot = [n](const std::vector<Real>& u, const std::vector<Real>& v) {
      Real sum = 0;
      for (std::size_t i = 0; i < n; ++i) sum += u[i] * v[i];
      return sum;
    };
    const Real stop = tolerance * std::sqrt(dot(res, res));
    precondition();
    p = z;
    Real rz = dot(res, z);
    int it = 0;
    while (it < budget) {
      std::fill(q.begin(), q.end(), 0.0);  // q = (H + Σ w u uᵀ) p
      for (Eigen::Index c = 0; c < n3; ++c)
        for (auto e = outer[c]; e < outer[c + 1]; ++e) q[static_cast<std::size_t>(inner[e])] += value[e] * p[c];
      for (std::size_t k = 0; k < rank_one.rank_one_weight.size(); ++k) {
        const std::vector<Real>& u = rank_one.rank_one_vector[k];
        const Real w = rank_one.rank_one_weight[k] * dot(u, p);
        for (std::size_t i = 0; i < n; ++i) q[i] += w * u[i];
      }
      const Real pq = dot(p, q);
      if (!(pq > 0)) break;  // H + M/h² is definite; round-off at a solved system
      const Real a = rz / pq;
      for (std::size_t i = 0; i < n; ++i) dx[i] += a * p[i], res[i] -= a * q[i];
      ++it;
      if (std::sqrt(dot(res, res)) <= stop) break;
      precondition();
      const Real rz_next = dot(res, z);
      const Real beta = rz_next / rz;
      rz = rz_next;
      for (std::size_t i = 0; i < n; ++i) p[i] = z[i] + beta * p[i];
    }
    return it;
  }
  std::vector<Mat3> block_inverse;
  std::vector<Real> res, z, p, q;

  // The LDLᵀ analysed for H's pattern: a kept one, or a new analysis (the oldest dropped).
  Ldlt& analysed() {
    const auto* outer = H.outerIndexPtr();
    const auto* inner = H.innerIndexPtr();
    const auto no = static_cast<std::size_t>(H.cols() + 1), ni = static_cast<std::size_t>(H.nonZeros());
    for (Analysis& a : analyses)
      if (a.outer.size() == no && a.inner.size() == ni && std::equal(a.outer.begin(), a.outer.end(), outer) &&
          std::equal(a.inner.begin(), a.inner.end(), inner)) {
        a.used = ++clock;
        return *a.ldlt;
      }
    constexpr std::size_t kept = 4;
    if (analyses.size() >= kept)
      analyses.erase(std::min_element(analyses.begin(), analyses.end(),
                                      [](const Analysis& a, const Analysis& b) { return a.used < b.used; }));
    Analysis a;
    a.outer.assign(outer, outer + no);
    a.inner.assign(inner, inner + ni);
    a.ldlt = std::make_unique<Ldlt>();
    a.ldlt->analyzePattern(H);
    a.used = ++clock;
    analyses.push_back(std::move(a));
    return *analyses.back().ldlt;
  }
};

BackwardEulerStepper::WorkspaceHolder::WorkspaceHolder() : p_(std::make_unique<Workspace>()) {}
BackwardEulerStepper::WorkspaceHolder::~WorkspaceHolder() = default;
BackwardEulerStepper::WorkspaceHolder::WorkspaceHolder(const WorkspaceHolder&) : p_(std::make_unique<Workspace>()) {}
BackwardEulerStepper::WorkspaceHolder& BackwardEulerStepper::WorkspaceHolder::operator=(const WorkspaceHolder&) {
  p_ = std::make_unique<Workspace>();
  return *this;
}

BackwardEulerStepper::BackwardEulerStepper(const BackwardEulerSettings& settings) : settings_(settings) {
  check_dt(settings_.dt);
  if (!settings_.gravity.allFinite()) throw InvalidArgument("gravity must be finite, got " + str(settings_.gravity));
  if (!(settings_.rtol > 0) || !std::isfinite(settings_.rtol))
    throw InvalidArgument("rtol must be a finite tolerance > 0, got " + str(settings_.rtol));
  if (settings_.substeps < 1) throw InvalidArgument("substeps must be >= 1, got " + std::to_string(settings_.substeps));
  if (settings_.max_iterations < 1)
    throw InvalidArgument("max_iterations must be >= 1, got " + std::to_string(settings_.max_iterations));
  if (settings_.newton_iterations < 0)
    throw InvalidArgument("newton_iterations must be >= 0 (0: to convergence), got " +
                          std::to_string(settings_.newton_iterations));
  if (settings_.cg_iterations < 1)
    throw InvalidArgument("cg_iterations must be >= 1, got " + std::to_string(settings_.cg_iterations));
  if (!(settings_.cg_tolerance >= 0 && settings_.cg_tolerance < 1))
    throw InvalidArgument("cg_tolerance must be in [0, 1), got " + str(settings_.cg_tolerance));
  if (!(settings_.contact_stiffness > 0) || !std::isfinite(settings_.contact_stiffness))
    throw InvalidArgument("contact_stiffness must be a finite stiffness > 0 (in units of m/h²), got " +
                          str(settings_.contact_stiffness));
  if (settings_.newton_iterations == 0) {
    if (settings_.linear_solver != BackwardEulerSettings::Linear::Direct)
      throw InvalidArgument("the converged form (newton_iterations = 0) solves directly; conjugate gradients are "
                            "for the budgeted form (newton_iterations > 0)");
    if (!settings_.line_search)
      throw InvalidArgument("the converged form (newton_iterations = 0) needs its line search");
  }
}

void BackwardEulerStepper::step(const Model& model, State& state, std::int64_t steps,
                                const std::function<bool()>& interrupt) {
  const UseGuard::Scope in_use(use_, "BackwardEuler.step");
  check_implicit_step(model, state, steps);
  const Real h = settings_.dt / settings_.substeps;
  run_implicit_steps(model, state, steps, settings_.substeps, settings_.dt, interrupt,
                     [&](int) { solve_one(model, state, h); }, &self_collision_);
}

void BackwardEulerStepper::solve_one(const Model& model, State& state, Real h) {
  const Index np = model.num_particles();
  const bool budgeted = settings_.newton_iterations > 0;
  const bool cg = budgeted && settings_.linear_solver == BackwardEulerSettings::Linear::ConjugateGradient;
  {
    IncrementalPotential P(model, state, state, h, settings_.gravity);
    const auto& dyn = P.network().dynamic_particles();
    const std::size_t n3 = 3 * dyn.size();
    const Positions x_start = model.colliders.empty() ? Positions() : state.x;
    if (!model.colliders.empty()) {  // the step's contacts, from xⁿ towards x̃
      Positions x_tilde = state.x;
      for (std::size_t s = 0; s < dyn.size(); ++s)
        for (int k = 0; k < 3; ++k) x_tilde(k, dyn[s]) = P.inertial_positions()[3 * s + k];
      contacts_.generate(model, state.x, x_tilde, h, settings_.contact_stiffness);
      P.set_contacts(&contacts_);
    }
    std::vector<Real> x = P.inertial_positions(), r(n3), dx(n3), trial(n3), rt(n3), rhs(n3);
    if (settings_.initial_guess != BackwardEulerSettings::Guess::Inertia) {
      // From xⁿ, except a particle whose prediction x̃ is past a contact's plane: it starts at x̃,
      // where its contact is active, so that the first Newton step's quadratic model holds the
      // contact (from xⁿ the penalty is flat, and a short budget would leave the particle where
      // the line search stopped it, short of the plane, with no contact force to bounce or rub).
      std::vector<char> touching(static_cast<std::size_t>(np), 0);
      for (std::size_t c = 0; c < contacts_.contacts().size() && !model.colliders.empty(); ++c) {
        const Index i = contacts_.contacts()[c].particle;
        const auto s = static_cast<std::size_t>(std::lower_bound(dyn.begin(), dyn.end(), i) - dyn.begin());  // increasing
        if (contacts_.violation(c, Vec3(x[3 * s], x[3 * s + 1], x[3 * s + 2])) < 0) touching[static_cast<std::size_t>(i)] = 1;
      }
      for (std::size_t s = 0; s < dyn.size(); ++s)
        if (!touching[static_cast<std::size_t>(dyn[s])])
          for (int k = 0; k < 3; ++k) x[3 * s + k] = state.x(k, dyn[s]);
      // Lower: whichever of the two starts has the lower E (Newton descends E from its start).
      if (settings_.initial_guess == BackwardEulerSettings::Guess::Lower &&
          !(P.energy(x.data()) < P.energy(P.inertial_positions().data())))
        x = P.inertial_positions();
    }
    BackwardEulerStats st;
    Workspace& ws = *workspace_;
    const Eigen::SparseMatrix<Real>& H = ws.H;
    const SpringNetwork::Stiffness& work = ws.work;
    for (int it = 0;; ++it) {
      P.gradient(x.data(), r.data());
      Real scale = 0, rounding = 0;
      P.scales(x.data(), scale, rounding);
      const Real res = max_abs(r), tol = settings_.rtol * scale + rounding;
      st.history.push_back(res);
      st.newton_iterations = it;
      st.residual = res;
      st.residual_norm = norm2(r);
      st.tolerance = tol;
      if (!std::isfinite(res))
        throw SimulationError("backward Euler: step " + std::to_string(state.step) + " reached a non-finite residual at "
                              "Newton iteration " + std::to_string(it) + "; the state is left at the end of the last step");
      if (res <= tol) break;
      if (budgeted && it == settings_.newton_iterations) break;  // the budget is spent
      if (!budgeted && it == settings_.max_iterations) {
        std::ostringstream msg;
        msg << "backward Euler: step " << state.step << ": Newton's residual " << res << " N after " << it
            << " iterations, above the tolerance " << tol << " N (rtol " << settings_.rtol
            << "); the state is left at the end of the last step";
        throw SimulationError(msg.str());
      }
      bool found = false;
      Real slope = 0;
      if (cg) {  // the Gauss-Newton Hessian (positive definite with M/h²), PCG on a fixed budget
        P.hessian_entries(x.data(), /*definite=*/true, ws.work);
        ws.assemble(static_cast<Eigen::Index>(n3));
        for (std::size_t i = 0; i < n3; ++i) rhs[i] = -r[i];
        st.cg_iterations += ws.conjugate_gradients(work, rhs.data(), dx.data(), settings_.cg_iterations,
                                                   settings_.cg_tolerance);
        slope = 0;
        for (std::size_t i = 0; i < n3; ++i) slope += r[i] * dx[i];
        found = std::isfinite(slope) && slope < 0;
        ++st.definiteness_fixes;
      }
      // Newton direction: the exact Hessian, else Gauss-Newton, else Gauss-Newton with a growing shift.
      for (int level = 0; level < 8 && !found && !cg; ++level) {
        P.hessian_entries(x.data(), level > 0, ws.work);
        ws.assemble(static_cast<Eigen::Index>(n3));
        if (level > 1) {
          const Real shift = std::pow(Real(100), level - 2) * 1e-6;
          for (Eigen::Index i = 0; i < ws.H.rows(); ++i) ws.H.coeffRef(i, i) *= 1 + shift;
        }
        Ldlt& ldlt = ws.analysed();
        ldlt.factorize(H);
        if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0)) continue;
        Eigen::Map<const Eigen::VectorXd> rv(r.data(), static_cast<Eigen::Index>(n3));
        Eigen::VectorXd z = -(ldlt.solve(rv));
        const std::size_t m = work.rank_one_weight.size();
        if (m > 0) {  // Woodbury: (A + U D Uᵀ)⁻¹ = A⁻¹ - A⁻¹U (D⁻¹ + UᵀA⁻¹U)⁻¹ UᵀA⁻¹
          Eigen::MatrixXd U(static_cast<Eigen::Index>(n3), static_cast<Eigen::Index>(m));
          Eigen::MatrixXd S = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(m), static_cast<Eigen::Index>(m));
          for (std::size_t b = 0; b < m; ++b) {
            U.col(static_cast<Eigen::Index>(b)) = Eigen::Map<const Eigen::VectorXd>(work.rank_one_vector[b].data(), static_cast<Eigen::Index>(n3));
            S(static_cast<Eigen::Index>(b), static_cast<Eigen::Index>(b)) = 1 / work.rank_one_weight[b];
          }
          const Eigen::MatrixXd W = ldlt.solve(U);
          S += U.transpose() * W;
          z -= W * S.ldlt().solve(U.transpose() * z);
        }
        if (!z.allFinite()) continue;
        slope = rv.dot(z);
        if (!(slope < 0)) continue;
        std::copy(z.data(), z.data() + n3, dx.begin());
        found = true;
        if (level > 0) ++st.definiteness_fixes;
      }
      if (!found) {
        if (budgeted) break;  // no descent at this iterate: the step ends where it is
        throw SimulationError("backward Euler: step " + std::to_string(state.step) +
                              ": no descent direction (the Newton matrix stays singular after shifts)");
      }
      if (!settings_.line_search) {
        for (std::size_t i = 0; i < n3; ++i) x[i] += dx[i];
        continue;
      }
      const Real e0 = P.energy(x.data());
      Real t = 1;
      bool stalled = false;
      for (;;) {
        for (std::size_t i = 0; i < n3; ++i) trial[i] = x[i] + t * dx[i];
        const Real e = P.energy(trial.data());
        if (e <= e0 + 1e-4 * t * slope) break;
        P.gradient(trial.data(), rt.data());
        if (max_abs(rt) < (1 - 1e-4 * t) * res) break;
        t /= 2;
        ++st.line_search_halvings;
        if (t < 1e-12) {
          if (budgeted) {
            stalled = true;
            break;
          }
          std::ostringstream msg;
          msg << "backward Euler: step " << state.step << ": the line search stalled at residual " << res
              << " N (tolerance " << tol << " N); the state is left at the end of the last step";
          throw SimulationError(msg.str());
        }
      }
      if (stalled) break;  // budgeted: no decrease along the direction; keep the iterate
      x.swap(trial);
    }
    for (std::size_t s = 0; s < dyn.size(); ++s)
      for (int k = 0; k < 3; ++k) {
        const Real xn = x[3 * s + k];
        state.v(k, dyn[s]) = (xn - state.x(k, dyn[s])) / h;
        state.x(k, dyn[s]) = xn;
      }
    for (Index i = 0; i < np; ++i)
      if (!(model.inv_mass[i] > 0)) state.v.col(i).setZero();
    if (!model.colliders.empty()) contacts_.finish(model, x_start, state, h, settings_.gravity);
    total_iterations_ += st.newton_iterations;
    max_residual_ = std::max(max_residual_, st.residual);
    last_ = std::move(st);
  }
}

}  // namespace csb
