#include "sketch/grid.h"

#include "core/lattice.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <new>

#include "core/error.h"

namespace physketch::sketch {

GridMapping::GridMapping(const Vec3& center, double size) : center_(center), size_(size), h_(size / kGridSize) {
  if (!(size > 0) || !std::isfinite(size) || !center.allFinite())
    throw RuntimeError("GridMapping: workspace size must be finite and > 0");
}

Vec3i GridMapping::discretize(const Vec3& world) const {
  const Vec3 g = toGrid(world);
  // floor(g + 1/2): cell k owns [k - 1/2, k + 1/2), so every point of the workspace has exactly one cell.
  return Vec3i(static_cast<int>(std::floor(g.x() + 0.5)), static_cast<int>(std::floor(g.y() + 0.5)),
               static_cast<int>(std::floor(g.z() + 0.5)));
}

bool GridMapping::contains(const Vec3& world) const {
  const Vec3 g = toGrid(world);
  const double lo = -0.5, hi = kGridSize - 0.5;
  return g.x() >= lo && g.y() >= lo && g.z() >= lo && g.x() < hi && g.y() < hi && g.z() < hi;
}

namespace {
std::int32_t* zeroCells() {
  auto* p = static_cast<std::int32_t*>(std::calloc(static_cast<std::size_t>(kGridCells), sizeof(std::int32_t)));
  if (!p) throw std::bad_alloc();
  return p;
}
}  // namespace

void OccupancyGrid::Free::operator()(std::int32_t* p) const { std::free(p); }

OccupancyGrid::OccupancyGrid() : cells_(zeroCells()) {}

OccupancyGrid::OccupancyGrid(const OccupancyGrid& other) : cells_(zeroCells()) { *this = other; }

OccupancyGrid& OccupancyGrid::operator=(const OccupancyGrid& other) {
  if (this != &other) {
    if (!cells_) cells_.reset(zeroCells());
    std::memcpy(cells_.get(), other.cells_.get(), static_cast<std::size_t>(kGridCells) * sizeof(std::int32_t));
  }
  return *this;
}

std::int64_t OccupancyGrid::occupied() const {
  std::int64_t n = 0;
  for (std::int64_t i = 0; i < kGridCells; ++i) n += cells_[static_cast<std::size_t>(i)] != 0;
  return n;
}

bool OccupancyGrid::operator==(const OccupancyGrid& other) const {
  const std::size_t bytes = static_cast<std::size_t>(kGridCells) * sizeof(std::int32_t);
  return std::memcmp(cells_.get(), other.cells_.get(), bytes) == 0;
}

std::vector<int> connectedComponents26(const std::vector<Vec3i>& cells) {
  for (const Vec3i& c : cells)
    if (!GridMapping::inGrid(c)) throw RuntimeError("connectedComponents26: a cell lies outside the grid");
  const std::vector<std::int32_t> label = componentLabels26(cells);
  return std::vector<int>(label.begin(), label.end());
}

}  // namespace physketch::sketch
