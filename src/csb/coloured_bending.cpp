// csb — the coloured bending blocks, dispatched by instruction set (issue 7).
//
// The three loops of bending_block (geometry, angle, multiplier) are ~150 flops, six divisions
// and a square root per constraint in SIMD lanes: two lanes of doubles with SSE2, the portable
// x86-64 baseline, four with AVX2. The portable build compiles them twice and picks the AVX2
// copy once, from the processor (GCC's __builtin_cpu_supports); a native build (CSB_NATIVE)
// compiles one copy for its own machine. Neither enables FMA contraction (-ffp-contract=off),
// and IEEE +, -, *, /, sqrt and selects give the same bits in any lane width, so both copies
// give the same results (tests/test_bending_simd.py compares them bit for bit).
#include "csb/coloured_bending.hpp"
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

template <bool Xpbd>
CSB_ATAN2_INLINE void blocks(ColouredFour& b, Index begin, Index end, const Real* r, Real* o, const Real* x) {
  for (Index c0 = begin; c0 < end; c0 += kBendingBlock)
    bending_block<Xpbd>(b, c0, std::min(kBendingBlock, end - c0), r, o, x);
}

void blocks_base(ColouredFour& b, bool xpbd, Index begin, Index end, const Real* r, Real* o, const Real* x) {
  if (xpbd)
    blocks<true>(b, begin, end, r, o, x);
  else
    blocks<false>(b, begin, end, r, o, x);
}

#if CSB_BENDING_AVX2
__attribute__((target("avx2"))) void blocks_avx2(ColouredFour& b, bool xpbd, Index begin, Index end, const Real* r,
                                                  Real* o, const Real* x) {
  if (xpbd)
    blocks<true>(b, begin, end, r, o, x);
  else
    blocks<false>(b, begin, end, r, o, x);
}

bool cpu_has_avx2() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2");
}
std::atomic<bool> use_avx2{cpu_has_avx2()};
#endif

}  // namespace

void bending_blocks(ColouredFour& b, bool xpbd, Index begin, Index end, const Real* r, Real* o, const Real* x) {
#if CSB_BENDING_AVX2
  if (use_avx2.load(std::memory_order_relaxed)) {
    blocks_avx2(b, xpbd, begin, end, r, o, x);
    return;
  }
#endif
  blocks_base(b, xpbd, begin, end, r, o, x);
}

bool kernels_use_avx2() {
#if CSB_BENDING_AVX2
  return use_avx2.load(std::memory_order_relaxed);
#else
  return false;
#endif
}

std::string kernel_isa() {
#if CSB_BENDING_AVX2
  return use_avx2.load() ? "avx2" : "sse2";
#else
  return "native";
#endif
}

void set_kernel_isa(const std::string& isa) {
  if (isa != "auto" && isa != "sse2" && isa != "avx2")
    throw InvalidArgument("isa must be 'auto', 'sse2' or 'avx2', got '" + isa + "'");
#if CSB_BENDING_AVX2
  if (isa == "avx2" && !cpu_has_avx2()) throw InvalidArgument("isa 'avx2': this processor has no AVX2");
  use_avx2.store(isa != "sse2" && cpu_has_avx2());
#endif
}

void project_bending_coloured(ColouredFour& b, bool xpbd, bool independent, Real* p, const Real* x) {
  const Index m = static_cast<Index>(b.q.size());
  if (xpbd)
    project_bending_range<true>(b, 0, m, independent, p, p, x);
  else
    project_bending_range<false>(b, 0, m, independent, p, p, x);
}

void atan2_rational_array(const Real* y, const Real* x, Real* out, Index n) {
#pragma omp simd
  for (Index i = 0; i < n; ++i) out[i] = atan2_rational(y[i], x[i]);
}

}  // namespace csb
