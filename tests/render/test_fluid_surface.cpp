// meshFluid: anisotropic fluid surfaces (Yu & Turk 2013; PhyVR §4.2).
// Oracles: closed forms (a lone kernel's iso-sphere radius; the kernel integral), the isotropic
// surface of the same particles (the comparison the issue asks for), mesh bytes under 1 and 2
// TBB threads, and the normal a flat slab must have (+y).
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "core/error.h"
#include "render/fluid_surface.h"
#include "tests/render/render_test_util.h"

namespace physketch::render {
namespace {

using namespace test;  // NOLINT: shared helpers of the render tests

constexpr double kPi = 3.14159265358979323846;
constexpr double kH = 0.01;  // particle spacing (m)

// A resting slab of nx * ny * nz particles, each jittered by up to +-jitter*h on every axis
// (mt19937's raw output, the same on every platform): what a PBF pool looks like at rest.
std::vector<Vec3> jitteredSlab(int nx, int ny, int nz, double jitter, unsigned seed) {
  std::mt19937 rng(seed);
  auto u = [&rng] { return static_cast<double>(rng()) / 4294967295.0 * 2.0 - 1.0; };
  std::vector<Vec3> p;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        const Vec3 d(u(), u(), u());
        p.push_back(kH * (Vec3(i, j, k) + jitter * d));
      }
  return p;
}

// Area-weighted spread of the unit normals of the triangles facing up (n.y > 0.5) whose centroid
// lies over the slab's inner part (at least `margin` from its sides): sum a |n - mean|^2 / sum a.
// 0 for a perfectly flat top.
struct TopStats {
  double variance = 0.0;
  Vec3 mean = Vec3::Zero();
  double area = 0.0;
};
TopStats topNormals(const TriangleMesh& m, double x0, double x1, double z0, double z1) {
  std::vector<std::pair<double, Vec3>> faces;
  Vec3 sum = Vec3::Zero();
  double area = 0.0;
  for (std::size_t t = 0; t < m.indices.size(); t += 3) {
    const Vec3 a = m.positions[m.indices[t]].cast<double>(), b = m.positions[m.indices[t + 1]].cast<double>(),
               c = m.positions[m.indices[t + 2]].cast<double>();
    const Vec3 cr = (b - a).cross(c - a);
    const double ar = 0.5 * cr.norm();
    if (!(ar > 0.0)) continue;
    const Vec3 n = cr.normalized(), g = (a + b + c) / 3.0;
    if (n.y() <= 0.5 || g.x() < x0 || g.x() > x1 || g.z() < z0 || g.z() > z1) continue;
    faces.emplace_back(ar, n);
    sum += ar * n;
    area += ar;
  }
  TopStats s;
  if (area == 0.0) return s;
  s.mean = sum / area;
  s.area = area;
  for (const auto& [ar, n] : faces) s.variance += ar * (n - s.mean).squaredNorm();
  s.variance /= area;
  return s;
}

// Thin-over-wide ratio and the tilt of the thin axis from +y (rad) of a kernel.
struct KernelShape {
  double thinOverWide = 1.0;
  double tilt = 0.0;
};
KernelShape shapeOf(const Mat3& inverseAxes) {
  Eigen::JacobiSVD<Mat3> svd(Mat3(inverseAxes.inverse()), Eigen::ComputeFullU);
  const Vec3 sv = svd.singularValues();  // axis lengths, largest first
  return {sv[2] / sv[0], std::acos(std::min(1.0, std::abs(svd.matrixU().col(2).y())))};
}

// A lone particle is spray: a ball of half the kernel radius with 8x the weight. Its surface is
// the sphere where 8 (1 - r^2 / (R/2)^2)^3 = iso = interiorField / 2 (closed form). Marching
// cubes loses volume on a sphere this small (3 % at 5.6 voxels radius) with second-order
// convergence, so the volumes meshed on voxels of 0.2 and 0.1 spacings are extrapolated
// (Richardson: (4 V_fine - V_coarse) / 3) and must match the sphere within 1 %; a wrong weight
// or radius moves it by over 20 %. With keepVolume the level drops until the drop holds one
// spacing^3 counted in voxels: within the marching-cubes loss just measured plus 1 %.
TEST(FluidSurface, ALoneDropIsTheSphereItsKernelMakes) {
  FluidSurfaceOptions o;
  o.keepVolume = false;
  const std::vector<Vec3> one{Vec3(0.1234, 0.0567, -0.089)};
  FluidSurfaceReport coarse, fine;
  o.voxelFraction = 0.2;
  meshFluid(one, kH, o, &coarse);
  o.voxelFraction = 0.1;
  const TriangleMesh m = meshFluid(one, kH, o, &fine);
  const double R = o.kernelRadius * kH / 2.0;
  const double iso = 0.5 * 64.0 * kPi / 315.0 * std::pow(o.kernelRadius, 3);
  const double r = R * std::sqrt(1.0 - std::cbrt(iso / 8.0));
  const double sphere = 4.0 / 3.0 * kPi * r * r * r;
  const double extrapolated = (4.0 * fine.meshVolume - coarse.meshVolume) / 3.0;
  const double mcLoss = 1.0 - fine.meshVolume / sphere;
  std::printf("lone drop: meshed %.4g (h/5), %.4g (h/10), extrapolated %.4g m^3; sphere %.4g m^3 (r = %.3f spacings)\n",
              coarse.meshVolume, fine.meshVolume, extrapolated, sphere, r / kH);
  EXPECT_EQ(closedManifoldViolation(m), "");
  EXPECT_NEAR(extrapolated, sphere, 0.01 * sphere);
  EXPECT_NEAR((bounds(m).center() - one[0]).norm(), 0.0, 0.1 * kH);

  o.keepVolume = true;
  FluidSurfaceReport kept;
  meshFluid(one, kH, o, &kept);
  const double cell = kH * kH * kH;
  std::printf("lone drop, volume kept: %.4f spacing^3 at level %.3f of the interior field\n", kept.meshVolume / cell,
              kept.level);
  EXPECT_NEAR(kept.meshVolume, cell, (std::max(mcLoss, 0.0) + 0.01) * cell);
  EXPECT_LT(kept.level, 0.5);
}

// The test: a resting slab (jittered as a PBF pool at rest) meshed with anisotropic
// kernels has a flatter top than the isotropic kernels of the same particles: the area-weighted
// spread of the up-facing normals over the slab's inner part is under half (measured 0.21x).
// It keeps the fluid's volume (particles * h^3) within 3 %: the level is chosen by a voxel
// count (about 1 % off on a surface this smooth; measured 0.989). Both meshes are
// closed, and the mean top normal is +y within 0.02.
TEST(FluidSurface, ARestingSlabMeshesFlatterThanIsotropicKernels) {
  const int nx = 24, ny = 6, nz = 24;
  const std::vector<Vec3> p = jitteredSlab(nx, ny, nz, 0.25, 7);
  FluidSurfaceOptions aniso, iso;
  iso.anisotropic = false;
  iso.keepVolume = false;
  FluidSurfaceReport ra, ri;
  const TriangleMesh ma = meshFluid(p, kH, aniso, &ra);
  const TriangleMesh mi = meshFluid(p, kH, iso, &ri);
  const double m0 = 4 * kH, m1 = (nx - 5) * kH;
  const TopStats ta = topNormals(ma, m0, m1, m0, m1), ti = topNormals(mi, m0, m1, m0, m1);
  std::printf("anisotropic: %zu triangles, volume %.4f of particles', top normal spread %.5f | isotropic: %zu, %.4f, %.5f\n",
              ma.triangleCount(), ra.meshVolume / ra.particleVolume, ta.variance, mi.triangleCount(),
              ri.meshVolume / ri.particleVolume, ti.variance);
  EXPECT_EQ(closedManifoldViolation(ma), "");
  EXPECT_EQ(closedManifoldViolation(mi), "");
  ASSERT_GT(ta.area, 0.8 * (m1 - m0) * (m1 - m0));  // the top was found
  EXPECT_LT(ta.variance, 0.5 * ti.variance);
  EXPECT_NEAR(ta.mean.normalized().y(), 1.0, 0.02);
  EXPECT_NEAR(ra.meshVolume, ra.particleVolume, 0.03 * ra.particleVolume);
}

// What the kernels are: flattened across the surface, round inside. In the same slab the top
// layer's kernels have their thin axis within 0.2 rad of +y (measured 0.03) and are at most 0.75
// as thin as wide (measured 0.49; the corrections allow 1/3); kernels two layers deep see a full
// neighbourhood and stay within 0.8 of round (measured 0.91). Smoothing moves the top layer
// down (measured 0.27 spacings).
TEST(FluidSurface, KernelsFlattenAcrossTheSurfaceAndStayRoundInside) {
  const int nx = 24, ny = 6, nz = 24;
  const std::vector<Vec3> p = jitteredSlab(nx, ny, nz, 0.25, 7);
  const FluidKernels k = fluidKernels(p, kH);
  auto id = [&](int i, int j, int kk) { return (std::size_t(kk) * ny + j) * nx + i; };
  double topTilt = 0, topThin = 0, deepThin = 0, topDy = 0;
  int count = 0;
  for (int kk = 6; kk < 18; ++kk)
    for (int i = 6; i < 18; ++i, ++count) {
      const KernelShape top = shapeOf(k.inverseAxes[id(i, ny - 1, kk)]);
      topTilt += top.tilt;
      topThin += top.thinOverWide;
      deepThin += shapeOf(k.inverseAxes[id(i, 2, kk)]).thinOverWide;
      topDy += (k.centre[id(i, ny - 1, kk)] - p[id(i, ny - 1, kk)]).y() / kH;
    }
  std::printf("top layer: tilt %.3f rad, thin/wide %.3f, moved %.3f spacings in y; two deep: thin/wide %.3f\n",
              topTilt / count, topThin / count, topDy / count, deepThin / count);
  EXPECT_LT(topTilt / count, 0.2);
  EXPECT_LT(topThin / count, 0.75);
  EXPECT_GT(deepThin / count, 0.8);
  EXPECT_LT(topDy / count, 0.0);
}

// The shortcut for particles deep inside (filled, not summed) leaves the surface of a thick block
// as summing every kernel makes it: the same volume within 0.5 % (both pick their level by a
// voxel count of nearly the same field near the surface; measured equal to 5 digits), the same bounds within
// one field voxel, and one closed piece (no bubbles where the filled cubes meet).
TEST(FluidSurface, SkippingDeepParticlesKeepsTheSurface) {
  const std::vector<Vec3> p = jitteredSlab(20, 20, 20, 0.25, 11);
  FluidSurfaceOptions all;
  all.skipDeep = false;
  FluidSurfaceReport fast, full;
  const FluidKernels k = fluidKernels(p, kH);
  std::size_t deep = 0;
  for (std::uint8_t d : k.interior) deep += d;
  const TriangleMesh a = meshFluid(p, kH, FluidSurfaceOptions{}, &fast);
  const TriangleMesh b = meshFluid(p, kH, all, &full);
  std::printf("deep particles %zu of %zu; volume skipping %.5f, summing all %.5f of the particles'\n", deep, p.size(),
              fast.meshVolume / fast.particleVolume, full.meshVolume / full.particleVolume);
  ASSERT_GT(deep, p.size() / 10);  // the shortcut was taken (11^3 of 20^3 expected)
  EXPECT_EQ(closedManifoldViolation(a), "");
  EXPECT_NEAR(fast.meshVolume, full.meshVolume, 0.005 * full.meshVolume);
  const Eigen::AlignedBox3d ba = bounds(a), bb = bounds(b);
  EXPECT_LT((ba.min() - bb.min()).cwiseAbs().maxCoeff(), 0.5 * kH);
  EXPECT_LT((ba.max() - bb.max()).cwiseAbs().maxCoeff(), 0.5 * kH);
}

// Meshing is deterministic: the same particles give the same bytes under 1 and 2 TBB threads
// (a block 40 spacings deep in z: the field is summed in several slabs of 16 spacings).
TEST(FluidSurface, MeshBytesDoNotDependOnTheThreadCount) {
  const std::vector<Vec3> p = jitteredSlab(12, 5, 40, 0.25, 3);
  TriangleMesh one, two;
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
    one = meshFluid(p, kH);
  }
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
    two = meshFluid(p, kH);
  }
  ASSERT_FALSE(one.empty());
  EXPECT_EQ(one.positions, two.positions);
  EXPECT_EQ(one.normals, two.normals);
  EXPECT_EQ(one.indices, two.indices);
}

TEST(FluidSurface, BadInputIsAClearError) {
  std::vector<Vec3> p = jitteredSlab(3, 3, 3, 0.0, 1);
  p[5].y() = std::nan("");
  try {
    meshFluid(p, kH);
    FAIL() << "a NaN position was accepted";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("particle 5"), std::string::npos) << e.what();
  }
  p[5].y() = 0.0;
  EXPECT_THROW(meshFluid(p, -kH), RuntimeError);
  FluidSurfaceOptions o;
  o.lambda = 1.5;
  EXPECT_THROW(meshFluid(p, kH, o), RuntimeError);
  // A reach of one spacing weighs every neighbour node 0: a clear error, not NaN kernels; the
  // smallest reach allowed meshes (a jittered slab: nodes are not all at one distance).
  FluidSurfaceOptions near;
  near.reach = 1.0;
  try {
    meshFluid(p, kH, near);
    FAIL() << "reach 1 was accepted";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("reach"), std::string::npos) << e.what();
  }
  near.reach = 1.5;
  EXPECT_FALSE(meshFluid(jitteredSlab(6, 4, 6, 0.25, 2), kH, near).empty());
  EXPECT_TRUE(meshFluid({}, kH).empty());
}

}  // namespace
}  // namespace physketch::render
