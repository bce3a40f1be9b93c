// csb — one thread at a time: the guard a stepper holds while it is used.
//
// What may be shared between threads (as Jolt and MuJoCo state theirs): a Model is immutable
// once built and may be read by any number of threads and steppers at once. A stepper owns a
// per-model workspace that a step rebuilds and writes (coloured batches, multipliers, contacts,
// grabs), and a State is written by the step that advances it: each is used by one thread at a
// time. Steppers in different threads, each with its own State, run in parallel and give the
// same bits as one after the other. Using one stepper from two threads at once is refused with
// ConcurrentUse (no lock is taken: the second caller fails at once, the first is not disturbed).
#pragma once

#include "csb/types.hpp"

#include <atomic>
#include <string>

namespace csb {

// Copyable (a copy starts free), so that the stepper holding it stays copyable.
class UseGuard {
 public:
  UseGuard() = default;
  UseGuard(const UseGuard&) {}
  UseGuard& operator=(const UseGuard&) { return *this; }

  // Holds the guard for a scope; throws ConcurrentUse naming `what` if another thread holds it.
  class Scope {
   public:
    Scope(const UseGuard& guard, const char* what) : guard_(guard) {
      if (guard_.busy_.exchange(true, std::memory_order_acquire))
        throw ConcurrentUse(std::string(what) +
                            ": this stepper is in use by another thread (a step, a grab or a read of its "
                            "contacts); a stepper and the State it steps belong to one thread at a time, a Model "
                            "may be shared: give each thread its own stepper and State");
    }
    ~Scope() { guard_.busy_.store(false, std::memory_order_release); }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

   private:
    const UseGuard& guard_;
  };

 private:
  mutable std::atomic<bool> busy_{false};
};

}  // namespace csb
