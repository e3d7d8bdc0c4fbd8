// tubeMesh: rope surfaces. Oracles: the volume of a prism of the ring's polygon (closed form),
// the distance of every ring vertex from its chain point, and closedness by edge counting.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/error.h"
#include "render/mesh.h"
#include "tests/render/render_test_util.h"

namespace physketch::render {
namespace {

using namespace test;  // NOLINT: shared helpers of the render tests

constexpr double kPi = 3.14159265358979323846;

// A straight chain of 20 points 1 cm apart: a prism of the regular 8-gon of radius r, whose area
// is (8/2) r^2 sin(2 pi / 8), over the chain's length (the flat caps add nothing); to float
// rounding (1e-6 relative). Closed and wound outwards (positive volume).
TEST(Tube, AStraightChainIsAClosedPrism) {
  std::vector<Vec3> chain;
  for (int i = 0; i < 20; ++i) chain.emplace_back(0.1 + 0.01 * i, 0.3, -0.2);
  const double r = 0.004;
  const TriangleMesh m = tubeMesh({chain}, r, 8);
  EXPECT_EQ(closedManifoldViolation(m), "");
  const double prism = 4.0 * r * r * std::sin(2.0 * kPi / 8.0) * 0.19;
  EXPECT_NEAR(enclosedVolume(m), prism, 1e-5 * prism);
}

// A chain bent into a half circle and a lone point: closed pieces; every ring vertex is r from
// its point (parallel transport keeps the rings round and normal to the chain); the lone point is
// a short tube of length 2r along x.
TEST(Tube, ABentChainStaysRoundAndALonePointIsAStub) {
  std::vector<Vec3> arc;
  for (int i = 0; i <= 30; ++i) arc.push_back(0.1 * Vec3(std::cos(kPi * i / 30.0), std::sin(kPi * i / 30.0), 0.0));
  const double r = 0.003;
  const TriangleMesh m = tubeMesh({arc, {Vec3(0.5, 0.5, 0.5)}}, r, 6);
  EXPECT_EQ(closedManifoldViolation(m), "");
  for (std::size_t i = 0; i < arc.size(); ++i)
    for (int k = 0; k < 6; ++k) {
      const Vec3 v = m.positions[i * 6 + std::size_t(k)].cast<double>();
      EXPECT_NEAR((v - arc[i]).norm(), r, 1e-6);
      const Vec3 along = i + 1 < arc.size() ? arc[i + 1] - arc[i] : arc[i] - arc[i - 1];
      EXPECT_LT(std::abs((v - arc[i]).normalized().dot(along.normalized())), 0.06);  // in the ring's plane
    }
  const double stub = 3.0 * r * r * std::sin(2.0 * kPi / 6.0) * 2.0 * r;
  const double arcPrism = 3.0 * r * r * std::sin(2.0 * kPi / 6.0) * 0.1 * kPi;  // about: chord length < arc
  EXPECT_NEAR(enclosedVolume(m), arcPrism + stub, 0.01 * arcPrism);
  EXPECT_THROW(tubeMesh({arc}, 0.0), RuntimeError);
  EXPECT_THROW(tubeMesh({{Vec3(std::nan(""), 0, 0)}}, r), RuntimeError);
}

}  // namespace
}  // namespace physketch::render
