// csb — how many threads a coloured sweep takes: the cores that are free (/proc/loadavg), at most the
// model's parts, and whether they may spin while they wait.
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"
#include "csb/solver/team.hpp"
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <thread>

namespace csb {

using detail::str;
using namespace stepper_detail;

namespace {


// Cores free for the team: `decided` sets the thread count, `now` (<= decided) whether its
// threads may spin while they wait.
struct FreeCores {
  int decided, now;
};

#if defined(__linux__)
// Cores not busy with other runnable tasks: /proc/loadavg's fourth field is "runnable/total"
// scheduling entities now, the caller's thread included. Reading it costs ~10 µs on a virtual
// machine, a few per cent of a small cloth's step: a step within 5 ms of the last reading (of
// any stepper in the process) takes that reading again.
// A reading is one instant: one that lands on a task runnable for a few microseconds would
// halve a small cloth's speed for the next 5 ms (a 32x32 cloth stepped on one thread in 6-29 %
// of its frames on an idle machine, in runs of ~10 frames, one reading each). So fewer free
// cores count only once a second reading 1.3 ms later (not a multiple of the 5 ms, so a task
// with a period near it is not seen twice) agrees; until then the team keeps its threads but
// waits by sleeping, not spinning. More free cores count at once.
FreeCores free_cores(int cores) {
  static std::atomic<std::int64_t> read_at{std::numeric_limits<std::int64_t>::min() / 2};  // ns
  static std::atomic<std::int64_t> valid_for{5'000'000};  // ns
  static std::atomic<int> decided{1}, seen{1};
  const std::int64_t now =
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
          .count();
  if (now - read_at.load(std::memory_order_relaxed) < valid_for.load(std::memory_order_relaxed)) {
    const int d = std::min(cores, decided.load(std::memory_order_relaxed));
    return {d, std::min(d, seen.load(std::memory_order_relaxed))};
  }
  std::FILE* f = std::fopen("/proc/loadavg", "r");
  if (!f) return {cores, cores};
  double l1, l5, l15;
  int running = 1, total = 0;
  const int got = std::fscanf(f, "%lf %lf %lf %d/%d", &l1, &l5, &l15, &running, &total);
  std::fclose(f);
  if (got != 5) return {cores, cores};
  running -= Team::idle_spinning();  // csb's own threads about to sleep
  const int free = std::max(1, std::min(cores, cores - (running - 1)));
  const int before = seen.exchange(free, std::memory_order_relaxed);
  int d = decided.load(std::memory_order_relaxed);
  if (free >= d || before <= free) {  // more free cores, or confirmed by the reading before
    d = free;
    decided.store(d, std::memory_order_relaxed);
    valid_for.store(5'000'000, std::memory_order_relaxed);
  } else {
    valid_for.store(1'300'000, std::memory_order_relaxed);  // confirm soon
  }
  read_at.store(now, std::memory_order_relaxed);
  d = std::min(cores, d);
  return {d, std::min(d, free)};
}
#else
FreeCores free_cores(int cores) { return {cores, cores}; }
#endif

}  // namespace


int PbdStepper::resolve_threads(const Model& model) {
  spin_ = false;
  if (settings_.ordering == Ordering::Sequential) return 1;
  if (settings_.threads == 1 || (settings_.threads == 0 && model.num_parts == 1) || model.serial_families())
    return 1;  // (automatic: a model of one part has one task per phase)
  // hardware_concurrency reads /sys on every call (glibc): once per process is enough.
  static const int cores = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  const FreeCores free = free_cores(cores);
  const int threads =
      settings_.threads > 0 ? settings_.threads : std::min<int>(free.decided, static_cast<int>(model.num_parts));
  // Waiting threads may spin when every one has a core to itself (csb/team.hpp). CSB_WAIT=spin
  // or sleep fixes the choice (for measurements, papers/benchmarks.md).
  static const std::string wait = [] {
    const char* v = std::getenv("CSB_WAIT");
    return std::string(v ? v : "");
  }();
  spin_ = wait == "spin" || (wait != "sleep" && threads <= free.now);
  return threads;
}

}  // namespace csb
