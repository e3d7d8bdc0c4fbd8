// Test helpers shared by the sketch suites.
#pragma once

#include <queue>
#include <set>
#include <vector>

#include "sketch/grid.h"

namespace physketch::sketch::testing {

// Number of 26-connected components of a set of cells.
inline int components(const std::vector<Vec3i>& cells) {
  std::set<std::int64_t> all, seen;
  for (const auto& c : cells) all.insert(GridMapping::linear(c));
  int n = 0;
  for (const auto& start : cells) {
    if (seen.count(GridMapping::linear(start))) continue;
    ++n;
    std::queue<Vec3i> q;
    q.push(start);
    seen.insert(GridMapping::linear(start));
    while (!q.empty()) {
      const Vec3i c = q.front();
      q.pop();
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const Vec3i nb = c + Vec3i(dx, dy, dz);
            const auto k = GridMapping::linear(nb);
            if (GridMapping::inGrid(nb) && all.count(k) && seen.insert(k).second) q.push(nb);
          }
    }
  }
  return n;
}

}  // namespace physketch::sketch::testing
