#include "csb/reference.hpp"
#include "csb/format.hpp"

#include "csb/constraints/bending.hpp"
#include "csb/constraints/distance.hpp"
#include "csb/constraints/volume.hpp"

#include <cvode/cvode.h>
#include <nvector/nvector_serial.h>
#include <sundials/sundials_context.h>
#include <sunlinsol/sunlinsol_klu.h>
#include <sunlinsol/sunlinsol_spgmr.h>
#include <sunmatrix/sunmatrix_sparse.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>

namespace csb {

using detail::str;

namespace {

using Mat3r = Eigen::Matrix<Real, 3, 3, Eigen::RowMajor>;

void check_settings(const ReferenceSettings& s) {
  if (!(s.rtol > 0) || !std::isfinite(s.rtol)) throw InvalidArgument("rtol must be a finite tolerance > 0, got " + str(s.rtol));
  if (!(s.atol > 0) || !std::isfinite(s.atol)) throw InvalidArgument("atol must be a finite tolerance > 0, got " + str(s.atol));
  if (!s.gravity.allFinite()) throw InvalidArgument("gravity must be finite, got " + str(s.gravity));
  if (!(s.damping >= 0) || !std::isfinite(s.damping))
    throw InvalidArgument("damping must be a finite coefficient >= 0 N s/m, got " + str(s.damping));
  if (!(s.drag >= 0) || !std::isfinite(s.drag))
    throw InvalidArgument("drag must be a finite rate >= 0 1/s, got " + str(s.drag));
  if (s.max_order < 1 || s.max_order > 5) throw InvalidArgument("max_order must be 1 to 5, got " + std::to_string(s.max_order));
  if (s.max_steps < 1) throw InvalidArgument("max_steps must be >= 1, got " + std::to_string(s.max_steps));
  if (!(s.max_wall_time >= 0) || !std::isfinite(s.max_wall_time))
    throw InvalidArgument("max_wall_time must be >= 0 s (0: no limit), got " + str(s.max_wall_time));
}

// A sparsity pattern in compressed sparse columns, built from (column, row) entries.
struct Csc {
  std::vector<std::int64_t> col_start, row_index;

  Csc() = default;
  Csc(std::vector<std::pair<std::int64_t, std::int64_t>> entries, std::int64_t columns) {
    std::sort(entries.begin(), entries.end());
    entries.erase(std::unique(entries.begin(), entries.end()), entries.end());
    col_start.assign(columns + 1, 0);
    row_index.resize(entries.size());
    for (std::size_t e = 0; e < entries.size(); ++e) {
      ++col_start[entries[e].first + 1];
      row_index[e] = entries[e].second;
    }
    for (std::int64_t c = 0; c < columns; ++c) col_start[c + 1] += col_start[c];
  }

  // Position of entry (row, col) in the value array, or -1 if it is not in the pattern.
  std::int64_t find(std::int64_t row, std::int64_t col) const {
    const auto first = row_index.begin() + col_start[col], last = row_index.begin() + col_start[col + 1];
    const auto it = std::lower_bound(first, last, row);
    return (it != last && *it == row) ? static_cast<std::int64_t>(it - row_index.begin()) : -1;
  }
};

std::string hard_message(const std::string& what, Index c, const char* unit) {
  return what + " constraint " + std::to_string(c) +
         " is hard (compliance 0); the spring network (the reference integrator, the force-based steppers) "
         "models every constraint as the potential "
         "C²/(2α) and needs a compliance α > 0 (" + unit + "): give the model's constraints a compliance";
}

// [u]x, the matrix of u x (.).
Mat3r skew(const Vec3& u) {
  Mat3r m;
  m << 0, -u.z(), u.y(), u.z(), 0, -u.x(), -u.y(), u.x(), 0;
  return m;
}

// Hessian blocks H[i][j] = ∂²V/∂p_i∂p_j of V = (1/6) det(e1, e2, e3), e_i = p_i - p0. V is linear
// in each e_i, so H[i][i] = 0 and, from ∂²det/∂e1∂e2 = -[e3]x and its cyclic shifts,
// H[1][2] = -[e3]x/6, H[2][3] = -[e1]x/6, H[3][1] = -[e2]x/6, H[j][i] = H[i][j]ᵀ; translation
// invariance gives the p0 row and column: H[0][j] = -Σ_{i>0} H[i][j].
void tet_volume_hessian(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& p3, Mat3r H[4][4]) {
  const Vec3 e[4] = {Vec3::Zero(), p1 - p0, p2 - p0, p3 - p0};
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) H[i][j].setZero();
  for (int i = 1; i <= 3; ++i) {
    const int j = i % 3 + 1, k = j % 3 + 1;  // (1, 2, 3), (2, 3, 1), (3, 1, 2)
    H[i][j] = -skew(e[k]) / 6;
    H[j][i] = H[i][j].transpose();
  }
  for (int j = 1; j <= 3; ++j) {
    H[0][j] = -(H[1][j] + H[2][j] + H[3][j]);
    H[j][0] = H[0][j].transpose();
  }
}

}  // namespace

// ------------------------------------------------------------------------------------ network

SpringNetwork::SpringNetwork(const Model& model, const State& start, const ReferenceSettings& settings,
                             bool with_jacobian)
    : settings_(settings) {
  check_settings(settings_);
  const Index n = model.num_particles();
  if (start.x.cols() != n || start.v.cols() != n)
    throw InvalidArgument("the start state has " + std::to_string(start.x.cols()) + " particles, the model " +
                          std::to_string(n));
  if (!start.x.allFinite() || !start.v.allFinite()) throw InvalidArgument("the start state has non-finite values");
  slot_of_.assign(n, -1);
  for (Index i = 0; i < n; ++i)
    if (model.inv_mass[i] > 0) {
      slot_of_[i] = static_cast<Index>(dynamic_.size());
      dynamic_.push_back(i);
      mass_.push_back(model.mass[i]);
    }
  if (dynamic_.empty())
    throw InvalidArgument("the model has no dynamic particles (all are pinned): there is nothing to integrate");
  pinned_x_ = start.x;

  const auto& d = model.distance;
  for (Index c = 0; c < d.size(); ++c) {
    if (!(d.compliance[c] > 0)) throw InvalidArgument(hard_message("distance", c, "m/N"));
    Spring s;
    s.a = slot_of_[d.particles[c][0]];
    s.b = slot_of_[d.particles[c][1]];
    if (s.a < 0 && s.b < 0) continue;
    s.fixed_a = start.x.col(d.particles[c][0]);
    s.fixed_b = start.x.col(d.particles[c][1]);
    s.k = 1 / d.compliance[c];
    s.rest = d.rest_length[c];
    s.sense = d.sense[c];
    springs_.push_back(s);
  }
  const auto& b = model.bending;
  for (Index c = 0; c < b.size(); ++c) {
    if (!(b.compliance[c] > 0)) throw InvalidArgument(hard_message("bending", c, "1/(N m)"));
    Bend e;
    bool any = false;
    for (int k = 0; k < 4; ++k) {
      e.slot[k] = slot_of_[b.particles[c][k]];
      e.fixed[k] = start.x.col(b.particles[c][k]);
      any = any || e.slot[k] >= 0;
    }
    if (!any) continue;
    e.k = 1 / b.compliance[c];
    e.rest = b.rest_angle[c];
    bending_.push_back(e);
  }
  const auto& vb = model.volume;
  for (Index c = 0; c < vb.size(); ++c) {
    if (!(vb.compliance[c] > 0)) throw InvalidArgument(hard_message("volume", c, "m⁶/J"));
    Volume e;
    bool any = false;
    for (int k = 0; k < 4; ++k) {
      e.slot[k] = slot_of_[vb.particles[c][k]];
      e.fixed[k] = start.x.col(vb.particles[c][k]);
      any = any || e.slot[k] >= 0;
    }
    if (!any) continue;
    e.k = 1 / vb.compliance[c];
    e.rest = vb.rest_volume[c];
    volumes_.push_back(e);
  }
  const auto& bb = model.balloons;
  for (Index c = 0; c < bb.size(); ++c) {
    if (!(bb.compliance[c] > 0)) throw InvalidArgument(hard_message("balloon", c, "m⁶/J"));
    Balloon e;
    for (Index o = bb.particle_offsets[c]; o < bb.particle_offsets[c + 1]; ++o) {
      e.slot.push_back(slot_of_[bb.particles[o]]);
      e.fixed.push_back(start.x.col(bb.particles[o]));
    }
    e.triangles.assign(bb.triangles.begin() + bb.triangle_offsets[c], bb.triangles.begin() + bb.triangle_offsets[c + 1]);
    e.k = 1 / bb.compliance[c];
    e.target = bb.pressure[c] * bb.rest_volume[c];
    if (std::any_of(e.slot.begin(), e.slot.end(), [](Index s) { return s >= 0; })) balloons_.push_back(std::move(e));
  }
  const auto& a = model.attachments;
  for (Index c = 0; c < a.size(); ++c) {
    if (!(a.compliance[c] > 0)) throw InvalidArgument(hard_message("attachment", c, "m/N"));
    const Index s = slot_of_[a.particle[c]];
    if (s < 0) continue;
    anchors_.push_back({s, a.target.col(c), 1 / a.compliance[c]});
  }
  for (const auto& f : model.families) {
    if (f->size() == 0) continue;
    for (Index c = 0; c < f->size(); ++c)
      if (!(f->compliance[c] > 0))
        throw InvalidArgument(hard_message(f->info().label, c, f->info().compliance_unit.c_str()));
    families_.push_back({f, {}});
  }
  if (settings_.linear_solver == ReferenceSettings::Linear::Klu && !has_analytic_jacobian())
    throw InvalidArgument("linear_solver 'klu' needs an analytic Jacobian, but the model has compliant bending "
                          "constraints, balloons or a constraint family without its Hessian: use 'gmres' or 'auto'");
  if (with_jacobian) build_structure();
}

bool SpringNetwork::has_analytic_jacobian() const {
  for (const FamilyTerm& t : families_)
    if (!t.batch->info().has_hessian) return false;
  return bending_.empty() && balloons_.empty();
}

void SpringNetwork::full_positions(const Real* y, std::vector<Real>& x) const {
  x.assign(pinned_x_.data(), pinned_x_.data() + pinned_x_.size());
  for (std::size_t s = 0; s < dynamic_.size(); ++s)
    for (int k = 0; k < 3; ++k) x[3 * static_cast<std::size_t>(dynamic_[s]) + k] = y[3 * s + k];
}

void SpringNetwork::build_structure() {
  const std::int64_t n = num_dynamic(), N = 6 * n;
  const bool damped = settings_.damping > 0;
  std::vector<std::pair<std::int64_t, std::int64_t>> entries;  // (col, row)
  for (std::int64_t r = 0; r < N; ++r) entries.push_back({r, r});
  for (std::int64_t r = 0; r < 3 * n; ++r) entries.push_back({3 * n + r, r});  // ∂ẋ/∂v = I
  const auto block = [&](std::int64_t slot_row, std::int64_t slot_col, bool velocity) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        entries.push_back({(velocity ? 3 * n : 0) + 3 * slot_col + c, 3 * n + 3 * slot_row + r});
  };
  for (const auto& s : springs_)
    for (bool velocity : {false, true}) {
      if (velocity && !damped) continue;
      if (s.a >= 0) block(s.a, s.a, velocity);
      if (s.b >= 0) block(s.b, s.b, velocity);
      if (s.a >= 0 && s.b >= 0) {
        block(s.a, s.b, velocity);
        block(s.b, s.a, velocity);
      }
    }
  for (const auto& q : anchors_)
    for (bool velocity : {false, true})
      if (!velocity || damped) block(q.slot, q.slot, velocity);
  for (const auto& e : volumes_)
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j)
        if (e.slot[i] >= 0 && e.slot[j] >= 0) block(e.slot[i], e.slot[j], false);
  for (const FamilyTerm& t : families_) {
    const int arity = t.batch->info().arity;
    const Index* q = t.batch->particle_data();
    for (Index c = 0; c < t.batch->size(); ++c)
      for (int i = 0; i < arity; ++i)
        for (int j = 0; j < arity; ++j) {
          const Index si = slot_of_[q[c * arity + i]], sj = slot_of_[q[c * arity + j]];
          if (si >= 0 && sj >= 0) block(si, sj, false);
        }
  }
  Csc pattern(std::move(entries), N);
  col_start_ = pattern.col_start;
  row_index_ = pattern.row_index;
  const auto find = [&pattern](std::int64_t row, std::int64_t col) { return pattern.find(row, col); };
  const auto positions = [&](Index slot_row, Index slot_col, bool velocity, std::int64_t out[9]) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        out[3 * r + c] = (slot_row < 0 || slot_col < 0 || (velocity && !damped))
                             ? -1
                             : find(3 * n + 3 * slot_row + r, (velocity ? 3 * n : 0) + 3 * slot_col + c);
  };
  spring_blocks_.resize(springs_.size());
  for (std::size_t k = 0; k < springs_.size(); ++k) {
    const auto& s = springs_[k];
    const Index pairs[4][2] = {{s.a, s.a}, {s.a, s.b}, {s.b, s.a}, {s.b, s.b}};
    for (int p = 0; p < 4; ++p) {
      positions(pairs[p][0], pairs[p][1], false, spring_blocks_[k].x[p]);
      positions(pairs[p][0], pairs[p][1], true, spring_blocks_[k].v[p]);
    }
  }
  anchor_blocks_.resize(anchors_.size());
  for (std::size_t k = 0; k < anchors_.size(); ++k) {
    positions(anchors_[k].slot, anchors_[k].slot, false, anchor_blocks_[k].x[0]);
    positions(anchors_[k].slot, anchors_[k].slot, true, anchor_blocks_[k].v[0]);
  }
  volume_blocks_.resize(volumes_.size());
  for (std::size_t k = 0; k < volumes_.size(); ++k)
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) positions(volumes_[k].slot[i], volumes_[k].slot[j], false, volume_blocks_[k].x[4 * i + j]);
  for (FamilyTerm& t : families_) {
    const int arity = t.batch->info().arity;
    const Index* q = t.batch->particle_data();
    t.blocks.resize(static_cast<std::size_t>(t.batch->size()) * arity * arity * 9);
    for (Index c = 0; c < t.batch->size(); ++c)
      for (int i = 0; i < arity; ++i)
        for (int j = 0; j < arity; ++j)
          positions(slot_of_[q[c * arity + i]], slot_of_[q[c * arity + j]], false,
                    t.blocks.data() + ((static_cast<std::size_t>(c) * arity + i) * arity + j) * 9);
  }
  identity_.resize(3 * n);
  for (std::int64_t r = 0; r < 3 * n; ++r) identity_[r] = find(r, 3 * n + r);
  drag_diagonal_.resize(3 * n);
  for (std::int64_t r = 0; r < 3 * n; ++r) drag_diagonal_[r] = find(3 * n + r, 3 * n + r);
}

void SpringNetwork::pack(const State& state, Real* y) const {
  const std::size_t n = dynamic_.size();
  for (std::size_t s = 0; s < n; ++s)
    for (int c = 0; c < 3; ++c) {
      y[3 * s + c] = state.x(c, dynamic_[s]);
      y[3 * n + 3 * s + c] = state.v(c, dynamic_[s]);
    }
}

void SpringNetwork::unpack(const Real* y, Positions& x, Positions& v) const {
  const std::size_t n = dynamic_.size();
  x = pinned_x_;
  v = Positions::Zero(3, pinned_x_.cols());
  for (std::size_t s = 0; s < n; ++s)
    for (int c = 0; c < 3; ++c) {
      x(c, dynamic_[s]) = y[3 * s + c];
      v(c, dynamic_[s]) = y[3 * n + 3 * s + c];
    }
}

void SpringNetwork::rhs(const Real* y, Real* ydot) const {
  const Index n = num_dynamic();
  const Real* v = y + 3 * n;
  Real* a = ydot + 3 * n;
  std::copy(v, v + 3 * n, ydot);  // ẋ = v
  std::fill(a, a + 3 * n, 0.0);   // forces first, divided by the masses at the end
  add_forces(y, v, settings_.damping, a);
  for (Index s = 0; s < n; ++s)
    for (int k = 0; k < 3; ++k)
      a[3 * s + k] = a[3 * s + k] / mass_[s] + settings_.gravity[k] - settings_.drag * v[3 * s + k];
}

void SpringNetwork::add_forces(const Real* y, const Real* v, Real c, Real* a) const {
  const Index n = num_dynamic();
  const auto add = [a](Index slot, const Vec3& f) {
    if (slot >= 0)
      for (int k = 0; k < 3; ++k) a[3 * slot + k] += f[k];
  };
  const auto vel = [v](Index slot) {
    return slot >= 0 && v ? Vec3(v[3 * slot], v[3 * slot + 1], v[3 * slot + 2]) : Vec3::Zero();
  };
  for (const auto& s : springs_) {
    const Vec3 d = position(y, s.a, s.fixed_a) - position(y, s.b, s.fixed_b);
    const Real len = d.norm();
    if (!(len > 0)) continue;
    const Vec3 nrm = d / len;
    const Real viol = distance_violation(len - s.rest, s.sense);
    const bool active = s.sense == 0 || viol != 0;
    if (!active) continue;
    Vec3 f = -s.k * viol * nrm;  // on a
    if (c > 0) f -= c * nrm.dot(vel(s.a) - vel(s.b)) * nrm;
    add(s.a, f);
    add(s.b, -f);
  }
  for (const auto& e : bending_) {
    Vec3 p[4], grad[4];
    for (int k = 0; k < 4; ++k) p[k] = position(y, e.slot[k], e.fixed[k]);
    Real theta = 0;
    if (!dihedral_angle_and_gradient(p[0], p[1], p[2], p[3], theta, grad)) continue;
    const Real C = wrap_angle(theta - e.rest);
    for (int k = 0; k < 4; ++k) add(e.slot[k], -e.k * C * grad[k]);
  }
  // Volumes and balloons: F_i = -k C grad_i V (no dashpot: `damping` acts along distance
  // constraints and attachments only).
  for (const auto& e : volumes_) {
    Vec3 p[4], grad[4];
    for (int k = 0; k < 4; ++k) p[k] = position(y, e.slot[k], e.fixed[k]);
    const Real C = tet_volume_gradient(p[0], p[1], p[2], p[3], grad) - e.rest;
    for (int k = 0; k < 4; ++k) add(e.slot[k], -e.k * C * grad[k]);
  }
  for (const auto& b : balloons_) {
    const Index m = static_cast<Index>(b.slot.size());
    Positions x;
    std::vector<Vec3> grad;
    const Real C = balloon_constraint(y, b, x, grad);
    for (Index k = 0; k < m; ++k) add(b.slot[k], -b.k * C * grad[k]);
  }
  for (const auto& q : anchors_) add(q.slot, -q.k * (position(y, q.slot, q.target) - q.target) - c * vel(q.slot));
  if (!families_.empty()) {  // -(C₊/α) ∇C, on all particles' positions (the pinned ones' forces dropped)
    std::vector<Real> x, f(static_cast<std::size_t>(pinned_x_.size()), 0.0);
    full_positions(y, x);
    for (const FamilyTerm& t : families_) t.batch->add_forces(x.data(), f.data());
    for (Index s = 0; s < n; ++s)
      for (int k = 0; k < 3; ++k) a[3 * s + k] += f[3 * static_cast<std::size_t>(dynamic_[s]) + k];
  }
}

void SpringNetwork::jacobian(const Real* y, Real* values) const {
  const Index n = num_dynamic();
  const Real* v = y + 3 * n;
  std::fill(values, values + row_index_.size(), 0.0);
  for (std::int64_t p : identity_) values[p] = 1;
  for (std::int64_t p : drag_diagonal_) values[p] = -settings_.drag;
  const Real c = settings_.damping;
  const auto vel = [v](Index slot) { return slot >= 0 ? Vec3(v[3 * slot], v[3 * slot + 1], v[3 * slot + 2]) : Vec3::Zero(); };
  // Adds sign * M / m_row to the 3x3 block at the given value positions.
  const auto put = [&](const std::int64_t pos[9], const Mat3r& M, Real scale) {
    if (pos[0] < 0) return;
    for (int k = 0; k < 9; ++k) values[pos[k]] += scale * M.data()[k];
  };
  const Mat3r I = Mat3r::Identity();
  for (std::size_t k = 0; k < springs_.size(); ++k) {
    const auto& s = springs_[k];
    const Vec3 d = position(y, s.a, s.fixed_a) - position(y, s.b, s.fixed_b);
    const Real len = d.norm();
    if (!(len > 0)) continue;
    const Vec3 nrm = d / len;
    const Real viol = distance_violation(len - s.rest, s.sense);
    if (!(s.sense == 0 || viol != 0)) continue;  // an inactive inequality: no force, no Jacobian
    const Mat3r nn = nrm * nrm.transpose();
    // ∂F_a/∂x_a = -Kt with the spring's Ks = k (n nᵀ + viol/|d| (I - n nᵀ)) and, with a dashpot
    // F_a = -c (n·u) n (u = v_a - v_b), Dx = c (n uᵀ + (n·u) I)(I - n nᵀ)/|d| and ∂F_a/∂v_a = -c n nᵀ.
    Mat3r Kt = s.k * (nn + (viol / len) * (I - nn));
    Mat3r Cv = Mat3r::Zero();
    if (c > 0) {
      const Vec3 u = vel(s.a) - vel(s.b);
      Kt += c * (nrm * u.transpose() + nrm.dot(u) * I) * (I - nn) / len;
      Cv = c * nn;
    }
    const auto& B = spring_blocks_[k];
    const Real ia = s.a >= 0 ? 1 / mass_[s.a] : 0, ib = s.b >= 0 ? 1 / mass_[s.b] : 0;
    put(B.x[0], Kt, -ia);
    put(B.x[1], Kt, ia);
    put(B.x[2], Kt, ib);
    put(B.x[3], Kt, -ib);
    if (c > 0) {
      put(B.v[0], Cv, -ia);
      put(B.v[1], Cv, ia);
      put(B.v[2], Cv, ib);
      put(B.v[3], Cv, -ib);
    }
  }
  for (std::size_t k = 0; k < anchors_.size(); ++k) {
    const Real im = 1 / mass_[anchors_[k].slot];
    put(anchor_blocks_[k].x[0], anchors_[k].k * I, -im);
    if (c > 0) put(anchor_blocks_[k].v[0], c * I, -im);
  }
  // F_i = -k C g_i  =>  ∂F_i/∂x_j = -k (g_i g_jᵀ + C H_ij), H the Hessian of V.
  for (std::size_t k = 0; k < volumes_.size(); ++k) {
    const auto& e = volumes_[k];
    Vec3 p[4], g[4];
    for (int q = 0; q < 4; ++q) p[q] = position(y, e.slot[q], e.fixed[q]);
    const Real C = tet_volume_gradient(p[0], p[1], p[2], p[3], g) - e.rest;
    Mat3r H[4][4];
    tet_volume_hessian(p[0], p[1], p[2], p[3], H);
    for (int i = 0; i < 4; ++i) {
      if (e.slot[i] < 0) continue;
      const Real im = 1 / mass_[e.slot[i]];
      for (int j = 0; j < 4; ++j) {
        const Mat3r K = e.k * (g[i] * g[j].transpose() + C * H[i][j]);
        put(volume_blocks_[k].x[4 * i + j], K, -im);
      }
    }
  }
  // Families: their blocks ∂f_i/∂x_j (Gauss-Newton, plus curvature where the family has it), / m_i.
  if (!families_.empty()) {
    std::vector<Real> x, K;
    full_positions(y, x);
    for (const FamilyTerm& t : families_) {
      const int arity = t.batch->info().arity;
      const Index* q = t.batch->particle_data();
      K.resize(t.blocks.size());
      t.batch->stiffness_blocks(x.data(), K.data());
      for (Index c = 0; c < t.batch->size(); ++c)
        for (int i = 0; i < arity; ++i) {
          const Index si = slot_of_[q[c * arity + i]];
          if (si < 0) continue;
          const Real im = 1 / mass_[si];
          for (int j = 0; j < arity; ++j) {
            const std::size_t b = ((static_cast<std::size_t>(c) * arity + i) * arity + j) * 9;
            if (t.blocks[b] < 0) continue;
            for (int e = 0; e < 9; ++e) values[t.blocks[b + e]] += im * K[b + e];
          }
        }
    }
  }
}

// ------------------------------------------------------------------------- position-level network

Real SpringNetwork::balloon_constraint(const Real* y, const Balloon& b, Positions& p, std::vector<Vec3>& grad) const {
  const Index m = static_cast<Index>(b.slot.size());
  p.resize(3, m);
  std::vector<Index> local(m);
  for (Index k = 0; k < m; ++k) {
    p.col(k) = position(y, b.slot[k], b.fixed[k]);
    local[k] = k;
  }
  grad.resize(m);
  return enclosed_volume_gradient(p.data(), local.data(), m, b.triangles.data(), static_cast<Index>(b.triangles.size()),
                                  grad.data()) -
         b.target;
}

Real SpringNetwork::potential(const Real* x) const {
  Real u = 0;
  for (const auto& s : springs_) {
    const Real len = (position(x, s.a, s.fixed_a) - position(x, s.b, s.fixed_b)).norm();
    const Real viol = distance_violation(len - s.rest, s.sense);
    u += s.k * viol * viol / 2;
  }
  for (const auto& e : bending_) {
    Vec3 p[4], grad[4];
    for (int k = 0; k < 4; ++k) p[k] = position(x, e.slot[k], e.fixed[k]);
    Real theta = 0;
    if (!dihedral_angle_and_gradient(p[0], p[1], p[2], p[3], theta, grad)) continue;
    const Real C = wrap_angle(theta - e.rest);
    u += e.k * C * C / 2;
  }
  for (const auto& e : volumes_) {
    Vec3 p[4], g[4];
    for (int k = 0; k < 4; ++k) p[k] = position(x, e.slot[k], e.fixed[k]);
    const Real C = tet_volume_gradient(p[0], p[1], p[2], p[3], g) - e.rest;  // the forces' V, bit for bit
    u += e.k * C * C / 2;
  }
  for (const auto& b : balloons_) {
    Positions p;
    std::vector<Vec3> grad;
    const Real C = balloon_constraint(x, b, p, grad);
    u += b.k * C * C / 2;
  }
  for (const auto& q : anchors_) u += q.k * (position(x, q.slot, q.target) - q.target).squaredNorm() / 2;
  if (!families_.empty()) {
    std::vector<Real> all;
    full_positions(x, all);
    for (const FamilyTerm& t : families_) u += t.batch->energy(all.data());
  }
  return u;
}

void SpringNetwork::stiffness(const Real* x, bool definite, Stiffness& out) const {
  out.entries.clear();
  out.rank_one_weight.clear();
  out.rank_one_vector.clear();
  const Mat3r I = Mat3r::Identity();
  const auto put = [&out](Index si, Index sj, const Mat3r& K) {
    if (si < 0 || sj < 0) return;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        if (K(r, c) != 0) out.entries.emplace_back(3 * si + r, 3 * sj + c, K(r, c));
  };
  for (const auto& s : springs_) {
    const Vec3 d = position(x, s.a, s.fixed_a) - position(x, s.b, s.fixed_b);
    const Real len = d.norm();
    if (!(len > 0)) continue;
    const Vec3 nrm = d / len;
    const Real viol = distance_violation(len - s.rest, s.sense);
    if (!(s.sense == 0 || viol != 0)) continue;
    const Mat3r nn = nrm * nrm.transpose();
    Real geometric = viol / len;  // k (n nᵀ + C/|d| (I - n nᵀ)), the compressed one's second term < 0
    if (definite) geometric = std::max<Real>(geometric, 0);
    const Mat3r K = s.k * (nn + geometric * (I - nn));
    put(s.a, s.a, K);
    put(s.b, s.b, K);
    put(s.a, s.b, -K);
    put(s.b, s.a, -K);
  }
  for (const auto& e : bending_) {
    // k (∇θ ∇θᵀ + C ∇²θ); ∇²θ by central differences of the analytic gradient.
    Vec3 p[4], g[4];
    for (int k = 0; k < 4; ++k) p[k] = position(x, e.slot[k], e.fixed[k]);
    Real theta = 0;
    if (!dihedral_angle_and_gradient(p[0], p[1], p[2], p[3], theta, g)) continue;
    const Real C = wrap_angle(theta - e.rest);
    Mat3r H[4][4];
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) H[i][j] = g[i] * g[j].transpose();
    if (!definite && C != 0) {
      const Real scale = std::max({(p[1] - p[0]).norm(), (p[2] - p[0]).norm(), (p[3] - p[0]).norm()});
      const Real delta = 1e-5 * scale;
      Mat3r D[4][4];
      bool ok = true;
      for (int j = 0; j < 4 && ok; ++j)
        for (int c = 0; c < 3 && ok; ++c) {
          Vec3 q[4] = {p[0], p[1], p[2], p[3]}, gp[4], gm[4];
          q[j][c] = p[j][c] + delta;
          ok = dihedral_gradient(q[0], q[1], q[2], q[3], gp);
          q[j][c] = p[j][c] - delta;
          ok = ok && dihedral_gradient(q[0], q[1], q[2], q[3], gm);
          for (int i = 0; i < 4; ++i) D[i][j].col(c) = (gp[i] - gm[i]) / (2 * delta);
        }
      if (ok)
        for (int i = 0; i < 4; ++i)
          for (int j = 0; j < 4; ++j) H[i][j] += C * (D[i][j] + D[j][i].transpose()) / 2;
    }
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) put(e.slot[i], e.slot[j], e.k * H[i][j]);
  }
  for (const auto& e : volumes_) {
    Vec3 p[4], g[4];
    for (int q = 0; q < 4; ++q) p[q] = position(x, e.slot[q], e.fixed[q]);
    const Real C = tet_volume_gradient(p[0], p[1], p[2], p[3], g) - e.rest;
    Mat3r H[4][4];
    tet_volume_hessian(p[0], p[1], p[2], p[3], H);
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j)
        put(e.slot[i], e.slot[j], e.k * (g[i] * g[j].transpose() + (definite ? 0 : C) * H[i][j]));
  }
  for (const auto& b : balloons_) {
    // k ∇V ∇Vᵀ (dense over the surface: returned apart) + k C ∇²V, with V = Σ a·(b×c)/6 over the
    // triangles: ∂²V/∂a∂b = -[c]x/6 and its cyclic shifts.
    const Index m = static_cast<Index>(b.slot.size());
    Positions p;
    std::vector<Vec3> grad;
    const Real C = balloon_constraint(x, b, p, grad);
    std::vector<Real> u(3 * dynamic_.size(), 0.0);
    for (Index k = 0; k < m; ++k)
      if (b.slot[k] >= 0)
        for (int c = 0; c < 3; ++c) u[3 * b.slot[k] + c] += grad[k][c];
    out.rank_one_weight.push_back(b.k);
    out.rank_one_vector.push_back(std::move(u));
    if (definite || C == 0) continue;
    for (const Triangle& t : b.triangles)
      for (int i = 0; i < 3; ++i) {
        const int j = (i + 1) % 3, k = (i + 2) % 3;
        const Mat3r H = -skew(p.col(t[k])) / 6 * (b.k * C);  // ∂²V/∂p_i∂p_j
        put(b.slot[t[i]], b.slot[t[j]], H);
        put(b.slot[t[j]], b.slot[t[i]], H.transpose());
      }
  }
  for (const auto& q : anchors_) put(q.slot, q.slot, q.k * I);
  if (!families_.empty()) {
    std::vector<Real> all, blocks, c, grad, v;
    full_positions(x, all);
    for (const FamilyTerm& t : families_) {
      const int arity = t.batch->info().arity;
      const Index* q = t.batch->particle_data();
      const Index count = t.batch->size();
      const std::size_t per = static_cast<std::size_t>(arity) * arity * 9;
      blocks.assign(per * static_cast<std::size_t>(count), 0.0);
      if (!definite) {
        t.batch->stiffness_blocks(all.data(), blocks.data());  // ∂f/∂x = -∇²U
      } else {  // Gauss-Newton: ∇C ∇Cᵀ/α where active
        c.resize(count);
        v.resize(count);
        grad.resize(static_cast<std::size_t>(count) * arity * 3);
        t.batch->evaluate(all.data(), c.data(), grad.data());
        t.batch->violations(all.data(), v.data());
        for (Index k = 0; k < count; ++k) {
          const Real alpha = t.batch->compliance[k];
          if (!(alpha > 0) || (t.batch->info().unilateral && v[k] == 0)) continue;
          for (int i = 0; i < arity; ++i)
            for (int j = 0; j < arity; ++j)
              for (int r = 0; r < 3; ++r)
                for (int s = 0; s < 3; ++s)
                  blocks[per * k + (i * arity + j) * 9 + 3 * r + s] =
                      -grad[(static_cast<std::size_t>(k) * arity + i) * 3 + r] * grad[(static_cast<std::size_t>(k) * arity + j) * 3 + s] / alpha;
        }
      }
      for (Index k = 0; k < count; ++k)
        for (int i = 0; i < arity; ++i)
          for (int j = 0; j < arity; ++j) {
            const Index si = slot_of_[q[k * arity + i]], sj = slot_of_[q[k * arity + j]];
            Mat3r K;
            for (int e = 0; e < 9; ++e) K.data()[e] = -blocks[per * k + (i * arity + j) * 9 + e];
            put(si, sj, K);
          }
    }
  }
}

void SpringNetwork::force_scale(const Real* x, Real& largest, Real& rounding) const {
  constexpr Real eps = std::numeric_limits<Real>::epsilon();
  largest = 0;
  rounding = 0;
  const auto inf = [](const Vec3& p) { return p.cwiseAbs().maxCoeff(); };
  // A constraint of value C, gradient blocks g_j over positions p_j and stiffness k = 1/α.
  const auto account = [&](Real C, const Vec3* g, const Vec3* p, int arity, Real k) {
    Real size = 0, sum = 0, top = 0;
    for (int j = 0; j < arity; ++j) {
      size = std::max(size, inf(p[j]));
      sum += g[j].norm();
      top = std::max(top, g[j].norm());
    }
    largest = std::max(largest, std::abs(C) * k * top);
    rounding = std::max(rounding, 4 * eps * size * sum * k * top);
  };
  for (const auto& s : springs_) {
    const Vec3 pa = position(x, s.a, s.fixed_a), pb = position(x, s.b, s.fixed_b);
    const Real viol = distance_violation((pa - pb).norm() - s.rest, s.sense);
    largest = std::max(largest, std::abs(viol) * s.k);
    rounding = std::max(rounding, 4 * eps * (inf(pa) + inf(pb)) * s.k);
  }
  for (const auto& e : bending_) {
    Vec3 p[4], g[4];
    for (int k = 0; k < 4; ++k) p[k] = position(x, e.slot[k], e.fixed[k]);
    Real theta = 0;
    if (dihedral_angle_and_gradient(p[0], p[1], p[2], p[3], theta, g)) account(wrap_angle(theta - e.rest), g, p, 4, e.k);
  }
  for (const auto& e : volumes_) {
    Vec3 p[4], g[4];
    for (int k = 0; k < 4; ++k) p[k] = position(x, e.slot[k], e.fixed[k]);
    account(tet_volume_gradient(p[0], p[1], p[2], p[3], g) - e.rest, g, p, 4, e.k);
  }
  for (const auto& b : balloons_) {
    Positions p;
    std::vector<Vec3> grad;
    const Real C = balloon_constraint(x, b, p, grad);
    Real terms = 0, top = 0;  // V's rounding: eps times the sum of its terms' sizes
    for (const Triangle& t : b.triangles)
      terms += p.col(t[0]).norm() * p.col(t[1]).norm() * p.col(t[2]).norm() / 6;
    for (const Vec3& g : grad) top = std::max(top, g.norm());
    largest = std::max(largest, std::abs(C) * b.k * top);
    rounding = std::max(rounding, 4 * eps * terms * b.k * top);
  }
  for (const auto& q : anchors_) {
    const Vec3 p = position(x, q.slot, q.target);
    largest = std::max(largest, (p - q.target).norm() * q.k);
    rounding = std::max(rounding, 4 * eps * (inf(p) + inf(q.target)) * q.k);
  }
  if (!families_.empty()) {
    std::vector<Real> all, c, grad, v;
    full_positions(x, all);
    for (const FamilyTerm& t : families_) {
      const int arity = t.batch->info().arity;
      const Index* q = t.batch->particle_data();
      const Index count = t.batch->size();
      c.resize(count);
      v.resize(count);
      grad.resize(static_cast<std::size_t>(count) * arity * 3);
      t.batch->evaluate(all.data(), c.data(), grad.data());
      t.batch->violations(all.data(), v.data());
      std::vector<Vec3> g(arity), p(arity);
      for (Index k = 0; k < count; ++k) {
        for (int j = 0; j < arity; ++j) {
          const std::size_t o = (static_cast<std::size_t>(k) * arity + j) * 3;
          g[j] = Vec3(grad[o], grad[o + 1], grad[o + 2]);
          const std::size_t i = 3 * static_cast<std::size_t>(q[k * arity + j]);
          p[j] = Vec3(all[i], all[i + 1], all[i + 2]);
        }
        account(v[k], g.data(), p.data(), arity, 1 / t.batch->compliance[k]);
      }
    }
  }
}

// ------------------------------------------------------------------------------------ CVODE

namespace {

// GMRES preconditioner: the Newton matrix of the springs and attachments,
// P = I - γ J_s = [[I, -γI], [-γA, I - γB]] with A = ∂v̇/∂x and B = ∂v̇/∂v, solved through its
// Schur complement S = I - γB - γ²A (3n x 3n, the pattern of the spring graph), factored by
// KLU: P z = r  <=>  S z_v = r_v + γ A r_x,  z_x = r_x + γ z_v.
struct Schur {
  std::int64_t n3 = 0;
  std::vector<std::int64_t> col_start, row_index;            // S, compressed sparse columns
  std::vector<std::int64_t> a_entry, a_target, a_row, a_col;  // A's entries in J and in S
  std::vector<std::int64_t> b_entry, b_target;                // B's entries in J and in S
  std::vector<std::int64_t> diagonal;                         // S's diagonal entries
  std::vector<Real> jac;                                      // J_s at the last set-up
  Real gamma = 0;
  SUNMatrix S = nullptr;
  SUNLinearSolver solver = nullptr;
  N_Vector rhs = nullptr, sol = nullptr;

  void build(const SpringNetwork& net) {
    n3 = static_cast<std::int64_t>(net.size() / 2);
    const auto& cs = net.jacobian_column_starts();
    const auto& ri = net.jacobian_row_indices();
    std::vector<std::pair<std::int64_t, std::int64_t>> entries;  // (col, row) of S
    for (std::int64_t c = 0; c < 2 * n3; ++c)
      for (std::int64_t e = cs[c]; e < cs[c + 1]; ++e)
        if (ri[e] >= n3) entries.push_back({c % n3, ri[e] - n3});
    for (std::int64_t r = 0; r < n3; ++r) entries.push_back({r, r});
    const Csc pattern(std::move(entries), n3);
    col_start = pattern.col_start;
    row_index = pattern.row_index;
    const auto find = [&pattern](std::int64_t row, std::int64_t col) { return pattern.find(row, col); };
    for (std::int64_t c = 0; c < 2 * n3; ++c)
      for (std::int64_t e = cs[c]; e < cs[c + 1]; ++e) {
        if (ri[e] < n3) continue;
        const std::int64_t target = find(ri[e] - n3, c % n3);
        if (c < n3) {
          a_entry.push_back(e);
          a_target.push_back(target);
          a_row.push_back(ri[e] - n3);
          a_col.push_back(c);
        } else {
          b_entry.push_back(e);
          b_target.push_back(target);
        }
      }
    for (std::int64_t r = 0; r < n3; ++r) diagonal.push_back(find(r, r));
  }

  int setup() {
    std::copy(col_start.begin(), col_start.end(), SUNSparseMatrix_IndexPointers(S));
    std::copy(row_index.begin(), row_index.end(), SUNSparseMatrix_IndexValues(S));
    Real* v = SUNSparseMatrix_Data(S);
    std::fill(v, v + row_index.size(), 0.0);
    for (std::int64_t d : diagonal) v[d] = 1;
    for (std::size_t k = 0; k < a_entry.size(); ++k) v[a_target[k]] -= gamma * gamma * jac[a_entry[k]];
    for (std::size_t k = 0; k < b_entry.size(); ++k) v[b_target[k]] -= gamma * jac[b_entry[k]];
    return SUNLinSolSetup(solver, S) == 0 ? 0 : 1;
  }

  int solve(const Real* r, Real* z) {
    Real* b = N_VGetArrayPointer(rhs);
    std::copy(r + n3, r + 2 * n3, b);
    for (std::size_t k = 0; k < a_entry.size(); ++k) b[a_row[k]] += gamma * jac[a_entry[k]] * r[a_col[k]];
    if (SUNLinSolSolve(solver, S, sol, rhs, 0.0) != 0) return 1;
    const Real* zv = N_VGetArrayPointer(sol);
    for (std::int64_t i = 0; i < n3; ++i) {
      z[n3 + i] = zv[i];
      z[i] = r[i] + gamma * zv[i];
    }
    return 0;
  }

  void release() {
    if (solver) SUNLinSolFree(solver);
    if (S) SUNMatDestroy(S);
    if (rhs) N_VDestroy(rhs);
    if (sol) N_VDestroy(sol);
    solver = nullptr;
    S = nullptr;
    rhs = sol = nullptr;
  }
  ~Schur() { release(); }
};

struct Run {
  const SpringNetwork* net = nullptr;
  std::chrono::steady_clock::time_point deadline;
  bool has_deadline = false;
  bool timed_out = false;
  bool non_finite = false;
  std::string cvode_message;
  Schur schur;
};

int rhs_fn(realtype, N_Vector y, N_Vector ydot, void* data) {
  auto* run = static_cast<Run*>(data);
  if (run->has_deadline && std::chrono::steady_clock::now() > run->deadline) {
    run->timed_out = true;
    return -1;
  }
  const Real* yp = N_VGetArrayPointer(y);
  Real* out = N_VGetArrayPointer(ydot);
  run->net->rhs(yp, out);
  const std::size_t n = run->net->size();
  for (std::size_t k = 0; k < n; ++k)
    if (!std::isfinite(out[k])) {
      run->non_finite = true;
      return 1;  // recoverable: CVODE retries with a smaller step
    }
  return 0;
}

void set_structure(SUNMatrix A, const SpringNetwork& net) {
  const auto& cs = net.jacobian_column_starts();
  const auto& ri = net.jacobian_row_indices();
  std::copy(cs.begin(), cs.end(), SUNSparseMatrix_IndexPointers(A));
  std::copy(ri.begin(), ri.end(), SUNSparseMatrix_IndexValues(A));
}

int jac_fn(realtype, N_Vector y, N_Vector, SUNMatrix J, void* data, N_Vector, N_Vector, N_Vector) {
  auto* run = static_cast<Run*>(data);
  set_structure(J, *run->net);  // SUNMatZero clears the structure too
  run->net->jacobian(N_VGetArrayPointer(y), SUNSparseMatrix_Data(J));
  return 0;
}

int prec_setup(realtype, N_Vector y, N_Vector, booleantype jok, booleantype* jcur, realtype gamma, void* data) {
  auto* run = static_cast<Run*>(data);
  Schur& p = run->schur;
  if (!jok || p.jac.empty()) {
    p.jac.resize(run->net->jacobian_row_indices().size());
    run->net->jacobian(N_VGetArrayPointer(y), p.jac.data());
    *jcur = SUNTRUE;
  } else {
    *jcur = SUNFALSE;
  }
  p.gamma = gamma;
  return p.setup();
}

int prec_solve(realtype, N_Vector, N_Vector, N_Vector r, N_Vector z, realtype, realtype, int, void* data) {
  return static_cast<Run*>(data)->schur.solve(N_VGetArrayPointer(r), N_VGetArrayPointer(z));
}

void error_handler(int, const char* module, const char* function, char* msg, void* data) {
  auto* run = static_cast<Run*>(data);
  run->cvode_message = std::string(module) + "." + function + ": " + msg;
}

// RAII owners of the SUNDIALS objects.
struct Sundials {
  SUNContext ctx = nullptr;
  N_Vector y = nullptr;
  void* mem = nullptr;
  SUNMatrix A = nullptr;
  SUNLinearSolver LS = nullptr;
  Run* run = nullptr;
  ~Sundials() {
    if (mem) CVodeFree(&mem);
    if (LS) SUNLinSolFree(LS);
    if (A) SUNMatDestroy(A);
    if (run) run->schur.release();  // before the context it was made in
    if (y) N_VDestroy(y);
    if (ctx) SUNContext_Free(&ctx);
  }
};

void check(int flag, const char* what) {
  if (flag < 0) throw Error(std::string("reference: SUNDIALS set-up failed in ") + what + " (flag " + std::to_string(flag) + ")");
}

}  // namespace

ReferenceResult integrate_reference(const Model& model, const State& start, const std::vector<Real>& times,
                                    const ReferenceSettings& settings) {
  const auto wall0 = std::chrono::steady_clock::now();
  SpringNetwork net(model, start, settings);
  const Real t0 = start.t;
  for (std::size_t k = 0; k < times.size(); ++k) {
    if (!std::isfinite(times[k])) throw InvalidArgument("output time " + std::to_string(k) + " is not finite");
    if (times[k] < t0)
      throw InvalidArgument("output time " + std::to_string(k) + " (" + str(times[k]) + " s) is before the start time " +
                            str(t0) + " s");
    if (k > 0 && !(times[k] > times[k - 1]))
      throw InvalidArgument("output times must increase: time " + std::to_string(k) + " (" + str(times[k]) +
                            " s) is not after time " + std::to_string(k - 1) + " (" + str(times[k - 1]) + " s)");
  }

  Run run;
  run.net = &net;
  if (settings.max_wall_time > 0) {
    run.has_deadline = true;
    run.deadline = wall0 + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                               std::chrono::duration<double>(settings.max_wall_time));
  }
  Sundials s;
  s.run = &run;
  check(SUNContext_Create(nullptr, &s.ctx), "SUNContext_Create");
  const auto N = static_cast<sunindextype>(net.size());
  s.y = N_VNew_Serial(N, s.ctx);
  if (!s.y) throw Error("reference: cannot allocate the state vector");
  net.pack(start, N_VGetArrayPointer(s.y));
  s.mem = CVodeCreate(CV_BDF, s.ctx);
  if (!s.mem) throw Error("reference: CVodeCreate failed");
  check(CVodeSetErrHandlerFn(s.mem, error_handler, &run), "CVodeSetErrHandlerFn");
  check(CVodeInit(s.mem, rhs_fn, t0, s.y), "CVodeInit");
  check(CVodeSStolerances(s.mem, settings.rtol, settings.atol), "CVodeSStolerances");
  check(CVodeSetUserData(s.mem, &run), "CVodeSetUserData");
  check(CVodeSetMaxOrd(s.mem, settings.max_order), "CVodeSetMaxOrd");
  check(CVodeSetStabLimDet(s.mem, settings.stability_limit_detection ? SUNTRUE : SUNFALSE), "CVodeSetStabLimDet");
  check(CVodeSetMaxHnilWarns(s.mem, -1), "CVodeSetMaxHnilWarns");

  const auto nnz = static_cast<sunindextype>(net.jacobian_row_indices().size());
  const bool klu = settings.linear_solver == ReferenceSettings::Linear::Klu ||
                   (settings.linear_solver == ReferenceSettings::Linear::Automatic && net.has_analytic_jacobian());
  ReferenceResult result;
  result.stats.linear_solver = klu ? "klu" : "gmres";
  if (klu) {
    s.A = SUNSparseMatrix(N, N, nnz, CSC_MAT, s.ctx);
    s.LS = SUNLinSol_KLU(s.y, s.A, s.ctx);
    if (!s.A || !s.LS) throw Error("reference: cannot create the KLU solver");
    // AMD on the symmetric pattern of the Newton matrix [[I, -γI], [-γA, I - γB]] fills in far
    // less than KLU's default COLAMD.
    check(SUNLinSol_KLUSetOrdering(s.LS, 0), "SUNLinSol_KLUSetOrdering");
    check(CVodeSetLinearSolver(s.mem, s.LS, s.A), "CVodeSetLinearSolver");
    check(CVodeSetJacFn(s.mem, jac_fn), "CVodeSetJacFn");
  } else {
    s.LS = SUNLinSol_SPGMR(s.y, SUN_PREC_LEFT, 30, s.ctx);
    Schur& p = run.schur;
    p.build(net);
    const auto n3 = static_cast<sunindextype>(p.n3);
    p.rhs = N_VNew_Serial(n3, s.ctx);
    p.sol = N_VNew_Serial(n3, s.ctx);
    p.S = SUNSparseMatrix(n3, n3, static_cast<sunindextype>(p.row_index.size()), CSC_MAT, s.ctx);
    p.solver = p.rhs && p.S ? SUNLinSol_KLU(p.rhs, p.S, s.ctx) : nullptr;
    if (!s.LS || !p.sol || !p.solver) throw Error("reference: cannot create the GMRES solver");
    check(SUNLinSol_KLUSetOrdering(p.solver, 0), "SUNLinSol_KLUSetOrdering");
    check(CVodeSetLinearSolver(s.mem, s.LS, nullptr), "CVodeSetLinearSolver");
    check(CVodeSetPreconditioner(s.mem, prec_setup, prec_solve), "CVodeSetPreconditioner");
  }

  const auto collect_stats = [&]() {
    ReferenceStats& st = result.stats;
    CVodeGetNumSteps(s.mem, &st.steps);
    CVodeGetNumRhsEvals(s.mem, &st.rhs_evals);
    CVodeGetNumNonlinSolvIters(s.mem, &st.newton_iters);
    CVodeGetNumNonlinSolvConvFails(s.mem, &st.newton_failures);
    CVodeGetNumErrTestFails(s.mem, &st.error_test_failures);
    if (klu)
      CVodeGetNumJacEvals(s.mem, &st.jacobian_evals);
    else
      CVodeGetNumPrecEvals(s.mem, &st.jacobian_evals);
    CVodeGetNumLinIters(s.mem, &st.linear_iters);
    CVodeGetLastOrder(s.mem, &st.last_order);
    CVodeGetLastStep(s.mem, &st.last_step);
    st.wall_time = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  };

  Positions x, v;
  realtype t_reached = t0;
  for (std::size_t k = 0; k < times.size(); ++k) {
    if (times[k] > t_reached) {
      long steps = 0;
      CVodeGetNumSteps(s.mem, &steps);
      const long left = static_cast<long>(settings.max_steps) - steps;
      if (left <= 0 || CVodeSetMaxNumSteps(s.mem, left) < 0) {
        collect_stats();
        throw SimulationError("reference: gave up at t = " + str(t_reached) + " s after max_steps = " +
                              std::to_string(settings.max_steps) + " internal steps");
      }
      const int flag = CVode(s.mem, times[k], s.y, &t_reached, CV_NORMAL);
      if (flag < 0) {
        collect_stats();
        realtype t_now = t_reached;
        CVodeGetCurrentTime(s.mem, &t_now);
        std::ostringstream msg;
        msg << "reference: CVODE stopped at t = " << t_now << " s on the way to " << times[k] << " s: ";
        if (run.timed_out)
          msg << "max_wall_time = " << settings.max_wall_time << " s ran out";
        else if (flag == CV_TOO_MUCH_WORK)
          msg << "max_steps = " << settings.max_steps << " internal steps were not enough";
        else
          msg << CVodeGetReturnFlagName(flag) << (run.cvode_message.empty() ? "" : " (" + run.cvode_message + ")")
              << (run.non_finite ? "; the forces became non-finite" : "");
        msg << " [" << result.stats.steps << " steps, last step " << result.stats.last_step << " s, order "
            << result.stats.last_order << "]";
        throw SimulationError(msg.str());
      }
    }
    net.unpack(N_VGetArrayPointer(s.y), x, v);
    result.times.push_back(times[k]);
    result.x.push_back(x);
    result.v.push_back(v);
  }
  collect_stats();
  return result;
}

}  // namespace csb
