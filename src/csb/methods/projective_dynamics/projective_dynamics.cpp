#include "csb/methods/projective_dynamics/projective_dynamics.hpp"

#include "csb/constraints/bending.hpp"
#include "csb/constraints/volume.hpp"
#include "csb/format.hpp"
#include "csb/implicit_euler.hpp"
#include "csb/reference.hpp"
#include "csb/solver/team.hpp"

#include <Eigen/Dense>
#include <Eigen/Eigenvalues>
#include <Eigen/SparseCholesky>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <sstream>
#include <string>
#include <thread>

namespace csb {

using detail::str;

namespace {

// Gauss-Newton steps of a generic projection (bending, volumes, families), at most.
constexpr int kProjectionSteps = 10;
// ... stopping once |C| is below this fraction of its value at the centred positions.
constexpr Real kProjectionTolerance = 1e-9;
// Constraints per task of the local step, particles per task of the gather: fixed, so that
// which thread does what never changes a result (each task writes its own slots).
constexpr Index kTermsPerTask = 256;
constexpr Index kParticlesPerTask = 512;
// Automatic threads: one per this many terms (a thread's barrier wake-ups cost tens of µs, a
// few thousand projections' worth), at most the cores and kMaxAutoThreads.
constexpr Index kTermsPerThread = 4096;
constexpr int kMaxAutoThreads = 8;

using Llt = Eigen::SimplicialLLT<Eigen::SparseMatrix<Real>>;

void check_settings(const ProjectiveDynamicsSettings& s) {
  if (!(s.dt > 0) || !std::isfinite(s.dt)) throw InvalidArgument("dt must be a finite time step > 0 s, got " + str(s.dt));
  if (s.substeps < 1) throw InvalidArgument("substeps must be >= 1, got " + std::to_string(s.substeps));
  if (s.iterations < 1) throw InvalidArgument("iterations must be >= 1, got " + std::to_string(s.iterations));
  if (!s.gravity.allFinite()) throw InvalidArgument("gravity must be finite, got " + str(s.gravity));
  if (!(s.spectral_radius >= 0 && s.spectral_radius < 1))
    throw InvalidArgument("spectral_radius must be in (0, 1), or 0 to measure it each sub-step, got " +
                          str(s.spectral_radius));
  if (s.chebyshev_delay < 0) throw InvalidArgument("chebyshev_delay must be >= 0 iterations, got " + std::to_string(s.chebyshev_delay));
  if (!(s.relaxation > 0 && s.relaxation <= 1))
    throw InvalidArgument("relaxation must be in (0, 1], got " + str(s.relaxation));
  if (s.threads < 0) throw InvalidArgument("threads must be >= 0 (0: automatic), got " + std::to_string(s.threads));
  if (s.chebyshev && s.spectral_radius == 0 && s.chebyshev_delay < 2)
    throw InvalidArgument("chebyshev_delay must be >= 2 iterations to measure the spectral radius (spectral_radius "
                          "0), got " + std::to_string(s.chebyshev_delay) + ": give spectral_radius in (0, 1)");
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

// ------------------------------------------------------------------------------ the cache

// Every term of the projective energy, L's factorisation and the gather CSR of one model and
// sub-step length h. Terms are numbered distance, attachments, bending, volumes, then each
// family's; term t of arity k owns the right-hand-side slots [slot_start[t], slot_start[t] + k)
// (3 reals each): w (Aᵀp)_i for its particles, pinned ones included (not gathered).
struct ProjectiveDynamicsStepper::Cache {
  std::uint64_t model_id = 0;
  Real h = 0;
  Index n = 0;                   // particles
  std::vector<Index> dynamic;    // particle of each unknown
  std::vector<Index> slot_of;    // unknown of each particle, -1 if pinned
  std::vector<Real> mass;        // kg, per unknown

  // Weights (N/m) per term of each kind, in the batches' order.
  std::vector<Real> w_distance, w_attachment, w_bending, w_volume;
  struct Family {
    const FamilyBatch* batch = nullptr;
    std::unique_ptr<FamilyBatch> local;  // the same constraints over private particle numbers
    int arity = 0;
    bool unilateral = false;
    std::vector<Real> w;
    Index first_slot = 0;
  };
  std::vector<Family> families;
  // Balloons: the centring operator over a whole surface makes L dense there, but only by a
  // rank-one term per balloon: L = L_s + U D Uᵀ with L_s sparse (the rest, and w_b on the
  // diagonal of balloon b's unknowns), U's column b the indicator of b's unknowns and
  // D_bb = -w_b/n_b. L_s is factored; L⁻¹ by the Woodbury identity,
  // L⁻¹ = L_s⁻¹ - W (D⁻¹ + UᵀW)⁻¹ Wᵀ, W = L_s⁻¹ U.
  struct Balloon {
    Index first_slot = 0;
    Real w = 0;       // N/m, |∇V|²/α at rest
    Real target = 0;  // m³, pressure × rest volume
  };
  std::vector<Balloon> balloons;
  std::vector<Index> iota;  // 0, 1, 2, ...: a balloon's own numbering of its particles
  Eigen::MatrixXd U, W;     // nd x balloons
  Eigen::VectorXd D;        // N/m, -w_b/n_b per balloon
  Eigen::PartialPivLU<Eigen::MatrixXd> capacitance;  // D⁻¹ + UᵀW
  Index first_attachment = 0, first_bending = 0, first_volume = 0;  // slot offsets
  Index num_slots = 0;
  Index num_fixed_terms = 0;     // distance + attachments + bending + volumes

  // Per unknown s: its slots, gathered in increasing order: slots[gather_start[s] .. [s + 1]).
  std::vector<Index> gather_start, gather;
  // The pinned particles' share of the right-hand side: unknown s -= coeff × x_pinned, in order.
  struct Coupling {
    Index s, pinned;
    Real coeff;  // N/m
  };
  std::vector<Coupling> couplings;
  Eigen::SparseMatrix<Real> L;   // N/m, L_s below (L itself without balloons)
  Llt llt;

  void build(const Model& model, Real h_);
  void add_scalar(std::vector<Eigen::Triplet<Real>>& entries, const Index* particles, int k, const Real* ata, Real w);
};

void ProjectiveDynamicsStepper::Cache::add_scalar(std::vector<Eigen::Triplet<Real>>& entries, const Index* particles,
                                                  int k, const Real* ata, Real w) {
  // The scalar block w AᵀA (k x k, row-major) of a term: unknowns into L, pinned columns into the
  // right-hand side's couplings.
  for (int i = 0; i < k; ++i) {
    const Index si = slot_of[particles[i]];
    if (si < 0) continue;
    for (int j = 0; j < k; ++j) {
      const Real c = w * ata[i * k + j];
      const Index sj = slot_of[particles[j]];
      if (sj >= 0)
        entries.emplace_back(si, sj, c);
      else
        couplings.push_back({si, particles[j], c});
    }
  }
}

void ProjectiveDynamicsStepper::Cache::build(const Model& model, Real h_) {
  model_id = model.id;
  h = h_;
  n = model.num_particles();
  dynamic.clear();
  mass.clear();
  slot_of.assign(static_cast<std::size_t>(n), -1);
  for (Index i = 0; i < n; ++i)
    if (model.inv_mass[i] > 0) {
      slot_of[i] = static_cast<Index>(dynamic.size());
      dynamic.push_back(i);
      mass.push_back(model.mass[i]);
    }
  const Index nd = static_cast<Index>(dynamic.size());
  couplings.clear();
  std::vector<Eigen::Triplet<Real>> entries;
  const Positions& X = model.rest_positions;

  // distance: A = [1, -1], AᵀA = [[1, -1], [-1, 1]], w = 1/α
  const DistanceBatch& d = model.distance;
  static const Real ata2[4] = {1, -1, -1, 1};
  w_distance.resize(static_cast<std::size_t>(d.size()));
  for (Index c = 0; c < d.size(); ++c) {
    w_distance[c] = 1 / d.compliance[c];
    add_scalar(entries, d.particles[c].data(), 2, ata2, w_distance[c]);
  }
  // attachments: A = [1], w = 1/α
  const AttachmentBatch& a = model.attachments;
  static const Real ata1[1] = {1};
  first_attachment = 2 * d.size();
  w_attachment.resize(static_cast<std::size_t>(a.size()));
  for (Index c = 0; c < a.size(); ++c) {
    w_attachment[c] = 1 / a.compliance[c];
    add_scalar(entries, &a.particle[c], 1, ata1, w_attachment[c]);
  }
  // The centring operator of k particles, A = I - 11ᵀ/k: AᵀA = A.
  auto centring = [](int k) {
    std::vector<Real> m(static_cast<std::size_t>(k * k));
    for (int i = 0; i < k; ++i)
      for (int j = 0; j < k; ++j) m[i * k + j] = (i == j ? 1 : 0) - Real(1) / k;
    return m;
  };
  const std::vector<Real> centring4 = centring(4);
  // bending: w = |∇θ|²/α at rest
  const BendingBatch& b = model.bending;
  first_bending = first_attachment + a.size();
  w_bending.resize(static_cast<std::size_t>(b.size()));
  for (Index c = 0; c < b.size(); ++c) {
    const auto& p = b.particles[c];
    const BendingGeometry g = bending_geometry(X.col(p[0]), X.col(p[1]), X.col(p[2]), X.col(p[3]), 1, 1, 1, 1,
                                               b.rest_angle[c]);
    if (!(g.ok && g.wgrad > 0))
      throw InvalidArgument("bending constraint " + std::to_string(c) + " is degenerate at rest (a zero-length edge "
                            "or a zero-area triangle): Projective Dynamics weighs it by |∇θ|² at rest");
    w_bending[c] = g.wgrad / b.compliance[c];
    add_scalar(entries, p.data(), 4, centring4.data(), w_bending[c]);
  }
  // volumes: w = |∇V|²/α at rest
  const VolumeBatch& v = model.volume;
  first_volume = first_bending + 4 * b.size();
  w_volume.resize(static_cast<std::size_t>(v.size()));
  for (Index c = 0; c < v.size(); ++c) {
    const auto& p = v.particles[c];
    const VolumeGeometry g = volume_geometry(X.col(p[0]), X.col(p[1]), X.col(p[2]), X.col(p[3]), 1, 1, 1, 1,
                                             v.rest_volume[c]);
    if (!g.ok)
      throw InvalidArgument("volume constraint " + std::to_string(c) + " is degenerate at rest: Projective Dynamics "
                            "weighs it by |∇V|² at rest");
    w_volume[c] = g.wgrad / v.compliance[c];
    add_scalar(entries, p.data(), 4, centring4.data(), w_volume[c]);
  }
  num_fixed_terms = d.size() + a.size() + b.size() + v.size();
  // families: w = |∇C|²/α at rest; a private copy numbers constraint c's particles c arity + j
  Index slot = first_volume + 4 * v.size();
  families.clear();
  for (const auto& fb : model.families) {
    Family f;
    f.batch = fb.get();
    const FamilyInfo& info = fb->info();
    f.arity = info.arity;
    f.unilateral = info.unilateral;
    f.first_slot = slot;
    const Index m = fb->size();
    const int k = f.arity, np = info.num_params();
    std::vector<Real> rest(3 * static_cast<std::size_t>(n));
    std::copy(X.data(), X.data() + 3 * n, rest.begin());
    std::vector<Real> cval(static_cast<std::size_t>(m)), grad(static_cast<std::size_t>(m) * k * 3);
    if (m > 0) fb->evaluate(rest.data(), cval.data(), grad.data());
    f.local = info.make();
    const std::vector<Real> ata = centring(k);
    f.w.resize(static_cast<std::size_t>(m));
    std::vector<Index> ids(static_cast<std::size_t>(k));
    const Index* parts = fb->particle_data();
    const Real* params = fb->param_data();
    for (Index c = 0; c < m; ++c) {
      Real g2 = 0;
      for (int e = 0; e < 3 * k; ++e) g2 += grad[static_cast<std::size_t>(c) * k * 3 + e] * grad[static_cast<std::size_t>(c) * k * 3 + e];
      if (!(g2 > 0))
        throw InvalidArgument(info.label + " constraint " + std::to_string(c) + " has no gradient at rest: Projective "
                              "Dynamics weighs it by |∇C|² at rest");
      f.w[c] = g2 / fb->compliance[c];
      for (int j = 0; j < k; ++j) ids[j] = static_cast<Index>(c * k + j);
      f.local->append(ids.data(), params + static_cast<std::size_t>(c) * np, fb->stiffness[c], fb->compliance[c]);
      add_scalar(entries, parts + static_cast<std::size_t>(c) * k, k, ata.data(), f.w[c]);
    }
    slot += k * m;
    families.push_back(std::move(f));
  }
  // balloons: w = |∇V|²/α at rest; the diagonal part of w AᵀA into L_s, the rank-one part below
  const BalloonBatch& bb = model.balloons;
  balloons.clear();
  Index largest = 0;
  for (Index c = 0; c < bb.size(); ++c) {
    const Index nb = bb.num_particles(c);
    const Index* parts = bb.particles.data() + bb.particle_offsets[c];
    std::vector<Vec3> grad(static_cast<std::size_t>(nb));
    enclosed_volume_gradient(X.data(), parts, nb, bb.triangles.data() + bb.triangle_offsets[c], bb.num_triangles(c),
                             grad.data());
    Real g2 = 0;
    for (const Vec3& g : grad) g2 += g.squaredNorm();
    if (!(g2 > 0))
      throw InvalidArgument("balloon constraint " + std::to_string(c) + " has no volume gradient at rest: Projective "
                            "Dynamics weighs it by |∇V|² at rest");
    Balloon B;
    B.first_slot = slot;
    B.w = g2 / bb.compliance[c];
    B.target = bb.pressure[c] * bb.rest_volume[c];
    for (Index i = 0; i < nb; ++i) {
      const Index si = slot_of[parts[i]];
      if (si < 0) continue;
      entries.emplace_back(si, si, B.w);
      for (Index j = 0; j < nb; ++j)  // (AᵀA)_ij = -1/n_b towards the pinned ones
        if (slot_of[parts[j]] < 0) couplings.push_back({si, parts[j], -B.w / nb});
    }
    slot += nb;
    largest = std::max(largest, nb);
    balloons.push_back(B);
  }
  iota.resize(static_cast<std::size_t>(largest));
  for (Index i = 0; i < largest; ++i) iota[i] = i;
  num_slots = slot;

  // The gather CSR: each unknown's slots in increasing order.
  gather_start.assign(static_cast<std::size_t>(nd) + 1, 0);
  std::vector<Index> slot_particle(static_cast<std::size_t>(num_slots));
  {
    Index s = 0;
    for (Index c = 0; c < d.size(); ++c) slot_particle[s++] = d.particles[c][0], slot_particle[s++] = d.particles[c][1];
    for (Index c = 0; c < a.size(); ++c) slot_particle[s++] = a.particle[c];
    for (Index c = 0; c < b.size(); ++c)
      for (int j = 0; j < 4; ++j) slot_particle[s++] = b.particles[c][j];
    for (Index c = 0; c < v.size(); ++c)
      for (int j = 0; j < 4; ++j) slot_particle[s++] = v.particles[c][j];
    for (const Family& f : families) {
      const Index* parts = f.batch->particle_data();
      for (Index e = 0; e < f.arity * f.batch->size(); ++e) slot_particle[s++] = parts[e];
    }
    for (Index c = 0; c < bb.size(); ++c)
      for (Index o = bb.particle_offsets[c]; o < bb.particle_offsets[c + 1]; ++o) slot_particle[s++] = bb.particles[o];
  }
  for (Index s = 0; s < num_slots; ++s)
    if (slot_of[slot_particle[s]] >= 0) ++gather_start[slot_of[slot_particle[s]] + 1];
  for (Index s = 0; s < nd; ++s) gather_start[s + 1] += gather_start[s];
  gather.assign(static_cast<std::size_t>(gather_start[nd]), 0);
  {
    std::vector<Index> fill(gather_start.begin(), gather_start.end() - 1);
    for (Index s = 0; s < num_slots; ++s) {
      const Index u = slot_of[slot_particle[s]];
      if (u >= 0) gather[fill[u]++] = s;
    }
  }

  // L = M/h² + Σ w AᵀA over the unknowns.
  for (Index s = 0; s < nd; ++s) entries.emplace_back(s, s, mass[s] / (h * h));
  L.resize(nd, nd);
  L.setFromTriplets(entries.begin(), entries.end());
  llt.compute(L);
  if (llt.info() != Eigen::Success)
    throw SimulationError("projective dynamics: the global matrix M/h² + Σ w AᵀA (h = " + str(h) +
                          " s) could not be factored (not positive definite)");
  const Index nbal = bb.size();
  if (nbal > 0) {
    U = Eigen::MatrixXd::Zero(nd, nbal);
    D.resize(nbal);
    Eigen::MatrixXd Cap = Eigen::MatrixXd::Zero(nbal, nbal);
    for (Index c = 0; c < nbal; ++c) {
      for (Index o = bb.particle_offsets[c]; o < bb.particle_offsets[c + 1]; ++o)
        if (slot_of[bb.particles[o]] >= 0) U(slot_of[bb.particles[o]], c) = 1;
      D(c) = -balloons[c].w / static_cast<Real>(bb.num_particles(c));
      Cap(c, c) = 1 / D(c);
    }
    W = llt.solve(U);
    Cap += U.transpose() * W;
    capacitance.compute(Cap);
  } else {
    U.resize(0, 0);
    W.resize(0, 0);
    D.resize(0);
  }
}

// ------------------------------------------------------------------------------ the stepper

ProjectiveDynamicsStepper::ProjectiveDynamicsStepper(const ProjectiveDynamicsSettings& settings)
    : settings_(settings) {
  check_settings(settings_);
}
ProjectiveDynamicsStepper::~ProjectiveDynamicsStepper() = default;
ProjectiveDynamicsStepper::ProjectiveDynamicsStepper(const ProjectiveDynamicsStepper& o)
    : settings_(o.settings_), stats_(o.stats_) {}  // a copy factors afresh
ProjectiveDynamicsStepper& ProjectiveDynamicsStepper::operator=(const ProjectiveDynamicsStepper& o) {
  settings_ = o.settings_;
  stats_ = o.stats_;
  cache_.reset();
  return *this;
}

void ProjectiveDynamicsStepper::step(const Model& model, State& state, std::int64_t steps,
                                     const std::function<bool()>& interrupt) {
  const UseGuard::Scope in_use(use_, "ProjectiveDynamics.step");
  check_implicit_step(model, state, steps);
  const Real h = settings_.dt / settings_.substeps;
  if (steps == 0) return;
  if (!cache_ || cache_->model_id != model.id || cache_->h != h) {
    // The spring network names a hard constraint and refuses a model with nothing that moves.
    try {
      const SpringNetwork check(model, state, ReferenceSettings{}, /*with_jacobian=*/false);
    } catch (const InvalidArgument& e) {
      throw InvalidArgument(std::string("Projective Dynamics weighs each constraint by 1/α: ") + e.what());
    }
    const auto t0 = std::chrono::steady_clock::now();
    auto fresh = std::make_unique<Cache>();
    fresh->build(model, h);
    cache_ = std::move(fresh);
    stats_.last_factorization_time = seconds_since(t0);
    stats_.factorization_time += stats_.last_factorization_time;
    ++stats_.factorizations;
  }
  run_implicit_steps(model, state, steps, settings_.substeps, settings_.dt, interrupt,
                     [&](int sub) { solve_one(model, state, h, sub); }, &self_collision_);
}

namespace {

// The generic projection of k centred positions y (3 k, in place) onto {C = 0}: Gauss-Newton
// steps with equal weights. `eval` gives C and ∇C (false: no direction). Unilateral: only while
// C > 0.
template <class Eval>
void project_generic(Real* y, int k, bool unilateral, Eval&& eval) {
  Vec3 g[8];
  Real c = 0;
  if (!eval(y, c, g)) return;
  const Real c0 = std::abs(c);
  for (int step = 0; step < kProjectionSteps; ++step) {
    if (unilateral ? !(c > kProjectionTolerance * c0) : !(std::abs(c) > kProjectionTolerance * c0)) break;
    Real g2 = 0;
    for (int j = 0; j < k; ++j) g2 += g[j].squaredNorm();
    if (!(g2 > 0)) break;
    const Real s = c / g2;
    for (int j = 0; j < k; ++j)
      for (int e = 0; e < 3; ++e) y[3 * j + e] -= s * g[j][e];
    if (!eval(y, c, g)) break;
  }
}

// y = the centred positions of k particles (3 k).
void centre(const Real* x, const Index* particles, int k, Real* y) {
  Real mean[3] = {0, 0, 0};
  for (int j = 0; j < k; ++j)
    for (int e = 0; e < 3; ++e) mean[e] += x[3 * particles[j] + e];
  for (int e = 0; e < 3; ++e) mean[e] /= k;
  for (int j = 0; j < k; ++j)
    for (int e = 0; e < 3; ++e) y[3 * j + e] = x[3 * particles[j] + e] - mean[e];
}

// out = w A p for the centring operator (p's mean removed: Aᵀp = Ap), 3 k.
void centred_contribution(const Real* p, int k, Real w, Real* out) {
  Real mean[3] = {0, 0, 0};
  for (int j = 0; j < k; ++j)
    for (int e = 0; e < 3; ++e) mean[e] += p[3 * j + e];
  for (int e = 0; e < 3; ++e) mean[e] /= k;
  for (int j = 0; j < k; ++j)
    for (int e = 0; e < 3; ++e) out[3 * j + e] = w * (p[3 * j + e] - mean[e]);
}

using Block = Eigen::Matrix<Real, Eigen::Dynamic, 3>;

// <a, b>_L = Σ_e a_eᵀ L b_e over the three coordinates (Lb given).
Real l_dot(const Block& a, const Block& lb) { return (a.array() * lb.array()).sum(); }

// The largest Ritz value of the plain iteration's linearisation G from its successive updates
// d[k + 1] = G d[k] (Rayleigh-Ritz on their Krylov space). G = I - γ L⁻¹H is self-adjoint in
// the L-inner product (L G = L - γ H is symmetric: a closest-point projection's derivative is
// symmetric, the Gauss-Newton projection's nearly so), so its Ritz values lie within its spectrum:
// the largest tends to the spectral radius from below, far faster than the ratio of update norms
// does (Lanczos against the power method), and does not overshoot it where the iteration is
// linear. Basis: d[first .. m - 1], L-orthonormalised by modified Gram-Schmidt (a nearly
// dependent one dropped), the images d[first + 1 .. m] carried along by the same combinations
// (G is linear). Returns the largest Ritz value below
// 1: one above comes from unilateral constraints (tethers, inequalities) switching between slack
// and taut during those iterations, a non-smooth change the linear model does not describe (on a
// 32x32 cloth with tethers, half the sub-steps had one; the largest below it still accelerates).
template <class ApplyL>
Real largest_ritz_value(const std::vector<Block>& d, std::size_t first, ApplyL&& apply_l) {
  std::vector<Block> v, g, lv;
  for (std::size_t k = first; k + 1 < d.size(); ++k) {
    Block vk = d[k], gk = d[k + 1];
    Block lk = apply_l(vk);
    const Real n0 = std::sqrt(std::max(Real(0), l_dot(vk, lk)));
    for (std::size_t j = 0; j < v.size(); ++j) {
      const Real c = l_dot(vk, lv[j]);
      vk -= c * v[j];
      gk -= c * g[j];
      lk -= c * lv[j];
    }
    const Real n = std::sqrt(std::max(Real(0), l_dot(vk, lk)));
    if (!(n > 1e-8 * n0)) continue;
    v.push_back(vk / n);
    g.push_back(gk / n);
    lv.push_back(lk / n);
  }
  if (v.empty()) return 0;
  const Eigen::Index m = static_cast<Eigen::Index>(v.size());
  Eigen::MatrixXd T(m, m);
  for (Eigen::Index i = 0; i < m; ++i)
    for (Eigen::Index j = 0; j < m; ++j) T(i, j) = l_dot(g[static_cast<std::size_t>(j)], lv[static_cast<std::size_t>(i)]);
  const Eigen::MatrixXd Ts = (T + T.transpose()) / 2;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(Ts, Eigen::EigenvaluesOnly);
  if (eig.info() != Eigen::Success) return 0;
  for (Eigen::Index k = m; k-- > 0;)
    if (eig.eigenvalues()(k) < 1) return eig.eigenvalues()(k);
  return 0;
}

}  // namespace

void ProjectiveDynamicsStepper::solve_one(const Model& model, State& state, Real h, int sub) {
  const Cache& C = *cache_;
  const Index nd = static_cast<Index>(C.dynamic.size());
  const Index n = C.n;
  const Real ih2 = 1 / (h * h);
  const ProjectiveDynamicsSettings& S = settings_;

  // x̃ and the constant part of the right-hand side: M x̃/h² minus the pinned particles' couplings.
  Eigen::Matrix<Real, Eigen::Dynamic, 3> q(nd, 3), q_prev(nd, 3), b0(nd, 3), rhs(nd, 3), q_hat(nd, 3);
  for (Index s = 0; s < nd; ++s)
    for (int e = 0; e < 3; ++e) {
      const Index i = C.dynamic[s];
      q(s, e) = state.x(e, i) + h * state.v(e, i) + h * h * S.gravity[e];
      b0(s, e) = C.mass[s] * q(s, e) * ih2;
    }
  for (const Cache::Coupling& c : C.couplings)
    for (int e = 0; e < 3; ++e) b0(c.s, e) -= c.coeff * state.x(e, c.pinned);
  q_prev = q;

  // The sub-step's contacts, from xⁿ towards x̃, and the slots of their particles.
  const bool touching = !model.colliders.empty();
  Positions x_start, x_tilde;
  std::vector<Index> contact_slot;
  if (touching) {
    x_start = state.x;
    x_tilde = state.x;
    for (Index s = 0; s < nd; ++s)
      for (int e = 0; e < 3; ++e) x_tilde(e, C.dynamic[s]) = q(s, e);
    contacts_.generate(model, x_start, x_tilde, h, PenaltyContacts::kDefaultStiffness);
    for (const Contact& k : contacts_.contacts()) contact_slot.push_back(C.slot_of[static_cast<std::size_t>(k.particle)]);
  }

  // All particles' positions (3 n): the pinned ones where the state has them.
  std::vector<Real> xf(3 * static_cast<std::size_t>(n));
  std::copy(state.x.data(), state.x.data() + 3 * n, xf.begin());
  auto scatter = [&](const Eigen::Matrix<Real, Eigen::Dynamic, 3>& from) {
    for (Index s = 0; s < nd; ++s)
      for (int e = 0; e < 3; ++e) xf[3 * static_cast<std::size_t>(C.dynamic[s]) + e] = from(s, e);
  };
  scatter(q);

  std::vector<Real> slots(3 * static_cast<std::size_t>(C.num_slots), 0.0);

  // The backward-Euler residual, if asked: its potential is built for this sub-step.
  std::unique_ptr<IncrementalPotential> potential;
  std::vector<Real> rx, rr;
  stats_.residual_history.clear();
  auto record = [&]() {
    if (!potential) return;
    for (Index s = 0; s < nd; ++s)
      for (int e = 0; e < 3; ++e) rx[3 * s + e] = q(s, e);
    potential->gradient(rx.data(), rr.data());
    Real m = 0;
    for (Real r : rr) m = std::max(m, std::abs(r));
    stats_.residual_history.push_back(m);
  };
  if (S.record_residuals) {
    potential = std::make_unique<IncrementalPotential>(model, state, state, h, S.gravity);
    rx.resize(3 * static_cast<std::size_t>(nd));
    rr.resize(rx.size());
    record();
  }

  // Tasks of the local step: chunks of the fixed-form terms, then one per family batch.
  const Index fixed_tasks = (C.num_fixed_terms + kTermsPerTask - 1) / kTermsPerTask;
  const Index family_tasks = static_cast<Index>(C.families.size());
  const Index local_tasks = fixed_tasks + family_tasks + static_cast<Index>(C.balloons.size());
  const Index gather_tasks = (nd + kParticlesPerTask - 1) / kParticlesPerTask;
  const Index nd_dist = model.distance.size(), nd_att = model.attachments.size(), nd_bend = model.bending.size();

  auto local_fixed = [&](Index t) {
    const Index lo = t * kTermsPerTask, hi = std::min(C.num_fixed_terms, lo + kTermsPerTask);
    Real y[12], out[12];
    for (Index j = lo; j < hi; ++j) {
      if (j < nd_dist) {
        const Index c = j;
        const DistanceBatch& d = model.distance;
        const Index ia = d.particles[c][0], ib = d.particles[c][1];
        Vec3 e(xf[3 * ia] - xf[3 * ib], xf[3 * ia + 1] - xf[3 * ib + 1], xf[3 * ia + 2] - xf[3 * ib + 2]);
        const Real len = e.norm(), L = d.rest_length[c];
        const int sense = d.sense[c];
        const bool satisfied = (sense > 0 && len >= L) || (sense < 0 && len <= L) || !(len > 0);
        const Vec3 p = satisfied ? e : Vec3(e * (L / len));
        Real* o = slots.data() + 3 * static_cast<std::size_t>(2 * c);
        const Real w = C.w_distance[c];
        for (int k = 0; k < 3; ++k) o[k] = w * p[k], o[3 + k] = -(w * p[k]);
      } else if (j < nd_dist + nd_att) {
        const Index c = j - nd_dist;
        Real* o = slots.data() + 3 * static_cast<std::size_t>(C.first_attachment + c);
        const Real w = C.w_attachment[c];
        for (int k = 0; k < 3; ++k) o[k] = w * model.attachments.target(k, c);
      } else if (j < nd_dist + nd_att + nd_bend) {
        const Index c = j - nd_dist - nd_att;
        const Real rest = model.bending.rest_angle[c];
        centre(xf.data(), model.bending.particles[c].data(), 4, y);
        project_generic(y, 4, false, [rest](const Real* z, Real& cv, Vec3* g) {
          const BendingGeometry bg = bending_geometry(Eigen::Map<const Vec3>(z), Eigen::Map<const Vec3>(z + 3),
                                                      Eigen::Map<const Vec3>(z + 6), Eigen::Map<const Vec3>(z + 9), 1,
                                                      1, 1, 1, rest);
          if (!bg.ok) return false;
          cv = bg.violation;
          for (int k = 0; k < 4; ++k) g[k] = bg.grad[k];
          return true;
        });
        centred_contribution(y, 4, C.w_bending[c], out);
        std::copy(out, out + 12, slots.data() + 3 * static_cast<std::size_t>(C.first_bending + 4 * c));
      } else {
        const Index c = j - nd_dist - nd_att - nd_bend;
        const Real rest = model.volume.rest_volume[c];
        centre(xf.data(), model.volume.particles[c].data(), 4, y);
        project_generic(y, 4, false, [rest](const Real* z, Real& cv, Vec3* g) {
          const VolumeGeometry vg = volume_geometry(Eigen::Map<const Vec3>(z), Eigen::Map<const Vec3>(z + 3),
                                                    Eigen::Map<const Vec3>(z + 6), Eigen::Map<const Vec3>(z + 9), 1, 1,
                                                    1, 1, rest);
          if (!vg.ok) return false;
          cv = vg.violation;
          for (int k = 0; k < 4; ++k) g[k] = vg.grad[k];
          return true;
        });
        centred_contribution(y, 4, C.w_volume[c], out);
        std::copy(out, out + 12, slots.data() + 3 * static_cast<std::size_t>(C.first_volume + 4 * c));
      }
    }
  };

  // A family batch: its constraints' centred positions side by side (the private batch numbers
  // constraint c's particle j as c arity + j), projected together, one evaluate per step.
  auto local_family = [&](const Cache::Family& f) {
    const Index m = f.batch->size();
    const int k = f.arity;
    if (m == 0) return;
    const Index* parts = f.batch->particle_data();
    std::vector<Real> y(3 * static_cast<std::size_t>(m) * k), cv(static_cast<std::size_t>(m)),
        grad(y.size()), c0(static_cast<std::size_t>(m));
    std::vector<char> active(static_cast<std::size_t>(m), 1);
    for (Index c = 0; c < m; ++c) centre(xf.data(), parts + static_cast<std::size_t>(c) * k, k, y.data() + 3 * static_cast<std::size_t>(c) * k);
    f.local->evaluate(y.data(), cv.data(), grad.data());
    for (Index c = 0; c < m; ++c) c0[c] = std::abs(cv[c]);
    for (int step = 0; step < kProjectionSteps; ++step) {
      bool any = false;
      for (Index c = 0; c < m; ++c) {
        if (!active[c]) continue;
        const Real v = cv[c];
        if (f.unilateral ? !(v > kProjectionTolerance * c0[c]) : !(std::abs(v) > kProjectionTolerance * c0[c])) {
          active[c] = 0;
          continue;
        }
        Real* g = grad.data() + 3 * static_cast<std::size_t>(c) * k;
        Real g2 = 0;
        for (int e = 0; e < 3 * k; ++e) g2 += g[e] * g[e];
        if (!(g2 > 0)) {
          active[c] = 0;
          continue;
        }
        Real* yc = y.data() + 3 * static_cast<std::size_t>(c) * k;
        for (int e = 0; e < 3 * k; ++e) yc[e] -= v / g2 * g[e];
        any = true;
      }
      if (!any) break;
      f.local->evaluate(y.data(), cv.data(), grad.data());
    }
    for (Index c = 0; c < m; ++c)
      centred_contribution(y.data() + 3 * static_cast<std::size_t>(c) * k, k, f.w[c],
                           slots.data() + 3 * static_cast<std::size_t>(f.first_slot + c * k));
  };

  // A balloon: its surface's centred positions projected onto V = target by Gauss-Newton steps.
  auto local_balloon = [&](Index c) {
    const BalloonBatch& bb = model.balloons;
    const Cache::Balloon& B = C.balloons[static_cast<std::size_t>(c)];
    const Index nb = bb.num_particles(c), nt = bb.num_triangles(c);
    const Triangle* tris = bb.triangles.data() + bb.triangle_offsets[c];
    std::vector<Real> y(3 * static_cast<std::size_t>(nb));
    std::vector<Vec3> g(static_cast<std::size_t>(nb));
    centre(xf.data(), bb.particles.data() + bb.particle_offsets[c], static_cast<int>(nb), y.data());
    Real cv = enclosed_volume_gradient(y.data(), C.iota.data(), nb, tris, nt, g.data()) - B.target;
    const Real c0 = std::abs(cv);
    for (int step = 0; step < kProjectionSteps && std::abs(cv) > kProjectionTolerance * c0; ++step) {
      Real g2 = 0;
      for (const Vec3& gi : g) g2 += gi.squaredNorm();
      if (!(g2 > 0)) break;
      const Real sc = cv / g2;
      for (Index i = 0; i < nb; ++i)
        for (int e = 0; e < 3; ++e) y[3 * i + e] -= sc * g[i][e];
      cv = enclosed_volume_gradient(y.data(), C.iota.data(), nb, tris, nt, g.data()) - B.target;
    }
    centred_contribution(y.data(), static_cast<int>(nb), B.w, slots.data() + 3 * static_cast<std::size_t>(B.first_slot));
  };

  auto gather = [&](Index t) {
    const Index lo = t * kParticlesPerTask, hi = std::min(nd, lo + kParticlesPerTask);
    for (Index s = lo; s < hi; ++s)
      for (int e = 0; e < 3; ++e) {
        Real sum = b0(s, e);
        for (Index k = C.gather_start[s]; k < C.gather_start[s + 1]; ++k) sum += slots[3 * static_cast<std::size_t>(C.gather[k]) + e];
        rhs(s, e) = sum;
      }
  };

  // Chebyshev state (Wang 2015, Algorithm 1).
  Real omega = 1, rho = S.chebyshev ? S.spectral_radius : 0;
  std::vector<Block> updates;  // the plain iterations' q⁽ᵏ⁺¹⁾ - q⁽ᵏ⁾, for measuring ρ
  const Real gamma = S.relaxation;
  std::string failure;

  auto global_and_accelerate = [&](int it) {
    q_hat = C.llt.solve(rhs);
    if (C.U.cols() > 0) {  // Woodbury: the balloons' rank-one terms
      const Eigen::MatrixXd corr = C.capacitance.solve(C.U.transpose() * q_hat);
      q_hat -= C.W * corr;
    }
    if (S.chebyshev) {
      const int Sd = S.chebyshev_delay;
      if (it == Sd && S.spectral_radius == 0) {
        // ρ measured from the relaxed plain iterations' update norms (the header's comment).
        // (the first update, from x̃, is the least linear: left out when there are enough)
        const Real mu = largest_ritz_value(updates, Sd >= 4 ? 1 : 0, [&C](const Block& v) {
          Block lv = C.L * v;  // L v = L_s v + U D Uᵀ v
          if (C.U.cols() > 0) lv += C.U * (C.D.asDiagonal() * (C.U.transpose() * v));
          return lv;
        });
        const Real r = 1 - (1 - mu) / gamma;
        stats_.measured_spectral_radius = r;
        rho = (r > 0 && r < 1) ? r : 0;
      }
      if (it < Sd) omega = 1;
      else if (it == Sd) omega = 2 / (2 - rho * rho);
      else omega = 4 / (4 - rho * rho * omega);
      // q⁽ᵏ⁺¹⁾ = ω (γ (q̂ - q⁽ᵏ⁾) + q⁽ᵏ⁾ - q⁽ᵏ⁻¹⁾) + q⁽ᵏ⁻¹⁾
      Eigen::Matrix<Real, Eigen::Dynamic, 3> next = omega * (gamma * (q_hat - q) + q - q_prev) + q_prev;
      if (it < Sd && S.spectral_radius == 0) updates.push_back(next - q);
      q_prev.swap(q);
      q.swap(next);
    } else {
      q.swap(q_hat);
    }
    for (std::size_t c = 0; c < contact_slot.size(); ++c) {  // onto the contacts' planes
      Real p[3] = {q(contact_slot[c], 0), q(contact_slot[c], 1), q(contact_slot[c], 2)};
      contacts_.project(c, p);
      for (int e = 0; e < 3; ++e) q(contact_slot[c], e) = p[e];
    }
    for (Index s = 0; touching && s < nd; ++s)  // and out of any collider the contacts did not foresee
      for (const Collider& col : model.colliders) {
        Real p[3] = {q(s, 0), q(s, 1), q(s, 2)};
        if (PenaltyContacts::push_out(col, model.thickness[C.dynamic[s]], p))
          for (int e = 0; e < 3; ++e) q(s, e) = p[e];
      }
    for (Index s = 0; s < nd; ++s)
      if (!(std::isfinite(q(s, 0)) && std::isfinite(q(s, 1)) && std::isfinite(q(s, 2)))) {
        std::ostringstream msg;
        msg << "projective dynamics: step " << state.step << ", sub-step " << sub << ", iteration " << it
            << ": particle " << C.dynamic[s] << "'s position became non-finite; the state is left at the end of the "
            << "last step";
        failure = msg.str();
        return;
      }
    scatter(q);
    record();
  };

  // Threads: automatic, one per kTermsPerThread terms.
  static const int cores = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  int threads = S.threads > 0 ? S.threads
                              : std::min({cores, kMaxAutoThreads,
                                          static_cast<int>(1 + (C.num_slots / 3) / kTermsPerThread)});
  threads = std::max(1, std::min<int>(threads, static_cast<int>(std::max(local_tasks, gather_tasks))));
  if (model.serial_families()) threads = 1;  // a family written in Python projects on the caller's thread
  stats_.threads_used = threads;

  if (threads == 1) {
    for (int it = 0; it < S.iterations && failure.empty(); ++it) {
      for (Index t = 0; t < fixed_tasks; ++t) local_fixed(t);
      for (const Cache::Family& f : C.families) local_family(f);
      for (Index c = 0; c < static_cast<Index>(C.balloons.size()); ++c) local_balloon(c);
      for (Index t = 0; t < gather_tasks; ++t) gather(t);
      global_and_accelerate(it);
    }
  } else {
    Team& team = team_.get();
    std::atomic<bool> stop{false};
    team.run(threads, /*spin=*/false, [&](int t) {
      std::int64_t phase = 0;
      for (int it = 0; it < S.iterations; ++it) {
        for (int task; (task = team.take(phase)) < local_tasks;) {
          if (task < fixed_tasks) local_fixed(task);
          else if (task < fixed_tasks + family_tasks) local_family(C.families[static_cast<std::size_t>(task - fixed_tasks)]);
          else local_balloon(task - fixed_tasks - family_tasks);
        }
        team.barrier();
        if (t == 0) team.reset(phase);
        ++phase;
        for (int task; (task = team.take(phase)) < gather_tasks;) gather(task);
        team.barrier();
        if (t == 0) {
          team.reset(phase);
          global_and_accelerate(it);
          if (!failure.empty()) stop.store(true, std::memory_order_relaxed);
        }
        ++phase;
        team.barrier();
        if (stop.load(std::memory_order_relaxed)) return;
      }
    });
  }
  if (!failure.empty()) throw SimulationError(failure);
  stats_.spectral_radius = rho;

  for (Index s = 0; s < nd; ++s)
    for (int e = 0; e < 3; ++e) {
      const Index i = C.dynamic[s];
      state.v(e, i) = (q(s, e) - state.x(e, i)) / h;
      state.x(e, i) = q(s, e);
    }
  for (Index i = 0; i < n; ++i)
    if (!(model.inv_mass[i] > 0)) state.v.col(i).setZero();
  if (touching) contacts_.finish_projected(model, x_start, x_tilde, state, h, S.gravity);
}

}  // namespace csb
