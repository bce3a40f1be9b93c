// csb — the coloured sweep: the model's parts and interfaces as the team's tasks, each batch colour by
// colour in SIMD lanes (solver/coloured_kernels.hpp); bits independent of the thread count.
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/solver/coloured_kernels.hpp"
#include "csb/solver/team.hpp"
#include "csb/constraints/volume.hpp"
#include <cstring>
#include <sstream>

namespace csb {

using detail::str;
using namespace stepper_detail;


// ------------------------------------------------------------------------------ coloured sweep
//
// Each batch is projected colour by colour (Model's `colours`); the constraints of one
// colour share no particle, so within a colour a range of constraints is a loop whose iterations
// are independent: `omp simd` lets the compiler put one constraint in each SIMD lane (the kernels
// below are branch-free in the common case: masks instead of early returns, coefficients
// precomputed in ColouredBatches).
//
// Threads share the work by groups (see Colouring): a sweep is
//  1. the parts' interiors, each part a task: one thread projects every batch's colours of that
//     part (distance, then bending, volume, attachments; with Gauss-Seidel a bending element
//     also projects the distance constraint on its edge, just before itself, see
//     build_coloured), no barrier between colours;
//  2. the interfaces (constraints between parts i and i + 1), each a task, in the model's
//     interface phases, whose interfaces share no particle (one phase for a cloth);
//  3. the rest, colour by colour, threads sharing ranges of a colour (`kChunk`) with a barrier
//     after each (constraints across non-adjacent parts; usually none).
// Balloons, the constraint families (tethers, ...) and contacts follow on one thread, in order.
// The tasks of one phase share no particle, and threads take them dynamically, so a thread
// slowed by a busy core takes fewer. A cloth's sweep thus has two barriers where colour by
// colour it had one per colour, 26; and a part's particles stay in the core's cache while all of
// its colours are projected.
//
// Every constraint is computed by the same instructions whatever the thread count or the range
// it falls in (IEEE +, -, *, / and sqrt give the same bits in a SIMD lane and in a scalar
// register; no FMA contraction), every task runs its colours in a fixed order, and no two tasks
// of a phase touch the same particle, so the result does not depend on the number of threads.
// A serial colour (constraints that may share particles) is projected in its order. Jacobi reads
// the sweep's start and adds each correction to the particle's sum: each particle receives its
// corrections in a fixed order (no atomics on floats).
//
// Kernels read positions from r and apply corrections to o: Gauss-Seidel r = o = p, Jacobi
// r = the positions at the sweep's start, o = the correction sums.


namespace {

using namespace coloured_kernels;

// Constraints per dynamically scheduled range: a few microseconds of work, so that taking a
// range costs little beside it; fixed, so that ranges do not depend on the thread count.
constexpr Index kChunkDistance = 256, kChunkFour = 64, kChunkAttachment = 256;

// Runs `kernel(begin, end, independent)` over the colours of group g of `colours`, in order,
// on the calling thread.
template <class Kernel>
void group_colours(const Colouring& colours, Index g, Kernel&& kernel) {
  for (Index k = colours.group_colours[g]; k < colours.group_colours[g + 1]; ++k)
    kernel(colours.colour_offsets[k], colours.colour_offsets[k + 1], !colours.serial(k));
}

// One thread's view of the team during a projection: every thread makes the same calls in the
// same order (the phases are counted alike on each).
struct Share {
  Team& team;
  int t;                   // this thread
  std::int64_t phase = 0;  // phases begun

  // Tasks 0 .. count - 1 shared dynamically, then a barrier. The tasks are cut into one range per
  // thread (up to Team::kRanges), each with its own counter: a thread takes the tasks of its own
  // range first, then those left in the others'. So a part stays on one core from sweep to sweep
  // (its particles and constraints in that core's cache: 2-5 % of a 64x64 frame), and a thread
  // slowed by a busy core still leaves its tasks to the others.
  template <class F>
  void tasks(Index count, F&& f) {
    if (count <= 0) return;
    const int ranges = std::min(team.size(), Team::kRanges);
    for (int i = 0; i < ranges; ++i) {
      const int r = (t + i) % ranges;
      const Index begin = static_cast<Index>(static_cast<std::int64_t>(count) * r / ranges);
      const Index end = static_cast<Index>(static_cast<std::int64_t>(count) * (r + 1) / ranges);
      for (int k; (k = team.take(phase, r)) < end - begin;) f(begin + static_cast<Index>(k));
    }
    team.barrier();
    if (t == 0) team.reset(phase);
    ++phase;
  }
  // f on thread 0 only, then a barrier.
  template <class F>
  void single(F&& f) {
    if (t == 0) f();
    team.barrier();
  }
  // f(begin, end) on this thread's share of [0, n) (fixed ranges), then a barrier.
  template <class F>
  void split(Index n, F&& f) {
    const int threads = team.size();
    f(static_cast<Index>(static_cast<std::int64_t>(n) * t / threads),
      static_cast<Index>(static_cast<std::int64_t>(n) * (t + 1) / threads));
    team.barrier();
  }
};

// Runs `kernel(begin, end, independent)` over the colours of group g, in order, the team sharing
// ranges of `chunk` constraints of a colour (a serial colour on one thread); a barrier after each.
template <class Kernel>
void shared_colours(Share& share, const Colouring& colours, Index g, Index chunk, Kernel&& kernel) {
  for (Index k = colours.group_colours[g]; k < colours.group_colours[g + 1]; ++k) {
    const Index begin = colours.colour_offsets[k], end = colours.colour_offsets[k + 1];
    if (colours.serial(k))
      share.single([&] { kernel(begin, end, false); });
    else
      share.tasks((end - begin + chunk - 1) / chunk,
                  [&](Index r) { kernel(begin + r * chunk, std::min(end, begin + (r + 1) * chunk), true); });
  }
}

// One coloured sweep over distance, bending, volume and attachment constraints.
// d, bend: the distance and bending batches in the solver's scalar S (cb's own, or the
// single-precision step's, which has no volumes or attachments); cb: their colourings.
// start(g): called at the start of group g's task (a part's interior or an interface).
// relax: XPBD with averaged Jacobi (else null), see PbdStepper::set_relaxation.
// first: the sub-step's first sweep, whose XPBD distance and bending multipliers are +0: their
// kernels write them without reading them, so they need not be set to zero before it (but for
// the relaxed Jacobi kernels, which read them).
template <Method M, bool Jacobi, class S, class Start>
void sweep_coloured(Share& share, const Model& model, ColouredBatches& cb, ColouredDistanceT<S>& d,
                    ColouredFourT<S>& bend, bool approx, bool first, const S* r, S* o, const S* x, const Real* relax,
                    Start&& start) {
  const auto distance = [&](Index begin, Index end, bool independent) {
    if constexpr (M == Method::Xpbd && Jacobi) {
      if (relax) {
        for (Index c = begin; c < end; ++c) distance_xpbd<true>(d, c, r, o, x, relax);
        return;
      }
    }
    if constexpr (M == Method::Xpbd) {
      if (independent) {
        first ? distance_xpbd_range<true>(d, begin, end, r, o, x) : distance_xpbd_range<false>(d, begin, end, r, o, x);
      } else if (first) {
        for (Index c = begin; c < end; ++c) distance_xpbd<false, S, true>(d, c, r, o, x);
      } else {
        for (Index c = begin; c < end; ++c) distance_xpbd(d, c, r, o, x);
      }
    } else if (approx) {
      if (independent) {
        distance_pbd_range<true>(d, begin, end, r, o);
      } else {
        for (Index c = begin; c < end; ++c) distance_pbd<true>(d, c, r, o);
      }
    } else {
      if (independent) {
        distance_pbd_range<false>(d, begin, end, r, o);
      } else {
        for (Index c = begin; c < end; ++c) distance_pbd<false>(d, c, r, o);
      }
    }
  };
  const auto bending = [&](Index begin, Index end, bool independent) {
    if constexpr (M == Method::Xpbd && Jacobi) {
      if (relax) {
        for (Index c = begin; c < end; ++c) bending_xpbd_relaxed(bend, c, r, o, x, relax);
        return;
      }
    }
    project_bending_range<M == Method::Xpbd>(bend, begin, end, independent, first, r, o, x);
  };
  ColouredFour& vol = cb.volume;
  const auto volume = [&](Index begin, Index end, bool) {
    if constexpr (std::is_same_v<S, Real>)
      for (Index c = begin; c < end; ++c) volume_one<M, Jacobi>(vol, c, r, o, x, relax);
  };
  ColouredAttachments& att = cb.attachments;
  const auto attachment = [&](Index begin, Index end, bool) {
    if constexpr (std::is_same_v<S, Real>)
      for (Index c = begin; c < end; ++c) attachment_one<M, Jacobi>(att, c, r, o, x, relax);
  };
  const auto group = [&](Index g) {
    start(g);
    group_colours(cb.distance_colours, g, distance);
    group_colours(model.bending.colours, g, bending);
    group_colours(model.volume.colours, g, volume);
    group_colours(model.attachments.colours, g, attachment);
  };
  const Index parts = model.num_parts;
  // 1. The interiors.
  share.tasks(parts, group);
  // 2. The interfaces, in phases whose interfaces share no particle (usually one).
  for (const std::vector<Index>& phase : model.interface_phases)
    share.tasks(static_cast<Index>(phase.size()), [&](Index k) { group(parts + phase[k]); });
  // 3. The rest, colour by colour.
  const Index rest = 2 * parts - 1;
  shared_colours(share, cb.distance_colours, rest, kChunkDistance, distance);
  shared_colours(share, model.bending.colours, rest, kChunkFour, bending);
  shared_colours(share, model.volume.colours, rest, kChunkFour, volume);
  shared_colours(share, model.attachments.colours, rest, kChunkAttachment, attachment);
}

}  // namespace


template <Method M, bool Jacobi>
void PbdStepper::project_coloured(const Model& model, const Positions& x_start, Fused* fused) {
  const Index n = model.num_particles();
  const int threads = threads_used_;
  Real* p = p_.data();
  Real* ps = Jacobi ? p_start_.data() : nullptr;
  Real* delta = Jacobi ? delta_.data() : nullptr;
  Real* count = Jacobi ? count_.data() : nullptr;
  const Real* count0 = Jacobi ? coloured_.count.data() : nullptr;
  const Real* r = Jacobi ? ps : p;
  Real* o = Jacobi ? delta : p;
  const Real* x = x_start.data();
  const Real* w = grabs_.empty() ? model.inv_mass.data() : w_.data();
  const bool contacts = !contacts_.empty() || !self_.contacts().empty();
  bool families = false;  // constraint families: projected after the coloured batches, on one thread
  for (const auto& f : model.families) families = families || f->size() > 0;
  const bool tail = model.balloons.size() > 0 || contacts || families;
  bool compliant_grabs = false;
  for (const Grab& g : grabs_) compliant_grabs = compliant_grabs || g.compliance > 0;
  set_relaxation(model);
  const Real* relax = relax_.empty() ? nullptr : relax_.data();
  const bool average = settings_.solver == Solver::Jacobi && !relax;
  const bool approx = settings_.sqrt_approximation;
  const auto& bal = model.balloons;
  const int iterations = settings_.iterations;
  bad_.assign(static_cast<std::size_t>(std::max(threads, 1)), -1);
  // A fused step of several sub-steps whose constraints all lie in parts and interfaces (no rest
  // group, no serial tail, Gauss-Seidel): part g's task of a sub-step's first sweep first
  // updates its particles from the last sub-step and predicts them (the last sub-step's
  // interfaces, the only other constraints on them, are done: a barrier ends their phase), and
  // each group's task sets its XPBD multipliers to zero; the finiteness check runs once, after
  // the last sub-step, the step's start kept to go back to. Two barriers a sub-step instead of
  // four (a cloth).
  const bool in_tasks = fused && fused->substeps > 1 && !Jacobi && !tail && !compliant_grabs && coloured_.rest_empty;
  const bool advancing = fused && fused->substeps > 1;  // a sub-step's update is followed by a prediction
  if (in_tasks) {
    x_step_.resize(3, n);
    v_step_.resize(3, n);
  }
  if (advancing) accel_.resize(3 * static_cast<std::size_t>(n));
  const Index parts = model.num_parts;
  // XPBD: group g's multipliers set to zero (but the distance and bending constraints', which the
  // first sweep writes without reading).
  const auto zero_group_multipliers = [&](Index g) {
    zero_group(model.volume.colours, g, coloured_.volume.lambda);
    zero_group(model.attachments.colours, g, coloured_.attachments.lambda);
  };
  team_.get().run(threads, spin_, [&](int t) {
    Share share{team_.get(), t};
    // (5)-(7) of Algorithm 1, and XPBD's multipliers set to zero.
    const auto predict = [&](Index begin, Index end) {
      predict_range(model, *fused->state, fused->h, begin, end);
      if constexpr (M == Method::Xpbd) zero_coloured_multipliers(t, share.team.size(), relax != nullptr);
    };
    if (in_tasks) {
      // Keep the step's start, then predict (the multipliers are zeroed by the group tasks).
      const Real* v = settings_.front_end == FrontEnd::Verlet ? x_prev_.data() : fused->state->v.data();
      share.split(n, [&](Index begin, Index end) {
        const Real* x0 = fused->state->x.data();
        std::memcpy(x_step_.data() + 3 * begin, x0 + 3 * begin, sizeof(Real) * 3 * (end - begin));
        std::memcpy(v_step_.data() + 3 * begin, v + 3 * begin, sizeof(Real) * 3 * (end - begin));
        predict_range(model, *fused->state, fused->h, begin, end);
        set_accel(model, fused->h, begin, end);
      });
    } else if (fused) {
      share.split(n, [&](Index begin, Index end) {
        predict(begin, end);
        if (advancing) set_accel(model, fused->h, begin, end);
      });
    }
    for (int sub = 0; sub < (fused ? fused->substeps : 1); ++sub) {
      for (int it = 0; it < iterations; ++it) {
        // What a group's task does before its constraints (in_tasks only).
        const bool update = in_tasks && it == 0 && sub > 0;
        const auto start = [&](Index g) {
          if (!in_tasks) return;
          if constexpr (M == Method::Xpbd)
            if (it == 0) zero_group_multipliers(g);
          if (update && g < parts) {
            for (Index k = coloured_.part_run_offsets[g]; k < coloured_.part_run_offsets[g + 1]; ++k) {
              const auto [begin, end] = coloured_.part_runs[k];
              advance(*fused->state, fused->h, begin, end);
            }
          }
        };
        if constexpr (Jacobi) {
          share.split(n, [&](Index begin, Index end) {
            for (Index i = begin; i < end; ++i) {
              for (int e = 0; e < 3; ++e) {
                ps[3 * i + e] = p[3 * i + e];
                delta[3 * i + e] = 0;
              }
              count[i] = count0[i];
            }
          });
        }
        sweep_coloured<M, Jacobi>(share, model, coloured_, coloured_.distance, coloured_.bending, approx, it == 0, r, o,
                                  x, relax, start);
        if (tail) {
          share.single([&] {
            // Balloons: one constraint over many particles each, serial (see sweep_batches).
            for (Index c = 0; c < bal.size(); ++c) {
              const Index* ids = bal.particles.data() + bal.particle_offsets[c];
              const Triangle* tris = bal.triangles.data() + bal.triangle_offsets[c];
              const Real target = bal.pressure[c] * bal.rest_volume[c];
              if constexpr (M == Method::Xpbd)
                project_balloon(r, o, nullptr, w, ids, bal.num_particles(c), tris, bal.num_triangles(c), target, 0,
                                x, a_balloon_[c], g_balloon_[c], &lambda_.balloon[c], balloon_grad_.data(),
                                relaxation(relax, ids, bal.num_particles(c)));
              else
                project_balloon(r, o, nullptr, w, ids, bal.num_particles(c), tris, bal.num_triangles(c), target,
                                k_balloon_[c], nullptr, 0, 0, nullptr, balloon_grad_.data());
            }
            // The constraint families, in the model's order (their Jacobi counts are in count0).
            if (families) project_families(model, w, r, o, nullptr, x, relax);
            if (contacts) project_contacts(model, Jacobi);
          });
        }
        if constexpr (Jacobi) {
          // Averaged Jacobi moves each particle by the mean of its corrections (XPBD: by the sum
          // of its relaxed ones), summed Jacobi by their sum.
          share.split(n, [&](Index begin, Index end) {
            for (Index i = begin; i < end; ++i) {
              const Real scale = average ? (count[i] > 0 ? 1 / count[i] : 0) : 1;
              for (int e = 0; e < 3; ++e) p[3 * i + e] = ps[3 * i + e] + scale * delta[3 * i + e];
            }
          });
          if (contacts && M != Method::Xpbd) share.single([&] { settle_contact_moves(average); });
        }
        if (compliant_grabs) share.single([&] { project_grabs(x_start); });
      }
      if (fused) {
        const bool last = sub + 1 == fused->substeps;
        if (in_tasks && !last) continue;  // updated and predicted by the part tasks
        // The new positions must all be finite before any is taken (else the state stays).
        share.split(n, [&](Index begin, Index end) { bad_[t] = first_non_finite(p_, begin, end); });
        Index bad = -1;
        for (const Index b : bad_)
          if (b >= 0) bad = bad < 0 ? b : std::min(bad, b);
        if (bad >= 0) {
          if (t == 0) fused->bad = bad, fused->bad_sub = in_tasks ? -1 : sub;
          return;
        }
        // (12)-(15) of Algorithm 1, then the next sub-step's prediction of the same particles.
        const bool next = sub + 1 < fused->substeps;
        share.split(n, [&](Index begin, Index end) {
          if (!next) {
            commit(*fused->state, fused->h, begin, end);
            return;
          }
          advance(*fused->state, fused->h, begin, end);
          if constexpr (M == Method::Xpbd) zero_coloured_multipliers(t, share.team.size(), relax != nullptr);
        });
      }
    }
  });
}


// ------------------------------------------------------------------------- single precision
//
// Precision::Single: `count` sub-steps of a step (at most kFusedSubsteps, so that a step of very
// many can be interrupted between them) in one fork of the team, in float. The state is
// rounded to float (positions, and velocities or Verlet's previous positions: each particle's x,
// y, z and a pad, kStride<float> apart, the pad its inverse mass w, 0 for velocities; h g per
// particle is the model's, set when built, its pad 0, so that every prediction and update gives
// the pads of x and p w again, w + h 0 or w + keep (w - w) + 0, and those of v 0),
// then per sub-step the prediction, `iterations` coloured Gauss-Seidel sweeps of the float
// batches (the kernels of the double sweep, instantiated for float: twice the SIMD lanes, half
// the bytes) and the update. When every constraint lies in a part or an interface (no rest
// group), part g's task of a sub-step's first sweep updates and predicts its own particles and
// each group's task zeroes its XPBD multipliers, as in the double fused step (two barriers a
// sub-step); otherwise the update and prediction are split by particle between the threads. At
// the end every new position is checked finite, and only then does the last update write the
// state, its float results widened to double (exactly, so that rounding them again for the next
// sub-steps gives the same floats). The same operations in the same order whatever the thread
// count and however a step is cut: the same bits.
template <Method M>
void PbdStepper::substeps_single(const Model& model, State& state, Real h, int first, int count) {
  const Index n = model.num_particles();
  const bool verlet = settings_.front_end == FrontEnd::Verlet;
  const int substeps = count, iterations = settings_.iterations, threads = threads_used_;
  const bool approx = settings_.sqrt_approximation;
  const float hf = static_cast<float>(h), keep = static_cast<float>(1 - settings_.verlet_drag);
  float* x = single_.x.data();
  float* v = single_.v.data();
  float* p = single_.p.data();
  float* a = single_.accel.data();
  bad_.assign(static_cast<std::size_t>(std::max(threads, 1)), -1);
  const Index parts = model.num_parts;
  // Kinematic grabs (check_single refuses compliant ones): each sub-step's predictions of the held
  // particles (w = 0 in the batches and pads while held) are put at the hand, apply_grab_targets'
  // straight line, after every thread's prediction and before the sweeps. With grabs the update
  // and prediction are split by particle (not in the parts' tasks), so that one thread can place
  // the hands between them and the sweeps.
  const bool held = !grabs_.empty();
  const bool in_tasks = coloured_.rest_empty && !held;
  const auto hold = [&](int sub) {
    const Real fraction = Real(first + sub + 1) / settings_.substeps;
    for (const Grab& g : grabs_) {
      const Vec3 at = g.at(fraction);
      for (int e = 0; e < 3; ++e) p[kStride<float> * g.particle + e] = static_cast<float>(at[e]);
    }
  };
  // (XPBD's multipliers need not be set to zero: a sub-step's first sweep writes them without
  // reading them, see sweep_coloured.)
  team_.get().run(threads, spin_, [&](int t) {
    Share share{team_.get(), t};
    share.split(n, [&](Index begin, Index end) {
      start_single(state.x.data(), verlet ? x_prev_.data() : state.v.data(), single_.w.data(), x, v, p, a, hf, keep,
                   verlet, begin, end);
    });
    if (held) share.single([&] { hold(0); });
    for (int sub = 0; sub < substeps; ++sub) {
      for (int it = 0; it < iterations; ++it) {
        // In tasks: the group's multipliers zeroed, and (after the first sub-step) the part's
        // particles updated and predicted, before its first sweep's constraints.
        const auto start = [&](Index g) {
          if (!in_tasks || it > 0) return;
          if (sub > 0 && g < parts)
            for (Index k = coloured_.part_run_offsets[g]; k < coloured_.part_run_offsets[g + 1]; ++k) {
              const auto [begin, end] = coloured_.part_runs[k];
              advance_single(x, v, p, a, hf, keep, verlet, kStride<float> * begin, kStride<float> * end);
            }
        };
        sweep_coloured<M, false>(share, model, coloured_, single_.distance, single_.bending, approx, it == 0, p, p, x,
                                 nullptr, start);
      }
      const bool last = sub + 1 == substeps;
      if (in_tasks && !last) continue;
      // (12)-(15) and the next sub-step's prediction in one pass, or (last sub-step) the check that
      // every projected position is finite, before (12)-(15) write the state.
      share.split(n, [&](Index begin, Index end) {
        if (!last) {
          advance_single(x, v, p, a, hf, keep, verlet, kStride<float> * begin, kStride<float> * end);
          return;
        }
        const Index bad = first_non_finite_single(p, begin, end);
        if (bad_[t] < 0) bad_[t] = bad;
      });
      if (held && !last) share.single([&] { hold(sub + 1); });
    }
    for (const Index b : bad_)
      if (b >= 0) return;  // every thread sees the same bad_ after the last barrier
    share.split(n, [&](Index begin, Index end) {
      finish_single(x, p, hf, verlet, state.x.data(), verlet ? x_prev_.data() : state.v.data(), begin, end);
    });
  });
  Index bad = -1;
  for (const Index b : bad_)
    if (b >= 0) bad = bad < 0 ? b : std::min(bad, b);
  if (bad >= 0) {
    if (verlet) state.v = (state.x - x_prev_) / h;
    std::ostringstream msg;
    const float* xb = p + kStride<float> * bad;
    msg << "step " << state.step << " (sub-steps " << first << "-" << first + count - 1 << ", t = " << state.t
        << " s, single precision): particle " << bad << " got a non-finite position (" << xb[0] << ", " << xb[1]
        << ", " << xb[2] << "); the state is left where sub-step " << first << " started";
    throw SimulationError(msg.str());
  }
  if constexpr (M == Method::Xpbd) lambda_stale_ = true;
}

void PbdStepper::substeps_single(const Model& model, State& state, Real h, int first, int count) {
  switch (settings_.method) {
    case Method::Pbd:
      return substeps_single<Method::Pbd>(model, state, h, first, count);
    case Method::Xpbd:
      return substeps_single<Method::Xpbd>(model, state, h, first, count);
    case Method::Jakobsen:
      return substeps_single<Method::Jakobsen>(model, state, h, first, count);
  }
}


void PbdStepper::project(const Model& model, const Positions& x_start, Fused* fused) {
  if (settings_.ordering == Ordering::Sequential) {
    project_sequential(model, x_start);
    return;
  }
  const bool jacobi = settings_.solver != Solver::GaussSeidel;
  switch (settings_.method) {
    case Method::Pbd:
      jacobi ? project_coloured<Method::Pbd, true>(model, x_start, fused)
             : project_coloured<Method::Pbd, false>(model, x_start, fused);
      break;
    case Method::Xpbd:
      jacobi ? project_coloured<Method::Xpbd, true>(model, x_start, fused)
             : project_coloured<Method::Xpbd, false>(model, x_start, fused);
      break;
    case Method::Jakobsen:
      jacobi ? project_coloured<Method::Jakobsen, true>(model, x_start, fused)
             : project_coloured<Method::Jakobsen, false>(model, x_start, fused);
      break;
  }
}

}  // namespace csb
