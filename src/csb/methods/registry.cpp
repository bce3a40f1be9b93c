// csb — the list of methods: one line per method module.
#include "csb/methods/registry.hpp"

#include <algorithm>
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
      backward_euler_method(),
  };
  return list;
}

namespace {

bool answers_to(const MethodInfo& m, const std::string& name) {
  return m.name == name || std::find(m.aliases.begin(), m.aliases.end(), name) != m.aliases.end();
}

// "method must be 'a', 'b' or 'c', got 'd'"
InvalidArgument unknown(const std::vector<std::string>& known, const std::string& name) {
  std::string list;
  for (std::size_t i = 0; i < known.size(); ++i)
    list += (i == 0 ? "'" : i + 1 == known.size() ? " or '" : ", '") + known[i] + "'";
  return InvalidArgument("method must be " + list + ", got '" + name + "'");
}

}  // namespace

const MethodInfo& method_info(const std::string& name) {
  std::vector<std::string> known;
  for (const MethodInfo& m : methods()) {
    if (answers_to(m, name)) return m;
    known.push_back(m.name);
  }
  throw unknown(known, name);
}

std::vector<Method> pbd_variants() {
  std::vector<Method> variants;
  for (const MethodInfo& m : methods())
    if (m.pbd && &method_info(*m.pbd) == &m) variants.push_back(*m.pbd);  // else a set-up of one
  return variants;
}

Method pbd_variant(const std::string& name) {
  std::vector<std::string> known;
  for (const Method v : pbd_variants()) {
    if (answers_to(method_info(v), name)) return v;
    known.push_back(method_info(v).name);
  }
  throw unknown(known, name);
}

const MethodInfo& method_info(Method method) {
  for (const MethodInfo& m : methods())  // the first registered: small steps are XPBD's too
    if (m.pbd == method) return m;
  throw InvalidArgument("no registered method for this position-based variant");
}

ForceIntegrator force_integrator(const std::string& name) {
  std::vector<std::string> known;
  for (const MethodInfo& m : methods()) {
    if (!m.force) continue;
    if (answers_to(m, name)) return *m.force;
    known.push_back(m.name);
  }
  throw unknown(known, name);
}

const MethodInfo& method_info(ForceIntegrator integrator) {
  for (const MethodInfo& m : methods())
    if (m.force == integrator) return m;
  throw InvalidArgument("no registered method for this force-based integrator");
}

}  // namespace csb
