#include "sketch/grid.h"

#include <cmath>

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

}  // namespace physketch::sketch
