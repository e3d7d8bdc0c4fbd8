// A scalar field sampled on the nodes of a regular grid: what a grid-based solver can hand the
// renderer (MPM's grid mass, PhyVR §4.1) without the renderer knowing the solver.
#pragma once

#include <cstddef>
#include <vector>

#include "core/math.h"

namespace physketch {

struct NodeField {
  double spacing = 0.0;          // m between nodes
  Vec3 origin = Vec3::Zero();    // m: where node (0, 0, 0) sits; node (i, j, k) is origin + spacing (i, j, k)
  Vec3i size = Vec3i::Zero();    // nodes per axis
  std::vector<float> values;     // size.x * size.y * size.z, x fastest, then y, then z

  std::size_t index(int i, int j, int k) const {
    return std::size_t(i) + std::size_t(size.x()) * (std::size_t(j) + std::size_t(size.y()) * std::size_t(k));
  }
  float at(int i, int j, int k) const { return values[index(i, j, k)]; }
};

}  // namespace physketch
