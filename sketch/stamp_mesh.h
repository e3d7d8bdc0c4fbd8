// Mesh stamps: a closed, manifold triangle mesh voxelized into the sketch grid.
// The CGAL bridge: CGAL appears only in stamp_mesh.cpp (its headers cost seconds
// and over a GB of compiler memory per translation unit).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "core/math.h"
#include "sketch/grid.h"

namespace physketch::sketch {

class StampMesh {
 public:
  // Reads OBJ, OFF or PLY (by extension). Throws InputError(path, 0, "", reason) when
  // the file is missing or unreadable, has an unknown extension, holds no faces or a
  // non-finite coordinate, is not manifold, or is not closed (naming how many border
  // edges), or has more than kMaxFaces faces.
  static StampMesh load(const std::string& path);

  static constexpr std::size_t kMaxFaces = 5'000'000;

  std::size_t vertexCount() const;
  std::size_t faceCount() const;  // triangles
  double volume() const;          // enclosed volume, file units^3

  StampMesh(StampMesh&&) noexcept;
  StampMesh& operator=(StampMesh&&) noexcept;
  ~StampMesh();

  // Cells whose centres lie inside (or on) the mesh placed by
  // world = rotation * (scale * p) + translation, in z, y, x order.
  std::vector<Vec3i> voxelize(const GridMapping& mapping, double scale, const Mat3& rotation,
                              const Vec3& translation) const;

 private:
  struct Impl;
  explicit StampMesh(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace physketch::sketch
