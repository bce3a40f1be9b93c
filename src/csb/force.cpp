#include "csb/force.hpp"
#include "csb/methods/registry.hpp"
#include "csb/memory_budget.hpp"
#include "csb/format.hpp"

#include <cmath>
#include <cstring>
#include <sstream>

namespace csb {

using detail::str;

namespace {

bool same_bits(const Positions& a, const Positions& b) {
  return a.cols() == b.cols() && std::memcmp(a.data(), b.data(), sizeof(Real) * a.size()) == 0;
}

}  // namespace

std::string ForceStepper::name() const { return method_info(settings_.method).name; }

ForceStepper::ForceStepper(const ForceSettings& settings) : settings_(settings) {
  const ForceSettings& s = settings_;
  if (!(s.dt > 0) || !std::isfinite(s.dt)) throw InvalidArgument("dt must be a finite time step > 0 s, got " + str(s.dt));
  if (s.substeps < 1) throw InvalidArgument("substeps must be >= 1, got " + std::to_string(s.substeps));
  if (!s.gravity.allFinite()) throw InvalidArgument("gravity must be finite, got " + str(s.gravity));
  if (!(s.damping >= 0) || !std::isfinite(s.damping))
    throw InvalidArgument("damping must be a finite coefficient >= 0 N s/m, got " + str(s.damping));
  if (!(s.drag >= 0) || !std::isfinite(s.drag)) throw InvalidArgument("drag must be a finite rate >= 0 1/s, got " + str(s.drag));
}

void ForceStepper::step(const Model& model, State& state, std::int64_t steps, const std::function<bool()>& interrupt) {
  const UseGuard::Scope in_use(use_, "ForceStepper.step");
  if (steps < 0) throw InvalidArgument("steps must be >= 0, got " + std::to_string(steps));
  // The spring network has no contact term: a collider or self-collision would be ignored, the
  // cloth passing through the floor or itself. Refused by name rather than silently dropped.
  if (!model.colliders.empty())
    throw InvalidArgument(name() + " integrates the springs alone and has no contacts, but the model has " +
                          std::to_string(model.colliders.size()) + " collider(s) ('" + model.colliders[0].name +
                          "'): use a position-based or implicit method (pbd, xpbd, vbd, backward-euler, ...)");
  for (std::size_t g = 0; g < model.self_collision_thickness.size(); ++g)
    if (model.self_collision_thickness[g] > 0)
      throw InvalidArgument(name() + " integrates the springs alone and has no contacts, but group '" +
                            model.group_names[g] + "' has self-collision: use a position-based or implicit method");
  // A force evaluation visits every spring (distance constraint and attachment) and particle.
  require_time_for("steps = " + std::to_string(steps),
                   static_cast<double>(steps) * settings_.substeps *
                       (static_cast<double>(model.distance.size() + model.attachments.size()) + model.num_particles()));
  ReferenceSettings rs;
  rs.gravity = settings_.gravity;
  rs.damping = settings_.damping;
  rs.drag = settings_.drag;
  const SpringNetwork net(model, state, rs, /*with_jacobian=*/false);
  const std::size_t N = net.size(), n3 = N / 2;
  std::vector<Real> y(N), f(N), y2(N), f2(N);
  net.pack(state, y.data());
  // Without damping and drag the acceleration depends on the positions alone: the dashpot and
  // drag terms are then zeros of either sign, added to force sums that start at +0 before
  // gravity is added, so not even a zero's sign depends on v. Verlet's a(x', v + h a) is thus
  // the next sub-step's a(x', v'): one evaluation per sub-step instead of two, the same bits.
  const bool reuse = settings_.method == ForceIntegrator::VelocityVerlet && settings_.damping == 0 && settings_.drag == 0;
  bool have_a = false;  // f's acceleration half holds a(y)
  if (reuse && cache_.valid && cache_.model_id == model.id && same_bits(cache_.x, state.x) &&
      same_bits(cache_.v, state.v) && std::memcmp(&cache_.t, &state.t, sizeof(Real)) == 0 &&
      cache_.accel.size() == n3) {
    std::copy(cache_.accel.begin(), cache_.accel.end(), f.begin() + n3);
    have_a = true;
  }
  cache_.valid = false;
  const auto evaluate = [&](const Real* at, Real* out) {
    net.rhs(at, out);
    ++force_evaluations_;
  };
  const Real h = settings_.dt / settings_.substeps;
  const ForceIntegrator method = settings_.method;
  Positions x, v;
  const auto fail = [&](int sub, std::size_t k) {
    const Index particle = net.dynamic_particles()[k % n3 / 3];
    std::ostringstream msg;
    msg << "step " << state.step << " (substep " << sub << ", t = " << state.t << " s): particle " << particle
        << " got a non-finite " << (k < n3 ? "position" : "velocity") << " (the method is unstable at this time step)"
        << "; the state is left at the end of the last finite substep";
    throw SimulationError(msg.str());
  };
  for (std::int64_t s = 0; s < steps; ++s) {
    if (s > 0 && interrupt && interrupt()) {
      net.unpack(y.data(), x, v);
      state.x = x;
      state.v = v;
      throw Interrupted("interrupted after " + std::to_string(s) + " of " + std::to_string(steps) + " steps");
    }
    for (int sub = 0; sub < settings_.substeps; ++sub) {
      if (!have_a) evaluate(y.data(), f.data());  // f = [v; a]
      have_a = false;
      switch (method) {
        case ForceIntegrator::ExplicitEuler:
          for (std::size_t k = 0; k < N; ++k) y2[k] = y[k] + h * f[k];
          break;
        case ForceIntegrator::SymplecticEuler:
          for (std::size_t k = 0; k < n3; ++k) {
            y2[n3 + k] = y[n3 + k] + h * f[n3 + k];
            y2[k] = y[k] + h * y2[n3 + k];
          }
          break;
        case ForceIntegrator::VelocityVerlet:
          for (std::size_t k = 0; k < n3; ++k) {
            y2[k] = y[k] + h * y[n3 + k] + 0.5 * h * h * f[n3 + k];
            y2[n3 + k] = y[n3 + k] + h * f[n3 + k];  // predicted velocity, for velocity-dependent forces
          }
          evaluate(y2.data(), f2.data());
          for (std::size_t k = 0; k < n3; ++k) y2[n3 + k] = y[n3 + k] + 0.5 * h * (f[n3 + k] + f2[n3 + k]);
          if (reuse) {
            f.swap(f2);
            have_a = true;
          }
          break;
      }
      for (std::size_t k = 0; k < N; ++k)
        if (!std::isfinite(y2[k])) {
          net.unpack(y.data(), x, v);
          state.x = x;
          state.v = v;
          fail(sub, k);
        }
      y.swap(y2);
    }
    ++state.step;
    state.t += settings_.dt;
  }
  net.unpack(y.data(), x, v);
  state.x = x;
  state.v = v;
  if (have_a) {
    cache_.model_id = model.id;
    cache_.x = state.x;
    cache_.v = state.v;
    cache_.t = state.t;
    cache_.accel.assign(f.begin() + n3, f.end());
    cache_.valid = true;
  }
}

}  // namespace csb
