// Files artists open elsewhere (physketch run --export; docs/formats.md, "Exports"): a body's
// meshes as Wavefront OBJ and binary PLY, the particles of a frame as binary PLY, and a
// Wavefront material library with the materials' colours. Every writer writes atomically
// (core/atomic_file.h) and throws RuntimeError naming the path.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "core/math.h"
#include "render/mesh.h"

namespace physketch::render {

// One material's surface of a body, in world coordinates (m).
struct MaterialMesh {
  int material = 0;  // index into the material list the file names
  TriangleMesh mesh;
};

// A material as the export files name it.
struct ExportMaterial {
  std::string name;
  std::array<float, 3> color{0.7f, 0.7f, 0.7f};  // linear RGB in [0, 1]
  double roughness = 0.5;
};

// OBJ: `o object`, then every part's vertices and normals, and per part `usemtl NAME` and its
// faces (1-based, v//vn). `mtllib`, when not empty, is written as the material library line.
void writeBodyObj(const std::string& path, const std::string& object, const std::vector<MaterialMesh>& parts,
                  const std::vector<ExportMaterial>& materials, const std::string& mtllib);

// Binary little-endian PLY: vertices x y z nx ny nz (float32) red green blue (uint8, the
// material's colour gamma-encoded, 2.2), faces as `list uchar uint vertex_indices` plus
// `ushort material_index`; header comments name the object and each material index.
void writeBodyPly(const std::string& path, const std::string& object, const std::vector<MaterialMesh>& parts,
                  const std::vector<ExportMaterial>& materials);

// A Wavefront material library: per material `newmtl NAME`, `Kd r g b` (linear colour), and
// `Ns` (the Blinn-Phong exponent its roughness gives, see render/renderer.h).
void writeMtl(const std::string& path, const std::vector<ExportMaterial>& materials);

// The particles of one frame, one entry per particle in every array.
struct ParticleCloud {
  std::vector<Vec3f> position;  // m
  std::vector<Vec3f> velocity;  // m/s
  std::vector<std::int32_t> body;      // body index (report.json's "bodies"), -1: none
  std::vector<std::int32_t> material;  // index into `materials`
  std::vector<std::int32_t> stroke;    // id of the operation that created the particle
  std::vector<std::string> materials;  // material names, written as header comments
  std::size_t size() const { return position.size(); }
};

// Binary little-endian PLY, element `vertex` with float x y z vx vy vz and int body material
// stroke (docs/formats.md). Throws RuntimeError for arrays of different lengths.
void writeParticlesPly(const std::string& path, const ParticleCloud& cloud);

// A name safe in a file name on every system: ASCII letters, digits, '-', '_' and '.' kept,
// every other byte replaced by '_', never empty ("_"), never starting with '.'.
std::string fileSafeName(const std::string& name);

}  // namespace physketch::render
