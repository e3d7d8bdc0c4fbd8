// Collider meshes (sketch::readTriangleSoup): open and closed files read, closed ones
// oriented outward (signed volume computed here from the triangles), bad files refused
// with an InputError that names the file.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>

#include "core/error.h"
#include "sketch/mesh_stamp.h"

using namespace physketch;
using namespace physketch::sketch;

namespace {

namespace fs = std::filesystem;

const std::string kMeshes = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/meshes/";

class TempDir {
 public:
  TempDir() : dir_(fs::temp_directory_path() / ("physketch_collider_mesh_" + std::to_string(::getpid()))) {
    fs::create_directories(dir_);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  std::string write(const std::string& name, const std::string& text) const {
    const fs::path p = dir_ / name;
    std::ofstream(p, std::ios::binary) << text;
    return p.string();
  }

 private:
  fs::path dir_;
};

// Signed volume by the divergence theorem: sum of det(a, b, c) / 6 over the triangles.
double signedVolume(const TriangleSoup& s) {
  double v = 0;
  for (const auto& t : s.triangles)
    v += s.vertices[t[0]].dot(s.vertices[t[1]].cross(s.vertices[t[2]])) / 6;
  return v;
}

// Reads `path` expecting an InputError for the whole file; returns its message.
std::string readError(const std::string& path, std::size_t maxTriangles = kMaxColliderTriangles) {
  try {
    readTriangleSoup(path, maxTriangles);
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), path);
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << "the message names the file";
    return e.reason();
  }
  ADD_FAILURE() << "expected an InputError for " << path;
  return "";
}

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

const char* kCubeVertices =
    "v -0.5 -0.5 -0.5\nv 0.5 -0.5 -0.5\nv 0.5 0.5 -0.5\nv -0.5 0.5 -0.5\n"
    "v -0.5 -0.5 0.5\nv 0.5 -0.5 0.5\nv 0.5 0.5 0.5\nv -0.5 0.5 0.5\n";

}  // namespace

// The unit cube in all three formats: closed, 12 triangles, volume +1 (outward).
TEST(ColliderMesh, ClosedCubeReadsOutwardInEveryFormat) {
  for (const char* name : {"cube.obj", "cube.off", "cube.ply"}) {
    const TriangleSoup s = readTriangleSoup(kMeshes + name);
    EXPECT_TRUE(s.closed) << name;
    EXPECT_EQ(s.triangles.size(), 12u) << name;
    EXPECT_NEAR(signedVolume(s), 1.0, 1e-12) << name;
  }
}

// Wound inward, as quads: still a solid, triangulated and turned outward.
TEST(ColliderMesh, InwardQuadCubeIsTurnedOutward) {
  TempDir dir;
  const std::string path = dir.write("inward.obj", std::string(kCubeVertices) +
                                                       "f 1 2 3 4\nf 5 8 7 6\nf 1 5 6 2\nf 4 3 7 8\nf 1 4 8 5\nf 2 6 7 3\n");
  const TriangleSoup s = readTriangleSoup(path);
  EXPECT_TRUE(s.closed);
  EXPECT_EQ(s.triangles.size(), 12u);
  EXPECT_NEAR(signedVolume(s), 1.0, 1e-12);
}

// Open, non-manifold and sheet meshes are colliders too (a stamp refuses them): two-sided,
// in the file's winding, polygons split as fans.
TEST(ColliderMesh, OpenAndNonManifoldMeshesReadAsSheets) {
  const TriangleSoup open = readTriangleSoup(kMeshes + "cube_open.obj");
  EXPECT_FALSE(open.closed);
  EXPECT_EQ(open.triangles.size(), 11u);
  const TriangleSoup nonManifold = readTriangleSoup(kMeshes + "nonmanifold.obj");
  EXPECT_FALSE(nonManifold.closed);
  TempDir dir;
  const TriangleSoup quad = readTriangleSoup(dir.write("quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"));
  EXPECT_FALSE(quad.closed);
  ASSERT_EQ(quad.triangles.size(), 2u);
  EXPECT_EQ(quad.triangles[0], (std::array<std::int32_t, 3>{0, 1, 2}));
  EXPECT_EQ(quad.triangles[1], (std::array<std::int32_t, 3>{0, 2, 3}));
  // A face that repeats a vertex has no area and is dropped; the rest stays.
  const TriangleSoup sliver = readTriangleSoup(dir.write("sliver.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\nf 1 1 2\n"));
  EXPECT_EQ(sliver.triangles.size(), 1u);
}

TEST(ColliderMesh, BadFilesAreErrorsNamingTheFile) {
  TempDir dir;
  EXPECT_TRUE(contains(readError(dir.write("gone.obj", "") + ".missing.obj"), "does not exist"));
  EXPECT_TRUE(contains(readError(dir.write("empty.obj", "")), "empty"));
  EXPECT_TRUE(contains(readError(dir.write("mesh.stl", "solid\n")), "unknown mesh format"));
  EXPECT_TRUE(contains(readError(dir.write("nofaces.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n")), "cannot read"));
  EXPECT_TRUE(contains(readError(dir.write("index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")), "cannot read"));
  EXPECT_TRUE(contains(readError(dir.write("index.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")), "cannot read"));
  EXPECT_TRUE(contains(readError(dir.write("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")), "cannot read"));
  EXPECT_TRUE(contains(readError(dir.write("two.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n")), "a face needs 3"));
  EXPECT_TRUE(contains(readError(dir.write("degenerate.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 1 2\nf 2 3 3\n")),
                       "no triangle is left"));
  // Binary PLY stores the bits, so its reader takes a NaN and our own check names the vertex.
  std::string ply = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
  const float xyz[3][3] = {{0, 0, 0}, {1, std::numeric_limits<float>::quiet_NaN(), 0}, {0, 1, 0}};
  const std::int32_t face[3] = {0, 1, 2};
  ply.append(reinterpret_cast<const char*>(xyz), sizeof xyz);  // x86: little-endian as declared
  ply.append(1, '\3').append(reinterpret_cast<const char*>(face), sizeof face);
  EXPECT_EQ(readError(dir.write("nan.ply", ply)), "vertex 2 has a non-finite coordinate");
  const std::string many = readError(kMeshes + "cube.obj", 11);
  EXPECT_TRUE(contains(many, "12 triangles")) << many;
  EXPECT_TRUE(contains(many, "limit is 11")) << many;
}
