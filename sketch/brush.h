// Where an operation puts its brush: the stamp positions of a stroke (Eq. 6-7),
// the solid at each stamp, the exact primitives, and the mirror image of a cell.
// Pure functions of the stroke file's records; no grid state.
#pragma once

#include <cstdint>
#include <vector>

#include "core/math.h"
#include "sketch/grid.h"
#include "sketch/solids.h"
#include "sketch/strokes.h"

namespace physketch::sketch {

// True for the operations that make particles: create strokes, primitives and mesh stamps.
bool createsParticles(const Operation& op);

// Eq. 6-7: the brush positions stamped for the segment from `prev` to `cur`:
// P'(i) = cur - i * V/|V| * d for i in [0, i_max], i_max = Round(|V| dt / d).
// |V| dt is the distance travelled. `out` is cleared first; a zero-length segment gives {cur}.
void interpolateSegment(const Vec3& prev, const Vec3& cur, double particleDiameter, std::vector<Vec3>& out);

// One brush position of a stroke.
struct Stamp {
  Vec3 position;    // m
  Vec3 direction;   // unit: the direction of travel of its segment (orient=follow)
  double pressure;  // (0, 1], interpolated linearly along the segment
  double time;      // s: the sample time at the end of the stamp's segment
};

// Every brush position of a stroke: its first sample, then each segment's Eq. 6-7
// points (voxelSize = particle diameter d).
std::vector<Stamp> stampsOf(const Stroke& stroke, double voxelSize);

// The brush of a stroke at one stamp: size scaled by pressure, axis fixed or along `direction`.
Solid brushSolid(const Stroke& stroke, const Vec3& position, double pressure, const Vec3& direction, double voxelSize);

// The exact solid of a primitive record.
Solid primitiveSolid(const Primitive& primitive);

// The thinnest dimension an operation draws (m), for the thin-feature lint warning;
// a huge value for mesh stamps (a mesh's thickness is not known).
double smallestFeature(const Operation& op, double voxelSize);

// Reflects a cell across a mirror plane snapped to the nearest cell centre or
// face (so the mirrored set is exact): i' = 2m - i on the mirror axis.
Vec3i mirrorCell(const Vec3i& cell, const Mirror& mirror, const GridMapping& mapping);

// Reflects a world point across the mirror plane (unsnapped: for brush paths).
Vec3 mirrorPoint(const Vec3& point, const Mirror& mirror);

}  // namespace physketch::sketch
