// csb — Vertex Block Descent (csb/methods/vbd/vbd.hpp).
#include "csb/methods/vbd/vbd.hpp"

#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"
#include "csb/format.hpp"
#include "csb/reference.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <functional>
#include <thread>

#if defined(__linux__)
#include <fcntl.h>
#include <unistd.h>
#endif

namespace csb {

using detail::str;

const char* initialization_name(VbdSettings::Initialization i) {
  switch (i) {
    case VbdSettings::Initialization::Adaptive: return "adaptive";
    case VbdSettings::Initialization::Inertia: return "inertia";
    case VbdSettings::Initialization::Previous: return "previous";
  }
  return "adaptive";
}

VbdSettings::Initialization parse_initialization(const std::string& name) {
  if (name == "adaptive") return VbdSettings::Initialization::Adaptive;
  if (name == "inertia") return VbdSettings::Initialization::Inertia;
  if (name == "previous") return VbdSettings::Initialization::Previous;
  throw InvalidArgument("initialization must be 'adaptive', 'inertia' or 'previous', got '" + name + "'");
}

namespace {

// What a particle belongs to: a constraint of a batch and its place in it.
enum Kind : std::uint8_t { kDistance, kBending, kVolume, kAttachment, kFamily, kBalloonTriangle };

struct Incidence {
  std::uint8_t kind;
  std::uint8_t slot;     // the particle's place in the constraint (in the triangle for a balloon)
  std::uint16_t family;  // kFamily: index into Model::families; kBalloonTriangle: unused
  Index index;           // the constraint (kBalloonTriangle: the triangle, in BalloonBatch::triangles)
};

// Greedy first-fit colouring of a graph's vertices in index order (deterministic): vertex v takes
// the lowest colour none of its already coloured neighbours (those below it) has. neighbours: CSR (start, list).
std::vector<Index> colour_vertices(const std::vector<Index>& start, const std::vector<Index>& list, Index n) {
  std::vector<Index> colour(static_cast<std::size_t>(n), -1);
  std::vector<Index> seen;  // seen[c] == v: colour c taken by a neighbour of v
  for (Index v = 0; v < n; ++v) {
    for (Index e = start[v]; e < start[v + 1]; ++e) {
      const Index c = colour[list[e]];
      if (c < 0) continue;
      if (static_cast<std::size_t>(c) >= seen.size()) seen.resize(static_cast<std::size_t>(c) + 1, -1);
      seen[c] = v;
    }
    Index c = 0;
    while (static_cast<std::size_t>(c) < seen.size() && seen[c] == v) ++c;
    colour[v] = c;
  }
  return colour;
}

// Cores not busy with other runnable tasks now (/proc/loadavg's running count, the caller and
// csb's idle spinning team threads not counted), at least 1; all of them where it is unreadable.
int free_cores() {
  static const int cores = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
#if defined(__linux__)
  char text[128];  // read with system calls into the stack: a step allocates nothing
  const int fd = ::open("/proc/loadavg", O_RDONLY);
  if (fd < 0) return cores;
  const ssize_t n = ::read(fd, text, sizeof(text) - 1);
  ::close(fd);
  if (n <= 0) return cores;
  text[n] = 0;
  double l1, l5, l15;
  int running = 1, total = 0;
  if (std::sscanf(text, "%lf %lf %lf %d/%d", &l1, &l5, &l15, &running, &total) != 5) return cores;
  running -= Team::idle_spinning();
  return std::max(1, std::min(cores, cores - (running - 1)));
#else
  return cores;
#endif
}

void check_settings(const VbdSettings& s) {
  if (!(s.dt > 0) || !std::isfinite(s.dt)) throw InvalidArgument("dt must be a finite time step > 0 s, got " + str(s.dt));
  if (s.substeps < 1) throw InvalidArgument("substeps must be >= 1, got " + std::to_string(s.substeps));
  if (s.iterations < 1) throw InvalidArgument("iterations must be >= 1 (VBD sweeps per sub-step), got " +
                                              std::to_string(s.iterations));
  if (!s.gravity.allFinite()) throw InvalidArgument("gravity must be finite, got " + str(s.gravity));
  if (!(s.acceleration >= 0 && s.acceleration < 1))
    throw InvalidArgument("acceleration must be a spectral radius in [0, 1) (0: off), got " + str(s.acceleration));
  if (s.threads < 0) throw InvalidArgument("threads must be >= 0 (0: automatic), got " + std::to_string(s.threads));
  if (!(s.contact_stiffness > 0) || !std::isfinite(s.contact_stiffness))
    throw InvalidArgument("contact_stiffness must be a finite stiffness > 0 (in units of m/h²), got " +
                          str(s.contact_stiffness));
}

}  // namespace

// Per model: the colouring, each particle's constraints, the scratch of a sub-step and what the
// last step left (the adaptive initialisation's history, the residual's states).
struct VbdStepper::Plan {
  std::uint64_t model_id = 0;
  Index np = 0;
  std::vector<Index> order;           // dynamic particles, colour by colour, increasing within a colour
  std::vector<Index> colour_offsets;  // colour k is order[colour_offsets[k] .. [k+1])
  std::vector<Index> inc_start;       // np + 1: particle p's constraints are inc[inc_start[p] .. [p+1])
  std::vector<Incidence> inc;
  // Families: whether colour k has a vertex in family f (family_in_colour[f][k]), and each
  // family's C (size) and ∇C (size x arity x 3) at the start of the colour.
  std::vector<std::vector<char>> family_in_colour;
  std::vector<std::vector<Real>> family_c, family_grad;
  std::vector<char> family_unilateral;  // per family, read once (FamilyBatch::info is virtual)
  std::vector<int> family_arity;
  // Balloons: each particle's balloon (-1: none), each balloon's C at the start of a colour and
  // the Sherman-Morrison sums of the colour.
  std::vector<Index> balloon_of;
  std::vector<char> balloon_in_colour;  // colours x balloons
  std::vector<Real> balloon_c, balloon_s1, balloon_s2;
  std::vector<Real> u, w, g;  // 3 np: D⁻¹f, D⁻¹∇V, ∇V of a balloon's vertices
  // A sub-step's arrays, 3 np (all particles; the pinned ones' entries unused).
  std::vector<Real> x, x_tilde, prev1, prev2;  // x⁽ⁿ⁻¹⁾ and x⁽ⁿ⁻²⁾: the acceleration's
  // The sub-step's contacts with the colliders (a penalty, collision/penalty.hpp) and each
  // particle's, contact_start[i] .. [i + 1] (generated particle by particle, so in order).
  PenaltyContacts contacts;
  std::vector<Index> contact_start;
  Positions contact_from, contact_to;  // xⁿ and x̃ for the generation
  State sub_start;  // the state at the start of the last sub-step
  State left;       // the state the last step left
  State rollback;   // the state at the start of the step being taken
  bool history = false;  // sub_start.v is the velocity one sub-step before `left`'s
  Real h = 0;
};

VbdStepper::VbdStepper(const VbdSettings& settings) : settings_(settings) { check_settings(settings_); }
VbdStepper::~VbdStepper() = default;
VbdStepper::VbdStepper(const VbdStepper& o) : settings_(o.settings_) {}
VbdStepper& VbdStepper::operator=(const VbdStepper& o) {
  settings_ = o.settings_;
  plan_.reset();
  return *this;
}

Index VbdStepper::num_colours() const {
  return plan_ ? static_cast<Index>(plan_->colour_offsets.size()) - 1 : 0;
}

void VbdStepper::step(const Model& model, State& state, std::int64_t steps, const std::function<bool()>& interrupt) {
  const UseGuard::Scope in_use(use_, "VertexBlockDescent.step");
  check_implicit_step(model, state, steps);
  const Index np = model.num_particles();

  if (!plan_ || plan_->model_id != model.id) {
    // The spring network's constructor refuses a hard constraint (naming it) and a model with
    // nothing that moves: VBD minimises the same potential.
    const SpringNetwork network(model, state, ReferenceSettings{}, /*with_jacobian=*/false);
    (void)network;
    auto p = std::make_unique<Plan>();
    p->model_id = model.id;
    p->np = np;
    const std::size_t n = static_cast<std::size_t>(np);
    // Each particle's constraints (only the dynamic particles': a pinned one is never updated).
    std::vector<Index> count(n + 1, 0);
    std::vector<Incidence> raw;
    std::vector<Index> owner;
    const auto add = [&](Index particle, Kind kind, int slot, int family, Index index) {
      if (!(model.inv_mass[particle] > 0)) return;
      raw.push_back({kind, static_cast<std::uint8_t>(slot), static_cast<std::uint16_t>(family), index});
      owner.push_back(particle);
    };
    // The vertex graph: an edge between two dynamic particles of one constraint.
    std::vector<std::pair<Index, Index>> edges;
    const auto clique = [&](const Index* q, int arity) {
      for (int a = 0; a < arity; ++a)
        for (int b = 0; b < arity; ++b)
          if (a != b && model.inv_mass[q[a]] > 0 && model.inv_mass[q[b]] > 0 && q[a] != q[b]) edges.emplace_back(q[a], q[b]);
    };
    const auto& d = model.distance;
    for (Index c = 0; c < d.size(); ++c) {
      for (int s = 0; s < 2; ++s) add(d.particles[c][s], kDistance, s, 0, c);
      clique(d.particles[c].data(), 2);
    }
    const auto& be = model.bending;
    for (Index c = 0; c < be.size(); ++c) {
      for (int s = 0; s < 4; ++s) add(be.particles[c][s], kBending, s, 0, c);
      clique(be.particles[c].data(), 4);
    }
    const auto& vo = model.volume;
    for (Index c = 0; c < vo.size(); ++c) {
      for (int s = 0; s < 4; ++s) add(vo.particles[c][s], kVolume, s, 0, c);
      clique(vo.particles[c].data(), 4);
    }
    const auto& at = model.attachments;
    for (Index c = 0; c < at.size(); ++c) add(at.particle[c], kAttachment, 0, 0, c);
    if (model.families.size() > 65535) throw InvalidArgument("VBD takes at most 65535 constraint families");
    for (std::size_t f = 0; f < model.families.size(); ++f) {
      const FamilyBatch& fb = *model.families[f];
      const int arity = fb.info().arity;
      const Index* q = fb.particle_data();
      for (Index c = 0; c < fb.size(); ++c) {
        for (int s = 0; s < arity; ++s) add(q[static_cast<std::size_t>(c) * arity + s], kFamily, s, static_cast<int>(f), c);
        clique(q + static_cast<std::size_t>(c) * arity, arity);
      }
    }
    const auto& bb = model.balloons;
    p->balloon_of.assign(n, -1);
    for (Index b = 0; b < bb.size(); ++b) {
      const Index* local = bb.particles.data() + bb.particle_offsets[b];
      for (Index k = 0; k < bb.num_particles(b); ++k) {
        const Index i = local[k];
        if (!(model.inv_mass[i] > 0)) continue;
        if (p->balloon_of[i] >= 0 && p->balloon_of[i] != b)
          throw InvalidArgument("particle " + std::to_string(i) + " belongs to balloons " +
                                std::to_string(p->balloon_of[i]) + " and " + std::to_string(b) +
                                ": VBD solves one balloon per particle exactly per colour, not two");
        p->balloon_of[i] = b;
      }
      for (Index t = bb.triangle_offsets[b]; t < bb.triangle_offsets[b + 1]; ++t) {
        Index q[3];
        for (int s = 0; s < 3; ++s) q[s] = local[bb.triangles[t][s]];
        for (int s = 0; s < 3; ++s) add(q[s], kBalloonTriangle, s, 0, t);
        clique(q, 3);
      }
    }
    // CSR of the incidences, in the order added (batches in a fixed order, constraints in theirs).
    for (const Index o : owner) ++count[static_cast<std::size_t>(o) + 1];
    for (std::size_t i = 0; i < n; ++i) count[i + 1] += count[i];
    p->inc_start = count;
    p->inc.resize(raw.size());
    {
      std::vector<Index> at_(count.begin(), count.end() - 1);
      for (std::size_t r = 0; r < raw.size(); ++r) p->inc[at_[owner[r]]++] = raw[r];
    }
    // The vertex graph's CSR, sorted, without duplicates; colours by first fit.
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    std::vector<Index> start(n + 1, 0), list(edges.size());
    for (const auto& e : edges) ++start[static_cast<std::size_t>(e.first) + 1];
    for (std::size_t i = 0; i < n; ++i) start[i + 1] += start[i];
    for (std::size_t e = 0; e < edges.size(); ++e) list[e] = edges[e].second;  // sorted by first: CSR order
    const std::vector<Index> colour = colour_vertices(start, list, np);
    Index colours = 0;
    for (Index i = 0; i < np; ++i)
      if (model.inv_mass[i] > 0) colours = std::max(colours, colour[i] + 1);
    p->colour_offsets.assign(static_cast<std::size_t>(colours) + 1, 0);
    for (Index i = 0; i < np; ++i)
      if (model.inv_mass[i] > 0) ++p->colour_offsets[static_cast<std::size_t>(colour[i]) + 1];
    for (Index k = 0; k < colours; ++k) p->colour_offsets[k + 1] += p->colour_offsets[k];
    p->order.resize(static_cast<std::size_t>(p->colour_offsets.back()));
    {
      std::vector<Index> at_(p->colour_offsets.begin(), p->colour_offsets.end() - 1);
      for (Index i = 0; i < np; ++i)
        if (model.inv_mass[i] > 0) p->order[at_[colour[i]]++] = i;
    }
    // Which colours need a family evaluated or a balloon solved.
    p->family_in_colour.assign(model.families.size(), std::vector<char>(static_cast<std::size_t>(colours), 0));
    p->balloon_in_colour.assign(static_cast<std::size_t>(colours) * static_cast<std::size_t>(bb.size()), 0);
    for (Index k = 0; k < colours; ++k)
      for (Index o = p->colour_offsets[k]; o < p->colour_offsets[k + 1]; ++o) {
        const Index i = p->order[o];
        for (Index e = p->inc_start[i]; e < p->inc_start[i + 1]; ++e)
          if (p->inc[e].kind == kFamily) p->family_in_colour[p->inc[e].family][k] = 1;
        if (p->balloon_of[i] >= 0) p->balloon_in_colour[static_cast<std::size_t>(k) * bb.size() + p->balloon_of[i]] = 1;
      }
    p->family_c.resize(model.families.size());
    for (const auto& f : model.families) {
      p->family_unilateral.push_back(f->info().unilateral ? 1 : 0);
      p->family_arity.push_back(f->info().arity);
    }
    p->family_grad.resize(model.families.size());
    for (std::size_t f = 0; f < model.families.size(); ++f) {
      p->family_c[f].assign(static_cast<std::size_t>(model.families[f]->size()), 0.0);
      p->family_grad[f].assign(static_cast<std::size_t>(model.families[f]->size()) * model.families[f]->info().arity * 3, 0.0);
    }
    p->balloon_c.assign(static_cast<std::size_t>(bb.size()), 0.0);
    p->balloon_s1.assign(static_cast<std::size_t>(bb.size()), 0.0);
    p->balloon_s2.assign(static_cast<std::size_t>(bb.size()), 0.0);
    for (auto* a : {&p->u, &p->w, &p->g, &p->x, &p->x_tilde, &p->prev1, &p->prev2}) a->assign(3 * n, 0.0);
    p->sub_start = state;
    p->left = state;
    plan_ = std::move(p);
  }
  Plan& plan = *plan_;
  // The adaptive initialisation's history holds only if this is the state the last step left.
  if (plan.history && !(state.x == plan.left.x && state.v == plan.left.v)) plan.history = false;

  // Threads (automatic): as the position-based stepper, the free cores, at most the model's parts
  // (Model::num_parts: one per 512 particles, at most 8); the bits do not depend on the count.
  // The team's threads spin at the colours' barriers only while each has a free core
  // (csb/solver/team.hpp: a spinner sharing its core starves the thread it waits for), else they
  // sleep; CSB_WAIT=spin or sleep fixes the choice.
  const int parts = static_cast<int>(std::max<Index>(1, model.num_parts));
  if (settings_.threads == 1 || (settings_.threads == 0 && parts <= 1) || model.serial_families()) {
    threads_used_ = 1;  // (no reading of the load: ~10 µs, much of a small model's step)
    spin_ = false;
  } else {
    const int free = free_cores();
    threads_used_ = settings_.threads > 0 ? settings_.threads : std::max(1, std::min(free, parts));
    static const std::string wait = [] {
      const char* v = std::getenv("CSB_WAIT");
      return std::string(v ? v : "");
    }();
    spin_ = wait == "spin" || (wait != "sleep" && threads_used_ <= free);
  }

  const Real h = settings_.dt / settings_.substeps;
  const bool self = self_collision_.active(model);
  for (std::int64_t s = 0; s < steps; ++s) {
    if (s > 0 && interrupt && interrupt())
      throw Interrupted("interrupted after " + std::to_string(s) + " of " + std::to_string(steps) +
                        " steps (t = " + str(state.t) + " s): the state is left at the end of that step");
    plan.rollback.x = state.x;  // the same size each step: no allocation
    plan.rollback.v = state.v;
    try {
      for (int sub = 0; sub < settings_.substeps; ++sub) {
        if (self) self_collision_.before(state, sub);
        substep(model, state, plan, h);
        if (self) self_collision_.after(model, state, settings_.substeps, h);
      }
    } catch (...) {
      state.x = plan.rollback.x;
      state.v = plan.rollback.v;
      plan.history = false;
      plan.h = 0;  // no residual of a step that did not finish
      throw;
    }
    state.t += settings_.dt;
    state.step += 1;
    plan.left.x = state.x;
    plan.left.v = state.v;
  }
}

namespace {

// One vertex's Newton block of E: f (N) and H (N/m) at positions x (3 per particle).
struct Block {
  const Model& model;
  const VbdStepper::Plan& plan;
  const Real* x;
  Real ih2;  // 1/h², 1/s²

  Vec3 at(Index i) const { return Vec3(x[3 * i], x[3 * i + 1], x[3 * i + 2]); }

  // With `balloon` set, the balloon's rank-one term is left out of H and its ∇V returned.
  void operator()(Index i, const std::vector<Incidence>& inc, Vec3& f, Mat3& H, Vec3* balloon_grad) const;
};

void Block::operator()(Index i, const std::vector<Incidence>& inc, Vec3& f, Mat3& H, Vec3* balloon_grad) const {
  const Real m = model.mass[i];
  const Vec3 xi = at(i);
  const Vec3 xt(plan.x_tilde[3 * i], plan.x_tilde[3 * i + 1], plan.x_tilde[3 * i + 2]);
  f = -(m * ih2) * (xi - xt);
  H = (m * ih2) * Mat3::Identity();
  Vec3 gb = Vec3::Zero();
  if (!plan.contact_start.empty())
    for (Index c = plan.contact_start[i]; c < plan.contact_start[i + 1]; ++c) {  // (k/2) min(C, 0)²
      const auto cc = static_cast<std::size_t>(c);
      const Real C = plan.contacts.violation(cc, xi);
      if (!(C < 0)) continue;
      const Vec3& n = plan.contacts.contacts()[cc].normal;
      const Real k = plan.contacts.stiffness(cc);
      f -= (k * C) * n;
      H += k * (n * n.transpose());  // exact: C is linear in x_i
    }
  for (Index e = plan.inc_start[i]; e < plan.inc_start[i + 1]; ++e) {
    const Incidence& q = inc[e];
    const Index c = q.index;
    switch (q.kind) {
      case kDistance: {
        const auto& b = model.distance;
        const Vec3 dv = xi - at(b.particles[c][1 - q.slot]);  // ∇_i C = dv/|dv| from either end
        const Real len = dv.norm();
        if (!(len > 0)) break;
        const Real viol = distance_violation(len - b.rest_length[c], b.sense[c]);
        if (b.sense[c] != 0 && viol == 0) break;  // a slack inequality
        const Real k = 1 / b.compliance[c];
        const Vec3 n = dv / len;
        f -= (k * viol) * n;
        const Mat3 nn = n * n.transpose();
        const Real geometric = std::max<Real>(viol / len, 0);  // k(1 - L/l), clamped: PSD
        H += k * (nn + geometric * (Mat3::Identity() - nn));
        break;
      }
      case kBending: {
        const auto& b = model.bending;
        const auto& q4 = b.particles[c];
        Vec3 grad[4];
        Real theta = 0;
        if (!dihedral_angle_and_gradient(at(q4[0]), at(q4[1]), at(q4[2]), at(q4[3]), theta, grad)) break;
        const Vec3& gi = grad[q.slot];
        const Real C = wrap_angle(theta - b.rest_angle[c]);
        const Real k = 1 / b.compliance[c];
        f -= (k * C) * gi;
        H += k * (gi * gi.transpose());  // Gauss-Newton: C ∇²θ dropped, PSD
        break;
      }
      case kVolume: {
        const auto& b = model.volume;
        const auto& q4 = b.particles[c];
        Vec3 grad[4];
        const Real C = tet_volume_gradient(at(q4[0]), at(q4[1]), at(q4[2]), at(q4[3]), grad) - b.rest_volume[c];
        const Real k = 1 / b.compliance[c];
        const Vec3& gi = grad[q.slot];
        f -= (k * C) * gi;
        H += k * (gi * gi.transpose());  // exact: V is linear in x_i alone (∂²V/∂x_i² = 0)
        break;
      }
      case kAttachment: {
        const auto& b = model.attachments;
        const Real k = 1 / b.compliance[c];
        f -= k * (xi - b.target.col(c));
        H += k * Mat3::Identity();
        break;
      }
      case kFamily: {
        const Real C = plan.family_c[q.family][c];
        if (plan.family_unilateral[q.family] && !(C > 0)) break;  // slack: no force, no stiffness
        const Real alpha = model.families[q.family]->compliance[c];
        const Real* gp =
            plan.family_grad[q.family].data() + (static_cast<std::size_t>(c) * plan.family_arity[q.family] + q.slot) * 3;
        const Vec3 gi(gp[0], gp[1], gp[2]);
        f -= (C / alpha) * gi;
        H += (gi * gi.transpose()) / alpha;  // Gauss-Newton (the family's curvature dropped), PSD
        break;
      }
      case kBalloonTriangle: {
        const auto& b = model.balloons;
        const Triangle& t = b.triangles[c];
        const Index* local = b.particles.data() + b.particle_offsets[plan.balloon_of[i]];
        gb += at(local[t[(q.slot + 1) % 3]]).cross(at(local[t[(q.slot + 2) % 3]])) / 6;
        break;
      }
    }
  }
  const Index bl = plan.balloon_of[i];
  if (bl >= 0) {
    const Real k = 1 / model.balloons.compliance[bl];
    f -= (k * plan.balloon_c[bl]) * gb;
    if (balloon_grad)
      *balloon_grad = gb;
    else
      H += k * (gb * gb.transpose());  // exact: V is linear in x_i alone
  }
}

// H⁻¹ f by the adjugate (H symmetric); false where det(H) is below 1e-30 of its diagonal's cube.
bool solve3(const Mat3& H, const Vec3& f, Vec3& out) {
  const Real a00 = H(1, 1) * H(2, 2) - H(1, 2) * H(2, 1);
  const Real a01 = H(0, 2) * H(2, 1) - H(0, 1) * H(2, 2);
  const Real a02 = H(0, 1) * H(1, 2) - H(0, 2) * H(1, 1);
  const Real det = H(0, 0) * a00 + H(1, 0) * a01 + H(2, 0) * a02;
  const Real scale = std::max({std::abs(H(0, 0)), std::abs(H(1, 1)), std::abs(H(2, 2))});
  if (!(std::abs(det) > 1e-30 * scale * scale * scale)) return false;
  const Real a11 = H(0, 0) * H(2, 2) - H(0, 2) * H(2, 0);
  const Real a12 = H(0, 2) * H(1, 0) - H(0, 0) * H(1, 2);
  const Real a22 = H(0, 0) * H(1, 1) - H(0, 1) * H(1, 0);
  // adj(H) is symmetric for a symmetric H: rows (a00 a01 a02), (a01 a11 a12), (a02 a12 a22).
  out[0] = (a00 * f[0] + a01 * f[1] + a02 * f[2]) / det;
  out[1] = (a01 * f[0] + a11 * f[1] + a12 * f[2]) / det;
  out[2] = (a02 * f[0] + a12 * f[1] + a22 * f[2]) / det;
  return true;
}

}  // namespace

void VbdStepper::substep(const Model& model, State& state, Plan& plan, Real h) {
  const Index np = model.num_particles();
  const std::size_t n3 = 3 * static_cast<std::size_t>(np);
  const Vec3 g = settings_.gravity;
  const Real gn = g.norm();
  const Vec3 ghat = gn > 0 ? Vec3(g / gn) : Vec3::Zero();
  const bool history = plan.history && plan.h == h;
  // x̃ and the start positions; the pinned particles stay where the state has them.
  std::copy(state.x.data(), state.x.data() + n3, plan.x.begin());
  for (const Index i : plan.order) {
    Vec3 a = g;  // ã: adaptive (§3.6), without a history the inertial guess
    if (history) {
      const Real along = ((state.v.col(i) - plan.sub_start.v.col(i)) / h).dot(ghat);
      a = std::min(std::max(along, Real(0)), gn) * ghat;
    }
    for (int k = 0; k < 3; ++k) {
      const Real xt = state.x(k, i) + h * state.v(k, i) + h * h * g[k];
      plan.x_tilde[3 * i + k] = xt;
      switch (settings_.initialization) {
        case VbdSettings::Initialization::Adaptive: plan.x[3 * i + k] = state.x(k, i) + h * state.v(k, i) + h * h * a[k]; break;
        case VbdSettings::Initialization::Inertia: plan.x[3 * i + k] = xt; break;
        case VbdSettings::Initialization::Previous: break;
      }
    }
  }
  plan.sub_start.x = state.x;
  plan.sub_start.v = state.v;
  plan.sub_start.t = state.t;
  plan.sub_start.step = state.step;
  plan.contact_start.clear();
  if (!model.colliders.empty()) {  // the sub-step's contacts, from xⁿ towards x̃
    plan.contact_from = state.x;
    plan.contact_to = state.x;
    for (const Index i : plan.order)
      for (int k = 0; k < 3; ++k) plan.contact_to(k, i) = plan.x_tilde[3 * i + k];
    plan.contacts.generate(model, plan.contact_from, plan.contact_to, h, settings_.contact_stiffness);
    plan.contact_start.assign(static_cast<std::size_t>(np) + 1, 0);
    for (const Contact& c : plan.contacts.contacts()) ++plan.contact_start[static_cast<std::size_t>(c.particle) + 1];
    for (Index i = 0; i < np; ++i) plan.contact_start[i + 1] += plan.contact_start[i];
  }
  std::copy(plan.x.begin(), plan.x.end(), plan.prev1.begin());

  const Index colours = static_cast<Index>(plan.colour_offsets.size()) - 1;
  const bool families = !model.families.empty();
  const Index balloons = model.balloons.size();
  const Real rho = settings_.acceleration;
  const int iterations = settings_.iterations;
  const int threads = threads_used_;
  Real* x = plan.x.data();
  const Block block{model, plan, x, 1 / (h * h)};
  Team& team = team_.get();

  // Between the colours: the families and balloons evaluated where the colour needs them (thread 0).
  const auto prepare = [&](Index k) {
    for (std::size_t f = 0; f < model.families.size(); ++f)
      if (plan.family_in_colour[f][k]) model.families[f]->evaluate(x, plan.family_c[f].data(), plan.family_grad[f].data());
    const auto& bb = model.balloons;
    for (Index b = 0; b < balloons; ++b)
      if (plan.balloon_in_colour[static_cast<std::size_t>(k) * balloons + b]) {
        plan.balloon_c[b] = enclosed_volume(x, bb.particles.data() + bb.particle_offsets[b],
                                            bb.triangles.data() + bb.triangle_offsets[b], bb.num_triangles(b)) -
                            bb.pressure[b] * bb.rest_volume[b];
        plan.balloon_s1[b] = plan.balloon_s2[b] = 0;
      }
  };
  // The first vertex update (in the sweeps' order) whose force or stiffness became non-finite:
  // the smallest key (sweep, colour, place in the colour order), the same on any thread count.
  const std::int64_t none = std::numeric_limits<std::int64_t>::max();
  std::atomic<std::int64_t> first_failure{none};
  const auto failed = [&](int it, Index k, Index o) {
    const std::int64_t key = (static_cast<std::int64_t>(it - 1) * colours + k) * np + o;
    std::int64_t seen = first_failure.load(std::memory_order_relaxed);
    while (key < seen && !first_failure.compare_exchange_weak(seen, key, std::memory_order_relaxed)) {
    }
  };
  const auto job = [&](int t) {
    Real omega = 1;
    for (int it = 1; it <= iterations; ++it) {
      for (Index k = 0; k < colours; ++k) {
        if (families || balloons > 0) {
          if (t == 0) prepare(k);
          team.barrier();
        }
        const Index first = plan.colour_offsets[k], size = plan.colour_offsets[k + 1] - first;
        const Index lo = first + static_cast<Index>(static_cast<std::int64_t>(size) * t / threads);
        const Index hi = first + static_cast<Index>(static_cast<std::int64_t>(size) * (t + 1) / threads);
        for (Index o = lo; o < hi; ++o) {
          const Index i = plan.order[o];
          Vec3 f, dx, gb;
          Mat3 H;
          const bool in_balloon = plan.balloon_of[i] >= 0;
          block(i, plan.inc, f, H, in_balloon ? &gb : nullptr);
          if (!(f.allFinite() && H.allFinite() && (!in_balloon || gb.allFinite()))) {
            failed(it, k, o);  // no update: the step is refused after the sweeps
            gb.setZero();
            f.setZero();
            H.setIdentity();
          }
          if (!solve3(H, f, dx)) dx.setZero();
          if (in_balloon) {
            Vec3 w;
            if (!solve3(H, gb, w)) w.setZero();
            for (int e = 0; e < 3; ++e) {
              plan.u[3 * i + e] = dx[e];
              plan.w[3 * i + e] = w[e];
              plan.g[3 * i + e] = gb[e];
            }
            continue;  // a balloon's vertex waits for the colour's sums
          }
          for (int e = 0; e < 3; ++e) x[3 * i + e] += dx[e];
        }
        if (balloons > 0) {
          team.barrier();
          if (t == 0)  // the colour's sums, in vertex order
            for (Index o = first; o < first + size; ++o) {
              const Index i = plan.order[o], b = plan.balloon_of[i];
              if (b < 0) continue;
              for (int e = 0; e < 3; ++e) {
                plan.balloon_s1[b] += plan.g[3 * i + e] * plan.u[3 * i + e];
                plan.balloon_s2[b] += plan.g[3 * i + e] * plan.w[3 * i + e];
              }
            }
          team.barrier();
          for (Index o = lo; o < hi; ++o) {
            const Index i = plan.order[o], b = plan.balloon_of[i];
            if (b < 0) continue;
            const Real kb = 1 / model.balloons.compliance[b];
            const Real s = kb * plan.balloon_s1[b] / (1 + kb * plan.balloon_s2[b]);
            for (int e = 0; e < 3; ++e) x[3 * i + e] += plan.u[3 * i + e] - s * plan.w[3 * i + e];
          }
        }
        team.barrier();
      }
      // Chebyshev (§3.8): x⁽ⁿ⁾ = ω_n (x̄⁽ⁿ⁾ - x⁽ⁿ⁻²⁾) + x⁽ⁿ⁻²⁾.
      if (rho > 0) {
        omega = it == 1 ? 1 : it == 2 ? 2 / (2 - rho * rho) : 4 / (4 - rho * rho * omega);
        const Index all = static_cast<Index>(plan.order.size());
        const Index lo = static_cast<Index>(static_cast<std::int64_t>(all) * t / threads);
        const Index hi = static_cast<Index>(static_cast<std::int64_t>(all) * (t + 1) / threads);
        for (Index o = lo; o < hi; ++o) {
          const Index i = plan.order[o];
          for (int e = 0; e < 3; ++e) {
            const std::size_t j = 3 * static_cast<std::size_t>(i) + e;
            const Real xn = it >= 2 ? omega * (x[j] - plan.prev2[j]) + plan.prev2[j] : x[j];
            x[j] = xn;
            plan.prev2[j] = plan.prev1[j];
            plan.prev1[j] = xn;
          }
        }
        team.barrier();
      }
    }
  };
  // A reference wrapper: std::function holds it without allocating.
  team.run(threads, spin_, std::function<void(int)>(std::ref(job)));

  if (const std::int64_t key = first_failure.load(); key != none) {
    const Index particle = plan.order[static_cast<std::size_t>(key % np)];
    throw SimulationError("VBD: step " + std::to_string(state.step) + ": particle " + std::to_string(particle) +
                          " met a non-finite force or stiffness in sweep " +
                          std::to_string(key / (static_cast<std::int64_t>(colours) * np) + 1) +
                          " (its constraints' values overflow); the state is left at the end of the last step");
  }
  // The first non-finite position, then the velocities v = (x - xⁿ)/h.
  for (const Index i : plan.order)
    for (int e = 0; e < 3; ++e)
      if (!std::isfinite(x[3 * i + e]))
        throw SimulationError("VBD: step " + std::to_string(state.step) + ": particle " + std::to_string(i) +
                              " reached a non-finite position; the state is left at the end of the last step");
  for (const Index i : plan.order)
    for (int e = 0; e < 3; ++e) {
      state.v(e, i) = (x[3 * i + e] - state.x(e, i)) / h;
      state.x(e, i) = x[3 * i + e];
    }
  for (Index i = 0; i < np; ++i)
    if (!(model.inv_mass[i] > 0)) state.v.col(i).setZero();
  if (!plan.contact_start.empty()) plan.contacts.finish(model, plan.contact_from, state, h, settings_.gravity);
  plan.history = true;
  plan.h = h;
}

Residual VbdStepper::last_residual(const Model& model) const {
  if (!plan_ || plan_->model_id != model.id || plan_->h == 0)
    throw InvalidArgument("last_residual: this VBD stepper has not stepped this model yet");
  return backward_euler_residual(model, plan_->sub_start, plan_->left, plan_->h, settings_.gravity);
}

}  // namespace csb
