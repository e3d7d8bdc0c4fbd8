// DenseLevelSet against OpenVDB's own tools, voxel by voxel: the oracle is the library whose
// updates it repeats (topologyToLevelSet, LevelSetFilter::meanCurvature / normalize,
// LevelSetMeasure), run here on the same cells. The values must be the same floats, bit for bit:
// both run the same float operations in the same order, and the project builds with
// -ffp-contract=off (no fused multiply-adds). The measures sum in another order than
// LevelSetMeasure (which adds sorted per-leaf sums), so they agree to 1e-9 relative: double
// rounding over ~10^4 terms of mixed sign is ~1e-12, the bound leaves room.
#include <gtest/gtest.h>
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetFilter.h>
#include <openvdb/tools/LevelSetMeasure.h>
#include <openvdb/tools/TopologyToLevelSet.h>
#include <tbb/global_control.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "render/dense_level_set.h"
#include "render/voxel_mesh.h"

namespace physketch::render {
namespace {

constexpr double kH = 0.01;

// Cells of a ball of radius r (voxels) on a lattice turned by `angle` about a tilted axis and
// shifted off the cell centres, as a spinning soft body's particles mark them (holes and
// doubles included).
std::vector<Vec3i> turnedBall(double r, double angle) {
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(angle, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  std::vector<Vec3> p;
  const int n = int(std::ceil(r));
  for (int k = -n; k <= n; ++k)
    for (int j = -n; j <= n; ++j)
      for (int i = -n; i <= n; ++i)
        if (Vec3(i, j, k).norm() <= r) p.push_back(kH * (turn * Vec3(i, j, k) + Vec3(0.3, -0.2, 0.1)));
  return particleCells(p, kH, Vec3::Zero());
}

// A plate one cell thick with a post on it: thin features, concave edges.
std::vector<Vec3i> plateWithPost() {
  std::vector<Vec3i> c;
  for (int i = -8; i <= 8; ++i)
    for (int k = -5; k <= 5; ++k) c.emplace_back(i, 0, k);
  for (int j = 1; j <= 6; ++j) c.emplace_back(2, j, 1);
  return c;
}

openvdb::FloatGrid::Ptr vdbOfCells(const std::vector<Vec3i>& cells, int halfWidth, int closing, int smoothing) {
  openvdb::initialize();
  openvdb::BoolGrid::Ptr grid = openvdb::BoolGrid::create(false);
  grid->setTransform(openvdb::math::Transform::createLinearTransform(kH));
  auto acc = grid->getAccessor();
  for (const Vec3i& c : cells) acc.setValueOn(openvdb::Coord(c.x(), c.y(), c.z()), true);
  return openvdb::tools::topologyToLevelSet(*grid, halfWidth, closing, 0, smoothing);
}

struct Difference {
  std::size_t onlyDense = 0, onlyVdb = 0, compared = 0;
  double maxValue = 0.0;  // largest |phi_dense - phi_vdb| over every box voxel (voxels)
};

// Every voxel of the dense box against the OpenVDB grid (active states and values, inactive
// ones included), and OpenVDB's active voxels outside the box (there should be none).
Difference compare(const DenseLevelSet& ls, const openvdb::FloatGrid& vdb) {
  Difference d;
  auto acc = vdb.getConstAccessor();
  const Vec3i& n = ls.dims();
  std::size_t i = 0;
  for (int z = 0; z < n.z(); ++z)
    for (int y = 0; y < n.y(); ++y)
      for (int x = 0; x < n.x(); ++x, ++i) {
        const Vec3i c = ls.lo() + Vec3i(x, y, z);
        const openvdb::Coord ijk(c.x(), c.y(), c.z());
        const bool on = acc.isValueOn(ijk);
        d.onlyDense += ls.active(i) && !on;
        d.onlyVdb += on && !ls.active(i);
        d.compared += on;
        d.maxValue = std::max(d.maxValue, std::abs(double(ls.values()[i]) - double(acc.getValue(ijk))) / kH);
      }
  std::size_t vdbOn = 0;
  for (auto it = vdb.cbeginValueOn(); it; ++it) ++vdbOn;
  d.onlyVdb += vdbOn - d.compared;  // active voxels beyond the box
  return d;
}

void expectSame(const DenseLevelSet& ls, const openvdb::FloatGrid& vdb, const char* what) {
  const Difference d = compare(ls, vdb);
  EXPECT_GT(d.compared, 0u) << what;
  EXPECT_EQ(d.onlyDense, 0u) << what;
  EXPECT_EQ(d.onlyVdb, 0u) << what;
  EXPECT_EQ(d.maxValue, 0.0) << what;
  if (std::getenv("DENSE_LS_PRINT")) std::printf("%s: max |difference| %.3g voxels over %zu voxels\n", what, d.maxValue, d.compared);
}

TEST(DenseLevelSet, BuildsWhatTopologyToLevelSetBuilds) {
  const std::vector<std::vector<Vec3i>> shapes = {turnedBall(9.0, 0.7), plateWithPost(), {Vec3i(4, -3, 2)},
                                                  {Vec3i(0, 0, 0), Vec3i(9, 0, 0)}};
  for (std::size_t s = 0; s < shapes.size(); ++s)
    for (int halfWidth : {1, 2, 3})
      for (int closing : {0, 1, 2})
        for (int smoothing : {0, 1, 2}) {
          SCOPED_TRACE("shape " + std::to_string(s) + ", half width " + std::to_string(halfWidth) + ", closing " +
                       std::to_string(closing) + ", smoothing " + std::to_string(smoothing));
          const DenseLevelSet ls = DenseLevelSet::fromCells(shapes[s], kH, halfWidth, closing, smoothing);
          expectSame(ls, *vdbOfCells(shapes[s], halfWidth, closing, smoothing), "fromCells");
        }
}

TEST(DenseLevelSet, FlowsMeasuresAndOffsetsAsLevelSetFilterAndLevelSetMeasure) {
  const std::vector<Vec3i> cells = turnedBall(12.0, 0.4);
  DenseLevelSet ls = DenseLevelSet::fromCells(cells, kH, 3, 1, 1);
  openvdb::FloatGrid::Ptr vdb = vdbOfCells(cells, 3, 1, 1);

  auto measures = [&](const char* what) {
    double area = 0.0, volume = 0.0;
    ls.measure(area, volume);
    openvdb::tools::LevelSetMeasure<openvdb::FloatGrid> m(*vdb);
    EXPECT_NEAR(area, m.area(), 1e-9 * m.area()) << what;
    EXPECT_NEAR(volume, m.volume(), 1e-9 * m.volume()) << what;
  };
  measures("built");

  ls.offset(float(0.3 * kH));
  for (auto it = vdb->beginValueOn(); it; ++it) it.setValue(*it + float(0.3 * kH));
  expectSame(ls, *vdb, "offset");
  measures("offset");

  openvdb::tools::LevelSetFilter<openvdb::FloatGrid> filter(*vdb);
  filter.setSpatialScheme(openvdb::math::FIRST_BIAS);
  filter.setNormCount(1);
  for (int i = 0; i < 3; ++i) {
    filter.meanCurvature();
    ls.meanCurvature(1);
    expectSame(ls, *vdb, "mean curvature");
  }
  filter.setNormCount(3);
  filter.normalize();
  ls.normalize(3);
  expectSame(ls, *vdb, "normalize");
  measures("smoothed");
}

TEST(DenseLevelSet, SameBitsForOneAndTwoThreads) {
  // A ball of radius 20 has a band of ~30,000 voxels: several of the 4,096-voxel chunks.
  const std::vector<Vec3i> cells = turnedBall(20.0, 0.3);
  auto build = [&](int threads) {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, threads);
    DenseLevelSet ls = DenseLevelSet::fromCells(cells, kH, 3, 1, 1);
    ls.meanCurvature(1);
    ls.meanCurvature(1);
    ls.normalize(3);
    return ls.values();
  };
  const std::vector<float> one = build(1), two = build(2);
  ASSERT_EQ(one.size(), two.size());
  EXPECT_EQ(0, std::memcmp(one.data(), two.data(), one.size() * sizeof(float)));
}

TEST(DenseLevelSet, MeshParticlesGivesTheMeshOfOpenVdbsTools) {
  // The whole meshParticles pipeline (closing, smoothing step, volume target, mean-curvature
  // iterations and the volume correction) both ways: the same triangles, vertex positions to
  // 1e-4 of a voxel (the volume offsets come from the measures, equal to rounding, so the
  // values may differ in their last bits).
  std::vector<Vec3> particles;
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.9, Vec3(0, 1, 1).normalized()).toRotationMatrix();
  for (int k = -10; k <= 10; ++k)
    for (int j = -6; j <= 6; ++j)
      for (int i = -14; i <= 14; ++i)
        if (Vec3(i / 14.0, j / 6.0, k / 10.0).norm() <= 1.0) particles.push_back(kH * (turn * Vec3(i, j, k)));
  ParticleMeshOptions options;
  options.smoothIterations = 2;
  options.targetVolume = double(particles.size()) * kH * kH * kH;
  SmoothingReport dense, reference;
  MeshStageTimes denseTimes, referenceTimes;
  const TriangleMesh a = meshParticles(particles, kH, options, &dense, &denseTimes);
  options.surface.denseLevelSet = false;
  const TriangleMesh b = meshParticles(particles, kH, options, &reference, &referenceTimes);
  EXPECT_TRUE(denseTimes.denseLevelSet);  // the two paths did run
  EXPECT_FALSE(referenceTimes.denseLevelSet);
  ASSERT_EQ(a.positions.size(), b.positions.size());
  ASSERT_EQ(a.indices, b.indices);
  double worst = 0.0;
  for (std::size_t i = 0; i < a.positions.size(); ++i)
    worst = std::max(worst, double((a.positions[i] - b.positions[i]).norm()) / kH);
  EXPECT_LT(worst, 1e-4);
  EXPECT_NEAR(dense.volumeBefore, reference.volumeBefore, 1e-9 * reference.volumeBefore);
  EXPECT_NEAR(dense.volumeAfter, reference.volumeAfter, 1e-6 * reference.volumeAfter);
}

// writeLevelSetsVdb's grid (the dense level set copied into OpenVDB's tree: leaves, interior
// tiles, inactive values) against the OpenVDB-built one, read back from the file, over a box
// two leaves wider than the dense box on every side: same active voxels, same values, the
// inactive ones included (a wrong sign there would be a spurious surface for volumeToMesh).
TEST(DenseLevelSet, ItsOpenVdbGridIsTheOneOpenVdbsToolsBuild) {
  LevelSetGrid dense;
  dense.name = "dense";
  dense.cells = turnedBall(17.0, 1.1);  // a box whose interior holds whole 8^3 tiles
  dense.surface.closingSteps = 1;
  LevelSetGrid reference = dense;
  reference.name = "reference";
  reference.surface.denseLevelSet = false;
  const std::string path = (std::filesystem::temp_directory_path() / "physketch_dense_level_set.vdb").string();
  writeLevelSetsVdb(path, {dense, reference}, kH, Vec3::Zero());
  openvdb::io::File file(path);
  file.open();
  openvdb::GridPtrVecPtr grids = file.getGrids();
  file.close();
  std::filesystem::remove(path);
  ASSERT_EQ(grids->size(), 2u);
  const auto a = openvdb::gridPtrCast<openvdb::FloatGrid>((*grids)[0]);
  const auto b = openvdb::gridPtrCast<openvdb::FloatGrid>((*grids)[1]);
  ASSERT_TRUE(a && b);
  EXPECT_EQ(a->activeVoxelCount(), b->activeVoxelCount());
  const DenseLevelSet ls = DenseLevelSet::fromCells(dense.cells, kH, 3, 1, 1);
  const Vec3i lo = ls.lo() - Vec3i::Constant(16), hi = ls.lo() + ls.dims() + Vec3i::Constant(16);
  auto accA = a->getConstAccessor();
  auto accB = b->getConstAccessor();
  std::size_t differ = 0, inside = 0;
  for (int z = lo.z(); z < hi.z(); ++z)
    for (int y = lo.y(); y < hi.y(); ++y)
      for (int x = lo.x(); x < hi.x(); ++x) {
        const openvdb::Coord ijk(x, y, z);
        differ += accA.isValueOn(ijk) != accB.isValueOn(ijk) || accA.getValue(ijk) != accB.getValue(ijk);
        inside += !accA.isValueOn(ijk) && accA.getValue(ijk) < 0.0f;
      }
  EXPECT_EQ(differ, 0u);
  EXPECT_GT(inside, 512u);  // interior voxels off the band, whole tiles among them
}

// Cells 2^31 apart: their box's voxel count overflows 64 bits. boxVoxels saturates, so the level
// set goes to OpenVDB's tools (which are sparse) instead of a dense box (before the fix the count
// wrapped to 0, passed the budget, and fromCells wrote out of bounds).
TEST(DenseLevelSet, CellsTooFarApartGoToOpenVdbsTools) {
  const std::vector<Vec3i> cells = {Vec3i(-(1 << 30), -(1 << 30), 0), Vec3i((1 << 30) - 15, (1 << 30) - 15, 1)};
  EXPECT_EQ(DenseLevelSet::boxVoxels(cells, 3, 0), std::numeric_limits<std::uint64_t>::max());
  EXPECT_THROW(DenseLevelSet::fromCells(cells, kH, 3, 0, 0), std::invalid_argument);
  std::vector<Vec3> particles;
  for (const Vec3i& c : cells) particles.push_back(kH * c.cast<double>());
  MeshStageTimes times;
  const TriangleMesh mesh = meshParticles(particles, kH, {}, nullptr, &times);
  EXPECT_FALSE(times.denseLevelSet);
  EXPECT_GT(mesh.triangleCount(), 0u);
}

// A band pushed out to the box's edge is flagged, so the caller can build it with OpenVDB
// instead. The surface is moved out a voxel at a time, each move followed by a flow step (whose
// tracking dilates the band by one voxel and renormalizes it): ten voxels out it crosses the box's
// 7-voxel margin; one voxel out (ten moves of a tenth) it stays clear of it.
TEST(DenseLevelSet, ABandAtTheBoxEdgeIsFlagged) {
  const std::vector<Vec3i> cells = turnedBall(6.0, 0.2);
  for (const double step : {0.1, 1.0}) {
    DenseLevelSet ls = DenseLevelSet::fromCells(cells, kH, 3, 0, 0);
    for (int i = 0; i < 10; ++i) {
      ls.offset(float(-step * kH));
      ls.meanCurvature(3);
    }
    EXPECT_EQ(ls.reachedBorder(), step > 0.5) << step << " voxels a step";
  }
}

}  // namespace
}  // namespace physketch::render
