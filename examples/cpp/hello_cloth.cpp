// A cloth imported from a mesh file (or generated), two corners pinned, one second of PBD.
//   hello_cloth [mesh file]
#include <csb/csb.hpp>

#include <cstdio>
#include <exception>

int main(int argc, char** argv) try {
  const csb::Mesh mesh = argc > 1 ? csb::load_mesh(argv[1]) : csb::cloth_grid(1.0, 1.0, 32, 32);

  csb::ModelBuilder builder;
  csb::MeshOptions options;
  options.mass = {csb::MassSpec::Kind::Total, 0.2};  // kg
  options.bending_stiffness = 0.1;
  const csb::MeshInstance cloth = builder.add_mesh(mesh, options);
  // Pin the two particles nearest to the corners (-x, -z) and (+x, -z) of the bounding box.
  const csb::Vec3 lo = mesh.vertices.rowwise().minCoeff(), hi = mesh.vertices.rowwise().maxCoeff();
  for (const csb::Vec3 corner : {csb::Vec3(lo.x(), hi.y(), lo.z()), csb::Vec3(hi.x(), hi.y(), lo.z())}) {
    Eigen::Index nearest = 0;
    (mesh.vertices.colwise() - corner).colwise().squaredNorm().minCoeff(&nearest);
    builder.pin(cloth.first_particle + static_cast<csb::Index>(nearest));
  }
  const auto model = builder.build();

  csb::PbdSettings settings;
  settings.dt = 1.0 / 60.0;  // s
  settings.substeps = 10;
  settings.iterations = 2;
  csb::PbdStepper stepper(settings);
  csb::State state = model->initial_state();
  stepper.step(*model, state, 60);

  const csb::Metrics m = csb::measure(*model, state, settings.gravity);
  std::printf("%d particles, %d constraints, t = %.3f s: kinetic %.6f J, gravitational %.6f J, max strain %.4f\n",
              model->num_particles(), model->num_constraints(), state.t, m.kinetic_energy, m.gravitational_energy,
              m.max_strain);
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "hello_cloth: %s\n", e.what());
  return 1;
}
