// csb — contacts with the colliders for the implicit methods (implicit Euler, Projective Dynamics,
// Vertex Block Descent), which minimise an incremental potential instead of projecting.
//
// Once per step of h, from the positions x at its start towards the inertial prediction
// x̃ = x + h v + h² g, the contacts are generated exactly as the position-based pipeline's
// (collision.hpp: continuous along the ray x → x̃, the static fallback for a particle already
// inside, speculative within a margin, the farthest any particle of the group moves in the
// prediction). Each contact is the half-space of its tangent plane, C(x) = (x - q)·n - r >= 0.
//
// A minimiser takes it as the penalty
//
//   E_c(x) = (k/2) min(C, 0)²,   ∇E_c = k min(C, 0) n,   ∇²E_c = k n nᵀ while C < 0
//
// (the Hessian exact and positive semi-definite: C is linear in x), with k = κ m/h² for a particle
// of mass m. At a minimum the inertia m/h² (x - x̃) balances the penalty, so a particle predicted
// to go a depth δ past the plane stops at δ/(1 + κ): with κ = 1e4, a cloth resting on the ground
// under gravity sinks g h²/κ, 0.3 µm at h = 1/60 s. κ is a method setting (contact_stiffness).
//
// After the step, friction and restitution act on the step's displacement and velocity as the
// pipeline's do (contacts.cpp): the normal correction a contact made is its force times h²/m,
// κ |C| at the end of the step (Coulomb at the position level, Macklin et al. 2014 Eq. 24);
// restitution reflects an impact's approach speed with e (Müller et al. 2020 §3.6's threshold).
//
// Projective Dynamics, whose global matrix is constant, takes the contacts by projection instead:
// after each global solve, a particle past a contact's plane is moved onto it (adding the contacts
// to the global matrix would refactor it whenever they change), so the step ends outside the
// colliders; finish_projected() then measures each contact's normal correction.
#pragma once

#include "csb/collision/collision.hpp"
#include "csb/model.hpp"

#include <cstdint>
#include <vector>

namespace csb {

class PenaltyContacts {
 public:
  // The default κ of the implicit methods' contact_stiffness setting (dimensionless).
  static constexpr Real kDefaultStiffness = 1e4;

  // The step's contacts of every particle that can move, from x (3 x N, m) towards x̃ (m), with
  // penalty stiffness κ m/h² (N/m). Clears the last step's.
  void generate(const Model& model, const Positions& x, const Positions& x_tilde, Real h, Real kappa);
  const std::vector<Contact>& contacts() const { return contacts_; }
  bool empty() const { return contacts_.empty(); }
  Real stiffness(std::size_t c) const { return stiffness_[c]; }  // N/m

  // min(C, 0) of contact c at position p (m): the penetration past its plane, <= 0.
  Real violation(std::size_t c, const Vec3& p) const {
    const Contact& k = contacts_[c];
    const Real C = (p - k.point).dot(k.normal) - k.thickness;
    return C < 0 ? C : Real(0);
  }

  // Friction and restitution after a step from x_start that ended at state (x, v; v already
  // (x - x_start)/h): moves x back along the tangent within the friction cone, sets v from it, and
  // reflects the normal velocity of an impact with the collider's restitution.
  void finish(const Model& model, const Positions& x_start, State& state, Real h, const Vec3& gravity);

  // For a method that holds its particles out of the contacts' planes by projection instead of
  // the penalty (Projective Dynamics): moves p (m, 3 values) onto contact c's plane if it is past
  // it. And finish() for such a method: the normal correction of a contact whose particle ended on
  // its plane is how far the particle ended above its inertial prediction x̃ along n (for a lone
  // particle, exactly the push of the position-based pipeline's projection).
  void project(std::size_t c, Real* p) const {
    const Contact& k = contacts_[c];
    const Real C = (Vec3(p[0], p[1], p[2]) - k.point).dot(k.normal) - k.thickness;
    if (C < 0)
      for (int e = 0; e < 3; ++e) p[e] -= C * k.normal[e];
  }
  void finish_projected(const Model& model, const Positions& x_start, const Positions& x_tilde, State& state, Real h,
                        const Vec3& gravity);
  // The static fallback of a projecting method's iterations: a particle that its neighbours
  // dragged inside an analytic collider (one the sub-step's contacts did not foresee: its
  // prediction was beyond the margin) is moved to the nearest surface point plus its thickness r
  // (m). A mesh sheet has no inside and is left to the contacts. Returns whether p moved.
  static bool push_out(const Collider& collider, Real r, Real* p);

 private:
  std::vector<Contact> contacts_;
  std::vector<Real> stiffness_;
  std::vector<Real> margin_;
  // Friction and restitution from the contacts' normal corrections.
  void rub_and_bounce(const Model& model, const Positions& x_start, State& state, Real h, const Vec3& gravity);
  std::vector<std::uint32_t> stamps_;
  std::uint32_t stamp_ = 0;
  Real kappa_ = kDefaultStiffness;
};

}  // namespace csb
