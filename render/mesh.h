// Plain triangle mesh: the only geometry type that crosses the render module's
// boundary (OpenVDB stays inside vdb_bridge.cpp).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/math.h"

namespace physketch::render {

struct TriangleMesh {
  std::vector<Vec3f> positions;       // vertex positions (m)
  std::vector<Vec3f> normals;         // unit vertex normals, pointing out of the solid
  std::vector<std::uint32_t> indices; // 3 per triangle, counter-clockwise seen from outside

  std::size_t triangleCount() const { return indices.size() / 3; }
  bool empty() const { return indices.empty(); }
};

// Volume enclosed by a closed mesh wound counter-clockwise seen from outside (divergence
// theorem: the sum of the signed tetrahedra each triangle makes with the origin), m^3.
// Negative for a mesh wound the other way.
double enclosedVolume(const TriangleMesh& mesh);

// Total area of the triangles (m^2).
double surfaceArea(const TriangleMesh& mesh);

// A closed tube of `radius` (m) around each chain of points (a rope's particles in chain order):
// a ring of `sides` vertices around every point, in the plane normal to the chain's direction
// there (central differences), turned from ring to ring by parallel transport so the tube does
// not twist; the end rings are closed by fans around the end points. A chain of one point
// becomes a tube of length 2 radius along x. Normals: radial. Throws RuntimeError for a
// non-finite point, a radius that is not > 0 or fewer than 3 sides.
TriangleMesh tubeMesh(const std::vector<std::vector<Vec3>>& chains, double radius, int sides = 8);

// A cloth lattice as a closed sheet of thickness 2 halfThickness (m): `nodes` holds rows x cols
// points, row-major, `alive` (same size) 0 at a hole. Every cell whose four nodes are alive
// gives two triangles on each side, the nodes moved by +-halfThickness along their normals (the
// mean of the adjacent live cells' normals, weighted by area); every cell edge that no other
// live cell shares gets a wall joining the two sides. So the sheet follows the lattice exactly:
// no voxel steps and no holes where the cloth lies between lattice layers. A node of no live
// cell draws nothing. Normals: the node's on each side, the wall's own on the walls. Throws
// RuntimeError for sizes that do not match, a non-finite live node, or a halfThickness that is
// not finite and > 0.
TriangleMesh sheetMesh(const std::vector<Vec3>& nodes, const std::vector<std::uint8_t>& alive, int rows, int cols,
                       double halfThickness);

// Writes a mesh as Wavefront OBJ (positions, normals, faces). Throws RuntimeError.
void writeObj(const std::string& path, const TriangleMesh& mesh);

}  // namespace physketch::render
