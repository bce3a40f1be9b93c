// Your loop, your renderer: csb steps a cloth falling onto a ball, and every frame hands over what
// a renderer uploads (positions, normals, triangle indices as 32-bit floats and integers). The
// renderer here is a small software one (orthographic, z-buffered, Lambert-shaded) that writes
// the last frame as a PPM image; an OpenGL, Vulkan or engine renderer takes the same buffers.
//   own_loop [frames] [image.ppm]
#include <csb/csb.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

// What a renderer takes each frame.
struct Frame {
  std::vector<float> positions, normals;  // 3 per vertex, m and unit
  std::vector<std::uint32_t> indices;     // 3 per triangle
};

// Looks along -z from above the xz plane, tilted down by 30 degrees; light from the camera's side.
class SoftwareRenderer {
 public:
  SoftwareRenderer(int width, int height, float extent) : w_(width), h_(height), extent_(extent) {}

  void draw(const Frame& f) {
    rgb_.assign(static_cast<std::size_t>(w_) * h_ * 3, 235);
    depth_.assign(static_cast<std::size_t>(w_) * h_, 1e30f);
    const float c = std::cos(0.52f), s = std::sin(0.52f);
    const auto view = [&](const float* p) {  // camera frame: x right, y up, z towards the camera; 0.3 m up in the middle
      const float y = p[1] - 0.3f;
      return std::array<float, 3>{p[0], c * y - s * p[2], s * y + c * p[2]};
    };
    const float light[3] = {0.3f, 0.8f, 0.5f};
    for (std::size_t t = 0; t + 2 < f.indices.size(); t += 3) {
      std::array<std::array<float, 3>, 3> q;
      float shade[3];
      for (int k = 0; k < 3; ++k) {
        const std::uint32_t i = f.indices[t + k];
        q[k] = view(&f.positions[3 * i]);
        const float* n = &f.normals[3 * i];
        shade[k] = 0.25f + 0.75f * std::abs(n[0] * light[0] + n[1] * light[1] + n[2] * light[2]);  // two-sided
      }
      fill(q, shade);
    }
  }

  bool save(const std::string& path) const {
    std::FILE* out = std::fopen(path.c_str(), "wb");
    if (!out) return false;
    std::fprintf(out, "P6\n%d %d\n255\n", w_, h_);
    const bool ok = std::fwrite(rgb_.data(), 1, rgb_.size(), out) == rgb_.size();
    return std::fclose(out) == 0 && ok;
  }

 private:
  void fill(const std::array<std::array<float, 3>, 3>& q, const float shade[3]) {
    float x[3], y[3];
    for (int k = 0; k < 3; ++k) {
      x[k] = (q[k][0] / extent_ * 0.5f + 0.5f) * w_;
      y[k] = (0.5f - q[k][1] / extent_ * 0.5f * w_ / h_) * h_;
    }
    const float area = (x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0]);
    if (std::abs(area) < 1e-12f) return;
    const int x0 = std::max(0, static_cast<int>(std::min({x[0], x[1], x[2]}))),
              x1 = std::min(w_ - 1, static_cast<int>(std::max({x[0], x[1], x[2]}))),
              y0 = std::max(0, static_cast<int>(std::min({y[0], y[1], y[2]}))),
              y1 = std::min(h_ - 1, static_cast<int>(std::max({y[0], y[1], y[2]})));
    for (int py = y0; py <= y1; ++py)
      for (int px = x0; px <= x1; ++px) {
        const float fx = px + 0.5f, fy = py + 0.5f;
        const float b0 = ((x[1] - fx) * (y[2] - fy) - (x[2] - fx) * (y[1] - fy)) / area;
        const float b1 = ((x[2] - fx) * (y[0] - fy) - (x[0] - fx) * (y[2] - fy)) / area;
        const float b2 = 1 - b0 - b1;
        if (b0 < 0 || b1 < 0 || b2 < 0) continue;
        const float z = -(b0 * q[0][2] + b1 * q[1][2] + b2 * q[2][2]);  // distance from the camera
        const std::size_t at = static_cast<std::size_t>(py) * w_ + px;
        if (z >= depth_[at]) continue;
        depth_[at] = z;
        const float l = b0 * shade[0] + b1 * shade[1] + b2 * shade[2];
        rgb_[3 * at] = static_cast<std::uint8_t>(40 * l), rgb_[3 * at + 1] = static_cast<std::uint8_t>(110 * l),
        rgb_[3 * at + 2] = static_cast<std::uint8_t>(220 * l);
      }
  }

  int w_, h_;
  float extent_;
  std::vector<std::uint8_t> rgb_;
  std::vector<float> depth_;
};

int main(int argc, char** argv) try {
  const int frames = argc > 1 ? std::stoi(argv[1]) : 120;
  const std::string image = argc > 2 ? argv[2] : "own_loop.ppm";

  csb::ModelBuilder builder;
  csb::Mesh sheet = csb::cloth_grid(1.0, 1.0, 32, 32);  // the xz plane at y = 0
  sheet.vertices.row(1).array() += 0.6;                  // 0.6 m up
  csb::MeshOptions options;
  options.mass = {csb::MassSpec::Kind::Density, 0.2};  // kg/m²
  options.stretch_compliance = 1e-6;                    // m/N
  options.bending_compliance = 10.0;                    // 1/(N m)
  options.bending_stiffness = 1.0;
  builder.add_mesh(sheet, options);
  builder.add_sphere(csb::Vec3(0, 0.3, 0), 0.25, csb::ContactMaterial{0.4, 0.3, 0});
  const auto model = builder.build();

  csb::PbdSettings settings;
  settings.method = csb::Method::Xpbd;
  settings.dt = 1.0 / 60.0;  // s: one frame
  settings.substeps = 10;
  settings.iterations = 1;
  csb::PbdStepper stepper(settings);
  csb::State state = model->initial_state();

  Frame frame;
  for (const csb::Triangle& t : model->triangles)
    for (const csb::Index i : t) frame.indices.push_back(static_cast<std::uint32_t>(i));
  SoftwareRenderer renderer(480, 300, 1.6f);
  csb::Positions normals;
  for (int f = 0; f < frames; ++f) {  // your loop: input, physics, render
    stepper.step(*model, state);
    csb::vertex_normals(state.x, model->triangles, normals);
    frame.positions.assign(state.x.data(), state.x.data() + state.x.size());
    frame.normals.assign(normals.data(), normals.data() + normals.size());
    renderer.draw(frame);
  }
  if (!renderer.save(image)) throw csb::Error("cannot write " + image);
  const csb::Metrics m = csb::measure(*model, state, settings.gravity);
  std::printf("%d frames of %d vertices and %zu triangles, t = %.3f s, lowest point %.4f m, max strain %.4f; wrote %s\n",
              frames, model->num_particles(), model->triangles.size(), state.t, state.x.row(1).minCoeff(),
              m.max_strain, image.c_str());
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "own_loop: %s\n", e.what());
  return 1;
}
