#include "core/lattice.h"

#include <algorithm>
#include <numeric>

namespace physketch {

std::vector<std::int32_t> componentLabels26(const std::vector<Vec3i>& cells, int* componentCount) {
  const std::size_t n = cells.size();
  std::vector<std::int32_t> label(n, -1);
  // Sort indices by cell so neighbours are found by binary search (no hashing:
  // the result must not depend on hash order, and this is O(n log n)).
  std::vector<std::int32_t> order(n);
  std::iota(order.begin(), order.end(), 0);
  const auto less = [](const Vec3i& a, const Vec3i& b) {
    if (a.z() != b.z()) return a.z() < b.z();
    if (a.y() != b.y()) return a.y() < b.y();
    return a.x() < b.x();
  };
  std::stable_sort(order.begin(), order.end(), [&](std::int32_t a, std::int32_t b) { return less(cells[a], cells[b]); });
  int count = 0;
  std::vector<std::int32_t> stack;
  for (std::size_t s = 0; s < n; ++s) {
    if (label[s] >= 0) continue;
    label[s] = count;
    stack.assign(1, static_cast<std::int32_t>(s));
    while (!stack.empty()) {
      const std::int32_t i = stack.back();
      stack.pop_back();
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const Vec3i c = cells[static_cast<std::size_t>(i)] + Vec3i(dx, dy, dz);
            // Every index holding this cell (duplicates are adjacent in `order`).
            auto it = std::lower_bound(order.begin(), order.end(), c,
                                       [&](std::int32_t a, const Vec3i& key) { return less(cells[a], key); });
            for (; it != order.end() && cells[*it] == c; ++it)
              if (label[*it] < 0) {
                label[*it] = count;
                stack.push_back(*it);
              }
          }
    }
    ++count;
  }
  if (componentCount) *componentCount = count;
  return label;
}

}  // namespace physketch
