#include "render/mesh_distance.h"

#include <cmath>
#include <string>

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Simple_cartesian.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.h"

namespace physketch::render {
namespace {

using Kernel = CGAL::Simple_cartesian<double>;
using Point = Kernel::Point_3;
using Triangle = Kernel::Triangle_3;
using Iterator = std::vector<Triangle>::const_iterator;
using Primitive = CGAL::AABB_triangle_primitive<Kernel, Iterator>;
using Tree = CGAL::AABB_tree<CGAL::AABB_traits<Kernel, Primitive>>;

Point point(const Vec3f& v, const char* what) {
  if (!v.allFinite()) throw RuntimeError(std::string("distancesToMesh: non-finite ") + what);
  return Point(v.x(), v.y(), v.z());
}

}  // namespace

std::vector<double> distancesToMesh(const std::vector<Vec3f>& points, const TriangleMesh& mesh) {
  std::vector<Triangle> triangles;
  triangles.reserve(mesh.triangleCount());
  for (std::size_t t = 0; t < mesh.triangleCount(); ++t) {
    Point q[3];
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t i = mesh.indices[3 * t + std::size_t(k)];
      if (i >= mesh.positions.size()) throw RuntimeError("distancesToMesh: triangle index past the vertices");
      q[k] = point(mesh.positions[i], "mesh vertex");
    }
    const Triangle tri(q[0], q[1], q[2]);
    if (tri.squared_area() > 0.0) triangles.push_back(tri);
  }
  if (triangles.empty()) throw RuntimeError("distancesToMesh: the mesh has no triangle of positive area");
  Tree tree(triangles.begin(), triangles.end());
  tree.accelerate_distance_queries();
  std::vector<Point> queries;
  queries.reserve(points.size());
  for (const Vec3f& v : points) queries.push_back(point(v, "point"));
  std::vector<double> out(points.size());
  // The tree builds its search structures on the first query: make it here, not inside the threads.
  if (!queries.empty()) out[0] = std::sqrt(tree.squared_distance(queries[0]));
  tbb::parallel_for(tbb::blocked_range<std::size_t>(1, std::max<std::size_t>(1, queries.size())),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t i = r.begin(); i < r.end(); ++i) out[i] = std::sqrt(tree.squared_distance(queries[i]));
                    });
  return out;
}

double rmsSurfaceDistance(const TriangleMesh& a, const TriangleMesh& b) {
  double sum = 0.0;
  for (double d : distancesToMesh(a.positions, b)) sum += d * d;
  for (double d : distancesToMesh(b.positions, a)) sum += d * d;
  const std::size_t n = a.positions.size() + b.positions.size();
  return n ? std::sqrt(sum / double(n)) : 0.0;
}

}  // namespace physketch::render
