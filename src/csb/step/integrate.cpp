// csb — the stepper's particle stages: prediction (5)-(7), Müller's damping (6) and the velocity
// update (12)-(15) of Algorithm 1, for the Euler and the Verlet front ends.
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/solver/avx2_rows.hpp"
#include "csb/solver/coloured_bending.hpp"
#include <Eigen/Eigenvalues>

#include <cmath>
#include <cstdint>
#include <cstring>

namespace csb {

using detail::str;
using namespace stepper_detail;


void PbdStepper::predict(const Model& model, State& state, Real h) {
  const Index n = model.num_particles();
  if (settings_.front_end == FrontEnd::Euler && settings_.damping > 0) {
    // (5), then (6), which needs every velocity updated, then (7).
    const Real* w = model.inv_mass.data();
    for (Index i = 0; i < n; ++i)
      if (w[i] > 0) state.v.col(i) += h * settings_.gravity;
    damp_velocities(model, state);
    const Real* x = state.x.data();
    const Real* v = state.v.data();
    Real* p = p_.data();
    for (Index k = 0; k < 3 * n; ++k) p[k] = x[k] + h * v[k];
    return;
  }
  predict_range(model, state, h, 0, n);
}


void PbdStepper::predict_range(const Model& model, State& state, Real h, Index begin, Index end) {
  const Real* w = model.inv_mass.data();
  const Vec3& g = settings_.gravity;
  const Real* x = state.x.data();
  Real* v = state.v.data();
  Real* p = p_.data();
  if (settings_.front_end == FrontEnd::Verlet) {
    // p = x + (1 - d)(x - x*) + h² g: the velocity lives in the previous positions.
    const Real keep = 1 - settings_.verlet_drag;
    const Real* xp = x_prev_.data();
    for (Index i = begin; i < end; ++i) {
      const Real a = w[i] > 0 ? h * h : 0;
      for (int k = 0; k < 3; ++k) p[3 * i + k] = x[3 * i + k] + keep * (x[3 * i + k] - xp[3 * i + k]) + a * g[k];
    }
    return;
  }
  // (5) and (7) in one pass.
  for (Index i = begin; i < end; ++i) {
    const Real a = w[i] > 0 ? h : 0;
    for (int k = 0; k < 3; ++k) {
      v[3 * i + k] += a * g[k];
      p[3 * i + k] = x[3 * i + k] + h * v[3 * i + k];
    }
  }
}

namespace {

// The update of a sub-step and the prediction of the next for coordinates [k0, k1) in one pass:
// Euler v = (p - x)/h + a, x = p, p = x + h v; Verlet x* = x, x = p, p = x + keep (x - x*) + a
// (a = accel_). The operations of commit and predict_range, in their order: the same bits. S:
// double, or float for the single-precision step.
template <class S>
inline __attribute__((always_inline)) void advance_euler_body(S* __restrict x, S* __restrict v, S* __restrict p,
                                                              const S* __restrict a, S h, Index k0, Index k1) {
  for (Index k = k0; k < k1; ++k) {
    const S pk = p[k];
    const S vk = (pk - x[k]) / h + a[k];
    x[k] = pk;
    v[k] = vk;
    p[k] = pk + h * vk;
  }
}
template <class S>
inline __attribute__((always_inline)) void advance_verlet_body(S* __restrict x, S* __restrict xp, S* __restrict p,
                                                               const S* __restrict a, S keep, Index k0, Index k1) {
  for (Index k = k0; k < k1; ++k) {
    const S pk = p[k], xk = x[k];
    xp[k] = xk;
    x[k] = pk;
    p[k] = pk + keep * (pk - xk) + a[k];
  }
}
// The single-precision step's first prediction (predict_range's operations in float, the
// gravity in a: Euler v = v + a, p = x + h v; Verlet p = x + keep (x - x*) + a) for coordinates
// [k0, k1): start_single without AVX2.
template <class S>
inline __attribute__((always_inline)) void predict_euler_body(const S* __restrict x, S* __restrict v,
                                                              S* __restrict p, const S* __restrict a, S h, Index k0,
                                                              Index k1) {
  for (Index k = k0; k < k1; ++k) {
    v[k] = v[k] + a[k];
    p[k] = x[k] + h * v[k];
  }
}
template <class S>
inline __attribute__((always_inline)) void predict_verlet_body(const S* __restrict x, const S* __restrict xp,
                                                               S* __restrict p, const S* __restrict a, S keep,
                                                               Index k0, Index k1) {
  for (Index k = k0; k < k1; ++k) p[k] = x[k] + keep * (x[k] - xp[k]) + a[k];
}
// (12)-(15) alone for coordinates [k0, k1): Euler v = (p - x)/h, x = p.
inline __attribute__((always_inline)) void commit_euler_body(Real* __restrict x, Real* __restrict v,
                                                             const Real* __restrict p, Real h, Index k0, Index k1) {
  for (Index k = k0; k < k1; ++k) {
    v[k] = (p[k] - x[k]) / h;
    x[k] = p[k];
  }
}
// Whether some x, y or z of the float particles [begin, end) is not finite (its exponent all
// ones); the pads are not looked at.
inline __attribute__((always_inline)) bool any_non_finite_body(const float* x, Index begin, Index end) {
  const std::uint32_t exponent = 0x7f800000u;
  std::uint32_t bad = 0;
  for (Index i = begin; i < end; ++i) {
    std::uint32_t u[3];
    std::memcpy(u, x + 4 * i, sizeof u);
    bad |= ((u[0] & exponent) == exponent) | ((u[1] & exponent) == exponent) | ((u[2] & exponent) == exponent);
  }
  return bad != 0;
}
void commit_euler_base(Real* x, Real* v, const Real* p, Real h, Index k0, Index k1) {
  commit_euler_body(x, v, p, h, k0, k1);
}
template <class S>
void advance_euler_base(S* x, S* v, S* p, const S* a, S h, Index k0, Index k1) {
  advance_euler_body(x, v, p, a, h, k0, k1);
}
template <class S>
void advance_verlet_base(S* x, S* xp, S* p, const S* a, S keep, Index k0, Index k1) {
  advance_verlet_body(x, xp, p, a, keep, k0, k1);
}
bool any_non_finite_base(const float* x, Index begin, Index end) { return any_non_finite_body(x, begin, end); }
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__AVX2__)
// Four lanes instead of SSE2's two (the division dominates): taken with the AVX2 kernels.
#define CSB_ADVANCE_AVX2 1
template <class S>
__attribute__((target("avx2"))) void advance_euler_avx2(S* x, S* v, S* p, const S* a, S h, Index k0, Index k1) {
  advance_euler_body(x, v, p, a, h, k0, k1);
}
__attribute__((target("avx2"))) void commit_euler_avx2(Real* x, Real* v, const Real* p, Real h, Index k0, Index k1) {
  commit_euler_body(x, v, p, h, k0, k1);
}
template <class S>
__attribute__((target("avx2"))) void advance_verlet_avx2(S* x, S* xp, S* p, const S* a, S keep, Index k0, Index k1) {
  advance_verlet_body(x, xp, p, a, keep, k0, k1);
}
// any_non_finite_body two particles a 256-bit register.
__attribute__((target("avx2"))) bool any_non_finite_avx2(const float* x, Index begin, Index end) {
  const __m256i exponent = _mm256_set1_epi32(0x7f800000), xyz = _mm256_setr_epi32(-1, -1, -1, 0, -1, -1, -1, 0);
  __m256i bad = _mm256_setzero_si256();
  Index i = begin;
  for (; i + 2 <= end; i += 2) {
    const __m256i e = _mm256_and_si256(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(x + 4 * i)), exponent);
    bad = _mm256_or_si256(bad, _mm256_and_si256(_mm256_cmpeq_epi32(e, exponent), xyz));
  }
  return !_mm256_testz_si256(bad, bad) || any_non_finite_body(x, i, end);
}
#endif

}  // namespace


void PbdStepper::set_accel(const Model& model, Real h, Index begin, Index end) {
  const Real* w = model.inv_mass.data();
  const Vec3& g = settings_.gravity;
  const Real step = settings_.front_end == FrontEnd::Verlet ? h * h : h;
  for (Index i = begin; i < end; ++i) {
    const Real a = w[i] > 0 ? step : 0;
    for (int k = 0; k < 3; ++k) accel_[3 * i + k] = a * g[k];
  }
}


void PbdStepper::advance(State& state, Real h, Index begin, Index end) {
  const bool verlet = settings_.front_end == FrontEnd::Verlet;
  Real* x = state.x.data();
  Real* v = verlet ? x_prev_.data() : state.v.data();
  const Real keep = 1 - settings_.verlet_drag;
#if defined(CSB_ADVANCE_AVX2)
  if (kernels_use_avx2()) {
    if (verlet)
      advance_verlet_avx2(x, v, p_.data(), accel_.data(), keep, 3 * begin, 3 * end);
    else
      advance_euler_avx2(x, v, p_.data(), accel_.data(), h, 3 * begin, 3 * end);
    return;
  }
#endif
  if (verlet)
    advance_verlet_base(x, v, p_.data(), accel_.data(), keep, 3 * begin, 3 * end);
  else
    advance_euler_base(x, v, p_.data(), accel_.data(), h, 3 * begin, 3 * end);
}


void stepper_detail::advance_single(float* x, float* v, float* p, const float* a, float h, float keep, bool verlet,
                                    Index k0, Index k1) {
#if defined(CSB_ADVANCE_AVX2)
  if (kernels_use_avx2()) {
    verlet ? advance_verlet_avx2(x, v, p, a, keep, k0, k1) : advance_euler_avx2(x, v, p, a, h, k0, k1);
    return;
  }
#endif
  verlet ? advance_verlet_base(x, v, p, a, keep, k0, k1) : advance_euler_base(x, v, p, a, h, k0, k1);
}


Index stepper_detail::first_non_finite_single(const float* x, Index begin, Index end) {
  bool bad;
#if defined(CSB_ADVANCE_AVX2)
  if (kernels_use_avx2())
    bad = any_non_finite_avx2(x, begin, end);
  else
#endif
    bad = any_non_finite_base(x, begin, end);
  if (!bad) return -1;
  for (Index i = begin; i < end; ++i)
    if (!std::isfinite(x[4 * i]) || !std::isfinite(x[4 * i + 1]) || !std::isfinite(x[4 * i + 2])) return i;
  return -1;
}


namespace {

// Particles [begin, end) of double x, y, z (3 apart) into float x, y, z, pad (4 apart), rounded to
// nearest, and back (exact). The AVX2 copy of the way back moves a particle as one conversion, a
// 128-bit and a 64-bit store (a masked store is slow on some processors): the same values.
void narrow_base(const Real* in, float* out, Index begin, Index end, const float* pad) {
  for (Index i = begin; i < end; ++i) {
    for (int e = 0; e < 3; ++e) out[4 * i + e] = static_cast<float>(in[3 * i + e]);
    out[4 * i + 3] = pad ? pad[i] : 0.0f;
  }
}
// The single-precision step's last update (commit's operations in float: Euler v = (p - x)/h,
// x = p; Verlet x* = x, x = p) for particles [begin, end), its results widened straight into the
// double state xd, vd (Verlet: the previous positions).
template <bool Verlet>
void finish_base(const float* x, const float* p, float h, Real* xd, Real* vd, Index begin, Index end) {
  for (Index i = begin; i < end; ++i)
    for (int e = 0; e < 3; ++e) {
      const float pk = p[4 * i + e], xk = x[4 * i + e];
      vd[3 * i + e] = Verlet ? xk : (pk - xk) / h;
      xd[3 * i + e] = pk;
    }
}
#if CSB_HAS_AVX2_ROWS
// narrow_base of the positions (padded with w) and of the velocities (padded with 0; Verlet's
// previous positions with w) and the first prediction (predict_euler_body, predict_verlet_body)
// in one pass, a particle a 128-bit register: a particle's three doubles one masked load and one
// conversion, then the prediction's operations: the same values as the three passes.
template <bool Verlet>
__attribute__((target("avx2"))) void start_single_avx2(const Real* xd, const Real* vd, const float* w, float* x,
                                                       float* p, const float* a, float h, float keep, Index begin,
                                                       Index end) {
  const __m256i xyz = _mm256_setr_epi64x(-1, -1, -1, 0);
  const __m128 hv = _mm_set1_ps(h), kv = _mm_set1_ps(keep);
  for (Index i = begin; i < end; ++i) {
    const __m128 wi = _mm_set1_ps(w[i]);
    const __m128 xi = _mm_blend_ps(_mm256_cvtpd_ps(_mm256_maskload_pd(xd + 3 * i, xyz)), wi, 0b1000);
    __m128 vi = _mm256_cvtpd_ps(_mm256_maskload_pd(vd + 3 * i, xyz));  // pad 0
    const __m128 ai = _mm_loadu_ps(a + 4 * i);
    _mm_storeu_ps(x + 4 * i, xi);
    if constexpr (Verlet) {
      vi = _mm_blend_ps(vi, wi, 0b1000);
      _mm_storeu_ps(p + 4 * i, _mm_add_ps(_mm_add_ps(xi, _mm_mul_ps(kv, _mm_sub_ps(xi, vi))), ai));
    } else {
      vi = _mm_add_ps(vi, ai);
      _mm_storeu_ps(p + 4 * i, _mm_add_ps(xi, _mm_mul_ps(hv, vi)));
    }
  }
}
// A float particle's x, y, z widened into three doubles at out: one conversion, a 128-bit and a
// 64-bit store (a masked store is slow on some processors).
CSB_AVX2_INLINE void store_widened(Real* out, __m128 v) {
  const __m256d d = _mm256_cvtps_pd(v);
  _mm_storeu_pd(out, _mm256_castpd256_pd128(d));
  _mm_store_sd(out + 2, _mm256_extractf128_pd(d, 1));
}
// finish_base, a particle a 128-bit register.
template <bool Verlet>
__attribute__((target("avx2"))) void finish_avx2(const float* x, const float* p, float h, Real* xd, Real* vd,
                                                 Index begin, Index end) {
  const __m128 hv = _mm_set1_ps(h);
  for (Index i = begin; i < end; ++i) {
    const __m128 pk = _mm_loadu_ps(p + 4 * i), xk = _mm_loadu_ps(x + 4 * i);
    store_widened(vd + 3 * i, Verlet ? xk : _mm_div_ps(_mm_sub_ps(pk, xk), hv));
    store_widened(xd + 3 * i, pk);
  }
}
#endif

}  // namespace

void stepper_detail::start_single(const Real* xd, const Real* vd, const float* w, float* x, float* v, float* p,
                                  const float* a, float h, float keep, bool verlet, Index begin, Index end) {
#if CSB_HAS_AVX2_ROWS
  if (kernels_use_avx2())
    return verlet ? start_single_avx2<true>(xd, vd, w, x, p, a, h, keep, begin, end)
                  : start_single_avx2<false>(xd, vd, w, x, p, a, h, keep, begin, end);
#endif
  narrow_base(xd, x, begin, end, w);
  narrow_base(vd, v, begin, end, verlet ? w : nullptr);
  verlet ? predict_verlet_body(x, v, p, a, keep, 4 * begin, 4 * end)
         : predict_euler_body(x, v, p, a, h, 4 * begin, 4 * end);
}

void stepper_detail::finish_single(const float* x, const float* p, float h, bool verlet, Real* xd, Real* vd,
                                   Index begin, Index end) {
#if CSB_HAS_AVX2_ROWS
  if (kernels_use_avx2())
    return verlet ? finish_avx2<true>(x, p, h, xd, vd, begin, end) : finish_avx2<false>(x, p, h, xd, vd, begin, end);
#endif
  verlet ? finish_base<true>(x, p, h, xd, vd, begin, end) : finish_base<false>(x, p, h, xd, vd, begin, end);
}


void PbdStepper::commit(State& state, Real h, Index begin, Index end) {
  Real* x = state.x.data();
  Real* v = state.v.data();
  const Real* p = p_.data();
  if (settings_.front_end == FrontEnd::Verlet) {
    Real* xp = x_prev_.data();
    for (Index k = 3 * begin; k < 3 * end; ++k) {
      xp[k] = x[k];
      x[k] = p[k];
    }
    return;
  }
#if defined(CSB_ADVANCE_AVX2)
  if (kernels_use_avx2()) return commit_euler_avx2(x, v, p, h, 3 * begin, 3 * end);
#endif
  commit_euler_base(x, v, p, h, 3 * begin, 3 * end);
}


// Müller 2007 §3.5, per group over its particles that can move:
//   x_cm = Σ m_i x_i / Σ m_i,  v_cm = Σ m_i v_i / Σ m_i,  r_i = x_i - x_cm
//   L = Σ r_i x m_i v_i,  I = Σ m_i (|r_i|² 1 - r_i r_iᵀ)  (= Σ r̃_i r̃_iᵀ m_i),  ω = I⁻¹ L
//   Δv_i = v_cm + ω x r_i - v_i,  v_i <- v_i + k_damping Δv_i
// I is singular for collinear particles (a chain): the pseudo-inverse gives the ω of least norm,
// which still reproduces every rigid motion the particles can have.
void PbdStepper::damp_velocities(const Model& model, State& state) const {
  const Real k = settings_.damping;
  for (Index g = 0; g < model.num_groups(); ++g) {
    Real m_total = 0;
    Vec3 x_cm = Vec3::Zero(), v_cm = Vec3::Zero();
    for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
      const Index i = model.group_particles[o];
      if (model.inv_mass[i] <= 0) continue;
      m_total += model.mass[i];
      x_cm += model.mass[i] * state.x.col(i);
      v_cm += model.mass[i] * state.v.col(i);
    }
    if (m_total <= 0) continue;
    x_cm /= m_total;
    v_cm /= m_total;
    Vec3 L = Vec3::Zero();
    Mat3 I = Mat3::Zero();
    for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
      const Index i = model.group_particles[o];
      if (model.inv_mass[i] <= 0) continue;
      const Vec3 r = state.x.col(i) - x_cm;
      L += r.cross(model.mass[i] * state.v.col(i));
      I += model.mass[i] * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
    }
    Eigen::SelfAdjointEigenSolver<Mat3> eig(I);
    const Vec3 lambda = eig.eigenvalues();
    const Real cutoff = 1e-12 * lambda.cwiseAbs().maxCoeff();
    Vec3 inv = Vec3::Zero();
    for (int a = 0; a < 3; ++a)
      if (lambda[a] > cutoff) inv[a] = 1 / lambda[a];
    const Vec3 omega = eig.eigenvectors() * inv.asDiagonal() * eig.eigenvectors().transpose() * L;
    for (Index o = model.group_offsets[g]; o < model.group_offsets[g + 1]; ++o) {
      const Index i = model.group_particles[o];
      if (model.inv_mass[i] <= 0) continue;
      const Vec3 r = state.x.col(i) - x_cm;
      state.v.col(i) += k * (v_cm + omega.cross(r) - state.v.col(i));
    }
  }
}

}  // namespace csb
