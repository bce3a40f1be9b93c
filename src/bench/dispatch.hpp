// csb — the proposal's polymorphic constraint interface, and a benchmark of it against the
// batched kernels the steppers use.
//
// The proposal gives every constraint an object with a virtual project(equality, stiffness,
// inverse_mass). The production path instead runs one plain array per constraint type
// (constraints/*.hpp, PbdStepper); this interface exists to measure what dynamic dispatch
// costs, and for constraints a user writes. Both call the same kernels in the same order, so
// they produce the same positions to the last bit.
#pragma once

#include "csb/model.hpp"

#include <memory>
#include <vector>

namespace csb {

class Constraint {
 public:
  virtual ~Constraint() = default;
  // Projects this constraint on `positions` (x, y, z per particle, in place) with stiffness k
  // in [0, 1] and the particles' inverse masses; equality = false keeps the constraint's own
  // inequality sense, if it has one. Returns the violation before the projection.
  virtual Real project(bool equality, Real stiffness, const Real* inverse_mass, Real* positions) const = 0;
};

// One object per constraint of the model, in the batches' order (distance, bending, volume,
// balloons, attachments).
std::vector<std::unique_ptr<Constraint>> polymorphic_constraints(const Model& model);

struct DispatchTiming {
  std::int64_t projections = 0;        // per timed run
  std::vector<double> batched_ns;      // ns per projection, one per repeat
  std::vector<double> virtual_ns;
  bool identical = false;              // the two final positions agree bit for bit
};

// Gauss-Seidel sweeps of Müller's projection over all constraints of the model (with the
// stiffness corrected for `sweeps` iterations), starting from `positions` (3 x N), once through
// the batched kernels and once through polymorphic_constraints(); `repeats` timed runs of each.
DispatchTiming benchmark_dispatch(const Model& model, const Positions& positions, int sweeps, int repeats);

// The baseline the coloured sweep is measured against: `sweeps` passes of a plain loop over the
// model's distance constraints in build order, one after the other, in double precision, with
// Müller's projection at stiffness 1 (p_i -= w_i/(w_i + w_j) C n, p_j += w_j/(w_i + w_j) C n),
// starting from `positions` (3 x N); ns per projection of each of `repeats` timed runs.
std::vector<double> benchmark_plain_distance(const Model& model, const Positions& positions, int sweeps, int repeats);

}  // namespace csb
