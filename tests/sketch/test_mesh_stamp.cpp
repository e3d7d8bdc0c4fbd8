// Mesh stamps (sketch/mesh_stamp.h): loading checks and the voxelization of closed
// meshes into the 151^3 grid against closed-form answers (boxes, a tetrahedron's volume).
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <vector>

#include "core/error.h"
#include "sketch/mesh_stamp.h"

using namespace physketch;
using namespace physketch::sketch;

namespace {

namespace fs = std::filesystem;

const GridMapping kMap(Vec3(0.0, 0.5, 0.0), 1.0);  // 1 m workspace, h = 1/151 m
const std::string kMeshes = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/meshes/";

// A scratch folder for meshes written by the tests, removed afterwards.
class TempDir {
 public:
  TempDir() : dir_(fs::temp_directory_path() / ("physketch_mesh_stamp_" + std::to_string(::getpid()))) {
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

// The 12 outward triangles of a cube over its 8 corners numbered from 1 as in
// scenes/meshes/cube.obj: (-,-,-) (+,-,-) (+,+,-) (-,+,-), then the same four at +z.
constexpr int kCubeTris[12][3] = {{1, 3, 2}, {1, 4, 3}, {5, 6, 7}, {5, 7, 8}, {1, 2, 6}, {1, 6, 5},
                                  {4, 8, 7}, {4, 7, 3}, {1, 5, 8}, {1, 8, 4}, {2, 3, 7}, {2, 7, 6}};

struct Box {
  Vec3 centre;
  double half;
};

// An OBJ with one closed cube per box, all wound outward.
std::string cubesObj(const std::vector<Box>& boxes) {
  std::ostringstream s;
  s.precision(17);
  const int sx[8] = {-1, 1, 1, -1, -1, 1, 1, -1}, sy[8] = {-1, -1, 1, 1, -1, -1, 1, 1};
  for (const Box& b : boxes)
    for (int i = 0; i < 8; ++i)
      s << "v " << b.centre.x() + sx[i] * b.half << ' ' << b.centre.y() + sy[i] * b.half << ' '
        << b.centre.z() + (i < 4 ? -1 : 1) * b.half << '\n';
  for (std::size_t k = 0; k < boxes.size(); ++k)
    for (const auto& t : kCubeTris)
      s << "f " << t[0] + 8 * k << ' ' << t[1] + 8 * k << ' ' << t[2] + 8 * k << '\n';
  return s.str();
}

// Loads `path`, expecting an InputError for the whole file; returns its message.
std::string loadError(const std::string& path) {
  try {
    StampMesh::load(path);
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), path);
    EXPECT_EQ(e.line(), 0);
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << "the message names the file";
    return e.reason();
  }
  ADD_FAILURE() << "expected an InputError for " << path;
  return "";
}

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

// Every cell of the grid in z, y, x order, as a 0/1 mask indexed by GridMapping::linear.
std::vector<char> mask(const std::vector<Vec3i>& cells) {
  std::vector<char> m(static_cast<std::size_t>(kGridCells), 0);
  for (const Vec3i& c : cells) m[static_cast<std::size_t>(GridMapping::linear(c))] = 1;
  return m;
}

template <class F>
void forEachCell(F f) {
  for (int z = 0; z < kGridSize; ++z)
    for (int y = 0; y < kGridSize; ++y)
      for (int x = 0; x < kGridSize; ++x) f(Vec3i(x, y, z));
}

}  // namespace

// An axis-aligned unit cube scaled by s and moved by t covers exactly the cells with
// |c - t|_inf <= s/2. s = 20.4 h and t off the lattice keep every face at least 0.03 h
// from every cell-centre plane (asserted), so both sides are exact and must agree cell
// for cell, in the same order. The second case straddles the grid's corner (clipping).
TEST(MeshStamp, AxisAlignedCubeEqualsTheAnalyticBox) {
  const double h = kMap.voxelSize();
  const StampMesh cube = StampMesh::load(kMeshes + "cube.obj");
  const Box cases[] = {{kMap.toWorld(Vec3i(75, 80, 70)) + h * Vec3(0.3, -0.17, 0.11), 10.2 * h},
                       {kMap.toWorld(Vec3i(3, 148, 140)) + h * Vec3(0.21, 0.13, -0.37), 15.3 * h}};
  for (const Box& b : cases) {
    const std::vector<Vec3i> cells = voxelizeMesh(cube, kMap, 2 * b.half, Mat3::Identity(), b.centre);
    std::vector<Vec3i> expected;
    double margin = 1e300;
    forEachCell([&](const Vec3i& cell) {
      const Vec3 d = (kMap.toWorld(cell) - b.centre).cwiseAbs();
      margin = std::min(margin, (d - Vec3::Constant(b.half)).cwiseAbs().minCoeff());
      if (d.maxCoeff() <= b.half) expected.push_back(cell);
    });
    ASSERT_GT(margin, 0.01 * h) << "a cell centre lies on a face: the case is not exact";
    EXPECT_GT(expected.size(), 3000u);
    EXPECT_EQ(cells, expected) << "box at " << b.centre.transpose();
  }
}

// Rotated: the analytic test is |R^T (c - t)|_inf <= s/2. Cells whose centre is within
// 1e-9 m of a face plane (gap below) may go either way after rounding of the placed
// vertices; everywhere else there must be no mismatch at all.
TEST(MeshStamp, RotatedCubeEqualsTheAnalyticRotatedBox) {
  const double h = kMap.voxelSize();
  const StampMesh cube = StampMesh::load(kMeshes + "cube.obj");
  const double s = 25.3 * h;
  const Vec3 t = kMap.toWorld(Vec3i(70, 75, 78)) + h * Vec3(0.31, 0.27, -0.45);
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  const std::vector<char> got = mask(voxelizeMesh(cube, kMap, s, R, t));
  std::size_t inside = 0, mismatches = 0, ambiguous = 0;
  forEachCell([&](const Vec3i& cell) {
    const double gap = (R.transpose() * (kMap.toWorld(cell) - t)).cwiseAbs().maxCoeff() - s / 2;
    const bool in = gap <= 0;
    inside += in;
    if (std::abs(gap) <= 1e-9) {
      ++ambiguous;
      return;
    }
    mismatches += in != (got[static_cast<std::size_t>(GridMapping::linear(cell))] != 0);
  });
  EXPECT_GT(inside, 15000u);
  EXPECT_EQ(mismatches, 0u) << "of " << inside << " inside cells (" << ambiguous << " within 1e-9 of a face)";
}

// A tetrahedron in general position: the cell count approximates V / h^3. The error is a
// sum of partial-cell contributions along the surface, so it is bounded by the number
// of surface cells A / h^2 (about 8.6k here); for a generic placement they mostly cancel,
// and we allow 5 % of A / h^2 (about 430 cells, 1.2 % of the 36.7k-cell volume).
TEST(MeshStamp, TetrahedronCountMatchesItsVolume) {
  const StampMesh tetra = StampMesh::load(kMeshes + "tetra.off");
  EXPECT_EQ(tetra.vertexCount(), 4u);
  EXPECT_EQ(tetra.faceCount(), 4u);
  EXPECT_NEAR(tetra.volume(), 1.0 / 6.0, 1e-15);
  EXPECT_EQ(tetra.boundsMin(), Vec3(0, 0, 0));
  EXPECT_EQ(tetra.boundsMax(), Vec3(1, 1, 1));

  const double h = kMap.voxelSize(), s = 0.4;
  const Mat3 R = Eigen::AngleAxisd(0.4, Vec3(1, -1, 2).normalized()).toRotationMatrix();
  const std::vector<Vec3i> cells = voxelizeMesh(tetra, kMap, s, R, Vec3(0.0123, 0.4871, -0.0311));
  const double volumeCells = s * s * s / 6 / (h * h * h);
  const double surfaceCells = s * s * (1.5 + std::sqrt(3.0) / 2) / (h * h);
  const double error = static_cast<double>(cells.size()) - volumeCells;
  EXPECT_LE(std::abs(error), 0.05 * surfaceCells)
      << cells.size() << " cells vs V/h^3 = " << volumeCells << " (A/h^2 = " << surfaceCells << ")";
  std::printf("[ info     ] tetrahedron: %zu cells, V/h^3 = %.1f, error %.1f = %.2f %% of A/h^2 = %.0f\n",
              cells.size(), volumeCells, error, 100 * error / surfaceCells, surfaceCells);
}

TEST(MeshStamp, ObjOffAndPlyCubesGiveTheSameCells) {
  const Mat3 R = Eigen::AngleAxisd(0.3, Vec3(0, 1, 0)).toRotationMatrix();
  const Vec3 t(0.011, 0.503, 0.021);
  const StampMesh obj = StampMesh::load(kMeshes + "cube.obj");
  const StampMesh off = StampMesh::load(kMeshes + "cube.off");  // quads, triangulated on load
  const StampMesh ply = StampMesh::load(kMeshes + "cube.ply");  // ASCII PLY, quads
  for (const StampMesh* m : {&obj, &off, &ply}) {
    EXPECT_EQ(m->vertexCount(), 8u);
    EXPECT_EQ(m->faceCount(), 12u);
    EXPECT_NEAR(m->volume(), 1.0, 1e-14);
    EXPECT_EQ(m->boundsMin(), Vec3::Constant(-0.5));
    EXPECT_EQ(m->boundsMax(), Vec3::Constant(0.5));
  }
  const std::vector<Vec3i> a = voxelizeMesh(obj, kMap, 0.17, R, t);
  EXPECT_GT(a.size(), 10000u);
  EXPECT_EQ(a, voxelizeMesh(off, kMap, 0.17, R, t));
  EXPECT_EQ(a, voxelizeMesh(ply, kMap, 0.17, R, t));
}

// z-major, then y, then x ascending, i.e. strictly increasing GridMapping::linear (which
// also proves there are no duplicates); only cells of the grid; the same on a second call.
TEST(MeshStamp, OutputIsSortedUniqueInsideTheGridAndRepeatable) {
  const StampMesh cube = StampMesh::load(kMeshes + "cube.obj");
  const Mat3 R = Eigen::AngleAxisd(0.9, Vec3(3, -1, 2).normalized()).toRotationMatrix();
  const Vec3 nearCorner(-0.47, 0.03, 0.46);  // the rotated cube pokes out of three faces of the workspace
  const std::vector<Vec3i> cells = voxelizeMesh(cube, kMap, 0.21, R, nearCorner);
  ASSERT_GT(cells.size(), 1000u);
  for (const Vec3i& c : cells) ASSERT_TRUE(GridMapping::inGrid(c)) << c.transpose();
  for (std::size_t i = 1; i < cells.size(); ++i)
    ASSERT_LT(GridMapping::linear(cells[i - 1]), GridMapping::linear(cells[i])) << "at " << i;
  EXPECT_EQ(cells, voxelizeMesh(cube, kMap, 0.21, R, nearCorner));
  // Entirely outside the workspace: nothing.
  EXPECT_TRUE(voxelizeMesh(cube, kMap, 0.1, R, Vec3(3, 0.5, 0)).empty());
}

// A cube with a cubic cavity: the cavity's cells are outside (ray parity), its surface
// counts as inside, and the volume subtracts the cavity even though the file winds both
// shells outward (load re-orients the inner one).
TEST(MeshStamp, NestedShellsBoundASolidWithACavity) {
  const TempDir tmp;
  const StampMesh hollow = StampMesh::load(tmp.write("hollow.obj", cubesObj({{Vec3::Zero(), 0.5}, {Vec3::Zero(), 0.25}})));
  EXPECT_NEAR(hollow.volume(), 1.0 - 0.125, 1e-14);
  const double h = kMap.voxelSize(), s = 30.6 * h;  // outer faces 15.3 h, inner 7.65 h from t
  const Vec3 t = kMap.toWorld(Vec3i(75, 75, 75)) + h * Vec3(0.11, 0.23, 0.37);
  std::vector<Vec3i> expected;
  forEachCell([&](const Vec3i& cell) {
    const double d = (kMap.toWorld(cell) - t).cwiseAbs().maxCoeff();
    if (d <= s / 2 && d >= s / 4) expected.push_back(cell);
  });
  EXPECT_EQ(voxelizeMesh(hollow, kMap, s, Mat3::Identity(), t), expected);
}

// Repairs load does on purpose: a mis-wound face, exact duplicate vertices (every
// triangle with its own three, as exporters write along seams) and an upper-case
// extension. Each still stamps the plain cube's cells.
TEST(MeshStamp, BenignDefectsAreRepairedAndStampTheSameCells) {
  const TempDir tmp;
  const Mat3 R = Eigen::AngleAxisd(0.5, Vec3(1, 1, 0).normalized()).toRotationMatrix();
  const Vec3 t(-0.02, 0.47, 0.05);
  const std::vector<Vec3i> reference = voxelizeMesh(StampMesh::load(kMeshes + "cube.obj"), kMap, 0.19, R, t);
  const std::string cube = cubesObj({{Vec3::Zero(), 0.5}});

  std::string flipped = cube;
  flipped.replace(flipped.find("f 1 3 2"), 7, "f 1 2 3");
  std::ostringstream soup;
  std::istringstream lines(cube);
  std::vector<std::string> v;
  int written = 0;
  for (std::string line; std::getline(lines, line);) {
    if (line[0] == 'v') v.push_back(line);
    if (line[0] != 'f') continue;
    int a, b, c;
    std::sscanf(line.c_str(), "f %d %d %d", &a, &b, &c);
    soup << v[a - 1] << '\n' << v[b - 1] << '\n' << v[c - 1] << '\n';
    soup << "f " << written + 1 << ' ' << written + 2 << ' ' << written + 3 << '\n';
    written += 3;
  }
  for (const auto& [name, text] : {std::pair<std::string, std::string>{"flipped.obj", flipped},
                                   {"soup.obj", soup.str()},
                                   {"UPPER.OBJ", cube}}) {
    const StampMesh m = StampMesh::load(tmp.write(name, text));
    EXPECT_EQ(m.faceCount(), 12u) << name;
    EXPECT_EQ(m.vertexCount(), 8u) << name;
    EXPECT_NEAR(m.volume(), 1.0, 1e-14) << name;
    EXPECT_EQ(voxelizeMesh(m, kMap, 0.19, R, t), reference) << name;
  }
}

TEST(MeshStamp, AnOpenMeshIsAnErrorThatCountsItsBorderEdges) {
  const std::string why = loadError(kMeshes + "cube_open.obj");  // one triangle missing
  EXPECT_TRUE(contains(why, "not closed (3 border edges")) << why;
}

TEST(MeshStamp, NonManifoldEdgesAndVerticesAreErrors) {
  const std::string edge = loadError(kMeshes + "nonmanifold.obj");  // two cubes sharing an edge
  EXPECT_TRUE(contains(edge, "not manifold") && contains(edge, "1 edge is shared by more than two faces")) << edge;
  const std::string vertex = loadError(kMeshes + "nonmanifold_vertex.obj");  // two cubes sharing a vertex
  EXPECT_TRUE(contains(vertex, "not manifold") && contains(vertex, "1 vertex joins separate sheets") &&
              contains(vertex, "(1, 1, 1)"))
      << vertex;
}

TEST(MeshStamp, MissingUnknownEmptyAndUnparsableFilesAreErrors) {
  const TempDir tmp;
  EXPECT_TRUE(contains(loadError(kMeshes + "no_such_mesh.obj"), "does not exist"));
  // The extension is checked first, whether or not the file exists.
  EXPECT_TRUE(contains(loadError(tmp.write("cube.stl", "solid x\nendsolid x\n")), "unknown mesh format '.stl'"));
  EXPECT_TRUE(contains(loadError(kMeshes + "cube.gltf"), "unknown mesh format"));
  EXPECT_TRUE(contains(loadError(tmp.write("cube", "v 0 0 0\n")), "no extension"));
  EXPECT_TRUE(contains(loadError(tmp.write("empty.obj", "")), "empty"));
  EXPECT_TRUE(contains(loadError(tmp.write("comments.obj", "# nothing here\n")), "cannot read the file as OBJ"));
  EXPECT_TRUE(contains(loadError(tmp.write("garbage.off", "this is not an OFF file\n")), "cannot read the file as OFF"));
  EXPECT_TRUE(contains(loadError(tmp.write("garbage.ply", "ply\nformat ascii 1.0\nend_of_nothing\n")),
                       "cannot read the file as PLY"));
  EXPECT_FALSE(loadError(tmp.write("index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")).empty());
}

// "nan" and "inf" in any of the three formats: an InputError, never a silent NaN cell test.
TEST(MeshStamp, NonFiniteCoordinatesAreErrors) {
  const TempDir tmp;
  const std::string tetraFaces = "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";
  for (const char* bad : {"nan", "inf", "-inf", "NaN"}) {
    const std::string b = bad;
    const std::string obj = "v 0 0 0\nv 1 0 0\nv 0 " + b + " 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    const std::string off = "OFF\n4 4 0\n0 0 0\n1 0 0\n0 " + b + " 0\n0 0 1\n" + tetraFaces;
    const std::string ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\n"
                            "property double z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n"
                            "0 0 0\n1 0 0\n0 " + b + " 0\n0 0 1\n" + tetraFaces;
    for (const auto& [name, text] : {std::pair<std::string, std::string>{"t.obj", obj}, {"t.off", off}, {"t.ply", ply}}) {
      const std::string why = loadError(tmp.write(name, text));
      EXPECT_TRUE(contains(why, "not a finite number") || contains(why, "non-finite")) << bad << " " << name << ": " << why;
    }
  }
  // Binary PLY stores the bits, so its reader accepts them and load's own check names the
  // vertex. With y = 1 the same bytes are the valid tetrahedron (binary PLY is read).
  for (const float y : {1.0f, std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
    std::string ply = "ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                      "property float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n";
    const float xyz[4][3] = {{0, 0, 0}, {1, 0, 0}, {0, y, 0}, {0, 0, 1}};
    const std::int32_t faces[4][3] = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    ply.append(reinterpret_cast<const char*>(xyz), sizeof xyz);  // x86: little-endian as declared
    for (const auto& f : faces) ply.append(1, '\3').append(reinterpret_cast<const char*>(f), sizeof f);
    const std::string path = tmp.write("binary.ply", ply);
    if (std::isfinite(y))
      EXPECT_NEAR(StampMesh::load(path).volume(), 1.0 / 6.0, 1e-15);
    else
      EXPECT_EQ(loadError(path), "vertex 3 has a non-finite coordinate");
  }
}

TEST(MeshStamp, DegenerateSelfIntersectingAndFlatMeshesAreErrors) {
  const TempDir tmp;
  // All four vertices on a line: closed and manifold, but every face has zero area.
  EXPECT_TRUE(contains(loadError(tmp.write("needle.off", "OFF\n4 4 0\n0 0 0\n1 0 0\n2 0 0\n3 0 0\n"
                                                          "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")),
                       "all 4 faces of the mesh are degenerate"));
  // Two overlapping cubes: each closed and manifold, together self-intersecting.
  EXPECT_TRUE(contains(loadError(tmp.write("overlap.obj", cubesObj({{Vec3::Zero(), 0.5}, {Vec3(0.3, 0.2, 0.1), 0.5}}))),
                       "intersects itself"));
  // A flat tetrahedron (four coplanar vertices): its faces overlap in the plane.
  EXPECT_TRUE(contains(loadError(tmp.write("flat.off", "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n"
                                                        "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")),
                       "intersects itself"));
  // A closed, manifold cube whose front edge 1-2 is split at its midpoint 9 and glued
  // back by the zero-area sliver (1, 2, 9): the faces on either side overlap along 1-9.
  std::string sliver = cubesObj({{Vec3::Zero(), 0.5}}) + "v 0 -0.5 -0.5\nf 1 9 6\nf 9 2 6\nf 1 2 9\n";
  sliver.erase(sliver.find("f 1 2 6\n"), 8);
  const std::string why = loadError(tmp.write("sliver.obj", sliver));
  EXPECT_TRUE(contains(why, "intersects itself") && contains(why, "1 zero-area face")) << why;
  // A face with a repeated vertex, and one with two vertices.
  EXPECT_TRUE(contains(loadError(tmp.write("repeat.obj", cubesObj({{Vec3::Zero(), 0.5}}) + "f 1 1 2\n")),
                       "uses the same vertex"));
  EXPECT_TRUE(contains(loadError(tmp.write("two.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n")),
                       "a face needs 3 or more"));
}

TEST(MeshStamp, BadPlacementsAreCallerErrors) {
  const StampMesh cube = StampMesh::load(kMeshes + "cube.obj");
  const Vec3 t(0, 0.5, 0);
  EXPECT_THROW(voxelizeMesh(cube, kMap, 0.0, Mat3::Identity(), t), RuntimeError);
  EXPECT_THROW(voxelizeMesh(cube, kMap, std::nan(""), Mat3::Identity(), t), RuntimeError);
  EXPECT_THROW(voxelizeMesh(cube, kMap, 0.1, Mat3::Zero(), t), RuntimeError);
  EXPECT_THROW(voxelizeMesh(cube, kMap, 0.1, Mat3::Identity(), Vec3(0, std::nan(""), 0)), RuntimeError);
}
