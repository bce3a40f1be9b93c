// machine_limits: this machine's arithmetic peaks per core and its memory bandwidths, the ceilings
// that csb's measured cost per constraint and per frame is set against.
//
// A standalone program, not part of csb's build; scripts/machine_limits.py compiles it with
// `g++ -O2 -std=c++17 -pthread`, runs it and tabulates what it prints.
//
// Arithmetic (one thread unless the name says 2threads), for 256-bit vectors (AVX2, with FMA)
// and 512-bit vectors (AVX-512 F), each in its own function compiled for that instruction set
// (__attribute__((target))) and run only if the processor has it (__builtin_cpu_supports):
//   fma     12 independent chains x = x * m + a of fused multiply-adds (more than FMA latency
//           x FMA pipes on current x86 cores, so the pipes, not the chains, set the pace);
//           2 flops a lane each. Also on 2 threads at once (the sum of both): twice the one
//           thread's figure if the two threads have a core each.
//   addmul  8 chains of multiplies and 8 of additions, no FMA: the peak of code compiled
//           without FMA contraction, as csb's kernels are (x86 cores have separate pipes for
//           the two); 1 flop a lane each.
//   sqrt    8 independent square roots an iteration, of inputs the compiler has to assume
//           changed (an empty asm statement), results consumed the same way; no chain, so the
//           rate is the unit's throughput. Also for scalars (one lane, SSE2).
//   div     the same for divisions.
//   clock   a chain of dependent integer additions (1 cycle each on x86 cores): cycles per ns,
//           the core clock while it ran.
// Figures: GFLOP/s (1e9 flops per second) for fma and addmul, lane results per ns for sqrt and
// div, GHz for the clock.
//
// Memory, STREAM's copy a[i] = b[i] and triad a[i] = b[i] + s * c[i] (which the compiler may
// fuse into an FMA) on arrays of doubles, in the widest vectors the processor has (AVX-512, else
// AVX2), ordinary stores (no non-temporal ones), on 1 and 2 threads (each thread a contiguous
// half of the arrays). Four working sets: three arrays of 256 KiB (l2: fits a 1 MiB L2), 2 MiB
// (l3small: beyond two L2s, a fifth of a 32 MiB L3), 8 MiB (l3: three quarters of a 32 MiB L3) and
// 256 MiB (dram: far beyond any cache). An L3 shared with other cores (or, in a virtual machine,
// with other guests) may not hold all of l3: l3small shows the L3's bandwidth without that.
// Bytes are counted as STREAM counts them: 16 per element for copy (one read, one write) and 24
// for triad (two reads, one write); the write-allocate read that ordinary stores of a missing line
// also cause is not counted. Figures: GB/s (1e9 bytes per second).
//
// Every figure is measured --reps times (7 unless told), each time over about 20 ms of repeated
// work (memory: 50 ms, or one pass over arrays that take longer) after a calibration run that
// also warms the unit up (memory: touches the pages and fills the caches), and printed as one
// line: `name median min max` over the repetitions. Lines `info key value` say what was
// measured; a line starting with '#' is a comment. --quick: small arrays (3 x 32 KiB, 128 KiB,
// 256 KiB, 1 MiB), 3 repetitions of about 1 ms, for tests: its figures are not this machine's
// limits.

// GCC 12's avx512fintrin.h trips -W(maybe-)uninitialized (with -Wall) on its own
// _mm512_undefined_pd() where _mm512_sqrt_pd and _mm512_sqrt_ps are inlined.
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <immintrin.h>
#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace {

using Clock = std::chrono::steady_clock;

// ---------------------------------------------------------------------------------------------
// Options

struct Options {
  int reps = 7;
  double compute_seconds = 0.02;  // s of work per repetition of an arithmetic figure
  double memory_seconds = 0.05;   // s of work per repetition of a bandwidth figure
  std::size_t l2_bytes = 256u << 10;      // bytes per array: three fit a 1 MiB L2
  std::size_t l3small_bytes = 2u << 20;  // three are 3 times two L2s and a fifth of a 32 MiB L3
  std::size_t l3_bytes = 8u << 20;       // three are three quarters of a 32 MiB L3
  std::size_t dram_bytes = 256u << 20;   // three are 24 times a 32 MiB L3
  bool quick = false;
};

// ---------------------------------------------------------------------------------------------
// Keeping values live

// The compiler has to assume that v changed (and so recompute anything derived from it).
template <class V>
inline __attribute__((always_inline)) void opaque(V& v) {
  __asm__ volatile("" : "+v"(v));
}
// The compiler has to compute v.
template <class V>
inline __attribute__((always_inline)) void consume(const V& v) {
  __asm__ volatile("" : : "v"(v));
}

volatile double g_sink = 0;  // every kernel's result ends here

// ---------------------------------------------------------------------------------------------
// Arithmetic kernels, one struct per vector type: its operations (one intrinsic each, inlined),
// then the kernels, written once (CSB_ARITHMETIC_KERNELS, CSB_UNIT_KERNELS) and compiled for the
// struct's instruction set. Independent chains and inputs are written out one by one
// (CSB_REPEAT: F(0) ... F(n - 1)) so that each lives in its own register.

#define CSB_REPEAT6(F) F(0) F(1) F(2) F(3) F(4) F(5)
#define CSB_REPEAT8(F) CSB_REPEAT6(F) F(6) F(7)
#define CSB_REPEAT12(F) CSB_REPEAT8(F) F(8) F(9) F(10) F(11)

constexpr int kFmaChains = 12;    // x = x m + a
constexpr int kAddMulChains = 8;  // of each: 8 of multiplies and 8 of additions
constexpr int kUnitInputs = 8;    // independent square roots or divisions an iteration

// A vector type's operations: T the lane's type, V the vector, PFX and SFX the intrinsics' prefix
// and suffix (PFX##_fmadd_##SFX: _mm256_fmadd_pd, _mm512_fmadd_ps, ...).
#define CSB_VECTOR_OPERATIONS(TARGET, PFX, SFX)                                                        \
  static constexpr int lanes = sizeof(V) / sizeof(T);                                                  \
  __attribute__((target(TARGET), always_inline)) static V set1(T x) { return PFX##_set1_##SFX(x); }    \
  __attribute__((target(TARGET), always_inline)) static V fmadd(V x, V m, V a) {                       \
    return PFX##_fmadd_##SFX(x, m, a);                                                                 \
  }                                                                                                    \
  __attribute__((target(TARGET), always_inline)) static V mul(V x, V y) { return PFX##_mul_##SFX(x, y); } \
  __attribute__((target(TARGET), always_inline)) static V add(V x, V y) { return PFX##_add_##SFX(x, y); } \
  __attribute__((target(TARGET), always_inline)) static V root(V x) { return PFX##_sqrt_##SFX(x); }    \
  __attribute__((target(TARGET), always_inline)) static V divide(V x, V y) { return PFX##_div_##SFX(x, y); } \
  /* the sum of the lanes */                                                                           \
  __attribute__((target(TARGET))) static double total(V v) {                                           \
    T t[lanes];                                                                                        \
    PFX##_storeu_##SFX(t, v);                                                                          \
    double s = 0;                                                                                      \
    for (int i = 0; i < lanes; ++i) s += double(t[i]);                                                 \
    return s;                                                                                          \
  }                                                                                                    \
  /* 1.1 + 0.2 k + 0.011 i in lane i: different in every lane and input */                             \
  __attribute__((target(TARGET))) static V input(int k) {                                              \
    T t[lanes];                                                                                        \
    for (int i = 0; i < lanes; ++i) t[i] = T(1.1 + 0.2 * k + 0.011 * i);                               \
    return PFX##_loadu_##SFX(t);                                                                       \
  }

// fma: 12 chains x = x m + a (m = 0.999, a = 0.001: x tends to a / (1 - m) = 1, so it neither
// overflows nor reaches subnormals). addmul: 8 chains x = x x from x = 1 and 8 chains y = y + y
// from y = 0, fixed points that need no constant register, so that all 16 chains fit AVX2's 16
// registers: more chains of each kind than the 2 pipes x 3 cycles of latency they fill, so that a
// chain held up for a cycle costs no throughput. The floating-point units take no shortcut for
// these values (the rate is the same as with other values where the registers allow constants,
// with AVX-512's 32). The starting values are hidden from the compiler (opaque), so that it cannot
// evaluate a chain.
#define CSB_FMA_START(k) V x##k = set1(T(1.0 + 0.01 * k)); opaque(x##k);
#define CSB_FMA_STEP(k) x##k = fmadd(x##k, m, a);
#define CSB_ADDMUL_START(k) V x##k = set1(T(1)), y##k = set1(T(0)); opaque(x##k), opaque(y##k);
#define CSB_ADDMUL_STEP(k) x##k = mul(x##k, x##k); y##k = add(y##k, y##k);
#define CSB_X_TOTAL(k) s += total(x##k);
#define CSB_Y_TOTAL(k) s += total(y##k);
#define CSB_ARITHMETIC_KERNELS(TARGET)                                                                 \
  __attribute__((target(TARGET))) static double fma_kernel(std::int64_t iters) {                       \
    const V m = set1(T(0.999)), a = set1(T(0.001));                                                    \
    CSB_REPEAT12(CSB_FMA_START)                                                                        \
    for (std::int64_t i = 0; i < iters; ++i) {                                                         \
      CSB_REPEAT12(CSB_FMA_STEP)                                                                       \
    }                                                                                                  \
    double s = 0;                                                                                      \
    CSB_REPEAT12(CSB_X_TOTAL)                                                                          \
    return s;                                                                                          \
  }                                                                                                    \
  __attribute__((target(TARGET))) static double addmul_kernel(std::int64_t iters) {                    \
    CSB_REPEAT8(CSB_ADDMUL_START)                                                                      \
    for (std::int64_t i = 0; i < iters; ++i) {                                                         \
      CSB_REPEAT8(CSB_ADDMUL_STEP)                                                                     \
    }                                                                                                  \
    double s = 0;                                                                                      \
    CSB_REPEAT8(CSB_X_TOTAL) CSB_REPEAT8(CSB_Y_TOTAL)                                                  \
    return s;                                                                                          \
  }

// sqrt, div: 8 inputs hidden from the compiler at every iteration (so it has to compute every
// result anew), 8 results consumed (so it has to compute them), no chain from one iteration to the
// next: the rate is the unit's throughput.
#define CSB_UNIT_START(k) V c##k = input(k);
#define CSB_UNIT_HIDE(k) opaque(c##k);
#define CSB_SQRT_STEP(k) consume(root(c##k));
#define CSB_DIV_STEP(k) consume(divide(n, c##k));
#define CSB_UNIT_KERNELS(TARGET)                                                                       \
  __attribute__((target(TARGET))) static double sqrt_kernel(std::int64_t iters) {                      \
    CSB_REPEAT8(CSB_UNIT_START)                                                                        \
    for (std::int64_t i = 0; i < iters; ++i) {                                                         \
      CSB_REPEAT8(CSB_UNIT_HIDE)                                                                       \
      CSB_REPEAT8(CSB_SQRT_STEP)                                                                       \
    }                                                                                                  \
    return total(root(c0));                                                                            \
  }                                                                                                    \
  __attribute__((target(TARGET))) static double div_kernel(std::int64_t iters) {                       \
    const V n = set1(T(2.718281828));                                                                  \
    CSB_REPEAT8(CSB_UNIT_START)                                                                        \
    for (std::int64_t i = 0; i < iters; ++i) {                                                         \
      CSB_REPEAT8(CSB_UNIT_HIDE)                                                                       \
      CSB_REPEAT8(CSB_DIV_STEP)                                                                        \
    }                                                                                                  \
    return total(divide(n, c0));                                                                       \
  }

struct Avx2Double {
  using V = __m256d;
  using T = double;
  CSB_VECTOR_OPERATIONS("avx2,fma", _mm256, pd)
  CSB_ARITHMETIC_KERNELS("avx2,fma")
  CSB_UNIT_KERNELS("avx2,fma")
};
struct Avx2Float {
  using V = __m256;
  using T = float;
  CSB_VECTOR_OPERATIONS("avx2,fma", _mm256, ps)
  CSB_ARITHMETIC_KERNELS("avx2,fma")
  CSB_UNIT_KERNELS("avx2,fma")
};
struct Avx512Double {
  using V = __m512d;
  using T = double;
  CSB_VECTOR_OPERATIONS("avx512f", _mm512, pd)
  CSB_ARITHMETIC_KERNELS("avx512f")
  CSB_UNIT_KERNELS("avx512f")
};
struct Avx512Float {
  using V = __m512;
  using T = float;
  CSB_VECTOR_OPERATIONS("avx512f", _mm512, ps)
  CSB_ARITHMETIC_KERNELS("avx512f")
  CSB_UNIT_KERNELS("avx512f")
};

// Scalars: the low lane of an SSE2 register (x86-64's baseline), sqrtsd, sqrtss, divsd, divss,
// the instructions of code that is not vectorised.
struct ScalarDouble {
  using V = __m128d;
  static constexpr int lanes = 1;
  static V root(V x) { return _mm_sqrt_sd(x, x); }
  static V divide(V x, V y) { return _mm_div_sd(x, y); }
  static V set1(double x) { return _mm_set_sd(x); }
  static V input(int k) { return _mm_set_sd(1.1 + 0.2 * k); }
  static double total(V v) { return _mm_cvtsd_f64(v); }
  using T = double;
  CSB_UNIT_KERNELS("sse2")
};
struct ScalarFloat {
  using V = __m128;
  static constexpr int lanes = 1;
  static V root(V x) { return _mm_sqrt_ss(x); }
  static V divide(V x, V y) { return _mm_div_ss(x, y); }
  static V set1(float x) { return _mm_set_ss(x); }
  static V input(int k) { return _mm_set_ss(float(1.1 + 0.2 * k)); }
  static double total(V v) { return double(_mm_cvtss_f32(v)); }
  using T = float;
  CSB_UNIT_KERNELS("sse2")
};

// 64 dependent integer additions an iteration: 64 cycles (the loop's own counter runs beside).
double clock_chain(std::int64_t iters) {
  std::uint64_t x = std::uint64_t(iters);
  for (std::int64_t i = 0; i < iters; ++i) __asm__ volatile(".rept 64\n\taddq $1, %0\n\t.endr" : "+r"(x));
  return double(x);
}
constexpr int kClockAdds = 64;

// ---------------------------------------------------------------------------------------------
// Memory kernels: elements [begin, end) of the arrays (multiples of 8), `passes` times over.
// The empty asm with a memory clobber between passes keeps every pass.

using MemoryKernel = void (*)(double* a, const double* b, const double* c, double s, std::size_t begin,
                              std::size_t end, int passes);

__attribute__((target("avx512f"))) void copy_avx512(double* a, const double* b, const double*, double,
                                                    std::size_t begin, std::size_t end, int passes) {
  for (int p = 0; p < passes; ++p) {
    for (std::size_t i = begin; i < end; i += 8) _mm512_storeu_pd(a + i, _mm512_loadu_pd(b + i));
    __asm__ volatile("" : : : "memory");
  }
}
__attribute__((target("avx512f"))) void triad_avx512(double* a, const double* b, const double* c, double s,
                                                     std::size_t begin, std::size_t end, int passes) {
  const __m512d vs = _mm512_set1_pd(s);
  for (int p = 0; p < passes; ++p) {
    for (std::size_t i = begin; i < end; i += 8)
      _mm512_storeu_pd(a + i, _mm512_add_pd(_mm512_loadu_pd(b + i), _mm512_mul_pd(vs, _mm512_loadu_pd(c + i))));
    __asm__ volatile("" : : : "memory");
  }
}
__attribute__((target("avx2"))) void copy_avx2(double* a, const double* b, const double*, double, std::size_t begin,
                                               std::size_t end, int passes) {
  for (int p = 0; p < passes; ++p) {
    for (std::size_t i = begin; i < end; i += 4) _mm256_storeu_pd(a + i, _mm256_loadu_pd(b + i));
    __asm__ volatile("" : : : "memory");
  }
}
__attribute__((target("avx2"))) void triad_avx2(double* a, const double* b, const double* c, double s,
                                                std::size_t begin, std::size_t end, int passes) {
  const __m256d vs = _mm256_set1_pd(s);
  for (int p = 0; p < passes; ++p) {
    for (std::size_t i = begin; i < end; i += 4)
      _mm256_storeu_pd(a + i, _mm256_add_pd(_mm256_loadu_pd(b + i), _mm256_mul_pd(vs, _mm256_loadu_pd(c + i))));
    __asm__ volatile("" : : : "memory");
  }
}
void copy_sse2(double* a, const double* b, const double*, double, std::size_t begin, std::size_t end, int passes) {
  for (int p = 0; p < passes; ++p) {
    for (std::size_t i = begin; i < end; i += 2) _mm_storeu_pd(a + i, _mm_loadu_pd(b + i));
    __asm__ volatile("" : : : "memory");
  }
}
void triad_sse2(double* a, const double* b, const double* c, double s, std::size_t begin, std::size_t end,
                int passes) {
  const __m128d vs = _mm_set1_pd(s);
  for (int p = 0; p < passes; ++p) {
    for (std::size_t i = begin; i < end; i += 2)
      _mm_storeu_pd(a + i, _mm_add_pd(_mm_loadu_pd(b + i), _mm_mul_pd(vs, _mm_loadu_pd(c + i))));
    __asm__ volatile("" : : : "memory");
  }
}

// ---------------------------------------------------------------------------------------------
// Timing

struct Stats {
  double median, min, max;
};

Stats summarize(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  const double median = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
  return {median, v.front(), v.back()};
}

void print(const std::string& name, const Stats& s) {
  std::printf("%s %.6g %.6g %.6g\n", name.c_str(), s.median, s.min, s.max);
  std::fflush(stdout);
}

// The CPUs this process may run on (its affinity mask), in order.
std::vector<int> allowed_cpus() {
  std::vector<int> cpus;
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof set, &set) == 0)
    for (int c = 0; c < CPU_SETSIZE; ++c)
      if (CPU_ISSET(c, &set)) cpus.push_back(c);
  return cpus;
}
const std::vector<int> g_cpus = allowed_cpus();

// Seconds of wall time for `work(t)` run on threads t = 0 .. threads - 1 at once: the clock
// starts when every thread is ready and stops when the last one is done. One thread: the calling
// one. More: new threads, thread t pinned to the t-th allowed CPU, so that a thread's share of the
// arrays stays in the caches of the core it was first read into.
template <class F>
double wall_seconds(int threads, F work) {
  if (threads == 1) {
    const auto t0 = Clock::now();
    work(0);
    return std::chrono::duration<double>(Clock::now() - t0).count();
  }
  std::atomic<int> ready{0};
  std::atomic<bool> go{false};
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t)
    pool.emplace_back([&, t] {
      ready.fetch_add(1);
      while (!go.load(std::memory_order_acquire)) std::this_thread::yield();
      work(t);
    });
  for (int t = 0; t < threads && !g_cpus.empty(); ++t) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(g_cpus[std::size_t(t) % g_cpus.size()], &set);
    pthread_setaffinity_np(pool[std::size_t(t)].native_handle(), sizeof set, &set);  // a hint: may fail
  }
  while (ready.load() < threads) std::this_thread::yield();
  const auto t0 = Clock::now();
  go.store(true, std::memory_order_release);
  for (auto& th : pool) th.join();
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// An arithmetic figure: `kernel(iters)` does `per_iter` units (flops or lane results) an
// iteration; printed as units per ns on `threads` threads together (GFLOP/s for flops).
void arithmetic(const Options& opt, const std::string& name, double (*kernel)(std::int64_t), double per_iter,
                int threads = 1) {
  // Calibration (and warm-up): double the iterations until a run takes an eighth of the target.
  std::int64_t iters = 1024;
  for (;;) {
    double sink = 0;
    const double t = wall_seconds(1, [&](int) { sink = kernel(iters); });
    g_sink = g_sink + sink;
    if (t >= opt.compute_seconds / 8) {
      iters = std::max<std::int64_t>(1, std::int64_t(double(iters) * opt.compute_seconds / t));
      break;
    }
    iters *= 2;
  }
  std::vector<double> rates;
  std::vector<double> sinks(threads);
  for (int r = 0; r < opt.reps; ++r) {
    const double t = wall_seconds(threads, [&](int i) { sinks[i] = kernel(iters); });
    for (double s : sinks) g_sink = g_sink + s;
    rates.push_back(per_iter * double(iters) * threads / t * 1e-9);
  }
  print(name, summarize(rates));
}

template <class K>
void arithmetic_set(const Options& opt, const std::string& isa, const std::string& type) {
  arithmetic(opt, "fma_" + type + "_" + isa + "_gflops", K::fma_kernel, 2.0 * kFmaChains * K::lanes);
  arithmetic(opt, "fma_" + type + "_" + isa + "_2threads_gflops", K::fma_kernel, 2.0 * kFmaChains * K::lanes, 2);
  arithmetic(opt, "addmul_" + type + "_" + isa + "_gflops", K::addmul_kernel, 2.0 * kAddMulChains * K::lanes);
}

template <class K>
void unit_set(const Options& opt, const std::string& isa, const std::string& type) {
  arithmetic(opt, "sqrt_" + type + "_" + isa + "_per_ns", K::sqrt_kernel, double(kUnitInputs * K::lanes));
  arithmetic(opt, "div_" + type + "_" + isa + "_per_ns", K::div_kernel, double(kUnitInputs * K::lanes));
}

// ---------------------------------------------------------------------------------------------
// Bandwidth

// Three arrays of n doubles, 2 MiB-aligned (whole huge pages where the system gives them), the
// second and third offset by 4 KiB + 64 B and twice that, so that a[i], b[i] and c[i] do not
// fall in the same cache set.
struct Arrays {
  std::size_t n;
  std::vector<void*> blocks;
  double *a, *b, *c;
  explicit Arrays(std::size_t bytes) : n(bytes / sizeof(double)) {
    constexpr std::size_t align = 2u << 20, skew = 4096 + 64;
    double* p[3];
    for (int k = 0; k < 3; ++k) {
      const std::size_t size = (bytes + 2 * skew + align - 1) / align * align;
      void* block = std::aligned_alloc(align, size);
      if (!block) {
        std::fprintf(stderr, "machine_limits: cannot allocate %zu bytes\n", size);
        std::exit(1);
      }
      blocks.push_back(block);
      p[k] = reinterpret_cast<double*>(static_cast<char*>(block) + k * skew);
    }
    a = p[0], b = p[1], c = p[2];
    for (std::size_t i = 0; i < n; ++i) a[i] = 0.0, b[i] = 1.0 + double(i % 7), c[i] = 2.0 + double(i % 5);
  }
  ~Arrays() {
    for (void* block : blocks) std::free(block);
  }
  Arrays(const Arrays&) = delete;
  Arrays& operator=(const Arrays&) = delete;
};

// A bandwidth figure: `kernel` over the arrays on `threads` threads, each a contiguous share
// (multiples of 8 elements), `bytes_per_element` counted as STREAM counts them.
void bandwidth(const Options& opt, const std::string& name, Arrays& arr, MemoryKernel kernel, double bytes_per_element,
               int threads) {
  const double s = 3.0;
  auto run = [&](int passes) {
    return wall_seconds(threads, [&](int t) {
      const std::size_t share = (arr.n / 8 + threads - 1) / threads * 8;
      const std::size_t begin = std::min(arr.n, share * t), end = std::min(arr.n, begin + share);
      kernel(arr.a, arr.b, arr.c, s, begin, end, passes);
    });
  };
  // Warm-up (pages touched, caches filled), then passes for the target time.
  run(1);
  const double t1 = run(1);
  const int passes = std::max(1, int(opt.memory_seconds / t1));
  std::vector<double> rates;
  for (int r = 0; r < opt.reps; ++r) {
    const double t = run(passes);
    rates.push_back(bytes_per_element * double(arr.n) * passes / t * 1e-9);
  }
  print(name, summarize(rates));
}

bool triad_holds(const Arrays& arr, double s) {
  for (std::size_t i = 0; i < arr.n; i += 1 + arr.n / 1000)
    if (arr.a[i] != arr.b[i] + s * arr.c[i]) return false;
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--quick") {
      opt.quick = true;
      opt.reps = 3;
      opt.compute_seconds = opt.memory_seconds = 0.001;
      opt.l2_bytes = 32u << 10, opt.l3small_bytes = 128u << 10;
      opt.l3_bytes = 256u << 10, opt.dram_bytes = 1u << 20;
    } else if (arg == "--reps" && i + 1 < argc) {
      opt.reps = std::max(1, std::atoi(argv[++i]));
    } else {
      std::fprintf(stderr, "usage: machine_limits [--quick] [--reps N]\n");
      return 2;
    }
  }

  __builtin_cpu_init();
  const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  const bool avx512 = __builtin_cpu_supports("avx512f");
  std::printf("info quick %d\ninfo reps %d\ninfo avx2_fma %d\ninfo avx512f %d\n", int(opt.quick), opt.reps, int(avx2),
              int(avx512));
  std::printf("info cpus_allowed %zu\n", g_cpus.size());
  std::printf("info array_bytes_l2 %zu\ninfo array_bytes_l3small %zu\ninfo array_bytes_l3 %zu\n", opt.l2_bytes,
              opt.l3small_bytes, opt.l3_bytes);
  std::printf("info array_bytes_dram %zu\n", opt.dram_bytes);
  const char* width = avx512 ? "avx512" : avx2 ? "avx2" : "sse2";
  std::printf("info stream_vectors %s\n", width);
  std::fflush(stdout);

  arithmetic(opt, "clock_ghz", clock_chain, double(kClockAdds));
  if (avx2) {
    arithmetic_set<Avx2Double>(opt, "avx2", "double");
    arithmetic_set<Avx2Float>(opt, "avx2", "float");
  }
  if (avx512) {
    arithmetic_set<Avx512Double>(opt, "avx512", "double");
    arithmetic_set<Avx512Float>(opt, "avx512", "float");
  }
  unit_set<ScalarDouble>(opt, "scalar", "double");
  unit_set<ScalarFloat>(opt, "scalar", "float");
  if (avx2) {
    unit_set<Avx2Double>(opt, "avx2", "double");
    unit_set<Avx2Float>(opt, "avx2", "float");
  }
  if (avx512) {
    unit_set<Avx512Double>(opt, "avx512", "double");
    unit_set<Avx512Float>(opt, "avx512", "float");
  }

  const MemoryKernel copy = avx512 ? copy_avx512 : avx2 ? copy_avx2 : copy_sse2;
  const MemoryKernel triad = avx512 ? triad_avx512 : avx2 ? triad_avx2 : triad_sse2;
  const std::pair<const char*, std::size_t> levels[] = {
      {"l2", opt.l2_bytes}, {"l3small", opt.l3small_bytes}, {"l3", opt.l3_bytes}, {"dram", opt.dram_bytes}};
  for (const auto& [level, bytes] : levels) {
    Arrays arr(bytes);
    for (int threads : {1, 2}) {
      const std::string suffix = std::string("_") + level + (threads == 1 ? "_1thread_gbps" : "_2threads_gbps");
      bandwidth(opt, "copy" + suffix, arr, copy, 16.0, threads);
      bandwidth(opt, "triad" + suffix, arr, triad, 24.0, threads);
      if (!triad_holds(arr, 3.0)) {
        std::fprintf(stderr, "machine_limits: the triad's result is wrong (%s)\n", level);
        return 1;
      }
    }
  }
  std::printf("# sink %g\n", double(g_sink));
  return 0;
}
