// csb — loading a plug-in (dlopen) and stepping it through the C interface of csb_plugin.h.
#include "csb/plugin/plugin.hpp"
#include "csb/format.hpp"

#include <dlfcn.h>
#include <sys/stat.h>

#include <cmath>
#include <cstring>
#include <type_traits>
#include <utility>

namespace csb {

using detail::str;

// The views hand csb's own arrays to the plug-in: these are the header's layouts.
static_assert(sizeof(Edge) == 2 * sizeof(std::int32_t) && std::is_same_v<Index, std::int32_t>,
              "a distance constraint's particles are two contiguous int32 (csb_model_view)");
static_assert(std::is_same_v<Real, double>, "csb_plugin.h passes doubles");

namespace {

constexpr std::size_t kMessageSize = 1024;  // bytes a plug-in may write as its error message

std::string last_dl_error() {
  const char* e = dlerror();
  return e ? std::string(e) : std::string("unknown error");
}

// A symbol the library must export; InvalidArgument naming the file and the symbol otherwise.
template <class Fn>
Fn entry_point(void* dl, const std::string& path, const char* symbol) {
  dlerror();
  void* p = dlsym(dl, symbol);
  if (!p) {
    dlclose(dl);
    throw InvalidArgument("plug-in " + path + " does not export " + symbol +
                          ", which a csb plug-in defines (extern \"C\", see csb_plugin.h: csb_plugin_abi_version, "
                          "csb_plugin_name, csb_plugin_create, csb_plugin_step, csb_plugin_destroy)");
  }
  return reinterpret_cast<Fn>(p);
}

// The plug-in's message: what it wrote, NUL-terminated here whatever it did, or a placeholder.
std::string message_of(char* buffer) {
  buffer[kMessageSize - 1] = '\0';
  return buffer[0] ? std::string(buffer) : std::string("(the plug-in gave no message)");
}

csb_model_view view_of(const Model& model) {
  csb_model_view v{};
  v.abi_version = CSB_PLUGIN_ABI_VERSION;
  v.model_id = model.id;
  v.num_particles = model.num_particles();
  v.mass = model.mass.data();
  v.inv_mass = model.inv_mass.data();
  v.rest_positions = model.rest_positions.data();
  const DistanceBatch& d = model.distance;
  v.num_distance = d.size();
  v.distance_particles = d.particles.empty() ? nullptr : d.particles.front().data();
  v.distance_rest_length = d.rest_length.data();
  v.distance_compliance = d.compliance.data();
  v.distance_stiffness = d.stiffness.data();
  v.distance_sense = d.sense.data();
  v.num_bending = model.bending.size();
  v.num_volume = model.volume.size();
  v.num_balloons = model.balloons.size();
  v.num_attachments = model.attachments.size();
  v.num_other = 0;
  for (const auto& f : model.families) v.num_other += f->size();
  v.num_colliders = static_cast<std::int64_t>(model.colliders.size());
  return v;
}

// The first particle with a non-finite coordinate in `x`, or -1.
Index first_non_finite(const Positions& x) {
  const Real* p = x.data();
  for (Index i = 0; i < x.cols(); ++i)
    if (!std::isfinite(p[3 * i]) || !std::isfinite(p[3 * i + 1]) || !std::isfinite(p[3 * i + 2])) return i;
  return -1;
}

}  // namespace

std::shared_ptr<const PluginLibrary> PluginLibrary::load(const std::string& path) {
  if (path.empty()) throw InvalidArgument("plug-in path is empty: give the file of a shared library (.so)");
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) throw FileNotFound("plug-in " + path + " does not exist");
  if (!S_ISREG(st.st_mode)) throw InvalidArgument("plug-in " + path + " is not a file (a shared library, .so)");
  // dlopen searches the library path for a name without a slash; the user named a file.
  const std::string file = path.find('/') == std::string::npos ? "./" + path : path;
  dlerror();
  void* dl = dlopen(file.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!dl)
    throw InvalidArgument("plug-in " + path + " is not a shared library csb can load: " + last_dl_error());
  auto version = entry_point<csb_plugin_abi_version_fn>(dl, path, "csb_plugin_abi_version");
  const int abi = version();
  if (abi != CSB_PLUGIN_ABI_VERSION) {
    dlclose(dl);
    throw InvalidArgument("plug-in " + path + " was built for version " + std::to_string(abi) +
                          " of csb's plug-in interface, and this csb speaks version " +
                          std::to_string(CSB_PLUGIN_ABI_VERSION) +
                          ": rebuild it against the csb_plugin.h in csb.plugin_include_dir()");
  }
  auto name_fn = entry_point<csb_plugin_name_fn>(dl, path, "csb_plugin_name");
  std::shared_ptr<PluginLibrary> lib(new PluginLibrary());
  lib->path_ = path;
  lib->abi_version_ = abi;
  lib->create_ = entry_point<csb_plugin_create_fn>(dl, path, "csb_plugin_create");
  lib->step_ = entry_point<csb_plugin_step_fn>(dl, path, "csb_plugin_step");
  lib->destroy_ = entry_point<csb_plugin_destroy_fn>(dl, path, "csb_plugin_destroy");
  const char* name = name_fn();
  lib->name_ = name && name[0] ? std::string(name) : std::string("plugin");
  lib->dl_ = dl;  // from here the library is closed by the destructor
  return lib;
}

PluginLibrary::~PluginLibrary() {
  if (dl_) dlclose(dl_);
}

PluginIntegrator::PluginIntegrator(std::shared_ptr<const PluginLibrary> library, const MethodOptions& options)
    : library_(std::move(library)), options_(options) {
  if (!library_) throw InvalidArgument("PluginIntegrator: no plug-in library given");
  if (!(options_.dt > 0) || !std::isfinite(options_.dt))
    throw InvalidArgument(who() + ": dt must be a finite time step > 0 s, got " + str(options_.dt));
  if (options_.substeps < 1) throw InvalidArgument(who() + ": substeps must be >= 1, got " + std::to_string(options_.substeps));
  if (options_.iterations < 1)
    throw InvalidArgument(who() + ": iterations must be >= 1, got " + std::to_string(options_.iterations));
  if (!options_.gravity.allFinite()) throw InvalidArgument(who() + ": gravity must be finite (m/s²), got " + str(options_.gravity));
  csb_settings s{};
  s.abi_version = CSB_PLUGIN_ABI_VERSION;
  s.dt = options_.dt;
  s.substeps = options_.substeps;
  s.iterations = options_.iterations;
  for (int k = 0; k < 3; ++k) s.gravity[k] = options_.gravity[k];
  char message[kMessageSize] = {};
  handle_ = library_->create_(&s, message, kMessageSize);
  if (!handle_) throw InvalidArgument(who() + " refused its settings (dt = " + str(options_.dt) + " s, substeps = " +
                                      std::to_string(options_.substeps) + ", iterations = " +
                                      std::to_string(options_.iterations) + "): " + message_of(message));
}

PluginIntegrator::~PluginIntegrator() {
  if (handle_) library_->destroy_(handle_);
}

std::string PluginIntegrator::who() const { return "plug-in '" + library_->name() + "' (" + library_->path() + ")"; }

void PluginIntegrator::step(const Model& model, State& state, std::int64_t steps,
                            const std::function<bool()>& interrupt) {
  UseGuard::Scope in_use(guard_, "PluginIntegrator::step");
  if (steps < 0) throw InvalidArgument("steps must be >= 0, got " + std::to_string(steps));
  const Index n = model.num_particles();
  if (state.x.cols() != n || state.v.cols() != n)
    throw InvalidArgument(who() + ": the state has " + std::to_string(state.x.cols()) + " positions and " +
                          std::to_string(state.v.cols()) + " velocities, the model " + std::to_string(n) +
                          " particles");
  const csb_model_view mv = view_of(model);
  char message[kMessageSize];
  for (std::int64_t s = 0; s < steps; ++s) {
    x_saved_ = state.x;
    v_saved_ = state.v;
    csb_state_view sv{};
    sv.abi_version = CSB_PLUGIN_ABI_VERSION;
    sv.num_particles = n;
    sv.t = state.t;
    sv.step = state.step;
    sv.positions = state.x.data();
    sv.velocities = state.v.data();
    message[0] = '\0';
    const int rc = library_->step_(handle_, &mv, &sv, 1, message, kMessageSize);
    const std::string at = "step " + std::to_string(state.step) + " (t = " + str(state.t) + " s)";
    if (rc != CSB_PLUGIN_OK) {
      state.x = x_saved_;
      state.v = v_saved_;
      const std::string what = who() + " failed at " + at + ": " + message_of(message) +
                               "; the state is left at the start of that step";
      if (rc == CSB_PLUGIN_BAD_INPUT) throw InvalidArgument(what);
      throw SimulationError(rc == CSB_PLUGIN_FAILED ? what : what + " (it returned " + std::to_string(rc) + ")");
    }
    const Index bad_x = first_non_finite(state.x), bad_v = bad_x >= 0 ? bad_x : first_non_finite(state.v);
    if (bad_x >= 0 || bad_v >= 0) {
      const Index i = bad_x >= 0 ? bad_x : bad_v;
      const Positions& q = bad_x >= 0 ? state.x : state.v;
      const std::string value = str(Vec3(q.col(i)));
      state.x = x_saved_;
      state.v = v_saved_;
      throw SimulationError(who() + " wrote a non-finite " + (bad_x >= 0 ? "position" : "velocity") + " " + value +
                            " of particle " + std::to_string(i) + " at " + at +
                            "; the state is left at the start of that step");
    }
    state.t += options_.dt;
    state.step += 1;
    if (s + 1 < steps && interrupt && interrupt())
      throw Interrupted("interrupted after step " + std::to_string(state.step) + " (t = " + str(state.t) +
                        " s): the state is left at the end of that step");
  }
}

}  // namespace csb
