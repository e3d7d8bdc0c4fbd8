// The sketching stage: operations -> occupancy grid M and static particles
// (Phys-Sketch Alg. 1 and 2 with the interpolation of Eq. 6-7).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "core/material.h"
#include "core/particles.h"
#include "sketch/brush.h"
#include "sketch/grid.h"
#include "sketch/rasterize.h"
#include "sketch/solids.h"
#include "sketch/strokes.h"

namespace physketch::sketch {

// What one operation did, for reports and lint.
struct OperationSummary {
  int id = 0;
  int line = 0;
  std::string what;            // "stroke create sphere", "primitive box", "stamp cube.obj"
  std::int16_t material = -1;  // index into the scene's materials; -1 for remove/move
  bool active = true;          // false when undone
  std::int32_t created = 0;    // particles created
  std::int32_t removed = 0;    // particles it removed (remove strokes; cells a move landed on)
  std::int32_t moved = 0;      // particles it carried (move strokes)
  std::int32_t remaining = 0;  // of the particles it created, how many are in the final sketch
  std::int64_t stamps = 0;     // brush positions stamped (samples + interpolated points, mirror copies included)
  double minFeature = 0.0;     // m: smallest brush/primitive dimension, for the thin-feature warning (active ones)
  int body = -1;               // body of its particles in the final sketch, the first of them when a remove
                               // or move cut its body; -1 for none (and for operations after play)
  bool afterPlay = false;      // happens while the simulation runs (see Sketch::runtime)
};

// An operation that happens while the simulation runs (it starts after `play`).
// Times are simulation times: seconds after play.
struct RuntimeOp {
  enum class Kind { kCreate, kRemove, kMove, kTool } kind = Kind::kCreate;
  int op = 0;                  // operation id (provenance)
  int line = 0;
  double start = 0.0, end = 0.0;
  // kCreate: a new body, static from `start` until `end` (while it is being drawn), then dynamic.
  // A rope or cloth create makes one kCreate per mirror copy (a chain or lattice each).
  ParticleArrays particles;    // at voxel centres (kVoxels), or a rope's or cloth's nodes in layout order
  std::vector<Vec3i> cells;    // per particle: its voxel, or the cell a node's position falls in
  std::string bodyName;
  BodyInit init;               // vel=, spin=, fixed of the create
  BodyLayout layout = BodyLayout::kVoxels;  // as BodyRange: how the particles hang together
  std::int32_t rows = 0, cols = 0;          // kLattice
  float radius = 0.0f;                      // kChain, kLattice: contact and render radius (m)
  // kRemove: at each time, the particles whose current cell is in the set are removed.
  std::vector<std::pair<double, std::vector<Vec3i>>> removals;
  // kMove: at `start` the bodies of the particles whose current cell is in `grab` become
  // kinematic and follow the brush path (times, positions) until `end`, then are released.
  std::vector<Vec3i> grab;
  std::vector<std::pair<double, Vec3>> path;
  // kTool: `particles` (and `cells`) are the brush at its first sample, voxelized like a create's
  // stamp but not in M, not material and never removed; from `start` to `end` they are a kinematic
  // body whose centre follows `path` (offset by the first sample), then they leave the simulation.
  // Their material is the app's (apps/physketch/prepare.cpp gives each tool one); `friction` is
  // the stroke's friction= (Coulomb coefficient, static = dynamic), if given.
  std::optional<double> friction;
};

// Every particle is in a body range; bodies are in the order of their first operation (the
// pieces of a cut body together), whatever their layout.
// M holds exactly the voxel particles (one per voxel, at its centre). Rope and cloth
// particles are not in M: they are not voxel centres and several may share a cell; a voxel
// create may fill a cell a rope runs through (docs/formats.md, "Ropes and cloth").
struct Sketch {
  GridMapping mapping;
  OccupancyGrid grid;                 // M (final, particle indices after compaction): the voxel particles
  ParticleArrays particles;           // final particles, at rest, grouped by body: voxel centres (Eq. 5) for
                                      // kVoxels bodies, a rope's or cloth's nodes in layout order (holes of a cut
                                      // cloth have phase::kRemoved)
  std::vector<Vec3i> cells;           // per particle: its voxel, or (rope, cloth) the cell its position falls in
  std::vector<OperationSummary> operations;  // one per operation in the file (undone ones too)
  std::vector<BodyRange> bodies;      // contiguous particle ranges; material = the first particle's
  std::vector<std::string> bodyNames; // "chair" for body=chair, else "stroke N"; "chair #2", "stroke N #2", ... for
                                      // the further pieces of a body that a remove or move cut
  std::vector<std::string> warnings;  // lint warnings (file:line: text)
  std::vector<RuntimeOp> runtime;     // operations after play, in start-time order

  explicit Sketch(const GridMapping& m) : mapping(m) {}
};

// Particles that are in the simulation: all but the holes of cut cloths (phase::kRemoved).
std::int64_t liveParticles(const ParticleArrays& particles);

struct VoxelizeOptions {
  // Threads for the parallel parts (a long stroke is swept in this many parts, the
  // particle arrays are written in pieces), run in a TBB arena of this many threads;
  // 0 = every core. TBB's process-wide limit is not read. The sketch is the same bit
  // for bit for any count.
  int threads = 0;
};

// Replays the active operations that start before the play time, in file order;
// operations that start after it become RuntimeOps (creates are voxelized into a
// grid of their own, in file order, so they never overlap each other). A body that
// a remove or a move disconnects becomes one body per piece (sketch/bodies.h).
// Throws InputError (stroke file:line:field) for an unknown material, a sample
// outside the workspace, a rope or cloth that cannot be made (sketch/strands.h), a named
// body whose parts mix kinds (sketch/bodies.h), a move that carries particles out of the workspace,
// an unreadable stamp mesh, or a sketch that crosses the particle cap (naming
// the line and field of the operation that crossed it).
// Mesh stamps are voxelized with StampMesh (CGAL, sketch/mesh_stamp.cpp).
Sketch voxelize(const StrokeFile& file, const GridMapping& mapping, const std::vector<Material>& materials,
                const VoxelizeOptions& options = {});

}  // namespace physketch::sketch
