// Distances between points and triangle surfaces, for error norms of meshes (physketch study's
// meshing knobs; docs/accuracy.md). CGAL's AABB tree answers the closest-point queries; CGAL stays
// inside mesh_distance.cpp.
#pragma once

#include <vector>

#include "core/math.h"
#include "render/mesh.h"

namespace physketch::render {

// The unsigned distance (m) from each point to the nearest point of the mesh's triangles (not
// only its vertices). Triangles of zero area are skipped (their points lie on the edges of
// their neighbours in a closed mesh). The same result for any thread count. Throws
// RuntimeError for a mesh with no triangle of positive area, an index past the vertices, or a
// non-finite point or vertex.
std::vector<double> distancesToMesh(const std::vector<Vec3f>& points, const TriangleMesh& mesh);

// The symmetric RMS distance (m) between two surfaces: the square root of the mean, over the
// vertices of both meshes, of the squared distance from each vertex to the other mesh. 0 for
// two copies of one mesh. Throws as distancesToMesh does.
double rmsSurfaceDistance(const TriangleMesh& a, const TriangleMesh& b);

}  // namespace physketch::render
