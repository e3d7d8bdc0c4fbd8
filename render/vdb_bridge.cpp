// meshVoxels and meshParticles: the one translation unit that includes OpenVDB (its headers cost ~3 s to parse;
// stack.md §7). It uses only tools that libopenvdb instantiates explicitly (topologyToLevelSet,
// volumeToMesh), so this TU compiles in seconds and runs at full speed even in Debug builds.
#include <openvdb/openvdb.h>
#include <openvdb/tools/TopologyToLevelSet.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <cmath>
#include <mutex>
#include <string>

#include "core/error.h"
#include "render/voxel_mesh.h"

namespace physketch::render {
namespace {

void initializeOpenVdbOnce() {
  // openvdb::initialize() registers grid types (needed for .vdb I/O only, harmless here).
  // It is not documented as thread-safe, so guard it.
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

void checkOptions(const char* who, double voxelSize, const Vec3& origin, const VoxelMeshOptions& o) {
  auto fail = [who](const std::string& what) { throw RuntimeError(std::string(who) + ": " + what); };
  if (!(voxelSize > 0.0) || !std::isfinite(voxelSize)) fail("voxel size must be finite and > 0 m");
  if (!origin.allFinite()) fail("origin must be finite");
  if (o.halfWidth < 1) fail("halfWidth must be >= 1 voxel");
  if (o.closingSteps < 0) fail("closingSteps must be >= 0");
  if (o.smoothingSteps < 0) fail("smoothingSteps must be >= 0");
  if (!(o.adaptivity >= 0.0 && o.adaptivity <= 1.0)) fail("adaptivity must be in [0, 1]");
}

// Converts volumeToMesh's output into TriangleMesh: drops unreferenced points and degenerate
// faces, reverses the winding, splits quads, and computes area-weighted vertex normals.
// Serial and in input order, so the result is a pure function of volumeToMesh's output.
TriangleMesh assemble(const std::vector<openvdb::Vec3s>& points, const std::vector<openvdb::Vec3I>& triangles,
                      const std::vector<openvdb::Vec4I>& quads) {
  std::vector<std::uint32_t> faces;
  faces.reserve(3 * triangles.size() + 6 * quads.size());
  auto addTriangle = [&faces](std::uint32_t a, std::uint32_t b, std::uint32_t c) {
    if (a == b || b == c || c == a) return;  // collapsed by adaptivity: zero area, no normal
    faces.push_back(a);
    faces.push_back(b);
    faces.push_back(c);
  };
  // volumeToMesh emits polygons clockwise seen from outside (negative signed volume, checked
  // by the tests); reversing the index order makes them counter-clockwise (stack.md §4).
  for (const openvdb::Vec3I& t : triangles) addTriangle(t[2], t[1], t[0]);
  for (const openvdb::Vec4I& q : quads) {
    // Reversed quad r = (q3, q2, q1, q0), split along the fixed diagonal r0-r2 so the
    // triangulation never depends on floating-point comparisons.
    addTriangle(q[3], q[2], q[1]);
    addTriangle(q[3], q[1], q[0]);
  }

  // Compact: keep only referenced points, numbered in order of first appearance in `points`.
  constexpr std::uint32_t kUnused = 0xffffffffu;
  std::vector<std::uint32_t> remap(points.size(), kUnused);
  for (std::uint32_t i : faces) remap[i] = 0;
  TriangleMesh mesh;
  std::uint32_t next = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (remap[i] == kUnused) continue;
    remap[i] = next++;
    mesh.positions.emplace_back(points[i].x(), points[i].y(), points[i].z());
  }
  mesh.indices.reserve(faces.size());
  for (std::uint32_t i : faces) mesh.indices.push_back(remap[i]);

  // Area-weighted normals: the un-normalised cross product has length 2*area, so summing it
  // weights each face by its area. Accumulated in double, in face order (deterministic).
  std::vector<Vec3> acc(mesh.positions.size(), Vec3::Zero());
  for (std::size_t t = 0; t < mesh.indices.size(); t += 3) {
    const std::uint32_t a = mesh.indices[t], b = mesh.indices[t + 1], c = mesh.indices[t + 2];
    const Vec3 pa = mesh.positions[a].cast<double>();
    const Vec3 n = (mesh.positions[b].cast<double>() - pa).cross(mesh.positions[c].cast<double>() - pa);
    acc[a] += n;
    acc[b] += n;
    acc[c] += n;
  }
  mesh.normals.reserve(acc.size());
  for (const Vec3& n : acc) {
    const double len = n.norm();
    // A vertex whose faces all have zero area has no defined normal; +y keeps it unit length.
    mesh.normals.push_back(len > 0.0 ? (n / len).cast<float>() : Vec3f(0.0f, 1.0f, 0.0f));
  }
  return mesh;
}

// The shared pipeline: cells (i,j,k) with centres origin + h*(i,j,k) -> closed mesh.
// Options are checked by the caller.
TriangleMesh meshCells(const std::vector<openvdb::Coord>& cells, double voxelSize, const Vec3& origin,
                       const VoxelMeshOptions& options) {
  if (cells.empty()) return {};
  initializeOpenVdbOnce();

  // Index space = the lattice: OpenVDB puts voxel (i,j,k)'s centre at index (i,j,k),
  // so world = origin + h*(i,j,k) is a uniform scale followed by a translation.
  openvdb::BoolGrid::Ptr grid = openvdb::BoolGrid::create(false);
  openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform(voxelSize);
  xform->postTranslate(openvdb::Vec3d(origin.x(), origin.y(), origin.z()));
  grid->setTransform(xform);
  {
    // Serial: the grid's topology is the set of cells, whatever their order or repeats.
    openvdb::BoolGrid::Accessor acc = grid->getAccessor();
    for (const openvdb::Coord& c : cells) acc.setValueOn(c, true);
  }

  // The level set's zero crossing lies on the boundary between active and inactive voxels,
  // i.e. on the cube faces of the voxel union (before smoothing).
  openvdb::FloatGrid::Ptr sdf = openvdb::tools::topologyToLevelSet(
      *grid, options.halfWidth, options.closingSteps, /*dilation=*/0, options.smoothingSteps);

  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(*sdf, points, triangles, quads, /*isovalue=*/0.0, options.adaptivity);
  return assemble(points, triangles, quads);
}

}  // namespace

TriangleMesh meshVoxels(const std::vector<Vec3i>& voxels, double voxelSize, const Vec3& origin,
                        const VoxelMeshOptions& options) {
  checkOptions("meshVoxels", voxelSize, origin, options);
  std::vector<openvdb::Coord> cells;
  cells.reserve(voxels.size());
  for (const Vec3i& v : voxels) cells.emplace_back(v.x(), v.y(), v.z());
  return meshCells(cells, voxelSize, origin, options);
}

TriangleMesh meshParticles(const std::vector<Vec3>& positions, double particleSpacing,
                           const ParticleMeshOptions& options) {
  checkOptions("meshParticles", particleSpacing, options.latticeOrigin, options.surface);
  // |index| <= 2^30 leaves OpenVDB's int32 coordinates room for the narrow band and closing.
  constexpr double kMaxIndex = 1073741824.0;
  std::vector<openvdb::Coord> cells;
  cells.reserve(positions.size());
  for (std::size_t i = 0; i < positions.size(); ++i) {
    const Vec3& p = positions[i];
    if (!p.allFinite()) throw RuntimeError("meshParticles: particle " + std::to_string(i) + " position is not finite");
    // Nearest cell centre: round((p - origin) / h), ties upward (floor(x + 0.5)), so the
    // cell is a pure function of the position.
    const Vec3 index = ((p - options.latticeOrigin) / particleSpacing).array() + 0.5;
    const Vec3 cell = index.array().floor();
    if (cell.cwiseAbs().maxCoeff() > kMaxIndex) {
      throw RuntimeError("meshParticles: particle " + std::to_string(i) + " is more than 2^30 spacings from the lattice origin");
    }
    cells.emplace_back(static_cast<int>(cell.x()), static_cast<int>(cell.y()), static_cast<int>(cell.z()));
  }
  return meshCells(cells, particleSpacing, options.latticeOrigin, options.surface);
}

}  // namespace physketch::render
