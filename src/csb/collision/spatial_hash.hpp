// csb — a spatial hash of axis-aligned boxes for the cloth self-collision broad phase (Teschner,
// Heidelberger, Müller, Pomeranets, Gross 2003, "Optimized Spatial Hashing for Collision
// Detection of Deformable Objects": cells of a uniform grid hashed into a table whose size is a
// small multiple of the number of entries, rebuilt every sub-step).
//
// Entries are stored bucket by bucket (CSR) in increasing item order, so a query visits its
// candidates in an order that depends only on the input: the contacts it yields, and therefore
// the Gauss-Seidel result, are deterministic.
//
// Work and memory stay bounded whatever the boxes: a box over more than kMaxCells cells (a
// particle flung 3e5 m away once made one sub-step 11 s and 1.5 GB, at 1e12 m the cell indices
// overflowed) is kept in a list of large items that every query visits, and a query box over
// more than kMaxCells cells visits every item: O(items) at worst, never O(cells).
#pragma once

#include "csb/types.hpp"

#include <cmath>
#include <cstdint>
#include <vector>

namespace csb {

class SpatialHash {
 public:
  // Inserts item k into every cell its box [lo[k], hi[k]] overlaps; cell is the cell edge (m).
  void build(Real cell, const std::vector<Vec3>& lo, const std::vector<Vec3>& hi);

  // Calls visit(item) for every item stored in a cell overlapping [lo, hi], then every large
  // item (a query box over more than kMaxCells cells: every item, in order); an item can be
  // visited more than once (several cells, hash collisions), the caller filters.
  template <class F>
  void query(const Vec3& lo, const Vec3& hi, F&& visit) const {
    if (!(cells(lo, hi) <= kMaxCells)) {
      for (Index t = 0; t < items_count_; ++t) visit(t);
      return;
    }
    if (!bucket_start_.empty()) {
      const auto c0 = cell_of(lo), c1 = cell_of(hi);
      for (std::int64_t i = c0[0]; i <= c1[0]; ++i)
        for (std::int64_t j = c0[1]; j <= c1[1]; ++j)
          for (std::int64_t k = c0[2]; k <= c1[2]; ++k) {
            const std::size_t b = bucket(i, j, k);
            for (Index e = bucket_start_[b]; e < bucket_start_[b + 1]; ++e) visit(items_[e]);
          }
    }
    for (const Index t : large_) visit(t);
  }

  Real cell() const { return cell_; }
  static constexpr double kMaxCells = 64;

 private:
  // Cells a box overlaps, in floating point (no overflow; NaN or infinity for a non-finite box).
  double cells(const Vec3& lo, const Vec3& hi) const {
    double n = 1;
    for (int a = 0; a < 3; ++a) n *= std::floor(hi[a] / cell_) - std::floor(lo[a] / cell_) + 1;
    return n;
  }
  std::array<std::int64_t, 3> cell_of(const Vec3& x) const {
    return {static_cast<std::int64_t>(std::floor(x[0] / cell_)), static_cast<std::int64_t>(std::floor(x[1] / cell_)),
            static_cast<std::int64_t>(std::floor(x[2] / cell_))};
  }
  // Teschner et al. 2003, §4.1: (i p1 xor j p2 xor k p3) mod n, with their three large primes.
  std::size_t bucket(std::int64_t i, std::int64_t j, std::int64_t k) const {
    const std::uint64_t h = (static_cast<std::uint64_t>(i) * 73856093u) ^ (static_cast<std::uint64_t>(j) * 19349663u) ^
                            (static_cast<std::uint64_t>(k) * 83492791u);
    return static_cast<std::size_t>(h & mask_);
  }

  Real cell_ = 1;
  std::uint64_t mask_ = 0;
  std::vector<Index> bucket_start_;  // size buckets + 1
  std::vector<Index> items_;
  std::vector<Index> large_;         // items whose box covers more than kMaxCells cells
  Index items_count_ = 0;
  std::vector<std::size_t> scratch_;  // bucket of each entry, kept to avoid reallocation
};

}  // namespace csb
