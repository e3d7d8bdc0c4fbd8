// meshVoxels, meshParticles and writeLevelSetsVdb: the one translation unit that includes OpenVDB
// (its headers cost ~3 s to parse; stack.md §7). It uses only tools that libopenvdb instantiates
// explicitly (topologyToLevelSet, volumeToMesh, LevelSetFilter, LevelSetMeasure), so this TU
// compiles in seconds and runs at full speed even in Debug builds.
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetFilter.h>
#include <openvdb/tools/LevelSetMeasure.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tools/TopologyToLevelSet.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <mutex>
#include <set>
#include <string>

#include <tbb/parallel_for.h>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/profile.h"
#include "render/dense_level_set.h"
#include "render/fluid_surface.h"
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

// The steps the volume target and the smoothing take, for both representations of a level set
// (OpenVDB's grid, the reference; DenseLevelSet, the same updates on a dense box).
//
// Area (m^2) and enclosed volume (m^3).
void measure(openvdb::FloatGrid& sdf, double& area, double& volume) {
  openvdb::tools::LevelSetMeasure<openvdb::FloatGrid> m(sdf);
  area = m.area();
  volume = m.volume();
}
void measure(DenseLevelSet& ls, double& area, double& volume) { ls.measure(area, volume); }

// Adds d to every band value. A shifted distance field is still one, so this is a plain add,
// not LevelSetFilter's offset, whose renormalization cost as much as a smoothing iteration
// (13 ms on a 20k-cell ball) and changes nothing here.
void offsetBand(openvdb::FloatGrid& sdf, float d) {
  for (auto it = sdf.beginValueOn(); it; ++it) it.setValue(*it + d);
}
void offsetBand(DenseLevelSet& ls, float d) { ls.offset(d); }

// `iterations` steps of mean-curvature flow, each ending with the band renormalized
// (|grad phi| = 1) by one first-order upwind sweep, then the whole band once more.
// LevelSetFilter's default renormalizes with three fifth-order HJWENO5 sweeps, 70 % of the
// smoothing's time; one first-order sweep (what topologyToLevelSet itself renormalizes with)
// keeps the zero crossing as well for a surface that moves under a voxel per iteration:
// bench_render's sphere of 7,153 particles after 2 iterations is 0.672 mm RMS off the true
// sphere against 0.684 mm, and the frame's smoothing takes 59 ms against 233
// (docs/benchmarks.md). The final sweeps over the whole band: LevelSetMeasure's volume, and so
// the volume correction after the flow, assumes a distance field (without them the measured
// volume was 2.1 % off the mesh's). LevelSetFilter's parallel loops write disjoint voxels, so
// the result does not depend on the thread count.
void meanCurvatureFlow(openvdb::FloatGrid& sdf, int iterations) {
  openvdb::tools::LevelSetFilter<openvdb::FloatGrid> filter(sdf);
  filter.setSpatialScheme(openvdb::math::FIRST_BIAS);
  const int bandSweeps = filter.getNormCount();
  filter.setNormCount(1);
  for (int i = 0; i < iterations; ++i) filter.meanCurvature();
  filter.setNormCount(bandSweeps);
  filter.normalize();
}
void meanCurvatureFlow(DenseLevelSet& ls, int iterations) {
  for (int i = 0; i < iterations; ++i) ls.meanCurvature(1);
  ls.normalize(3);  // LevelSetFilter's default count
}

// Moves the level set's surface along its normal until it encloses `target` (m^3): adding d to
// every distance moves the surface by -d, and dV = A dn, so d = (V - target) / A, twice (the
// second pass corrects the first's change of area). Area and volume in one measure per pass.
template <typename LevelSet>
void offsetToVolume(LevelSet& ls, double target) {
  for (int pass = 0; pass < 2; ++pass) {
    double area = 0.0, volume = 0.0;
    measure(ls, area, volume);
    if (!(area > 0.0)) return;
    offsetBand(ls, static_cast<float>((volume - target) / area));
  }
}

// Mean-curvature flow on the level set, then a dilation by the lost volume over the area
// (offsetToVolume). report: the volume before and after.
template <typename LevelSet>
void smoothLevelSet(LevelSet& ls, int iterations, SmoothingReport* report) {
  if (iterations <= 0) return;
  double area = 0.0, before = 0.0, after = 0.0;
  measure(ls, area, before);
  meanCurvatureFlow(ls, iterations);
  offsetToVolume(ls, before);
  if (report) {
    measure(ls, area, after);
    report->volumeBefore = before;
    report->volumeAfter = after;
  }
}

// The dense level set as an OpenVDB level set: a leaf for every 8^3 block with a band voxel
// (values as they are, inactive ones +-background), an inactive interior tile of -background
// for a block wholly inside, nothing (the +background background) for one wholly outside.
openvdb::FloatGrid::Ptr toGrid(const DenseLevelSet& ls, const openvdb::math::Transform::Ptr& xform) {
  using Leaf = openvdb::FloatGrid::TreeType::LeafNodeType;
  const float background = ls.background();
  openvdb::FloatGrid::Ptr sdf = openvdb::FloatGrid::create(background);
  sdf->setTransform(xform);
  sdf->setGridClass(openvdb::GRID_LEVEL_SET);
  openvdb::FloatTree& tree = sdf->tree();
  const Vec3i lo = ls.lo(), hi = ls.lo() + ls.dims() - Vec3i::Ones();
  const std::vector<float>& phi = ls.values();
  std::array<float, Leaf::SIZE> values;
  std::array<bool, Leaf::SIZE> on;
  for (int bz = lo.z() & ~7; bz <= hi.z(); bz += 8)
    for (int by = lo.y() & ~7; by <= hi.y(); by += 8)
      for (int bx = lo.x() & ~7; bx <= hi.x(); bx += 8) {
        bool anyOn = false, anyInside = false, anyOutside = false;
        for (int x = 0; x < 8; ++x)
          for (int y = 0; y < 8; ++y)
            for (int z = 0; z < 8; ++z) {
              const Vec3i c(bx + x, by + y, bz + z);
              const openvdb::Index o = Leaf::coordToOffset(openvdb::Coord(c.x(), c.y(), c.z()));
              float v = background;
              bool a = false;
              if ((c.array() >= lo.array()).all() && (c.array() <= hi.array()).all()) {
                const Vec3i r = c - lo;
                const std::size_t i = ls.index(r.x(), r.y(), r.z());
                v = phi[i];
                a = ls.active(i);
              }
              values[o] = v;
              on[o] = a;
              anyOn = anyOn || a;
              (v < 0.0f ? anyInside : anyOutside) = true;
            }
        const openvdb::Coord origin(bx, by, bz);
        if (anyOn || (anyInside && anyOutside)) {
          Leaf* leaf = tree.touchLeaf(origin);
          for (openvdb::Index o = 0; o < Leaf::SIZE; ++o) {
            leaf->setValueOnly(o, values[o]);
            leaf->setActiveState(o, on[o]);
          }
        } else if (anyInside) {
          tree.addTile(1, origin, -background, false);
        }
      }
  openvdb::tools::pruneLevelSet(tree);
  return sdf;
}

// Cells (i,j,k) with centres origin + h*(i,j,k) -> narrow-band signed distance field in world
// units (nullptr for no cells), moved to enclose targetVolume when it is > 0, then smoothed.
// Options are checked by the caller.
openvdb::FloatGrid::Ptr levelSetOfCells(const std::vector<Vec3i>& cells, double voxelSize,
                                        const Vec3& origin, const VoxelMeshOptions& options, int smoothIterations,
                                        SmoothingReport* report, MeshStageTimes* times = nullptr,
                                        double targetVolume = 0.0) {
  if (cells.empty()) return nullptr;
  initializeOpenVdbOnce();

  // Index space = the lattice: OpenVDB puts voxel (i,j,k)'s centre at index (i,j,k),
  // so world = origin + h*(i,j,k) is a uniform scale followed by a translation.
  openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform(voxelSize);
  xform->postTranslate(openvdb::Vec3d(origin.x(), origin.y(), origin.z()));

  if (options.denseLevelSet &&
      DenseLevelSet::boxVoxels(cells, options.halfWidth, options.closingSteps) <= kDenseLevelSetVoxels) {
    DenseLevelSet ls = DenseLevelSet::fromCells(cells, voxelSize, options.halfWidth, options.closingSteps,
                                                options.smoothingSteps);
    if (targetVolume > 0.0) offsetToVolume(ls, targetVolume);
    const double built = nowSeconds();
    smoothLevelSet(ls, smoothIterations, report);
    if (times) times->smoothing = nowSeconds() - built;
    // A band that reached the box's edge could not grow as OpenVDB's would: build it again
    // with OpenVDB's tools (not seen in practice: the margin is 4 voxels past the band).
    if (!ls.reachedBorder()) {
      if (times) times->denseLevelSet = true;
      return toGrid(ls, xform);
    }
  }
  if (times) times->denseLevelSet = false;

  openvdb::BoolGrid::Ptr grid = openvdb::BoolGrid::create(false);
  grid->setTransform(xform);
  {
    // Serial: the grid's topology is the set of cells, whatever their order or repeats.
    openvdb::BoolGrid::Accessor acc = grid->getAccessor();
    for (const Vec3i& c : cells) acc.setValueOn(openvdb::Coord(c.x(), c.y(), c.z()), true);
  }

  // The level set's zero crossing lies on the boundary between active and inactive voxels,
  // i.e. on the cube faces of the voxel union (before smoothing).
  openvdb::FloatGrid::Ptr sdf = openvdb::tools::topologyToLevelSet(
      *grid, options.halfWidth, options.closingSteps, /*dilation=*/0, options.smoothingSteps);
  if (targetVolume > 0.0) offsetToVolume(*sdf, targetVolume);
  const double built = nowSeconds();
  smoothLevelSet(*sdf, smoothIterations, report);
  if (times) times->smoothing = nowSeconds() - built;
  return sdf;
}

TriangleMesh meshLevelSet(const openvdb::FloatGrid* sdf, double adaptivity, double isovalue = 0.0) {
  if (!sdf) return {};
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(*sdf, points, triangles, quads, isovalue, adaptivity);
  return assemble(points, triangles, quads);
}


}  // namespace

TriangleMesh meshVoxels(const std::vector<Vec3i>& voxels, double voxelSize, const Vec3& origin,
                        const VoxelMeshOptions& options) {
  checkOptions("meshVoxels", voxelSize, origin, options);
  const openvdb::FloatGrid::Ptr sdf = levelSetOfCells(voxels, voxelSize, origin, options, 0, nullptr);
  return meshLevelSet(sdf.get(), options.adaptivity);
}

std::vector<Vec3i> particleCells(const std::vector<Vec3>& positions, double particleSpacing, const Vec3& latticeOrigin) {
  if (!(particleSpacing > 0.0) || !std::isfinite(particleSpacing)) {
    throw RuntimeError("meshParticles: particle spacing must be finite and > 0 m");
  }
  if (!latticeOrigin.allFinite()) throw RuntimeError("meshParticles: lattice origin must be finite");
  // |index| <= 2^30 leaves OpenVDB's int32 coordinates room for the narrow band and closing.
  constexpr double kMaxIndex = 1073741824.0;
  std::vector<Vec3i> cells;
  cells.reserve(positions.size());
  for (std::size_t i = 0; i < positions.size(); ++i) {
    const Vec3& p = positions[i];
    if (!p.allFinite()) throw RuntimeError("meshParticles: particle " + std::to_string(i) + " position is not finite");
    // Nearest cell centre: round((p - origin) / h), ties upward (floor(x + 0.5)), so the
    // cell is a pure function of the position.
    const Vec3 index = ((p - latticeOrigin) / particleSpacing).array() + 0.5;
    const Vec3 cell = index.array().floor();
    if (cell.cwiseAbs().maxCoeff() > kMaxIndex) {
      throw RuntimeError("meshParticles: particle " + std::to_string(i) + " is more than 2^30 spacings from the lattice origin");
    }
    cells.emplace_back(static_cast<int>(cell.x()), static_cast<int>(cell.y()), static_cast<int>(cell.z()));
  }
  return cells;
}

namespace {

// The lattice cells particles mark (particleCells), as a sorted set. Cells within +-2^20 of the
// origin pack into 63 bits; farther ones are left out (a particle 2^20 spacings out is spray, not
// part of a body's surface).
class CellSet {
 public:
  explicit CellSet(const std::vector<Vec3i>& cells) {
    keys_.reserve(cells.size());
    for (const Vec3i& c : cells)
      if (inRange(c)) keys_.push_back(key(c));
    std::sort(keys_.begin(), keys_.end());
  }
  static bool inRange(const Vec3i& c) { return c.cwiseAbs().maxCoeff() < kReach - 1; }
  bool has(const Vec3i& c) const { return std::binary_search(keys_.begin(), keys_.end(), key(c)); }

 private:
  static constexpr int kReach = 1 << 20;
  static std::uint64_t key(const Vec3i& c) {
    return (std::uint64_t(c.x() + kReach) << 42) | (std::uint64_t(c.y() + kReach) << 21) | std::uint64_t(c.z() + kReach);
  }
  std::vector<std::uint64_t> keys_;
};

}  // namespace

std::vector<std::uint8_t> enclosedParticles(const std::vector<Vec3>& positions, double particleSpacing,
                                            const Vec3& latticeOrigin) {
  const std::vector<Vec3i> cells = particleCells(positions, particleSpacing, latticeOrigin);
  const CellSet set(cells);
  std::vector<std::uint8_t> enclosed(cells.size(), 0);
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const Vec3i& c = cells[i];
    enclosed[i] = CellSet::inRange(c) && set.has(c + Vec3i(1, 0, 0)) && set.has(c - Vec3i(1, 0, 0)) &&
                  set.has(c + Vec3i(0, 1, 0)) && set.has(c - Vec3i(0, 1, 0)) && set.has(c + Vec3i(0, 0, 1)) &&
                  set.has(c - Vec3i(0, 0, 1));
  }
  return enclosed;
}

std::vector<Vec3> particleNormals(const std::vector<Vec3>& positions, double particleSpacing, const Vec3& latticeOrigin,
                                  const std::vector<std::uint8_t>* skip) {
  const std::vector<Vec3i> cells = particleCells(positions, particleSpacing, latticeOrigin);
  if (skip && skip->size() != cells.size()) throw RuntimeError("particleNormals: skip and positions differ in length");
  const CellSet set(cells);
  std::vector<Vec3> normals(cells.size(), Vec3::Zero());
  for (std::size_t i = 0; i < cells.size(); ++i) {
    if (!CellSet::inRange(cells[i]) || (skip && (*skip)[i])) continue;
    Vec3 sum = Vec3::Zero();
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const Vec3i d(dx, dy, dz);
          if (d == Vec3i::Zero() || set.has(cells[i] + d)) continue;
          sum += d.cast<double>().normalized();
        }
    // Empty cells all round cancel (a lone particle, a sheet one cell thick): no direction.
    if (sum.norm() > 1e-6) normals[i] = sum.normalized();
  }
  return normals;
}

TriangleMesh meshParticles(const std::vector<Vec3>& positions, double particleSpacing,
                           const ParticleMeshOptions& options, SmoothingReport* report, MeshStageTimes* times) {
  checkOptions("meshParticles", particleSpacing, options.latticeOrigin, options.surface);
  if (options.smoothIterations < 0) throw RuntimeError("meshParticles: smoothIterations must be >= 0");
  if (!(options.targetVolume >= 0.0) || !std::isfinite(options.targetVolume))
    throw RuntimeError("meshParticles: targetVolume must be finite and >= 0");
  if (report) *report = SmoothingReport{};
  MeshStageTimes local;
  const double t0 = nowSeconds();
  const std::vector<Vec3i> cells = particleCells(positions, particleSpacing, options.latticeOrigin);
  const double t1 = nowSeconds();
  const openvdb::FloatGrid::Ptr sdf = levelSetOfCells(cells, particleSpacing, options.latticeOrigin,
                                                      options.surface, options.smoothIterations, report, &local,
                                                      options.targetVolume);
  const double t2 = nowSeconds();
  TriangleMesh mesh = meshLevelSet(sdf.get(), options.surface.adaptivity);
  if (options.targetVolume > 0.0 && !mesh.empty()) {
    // The dual mesh cuts the level set's corners (1.3 % of a ball's volume unsmoothed): the
    // surface moves out by the shortfall over the mesh's area (dV = A dn). A move under a
    // quarter of a voxel moves the vertices along their normals, which is what meshing again at
    // that isovalue gives to first order, at a tenth of its cost; a larger or an inward one
    // meshes again.
    const double shortfall = options.targetVolume - enclosedVolume(mesh), area = surfaceArea(mesh);
    if (area > 0.0 && std::abs(shortfall) > 2e-3 * options.targetVolume) {
      const double move = shortfall / area;
      // Outwards only: moved inwards, a sheet thinner than twice the move would fold over,
      // where meshing again opens a hole as the level set does.
      if (move > 0.0 && move < 0.25 * particleSpacing) {
        for (std::size_t i = 0; i < mesh.positions.size(); ++i)
          mesh.positions[i] += static_cast<float>(move) * mesh.normals[i];
      } else {
        mesh = meshLevelSet(sdf.get(), options.surface.adaptivity, move);
      }
    }
  }
  if (times) {
    times->cells = t1 - t0;
    times->levelSet = t2 - t1 - local.smoothing;
    times->smoothing = local.smoothing;
    times->meshing = nowSeconds() - t2;
    times->denseLevelSet = local.denseLevelSet;
  }
  return mesh;
}

TriangleMesh meshKernelField(const FluidKernels& kernels, double voxelSize, double iso, double targetVolume,
                             double* isoUsed) {
  const std::size_t n = kernels.centre.size();
  if (kernels.inverseAxes.size() != n || kernels.weight.size() != n || kernels.interior.size() != n)
    throw RuntimeError("meshKernelField: centre, inverseAxes, weight and interior differ in length");
  if (!(voxelSize > 0.0) || !std::isfinite(voxelSize)) throw RuntimeError("meshKernelField: voxel size must be finite and > 0 m");
  if (!(iso > 0.0) || !std::isfinite(iso)) throw RuntimeError("meshKernelField: iso must be finite and > 0");
  if (!(targetVolume >= 0.0) || !std::isfinite(targetVolume)) throw RuntimeError("meshKernelField: target volume must be finite and >= 0");
  if (isoUsed) *isoUsed = iso;
  if (n == 0) return {};
  initializeOpenVdbOnce();
  // Each kernel's voxel box: the ellipsoid |M (x - c)| < 1 reaches |row e of M^-1| along
  // axis e; an interior kernel fills the cube of +-fillRadius.
  struct Box {
    Vec3i lo, hi;
  };
  std::vector<Box> boxes(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Vec3& c = kernels.centre[i];
    const Mat3 A = kernels.inverseAxes[i].inverse();
    if (!c.allFinite() || (c / voxelSize).cwiseAbs().maxCoeff() > 1e9 || !A.allFinite() ||
        !std::isfinite(kernels.weight[i]))
      throw RuntimeError("meshKernelField: kernel " + std::to_string(i) + " is not finite, degenerate or too far out");
    const Vec3 ext = kernels.interior[i] ? Vec3::Constant(kernels.fillRadius) : Vec3(A.rowwise().norm());
    boxes[i] = {((c - ext) / voxelSize).array().ceil().cast<int>(), ((c + ext) / voxelSize).array().floor().cast<int>()};
  }
  // Kernels in the order of their centre's 8^3 block (then index), so the accessor's cached leaf
  // is usually the one written next. Every voxel sums its kernels in this order.
  std::vector<std::array<std::int64_t, 4>> order(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Vec3 c = kernels.centre[i] / voxelSize;
    order[i] = {static_cast<std::int64_t>(std::floor(c.z() / 8.0)), static_cast<std::int64_t>(std::floor(c.y() / 8.0)),
                static_cast<std::int64_t>(std::floor(c.x() / 8.0)), static_cast<std::int64_t>(i)};
  }
  std::sort(order.begin(), order.end());
  int zMin = boxes[0].lo.z(), zMax = boxes[0].hi.z();
  for (const Box& b : boxes) {
    zMin = std::min(zMin, b.lo.z());
    zMax = std::max(zMax, b.hi.z());
  }
  // Slabs of kSlab voxels in z, a multiple of a leaf's 8, so no two slabs share a leaf: each is
  // summed into its own grid, in parallel, and the grids are merged by moving leaves. A voxel's
  // value is the same whichever slab holds it (same kernels, same order), so the field does not
  // depend on the thread count or on the slab width.
  constexpr int kSlab = 32;
  const int zFirst = static_cast<int>(std::floor(zMin / double(kSlab))) * kSlab;
  const int slabs = (zMax - zFirst) / kSlab + 1;
  const float inside = static_cast<float>(kernels.interiorField);
  std::vector<openvdb::FloatGrid::Ptr> parts(static_cast<std::size_t>(slabs));
  tbb::parallel_for(0, slabs, [&](int slab) {
    const int z0 = zFirst + slab * kSlab, z1 = z0 + kSlab - 1;
    // The field is stored as it is (background 0 outside, inside above iso): volumeToMesh then
    // winds it opposite to a level set (inside below the isovalue), which is what assemble's
    // reversal expects.
    openvdb::FloatGrid::Ptr part = openvdb::FloatGrid::create(0.0f);
    openvdb::FloatGrid::Accessor acc = part->getAccessor();
    using Leaf = openvdb::FloatGrid::TreeType::LeafNodeType;
    for (const auto& o : order) {
      const std::size_t i = static_cast<std::size_t>(o[3]);
      const Box& b = boxes[i];
      if (kernels.interior[i] || b.hi.z() < z0 || b.lo.z() > z1) continue;
      const Mat3& M = kernels.inverseAxes[i];
      const Vec3& c = kernels.centre[i];
      const double w = kernels.weight[i];
      const int za = std::max(b.lo.z(), z0), zb = std::min(b.hi.z(), z1);
      const Vec3 step = M.col(2) * voxelSize;
      const double sx = step.x(), sy = step.y(), sz = step.z();
      for (int x = b.lo.x(); x <= b.hi.x(); ++x)
        for (int y = b.lo.y(); y <= b.hi.y(); ++y) {
          const Vec3 u0 = M * (voxelSize * Vec3(x, y, za) - c);
          // u in three scalars (as a Vec3 it lived on the stack), the same operations.
          double ux = u0.x(), uy = u0.y(), uz = u0.z();
          // The run's voxels straight in their leaf's buffer (what acc.setValue does, without
          // finding the leaf again for every voxel); a leaf is made only where a voxel is hit.
          Leaf* leaf = nullptr;
          int leafZ = 0;
          for (int z = za; z <= zb; ++z, ux += sx, uy += sy, uz += sz) {
            const double r2 = (ux * ux + uy * uy) + uz * uz;
            if (r2 >= 1.0) continue;
            const double t = 1.0 - r2;
            const openvdb::Coord ijk(x, y, z);
            if (!leaf || (z & ~int(Leaf::DIM - 1)) != leafZ) {
              leaf = acc.touchLeaf(ijk);
              leafZ = z & ~int(Leaf::DIM - 1);
            }
            const openvdb::Index offset = Leaf::coordToOffset(ijk);
            float* value = leaf->buffer().data() + offset;
            *value = *value + static_cast<float>(w * t * t * t);
            leaf->setValueOn(offset);
          }
        }
    }
    // Interior kernels after every sum: each raises its cube to the interior field (a max, so
    // the order among them does not matter).
    for (const auto& o : order) {
      const std::size_t i = static_cast<std::size_t>(o[3]);
      const Box& b = boxes[i];
      if (!kernels.interior[i] || b.hi.z() < z0 || b.lo.z() > z1) continue;
      for (int x = b.lo.x(); x <= b.hi.x(); ++x)
        for (int y = b.lo.y(); y <= b.hi.y(); ++y)
          for (int z = std::max(b.lo.z(), z0); z <= std::min(b.hi.z(), z1); ++z) {
            const openvdb::Coord ijk(x, y, z);
            if (acc.getValue(ijk) < inside) acc.setValue(ijk, inside);
          }
    }
    parts[static_cast<std::size_t>(slab)] = part;
  });
  openvdb::FloatGrid::Ptr grid = parts[0];
  for (std::size_t s = 1; s < parts.size(); ++s) grid->tree().merge(parts[s]->tree());
  grid->setTransform(openvdb::math::Transform::createLinearTransform(voxelSize));
  if (targetVolume > 0.0) {
    // The level in [iso / 2, iso] whose inside holds targetVolume: each voxel centre inside
    // stands for one voxel of volume (an unbiased count for a surface smooth on the voxel
    // scale). The values are collected in the tree's fixed order and selected by rank, so the
    // level is a pure function of the field.
    std::vector<float> values;
    for (auto it = grid->cbeginValueOn(); it; ++it)
      if (*it > 0.5 * iso) values.push_back(*it);
    const double voxel = voxelSize * voxelSize * voxelSize;
    const std::size_t want = static_cast<std::size_t>(std::llround(targetVolume / voxel));
    double level = 0.5 * iso;
    if (want == 0) {
      level = iso;
    } else if (want <= values.size()) {
      std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(want - 1), values.end(), std::greater<float>());
      level = std::clamp(static_cast<double>(values[want - 1]), 0.5 * iso, iso);
    }
    iso = level;
    if (isoUsed) *isoUsed = iso;
  }
  return meshLevelSet(grid.get(), 0.0, iso);
}

TriangleMesh meshNodeField(const NodeField& field, double iso, double targetVolume, double* levelUsed) {
  if (!(field.spacing > 0.0) || !std::isfinite(field.spacing)) throw RuntimeError("meshNodeField: spacing must be finite and > 0 m");
  if (!(iso > 0.0) || !std::isfinite(iso)) throw RuntimeError("meshNodeField: iso must be finite and > 0");
  if (!field.origin.allFinite()) throw RuntimeError("meshNodeField: origin must be finite");
  if ((field.size.array() < 0).any() || field.values.size() != std::size_t(field.size.cast<std::int64_t>().prod()))
    throw RuntimeError("meshNodeField: " + std::to_string(field.values.size()) + " values for a box of " +
                       std::to_string(field.size.x()) + " x " + std::to_string(field.size.y()) + " x " +
                       std::to_string(field.size.z()) + " nodes");
  if (!(targetVolume >= 0.0) || !std::isfinite(targetVolume)) throw RuntimeError("meshNodeField: target volume must be finite and >= 0");
  if (levelUsed) *levelUsed = iso;
  if (field.values.empty()) return {};
  initializeOpenVdbOnce();
  // Stored as it is (background 0, inside above iso), as meshKernelField's field.
  openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(0.0f);
  openvdb::FloatGrid::Accessor acc = grid->getAccessor();
  for (int k = 0; k < field.size.z(); ++k)
    for (int j = 0; j < field.size.y(); ++j)
      for (int i = 0; i < field.size.x(); ++i) {
        const float v = field.at(i, j, k);
        if (!std::isfinite(v))
          throw RuntimeError("meshNodeField: value at node (" + std::to_string(i) + ", " + std::to_string(j) + ", " +
                             std::to_string(k) + ") is not finite");
        if (v != 0.0f) acc.setValue(openvdb::Coord(i, j, k), v);
      }
  openvdb::math::Transform::Ptr xf = openvdb::math::Transform::createLinearTransform(field.spacing);
  xf->postTranslate(openvdb::Vec3d(field.origin.x(), field.origin.y(), field.origin.z()));
  grid->setTransform(xf);
  TriangleMesh mesh = meshLevelSet(grid.get(), 0.0, iso);
  if (targetVolume <= 0.0) return mesh;
  // The enclosed volume falls as the level rises: regula falsi (Illinois) on V(level) - target
  // within [iso / 2, 3 iso / 2], from iso, to 0.2 % of the target or 6 more meshings.
  const auto miss = [&](const TriangleMesh& m) { return enclosedVolume(m) - targetVolume; };
  double a = iso, fa = miss(mesh);
  const double tolerance = 2e-3 * targetVolume;
  if (std::abs(fa) <= tolerance) return mesh;
  double b = fa > 0.0 ? 1.5 * iso : 0.5 * iso;
  TriangleMesh mb = meshLevelSet(grid.get(), 0.0, b);
  double fb = miss(mb);
  if ((fa > 0.0) == (fb > 0.0)) {  // the range's end still misses: the nearer one
    if (levelUsed) *levelUsed = std::abs(fb) < std::abs(fa) ? b : a;
    return std::abs(fb) < std::abs(fa) ? mb : mesh;
  }
  double best = b, fbest = fb;
  TriangleMesh mbest = std::move(mb);
  if (std::abs(fa) < std::abs(fb)) {
    best = a;
    fbest = fa;
    mbest = std::move(mesh);
  }
  int side = 0;
  for (int it = 0; it < 6 && std::abs(fbest) > tolerance; ++it) {
    const double c = (a * fb - b * fa) / (fb - fa);
    TriangleMesh mc = meshLevelSet(grid.get(), 0.0, c);
    const double fc = miss(mc);
    if ((fc > 0.0) == (fb > 0.0)) {
      b = c;
      fb = fc;
      if (side == -1) fa *= 0.5;
      side = -1;
    } else {
      a = c;
      fa = fc;
      if (side == 1) fb *= 0.5;
      side = 1;
    }
    if (std::abs(fc) < std::abs(fbest)) {
      best = c;
      fbest = fc;
      mbest = std::move(mc);
    }
  }
  if (levelUsed) *levelUsed = best;
  return mbest;
}

std::vector<std::uint64_t> writeLevelSetsVdb(const std::string& path, const std::vector<LevelSetGrid>& grids,
                                             double voxelSize, const Vec3& origin) {
  initializeOpenVdbOnce();
  openvdb::GridPtrVec out;
  std::vector<std::uint64_t> active;
  std::set<std::string> names;
  for (const LevelSetGrid& g : grids) {
    const std::string who = "writeLevelSetsVdb: grid '" + g.name + "'";
    checkOptions(who.c_str(), voxelSize, origin, g.surface);
    if (g.smoothIterations < 0) throw RuntimeError(who + ": smoothIterations must be >= 0");
    if (!names.insert(g.name).second) throw RuntimeError(who + ": name used twice");
    if (!g.model.allFinite() || g.model.row(3) != Eigen::RowVector4d(0, 0, 0, 1) ||
        !(std::abs(g.model.topLeftCorner<3, 3>().determinant()) > 0.0)) {
      throw RuntimeError(who + ": model must be a finite, invertible affine matrix");
    }
    openvdb::FloatGrid::Ptr sdf;
    if (!g.mesh.empty()) {
      if (!g.cells.empty() || g.model != Eigen::Matrix4d::Identity())
        throw RuntimeError(who + ": a mesh grid takes no cells and no model");
      openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform(voxelSize);
      xform->postTranslate(openvdb::Vec3d(origin.x(), origin.y(), origin.z()));
      std::vector<openvdb::Vec3s> points;
      points.reserve(g.mesh.positions.size());
      for (const Vec3f& v : g.mesh.positions) points.emplace_back(v.x(), v.y(), v.z());
      std::vector<openvdb::Vec3I> triangles;
      for (std::size_t t = 0; t + 2 < g.mesh.indices.size(); t += 3)
        triangles.emplace_back(g.mesh.indices[t], g.mesh.indices[t + 1], g.mesh.indices[t + 2]);
      openvdb::util::NullInterrupter interrupt;
      sdf = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(interrupt, *xform, points, triangles,
                                                               static_cast<float>(g.surface.halfWidth));
    } else {
      sdf = levelSetOfCells(g.cells, voxelSize, origin, g.surface, g.smoothIterations, nullptr, nullptr,
                            g.targetVolume);
    }
    if (!sdf) sdf = openvdb::createLevelSet<openvdb::FloatGrid>(voxelSize, double(g.surface.halfWidth));
    // index -> world: lattice scale and offset, then the body's pose. OpenVDB matrices act on
    // row vectors (p' = p M), the transpose of Eigen's column convention.
    Eigen::Matrix4d lattice = Eigen::Matrix4d::Identity();
    lattice.topLeftCorner<3, 3>() *= voxelSize;
    lattice.topRightCorner<3, 1>() = origin;
    const Eigen::Matrix4d world = g.model * lattice;
    openvdb::math::Mat4d m;
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) m(c, r) = world(r, c);
    sdf->setTransform(openvdb::math::Transform::createLinearTransform(m));
    sdf->setName(g.name);
    sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    sdf->insertMeta("material", openvdb::StringMetadata(g.material));
    active.push_back(sdf->activeVoxelCount());
    out.push_back(sdf);
  }
  // io::File writes by name: write under the AtomicFile's temporary name, then commit renames
  // it (the FILE* it holds has had nothing written through it, so closing it changes nothing).
  AtomicFile file(path);
  try {
    openvdb::io::File vdb(file.tmpPath());
    vdb.write(out);
    vdb.close();
  } catch (const std::exception& e) {
    file.fail(std::string("OpenVDB write failed: ") + e.what());
  }
  file.commit();
  return active;
}

}  // namespace physketch::render
