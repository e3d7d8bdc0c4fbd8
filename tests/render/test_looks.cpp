// How frames look: the ground's shadow under a floating box (its place from the light
// direction, its depth from the lighting model), MSAA's blended edge pixels, the background
// gradient (closed form per row), the roughness highlight (closed-form bounds), and bytes that
// repeat exactly.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/error.h"
#include "render/renderer.h"
#include "render/voxel_mesh.h"
#include "tests/render/render_test_util.h"

namespace physketch::render {
namespace {

using namespace test;  // NOLINT: shared helpers of the render tests

constexpr double kPi = 3.14159265358979323846;

// What the shaders do to a linear value: clamp, gamma 2.2, 8 bits.
double encoded(double linear) { return 255.0 * std::pow(std::clamp(linear, 0.0, 1.0), 1.0 / 2.2); }

Mat4f translation(const Vec3& t) {
  Mat4f m = Mat4f::Identity();
  m.block<3, 1>(0, 3) = t.cast<float>();
  return m;
}

// ---- shadows

// A 0.2 m box floating 0.3 m above a grey ground, seen from the side the light is not on, so
// both the shadow and a far piece of ground are in view and not hidden by the box.
struct ShadowScene {
  TriangleMesh box = [] {
    VoxelMeshOptions opt;
    opt.smoothingSteps = 0;
    return meshVoxels(boxVoxels(10, 10, 10), 0.02, Vec3::Zero(), opt);  // ~[-0.01, 0.19]^3 m
  }();
  Mat4f model = translation(Vec3(-0.09, 0.31, -0.09));  // box over x, z in [-0.1, 0.1], y in [0.3, 0.5]
  Vec3 centre{0.0, 0.4, 0.0};
  Camera camera = [] {
    Camera c;
    c.eye = Vec3(-1.0, 1.2, -1.0);
    c.target = Vec3(0.0, 0.1, 0.0);
    return c;
  }();
};

Image renderShadowScene(const ShadowScene& s, bool shadows) {
  Looks looks;
  looks.shadows = shadows;
  OffscreenRenderer r(200, 150, looks);
  const int h = r.uploadMesh(s.box);
  r.beginFrame(s.camera, Color{0.8f, 0.85f, 0.9f});
  r.drawGround(0.0, 0.0, 0.0, 2.0, Color{0.6f, 0.6f, 0.6f});
  r.drawMesh(h, s.model, Color{0.9f, 0.2f, 0.1f});
  return r.endFrame();
}

// Mean of the three channels at the pixel that shows world point p.
double valueAt(const Image& img, const Camera& cam, const Vec3& p) {
  Eigen::Vector2d px;
  EXPECT_TRUE(projectToPixel(cam, img.width, img.height, p, px));
  const int x = static_cast<int>(px.x()), y = static_cast<int>(px.y());
  EXPECT_TRUE(x >= 0 && x < img.width && y >= 0 && y < img.height) << p.transpose();
  const std::uint8_t* q = pixelAt(img, std::clamp(x, 0, img.width - 1), std::clamp(y, 0, img.height - 1));
  return (q[0] + q[1] + q[2]) / 3.0;
}

// The shadow of the box's centre falls where the ray from it along -lightDirection() meets the
// ground. There only ambient light remains: linear 0.25 base against 0.25 + 0.75 (n . l) in
// full light, (n . l) = l_y = 0.82 for the ground, so the encoded value drops to
// (0.25 / 0.866)^(1/2.2) = 0.57 of the lit one (the ground's faint highlight aside). We require
// at most 0.7: a missing or misplaced shadow leaves 1.0. The point mirrored to the light's side
// of the box, and a far point, must stay as lit as without shadows.
TEST(Looks, FloatingBoxShadowsTheGroundWhereTheLightSays) {
  const ShadowScene s;
  const Image lit = renderShadowScene(s, false);
  const Image shaded = renderShadowScene(s, true);
  const Vec3 l = lightDirection();
  const Vec3 shadow = s.centre - l * (s.centre.y() / l.y());  // on the ground, y = 0
  const Vec3 mirrored(2.0 * s.centre.x() - shadow.x(), 0.0, 2.0 * s.centre.z() - shadow.z());
  const Vec3 far(0.7, 0.0, 0.1);

  const double under = valueAt(shaded, s.camera, shadow), underLit = valueAt(lit, s.camera, shadow);
  std::printf("ground under the box: %.1f with shadows, %.1f without (ratio %.2f)\n", under, underLit, under / underLit);
  EXPECT_LE(under, 0.7 * underLit);
  EXPECT_GE(under, 0.45 * underLit);  // ambient stays: not black
  EXPECT_NEAR(valueAt(shaded, s.camera, mirrored), valueAt(lit, s.camera, mirrored), 1.0);
  EXPECT_NEAR(valueAt(shaded, s.camera, far), valueAt(lit, s.camera, far), 1.0);
  // Also against the far ground in the same image: darker by the same margin (the checker's
  // dark cells are 0.8 of the light ones, so compare with the darker of the two points).
  const double farValue = valueAt(shaded, s.camera, far);
  EXPECT_LE(under, 0.7 * std::min(farValue, underLit));
}

// The same with the box made of Gaussian splats (10^3 splats of sigma 0.01 m, 0.02 m apart,
// opacity 1: each casts where its Gaussian reaches 1/2, a disc of radius 1.18 sigma, so
// neighbours overlap and the block is opaque to the light). Same oracle and bounds as above.
TEST(Looks, FloatingSplatBlockShadowsTheGroundWhereTheLightSays) {
  const ShadowScene s;
  std::vector<Splat> block;
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 10; ++j)
      for (int k = 0; k < 10; ++k) {
        Splat sp;
        sp.centre = Vec3f(-0.09f + 0.02f * i, 0.31f + 0.02f * j, -0.09f + 0.02f * k);
        sp.covariance = Eigen::Matrix3f::Identity() * 1e-4f;
        sp.color = Color{0.9f, 0.2f, 0.1f};
        block.push_back(sp);
      }
  auto render = [&](bool shadows) {
    Looks looks;
    looks.shadows = shadows;
    OffscreenRenderer r(200, 150, looks);
    r.beginFrame(s.camera, Color{0.8f, 0.85f, 0.9f});
    r.drawGround(0.0, 0.0, 0.0, 2.0, Color{0.6f, 0.6f, 0.6f});
    r.drawSplats(block);
    return r.endFrame();
  };
  const Image lit = render(false), shaded = render(true);
  const Vec3 l = lightDirection();
  const Vec3 shadow = s.centre - l * (s.centre.y() / l.y());
  const Vec3 mirrored(2.0 * s.centre.x() - shadow.x(), 0.0, 2.0 * s.centre.z() - shadow.z());
  const double under = valueAt(shaded, s.camera, shadow), underLit = valueAt(lit, s.camera, shadow);
  std::printf("ground under the splats: %.1f with shadows, %.1f without (ratio %.2f)\n", under, underLit,
              under / underLit);
  EXPECT_LE(under, 0.7 * underLit);
  EXPECT_GE(under, 0.45 * underLit);
  EXPECT_NEAR(valueAt(shaded, s.camera, mirrored), valueAt(lit, s.camera, mirrored), 1.0);
  EXPECT_NEAR(valueAt(shaded, s.camera, Vec3(0.7, 0.0, 0.1)), valueAt(lit, s.camera, Vec3(0.7, 0.0, 0.1)), 1.0);
}

// ---- MSAA

// One flat triangle facing the camera, roughness 1 (Blinn-Phong exponent 0: the highlight is
// constant too), so every covered sample has the same colour V over a black background. With
// one sample per pixel each pixel is 0 or V; with 4, pixels on the slanted edges blend: in most
// rows that cross an edge some pixel lies strictly between (10% .. 90% of V).
Image renderTriangle(int samples, double& interior) {
  TriangleMesh tri;
  tri.positions = {Vec3f(-0.5f, -0.5f, 0.0f), Vec3f(0.5f, -0.4f, 0.0f), Vec3f(0.05f, 0.6f, 0.0f)};
  tri.normals.assign(3, Vec3f(0, 0, 1));
  tri.indices = {0, 1, 2};
  Looks looks;
  looks.samples = samples;
  looks.shadows = false;
  OffscreenRenderer r(160, 120, looks);
  const int h = r.uploadMesh(tri);
  Camera cam;
  cam.eye = Vec3(0, 0, 2);
  cam.target = Vec3(0, 0, 0);
  r.beginFrame(cam, Color{0, 0, 0});
  r.drawMesh(h, Mat4f::Identity(), Color{0.8f, 0.8f, 0.8f}, 1.0f);
  const Image img = r.endFrame();
  interior = pixelAt(img, 80, 60)[1];  // the triangle's middle
  return img;
}

int rowsWithBlendedEdge(const Image& img, double v, int& rowsCrossing) {
  int blended = 0;
  rowsCrossing = 0;
  for (int y = 0; y < img.height; ++y) {
    bool crossing = false, mixed = false;
    for (int x = 0; x < img.width; ++x) {
      const double g = pixelAt(img, x, y)[1];
      crossing = crossing || g > 0.5 * v;
      mixed = mixed || (g > 0.1 * v && g < 0.9 * v);
    }
    rowsCrossing += crossing;
    blended += crossing && mixed;
  }
  return blended;
}

TEST(Looks, MsaaBlendsEdgePixels) {
  double v1 = 0, v4 = 0;
  const Image single = renderTriangle(1, v1), multi = renderTriangle(4, v4);
  ASSERT_GT(v1, 100.0);
  EXPECT_EQ(v1, v4);  // the same shading inside
  int rows1 = 0, rows4 = 0;
  const int blended1 = rowsWithBlendedEdge(single, v1, rows1), blended4 = rowsWithBlendedEdge(multi, v4, rows4);
  ASSERT_GT(rows1, 50);
  std::printf("rows with a blended edge pixel: %d of %d (1 sample), %d of %d (4 samples)\n", blended1, rows1, blended4,
              rows4);
  EXPECT_EQ(blended1, 0);
  EXPECT_GE(blended4, rows4 * 8 / 10);
  EXPECT_NE(single.rgba, multi.rgba);
}

TEST(Looks, RejectsSampleCountsAndShadowMapSizesTheDriverLacks) {
  Looks bad;
  bad.samples = 3;  // not a power of two
  EXPECT_THROW(OffscreenRenderer(16, 16, bad), RuntimeError);
  bad.samples = 1 << 12;
  EXPECT_THROW(OffscreenRenderer(16, 16, bad), RuntimeError);
  bad = Looks{};
  bad.shadowMapSize = 4;
  EXPECT_THROW(OffscreenRenderer(16, 16, bad), RuntimeError);
}

// ---- background

// Row y (0 = top) is shaded at its centre, at height (H - y - 0.5) / H from the bottom edge:
// linear = bottom + (top - bottom) * that, then gamma-encoded. Every row within one level.
TEST(Looks, BackgroundGradientRunsFromTopToBottomColour) {
  const Background bg{{0.1f, 0.2f, 0.9f}, {0.9f, 0.5f, 0.1f}};
  const int w = 40, h = 100;
  OffscreenRenderer r(w, h);
  Camera cam;
  r.beginFrame(cam, bg);
  const Image img = r.endFrame();
  for (int y = 0; y < h; ++y) {
    const double t = (h - y - 0.5) / h;
    for (int c = 0; c < 3; ++c) {
      const double want = encoded(bg.bottom[c] + (bg.top[c] - bg.bottom[c]) * t);
      EXPECT_NEAR(pixelAt(img, 0, y)[c], want, 1.0) << "row " << y << " channel " << c;
      EXPECT_EQ(pixelAt(img, w - 1, y)[c], pixelAt(img, 0, y)[c]) << "rows are uniform";
    }
  }
  EXPECT_GT(pixelAt(img, 0, 0)[2], pixelAt(img, 0, h - 1)[2] + 100);  // bluer at the top
  EXPECT_LT(pixelAt(img, 0, 0)[0], pixelAt(img, 0, h - 1)[0] - 100);  // redder at the bottom
  EXPECT_THROW(r.beginFrame(cam, Background{{1.5f, 0, 0}, {0, 0, 0}}), RuntimeError);
}

// ---- roughness

// A UV sphere with exact normals, blue channel only: base 0.1. Linear blue is
// 0.1 (0.25 + 0.75 n.l) + s with the highlight s = 0.04 (n + 8) / 8 (n.h)^n (n.l).
//  - roughness 0.8: exponent 2 / 0.8^4 - 2 = 2.88, so s <= 0.04 * 10.88 / 8 = 0.054 and blue
//    <= encoded(0.154) = 109: we require < 115.
//  - roughness 0.2: exponent 1248, peak s = 6.3: pixels within ~4 degrees of the mirror normal
//    saturate, so the brightest blue is >= 250.
TriangleMesh uvSphere(double radius, int slices, int stacks) {
  TriangleMesh m;
  for (int j = 0; j <= stacks; ++j)
    for (int i = 0; i <= slices; ++i) {
      const double theta = kPi * j / stacks, phi = 2.0 * kPi * i / slices;
      const Vec3 n(std::sin(theta) * std::cos(phi), std::cos(theta), std::sin(theta) * std::sin(phi));
      m.positions.push_back((radius * n).cast<float>());
      m.normals.push_back(n.cast<float>());
    }
  for (int j = 0; j < stacks; ++j)
    for (int i = 0; i < slices; ++i) {
      const std::uint32_t a = j * (slices + 1) + i, b = a + slices + 1;
      m.indices.insert(m.indices.end(), {a, a + 1, b, a + 1, b + 1, b});
    }
  return m;
}

int brightestBlue(float roughness) {
  OffscreenRenderer r(160, 120);
  const int h = r.uploadMesh(uvSphere(0.3, 96, 48));
  Camera cam;
  cam.eye = Vec3(0.4, 0.5, 1.4);
  cam.target = Vec3(0, 0, 0);
  r.beginFrame(cam, Color{0, 0, 0});
  r.drawMesh(h, Mat4f::Identity(), Color{0.5f, 0.3f, 0.1f}, roughness);
  const Image img = r.endFrame();
  int best = 0;
  for (std::size_t i = 2; i < img.rgba.size(); i += 4) best = std::max(best, int(img.rgba[i]));
  return best;
}

TEST(Looks, SmootherMaterialsHaveASharperBrighterHighlight) {
  const int rough = brightestBlue(0.8f), smooth = brightestBlue(0.2f);
  std::printf("brightest blue: %d (roughness 0.8), %d (roughness 0.2)\n", rough, smooth);
  EXPECT_LT(rough, 115);
  EXPECT_GE(smooth, 250);
  OffscreenRenderer r(8, 8);
  const int h = r.uploadMesh(uvSphere(0.1, 8, 4));
  r.beginFrame(Camera{}, Color{0, 0, 0});
  EXPECT_THROW(r.drawMesh(h, Mat4f::Identity(), Color{1, 1, 1}, 1.5f), RuntimeError);
  EXPECT_THROW(r.drawMesh(h, Mat4f::Identity(), Color{1, 1, 1}, std::nanf("")), RuntimeError);
}

// ---- determinism

// Shadows, MSAA, gradient, ground and two meshes: the same bytes from two renderers.
TEST(Looks, FullLookIsBitIdenticalAcrossRenderers) {
  const ShadowScene s;
  auto render = [&s] {
    OffscreenRenderer r(160, 120);
    const int box = r.uploadMesh(s.box);
    const int ball = r.uploadMesh(uvSphere(0.1, 32, 16));
    r.beginFrame(s.camera, Background{{0.6f, 0.7f, 0.9f}, {0.95f, 0.95f, 0.95f}});
    r.drawGround(0.0, 0.0, 0.0, 2.0, Color{0.6f, 0.6f, 0.6f});
    r.drawMesh(box, s.model, Color{0.9f, 0.2f, 0.1f}, 0.3f);
    r.drawMesh(ball, translation(Vec3(0.3, 0.1, -0.2)), Color{0.2f, 0.3f, 0.9f});
    return r.endFrame();
  };
  const Image a = render(), b = render();
  EXPECT_GT(a.meshSamples, 0u);
  EXPECT_EQ(a.rgba, b.rgba);
}

}  // namespace
}  // namespace physketch::render
