// The sketch grid of Phys-Sketch §4.1: a 151^3 occupancy grid M over a cubic
// workspace, M = -1 where empty, otherwise the index of the particle in that voxel.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "core/math.h"

namespace physketch::sketch {

constexpr int kGridSize = 151;                          // |w|, cells per axis
constexpr int kGridCenter = kGridSize / 2;              // c = 75, the centre cell index
constexpr std::int64_t kGridCells = std::int64_t(kGridSize) * kGridSize * kGridSize;
constexpr std::int32_t kMaxParticles = 688590;          // 20 % of the grid (Phys-Sketch §7)

// World <-> grid mapping (Phys-Sketch Eq. 4-5). The workspace is a cube of edge |W|
// (metres) centred at C; the grid is 151 cells of edge h = |W| / |w| centred at c = 75.
class GridMapping {
 public:
  GridMapping(const Vec3& center, double size);

  double voxelSize() const { return h_; }           // h = |W|/|w| (m); also the particle diameter
  const Vec3& center() const { return center_; }    // C (m)
  double size() const { return size_; }             // |W| (m)

  // Eq. 4: p = (Q - C) |w|/|W| + c, continuous grid coordinates.
  Vec3 toGrid(const Vec3& world) const { return (world - center_) / h_ + Vec3::Constant(kGridCenter); }
  // discretization(P): the cell whose centre is nearest; cell k owns [k - 1/2, k + 1/2).
  Vec3i discretize(const Vec3& world) const;
  // Eq. 5: Q = (p - c) |W|/|w| + C, the world position of a cell centre.
  Vec3 toWorld(const Vec3i& cell) const { return (cell.cast<double>() - Vec3::Constant(kGridCenter)) * h_ + center_; }
  // True when the world point lies inside the workspace cube, i.e. discretize() gives a cell of the grid.
  bool contains(const Vec3& world) const;
  static bool inGrid(const Vec3i& c) {
    return c.x() >= 0 && c.y() >= 0 && c.z() >= 0 && c.x() < kGridSize && c.y() < kGridSize && c.z() < kGridSize;
  }
  static std::int64_t linear(const Vec3i& c) {
    return (std::int64_t(c.z()) * kGridSize + c.y()) * kGridSize + c.x();
  }
  // The cell of a linear index (the inverse of linear()).
  static Vec3i cellOf(std::int64_t l) {
    return Vec3i(static_cast<int>(l % kGridSize), static_cast<int>(l / kGridSize % kGridSize),
                 static_cast<int>(l / (std::int64_t(kGridSize) * kGridSize)));
  }

 private:
  Vec3 center_;
  double size_;
  double h_;
};

// M: one int32 per cell (13.8 MB), -1 = empty. Stored as index + 1, so that an
// empty grid is all zero bytes: it is calloc'ed, and the system hands out zero
// pages only when they are first written, so the cells a sketch never reaches
// cost neither time nor memory.
class OccupancyGrid {
 public:
  OccupancyGrid();
  OccupancyGrid(const OccupancyGrid& other);
  OccupancyGrid& operator=(const OccupancyGrid& other);
  OccupancyGrid(OccupancyGrid&&) noexcept = default;
  OccupancyGrid& operator=(OccupancyGrid&&) noexcept = default;

  // The particle in cell c, -1 when empty.
  std::int32_t at(const Vec3i& c) const { return cells_[static_cast<std::size_t>(GridMapping::linear(c))] - 1; }
  // Puts particle p (-1: none) in cell c.
  void set(const Vec3i& c, std::int32_t p) { cells_[static_cast<std::size_t>(GridMapping::linear(c))] = p + 1; }
  // Number of occupied cells.
  std::int64_t occupied() const;
  bool operator==(const OccupancyGrid& other) const;
  bool operator!=(const OccupancyGrid& other) const { return !(*this == other); }

 private:
  struct Free {
    void operator()(std::int32_t* p) const;
  };
  std::unique_ptr<std::int32_t[], Free> cells_;
};

// The 26-connected components of a set of grid cells (two cells touch when they
// share a face, an edge or a corner). Returns one component id per entry of
// `cells`, 0, 1, 2, ... numbered in the order of each component's first cell in
// z, y, x order (its smallest GridMapping::linear index), so the labels depend on
// the set alone, not on the order of `cells`. A cell listed twice gets one id.
// Every cell must be in the grid (throws RuntimeError otherwise). Cost: one int32
// per cell of the set's bounding box (at most the 13.8 MB of M) and a scan of it.
std::vector<int> connectedComponents26(const std::vector<Vec3i>& cells);

}  // namespace physketch::sketch
