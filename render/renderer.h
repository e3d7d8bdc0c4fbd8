// Off-screen OpenGL renderer on EGL (Mesa surfaceless platform: no display, no GPU).
// GL 3.3 core, an FBO with RGBA8 colour and 24-bit depth, Blinn-Phong lighting.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/math.h"
#include "core/scene.h"
#include "render/mesh.h"

namespace physketch::render {

using Color = std::array<float, 3>;  // linear RGB in [0, 1]

struct Image {
  int width = 0, height = 0;
  std::vector<std::uint8_t> rgba;  // width*height*4 bytes, row 0 is the TOP row
};

// Clip planes the renderer uses (m). Scenes are metre-sized, so 1e4:1 keeps 24-bit depth
// precision far below a millimetre at the camera distances used; geometry outside
// [kNearPlane, kFarPlane] from the eye is clipped.
constexpr double kNearPlane = 0.01;
constexpr double kFarPlane = 100.0;

// Camera matrices (right-handed, OpenGL clip conventions): viewMatrix is gluLookAt(eye, target,
// up), projectionMatrix is gluPerspective(fovYDeg, aspect, zNear, zFar). Both throw RuntimeError
// on a degenerate camera (eye == target, up parallel to the view direction, non-finite values).
Mat4f viewMatrix(const Camera& camera);
Mat4f projectionMatrix(const Camera& camera, double aspect, double zNear, double zFar);
// World point -> pixel coordinates (x to the right, y down, pixel centres at +0.5), with the
// same matrices the renderer uses (aspect = width/height). Computed in double.
// Returns false when the point is behind the camera (clip w <= 0).
bool projectToPixel(const Camera& camera, int width, int height, const Vec3& world, Eigen::Vector2d& pixel);

// One EGL context per renderer, rendering into its own framebuffer; the GPU is never used
// (llvmpipe is chosen first, so images are bit-identical wherever the Mesa version is the same).
// Several renderers may exist at once and one after another; each makes its context current
// on every call. Use a renderer from one thread at a time.
class OffscreenRenderer {
 public:
  // Creates the EGL display/context and the framebuffer. Throws RuntimeError with the EGL/GL error.
  OffscreenRenderer(int width, int height);
  ~OffscreenRenderer();
  OffscreenRenderer(const OffscreenRenderer&) = delete;
  OffscreenRenderer& operator=(const OffscreenRenderer&) = delete;

  // Uploads a mesh once; returns a handle valid for the renderer's lifetime.
  int uploadMesh(const TriangleMesh& mesh);

  void beginFrame(const Camera& camera, const Color& background);
  // A square ground plane at height y, centred under (cx, cz), half extent in metres, normal +y;
  // a 16 x 16 checkerboard whose dark cells are 80% of `color`. Drawn with a small depth
  // offset so bodies resting on it at the same height are not hidden by it.
  void drawGround(double y, double cx, double cz, double halfExtent, const Color& color);
  // Draws an uploaded mesh with a model matrix (rest frame -> world). Normals are transformed
  // by the inverse transpose of its 3x3 block. For a rigid body whose mesh was built around its
  // rest-pose centre of mass c0, with current rotation R and centre c: model = [R | c - R*c0].
  // Lighting: one directional light from above plus ambient, Blinn-Phong, gamma 2.2.
  void drawMesh(int handle, const Mat4f& model, const Color& color);
  // Finishes the frame and reads it back (top row first).
  Image endFrame();

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
