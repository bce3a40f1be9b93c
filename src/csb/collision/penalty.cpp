#include "csb/collision/penalty.hpp"

#include <algorithm>
#include <limits>

namespace csb {

void PenaltyContacts::generate(const Model& model, const Positions& x, const Positions& x_tilde, Real h, Real kappa) {
  contacts_.clear();
  stiffness_.clear();
  kappa_ = kappa;
  if (model.colliders.empty()) return;
  std::size_t most_triangles = 0;
  for (const Collider& c : model.colliders)
    if (c.mesh) most_triangles = std::max(most_triangles, c.mesh->triangles.size());
  if (stamps_.size() != most_triangles) {
    stamps_.assign(most_triangles, 0);
    stamp_ = 0;
  }
  // Speculative margin per group: the farthest any of its particles moves in the prediction
  // (the pipeline's rule, contacts.cpp).
  margin_.assign(static_cast<std::size_t>(model.num_groups()), 0);
  for (Index i = 0; i < model.num_particles(); ++i)
    if (model.inv_mass[i] > 0)
      margin_[model.group[i]] = std::max(margin_[model.group[i]], (x_tilde.col(i) - x.col(i)).norm());
  for (Index i = 0; i < model.num_particles(); ++i) {
    if (!(model.inv_mass[i] > 0)) continue;
    const Vec3 xi = x.col(i), pi = x_tilde.col(i);
    for (Index c = 0; c < static_cast<Index>(model.colliders.size()); ++c)
      generate_contact(model.colliders[c], c, i, xi, pi, model.thickness[i], margin_[model.group[i]], h, contacts_,
                       stamps_, stamp_);
  }
  stiffness_.reserve(contacts_.size());
  for (const Contact& k : contacts_) stiffness_.push_back(kappa * model.mass[k.particle] / (h * h));
}

void PenaltyContacts::finish(const Model& model, const Positions& x_start, State& state, Real h, const Vec3& gravity) {
  if (contacts_.empty()) return;
  // The normal correction each contact made: its force k|C| times h²/m, i.e. κ|C| (m).
  for (std::size_t c = 0; c < contacts_.size(); ++c) {
    Contact& k = contacts_[c];
    k.normal_correction = -kappa_ * violation(c, state.x.col(k.particle));
  }
  rub_and_bounce(model, x_start, state, h, gravity);
}

void PenaltyContacts::finish_projected(const Model& model, const Positions& x_start, const Positions& x_tilde,
                                       State& state, Real h, const Vec3& gravity) {
  if (contacts_.empty()) return;
  constexpr Real eps = std::numeric_limits<Real>::epsilon();
  for (Contact& k : contacts_) {
    const Vec3 p = state.x.col(k.particle);
    const Real C = (p - k.point).dot(k.normal) - k.thickness;
    const bool on_plane = C <= 8 * eps * (p.norm() + k.point.norm() + k.thickness);  // projected onto it
    k.normal_correction = on_plane ? std::max<Real>(0, (p - x_tilde.col(k.particle)).dot(k.normal)) : 0;
  }
  rub_and_bounce(model, x_start, state, h, gravity);
}

void PenaltyContacts::rub_and_bounce(const Model& model, const Positions& x_start, State& state, Real h,
                                     const Vec3& gravity) {
  for (const Contact& k : contacts_) {  // Coulomb friction on the step's displacement
    const Real d = k.normal_correction;
    const ContactMaterial& m = model.colliders[k.collider].material;
    if (!(d > 0) || !(m.friction_static > 0)) continue;
    const Index i = k.particle;
    const Vec3 dx = state.x.col(i) - x_start.col(i);
    const Vec3 dt = dx - dx.dot(k.normal) * k.normal;
    const Real len = dt.norm();
    const Vec3 back = len <= m.friction_static * d ? dt : Vec3((m.friction_kinetic * d / len) * dt);
    state.x.col(i) -= back;
    state.v.col(i) -= back / h;
  }
  const Real v_rest = 2 * gravity.norm() * h;
  for (const Contact& k : contacts_) {  // restitution
    if (!(k.normal_correction > 0)) continue;
    const Index i = k.particle;
    const Real vn = state.v.col(i).dot(k.normal);
    Real target = vn;
    if (k.started_inside)
      target = std::min(vn, Real(0));
    else if (k.approach_speed < -v_rest)
      target = std::max(vn, -model.colliders[k.collider].material.restitution * k.approach_speed);
    if (target != vn) state.v.col(i) += (target - vn) * k.normal;
  }
}

bool PenaltyContacts::push_out(const Collider& collider, Real r, Real* p) {
  if (collider.kind == ColliderKind::Mesh) return false;
  const Vec3 x(p[0], p[1], p[2]);
  if (!(signed_distance(collider, x) < r)) return false;
  const SurfacePoint q = closest_surface_point(collider, x);
  const Vec3 out = q.point + r * q.normal;
  for (int e = 0; e < 3; ++e) p[e] = out[e];
  return true;
}

}  // namespace csb
