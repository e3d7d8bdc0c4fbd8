// Gaussian splats (OffscreenRenderer::drawSplats). Oracle: the closed form of a projected
// Gaussian. A splat of covariance Sigma at distance z straight ahead of a pinhole camera of focal
// length f pixels projects to a 2-D Gaussian of standard deviation sqrt(f^2 sigma^2 / z^2 + 0.3)
// pixels along each axis; a white splat of opacity 1 on black leaves 255 * 0.99 exp(-x^2 / 2 s^2)
// at pixel offset x (one sample per pixel, colour 1 is 1 in any gamma).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "core/error.h"
#include "render/renderer.h"
#include "render/voxel_mesh.h"
#include "tests/render/render_test_util.h"

namespace physketch::render {
namespace {

using namespace test;  // NOLINT: shared helpers of the render tests

constexpr double kPi = 3.14159265358979323846;
constexpr int kSize = 200;
constexpr double kDistance = 2.0;  // m, eye to the splat
constexpr double kSigma = 0.05;    // m

Camera frontCamera() {
  Camera c;
  c.eye = Vec3(0.0, 0.0, kDistance);
  c.target = Vec3::Zero();
  c.up = Vec3(0, 1, 0);
  c.fovYDeg = 40.0;
  return c;
}

// Focal length in pixels of frontCamera on a kSize image.
double focalPixels() { return 0.5 * kSize / std::tan(0.5 * 40.0 * kPi / 180.0); }

// The full width (pixels) at which the image's red channel crosses `level` (0-255) along row y
// (or column x), from the centre outwards, linear between pixel centres.
double widthAt(const Image& img, bool alongX, double level) {
  auto value = [&](int k) {
    const int c = kSize / 2;
    return double(alongX ? pixelAt(img, k, c)[0] : pixelAt(img, c, k)[0]);
  };
  auto crossing = [&](int from, int step) {
    for (int k = from; k >= 0 && k + step >= 0 && k + step < kSize; k += step) {
      const double a = value(k), b = value(k + step);
      if (a >= level && b < level) return k + step * (a - level) / (a - b);
    }
    return double(from);
  };
  // Pixel centres are at k + 0.5; the projected centre is at kSize / 2, between pixels 99 and 100.
  return crossing(kSize / 2, 1) - crossing(kSize / 2 - 1, -1);
}

Image renderOne(const Eigen::Matrix3f& covariance, const Vec3f& normal = Vec3f::Zero()) {
  Looks looks;
  looks.samples = 1;  // one sample at each pixel's centre: the closed form holds per pixel
  looks.shadows = false;
  OffscreenRenderer r(kSize, kSize, looks);
  r.beginFrame(frontCamera(), Color{0.0f, 0.0f, 0.0f}, ClipRange{0.1, 10.0});
  Splat s;
  s.covariance = covariance;
  s.normal = normal;
  r.drawSplats({s});
  return r.endFrame();
}

// The half-maximum width a Gaussian of standard deviation s pixels (after the 0.3 px^2 filter)
// has where 0.99 exp(-x^2 / 2 s^2) = 1/2.
double halfWidth(double sigmaPixels) {
  const double s = std::sqrt(sigmaPixels * sigmaPixels + 0.3);
  return 2.0 * s * std::sqrt(2.0 * std::log(2.0 * 0.99));
}

// Tolerance 0.3 px: the crossings are interpolated linearly between pixel centres on a
// Gaussian whose curvature there is small, and 8-bit rounding moves a crossing by under
// 1/(255 slope) = 0.03 px; a wrong projection scale (e.g. the focal length of the wrong axis
// or a factor 2 in the viewport) is off by pixels.
TEST(Splats, AnUndeformedSplatHasTheProjectedWidth) {
  const Image img = renderOne(Eigen::Matrix3f::Identity() * float(kSigma * kSigma));
  const double want = halfWidth(focalPixels() * kSigma / kDistance);
  const double wx = widthAt(img, true, 127.5), wy = widthAt(img, false, 127.5);
  std::printf("undeformed: width %.3f x %.3f px, closed form %.3f px\n", wx, wy, want);
  EXPECT_NEAR(wx, want, 0.3);
  EXPECT_NEAR(wy, want, 0.3);
}

// The test: the splat of a block stretched by F (Sigma' = F Sigma F^T, PhysGaussian)
// differs from the undeformed one as F says: stretched 2x along x and squeezed to 0.7 along y,
// its widths follow the closed form of the new standard deviations (2 sigma, 0.7 sigma); a
// shear tilts its long axis in the image by the angle F gives.
TEST(Splats, AStretchedSplatFollowsItsDeformationGradient) {
  const Eigen::Matrix3f sigma = Eigen::Matrix3f::Identity() * float(kSigma * kSigma);
  Eigen::Matrix3f F = Eigen::Matrix3f::Identity();
  F(0, 0) = 2.0f;
  F(1, 1) = 0.7f;
  const Image img = renderOne(F * sigma * F.transpose());
  const double f = focalPixels() / kDistance;
  const double wx = widthAt(img, true, 127.5), wy = widthAt(img, false, 127.5);
  std::printf("stretched: width %.3f x %.3f px, closed form %.3f x %.3f px\n", wx, wy, halfWidth(f * 2.0 * kSigma),
              halfWidth(f * 0.7 * kSigma));
  EXPECT_NEAR(wx, halfWidth(f * 2.0 * kSigma), 0.3);
  EXPECT_NEAR(wy, halfWidth(f * 0.7 * kSigma), 0.3);

  // Rotated 30 degrees about the view axis: the brightest pixels lie along that direction.
  const Eigen::Matrix3f R = Eigen::AngleAxisf(float(kPi / 6.0), Eigen::Vector3f::UnitZ()).toRotationMatrix();
  const Image tilted = renderOne((R * F) * sigma * (R * F).transpose());
  double sxx = 0, syy = 0, sxy = 0;
  for (int y = 0; y < kSize; ++y)
    for (int x = 0; x < kSize; ++x) {
      const double v = pixelAt(tilted, x, y)[0];
      const double dx = x + 0.5 - kSize / 2.0, dy = kSize / 2.0 - (y + 0.5);  // y up
      sxx += v * dx * dx;
      syy += v * dy * dy;
      sxy += v * dx * dy;
    }
  const double angle = 0.5 * std::atan2(2.0 * sxy, sxx - syy);
  std::printf("tilted: long axis at %.2f degrees (want 30)\n", angle * 180.0 / kPi);
  EXPECT_NEAR(angle, kPi / 6.0, 1.0 * kPi / 180.0);
}

// A splat with a normal is lit as a mesh's diffuse part: a white splat's centre pixel (alpha at
// its 0.99 cap there) is 255 * 0.99 * (0.25 + 0.75 max(n . l, 0))^(1 / 2.2) on black: 252 facing
// the light, 1/4 of the light's share (134) facing away or side-on, and 252 again without a
// normal (unlit). Tolerance 1.5 levels: 8-bit rounding of the colour and of the blend.
TEST(Splats, ASplatWithANormalIsLitAsAMeshsDiffusePart) {
  const Eigen::Matrix3f sigma = Eigen::Matrix3f::Identity() * float(kSigma * kSigma);
  const Vec3f l = lightDirection().cast<float>();
  const Vec3f side = l.cross(Vec3f::UnitZ()).normalized();
  const auto centre = [&](const Vec3f& n) { return double(pixelAt(renderOne(sigma, n), kSize / 2, kSize / 2)[0]); };
  const auto expected = [](double shade) { return 255.0 * 0.99 * std::pow(shade, 1.0 / 2.2); };
  EXPECT_NEAR(centre(l), expected(1.0), 1.5);
  EXPECT_NEAR(centre(-l), expected(0.25), 1.5);
  EXPECT_NEAR(centre(side), expected(0.25), 1.5);
  const Vec3f halfway = (l + side).normalized();  // 45 degrees from the light
  EXPECT_NEAR(centre(halfway), expected(0.25 + 0.75 * std::sqrt(0.5)), 1.5);
  EXPECT_NEAR(centre(Vec3f::Zero()), expected(1.0), 1.5);
}

// Splats are drawn back to front over the meshes: a red splat behind a green one shows green in
// the middle; a box in front of both hides them (depth test against the meshes).
TEST(Splats, NearerSplatsCoverFartherOnesAndMeshesHideThem) {
  Looks looks;
  looks.samples = 1;
  looks.shadows = false;
  OffscreenRenderer r(kSize, kSize, looks);
  Splat red, green;
  red.centre = Vec3f(0.0f, 0.0f, -0.3f);
  red.color = {1.0f, 0.0f, 0.0f};
  green.centre = Vec3f(0.0f, 0.0f, 0.3f);
  green.color = {0.0f, 1.0f, 0.0f};
  red.covariance = green.covariance = Eigen::Matrix3f::Identity() * float(kSigma * kSigma);
  for (int order = 0; order < 2; ++order) {
    r.beginFrame(frontCamera(), Color{0.0f, 0.0f, 0.0f}, ClipRange{0.1, 10.0});
    r.drawSplats(order == 0 ? std::vector<Splat>{red, green} : std::vector<Splat>{green, red});
    const Image img = r.endFrame();
    const std::uint8_t* c = pixelAt(img, kSize / 2, kSize / 2);
    EXPECT_LT(c[0], 10) << "order " << order;  // 0.99 green over red leaves 1 % of red
    EXPECT_GT(c[1], 240) << "order " << order;
  }
  // A box between the eye and the splats hides them: the pixels it covers (the middle 9 x 9) are
  // the same with and without the splats behind it.
  const int box = r.uploadMesh(meshVoxels(boxVoxels(1, 1, 1), 1.0, Vec3::Zero()));  // a unit cube about 0
  Mat4f model = Mat4f::Identity();
  model.topLeftCorner<3, 3>() *= 0.4f;
  model.topRightCorner<3, 1>() = Vec3f(0.0f, 0.0f, 1.0f);
  Image frames[2];
  for (int withSplats = 0; withSplats < 2; ++withSplats) {
    r.beginFrame(frontCamera(), Color{0.0f, 0.0f, 0.0f}, ClipRange{0.1, 10.0});
    r.drawMesh(box, model, {0.0f, 0.0f, 1.0f});
    if (withSplats) r.drawSplats({red, green});
    frames[withSplats] = r.endFrame();
  }
  for (int dy = -4; dy <= 4; dy += 2)
    for (int dx = -4; dx <= 4; dx += 2) {
      ASSERT_GT(pixelAt(frames[0], kSize / 2 + dx, kSize / 2 + dy)[2], 50);  // the box is there
      for (int ch = 0; ch < 3; ++ch)
        EXPECT_EQ(pixelAt(frames[0], kSize / 2 + dx, kSize / 2 + dy)[ch], pixelAt(frames[1], kSize / 2 + dx, kSize / 2 + dy)[ch]);
    }
}

TEST(Splats, BadSplatsAreClearErrors) {
  OffscreenRenderer r(32, 32);
  r.beginFrame(frontCamera(), Color{0.0f, 0.0f, 0.0f});
  Splat s;
  s.covariance(0, 1) = 0.5f;  // not symmetric
  try {
    r.drawSplats({Splat{}, s});
    FAIL() << "an asymmetric covariance was accepted";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("splat 1"), std::string::npos) << e.what();
  }
  Splat flat;
  flat.covariance(2, 2) = 0.0f;
  EXPECT_THROW(r.drawSplats({flat}), RuntimeError);
  Splat dim;
  dim.opacity = 0.0f;
  EXPECT_THROW(r.drawSplats({dim}), RuntimeError);
  Splat longNormal;
  longNormal.normal = Vec3f(0.0f, 2.0f, 0.0f);
  EXPECT_THROW(r.drawSplats({longNormal}), RuntimeError);
  r.endFrame();
  EXPECT_THROW(r.drawSplats({Splat{}}), RuntimeError);  // outside a frame
}

}  // namespace
}  // namespace physketch::render
