// csb — the coloured bending blocks, dispatched by instruction set.
//
// The three loops of bending_block (geometry, angle, multiplier) are ~150 flops, six divisions
// and a square root per constraint in SIMD lanes: two lanes of doubles with SSE2, the portable
// x86-64 baseline, four with AVX2, four or eight with AVX-512. The portable build compiles them
// three times and picks the best copy the processor runs once (GCC's __builtin_cpu_supports); a
// native build (CSB_NATIVE) compiles one copy for its own machine. None enables FMA contraction
// (-ffp-contract=off), and IEEE +, -, *, /, sqrt and selects give the same bits in any lane
// width, so all copies give the same results (tests/test_bending_simd.py compares them bit for
// bit).
#include "csb/solver/coloured_bending.hpp"
#include "csb/solver/avx2_rows.hpp"
#include "csb/types.hpp"

#include <atomic>
#include <stdexcept>

#if defined(__GNUC__) && defined(__x86_64__) && !defined(__AVX2__)
#define CSB_BENDING_AVX2 1
#else
#define CSB_BENDING_AVX2 0
#endif

namespace csb {

namespace {

// The kernels' variants, each instruction set's blocks below choosing one per block in the same
// way: PBD; or XPBD with or without damping (ColouredFourT::damped), its multipliers +0 or not
// (fresh: a sub-step's first sweep).

// The portable blocks (gathers and scatters one constraint at a time).
template <class S>
CSB_ATAN2_INLINE void blocks_portable(ColouredFourT<S>& b, bool xpbd, bool fresh, Index begin, Index end, const S* r,
                                      S* o, const S* x) {
  for (Index c0 = begin; c0 < end; c0 += kBendingBlock) {
    const Index m = std::min(kBendingBlock, end - c0);
    if (!xpbd)
      bending_block<false, false, S, false>(b, c0, m, r, o, x);
    else if (b.damped)
      fresh ? bending_block<true, true, S, true>(b, c0, m, r, o, x)
            : bending_block<true, true, S, false>(b, c0, m, r, o, x);
    else
      fresh ? bending_block<true, false, S, true>(b, c0, m, r, o, x)
            : bending_block<true, false, S, false>(b, c0, m, r, o, x);
  }
}

#if CSB_HAS_AVX2_ROWS
// The AVX2 copy also gathers and scatters four constraints at a time in AVX2 registers
// (csb/avx2_rows.hpp); a block's last m % 4 constraints go one at a time.
template <bool Xpbd, bool Damped, bool Fresh>
CSB_AVX2_INLINE void block_rows(ColouredFour& b, Index c0, Index m, const Real* r, Real* o, const Real* x) {
  using namespace avx2;
  BendingBlock<Xpbd, Damped> t;
  const Index m4 = m - m % 4;
  for (Index k = 0; k < m4; k += 4) {
    const auto* q = &b.q[c0 + k];
    for (int s = 0; s < 4; ++s) {
      __m256d v[4], d[4];
      for (int l = 0; l < 4; ++l) {
        const Offset i = Offset(q[l][s]);
        v[l] = load_xyz(r + i);
        if constexpr (Damped) d[l] = load_xyz(x + i);
      }
      __m256d ex, ey, ez;
      rows(v[0], v[1], v[2], v[3], ex, ey, ez);
      _mm256_store_pd(&t.P[3 * s][k], ex);
      _mm256_store_pd(&t.P[3 * s + 1][k], ey);
      _mm256_store_pd(&t.P[3 * s + 2][k], ez);
      if constexpr (Damped) {
        rows(d[0], d[1], d[2], d[3], ex, ey, ez);
        _mm256_store_pd(&t.X[3 * s][k], ex);
        _mm256_store_pd(&t.X[3 * s + 1][k], ey);
        _mm256_store_pd(&t.X[3 * s + 2][k], ez);
      }
    }
    __m256d wa, wb, wc, wd;
    rows4(b.w[c0 + k].data(), wa, wb, wc, wd);
    _mm256_store_pd(&t.W[0][k], wa);
    _mm256_store_pd(&t.W[1][k], wb);
    _mm256_store_pd(&t.W[2][k], wc);
    _mm256_store_pd(&t.W[3][k], wd);
  }
  bending_gather(t, b, c0, m4, m, r, x);
  bending_compute<Xpbd, Damped, Real, Fresh>(t, b, c0, m);
  const bool in_place = o == r;
  for (Index k = 0; k < m4; k += 4) {
    const auto* q = &b.q[c0 + k];
    const __m256d S = _mm256_load_pd(&t.S[k]);
    for (int s = 0; s < 4; ++s) {
      const __m256d ws = _mm256_mul_pd(S, _mm256_load_pd(&t.W[s][k]));
      const Offset at[4] = {Offset(q[0][s]), Offset(q[1][s]), Offset(q[2][s]), Offset(q[3][s])};
      const __m256d dx = _mm256_mul_pd(ws, _mm256_load_pd(&t.G[3 * s][k])),
                    dy = _mm256_mul_pd(ws, _mm256_load_pd(&t.G[3 * s + 1][k])),
                    dz = _mm256_mul_pd(ws, _mm256_load_pd(&t.G[3 * s + 2][k]));
      if (in_place)
        store_rows(o, at, _mm256_add_pd(_mm256_load_pd(&t.P[3 * s][k]), dx),
                   _mm256_add_pd(_mm256_load_pd(&t.P[3 * s + 1][k]), dy),
                   _mm256_add_pd(_mm256_load_pd(&t.P[3 * s + 2][k]), dz));
      else
        add_rows(o, at, dx, dy, dz);
    }
  }
  bending_scatter(t, b, c0, m4, m, in_place, o);
}

CSB_AVX2_INLINE void blocks_rows(ColouredFour& b, bool xpbd, bool fresh, Index begin, Index end, const Real* r,
                                 Real* o, const Real* x) {
  for (Index c0 = begin; c0 < end; c0 += kBendingBlock) {
    const Index m = std::min(kBendingBlock, end - c0);
    if (!xpbd)
      block_rows<false, false, false>(b, c0, m, r, o, x);
    else if (b.damped)
      fresh ? block_rows<true, true, true>(b, c0, m, r, o, x) : block_rows<true, true, false>(b, c0, m, r, o, x);
    else
      fresh ? block_rows<true, false, true>(b, c0, m, r, o, x) : block_rows<true, false, false>(b, c0, m, r, o, x);
  }
}

// The new coordinates p + ws g of eight (four) constraints' particles, lane by lane (bending_scatter's
// operations).
CSB_AVX2_INLINE __m256 moved(const float* p, const float* g, __m256 ws) {
  return _mm256_add_ps(_mm256_load_ps(p), _mm256_mul_ps(ws, _mm256_load_ps(g)));
}
CSB_AVX2_INLINE __m128 moved(const float* p, const float* g, __m128 ws) {
  return _mm_add_ps(_mm_load_ps(p), _mm_mul_ps(ws, _mm_load_ps(g)));
}

// Single precision (the single-precision step, Gauss-Seidel: o = r): eight constraints gathered at
// a time in 256-bit registers (then four, in 128-bit ones), each particle's inverse mass w with it
// (the step keeps it in the position's pad: the batch's own w, 16 B a constraint, is neither
// streamed nor transposed; about 5 % of the kernel's time at 128², 15 % at 256²), the new
// positions P + (S w_s) ∇_s C (bending_scatter's operations) computed in SIMD lanes as they are
// stored, eight (four) constraints at a time (a pass of its own over the block, writing them into
// G first, cost 7 % of the kernel's time); a block's last m % 4 constraints one at a time, with
// the batch's w. Full: m is kBendingBlock, a constant the compiler sizes the loops by (no
// remainder code: 2 % here; the double blocks did not gain).
template <bool Xpbd, bool Damped, bool Fresh, bool Full>
CSB_AVX2_INLINE void block_rows_single(ColouredFourT<float>& b, Index c0, Index block_size, const float* r, float* o,
                                       const float* x) {
  using namespace avx2;
  const Index m = Full ? kBendingBlock : block_size;
  BendingBlock<Xpbd, Damped, float> t;
  const Index m8 = m - m % 8, m4 = m - m % 4;
  for (Index k = 0; k < m8; k += 8) {
    const auto* q = &b.q[c0 + k];
    for (int s = 0; s < 4; ++s) {
      const Offset at[8] = {Offset(q[0][s]), Offset(q[1][s]), Offset(q[2][s]), Offset(q[3][s]),
                            Offset(q[4][s]), Offset(q[5][s]), Offset(q[6][s]), Offset(q[7][s])};
      __m256 ex, ey, ez, ew;
      gather8(r, at, ex, ey, ez, ew);
      _mm256_store_ps(&t.P[3 * s][k], ex);
      _mm256_store_ps(&t.P[3 * s + 1][k], ey);
      _mm256_store_ps(&t.P[3 * s + 2][k], ez);
      _mm256_store_ps(&t.W[s][k], ew);
      if constexpr (Damped) {
        gather8(x, at, ex, ey, ez);
        _mm256_store_ps(&t.X[3 * s][k], ex);
        _mm256_store_ps(&t.X[3 * s + 1][k], ey);
        _mm256_store_ps(&t.X[3 * s + 2][k], ez);
      }
    }
  }
  for (Index k = m8; k < m4; k += 4) {
    const auto* q = &b.q[c0 + k];
    for (int s = 0; s < 4; ++s) {
      __m128 v[4], d[4];
      for (int l = 0; l < 4; ++l) {
        const Offset i = Offset(q[l][s]);
        v[l] = load_xyz(r + i);
        if constexpr (Damped) d[l] = load_xyz(x + i);
      }
      __m128 ex, ey, ez, ew;
      rows(v[0], v[1], v[2], v[3], ex, ey, ez, ew);
      _mm_store_ps(&t.P[3 * s][k], ex);
      _mm_store_ps(&t.P[3 * s + 1][k], ey);
      _mm_store_ps(&t.P[3 * s + 2][k], ez);
      _mm_store_ps(&t.W[s][k], ew);
      if constexpr (Damped) {
        rows(d[0], d[1], d[2], d[3], ex, ey, ez);
        _mm_store_ps(&t.X[3 * s][k], ex);
        _mm_store_ps(&t.X[3 * s + 1][k], ey);
        _mm_store_ps(&t.X[3 * s + 2][k], ez);
      }
    }
  }
  bending_gather(t, b, c0, m4, m, r, x);
  bending_compute<Xpbd, Damped, float, Fresh>(t, b, c0, m);
  for (Index k = 0; k < m8; k += 8) {
    const auto* q = &b.q[c0 + k];
    for (int s = 0; s < 4; ++s) {
      const Offset at[8] = {Offset(q[0][s]), Offset(q[1][s]), Offset(q[2][s]), Offset(q[3][s]),
                            Offset(q[4][s]), Offset(q[5][s]), Offset(q[6][s]), Offset(q[7][s])};
      const __m256 w = _mm256_load_ps(&t.W[s][k]), ws = _mm256_mul_ps(_mm256_load_ps(&t.S[k]), w);
      store8(o, at, moved(&t.P[3 * s][k], &t.G[3 * s][k], ws), moved(&t.P[3 * s + 1][k], &t.G[3 * s + 1][k], ws),
             moved(&t.P[3 * s + 2][k], &t.G[3 * s + 2][k], ws), w);
    }
  }
  for (Index k = m8; k < m4; k += 4) {
    const auto* q = &b.q[c0 + k];
    for (int s = 0; s < 4; ++s) {
      const Offset at[4] = {Offset(q[0][s]), Offset(q[1][s]), Offset(q[2][s]), Offset(q[3][s])};
      const __m128 w = _mm_load_ps(&t.W[s][k]), ws = _mm_mul_ps(_mm_load_ps(&t.S[k]), w);
      store_rows(o, at, moved(&t.P[3 * s][k], &t.G[3 * s][k], ws), moved(&t.P[3 * s + 1][k], &t.G[3 * s + 1][k], ws),
                 moved(&t.P[3 * s + 2][k], &t.G[3 * s + 2][k], ws), w);
    }
  }
  bending_scatter(t, b, c0, m4, m, true, o);
}

template <bool Full>
CSB_AVX2_INLINE void block_single(ColouredFourT<float>& b, bool xpbd, bool fresh, Index c0, Index m, const float* r,
                                  float* o, const float* x) {
  if (!xpbd)
    block_rows_single<false, false, false, Full>(b, c0, m, r, o, x);
  else if (b.damped)
    fresh ? block_rows_single<true, true, true, Full>(b, c0, m, r, o, x)
          : block_rows_single<true, true, false, Full>(b, c0, m, r, o, x);
  else
    fresh ? block_rows_single<true, false, true, Full>(b, c0, m, r, o, x)
          : block_rows_single<true, false, false, Full>(b, c0, m, r, o, x);
}

CSB_AVX2_INLINE void blocks_rows_single(ColouredFourT<float>& b, bool xpbd, bool fresh, Index begin, Index end,
                                        const float* r, float* o, const float* x) {
  if (o != r) return blocks_portable(b, xpbd, fresh, begin, end, r, o, x);
  for (Index c0 = begin; c0 < end; c0 += kBendingBlock) {
    const Index m = std::min(kBendingBlock, end - c0);
    if (m == kBendingBlock)
      block_single<true>(b, xpbd, fresh, c0, m, r, o, x);
    else
      block_single<false>(b, xpbd, fresh, c0, m, r, o, x);
  }
}

__attribute__((target("avx2"))) void blocks_avx2(ColouredFour& b, bool xpbd, bool fresh, Index begin, Index end,
                                                  const Real* r, Real* o, const Real* x) {
  blocks_rows(b, xpbd, fresh, begin, end, r, o, x);
}
#endif

#if CSB_BENDING_AVX2
// The same code compiled for AVX-512 (F, VL, DQ, BW): GCC runs some of its loops in 512-bit
// registers (eight doubles, sixteen floats) and the rest in 256-bit ones, with 32 registers
// instead of 16 and mask registers for the selects (the Zen 4 this was measured on splits a
// 512-bit operation in two, so the registers and masks are the gain). Bending: 14.6 → 13.3 ns per
// projection. The distance blocks were slower so (3.94 → 4.25 ns) and keep the AVX2 copy
// (papers/benchmarks.md).
__attribute__((target("avx2,avx512f,avx512vl,avx512dq,avx512bw"))) void blocks_avx512(
    ColouredFour& b, bool xpbd, bool fresh, Index begin, Index end, const Real* r, Real* o, const Real* x) {
  blocks_rows(b, xpbd, fresh, begin, end, r, o, x);
}
#endif

void blocks_base(ColouredFour& b, bool xpbd, bool fresh, Index begin, Index end, const Real* r, Real* o,
                 const Real* x) {
#if CSB_HAS_AVX2_ROWS && defined(__AVX2__)  // a native build for a processor with AVX2
  blocks_avx2(b, xpbd, fresh, begin, end, r, o, x);
#else
  blocks_portable(b, xpbd, fresh, begin, end, r, o, x);
#endif
}

// Single precision: the blocks in the lanes of each instruction set, twice as many floats as
// doubles (SSE2 four, AVX2 and AVX-512 eight), with AVX2's gathers and stores four at a time.
void blocks_single(ColouredFourT<float>& b, bool xpbd, bool fresh, Index begin, Index end, const float* r, float* o,
                   const float* x) {
#if CSB_HAS_AVX2_ROWS && defined(__AVX2__)  // a native build for a processor with AVX2
  blocks_rows_single(b, xpbd, fresh, begin, end, r, o, x);
#else
  blocks_portable(b, xpbd, fresh, begin, end, r, o, x);
#endif
}
#if CSB_BENDING_AVX2
__attribute__((target("avx2"))) void blocks_single_avx2(ColouredFourT<float>& b, bool xpbd, bool fresh, Index begin,
                                                         Index end, const float* r, float* o, const float* x) {
  blocks_rows_single(b, xpbd, fresh, begin, end, r, o, x);
}
__attribute__((target("avx2,avx512f,avx512vl,avx512dq,avx512bw"))) void blocks_single_avx512(
    ColouredFourT<float>& b, bool xpbd, bool fresh, Index begin, Index end, const float* r, float* o, const float* x) {
  blocks_rows_single(b, xpbd, fresh, begin, end, r, o, x);
}
#endif

#if CSB_BENDING_AVX2
enum Isa : int { kSse2, kAvx2, kAvx512 };
// The best copy this processor runs.
int cpu_isa() {
  __builtin_cpu_init();
  if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
      __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512bw"))
    return kAvx512;
  return __builtin_cpu_supports("avx2") ? kAvx2 : kSse2;
}
std::atomic<int> use_isa{cpu_isa()};
#endif

}  // namespace

void bending_blocks(ColouredFour& b, bool xpbd, bool fresh, Index begin, Index end, const Real* r, Real* o,
                    const Real* x) {
#if CSB_BENDING_AVX2
  switch (use_isa.load(std::memory_order_relaxed)) {
    case kAvx512:
      blocks_avx512(b, xpbd, fresh, begin, end, r, o, x);
      return;
    case kAvx2:
      blocks_avx2(b, xpbd, fresh, begin, end, r, o, x);
      return;
    default:
      break;
  }
#endif
  blocks_base(b, xpbd, fresh, begin, end, r, o, x);
}

void bending_blocks(ColouredFourT<float>& b, bool xpbd, bool fresh, Index begin, Index end, const float* r, float* o,
                    const float* x) {
#if CSB_BENDING_AVX2
  switch (use_isa.load(std::memory_order_relaxed)) {
    case kAvx512:
      blocks_single_avx512(b, xpbd, fresh, begin, end, r, o, x);
      return;
    case kAvx2:
      blocks_single_avx2(b, xpbd, fresh, begin, end, r, o, x);
      return;
    default:
      break;
  }
#endif
  blocks_single(b, xpbd, fresh, begin, end, r, o, x);
}

bool kernels_use_avx2() {
#if CSB_BENDING_AVX2
  return use_isa.load(std::memory_order_relaxed) >= kAvx2;
#else
  return false;
#endif
}

std::string kernel_isa() {
#if CSB_BENDING_AVX2
  static const char* const names[] = {"sse2", "avx2", "avx512"};
  return names[use_isa.load()];
#else
  return "native";
#endif
}

void set_kernel_isa(const std::string& isa) {
  if (isa != "auto" && isa != "sse2" && isa != "avx2" && isa != "avx512")
    throw InvalidArgument("isa must be 'auto', 'sse2', 'avx2' or 'avx512', got '" + isa + "'");
#if CSB_BENDING_AVX2
  const int best = cpu_isa();
  const int want = isa == "auto" ? best : isa == "avx512" ? kAvx512 : isa == "avx2" ? kAvx2 : kSse2;
  if (want > best)
    throw InvalidArgument("isa '" + isa + "': this processor has no " + (want == kAvx512 ? "AVX-512" : "AVX2"));
  use_isa.store(want);
#endif
}

void project_bending_coloured(ColouredFour& b, bool xpbd, bool independent, Real* p, const Real* x) {
  const Index m = static_cast<Index>(b.q.size());
  b.damped = any_damping(b.gamma);
  if (xpbd)
    project_bending_range<true>(b, 0, m, independent, false, p, p, x);
  else
    project_bending_range<false>(b, 0, m, independent, false, p, p, x);
}

void atan2_rational_array(const Real* y, const Real* x, Real* out, Index n) {
#pragma omp simd
  for (Index i = 0; i < n; ++i) out[i] = atan2_rational(y[i], x[i]);
}

}  // namespace csb
