// A triangle soup: the plain geometry a mesh collider is made of. The sketch reads it
// (sketch::readTriangleSoup, CGAL stays in sketch/mesh_stamp.cpp) and the PBD solver
// queries it (pbd::ColliderSet, Bullet stays in pbd/mesh_collider.cpp); it lives in core
// because both modules use it and neither may include the other.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "core/math.h"

namespace physketch {

struct TriangleSoup {
  std::vector<Vec3> vertices;                          // file coordinates (the collider's units)
  std::vector<std::array<std::int32_t, 3>> triangles;  // indices into vertices
  // True when the surface bounds a solid: closed, manifold, without self-intersections, and
  // wound counter-clockwise seen from outside (outer shells outward, cavities inward). Then
  // "inside" is defined and a collider pushes a particle found inside back out. False: an
  // open (or unorientable, or self-intersecting) sheet, which has two sides and no inside.
  bool closed = false;
};

}  // namespace physketch
