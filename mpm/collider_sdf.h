// A mesh collider as MPM sees it: a distance field on an OpenVDB narrow band in the
// collider's own frame (VR-Doh and PhyVR impose colliders on the grid through such a field).
// Closed meshes (TriangleSoup::closed) give a signed distance, negative inside
// (openvdb::tools::meshToLevelSet); open sheets, which have no inside, give the unsigned
// distance minus a half-thickness, so a sheet is a shell `thickness` thick
// (meshToUnsignedDistanceField). Both are pre-instantiated in libopenvdb (../shared/stack.md),
// and collider_sdf.cpp is the one translation unit of mpm/ that includes OpenVDB.
#pragma once

#include <memory>

#include "core/math.h"
#include "core/triangle_soup.h"

namespace physketch::mpm {

class ColliderSdf {
 public:
  // mesh: in the collider's frame, times scale (m). voxel: the field's spacing (m); thickness:
  // an open sheet's shell thickness (m). The narrow band holds about area / voxel^2 x 2 x 3
  // voxels; where that exceeds maxBandVoxels (a 100 m^2 mesh at 5 mm would need 24 M, about
  // 0.5 GB with the tree) the voxel grows until it fits: voxel() says which was used. Throws
  // RuntimeError on an empty mesh or a bad size.
  static constexpr double kMaxBandVoxels = 2e7;
  ColliderSdf(const TriangleSoup& mesh, double scale, double voxel, double thickness,
              double maxBandVoxels = kMaxBandVoxels);
  double voxel() const;
  // An open sheet's half-thickness (m): phi + halfThickness() is the distance to the sheet
  // itself; 0 for a closed mesh.
  double halfThickness() const;
  double area() const { return area_; }  // m^2, the scaled mesh's surface
  // How far outside the surface (m) sample() can still answer true: boundsMax() - the mesh's
  // largest coordinate.
  double reach() const { return reach_; }
  std::size_t bytes() const;             // what the field holds (OpenVDB's memUsage)
  ~ColliderSdf();
  ColliderSdf(ColliderSdf&&) noexcept;
  ColliderSdf& operator=(ColliderSdf&&) noexcept;

  // The distance phi (m; < 0 inside the solid or the shell) at a point of the collider's frame
  // and its gradient (the outward normal where |gradient| > 0), trilinear in the field. False
  // where the point is outside the narrow band on the outside (phi would be the band's width).
  bool sample(const Vec3& local, double& phi, Vec3& gradient) const;
  // The mesh's bounds in its frame (m), grown by the narrow band.
  const Vec3& boundsMin() const { return lo_; }
  const Vec3& boundsMax() const { return hi_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  Vec3 lo_ = Vec3::Zero(), hi_ = Vec3::Zero();
  double area_ = 0.0, reach_ = 0.0;
};

}  // namespace physketch::mpm
