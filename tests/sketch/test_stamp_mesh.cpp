// Mesh stamps (CGAL point-in-mesh): a closed cube mesh equals the box primitive of the
// same size; OBJ, OFF and PLY agree; open, non-manifold, missing and broken meshes are errors.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <set>

#include "core/error.h"
#include "sketch/stamp_mesh.h"
#include "sketch/voxelize.h"

using namespace physketch;
using namespace physketch::sketch;

namespace {

const GridMapping kMap(Vec3(0.0, 0.5, 0.0), 1.0);
const std::string kMeshes = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/meshes/";

std::set<std::int64_t> asSet(const std::vector<Vec3i>& cells) {
  std::set<std::int64_t> s;
  for (const auto& c : cells) s.insert(GridMapping::linear(c));
  return s;
}

std::string loadError(const std::string& path) {
  try {
    StampMesh::load(path);
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), path);
    return e.what();
  }
  ADD_FAILURE() << "expected InputError for " << path;
  return "";
}

std::vector<Material> materials() {
  Material m;
  m.name = "wood";
  return {m};
}

}  // namespace

TEST(StampMesh, CubeStampEqualsTheBoxPrimitiveOfTheSameSize) {
  // Sizes off the lattice so no cell centre lies on a face (both tests are then exact).
  for (const char* placement : {"scale=0.1347 at=0.0123,0.4871,-0.0311",
                                "scale=0.2213 rot=1,2,3,37 at=-0.05,0.55,0.04"}) {
    const std::string rot = std::string(placement).find("rot=") != std::string::npos ? " rot=1,2,3,37" : "";
    const double s = std::string(placement).find("0.1347") != std::string::npos ? 0.1347 : 0.2213;
    const std::string at = std::string(placement).find("0.0123") != std::string::npos ? "0.0123 0.4871 -0.0311"
                                                                                         : "-0.05 0.55 0.04";
    const std::string stamp = "physketch-strokes 1\nstamp meshes/cube.obj wood 0 " + std::string(placement) + "\n";
    const std::string box = "physketch-strokes 1\nprimitive box wood 0 " + at + " " + std::to_string(s) + " " +
                            std::to_string(s) + " " + std::to_string(s) + rot + "\n";
    const Sketch a = voxelize(parseStrokes(stamp, PHYSKETCH_SOURCE_DIR "/scenes/x.strokes"), kMap, materials());
    const Sketch b = voxelize(parseStrokes(box, "box.strokes"), kMap, materials());
    EXPECT_GT(a.particles.size(), 1000u);
    EXPECT_EQ(asSet(a.cells), asSet(b.cells)) << placement;
  }
}

TEST(StampMesh, ObjOffAndPlyGiveTheSameCells) {
  const Mat3 R = Eigen::AngleAxisd(0.3, Vec3(0, 1, 0)).toRotationMatrix();
  const auto obj = StampMesh::load(kMeshes + "cube.obj").voxelize(kMap, 0.17, R, Vec3(0.01, 0.5, 0.02));
  const auto off = StampMesh::load(kMeshes + "cube.off").voxelize(kMap, 0.17, R, Vec3(0.01, 0.5, 0.02));
  const auto ply = StampMesh::load(kMeshes + "cube.ply").voxelize(kMap, 0.17, R, Vec3(0.01, 0.5, 0.02));
  EXPECT_EQ(obj, off);
  EXPECT_EQ(obj, ply);
  // Deterministic z, y, x order without duplicates.
  for (std::size_t i = 1; i < obj.size(); ++i)
    ASSERT_LT(GridMapping::linear(obj[i - 1]), GridMapping::linear(obj[i]));
  EXPECT_NEAR(StampMesh::load(kMeshes + "cube.off").volume(), 1.0, 1e-12);
}

TEST(StampMesh, BadMeshesAreErrorsThatSayWhy) {
  EXPECT_NE(loadError(kMeshes + "cube_open.obj").find("not closed (3 border edges)"), std::string::npos);
  EXPECT_NE(loadError(kMeshes + "nonmanifold.obj").find("not manifold"), std::string::npos);
  EXPECT_NE(loadError(kMeshes + "missing.obj").find("cannot open"), std::string::npos);
  EXPECT_NE(loadError(kMeshes + "cube.stl").find("unknown mesh format"), std::string::npos);
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("physketch_stamp_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  {
    std::ofstream f(dir / "nan.obj");
    f << "v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n";
    std::ofstream g(dir / "empty.obj");
    g << "# nothing\n";
    std::ofstream h(dir / "garbage.off");
    h << "this is not an OFF file\n";
  }
  // CGAL's OBJ reader refuses "nan" itself; formats that parse it are caught by the finiteness check.
  const std::string nanError = loadError((dir / "nan.obj").string());
  EXPECT_TRUE(nanError.find("cannot read") != std::string::npos || nanError.find("non-finite") != std::string::npos)
      << nanError;
  EXPECT_FALSE(loadError((dir / "empty.obj").string()).empty());
  EXPECT_FALSE(loadError((dir / "garbage.off").string()).empty());
  fs::remove_all(dir);
}

TEST(StampMesh, AStampRecordWithABadMeshNamesTheStrokeLineAndTheMesh) {
  try {
    voxelize(parseStrokes("physketch-strokes 1\n\nstamp meshes/cube_open.obj wood 0 scale=0.1\n",
                          PHYSKETCH_SOURCE_DIR "/scenes/x.strokes"),
             kMap, materials());
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 3);
    EXPECT_EQ(e.field(), "path");
    EXPECT_NE(std::string(e.what()).find("cube_open.obj: mesh is not closed"), std::string::npos) << e.what();
  }
}
