// csb — versions of csb and of the libraries it was built against.
#pragma once

#include <string>

namespace csb {

struct BuildInfo {
  std::string csb_version;
  std::string eigen_version;
  std::string assimp_version;
  std::string sundials_version;
  bool sundials_klu = false;  // SUNDIALS was built with the KLU sparse direct solver
  std::string compiler;
  std::string simd;       // widest vector instructions the build targets: "SSE2" (portable), "AVX2", "AVX-512"
};

BuildInfo build_info();

}  // namespace csb
