// csb — a method brought as a plug-in: a shared library, written against the C interface of
// csb_plugin.h, loaded at run time (dlopen) and stepped as an Integrator like a built-in. The
// interface is C so that the plug-in depends on nothing of csb's C++ (its ABI, compiler, Eigen).
#pragma once

#include "csb/integrator.hpp"
#include "csb/methods/registry.hpp"
#include "csb/plugin/csb_plugin.h"
#include "csb/use_guard.hpp"

#include <memory>
#include <string>

namespace csb {

// A loaded plug-in library: its entry points, resolved and its ABI version checked. Shared by
// every PluginIntegrator made from it; the library is unloaded when the last of them goes.
class PluginLibrary {
 public:
  // Loads the shared library at `path` (RTLD_NOW | RTLD_LOCAL: its symbols stay its own). A path
  // without a slash is taken in the working directory, never searched for on the library path.
  // FileNotFound if nothing is there; InvalidArgument naming the file if it is not a shared
  // library that loads, lacks an entry point (named), or reports another ABI version than
  // CSB_PLUGIN_ABI_VERSION.
  static std::shared_ptr<const PluginLibrary> load(const std::string& path);
  ~PluginLibrary();
  PluginLibrary(const PluginLibrary&) = delete;
  PluginLibrary& operator=(const PluginLibrary&) = delete;

  const std::string& path() const { return path_; }
  // csb_plugin_name()'s answer, copied at load.
  const std::string& name() const { return name_; }
  int abi_version() const { return abi_version_; }

 private:
  PluginLibrary() = default;
  friend class PluginIntegrator;

  std::string path_, name_;
  int abi_version_ = 0;
  void* dl_ = nullptr;
  csb_plugin_create_fn create_ = nullptr;
  csb_plugin_step_fn step_ = nullptr;
  csb_plugin_destroy_fn destroy_ = nullptr;
};

// One integrator of a plug-in: csb_plugin_create's handle with the settings dt, substeps,
// iterations and gravity (MethodOptions, checked here: InvalidArgument naming the setting, or
// the plug-in's own message if it refuses them).
//
// step() calls the plug-in one step at a time with views of the model and the state (no copy:
// csb's arrays are the header's layout), and after each call checks that every position and
// velocity is finite and advances state.t and state.step. A call that reports an error, or
// leaves a non-finite value, puts the state back at the end of the last completed step and
// throws: InvalidArgument for CSB_PLUGIN_BAD_INPUT, SimulationError otherwise, naming the
// plug-in, its file, the step and the plug-in's message.
class PluginIntegrator : public Integrator {
 public:
  PluginIntegrator(std::shared_ptr<const PluginLibrary> library, const MethodOptions& options);
  ~PluginIntegrator() override;
  PluginIntegrator(const PluginIntegrator&) = delete;
  PluginIntegrator& operator=(const PluginIntegrator&) = delete;

  std::string name() const override { return library_->name(); }
  Real dt() const override { return options_.dt; }
  void step(const Model& model, State& state, std::int64_t steps = 1,
            const std::function<bool()>& interrupt = {}) override;

  const std::shared_ptr<const PluginLibrary>& library() const { return library_; }
  const MethodOptions& options() const { return options_; }

 private:
  std::string who() const;  // "plug-in 'name' (path)", for messages

  std::shared_ptr<const PluginLibrary> library_;
  MethodOptions options_;
  void* handle_ = nullptr;
  Positions x_saved_, v_saved_;  // the state before a call, restored if it fails
  UseGuard guard_;
};

}  // namespace csb
