// The sketching stage: strokes -> occupancy grid M and static particles
// (Phys-Sketch Alg. 1 with the interpolation of Eq. 6-7).
#pragma once

#include <cstdint>
#include <vector>

#include "core/material.h"
#include "core/particles.h"
#include "sketch/grid.h"
#include "sketch/strokes.h"

namespace physketch::sketch {

struct StrokeSummary {
  int id = 0;
  int line = 0;
  std::int16_t material = 0;  // index into the scene's materials
  std::int32_t first = 0;     // first particle created by the stroke
  std::int32_t count = 0;     // particles created (voxels already taken are not counted)
  std::int64_t stamps = 0;    // brush positions stamped (samples + interpolated points)
};

struct Sketch {
  GridMapping mapping;
  OccupancyGrid grid;               // M
  ParticleArrays particles;         // one per occupied voxel, at the voxel centre (Eq. 5), at rest
  std::vector<Vec3i> cells;         // grid cell of each particle
  std::vector<StrokeSummary> strokes;

  explicit Sketch(const GridMapping& m) : mapping(m) {}
};

// Eq. 6-7: the brush positions stamped for the segment from `prev` to `cur`:
// P'(i) = cur - i * V/|V| * d for i in [0, i_max], i_max = Round(|V| dt / d).
// |V| dt is the distance travelled. `out` is cleared first; a zero-length segment gives {cur}.
void interpolateSegment(const Vec3& prev, const Vec3& cur, double particleDiameter, std::vector<Vec3>& out);

// Stamps one brush position into the sketch (Alg. 1): every empty cell whose
// centre lies inside the brush gets a new particle; a brush smaller than a cell
// stamps the cell containing the position. Cells outside the grid are skipped
// (Alg. 1: "if p in M"). Returns the number of particles created.
std::int32_t stampBrush(Sketch& sketch, BrushShape shape, double size, const Vec3& position, std::int32_t strokeId,
                        std::int16_t materialId);

// Voxelizes every stroke in file order. Throws InputError (stroke file:line:field)
// for an unknown material, a sample outside the workspace, or a sketch that
// crosses the particle cap (naming the stroke that crossed it).
Sketch voxelize(const StrokeFile& file, const GridMapping& mapping, const std::vector<Material>& materials);

}  // namespace physketch::sketch
