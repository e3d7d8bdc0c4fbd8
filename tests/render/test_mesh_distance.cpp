// distancesToMesh and rmsSurfaceDistance (the study's surface norms). Oracles: distances from
// points to the unit cube in closed form (face, edge and corner regions), and the RMS distance
// between the cube and a shifted copy counted corner by corner.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/error.h"
#include "render/mesh_distance.h"

namespace physketch::render {
namespace {

// The cube [0,1]^3 (plus `shift`), 12 triangles wound outward.
TriangleMesh cube(const Vec3f& shift = Vec3f::Zero()) {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i) m.positions.push_back(Vec3f(float(i & 1), float((i >> 1) & 1), float((i >> 2) & 1)) + shift);
  m.indices = {0, 2, 3, 0, 3, 1,  4, 5, 7, 4, 7, 6,  0, 1, 5, 0, 5, 4,
               2, 6, 7, 2, 7, 3,  0, 4, 6, 0, 6, 2,  1, 3, 7, 1, 7, 5};
  return m;
}

TEST(MeshDistance, PointsToTheUnitCubeMatchClosedForms) {
  // Inside the centre: half an edge to every face; beyond a face, an edge and a corner; on a face
  // between vertices (0: the nearest point is not a vertex).
  const std::vector<Vec3f> points = {{0.5f, 0.5f, 0.5f}, {2.0f, 0.5f, 0.5f}, {2.0f, 2.0f, 0.5f},
                                     {2.0f, 2.0f, 2.0f}, {0.3f, 0.6f, 1.0f}, {0.5f, -0.25f, 0.5f}};
  const std::vector<double> expected = {0.5, 1.0, std::sqrt(2.0), std::sqrt(3.0), 0.0, 0.25};
  const std::vector<double> d = distancesToMesh(points, cube());
  ASSERT_EQ(d.size(), expected.size());
  // Float vertices, double queries: a few ulps of 1.
  for (std::size_t i = 0; i < d.size(); ++i) EXPECT_NEAR(d[i], expected[i], 1e-6) << "point " << i;
}

TEST(MeshDistance, SymmetricRmsOfAShiftedCubeCountsEachCorner) {
  // B = A + (0.1, 0, 0). A's four corners at x = 0 are 0.1 from B (B's face x = 0.1), its four at
  // x = 1 lie on B's faces y, z = 0 or 1 (0); B's likewise. RMS = sqrt(8 * 0.01 / 16).
  EXPECT_NEAR(rmsSurfaceDistance(cube(), cube(Vec3f(0.1f, 0.0f, 0.0f))), std::sqrt(8 * 0.01 / 16), 1e-6);
  EXPECT_EQ(rmsSurfaceDistance(cube(), cube()), 0.0);
}

TEST(MeshDistance, DegenerateAndBadInputAreErrors) {
  TriangleMesh flat;
  flat.positions = {Vec3f(0, 0, 0), Vec3f(1, 0, 0), Vec3f(2, 0, 0)};  // collinear: zero area
  flat.indices = {0, 1, 2};
  EXPECT_THROW(distancesToMesh({Vec3f(0, 1, 0)}, flat), RuntimeError);
  TriangleMesh past = cube();
  past.indices.back() = 8;
  EXPECT_THROW(distancesToMesh({Vec3f(0, 1, 0)}, past), RuntimeError);
  EXPECT_THROW(distancesToMesh({Vec3f(NAN, 0, 0)}, cube()), RuntimeError);
  EXPECT_TRUE(distancesToMesh({}, cube()).empty());
}

}  // namespace
}  // namespace physketch::render
