// Ropes and cloth in the sketch (docs/formats.md, "Ropes and cloth"): a rope create is its
// path's centreline at spacing h (a chain), a cloth create the lattice a disc's diameter
// sweeps; removes and moves act on them by position; they count towards the cap; named
// bodies keep one kind. Expectations are closed forms written from the format's
// definitions, never read back from the code under test.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "core/error.h"
#include "core/material_table.h"
#include "sketch/voxelize.h"

using namespace physketch;
using namespace physketch::sketch;

namespace {

const GridMapping kMap(Vec3(0.0, 0.5, 0.0), 1.0);  // h = 1/151 m
const double kH = kMap.voxelSize();
// Positions are stored as float (~0.5 m: an ulp is 6e-8 m), so a distance between two of them
// is known to about 1e-7 m; 1e-6 m is 1.5e-4 h.
constexpr double kTol = 1e-6;

std::vector<Material> materials() {
  return {makeMaterial(MaterialKind::kRigid, "wood"), makeMaterial(MaterialKind::kRope, "cord"),
          makeMaterial(MaterialKind::kCloth, "linen"), makeMaterial(MaterialKind::kFluid, "water"),
          makeMaterial(MaterialKind::kSoft, "jelly"), makeMaterial(MaterialKind::kRigid, "stone")};
}

Sketch sketchOf(const std::string& body, int threads = 0) {
  return voxelize(parseStrokes("physketch-strokes 1\n" + body, "t.strokes"), kMap, materials(), {threads});
}

std::string num(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.12g", v);
  return buf;
}
std::string sample(double t, const Vec3& p) {
  return "sample " + num(t) + " " + num(p.x()) + " " + num(p.y()) + " " + num(p.z()) + "\n";
}

Vec3 at(const Sketch& sk, std::int32_t i) {
  const auto k = static_cast<std::size_t>(i);
  return Vec3(sk.particles.x[k], sk.particles.y[k], sk.particles.z[k]);
}

// The error voxelize throws for `body`, or a failure.
InputError errorOf(const std::string& body) {
  try {
    sketchOf(body);
  } catch (const InputError& e) {
    return e;
  }
  ADD_FAILURE() << "no error for:\n" << body;
  return InputError("", 0, "", "");
}

// M holds exactly the voxel particles; rope and cloth particles are not in it (several may
// share a cell), and their cells are the cells their positions fall in.
void expectConsistent(const Sketch& sk) {
  std::int64_t voxels = 0;
  std::int32_t next = 0;
  for (const BodyRange& b : sk.bodies) {
    ASSERT_EQ(b.first, next);  // bodies tile the particle array in order
    next += b.count;
    for (std::int32_t i = b.first; i < b.first + b.count; ++i) {
      const auto k = static_cast<std::size_t>(i);
      if (b.layout == BodyLayout::kVoxels) {
        ++voxels;
        ASSERT_EQ(sk.grid.at(sk.cells[k]), i);
      } else {
        ASSERT_NE(sk.grid.at(sk.cells[k]), i);
        ASSERT_EQ(sk.cells[k], kMap.discretize(at(sk, i)));
      }
    }
    if (b.layout == BodyLayout::kLattice) {
      ASSERT_EQ(b.rows * b.cols, b.count);
    }
  }
  ASSERT_EQ(next, static_cast<std::int32_t>(sk.particles.size()));
  ASSERT_EQ(sk.grid.occupied(), voxels);
}

}  // namespace

// --- Rope: the centreline at spacing h ------------------------------------------------

// A straight rope of length L: round(L/h) + 1 particles at start + k h dir (Eq. 6-7 counted
// from the start), one chain, the brush size its diameter. Lengths just under and over a
// half spacing check the rounding.
TEST(Rope, AStraightStrokeIsRoundLOverHPlusOneParticlesSpacedH) {
  const Vec3 start(-0.31, 0.22, 0.05);
  const Vec3 dir = Vec3(3, 1, -2).normalized();
  for (const double steps : {40.0, 40.3, 40.45, 40.55, 73.7}) {
    const double length = steps * kH;
    const Sketch sk = sketchOf("stroke create sphere 0.012 cord\n" + sample(0, start) +
                               sample(0.5, start + 0.4 * length * dir) + sample(1, start + length * dir));
    const auto n = static_cast<std::int32_t>(std::lround(steps)) + 1;
    ASSERT_EQ(sk.bodies.size(), 1u);
    const BodyRange& b = sk.bodies[0];
    EXPECT_EQ(b.layout, BodyLayout::kChain);
    ASSERT_EQ(b.count, n) << "L = " << steps << " h";
    EXPECT_FLOAT_EQ(b.radius, 0.006f);
    for (std::int32_t k = 0; k < n; ++k) EXPECT_NEAR((at(sk, k) - (start + k * kH * dir)).norm(), 0.0, kTol) << k;
    EXPECT_EQ(sk.operations[0].created, n);
    EXPECT_EQ(sk.operations[0].remaining, n);
    EXPECT_EQ(sk.operations[0].body, 0);
    expectConsistent(sk);
  }
}

// An L-shaped path: along x for a, then along y. The walk places x = k h while k h <= a, then
// the next particle on the y leg at distance h from the last one: y = sqrt(h^2 - (a - k h)^2).
TEST(Rope, AroundACornerTheNextParticleIsAChordOfHAway) {
  const Vec3 o(-0.2, 0.3, 0.0);
  const double a = 10.37 * kH, bLeg = 6.0 * kH;
  const Sketch sk = sketchOf("stroke create sphere 0.01 cord\n" + sample(0, o) + sample(1, o + Vec3(a, 0, 0)) +
                             sample(2, o + Vec3(a, bLeg, 0)));
  ASSERT_EQ(sk.bodies.size(), 1u);
  for (int k = 0; k <= 10; ++k) EXPECT_NEAR((at(sk, k) - (o + Vec3(k * kH, 0, 0))).norm(), 0.0, kTol) << k;
  const double y1 = std::sqrt(kH * kH - (a - 10 * kH) * (a - 10 * kH));
  EXPECT_NEAR((at(sk, 11) - (o + Vec3(a, y1, 0))).norm(), 0.0, kTol);
  for (int k = 12; k < sk.bodies[0].count; ++k)
    EXPECT_NEAR((at(sk, k) - (o + Vec3(a, y1 + (k - 11) * kH, 0))).norm(), 0.0, kTol) << k;
  // The end: the last one is the first within h/2 of the last sample (round, as Eq. 6).
  const double left = bLeg - (y1 + (sk.bodies[0].count - 1 - 11) * kH);
  EXPECT_LT(std::abs(left), 0.5 * kH + kTol);
}

// A half circle of radius R drawn with 400 samples: every neighbour distance is h (chords of
// exactly h; tolerance kTol from the float storage), every particle lies on the polyline,
// within its sagitta R (1 - cos(pi/800)) = 1.5e-6 m of the circle, and their number is that of
// chords h on the circle, pi / (2 asin(h / 2R)), rounded, plus one (+-1: the polyline is not
// the circle).
TEST(Rope, OnACurvedPathNeighboursStayHApartAndOnThePath) {
  const double r = 0.2;
  const Vec3 c(0.0, 0.5, 0.0);
  std::string text = "stroke create sphere 0.01 cord\n";
  const int samples = 400;
  for (int i = 0; i <= samples; ++i) {
    const double a = M_PI * i / samples;
    text += sample(0.01 * i, c + r * Vec3(std::cos(a), std::sin(a), 0));
  }
  const Sketch sk = sketchOf(text);
  ASSERT_EQ(sk.bodies.size(), 1u);
  const std::int32_t n = sk.bodies[0].count;
  const double chords = M_PI / (2.0 * std::asin(kH / (2.0 * r)));
  EXPECT_NEAR(n, std::lround(chords) + 1, 1);
  const double sagitta = r * (1.0 - std::cos(M_PI / (2.0 * samples)));
  for (std::int32_t k = 0; k < n; ++k) {
    const double d = (at(sk, k) - c).norm();
    EXPECT_NEAR(at(sk, k).z(), 0.0, kTol);
    if (k + 1 == n) {  // the last one goes h on from the one before, towards the end: within h/2 of it
      EXPECT_LE((at(sk, k) - (c + Vec3(-r, 0, 0))).norm(), 0.5 * kH + kTol);
      continue;
    }
    EXPECT_NEAR((at(sk, k + 1) - at(sk, k)).norm(), kH, kTol) << k;
    EXPECT_GE(d, r - sagitta - kTol) << k;
    EXPECT_LE(d, r + kTol) << k;
  }
}

// --- Cloth: the lattice a disc's diameter sweeps ------------------------------------------

// A disc of diameter D (axis y: horizontal) dragged a length L along x sweeps the sheet
// spanned by x and w = y x x = -z: rows = round(L/h) + 1 along x, cols = round(D/h) + 1 across,
// node (r, c) = start + r h x + (c - (cols-1)/2) h w.
TEST(Cloth, ADiscDraggedAlongAPathGivesARowsByColsLatticeSpacedH) {
  const Vec3 start(-0.2, 0.4, 0.01);
  const double length = 0.3037, diameter = 0.2113;
  const Sketch sk =
      sketchOf("stroke create disc " + num(diameter) + " linen\n" + sample(0, start) + sample(1, start + Vec3(length, 0, 0)));
  ASSERT_EQ(sk.bodies.size(), 1u);
  const BodyRange& b = sk.bodies[0];
  const int rows = static_cast<int>(std::lround(length / kH)) + 1, cols = static_cast<int>(std::lround(diameter / kH)) + 1;
  EXPECT_EQ(b.layout, BodyLayout::kLattice);
  ASSERT_EQ(b.rows, rows);
  ASSERT_EQ(b.cols, cols);
  ASSERT_EQ(b.count, rows * cols);
  EXPECT_FLOAT_EQ(b.radius, static_cast<float>(0.5 * kH));  // a disc one voxel thick by default
  const Vec3 w(0, 0, -1);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const Vec3 expect = start + r * kH * Vec3::UnitX() + (c - 0.5 * (cols - 1)) * kH * w;
      ASSERT_NEAR((at(sk, r * cols + c) - expect).norm(), 0.0, kTol) << r << "," << c;
    }
  // Neighbour spacing along rows and across cols: h.
  EXPECT_NEAR((at(sk, cols) - at(sk, 0)).norm(), kH, kTol);
  EXPECT_NEAR((at(sk, 1) - at(sk, 0)).norm(), kH, kTol);
  expectConsistent(sk);
}

// A disc standing in the xy plane (axis z) dragged along x hangs a curtain: w = z x x = +y.
TEST(Cloth, ADiscOnItsEdgeSweepsAVerticalSheet) {
  const Vec3 start(-0.1, 0.5, 0.0);
  const Sketch sk = sketchOf("stroke create disc 0.1 linen axis=0,0,1 length=0.004\n" + sample(0, start) +
                             sample(1, start + Vec3(0.2, 0, 0)));
  const BodyRange& b = sk.bodies.at(0);
  EXPECT_FLOAT_EQ(b.radius, 0.002f);  // half the disc's thickness
  const double half = 0.5 * (b.cols - 1) * kH;
  EXPECT_NEAR((at(sk, 0) - (start - half * Vec3::UnitY())).norm(), 0.0, kTol);
  EXPECT_NEAR((at(sk, b.cols - 1) - (start + half * Vec3::UnitY())).norm(), 0.0, kTol);
  for (std::int32_t i = 0; i < b.count; ++i) EXPECT_NEAR(at(sk, i).z(), 0.0, kTol);
}

// --- Errors name file:line:field ------------------------------------------------------

TEST(Strands, WhatCannotMakeARopeOrAClothNamesItsLineAndField) {
  auto expectError = [](const std::string& body, int line, const std::string& field, const std::string& text) {
    const InputError e = errorOf(body);
    EXPECT_EQ(e.file(), "t.strokes");
    EXPECT_EQ(e.line(), line) << e.what();
    EXPECT_EQ(e.field(), field) << e.what();
    EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
  };
  expectError("primitive box wood 0  0 0.5 0  0.1 0.1 0.1\nprimitive box cord 1  0 0.3 0  0.1 0.1 0.1\n", 3, "material",
              "material 'cord' is kind rope: a rope is drawn with a create stroke");
  expectError("stamp " PHYSKETCH_SOURCE_DIR "/scenes/meshes/cube.obj linen 0 scale=0.1 at=0,0.5,0\n", 2, "material",
              "kind cloth");
  expectError("stroke create sphere 0.1 linen\nsample 0 0 0.5 0\nsample 1 0.1 0.5 0\n", 2, "brush",
              "use brush 'disc', not 'sphere'");
  expectError("stroke create disc 0.1 linen orient=follow\nsample 0 0 0.5 0\nsample 1 0.1 0.5 0\n", 2, "orient",
              "orient=follow");
  // A horizontal disc (axis y) dragged straight up: the path runs along the axis from line 5 on.
  expectError("stroke create disc 0.1 linen\nsample 0 0 0.5 0\nsample 1 0.1 0.5 0\nsample 2 0.1 0.7 0\n", 5, "axis",
              "runs along the disc's axis");
  expectError("stroke create disc 0.1 linen\nsample 0 0 0.5 0\n", 2, "samples", "a cloth needs a path");
  // A cloth wider than the workspace allows: the node outside names its sample's line and the axis.
  expectError("stroke create disc 0.4 linen\nsample 0 -0.2 0.5 0.4\nsample 1 0.2 0.5 0.4\n", 3, "z",
              "cloth node outside the workspace");
}

TEST(Strands, ANamedBodyCannotMixARigidPartWithAFluidRopeClothOrSoftOne) {
  const std::string box = "primitive box wood 0  0 0.5 0  0.1 0.1 0.1 body=b\n";
  for (const char* other : {"water", "jelly"}) {
    const InputError e = errorOf(box + "primitive sphere " + other + " 1  0.2 0.5 0  0.05 body=b\n");
    EXPECT_EQ(e.line(), 3) << e.what();
    EXPECT_EQ(e.field(), "body") << e.what();
    EXPECT_NE(std::string(e.what()).find("body 'b' mixes kinds"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("its part at line 2 is kind rigid (material 'wood')"), std::string::npos)
        << e.what();
  }
  for (const char* other : {"cord", "linen"}) {
    const InputError e = errorOf(box + "stroke create disc 0.05 " + other + " body=b\nsample 1 0 0.3 0\nsample 2 0.1 0.3 0\n");
    EXPECT_EQ(e.line(), 3) << e.what();
    EXPECT_EQ(e.field(), "body") << e.what();
    EXPECT_NE(std::string(e.what()).find("a rope or a cloth is a body of its own"), std::string::npos) << e.what();
  }
  // Two ropes under one name: two chains are not one body either.
  const InputError e = errorOf("stroke create sphere 0.01 cord body=r\nsample 0 0 0.5 0\nsample 1 0.1 0.5 0\n"
                               "stroke create sphere 0.01 cord body=r\nsample 2 0 0.6 0\nsample 3 0.1 0.6 0\n");
  EXPECT_EQ(e.line(), 5) << e.what();
  EXPECT_EQ(e.field(), "body") << e.what();
  // Rigid parts still mix rigid materials; a fluid and a soft create are voxel bodies of their own.
  const Sketch sk = sketchOf(box + "primitive sphere stone 1  0.1 0.5 0  0.05 body=b\n"
                                   "primitive sphere water 2  -0.3 0.5 0  0.05\nprimitive sphere jelly 3  0.3 0.5 0  0.05\n");
  ASSERT_EQ(sk.bodies.size(), 3u);
  for (const BodyRange& b : sk.bodies) EXPECT_EQ(b.layout, BodyLayout::kVoxels);
  EXPECT_EQ(sk.bodyNames, (std::vector<std::string>{"b", "stroke 2", "stroke 3"}));
  expectConsistent(sk);
}

// Bodies are in file order whatever their layout, and M follows the voxel particles there.
TEST(Strands, BodiesAreInFileOrderWithVoxelsInM) {
  const Sketch sk = sketchOf("primitive box wood 0  0 0.5 0  0.1 0.1 0.1\n"
                             "stroke create sphere 0.01 cord\nsample 1 -0.2 0.7 0\nsample 2 0.2 0.7 0\n"
                             "primitive sphere jelly 3  0.3 0.5 0  0.05\n"
                             "stroke create disc 0.1 linen\nsample 4 -0.2 0.3 0\nsample 5 0.2 0.3 0\n"
                             "primitive sphere water 6  -0.3 0.5 0  0.05\n"
                             "stroke remove sphere 0.05\nsample 7 0 0.5 0.05\n"  // a dent in the box
                             "stroke remove sphere 0.02\nsample 8 0.05 0.7 0\n");   // cuts the rope in two
  ASSERT_EQ(sk.bodies.size(), 6u);
  EXPECT_EQ(sk.bodyNames,
            (std::vector<std::string>{"stroke 0", "stroke 1", "stroke 1 #2", "stroke 2", "stroke 3", "stroke 4"}));
  const BodyLayout layout[] = {BodyLayout::kVoxels,  BodyLayout::kChain,   BodyLayout::kChain,
                               BodyLayout::kVoxels, BodyLayout::kLattice, BodyLayout::kVoxels};
  const int op[] = {0, 1, 1, 2, 3, 4};
  for (std::size_t b = 0; b < 6; ++b) {
    EXPECT_EQ(sk.bodies[b].layout, layout[b]) << b;
    EXPECT_EQ(sk.bodies[b].stroke, op[b]);
    for (std::int32_t i = sk.bodies[b].first; i < sk.bodies[b].first + sk.bodies[b].count; ++i)
      ASSERT_EQ(sk.particles.stroke[static_cast<std::size_t>(i)], op[b]);
  }
  for (int o = 0; o < 5; ++o) EXPECT_EQ(sk.operations[static_cast<std::size_t>(o)].body, o < 2 ? o : o + 1) << o;
  bool named = false;  // lint names the pieces of the cut rope where they now are
  for (const auto& w : sk.warnings)
    named = named || w.find("body 'stroke 1' was cut by a remove or move into 2 bodies: 'stroke 1', 'stroke 1 #2'") !=
                         std::string::npos;
  EXPECT_TRUE(named);
  expectConsistent(sk);
}

// --- Remove and move by position ------------------------------------------------------

// A rope along x at x0 + k h; a sphere remove of radius r at xc takes exactly the particles
// with |x0 + k h - xc| <= r (by position, Alg. 2), leaving two chains: the longer first,
// keeping the name, the other "stroke 0 #2".
TEST(Rope, ARemoveByPositionCutsItIntoTwoChains) {
  const Vec3 start(-0.3, 0.41, 0.013);
  const int n = 81;  // round(80.2) + 1
  const double xc = start.x() + 20.4 * kH, radius = 0.5 * 0.031;
  const Sketch sk = sketchOf("stroke create sphere 0.01 cord\n" + sample(0, start) +
                             sample(1, start + Vec3(80.2 * kH, 0, 0)) + "stroke remove sphere 0.031\n" +
                             sample(2, Vec3(xc, start.y(), start.z())));
  int before = 0, removed = 0;
  for (int k = 0; k < n; ++k) {
    const double d = std::abs(start.x() + k * kH - xc);
    if (d <= radius) ++removed;
    else if (removed == 0) ++before;
  }
  const int after = n - before - removed;
  ASSERT_GT(before, 0);
  ASSERT_LT(before, after);
  ASSERT_EQ(sk.bodies.size(), 2u);
  EXPECT_EQ(sk.bodies[0].count, after);
  EXPECT_EQ(sk.bodies[1].count, before);
  for (const BodyRange& b : sk.bodies) EXPECT_EQ(b.layout, BodyLayout::kChain);
  EXPECT_EQ(sk.bodyNames, (std::vector<std::string>{"stroke 0", "stroke 0 #2"}));
  // The longer chain is the far end of the path, in path order.
  EXPECT_NEAR(at(sk, 0).x(), start.x() + (before + removed) * kH, kTol);
  EXPECT_NEAR(at(sk, sk.bodies[1].first).x(), start.x(), kTol);
  EXPECT_EQ(sk.operations[1].removed, removed);
  EXPECT_EQ(sk.operations[0].remaining, n - removed);
  bool warned = false;
  for (const auto& w : sk.warnings) warned = warned || w.find("cut by a remove or move into 2 bodies") != std::string::npos;
  EXPECT_TRUE(warned);
  expectConsistent(sk);
}

// A remove through the middle of a cloth leaves holes: the lattice keeps its rows and cols,
// the nodes inside the brush get phase::kRemoved. One that takes whole first rows crops them.
TEST(Cloth, ARemoveLeavesHolesAndCropsRowsItEmptied) {
  const Vec3 start(-0.2, 0.4, 0.0);
  const std::string cloth = "stroke create disc 0.1 linen\n" + sample(0, start) + sample(1, start + Vec3(0.2, 0, 0));
  const Sketch whole = sketchOf(cloth);
  const BodyRange full = whole.bodies.at(0);
  const Vec3 hole(0.0, 0.4, 0.0);
  const Sketch holed = sketchOf(cloth + "stroke remove sphere 0.04\n" + sample(2, hole));
  int inside = 0;
  for (std::int32_t i = 0; i < full.count; ++i) inside += (at(whole, i) - hole).norm() <= 0.02;
  ASSERT_GT(inside, 10);
  ASSERT_EQ(holed.bodies.size(), 1u);
  EXPECT_EQ(holed.bodies[0].rows, full.rows);
  EXPECT_EQ(holed.bodies[0].cols, full.cols);
  int holes = 0;
  for (std::int32_t i = 0; i < full.count; ++i) {
    const bool gone = phase::has(holed.particles.phase[static_cast<std::size_t>(i)], phase::kRemoved);
    EXPECT_EQ(gone, (at(whole, i) - hole).norm() <= 0.02) << i;
    holes += gone;
  }
  EXPECT_EQ(holes, inside);
  EXPECT_EQ(liveParticles(holed.particles), full.count - inside);
  EXPECT_EQ(holed.operations[0].remaining, full.count - inside);
  // A cube 3.5 h wide centred on the first row, dragged across the cloth, takes rows 0 and 1
  // whole: 2 rows fewer.
  const Sketch cropped = sketchOf(cloth + "stroke remove cube " + num(3.5 * kH) + "\n" +
                                  sample(2, start + Vec3(0, 0, -0.07)) + sample(3, start + Vec3(0, 0, 0.07)));
  ASSERT_EQ(cropped.bodies.size(), 1u);
  EXPECT_EQ(cropped.bodies[0].rows, full.rows - 2);
  EXPECT_EQ(cropped.bodies[0].cols, full.cols);
  EXPECT_NEAR((at(cropped, 0) - at(whole, 2 * full.cols)).norm(), 0.0, kTol);
  expectConsistent(cropped);
}

// A move grabbing one particle of a rope carries the whole rope by the brush's travel rounded
// to whole voxels (as it carries voxels), and the voxels with it.
TEST(Rope, AMoveCarriesTheWholeRopeItGrabs) {
  const Vec3 start(-0.2, 0.3, 0.0);
  const std::string rope = "stroke create sphere 0.01 cord\n" + sample(0, start) + sample(1, start + Vec3(0.2, 0, 0));
  const Sketch still = sketchOf(rope);
  const Vec3 travel(0.0312, 0.1007, -0.02);
  const Vec3 shift = (travel / kH).array().round().matrix() * kH;
  const Sketch moved = sketchOf(rope + "stroke move sphere 0.02\n" + sample(2, start + Vec3(0.2, 0, 0)) +
                                sample(3, start + Vec3(0.2, 0, 0) + travel));
  ASSERT_EQ(moved.bodies.size(), 1u);
  ASSERT_EQ(moved.bodies[0].count, still.bodies[0].count);
  for (std::int32_t i = 0; i < still.bodies[0].count; ++i)
    EXPECT_NEAR((at(moved, i) - (at(still, i) + shift)).norm(), 0.0, kTol) << i;
  EXPECT_EQ(moved.operations[1].moved, still.bodies[0].count);
  // After a remove cut it in two, a move grabbing one chain carries that chain only.
  const std::string cut = rope + "stroke remove sphere 0.02\n" + sample(2, start + Vec3(0.05, 0, 0));
  const Sketch cutStill = sketchOf(cut);
  const Sketch cutMoved = sketchOf(cut + "stroke move sphere 0.02\n" + sample(3, start + Vec3(0.2, 0, 0)) +
                                   sample(4, start + Vec3(0.2, 0, 0) + travel));
  ASSERT_EQ(cutMoved.bodies.size(), 2u);
  const BodyRange far = cutMoved.bodies[0], near = cutMoved.bodies[1];  // longer first: the far one
  for (std::int32_t i = far.first; i < far.first + far.count; ++i)
    EXPECT_NEAR((at(cutMoved, i) - (at(cutStill, i) + shift)).norm(), 0.0, kTol) << i;
  for (std::int32_t i = near.first; i < near.first + near.count; ++i)
    EXPECT_NEAR((at(cutMoved, i) - at(cutStill, i)).norm(), 0.0, kTol) << i;
  EXPECT_EQ(cutMoved.operations[2].moved, far.count);
  // A move that misses it leaves it where it is.
  const Sketch missed = sketchOf(rope + "stroke move sphere 0.02\n" + sample(2, Vec3(0, 0.6, 0)) + sample(3, Vec3(0, 0.7, 0)));
  EXPECT_EQ(missed.particles.x, still.particles.x);
  EXPECT_EQ(missed.particles.y, still.particles.y);
}

// --- The cap, mirror, after play, threads ---------------------------------------------

// Rope particles count towards the 688,590 cap: with voxels K (measured alone) a rope of
// cap - K particles fits and one more crosses it, named by the rope's line and 'samples';
// after play too.
TEST(Rope, ParticlesCountTowardsTheCap) {
  // Three boxes just under the cap; each dimension a whole odd count of cells (n - 0.5) h.
  auto box = [](double t, const Vec3& c, int nx, int ny, int nz) {
    return "primitive box wood " + num(t) + " " + num(c.x()) + " " + num(c.y()) + " " + num(c.z()) + " " +
           num((nx - 0.5) * kH) + " " + num((ny - 0.5) * kH) + " " + num((nz - 0.5) * kH) + "\n";
  };
  const std::string boxes = box(0, Vec3(0, 0.5, 0), 87, 87, 87) + box(0, Vec3(0, 0.5 + 50 * kH, 0), 87, 3, 87) +
                            box(0, Vec3(0, 0.5 - 50 * kH, 0), 87, 1, 83);
  const std::int64_t k = static_cast<std::int64_t>(sketchOf(boxes).particles.size());
  const std::int64_t room = kMaxParticles - k;
  ASSERT_GT(room, 10);
  ASSERT_LT(room, 230);  // a straight rope of that many fits along the workspace's diagonal
  auto rope = [&](double t, std::int64_t n) {  // n particles: L = (n - 1.2) h
    const Vec3 a(-0.45, 0.05, -0.45), dir = Vec3(1, 1, 1).normalized();
    return std::string("stroke create sphere 0.01 cord\n") + sample(t, a) + sample(t + 1, a + (n - 1.2) * kH * dir);
  };
  EXPECT_EQ(sketchOf(rope(0, room)).particles.size(), static_cast<std::size_t>(room));
  EXPECT_EQ(liveParticles(sketchOf(boxes + rope(1, room)).particles), kMaxParticles);
  for (const bool afterPlay : {false, true}) {
    const InputError e = errorOf(boxes + (afterPlay ? "play 0.5\n" : "") + rope(1, room + 1));
    EXPECT_EQ(e.line(), afterPlay ? 6 : 5) << e.what();
    EXPECT_EQ(e.field(), "samples") << e.what();
    EXPECT_NE(std::string(e.what()).find("crosses the particle cap of 688590"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("use a shorter rope"), std::string::npos) << e.what();
  }
}

// A mirrored rope is two chains, two bodies; after play each copy is a create of its own
// with the layout, and counts towards the cap like the sketch's.
TEST(Rope, MirrorCopiesAndCreatesAfterPlayKeepTheirLayout) {
  auto text = [](int t) {
    return "mirror x 0\nstroke create sphere 0.01 cord\n" + sample(t, Vec3(0.1, 0.5, 0)) + sample(t + 1, Vec3(0.3, 0.5, 0)) +
           "stroke create disc 0.1 linen\n" + sample(t + 2, Vec3(0.1, 0.3, 0)) + sample(t + 3, Vec3(0.3, 0.3, 0)) +
           "mirror off\n";
  };
  const Sketch before = sketchOf(text(0));
  ASSERT_EQ(before.bodies.size(), 4u);
  EXPECT_EQ(before.bodyNames, (std::vector<std::string>{"stroke 0", "stroke 0 #2", "stroke 1", "stroke 1 #2"}));
  for (int b : {0, 1}) EXPECT_EQ(before.bodies[static_cast<std::size_t>(b)].layout, BodyLayout::kChain);
  for (int b : {2, 3}) EXPECT_EQ(before.bodies[static_cast<std::size_t>(b)].layout, BodyLayout::kLattice);
  for (std::int32_t i = 0; i < before.bodies[0].count; ++i)  // the copy: x -> -x
    EXPECT_NEAR((at(before, before.bodies[1].first + i) - at(before, i).cwiseProduct(Vec3(-1, 1, 1))).norm(), 0.0, kTol);
  expectConsistent(before);
  const Sketch after = sketchOf("primitive box wood 0  0 0.1 0  0.1 0.1 0.1\nplay 0\n" + text(1));
  ASSERT_EQ(after.runtime.size(), 4u);
  for (std::size_t r = 0; r < 4; ++r) {
    const RuntimeOp& op = after.runtime[r];
    const BodyRange& b = before.bodies[r];
    EXPECT_EQ(op.kind, RuntimeOp::Kind::kCreate);
    EXPECT_EQ(op.layout, b.layout);
    EXPECT_EQ(op.rows, b.rows);
    EXPECT_EQ(op.cols, b.cols);
    EXPECT_EQ(op.radius, b.radius);
    EXPECT_EQ(op.bodyName, std::vector<std::string>({"stroke 1", "stroke 1 #2", "stroke 2", "stroke 2 #2"})[r]);
    ASSERT_EQ(op.particles.size(), static_cast<std::size_t>(b.count));
    for (std::int32_t i = 0; i < b.count; ++i) EXPECT_EQ(op.particles.x[static_cast<std::size_t>(i)], before.particles.x[static_cast<std::size_t>(b.first + i)]);
  }
}

// The same sketch, bit for bit, with 1 and 2 threads: ropes and cloth mixed with voxels,
// mirrored, cut by a remove and carried by a move.
TEST(Strands, SameSketchForOneAndTwoThreads) {
  std::string text = "mirror x 0.013\nstroke create sphere 0.01 cord\n";
  for (int i = 0; i <= 300; ++i)
    text += sample(0.01 * i, Vec3(0.1 + 0.2 * std::cos(0.02 * i), 0.3 + 0.0008 * i, 0.2 * std::sin(0.02 * i)));
  text += "stroke create capsule 0.05 wood\nsample 4 -0.3 0.6 0\nsample 5 0.3 0.6 0.1\nmirror off\n"
          "stroke create disc 0.2 linen axis=0,0.2,1\nsample 6 -0.2 0.8 0\nsample 7 0 0.75 0.1\nsample 8 0.2 0.8 0.15\n"
          "stroke remove sphere 0.03\nsample 9 0.0168 0.38 0.1819\nsample 10 -0.1 0.75 0.1\n"
          "stroke move cube 0.04\nsample 11 0.2 0.8 0.15\nsample 12 0.25 0.85 0.1\n";
  const Sketch one = sketchOf(text, 1), two = sketchOf(text, 2);
  // The remove cuts the rope (its copy is "#2"), the move carries the cloth.
  ASSERT_NE(std::find(one.bodyNames.begin(), one.bodyNames.end(), "stroke 0 #3"), one.bodyNames.end());
  ASSERT_GT(one.operations[4].moved, 0);
  EXPECT_TRUE(one.grid == two.grid);
  EXPECT_EQ(one.cells, two.cells);
  EXPECT_EQ(one.particles.x, two.particles.x);
  EXPECT_EQ(one.particles.y, two.particles.y);
  EXPECT_EQ(one.particles.z, two.particles.z);
  EXPECT_EQ(one.particles.phase, two.particles.phase);
  EXPECT_EQ(one.particles.stroke, two.particles.stroke);
  EXPECT_EQ(one.bodyNames, two.bodyNames);
  ASSERT_EQ(one.bodies.size(), two.bodies.size());
  for (std::size_t b = 0; b < one.bodies.size(); ++b) {
    EXPECT_EQ(one.bodies[b].first, two.bodies[b].first);
    EXPECT_EQ(one.bodies[b].count, two.bodies[b].count);
    EXPECT_EQ(one.bodies[b].layout, two.bodies[b].layout);
    EXPECT_EQ(one.bodies[b].rows, two.bodies[b].rows);
    EXPECT_EQ(one.bodies[b].cols, two.bodies[b].cols);
  }
  expectConsistent(one);
}

// Random sketches of ropes, straight cloths and voxels, mirrored, cut by removes and carried by
// moves: whatever happens, M holds exactly the voxel particles, every chain's neighbours stay h
// apart and every lattice's live row and col neighbours too (removes take nodes, moves carry
// whole chains and lattices), the particles left are those the operations say remain, and a
// cut cloth's holes are exactly its removed nodes.
TEST(Strands, RandomSketchesKeepTheLayoutsAndTheCounts) {
  std::uint64_t state = 12345;
  auto uniform = [&](double lo, double hi) {  // a fixed LCG: the same sketches on every platform
    state = state * 6364136223846793005ULL + 1442695040888963407ULL;
    return lo + (hi - lo) * double(state >> 11) / double(1ULL << 53);
  };
  auto point = [&] {  // one draw per statement: the order of evaluation is fixed
    const double x = uniform(-0.3, 0.3);
    const double y = uniform(0.2, 0.8);
    const double z = uniform(-0.3, 0.3);
    return Vec3(x, y, z);
  };
  double t = 0;
  auto next = [&](const Vec3& p) { return sample(t += 0.1, p); };
  int sketches = 0, cutRopes = 0, holedCloths = 0, carried = 0;  // what the rounds exercised
  for (int round = 0; round < 40; ++round) {
    std::string text;
    for (int op = 0; op < 8; ++op) {
      const int what = static_cast<int>(uniform(0, 6));
      if (what == 0) text += "mirror x " + num(uniform(-0.05, 0.05)) + "\n";
      const double size = uniform(0.005, 0.15);
      if (what <= 1) {
        text += "stroke create sphere " + num(0.1 * size + 0.005) + " cord\n";
        for (int k = 0; k < 4; ++k) text += next(point());
      } else if (what == 2) {  // a straight cloth: a horizontal disc dragged along x
        const Vec3 a = point();
        const double length = uniform(0.05, 0.2);
        text += "stroke create disc " + num(size) + " linen\n";
        text += next(a);
        text += next(a + Vec3(length, 0, 0));
      } else if (what == 3) {
        text += "primitive sphere wood " + num(t += 0.1) + " " + num(size) + " 0.5 0 0.05\n";
      } else if (what == 4) {
        text += "stroke remove sphere " + num(0.5 * size + 0.01) + "\n";
        text += next(point());
        text += next(point());
      } else {
        text += "stroke move sphere " + num(size + 0.03) + "\n";
        text += next(point());
        text += next(point() * 0.1 + Vec3(0, 0.45, 0));
      }
      text += "mirror off\n";
    }
    Sketch sk(kMap);
    try {
      sk = sketchOf(text);
    } catch (const InputError&) {
      continue;  // a move that would carry something out of the workspace
    }
    SCOPED_TRACE(text);
    ++sketches;
    for (std::size_t b = 0; b < sk.bodies.size(); ++b) {
      cutRopes += sk.bodies[b].layout == BodyLayout::kChain && sk.bodyNames[b].find(" #3") != std::string::npos;
      const BodyRange& r = sk.bodies[b];
      if (r.layout != BodyLayout::kLattice) continue;
      bool holed = false;
      for (std::int32_t i = r.first; i < r.first + r.count; ++i)
        holed = holed || phase::has(sk.particles.phase[static_cast<std::size_t>(i)], phase::kRemoved);
      holedCloths += holed;
    }
    for (const auto& o : sk.operations) carried += o.moved > 0 && o.material < 0;
    expectConsistent(sk);
    std::int64_t remaining = 0;
    for (const auto& o : sk.operations) remaining += o.remaining;
    EXPECT_EQ(remaining, liveParticles(sk.particles));
    for (const BodyRange& b : sk.bodies) {
      auto live = [&](std::int32_t i) { return !phase::has(sk.particles.phase[static_cast<std::size_t>(i)], phase::kRemoved); };
      if (b.layout == BodyLayout::kChain) {
        for (std::int32_t i = b.first; i + 1 < b.first + b.count; ++i) {
          ASSERT_TRUE(live(i));
          ASSERT_NEAR((at(sk, i + 1) - at(sk, i)).norm(), kH, kTol);
        }
      }
      if (b.layout == BodyLayout::kLattice)
        for (std::int32_t r = 0; r < b.rows; ++r)
          for (std::int32_t c = 0; c < b.cols; ++c) {
            const std::int32_t i = b.first + r * b.cols + c;
            if (c + 1 < b.cols && live(i) && live(i + 1)) {
              ASSERT_NEAR((at(sk, i + 1) - at(sk, i)).norm(), kH, kTol);
            }
            if (r + 1 < b.rows && live(i) && live(i + b.cols)) {
              ASSERT_NEAR((at(sk, i + b.cols) - at(sk, i)).norm(), kH, kTol);
            }
          }
    }
  }
  // The rounds did exercise what they check (this seed: 38 sketches, 5 cut ropes, 1 holed cloth, 6 moves).
  EXPECT_GE(sketches, 30);
  EXPECT_GT(cutRopes, 0);
  EXPECT_GT(holedCloths, 0);
  EXPECT_GT(carried, 0);
}
