// csb._viewer — the OpenGL viewer from Python, a module of its own over the csb library that
// csb._core uses (built when the viewer's libraries were found; see src/viewer/CMakeLists.txt).
// It takes csb._core's types (Model, State, Integrator, PbdSettings) and raises its exceptions.
#include "bindings.hpp"
#include "int_arg.hpp"

#include "csb/methods/registry.hpp"
#include "viewer/capture.hpp"
#include "viewer/command.hpp"
#include "viewer/viewer.hpp"

#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <cstring>

namespace py = pybind11;
using namespace csb;
using csb::viewer::Viewer;
using namespace csb::python;

namespace {

Vec3 vec3(const py::handle& obj, const char* what) {
  const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(obj);
  if (!a || a.ndim() != 1 || a.shape(0) != 3) throw InvalidArgument(std::string(what) + " must be 3 numbers");
  return Vec3(a.at(0), a.at(1), a.at(2));
}

py::array_t<std::uint8_t> image_array(const csb::viewer::Image& image) {
  py::array_t<std::uint8_t> a({static_cast<py::ssize_t>(image.height), static_cast<py::ssize_t>(image.width), py::ssize_t(3)});
  if (!image.rgb.empty()) std::memcpy(a.mutable_data(), image.rgb.data(), image.rgb.size());
  return a;
}

csb::viewer::ViewerOptions viewer_options(IntArg width, IntArg height, bool offscreen, const std::string& title,
                                          IntArg samples, bool vsync, bool overlay, bool wireframe, bool particles,
                                          bool grid, bool paused, double frame_time, double grab_compliance,
                                          double tear_max_strain, IntArg tear_max_per_step,
                                          const std::string& screenshot_prefix) {
  csb::viewer::ViewerOptions o;
  o.width = in_range<int>(width, "viewer: width", 16, 16384);
  o.height = in_range<int>(height, "viewer: height", 16, 16384);
  o.offscreen = offscreen;
  o.title = title;
  o.samples = in_range<int>(samples, "viewer: samples", 0, 16);
  o.vsync = vsync;
  o.overlay = overlay;
  o.wireframe = wireframe;
  o.particles = particles;
  o.grid = grid;
  o.paused = paused;
  o.frame_time = frame_time;
  o.grab_compliance = grab_compliance;
  o.tear_max_strain = tear_max_strain;
  o.tear_max_per_step = in_range(tear_max_per_step, "viewer: tear_max_per_step", 1, kMaxIndex);
  o.screenshot_prefix = screenshot_prefix;
  return o;
}

// The keyword arguments both constructors take after the method.
#define VIEWER_OPTION_ARGS                                                                                     \
  py::kw_only(), py::arg("width") = 1280, py::arg("height") = 800, py::arg("offscreen") = false,              \
      py::arg("title") = "csb", py::arg("samples") = 4, py::arg("vsync") = true, py::arg("overlay") = true,   \
      py::arg("wireframe") = false, py::arg("particles") = false, py::arg("grid") = true,                     \
      py::arg("paused") = false, py::arg("frame_time") = 1.0 / 60.0, py::arg("grab_compliance") = 0.0,       \
      py::arg("tear_max_strain") = 0.0, py::arg("tear_max_per_step") = 1,                                      \
      py::arg("screenshot_prefix") = "csb-screenshot"

}  // namespace

PYBIND11_MODULE(_viewer, m) {
  m.doc() = "csb's OpenGL viewer: a window, or offscreen rendering into images and MP4";
  // csb._core's types first: the signatures below name them, and its exception translator
  // turns csb's errors raised here into csb.Error and its subclasses.
  py::module_::import("csb._core");
  m.def("command", [](const std::vector<std::string>& args) {
    std::vector<const char*> argv{"csb-view"};
    for (const std::string& a : args) argv.push_back(a.c_str());
    py::gil_scoped_release unlocked;
    return csb::viewer::command(static_cast<int>(argv.size()), argv.data());
  }, py::arg("args"), "Runs the csb-view command on args (without the program's name); returns its exit status.");

  using csb::viewer::Camera;
  py::class_<Camera>(m, "Camera", "The viewer's orbit camera (m, rad; pixels from the top-left corner).")
      .def_property("target", [](const Camera& c) { return Vec3(c.target); },
                    [](Camera& c, py::handle t) { c.target = vec3(t, "target"); }, "m, the point looked at")
      .def_readwrite("distance", &Camera::distance, "m, from the eye to the target")
      .def_readwrite("yaw", &Camera::yaw, "rad about +y; 0 looks along -z")
      .def_readwrite("pitch", &Camera::pitch, "rad above the horizon")
      .def_readwrite("fov_y", &Camera::fov_y, "rad, vertical field of view")
      .def_readonly("width", &Camera::width)
      .def_readonly("height", &Camera::height)
      .def_property_readonly("eye", &Camera::eye)
      .def_property_readonly("forward", &Camera::forward)
      .def("project", [](const Camera& c, py::handle p) {
        double depth = 0;
        const Eigen::Vector2d px = c.project(vec3(p, "point"), &depth);
        return py::make_tuple(px.x(), px.y(), depth);
      }, py::arg("point"), "(x, y, depth): where a world point (m) lands in the image, in pixels, and its depth "
                           "(m) in front of the eye")
      .def("ray", [](const Camera& c, double x, double y) {
        const csb::viewer::Ray r = c.ray(x, y);
        return py::make_tuple(r.origin, r.direction);
      }, py::arg("x"), py::arg("y"), "(origin, unit direction) of the ray through pixel (x, y)")
      .def("orbit", &Camera::orbit, py::arg("dx"), py::arg("dy"))
      .def("pan", &Camera::pan, py::arg("dx"), py::arg("dy"))
      .def("zoom", &Camera::zoom, py::arg("steps"));

  py::class_<Viewer>(m, "Viewer",
      "Steps a simulation in real time and draws it with OpenGL 3.3, in a window or offscreen. See csb.view().")
      .def(py::init([](const Model& model, const State& state, std::shared_ptr<Integrator> stepper, IntArg width,
                       IntArg height, bool offscreen, const std::string& title, IntArg samples, bool vsync, bool overlay,
                       bool wireframe, bool particles, bool grid, bool paused, double frame_time,
                       double grab_compliance, double tear_max_strain, IntArg tear_max_per_step,
                       const std::string& screenshot_prefix, py::handle gravity, py::handle substeps,
                       py::handle iterations) {
             csb::viewer::ViewerOptions o = viewer_options(width, height, offscreen, title, samples, vsync, overlay,
                                                           wireframe, particles, grid, paused, frame_time,
                                                           grab_compliance, tear_max_strain, tear_max_per_step,
                                                           screenshot_prefix);
             if (!gravity.is_none()) o.gravity = vec3(gravity, "gravity");
             if (substeps.is_none() != iterations.is_none())
               throw InvalidArgument("viewer: give substeps and iterations together (the method switch's settings), "
                                     "or neither");
             if (!substeps.is_none() && stepper) {
               MethodOptions mo;
               mo.dt = stepper->dt();
               mo.substeps = in_range<int>(IntArg{py::reinterpret_borrow<py::object>(substeps)}, "viewer: substeps", 1, kMaxSubsteps);
               mo.iterations = in_range<int>(IntArg{py::reinterpret_borrow<py::object>(iterations)}, "viewer: iterations", 1, kMaxIterations);
               mo.gravity = o.gravity;
               o.method_options = mo;
             }
             return std::make_unique<Viewer>(model, state, std::move(stepper), o);
           }),
           py::arg("model"), py::arg("state"), py::arg("stepper"), VIEWER_OPTION_ARGS, py::arg("gravity") = py::none(),
           py::arg("substeps") = py::none(), py::arg("iterations") = py::none(),
           "Copies model and state (reset returns to them) and steps them with `stepper`, any csb.Integrator "
           "(a built-in, or a Python subclass: kept alive by the viewer). Grabbing needs a PbdStepper. The method "
           "switch (the `method` property, the m and 1-9 keys) goes through csb.methods(): it works for a "
           "PbdStepper (made from its settings), and for a built-in stepper given `substeps` and `iterations`, "
           "the settings (with its dt() and `gravity`) the other methods are made with; without them, for a "
           "user's own method, it is off. width, height: pixels. offscreen: EGL, no window. "
           "frame_time: s of simulated time per frame (whole steps of the stepper's dt()). grab_compliance: m/N of "
           "the mouse's grab (0: kinematic). tear_max_strain: tearing after every step (0: none). gravity: m/s², "
           "for the overlay's energies when the stepper is not a PbdStepper (default (0, -9.81, 0)). "
           "csb.SimulationError (a diverging method) or csb.ParameterError (a model the method refuses) from a "
           "built-in pauses the viewer and is shown; any other exception the stepper raises passes through "
           "frame(), run() and capture().")
      .def(py::init([](const Model& model, const State& state, const PbdSettings& settings, IntArg width,
                       IntArg height, bool offscreen, const std::string& title, IntArg samples, bool vsync, bool overlay,
                       bool wireframe, bool particles, bool grid, bool paused, double frame_time,
                       double grab_compliance, double tear_max_strain, IntArg tear_max_per_step,
                       const std::string& screenshot_prefix) {
             return std::make_unique<Viewer>(model, state, settings,
                                             viewer_options(width, height, offscreen, title, samples, vsync, overlay,
                                                            wireframe, particles, grid, paused, frame_time,
                                                            grab_compliance, tear_max_strain, tear_max_per_step,
                                                            screenshot_prefix));
           }),
           py::arg("model"), py::arg("state"), py::arg("settings"), VIEWER_OPTION_ARGS,
           "The same with a PbdStepper made from `settings`.")
      .def("run", [](Viewer& v, IntArg max_frames_arg) {
        const std::int64_t max_frames = in_range<std::int64_t>(max_frames_arg, "max_frames", 0, kMaxInt64);
        // Python's signal handlers run between frames: Ctrl-C in the terminal raises
        // KeyboardInterrupt here instead of being held until the window closes.
        py::gil_scoped_release release;
        return v.run(max_frames, [] {
          py::gil_scoped_acquire acquire;
          if (PyErr_CheckSignals() != 0) throw py::error_already_set();
        });
      }, py::arg("max_frames") = 0, "Frames until the window closes (or max_frames > 0 were drawn); returns the "
                                    "frames drawn. The GIL is released during each frame; Python's signals "
                                    "(Ctrl-C: KeyboardInterrupt) are handled between frames.")
      .def("frame", [](Viewer& v) {
        py::gil_scoped_release release;
        return v.frame();
      }, "One frame: events, the simulation's advance (unless paused), drawing. False once the window closed.")
      .def("redraw", &Viewer::redraw, "Draws the current state again without stepping.")
      .def("set_before_step", [](Viewer& v, std::optional<Viewer::BeforeStep> f) { v.set_before_step(f ? *f : nullptr); },
           py::arg("before_step"),
           "before_step(stepper, model, state, fresh), called before every step (None: nothing): where a scene "
           "moves its colliders (stepper.move_collider to their poses at the step's end, state.t + dt) and attaches "
           "particles to them when `fresh` (the first step of the first stepper, or of one a reset or the method "
           "switch made). An exception it raises passes through frame(), run() and capture().")
      .def("collider_poses", [](const Viewer& v) {
        py::list out;
        for (const csb::viewer::ColliderFrame& f : v.collider_frames()) {
          py::array_t<double> r({py::ssize_t(3), py::ssize_t(3)});
          for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) r.mutable_at(i, j) = f.pose.rotation(i, j);
          out.append(py::make_tuple(r, f.pose.translation));
        }
        return out;
      }, "(rotation, translation in m) of every collider as frames draw it now: the stepper's pose at the end of "
         "its last step (PbdStepper.collider_pose), the identity (as declared) for a method that does not move "
         "colliders.")
      .def("collider_vertices", [](const Viewer& v) {
        py::list out;
        for (const csb::viewer::ColliderFrame& f : v.collider_frames()) {
          if (f.vertices.cols() == 0) {
            out.append(py::none());
            continue;
          }
          py::array_t<double> x({static_cast<py::ssize_t>(f.vertices.cols()), py::ssize_t(3)});
          std::memcpy(x.mutable_data(), f.vertices.data(), sizeof(double) * f.vertices.size());
          out.append(x);
        }
        return out;
      }, "Per collider, the vertices (V x 3, m, model frame; collider_poses() applies on top) frames draw a "
         "deforming mesh collider with now (PbdStepper.collider_vertices), None for a collider that does not "
         "deform (drawn as declared).")
      .def_property_readonly("closed", &Viewer::closed, "The window was asked to close, or close() was called.")
      .def("close", &Viewer::close, "Releases the window (or offscreen context) now; frame() then returns False.")
      .def("__enter__", [](Viewer& v) -> Viewer& { return v; }, py::return_value_policy::reference)
      .def("__exit__", [](Viewer& v, py::args) { v.close(); })
      .def("screenshot", [](Viewer& v) { return image_array(v.screenshot()); },
           "The last frame drawn as an (height, width, 3) uint8 array, top row first.")
      .def("save_png", [](Viewer& v, const std::string& path) { csb::viewer::write_png(v.screenshot(), path); },
           py::arg("path"))
      .def("capture", [](Viewer& v, IntArg frames, const std::string& directory, IntArg every,
                         const std::string& prefix, bool png, bool video, py::object progress) {
        csb::viewer::CaptureOptions o;
        if (!progress.is_none())  // called with the GIL, which capture() otherwise runs without
          o.progress = [&progress](std::int64_t done) {
            py::gil_scoped_acquire gil;
            progress(done);
          };
        o.frames = in_range<std::int64_t>(frames, "capture: frames", 1, kMaxInt64);
        o.directory = directory;
        o.every = in_range<std::int64_t>(every, "capture: every", 1, kMaxInt64);
        o.prefix = prefix;
        o.png = png;
        o.video = video;
        csb::viewer::CaptureResult r;
        {
          py::gil_scoped_release release;
          r = csb::viewer::capture(v, o);
        }
        py::dict d;
        d["images"] = r.images;
        d["video"] = r.video.empty() ? py::object(py::none()) : py::object(py::str(r.video));
        d["video_note"] = r.video_note;
        d["ms_per_frame"] = r.ms_per_frame;
        d["draw_ms_per_frame"] = r.draw_ms_per_frame;
        return d;
      }, py::kw_only(), py::arg("frames"), py::arg("directory"), py::arg("every") = 1, py::arg("prefix") = "frame",
         py::arg("png") = true, py::arg("video") = true, py::arg("progress") = py::none(),
         "Draws `frames` frames and writes every `every`-th as <directory>/<prefix>_NNNNN.png, and "
         "<prefix>.mp4 when ffmpeg is on the PATH. Returns the files and the median ms per frame. "
         "progress(frames_done), if given, is called after each frame.")
      .def("mouse_button", [](Viewer& v, IntArg button, bool pressed, double x, double y, bool shift) {
        v.mouse_button(in_range<int>(button, "mouse_button: button", 0, 2), pressed, x, y, shift);
      }, py::arg("button"), py::arg("pressed"), py::arg("x"), py::arg("y"),
           py::arg("shift") = false, "A synthetic mouse button event: button 0 left, 1 right, 2 middle; x, y in pixels.")
      .def("mouse_move", &Viewer::mouse_move, py::arg("x"), py::arg("y"))
      .def("scroll", &Viewer::scroll, py::arg("steps"))
      .def("key", [](Viewer& v, const std::string& name) { v.key(csb::viewer::key_code(name)); }, py::arg("name"),
           "A synthetic key press by name: 'space', 'period', 'right', 'escape', or a letter or digit.")
      .def_property("paused", &Viewer::paused, &Viewer::set_paused)
      .def("single_step", &Viewer::single_step)
      .def("reset", &Viewer::reset)
      .def_property("method", &Viewer::method_name,
                    [](Viewer& v, const std::string& m) { v.set_method(m); },
                    "The method's name (csb.methods()' name, or a user's method's name()). Set: any registered "
                    "method or alias ('pbd', 'xpbd', 'small-steps', 'symplectic-euler', 'backward-euler', ... see "
                    "csb.methods()), from the same state; csb.ParameterError saying why, with the method and the "
                    "state unchanged, when the method cannot step this model (hard constraints, colliders, ...) "
                    "or the switch is off (a user's own method).")
      .def_property_readonly("stepper", [](const Viewer& v) { return v.integrator_ptr(); },
                             "The Integrator being stepped (after a method switch or a reset of a PbdStepper, a new one).")
      .def_property_readonly("position_based", &Viewer::position_based,
                             "Whether the method is a PbdStepper: grabbing works only then.")
      .def_property_readonly("method_switch", &Viewer::method_switch,
                             "Whether the method switch works: the viewer knows the settings to make the methods "
                             "from (a PbdStepper's, or the substeps and iterations given with a built-in).")
      .def_property_readonly("dt", &Viewer::dt, "s, the method's step")
      .def_property_readonly("message", [](const Viewer& v) { return v.message(); },
                             "The overlay's last notice: a method switch (with what the method cannot read of the "
                             "model's material), a method that cannot step the model, a screenshot written, a "
                             "simulation error.")
      .def_property("wireframe", [](Viewer& v) { return v.draw_options().wireframe; },
                    [](Viewer& v, bool on) { v.draw_options().wireframe = on; })
      .def_property("particles", [](Viewer& v) { return v.draw_options().particles; },
                    [](Viewer& v, bool on) { v.draw_options().particles = on; })
      .def_property("grid", [](Viewer& v) { return v.draw_options().grid; },
                    [](Viewer& v, bool on) { v.draw_options().grid = on; })
      .def("set_overlay", &Viewer::set_overlay, py::arg("on"))
      .def("frame_scene", &Viewer::frame_scene)
      .def_property_readonly("camera", py::overload_cast<>(&Viewer::camera), py::return_value_policy::reference_internal)
      .def_property_readonly("model", [](const Viewer& v) { return Model(v.model()); },
                             "A copy of the model being simulated (a tear makes a new one).")
      .def_property_readonly("state", py::overload_cast<>(&Viewer::state), py::return_value_policy::reference_internal,
                             "The live state (positions and velocities as numpy views).")
      .def_property_readonly("settings", [](const Viewer& v) -> py::object {
        return v.position_based() ? py::cast(v.settings()) : py::object(py::none());
      }, "The PbdStepper's settings, or None for another method.")
      .def_property_readonly("held_particle", &Viewer::held_particle, "The particle under the mouse's grab, or -1.")
      .def_property_readonly("steps_per_frame", &Viewer::steps_per_frame)
      .def_property_readonly("stats", [](const Viewer& v) {
        const csb::viewer::Stats& s = v.stats();
        py::dict d;
        d["fps"] = s.fps;
        d["frame_ms"] = s.frame_ms;
        d["step_ms"] = s.step_ms;
        d["draw_ms"] = s.draw_ms;
        d["frames"] = s.frames;
        d["steps"] = s.steps;
        d["kinetic_energy"] = s.kinetic;
        d["gravitational_energy"] = s.gravitational;
        d["elastic_energy"] = s.elastic;
        return d;
      }, "What the overlay shows: fps, ms per frame, per step and to draw (wall clock, smoothed), energies (J).");
}
