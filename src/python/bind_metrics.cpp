// csb._core: measurements of a state (energies, violations, volumes).
#include "bindings.hpp"

namespace csb::python {

void bind_metrics(py::module_& m) {
  // ---------------------------------------------------------------- metrics
  m.def("measure", [](const Model& model, const State& state, py::handle gravity) {
    const Metrics r = measure(model, state, to_vec3(gravity, "gravity"));
    py::dict d;
    d["t"] = r.t;
    d["kinetic_energy"] = r.kinetic_energy;
    d["gravitational_energy"] = r.gravitational_energy;
    d["elastic_energy"] = r.elastic_energy;
    d["total_energy"] = r.total_energy();
    d["linear_momentum"] = vec3_array(r.linear_momentum);
    d["angular_momentum"] = vec3_array(r.angular_momentum);
    d["distance"] = violation_dict(r.distance);
    d["bending"] = violation_dict(r.bending);
    d["attachment"] = violation_dict(r.attachment);
    d["volume"] = violation_dict(r.volume);
    d["balloon"] = violation_dict(r.balloon);
    for (const auto& [name, v] : r.families) d[name.c_str()] = violation_dict(v);
    d["max_strain"] = r.max_strain;
    d["rms_strain"] = r.rms_strain;
    return d;
  }, py::arg("model"), py::arg("state"), py::arg("gravity"),
     "What a state holds, measured (gravity in m/s²; pinned particles included): t (s); kinetic_energy "
     "½ Σ m |v|², gravitational_energy -Σ m g·x (zero at the origin), elastic_energy Σ C²/(2α) over the "
     "constraints with compliance α > 0 (hard ones store none: see their violations), total_energy their sum "
     "(J); linear_momentum Σ m v (kg m/s) and angular_momentum Σ m x × v about the origin (kg m²/s), (3,) "
     "arrays; per batch a dict of count, max |violation| and rms: distance (m), bending (rad), attachment (m), "
     "volume (V - V0 per tet, m³), balloon (V - pressure V0, m³) and each constraint family by its name (C₊ in "
     "its C's unit); max_strain and rms_strain, |violation| / rest length over the distance constraints.");
  m.def("elastic_energy", &elastic_energy, py::arg("model"), py::arg("state"),
        "Σ C²/(2α) over the constraints with compliance α > 0, J.");
  m.def("distance_violations", [](const Model& model, const State& state) {
    std::vector<Real> v = distance_violations(model, state);
    return py::array_t<Real>(static_cast<py::ssize_t>(v.size()), v.data());
  }, py::arg("model"), py::arg("state"), "Violation |xi - xj| - rest of every distance constraint, m.");
  m.def("bending_violations", [](const Model& model, const State& state) {
    std::vector<Real> v = bending_violations(model, state);
    return py::array_t<Real>(static_cast<py::ssize_t>(v.size()), v.data());
  }, py::arg("model"), py::arg("state"), "Violation θ - θ0 of every bending constraint, rad.");
  m.def("volume_violations", [](const Model& model, const State& state) {
    std::vector<Real> v = volume_violations(model, state);
    return py::array_t<Real>(static_cast<py::ssize_t>(v.size()), v.data());
  }, py::arg("model"), py::arg("state"), "Violation V - V0 of every tetrahedral volume constraint, m³.");
  m.def("balloon_volumes", [](const Model& model, const State& state) {
    std::vector<Real> v = balloon_volumes(model, state);
    return py::array_t<Real>(static_cast<py::ssize_t>(v.size()), v.data());
  }, py::arg("model"), py::arg("state"), "Volume enclosed by every balloon's surface, m³.");

}

}  // namespace csb::python
