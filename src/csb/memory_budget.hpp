// csb — refusing, with the estimate, a request whose memory or time is clearly beyond the machine.
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

// What a particle of a generated shape costs at the peak of its building (the builder's arrays,
// the mesh and the model at once), which is above what the built model and its stepper then hold:
// cloths of 512 x 512 and 1024 x 1024 particles (XPBD, compliant stretch and bending) peaked at
// 986 and 935 B a particle of resident memory while building and at 594 and 585 B while stepping
// (docs/design.md, "Memory").
constexpr double kBytesPerParticle = 1000;

// Throws InvalidArgument, with the estimate, when `particles` of shape `what` could not be
// simulated in this machine's memory.
inline void require_memory_for(const std::string& what, double particles) {
  const double need = particles * kBytesPerParticle, have = physical_memory_bytes();
  if (have > 0 && need > have)
    throw InvalidArgument(what + ": " + detail::str(particles) + " particles would need about " +
                          detail::str(need / 1e9) + " GB at the peak of building the model (" +
                          detail::str(kBytesPerParticle) + " B a particle), more than this "
                          "machine's " + detail::str(have / 1e9) + " GB of memory");
}

// The time a request would take at the very least: its constraint projections and particle
// updates at 1e9 a second, about 7 times what one core measured on a 64 x 64 cloth (1.4e8
// projections a second, PBD, 10 iterations); a request that would take more than a year even so
// is refused. A long run that fits is interruptible instead (Ctrl-C between sub-steps).
constexpr double kFastestOperationsPerSecond = 1e9;
constexpr double kLongestRequestSeconds = 365.25 * 24 * 3600;

// Throws InvalidArgument, with the estimate, when `operations` (projections and particle updates)
// could not be done within a year.
inline void require_time_for(const std::string& what, double operations) {
  const double seconds = operations / kFastestOperationsPerSecond;
  if (seconds > kLongestRequestSeconds)
    throw InvalidArgument(what + ": " + detail::str(operations) + " constraint projections and particle updates "
                          "would take at least " + detail::str(seconds / kLongestRequestSeconds) +
                          " years (at 1e9 a second, faster than csb runs on any one machine); ask for fewer steps");
}

}  // namespace csb
