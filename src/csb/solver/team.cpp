#include "csb/solver/team.hpp"

#include <chrono>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define CSB_PAUSE() _mm_pause()
#else
#define CSB_PAUSE() std::this_thread::yield()
#endif

namespace csb {

namespace {
std::atomic<int> idle_spinners{0};  // team threads of this process spinning while waiting for work
}  // namespace

int Team::idle_spinning() { return idle_spinners.load(std::memory_order_relaxed); }

Team::~Team() { resize(1); }

void Team::resize(int threads) {
  if (threads == size_) return;
  if (!workers_.empty()) {
    quit_.store(true, std::memory_order_seq_cst);
    fork_.fetch_add(1, std::memory_order_seq_cst);
    wake_all();
    for (std::thread& w : workers_) w.join();
    workers_.clear();
    quit_.store(false, std::memory_order_seq_cst);
  }
  size_ = threads;
  const std::uint32_t seen = fork_.load(std::memory_order_seq_cst);
  for (int t = 1; t < threads; ++t) workers_.emplace_back(&Team::worker, this, t, seen);
}

template <class Pred>
void Team::wait_while(Pred&& still, bool idle) {
  if (spin_.load(std::memory_order_relaxed)) {
    if (idle) idle_spinners.fetch_add(1, std::memory_order_relaxed);
    const auto t0 = std::chrono::steady_clock::now();
    bool done = false;
    for (unsigned i = 1;; ++i) {
      if (!still()) {
        done = true;
        break;
      }
      CSB_PAUSE();
      if ((i & 255) == 0 && std::chrono::steady_clock::now() - t0 > std::chrono::nanoseconds(kSpinNs)) break;
    }
    if (idle) idle_spinners.fetch_sub(1, std::memory_order_relaxed);
    if (done) return;
  }
  // Sleep. The waker publishes its store before it reads sleepers_ (both sequentially
  // consistent) and this thread counts itself before it tests again, so either it sees the store
  // or the waker sees it counted and notifies under the mutex.
  std::unique_lock<std::mutex> lock(mutex_);
  sleepers_.fetch_add(1, std::memory_order_seq_cst);
  wake_.wait(lock, [&] { return !still(); });
  sleepers_.fetch_sub(1, std::memory_order_seq_cst);
}

void Team::wake_all() {
  if (sleepers_.load(std::memory_order_seq_cst) > 0) {
    std::lock_guard<std::mutex> lock(mutex_);
    wake_.notify_all();
  }
}

void Team::worker(int t, std::uint32_t seen) {
  for (;;) {
    wait_while([&] { return fork_.load(std::memory_order_seq_cst) == seen; }, true);
    seen = fork_.load(std::memory_order_seq_cst);
    if (quit_.load(std::memory_order_seq_cst)) return;
    (*job_)(t);
    barrier();
  }
}

void Team::run(int threads, bool spin, const std::function<void(int)>& job) {
  for (auto& ring : counters_)
    for (Counter& c : ring) c.value.store(0, std::memory_order_relaxed);
  if (threads <= 1) {
    active_ = 1;
    job(0);
    return;
  }
  resize(threads);
  active_ = threads;
  spin_.store(spin, std::memory_order_relaxed);
  job_ = &job;
  fork_.fetch_add(1, std::memory_order_seq_cst);
  wake_all();
  job(0);
  barrier();
}

void Team::barrier() {
  if (active_ <= 1) return;
  const std::uint32_t gen = barrier_.load(std::memory_order_seq_cst);
  if (arrived_.fetch_add(1, std::memory_order_acq_rel) + 1 == active_) {
    arrived_.store(0, std::memory_order_relaxed);
    barrier_.store(gen + 1, std::memory_order_seq_cst);
    wake_all();
  } else {
    wait_while([&] { return barrier_.load(std::memory_order_seq_cst) == gen; }, false);
  }
}

}  // namespace csb
