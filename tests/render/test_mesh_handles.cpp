// Mesh handles of the off-screen renderer: updateMesh replaces a mesh in place, freeMesh
// releases its GL objects and invalidates the handle, meshStats reports what is held, and
// re-meshing in a loop holds no more GL memory than one mesh.
//
// Oracles: byte counts in closed form from the mesh sizes (24 bytes per vertex: position +
// normal as float; 4 per index), images rendered by a fresh renderer, and GL itself: the
// test asks the renderer's context (current on this thread after any renderer call) which
// buffer and vertex-array names exist, so a free that forgot glDelete* is caught even though
// the renderer's own bookkeeping would look right.
#define GL_GLEXT_PROTOTYPES 1
#include <GL/gl.h>
#include <GL/glext.h>
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "core/error.h"
#include "render/renderer.h"
#include "render/voxel_mesh.h"
#include "tests/render/render_test_util.h"

namespace physketch::render {
namespace {

using namespace test;  // NOLINT: shared helpers of the render tests

std::size_t expectedBytes(const TriangleMesh& m) {
  return m.positions.size() * 6 * sizeof(float) + m.indices.size() * sizeof(std::uint32_t);
}

TriangleMesh boxMesh(int a, int b, int c, double h) {
  VoxelMeshOptions opt;
  opt.smoothingSteps = 0;
  return meshVoxels(boxVoxels(a, b, c), h, Vec3::Zero(), opt);
}

// Buffer and vertex-array names that exist in the current GL context. Mesa hands out small
// consecutive names, so scanning the first 8192 sees every one a test can create.
int liveGlNames() {
  int n = 0;
  for (GLuint name = 1; name <= 8192; ++name) n += (glIsBuffer(name) == GL_TRUE) + (glIsVertexArray(name) == GL_TRUE);
  return n;
}

Camera frontCamera() {
  Camera cam;
  cam.eye = Vec3(0.5, 0.4, 0.7);
  cam.target = Vec3(0.05, 0.05, 0.05);
  return cam;
}

Image renderOne(OffscreenRenderer& r, int handle) {
  r.beginFrame(frontCamera(), Color{0.1f, 0.1f, 0.1f});
  r.drawMesh(handle, Mat4f::Identity(), Color{0.8f, 0.3f, 0.2f});
  return r.endFrame();
}

TEST(MeshHandles, StatsReportTheBufferBytesOfLiveMeshes) {
  OffscreenRenderer r(16, 16);
  const TriangleMesh big = boxMesh(3, 2, 1, 0.05), small = boxMesh(1, 1, 1, 0.05);
  ASSERT_NE(expectedBytes(big), expectedBytes(small));
  EXPECT_EQ(r.meshStats().liveMeshes, 0);
  EXPECT_EQ(r.meshStats().gpuBytes, 0u);

  const int a = r.uploadMesh(big);
  EXPECT_EQ(r.meshStats().liveMeshes, 1);
  EXPECT_EQ(r.meshStats().gpuBytes, expectedBytes(big));
  const int b = r.uploadMesh(small);
  EXPECT_EQ(r.meshStats().liveMeshes, 2);
  EXPECT_EQ(r.meshStats().gpuBytes, expectedBytes(big) + expectedBytes(small));

  r.updateMesh(a, small);  // the old, larger storage is released
  EXPECT_EQ(r.meshStats().liveMeshes, 2);
  EXPECT_EQ(r.meshStats().gpuBytes, 2 * expectedBytes(small));
  r.updateMesh(b, TriangleMesh{});  // an empty mesh holds no bytes
  EXPECT_EQ(r.meshStats().gpuBytes, expectedBytes(small));

  r.freeMesh(a);
  EXPECT_EQ(r.meshStats().liveMeshes, 1);
  EXPECT_EQ(r.meshStats().gpuBytes, 0u);
  r.freeMesh(b);
  EXPECT_EQ(r.meshStats().liveMeshes, 0);
}

// After updateMesh the handle draws exactly what a fresh upload of the new mesh draws.
TEST(MeshHandles, UpdatedMeshDrawsLikeAFreshUpload) {
  const TriangleMesh before = boxMesh(2, 2, 2, 0.05), after = boxMesh(4, 1, 3, 0.05);
  OffscreenRenderer r(96, 72);
  const int h = r.uploadMesh(before);
  const Image first = renderOne(r, h);
  r.updateMesh(h, after);
  const Image updated = renderOne(r, h);

  OffscreenRenderer fresh(96, 72);
  const Image reference = renderOne(fresh, fresh.uploadMesh(after));
  EXPECT_EQ(updated.rgba, reference.rgba);
  EXPECT_NE(updated.rgba, first.rgba);  // the two meshes really look different
}

TEST(MeshHandles, InvalidUpdateThrowsAndKeepsTheOldMesh) {
  const TriangleMesh mesh = boxMesh(2, 2, 2, 0.05);
  OffscreenRenderer r(64, 48);
  const int h = r.uploadMesh(mesh);
  const Image before = renderOne(r, h);
  TriangleMesh broken = mesh;
  broken.indices.back() = static_cast<std::uint32_t>(broken.positions.size());  // out of range
  EXPECT_THROW(r.updateMesh(h, broken), RuntimeError);
  broken = mesh;
  broken.normals.pop_back();
  EXPECT_THROW(r.updateMesh(h, broken), RuntimeError);
  EXPECT_EQ(r.meshStats().gpuBytes, expectedBytes(mesh));
  EXPECT_EQ(renderOne(r, h).rgba, before.rgba);
}

TEST(MeshHandles, FreedHandleIsInvalidEverywhere) {
  const TriangleMesh mesh = boxMesh(2, 2, 2, 0.05);
  OffscreenRenderer r(64, 48);
  const int freed = r.uploadMesh(mesh);
  const int kept = r.uploadMesh(mesh);
  const Image reference = renderOne(r, kept);
  r.freeMesh(freed);

  try {
    r.updateMesh(freed, mesh);
    ADD_FAILURE() << "expected RuntimeError";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("freed"), std::string::npos) << e.what();
  }
  EXPECT_THROW(r.freeMesh(freed), RuntimeError);
  EXPECT_THROW(r.freeMesh(-1), RuntimeError);
  EXPECT_THROW(r.updateMesh(99, mesh), RuntimeError);
  r.beginFrame(frontCamera(), Color{0.1f, 0.1f, 0.1f});
  EXPECT_THROW(r.drawMesh(freed, Mat4f::Identity(), Color{1, 1, 1}), RuntimeError);
  r.drawMesh(kept, Mat4f::Identity(), Color{0.8f, 0.3f, 0.2f});  // the other handle is untouched
  EXPECT_EQ(r.endFrame().rgba, reference.rgba);

  // Handles are never reused: a new upload does not revive the freed one.
  const int next = r.uploadMesh(mesh);
  EXPECT_NE(next, freed);
  EXPECT_THROW(r.freeMesh(freed), RuntimeError);
}

// The app's re-meshing loops: a deforming surface updated every step, and a body cut by a
// remove stroke (free the old mesh, upload the new one). Neither may hold more GL objects or
// bytes after 60 steps than after the first.
TEST(MeshHandles, RemeshingInALoopHoldsNoMoreMemory) {
  std::vector<TriangleMesh> shapes;
  for (int n = 1; n <= 6; ++n) shapes.push_back(boxMesh(n, 7 - n, 2, 0.03));

  OffscreenRenderer r(32, 32);
  r.meshStats();  // makes the renderer's context current for liveGlNames
  const int baseNames = liveGlNames();

  const int deforming = r.uploadMesh(shapes[0]);
  int cut = r.uploadMesh(shapes[1]);
  const int namesPerMesh = (liveGlNames() - baseNames) / 2;
  EXPECT_EQ(namesPerMesh, 3);  // vertex buffer, index buffer, vertex array
  for (int step = 0; step < 60; ++step) {
    const TriangleMesh& next = shapes[static_cast<std::size_t>(step) % shapes.size()];
    r.updateMesh(deforming, next);
    r.freeMesh(cut);
    cut = r.uploadMesh(next);
    renderOne(r, deforming);
  }
  const TriangleMesh& last = shapes[59 % shapes.size()];
  EXPECT_EQ(r.meshStats().liveMeshes, 2);
  EXPECT_EQ(r.meshStats().gpuBytes, 2 * expectedBytes(last));
  EXPECT_EQ(liveGlNames(), baseNames + 2 * namesPerMesh);
}

}  // namespace
}  // namespace physketch::render
