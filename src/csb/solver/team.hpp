// csb — the threads of the coloured projection.
//
// A small fork-join team made for the coloured Gauss-Seidel sweep: a step forks it once (once
// per sub-step when contacts, grabs or Müller damping keep the sub-step's other work serial)
// and its threads meet at two barriers per sweep of a cloth. OpenMP's runtime (libgomp)
// fixes how a waiting thread behaves when it is loaded: spinning (fast when every thread has a
// core of its own, a collapse when one shares its core with another process: the spinner keeps
// the core the late thread needs) or sleeping at once (robust, but each wake-up of a sleeping
// core costs tens of microseconds on a virtual machine, 20 % of a 128x128 cloth frame). The
// team decides per step instead: it spins briefly only while the machine has a free core for
// each of its threads (the caller reads /proc/loadavg, see free_cores in pbd.cpp), and otherwise
// sleeps at once. A thread that spun for kSpinNs without being released sleeps too.
//
// Work is shared by `take`: counters per phase (one per range of its tasks) hand out task
// numbers, so a thread slowed by a busy core takes fewer. Which thread runs a task never changes
// a result: the tasks of one phase write disjoint data (the sweep's colouring guarantees it).
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

namespace csb {

class Team {
 public:
  Team() = default;
  ~Team();
  Team(const Team&) = delete;
  Team& operator=(const Team&) = delete;

  // Runs job(t) on `threads` threads, t = 0 (the caller) .. threads - 1, and returns when every
  // one has returned. spin: wait by spinning (up to kSpinNs) before sleeping.
  void run(int threads, bool spin, const std::function<void(int)>& job);
  // Within run: waits until every thread of the team has arrived.
  void barrier();
  // Within run: the next task number of `phase` in `range` (phases are counted by the caller,
  // the same on every thread; thread 0 resets a phase's counters after the barrier that ends the
  // phase, and they serve again kRing phases later, several barriers on). Tasks past the range's
  // count mean it is done.
  int take(std::int64_t phase, int range = 0) {
    return counters_[phase % kRing][range].value.fetch_add(1, std::memory_order_relaxed);
  }
  // Within run, on thread 0 after a barrier that ends `phase`: makes its counters ready for reuse.
  void reset(std::int64_t phase) {
    for (Counter& c : counters_[phase % kRing]) c.value.store(0, std::memory_order_relaxed);
  }
  int size() const { return active_; }

  // Threads of every team in this process now spinning while they wait for work (between runs):
  // they show as running in /proc/loadavg but leave their core as soon as work or sleep comes.
  static int idle_spinning();

  static constexpr int kRing = 4;
  static constexpr int kRanges = 8;  // counters per phase (`take`'s range)
  static constexpr std::int64_t kSpinNs = 50'000;  // how long a waiting thread spins, at most

 private:
  template <class Pred>
  void wait_while(Pred&& still, bool idle);
  void wake_all();
  void worker(int t, std::uint32_t seen);
  void resize(int threads);

  struct alignas(64) Counter {
    std::atomic<int> value{0};
  };
  int size_ = 1;                       // threads started (workers + the caller)
  int active_ = 1;                     // threads of the current run
  std::atomic<bool> spin_{false};
  std::vector<std::thread> workers_;
  const std::function<void(int)>* job_ = nullptr;
  alignas(64) std::atomic<std::uint32_t> fork_{0};     // generation of run() calls
  alignas(64) std::atomic<int> arrived_{0};            // at the barrier
  alignas(64) std::atomic<std::uint32_t> barrier_{0};  // generation of barriers
  alignas(64) std::atomic<int> sleepers_{0};
  std::atomic<bool> quit_{false};
  Counter counters_[kRing][kRanges];
  std::mutex mutex_;
  std::condition_variable wake_;
};

// A Team that a copyable owner (PbdStepper) can hold: a copy gets a team of its own, started
// when it is first used.
class TeamHandle {
 public:
  TeamHandle() = default;
  TeamHandle(const TeamHandle&) {}
  TeamHandle& operator=(const TeamHandle&) { return *this; }
  TeamHandle(TeamHandle&&) noexcept = default;
  TeamHandle& operator=(TeamHandle&&) noexcept = default;
  Team& get() {
    if (!team_) team_ = std::make_unique<Team>();
    return *team_;
  }

 private:
  std::unique_ptr<Team> team_;
};

}  // namespace csb
