// Particle storage shared by sketch output, the solvers and the renderer.
//
// Structure of arrays, one owner, indexed by int32 particle id. Hot arrays are
// the ones a solver streams every substep; cold arrays are provenance written
// once by the sketch stage and read by reports and the renderer.
#pragma once

#include <cstdint>
#include <vector>

namespace physketch {

struct ParticleArrays {
  // --- hot: solver state ---------------------------------------------------
  std::vector<float> x, y, z;     // position (m), world frame; written by the solver's 'update' pass
  std::vector<float> vx, vy, vz;  // velocity (m/s); written by the solver's 'update' pass
  std::vector<float> invMass;     // inverse mass (1/kg); 0 = static or kinematic; set at simulation start
  std::vector<std::int32_t> body; // owning body (index into bodies), -1 = none; set at simulation start
  // --- cold: provenance ----------------------------------------------------
  std::vector<std::int32_t> stroke;   // id of the stroke that created the particle (sketch)
  std::vector<std::int16_t> material; // index into SceneDesc::materials (sketch)

  std::size_t size() const { return x.size(); }
  void reserve(std::size_t n);
  void resize(std::size_t n);
  // Appends a particle at rest. Returns its id.
  std::int32_t push(float px, float py, float pz, std::int32_t strokeId, std::int16_t materialId);
};

// A body is a contiguous range of particles simulated together (one stroke for
// rigid bodies in v1).
struct BodyRange {
  std::int32_t first = 0;     // first particle id
  std::int32_t count = 0;     // number of particles
  std::int16_t material = 0;  // index into SceneDesc::materials
  std::int32_t stroke = 0;    // stroke id the body came from
};

}  // namespace physketch
