// csb._core: the SUNDIALS reference and its spring network.
#include "bindings.hpp"

namespace csb::python {

void bind_reference(py::module_& m) {
  // ---------------------------------------------------------------- reference
  const auto reference_settings = [](py::handle gravity, double rtol, double atol, double damping, double drag,
                                     int max_order, bool stald, const std::string& linear, long long max_steps,
                                     double max_wall_time) {
    ReferenceSettings s;
    s.gravity = to_vec3(gravity, "gravity");
    s.rtol = rtol;
    s.atol = atol;
    s.damping = damping;
    s.drag = drag;
    s.max_order = max_order;
    s.stability_limit_detection = stald;
    if (linear == "auto")
      s.linear_solver = ReferenceSettings::Linear::Automatic;
    else if (linear == "klu")
      s.linear_solver = ReferenceSettings::Linear::Klu;
    else if (linear == "gmres")
      s.linear_solver = ReferenceSettings::Linear::Gmres;
    else
      throw InvalidArgument("linear_solver must be 'auto', 'klu' or 'gmres', got '" + linear + "'");
    s.max_steps = max_steps;
    s.max_wall_time = max_wall_time;
    return s;
  };

  m.def("_integrate_reference", [reference_settings](const Model& model, const State& start, std::vector<double> times,
                                                     py::handle gravity, double rtol, double atol, double damping,
                                                     double drag, IntArg max_order, bool stald, const std::string& linear,
                                                     IntArg max_steps, double max_wall_time) {
    const int order = in_range<int>(max_order, "max_order", 1, 5);
    const long long steps = in_range<long long>(max_steps, "max_steps", 1, kMaxInt64);
    const ReferenceSettings s =
        reference_settings(gravity, rtol, atol, damping, drag, order, stald, linear, steps, max_wall_time);
    ReferenceResult r;
    {
      py::gil_scoped_release release;
      r = integrate_reference(model, start, times, s);
    }
    const py::ssize_t T = static_cast<py::ssize_t>(r.times.size()), N = model.num_particles();
    py::array_t<double> x({T, N, py::ssize_t(3)}), v({T, N, py::ssize_t(3)});
    for (py::ssize_t k = 0; k < T; ++k) {
      std::memcpy(x.mutable_data(k), r.x[k].data(), sizeof(double) * 3 * N);
      std::memcpy(v.mutable_data(k), r.v[k].data(), sizeof(double) * 3 * N);
    }
    py::dict stats;
    stats["steps"] = r.stats.steps;
    stats["rhs_evals"] = r.stats.rhs_evals;
    stats["newton_iters"] = r.stats.newton_iters;
    stats["newton_failures"] = r.stats.newton_failures;
    stats["error_test_failures"] = r.stats.error_test_failures;
    stats["jacobian_evals"] = r.stats.jacobian_evals;
    stats["linear_iters"] = r.stats.linear_iters;
    stats["last_order"] = r.stats.last_order;
    stats["last_step"] = r.stats.last_step;
    stats["wall_time"] = r.stats.wall_time;
    stats["linear_solver"] = r.stats.linear_solver;
    return py::make_tuple(py::array_t<double>(T, r.times.data()), x, v, stats);
  }, py::arg("model"), py::arg("start"), py::arg("times"), py::arg("gravity"), py::arg("rtol"), py::arg("atol"),
     py::arg("damping"), py::arg("drag"), py::arg("max_order"), py::arg("stability_limit_detection"), py::arg("linear_solver"),
     py::arg("max_steps"), py::arg("max_wall_time"));

  py::class_<SpringNetwork>(m, "SpringNetwork",
      "The reference's first-order system y' = f(y), y = [x; v] of the dynamic particles: for tests and studies.")
      .def(py::init([reference_settings](const Model& model, const State& start, py::handle gravity, double damping,
                                         double drag) {
             return SpringNetwork(model, start,
                                  reference_settings(gravity, 1e-8, 1e-10, damping, drag, 5, false, "auto", 1, 0.0));
           }),
           py::arg("model"), py::arg("start"), py::kw_only(), py::arg("gravity") = std::vector<double>{0, -9.81, 0},
           py::arg("damping") = 0.0, py::arg("drag") = 0.0)
      .def_property_readonly("size", &SpringNetwork::size)
      .def_property_readonly("num_dynamic", &SpringNetwork::num_dynamic)
      .def_property_readonly("has_analytic_jacobian", &SpringNetwork::has_analytic_jacobian)
      .def("pack", [](const SpringNetwork& net, const State& state) {
        py::array_t<double> y(static_cast<py::ssize_t>(net.size()));
        net.pack(state, y.mutable_data());
        return y;
      }, py::arg("state"), "y = [x; v] of the dynamic particles")
      .def("rhs", [](const SpringNetwork& net, py::array_t<double, py::array::c_style | py::array::forcecast> y) {
        if (y.ndim() != 1 || static_cast<std::size_t>(y.shape(0)) != net.size())
          throw InvalidArgument("y must have shape (" + std::to_string(net.size()) + ",)");
        py::array_t<double> out(static_cast<py::ssize_t>(net.size()));
        net.rhs(y.data(), out.mutable_data());
        return out;
      }, py::arg("y"))
      .def("jacobian", [](const SpringNetwork& net, py::array_t<double, py::array::c_style | py::array::forcecast> y) {
        if (y.ndim() != 1 || static_cast<std::size_t>(y.shape(0)) != net.size())
          throw InvalidArgument("y must have shape (" + std::to_string(net.size()) + ",)");
        const auto& cs = net.jacobian_column_starts();
        const auto& ri = net.jacobian_row_indices();
        py::array_t<double> values(static_cast<py::ssize_t>(ri.size()));
        net.jacobian(y.data(), values.mutable_data());
        return py::make_tuple(py::array_t<std::int64_t>(static_cast<py::ssize_t>(cs.size()), cs.data()),
                              py::array_t<std::int64_t>(static_cast<py::ssize_t>(ri.size()), ri.data()), values);
      }, py::arg("y"),
         "(indptr, indices, data) of ∂f/∂y in compressed sparse columns (scipy.sparse.csc_matrix order); "
         "with bending, only the spring and attachment part");

}

}  // namespace csb::python
