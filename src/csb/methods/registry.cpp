// csb — the list of methods: one line per method module.
#include "csb/methods/registry.hpp"

#include "csb/format.hpp"

#include <algorithm>
#include <cmath>
#include <string>

namespace csb {

const std::vector<MethodInfo>& methods() {
  static const std::vector<MethodInfo> list = {
      pbd_method(),
      xpbd_method(),
      small_steps_method(),
      jakobsen_method(),
      vbd_method(),
      projective_dynamics_method(),
      implicit_euler_method(),
      backward_euler_method(),
      explicit_euler_method(),
      symplectic_euler_method(),
      velocity_verlet_method(),
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

// ------------------------------------------------------------------------------ settings

namespace {

const char* type_name(const MethodSettings::Value& v) {
  return std::holds_alternative<bool>(v) ? "a boolean"
         : std::holds_alternative<std::int64_t>(v) ? "an integer"
         : std::holds_alternative<double>(v) ? "a number"
                                             : "a string";
}

InvalidArgument wrong(const std::string& key, const std::string& expect, const std::string& got) {
  return InvalidArgument("setting '" + key + "' must be " + expect + ", got " + got);
}

}  // namespace

const MethodSettings::Value* MethodSettings::find(const std::string& key) const {
  known_.insert(key);
  const auto at = values_.find(key);
  return at == values_.end() ? nullptr : &at->second;
}

double MethodSettings::number(const std::string& key, double fallback, double lo, double hi) const {
  const Value* v = find(key);
  if (!v) return fallback;
  const std::string expect = "a number in [" + detail::str(lo) + ", " + detail::str(hi) + "]";
  double x;
  if (const auto* d = std::get_if<double>(v)) x = *d;
  else if (const auto* i = std::get_if<std::int64_t>(v)) x = static_cast<double>(*i);
  else throw wrong(key, expect, type_name(*v));
  if (!std::isfinite(x) || x < lo || x > hi) throw wrong(key, expect, detail::str(x));
  return x;
}

std::int64_t MethodSettings::integer(const std::string& key, std::int64_t fallback, std::int64_t lo,
                                     std::int64_t hi) const {
  const Value* v = find(key);
  if (!v) return fallback;
  const std::string expect = "an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
  const auto* i = std::get_if<std::int64_t>(v);
  if (!i) throw wrong(key, expect, type_name(*v));
  if (*i < lo || *i > hi) throw wrong(key, expect, std::to_string(*i));
  return *i;
}

bool MethodSettings::boolean(const std::string& key, bool fallback) const {
  const Value* v = find(key);
  if (!v) return fallback;
  const auto* b = std::get_if<bool>(v);
  if (!b) throw wrong(key, "true or false", type_name(*v));
  return *b;
}

std::string MethodSettings::choice(const std::string& key, const std::string& fallback,
                                   const std::vector<std::string>& choices) const {
  const Value* v = find(key);
  if (!v) return fallback;
  std::string expect;
  for (std::size_t i = 0; i < choices.size(); ++i)
    expect += (i == 0 ? "'" : i + 1 == choices.size() ? " or '" : ", '") + choices[i] + "'";
  const auto* s = std::get_if<std::string>(v);
  if (!s) throw wrong(key, expect, type_name(*v));
  if (std::find(choices.begin(), choices.end(), *s) == choices.end()) throw wrong(key, expect, "'" + *s + "'");
  return *s;
}

void MethodSettings::finish(const std::string& method) const {
  std::string unread;
  for (const auto& [key, value] : values_)
    if (!known_.count(key)) unread += (unread.empty() ? "'" : ", '") + key + "'";
  if (unread.empty()) return;
  std::string known;
  for (const std::string& k : known_) known += (known.empty() ? "'" : ", '") + k + "'";
  throw InvalidArgument("method '" + method + "' has no setting " + unread + "; " +
                        (known.empty() ? std::string("it takes none beyond dt, substeps, iterations and gravity")
                                       : "its settings are " + known));
}

std::unique_ptr<Integrator> make_method(const MethodInfo& info, const MethodOptions& o) {
  auto made = info.make(o);
  o.settings.finish(info.name);
  return made;
}

// ------------------------------------------------------------------------------ lookup

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
