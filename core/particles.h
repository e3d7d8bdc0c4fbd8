// Particle storage shared by sketch output, the solvers and the renderer.
//
// Structure of arrays, one owner, indexed by int32 particle id. Ids are stable in
// everything users see (outputs, provenance, reports); a solver that wants its hot
// arrays in cell order keeps its own copy and a permutation (docs/architecture.md,
// "Particle ids and orders"). Hot arrays are the ones a solver streams every
// substep; provenance (stroke, material) is cold: written once by the sketch stage,
// read by reports, lint and the renderer.
#pragma once

#include <cstdint>
#include <vector>

#include "core/math.h"

namespace physketch {

// A particle's phase (Macklin et al. 2014, "Unified particle physics", §4): the
// group it belongs to (a rigid body today; a soft body, rope or cloth later) in the
// low 24 bits, and flags in the high 8 bits. Particles of the same group do not
// collide with each other unless kSelfCollide is set.
namespace phase {
constexpr std::uint32_t kGroupMask = 0x00FFFFFFu;
constexpr std::uint32_t kNoGroup = kGroupMask;        // a free particle (fluid, granular)
constexpr std::uint32_t kSelfCollide = 1u << 24;      // collides with particles of its own group
constexpr std::uint32_t kFluid = 1u << 25;            // takes part in the fluid density constraint
constexpr std::uint32_t kPrescribed = 1u << 26;       // moved by the input (kinematic or fixed): infinite mass
constexpr std::uint32_t kRemoved = 1u << 27;          // taken out by a remove stroke after play
constexpr std::uint32_t make(std::int32_t group, std::uint32_t flags = 0) {
  return (group < 0 ? kNoGroup : (static_cast<std::uint32_t>(group) & kGroupMask)) | flags;
}
constexpr std::int32_t group(std::uint32_t ph) {
  return (ph & kGroupMask) == kNoGroup ? -1 : static_cast<std::int32_t>(ph & kGroupMask);
}
constexpr bool has(std::uint32_t ph, std::uint32_t flag) { return (ph & flag) != 0; }
// A particle the dynamic passes move: in the simulation and not prescribed.
constexpr bool dynamic(std::uint32_t ph) { return (ph & (kPrescribed | kRemoved)) == 0; }
}  // namespace phase

struct ParticleArrays {
  // --- hot: solver state ---------------------------------------------------
  std::vector<float> x, y, z;     // position (m), world frame; written by the solver's last pass of a step
  std::vector<float> vx, vy, vz;  // velocity (m/s); written with the positions
  std::vector<float> mass;        // kg, the particle's own (density x spacing^3); the one mass array.
                                  // 0 until the solver starts; kept when prescribed (a released body needs it)
  std::vector<std::uint32_t> phase;  // group + flags (namespace phase); prescribed while sketched
  // --- cold: provenance ----------------------------------------------------
  std::vector<std::int32_t> stroke;   // id of the operation that created the particle (sketch)
  std::vector<std::int16_t> material; // index into SceneDesc::materials (sketch)

  std::size_t size() const { return x.size(); }
  void reserve(std::size_t n);
  void resize(std::size_t n);
  // Appends a particle at rest, prescribed (static while being sketched, Phys-Sketch §4). Returns its id.
  std::int32_t push(float px, float py, float pz, std::int32_t strokeId, std::int16_t materialId);
  std::int32_t group(std::size_t i) const { return phase::group(phase[i]); }
};

// How a body starts when the simulation does (create options vel=, spin=, fixed).
struct BodyInit {
  Vec3 velocity = Vec3::Zero();  // m/s, of the centre of mass
  Vec3 spin = Vec3::Zero();      // rad/s, about the centre of mass (world axes)
  bool fixed = false;            // never moves: walls, slopes, table tops
};

// How the particles of a body are laid out, which says how they hang together:
// - kVoxels: one particle per voxel of the sketch grid (rigid and soft bodies, fluid fills,
//   every MPM kind); neighbours are found by position.
// - kChain: a rope, the brush path's centreline resampled at the particle spacing; particle
//   first + k is linked to first + k + 1 (one particle across).
// - kLattice: a cloth, the surface the brush swept resampled as a rows x cols lattice at the
//   particle spacing, row-major: particle first + r * cols + c is lattice node (r, c);
//   count == rows * cols. A node a remove took away before play stays in the range as a
//   hole (phase::kRemoved set, never simulated): the solver drops the constraints to it.
enum class BodyLayout : std::uint8_t { kVoxels, kChain, kLattice };
const char* toString(BodyLayout layout);

// A body: a contiguous range of particles simulated together. One per create operation,
// per named body (body=NAME, whose parts may mix materials: each particle keeps its own
// material and mass), or per piece a cut left. What the solver makes of it follows from its
// material's kind (rigid: shape matching; soft: clusters; fluid: free particles; rope and
// cloth: distance and bending constraints along the layout).
struct BodyRange {
  std::int32_t first = 0;     // first particle id
  std::int32_t count = 0;     // number of particles
  std::int32_t stroke = 0;    // id of the operation that created its first particle
  BodyInit init;
  BodyLayout layout = BodyLayout::kVoxels;
  std::int32_t rows = 0, cols = 0;  // kLattice only: rows * cols == count
  // kChain, kLattice: the contact and render radius of each particle (m), from the brush (a
  // rope: half the brush size; a cloth: half the disc's thickness). 0 for kVoxels: h/2.
  float radius = 0.0f;
};

// Pose of a rigid body: world = R (rest - restCentre) + centre.
struct BodyPose {
  Quat rotation = Quat::Identity();
  Vec3 centre = Vec3::Zero();
  Vec3 restCentre = Vec3::Zero();
  Mat4f model() const;  // the 4x4 rest->world matrix, for rendering
};

// How a body moves: by the solver, along a prescribed path (grabbed by a move
// stroke, or held while it is being drawn), not at all (fixed), or no longer
// (all its particles removed).
enum class BodyMode { kDynamic, kKinematic, kFixed, kEmpty };
const char* toString(BodyMode mode);

}  // namespace physketch
