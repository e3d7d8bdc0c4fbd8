// The inner loops of the rasterizer (sketch/rasterize.cpp): the chords of a solid on
// the rows of one plane of cells, and ORing row runs into a bit mask. Each comes in a
// scalar form and an AVX2 form that does the same exactly rounded IEEE operations in
// the same order, four rows at a time, so the two give the same bits (a test holds
// them to it) and a sketch does not depend on the CPU it was made on.
#pragma once

#include <algorithm>
#include <cstdint>

#include "core/math.h"
#include "sketch/grid.h"
#include "sketch/solids.h"

namespace physketch::sketch::kernels {

// Chord arrays hold at least kChordPad entries (the AVX2 forms write whole groups of 4).
constexpr int kChordPad = kGridSize + 5;

// True when the CPU runs the AVX2 forms.
bool hasAvx2();

// A double (a cell index computed in floating point) as an int; clamped first so
// that the huge values of a brush far larger than the grid convert safely.
inline int toInt(double x) { return static_cast<int>(std::min(std::max(x, -1e9), 1e9)); }

// The sphere: for the rows j0 .. j0+n-1 (n <= kGridSize) of a plane at distance ek
// (cells) from the centre (gx, gy): lo[t]..hi[t] are the cells of row j0+t whose
// centres are inside, ceil(gx - w)..floor(gx + w) with w = sqrt(ra2 - (j-gy)^2 - ek^2),
// lo > hi when the row misses the sphere (or its bounding radius^2 r2). Values are
// clamped to +-1e9 (a brush far larger than the grid).
void sphereChordsScalar(double gx, double gy, double ek, double r2, double ra2, int j0, int n, int* lo, int* hi);
void sphereChordsAvx2(double gx, double gy, double ek, double r2, double ra2, int j0, int n, int* lo, int* hi);

// Any other convex solid (box, cube, ellipsoid, cylinder, capsule), as its rows see it
// in its local frame: row (j, k) is the line o00 + j*dj + k*dk + t*d, where t is the
// cell index along x. Built once per stamp.
struct ConvexRows {
  enum class Shape { kBox, kEllipsoid, kCylinder, kCapsule } shape = Shape::kBox;
  double o00[3], dj[3], dk[3], d[3];
  double half[3] = {0, 0, 0};  // box: half extents; cylinder, capsule: half[2] is the half length
  double w[3] = {1, 1, 1};     // ellipsoid: 1/a^2, 1/b^2, 1/c^2
  double r2 = 0;               // cylinder, capsule: radius^2; ellipsoid: 1
  // Derived from the above by the constructor:
  double invD[3];     // 1 / d_i
  bool flatD[3];      // |d_i| < 1e-300: the rows run parallel to that pair of faces
  double A, invA;     // cylinder, capsule side: dx^2 + dy^2; ellipsoid: sum w_i d_i^2
  bool flatA;         // A < 1e-300: the rows run parallel to the cylinder's axis
  double A3, invA3;   // capsule caps: |d|^2

  // `solid` must be convex and not a sphere; h is the cell size (m).
  ConvexRows(const Solid& solid, const GridMapping& mapping);
};
// lo[t]..hi[t] for the rows j0 .. j0+n-1 of plane k, as for the sphere.
void convexChordsScalar(const ConvexRows& rows, int k, int j0, int n, int* lo, int* hi);
void convexChordsAvx2(const ConvexRows& rows, int k, int j0, int n, int* lo, int* hi);

// ORs the runs c0[t]..c1[t], clamped to lo..hi, into rows t = 0..n-1 of a CellMask
// plane (consecutive rows of 4 words, 32-byte aligned; cells 0..150 in the first 3);
// returns whether any run was non-empty.
bool markPlaneScalar(std::uint64_t* rows, int n, const int* c0, const int* c1, int lo, int hi);
bool markPlaneAvx2(std::uint64_t* rows, int n, const int* c0, const int* c1, int lo, int hi);

}  // namespace physketch::sketch::kernels
