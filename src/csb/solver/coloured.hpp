// csb — the stepper's copy of a model's constraint batches in colour order.
//
// Model::distance.colours (and the others) say in which order to project; this workspace holds
// each batch permuted into that order as plain arrays (structure of arrays), with what the
// method needs per constraint computed once: the rest value, the inverse masses of its
// particles (kinematic grabs at 0), PBD's share of the correction k w_i / Σw, XPBD's α̃ = α/h²,
// γ = α β / h and 1 / ((1 + γ) Σw + α̃). A kernel over a range of one colour then reads
// contiguous arrays and gathers only the positions, and its iterations are independent: the
// loop vectorises (SIMD lanes are constraints) and threads share a colour's ranges.
//
// Position c of a coloured batch is constraint colours.order[c] of the model's batch; XPBD
// multipliers live here in colour order and are put back in the model's order on request.
#pragma once

#include "csb/model.hpp"
#include "csb/types.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>
#include <vector>

namespace csb {

// Where particle i's coordinates start in the solver's positions: double x, y, z per particle,
// 3 apart (the state's own layout); float x, y, z and a pad, 4 apart: one 128-bit load or store a
// particle (the single-precision step keeps the particle's inverse mass in the pads of positions
// and predictions, 0 in those of velocities).
template <class S>
constexpr Index kStride = std::is_same_v<S, float> ? 4 : 3;
// The most particles the batches' offsets (kStride<float> times an index, in an Index) can address.
constexpr Index kMostColouredParticles = std::numeric_limits<Index>::max() / kStride<float>;

// S: the scalar the solver runs in, double (Real) or, with Precision::Single, float: the
// single-precision batches are the double ones rounded once (narrowed), see PbdStepper's
// single-precision step.
template <class S>
struct ColouredDistanceT {
  // Where the constraint's particles start in the solver's positions, kStride<S> times their
  // index: a kernel's load or store of a particle takes its address from the batch as it is (a
  // shift and a sign extension fewer a particle than from the index).
  std::vector<Index> i, j;
  std::vector<S> rest;               // m
  std::vector<std::int8_t> sense;
  std::vector<S> ci, cj;             // PBD, Jakobsen: k w_i/(w_i + w_j), k w_j/(w_i + w_j); XPBD: w_i, w_j
  std::vector<S> alpha, gamma, inv_den;  // XPBD: α̃, γ, 1/((1 + γ)(w_i + w_j) + α̃) (0: not projected)
  std::vector<S> lambda;             // XPBD
  bool damped = false;               // XPBD: some γ is not +0 (else the kernels skip the damping term)
  bool bilateral = false;            // every sense is 0 (the blocked kernels then read none)
};
using ColouredDistance = ColouredDistanceT<Real>;

// Bending (a, b, c, d) or tet volume (p0, p1, p2, p3).
template <class S>
struct ColouredFourT {
  std::vector<std::array<Index, 4>> q;  // the particles' offsets, kStride<S> times their indices
                                        // (as ColouredDistanceT::i)
  std::vector<S> rest;               // rad or m³
  std::vector<std::array<S, 4>> w;
  std::vector<S> k;                  // PBD, Jakobsen
  std::vector<S> alpha, gamma;       // XPBD
  std::vector<S> lambda;
  bool damped = false;               // XPBD: some γ is not +0 (else the kernels skip the damping term)
  // Bending with Gauss-Seidel (PBD and Jakobsen with the exact square root, and XPBD): the
  // distance constraint on each element's edge (a, b), when the model has one, projected by the
  // same kernel just before the bending constraint (see PbdStepper::build_coloured); empty
  // otherwise. Its rest length (m), and PBD's shares of the correction of a and of b, k w / Σw
  // (0 and 0 where the element has no distance constraint; XPBD's are w, the element's own w[0]
  // and w[1]). XPBD keeps the edge's α̃, γ, 1/((1 + γ) Σw + α̃) (0: none) and multiplier, at the
  // element's position.
  std::vector<S> pair_rest, pair_ca, pair_cb;
  std::vector<S> pair_alpha, pair_gamma, pair_inv_den, pair_lambda;
  // A coefficient every element of the batch shares (the usual case: one material): a block's
  // worth of copies (kBendingBlock) that the blocked kernels read in place of the batch's array,
  // which then stays out of the memory a sweep streams (8 B an element each in double); empty
  // when the elements differ. Kept with the arrays they copy (build_coloured, narrowed).
  std::vector<S> k_same, alpha_same, pair_alpha_same;
};

using ColouredFour = ColouredFourT<Real>;

// `copies` copies of v's value when v is not empty and its values are all alike (bit for bit),
// else empty (ColouredFourT::k_same and the others).
template <class S>
std::vector<S> same_copies(const std::vector<S>& v, Index copies) {
  if (v.empty()) return {};
  for (const S& e : v)
    if (std::memcmp(&e, &v[0], sizeof(S)) != 0) return {};
  return std::vector<S>(static_cast<std::size_t>(copies), v[0]);
}

struct ColouredAttachments {
  std::vector<Index> i;
  std::vector<std::array<Real, 3>> target;  // m
  std::vector<Real> w, k, alpha, gamma, lambda;
};

// A batch in another scalar: every coefficient rounded once (the single-precision step's batches
// from the double ones).
template <class To, class From>
ColouredDistanceT<To> narrowed(const ColouredDistanceT<From>& d) {
  const auto cast = [](const std::vector<From>& v) { return std::vector<To>(v.begin(), v.end()); };
  const auto offsets = [](const std::vector<Index>& at) {
    std::vector<Index> out(at.size());
    for (std::size_t c = 0; c < at.size(); ++c) out[c] = at[c] / kStride<From> * kStride<To>;
    return out;
  };
  return {offsets(d.i), offsets(d.j), cast(d.rest), d.sense, cast(d.ci), cast(d.cj), cast(d.alpha),
          cast(d.gamma), cast(d.inv_den), cast(d.lambda), d.damped, d.bilateral};
}
template <class To, class From>
ColouredFourT<To> narrowed(const ColouredFourT<From>& f) {
  const auto cast = [](const std::vector<From>& v) { return std::vector<To>(v.begin(), v.end()); };
  std::vector<std::array<To, 4>> w(f.w.size());
  for (std::size_t c = 0; c < w.size(); ++c)
    for (int s = 0; s < 4; ++s) w[c][s] = static_cast<To>(f.w[c][s]);
  std::vector<std::array<Index, 4>> q(f.q.size());
  for (std::size_t c = 0; c < q.size(); ++c)
    for (int s = 0; s < 4; ++s) q[c][s] = f.q[c][s] / kStride<From> * kStride<To>;
  return {std::move(q), cast(f.rest), std::move(w), cast(f.k), cast(f.alpha), cast(f.gamma), cast(f.lambda), f.damped,
          cast(f.pair_rest), cast(f.pair_ca), cast(f.pair_cb), cast(f.pair_alpha), cast(f.pair_gamma),
          cast(f.pair_inv_den), cast(f.pair_lambda), cast(f.k_same), cast(f.alpha_same), cast(f.pair_alpha_same)};
}

// Whether some damping coefficient γ is not +0 (ColouredDistance::damped, ColouredFour::damped).
inline bool any_damping(const std::vector<Real>& gamma) {
  return std::any_of(gamma.begin(), gamma.end(), [](Real g) { return g != 0 || std::signbit(g); });
}

struct ColouredBatches {
  std::uint64_t model_id = 0;        // the model they were built from
  std::vector<Index> kinematic;      // the particles held kinematically when built (w = 0)
  // The distance constraints projected on their own, and their colouring: the model's, less
  // those projected with a bending element (ColouredFour::pair_rest).
  Colouring distance_colours;
  ColouredDistance distance;
  ColouredFour bending, volume;
  ColouredAttachments attachments;
  std::vector<Real> count;           // Jacobi: projections that touch each particle in one sweep (contacts aside)
  // The particles of each part of the model (Model::part) as runs of consecutive indices: part
  // g's runs are part_runs[part_run_offsets[g] .. [g + 1]), each [first, end). A cloth grid's
  // part is one run.
  std::vector<Index> part_run_offsets;
  std::vector<std::array<Index, 2>> part_runs;
  bool rest_empty = false;           // no constraint of any batch lies in the rest group (2P - 1)
  std::size_t bytes() const;
};

}  // namespace csb
