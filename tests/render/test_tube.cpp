// tubeMesh and sheetMesh: rope and cloth surfaces. Oracles: the volume of a prism of the ring's
// polygon and of a slab (closed forms), the distance of every vertex from its point (or a
// cylinder's axis), and closedness by edge counting.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <map>
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

// sheetMesh copies a side's vertices for the walls (their own normals): weld vertices of the
// same position to one index, so that edge counting sees one surface.
TriangleMesh welded(const TriangleMesh& m) {
  std::map<std::array<float, 3>, std::uint32_t> first;
  TriangleMesh w = m;
  for (std::uint32_t& i : w.indices) {
    const Vec3f& p = m.positions[i];
    i = first.emplace(std::array<float, 3>{p.x(), p.y(), p.z()}, i).first->second;
  }
  return w;
}

// rows x cols nodes, rows along z and cols along x, `spacing` apart, at height y.
std::vector<Vec3> flatLattice(int rows, int cols, double spacing, double y) {
  std::vector<Vec3> nodes;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) nodes.emplace_back(0.1 + spacing * c, y, 0.1 + spacing * r);
  return nodes;
}

// A flat 6 x 9 lattice 1 cm apart, half thickness 3 mm: a closed slab (after welding) of
// volume 5 x 8 cells x 1 cm^2 x 6 mm (closed form, to float rounding: 1e-5 relative), wound
// outwards, every vertex 3 mm above or below the lattice's plane. With a hole (an inner node
// gone: its four cells) the sheet is 36 cells and still closed, walled round the hole; with a
// corner gone, 39 cells.
TEST(Sheet, AFlatLatticeIsAClosedSlabAndAHoleIsWalled) {
  const int rows = 6, cols = 9;
  const double h = 0.01, t = 0.003, y = 0.2;
  const std::vector<Vec3> nodes = flatLattice(rows, cols, h, y);
  std::vector<std::uint8_t> alive(nodes.size(), 1);
  const double cell = h * h * 2.0 * t;
  TriangleMesh m = sheetMesh(nodes, alive, rows, cols, t);
  EXPECT_EQ(closedManifoldViolation(welded(m)), "");
  EXPECT_NEAR(enclosedVolume(m), 40 * cell, 1e-5 * 40 * cell);
  for (const Vec3f& v : m.positions) EXPECT_NEAR(std::abs(double(v.y()) - y), t, 1e-6);
  alive[std::size_t(3 * cols + 4)] = 0;
  m = sheetMesh(nodes, alive, rows, cols, t);
  EXPECT_EQ(closedManifoldViolation(welded(m)), "");
  EXPECT_NEAR(enclosedVolume(m), 36 * cell, 1e-5 * 36 * cell);
  alive[0] = 0;
  m = sheetMesh(nodes, alive, rows, cols, t);
  EXPECT_EQ(closedManifoldViolation(welded(m)), "");
  EXPECT_NEAR(enclosedVolume(m), 35 * cell, 1e-5 * 35 * cell);
  // A lattice of one row has no cells: nothing to draw.
  EXPECT_TRUE(sheetMesh(flatLattice(1, 5, h, y), std::vector<std::uint8_t>(5, 1), 1, 5, t).empty());
}

// A lattice bent round a cylinder (radius 0.1 m, axis z; 12 nodes over a quarter turn, 5 along
// the axis): its inner nodes' two sides lie at 0.1 +- t from the axis (a node's normal is the
// mean of its cells', radial by symmetry), to float rounding. The sheet stays closed.
TEST(Sheet, ABentSheetKeepsItsThickness) {
  const int rows = 5, cols = 12;
  const double R = 0.1, t = 0.004;
  std::vector<Vec3> nodes;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const double a = 0.5 * kPi * c / (cols - 1);
      nodes.emplace_back(R * std::cos(a), R * std::sin(a), 0.01 * r);
    }
  const TriangleMesh m = sheetMesh(nodes, std::vector<std::uint8_t>(nodes.size(), 1), rows, cols, t);
  EXPECT_EQ(closedManifoldViolation(welded(m)), "");
  EXPECT_GT(enclosedVolume(m), 0.0);
  int checked = 0;
  for (int r = 1; r + 1 < rows; ++r)
    for (int c = 1; c + 1 < cols; ++c) {
      // Vertices come two per node with a normal, in node order: every node here has one.
      const std::size_t k = std::size_t(r * cols + c);
      EXPECT_NEAR(std::hypot(m.positions[2 * k].x(), m.positions[2 * k].y()), R + t, 1e-6);
      EXPECT_NEAR(std::hypot(m.positions[2 * k + 1].x(), m.positions[2 * k + 1].y()), R - t, 1e-6);
      ++checked;
    }
  EXPECT_EQ(checked, 30);
}

TEST(Sheet, BadInputIsAnError) {
  const std::vector<Vec3> nodes = flatLattice(2, 2, 0.01, 0.0);
  const std::vector<std::uint8_t> alive(4, 1);
  EXPECT_THROW(sheetMesh(nodes, alive, 2, 3, 0.001), RuntimeError);
  EXPECT_THROW(sheetMesh(nodes, std::vector<std::uint8_t>(3, 1), 2, 2, 0.001), RuntimeError);
  EXPECT_THROW(sheetMesh(nodes, alive, 2, 2, 0.0), RuntimeError);
  std::vector<Vec3> bad = nodes;
  bad[1].x() = std::nan("");
  EXPECT_THROW(sheetMesh(bad, alive, 2, 2, 0.001), RuntimeError);
}

}  // namespace
}  // namespace physketch::render
