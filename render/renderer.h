// Off-screen OpenGL renderer on EGL (no window system): which EGL display is used is
// described at OffscreenRenderer below. GL 3.3 core, an FBO with RGBA8 colour and 24-bit depth
// (multisampled, then resolved), normalised Blinn-Phong lighting with a per-material roughness,
// a shadow map for the one directional light, and a vertical background gradient.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/math.h"
#include "core/scene.h"
#include "render/mesh.h"

namespace physketch::render {

using Color = std::array<float, 3>;  // linear RGB in [0, 1]

// The sun: a fixed world-space direction from the surfaces towards the light (unit), from above
// and a little towards +x/+z, the side the default camera is on. Shadows fall along -kLightDir.
inline Vec3 lightDirection() { return Vec3(0.35, 1.0, 0.6).normalized(); }

// Roughness of a surface in [0, 1] (a material's `roughness=`): the Blinn-Phong exponent is
// n = 2 / a^2 - 2 with a = roughness^2 (the Beckmann-to-Phong match of Walter et al. 2007,
// Eq. 30), and the highlight is normalised by (n + 8) / 8 so rough surfaces spread the same
// reflected energy over a wider lobe. Values below kMinRoughness are drawn as kMinRoughness.
constexpr float kDefaultRoughness = 0.5f;
constexpr float kMinRoughness = 0.1f;

// How frames look; the defaults are what `physketch run` draws.
struct Looks {
  // Samples per pixel (MSAA), resolved to one colour per pixel in endFrame. 1 turns MSAA off.
  // Must be 1 or a power of two up to the driver's GL_MAX_SAMPLES (llvmpipe: 4 and 8 work).
  int samples = 4;
  // Shadows of the meshes and Gaussian splats (not of the ground) from the directional light, on
  // the ground and on the meshes, through a shadow map of shadowMapSize^2 depth texels fitted to
  // what is drawn. A splat casts where its opacity-weighted Gaussian reaches 1/2; splats are not
  // shadowed themselves (lit by their normal only).
  bool shadows = true;
  int shadowMapSize = 1024;  // 2048 costs about 8 ms more per frame on llvmpipe (docs/benchmarks.md)
};

// A vertical gradient behind everything: `top` at the top edge of the image, `bottom` at the
// bottom edge, interpolated linearly in linear RGB over the image height (screen space, so it
// does not move with the camera). top == bottom is a plain background.
// (A constructor rather than an aggregate, so beginFrame(camera, {r, g, b}) still means one colour.)
struct Background {
  Background() = default;
  Background(const Color& topColor, const Color& bottomColor) : top(topColor), bottom(bottomColor) {}
  Color top{0.0f, 0.0f, 0.0f};
  Color bottom{0.0f, 0.0f, 0.0f};
};

struct Image {
  int width = 0, height = 0;
  std::vector<std::uint8_t> rgba;  // width*height*4 bytes, row 0 is the TOP row
  // Fragments of this frame's drawMesh calls that passed the depth test (an occlusion query,
  // GL_SAMPLES_PASSED, divided by the samples per pixel and rounded up, so about one per pixel
  // per draw; overdraw counted; drawGround is not counted). 0 means no mesh pixel landed in the image: every mesh was
  // outside the view, clipped by the near/far planes, or hidden behind what was drawn before
  // it (e.g. under the ground). It is not the number of visible pixels: a mesh hidden only by
  // something drawn after it still counts.
  std::uint64_t meshSamples = 0;
  // Where endFrame's time went (s): drawing (shadow map, background, meshes, MSAA resolve, up to
  // glFinish) and reading the pixels back (glReadPixels and the row flip).
  double drawSeconds = 0.0;
  double readSeconds = 0.0;
};

// Distances from the eye along the viewing direction (m) between which geometry is drawn;
// everything nearer than zNear or farther than zFar is clipped. Need 0 < zNear < zFar.
// The default is the fixed range used before ranges were derived from the scene: right only
// for metre-sized scenes seen from a few metres. Pass clipRangeFor(...) instead.
struct ClipRange {
  double zNear = 0.01;
  double zFar = 100.0;
};

// Largest zFar / zNear clipRangeFor returns. The depth buffer has 24 bits and stores
// z_w = (f / (f - n)) (1 - n / d) for eye depth d, so one depth step at depth d is about
// d^2 / (n 2^24): at the far plane, f (f / n) / 2^24. With f / n <= 1e4 that is 0.06% of the
// far distance, well below a voxel (a workspace of edge W has voxels of W / 151 = 0.66% W,
// and far is at most a few W when the camera is inside or next to the scene), so touching
// bodies do not z-fight. 1e5 would give 0.6%, about a voxel. The price: when the camera is
// inside the scene, geometry nearer than far / 1e4 (1.5 cm at 150 m) is clipped.
constexpr double kMaxDepthRatio = 1e4;
// Relative margin around the box's depth range: the planes sit 1% outside the nearest and
// farthest corner, so float rounding in the projection (relative 1e-7) and the ground's
// polygon offset never push drawn geometry past a plane, and zFar / zNear >= 1.02 even for
// a box of zero depth (a float projection of a thinner range loses z to cancellation).
constexpr double kClipMargin = 0.01;

// The clip range for one frame: the tightest range (within kClipMargin) that holds every
// point of `drawable` in front of the camera, with zNear as large as possible for depth
// precision but no smaller than zFar / kMaxDepthRatio. `drawable` is an axis-aligned box
// around everything drawn this frame (workspace, ground patch, bodies that left the
// workspace), in world coordinates (m). The depth of a point is linear, so the box's 8 corners
// bound it. When the whole box is behind the camera nothing can be seen and any valid range
// is returned. Throws RuntimeError on an empty or non-finite box or a degenerate camera.
ClipRange clipRangeFor(const Camera& camera, const Eigen::AlignedBox3d& drawable);

// Camera matrices (right-handed, OpenGL clip conventions): viewMatrix is gluLookAt(eye, target,
// up), projectionMatrix is gluPerspective(fovYDeg, aspect, zNear, zFar). Both throw RuntimeError
// on a degenerate camera (eye == target, up parallel to the view direction, non-finite values).
Mat4f viewMatrix(const Camera& camera);
Mat4f projectionMatrix(const Camera& camera, double aspect, double zNear, double zFar);
// World point -> pixel coordinates (x to the right, y down, pixel centres at +0.5), with the
// same matrices the renderer uses (aspect = width/height). Computed in double.
// Returns false when the point is behind the camera (clip w <= 0).
bool projectToPixel(const Camera& camera, int width, int height, const Vec3& world, Eigen::Vector2d& pixel);

// GL buffer memory held by a renderer's meshes (those from uploadMesh, not the ground quad):
// on a GPU's memory, or in RAM with llvmpipe.
struct MeshStats {
  int liveMeshes = 0;         // uploaded and not freed
  std::size_t gpuBytes = 0;   // vertex + index buffer sizes as GL reports them (bytes)
};

// One 3D Gaussian (a splat): density exp(-(x - centre)^T covariance^-1 (x - centre) / 2), drawn
// as its screen-space projection (EWA splatting, Zwicker et al. 2002, as 3D Gaussian splatting
// draws it, Kerbl et al. 2023): Sigma2 = J W covariance W^T J^T + 0.3 px^2 (W the view's
// rotation, J the perspective projection's Jacobian at the centre, in pixels; the 0.3 px^2 keeps
// a splat at least a pixel wide), and a pixel at offset d from the projected centre gets
// alpha = opacity * exp(-d^T Sigma2^-1 d / 2), cut at 1/255 and capped at 0.99.
struct Splat {
  Vec3f centre = Vec3f::Zero();                          // m
  Eigen::Matrix3f covariance = Eigen::Matrix3f::Identity();  // m^2, symmetric positive definite
  Color color{1.0f, 1.0f, 1.0f};                        // linear RGB in [0, 1]
  float opacity = 1.0f;                                 // (0, 1]
  // Unit outward normal of the surface the splat is part of: lit as a mesh's diffuse part,
  // colour x (0.25 + 0.75 max(n . light, 0)) (no specular, no shadow). Zero: unlit, the colour as given.
  Vec3f normal = Vec3f::Zero();
};

// Which EGL display a renderer asks for (`physketch run --gl-device`, bench_render --gl-device).
enum class GlDevice {
  // The default: Mesa's software rasteriser (llvmpipe, on the CPU) first, so images are
  // bit-identical wherever the Mesa version is the same; where Mesa offers none, whatever EGL
  // has (the order at OffscreenRenderer).
  Cpu,
  // A hardware EGL device only (e.g. NVIDIA's EGL through libglvnd, or a Mesa GPU driver's DRM
  // device), in the order EGL lists them; the renderer throws RuntimeError when none
  // initialises, naming what EGL offered. Its images differ from llvmpipe's in rasterisation
  // and rounding (measured on an NVIDIA H200: docs/benchmarks.md, "Drawing on a GPU").
  Gpu,
};
// "cpu" / "gpu" <-> GlDevice; parseGlDevice throws RuntimeError naming a value it does not know.
GlDevice parseGlDevice(const std::string& name);
const char* glDeviceName(GlDevice device);

// One display a renderer tries: an EGL device (its position in eglQueryDevicesEXT's list) or
// Mesa's surfaceless platform.
struct DisplayCandidate {
  enum class Kind { Device, Surfaceless };
  Kind kind = Kind::Device;
  int deviceIndex = -1;  // Kind::Device only
  bool operator==(const DisplayCandidate& o) const { return kind == o.kind && deviceIndex == o.deviceIndex; }
};
// The order in which a renderer tries displays, from what EGL lists: deviceIsSoftware[i] is
// whether device i advertises EGL_MESA_device_software; hasSurfaceless whether the client
// offers EGL_MESA_platform_surfaceless. The rules are at OffscreenRenderer.
std::vector<DisplayCandidate> displayOrder(const std::vector<bool>& deviceIsSoftware, bool hasSurfaceless,
                                           GlDevice device);

// One EGL context per renderer, rendering into its own framebuffer. The EGL display is the
// first of these that initialises (deviceDescription() says which one was taken). With
// GlDevice::Cpu (the default):
//  1. an EGL device whose extensions contain EGL_MESA_device_software: Mesa's llvmpipe, a CPU
//     rasteriser. Preferred so images are bit-identical wherever the Mesa version is the
//     same; on the project's machines this is the one used.
//  2. Mesa's surfaceless platform. Mesa picks its driver itself: a GPU's hardware driver when
//     a DRM render node with a Mesa driver exists, else llvmpipe.
//  3. any other EGL device, in the order EGL lists them: a hardware GPU (e.g. NVIDIA's EGL
//     through libglvnd). Its images may differ from llvmpipe's (rasterisation and rounding).
// With GlDevice::Gpu: only 3 (the surfaceless platform is not tried: it may fall back to
// llvmpipe without saying so).
// Several renderers may exist at once and one after another; each makes its context current
// on every call. Use a renderer from one thread at a time.
class OffscreenRenderer {
 public:
  // Creates the EGL display/context and the framebuffers. Throws RuntimeError with the EGL/GL
  // error, or for a sample count or shadow map size the driver does not offer.
  explicit OffscreenRenderer(int width, int height, const Looks& looks = Looks{}, GlDevice device = GlDevice::Cpu);
  ~OffscreenRenderer();
  OffscreenRenderer(const OffscreenRenderer&) = delete;
  OffscreenRenderer& operator=(const OffscreenRenderer&) = delete;

  // Uploads a mesh; returns a handle valid until freeMesh. Handles are never reused, so a
  // freed handle stays invalid (each costs about 20 bytes of CPU memory for the renderer's life:
  // re-mesh with updateMesh, not free + upload).
  int uploadMesh(const TriangleMesh& mesh);
  // Replaces the vertex and index buffers of a live handle with `mesh` (any size; the old
  // storage is released). For surfaces re-meshed every frame. Throws RuntimeError for an
  // invalid or freed handle, or an invalid mesh (then the handle keeps its old mesh).
  void updateMesh(int handle, const TriangleMesh& mesh);
  // Releases the handle's GL buffers and vertex array. The handle becomes invalid: drawMesh,
  // updateMesh and freeMesh with it throw RuntimeError.
  void freeMesh(int handle);
  MeshStats meshStats() const;

  // "EGL <platform or device, which one> | GL_RENDERER <string>", e.g. "EGL device 0
  // (EGL_MESA_device_software) | GL_RENDERER llvmpipe (LLVM 15.0.6, 256 bits)", for
  // report.json and --help.
  const std::string& deviceDescription() const;

  // Starts a frame with a camera and a background. `clip`: see ClipRange and clipRangeFor.
  // The draw calls until endFrame are recorded and run in endFrame (the shadow map needs every
  // mesh before anything is lit), so a mesh is drawn as its handle holds it at endFrame.
  void beginFrame(const Camera& camera, const Background& background, const ClipRange& clip = ClipRange{});
  // A plain background of one colour.
  void beginFrame(const Camera& camera, const Color& background, const ClipRange& clip = ClipRange{});
  // A square ground plane at height y, centred under (cx, cz), half extent in metres, normal +y;
  // a 16 x 16 checkerboard whose dark cells are 80% of `color`. Drawn with a small depth
  // offset so bodies resting on it at the same height are not hidden by it.
  void drawGround(double y, double cx, double cz, double halfExtent, const Color& color);
  // Draws an uploaded mesh with a model matrix (rest frame -> world). Normals are transformed
  // by the inverse transpose of its 3x3 block. For a rigid body whose mesh was built around its
  // rest-pose centre of mass c0, with current rotation R and centre c: model = [R | c - R*c0].
  // Lighting: one directional light (lightDirection()) plus ambient, normalised Blinn-Phong with
  // `roughness` (see kDefaultRoughness), shadows from Looks, gamma 2.2.
  void drawMesh(int handle, const Mat4f& model, const Color& color, float roughness = kDefaultRoughness);
  // Draws Gaussian splats (lit by their normal, or unlit without one) after every mesh of the frame: sorted
  // back to front by their centre's depth (ties by order of the calls, then of the list) and
  // blended over what is drawn ("over", premultiplied alpha); meshes and the ground hide them
  // (depth test) but they do not hide each other or cast shadows. Not counted in meshSamples.
  // Throws RuntimeError for a non-finite centre, a covariance that is not symmetric positive
  // definite, a colour or opacity out of range, or a normal neither zero nor unit, naming the splat.
  void drawSplats(const std::vector<Splat>& splats);
  // Draws the frame (shadow map, background, ground, meshes), resolves the samples and reads it
  // back (top row first), with Image::meshSamples.
  Image endFrame();
  const Looks& looks() const;

  int width() const;
  int height() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Writes an RGBA image as PNG atomically (temporary file, then rename): a failed
// write leaves no partial file. Throws RuntimeError naming the path.
void writePng(const std::string& path, const Image& image);

}  // namespace physketch::render
