// Rasterization kernels (sketch/rasterize.h): the fast paths against the plain
// definition "a cell belongs to a solid when its centre is inside" (Alg. 1), the
// AVX2 kernels against their scalar forms, and voxelization against the thread count.
#include <gtest/gtest.h>

#include <random>
#include <set>

#include "sketch/raster_kernels.h"
#include "sketch/rasterize.h"
#include "sketch/voxelize.h"

using namespace physketch;
using namespace physketch::sketch;

namespace {

const GridMapping kMap(Vec3(0.0, 0.5, 0.0), 1.0);  // h = 1/151 m
const double kH = kMap.voxelSize();

// The cells of a solid by testing every cell centre of its bounding box, with the
// centre cell when none is inside (the reference the row kernels must reproduce).
std::set<std::int64_t> bruteForce(const Solid& s) {
  std::set<std::int64_t> out;
  const Vec3 g = kMap.toGrid(s.centre);
  const double r = s.boundingRadius() / kH + 1;
  for (int k = std::max(0, int(g.z() - r)); k <= std::min(kGridSize - 1, int(g.z() + r)); ++k)
    for (int j = std::max(0, int(g.y() - r)); j <= std::min(kGridSize - 1, int(g.y() + r)); ++j)
      for (int i = std::max(0, int(g.x() - r)); i <= std::min(kGridSize - 1, int(g.x() + r)); ++i)
        if (s.contains(kMap.toWorld(Vec3i(i, j, k)))) out.insert(GridMapping::linear(Vec3i(i, j, k)));
  if (out.empty() && kMap.contains(s.centre)) out.insert(GridMapping::linear(kMap.discretize(s.centre)));
  return out;
}

// A random brush-like solid: every shape, random size (a fraction of a cell to 20
// cells), orientation (grid-aligned half the time for boxes) and position (partly
// outside the grid at times).
Solid randomSolid(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Solid s;
  const SolidShape shapes[] = {SolidShape::kSphere, SolidShape::kCube,     SolidShape::kBox,   SolidShape::kEllipsoid,
                               SolidShape::kCylinder, SolidShape::kCapsule, SolidShape::kTorus};
  s.shape = shapes[rng() % 7];
  const double size = kH * (u(rng) < 0.1 ? 0.2 : 10.0 * u(rng) + 0.3);
  s.a = size, s.b = size * (0.3 + u(rng)), s.c = size * (0.3 + u(rng));
  if (s.shape == SolidShape::kTorus) s.b = 0.3 * s.a;
  s.centre = Vec3(u(rng) - 0.5, u(rng), u(rng) - 0.5) * 1.05 + Vec3(0, -0.025, 0);
  const bool aligned = (s.shape == SolidShape::kBox || s.shape == SolidShape::kCube) && u(rng) < 0.5;
  s.rotation = aligned ? frameFromAxis(Vec3::Unit(static_cast<int>(rng() % 3)))
                       : frameFromAxis(Vec3(u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5));
  return s;
}

std::set<std::int64_t> linearSet(const std::vector<Vec3i>& cells) {
  std::set<std::int64_t> s;
  for (const auto& c : cells) s.insert(GridMapping::linear(c));
  return s;
}

}  // namespace

// Every shape, every fast path (sphere chords, grid-aligned boxes, closed-form
// chords of the other convex shapes, the torus cell by cell) gives exactly the cells
// whose centres are inside. Random continuous positions make exact ties (a centre on
// the surface, where two roundings may disagree) practically impossible.
TEST(Rasterize, EqualsCellByCellTestForEveryShape) {
  std::mt19937 rng(11);
  std::vector<Vec3i> cells;
  for (int n = 0; n < 400; ++n) {
    const Solid s = randomSolid(rng);
    rasterize(s, kMap, cells);
    ASSERT_EQ(linearSet(cells), bruteForce(s)) << "solid " << n << " shape " << int(s.shape);
    ASSERT_EQ(linearSet(cells).size(), cells.size()) << "a cell listed twice";
  }
}

// The bit mask of an operation holds exactly the union of its stamps' cells, lists
// each once in z, y, x order, and merging masks is the union too.
TEST(CellMask, HoldsTheUnionOfItsStamps) {
  std::mt19937 rng(5);
  CellMask a, b;
  std::set<std::int64_t> expected;
  std::vector<Vec3i> cells;
  for (int n = 0; n < 300; ++n) {
    const Solid s = randomSolid(rng);
    (n % 2 ? a : b).add(s, kMap);
    rasterize(s, kMap, cells);
    for (const auto& c : cells) expected.insert(GridMapping::linear(c));
  }
  a.merge(b);
  std::vector<std::int64_t> listed;
  a.forEachCell([&](const Vec3i& c) { listed.push_back(GridMapping::linear(c)); });
  EXPECT_TRUE(std::is_sorted(listed.begin(), listed.end()));
  EXPECT_EQ(std::set<std::int64_t>(listed.begin(), listed.end()), expected);
  EXPECT_EQ(listed.size(), expected.size());
  EXPECT_EQ(a.count(), static_cast<std::int64_t>(expected.size()));
  // forEachCellNotIn hands over each cell not yet taken, once, and marks it taken.
  CellMask taken;
  taken.set(GridMapping::cellOf(listed[listed.size() / 2]));
  std::size_t handed = 0;
  a.forEachCellNotIn(taken, [&](const Vec3i& c) {
    ++handed;
    EXPECT_NE(GridMapping::linear(c), listed[listed.size() / 2]);
  });
  EXPECT_EQ(handed, listed.size() - 1);
  EXPECT_EQ(taken.count(), static_cast<std::int64_t>(listed.size()));
  a.clear();
  EXPECT_EQ(a.count(), 0);
}

// A grid-aligned cube moving by a tenth of a cell per stamp repeats the previous
// stamp's index ranges most of the time (the mask skips those); the union must still
// be every stamp's cells, also across clear() and after a cell was reset.
TEST(CellMask, SlowAlignedBoxesGiveTheUnionOfTheirStamps) {
  CellMask mask;
  std::set<std::int64_t> expected;
  std::vector<Vec3i> cells;
  Solid box;
  box.shape = SolidShape::kCube;
  box.a = 2.3 * kH;
  box.rotation = frameFromAxis(Vec3::UnitY());  // the cube brush's default frame: a signed permutation
  for (int pass = 0; pass < 2; ++pass) {
    mask.clear();
    expected.clear();
    // Backwards along every axis: each time a lower bound moves, new cells appear.
    for (int n = 0; n < 200; ++n) {
      box.centre = Vec3(0.2 - 0.1 * kH * n, 0.6 - 0.07 * kH * n, -0.04 * kH * n);
      mask.add(box, kMap);
      rasterize(box, kMap, cells);
      for (const auto& c : cells) expected.insert(GridMapping::linear(c));
    }
    if (pass == 1) {  // a cell of the last box is unmarked: the same box again must mark it again
      mask.reset(cells.front());
      mask.add(box, kMap);
    }
    std::set<std::int64_t> got;
    mask.forEachCell([&](const Vec3i& c) { got.insert(GridMapping::linear(c)); });
    EXPECT_EQ(got, expected) << "pass " << pass;
  }
}

// The AVX2 kernels are bit-identical to the scalar ones (exactly rounded IEEE
// operations only), including rows at exact integer distances and brushes far
// larger than the grid.
TEST(RasterizeKernels, Avx2MatchesScalar) {
  if (!kernels::hasAvx2()) GTEST_SKIP() << "no AVX2 on this CPU: the scalar kernels run";
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int a0[kernels::kChordPad], a1[kernels::kChordPad], b0[kernels::kChordPad], b1[kernels::kChordPad];
  for (int n = 0; n < 20000; ++n) {
    const bool exact = n % 4 == 0;  // integer centre and radius: chords end exactly on cell centres
    const double gx = exact ? double(rng() % 151) : 160 * u(rng) - 5, gy = exact ? double(rng() % 151) : 160 * u(rng) - 5;
    const double ra = exact ? double(rng() % 20) : (n % 97 == 0 ? 1e10 * u(rng) : 25 * u(rng));
    const double ek = exact ? double(int(rng() % 9) - 4) : 2 * ra * u(rng) - ra;
    const int j0 = int(rng() % 151), len = 1 + int(rng() % (151 - j0));
    kernels::sphereChordsScalar(gx, gy, ek, ra * ra, ra * ra, j0, len, a0, a1);
    kernels::sphereChordsAvx2(gx, gy, ek, ra * ra, ra * ra, j0, len, b0, b1);
    for (int t = 0; t < len; ++t) {
      ASSERT_EQ(a0[t], b0[t]) << "case " << n << " row " << t;
      ASSERT_EQ(a1[t], b1[t]) << "case " << n << " row " << t;
    }
  }
  // Boxes, ellipsoids, cylinders and capsules at any orientation, grid-aligned ones
  // included (rows parallel to faces or to the axis take the "flat" branches).
  for (int n = 0; n < 3000; ++n) {
    Solid s = randomSolid(rng);
    if (s.shape == SolidShape::kSphere || s.shape == SolidShape::kTorus) continue;
    if (n % 3 == 0) s.rotation = frameFromAxis(Vec3::Unit(static_cast<int>(rng() % 3)));
    const kernels::ConvexRows rows(s, kMap);
    const Vec3 g = kMap.toGrid(s.centre);
    for (int k = std::max(0, int(g.z()) - 12); k <= std::min(kGridSize - 1, int(g.z()) + 12); ++k) {
      const int j0 = std::max(0, int(g.y()) - 12), len = std::min(kGridSize - j0, 25);
      kernels::convexChordsScalar(rows, k, j0, len, a0, a1);
      kernels::convexChordsAvx2(rows, k, j0, len, b0, b1);
      for (int t = 0; t < len; ++t) {
        ASSERT_EQ(a0[t], b0[t]) << "solid " << n << " shape " << int(s.shape) << " plane " << k << " row " << t;
        ASSERT_EQ(a1[t], b1[t]) << "solid " << n << " shape " << int(s.shape) << " plane " << k << " row " << t;
      }
    }
  }
  // Runs across every word boundary, clamped at both ends, and empty runs.
  alignas(32) std::uint64_t s[4 * 8] = {}, v[4 * 8] = {};
  for (int n = 0; n < 20000; ++n) {
    int c0[8], c1[8];
    for (int t = 0; t < 8; ++t) {
      c0[t] = int(rng() % 180) - 15;
      c1[t] = c0[t] + int(rng() % 90) - 5;
    }
    const int lo = int(rng() % 40), hi = 110 + int(rng() % 41);
    const bool anyS = kernels::markPlaneScalar(s, 8, c0, c1, lo, hi);
    const bool anyV = kernels::markPlaneAvx2(v, 8, c0, c1, lo, hi);
    ASSERT_EQ(anyS, anyV);
    for (int w = 0; w < 32; ++w) ASSERT_EQ(s[w], v[w]) << "case " << n << " word " << w;
    if (n % 50 == 0) std::fill(s, s + 32, 0), std::fill(v, v + 32, 0);
  }
}

// Voxelization splits long strokes into parts swept in parallel: the sketch must be
// the same bit for bit with 1, 2 and 3 threads (creates, removes, mirror, moves, a cut body).
TEST(Voxelize, SameSketchForAnyThreadCount) {
  std::string text = "physketch-strokes 1\nmirror x 0.02\nstroke create sphere 0.06 wood\n";
  for (int i = 0; i < 5000; ++i) {
    const double a = 0.004 * i;
    text += "sample " + std::to_string(i / 90.0) + " " + std::to_string(0.25 * std::cos(a)) + " " +
            std::to_string(0.2 + 0.00008 * i) + " " + std::to_string(0.25 * std::sin(a)) + "\n";
  }
  text += "mirror off\nstroke remove cube 0.05\n";
  for (int i = 0; i < 3000; ++i)
    text += "sample " + std::to_string(100 + i / 90.0) + " " + std::to_string(-0.3 + 0.0002 * i) + " 0.3 0\n";
  text += "stroke create capsule 0.04 stone orient=follow\n";
  for (int i = 0; i < 2500; ++i)
    text += "sample " + std::to_string(200 + i / 90.0) + " 0 " + std::to_string(0.1 + 0.0003 * i) + " " +
            std::to_string(0.1 * std::sin(0.01 * i)) + "\n";
  // A cut through the capsule stroke where it passes y = 0.5 (i = 1333, z = 0.067): two bodies.
  text += "stroke remove cube 0.08\nsample 300 0 0.5 0.0674\n";
  const StrokeFile f = parseStrokes(text, "t.strokes");
  Material wood, stone;
  wood.name = "wood", stone.name = "stone";
  auto run = [&](int threads) { return voxelize(f, kMap, {wood, stone}, {threads}); };
  const Sketch one = run(1);
  ASSERT_GT(one.particles.size(), 50000u);
  ASSERT_GT(one.bodies.size(), 2u);  // the remove cuts the helix: its pieces are bodies of their own
  for (int threads : {2, 3}) {
    const Sketch many = run(threads);
    EXPECT_TRUE(many.grid == one.grid) << threads << " threads";
    EXPECT_EQ(many.cells, one.cells) << threads << " threads";
    EXPECT_EQ(many.particles.x, one.particles.x);
    EXPECT_EQ(many.particles.stroke, one.particles.stroke);
    EXPECT_EQ(many.particles.material, one.particles.material);
    EXPECT_EQ(many.bodyNames, one.bodyNames) << threads << " threads";
    ASSERT_EQ(many.bodies.size(), one.bodies.size());
    for (std::size_t b = 0; b < one.bodies.size(); ++b) {
      EXPECT_EQ(many.bodies[b].first, one.bodies[b].first);
      EXPECT_EQ(many.bodies[b].count, one.bodies[b].count);
    }
    for (std::size_t o = 0; o < one.operations.size(); ++o) {
      EXPECT_EQ(many.operations[o].created, one.operations[o].created);
      EXPECT_EQ(many.operations[o].removed, one.operations[o].removed);
      EXPECT_EQ(many.operations[o].remaining, one.operations[o].remaining);
    }
  }
}
