#include "render/export.h"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

#include "core/atomic_file.h"
#include "core/error.h"

namespace physketch::render {
namespace {

// std::to_chars: the shortest text that reads back to the same float, whatever the C locale.
void appendFloat(std::string& out, double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof(buf), static_cast<float>(v));
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

// Little-endian bytes of a value (x86 and ARM Linux are little-endian; checked at compile time
// through the byte order GCC reports).
static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "PLY writers assume a little-endian host");
template <class T>
void appendRaw(std::string& out, T v) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &v, sizeof(T));
  out.append(bytes, sizeof(T));
}

void checkParts(const std::string& path, const std::vector<MaterialMesh>& parts,
                const std::vector<ExportMaterial>& materials) {
  for (const MaterialMesh& p : parts) {
    const TriangleMesh& m = p.mesh;
    if (p.material < 0 || p.material >= static_cast<int>(materials.size())) {
      throw RuntimeError(path + ": material index " + std::to_string(p.material) + " out of range");
    }
    if (m.normals.size() != m.positions.size() || m.indices.size() % 3 != 0) {
      throw RuntimeError(path + ": malformed mesh (normals or index count)");
    }
    for (std::uint32_t i : m.indices)
      if (i >= m.positions.size()) throw RuntimeError(path + ": mesh index " + std::to_string(i) + " out of range");
  }
}

void writeAtomically(const std::string& path, const std::string& bytes) {
  AtomicFile out(path);
  if (std::fwrite(bytes.data(), 1, bytes.size(), out.file()) != bytes.size()) out.fail("write failed");
  out.commit();
}

// Header comments carry names; a newline in one would end the comment early.
std::string oneLine(const std::string& s) {
  std::string out = s;
  for (char& c : out)
    if (c == '\n' || c == '\r') c = ' ';
  return out;
}

std::uint8_t encode8(float linear) {
  const double v = std::pow(std::min(std::max(double(linear), 0.0), 1.0), 1.0 / 2.2);
  return static_cast<std::uint8_t>(std::lround(255.0 * v));
}

}  // namespace

std::string fileSafeName(const std::string& name) {
  std::string out;
  for (unsigned char c : name) {
    const bool keep = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '-' ||
                      c == '_' || c == '.';
    out += keep ? static_cast<char>(c) : '_';
  }
  if (out.empty() || out[0] == '.') out.insert(out.begin(), '_');
  return out;
}

void writeBodyObj(const std::string& path, const std::string& object, const std::vector<MaterialMesh>& parts,
                  const std::vector<ExportMaterial>& materials, const std::string& mtllib) {
  checkParts(path, parts, materials);
  std::size_t vertices = 0, triangles = 0;
  for (const MaterialMesh& p : parts) {
    vertices += p.mesh.positions.size();
    triangles += p.mesh.triangleCount();
  }
  std::string text = "# physketch body '" + oneLine(object) + "': " + std::to_string(vertices) + " vertices, " +
                     std::to_string(triangles) + " triangles, units m\n";
  if (!mtllib.empty()) text += "mtllib " + mtllib + "\n";
  text += "o " + fileSafeName(object) + "\n";
  for (const MaterialMesh& p : parts)
    for (const Vec3f& v : p.mesh.positions) appendVec(text, "v", v);
  for (const MaterialMesh& p : parts)
    for (const Vec3f& n : p.mesh.normals) appendVec(text, "vn", n);
  std::size_t base = 1;  // OBJ indices are 1-based and count across the whole file
  for (const MaterialMesh& p : parts) {
    text += "usemtl " + fileSafeName(materials[static_cast<std::size_t>(p.material)].name) + "\n";
    for (std::size_t t = 0; t < p.mesh.indices.size(); t += 3) {
      text += 'f';
      for (int c = 0; c < 3; ++c) {
        const std::string idx = std::to_string(base + p.mesh.indices[t + c]);
        text += ' ';
        text += idx;
        text += "//";
        text += idx;
      }
      text += '\n';
    }
    base += p.mesh.positions.size();
  }
  writeAtomically(path, text);
}

void writeBodyPly(const std::string& path, const std::string& object, const std::vector<MaterialMesh>& parts,
                  const std::vector<ExportMaterial>& materials) {
  checkParts(path, parts, materials);
  if (materials.size() > std::numeric_limits<std::uint16_t>::max()) throw RuntimeError(path + ": too many materials");
  std::size_t vertices = 0, triangles = 0;
  for (const MaterialMesh& p : parts) {
    vertices += p.mesh.positions.size();
    triangles += p.mesh.triangleCount();
  }
  if (vertices > std::numeric_limits<std::uint32_t>::max()) throw RuntimeError(path + ": too many vertices");
  std::string out = "ply\nformat binary_little_endian 1.0\ncomment physketch body '" + oneLine(object) + "', units m\n";
  for (std::size_t i = 0; i < materials.size(); ++i)
    out += "comment material " + std::to_string(i) + " " + oneLine(materials[i].name) + "\n";
  out += "element vertex " + std::to_string(vertices) +
         "\nproperty float x\nproperty float y\nproperty float z\n"
         "property float nx\nproperty float ny\nproperty float nz\n"
         "property uchar red\nproperty uchar green\nproperty uchar blue\n"
         "element face " + std::to_string(triangles) +
         "\nproperty list uchar uint vertex_indices\nproperty ushort material_index\nend_header\n";
  out.reserve(out.size() + vertices * 27 + triangles * 15);
  for (const MaterialMesh& p : parts) {
    const auto& color = materials[static_cast<std::size_t>(p.material)].color;
    for (std::size_t i = 0; i < p.mesh.positions.size(); ++i) {
      for (int c = 0; c < 3; ++c) appendRaw(out, p.mesh.positions[i][c]);
      for (int c = 0; c < 3; ++c) appendRaw(out, p.mesh.normals[i][c]);
      for (int c = 0; c < 3; ++c) appendRaw(out, encode8(color[static_cast<std::size_t>(c)]));
    }
  }
  std::uint32_t base = 0;
  for (const MaterialMesh& p : parts) {
    for (std::size_t t = 0; t < p.mesh.indices.size(); t += 3) {
      appendRaw(out, std::uint8_t{3});
      for (int c = 0; c < 3; ++c) appendRaw(out, static_cast<std::uint32_t>(base + p.mesh.indices[t + c]));
      appendRaw(out, static_cast<std::uint16_t>(p.material));
    }
    base += static_cast<std::uint32_t>(p.mesh.positions.size());
  }
  writeAtomically(path, out);
}

void writeMtl(const std::string& path, const std::vector<ExportMaterial>& materials) {
  std::string text = "# physketch materials: Kd is the linear RGB colour, Ns the Blinn-Phong exponent of the roughness\n";
  for (const ExportMaterial& m : materials) {
    text += "newmtl " + fileSafeName(m.name) + "\nKd";
    for (float c : m.color) {
      text += ' ';
      appendFloat(text, c);
    }
    // Ns = 2 / a^2 - 2, a = roughness^2 (render/renderer.h), with the renderer's lower bound.
    const double r = std::max(m.roughness, 0.1), a = r * r;
    text += "\nNs ";
    appendFloat(text, 2.0 / (a * a) - 2.0);
    text += "\n";
  }
  writeAtomically(path, text);
}

void writeParticlesPly(const std::string& path, const ParticleCloud& cloud) {
  const std::size_t n = cloud.size();
  if (cloud.velocity.size() != n || cloud.body.size() != n || cloud.material.size() != n || cloud.stroke.size() != n) {
    throw RuntimeError(path + ": particle arrays differ in length");
  }
  std::string out = "ply\nformat binary_little_endian 1.0\ncomment physketch particles, units m and m/s\n";
  for (std::size_t i = 0; i < cloud.materials.size(); ++i)
    out += "comment material " + std::to_string(i) + " " + oneLine(cloud.materials[i]) + "\n";
  out += "element vertex " + std::to_string(n) +
         "\nproperty float x\nproperty float y\nproperty float z\n"
         "property float vx\nproperty float vy\nproperty float vz\n"
         "property int body\nproperty int material\nproperty int stroke\nend_header\n";
  out.reserve(out.size() + n * 36);
  for (std::size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) appendRaw(out, cloud.position[i][c]);
    for (int c = 0; c < 3; ++c) appendRaw(out, cloud.velocity[i][c]);
    appendRaw(out, cloud.body[i]);
    appendRaw(out, cloud.material[i]);
    appendRaw(out, cloud.stroke[i]);
  }
  writeAtomically(path, out);
}

}  // namespace physketch::render
