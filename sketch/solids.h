// Solids that the sketch voxelizes: brush shapes at one stamp position and the
// exact primitives. Each is a pure inside test in its local frame plus a world
// placement; a cell belongs to the solid when its centre is inside (Alg. 1).
#pragma once

#include "core/math.h"

namespace physketch::sketch {

enum class SolidShape {
  kSphere,     // radius a
  kCube,       // half extents a, a, a
  kBox,        // half extents a, b, c
  kEllipsoid,  // semi-axes a, b, c
  kCylinder,   // radius a, half length b along local z
  kCapsule,    // radius a, segment half length b along local z
  kTorus,      // major radius a, minor radius b, around local z
};

struct Solid {
  SolidShape shape = SolidShape::kSphere;
  double a = 0.0, b = 0.0, c = 0.0;  // shape parameters (m), see SolidShape
  Vec3 centre = Vec3::Zero();        // world position of the local origin (m)
  Mat3 rotation = Mat3::Identity();  // local -> world

  // True when the world point lies inside (boundary included).
  bool contains(const Vec3& world) const { return containsLocal(rotation.transpose() * (world - centre)); }
  bool containsLocal(const Vec3& p) const;
  // Radius of a sphere around `centre` that holds the whole solid (m).
  double boundingRadius() const;
  // Exact volume (m^3), for tests and lint.
  double volume() const;
  // True for every shape but the torus: a line meets a convex solid in one interval.
  bool convex() const { return shape != SolidShape::kTorus; }
};

// Rotation whose local z axis is the unit vector `axis` (x and y chosen deterministically).
Mat3 frameFromAxis(const Vec3& axis);

}  // namespace physketch::sketch
