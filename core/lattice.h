// Connectivity of voxel sets: which cells of a lattice touch (26-connectivity:
// sharing a face, an edge or a corner). Used to split a rigid body that a cut or a
// move has disconnected, before play (sketch) and after (solvers).
#pragma once

#include <cstdint>
#include <vector>

#include "core/math.h"

namespace physketch {

// Labels each cell with the index of its 26-connected component. Components are
// numbered 0, 1, ... in the z, y, x order of their smallest cell (for cells of one grid:
// by their smallest linear index), so the labelling is a pure function of the set of
// cells, not of their order. Duplicate cells share a label. Dense over the bounding box
// (O(n + box)); a box too large to allocate falls back to a sorted search (O(n log n)).
std::vector<std::int32_t> componentLabels26(const std::vector<Vec3i>& cells, int* componentCount = nullptr);

// The bodies a body that lost particles becomes (docs/formats.md, "cut"; the same rule before
// play and after, in both solvers). members: its remaining particle ids, ascending; cells[k]:
// member k's cell in the body's rest lattice; design[id]: per particle id, the design piece (the
// connected part of the body when it was made) it belongs to. Design pieces still connected stay
// together as the body; every fragment of a design piece that broke becomes a body of its own;
// when no design piece is whole, the largest fragment keeps the body. Returns the body's new
// members first (ascending), then the fragments, largest first (ties: smallest first id).
std::vector<std::vector<std::int32_t>> cutPieces(const std::vector<std::int32_t>& members, const std::vector<Vec3i>& cells,
                                                 const std::vector<std::int32_t>& design);

}  // namespace physketch
