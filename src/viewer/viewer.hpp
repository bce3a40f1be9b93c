// csb viewer — steps a simulation in real time and draws it (OpenGL 3.3 core, GLSL shaders in
// src/viewer/shaders/), in a GLFW window or offscreen (EGL, no window system).
//
// Window: the left button on the mesh grabs the particle under the cursor (a ray cast,
// csb::pick_particle) and drags it in the plane through it facing the camera
// (PbdStepper::grab / move_grab / release); the left button elsewhere orbits, the right or middle
// button (or shift + left) pans, the wheel zooms. Keys:
//   space pause/run      . or → one step      r reset       w wireframe      p particles
//   m next method (every method of the registry, methods(), in its order)   1 2 ... 9 the n-th
//   o overlay      g grid      c save a screenshot      f frame the scene      q/escape quit
// The overlay (Dear ImGui) shows fps, ms per step, substeps × iterations, the method and the
// methods the keys choose among, energies and the simulated time.
//
// The viewer steps any Integrator (integrator.hpp): a built-in position-based stepper, a
// force-based or implicit one, or a user's method (from Python through the binding's trampoline).
// The method keys switch among the registry's methods when the viewer knows the settings to make
// them from (dt, substeps, iterations, gravity): a PbdStepper's, or ViewerOptions::method_options
// for another built-in; with a user's own method they are off, and the overlay says so. Grabbing
// acts through PbdStepper's grabs, so it works while the method is a PbdStepper.
//
// Every frame advances the simulation by `frame_time` of simulated time (whole steps of the
// stepper's dt), so at 60 frames per second and frame_time = 1/60 s it runs in real time. The
// window and the offscreen mode draw into the same offscreen target, so screenshots read the
// same pixels in both.
#pragma once

#include "csb/integrator.hpp"
#include "csb/methods/registry.hpp"
#include "csb/pbd.hpp"
#include "viewer/camera.hpp"
#include "viewer/renderer.hpp"

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace csb::viewer {

struct ViewerOptions {
  int width = 1280;              // pixels
  int height = 800;
  bool offscreen = false;        // EGL surfaceless context, no window
  std::string title = "csb";
  int samples = 4;               // multisampling
  bool vsync = true;             // window only
  bool overlay = true;           // the ImGui overlay (also drawn into screenshots and frames)
  bool wireframe = false;
  bool particles = false;
  bool grid = true;
  bool paused = false;
  Real frame_time = 1.0 / 60.0;  // s of simulated time per frame, rounded to whole steps (>= 1)
  // m/N: 0 drags kinematically, > 0 pulls with an XPBD spring of stiffness 1/compliance.
  Real grab_compliance = 0;
  // Tearing (Müller 2007 §4.6) after every step, as in scenes; max_strain 0: no tearing.
  Real tear_max_strain = 0;
  Index tear_max_per_step = 1;
  std::string screenshot_prefix = "csb-screenshot";  // the `c` key writes <prefix>-<n>.png
  // m/s², for the overlay's gravitational energy when the method is not a PbdStepper (whose
  // settings have their own gravity).
  Vec3 gravity = Vec3(0, -9.81, 0);
  // The settings the method keys make the registry's methods from (dt in s, substeps, iterations,
  // gravity in m/s²; make_method) when the stepper given is not a PbdStepper, whose settings say
  // them otherwise. Set it only for a built-in stepper (its dt() as dt): the viewer then finds its
  // method in the registry by its name(). Unset for another stepper: the method keys are off.
  std::optional<MethodOptions> method_options;
};

// What the overlay shows, measured over the last frames.
struct Stats {
  double fps = 0;              // frames per wall-clock second
  double frame_ms = 0;         // wall ms per frame, everything included
  double step_ms = 0;          // wall ms per stepper step (dt of simulated time)
  double draw_ms = 0;          // wall ms to draw a frame (commands issued; smoothed)
  double last_draw_ms = 0;     // the same for the last frame alone
  std::int64_t frames = 0;     // drawn since start
  std::int64_t steps = 0;      // stepper steps since the last reset
  double kinetic = 0, gravitational = 0, elastic = 0;  // J
};

// An RGB8 image, top row first.
struct Image {
  int width = 0, height = 0;
  std::vector<unsigned char> rgb;
};

void write_png(const Image& image, const std::string& path);

// The GLFW key code of a key's name ('space', 'period', 'right', 'escape', a letter or a digit),
// for synthetic key presses; throws InvalidArgument for other names.
int key_code(const std::string& name);

class Viewer {
 public:
  // Copies the model and state (reset returns to them) and steps them with `stepper` (kept, and
  // shared with the caller). A PbdStepper's settings are what the method switch and reset start
  // from (they make a fresh PbdStepper); any other method is stepped as it is, reset keeping it,
  // and the method switch works when options.method_options says its settings.
  // Opens the window or the offscreen context; throws csb::Error saying what is missing (no
  // display, no OpenGL 3.3) if it cannot, InvalidArgument for a stepper whose dt() is not > 0.
  Viewer(const Model& model, const State& state, std::shared_ptr<Integrator> stepper,
         const ViewerOptions& options = {});
  // The same with a PbdStepper made from `settings`.
  Viewer(const Model& model, const State& state, const PbdSettings& settings, const ViewerOptions& options = {});
  ~Viewer();
  Viewer(const Viewer&) = delete;
  Viewer& operator=(const Viewer&) = delete;

  // Frames until the window closes (or `max_frames` > 0 frames were drawn); returns the frames drawn.
  // after_frame, if given, runs after each frame drawn (the Python binding handles signals there);
  // an exception from it ends the loop and passes through.
  std::int64_t run(std::int64_t max_frames = 0, const std::function<void()>& after_frame = {});
  // One frame: window events, the simulation's advance (unless paused), drawing. Returns false
  // once the window has been asked to close.
  bool frame();
  // Draws the current state again without stepping (after a camera change, say).
  void redraw();
  // Whether the window was asked to close, or close() was called.
  bool closed() const;
  // Releases the window or offscreen context and its OpenGL objects now (the destructor does it
  // otherwise); frame() then returns false and drawing or screenshots throw.
  void close();

  // The last frame drawn.
  Image screenshot();  // draws first if nothing was drawn yet

  // Input, in window pixels from the top-left corner; the window's callbacks call these, and so
  // may tests and scripts (synthetic events). button: 0 left, 1 right, 2 middle.
  void mouse_button(int button, bool pressed, double x, double y, bool shift = false);
  void mouse_move(double x, double y);
  void scroll(double steps);
  // A key by its GLFW key code (GLFW_KEY_SPACE, ...); unknown keys are ignored.
  void key(int glfw_key);

  // The actions behind the keys.
  void set_paused(bool paused) { paused_ = paused; }
  bool paused() const { return paused_; }
  void single_step();  // one step of dt, also while paused
  void reset();        // the model and state given at construction; the camera stays
  // The method switch, among every registered method (methods()). A position-based variant is
  // made from the PbdSettings given (switching back restores them), the stepper given is taken
  // back for its own method, any other method is made by make_method from the settings given
  // (PbdSettings' or options.method_options' dt, substeps, iterations and gravity). The method
  // is tried on a copy of the state first: InvalidArgument saying why, with the method and the
  // state unchanged, when it cannot step this model (its constructor or its first step refuses:
  // hard constraints, colliders, ...), or when the switch is off (a user's own method).
  void set_method(const MethodInfo& info);
  void set_method(const std::string& name) { set_method(csb::method_info(name)); }
  void set_method(Method method) { set_method(csb::method_info(method)); }
  // The registered method being stepped, or null for a user's own.
  const MethodInfo* current_method() const { return method_; }
  // Its name ("pbd", "small-steps", "backward-euler", ...), or the stepper's name() for a user's.
  std::string method_name() const { return method_ ? method_->name : stepper_->name(); }
  Method method() const { return settings_.method; }  // meaningful when position_based()
  // Whether the method keys work (the viewer knows the settings to make the methods from).
  bool method_switch() const { return switchable_; }
  // Whether the method is a PbdStepper: grabbing works only then.
  bool position_based() const { return pbd_ != nullptr; }
  // The overlay's last notice: a method switch (with what the method cannot read of the
  // model's material, material.hpp), a method that cannot step the model, a screenshot written,
  // a simulation error.
  const std::string& message() const { return message_; }
  DrawOptions& draw_options() { return draw_; }
  void set_overlay(bool on) { options_.overlay = on; }
  void frame_scene();  // the camera frames the model and its colliders

  // Called before every step with the stepper about to take it, the model and the state at the
  // step's start: where a scene moves its colliders (PbdStepper::move_collider to their poses at
  // the step's end) and attaches particles to them. `fresh` is true on the first step of each
  // stepper: the first one, and each a reset or the method switch makes (its colliders at their
  // declared poses, nothing attached). An InvalidArgument it throws pauses the viewer with its
  // message, as the stepper's would; other exceptions (a Python one through the binding) pass
  // through frame(), run() and capture().
  // csb.open_viewer sets it for a scene's collider motions and attachments.
  using BeforeStep = std::function<void(Integrator* stepper, const Model* model, const State* state, bool fresh)>;
  void set_before_step(BeforeStep before_step) { before_step_ = std::move(before_step); }
  // Where each of the model's colliders is drawn this frame: a PbdStepper's poses
  // (collider_pose), the declared ones for another method (which does not move colliders).
  std::vector<ColliderFrame> collider_frames() const;

  Camera& camera() { return camera_; }
  const Camera& camera() const { return camera_; }
  const Model& model() const { return *model_; }
  const State& state() const { return state_; }
  State& state() { return state_; }
  const Integrator& integrator() const { return *stepper_; }
  const std::shared_ptr<Integrator>& integrator_ptr() const { return stepper_; }
  const PbdSettings& settings() const { return settings_; }  // meaningful when position_based()
  Real dt() const { return dt_; }  // s, the method's step
  // The particle held by the mouse, or -1.
  Index held_particle() const { return held_particle_; }
  const Stats& stats() const { return stats_; }
  int steps_per_frame() const { return steps_per_frame_; }

 private:
  struct Context;
  void advance(int steps);
  void draw();
  void draw_overlay();
  void build_overlay();  // the overlay's widgets for one ImGui frame, up to End()
  void update_energy();
  void release_grab();
  void require_open() const;
  // A new stepper of `info` (the stepper given for its own method), its PbdSettings in `settings`
  // when it is a PbdStepper, and what the overlay says of it in `note`.
  std::shared_ptr<Integrator> make_stepper(const MethodInfo& info, PbdSettings& settings, std::string& note) const;
  void use_stepper(std::shared_ptr<Integrator> stepper, const MethodInfo* info, const PbdSettings& settings);
  std::string method_label() const;  // "XPBD: Macklin, Müller and Chentanez 2016", or a user's name()

  std::unique_ptr<Context> context_;
  ViewerOptions options_;
  DrawOptions draw_;
  std::shared_ptr<const Model> initial_model_, model_;
  State initial_state_, state_;
  PbdSettings settings_;          // stepper_'s, when it is a PbdStepper
  PbdSettings initial_settings_;  // those given, when has_settings_
  bool has_settings_ = false;     // PbdSettings were given: the position-based variants start from them
  std::shared_ptr<Integrator> stepper_;
  PbdStepper* pbd_ = nullptr;  // stepper_ as a PbdStepper, or null
  // The method switch.
  std::shared_ptr<Integrator> given_;       // the stepper given, when it is not a PbdStepper
  const MethodInfo* given_method_ = nullptr;  // its registered method, if it is a built-in
  const MethodInfo* method_ = nullptr;      // stepper_'s registered method, or null (a user's)
  bool switchable_ = false;                 // the method keys work
  MethodOptions method_options_;            // what make_method makes the other methods from
  std::size_t method_cursor_ = 0;           // methods()'s index the m key goes on from
  Real dt_ = 0;                // s, stepper_->dt()
  Vec3 gravity_ = Vec3::Zero();  // m/s², for the energies
  Camera camera_;
  bool paused_ = false;
  int steps_per_frame_ = 1;
  // Mouse.
  int drag_button_ = -1;      // 0 orbit, 1 pan, 2 grab
  double mouse_x_ = 0, mouse_y_ = 0;
  int grab_handle_ = 0;
  Index held_particle_ = -1;
  Vec3 drag_point_ = Vec3::Zero();  // m, where the hand is
  Stats stats_;
  BeforeStep before_step_;
  bool fresh_stepper_ = true;  // stepper_ has not stepped since it was made or given
  double last_frame_time_ = -1;
  int screenshots_ = 0;
  int overlay_frames_ = 0;    // ImGui frames run so far
  bool released_ = false;     // close() was called
  std::string message_;       // the overlay's last notice (a save, a simulation error)
};

}  // namespace csb::viewer
