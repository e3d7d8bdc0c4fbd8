#include "sketch/rasterize.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>

#include "sketch/raster_kernels.h"

namespace physketch::sketch {
namespace {

using kernels::toInt;

// The grid cells (clamped to the grid) of the bounding sphere of a solid, in cells.
struct CellBounds {
  Vec3 g;        // centre in grid coordinates (Eq. 4)
  double r;      // bounding radius in cells
  int lo[3], hi[3];
  CellBounds(const Solid& solid, const GridMapping& m)
      : g(m.toGrid(solid.centre)), r(solid.boundingRadius() / m.voxelSize()) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::max(0, toInt(std::ceil(g[a] - r)));
      hi[a] = std::min(kGridSize - 1, toInt(std::floor(g[a] + r)));
    }
  }
};

// A box whose frame is a signed permutation of the grid axes (a cube brush with
// the default axis, an unrotated box primitive): its cells are a product of three
// index ranges.
bool gridAligned(const Solid& solid) {
  if (solid.shape != SolidShape::kBox && solid.shape != SolidShape::kCube) return false;
  for (int i = 0; i < 9; ++i) {
    const double v = solid.rotation.data()[i];
    if (v != 0.0 && v != 1.0 && v != -1.0) return false;
  }
  return true;
}

// For a grid-aligned box: the cells c of world axis e (within lo..hi) whose centre
// is within `half` of the box centre, tested with exactly the arithmetic of
// Solid::containsLocal, so the range matches a cell-by-cell test bit for bit.
void alignedRange(const Solid& solid, const GridMapping& m, const CellBounds& cb, int e, double half, int& a, int& b) {
  auto inside = [&](int c) { return std::abs(m.toWorld(Vec3i(c, c, c))[e] - solid.centre[e]) <= half; };
  const double w = half / m.voxelSize();
  a = std::min(std::max(toInt(std::ceil(cb.g[e] - w)), cb.lo[e]), cb.hi[e] + 1);
  b = std::max(std::min(toInt(std::floor(cb.g[e] + w)), cb.hi[e]), cb.lo[e] - 1);
  while (a > cb.lo[e] && inside(a - 1)) --a;
  while (a <= cb.hi[e] && !inside(a)) ++a;
  while (b < cb.hi[e] && inside(b + 1)) ++b;
  while (b >= cb.lo[e] && !inside(b)) --b;
}

// For a grid-aligned box: its cells are those of the index ranges a[e]..b[e] (an
// empty range when a > b). Returns false for any other solid.
bool alignedBox(const Solid& solid, const GridMapping& m, const CellBounds& cb, int a[3], int b[3]) {
  if (!gridAligned(solid)) return false;
  const Vec3 half =
      solid.shape == SolidShape::kCube ? Vec3(solid.a, solid.a, solid.a) : Vec3(solid.a, solid.b, solid.c);
  for (int e = 0; e < 3; ++e) {
    int local = 0;  // the local axis lying on world axis e
    while (solid.rotation(e, local) == 0.0) ++local;
    alignedRange(solid, m, cb, e, half[local], a[e], b[e]);
  }
  return true;
}

// forEachPlane() for a grid-aligned box of index ranges a..b: the same chord on
// every row of a rectangle of rows.
template <class PlaneFn>
void forEachAlignedPlane(const int a[3], const int b[3], PlaneFn&& plane) {
  if (a[0] > b[0] || a[1] > b[1]) return;
  int c0[kernels::kChordPad], c1[kernels::kChordPad];
  std::fill(c0, c0 + (b[1] - a[1] + 1), a[0]);
  std::fill(c1, c1 + (b[1] - a[1] + 1), b[0]);
  for (int k = a[2]; k <= b[2]; ++k) plane(k, a[1], b[1] - a[1] + 1, c0, c1);
}

// Calls plane(k, j0, n, c0, c1) for each plane k a convex solid may meet, with the
// rows j0 .. j0+n-1 of it (within the grid): c0[t]..c1[t] are the cells of row j0+t
// whose centres are inside (c0 > c1 when none), not yet clamped to cb.lo[0]..cb.hi[0].
// Each row is a line through the cell centres; its chord is found in closed form.
template <class PlaneFn>
void forEachPlane(const Solid& solid, const GridMapping& m, const CellBounds& cb, PlaneFn&& plane) {
  int a[3], b[3];
  if (alignedBox(solid, m, cb, a, b)) return forEachAlignedPlane(a, b, plane);
  int c0[kernels::kChordPad], c1[kernels::kChordPad];
  const double h = m.voxelSize();
  const Vec3& g = cb.g;
  const double r2 = cb.r * cb.r;
  const bool sphere = solid.shape == SolidShape::kSphere;
  static const bool avx2 = kernels::hasAvx2();
  const auto sphereChords = avx2 ? kernels::sphereChordsAvx2 : kernels::sphereChordsScalar;
  const auto convexChords = avx2 ? kernels::convexChordsAvx2 : kernels::convexChordsScalar;
  const double ra2 = (solid.a / h) * (solid.a / h);
  // Other shapes: row (j, k) is a line through cell centres, affine in (j, k) in the
  // solid's local frame; its chord is found in closed form.
  std::optional<kernels::ConvexRows> rows;
  if (!sphere) rows.emplace(solid, m);
  for (int k = cb.lo[2]; k <= cb.hi[2]; ++k) {
    // Only the rows within the bounding sphere's disc on plane k are visited (one more
    // on each side, so rounding in that bound never drops a row the exact test keeps).
    const double ek = k - g.z();
    const double rest = r2 - ek * ek;
    if (rest < 0) continue;
    const double s = std::sqrt(rest);
    const int jlo = std::max(cb.lo[1], toInt(std::ceil(g.y() - s)) - 1);
    const int jhi = std::min(cb.hi[1], toInt(std::floor(g.y() + s)) + 1);
    if (jlo > jhi) continue;
    const int n = jhi - jlo + 1;
    if (sphere)  // the common brush
      sphereChords(g.x(), g.y(), ek, r2, ra2, jlo, n, c0, c1);
    else
      convexChords(*rows, k, jlo, n, c0, c1);
    plane(k, jlo, n, c0, c1);
  }
}

// Calls row(j, k, i0, i1) for each run of cells i0..i1 (i0 <= i1) of row (j, k)
// whose centres are inside `solid`, with k, j and i0 ascending. Returns false when
// no cell centre is inside. A convex solid gives at most one run per row.
template <class RowFn>
bool forEachRow(const Solid& solid, const GridMapping& m, RowFn&& row) {
  const CellBounds cb(solid, m);
  bool any = false;
  if (solid.convex()) {
    forEachPlane(solid, m, cb, [&](int k, int j0, int n, const int* c0, const int* c1) {
      for (int t = 0; t < n; ++t) {
        const int i0 = std::max(cb.lo[0], c0[t]), i1 = std::min(cb.hi[0], c1[t]);
        if (i0 > i1) continue;
        any = true;
        row(j0 + t, k, i0, i1);
      }
    });
    return any;
  }
  // Not convex (the torus): each cell is tested; consecutive inside cells form a run.
  const double h = m.voxelSize();
  const Vec3& g = cb.g;
  const Mat3 Rt = solid.rotation.transpose();
  for (int k = cb.lo[2]; k <= cb.hi[2]; ++k)
    for (int j = cb.lo[1]; j <= cb.hi[1]; ++j) {
      int start = -1;
      for (int i = cb.lo[0]; i <= cb.hi[0] + 1; ++i) {
        const bool inside =
            i <= cb.hi[0] && solid.containsLocal(Rt * (Vec3(i - g.x(), j - g.y(), k - g.z()) * h));
        if (inside && start < 0) start = i;
        if (!inside && start >= 0) {
          any = true;
          row(j, k, start, i - 1);
          start = -1;
        }
      }
    }
  return any;
}

// A solid smaller than a cell covers no cell centre: it still marks the cell it is in.
template <class CellFn>
void centreCell(const Solid& solid, const GridMapping& m, CellFn&& cell) {
  const Vec3i c = m.discretize(solid.centre);
  if (GridMapping::inGrid(c)) cell(c);
}

}  // namespace

void rasterize(const Solid& solid, const GridMapping& m, std::vector<Vec3i>& out) {
  out.clear();
  const bool any = forEachRow(solid, m, [&](int j, int k, int i0, int i1) {
    for (int i = i0; i <= i1; ++i) out.emplace_back(i, j, k);
  });
  if (!any) centreCell(solid, m, [&](const Vec3i& c) { out.push_back(c); });
}

// --- CellMask ----------------------------------------------------------------

static_assert(CellMask::kWords == 3 && CellMask::kStride == 4, "the plane kernels assume rows of 151 cells in 4 words");

CellMask::CellMask()
    : bits_(std::size_t(kGridSize) * kGridSize * kStride + kStride, 0),  // + kStride: room to align
      base_(bits_.data() + (-(reinterpret_cast<std::uintptr_t>(bits_.data()) / sizeof(std::uint64_t)) & (kStride - 1))),
      k0_(kGridSize), k1_(-1), j0_(kGridSize), j1_(-1) {}

void CellMask::clear() {
  if (k0_ > k1_) return;
  const std::size_t words = std::size_t(j1_ - j0_ + 1) * kStride;
  for (int k = k0_; k <= k1_; ++k) std::memset(row(j0_, k), 0, words * sizeof(std::uint64_t));
  k0_ = j0_ = kGridSize;
  k1_ = j1_ = -1;
  std::fill(lastBox_, lastBox_ + 6, 0), lastBox_[0] = 1;  // an empty box
}

inline void CellMask::markRow(int j, int k, int i0, int i1) {
  kernels::markPlaneScalar(row(j, k), 1, &i0, &i1, i0, i1);
}

void CellMask::add(const Solid& solid, const GridMapping& m) {
  const CellBounds cb(solid, m);
  bool any = false;
  static const auto mark = kernels::hasAvx2() ? kernels::markPlaneAvx2 : kernels::markPlaneScalar;
  auto markPlane = [&](int k, int j0, int n, const int* c0, const int* c1) {
    any |= mark(row(j0, k), n, c0, c1, cb.lo[0], cb.hi[0]);
  };
  int a[3], b[3];
  if (alignedBox(solid, m, cb, a, b)) {
    // A grid-aligned box is three index ranges. While a stroke moves by less than a
    // cell per stamp they are often the previous stamp's: nothing new to mark.
    const bool empty = a[0] > b[0] || a[1] > b[1] || a[2] > b[2];
    if (!empty && std::equal(a, a + 3, lastBox_) && std::equal(b, b + 3, lastBox_ + 3)) return;
    if (!empty) std::copy(a, a + 3, lastBox_), std::copy(b, b + 3, lastBox_ + 3);
    forEachAlignedPlane(a, b, markPlane);
  } else if (solid.convex()) {
    forEachPlane(solid, m, cb, markPlane);
  } else {
    any = forEachRow(solid, m, [&](int j, int k, int i0, int i1) { markRow(j, k, i0, i1); });
  }
  if (any) {  // the rows marked lie within the bounding rows
    k0_ = std::min(k0_, cb.lo[2]), k1_ = std::max(k1_, cb.hi[2]);
    j0_ = std::min(j0_, cb.lo[1]), j1_ = std::max(j1_, cb.hi[1]);
    return;
  }
  centreCell(solid, m, [&](const Vec3i& c) { set(c); });
}

void CellMask::merge(const CellMask& other) {
  if (other.k0_ > other.k1_) return;
  k0_ = std::min(k0_, other.k0_), k1_ = std::max(k1_, other.k1_);
  j0_ = std::min(j0_, other.j0_), j1_ = std::max(j1_, other.j1_);
  for (int k = other.k0_; k <= other.k1_; ++k) {
    std::uint64_t* w = row(other.j0_, k);
    const std::uint64_t* o = other.row(other.j0_, k);
    for (int q = 0; q < (other.j1_ - other.j0_ + 1) * kStride; ++q) w[q] |= o[q];
  }
}

std::int64_t CellMask::count() const {
  std::int64_t n = 0;
  for (int k = k0_; k <= k1_; ++k)
    for (int j = j0_; j <= j1_; ++j)
      for (int q = 0; q < kWords; ++q) n += __builtin_popcountll(row(j, k)[q]);
  return n;
}

// --- StampDiff ---------------------------------------------------------------

void StampDiff::Rows::reset(int j0_, int j1, int k0_, int k1) {
  j0 = j0_, k0 = k0_, nj = std::max(0, j1 - j0_ + 1), nk = std::max(0, k1 - k0_ + 1);
  lo.assign(std::size_t(nj) * std::size_t(nk), 1);
  hi.assign(lo.size(), 0);
}

void StampDiff::stamp(const Solid& solid, const GridMapping& m, std::vector<Vec3i>& out) {
  out.clear();
  const CellBounds cb(solid, m);
  next_.reset(cb.lo[1], cb.hi[1], cb.lo[2], cb.hi[2]);
  const bool convex = solid.convex();
  const bool any = forEachRow(solid, m, [&](int j, int k, int i0, int i1) {
    int p0 = 1, p1 = 0;  // the previous stamp's cells on this row (none by default)
    if (prev_.has(j, k)) {
      const std::size_t at = prev_.index(j, k);
      p0 = prev_.lo[at], p1 = prev_.hi[at];
    }
    if (convex) {
      const std::size_t at = next_.index(j, k);
      next_.lo[at] = i0, next_.hi[at] = i1;
    }
    for (int i = i0; i <= i1; ++i) {
      if (i >= p0 && i <= p1) {
        i = p1;  // skip the run already stamped
        continue;
      }
      out.emplace_back(i, j, k);
    }
  });
  // A non-convex stamp leaves no intervals: the next one hands on all its cells.
  if (!any || !convex) next_.reset(0, -1, 0, -1);
  if (!any) centreCell(solid, m, [&](const Vec3i& c) { out.push_back(c); });
  std::swap(prev_, next_);
}

}  // namespace physketch::sketch
