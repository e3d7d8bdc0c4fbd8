// Per-frame behaviour of the off-screen renderer: clip planes derived from the scene's bounds
// (a 100 m scene seen from 150 m is drawn), the count of mesh samples that tells an empty
// frame, and the description of the EGL device in use.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "core/error.h"
#include "render/renderer.h"
#include "render/voxel_mesh.h"
#include "tests/render/render_test_util.h"

namespace physketch::render {
namespace {

using namespace test;  // NOLINT: shared helpers of the render tests

// ---- clipRangeFor

// Eye depth of a point along the viewing direction, from the camera's definition alone.
double eyeDepth(const Camera& cam, const Vec3& p) { return (p - cam.eye).dot((cam.target - cam.eye).normalized()); }

// Independent check: project every corner with the renderer's matrices (projectionMatrix is
// gluPerspective, tested in test_render.cpp) and require clip-space -w <= z <= w for every
// corner in front of the camera.
void expectCornersInsideDepthRange(const Camera& cam, const Eigen::AlignedBox3d& box, const ClipRange& range) {
  const double aspect = 4.0 / 3.0;
  const Eigen::Matrix4d pv = projectionMatrix(cam, aspect, range.zNear, range.zFar).cast<double>() *
                             viewMatrix(cam).cast<double>();
  for (int c = 0; c < 8; ++c) {
    const Vec3 corner = box.corner(static_cast<Eigen::AlignedBox3d::CornerType>(c));
    const Eigen::Vector4d clip = pv * corner.homogeneous();
    if (clip.w() <= 0.0) continue;  // behind the camera: never drawn, whatever the planes
    EXPECT_LE(std::abs(clip.z()), clip.w()) << "corner " << corner.transpose() << " near " << range.zNear
                                            << " far " << range.zFar;
  }
}

TEST(ClipRange, EnclosesEveryCornerAndIsTightForRandomScenes) {
  std::mt19937 rng(20240611);
  std::uniform_real_distribution<double> unit(-1.0, 1.0), scaleExp(-2.0, 3.0);  // scenes of 1 cm .. 1 km
  int outside = 0, inside = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const double scale = std::pow(10.0, scaleExp(rng));
    const Vec3 centre = scale * Vec3(unit(rng), unit(rng), unit(rng));
    const Vec3 half = scale * Vec3(0.05 + std::abs(unit(rng)), 0.05 + std::abs(unit(rng)), std::abs(unit(rng)));
    const Eigen::AlignedBox3d box(centre - half, centre + half);
    Camera cam;
    const Vec3 spread = Vec3(unit(rng), unit(rng), unit(rng));
    // Every third camera inside the box (the precision bound decides zNear), the rest around it.
    cam.eye = centre + (trial % 3 == 0 ? Vec3(0.9 * half.cwiseProduct(spread)) : Vec3(3.0 * scale * spread));
    cam.target = centre + scale * Vec3(unit(rng), unit(rng), unit(rng));
    cam.up = Vec3(0, 1, 0);
    if ((cam.target - cam.eye).norm() < 1e-3 * scale ||
        (cam.target - cam.eye).normalized().cross(cam.up).norm() < 1e-3)
      continue;  // degenerate camera (tested below)

    const ClipRange range = clipRangeFor(cam, box);
    ASSERT_GT(range.zNear, 0.0);
    ASSERT_GT(range.zFar, range.zNear);
    expectCornersInsideDepthRange(cam, box, range);

    double dMin = 1e300, dMax = -1e300;
    for (int c = 0; c < 8; ++c) {
      const double d = eyeDepth(cam, box.corner(static_cast<Eigen::AlignedBox3d::CornerType>(c)));
      dMin = std::min(dMin, d);
      dMax = std::max(dMax, d);
    }
    if (dMax <= 0.0) continue;  // all behind: any valid range (tested below)
    // The precision bound, and tightness: far within the margin of the farthest corner,
    // near within the margin of the nearest one unless the precision bound lifts it.
    EXPECT_GE(range.zNear * kMaxDepthRatio, range.zFar * (1 - 1e-12));
    EXPECT_LE(range.zFar, dMax * (1 + kClipMargin) * (1 + 1e-12));
    const double nearBound = std::max(dMin / (1 + kClipMargin), range.zFar / kMaxDepthRatio);
    EXPECT_NEAR(range.zNear, nearBound, 1e-9 * range.zFar);
    (box.contains(cam.eye) ? inside : outside)++;
  }
  EXPECT_GT(outside, 100);  // both kinds of scene were exercised
  EXPECT_GT(inside, 50);
}

TEST(ClipRange, CameraInsideTheSceneUsesTheDepthRatio) {
  Camera cam;
  cam.eye = Vec3(1, 2, 3);
  cam.target = Vec3(1, 2, 0);
  const Eigen::AlignedBox3d box(Vec3(-10, -10, -10), Vec3(10, 10, 10));
  const ClipRange range = clipRangeFor(cam, box);
  // Farthest corner straight ahead: z = -10 at depth 13 m.
  EXPECT_NEAR(range.zFar, 13.0 * (1 + kClipMargin), 1e-9);
  EXPECT_NEAR(range.zNear, range.zFar / kMaxDepthRatio, 1e-12);
}

TEST(ClipRange, SceneBehindTheCameraGivesAValidRange) {
  Camera cam;
  cam.eye = Vec3(0, 0, 0);
  cam.target = Vec3(0, 0, -1);
  const ClipRange range = clipRangeFor(cam, Eigen::AlignedBox3d(Vec3(-1, -1, 5), Vec3(1, 1, 7)));
  EXPECT_GT(range.zNear, 0.0);
  EXPECT_GT(range.zFar, range.zNear);
  EXPECT_NO_THROW(projectionMatrix(cam, 1.0, range.zNear, range.zFar));
}

TEST(ClipRange, RejectsBadInput) {
  Camera cam;
  EXPECT_THROW(clipRangeFor(cam, Eigen::AlignedBox3d()), RuntimeError);  // empty
  EXPECT_THROW(clipRangeFor(cam, Eigen::AlignedBox3d(Vec3(0, 0, 0), Vec3(1, std::nan(""), 1))), RuntimeError);
  EXPECT_THROW(clipRangeFor(cam, Eigen::AlignedBox3d(Vec3(0, 0, 0), Vec3(1, HUGE_VAL, 1))), RuntimeError);
  cam.target = cam.eye;
  EXPECT_THROW(clipRangeFor(cam, Eigen::AlignedBox3d(Vec3(0, 0, 0), Vec3(1, 1, 1))), RuntimeError);
  OffscreenRenderer r(8, 8);
  EXPECT_THROW(r.beginFrame(Camera{}, Color{0, 0, 0}, ClipRange{0.0, 1.0}), RuntimeError);
  EXPECT_THROW(r.beginFrame(Camera{}, Color{0, 0, 0}, ClipRange{2.0, 1.0}), RuntimeError);
}

// ---- a 100 m scene seen from 150 m

// A box of 10^3 voxels of `h` (edge 10 h) centred at `centre`, seen from `distance` away.
struct FarScene {
  TriangleMesh mesh;
  Camera camera;
};

FarScene boxSceneAtScale(double scale) {
  const double h = 10.0 * scale;  // 10 voxels: 100 m across at scale 1
  const Vec3 centre = scale * Vec3(30.0, 50.0, -20.0);
  VoxelMeshOptions opt;
  opt.smoothingSteps = 0;
  FarScene s;
  // Voxel (i,j,k) centre at origin + h*(i,j,k), i in [0, 10): the union is centred at `centre`.
  s.mesh = meshVoxels(boxVoxels(10, 10, 10), h, centre - Vec3::Constant(4.5 * h), opt);
  s.camera.eye = centre + 150.0 * scale * Vec3(0.3, 0.5, 1.0).normalized();
  s.camera.target = centre;
  return s;
}

// Pixels that differ from the top-left one (background in every scene here).
std::vector<bool> coverage(const Image& img) {
  const std::uint8_t* bg = pixelAt(img, 0, 0);
  std::vector<bool> covered(static_cast<std::size_t>(img.width) * img.height);
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x)
      covered[static_cast<std::size_t>(y) * img.width + x] = !samePixel(pixelAt(img, x, y), bg);
  return covered;
}

Image renderScene(const FarScene& s, const ClipRange& clip) {
  OffscreenRenderer r(160, 120);
  const int h = r.uploadMesh(s.mesh);
  r.beginFrame(s.camera, Color{0.1f, 0.2f, 0.6f}, clip);
  r.drawMesh(h, Mat4f::Identity(), Color{0.9f, 0.2f, 0.1f});
  return r.endFrame();
}

// The oracle: the same scene shrunk 100 times (a 1 m box seen from 1.5 m), rendered with the
// fixed 0.01..100 m range that is right at that scale. A perspective image does not change
// when the whole scene is scaled about the origin, so the 100 m scene must cover the same
// pixels (up to edge pixels where float rounding differs).
TEST(ClipRange, HundredMetreSceneSeenFrom150mIsDrawnLikeItsOneMetreTwin) {
  const FarScene big = boxSceneAtScale(1.0), twin = boxSceneAtScale(0.01);
  const Image reference = renderScene(twin, ClipRange{0.01, 100.0});
  const std::vector<bool> want = coverage(reference);
  const long wantCount = std::count(want.begin(), want.end(), true);
  ASSERT_GT(wantCount, 2000);  // the box fills a good part of the 160 x 120 image
  ASSERT_FALSE(want[0]);       // and the corner pixel is background

  auto mismatches = [&](const Image& img) {
    const std::vector<bool> got = coverage(img);
    long n = 0;
    for (std::size_t i = 0; i < got.size(); ++i) n += got[i] != want[i];
    return n;
  };
  const Eigen::AlignedBox3d drawable = bounds(big.mesh);
  const Image derived = renderScene(big, clipRangeFor(big.camera, drawable));
  EXPECT_GT(derived.meshSamples, 0u);
  EXPECT_LE(mismatches(derived), wantCount / 100) << "of " << wantCount << " covered pixels";

  // The defect this replaces: with the fixed 100 m far plane the back of the box is cut away.
  const Image fixed = renderScene(big, ClipRange{0.01, 100.0});
  EXPECT_GT(mismatches(fixed), wantCount / 10);
}

// ---- meshSamples: is anything of a mesh in the frame?

struct SampleScene {
  TriangleMesh mesh = [] {
    VoxelMeshOptions opt;
    opt.smoothingSteps = 0;
    return meshVoxels(boxVoxels(5, 5, 5), 0.04, Vec3::Zero(), opt);  // ~[-0.02, 0.18]^3 m
  }();
  Camera camera = [] {
    Camera c;
    c.eye = Vec3(0.6, 0.5, 0.8);
    c.target = Vec3(0.08, 0.08, 0.08);
    return c;
  }();
  Color background{0.1f, 0.2f, 0.6f};
};

Mat4f translation(const Vec3& t) {
  Mat4f m = Mat4f::Identity();
  m.block<3, 1>(0, 3) = t.cast<float>();
  return m;
}

long coveredPixels(const Image& img) {
  const std::vector<bool> c = coverage(img);
  return std::count(c.begin(), c.end(), true);
}

TEST(MeshSamples, MeshInViewCountsAtLeastItsCoveredPixels) {
  const SampleScene s;
  OffscreenRenderer r(120, 90);
  const int h = r.uploadMesh(s.mesh);
  r.beginFrame(s.camera, s.background);
  r.drawMesh(h, Mat4f::Identity(), Color{0.9f, 0.2f, 0.1f});
  const Image img = r.endFrame();
  const long covered = coveredPixels(img);
  ASSERT_GT(covered, 100);
  // Every covered pixel had at least one mesh fragment pass; back faces drawn first add more.
  EXPECT_GE(img.meshSamples, static_cast<std::uint64_t>(covered));
  EXPECT_LE(img.meshSamples, static_cast<std::uint64_t>(covered) * 4);
}

TEST(MeshSamples, MeshBehindTheCameraOrBesideTheViewCountsZero) {
  const SampleScene s;
  OffscreenRenderer r(120, 90);
  const int h = r.uploadMesh(s.mesh);
  const Vec3 backwards = s.camera.eye - s.camera.target;  // eye + this is behind the eye
  const Vec3 right = (s.camera.target - s.camera.eye).cross(s.camera.up).normalized();
  for (const Vec3& offset : {Vec3(backwards * 2.0), Vec3(5.0 * right)}) {
    r.beginFrame(s.camera, s.background);
    r.drawMesh(h, translation(offset), Color{0.9f, 0.2f, 0.1f});
    const Image img = r.endFrame();
    EXPECT_EQ(img.meshSamples, 0u) << offset.transpose();
    EXPECT_EQ(coveredPixels(img), 0) << offset.transpose();
  }
  // The count is per frame: the next frame with the mesh in view counts again.
  r.beginFrame(s.camera, s.background);
  r.drawMesh(h, Mat4f::Identity(), Color{0.9f, 0.2f, 0.1f});
  EXPECT_GT(r.endFrame().meshSamples, 0u);
}

// The ground is not a mesh, and a mesh entirely under the ground (drawn after it, as the app
// does) fails the depth test everywhere: both count zero.
TEST(MeshSamples, GroundAloneAndAMeshHiddenUnderItCountZero) {
  const SampleScene s;
  OffscreenRenderer r(120, 90);
  const int h = r.uploadMesh(s.mesh);
  r.beginFrame(s.camera, s.background);
  r.drawGround(0.0, 0.0, 0.0, 2.0, Color{0.5f, 0.5f, 0.5f});
  const Image groundOnly = r.endFrame();
  EXPECT_EQ(groundOnly.meshSamples, 0u);

  r.beginFrame(s.camera, s.background);
  r.drawGround(0.0, 0.0, 0.0, 2.0, Color{0.5f, 0.5f, 0.5f});
  r.drawMesh(h, translation(Vec3(0, -0.5, 0)), Color{0.9f, 0.2f, 0.1f});  // 0.3 m below ground
  const Image hidden = r.endFrame();
  EXPECT_EQ(hidden.meshSamples, 0u);
  EXPECT_EQ(hidden.rgba, groundOnly.rgba);
}

// ---- device

TEST(Renderer, DeviceDescriptionNamesTheEglDisplayAndTheGlRenderer) {
  OffscreenRenderer r(8, 8);
  const std::string d = r.deviceDescription();
  EXPECT_EQ(d.rfind("EGL ", 0), 0u) << d;
  const std::size_t gl = d.find(" | GL_RENDERER ");
  ASSERT_NE(gl, std::string::npos) << d;
  EXPECT_GT(d.size(), gl + 15) << d;  // a renderer string follows
  // Mesa's software device is llvmpipe.
  if (d.find("EGL_MESA_device_software") != std::string::npos) {
    EXPECT_NE(d.find("llvmpipe", gl), std::string::npos) << d;
  }
  OffscreenRenderer second(8, 8);
  EXPECT_EQ(second.deviceDescription(), d);  // the same display every time
}

// The documented order (renderer.h, OffscreenRenderer), written out by hand for a machine with
// a software device, a GPU, another software device and a second GPU: cpu tries the software
// devices in EGL's order, then the surfaceless platform, then the GPUs; gpu tries the GPUs only.
TEST(Renderer, DisplayOrderFollowsTheDocumentedPreference) {
  using K = DisplayCandidate::Kind;
  const std::vector<bool> soft{true, false, true, false};
  const std::vector<DisplayCandidate> cpu{{K::Device, 0}, {K::Device, 2}, {K::Surfaceless, -1}, {K::Device, 1}, {K::Device, 3}};
  EXPECT_EQ(displayOrder(soft, true, GlDevice::Cpu), cpu);
  const std::vector<DisplayCandidate> cpuNoSurfaceless{{K::Device, 0}, {K::Device, 2}, {K::Device, 1}, {K::Device, 3}};
  EXPECT_EQ(displayOrder(soft, false, GlDevice::Cpu), cpuNoSurfaceless);
  const std::vector<DisplayCandidate> gpu{{K::Device, 1}, {K::Device, 3}};
  EXPECT_EQ(displayOrder(soft, true, GlDevice::Gpu), gpu);
  // No devices listed (no enumeration): cpu still has the surfaceless platform; gpu has nothing.
  EXPECT_EQ(displayOrder({}, true, GlDevice::Cpu), (std::vector<DisplayCandidate>{{K::Surfaceless, -1}}));
  EXPECT_TRUE(displayOrder({}, true, GlDevice::Gpu).empty());
  EXPECT_TRUE(displayOrder({true}, true, GlDevice::Gpu).empty());
}

TEST(Renderer, GlDeviceNamesRoundTripAndUnknownOnesAreRejected) {
  EXPECT_EQ(parseGlDevice("cpu"), GlDevice::Cpu);
  EXPECT_EQ(parseGlDevice("gpu"), GlDevice::Gpu);
  EXPECT_STREQ(glDeviceName(GlDevice::Cpu), "cpu");
  EXPECT_STREQ(glDeviceName(GlDevice::Gpu), "gpu");
  EXPECT_THROW(parseGlDevice("GPU0"), RuntimeError);
  EXPECT_THROW(parseGlDevice(""), RuntimeError);
}

// --gl-device gpu takes a hardware EGL device or fails naming what EGL offered; it never draws
// with llvmpipe. On the project's machines (no GPU) it throws; on a machine with a GPU the
// renderer describes a hardware device.
TEST(Renderer, AskingForAGpuNeverFallsBackToSoftware) {
  try {
    OffscreenRenderer r(8, 8, Looks{}, GlDevice::Gpu);
    const std::string d = r.deviceDescription();
    EXPECT_EQ(d.find("EGL_MESA_device_software"), std::string::npos) << d;
    EXPECT_EQ(d.find("llvmpipe"), std::string::npos) << d;
    EXPECT_NE(d.find("(hardware"), std::string::npos) << d;
  } catch (const RuntimeError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("--gl-device gpu"), std::string::npos) << what;
    EXPECT_NE(what.find("no hardware (GPU) EGL device"), std::string::npos) << what;
  }
}

}  // namespace
}  // namespace physketch::render
