// Sketch operations: primitives against analytic volumes, remove (Alg. 2), move,
// mirror, undo/redo, brush shapes at high speed, pressure, body groups.
#include <gtest/gtest.h>

#include <cmath>
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

struct PrimitiveCase {
  const char* record;  // primitive record after "primitive KIND wood 0 " : centre and dims
  double volume;       // m^3
  double area;         // m^2, surface area
};

}  // namespace

TEST(Primitives, VoxelCountsMatchAnalyticVolumes) {
  const double pi = M_PI;
  // Dimensions deliberately off the lattice. Tolerance: the count of cell centres
  // inside a solid differs from V/h^3 by at most the cells cut by its surface,
  // A/h^2 of them, and by much less on average; we allow a quarter of that layer.
  const std::vector<PrimitiveCase> cases = {
      {"box wood 0  0.013 0.52 -0.021  0.213 0.117 0.305", 0.213 * 0.117 * 0.305,
       2 * (0.213 * 0.117 + 0.117 * 0.305 + 0.213 * 0.305)},
      {"box wood 0  0.013 0.52 -0.021  0.213 0.117 0.305 rot=1,1,0,33", 0.213 * 0.117 * 0.305,
       2 * (0.213 * 0.117 + 0.117 * 0.305 + 0.213 * 0.305)},
      {"sphere wood 0  0.01 0.49 0.003  0.151", 4.0 / 3 * pi * std::pow(0.151, 3), 4 * pi * 0.151 * 0.151},
      {"ellipsoid wood 0  0 0.5 0  0.2 0.1 0.15 rot=0,0,1,20", 4.0 / 3 * pi * 0.2 * 0.1 * 0.15,
       4 * pi * std::pow((std::pow(0.02, 1.6) + std::pow(0.03, 1.6) + std::pow(0.015, 1.6)) / 3, 1 / 1.6)},
      {"cylinder wood 0  0.004 0.5 0  0.12 0.31 rot=1,0,0,90", pi * 0.12 * 0.12 * 0.31,
       2 * pi * 0.12 * 0.12 + 2 * pi * 0.12 * 0.31},
      {"capsule wood 0  0 0.5 0.002  0.08 0.33 rot=0,0,1,45", pi * 0.08 * 0.08 * 0.33 + 4.0 / 3 * pi * std::pow(0.08, 3),
       2 * pi * 0.08 * 0.33 + 4 * pi * 0.08 * 0.08},
      {"torus wood 0  0 0.5 0  0.25 0.061 rot=1,0,0,90", 2 * pi * pi * 0.25 * 0.061 * 0.061,
       4 * pi * pi * 0.25 * 0.061},
  };
  for (const auto& c : cases) {
    const Sketch sk = sketchOf(std::string("primitive ") + c.record + "\n");
    const double expected = c.volume / (kH * kH * kH);
    const double surfaceCells = c.area / (kH * kH);
    EXPECT_NEAR(double(sk.particles.size()), expected, 0.25 * surfaceCells)
        << c.record << ": " << sk.particles.size() << " cells, V/h^3 = " << expected;
    EXPECT_EQ(components(sk.cells), 1) << c.record;
    expectConsistent(sk);
  }
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
  // Expected: the box cells minus the cells under the brush at every stamp.
  Stroke brush;
  brush.brush = BrushShape::kSphere;
  brush.size = 0.1;
  std::set<std::int64_t> under;
  std::vector<Vec3> pts;
  interpolateSegment(Vec3(0.1, 0.5, 0), Vec3(0.1, 0.6, 0), kH, pts);
  pts.push_back(Vec3(0.1, 0.5, 0));
  std::vector<Vec3i> cells;
  for (const auto& p : pts) {
    rasterize(brushSolid(brush, p, 1.0, Vec3::UnitY(), kH), kMap, cells);
    for (const auto& c : cells) under.insert(GridMapping::linear(c));
  }
  std::set<std::int64_t> expected;
  for (auto c : cellSet(before))
    if (!under.count(c)) expected.insert(c);
  EXPECT_EQ(cellSet(after), expected);
  EXPECT_EQ(after.operations[1].removed, static_cast<std::int32_t>(before.particles.size() - expected.size()));
  EXPECT_GT(after.operations[1].removed, 1000);
  for (auto c : under) {
    const Vec3i cell(static_cast<int>(c % kGridSize), static_cast<int>((c / kGridSize) % kGridSize),
                     static_cast<int>(c / (kGridSize * kGridSize)));
    EXPECT_EQ(after.grid.at(cell), -1);
  }
  expectConsistent(after);
}

TEST(Move, TranslatesExactlyTheGrabbedVoxels) {
  // Two boxes; the brush grabs part of the first at the first sample and carries it 0.13 m up.
  const std::string boxes =
      "primitive box wood 0  -0.1 0.3 0  0.1 0.1 0.1\n"
      "primitive box stone 0  0.2 0.3 0  0.1 0.1 0.1\n";
  const Sketch before = sketchOf(boxes);
  const Sketch after = sketchOf(boxes + "stroke move sphere 0.08\nsample 1 -0.1 0.3 0\nsample 1.5 -0.1 0.43 0.02\n");
  Stroke brush;
  brush.brush = BrushShape::kSphere;
  brush.size = 0.08;
  std::vector<Vec3i> under;
  rasterize(brushSolid(brush, Vec3(-0.1, 0.3, 0), 1.0, Vec3::UnitY(), kH), kMap, under);
  const Vec3i shift(0, static_cast<int>(std::lround(0.13 / kH)), static_cast<int>(std::lround(0.02 / kH)));
  std::set<std::int64_t> grabbed, expected = cellSet(before);
  for (const auto& c : under)
    if (before.grid.at(c) >= 0) grabbed.insert(GridMapping::linear(c));
  for (auto c : grabbed) expected.erase(c);
  for (const auto& c : under)
    if (before.grid.at(c) >= 0) expected.insert(GridMapping::linear(c + shift));
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

TEST(Move, CarryingParticlesOutOfTheWorkspaceIsAnError) {
  try {
    sketchOf("primitive box wood 0  0 0.9 0  0.1 0.1 0.1\nstroke move sphere 0.1\nsample 1 0 0.9 0\nsample 2 0 0.99 0\n");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 5);
    EXPECT_NE(std::string(e.what()).find("outside the workspace"), std::string::npos);
  }
}

TEST(Mirror, ProducesTheMirroredVoxelSetBitForBit) {
  const std::string stroke =
      "stroke create capsule 0.05 wood orient=follow\nsample 0 0.05 0.4 0.1\nsample 0.1 0.2 0.6 -0.05\n"
      "sample 0.2 0.3 0.55 -0.1\n";
  const Sketch plain = sketchOf(stroke);
  for (const char* plane : {"mirror x 0\n", "mirror x -0.0121\n", "mirror z 0.05\n", "mirror y 0.45\n"}) {
    const Sketch both = sketchOf(std::string(plane) + stroke);
    const StrokeFile f = parseStrokes(std::string("physketch-strokes 1\n") + plane + stroke, "m");
    std::set<std::int64_t> expected = cellSet(plain);
    for (const auto& c : plain.cells) {
      const Vec3i m = mirrorCell(c, f.operations[0].mirror, kMap);
      if (GridMapping::inGrid(m)) expected.insert(GridMapping::linear(m));
    }
    EXPECT_EQ(cellSet(both), expected) << plane;
    // And the result is symmetric: the mirror of every cell is in the set.
    for (const auto& c : both.cells)
      ASSERT_TRUE(expected.count(GridMapping::linear(mirrorCell(c, f.operations[0].mirror, kMap)))) << plane;
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
    EXPECT_NE(std::string(e.what()).find("particle cap"), std::string::npos);
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
