// csb — refusing, with the estimate, a request whose memory is clearly beyond the machine.
#pragma once

#include "csb/format.hpp"
#include "csb/types.hpp"

#include <string>

#if defined(__unix__) || defined(__APPLE__)
#include <unistd.h>
#endif

namespace csb {

// Bytes of memory the machine has (0: unknown).
inline double physical_memory_bytes() {
#if defined(_SC_PHYS_PAGES) && defined(_SC_PAGESIZE)
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  if (pages > 0 && page > 0) return static_cast<double>(pages) * static_cast<double>(page);
#endif
  return 0;
}

// What a particle of a generated shape costs once it is a Model stepped by a PbdStepper: a
// 1024 x 1024 cloth measured 662 B a particle (papers/benchmarks.md), its building more at its peak.
constexpr double kBytesPerParticle = 662;

// Throws InvalidArgument, with the estimate, when `particles` of shape `what` could not be
// simulated in this machine's memory.
inline void require_memory_for(const std::string& what, double particles) {
  const double need = particles * kBytesPerParticle, have = physical_memory_bytes();
  if (have > 0 && need > have)
    throw InvalidArgument(what + ": " + detail::str(particles) + " particles would need about " +
                          detail::str(need / 1e9) + " GB as a stepped model (" + detail::str(kBytesPerParticle) +
                          " B a particle), more than this "
                          "machine's " + detail::str(have / 1e9) + " GB of memory");
}

}  // namespace csb
