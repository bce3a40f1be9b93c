#include "viewer/viewer.hpp"

#include "csb/interaction/pick.hpp"
#include "csb/methods/registry.hpp"
#include "csb/metrics.hpp"
#include "csb/tearing.hpp"
#include "viewer/gl.hpp"
#include "viewer/renderer.hpp"

#include <GLFW/glfw3.h>
#include <epoxy/egl.h>
#include <imgui.h>
#include <imgui_impl_glfw.h>
#include <imgui_impl_opengl3.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <utility>

namespace csb::viewer {

namespace {

double now() {
  using clock = std::chrono::steady_clock;
  return std::chrono::duration<double>(clock::now().time_since_epoch()).count();
}

// GLFW reports errors through a callback; the last one goes into the exception we throw.
std::string& glfw_error() {
  static std::string message;
  return message;
}

void on_glfw_error(int code, const char* description) {
  glfw_error() = "GLFW error " + std::to_string(code) + ": " + (description ? description : "");
}

// What `method` cannot read of the model's material (material.hpp), a line per constraint family
// for the overlay; printed too, so that the terminal keeps it after the overlay changes.
std::string material_message(const Model& model, Method method) {
  std::string out;
  for (const MaterialNote& note : material_notes(model, method)) {
    std::fprintf(stderr, "csb: warning: %s\n", note.message.c_str());
    out += "\n" + note.message;
  }
  return out;
}

// The overlay's font (Dear ImGui's built-in one) has Latin-1 only: the Greek letters of csb's
// messages (compliance α, ...) are spelled out rather than drawn as '?'.
std::string overlay_text(std::string s) {
  static const std::pair<const char*, const char*> greek[] = {
      {"α", "alpha"}, {"β", "beta"}, {"γ", "gamma"}, {"Δ", "Delta"}, {"δ", "delta"}, {"ε", "epsilon"},
      {"θ", "theta"}, {"κ", "kappa"}, {"λ", "lambda"}, {"μ", "mu"}, {"ν", "nu"}, {"ρ", "rho"},
      {"σ", "sigma"}, {"τ", "tau"}, {"φ", "phi"}, {"ω", "omega"}, {"Ω", "Omega"}};
  for (const auto& [letter, name] : greek)
    for (std::size_t at = s.find(letter); at != std::string::npos; at = s.find(letter, at))
      s.replace(at, std::strlen(letter), name);
  return s;
}

// Exponential moving average: smooth enough to read, quick enough to follow a change.
void smooth(double& average, double sample, std::int64_t n) { average = n <= 1 ? sample : 0.9 * average + 0.1 * sample; }

std::string egl_error(const char* what) {
  char buffer[96];
  std::snprintf(buffer, sizeof buffer, "%s failed (EGL error 0x%04x)", what, static_cast<unsigned>(eglGetError()));
  return buffer;
}

// Framebuffer pixels per window coordinate (1 on X11; 2 on a HiDPI display that scales).
double pixels_per_point(GLFWwindow* w) {
  int ww = 0, wh = 0, fw = 0, fh = 0;
  glfwGetWindowSize(w, &ww, &wh);
  glfwGetFramebufferSize(w, &fw, &fh);
  return ww > 0 ? double(fw) / ww : 1.0;
}

int live_glfw_windows = 0;  // glfwInit/glfwTerminate around the windows that are open

}  // namespace

struct Viewer::Context {
  GLFWwindow* window = nullptr;
  EGLDisplay display = EGL_NO_DISPLAY;
  EGLContext egl = EGL_NO_CONTEXT;
  std::unique_ptr<RenderTarget> target;
  std::unique_ptr<Renderer> renderer;
  ImGuiContext* imgui = nullptr;
  bool imgui_glfw = false, imgui_gl = false;
  bool holds_glfw = false;  // counted in live_glfw_windows

  // Several viewers, windowed and offscreen, may live in one thread: a GLX context and an EGL
  // context cannot both be current, so the other kind is released first.
  void make_current() const {
    if (window) {
      if (eglGetCurrentContext() != EGL_NO_CONTEXT)
        eglMakeCurrent(eglGetCurrentDisplay(), EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
      if (glfwGetCurrentContext() != window) glfwMakeContextCurrent(window);
    } else if (egl != EGL_NO_CONTEXT && eglGetCurrentContext() != egl) {
      if (live_glfw_windows > 0 && glfwGetCurrentContext()) glfwMakeContextCurrent(nullptr);
      eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, egl);
    }
    if (imgui) ImGui::SetCurrentContext(imgui);
  }

  void open_window(const ViewerOptions& o) {
    glfwSetErrorCallback(on_glfw_error);
    glfw_error().clear();
    if (live_glfw_windows == 0 && !glfwInit())
      throw Error("viewer: cannot open a window (" + glfw_error() +
                  "); without a display use the offscreen mode (csb render, or offscreen=True)");
    ++live_glfw_windows;
    holds_glfw = true;
    if (eglGetCurrentContext() != EGL_NO_CONTEXT)
      eglMakeCurrent(eglGetCurrentDisplay(), EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
    glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
    glfwWindowHint(GLFW_SAMPLES, 0);  // multisampling happens in our own target
    window = glfwCreateWindow(o.width, o.height, o.title.c_str(), nullptr, nullptr);
    if (!window) {
      close();
      throw Error("viewer: cannot create an OpenGL 3.3 core window (" + glfw_error() + ")");
    }
    glfwMakeContextCurrent(window);
    glfwSwapInterval(o.vsync ? 1 : 0);
  }

  void open_offscreen() {
    // Mesa's surfaceless platform needs no window system at all; the default display is the
    // fallback for drivers without it.
    auto get_platform_display =
        reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(eglGetProcAddress("eglGetPlatformDisplayEXT"));
    if (get_platform_display) display = get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
    if (display == EGL_NO_DISPLAY) display = eglGetDisplay(EGL_DEFAULT_DISPLAY);
    EGLint major = 0, minor = 0;
    if (display == EGL_NO_DISPLAY || !eglInitialize(display, &major, &minor))
      throw Error("viewer: offscreen rendering needs EGL (Mesa's libegl-mesa0 and libgl1-mesa-dri): " +
                  egl_error("eglInitialize"));
    if (!eglBindAPI(EGL_OPENGL_API)) throw Error("viewer: " + egl_error("eglBindAPI(OpenGL)"));
    const EGLint config_attributes[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT,
                                        EGL_NONE};
    EGLConfig config = nullptr;
    EGLint configs = 0;
    eglChooseConfig(display, config_attributes, &config, 1, &configs);
    const EGLint context_attributes[] = {EGL_CONTEXT_MAJOR_VERSION, 3, EGL_CONTEXT_MINOR_VERSION, 3,
                                         EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                                         EGL_NONE};
    egl = eglCreateContext(display, configs > 0 ? config : EGL_NO_CONFIG_KHR, EGL_NO_CONTEXT, context_attributes);
    if (egl == EGL_NO_CONTEXT) {
      close();
      throw Error("viewer: no OpenGL 3.3 core context offscreen: " + egl_error("eglCreateContext"));
    }
    if (live_glfw_windows > 0 && glfwGetCurrentContext()) glfwMakeContextCurrent(nullptr);
    if (!eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, egl)) {
      const std::string e = egl_error("eglMakeCurrent");
      close();
      throw Error("viewer: " + e);
    }
  }

  void close() {
    if (imgui) {
      make_current();
      if (imgui_gl) ImGui_ImplOpenGL3_Shutdown();
      if (imgui_glfw) ImGui_ImplGlfw_Shutdown();
      ImGui::DestroyContext(imgui);
      imgui = nullptr;
    }
    if (window || egl != EGL_NO_CONTEXT) {
      if (renderer || target) make_current();
      renderer.reset();
      target.reset();
    }
    if (window) {
      glfwDestroyWindow(window);
      window = nullptr;
    }
    if (holds_glfw) {  // once per window, however often close() is called
      holds_glfw = false;
      if (--live_glfw_windows == 0) glfwTerminate();
    }
    if (egl != EGL_NO_CONTEXT) {
      eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
      eglDestroyContext(display, egl);
      egl = EGL_NO_CONTEXT;
    }
    if (display != EGL_NO_DISPLAY) {
      eglTerminate(display);
      display = EGL_NO_DISPLAY;
    }
  }

  // Pixels of the image: the window's framebuffer (which differs from its coordinates on
  // HiDPI displays), or the offscreen size asked for.
  void size(const ViewerOptions& o, int& width, int& height) const {
    if (window) {
      glfwGetFramebufferSize(window, &width, &height);
      width = std::max(width, 1);
      height = std::max(height, 1);
    } else {
      width = o.width;
      height = o.height;
    }
  }
};

Viewer::Viewer(const Model& model, const State& state, const PbdSettings& settings, const ViewerOptions& options)
    : Viewer(model, state, std::make_shared<PbdStepper>(settings), options) {}

Viewer::Viewer(const Model& model, const State& state, std::shared_ptr<Integrator> stepper,
               const ViewerOptions& options)
    : context_(std::make_unique<Context>()),
      options_(options),
      initial_model_(std::make_shared<const Model>(model)),
      model_(initial_model_),
      initial_state_(state),
      state_(state),
      stepper_(std::move(stepper)) {
  if (!stepper_) throw InvalidArgument("viewer: no method to step with (stepper is null)");
  if (options.width < 16 || options.height < 16 || options.width > 16384 || options.height > 16384)
    throw InvalidArgument("viewer: width and height must be 16 to 16384 pixels, got " + std::to_string(options.width) +
                          "x" + std::to_string(options.height));
  if (!(options.frame_time > 0) || !std::isfinite(options.frame_time))
    throw InvalidArgument("viewer: frame_time must be > 0 s, got " + std::to_string(options.frame_time));
  if (!(options.grab_compliance >= 0)) throw InvalidArgument("viewer: grab_compliance must be >= 0 m/N");
  if (!(options.tear_max_strain >= 0)) throw InvalidArgument("viewer: tear max_strain must be >= 0");
  if (options.tear_max_per_step < 1) throw InvalidArgument("viewer: tear max_per_step must be >= 1");
  if (options.samples < 0 || options.samples > 16) throw InvalidArgument("viewer: samples must be 0 to 16");
  if (state.x.cols() != model.num_particles() || state.v.cols() != model.num_particles())
    throw InvalidArgument("viewer: the state has " + std::to_string(state.x.cols()) + " particles, the model " +
                          std::to_string(model.num_particles()));
  if (!options.gravity.allFinite()) throw InvalidArgument("viewer: gravity must be finite");
  pbd_ = dynamic_cast<PbdStepper*>(stepper_.get());
  if (pbd_) {
    settings_ = initial_settings_ = pbd_->settings();
    has_settings_ = true;
    gravity_ = settings_.gravity;
    method_ = &csb::method_info(settings_.method);
    switchable_ = true;
    if (options.method_options) {
      method_options_ = *options.method_options;
    } else {
      method_options_.dt = settings_.dt;
      method_options_.substeps = settings_.substeps;
      method_options_.iterations = settings_.iterations;
      method_options_.gravity = settings_.gravity;
    }
    message_ = material_message(model, settings_.method);
    if (!message_.empty()) message_.erase(0, 1);
  } else {
    gravity_ = options.gravity;
    given_ = stepper_;
    if (options.method_options) {  // a built-in: its method by the name it gives
      method_options_ = *options.method_options;
      switchable_ = true;
      const std::string name = stepper_->name();
      for (const MethodInfo& m : methods())
        if (m.name == name) given_method_ = &m;
      if (!given_method_)
        for (const MethodInfo& m : methods())
          if (std::find(m.aliases.begin(), m.aliases.end(), name) != m.aliases.end()) given_method_ = &m;
      method_ = given_method_;
    }
  }
  // A method's own settings belong to it: the others are made with their defaults.
  method_options_.settings = MethodSettings{};
  if (method_)
    method_cursor_ = static_cast<std::size_t>(method_ - methods().data());
  else
    method_cursor_ = methods().size() - 1;  // m goes on to the first
  dt_ = stepper_->dt();
  if (!(dt_ > 0) || !std::isfinite(dt_))
    throw InvalidArgument("viewer: the method's dt() must be a time step > 0 s, got " + std::to_string(dt_));
  steps_per_frame_ = std::max(1, static_cast<int>(std::lround(options.frame_time / dt_)));
  paused_ = options.paused;
  draw_.wireframe = options.wireframe;
  draw_.particles = options.particles;
  draw_.grid = options.grid;

  Context& c = *context_;
  if (options.offscreen)
    c.open_offscreen();
  else
    c.open_window(options);
  try {
    c.target = std::make_unique<RenderTarget>();
    c.renderer = std::make_unique<Renderer>();
    c.renderer->set_model(*model_);
    IMGUI_CHECKVERSION();
    c.imgui = ImGui::CreateContext();
    ImGui::SetCurrentContext(c.imgui);
    ImGuiIO& io = ImGui::GetIO();
    io.IniFilename = nullptr;  // no imgui.ini in the user's directory
    ImGui::StyleColorsDark();
    ImGui::GetStyle().WindowRounding = 4;
    if (c.window) {
      glfwSetWindowUserPointer(c.window, this);
      glfwSetMouseButtonCallback(c.window, [](GLFWwindow* w, int button, int action, int mods) {
        auto* v = static_cast<Viewer*>(glfwGetWindowUserPointer(w));
        if (action == GLFW_PRESS && ImGui::GetIO().WantCaptureMouse) return;
        double x = 0, y = 0;
        glfwGetCursorPos(w, &x, &y);
        const double s = pixels_per_point(w);
        const int b = button == GLFW_MOUSE_BUTTON_LEFT ? 0 : button == GLFW_MOUSE_BUTTON_RIGHT ? 1 : 2;
        v->mouse_button(b, action == GLFW_PRESS, s * x, s * y, (mods & GLFW_MOD_SHIFT) != 0);
      });
      glfwSetCursorPosCallback(c.window, [](GLFWwindow* w, double x, double y) {
        const double s = pixels_per_point(w);
        static_cast<Viewer*>(glfwGetWindowUserPointer(w))->mouse_move(s * x, s * y);
      });
      glfwSetScrollCallback(c.window, [](GLFWwindow* w, double, double dy) {
        if (ImGui::GetIO().WantCaptureMouse) return;
        static_cast<Viewer*>(glfwGetWindowUserPointer(w))->scroll(dy);
      });
      glfwSetKeyCallback(c.window, [](GLFWwindow* w, int key, int, int action, int) {
        if (action == GLFW_RELEASE || ImGui::GetIO().WantCaptureKeyboard) return;
        static_cast<Viewer*>(glfwGetWindowUserPointer(w))->key(key);
      });
      c.imgui_glfw = ImGui_ImplGlfw_InitForOpenGL(c.window, true);  // chains to the callbacks above
    }
    c.imgui_gl = ImGui_ImplOpenGL3_Init("#version 330 core");
    if (!c.imgui_gl) throw Error("viewer: Dear ImGui's OpenGL 3 backend did not start");
  } catch (...) {
    c.close();
    throw;
  }
  int w = 0, h = 0;
  c.size(options_, w, h);
  camera_.width = w;
  camera_.height = h;
  frame_scene();
  update_energy();
}

Viewer::~Viewer() { close(); }

void Viewer::close() {
  if (context_) context_->close();
  released_ = true;
}

void Viewer::require_open() const {
  if (released_) throw Error("viewer: this viewer was closed");
}

bool Viewer::closed() const {
  return released_ || (context_->window && glfwWindowShouldClose(context_->window));
}

void Viewer::frame_scene() {
  Vec3 lo, hi;
  context_->renderer->bounds(lo, hi);
  camera_.frame(lo, hi);
}

std::int64_t Viewer::run(std::int64_t max_frames, const std::function<void()>& after_frame) {
  std::int64_t n = 0;
  while ((max_frames <= 0 || n < max_frames) && frame()) {
    ++n;
    if (after_frame) after_frame();
  }
  return n;
}

bool Viewer::frame() {
  if (released_) return false;
  Context& c = *context_;
  c.make_current();
  if (c.window) {
    glfwPollEvents();
    if (glfwWindowShouldClose(c.window)) return false;
  }
  if (!paused_) advance(steps_per_frame_);
  draw();
  if (c.window) glfwSwapBuffers(c.window);
  const double t = now();
  if (last_frame_time_ >= 0) {
    const double dt = t - last_frame_time_;
    smooth(stats_.frame_ms, 1e3 * dt, stats_.frames);
    stats_.fps = stats_.frame_ms > 0 ? 1e3 / stats_.frame_ms : 0;
  }
  last_frame_time_ = t;
  ++stats_.frames;
  return true;
}

void Viewer::redraw() {
  require_open();
  context_->make_current();
  draw();
  if (context_->window) glfwSwapBuffers(context_->window);
}

void Viewer::advance(int steps) {
  for (int s = 0; s < steps; ++s) {
    const double t0 = now();
    try {
      if (before_step_) {
        const bool fresh = fresh_stepper_;
        fresh_stepper_ = false;
        before_step_(stepper_.get(), model_.get(), &state_, fresh);
      }
      stepper_->step(*model_, state_, 1);
    } catch (const SimulationError& e) {
      paused_ = true;
      message_ = std::string(e.what()) + "\n(paused: r resets, m switches the method)";
      update_energy();
      return;
    } catch (const InvalidArgument& e) {
      // A built-in refuses this model (set_method tried it, but a tear or a user's change of the
      // state may come later); it refuses before stepping, the state is as it was.
      paused_ = true;
      message_ = method_name() + " cannot step this model: " + e.what() + "\n(paused: m switches the method)";
      return;
    }
    smooth(stats_.step_ms, 1e3 * (now() - t0), ++stats_.steps);
    if (options_.tear_max_strain > 0) {
      TearResult r = tear(*model_, state_, options_.tear_max_strain, options_.tear_max_per_step);
      if (r.torn > 0) {
        model_ = r.model;
        if (!released_) {
          context_->make_current();
          context_->renderer->set_model(*model_);
        }
      }
    }
  }
  update_energy();
}

void Viewer::update_energy() {
  const Metrics m = measure(*model_, state_, gravity_);
  stats_.kinetic = m.kinetic_energy;
  stats_.gravitational = m.gravitational_energy;
  stats_.elastic = m.elastic_energy;
}

void Viewer::single_step() {
  const bool was = paused_;
  advance(1);
  paused_ = was || paused_;
}

void Viewer::reset() {
  release_grab();
  model_ = initial_model_;
  state_ = initial_state_;
  if (stepper_ != given_) {  // a fresh stepper: no multipliers, grabs or workspace of the run before
    if (pbd_) {
      stepper_ = std::make_shared<PbdStepper>(settings_);
      pbd_ = static_cast<PbdStepper*>(stepper_.get());
    } else if (method_) {
      PbdSettings unused;
      std::string note;
      stepper_ = make_stepper(*method_, unused, note);
    }
  }
  fresh_stepper_ = true;  // made afresh above, or the one given going on from the reset state
  stats_.steps = 0;
  message_.clear();
  if (!released_) {
    context_->make_current();
    context_->renderer->set_model(*model_);
  }
  update_energy();
}

std::string Viewer::method_label() const {
  if (!method_) return stepper_->name();
  return method_->label + ": " + method_->source;
}

std::shared_ptr<Integrator> Viewer::make_stepper(const MethodInfo& info, PbdSettings& settings,
                                                 std::string& note) const {
  note.clear();
  if (given_ && &info == given_method_) return given_;
  const bool variant = info.pbd && &csb::method_info(*info.pbd) == &info;  // not a set-up of one (small steps)
  if (variant && has_settings_) {
    // From the settings given, so that switching back restores them. Jakobsen's method predicts
    // from the previous position (Verlet) and damps only by its drag: Müller's velocity damping
    // has nothing to act on there and is switched off, which the overlay says.
    settings = initial_settings_;
    settings.method = *info.pbd;
    if (settings.method == Method::Jakobsen) {
      settings.front_end = FrontEnd::Verlet;
      if (settings.damping > 0) {
        note = " (Mueller damping " + std::to_string(settings.damping) + " off: Verlet damps by its drag, " +
               std::to_string(settings.verlet_drag) + ")";
        settings.damping = 0;
      }
    } else if (initial_settings_.method == Method::Jakobsen) {
      settings.front_end = FrontEnd::Euler;
    }
    return std::make_shared<PbdStepper>(settings);
  }
  std::shared_ptr<Integrator> made = make_method(info, method_options_);
  if (const auto* p = dynamic_cast<const PbdStepper*>(made.get())) settings = p->settings();
  return made;
}

void Viewer::use_stepper(std::shared_ptr<Integrator> stepper, const MethodInfo* info, const PbdSettings& settings) {
  stepper_ = std::move(stepper);
  fresh_stepper_ = true;
  method_ = info;
  pbd_ = dynamic_cast<PbdStepper*>(stepper_.get());
  if (pbd_) settings_ = settings;
  gravity_ = pbd_ ? settings_.gravity : stepper_ == given_ ? options_.gravity : method_options_.gravity;
  dt_ = stepper_->dt();
  steps_per_frame_ = std::max(1, static_cast<int>(std::lround(options_.frame_time / dt_)));
  stats_.step_ms = 0;
  update_energy();
}

void Viewer::set_method(const MethodInfo& info) {
  if (!switchable_)
    throw InvalidArgument("viewer: the method switch chooses among the built-in methods; this viewer steps '" +
                          stepper_->name() + "', which it cannot switch");
  const auto& list = methods();
  const std::size_t index = static_cast<std::size_t>(&info - list.data());
  if (index >= list.size()) throw InvalidArgument("viewer: '" + info.name + "' is not a registered method");
  if (&info == method_) return;
  const std::string refused = "viewer: " + info.label + " (" + info.name + ") cannot step this model: ";
  const std::string staying = "; the method stays " + method_name();
  PbdSettings settings;
  std::string note;
  std::shared_ptr<Integrator> stepper;
  try {
    stepper = make_stepper(info, settings, note);
    if (stepper != given_) {
      // A step of a twin on a copy of the state: a method refuses a model (hard constraints,
      // colliders) in its first step, not when it is made; the stepper kept has not stepped, so
      // that its first step is a fresh stepper's.
      PbdSettings unused;
      std::string unused_note;
      const std::shared_ptr<Integrator> twin = make_stepper(info, unused, unused_note);
      State trial = state_;
      try {
        twin->step(*model_, trial, 1);
      } catch (const SimulationError&) {
        // It can step this model but diverges from this state: the switch goes ahead, and the
        // step in the frame pauses and shows it.
      }
    }
  } catch (const InvalidArgument& e) {
    throw InvalidArgument(refused + e.what() + staying);
  }
  release_grab();
  method_cursor_ = index;
  use_stepper(std::move(stepper), &info, settings);
  message_ = "method: " + method_label() + note;
  if (info.pbd) message_ += material_message(*model_, *info.pbd);
}

void Viewer::release_grab() {
  if (grab_handle_ && pbd_) pbd_->release(grab_handle_);
  grab_handle_ = 0;
  held_particle_ = -1;
  if (drag_button_ == 2) drag_button_ = -1;
}

void Viewer::mouse_button(int button, bool pressed, double x, double y, bool shift) {
  mouse_x_ = x;
  mouse_y_ = y;
  if (!pressed) {
    release_grab();
    drag_button_ = -1;
    return;
  }
  if (button == 0 && !shift) {  // grabbing: PbdStepper's grabs
    const Ray ray = camera_.ray(x, y);
    Vec3 lo, hi;
    context_->renderer->bounds(lo, hi);
    // Near a silhouette or on a chain, the nearest particle within 2 % of the scene's size.
    const Pick pick = pick_particle(*model_, state_, ray.origin, ray.direction, 0.02 * (hi - lo).norm());
    if (pick.particle >= 0 && !pbd_) {
      message_ = "grab: position-based methods only (" + method_name() + " is not one)";
    } else if (pick.particle >= 0) {
      release_grab();
      drag_point_ = state_.x.col(pick.particle);
      grab_handle_ = pbd_->grab(*model_, state_, pick.particle, drag_point_, options_.grab_compliance);
      held_particle_ = pick.particle;
      drag_button_ = 2;
      return;
    }
    drag_button_ = 0;
  } else {
    drag_button_ = 1;
  }
}

void Viewer::mouse_move(double x, double y) {
  const double dx = x - mouse_x_, dy = y - mouse_y_;
  mouse_x_ = x;
  mouse_y_ = y;
  switch (drag_button_) {
    case 0: camera_.orbit(dx, dy); break;
    case 1: camera_.pan(dx, dy); break;
    case 2: {
      // The hand moves in the plane through it that faces the camera.
      const Ray ray = camera_.ray(x, y);
      const Vec3 n = camera_.forward();
      const double denom = ray.direction.dot(n);
      if (std::abs(denom) < 1e-9) break;
      const double s = (drag_point_ - ray.origin).dot(n) / denom;
      if (!(s > 0)) break;
      drag_point_ = ray.origin + s * ray.direction;
      if (pbd_) pbd_->move_grab(grab_handle_, drag_point_);
      break;
    }
    default: break;
  }
}

void Viewer::scroll(double steps) { camera_.zoom(steps); }

void Viewer::key(int k) {
  switch (k) {
    case GLFW_KEY_SPACE: paused_ = !paused_; break;
    case GLFW_KEY_PERIOD:
    case GLFW_KEY_RIGHT: single_step(); break;
    case GLFW_KEY_R: reset(); break;
    case GLFW_KEY_W: draw_.wireframe = !draw_.wireframe; break;
    case GLFW_KEY_P: draw_.particles = !draw_.particles; break;
    case GLFW_KEY_G: draw_.grid = !draw_.grid; break;
    case GLFW_KEY_O: options_.overlay = !options_.overlay; break;
    case GLFW_KEY_F: frame_scene(); break;
    case GLFW_KEY_M:
    case GLFW_KEY_1: case GLFW_KEY_2: case GLFW_KEY_3: case GLFW_KEY_4: case GLFW_KEY_5:
    case GLFW_KEY_6: case GLFW_KEY_7: case GLFW_KEY_8: case GLFW_KEY_9:
      if (!switchable_) {
        message_ = "method keys off: " + stepper_->name() + " is not a built-in method";
        break;
      }
      {
        // m: the registry's next method, after the one last asked for (refused or not), so that
        // a method that cannot step this model is passed over by the next press. 1 to 9: the n-th.
        const std::size_t n = methods().size();
        const std::size_t next = k == GLFW_KEY_M ? (method_cursor_ + 1) % n : static_cast<std::size_t>(k - GLFW_KEY_1);
        if (next >= n) break;
        method_cursor_ = next;
        try {
          set_method(methods()[next]);
        } catch (const Error& e) {  // never through GLFW's callbacks: the overlay says it
          message_ = e.what();
          if (message_.rfind("viewer: ", 0) == 0) message_.erase(0, 8);
          std::fprintf(stderr, "csb: %s\n", message_.c_str());
        }
      }
      break;
    case GLFW_KEY_C: {
      const std::string path = options_.screenshot_prefix + "-" + std::to_string(++screenshots_) + ".png";
      try {
        write_png(screenshot(), path);
        message_ = "wrote " + path;
      } catch (const Error& e) {
        message_ = e.what();
      }
      break;
    }
    case GLFW_KEY_Q:
    case GLFW_KEY_ESCAPE:
      if (context_->window) glfwSetWindowShouldClose(context_->window, GLFW_TRUE);
      break;
    default: break;
  }
}

int key_code(const std::string& name) {
  if (name == "space") return GLFW_KEY_SPACE;
  if (name == "period" || name == ".") return GLFW_KEY_PERIOD;
  if (name == "right") return GLFW_KEY_RIGHT;
  if (name == "escape") return GLFW_KEY_ESCAPE;
  if (name.size() == 1 && std::isalpha(static_cast<unsigned char>(name[0])))
    return GLFW_KEY_A + (std::tolower(static_cast<unsigned char>(name[0])) - 'a');
  if (name.size() == 1 && std::isdigit(static_cast<unsigned char>(name[0]))) return GLFW_KEY_0 + (name[0] - '0');
  throw InvalidArgument("unknown key '" + name + "': use space, period, right, escape, a letter or a digit");
}

void Viewer::draw() {
  Context& c = *context_;
  int w = 0, h = 0;
  c.size(options_, w, h);
  camera_.width = w;
  camera_.height = h;
  const double t0 = now();
  c.target->resize(w, h, options_.samples);
  c.target->bind();
  std::vector<Index> held;
  if (held_particle_ >= 0) held.push_back(held_particle_);
  c.renderer->draw(*model_, state_, camera_, draw_, held, collider_frames());
  if (options_.overlay) draw_overlay();
  c.target->resolve();
  if (c.window) c.target->blit_to_window(w, h);
  stats_.last_draw_ms = 1e3 * (now() - t0);
  smooth(stats_.draw_ms, stats_.last_draw_ms, stats_.frames + 1);
}

std::vector<ColliderFrame> Viewer::collider_frames() const {
  std::vector<ColliderFrame> frames(model_->colliders.size());
  // The poses the state's positions saw. A deforming mesh collider's frame takes its vertices
  // at the end of the last step (model frame) in `vertices`; the renderer applies the pose.
  // Only a collider the stepper deforms is copied: a static mesh keeps the renderer's upload.
  if (pbd_)
    for (std::size_t i = 0; i < frames.size(); ++i) {
      const Index c = static_cast<Index>(i);
      frames[i].pose = pbd_->collider_pose(c);
      if (pbd_->collider_deforms(c)) frames[i].vertices = pbd_->collider_vertices(*model_, c);
    }
  return frames;
}

void Viewer::draw_overlay() {
  // A window that sizes itself to its contents is measured in its first frames and drawn from
  // then on: run those frames now, without drawing, so that the overlay is in the first image.
  while (overlay_frames_ < 2) {
    ++overlay_frames_;
    build_overlay();
    ImGui::EndFrame();
  }
  build_overlay();
  ImGui::Render();
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
}

void Viewer::build_overlay() {
  Context& c = *context_;
  ImGuiIO& io = ImGui::GetIO();
  ImGui_ImplOpenGL3_NewFrame();
  if (c.imgui_glfw) {
    ImGui_ImplGlfw_NewFrame();
  } else {
    io.DisplaySize = ImVec2(static_cast<float>(camera_.width), static_cast<float>(camera_.height));
    io.DeltaTime = static_cast<float>(std::max(options_.frame_time, 1e-3));
  }
  ImGui::NewFrame();
  ImGui::SetNextWindowPos(ImVec2(10, 10), ImGuiCond_Always);
  ImGui::SetNextWindowBgAlpha(0.6f);
  const ImGuiWindowFlags flags = ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_AlwaysAutoResize |
                                 ImGuiWindowFlags_NoSavedSettings | ImGuiWindowFlags_NoFocusOnAppearing |
                                 ImGuiWindowFlags_NoNav | ImGuiWindowFlags_NoMove;
  if (ImGui::Begin("csb", nullptr, flags)) {
    const Real dt = dt_;
    const std::string method = method_label();
    ImGui::Text("%s%s", method.c_str(), paused_ ? "   [paused]" : "");
    ImGui::Text("%.1f fps   %.2f ms/frame", stats_.fps, stats_.frame_ms);
    ImGui::Text("%.3f ms/step  (%d step%s/frame, dt %.4g s)", stats_.step_ms, steps_per_frame_,
                steps_per_frame_ == 1 ? "" : "s", dt);
    if (pbd_) {
      ImGui::Text("%d substep%s x %d iteration%s", settings_.substeps, settings_.substeps == 1 ? "" : "s",
                  settings_.iterations, settings_.iterations == 1 ? "" : "s");
    } else if (method_) {
      const int s = method_options_.substeps, i = method_options_.iterations;
      if (method_->iterates)
        ImGui::Text("%d substep%s x %d iteration%s", s, s == 1 ? "" : "s", i, i == 1 ? "" : "s");
      else
        ImGui::Text("%d substep%s", s, s == 1 ? "" : "s");
      ImGui::TextDisabled("grab: position-based methods only");
    } else {
      ImGui::TextDisabled("grab and method keys off: %s is not a built-in method", method.c_str());
    }
    ImGui::Text("t = %.3f s   %d particles   %d constraints", state_.t, model_->num_particles(),
                model_->num_constraints());
    ImGui::Text("energy %.5g J (kinetic %.4g, gravity %.4g, elastic %.4g)",
                stats_.kinetic + stats_.gravitational + stats_.elastic, stats_.kinetic, stats_.gravitational,
                stats_.elastic);
    if (held_particle_ >= 0) ImGui::Text("holding particle %d", held_particle_);
    if (!message_.empty()) ImGui::TextWrapped("%s", overlay_text(message_).c_str());
    if (switchable_) {  // the methods the keys choose among, four a line, the current one marked
      const auto& list = methods();
      std::string line;
      for (std::size_t i = 0; i < list.size(); ++i) {
        const std::string key = i < 9 ? std::to_string(i + 1) + " " : "m ";
        const std::string entry = &list[i] == method_ ? "[" + key + list[i].name + "]" : key + list[i].name;
        line += (line.empty() ? "" : "  ") + entry;
        if (i % 4 == 3 || i + 1 == list.size()) {
          ImGui::TextDisabled("%s", line.c_str());
          line.clear();
        }
      }
    }
    ImGui::TextDisabled("space pause  . step  r reset  w wire  p points  m/1-9 method");
  }
  ImGui::End();
}

Image Viewer::screenshot() {
  require_open();
  context_->make_current();
  if (context_->target->width() == 0) draw();  // nothing drawn yet
  Image image;
  image.width = context_->target->width();
  image.height = context_->target->height();
  image.rgb.resize(static_cast<std::size_t>(image.width) * image.height * 3);
  if (!image.rgb.empty()) context_->target->read(image.rgb.data());
  return image;
}

}  // namespace csb::viewer
