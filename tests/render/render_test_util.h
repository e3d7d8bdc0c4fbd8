// Helpers shared by the render tests: voxel boxes, mesh checks (closed and oriented, signed
// volume, bounds), pixels and temporary folders. Header-only, test code only.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "core/math.h"
#include "render/mesh.h"
#include "render/renderer.h"

namespace physketch::render::test {

inline std::vector<Vec3i> boxVoxels(int a, int b, int c) {
  std::vector<Vec3i> v;
  for (int k = 0; k < c; ++k)
    for (int j = 0; j < b; ++j)
      for (int i = 0; i < a; ++i) v.emplace_back(i, j, k);
  return v;
}

// Closed and consistently oriented: every directed edge (a, b) occurs exactly once and its
// reverse (b, a) exactly once, so every edge is shared by exactly two triangles that agree
// on orientation. Returns a description of the first violation, empty when none.
inline std::string closedManifoldViolation(const TriangleMesh& m) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, int> directed;
  for (std::size_t t = 0; t < m.indices.size(); t += 3) {
    for (int e = 0; e < 3; ++e) {
      const std::uint32_t a = m.indices[t + e], b = m.indices[t + (e + 1) % 3];
      if (a == b) return "degenerate triangle " + std::to_string(t / 3);
      ++directed[{a, b}];
    }
  }
  for (const auto& [edge, count] : directed) {
    if (count != 1) return "directed edge used " + std::to_string(count) + " times";
    if (!directed.count({edge.second, edge.first})) {
      return "edge " + std::to_string(edge.first) + "-" + std::to_string(edge.second) + " has one triangle";
    }
  }
  return "";
}

// Divergence theorem: V = sum over triangles of p0 . (p1 x p2) / 6; positive when the
// triangles are counter-clockwise seen from outside.
inline double signedVolume(const TriangleMesh& m) { return enclosedVolume(m); }

inline Eigen::AlignedBox3d bounds(const TriangleMesh& m) {
  Eigen::AlignedBox3d box;
  for (const Vec3f& p : m.positions) box.extend(p.cast<double>());
  return box;
}

inline bool sameMesh(const TriangleMesh& x, const TriangleMesh& y) {
  return x.indices == y.indices && x.positions == y.positions && x.normals == y.normals;
}

inline std::string tempDir(const std::string& name) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(::testing::TempDir()) /
                       ("physketch_render_" + name + "_" + std::to_string(static_cast<long>(::getpid())));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

inline const std::uint8_t* pixelAt(const Image& img, int x, int y) {
  return img.rgba.data() + (static_cast<std::size_t>(y) * img.width + x) * 4;
}

inline bool samePixel(const std::uint8_t* p, const std::uint8_t* q) { return p[0] == q[0] && p[1] == q[1] && p[2] == q[2]; }

}  // namespace physketch::render::test
