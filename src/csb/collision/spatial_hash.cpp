#include "csb/collision/spatial_hash.hpp"

#include <algorithm>

namespace csb {

void SpatialHash::build(Real cell, const std::vector<Vec3>& lo, const std::vector<Vec3>& hi) {
  cell_ = cell;
  const std::size_t n = lo.size();
  items_count_ = static_cast<Index>(n);
  large_.clear();
  std::vector<std::uint8_t> large(n, 0);
  for (std::size_t t = 0; t < n; ++t)
    if (!(cells(lo[t], hi[t]) <= kMaxCells)) large[t] = 1, large_.push_back(static_cast<Index>(t));
  // Count the entries first, to size the table (a power of two, at least twice the entries).
  std::size_t entries = 0;
  for (std::size_t t = 0; t < n; ++t) {
    if (large[t]) continue;
    const auto c0 = cell_of(lo[t]), c1 = cell_of(hi[t]);
    entries += static_cast<std::size_t>((c1[0] - c0[0] + 1) * (c1[1] - c0[1] + 1) * (c1[2] - c0[2] + 1));
  }
  std::size_t buckets = 16;
  while (buckets < 2 * entries) buckets *= 2;
  mask_ = buckets - 1;
  bucket_start_.assign(buckets + 1, 0);
  scratch_.clear();
  scratch_.reserve(entries);
  // Counting sort by bucket, items in increasing order within a bucket.
  for (std::size_t t = 0; t < n; ++t) {
    if (large[t]) continue;
    const auto c0 = cell_of(lo[t]), c1 = cell_of(hi[t]);
    for (std::int64_t i = c0[0]; i <= c1[0]; ++i)
      for (std::int64_t j = c0[1]; j <= c1[1]; ++j)
        for (std::int64_t k = c0[2]; k <= c1[2]; ++k) {
          const std::size_t b = bucket(i, j, k);
          scratch_.push_back(b);
          ++bucket_start_[b + 1];
        }
  }
  for (std::size_t b = 0; b < buckets; ++b) bucket_start_[b + 1] += bucket_start_[b];
  items_.resize(entries);
  std::vector<Index> cursor(bucket_start_.begin(), bucket_start_.end() - 1);
  std::size_t e = 0;
  for (std::size_t t = 0; t < n; ++t) {
    if (large[t]) continue;
    const auto c0 = cell_of(lo[t]), c1 = cell_of(hi[t]);
    const std::size_t count = static_cast<std::size_t>((c1[0] - c0[0] + 1) * (c1[1] - c0[1] + 1) * (c1[2] - c0[2] + 1));
    for (std::size_t m = 0; m < count; ++m) items_[cursor[scratch_[e++]]++] = static_cast<Index>(t);
  }
}

}  // namespace csb
