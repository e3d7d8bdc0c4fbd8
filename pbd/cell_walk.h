// The first taken cell a segment enters on a unit lattice (Amanatides & Woo 1987's traversal):
// the continuous collision of particle-level particles against sketched rigid bodies walks
// each particle's move of the substep through its body's rest cells with it (PbdWorld::
// looseBodySweep).
#pragma once

#include <cmath>
#include <cstdlib>
#include <limits>

#include "core/math.h"

namespace physketch::pbd {

// Where the segment a -> a + d (cell units: cell k spans [k, k + 1) on each axis) first enters a
// cell `filled` says is taken: fraction t, and the axis and direction of the face it crosses
// (Amanatides & Woo 1987's traversal). None if it starts in a taken cell or never enters one,
// and none for an end beyond 2^20 cells or not finite (a particle that fast is the guard's).
struct CellEntry {
  bool hit = false;
  double t = 1.0;
  int axis = 0, dir = 0;
};

template <class Filled>
CellEntry firstTakenCell(const Vec3& a, const Vec3& d, const Filled& filled) {
  CellEntry e;
  constexpr double kFar = double(1 << 20);
  const Vec3 b = a + d;
  if (!(a.cwiseAbs().maxCoeff() < kFar) || !(b.cwiseAbs().maxCoeff() < kFar)) return e;
  Vec3i cell(int(std::floor(a.x())), int(std::floor(a.y())), int(std::floor(a.z())));
  const Vec3i end(int(std::floor(b.x())), int(std::floor(b.y())), int(std::floor(b.z())));
  // Faces the whole segment crosses: the walk's bound (none for most of a substep's moves).
  const int crossings = (end - cell).cwiseAbs().sum();
  if (crossings == 0 || filled(cell)) return e;
  Vec3i step;
  Vec3 tMax, tDelta;
  for (int k = 0; k < 3; ++k) {
    step[k] = d[k] > 0.0 ? 1 : d[k] < 0.0 ? -1 : 0;
    const double inv = step[k] != 0 ? 1.0 / std::abs(d[k]) : 0.0;
    tDelta[k] = step[k] != 0 ? inv : std::numeric_limits<double>::infinity();
    tMax[k] = step[k] > 0 ? (cell[k] + 1 - a[k]) * inv : step[k] < 0 ? (a[k] - cell[k]) * inv
                                                                       : std::numeric_limits<double>::infinity();
  }
  for (int n = 0; n < crossings; ++n) {
    int k = 0;
    if (tMax[1] < tMax[k]) k = 1;
    if (tMax[2] < tMax[k]) k = 2;
    if (!(tMax[k] <= 1.0)) return e;
    cell[k] += step[k];
    if (filled(cell)) {
      e.hit = true, e.t = tMax[k], e.axis = k, e.dir = step[k];
      return e;
    }
    tMax[k] += tDelta[k];
  }
  return e;
}

}  // namespace physketch::pbd
