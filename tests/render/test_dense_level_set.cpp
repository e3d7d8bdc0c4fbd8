// DenseLevelSet against OpenVDB's own tools, voxel by voxel: the oracle is the library whose
// updates it repeats (topologyToLevelSet, LevelSetFilter::meanCurvature / normalize,
// LevelSetMeasure), run here on the same cells. Tolerances: the two run the same float
// operations, but the compiler may contract or reorder a few differently (and the measures sum
// in another order), so values agree to rounding, not bit for bit: 1e-5 of a voxel over up to
// 17 sweeps (float's 6e-8 relative on values up to 3 voxels, grown by the sweeps), and 1e-9
// relative for the measures' double sums.
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetFilter.h>
#include <openvdb/tools/LevelSetMeasure.h>
#include <openvdb/tools/TopologyToLevelSet.h>
#include <tbb/global_control.h>

#include <cmath>
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
  EXPECT_LT(d.maxValue, 1e-5) << what;
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
  // iterations and the volume correction) both ways: vertex positions agree to 1e-4 of a voxel
  // (the value tolerance above, through the edge interpolation of volumeToMesh).
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
  const TriangleMesh a = meshParticles(particles, kH, options, &dense);
  options.surface.denseLevelSet = false;
  const TriangleMesh b = meshParticles(particles, kH, options, &reference);
  ASSERT_EQ(a.positions.size(), b.positions.size());
  ASSERT_EQ(a.indices, b.indices);
  double worst = 0.0;
  for (std::size_t i = 0; i < a.positions.size(); ++i)
    worst = std::max(worst, double((a.positions[i] - b.positions[i]).norm()) / kH);
  EXPECT_LT(worst, 1e-4);
  EXPECT_NEAR(dense.volumeBefore, reference.volumeBefore, 1e-9 * reference.volumeBefore);
  EXPECT_NEAR(dense.volumeAfter, reference.volumeAfter, 1e-6 * reference.volumeAfter);
}

}  // namespace
}  // namespace physketch::render
