// csb — number formatting for error messages (an internal helper of the library sources).
#pragma once

#include "csb/types.hpp"

#include <sstream>
#include <string>

namespace csb::detail {

inline std::string str(Real v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

inline std::string str(const Vec3& v) {
  std::ostringstream s;
  s << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return s.str();
}

}  // namespace csb::detail
