// XPBD (Macklin, Müller and Chentanez 2016) over distance constraints, as a csb plug-in. Per
// sub-step of h = dt / substeps, the operations of csb's XPBD with ordering="sequential":
//   predict     v += h g (particles that can move), p = x + h v
//   project     λ = 0; `iterations` Gauss-Seidel sweeps in the constraints' order, each
//               C = |p_i - p_j| - d,  n = (p_i - p_j)/|p_i - p_j|,  α̃ = α/h²,
//               Δλ = (-C - α̃ λ)/(w_i + w_j + α̃)   (their Eq. 18; an inequality clamps λ's sign),
//               p_i += w_i Δλ n,  p_j -= w_j Δλ n
//   velocities  v = (p - x)/h, x = p
// Build: CMakeLists.txt beside this file. Load: csb.load_plugin("libmy_xpbd.so")(dt=..., ...).
#include "csb_plugin.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <vector>

namespace {

struct MyXpbd {
  csb_settings settings;
  std::vector<double> p;       // m, the predicted positions, 3 n
  std::vector<double> lambda;  // N s², one multiplier per distance constraint
};

int fail(char* error, size_t size, int code, const char* message) {
  std::snprintf(error, size, "%s", message);
  return code;
}

void substep(MyXpbd& s, const csb_model_view& m, csb_state_view& state, double h) {
  double *x = state.positions, *v = state.velocities, *p = s.p.data();
  const double* g = s.settings.gravity;
  for (int64_t i = 0; i < m.num_particles; ++i) {
    const double a = m.inv_mass[i] > 0 ? h : 0;
    for (int k = 0; k < 3; ++k) {
      v[3 * i + k] += a * g[k];
      p[3 * i + k] = x[3 * i + k] + h * v[3 * i + k];
    }
  }
  s.lambda.assign(m.num_distance, 0.0);
  for (int it = 0; it < s.settings.iterations; ++it)
    for (int64_t c = 0; c < m.num_distance; ++c) {
      const int32_t i = m.distance_particles[2 * c], j = m.distance_particles[2 * c + 1];
      const double wi = m.inv_mass[i], wj = m.inv_mass[j];
      double *pi = p + 3 * i, *pj = p + 3 * j;
      const double dx = pi[0] - pj[0], dy = pi[1] - pj[1], dz = pi[2] - pj[2];
      const double len = std::sqrt(dx * dx + dy * dy + dz * dz);
      if (wi + wj <= 0 || len <= 0) continue;  // pinned pair, or no direction
      const double at = m.distance_compliance[c] / (h * h);
      double dl = (-(len - m.distance_rest_length[c]) - at * s.lambda[c]) / (wi + wj + at);
      if (const int sense = m.distance_sense[c]; sense != 0)
        dl = (sense > 0 ? std::max(s.lambda[c] + dl, 0.0) : std::min(s.lambda[c] + dl, 0.0)) - s.lambda[c];
      s.lambda[c] += dl;
      const double n[3] = {dx / len, dy / len, dz / len};
      for (int k = 0; k < 3; ++k) pi[k] += wi * dl * n[k];
      for (int k = 0; k < 3; ++k) pj[k] -= wj * dl * n[k];
    }
  for (int64_t k = 0; k < 3 * m.num_particles; ++k) {
    v[k] = (p[k] - x[k]) / h;
    x[k] = p[k];
  }
}

}  // namespace

int csb_plugin_abi_version(void) { return CSB_PLUGIN_ABI_VERSION; }

const char* csb_plugin_name(void) { return "my-xpbd"; }

void* csb_plugin_create(const csb_settings* settings, char* error, size_t size) {
  try {
    return new MyXpbd{*settings, {}, {}};
  } catch (const std::exception& e) {
    fail(error, size, CSB_PLUGIN_FAILED, e.what());
    return nullptr;
  }
}

int csb_plugin_step(void* handle, const csb_model_view* m, csb_state_view* state, int64_t steps, char* error,
                    size_t size) {
  if (m->num_bending + m->num_volume + m->num_balloons + m->num_attachments + m->num_other + m->num_colliders > 0)
    return fail(error, size, CSB_PLUGIN_BAD_INPUT,
                "my-xpbd steps distance constraints only; this model has bending, volumes, balloons, attachments, "
                "other constraint families or colliders");
  try {
    MyXpbd& s = *static_cast<MyXpbd*>(handle);
    s.p.resize(3 * m->num_particles);
    const double h = s.settings.dt / s.settings.substeps;  // s
    for (int64_t k = 0; k < steps; ++k)
      for (int sub = 0; sub < s.settings.substeps; ++sub) substep(s, *m, *state, h);
    return CSB_PLUGIN_OK;
  } catch (const std::exception& e) {  // nothing may cross the C interface
    return fail(error, size, CSB_PLUGIN_FAILED, e.what());
  }
}

void csb_plugin_destroy(void* handle) { delete static_cast<MyXpbd*>(handle); }
