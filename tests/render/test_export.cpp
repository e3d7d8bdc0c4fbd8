// Export files read back by readers written here from the format specs (PLY: Turk's
// "The PLY Polygon File Format"; OBJ: Wavefront's), and .vdb files read back by OpenVDB's own
// io::File. This test TU may include OpenVDB (the render module's headers do not).
#include <gtest/gtest.h>
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/TopologyToLevelSet.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "core/error.h"
#include "render/export.h"
#include "render/fluid_surface.h"
#include "render/voxel_mesh.h"
#include "tests/render/render_test_util.h"

namespace physketch::render {
namespace {

namespace fs = std::filesystem;
using namespace test;  // NOLINT: shared helpers of the render tests

// ---- a minimal PLY reader (binary little-endian only)

struct PlyProperty {
  std::string type, name;
  std::string countType, itemType;  // lists only
};
struct PlyElement {
  std::string name;
  std::size_t count = 0;
  std::vector<PlyProperty> props;
};
struct Ply {
  std::string format;
  std::vector<std::string> comments;
  std::vector<PlyElement> elements;
  std::string body;  // bytes after end_header
};

Ply readPly(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string bytes = ss.str();
  Ply ply;
  const std::string end = "end_header\n";
  const std::size_t headerEnd = bytes.find(end);
  EXPECT_NE(headerEnd, std::string::npos) << path;
  if (headerEnd == std::string::npos) return ply;
  std::istringstream header(bytes.substr(0, headerEnd));
  std::string line;
  std::getline(header, line);
  EXPECT_EQ(line, "ply");
  while (std::getline(header, line)) {
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "format") {
      std::string version;
      ls >> ply.format >> version;
      EXPECT_EQ(version, "1.0");
    } else if (word == "comment") {
      ply.comments.push_back(line.substr(8));
    } else if (word == "element") {
      PlyElement e;
      ls >> e.name >> e.count;
      ply.elements.push_back(e);
    } else if (word == "property") {
      PlyProperty p;
      ls >> p.type;
      if (p.type == "list") ls >> p.countType >> p.itemType;
      ls >> p.name;
      ply.elements.back().props.push_back(p);
    } else {
      ADD_FAILURE() << "unexpected header line '" << line << "'";
    }
  }
  ply.body = bytes.substr(headerEnd + end.size());
  return ply;
}

template <class T>
T readAt(const std::string& body, std::size_t& at) {
  T v;
  EXPECT_LE(at + sizeof(T), body.size());
  std::memcpy(&v, body.data() + at, sizeof(T));  // little-endian host (x86, ARM Linux)
  at += sizeof(T);
  return v;
}

std::string propertyList(const PlyElement& e) {
  std::string s;
  for (const PlyProperty& p : e.props) s += (p.type == "list" ? "list " + p.countType + " " + p.itemType : p.type) + " " + p.name + ";";
  return s;
}

// ---- particles

TEST(ExportParticles, BinaryPlyReadsBackWithEveryValue) {
  ParticleCloud c;
  c.materials = {"wood", "jelly\nx"};  // a newline in a name must not break the header
  for (int i = 0; i < 5; ++i) {
    c.position.emplace_back(0.1f * i, -0.25f + i, 1e-3f * i);
    c.velocity.emplace_back(-1.5f * i, 2.0f, 0.125f);
    c.body.push_back(i == 4 ? -1 : i / 2);
    c.material.push_back(i % 2);
    c.stroke.push_back(100 + i);
  }
  const std::string dir = tempDir("export_particles");
  const std::string path = dir + "/p.ply";
  writeParticlesPly(path, c);
  const Ply ply = readPly(path);
  EXPECT_EQ(ply.format, "binary_little_endian");
  ASSERT_EQ(ply.elements.size(), 1u);
  EXPECT_EQ(ply.elements[0].name, "vertex");
  EXPECT_EQ(ply.elements[0].count, 5u);
  EXPECT_EQ(propertyList(ply.elements[0]),
            "float x;float y;float z;float vx;float vy;float vz;int body;int material;int stroke;");
  EXPECT_NE(std::find(ply.comments.begin(), ply.comments.end(), "material 0 wood"), ply.comments.end());
  EXPECT_NE(std::find(ply.comments.begin(), ply.comments.end(), "material 1 jelly x"), ply.comments.end());
  ASSERT_EQ(ply.body.size(), 5u * 36u);  // exactly the records, nothing after
  std::size_t at = 0;
  for (std::size_t i = 0; i < 5; ++i) {
    for (int k = 0; k < 3; ++k) EXPECT_EQ(readAt<float>(ply.body, at), c.position[i][k]);
    for (int k = 0; k < 3; ++k) EXPECT_EQ(readAt<float>(ply.body, at), c.velocity[i][k]);
    EXPECT_EQ(readAt<std::int32_t>(ply.body, at), c.body[i]);
    EXPECT_EQ(readAt<std::int32_t>(ply.body, at), c.material[i]);
    EXPECT_EQ(readAt<std::int32_t>(ply.body, at), c.stroke[i]);
  }
  c.stroke.pop_back();
  EXPECT_THROW(writeParticlesPly(dir + "/bad.ply", c), RuntimeError);
  EXPECT_FALSE(fs::exists(dir + "/bad.ply"));
  EXPECT_THROW(writeParticlesPly(dir + "/no/such/dir/p.ply", ParticleCloud{}), RuntimeError);
  fs::remove_all(dir);
}

// ---- body meshes

std::vector<MaterialMesh> twoPartBody() {
  VoxelMeshOptions opt;
  opt.smoothingSteps = 0;
  std::vector<MaterialMesh> parts(2);
  parts[0] = {1, meshVoxels(boxVoxels(3, 2, 2), 0.1, Vec3::Zero(), opt)};
  parts[1] = {0, meshVoxels({Vec3i(5, 0, 0)}, 0.1, Vec3::Zero(), opt)};
  return parts;
}

const std::vector<ExportMaterial> kMaterials = {{"stone", {0.5f, 0.5f, 0.5f}, 0.5}, {"red wood", {0.9f, 0.2f, 0.1f}, 0.3}};

TEST(ExportMesh, ObjHasEveryVertexNormalAndFaceWithItsMaterial) {
  const std::vector<MaterialMesh> parts = twoPartBody();
  const std::string dir = tempDir("export_obj");
  writeBodyObj(dir + "/b.obj", "chair #2", parts, kMaterials, "../materials.mtl");
  std::ifstream in(dir + "/b.obj");
  std::string line, material, object, mtllib;
  std::vector<Vec3f> v;
  std::size_t vn = 0;
  std::map<std::string, std::vector<std::uint32_t>> faces;  // material -> 0-based indices
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::string tag;
    ls >> tag;
    if (tag == "v") {
      Vec3f p;
      ls >> p.x() >> p.y() >> p.z();
      v.push_back(p);
    } else if (tag == "vn") {
      ++vn;
    } else if (tag == "usemtl") {
      ls >> material;
    } else if (tag == "o") {
      ls >> object;
    } else if (tag == "mtllib") {
      ls >> mtllib;
    } else if (tag == "f") {
      std::string corner;
      for (int c = 0; c < 3; ++c) {
        ls >> corner;
        const std::size_t slash = corner.find("//");
        ASSERT_NE(slash, std::string::npos) << line;
        EXPECT_EQ(corner.substr(0, slash), corner.substr(slash + 2));  // normal index = vertex index
        faces[material].push_back(static_cast<std::uint32_t>(std::stoul(corner.substr(0, slash)) - 1));
      }
    }
  }
  EXPECT_EQ(object, "chair__2");
  EXPECT_EQ(mtllib, "../materials.mtl");
  const std::size_t n0 = parts[0].mesh.positions.size(), n1 = parts[1].mesh.positions.size();
  EXPECT_EQ(v.size(), n0 + n1);  // the mesh's vertex count
  EXPECT_EQ(vn, n0 + n1);
  for (std::size_t i = 0; i < n0; ++i) EXPECT_EQ(v[i], parts[0].mesh.positions[i]);
  for (std::size_t i = 0; i < n1; ++i) EXPECT_EQ(v[n0 + i], parts[1].mesh.positions[i]);
  ASSERT_EQ(faces.size(), 2u);
  EXPECT_EQ(faces["red_wood"], parts[0].mesh.indices);
  std::vector<std::uint32_t> shifted = parts[1].mesh.indices;
  for (std::uint32_t& i : shifted) i += static_cast<std::uint32_t>(n0);
  EXPECT_EQ(faces["stone"], shifted);
  fs::remove_all(dir);
}

TEST(ExportMesh, PlyHasEveryVertexAndFaceWithItsMaterialIndex) {
  const std::vector<MaterialMesh> parts = twoPartBody();
  const std::string dir = tempDir("export_ply");
  writeBodyPly(dir + "/b.ply", "chair", parts, kMaterials);
  const Ply ply = readPly(dir + "/b.ply");
  EXPECT_EQ(ply.format, "binary_little_endian");
  ASSERT_EQ(ply.elements.size(), 2u);
  const std::size_t n0 = parts[0].mesh.positions.size(), n1 = parts[1].mesh.positions.size();
  const std::size_t t0 = parts[0].mesh.triangleCount(), t1 = parts[1].mesh.triangleCount();
  EXPECT_EQ(ply.elements[0].count, n0 + n1);
  EXPECT_EQ(ply.elements[1].count, t0 + t1);
  EXPECT_EQ(propertyList(ply.elements[0]),
            "float x;float y;float z;float nx;float ny;float nz;uchar red;uchar green;uchar blue;");
  EXPECT_EQ(propertyList(ply.elements[1]), "list uchar uint vertex_indices;ushort material_index;");
  EXPECT_NE(std::find(ply.comments.begin(), ply.comments.end(), "material 1 red wood"), ply.comments.end());
  std::size_t at = 0;
  for (std::size_t i = 0; i < n0 + n1; ++i) {
    const MaterialMesh& part = i < n0 ? parts[0] : parts[1];
    const std::size_t k = i < n0 ? i : i - n0;
    for (int c = 0; c < 3; ++c) EXPECT_EQ(readAt<float>(ply.body, at), part.mesh.positions[k][c]);
    for (int c = 0; c < 3; ++c) EXPECT_EQ(readAt<float>(ply.body, at), part.mesh.normals[k][c]);
    const auto& color = kMaterials[static_cast<std::size_t>(part.material)].color;
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(readAt<std::uint8_t>(ply.body, at), 255.0 * std::pow(color[static_cast<std::size_t>(c)], 1 / 2.2), 0.5);
  }
  for (std::size_t t = 0; t < t0 + t1; ++t) {
    ASSERT_EQ(readAt<std::uint8_t>(ply.body, at), 3);
    const MaterialMesh& part = t < t0 ? parts[0] : parts[1];
    const std::size_t k = t < t0 ? t : t - t0;
    const std::uint32_t base = t < t0 ? 0u : static_cast<std::uint32_t>(n0);
    for (int c = 0; c < 3; ++c) EXPECT_EQ(readAt<std::uint32_t>(ply.body, at), base + part.mesh.indices[3 * k + c]);
    EXPECT_EQ(readAt<std::uint16_t>(ply.body, at), part.material);
  }
  EXPECT_EQ(at, ply.body.size());
  std::vector<MaterialMesh> bad = parts;
  bad[1].material = 7;
  EXPECT_THROW(writeBodyPly(dir + "/bad.ply", "x", bad, kMaterials), RuntimeError);
  EXPECT_THROW(writeBodyObj(dir + "/bad.obj", "x", bad, kMaterials, ""), RuntimeError);
  EXPECT_FALSE(fs::exists(dir + "/bad.ply"));
  fs::remove_all(dir);
}

TEST(ExportMesh, FileSafeNames) {
  EXPECT_EQ(fileSafeName("stroke 3"), "stroke_3");
  EXPECT_EQ(fileSafeName("chair #2"), "chair__2");
  EXPECT_EQ(fileSafeName(""), "_");
  EXPECT_EQ(fileSafeName(".."), "_..");
  EXPECT_EQ(fileSafeName("a/b\\c"), "a_b_c");
  EXPECT_EQ(fileSafeName("Stein-1.v2"), "Stein-1.v2");
}

// ---- .vdb

// Written grids read back with OpenVDB's io::File: names, class, metadata, and the same active
// voxel count and values as a level set the test builds itself from the same cells with the
// same OpenVDB call; the world transform puts the rotated box's centre inside (negative
// distance) and a point beside it outside.
TEST(ExportVdb, LevelSetsReadBackWithOpenVdb) {
  openvdb::initialize();
  const double h = 0.02;
  const Vec3 origin(0.1, 0.2, 0.3);
  LevelSetGrid rigid;
  rigid.name = "0000_box/stone";
  rigid.material = "stone";
  rigid.cells = boxVoxels(8, 4, 6);
  const Eigen::Matrix3d rot = Eigen::AngleAxisd(0.6, Vec3(0, 1, 0)).toRotationMatrix();
  rigid.model.topLeftCorner<3, 3>() = rot;
  rigid.model.topRightCorner<3, 1>() = Vec3(1.0, 0.5, -0.5);
  LevelSetGrid soft;
  soft.name = "0001_blob/jelly";
  soft.material = "jelly";
  soft.cells = boxVoxels(5, 5, 5);
  soft.surface.closingSteps = 1;
  soft.smoothIterations = 2;
  LevelSetGrid empty;
  empty.name = "0002_gone/stone";

  const std::string dir = tempDir("export_vdb");
  const std::string path = dir + "/f.vdb";
  const std::vector<std::uint64_t> active = writeLevelSetsVdb(path, {rigid, soft, empty}, h, origin);
  ASSERT_EQ(active.size(), 3u);

  openvdb::io::File file(path);
  file.open();
  openvdb::GridPtrVecPtr grids = file.getGrids();
  file.close();
  ASSERT_EQ(grids->size(), 3u);
  auto box = openvdb::gridPtrCast<openvdb::FloatGrid>((*grids)[0]);
  ASSERT_TRUE(box);
  EXPECT_EQ(box->getName(), rigid.name);
  EXPECT_EQ(box->getGridClass(), openvdb::GRID_LEVEL_SET);
  EXPECT_EQ(box->metaValue<std::string>("material"), "stone");
  EXPECT_EQ(box->activeVoxelCount(), active[0]);

  // The same level set, built here: same topology, same values.
  openvdb::BoolGrid::Ptr mask = openvdb::BoolGrid::create(false);
  mask->setTransform(openvdb::math::Transform::createLinearTransform(h));  // distances in metres
  for (const Vec3i& c : rigid.cells) mask->tree().setValueOn(openvdb::Coord(c.x(), c.y(), c.z()), true);
  openvdb::FloatGrid::Ptr want = openvdb::tools::topologyToLevelSet(*mask, rigid.surface.halfWidth,
                                                                    rigid.surface.closingSteps, 0,
                                                                    rigid.surface.smoothingSteps);
  EXPECT_EQ(box->activeVoxelCount(), want->activeVoxelCount());
  for (auto it = want->cbeginValueOn(); it; ++it) {
    ASSERT_EQ(box->tree().getValue(it.getCoord()), *it) << it.getCoord();
  }

  // Where it is in the world: index (3.5, 1.5, 2.5) is the box's centre.
  const Vec3 restCentre = origin + h * Vec3(3.5, 1.5, 2.5);
  const Vec3 worldCentre = rot * restCentre + rigid.model.topRightCorner<3, 1>();
  const openvdb::Vec3d idx = box->transform().worldToIndex(openvdb::Vec3d(worldCentre.x(), worldCentre.y(), worldCentre.z()));
  EXPECT_NEAR(idx.x(), 3.5, 1e-6);
  EXPECT_NEAR(idx.y(), 1.5, 1e-6);
  EXPECT_NEAR(idx.z(), 2.5, 1e-6);
  EXPECT_LT(box->tree().getValue(openvdb::Coord(3, 1, 2)), 0.0f);
  EXPECT_GT(box->tree().getValue(openvdb::Coord(-3, 1, 2)), 0.0f);  // beside the box: outside
  EXPECT_NEAR(box->transform().voxelSize().x(), h, 1e-12);

  auto blob = openvdb::gridPtrCast<openvdb::FloatGrid>((*grids)[1]);
  ASSERT_TRUE(blob);
  EXPECT_EQ(blob->getName(), soft.name);
  EXPECT_EQ(blob->activeVoxelCount(), active[1]);
  EXPECT_GT(active[1], 0u);
  EXPECT_LT(blob->tree().getValue(openvdb::Coord(2, 2, 2)), 0.0f);
  auto gone = openvdb::gridPtrCast<openvdb::FloatGrid>((*grids)[2]);
  ASSERT_TRUE(gone);
  EXPECT_EQ(gone->activeVoxelCount(), 0u);
  EXPECT_EQ(active[2], 0u);

  // Bad input: a duplicate name, a singular model; nothing is written.
  EXPECT_THROW(writeLevelSetsVdb(dir + "/dup.vdb", {rigid, rigid}, h, origin), RuntimeError);
  LevelSetGrid flat = rigid;
  flat.model(1, 1) = 0.0;
  flat.model.row(1).setZero();
  EXPECT_THROW(writeLevelSetsVdb(dir + "/flat.vdb", {flat}, h, origin), RuntimeError);
  EXPECT_THROW(writeLevelSetsVdb(dir + "/no/such/f.vdb", {rigid}, h, origin), RuntimeError);
  std::vector<std::string> left;
  for (const auto& e : fs::directory_iterator(dir)) left.push_back(e.path().filename().string());
  EXPECT_EQ(left, std::vector<std::string>{"f.vdb"});
  fs::remove_all(dir);
}

// A fluid's surface goes out as the level set of the mesh the frames show (meshToLevelSet on
// the same lattice): read back, the distance is within 0.35 voxels of 0 at every 7th vertex of
// the mesh (measured 0.21: the level set's voxels are h, the mesh's h/2, and trilinear sampling
// of a distance field rounds the block's curved edges by about that much; a shifted or scaled
// transform is off by whole voxels), negative at the block's centre, positive a spacing outside. A mesh grid with cells or a pose is refused.
TEST(ExportVdb, AFluidMeshBecomesItsLevelSet) {
  openvdb::initialize();
  const double h = 0.02;
  const Vec3 origin(0.1, 0.2, 0.3);
  std::vector<Vec3> particles;
  for (int k = 0; k < 8; ++k)
    for (int j = 0; j < 5; ++j)
      for (int i = 0; i < 8; ++i) particles.push_back(origin + h * Vec3(i, j, k));
  LevelSetGrid water;
  water.name = "0000_pool/water";
  water.material = "water";
  water.mesh = meshFluid(particles, h);
  ASSERT_FALSE(water.mesh.empty());
  const std::string dir = tempDir("export_vdb_fluid");
  const std::string path = dir + "/f.vdb";
  const std::vector<std::uint64_t> active = writeLevelSetsVdb(path, {water}, h, origin);
  openvdb::io::File file(path);
  file.open();
  openvdb::GridPtrVecPtr grids = file.getGrids();
  file.close();
  ASSERT_EQ(grids->size(), 1u);
  auto sdf = openvdb::gridPtrCast<openvdb::FloatGrid>((*grids)[0]);
  ASSERT_TRUE(sdf);
  EXPECT_EQ(sdf->getGridClass(), openvdb::GRID_LEVEL_SET);
  EXPECT_EQ(sdf->activeVoxelCount(), active[0]);
  auto distanceAt = [&](const Vec3& w) {
    const openvdb::Vec3d idx = sdf->transform().worldToIndex(openvdb::Vec3d(w.x(), w.y(), w.z()));
    return openvdb::tools::BoxSampler::sample(sdf->tree(), idx);
  };
  double worst = 0.0;
  for (std::size_t v = 0; v < water.mesh.positions.size(); v += 7)
    worst = std::max(worst, std::abs(double(distanceAt(water.mesh.positions[v].cast<double>()))));
  std::printf("largest |distance| at mesh vertices: %.3f voxels\n", worst / h);
  EXPECT_LT(worst, 0.35 * h);
  EXPECT_LT(distanceAt(origin + h * Vec3(3.5, 2.0, 3.5)), 0.0f);
  EXPECT_GT(distanceAt(origin + h * Vec3(3.5, 5.5, 3.5)), 0.0f);

  LevelSetGrid both = water;
  both.cells = boxVoxels(2, 2, 2);
  EXPECT_THROW(writeLevelSetsVdb(dir + "/both.vdb", {both}, h, origin), RuntimeError);
}

}  // namespace
}  // namespace physketch::render
