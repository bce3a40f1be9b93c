// csb — the methods by name. Every method csb can step with is one module in this folder (its
// description, what it reads of the material, how it is made) and one line in registry.cpp's list;
// the bindings, the scene files, the command line, the viewer and the studies find it here.
#pragma once

#include "csb/force.hpp"
#include "csb/integrator.hpp"
#include "csb/pbd.hpp"

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <variant>
#include <vector>

namespace csb {

// A method's own settings beyond MethodOptions' (a linear solver's budget, an acceleration, ...),
// by name, as scene files ([solver.settings]), studies (a method's args) and Python
// (make_integrator's keywords) give them. A method's `make` reads the ones it knows through the
// typed getters, which check type and range and name the key in their errors; finish() then
// refuses any key left unread, listing the method's settings.
class MethodSettings {
 public:
  using Value = std::variant<bool, std::int64_t, double, std::string>;
  void set(const std::string& key, Value value) { values_[key] = std::move(value); }
  bool empty() const { return values_.empty(); }
  const std::map<std::string, Value>& values() const { return values_; }

  // A number (an integer is accepted), finite, in [lo, hi].
  double number(const std::string& key, double fallback, double lo, double hi) const;
  // An integer in [lo, hi].
  std::int64_t integer(const std::string& key, std::int64_t fallback, std::int64_t lo, std::int64_t hi) const;
  bool boolean(const std::string& key, bool fallback) const;
  // One of `choices`.
  std::string choice(const std::string& key, const std::string& fallback, const std::vector<std::string>& choices) const;
  // InvalidArgument naming the keys no getter read, and the ones `method` knows.
  void finish(const std::string& method) const;

 private:
  const Value* find(const std::string& key) const;
  std::map<std::string, Value> values_;
  mutable std::set<std::string> known_;
};

// The settings every method is made from (SI units); a method reads what applies to it.
struct MethodOptions {
  Real dt = 1.0 / 60.0;              // s, the time one step advances; > 0
  int substeps = 1;                  // sub-steps of dt/substeps per step; >= 1
  int iterations = 10;               // constraint sweeps per sub-step (position-based methods); >= 1
  Vec3 gravity = Vec3(0, -9.81, 0);  // m/s²
  MethodSettings settings;           // the method's own; a method without any refuses every key
};

// One of a method's own settings, for its documentation, the scene files and Python.
struct SettingInfo {
  std::string name;           // the key: "cg_iterations"
  std::string default_value;  // as a scene file writes it: "20", "true", "'cg'"
  std::string description;    // what it is, its unit and range
};

struct MethodInfo {
  std::string name;    // how users ask for it: "pbd", "xpbd", "symplectic-euler", ...
  std::vector<std::string> aliases;  // other names it answers to ("verlet" for Jakobsen's)
  std::string label;   // for tables and the viewer: "XPBD"
  std::string source;  // where it comes from: "Macklin, Müller and Chentanez 2016"
  std::string reads;   // what it reads of a constraint's material: "stiffness" or "compliance"
  bool iterates = false;  // whether MethodOptions::iterations means anything to it
  // The variant of csb's position-based pipeline (PbdStepper) or of the force-based integrators
  // (ForceStepper) it is, if it is one: settings that name it by string are resolved here.
  std::optional<Method> pbd;
  std::optional<ForceIntegrator> force;
  std::vector<SettingInfo> settings;  // its own settings (MethodSettings), in the order of its docs
  // Makes the method; reads o.settings and calls o.settings.finish(name) (make_method does).
  std::function<std::unique_ptr<Integrator>(const MethodOptions&)> make;
};

// info.make(o), then o.settings.finish(info.name): the one way every front end makes a method.
std::unique_ptr<Integrator> make_method(const MethodInfo& info, const MethodOptions& o);

// Every method, in the order of registry.cpp's list.
const std::vector<MethodInfo>& methods();
// The method of that name (or alias); InvalidArgument naming the known ones otherwise.
const MethodInfo& method_info(const std::string& name);
// The position-based variant PbdStepper runs for that name ("pbd", "xpbd", "jakobsen" and their
// aliases: the methods that are a variant by their own name, not a way of setting one up, as small
// steps are); InvalidArgument naming them otherwise.
Method pbd_variant(const std::string& name);
// Those variants, in the list's order (the viewer's method keys go through them).
std::vector<Method> pbd_variants();
// The force-based integrator ForceStepper runs for that name; InvalidArgument naming them otherwise.
ForceIntegrator force_integrator(const std::string& name);
// The registered method of a position-based variant or a force-based integrator.
const MethodInfo& method_info(Method method);
const MethodInfo& method_info(ForceIntegrator integrator);

// The method modules (one file or folder each in this folder), in the list's order.
MethodInfo pbd_method();                  // pbd.cpp
MethodInfo xpbd_method();                 // xpbd.cpp
MethodInfo small_steps_method();          // small_steps.cpp
MethodInfo jakobsen_method();             // jakobsen.cpp
MethodInfo vbd_method();                  // vbd/module.cpp
MethodInfo projective_dynamics_method();  // projective_dynamics/module.cpp
MethodInfo implicit_euler_method(), backward_euler_method();  // backward_euler.cpp
MethodInfo explicit_euler_method(), symplectic_euler_method(), velocity_verlet_method();  // force.cpp

}  // namespace csb
