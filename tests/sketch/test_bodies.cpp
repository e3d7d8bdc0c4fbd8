// Bodies cut before play (docs/formats.md, "Bodies"): a remove or a move that
// disconnects a body makes one body per piece; mirrored copies and named parts stay
// one body while each is whole. Expectations come from brute-force inside tests of
// the analytic solids and hand-derived cell arithmetic.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <string>

#include "sketch/voxelize.h"

using namespace physketch;
using namespace physketch::sketch;

namespace {

const GridMapping kMap(Vec3(0.0, 0.5, 0.0), 1.0);  // h = 1/151 m
const double kH = kMap.voxelSize();

Sketch sketchOf(const std::string& body) {
  Material wood, stone;
  wood.name = "wood", stone.name = "stone";
  return voxelize(parseStrokes("physketch-strokes 1\n" + body, "t.strokes"), kMap, {wood, stone});
}

// Every cell of the grid whose centre passes `inside`.
template <class Inside>
std::set<std::int64_t> cellsWhere(Inside&& inside) {
  std::set<std::int64_t> out;
  for (int k = 0; k < kGridSize; ++k)
    for (int j = 0; j < kGridSize; ++j)
      for (int i = 0; i < kGridSize; ++i)
        if (inside(kMap.toWorld(Vec3i(i, j, k)))) out.insert(GridMapping::linear(Vec3i(i, j, k)));
  return out;
}

bool inBox(const Vec3& q, const Vec3& centre, const Vec3& size) {
  return ((q - centre).cwiseAbs() - 0.5 * size).maxCoeff() <= 0;
}

// The cells of body b.
std::set<std::int64_t> bodyCells(const Sketch& sk, std::size_t b) {
  std::set<std::int64_t> out;
  for (std::int32_t i = sk.bodies[b].first; i < sk.bodies[b].first + sk.bodies[b].count; ++i)
    out.insert(GridMapping::linear(sk.cells[static_cast<std::size_t>(i)]));
  return out;
}

// Bodies tile the particle array, M and the particles agree, particles sit at their cell centres.
void expectConsistent(const Sketch& sk) {
  ASSERT_EQ(sk.bodies.size(), sk.bodyNames.size());
  std::int32_t next = 0;
  for (const auto& b : sk.bodies) {
    ASSERT_EQ(b.first, next);
    ASSERT_GT(b.count, 0);
    ASSERT_EQ(b.stroke, sk.particles.stroke[static_cast<std::size_t>(b.first)]);
    next += b.count;
  }
  ASSERT_EQ(next, static_cast<std::int32_t>(sk.particles.size()));
  ASSERT_EQ(static_cast<std::size_t>(sk.grid.occupied()), sk.particles.size());
  for (std::size_t i = 0; i < sk.particles.size(); ++i) {
    ASSERT_EQ(sk.grid.at(sk.cells[i]), static_cast<std::int32_t>(i));
    const Vec3 q = kMap.toWorld(sk.cells[i]);
    ASSERT_EQ(sk.particles.x[i], static_cast<float>(q.x()));
    ASSERT_EQ(sk.particles.y[i], static_cast<float>(q.y()));
    ASSERT_EQ(sk.particles.z[i], static_cast<float>(q.z()));
  }
}

std::string allWarnings(const Sketch& sk) {
  std::string all;
  for (const auto& w : sk.warnings) all += w + "\n";
  return all;
}

}  // namespace

TEST(Bodies, ARemoveThatCutsABodyInTwoMakesTwoBodies) {
  // A bar 0.4 m long; a cube brush of 0.15 m at x = 0.01 takes out its middle through
  // its whole section (0.1 x 0.1 m), leaving 0.135 m on the left and 0.115 m on the right.
  const Sketch sk = sketchOf("primitive box wood 0  0 0.5 0  0.4 0.1 0.1\n"
                             "stroke remove cube 0.15\nsample 1 0.01 0.5 0.003\n");
  std::set<std::int64_t> left, right;
  for (auto l : cellsWhere([](const Vec3& q) {
         return inBox(q, Vec3(0, 0.5, 0), Vec3(0.4, 0.1, 0.1)) && !inBox(q, Vec3(0.01, 0.5, 0.003), Vec3::Constant(0.15));
       }))
    (kMap.toWorld(GridMapping::cellOf(l)).x() < 0.01 ? left : right).insert(l);
  ASSERT_EQ(sk.bodies.size(), 2u);
  // The larger piece keeps the name.
  EXPECT_EQ(sk.bodyNames[0], "stroke 0");
  EXPECT_EQ(sk.bodyNames[1], "stroke 0 #2");
  EXPECT_EQ(bodyCells(sk, 0), left);
  EXPECT_EQ(bodyCells(sk, 1), right);
  EXPECT_GT(right.size(), 1000u);
  EXPECT_EQ(sk.operations[0].body, 0);
  EXPECT_EQ(sk.operations[0].remaining, static_cast<std::int32_t>(left.size() + right.size()));
  // Within a piece the particles keep their creation order (a primitive's: z, y, x).
  for (std::size_t b = 0; b < 2; ++b)
    for (std::int32_t i = sk.bodies[b].first + 1; i < sk.bodies[b].first + sk.bodies[b].count; ++i)
      ASSERT_LT(GridMapping::linear(sk.cells[static_cast<std::size_t>(i) - 1]),
                GridMapping::linear(sk.cells[static_cast<std::size_t>(i)]));
  expectConsistent(sk);
  EXPECT_NE(allWarnings(sk).find("t.strokes:2: body 'stroke 0' was cut by a remove or move into 2 bodies: "
                                 "'stroke 0', 'stroke 0 #2'"),
            std::string::npos)
      << allWarnings(sk);
}

TEST(Bodies, ARemoveThatDoesNotDisconnectKeepsOneBody) {
  // A bite out of one end of the bar.
  const Sketch sk = sketchOf("primitive box wood 0  0 0.5 0  0.4 0.1 0.1\n"
                             "stroke remove sphere 0.1\nsample 1 0.2 0.55 0\n");
  ASSERT_EQ(sk.bodies.size(), 1u);
  EXPECT_GT(sk.operations[1].removed, 100);
  EXPECT_EQ(allWarnings(sk).find("was cut"), std::string::npos) << allWarnings(sk);
}

TEST(Bodies, AMoveThatCarriesAChunkAwayMakesItABodyOfItsOwn) {
  // The brush grips the right end of a bar and lifts it 0.2 m (30.2 cells: 30).
  const std::string bar = "primitive box wood 0  0 0.3 0  0.3 0.1 0.1\n";
  const Sketch sk = sketchOf(bar + "stroke move sphere 0.08\nsample 1 0.15 0.3 0\nsample 2 0.15 0.5 0\n");
  std::set<std::int64_t> rest, chunk;
  for (auto l : cellsWhere([](const Vec3& q) { return inBox(q, Vec3(0, 0.3, 0), Vec3(0.3, 0.1, 0.1)); })) {
    const Vec3i c = GridMapping::cellOf(l);
    if ((kMap.toWorld(c) - Vec3(0.15, 0.3, 0)).squaredNorm() <= 0.04 * 0.04) chunk.insert(GridMapping::linear(c + Vec3i(0, 30, 0)));
    else rest.insert(l);
  }
  ASSERT_EQ(sk.bodies.size(), 2u);
  EXPECT_EQ(sk.bodyNames[0], "stroke 0");
  EXPECT_EQ(sk.bodyNames[1], "stroke 0 #2");
  EXPECT_EQ(bodyCells(sk, 0), rest);
  EXPECT_EQ(bodyCells(sk, 1), chunk);
  EXPECT_EQ(sk.operations[1].moved, static_cast<std::int32_t>(chunk.size()));
  expectConsistent(sk);
  // Carried 0.01 m (2 cells) only, the chunk still touches the bar: one body.
  const Sketch bent = sketchOf(bar + "stroke move sphere 0.08\nsample 1 0.15 0.3 0\nsample 2 0.15 0.31 0\n");
  EXPECT_EQ(bent.bodies.size(), 1u);
  EXPECT_EQ(bent.operations[1].moved, static_cast<std::int32_t>(chunk.size()));
}

TEST(Bodies, AMirroredBodyStaysOneUntilACutBreaksAHalf) {
  // A box at x = 0.2 and its mirror copy at x = -0.2: one body of two separate parts.
  const std::string pair = "mirror x 0\nprimitive box wood 0  0.2 0.5 0  0.1 0.1 0.1\nmirror off\n";
  EXPECT_EQ(sketchOf(pair).bodies.size(), 1u);
  // A bite off one corner disconnects nothing: still one body.
  const Sketch bitten = sketchOf(pair + "stroke remove sphere 0.08\nsample 1 0.25 0.55 0.05\n");
  EXPECT_GT(bitten.operations[1].removed, 50);
  EXPECT_EQ(bitten.bodies.size(), 1u);
  // A one-cell slab through the +x copy at y = 0.52 (grid 78.02: layer 78 of its
  // layers 68..82) breaks it into 10 layers below and 4 above. The whole copy stays
  // the body; the fragments, largest first, become bodies of their own.
  const Sketch cut = sketchOf(pair + "stroke remove disc 0.2\nsample 1 0.2 0.52 0\n");
  const Vec3 size(0.1, 0.1, 0.1);
  const auto whole = cellsWhere([&](const Vec3& q) { return inBox(q, Vec3(-0.2, 0.5, 0), size); });
  const auto below = cellsWhere([&](const Vec3& q) { return inBox(q, Vec3(0.2, 0.5, 0), size) && q.y() < 0.52 - 0.5 * kH; });
  const auto above = cellsWhere([&](const Vec3& q) { return inBox(q, Vec3(0.2, 0.5, 0), size) && q.y() > 0.52 + 0.5 * kH; });
  ASSERT_EQ(below.size(), 15u * 15u * 10u);
  ASSERT_EQ(above.size(), 15u * 15u * 4u);
  ASSERT_EQ(cut.bodies.size(), 3u);
  EXPECT_EQ(cut.bodyNames[0], "stroke 0");
  EXPECT_EQ(cut.bodyNames[1], "stroke 0 #2");
  EXPECT_EQ(cut.bodyNames[2], "stroke 0 #3");
  EXPECT_EQ(bodyCells(cut, 0), whole);
  EXPECT_EQ(bodyCells(cut, 1), below);
  EXPECT_EQ(bodyCells(cut, 2), above);
  expectConsistent(cut);
}

TEST(Bodies, AMoveOfAWholeMirroredHalfKeepsOneBody) {
  // The brush (radius 0.1 m) holds the whole +x copy (corners 0.087 m from its centre)
  // and lifts it: nothing was disconnected, so the pair stays one body.
  const Sketch sk = sketchOf("mirror x 0\nprimitive box wood 0  0.2 0.5 0  0.1 0.1 0.1\nmirror off\n"
                             "stroke move sphere 0.2\nsample 1 0.2 0.5 0\nsample 2 0.2 0.6 0\n");
  EXPECT_EQ(sk.operations[1].moved, 15 * 15 * 15);
  EXPECT_EQ(sk.bodies.size(), 1u);
}

TEST(Bodies, ANamedBodyKeepsItsWholePartsAndLetsTheBrokenOneFall) {
  // body=b: two balls that do not touch and a box apart from them; a slab cuts the box.
  const Sketch sk = sketchOf(
      "primitive sphere wood 0  -0.25 0.5 0  0.05 body=b\n"
      "primitive sphere stone 0.1  -0.25 0.5 0.25  0.05 body=b\n"
      "primitive box wood 0.2  0.2 0.5 0  0.1 0.1 0.1 body=b\n"
      "stroke remove disc 0.2\nsample 1 0.2 0.52 0\n");
  ASSERT_EQ(sk.bodies.size(), 3u);
  EXPECT_EQ(sk.bodyNames[0], "b");
  EXPECT_EQ(sk.bodyNames[1], "b #2");
  EXPECT_EQ(sk.bodyNames[2], "b #3");
  const auto balls = cellsWhere([](const Vec3& q) {
    return (q - Vec3(-0.25, 0.5, 0)).norm() <= 0.05 || (q - Vec3(-0.25, 0.5, 0.25)).norm() <= 0.05;
  });
  EXPECT_EQ(bodyCells(sk, 0), balls);
  EXPECT_EQ(sk.bodies[1].count, 15 * 15 * 10);
  EXPECT_EQ(sk.bodies[2].count, 15 * 15 * 4);
  EXPECT_EQ(sk.operations[0].body, 0);
  EXPECT_EQ(sk.operations[1].body, 0);
  EXPECT_EQ(sk.operations[2].body, 1);  // the first body holding its particles
  expectConsistent(sk);
  // The two balls still do not touch: lint still says so.
  const std::string all = allWarnings(sk);
  EXPECT_NE(all.find("body 'b' is made of 2 pieces that do not touch"), std::string::npos) << all;
  EXPECT_NE(all.find("t.strokes:2: body 'b' was cut by a remove or move into 3 bodies: 'b', 'b #2', 'b #3'"),
            std::string::npos)
      << all;
}

TEST(Bodies, ANamedBodyDrawnInOnePieceAndCutGivesItsNameToTheLargestPiece) {
  // A seat and a leg under it (body=chair, touching); a slab cuts the leg near its foot.
  const Sketch sk = sketchOf(
      "primitive box wood 0  0 0.5 0  0.3 0.04 0.3 body=chair\n"
      "primitive box stone 0.1  0.1 0.35 0.1  0.04 0.28 0.04 body=chair\n"
      "stroke remove disc 0.1\nsample 1 0.1 0.25 0.1\n");
  ASSERT_EQ(sk.bodies.size(), 2u);
  EXPECT_EQ(sk.bodyNames[0], "chair");
  EXPECT_EQ(sk.bodyNames[1], "chair #2");
  EXPECT_GT(sk.bodies[0].count, 10 * sk.bodies[1].count);
  for (std::int32_t i = sk.bodies[1].first; i < sk.bodies[1].first + sk.bodies[1].count; ++i)
    EXPECT_LT(sk.particles.y[static_cast<std::size_t>(i)], 0.25);  // the foot
  expectConsistent(sk);
}
