// Mesh stamps: a closed, manifold triangle mesh read from a file and voxelized into
// the 151^3 sketch grid by a point-in-solid test of every cell centre.
// CGAL does all the geometry, but only in mesh_stamp.cpp: its headers cost 5-30 s and
// up to a GB of compiler memory per translation unit, so this header exposes std and
// Eigen types only.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "core/math.h"
#include "core/triangle_soup.h"
#include "sketch/grid.h"

namespace physketch::sketch {

// A closed, manifold, non-self-intersecting triangle mesh read from OBJ, OFF or PLY
// (chosen by the file extension, case-insensitive; PLY ASCII or binary). Polygons with
// more than three vertices are triangulated; exact duplicate vertices are merged and
// unreferenced ones dropped; an inconsistently oriented soup is re-oriented. Those are
// the only repairs: anything that leaves inside and outside ill-defined is an error.
class StampMesh {
 public:
  // More triangles than this (after splitting polygons) is an InputError: load and the
  // self-intersection check grow to seconds and gigabytes beyond it.
  static constexpr std::size_t kMaxFaces = 5'000'000;

  // Throws InputError(path, 0, "", reason) when the file is missing, unreadable or empty,
  // has an unknown extension or does not parse, has a non-finite coordinate, a face with
  // fewer than three or repeated vertices or an index out of range, more than kMaxFaces
  // triangles, non-manifold edges (shared by more than two faces) or vertices (where
  // separate sheets meet), border edges (not closed; the count is named), only
  // degenerate (zero-area) faces, self-intersections, or encloses no volume.
  static StampMesh load(const std::string& path);

  std::size_t vertexCount() const;
  std::size_t faceCount() const;  // triangles
  // Axis-aligned bounds of the vertices, in file coordinates.
  Vec3 boundsMin() const;
  Vec3 boundsMax() const;
  // Enclosed volume in file units^3 (cavities, i.e. nested inner shells, subtracted).
  double volume() const;

  ~StampMesh();
  StampMesh(StampMesh&&) noexcept;
  StampMesh& operator=(StampMesh&&) noexcept;

  friend std::vector<Vec3i> voxelizeMesh(const StampMesh&, const GridMapping&, double, const Mat3&, const Vec3&);

 private:
  struct Impl;  // the CGAL side, defined in mesh_stamp.cpp only
  explicit StampMesh(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// The cells of the 151^3 grid whose centres (mapping.toWorld(cell)) lie inside the mesh
// placed by world = rotation * (scale * p) + translation, p in file coordinates. A centre
// on the surface counts as inside (exact predicates: CGAL::Side_of_triangle_mesh, Epick).
// Only centres within the placed mesh's bounding box are tested; cells outside the grid
// are skipped. Output is sorted z-major, then y, then x ascending, without duplicates.
// scale must be finite and > 0, rotation finite and non-singular (it need not be
// orthonormal), translation finite; otherwise RuntimeError (a caller bug: the stroke
// parser validates user input).
std::vector<Vec3i> voxelizeMesh(const StampMesh& mesh, const GridMapping& mapping, double scale,
                                const Mat3& rotation, const Vec3& translation);

// More triangles than this in a collider mesh is an InputError: Bullet's quantized BVH
// (btBvhTriangleMeshShape) numbers a mesh part's triangles in 21 bits (2,097,152).
constexpr std::size_t kMaxColliderTriangles = 2'000'000;

// A mesh collider's triangles, read leniently: open or closed, any file a stamp accepts and
// also open sheets, non-manifold or self-intersecting ones. Same formats and the same checks
// of the file as StampMesh::load (missing, unreadable or empty file, unknown extension, parse
// errors, a non-finite coordinate, a face with fewer than three vertices or an index out of
// range, more than maxTriangles triangles: InputError(path, 0, "", reason), naming the file).
// Exact duplicate positions are merged, unused vertices dropped, and faces that repeat a
// vertex (no area) dropped; a file with no face left is an error. The result is `closed`
// (and oriented outward, triangulated by CGAL) when it passes a stamp's solid checks (closed,
// manifold, orientable, no zero-area face, no self-intersection, positive volume); otherwise
// it keeps the file's winding, polygons split as fans.
TriangleSoup readTriangleSoup(const std::string& path, std::size_t maxTriangles = kMaxColliderTriangles);

}  // namespace physketch::sketch
