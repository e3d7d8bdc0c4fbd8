// meshNodeField: the surface of a node field's level (an MPM grid's mass, PhyVR §4.1).
// Oracle: a field whose level set is a sphere in closed form (f = 1 - |x - c| / R, level 1/2:
// the sphere of radius R/2), sampled at the nodes.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "core/error.h"
#include "render/voxel_mesh.h"

namespace physketch::render {
namespace {

constexpr double kPi = 3.14159265358979323846;

NodeField coneField(double spacing, const Vec3& origin, int n, const Vec3& centre, double radius) {
  NodeField f;
  f.spacing = spacing;
  f.origin = origin;
  f.size = Vec3i::Constant(n);
  f.values.resize(std::size_t(n) * n * n);
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const Vec3 x = origin + spacing * Vec3(i, j, k);
        f.values[f.index(i, j, k)] = float(std::max(0.0, 1.0 - (x - centre).norm() / radius));
      }
  return f;
}

// The level 1/2 of 1 - r/R is the sphere r = R/2 = 5 spacings s here. volumeToMesh finds where
// the level crosses each node edge (linear interpolation: r is not linear along an edge, at most
// s^2 / (8 r) = 0.025 s off) and puts one vertex per cell at the mean of its crossings, which
// for a sphere lies inside it by up to d^2 / (2 r) with d <= s sqrt(3) / 2, i.e. 0.075 s: the
// vertex tolerance is 0.1 s (measured 0.072 s). Vertices inside by up to 0.1 s / 5 s = 2 % of r
// bound the volume to within 6 % below the sphere's (measured 4.5 %).
TEST(NodeField, ALevelOfANodeFieldIsMeshedWhereItCrossesInWorldCoordinates) {
  const double s = 0.02;
  const Vec3 origin(0.3, 0.1, -0.2), centre = origin + s * Vec3(10.3, 10.6, 9.8);
  const double R = 10 * s;
  const TriangleMesh m = meshNodeField(coneField(s, origin, 22, centre, R), 0.5);
  ASSERT_FALSE(m.empty());
  double worst = 0.0, worstNormal = 1.0;
  for (std::size_t v = 0; v < m.positions.size(); ++v) {
    const Vec3 d = m.positions[v].cast<double>() - centre;
    worst = std::max(worst, std::abs(d.norm() - 0.5 * R));
    worstNormal = std::min(worstNormal, m.normals[v].cast<double>().dot(d.normalized()));
  }
  EXPECT_LT(worst, 0.1 * s);
  EXPECT_GT(worstNormal, 0.95);  // outward (a reversed winding gives -1)
  const double sphere = 4.0 / 3.0 * kPi * std::pow(0.5 * R, 3);
  EXPECT_NEAR(enclosedVolume(m), sphere, 0.06 * sphere);
  EXPECT_LT(enclosedVolume(m), sphere);  // inscribed
}

// With a target volume the level moves until the mesh holds it: the sphere's own volume is met
// to the 0.2 % the search stops at, by a level below 1/2 (the mesh at 1/2 is inside the sphere);
// a target beyond the range [iso/2, 3 iso/2] gets the range's nearer end (level 1/4: the field's
// r = 3R/4 sphere, the largest it can give).
TEST(NodeField, ATargetVolumeMovesTheLevelUntilTheMeshHoldsIt) {
  const double s = 0.02;
  const Vec3 origin(0.3, 0.1, -0.2), centre = origin + s * Vec3(10.3, 10.6, 9.8);
  const double R = 10 * s;
  const NodeField f = coneField(s, origin, 22, centre, R);
  const double sphere = 4.0 / 3.0 * kPi * std::pow(0.5 * R, 3);
  double level = 0.0;
  const TriangleMesh m = meshNodeField(f, 0.5, sphere, &level);
  EXPECT_NEAR(enclosedVolume(m), sphere, 2e-3 * sphere);
  EXPECT_LT(level, 0.5);
  EXPECT_GT(level, 0.45);  // vertices were at most 0.1 s = 1 % of R inside: the level moves by about that
  const TriangleMesh big = meshNodeField(f, 0.5, 100.0 * sphere, &level);
  EXPECT_DOUBLE_EQ(level, 0.25);
  EXPECT_NEAR(enclosedVolume(big), 4.0 / 3.0 * kPi * std::pow(0.75 * R, 3), 0.06 * enclosedVolume(big));
}

TEST(NodeField, BadFieldsAreErrorsAndAnEmptyOneGivesNoMesh) {
  NodeField f = coneField(0.02, Vec3::Zero(), 8, Vec3::Constant(0.07), 0.06);
  EXPECT_NO_THROW(meshNodeField(f, 0.5));
  NodeField shortOne = f;
  shortOne.values.pop_back();
  EXPECT_THROW(meshNodeField(shortOne, 0.5), RuntimeError);
  NodeField nan = f;
  nan.values[3] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(meshNodeField(nan, 0.5), RuntimeError);
  EXPECT_THROW(meshNodeField(f, 0.0), RuntimeError);
  EXPECT_THROW(meshNodeField(f, 0.5, -1.0), RuntimeError);
  NodeField flat = f;
  flat.spacing = -1.0;
  EXPECT_THROW(meshNodeField(flat, 0.5), RuntimeError);
  EXPECT_TRUE(meshNodeField(NodeField{0.02, Vec3::Zero(), Vec3i::Zero(), {}}, 0.5).empty());
}

}  // namespace
}  // namespace physketch::render
