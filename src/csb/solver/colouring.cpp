// csb — graph colouring of the constraint batches and the model's parts: first-fit colours per
// batch, grouped by part (parts' interiors, then the interfaces between them, in phases), built
// with the Model (ModelBuilder::build, tear) for the coloured sweep and its thread team.
#include "csb/model.hpp"

#include <algorithm>
#include <cstdint>
#include <vector>

namespace csb {

namespace {

// First-fit colouring of the constraints `members` (increasing) of a batch, appended to `out`
// as one group. `used` (one mask per particle, all zero) is left all zero.
void colour_group(const Index* particles, int arity, const std::vector<Index>& members, Index min_colour_size,
                  std::vector<std::uint64_t>& used, Colouring& out) {
  static_assert(kMaxColours <= 64, "one bit per colour in a 64-bit mask");
  std::vector<Index> colour(members.size());
  std::vector<Index> size(kMaxColours + 1, 0);  // the last one: no free colour
  for (std::size_t m = 0; m < members.size(); ++m) {
    const Index* q = particles + static_cast<std::size_t>(arity) * members[m];
    std::uint64_t taken = 0;
    for (int k = 0; k < arity; ++k) taken |= used[q[k]];
    Index k = kMaxColours;
    if (~taken != 0) k = static_cast<Index>(__builtin_ctzll(~taken));
    if (k < kMaxColours)
      for (int a = 0; a < arity; ++a) used[q[a]] |= std::uint64_t(1) << k;
    colour[m] = k;
    ++size[k];
  }
  for (const Index c : members)
    for (int a = 0; a < arity; ++a) used[particles[static_cast<std::size_t>(arity) * c + a]] = 0;
  // Colours too small to be worth a pass of their own join the serial colour.
  std::vector<Index> slot(kMaxColours + 1, -1);  // colour -> position in the group
  Index kept = 0;
  for (Index k = 0; k < kMaxColours; ++k)
    if (size[k] >= min_colour_size) slot[k] = kept++;
  bool serial = false;
  for (Index k = 0; k <= kMaxColours; ++k)
    if (size[k] > 0 && slot[k] < 0) {
      slot[k] = kept;
      serial = true;
    }
  const Index colours = kept + (serial ? 1 : 0);
  const Index first = out.num_colours(), start = out.colour_offsets.back();
  std::vector<Index> sizes(static_cast<std::size_t>(colours), 0);
  for (Index k = 0; k <= kMaxColours; ++k)
    if (size[k] > 0) sizes[slot[k]] += size[k];
  std::vector<Index> cursor(static_cast<std::size_t>(colours));
  for (Index k = 0, at = start; k < colours; ++k) {
    cursor[k] = at;
    at += sizes[k];
    out.colour_offsets.push_back(at);
    out.serial_colours.push_back(serial && k == colours - 1 ? 1 : 0);
  }
  out.order.resize(static_cast<std::size_t>(start) + members.size());
  for (std::size_t m = 0; m < members.size(); ++m) out.order[cursor[slot[colour[m]]]++] = members[m];
  // A colour's constraints share no particle: their order changes no result, and index order
  // keeps the sweep's memory access increasing. The serial colour keeps the members' order.
  for (Index k = 0; k < colours; ++k)
    if (!out.serial_colours[first + k])
      std::sort(out.order.begin() + out.colour_offsets[first + k], out.order.begin() + out.colour_offsets[first + k + 1]);
  out.group_colours.push_back(first + colours);
}

}  // namespace

Colouring colour_constraints(const Index* particles, int arity, Index count, Index num_particles,
                             Index min_colour_size) {
  std::vector<std::uint64_t> used(static_cast<std::size_t>(num_particles), 0);  // colours at each particle
  std::vector<Index> members(static_cast<std::size_t>(count));
  for (Index c = 0; c < count; ++c) members[c] = c;
  Colouring out;
  out.group_colours = {0};
  colour_group(particles, arity, members, min_colour_size, used, out);
  return out;
}

namespace {

// A split of the particles into `parts` runs of equal count, in the order of `rank`.
std::vector<Index> cut(const std::vector<Index>& rank, Index parts) {
  const Index n = static_cast<Index>(rank.size());
  std::vector<Index> part(rank.size(), 0);
  for (Index r = 0; r < n; ++r) part[rank[r]] = static_cast<Index>((static_cast<std::int64_t>(r) * parts) / n);
  return part;
}

// Group of constraint c of a batch (see Colouring): its part's interior, an interface, the rest.
inline Index group_of(const Index* q, int arity, const std::vector<Index>& part, Index parts) {
  Index lo = part[q[0]], hi = part[q[0]];
  for (int a = 1; a < arity; ++a) {
    lo = std::min(lo, part[q[a]]);
    hi = std::max(hi, part[q[a]]);
  }
  return lo == hi ? lo : hi == lo + 1 ? parts + lo : 2 * parts - 1;
}

// The model's parts. Candidates: runs of consecutive particle indices (contiguous in memory: a
// part's positions share no cache line with another's but at its ends), and slabs along each
// axis of the rest positions (ranked by the coordinate, ties by index). The one with the fewest
// constraints outside the interiors wins (a constraint of the rest group counts 8: its colours
// are shared with barriers); ties go to the earlier candidate.
std::vector<Index> choose_parts(const Model& m, Index parts) {
  const Index n = m.num_particles();
  if (parts <= 1) return std::vector<Index>(static_cast<std::size_t>(n), 0);
  std::vector<Index> rank(static_cast<std::size_t>(n));
  for (Index i = 0; i < n; ++i) rank[i] = i;
  std::vector<Index> best = cut(rank, parts);
  const auto cost = [&](const std::vector<Index>& part) {
    std::int64_t c = 0;
    const auto add = [&](const Index* q, int arity, Index count) {
      for (Index k = 0; k < count; ++k) {
        const Index g = group_of(q + static_cast<std::size_t>(arity) * k, arity, part, parts);
        c += g < parts ? 0 : g < 2 * parts - 1 ? 1 : 8;
      }
    };
    if (m.distance.size()) add(m.distance.particles[0].data(), 2, m.distance.size());
    if (m.bending.size()) add(m.bending.particles[0].data(), 4, m.bending.size());
    if (m.volume.size()) add(m.volume.particles[0].data(), 4, m.volume.size());
    return c;
  };
  std::int64_t best_cost = cost(best);
  const Real* x = m.rest_positions.data();
  for (int axis = 0; axis < 3; ++axis) {
    for (Index i = 0; i < n; ++i) rank[i] = i;
    std::stable_sort(rank.begin(), rank.end(), [&](Index a, Index b) { return x[3 * a + axis] < x[3 * b + axis]; });
    std::vector<Index> part = cut(rank, parts);
    const std::int64_t c = cost(part);
    if (c < best_cost) {
      best_cost = c;
      best = std::move(part);
    }
  }
  return best;
}

// Groups a batch's constraints by the parts their particles lie in (see Colouring) and colours
// each group, in build order or, with by_particles, in the order of the constraints' particle
// tuples (then of their index).
Colouring colour_by_parts(const Index* particles, int arity, Index count, const std::vector<Index>& part,
                          Index parts, std::vector<std::uint64_t>& used, bool by_particles = false) {
  std::vector<std::vector<Index>> members(static_cast<std::size_t>(2 * parts));
  for (Index c = 0; c < count; ++c)
    members[group_of(particles + static_cast<std::size_t>(arity) * c, arity, part, parts)].push_back(c);
  if (by_particles)
    for (auto& g : members)
      std::stable_sort(g.begin(), g.end(), [&](Index a, Index b) {
        const Index* p = particles + static_cast<std::size_t>(arity) * a;
        const Index* q = particles + static_cast<std::size_t>(arity) * b;
        return std::lexicographical_compare(p, p + arity, q, q + arity);
      });
  Colouring out;
  out.group_colours = {0};
  out.order.reserve(static_cast<std::size_t>(count));
  for (std::size_t g = 0; g < members.size(); ++g) {
    // A part's or an interface's colours are swept by one thread, without barriers: any colour
    // of a few constraints is worth its SIMD blocks. A model of one part keeps kMinColourSize, so
    // that a small chain stays one serial colour in build order; the rest is shared by threads.
    const bool task = parts > 1 && static_cast<Index>(g) < 2 * parts - 1;
    colour_group(particles, arity, members[g], task ? kMinTaskColourSize : kMinColourSize, used, out);
  }
  out.colour_offsets.shrink_to_fit();
  out.serial_colours.shrink_to_fit();
  out.group_colours.shrink_to_fit();
  return out;
}

}  // namespace

void colour_batches(Model& m) {
  const Index n = m.num_particles();
  m.num_parts = std::clamp<Index>(n / kParticlesPerPart, 1, kMaxParts);
  m.part = choose_parts(m, m.num_parts);
  const std::vector<Index>& part = m.part;
  std::vector<std::uint64_t> used(static_cast<std::size_t>(n), 0);
  const Index p = m.num_parts;
  // The distance batch is coloured in particle order: a mesh's edges are built in colour order for
  // the sequential sweep (sweep_order), and its colours are those of the index order.
  m.distance.colours = colour_by_parts(m.distance.particles.empty() ? nullptr : m.distance.particles[0].data(), 2,
                                       m.distance.size(), part, p, used, true);
  m.bending.colours = colour_by_parts(m.bending.particles.empty() ? nullptr : m.bending.particles[0].data(), 4,
                                      m.bending.size(), part, p, used);
  m.volume.colours = colour_by_parts(m.volume.particles.empty() ? nullptr : m.volume.particles[0].data(), 4,
                                     m.volume.size(), part, p, used);
  m.attachments.colours = colour_by_parts(m.attachments.particle.data(), 1, m.attachments.size(), part, p, used);
  // Interface phases: first fit over the interfaces in order, a phase taking interface i if none
  // of its interfaces touches a particle i touches (phase bits per particle, as for colours).
  std::vector<std::uint64_t>& phases_at = used;  // all zero again
  m.interface_phases.clear();
  const auto touched = [&](const Colouring& c, const Index* particles, int arity, Index i, auto&& f) {
    const Index g = p + i;
    for (Index k = c.colour_offsets[c.group_colours[g]]; k < c.colour_offsets[c.group_colours[g + 1]]; ++k)
      for (int a = 0; a < arity; ++a) f(particles[static_cast<std::size_t>(arity) * c.order[k] + a]);
  };
  const auto each_particle = [&](Index i, auto&& f) {
    if (m.distance.size()) touched(m.distance.colours, m.distance.particles[0].data(), 2, i, f);
    if (m.bending.size()) touched(m.bending.colours, m.bending.particles[0].data(), 4, i, f);
    if (m.volume.size()) touched(m.volume.colours, m.volume.particles[0].data(), 4, i, f);
    touched(m.attachments.colours, m.attachments.particle.data(), 1, i, f);
  };
  for (Index i = 0; i + 1 < p; ++i) {
    std::uint64_t busy = 0;
    each_particle(i, [&](Index q) { busy |= phases_at[q]; });
    const Index phase = static_cast<Index>(__builtin_ctzll(~busy));  // p - 1 < 64 interfaces: always free
    each_particle(i, [&](Index q) { phases_at[q] |= std::uint64_t(1) << phase; });
    if (static_cast<Index>(m.interface_phases.size()) <= phase) m.interface_phases.resize(phase + 1);
    m.interface_phases[phase].push_back(i);
  }
  std::fill(phases_at.begin(), phases_at.end(), 0);
}

}  // namespace csb
