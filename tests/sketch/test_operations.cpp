// Sketch operations: primitives against analytic volumes, remove (Alg. 2), move,
// mirror, undo/redo, brush shapes at high speed, pressure, body groups.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <queue>
#include <set>

#include "core/error.h"
#include "sketch/voxelize.h"
#include "tests/sketch/cells.h"

using namespace physketch;
using namespace physketch::sketch;

namespace {

const GridMapping kMap(Vec3(0.0, 0.5, 0.0), 1.0);  // h = 1/151 m
const double kH = kMap.voxelSize();

std::vector<Material> materials() {
  Material a, b;
  a.name = "wood";
  b.name = "stone";
  return {a, b};
}

Sketch sketchOf(const std::string& body) {
  return voxelize(parseStrokes("physketch-strokes 1\n" + body, "t.strokes"), kMap, materials());
}

std::set<std::int64_t> cellSet(const Sketch& sk) {
  std::set<std::int64_t> s;
  for (const auto& c : sk.cells) s.insert(GridMapping::linear(c));
  return s;
}

using physketch::sketch::testing::components;

// Checks the invariants every sketch must keep: M and the particles agree, one particle per voxel.
void expectConsistent(const Sketch& sk) {
  ASSERT_EQ(static_cast<std::size_t>(sk.grid.occupied()), sk.particles.size());
  for (std::size_t i = 0; i < sk.particles.size(); ++i) {
    ASSERT_EQ(sk.grid.at(sk.cells[i]), static_cast<std::int32_t>(i));
    const Vec3 q = kMap.toWorld(sk.cells[i]);
    ASSERT_NEAR(sk.particles.y[i], q.y(), 1e-6);
  }
  std::int32_t next = 0;
  for (const auto& b : sk.bodies) {  // bodies tile the particle array in order
    ASSERT_EQ(b.first, next);
    next += b.count;
  }
  ASSERT_EQ(next, static_cast<std::int32_t>(sk.particles.size()));
}

// Every cell whose centre passes `inside` (world coordinates), by brute force over
// the cells within `reach` metres of `around` along every axis (the whole grid by default).
template <class Inside>
std::set<std::int64_t> cellsWhere(Inside&& inside, const Vec3& around = Vec3(0, 0.5, 0), double reach = 1.0) {
  const Vec3i lo = kMap.discretize(around - Vec3::Constant(reach)).cwiseMax(0);
  const Vec3i hi = kMap.discretize(around + Vec3::Constant(reach)).cwiseMin(kGridSize - 1);
  std::set<std::int64_t> out;
  for (int k = lo.z(); k <= hi.z(); ++k)
    for (int j = lo.y(); j <= hi.y(); ++j)
      for (int i = lo.x(); i <= hi.x(); ++i)
        if (inside(kMap.toWorld(Vec3i(i, j, k)))) out.insert(GridMapping::linear(Vec3i(i, j, k)));
  return out;
}

// rot=ax,ay,az,deg as the format defines it: local -> world.
Mat3 rot(const Vec3& axis, double degrees) { return Eigen::AngleAxisd(degrees * M_PI / 180.0, axis.normalized()).toRotationMatrix(); }

struct PrimitiveCase {
  std::string record;                      // after "primitive "
  Vec3 centre;                             // m
  Mat3 rotation;                           // local -> world
  std::function<bool(const Vec3&)> local;  // the analytic solid in its local frame
  double volume;                           // m^3
};

}  // namespace

// Alg. 1 for the primitives: a cell belongs to a primitive exactly when its centre
// lies inside the analytic solid, written here from the format's definitions
// (docs/formats.md) and tested cell by cell over the whole grid: the sets must be
// equal, so a missing or extra layer of cells fails. Dimensions are deliberately off
// the lattice, so no centre lies on a surface (where two roundings might disagree).
TEST(Primitives, CellsAreThoseWhoseCentresLieInTheAnalyticSolid) {
  const double pi = M_PI;
  auto sq = [](double v) { return v * v; };
  const Vec3 c(0.013, 0.52, -0.021);
  const std::vector<PrimitiveCase> cases = {
      {"box wood 0  0.013 0.52 -0.021  0.213 0.117 0.305", c, Mat3::Identity(),
       [](const Vec3& p) { return std::abs(p.x()) <= 0.1065 && std::abs(p.y()) <= 0.0585 && std::abs(p.z()) <= 0.1525; },
       0.213 * 0.117 * 0.305},
      {"box wood 0  0.013 0.52 -0.021  0.213 0.117 0.305 rot=1,1,0,33", c, rot(Vec3(1, 1, 0), 33),
       [](const Vec3& p) { return std::abs(p.x()) <= 0.1065 && std::abs(p.y()) <= 0.0585 && std::abs(p.z()) <= 0.1525; },
       0.213 * 0.117 * 0.305},
      {"sphere wood 0  0.01 0.49 0.003  0.151", Vec3(0.01, 0.49, 0.003), Mat3::Identity(),
       [&](const Vec3& p) { return p.squaredNorm() <= sq(0.151); }, 4.0 / 3 * pi * std::pow(0.151, 3)},
      {"ellipsoid wood 0  0 0.5 0  0.2 0.1 0.15 rot=0,0,1,20", Vec3(0, 0.5, 0), rot(Vec3(0, 0, 1), 20),
       [&](const Vec3& p) { return sq(p.x() / 0.2) + sq(p.y() / 0.1) + sq(p.z() / 0.15) <= 1; },
       4.0 / 3 * pi * 0.2 * 0.1 * 0.15},
      {"cylinder wood 0  0.004 0.5 0  0.12 0.31 rot=1,0,0,90", Vec3(0.004, 0.5, 0), rot(Vec3(1, 0, 0), 90),
       [&](const Vec3& p) { return sq(p.x()) + sq(p.y()) <= sq(0.12) && std::abs(p.z()) <= 0.155; },
       pi * 0.12 * 0.12 * 0.31},
      {"capsule wood 0  0 0.5 0.002  0.08 0.33 rot=0,0,1,45", Vec3(0, 0.5, 0.002), rot(Vec3(0, 0, 1), 45),
       [&](const Vec3& p) {
         const double z = std::max(-0.165, std::min(0.165, p.z()));  // nearest point of the segment
         return sq(p.x()) + sq(p.y()) + sq(p.z() - z) <= sq(0.08);
       },
       pi * 0.08 * 0.08 * 0.33 + 4.0 / 3 * pi * std::pow(0.08, 3)},
      {"torus wood 0  0 0.5 0  0.25 0.061 rot=1,0,0,90", Vec3(0, 0.5, 0), rot(Vec3(1, 0, 0), 90),
       [&](const Vec3& p) { return sq(std::hypot(p.x(), p.y()) - 0.25) + sq(p.z()) <= sq(0.061); },
       2 * pi * pi * 0.25 * 0.061 * 0.061},
  };
  for (const auto& pc : cases) {
    const Sketch sk = sketchOf("primitive " + pc.record + "\n");
    const std::set<std::int64_t> expected =
        cellsWhere([&](const Vec3& q) { return pc.local(pc.rotation.transpose() * (q - pc.centre)); }, pc.centre, 0.35);
    EXPECT_EQ(cellSet(sk), expected) << pc.record;
    EXPECT_EQ(sk.particles.size(), expected.size()) << pc.record;
    // A guard on the oracle's reading of the dimensions (a radius read as a diameter
    // is a factor of 8): solids this many cells across hold V/h^3 cells within 3 %.
    EXPECT_NEAR(double(expected.size()), pc.volume / (kH * kH * kH), 0.03 * pc.volume / (kH * kH * kH)) << pc.record;
    expectConsistent(sk);
  }
  // The grid-aligned box in closed form: a product of the lattice points in three
  // intervals. Centre 0.013 -> grid 76.963, half 0.1065 -> 16.0815 cells: x cells
  // 61..93 (33); y: 0.52 -> 78.02, half 8.8335: 70..86 (17); z: -0.021 -> 71.829,
  // half 23.0275: 49..94 (46).
  EXPECT_EQ(sketchOf("primitive " + cases[0].record + "\n").particles.size(), 33u * 17u * 46u);
}

TEST(Primitives, CellsAreExactlyThoseWithCentresInside) {
  // An axis-aligned box test against a brute-force scan of the whole grid.
  const Sketch sk = sketchOf("primitive box wood 0  0.1 0.4 -0.05  0.1 0.2 0.07\n");
  std::set<std::int64_t> expected;
  for (int k = 0; k < kGridSize; ++k)
    for (int j = 0; j < kGridSize; ++j)
      for (int i = 0; i < kGridSize; ++i) {
        const Vec3 q = kMap.toWorld(Vec3i(i, j, k));
        if (std::abs(q.x() - 0.1) <= 0.05 && std::abs(q.y() - 0.4) <= 0.1 && std::abs(q.z() + 0.05) <= 0.035)
          expected.insert(GridMapping::linear(Vec3i(i, j, k)));
      }
  EXPECT_EQ(cellSet(sk), expected);
}

TEST(Remove, FreesTheVoxelsUnderTheBrushAndRemovesExactlyThoseParticles) {
  const std::string box = "primitive box wood 0  0 0.5 0  0.2 0.2 0.2\n";
  const Sketch before = sketchOf(box);
  const Sketch after = sketchOf(box + "stroke remove sphere 0.1\nsample 1 0.1 0.5 0\nsample 1.1 0.1 0.6 0\n");
  // The stamps in closed form (Eq. 6-7): the first sample, then the segment of
  // 0.1 m = 15.1 h: i_max = 15 points at y = 0.6 - i h, i = 0..15. A cell is freed
  // when its centre is within the brush radius 0.05 m of one of them.
  std::vector<Vec3> stamps{Vec3(0.1, 0.5, 0)};
  for (int i = 0; i <= 15; ++i) stamps.push_back(Vec3(0.1, 0.6 - i * kH, 0));
  auto underBrush = [&](const Vec3& q) {
    for (const Vec3& s : stamps)
      if ((q - s).squaredNorm() <= 0.05 * 0.05) return true;
    return false;
  };
  const std::set<std::int64_t> box0 =
      cellsWhere([](const Vec3& q) { return std::abs(q.x()) <= 0.1 && std::abs(q.y() - 0.5) <= 0.1 && std::abs(q.z()) <= 0.1; });
  ASSERT_EQ(cellSet(before), box0);
  std::set<std::int64_t> expected;
  std::int32_t freed = 0;
  for (auto l : box0) {
    if (underBrush(kMap.toWorld(GridMapping::cellOf(l)))) ++freed;
    else expected.insert(l);
  }
  EXPECT_EQ(cellSet(after), expected);
  EXPECT_EQ(after.operations[1].removed, freed);
  EXPECT_GT(freed, 1000);
  expectConsistent(after);
}

TEST(Move, TranslatesExactlyTheGrabbedVoxels) {
  // Two boxes; the brush grabs part of the first at the first sample and carries it 0.13 m up.
  const std::string boxes =
      "primitive box wood 0  -0.1 0.3 0  0.1 0.1 0.1\n"
      "primitive box stone 0  0.2 0.3 0  0.1 0.1 0.1\n";
  const Sketch after = sketchOf(boxes + "stroke move sphere 0.08\nsample 1 -0.1 0.3 0\nsample 1.5 -0.1 0.43 0.02\n");
  auto inBox = [](const Vec3& q, double cx) {
    return std::abs(q.x() - cx) <= 0.05 && std::abs(q.y() - 0.3) <= 0.05 && std::abs(q.z()) <= 0.05;
  };
  // Grabbed: the cells of the first box within the brush radius 0.04 m of the first
  // sample. The travel (0, 0.13, 0.02) m is (0, 19.63, 3.02) cells: rounded, (0, 20, 3).
  const Vec3 grip(-0.1, 0.3, 0);
  const Vec3i shift(0, 20, 3);
  std::set<std::int64_t> grabbed, expected = cellsWhere([&](const Vec3& q) { return inBox(q, 0.2); });
  for (auto l : cellsWhere([&](const Vec3& q) { return inBox(q, -0.1); })) {
    if ((kMap.toWorld(GridMapping::cellOf(l)) - grip).squaredNorm() <= 0.04 * 0.04) grabbed.insert(l);
    else expected.insert(l);
  }
  for (auto l : grabbed) expected.insert(GridMapping::linear(GridMapping::cellOf(l) + shift));
  EXPECT_EQ(cellSet(after), expected);
  EXPECT_EQ(after.operations[2].moved, static_cast<std::int32_t>(grabbed.size()));
  EXPECT_GT(grabbed.size(), 100u);
  // Moved particles keep their provenance (created by operation 0, material wood).
  for (std::size_t i = 0; i < after.particles.size(); ++i)
    if (after.cells[i].y() > kMap.discretize(Vec3(0, 0.36, 0)).y()) {
      EXPECT_EQ(after.particles.stroke[i], 0);
      EXPECT_EQ(after.particles.material[i], 0);
    }
  expectConsistent(after);
}

TEST(Move, CarryingParticlesOutOfTheWorkspaceNamesTheLastSampleAndTheAxis) {
  try {
    sketchOf("primitive box wood 0  0 0.9 0  0.1 0.1 0.1\nstroke move sphere 0.1\nsample 1 0 0.9 0\nsample 2 0 0.99 0\n");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), "t.strokes");
    EXPECT_EQ(e.line(), 5);
    EXPECT_EQ(e.field(), "y");
    EXPECT_NE(std::string(e.what()).find("outside the workspace"), std::string::npos) << e.what();
  }
}

TEST(Move, ASampleOutsideTheWorkspaceNamesItsLineAndAxisBeforeAndAfterPlay) {
  for (const char* play : {"", "play 0.5\n"}) {
    try {
      sketchOf(std::string("primitive box wood 0  0 0.5 0  0.1 0.1 0.1\n") + play +
               "stroke move sphere 0.1\nsample 1 0 0.5 0\nsample 2 0 0.5 0\nsample 3 0 0.5 -0.62\n");
      FAIL() << play;
    } catch (const InputError& e) {
      EXPECT_EQ(e.file(), "t.strokes");
      EXPECT_EQ(e.line(), *play ? 7 : 6) << play;
      EXPECT_EQ(e.field(), "z") << play;
      EXPECT_NE(std::string(e.what()).find("sample outside the workspace"), std::string::npos) << e.what();
    }
  }
}

TEST(Mirror, ProducesTheMirroredVoxelSetBitForBit) {
  const std::string stroke =
      "stroke create capsule 0.05 wood orient=follow\nsample 0 0.05 0.4 0.1\nsample 0.1 0.2 0.6 -0.05\n"
      "sample 0.2 0.3 0.55 -0.1\n";
  const Sketch plain = sketchOf(stroke);
  // Each plane in grid coordinates (Eq. 4: g = 151 (p - C) + 75), snapped to the
  // nearest multiple of 1/2 (a cell centre or face), reflects index i to 2g - i:
  struct Plane {
    const char* record;
    int axis;
    int twice;  // 2g
  };
  const Plane planes[] = {
      {"mirror x 0\n", 0, 150},        // g = 75: the centre cell
      {"mirror x -0.0121\n", 0, 146},  // g = 73.17 -> 73
      {"mirror z 0.05\n", 2, 165},     // g = 82.55 -> 82.5, a face
      {"mirror y 0.45\n", 1, 135},     // g = 67.45 -> 67.5, a face
  };
  for (const Plane& pl : planes) {
    auto reflect = [&](Vec3i c) {
      c[pl.axis] = pl.twice - c[pl.axis];
      return c;
    };
    const Sketch both = sketchOf(std::string(pl.record) + stroke);
    std::set<std::int64_t> expected = cellSet(plain);
    for (const auto& c : plain.cells)
      if (GridMapping::inGrid(reflect(c))) expected.insert(GridMapping::linear(reflect(c)));
    EXPECT_EQ(cellSet(both), expected) << pl.record;
    EXPECT_GT(expected.size(), cellSet(plain).size() + 1000) << pl.record;  // the copy is mostly apart from the stroke
    expectConsistent(both);
  }
  // 'mirror off' ends it.
  const Sketch off = sketchOf("mirror x 0\nmirror off\n" + stroke);
  EXPECT_EQ(cellSet(off), cellSet(plain));
}

TEST(UndoRedo, UndoThenRedoReproducesTheSameGrid) {
  const std::string ops =
      "stroke create sphere 0.08 wood\nsample 0 -0.2 0.5 0\nsample 0.3 0.2 0.5 0\n"
      "stroke remove cube 0.05\nsample 0.4 0 0.5 0\n"
      "primitive torus stone 0.5  0 0.3 0  0.15 0.03\n";
  const Sketch direct = sketchOf(ops);
  const Sketch replayed = sketchOf(ops + "undo 3\nredo 3\n");
  EXPECT_TRUE(direct.grid == replayed.grid);
  EXPECT_EQ(direct.particles.x, replayed.particles.x);
  EXPECT_EQ(direct.particles.stroke, replayed.particles.stroke);
  // Undoing the last two leaves exactly the first stroke.
  const Sketch undone = sketchOf(ops + "undo 2\n");
  const Sketch first = sketchOf("stroke create sphere 0.08 wood\nsample 0 -0.2 0.5 0\nsample 0.3 0.2 0.5 0\n");
  EXPECT_TRUE(undone.grid == first.grid);
  EXPECT_FALSE(undone.operations[1].active);
  EXPECT_FALSE(undone.operations[2].active);
}

TEST(Brushes, EveryShapeLeavesAConnectedSweptVolumeAtHighSpeed) {
  // Samples 0.25 m apart in one frame: ~38 cells per step, far wider than any brush.
  for (const char* brush : {"sphere 0.02 wood", "cube 0.02 wood", "cylinder 0.03 wood", "disc 0.05 wood",
                            "capsule 0.02 wood", "cylinder 0.04 wood orient=follow length=0.01",
                            "disc 0.06 wood orient=follow", "capsule 0.02 wood orient=follow length=0.05",
                            "cube 0.015 wood axis=1,1,0"}) {
    const Sketch sk = sketchOf(std::string("stroke create ") + brush +
                               "\nsample 0 -0.4 0.2 -0.3\nsample 0.01 -0.2 0.3 -0.1\nsample 0.02 0.05 0.25 0.1\n"
                               "sample 0.03 0.3 0.6 0.2\n");
    EXPECT_EQ(components(sk.cells), 1) << brush;
    EXPECT_GT(sk.operations[0].stamps, 100) << brush;
    expectConsistent(sk);
  }
}

TEST(Brushes, PressureScalesTheBrush) {
  const Sketch full = sketchOf("stroke create sphere 0.2 wood\nsample 0 0 0.5 0 1.0\n");
  const Sketch half = sketchOf("stroke create sphere 0.2 wood\nsample 0 0 0.5 0 0.5\n");
  // Volume scales with the cube of the size: 1/8, within the surface-cell error of the small ball.
  EXPECT_NEAR(double(half.particles.size()) / double(full.particles.size()), 0.125, 0.01);
}

TEST(Bodies, NamedStrokesOfDifferentMaterialsFormOneBody) {
  const Sketch sk = sketchOf(
      "stroke create cube 0.1 wood body=table\nsample 0 -0.1 0.5 0\nsample 0.1 0.1 0.5 0\n"
      "stroke create sphere 0.05 wood\nsample 0.2 0 0.2 0.3\n"
      "stroke create sphere 0.06 stone body=table\nsample 0.3 0.1 0.42 0\n");
  ASSERT_EQ(sk.bodies.size(), 2u);
  EXPECT_EQ(sk.bodyNames[0], "table");
  EXPECT_EQ(sk.operations[0].body, 0);
  EXPECT_EQ(sk.operations[2].body, 0);
  EXPECT_EQ(sk.operations[1].body, 1);
  std::set<int> mats;
  for (std::int32_t i = sk.bodies[0].first; i < sk.bodies[0].first + sk.bodies[0].count; ++i)
    mats.insert(sk.particles.material[static_cast<std::size_t>(i)]);
  EXPECT_EQ(mats, (std::set<int>{0, 1}));
  EXPECT_EQ(sk.bodies[0].count, sk.operations[0].remaining + sk.operations[2].remaining);
  expectConsistent(sk);
  EXPECT_TRUE(sk.warnings.empty()) << sk.warnings.front();
}

TEST(Lint, WarnsAboutThinFeaturesRemovedStrokesUnusedMaterialsAndSplitBodies) {
  const Sketch sk = sketchOf(
      "stroke create sphere 0.005 wood\nsample 0 0 0.5 0\n"                       // thinner than 2h
      "stroke create sphere 0.1 wood body=b\nsample 0.1 0.3 0.5 0\n"
      "stroke create sphere 0.1 wood body=b\nsample 0.2 -0.3 0.5 0\n"             // does not touch the other
      "stroke remove sphere 0.12\nsample 0.3 0.3 0.5 0\n"
      "stroke create sphere 0.05 wood\nsample 0.4 -0.3 0.5 0\n");                 // inside an earlier stroke
  std::string all;
  for (const auto& w : sk.warnings) all += w + "\n";
  EXPECT_NE(all.find("t.strokes:2: stroke create sphere: feature of"), std::string::npos) << all;
  EXPECT_NE(all.find("t.strokes:4: stroke create sphere: every particle it created is removed later"), std::string::npos) << all;
  EXPECT_NE(all.find("material 'stone' is never used"), std::string::npos) << all;
  EXPECT_NE(all.find("t.strokes:10: stroke create sphere: creates no particle"), std::string::npos) << all;
}

TEST(Lint, OperationsAfterPlay) {
  const Sketch sk = sketchOf(
      "primitive sphere wood 0  0 0.5 0  0.05 body=table\nplay 1\n"
      "stroke remove sphere 0.005\nsample 2 0 0.5 0\n"                           // thinner than 2h, after play
      "primitive sphere stone 3  0.2 0.5 0  0.05 body=table\n"                     // reuses a name from before play
      "stroke create sphere 0.05 wood\nsample 4 0 0.5 0.2\nundo\n");            // undone after play
  std::string all;
  for (const auto& w : sk.warnings) all += w + "\n";
  EXPECT_NE(all.find("t.strokes:4: stroke remove sphere: feature of"), std::string::npos) << all;
  // Stone is used, by a create after play only.
  EXPECT_EQ(all.find("material 'stone' is never used"), std::string::npos) << all;
  EXPECT_NE(all.find("t.strokes:6: primitive sphere: body=table after play makes a new body; it cannot join the body "
                     "'table' made before play"),
            std::string::npos)
      << all;
  EXPECT_NE(all.find("t.strokes:7: stroke create sphere: drawn after play and undone, so it never happens"),
            std::string::npos)
      << all;
  EXPECT_EQ(sk.bodies.size(), 1u);
  ASSERT_EQ(sk.runtime.size(), 2u);
  EXPECT_EQ(sk.runtime[1].bodyName, "table");
  EXPECT_EQ(sk.operations[3].body, -1);  // not a body of the sketch
}

TEST(Voxelize, OperationsAfterPlayBecomeRuntimeOperations) {
  const Sketch sk = sketchOf(
      "primitive sphere wood 0 0 0.5 0 0.05\nplay 1\n"
      "stroke move cube 0.1\nsample 1.5 0 0.5 0\nsample 1.8 0 0.6 0\n"
      "primitive sphere stone 2 0 0.5 0 0.05\n"                      // same place: its own grid, not blocked
      "stroke remove sphere 0.05\nsample 2.5 0 0.5 0\nsample 3 0.1 0.5 0\n");
  EXPECT_EQ(sk.bodies.size(), 1u);
  ASSERT_EQ(sk.runtime.size(), 3u);  // sorted by start time
  EXPECT_EQ(sk.runtime[0].kind, RuntimeOp::Kind::kMove);
  EXPECT_DOUBLE_EQ(sk.runtime[0].start, 0.5);
  EXPECT_DOUBLE_EQ(sk.runtime[0].end, 0.8);
  EXPECT_EQ(sk.runtime[0].path.size(), 2u);
  EXPECT_EQ(sk.runtime[1].kind, RuntimeOp::Kind::kCreate);
  EXPECT_DOUBLE_EQ(sk.runtime[1].start, 1.0);
  EXPECT_EQ(sk.runtime[1].particles.size(), sk.particles.size());  // the same sphere, voxelized afresh
  EXPECT_EQ(sk.runtime[1].particles.material[0], 1);
  EXPECT_EQ(sk.runtime[2].kind, RuntimeOp::Kind::kRemove);
  EXPECT_DOUBLE_EQ(sk.runtime[2].removals.front().first, 1.5);
  EXPECT_DOUBLE_EQ(sk.runtime[2].removals.back().first, 2.0);
}

TEST(Voxelize, CreatesAfterPlayCountTowardsTheCap) {
  // Each box alone is ~421k particles (under the cap); together they are over it.
  try {
    sketchOf("primitive box wood 0  0 0.5 0  0.495 0.495 0.495\nplay 1\n"
             "primitive box wood 2  0 0.5 0  0.495 0.495 0.495\n");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 4);
    EXPECT_EQ(e.field(), "sx");  // the largest dimension (all three are equal)
    EXPECT_NE(std::string(e.what()).find("primitive box crosses the particle cap"), std::string::npos) << e.what();
  }
}

TEST(Voxelize, AStampRecordWithABadMeshNamesTheStrokeLineAndTheMesh) {
  try {
    voxelize(parseStrokes("physketch-strokes 1\n\nstamp meshes/cube_open.obj wood 0 scale=0.1\n",
                          PHYSKETCH_SOURCE_DIR "/scenes/x.strokes"),
             kMap, materials());
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 3);
    EXPECT_EQ(e.field(), "path");
    EXPECT_NE(std::string(e.what()).find("cube_open.obj: mesh is not closed"), std::string::npos) << e.what();
  }
}
