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
  // points: the mesh in the collider's frame, already scaled (m). voxel: the field's spacing
  // (m); thickness: an open sheet's shell thickness (m). Throws RuntimeError on an empty mesh
  // or a bad size.
  ColliderSdf(const TriangleSoup& mesh, double scale, double voxel, double thickness);
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
};

}  // namespace physketch::mpm
