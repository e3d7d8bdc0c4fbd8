#include "sketch/grid.h"

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
  std::vector<int> label(cells.size(), -1);
  if (cells.empty()) return label;
  Vec3i lo = cells.front(), hi = cells.front();
  for (const Vec3i& c : cells) {
    if (!GridMapping::inGrid(c)) throw RuntimeError("connectedComponents26: a cell lies outside the grid");
    lo = lo.cwiseMin(c), hi = hi.cwiseMax(c);
  }
  // The bounding box, one slot per cell: the first entry of `cells` there, or -1.
  // Scanning the box in z, y, x order meets the components in the order of their
  // first cells, which numbers them by their smallest linear index.
  const Vec3i n = hi - lo + Vec3i::Ones();
  auto slotOf = [&](const Vec3i& c) {
    return (std::size_t(c.z() - lo.z()) * std::size_t(n.y()) + std::size_t(c.y() - lo.y())) * std::size_t(n.x()) +
           std::size_t(c.x() - lo.x());
  };
  std::vector<std::int32_t> slot(std::size_t(n.x()) * std::size_t(n.y()) * std::size_t(n.z()), -1);
  for (std::size_t i = 0; i < cells.size(); ++i) {
    std::int32_t& s = slot[slotOf(cells[i])];
    if (s < 0) s = static_cast<std::int32_t>(i);
  }
  int next = 0;
  std::vector<std::int32_t> stack;
  for (std::size_t s = 0; s < slot.size(); ++s) {
    if (slot[s] < 0 || label[static_cast<std::size_t>(slot[s])] >= 0) continue;
    label[static_cast<std::size_t>(slot[s])] = next;
    stack.push_back(slot[s]);
    while (!stack.empty()) {  // flood fill through the 26 neighbours
      const Vec3i c = cells[static_cast<std::size_t>(stack.back())];
      stack.pop_back();
      const Vec3i a = (c - Vec3i::Ones()).cwiseMax(lo), b = (c + Vec3i::Ones()).cwiseMin(hi);
      for (int z = a.z(); z <= b.z(); ++z)
        for (int y = a.y(); y <= b.y(); ++y)
          for (int x = a.x(); x <= b.x(); ++x) {
            const std::int32_t t = slot[slotOf(Vec3i(x, y, z))];
            if (t < 0 || label[static_cast<std::size_t>(t)] >= 0) continue;
            label[static_cast<std::size_t>(t)] = next;
            stack.push_back(t);
          }
    }
    ++next;
  }
  for (std::size_t i = 0; i < cells.size(); ++i)  // duplicates take the label of the slot's first entry
    label[i] = label[static_cast<std::size_t>(slot[slotOf(cells[i])])];
  return label;
}

}  // namespace physketch::sketch
