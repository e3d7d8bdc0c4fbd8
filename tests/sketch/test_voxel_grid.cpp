// Voxelizer: Phys-Sketch Eq. 4-5 mapping, Alg. 1 stamping, Eq. 6-7 interpolation.
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <queue>
#include <random>
#include <set>

#include "core/error.h"
#include "sketch/voxelize.h"
#include "tests/sketch/cells.h"

using namespace physketch;
using namespace physketch::sketch;

namespace {

std::vector<Material> oneMaterial() {
  Material m;
  m.name = "wood";
  return {m};
}

// A stroke operation with one sample per point, 0.01 s apart, lines 3, 4, ...
Operation makeStroke(BrushShape shape, double size, std::vector<Vec3> points) {
  Operation op;
  op.kind = Operation::Kind::kStroke;
  op.stroke.brush = shape;
  op.stroke.size = size;
  op.material = "wood";
  op.line = 2;
  double t = 0.0;
  int line = 3;
  for (const auto& p : points) op.stroke.samples.push_back(Sample{t += 0.01, p, 1.0, line++});
  return op;
}

void add(StrokeFile& f, Operation op) {
  op.id = static_cast<int>(f.operations.size());
  f.active.push_back(op.id);
  f.operations.push_back(std::move(op));
}

using physketch::sketch::testing::components;

}  // namespace

TEST(GridMapping, Eq4And5MapCentreAndCorners) {
  const GridMapping m(Vec3(1.0, 2.0, -3.0), 1.51);
  EXPECT_DOUBLE_EQ(m.voxelSize(), 0.01);  // |W| / |w|
  EXPECT_EQ(m.discretize(Vec3(1.0, 2.0, -3.0)), Vec3i(75, 75, 75));  // C -> c
  EXPECT_EQ(m.discretize(Vec3(1.0 - 0.755 + 1e-9, 2.0, -3.0)).x(), 0);
  EXPECT_EQ(m.discretize(Vec3(1.0 + 0.755 - 1e-9, 2.0, -3.0)).x(), 150);
  EXPECT_TRUE(m.contains(Vec3(1.0 + 0.7549, 2.0, -3.0)));
  EXPECT_FALSE(m.contains(Vec3(1.0 + 0.7551, 2.0, -3.0)));
  EXPECT_FALSE(m.contains(Vec3(1.0, 2.0 - 0.7551, -3.0)));
  const Vec3 q = m.toWorld(Vec3i(0, 75, 150));
  EXPECT_NEAR(q.x(), 1.0 - 0.75, 1e-12);
  EXPECT_NEAR(q.y(), 2.0, 1e-12);
  EXPECT_NEAR(q.z(), -3.0 + 0.75, 1e-12);
}

TEST(GridMapping, RoundTripWithinHalfAVoxel) {
  const GridMapping m(Vec3(0.0, 0.5, 0.0), 1.0);
  const double h = m.voxelSize();
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> u(-0.4999, 0.4999);
  for (int i = 0; i < 20000; ++i) {
    const Vec3 q(u(rng), 0.5 + u(rng), u(rng));
    ASSERT_TRUE(m.contains(q));
    const Vec3i c = m.discretize(q);
    ASSERT_TRUE(GridMapping::inGrid(c));
    const Vec3 back = m.toWorld(c);
    ASSERT_LE((back - q).cwiseAbs().maxCoeff(), 0.5 * h + 1e-12);
    // And grid -> world -> grid is exact.
    ASSERT_EQ(m.discretize(back), c);
  }
}

TEST(Interpolation, Eq6CountAndEq7Spacing) {
  std::vector<Vec3> pts;
  const double d = 0.01;
  interpolateSegment(Vec3(0, 0, 0), Vec3(0.104, 0, 0), d, pts);
  ASSERT_EQ(pts.size(), 11u);  // i_max = Round(0.104 / 0.01) = 10, i in [0, 10]
  EXPECT_DOUBLE_EQ(pts[0].x(), 0.104);  // P'(0) = P, the current sample
  for (std::size_t i = 1; i < pts.size(); ++i) EXPECT_NEAR(pts[i - 1].x() - pts[i].x(), d, 1e-12);
  interpolateSegment(Vec3(1, 1, 1), Vec3(1, 1, 1), d, pts);
  EXPECT_EQ(pts.size(), 1u);
}

TEST(Voxelize, FastTwoSampleStrokeIsAConnectedRunOfEq6Length) {
  const GridMapping m(Vec3(0.0, 0.5, 0.0), 1.0);
  const double h = m.voxelSize();
  // Brush smaller than a voxel: each stamp marks exactly one cell. The two
  // samples are 40 voxels apart, a jump of 40 cells in one frame.
  StrokeFile f;
  f.path = "fast.strokes";
  const Vec3 a = m.toWorld(Vec3i(50, 75, 75)), b = m.toWorld(Vec3i(90, 75, 75));
  add(f, makeStroke(BrushShape::kSphere, 0.4 * h, {a, b}));
  const Sketch sk = voxelize(f, m, oneMaterial());
  const long iMax = std::lround((b - a).norm() / h);
  EXPECT_EQ(iMax, 40);
  ASSERT_EQ(sk.particles.size(), static_cast<std::size_t>(iMax + 1));  // Eq. 6: i in [0, i_max]; P_0 is P'(i_max)
  std::set<int> xs;
  for (const auto& c : sk.cells) {
    EXPECT_EQ(c.y(), 75);
    EXPECT_EQ(c.z(), 75);
    xs.insert(c.x());
  }
  EXPECT_EQ(*xs.begin(), 50);
  EXPECT_EQ(*xs.rbegin(), 90);
  EXPECT_EQ(xs.size(), 41u);  // contiguous 50..90: no gaps
}

TEST(Voxelize, FastDiagonalStrokeWithoutInterpolationWouldHaveHoles) {
  const GridMapping m(Vec3(0.0, 0.5, 0.0), 1.0);
  const double h = m.voxelSize();
  StrokeFile f;
  f.path = "diag.strokes";
  // Five samples, 0.19 m apart in 3D: far more than a brush of 3 voxels.
  std::vector<Vec3> pts;
  for (int i = 0; i < 5; ++i) pts.push_back(Vec3(-0.4 + 0.12 * i, 0.2 + 0.1 * i, -0.3 + 0.11 * i));
  add(f, makeStroke(BrushShape::kCube, 3 * h, pts));
  const Sketch sk = voxelize(f, m, oneMaterial());
  // The stamps in closed form: the first sample, then per segment of length
  // L = |(0.12, 0.1, 0.11)| = 0.19105 m = 28.85 h: i_max = 29 points cur - i h dir.
  const double len = std::sqrt(0.12 * 0.12 + 0.1 * 0.1 + 0.11 * 0.11);
  ASSERT_EQ(std::lround(len / h), 29);
  std::vector<Vec3> stamps{pts[0]};
  for (int k = 1; k < 5; ++k)
    for (int i = 0; i <= 29; ++i) stamps.push_back(pts[k] - i * h * (pts[k] - pts[k - 1]) / len);
  // The cube brush (edge 3h, default axis: aligned with the grid) covers the cells
  // whose centres are within 1.5 h of its centre along every axis.
  std::set<std::int64_t> expected;
  for (const Vec3& s : stamps) {
    const Vec3i c = m.discretize(s);
    for (int dz = -2; dz <= 2; ++dz)
      for (int dy = -2; dy <= 2; ++dy)
        for (int dx = -2; dx <= 2; ++dx) {
          const Vec3i cell = c + Vec3i(dx, dy, dz);
          if ((m.toWorld(cell) - s).cwiseAbs().maxCoeff() <= 1.5 * h) expected.insert(GridMapping::linear(cell));
        }
  }
  std::set<std::int64_t> got;
  for (const auto& c : sk.cells) got.insert(GridMapping::linear(c));
  EXPECT_EQ(got, expected);
  // Without interpolation the five cubes of 27 cells lie apart.
  EXPECT_EQ(components(sk.cells), 1);
  EXPECT_GT(sk.particles.size(), 10u * 27u);
}

TEST(Voxelize, OneParticlePerVoxelAtTheVoxelCentre) {
  const GridMapping m(Vec3(0.0, 0.5, 0.0), 1.0);
  StrokeFile f;
  f.path = "overlap.strokes";
  // Three overlapping strokes over the same region.
  add(f, makeStroke(BrushShape::kSphere, 0.1, {Vec3(0, 0.5, 0), Vec3(0.1, 0.5, 0)}));
  add(f, makeStroke(BrushShape::kCube, 0.08, {Vec3(0.05, 0.5, 0), Vec3(0.05, 0.6, 0)}));
  add(f, makeStroke(BrushShape::kSphere, 0.1, {Vec3(0, 0.5, 0)}));
  const Sketch sk = voxelize(f, m, oneMaterial());
  EXPECT_EQ(sk.operations[2].created, 0);  // fully inside the first stroke: nothing new
  std::set<std::int64_t> cells;
  for (std::size_t i = 0; i < sk.particles.size(); ++i) {
    ASSERT_TRUE(cells.insert(GridMapping::linear(sk.cells[i])).second) << "two particles in one voxel";
    ASSERT_EQ(sk.grid.at(sk.cells[i]), static_cast<std::int32_t>(i));
    const Vec3 q = m.toWorld(sk.cells[i]);
    ASSERT_NEAR(sk.particles.x[i], q.x(), 1e-6);
    ASSERT_NEAR(sk.particles.y[i], q.y(), 1e-6);
    ASSERT_FALSE(phase::dynamic(sk.particles.phase[i]));  // static while sketched
  }
  EXPECT_EQ(static_cast<std::size_t>(sk.grid.occupied()), sk.particles.size());
}

TEST(Voxelize, SphereBrushVolumeMatchesAnalytic) {
  const GridMapping m(Vec3(0.0, 0.5, 0.0), 1.0);
  const double h = m.voxelSize();
  StrokeFile f;
  f.path = "ball.strokes";
  const double diameter = 31 * h;
  add(f, makeStroke(BrushShape::kSphere, diameter, {m.toWorld(Vec3i(75, 75, 75))}));
  const Sketch sk = voxelize(f, m, oneMaterial());
  const double exact = M_PI / 6.0 * std::pow(diameter / h, 3);  // in voxels: 15,599
  // Lattice points in a ball of radius 15.5: error is O(r^2) surface voxels, < 2 % here.
  EXPECT_NEAR(double(sk.particles.size()), exact, 0.02 * exact);
}

TEST(Voxelize, SampleOutsideWorkspaceNamesLineAndAxis) {
  const GridMapping m(Vec3(0.0, 0.5, 0.0), 1.0);
  StrokeFile f;
  f.path = "out.strokes";
  add(f, makeStroke(BrushShape::kSphere, 0.05, {Vec3(0, 0.5, 0), Vec3(0, 0.5, 0.6)}));
  try {
    voxelize(f, m, oneMaterial());
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), "out.strokes");
    EXPECT_EQ(e.line(), 4);
    EXPECT_EQ(e.field(), "z");
  }
}

TEST(Voxelize, UnknownMaterialNamesStrokeLine) {
  const GridMapping m(Vec3(0.0, 0.5, 0.0), 1.0);
  StrokeFile f;
  f.path = "mat.strokes";
  add(f, makeStroke(BrushShape::kSphere, 0.05, {Vec3(0, 0.5, 0)}));
  f.operations[0].material = "jelly";
  try {
    voxelize(f, m, oneMaterial());
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 2);
    EXPECT_EQ(e.field(), "material");
    EXPECT_NE(std::string(e.what()).find("wood"), std::string::npos);  // lists what is defined
  }
}

TEST(Voxelize, OverCapNamesTheStrokeThatCrossedIt) {
  const GridMapping m(Vec3(0.0, 0.5, 0.0), 1.0);
  StrokeFile f;
  f.path = "cap.strokes";
  add(f, makeStroke(BrushShape::kSphere, 0.3, {Vec3(0, 0.5, 0)}));  // ~52k particles
  add(f, makeStroke(BrushShape::kCube, 0.9, {Vec3(0, 0.5, 0)}));    // ~2.5M: over the cap
  f.operations[1].line = 9;
  try {
    voxelize(f, m, oneMaterial());
    FAIL();
  } catch (const InputError& e) {
    // The line and the field, not the operation's index (which counts from 0).
    EXPECT_EQ(e.line(), 9);
    EXPECT_EQ(e.field(), "size");
    EXPECT_NE(std::string(e.what()).find("stroke create cube crosses the particle cap of 688590"), std::string::npos)
        << e.what();
    EXPECT_EQ(std::string(e.what()).find("operation 1"), std::string::npos) << e.what();
  }
  // A primitive names its largest dimension.
  StrokeFile g = parseStrokes("physketch-strokes 1\nprimitive box wood 0  0 0.5 0  0.8 0.95 0.9\n", "cap.strokes");
  try {
    voxelize(g, m, oneMaterial());
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 2);
    EXPECT_EQ(e.field(), "sy");
  }
}

namespace {

// Components by brute force: union-find over every pair of cells, joined when they
// differ by at most one in every coordinate (26-connectivity); then numbered in
// the order of each component's smallest linear index.
std::vector<int> componentsByPairs(const std::vector<Vec3i>& cells) {
  std::vector<std::size_t> parent(cells.size());
  for (std::size_t i = 0; i < cells.size(); ++i) parent[i] = i;
  auto root = [&](std::size_t i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  for (std::size_t i = 0; i < cells.size(); ++i)
    for (std::size_t j = i + 1; j < cells.size(); ++j)
      if ((cells[i] - cells[j]).cwiseAbs().maxCoeff() <= 1) parent[root(i)] = root(j);
  std::map<std::size_t, std::int64_t> smallest;  // root -> smallest linear index
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const auto l = GridMapping::linear(cells[i]);
    auto [it, fresh] = smallest.emplace(root(i), l);
    if (!fresh) it->second = std::min(it->second, l);
  }
  std::map<std::int64_t, int> order;
  for (const auto& kv : smallest) order.emplace(kv.second, 0);
  int n = 0;
  for (auto& kv : order) kv.second = n++;
  std::vector<int> out(cells.size());
  for (std::size_t i = 0; i < cells.size(); ++i) out[i] = order[smallest[root(i)]];
  return out;
}

}  // namespace

TEST(ConnectedComponents26, SmallCasesByHand) {
  EXPECT_TRUE(connectedComponents26({}).empty());
  // Corner contact joins; a gap of one cell does not.
  EXPECT_EQ(connectedComponents26({Vec3i(5, 5, 5), Vec3i(6, 6, 6)}), (std::vector<int>{0, 0}));
  EXPECT_EQ(connectedComponents26({Vec3i(5, 5, 5), Vec3i(7, 5, 5)}), (std::vector<int>{0, 1}));
  // Numbered by the smallest linear index (z first): the cell at z = 3 is component 0.
  EXPECT_EQ(connectedComponents26({Vec3i(0, 0, 9), Vec3i(150, 150, 3), Vec3i(1, 1, 9)}), (std::vector<int>{1, 0, 1}));
  // A cell listed twice is one cell.
  EXPECT_EQ(connectedComponents26({Vec3i(2, 2, 2), Vec3i(9, 9, 9), Vec3i(2, 2, 2)}), (std::vector<int>{0, 1, 0}));
  // A chain that turns back on itself at grid corners.
  EXPECT_EQ(connectedComponents26({Vec3i(0, 0, 0), Vec3i(150, 150, 150), Vec3i(1, 1, 1)}), (std::vector<int>{0, 1, 0}));
  EXPECT_THROW(connectedComponents26({Vec3i(0, 0, 151)}), RuntimeError);
}

TEST(ConnectedComponents26, MatchesPairwiseBruteForceOnRandomSets) {
  std::mt19937 rng(7);
  for (int n = 0; n < 60; ++n) {
    // Random cells in a small box: from sparse dust to nearly solid, so components
    // of every size meet and merge through faces, edges and corners alike.
    const int box = 3 + static_cast<int>(rng() % 12);
    const int count = 1 + static_cast<int>(rng() % 400);
    const Vec3i corner(static_cast<int>(rng() % (kGridSize - box)), static_cast<int>(rng() % (kGridSize - box)),
                       static_cast<int>(rng() % (kGridSize - box)));
    std::vector<Vec3i> cells;
    for (int i = 0; i < count; ++i)
      cells.push_back(corner + Vec3i(static_cast<int>(rng() % box), static_cast<int>(rng() % box),
                                     static_cast<int>(rng() % box)));
    ASSERT_EQ(connectedComponents26(cells), componentsByPairs(cells)) << "set " << n;
  }
}
