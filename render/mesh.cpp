#include "render/mesh.h"

#include <charconv>
#include <cstdio>

#include "core/atomic_file.h"
#include "core/error.h"

namespace physketch::render {
namespace {

// std::to_chars gives the shortest text that reads back to the same float and, unlike
// printf, ignores the C locale (a "," decimal separator would corrupt the OBJ).
void appendFloat(std::string& out, float v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v);
  out.append(buf, r.ptr);
}

void appendVec(std::string& out, const char* tag, const Vec3f& v) {
  out += tag;
  for (int c = 0; c < 3; ++c) {
    out += ' ';
    appendFloat(out, v[c]);
  }
  out += '\n';
}

}  // namespace

double enclosedVolume(const TriangleMesh& mesh) {
  double v = 0.0;
  for (std::size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
    const Vec3 p0 = mesh.positions[mesh.indices[t]].cast<double>();
    const Vec3 p1 = mesh.positions[mesh.indices[t + 1]].cast<double>();
    const Vec3 p2 = mesh.positions[mesh.indices[t + 2]].cast<double>();
    v += p0.dot(p1.cross(p2)) / 6.0;
  }
  return v;
}

void writeObj(const std::string& path, const TriangleMesh& mesh) {
  const std::size_t n = mesh.positions.size();
  if (!mesh.normals.empty() && mesh.normals.size() != n) {
    throw RuntimeError(path + ": mesh has " + std::to_string(mesh.normals.size()) + " normals for " +
                       std::to_string(n) + " positions");
  }
  if (mesh.indices.size() % 3 != 0) {
    throw RuntimeError(path + ": mesh index count " + std::to_string(mesh.indices.size()) +
                       " is not a multiple of 3");
  }
  for (std::uint32_t i : mesh.indices) {
    if (i >= n) {
      throw RuntimeError(path + ": mesh index " + std::to_string(i) + " out of range (" + std::to_string(n) +
                         " vertices)");
    }
  }

  // Format the whole file in memory (a few MB at most), then one fwrite.
  std::string text = "# physketch mesh: " + std::to_string(n) + " vertices, " +
                     std::to_string(mesh.triangleCount()) + " triangles, units m\n";
  text.reserve(text.size() + n * 2 * 40 + mesh.indices.size() * 12);
  for (const Vec3f& p : mesh.positions) appendVec(text, "v", p);
  for (const Vec3f& nm : mesh.normals) appendVec(text, "vn", nm);
  const bool withNormals = !mesh.normals.empty();
  for (std::size_t t = 0; t < mesh.indices.size(); t += 3) {
    text += 'f';
    for (int c = 0; c < 3; ++c) {
      const std::string idx = std::to_string(mesh.indices[t + c] + 1u);  // OBJ indices are 1-based
      text += ' ';
      text += idx;
      if (withNormals) {
        text += "//";
        text += idx;
      }
    }
    text += '\n';
  }

  AtomicFile out(path);
  if (std::fwrite(text.data(), 1, text.size(), out.file()) != text.size()) out.fail("write failed");
  out.commit();
}

}  // namespace physketch::render
