// csb-view: opens a mesh file (any format Assimp reads) as a cloth and simulates it live, or
// renders frames of it offscreen. Scenes (TOML, tet meshes, colliders) open from Python:
// `csb view <scene>`. The program is a function of the viewer library, run by the executable of
// a C++ build (main.cpp) and by the Python package's `csb-view` command (csb._viewer.command).
#include "viewer/command.hpp"

#include "csb/io.hpp"
#include "csb/model.hpp"
#include "viewer/capture.hpp"
#include "csb/methods/registry.hpp"
#include "viewer/viewer.hpp"

#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <sstream>
#include <string>

namespace {

const char* kUsageHead = R"(usage: csb-view MESH [options]

Simulates MESH (OBJ, glTF, FBX, PLY, STL, Collada, ... : any format Assimp reads) as a cloth with
Position Based Dynamics and shows it live: drag the mesh with the left button, orbit with the
left button elsewhere, pan with the right, zoom with the wheel; space pauses, m switches method
(through every method below; 1 to 9 pick one).

options (SI units):
  --mass KG            total mass of the cloth (default 1)
  --stretch K          stretch stiffness in [0, 1] (PBD; default 1)
  --stretch-compliance A   m/N (XPBD; default 0)
  --bending K          bending stiffness in [0, 1] (PBD; default 0.1; 0: no bending)
  --bending-compliance A   1/(N m) (XPBD; default 1)
  --pin top|none|I,J,...   pin the highest vertices (within 1 % of the size), none, or these
                       vertex indices (default top)
  --no-ground          no ground plane below the mesh
  --method NAME        the method to start with (default pbd): one of the methods below
  --dt S               time step (default 1/60)
  --substeps N         sub-steps per step (default 1)
  --iterations N       constraint sweeps per sub-step (default 10)
  --size WxH           image size in pixels (default 1280x800)
  --offscreen FRAMES   draw FRAMES frames without a window (EGL) and write PNGs (and an MP4 if
                       ffmpeg is on the PATH) into --out
  --out DIR            where offscreen frames go (default csb-frames)
  --every K            offscreen: keep every K-th frame (default 1)
)";

// The usage text, with the registry's methods: a line each, its keys, its name, aliases and label.
std::string usage() {
  std::ostringstream out;
  out << kUsageHead << "\nmethods (the --method names; in the viewer the keys 1 to 9, and m through all). One that\n"
                       "cannot step the cloth says why: those that model constraints as springs need\n"
                       "--stretch-compliance > 0, some --no-ground as well.\n";
  const auto& list = csb::methods();
  for (std::size_t i = 0; i < list.size(); ++i) {
    const csb::MethodInfo& m = list[i];
    std::string names = m.name;
    for (const std::string& a : m.aliases) names += ", " + a;
    out << "  " << (i < 9 ? std::to_string(i + 1) : std::string(" ")) << "  " << names
        << std::string(names.size() < 30 ? 30 - names.size() : 1, ' ') << m.label << " (" << m.source
        << "; reads " << m.reads << ")\n";
  }
  return out.str();
}

// Thrown by fail(): the command ends with this status, having said why.
struct Exit {
  int status;
};

[[noreturn]] void fail(const std::string& message) {
  std::cerr << "csb-view: error: " << message << "\n";
  throw Exit{2};
}

double number(const std::string& option, const std::string& value) {
  try {
    std::size_t used = 0;
    const double x = std::stod(value, &used);
    if (used != value.size()) throw std::invalid_argument(value);
    return x;
  } catch (const std::exception&) {
    fail(option + " needs a number, got '" + value + "'");
  }
}

int integer(const std::string& option, const std::string& value) {
  const double x = number(option, value);
  if (x != static_cast<int>(x)) fail(option + " needs an integer, got '" + value + "'");
  return static_cast<int>(x);
}

}  // namespace

int csb::viewer::command(int argc, const char* const* argv) try {
  using namespace csb;
  std::string path, pin = "top", out = "csb-frames";
  double mass = 1, stretch = 1, stretch_compliance = 0, bending = 0.1, bending_compliance = 1;
  bool ground = true;
  PbdSettings settings;
  const MethodInfo* other_method = nullptr;  // --method that is not a position-based variant
  viewer::ViewerOptions options;
  std::int64_t offscreen_frames = 0, every = 1;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) fail(a + " needs a value");
      return argv[++i];
    };
    if (a == "-h" || a == "--help") {
      std::cout << usage();
      return 0;
    } else if (a == "--mass") mass = number(a, value());
    else if (a == "--stretch") stretch = number(a, value());
    else if (a == "--stretch-compliance") stretch_compliance = number(a, value());
    else if (a == "--bending") bending = number(a, value());
    else if (a == "--bending-compliance") bending_compliance = number(a, value());
    else if (a == "--pin") pin = value();
    else if (a == "--no-ground") ground = false;
    else if (a == "--method") {
      const std::string m = value();
      const MethodInfo* info = nullptr;
      try {
        info = &method_info(m);
      } catch (const InvalidArgument& e) {
        fail(std::string("--method: ") + e.what());
      }
      if (info->pbd && &method_info(*info->pbd) == info) {  // a variant: PbdSettings, which switching back restores
        settings.method = *info->pbd;
        if (settings.method == Method::Jakobsen) settings.front_end = FrontEnd::Verlet;
        other_method = nullptr;
      } else {  // made from the settings below when the viewer starts (Viewer::set_method)
        other_method = info;
      }
    } else if (a == "--dt") settings.dt = number(a, value());
    else if (a == "--substeps") settings.substeps = integer(a, value());
    else if (a == "--iterations") settings.iterations = integer(a, value());
    else if (a == "--size") {
      const std::string s = value();
      const auto x = s.find('x');
      if (x == std::string::npos) fail("--size needs WxH, got '" + s + "'");
      options.width = integer(a, s.substr(0, x));
      options.height = integer(a, s.substr(x + 1));
    } else if (a == "--offscreen") offscreen_frames = integer(a, value());
    else if (a == "--out") out = value();
    else if (a == "--every") every = integer(a, value());
    else if (!a.empty() && a[0] == '-') fail("unknown option " + a + " (see --help)");
    else if (path.empty()) path = a;
    else fail("one mesh file only, got '" + path + "' and '" + a + "'");
  }
  if (path.empty()) {
    std::cerr << usage();
    return 2;
  }
  try {
    MeshReport report;
    const csb::Mesh mesh = load_mesh(path, {}, &report);
    ModelBuilder b;
    MeshOptions mo;
    mo.mass.kind = MassSpec::Kind::Total;
    mo.mass.value = mass;
    mo.stretch_stiffness = stretch;
    mo.stretch_compliance = stretch_compliance;
    if (bending > 0) mo.bending_stiffness = bending;
    mo.bending_compliance = bending_compliance;
    const MeshInstance inst = b.add_mesh(mesh, mo);
    const Positions& x = mesh.vertices;
    const Vec3 lo = x.rowwise().minCoeff(), hi = x.rowwise().maxCoeff();
    const double size = (hi - lo).norm();
    if (pin == "top") {
      for (Index i = 0; i < x.cols(); ++i)
        if (x(1, i) >= hi.y() - 0.01 * size) b.pin(inst.first_particle + i);
    } else if (pin != "none") {
      std::stringstream list(pin);
      std::string item;
      while (std::getline(list, item, ',')) {
        const int i = integer("--pin", item);
        if (i < 0 || i >= x.cols())
          fail("--pin " + item + ": " + path + " has vertices 0 to " + std::to_string(x.cols() - 1));
        b.pin(inst.first_particle + i);
      }
    }
    if (ground) b.add_plane(Vec3(0, lo.y() - 0.5 * size, 0), Vec3::UnitY(), {}, "ground");
    const std::shared_ptr<const Model> built = b.build();
    const Model& model = *built;
    std::cerr << "csb-view: " << path << ": " << model.num_particles() << " particles, " << model.distance.size()
              << " distance and " << model.bending.size() << " bending constraints";
    if (report.input_vertices != model.num_particles())
      std::cerr << " (" << report.input_vertices << " vertices in the file before welding)";
    std::cerr << "\n";
    for (const std::string& w : report.warnings) std::cerr << "csb-view: warning: " << w << "\n";
    options.offscreen = offscreen_frames > 0;
    options.title = "csb - " + path;
    options.overlay = !options.offscreen;
    viewer::Viewer v(model, model.initial_state(), settings, options);
    if (other_method) {
      try {
        v.set_method(*other_method);
      } catch (const InvalidArgument& e) {
        std::string why = e.what();
        if (why.rfind("viewer: ", 0) == 0) why.erase(0, 8);
        fail("--method " + other_method->name + ": " + why);
      }
    }
    if (offscreen_frames > 0) {
      viewer::CaptureOptions co;
      co.frames = offscreen_frames;
      co.every = every;
      co.directory = out;
      const viewer::CaptureResult r = viewer::capture(v, co);
      std::cout << "wrote " << r.images.size() << " frames to " << out << " (" << r.ms_per_frame << " ms per frame)\n";
      if (!r.video.empty()) std::cout << "wrote " << r.video << "\n";
      else if (!r.video_note.empty()) std::cout << r.video_note << "\n";
    } else {
      v.run();
    }
  } catch (const Error& e) {
    fail(e.what());
  }
  return 0;
} catch (const Exit& e) {
  return e.status;
}
