// Connectivity of voxel sets: which cells of a lattice touch (26-connectivity:
// sharing a face, an edge or a corner). Used to split a rigid body that a cut or a
// move has disconnected, before play (sketch) and after (solvers).
#pragma once

#include <cstdint>
#include <vector>

#include "core/math.h"

namespace physketch {

// Labels each cell with the index of its 26-connected component. Components are
// numbered 0, 1, ... in the order of their first cell in `cells` (so the labelling
// is a pure function of the input order). Duplicate cells share a label.
std::vector<std::int32_t> componentLabels26(const std::vector<Vec3i>& cells, int* componentCount = nullptr);

}  // namespace physketch
