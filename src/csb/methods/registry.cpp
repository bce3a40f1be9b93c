// csb — the list of methods: one line per method module.
#include "csb/methods/registry.hpp"

#include <string>

namespace csb {

const std::vector<MethodInfo>& methods() {
  static const std::vector<MethodInfo> list = {
      pbd_method(),
      xpbd_method(),
      small_steps_method(),
      jakobsen_method(),
      explicit_euler_method(),
      symplectic_euler_method(),
      velocity_verlet_method(),
  };
  return list;
}

const MethodInfo& method_info(const std::string& name) {
  std::string known;
  for (const MethodInfo& m : methods()) {
    if (m.name == name) return m;
    known += (known.empty() ? "'" : ", '") + m.name + "'";
  }
  throw InvalidArgument("method must be one of " + known + ", got '" + name + "'");
}

const MethodInfo& method_info(Method method) {
  for (const MethodInfo& m : methods())  // the first registered: small steps are XPBD's too
    if (m.pbd == method) return m;
  throw InvalidArgument("no registered method for this position-based variant");
}

const MethodInfo& method_info(ForceIntegrator integrator) {
  for (const MethodInfo& m : methods())
    if (m.force == integrator) return m;
  throw InvalidArgument("no registered method for this force-based integrator");
}

}  // namespace csb
