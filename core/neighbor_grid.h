// A deterministic uniform grid for particle neighbour queries and for sorting
// particles by cell (Ihmsen et al. 2011, "A parallel SPH implementation on multi-core
// CPUs", §4: counting sort by cell index, physical reorder, reuse per step).
//
// Two index spaces:
//   id   - the index a particle had in the arrays given to build();
//   rank - its place in cell order: cells in (z, y, x) lexicographic order of their
//          integer coordinates (x fastest), and inside a cell ascending id.
// order()[rank] = id and rankOf(id) = rank. The sort is stable, so everything here is
// a pure function of the positions and cellSize: the same bits for any thread count.
//
// Why x fastest and not Morton order: the three cells x-1, x, x+1 of a row are then
// adjacent in rank order, so the 27 cells around a cell are 9 contiguous rank ranges
// ("rows"), found by direct lookup. Morton order splits them into up to 27 runs of ~8
// particles, found by search: measured on 80k and 688k jittered-lattice particles (cell
// = 2 spacings, 1 thread, AVX-512), its neighbour lists took 5.8 and 52 ms against 3.8
// and 33 ms, and its build (searches, sparse keys) 8.7 and 80 ms against 0.6 and 6.9 ms.
//
// Sizes: the sort is an LSD radix sort whose passes adapt to the key range (one plain
// counting sort for a compact box; more passes, not more memory, for a huge sparse one).
//
// Typical use by a solver (PBF, particle contacts), once per step:
//   grid.build(x, y, z, n, h);                 // h = kernel radius (+ skin) (m)
//   grid.gather(vx, vxSorted);                 // hot arrays in rank order ...
//   grid.buildNeighborLists(h, 32, lists);     // ... one neighbour structure per step,
//   ... iterate on the rank-ordered arrays with lists ...
//   grid.scatter(xSorted, x);                  // outputs back in stable id order
// A solver that keeps its arrays in last step's rank order builds from those instead
// (nearly sorted input, so the sort's scatter streams: bench_neighbor's build_ms against
// build_shuffled_ms) and composes the permutations with gather(int32) to keep stable ids.
// Ties inside a cell then follow last step's order: still deterministic and the same for
// any thread count, but a function of the history rather than of the positions alone.
//
// Sorting particles by block for MLS-MPM: buildFromCells() with the block coordinates
// the MPM computes itself (e.g. base node >> 2 for 4^3 blocks), so the block of a particle
// is exactly the one its P2G stencil uses; cells are then the blocks, cellBegin/cellEnd
// their particle ranges in rank order and cellCoord() their coordinates. (build() with
// cellSize = block size would bin by its own floating-point rule, not the MPM's.)
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/math.h"

namespace physketch {

// Fixed-width neighbour lists in rank space, for solver hot loops. Entry k < count[r]
// of row r is the rank of a neighbour of rank r; a row is ascending. Slots past
// count[r] hold r itself (a valid index to gather from; mask them by count).
struct NeighborLists {
  int width = 0;                    // W, slots per particle
  float radius = 0.0f;              // query radius (m)
  std::vector<std::int32_t> index;  // size n * W: index[r * W + k]
  std::vector<std::int32_t> count;  // size n: neighbours stored for rank r (<= W)
  // Overflow is reported, never silently dropped: overflowed particles had more than W
  // neighbours and their rows hold only the first W (in rank order, not the nearest).
  // A solver must treat overflowed > 0 as an error or rebuild with width >= maxCount.
  std::size_t overflowed = 0;
  std::int32_t maxCount = 0;        // largest true neighbour count of any particle
};

class NeighborGrid {
 public:
  // Cells are this much wider than cellSize (relative 2^-18) so that no pair the float
  // distance test accepts at radius == cellSize lies two cells apart through rounding.
  static constexpr double kBinMargin = 1.0 + 1.0 / 262144.0;
  // At most this many cells along an axis (2^21: keys fit 63 bits). Beyond it build()
  // throws: with 1 cm cells the points span more than 20 km, i.e. a particle has escaped.
  static constexpr std::int64_t kMaxAxisCells = std::int64_t(1) << 21;

  // Bins n points (SoA, metres) into cells of cellSize (m) over their bounding box and
  // sorts them. Throws RuntimeError for a non-finite coordinate (naming the lowest such
  // id), cellSize <= 0 or non-finite, n >= 2^31, or more than kMaxAxisCells cells along
  // an axis. A huge but allowed box (one far particle) costs more radix passes, not memory.
  void build(const float* x, const float* y, const float* z, std::size_t n, float cellSize);

  // Sorts n particles by the given integer cell coordinates (the MPM block sort). No
  // positions: the neighbour queries throw. Same errors for n and the axis span.
  void buildFromCells(const std::int32_t* cx, const std::int32_t* cy, const std::int32_t* cz, std::size_t n);

  std::size_t size() const { return order_.size(); }
  bool hasPositions() const { return hasPositions_; }
  float cellSize() const { return cellSize_; }
  // Cell (i, j, k) of build() covers origin + [i, i+1) * binWidth on x (same on y, z).
  double binWidth() const { return binWidth_; }
  const Vec3& origin() const { return origin_; }

  // The permutation: order()[rank] = id; rankOf(id) is its inverse.
  const std::vector<std::int32_t>& order() const { return order_; }
  const std::vector<std::int32_t>& ranks() const { return rank_; }
  std::int32_t rankOf(std::int32_t id) const { return rank_[static_cast<std::size_t>(id)]; }

  // Non-empty cells, in rank order: cell c holds ranks [cellBegin(c), cellEnd(c)).
  std::size_t cellCount() const { return cellStart_.empty() ? 0 : cellStart_.size() - 1; }
  std::int32_t cellBegin(std::size_t c) const { return cellStart_[c]; }
  std::int32_t cellEnd(std::size_t c) const { return cellStart_[c + 1]; }
  const std::vector<std::int32_t>& cellStarts() const { return cellStart_; }
  // Integer coordinates of cell c (build: relative to origin(); buildFromCells: as given).
  Vec3i cellCoord(std::size_t c) const;
  std::int32_t cellOfRank(std::int32_t rank) const { return cellOfRank_[static_cast<std::size_t>(rank)]; }
  std::int32_t cellOf(std::int32_t id) const { return cellOfRank(rankOf(id)); }
  // Radix passes the last build took (1 = a single counting sort); for tests and benches.
  int sortPasses() const { return sortPasses_; }

  // Positions in rank order (build() only): sortedX()[rank] = x[order()[rank]].
  const float* sortedX() const { return xs_.data(); }
  const float* sortedY() const { return ys_.data(); }
  const float* sortedZ() const { return zs_.data(); }

  // byRank[r] = byId[order()[r]] and its inverse byId[order()[r]] = byRank[r]; size() each.
  void gather(const float* byId, float* byRank) const;
  void gather(const double* byId, double* byRank) const;
  void gather(const std::int32_t* byId, std::int32_t* byRank) const;
  void scatter(const float* byRank, float* byId) const;
  void scatter(const double* byRank, double* byId) const;
  void scatter(const std::int32_t* byRank, std::int32_t* byId) const;

  // Calls f(jId) for every particle j != id with |x_j - x_i| <= radius, in ascending rank
  // of j. The test is done in float exactly as ((dx*dx + dy*dy) + dz*dz) <= radius*radius
  // with dx = x_j - x_i. Needs 0 < radius <= cellSize with radius^2 a normal float.
  template <class F>
  void forEachNeighbor(std::int32_t id, float radius, F&& f) const;

  // Which inner loop buildNeighborLists runs: the SIMD ones do the same exactly rounded
  // float operations in the same order as the scalar one, so all give the same lists (a
  // test holds them to it); kAuto takes the widest the CPU has. No -march flag needed.
  enum class Kernel { kAuto, kScalar, kAvx2, kAvx512 };
  static bool cpuHas(Kernel kernel);

  // Fills `out` (its buffers are reused) with the neighbours of every particle within
  // radius (same test and limits as forEachNeighbor), `width` slots each (width >= 1).
  // Runs in parallel over fixed blocks of cells; the same lists for any thread count.
  // Throws RuntimeError for a kernel the CPU does not have.
  void buildNeighborLists(float radius, int width, NeighborLists& out, Kernel kernel = Kernel::kAuto) const;

  // Bytes its arrays hold (capacity), scratch included.
  std::size_t heldBytes() const;

 private:
  void setKeySpace(const std::int64_t lo[3], const std::int64_t hi[3]);
  void sortKeys(const float* x, const float* y, const float* z);
  void findCells();
  void buildRows();
  void checkQuery(float radius) const;
  const std::int32_t* rowsOfRank(std::int32_t rank) const {
    return &rows_[18 * static_cast<std::size_t>(cellOfRank_[static_cast<std::size_t>(rank)])];
  }

  bool hasPositions_ = false;
  float cellSize_ = 0.0f;
  double binWidth_ = 0.0;
  Vec3 origin_ = Vec3::Zero();
  std::int64_t cellOffset_[3] = {0, 0, 0};  // cell coordinate of key digit 1 (0 is padding)
  std::uint64_t dimX_ = 0, dimXY_ = 0;      // key = kx + dimX * ky + dimXY * kz
  std::uint64_t maxKey_ = 0;                // largest key of the padded box
  int sortPasses_ = 0;

  std::vector<std::int32_t> order_, rank_;
  std::vector<std::int32_t> cellStart_;     // cellCount() + 1 entries
  std::vector<std::uint64_t> cellKey_;      // key of each non-empty cell, ascending
  std::vector<std::int32_t> cellOfRank_;
  std::vector<float> xs_, ys_, zs_;         // positions in rank order (m)
  // For each cell, 9 rank ranges [begin, end): the rows (dy, dz) in {-1,0,1}^2, each
  // covering cells x-1..x+1, in ascending key order. 18 entries per cell.
  std::vector<std::int32_t> rows_;
  // Scratch kept between builds (a solver builds every step; fresh pages cost ~2 us each).
  std::vector<std::uint64_t> keys_, keysTmp_;  // cell key per particle, then per rank
  std::vector<std::int32_t> idsTmp_;
  std::vector<std::uint32_t> hist_;            // radix histograms, one per chunk
  std::vector<std::uint32_t> keyStart_;        // first rank of each digit of the last pass
};

template <class F>
void NeighborGrid::forEachNeighbor(std::int32_t id, float radius, F&& f) const {
  checkQuery(radius);
  if (id < 0 || static_cast<std::size_t>(id) >= size())
    throw RuntimeError("NeighborGrid::forEachNeighbor: particle id " + std::to_string(id) + " out of range");
  const std::int32_t i = rankOf(id);
  const float xi = xs_[i], yi = ys_[i], zi = zs_[i];
  const float r2 = radius * radius;
  const std::int32_t* row = rowsOfRank(i);
  for (int k = 0; k < 9; ++k)
    for (std::int32_t j = row[2 * k]; j < row[2 * k + 1]; ++j) {
      const float dx = xs_[j] - xi, dy = ys_[j] - yi, dz = zs_[j] - zi;
      if ((dx * dx + dy * dy) + dz * dz <= r2 && j != i) f(order_[j]);
    }
}

}  // namespace physketch
