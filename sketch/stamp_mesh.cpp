#include "sketch/stamp_mesh.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <filesystem>

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/IO/polygon_soup_io.h>
#include <CGAL/Polygon_mesh_processing/measure.h>
#include <CGAL/Polygon_mesh_processing/orient_polygon_soup.h>
#include <CGAL/Polygon_mesh_processing/polygon_soup_to_polygon_mesh.h>
#include <CGAL/Polygon_mesh_processing/triangulate_faces.h>
#include <CGAL/Side_of_triangle_mesh.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/boost/graph/helpers.h>

#include "core/error.h"

namespace physketch::sketch {
namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Mesh = CGAL::Surface_mesh<Point>;
namespace PMP = CGAL::Polygon_mesh_processing;

}  // namespace

struct StampMesh::Impl {
  Mesh mesh;  // in file coordinates, closed, triangulated
};

StampMesh::StampMesh(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
StampMesh::StampMesh(StampMesh&&) noexcept = default;
StampMesh& StampMesh::operator=(StampMesh&&) noexcept = default;
StampMesh::~StampMesh() = default;

StampMesh StampMesh::load(const std::string& path) {
  namespace fs = std::filesystem;
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  if (ext != ".obj" && ext != ".off" && ext != ".ply")
    throw InputError(path, 0, "", "unknown mesh format '" + ext + "' (known: .obj, .off, .ply)");
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw InputError(path, 0, "", "cannot open mesh file");
  std::vector<Point> points;
  std::vector<std::vector<std::size_t>> polygons;
  if (!CGAL::IO::read_polygon_soup(path, points, polygons) )
    throw InputError(path, 0, "", "cannot read the mesh (not a valid " + ext.substr(1) + " file)");
  if (polygons.empty()) throw InputError(path, 0, "", "mesh has no faces");
  if (polygons.size() > kMaxFaces)
    throw InputError(path, 0, "", "mesh has " + std::to_string(polygons.size()) + " faces; the limit is " +
                                      std::to_string(kMaxFaces));
  for (std::size_t i = 0; i < points.size(); ++i)
    if (!std::isfinite(points[i].x()) || !std::isfinite(points[i].y()) || !std::isfinite(points[i].z()))
      throw InputError(path, 0, "", "vertex " + std::to_string(i + 1) + " has a non-finite coordinate");
  for (const auto& poly : polygons) {
    if (poly.size() < 3) throw InputError(path, 0, "", "a face has fewer than 3 vertices");
    for (std::size_t v : poly)
      if (v >= points.size()) throw InputError(path, 0, "", "a face refers to a vertex that does not exist");
  }
  // Orienting the soup duplicates the vertices where the surface is not a manifold
  // (an edge shared by three faces, two cones meeting at a vertex): that is our test.
  const std::size_t before = points.size();
  if (!PMP::orient_polygon_soup(points, polygons) || points.size() != before)
    throw InputError(path, 0, "",
                     "mesh is not manifold (" + std::to_string(points.size() - before) +
                         " vertices are shared by separate sheets, or an edge by more than two faces)");
  auto impl = std::make_unique<Impl>();
  PMP::polygon_soup_to_polygon_mesh(points, polygons, impl->mesh);
  if (!CGAL::is_triangle_mesh(impl->mesh)) PMP::triangulate_faces(impl->mesh);
  if (!CGAL::is_closed(impl->mesh)) {
    std::size_t border = 0;
    for (auto h : impl->mesh.halfedges())
      if (impl->mesh.is_border(h)) ++border;
    throw InputError(path, 0, "", "mesh is not closed (" + std::to_string(border) +
                                      " border edges): a stamp needs a watertight surface to tell inside from outside");
  }
  return StampMesh(std::move(impl));
}

std::size_t StampMesh::vertexCount() const { return impl_->mesh.number_of_vertices(); }
std::size_t StampMesh::faceCount() const { return impl_->mesh.number_of_faces(); }
double StampMesh::volume() const { return std::abs(CGAL::to_double(PMP::volume(impl_->mesh))); }

std::vector<Vec3i> StampMesh::voxelize(const GridMapping& m, double scale, const Mat3& rotation,
                                       const Vec3& translation) const {
  // Place the mesh in the world, then test each cell centre in its bounding box.
  Mesh placed = impl_->mesh;
  Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
  for (auto v : placed.vertices()) {
    const Point& p = placed.point(v);
    const Vec3 w = rotation * (scale * Vec3(p.x(), p.y(), p.z())) + translation;
    placed.point(v) = Point(w.x(), w.y(), w.z());
    lo = lo.cwiseMin(w);
    hi = hi.cwiseMax(w);
  }
  std::vector<Vec3i> out;
  const Vec3 glo = m.toGrid(lo), ghi = m.toGrid(hi);
  int a[3], b[3];
  for (int k = 0; k < 3; ++k) {
    a[k] = std::max(0, static_cast<int>(std::ceil(glo[k])));
    b[k] = std::min(kGridSize - 1, static_cast<int>(std::floor(ghi[k])));
    if (a[k] > b[k]) return out;
  }
  const CGAL::Side_of_triangle_mesh<Mesh, Kernel> inside(placed);
  for (int k = a[2]; k <= b[2]; ++k)
    for (int j = a[1]; j <= b[1]; ++j)
      for (int i = a[0]; i <= b[0]; ++i) {
        const Vec3 c = m.toWorld(Vec3i(i, j, k));
        if (inside(Point(c.x(), c.y(), c.z())) != CGAL::ON_UNBOUNDED_SIDE) out.emplace_back(i, j, k);
      }
  return out;
}

}  // namespace physketch::sketch
