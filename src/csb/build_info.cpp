#include "csb/build_info.hpp"

#include <Eigen/Core>
#include <assimp/version.h>
#include <sundials/sundials_config.h>
#include <sundials/sundials_version.h>

#include <array>

namespace csb {

BuildInfo build_info() {
  BuildInfo info;
  info.csb_version = CSB_VERSION;
  info.eigen_version = std::to_string(EIGEN_WORLD_VERSION) + "." + std::to_string(EIGEN_MAJOR_VERSION) +
                       "." + std::to_string(EIGEN_MINOR_VERSION);
  info.assimp_version = std::to_string(aiGetVersionMajor()) + "." + std::to_string(aiGetVersionMinor()) +
                        "." + std::to_string(aiGetVersionPatch());
  // Asked of the linked library at run time, so this also proves the SUNDIALS link works.
  std::array<char, 64> buffer{};
  SUNDIALSGetVersion(buffer.data(), static_cast<int>(buffer.size()));
  info.sundials_version = buffer.data();
#ifdef SUNDIALS_SUNLINSOL_KLU
  info.sundials_klu = true;
#endif
#if defined(__clang__)
  info.compiler = "clang " __clang_version__;
#elif defined(__GNUC__)
  info.compiler = "gcc " __VERSION__;
#else
  info.compiler = "unknown";
#endif
#if defined(__AVX512F__)
  info.simd = "AVX-512";
#elif defined(__AVX2__)
  info.simd = "AVX2";
#elif defined(__SSE2__) || defined(__x86_64__)
  info.simd = "SSE2";
#else
  info.simd = "scalar";
#endif
  return info;
}

}  // namespace csb
