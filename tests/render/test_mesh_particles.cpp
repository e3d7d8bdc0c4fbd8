// meshParticles: a closed surface around particles that no longer sit on the voxel lattice.
// Oracles: the ball's volume 4/3 pi r^3 (closed form), meshVoxels of the cells the particles
// fall in (an independently tested function), and the mesh bytes under 1 and 2 TBB threads.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <utility>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "core/error.h"
#include "render/voxel_mesh.h"
#include "tests/render/render_test_util.h"

namespace physketch::render {
namespace {

using namespace test;  // NOLINT: shared helpers of the render tests

constexpr double kPi = 3.14159265358979323846;

// Particles on a lattice of spacing h (rotated by `rotation` about `centre`) whose offsets
// from `centre` lie within the ball of radius r.
std::vector<Vec3> ballParticles(const Vec3& centre, double r, double h, const Eigen::Matrix3d& rotation) {
  std::vector<Vec3> p;
  const int n = static_cast<int>(std::ceil(r / h));
  for (int k = -n; k <= n; ++k)
    for (int j = -n; j <= n; ++j)
      for (int i = -n; i <= n; ++i) {
        const Vec3 q = h * Vec3(i, j, k);
        if (q.norm() <= r) p.push_back(centre + rotation * q);
      }
  return p;
}

// Connected pieces of a mesh (triangles sharing a vertex): 1 for a single closed surface;
// more when the surface has inner cavities or stray islands.
int components(const TriangleMesh& m) {
  std::vector<std::uint32_t> parent(m.positions.size());
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (std::size_t t = 0; t < m.indices.size(); t += 3) {
    parent[find(m.indices[t + 1])] = find(m.indices[t]);
    parent[find(m.indices[t + 2])] = find(m.indices[t]);
  }
  int n = 0;
  for (std::uint32_t i = 0; i < parent.size(); ++i) n += find(i) == i;
  return n;
}

// The volume tolerance: a shell of half a cell over the sphere, 4 pi r^2 (h / 2), i.e. the
// surface lies on average within h/2 of the sphere (7.5% of the volume at r = 20 h). Why it
// holds: each particle stands for one cell, and the union of the cells whose centres lie in
// the ball has its boundary within sqrt(3) h / 2 of the sphere everywhere; cells poke out
// and fall short about equally, so the lattice-count error N h^3 - 4/3 pi r^3 is a small part
// of that (-0.3% here; the test prints it). Meshing then moves the surface by a fraction of a
// cell: the dual mesh rounds the staircase's edges inwards (measured -0.4% at smoothing 0)
// and the one default smoothing step grows the solid by less than h/2 (test_render.cpp's
// smoothing bound; measured +5.1% on the lattice, +5.6% on the rotated lattice). A wrong
// spacing, a lost particle layer or missing cells move the volume by far more.
double volumeTolerance(double r, double h) { return 4.0 * kPi * r * r * 0.5 * h; }

TEST(MeshParticles, LatticeBallEnclosesTheBallVolume) {
  const double h = 0.01, r = 20 * h;
  const Vec3 centre(0.123, 0.456, -0.2);
  const std::vector<Vec3> p = ballParticles(centre, r, h, Eigen::Matrix3d::Identity());
  ParticleMeshOptions opt;
  opt.latticeOrigin = centre;  // particles sit exactly on cell centres
  const TriangleMesh m = meshParticles(p, h, opt);
  ASSERT_FALSE(m.empty());
  EXPECT_EQ(closedManifoldViolation(m), "");
  EXPECT_EQ(components(m), 1);
  const double ball = 4.0 / 3.0 * kPi * r * r * r;
  std::printf("lattice: N h^3 / ball = %.4f, mesh / ball = %.4f, tolerance %.4f\n", p.size() * h * h * h / ball,
              signedVolume(m) / ball, volumeTolerance(r, h) / ball);
  EXPECT_NEAR(signedVolume(m), ball, volumeTolerance(r, h));
  // Centred on the ball: the bounding box is symmetric about the centre within a cell.
  const Eigen::AlignedBox3d b = bounds(m);
  EXPECT_LT((b.center() - centre).cwiseAbs().maxCoeff(), h);
  EXPECT_NEAR(b.sizes().maxCoeff(), 2 * r, 2 * h);
}

// A rotated ball: particles fall off the lattice, some cells get two particles and some
// none. The default closing step fills the one-cell holes this leaves, so the surface is one
// closed piece (no inner cavities) with the ball's volume.
TEST(MeshParticles, RotatedBallOffTheLatticeIsOneClosedSurfaceWithTheBallVolume) {
  const double h = 0.01, r = 20 * h;
  const Vec3 centre(0.123, 0.456, -0.2);
  const Eigen::Matrix3d rot = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  const std::vector<Vec3> p = ballParticles(centre, r, h, rot);
  ParticleMeshOptions opt;
  opt.latticeOrigin = centre;
  const TriangleMesh m = meshParticles(p, h, opt);
  EXPECT_EQ(closedManifoldViolation(m), "");
  EXPECT_EQ(components(m), 1);
  const double ball = 4.0 / 3.0 * kPi * r * r * r;
  std::printf("rotated: mesh / ball = %.4f\n", signedVolume(m) / ball);
  EXPECT_NEAR(signedVolume(m), ball, volumeTolerance(r, h));
}

// With a target volume (ParticleMeshOptions::targetVolume: the particles' N h^3) the surface is
// moved until it holds it: the rotated ball's surface, 5-6 % over N h^3 as the cells make it
// (printed), encloses N h^3 within 0.5 % (the mesh is moved out when 0.2 % off; measured
// 0.9995 and 1.0000; -1.3 % without that step, the dual mesh's rounding of the level set), with
// and without smoothing, still one closed piece. Oracle: the particle count times h^3.
TEST(MeshParticles, ATargetVolumeHoldsTheSurfaceToTheParticlesVolume) {
  const double h = 0.01, r = 20 * h;
  const Vec3 centre(0.123, 0.456, -0.2);
  const Eigen::Matrix3d rot = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  const std::vector<Vec3> p = ballParticles(centre, r, h, rot);
  const double particles = double(p.size()) * h * h * h;
  ParticleMeshOptions opt;
  opt.latticeOrigin = centre;
  const double cellsVolume = signedVolume(meshParticles(p, h, opt));
  opt.targetVolume = particles;
  for (int smooth : {0, 4}) {
    opt.smoothIterations = smooth;
    const TriangleMesh m = meshParticles(p, h, opt);
    std::printf("smoothing %d: cells' surface / N h^3 = %.4f, held: %.4f\n", smooth, cellsVolume / particles,
                signedVolume(m) / particles);
    EXPECT_NEAR(signedVolume(m), particles, 0.005 * particles) << "smoothing " << smooth;
    EXPECT_EQ(closedManifoldViolation(m), "");
    EXPECT_EQ(components(m), 1);
  }
  EXPECT_GT(cellsVolume, 1.03 * particles);  // what the target removes
  opt.targetVolume = -1.0;
  EXPECT_THROW(meshParticles(p, h, opt), RuntimeError);
}

// Each particle marks the cell whose centre is nearest: particles moved by less than half a
// cell from the cell centres of a voxel set give exactly meshVoxels' mesh of that set.
TEST(MeshParticles, ParticlesNearCellCentresGiveTheMeshOfThoseCells) {
  const double h = 0.02;
  const Vec3 origin(0.3, -0.1, 0.25);
  std::vector<Vec3i> cells;
  for (int k = 0; k < 6; ++k)
    for (int j = 0; j < 5; ++j)
      for (int i = 0; i < 7; ++i)
        if ((i - 3) * (i - 3) + (j - 2) * (j - 2) + (k - 3) * (k - 3) <= 9 && !(i == 3 && j >= 2)) cells.emplace_back(i, j, k);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> jitter(-0.45 * h, 0.45 * h);
  std::vector<Vec3> p;
  for (const Vec3i& c : cells) p.push_back(origin + h * c.cast<double>() + Vec3(jitter(rng), jitter(rng), jitter(rng)));
  ParticleMeshOptions opt;
  opt.latticeOrigin = origin;
  EXPECT_TRUE(sameMesh(meshParticles(p, h, opt), meshVoxels(cells, h, origin, opt.surface)));
}

// Deterministic: the same bytes for 1 and 2 TBB threads and for any particle order.
TEST(MeshParticles, SameMeshForOneAndTwoThreadsAndAnyOrder) {
  const double h = 0.01;
  const Vec3 centre(0.0, 0.3, 0.0);
  const Eigen::Matrix3d rot = Eigen::AngleAxisd(0.4, Vec3(0, 1, 1).normalized()).toRotationMatrix();
  std::vector<Vec3> p = ballParticles(centre, 12 * h, h, rot);
  TriangleMesh one, two, shuffled;
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    one = meshParticles(p, h);
  }
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 2);
    two = meshParticles(p, h);
    std::shuffle(p.begin(), p.end(), std::mt19937(3));
    shuffled = meshParticles(p, h);
  }
  ASSERT_FALSE(one.empty());
  EXPECT_TRUE(sameMesh(one, two));
  EXPECT_TRUE(sameMesh(one, shuffled));
}

TEST(MeshParticles, EmptyInputGivesEmptyMeshAndBadInputThrows) {
  EXPECT_TRUE(meshParticles({}, 0.01).empty());
  const std::vector<Vec3> one{Vec3(0.1, 0.2, 0.3)};
  EXPECT_THROW(meshParticles(one, 0.0), RuntimeError);
  EXPECT_THROW(meshParticles(one, -0.01), RuntimeError);
  EXPECT_THROW(meshParticles(one, std::nan("")), RuntimeError);
  EXPECT_THROW(meshParticles({Vec3(0, std::nan(""), 0)}, 0.01), RuntimeError);
  EXPECT_THROW(meshParticles({Vec3(0, HUGE_VAL, 0)}, 0.01), RuntimeError);
  EXPECT_THROW(meshParticles({Vec3(0, 1e9, 0)}, 0.01), RuntimeError);  // 1e11 cells from the origin
  ParticleMeshOptions bad;
  bad.latticeOrigin = Vec3(0, 0, std::nan(""));
  EXPECT_THROW(meshParticles(one, 0.01, bad), RuntimeError);
  bad = ParticleMeshOptions{};
  bad.surface.closingSteps = -1;
  EXPECT_THROW(meshParticles(one, 0.01, bad), RuntimeError);
}

// ---- the smoothing knob

// Mean angle (rad) between the normals of faces that share an edge: 0 on a plane, about
// edge length / radius on a finely meshed sphere; the voxel staircase gives right angles.
double meanDihedralTurn(const TriangleMesh& m) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::size_t> firstFace;
  double sum = 0.0;
  long pairs = 0;
  auto faceNormal = [&](std::size_t t) {
    const Vec3 a = m.positions[m.indices[3 * t]].cast<double>();
    const Vec3 b = m.positions[m.indices[3 * t + 1]].cast<double>();
    const Vec3 c = m.positions[m.indices[3 * t + 2]].cast<double>();
    return Vec3((b - a).cross(c - a).normalized());
  };
  for (std::size_t t = 0; t < m.triangleCount(); ++t)
    for (int e = 0; e < 3; ++e) {
      std::uint32_t a = m.indices[3 * t + e], b = m.indices[3 * t + (e + 1) % 3];
      if (a > b) std::swap(a, b);
      const auto [it, inserted] = firstFace.insert({{a, b}, t});
      if (inserted) continue;
      sum += std::acos(std::clamp(faceNormal(it->second).dot(faceNormal(t)), -1.0, 1.0));
      ++pairs;
    }
  return pairs ? sum / pairs : 0.0;
}

// Mean angle (rad) between each face's normal and the sphere's radial direction at the face's
// centroid: 0 for a perfect sphere, large for a voxel staircase (its faces are axis-aligned).
double meanRadialDeviation(const TriangleMesh& m, const Vec3& centre) {
  double sum = 0.0;
  for (std::size_t t = 0; t < m.triangleCount(); ++t) {
    const Vec3 a = m.positions[m.indices[3 * t]].cast<double>();
    const Vec3 b = m.positions[m.indices[3 * t + 1]].cast<double>();
    const Vec3 c = m.positions[m.indices[3 * t + 2]].cast<double>();
    const Vec3 n = (b - a).cross(c - a).normalized();
    const Vec3 radial = ((a + b + c) / 3.0 - centre).normalized();
    sum += std::acos(std::clamp(n.dot(radial), -1.0, 1.0));
  }
  return m.triangleCount() ? sum / double(m.triangleCount()) : 0.0;
}

// A rotated lattice ball of r = 12 h (particles off the lattice, the case deforming bodies
// are in) meshed with and without the knob. Volume: the bound, within 2 % of the
// unsmoothed mesh (measured +1.2 %); the knob's own measure (the level set's volume,
// SmoothingReport) keeps it within 2 % too. Surface: the oracle is the sphere, whose normals are
// radial; the mean angle between face normals and the radial direction falls by a quarter or
// more (measured 0.093 -> 0.057 rad with 4 iterations, 0.040 with 16), and the mean turn between
// adjacent faces falls too (0.085 -> 0.072 rad; a fine sphere mesh has about 0.06 here).
TEST(MeshParticles, SmoothingKeepsTheVolumeAndFlattensTheStaircase) {
  const double h = 0.01, r = 12 * h;
  const Vec3 centre(0.05, 0.4, -0.1);
  const Eigen::Matrix3d rot = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  const std::vector<Vec3> p = ballParticles(centre, r, h, rot);
  ParticleMeshOptions opt;
  opt.latticeOrigin = centre;
  SmoothingReport none;
  const TriangleMesh plain = meshParticles(p, h, opt, &none);
  EXPECT_EQ(none.volumeBefore, 0.0);  // nothing smoothed, nothing measured
  opt.smoothIterations = 4;
  SmoothingReport report;
  const TriangleMesh smooth = meshParticles(p, h, opt, &report);
  ASSERT_FALSE(smooth.empty());
  EXPECT_EQ(closedManifoldViolation(smooth), "");
  EXPECT_EQ(components(smooth), 1);

  const double v0 = signedVolume(plain), v1 = signedVolume(smooth);
  const double turn0 = meanDihedralTurn(plain), turn1 = meanDihedralTurn(smooth);
  const double radial0 = meanRadialDeviation(plain, centre), radial1 = meanRadialDeviation(smooth, centre);
  std::printf("smoothing x4: mesh volume %+.3f %%, level set volume %+.3f %%; off the radial direction %.3f -> %.3f "
              "rad; between adjacent faces %.3f -> %.3f rad\n",
              100.0 * (v1 - v0) / v0, 100.0 * report.relativeChange(), radial0, radial1, turn0, turn1);
  EXPECT_NEAR(v1, v0, 0.02 * v0);
  EXPECT_LT(std::abs(report.relativeChange()), 0.02);
  // The report measures the level set, not the mesh: the dual mesh of the unsmoothed (not yet
  // signed-distance) level set cuts its corners, 2.4 % less volume measured; 1.2 % after.
  EXPECT_NEAR(report.volumeBefore, v0, 0.03 * v0);
  EXPECT_NEAR(report.volumeAfter, v1, 0.02 * v1);
  EXPECT_LT(radial1, 0.75 * radial0);
  EXPECT_LT(turn1, 0.95 * turn0);

  // Deterministic: the same bytes with one thread.
  TriangleMesh serial;
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    serial = meshParticles(p, h, opt);
  }
  EXPECT_TRUE(sameMesh(smooth, serial));

  opt.smoothIterations = -1;
  EXPECT_THROW(meshParticles(p, h, opt), RuntimeError);
}

}  // namespace
}  // namespace physketch::render
