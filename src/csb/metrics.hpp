// csb — quantities measured on a state: energies, momenta, constraint violations.
#pragma once

#include "csb/model.hpp"

namespace csb {

struct Violation {
  Index count = 0;
  Real max = 0;  // largest |violation|
  Real rms = 0;  // root mean square over the constraints of the batch
};

struct Metrics {
  Real t = 0;                      // s
  Real kinetic_energy = 0;         // J, ½ Σ m |v|²
  Real gravitational_energy = 0;   // J, -Σ m g·x (zero at the origin)
  // J, Σ C²/(2α) over the constraints with compliance α > 0; hard constraints (α = 0) store
  // no energy and show up in their violation instead.
  Real elastic_energy = 0;
  Real total_energy() const { return kinetic_energy + gravitational_energy + elastic_energy; }
  Vec3 linear_momentum = Vec3::Zero();   // kg m/s, Σ m v
  Vec3 angular_momentum = Vec3::Zero();  // kg m²/s, Σ m x × v about the origin
  Violation distance;              // m
  Violation bending;               // rad
  Violation attachment;            // m
  Violation volume;                // m³, V - V0 per tet
  Violation balloon;               // m³, V - pressure V0 per balloon
  // Per constraint family (Model::families, in its order): its name and its violations C₊
  // (max(C, 0) for a unilateral family such as tethers), in its C's unit.
  std::vector<std::pair<std::string, Violation>> families;
  Real max_strain = 0;             // max |violation| / rest length over distance constraints
  Real rms_strain = 0;
};

// Particles with inverse mass 0 are included: they are at rest unless moved by the user.
Metrics measure(const Model& model, const State& state, const Vec3& gravity);

// Σ C²/(2α) over the compliant constraints (J).
Real elastic_energy(const Model& model, const State& state);

// Violation of every distance constraint (m) and of every bending constraint (rad).
std::vector<Real> distance_violations(const Model& model, const State& state);
std::vector<Real> bending_violations(const Model& model, const State& state);
// V - V0 of every tetrahedral volume constraint (m³), V - pressure V0 of every balloon (m³), and
// the volume every balloon encloses (m³).
std::vector<Real> volume_violations(const Model& model, const State& state);
std::vector<Real> balloon_violations(const Model& model, const State& state);
std::vector<Real> balloon_volumes(const Model& model, const State& state);

}  // namespace csb
