// csb — grabs: a particle held by the user's hand, kinematic (it follows the hand) or compliant (an
// XPBD spring to it); the stepper owns them, the Model stays immutable.
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/constraints/attachment.hpp"

namespace csb {

using detail::str;
using namespace stepper_detail;

int PbdStepper::grab(const Model& model, const State& state, Index particle, const Vec3& target, Real compliance) {
  const UseGuard::Scope in_use(use_, "PbdStepper.grab");
  if (particle < 0 || particle >= model.num_particles())
    throw InvalidArgument("grab: particle " + std::to_string(particle) + " is out of range (the model has " +
                          std::to_string(model.num_particles()) + " particles)");
  if (state.x.cols() != model.num_particles()) throw InvalidArgument("grab: the state does not belong to the model");
  if (!target.allFinite()) throw InvalidArgument("grab: target must be finite, got " + str(target));
  if (!(compliance >= 0) || !std::isfinite(compliance))
    throw InvalidArgument("grab: compliance must be a finite value >= 0 m/N, got " + str(compliance));
  for (const Grab& g : grabs_)
    if (g.particle == particle)
      throw InvalidArgument("grab: particle " + std::to_string(particle) + " is already held (handle " +
                            std::to_string(g.handle) + ")");
  Grab g;
  g.handle = next_grab_++;
  g.particle = particle;
  g.target = target;
  g.from = state.x.col(particle);
  g.compliance = compliance;
  g.pinned = model.inv_mass[particle] == 0;
  grabs_.push_back(g);
  return g.handle;
}

Grab& PbdStepper::find_grab(int handle) {
  if (handle < 0)
    throw InvalidArgument("handle " + std::to_string(handle) + " holds a particle attached to a collider: use detach");
  for (Grab& g : grabs_)
    if (g.handle == handle) return g;
  throw InvalidArgument("no grab with handle " + std::to_string(handle) + " (released already?)");
}

void PbdStepper::move_grab(int handle, const Vec3& target) {
  const UseGuard::Scope in_use(use_, "PbdStepper.move_grab");
  if (!target.allFinite()) throw InvalidArgument("move_grab: target must be finite, got " + str(target));
  find_grab(handle).target = target;
}

void PbdStepper::release(int handle) {
  const UseGuard::Scope in_use(use_, "PbdStepper.release");
  const Grab& g = find_grab(handle);
  if (g.pinned) stop_.push_back(g.particle);
  grabs_.erase(grabs_.begin() + (&g - grabs_.data()));
}

// The hand's position `fraction` of the way through this step: kinematic grabs are put there,
// compliant ones pull towards it.
void PbdStepper::apply_grab_targets(Real fraction) {
  grab_fraction_ = fraction;
  for (const Grab& g : grabs_)
    if (g.compliance == 0) p_.col(g.particle) = g.at(fraction);
  std::fill(grab_lambda_.begin(), grab_lambda_.end(), 0.0);
}

// Compliant grabs: XPBD attachments to the hand (Macklin 2016 Eq. 18), after each sweep.
void PbdStepper::project_grabs(const Positions& x_start) {
  const Real h = substep_size();
  for (std::size_t k = 0; k < grabs_.size(); ++k) {
    const Grab& g = grabs_[k];
    if (g.compliance == 0) continue;
    const Index i = g.particle;
    const Vec3 target = g.from + grab_fraction_ * (g.target - g.from);
    project_attachment_xpbd(p_.col(i).data(), x_start.col(i).data(), w_[i], target.data(),
                            g.compliance / (h * h), 0, grab_lambda_[k]);
  }
}

// Kinematic grabs: infinite mass while held (w_ is the model's inverse masses with theirs at 0);
// the compliant grabs' multipliers.
void PbdStepper::hold_grabbed(const Model& model) {
  if (grabs_.empty()) return;
  const Index n = model.num_particles();
  w_ = model.inv_mass;
  for (const Grab& g : grabs_) {
    if (g.particle >= n)
      throw InvalidArgument("grab " + std::to_string(g.handle) + " holds particle " + std::to_string(g.particle) +
                            ", but this model has " + std::to_string(n) + " particles");
    if (g.compliance == 0) w_[g.particle] = 0;
  }
  grab_lambda_.assign(grabs_.size(), 0);
}

}  // namespace csb
