#include "sketch/mesh_stamp.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <sstream>
#include <utility>

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/IO/OBJ.h>
#include <CGAL/IO/OFF.h>
#include <CGAL/IO/PLY.h>
#include <CGAL/Polygon_mesh_processing/measure.h>
#include <CGAL/Polygon_mesh_processing/orient_polygon_soup.h>
#include <CGAL/Polygon_mesh_processing/orientation.h>
#include <CGAL/Polygon_mesh_processing/polygon_soup_to_polygon_mesh.h>
#include <CGAL/Polygon_mesh_processing/repair_polygon_soup.h>
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Polygon_mesh_processing/shape_predicates.h>
#include <CGAL/Polygon_mesh_processing/triangulate_faces.h>
#include <CGAL/Side_of_triangle_mesh.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/boost/graph/helpers.h>

#include "core/error.h"
#include "core/triangle_soup.h"

namespace physketch::sketch {
namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Mesh = CGAL::Surface_mesh<Point>;
using Polygon = std::vector<std::size_t>;
namespace PMP = CGAL::Polygon_mesh_processing;

[[noreturn]] void fail(const std::string& path, const std::string& reason) { throw InputError(path, 0, "", reason); }

std::string str(const Point& p) {
  std::ostringstream s;
  s.precision(9);
  s << '(' << p.x() << ", " << p.y() << ", " << p.z() << ')';
  return s.str();
}

// Edge and vertex topology of an indexed polygon soup, counted before CGAL builds a
// halfedge mesh (which cannot represent the non-manifold cases we want to name).
struct SoupTopology {
  static constexpr std::size_t kNone = std::numeric_limits<std::size_t>::max();
  std::size_t borderEdges = 0;          // edges of exactly one polygon
  std::size_t nonManifoldEdges = 0;     // edges of three or more polygons
  std::size_t nonManifoldVertices = 0;  // vertices whose polygons form more than one fan
  bool consistentlyWound = true;        // every two-polygon edge is used once in each direction
  std::size_t borderA = kNone, borderB = kNone;  // the first of each, for messages
  std::size_t edgeA = kNone, edgeB = kNone;
  std::size_t vertex = kNone;
};

// Needs polygons with >= 3 distinct in-range indices and points.size() < 2^31.
SoupTopology analyse(std::size_t pointCount, const std::vector<Polygon>& polygons) {
  SoupTopology t;
  // Edges as (min << 33 | max << 1 | direction), sorted: a run of equal key >> 1 is an
  // undirected edge of as many polygons as its length.
  std::vector<std::uint64_t> edges;
  std::size_t corners = 0;
  for (const Polygon& poly : polygons) corners += poly.size();
  edges.reserve(corners);
  for (const Polygon& poly : polygons)
    for (std::size_t i = 0; i < poly.size(); ++i) {
      const std::uint64_t a = poly[i], b = poly[(i + 1) % poly.size()];
      edges.push_back(std::min(a, b) << 33 | std::max(a, b) << 1 | (a > b ? 1 : 0));
    }
  std::sort(edges.begin(), edges.end());
  for (std::size_t i = 0; i < edges.size();) {
    std::size_t j = i + 1;
    while (j < edges.size() && edges[j] >> 1 == edges[i] >> 1) ++j;
    const std::size_t a = edges[i] >> 33, b = (edges[i] >> 1) & 0xffffffffu;
    if (j - i == 1 && t.borderEdges++ == 0) t.borderA = a, t.borderB = b;
    if (j - i > 2 && t.nonManifoldEdges++ == 0) t.edgeA = a, t.edgeB = b;
    if (j - i == 2 && edges[i] == edges[i + 1]) t.consistentlyWound = false;
    i = j;
  }
  // Vertex fans: around a vertex v, two corners are in the same fan when they share a
  // neighbour w (an edge v-w). A manifold vertex has one fan; two cubes touching at a
  // corner give two. Corners are bucketed by vertex (counting sort), then the fans of
  // each vertex are joined with a small union-find over its corners.
  std::vector<std::uint32_t> start(pointCount + 1, 0);
  for (const Polygon& poly : polygons)
    for (std::size_t v : poly) ++start[v + 1];
  for (std::size_t v = 0; v < pointCount; ++v) start[v + 1] += start[v];
  std::vector<std::pair<std::uint32_t, std::uint32_t>> nbr(corners);  // (previous, next) of each corner
  std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
  for (const Polygon& poly : polygons)
    for (std::size_t i = 0, n = poly.size(); i < n; ++i)
      nbr[fill[poly[i]]++] = {static_cast<std::uint32_t>(poly[(i + n - 1) % n]),
                              static_cast<std::uint32_t>(poly[(i + 1) % n])};
  std::vector<std::pair<std::uint32_t, std::uint32_t>> byNeighbour;  // (w, local corner)
  std::vector<std::uint32_t> parent;
  auto root = [&parent](std::uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (std::size_t v = 0; v < pointCount; ++v) {
    const std::uint32_t b = start[v], e = start[v + 1];
    if (e - b < 2) continue;
    byNeighbour.clear();
    parent.resize(e - b);
    for (std::uint32_t c = 0; c < e - b; ++c) {
      parent[c] = c;
      byNeighbour.emplace_back(nbr[b + c].first, c);
      byNeighbour.emplace_back(nbr[b + c].second, c);
    }
    std::sort(byNeighbour.begin(), byNeighbour.end());
    std::size_t fans = e - b;
    for (std::size_t k = 1; k < byNeighbour.size(); ++k) {
      if (byNeighbour[k].first != byNeighbour[k - 1].first) continue;
      const std::uint32_t x = root(byNeighbour[k].second), y = root(byNeighbour[k - 1].second);
      if (x != y) parent[x] = y, --fans;
    }
    if (fans > 1 && t.nonManifoldVertices++ == 0) t.vertex = v;
  }
  return t;
}

std::string plural(std::size_t n, const char* one, const char* many) {
  return std::to_string(n) + " " + (n == 1 ? one : many);
}

// Reads `path` into a soup; every failure is an InputError naming the file.
void readSoup(const std::string& path, const std::string& ext, std::vector<Point>& points,
              std::vector<Polygon>& polygons) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(path, ec)) fail(path, "mesh file does not exist");
  if (fs::is_directory(path, ec)) fail(path, "is a directory, not a mesh file");
  {
    std::ifstream probe(path, std::ios::binary);
    if (!probe) fail(path, "mesh file cannot be opened for reading");
    if (probe.peek() == std::ifstream::traits_type::eof()) fail(path, "mesh file is empty");
  }
  const std::string format = ext == ".obj" ? "OBJ" : ext == ".off" ? "OFF" : "PLY";
  bool ok = false;
  // The readers parse coordinates with operator>>, which refuses "nan" and "inf": those
  // files fail here. Binary PLY can still carry them; they are caught after reading.
  if (ext == ".obj") ok = CGAL::IO::read_OBJ(path, points, polygons);
  if (ext == ".off") ok = CGAL::IO::read_OFF(path, points, polygons);
  if (ext == ".ply") ok = CGAL::IO::read_PLY(path, points, polygons);
  if (!ok)
    fail(path, "cannot read the file as " + format +
                   ": a malformed line, a coordinate that is not a finite number, a face index out of range, "
                   "or no vertices or faces");
  if (polygons.empty()) fail(path, "mesh has no faces");
}

// Reads `path` (OBJ, OFF or PLY by its extension, case-insensitive) and checks the soup as
// written, numbering vertices and faces from 1 in file order: finite coordinates, faces of
// three or more vertices that exist, at most maxTriangles triangles after splitting polygons.
void readValidatedSoup(const std::string& path, std::size_t maxTriangles, std::vector<Point>& points,
                       std::vector<Polygon>& polygons) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext != ".obj" && ext != ".off" && ext != ".ply")
    fail(path, (ext.empty() ? std::string("mesh file has no extension") : "unknown mesh format '" + ext + "'") +
                   ": use .obj, .off or .ply");
  readSoup(path, ext, points, polygons);
  for (std::size_t i = 0; i < points.size(); ++i)
    if (!std::isfinite(points[i].x()) || !std::isfinite(points[i].y()) || !std::isfinite(points[i].z()))
      fail(path, "vertex " + std::to_string(i + 1) + " has a non-finite coordinate");
  std::size_t triangles = 0;
  for (std::size_t f = 0; f < polygons.size(); ++f) {
    const Polygon& poly = polygons[f];
    const std::string face = "face " + std::to_string(f + 1);
    if (poly.size() < 3) fail(path, face + " has " + std::to_string(poly.size()) + " vertices; a face needs 3 or more");
    for (std::size_t v : poly)
      if (v >= points.size())
        fail(path, face + " refers to a vertex that does not exist (the file has " +
                       std::to_string(points.size()) + " vertices)");
    triangles += poly.size() - 2;
  }
  if (triangles > maxTriangles)
    fail(path, "mesh has " + std::to_string(triangles) + " triangles (after splitting polygons); the limit is " +
                   std::to_string(maxTriangles));
}

}  // namespace

struct StampMesh::Impl {
  Mesh mesh;  // file coordinates; closed, manifold, triangulated, oriented to bound its volume
  Vec3 lo, hi;
  double volume = 0;
};

StampMesh::StampMesh(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
StampMesh::~StampMesh() = default;
StampMesh::StampMesh(StampMesh&&) noexcept = default;
StampMesh& StampMesh::operator=(StampMesh&&) noexcept = default;

std::size_t StampMesh::vertexCount() const { return impl_->mesh.number_of_vertices(); }
std::size_t StampMesh::faceCount() const { return impl_->mesh.number_of_faces(); }
Vec3 StampMesh::boundsMin() const { return impl_->lo; }
Vec3 StampMesh::boundsMax() const { return impl_->hi; }
double StampMesh::volume() const { return impl_->volume; }

StampMesh StampMesh::load(const std::string& path) {
  std::vector<Point> points;
  std::vector<Polygon> polygons;
  readValidatedSoup(path, kMaxFaces, points, polygons);

  // Benign repairs: exporters split vertices along UV seams and sharp edges (the same
  // position twice) and may leave unused vertices. Merging exact duplicates is what
  // makes such a file closed; it cannot hide a real hole.
  PMP::merge_duplicate_points_in_polygon_soup(points, polygons);
  PMP::remove_isolated_points_in_polygon_soup(points, polygons);
  for (std::size_t f = 0; f < polygons.size(); ++f) {
    Polygon sorted = polygons[f];
    std::sort(sorted.begin(), sorted.end());
    if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end())
      fail(path, "face " + std::to_string(f + 1) + " uses the same vertex (or vertex position) twice");
  }
  if (points.size() > std::numeric_limits<std::int32_t>::max())
    fail(path, "mesh has too many vertices (" + std::to_string(points.size()) + ")");

  const SoupTopology topo = analyse(points.size(), polygons);
  if (topo.nonManifoldEdges > 0 || topo.nonManifoldVertices > 0) {
    std::string why = "mesh is not manifold:";
    if (topo.nonManifoldEdges > 0)
      why += " " + plural(topo.nonManifoldEdges, "edge is", "edges are") + " shared by more than two faces (e.g. " +
             str(points[topo.edgeA]) + "-" + str(points[topo.edgeB]) + ")";
    if (topo.nonManifoldVertices > 0)
      why += std::string(topo.nonManifoldEdges > 0 ? ";" : "") + " " +
             plural(topo.nonManifoldVertices, "vertex joins", "vertices join") +
             " separate sheets of surface (e.g. " + str(points[topo.vertex]) + ")";
    fail(path, why + "; a stamp needs a surface that bounds a solid unambiguously");
  }
  if (topo.borderEdges > 0)
    fail(path, "mesh is not closed (" + plural(topo.borderEdges, "border edge", "border edges") +
                   ", i.e. edges of only one face, e.g. " + str(points[topo.borderA]) + "-" +
                   str(points[topo.borderB]) + "): a stamp needs a watertight surface to tell inside from outside");

  // Manifold and closed, so orienting fails only for a non-orientable surface (which
  // in 3D must also intersect itself). Most files are wound consistently already, and
  // the orientation pass (about half the cost of reading) is skipped for them.
  const std::size_t pointsBefore = points.size();
  if (!topo.consistentlyWound &&
      (!PMP::orient_polygon_soup(points, polygons) || points.size() != pointsBefore))
    fail(path, "mesh surface is not orientable (its faces cannot be wound consistently)");

  auto impl = std::make_unique<Impl>();
  Mesh& mesh = impl->mesh;
  PMP::polygon_soup_to_polygon_mesh(points, polygons, mesh);
  if (!CGAL::is_triangle_mesh(mesh) && !PMP::triangulate_faces(mesh))
    fail(path, "a polygon of the mesh could not be split into triangles");
  if (!CGAL::is_closed(mesh)) fail(path, "mesh is not closed after triangulation");  // not expected after the checks above

  // Zero-area faces: CGAL's self-intersection test would report each as intersecting
  // itself, so it runs on the others. A collinear sliver (a, m, b) still makes the faces
  // across its edges overlap along a-m or m-b, so any sliver ends as a self-intersection
  // below; the message then says why.
  std::vector<Mesh::Face_index> solidFaces;
  solidFaces.reserve(mesh.number_of_faces());
  for (Mesh::Face_index f : mesh.faces())
    if (!PMP::is_degenerate_triangle_face(f, mesh)) solidFaces.push_back(f);
  if (solidFaces.empty())
    fail(path, "all " + std::to_string(mesh.number_of_faces()) + " faces of the mesh are degenerate (zero area)");

  // Self-intersections make inside/outside (and the volume) ill-defined; CGAL's
  // Side_of_triangle_mesh and orient_to_bound_a_volume both require their absence.
  std::vector<std::pair<Mesh::Face_index, Mesh::Face_index>> crossing;
  PMP::self_intersections(solidFaces, mesh, std::back_inserter(crossing), CGAL::parameters::maximum_number(1));
  if (!crossing.empty()) {
    const std::size_t slivers = mesh.number_of_faces() - solidFaces.size();
    fail(path, "mesh intersects itself (e.g. at the face with corner " +
                   str(mesh.point(mesh.target(mesh.halfedge(crossing.front().first)))) + ")" +
                   (slivers > 0 ? "; it has " + plural(slivers, "zero-area face", "zero-area faces") +
                                      ", and the faces around a zero-area face overlap: dissolve them"
                                : std::string()) +
                   "; a stamp needs a surface without overlaps");
  }

  // Outer shells outward, cavities inward: the signed volume is then the solid's.
  PMP::orient_to_bound_a_volume(mesh);
  impl->volume = CGAL::to_double(PMP::volume(mesh));
  if (!(impl->volume > 0)) fail(path, "mesh encloses no volume");

  impl->lo = Vec3::Constant(std::numeric_limits<double>::infinity());
  impl->hi = -impl->lo;
  for (Mesh::Vertex_index v : mesh.vertices()) {
    const Point& p = mesh.point(v);
    impl->lo = impl->lo.cwiseMin(Vec3(p.x(), p.y(), p.z()));
    impl->hi = impl->hi.cwiseMax(Vec3(p.x(), p.y(), p.z()));
  }
  return StampMesh(std::move(impl));
}

namespace {

// The placed (world) positions of the mesh vertices, indexed by vertex index, as a
// readable property map: Side_of_triangle_mesh then works on the placed mesh without
// copying its connectivity.
struct WorldPointMap {
  using key_type = Mesh::Vertex_index;
  using value_type = Point;
  using reference = const Point&;
  using category = boost::readable_property_map_tag;
  const std::vector<Point>* points = nullptr;
  friend reference get(const WorldPointMap& m, key_type v) { return (*m.points)[v.idx()]; }
};

}  // namespace

std::vector<Vec3i> voxelizeMesh(const StampMesh& stamp, const GridMapping& mapping, double scale,
                                const Mat3& rotation, const Vec3& translation) {
  if (!(scale > 0) || !std::isfinite(scale))
    throw RuntimeError("voxelizeMesh: scale must be finite and > 0, got " + std::to_string(scale));
  if (!rotation.allFinite() || !(std::abs(rotation.determinant()) > 1e-12))
    throw RuntimeError("voxelizeMesh: rotation must be finite and non-singular");
  if (!translation.allFinite()) throw RuntimeError("voxelizeMesh: translation must be finite");

  const Mesh& mesh = stamp.impl_->mesh;
  std::vector<Point> world(mesh.num_vertices());  // num_vertices: indices incl. removed ones (none here)
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (Mesh::Vertex_index v : mesh.vertices()) {
    const Point& p = mesh.point(v);
    const Vec3 w = rotation * (scale * Vec3(p.x(), p.y(), p.z())) + translation;
    if (!w.allFinite()) throw RuntimeError("voxelizeMesh: the placed mesh has a non-finite vertex (scale too large?)");
    world[v.idx()] = Point(w.x(), w.y(), w.z());
    lo = lo.cwiseMin(w);
    hi = hi.cwiseMax(w);
  }

  // Cells whose centres may lie in the placed bounding box, clipped to the grid. One
  // cell of margin absorbs rounding in toGrid(); Side_of_triangle_mesh rejects centres
  // outside the exact box first, so the margin costs a comparison per cell and no more.
  const Vec3 glo = mapping.toGrid(lo), ghi = mapping.toGrid(hi);
  int first[3], last[3];
  for (int k = 0; k < 3; ++k) {
    const double a = std::max(0.0, std::ceil(glo[k]) - 1), b = std::min(kGridSize - 1.0, std::floor(ghi[k]) + 1);
    if (!(a <= b)) return {};
    first[k] = static_cast<int>(a), last[k] = static_cast<int>(b);
  }

  // Built once per call; its AABB tree is built lazily on the first query inside the box.
  const CGAL::Side_of_triangle_mesh<Mesh, Kernel, WorldPointMap> inside(mesh, WorldPointMap{&world});
  std::vector<Vec3i> cells;
  for (int z = first[2]; z <= last[2]; ++z)
    for (int y = first[1]; y <= last[1]; ++y)
      for (int x = first[0]; x <= last[0]; ++x) {
        const Vec3i cell(x, y, z);
        const Vec3 c = mapping.toWorld(cell);
        if (inside(Point(c.x(), c.y(), c.z())) != CGAL::ON_UNBOUNDED_SIDE) cells.push_back(cell);
      }
  return cells;
}

namespace {

// Drops repeated corners that follow each other (a b b c -> a b c, cyclic), which exact
// duplicate positions leave once merged; a face left with fewer than three corners, or
// with a corner twice elsewhere, has no area and is dropped: a collider needs no slivers.
void dropDegenerateFaces(std::vector<Polygon>& polygons) {
  std::vector<Polygon> kept;
  kept.reserve(polygons.size());
  for (Polygon& poly : polygons) {
    Polygon p;
    for (std::size_t i = 0; i < poly.size(); ++i)
      if (poly[i] != poly[(i + 1) % poly.size()]) p.push_back(poly[i]);
    Polygon sorted = p;
    std::sort(sorted.begin(), sorted.end());
    if (p.size() >= 3 && std::adjacent_find(sorted.begin(), sorted.end()) == sorted.end()) kept.push_back(std::move(p));
  }
  polygons.swap(kept);
}

// The soup as a solid, when it is one: closed, manifold (edges and vertices), orientable,
// no zero-area face, no self-intersection, positive volume. Then it is triangulated and
// oriented to bound its volume (outer shells outward, cavities inward) and written to
// `out`; otherwise `out` is untouched and the answer is false. Same checks as a stamp
// (StampMesh::load), but failing one makes the collider an open sheet, not an error.
bool solidTriangles(std::vector<Point> points, std::vector<Polygon> polygons, TriangleSoup& out) {
  const SoupTopology topo = analyse(points.size(), polygons);
  if (topo.borderEdges > 0 || topo.nonManifoldEdges > 0 || topo.nonManifoldVertices > 0) return false;
  const std::size_t pointsBefore = points.size();
  if (!topo.consistentlyWound && (!PMP::orient_polygon_soup(points, polygons) || points.size() != pointsBefore))
    return false;
  Mesh mesh;
  PMP::polygon_soup_to_polygon_mesh(points, polygons, mesh);
  if (!CGAL::is_triangle_mesh(mesh) && !PMP::triangulate_faces(mesh)) return false;
  if (!CGAL::is_closed(mesh)) return false;
  for (Mesh::Face_index f : mesh.faces())
    if (PMP::is_degenerate_triangle_face(f, mesh)) return false;  // no normal: the inside test needs one per face
  if (PMP::does_self_intersect(mesh)) return false;
  PMP::orient_to_bound_a_volume(mesh);
  if (!(CGAL::to_double(PMP::volume(mesh)) > 0)) return false;

  out.vertices.resize(mesh.number_of_vertices());
  for (Mesh::Vertex_index v : mesh.vertices()) {
    const Point& p = mesh.point(v);
    out.vertices[v.idx()] = Vec3(p.x(), p.y(), p.z());
  }
  out.triangles.clear();
  out.triangles.reserve(mesh.number_of_faces());
  for (Mesh::Face_index f : mesh.faces()) {
    std::array<std::int32_t, 3> t{};
    int k = 0;
    for (Mesh::Vertex_index v : CGAL::vertices_around_face(mesh.halfedge(f), mesh))
      t[static_cast<std::size_t>(k++)] = static_cast<std::int32_t>(v.idx());
    out.triangles.push_back(t);
  }
  out.closed = true;
  return true;
}

}  // namespace

TriangleSoup readTriangleSoup(const std::string& path, std::size_t maxTriangles) {
  std::vector<Point> points;
  std::vector<Polygon> polygons;
  readValidatedSoup(path, maxTriangles, points, polygons);
  // The same benign repairs as a stamp (exact duplicate positions merged, unused vertices
  // dropped), then faces without area dropped instead of refused.
  PMP::merge_duplicate_points_in_polygon_soup(points, polygons);
  dropDegenerateFaces(polygons);
  PMP::remove_isolated_points_in_polygon_soup(points, polygons);
  if (polygons.empty()) fail(path, "every face of the mesh repeats a vertex (or vertex position): no triangle is left");
  if (points.size() > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
    fail(path, "mesh has too many vertices (" + std::to_string(points.size()) + ")");

  TriangleSoup soup;
  if (solidTriangles(points, polygons, soup)) return soup;
  // An open sheet: the file's vertices and winding, polygons split as fans (0, i, i + 1).
  soup.vertices.reserve(points.size());
  for (const Point& p : points) soup.vertices.emplace_back(p.x(), p.y(), p.z());
  for (const Polygon& poly : polygons)
    for (std::size_t i = 1; i + 1 < poly.size(); ++i)
      soup.triangles.push_back({static_cast<std::int32_t>(poly[0]), static_cast<std::int32_t>(poly[i]),
                                static_cast<std::int32_t>(poly[i + 1])});
  soup.closed = false;
  return soup;
}

}  // namespace physketch::sketch
