#include "sketch/rasterize.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

namespace physketch::sketch {
namespace {

// A double (a cell index computed in floating point) as an int; clamped first so
// that the huge values of a brush far larger than the grid convert safely.
inline int toInt(double x) { return static_cast<int>(std::min(std::max(x, -1e9), 1e9)); }

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
// the default axis, an unrotated box primitive): which world axis each local axis
// lies on. Its cells are a product of three index ranges.
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

// Calls plane(k, j0, n, c0, c1) for each plane k a convex solid may meet, with the
// rows j0 .. j0+n-1 of it (within the grid): c0[t]..c1[t] are the cells of row j0+t
// whose centres are inside (c0 > c1 when none), not yet clamped to cb.lo[0]..cb.hi[0].
// Each row is a line through the cell centres; its chord is found in closed form.
template <class PlaneFn>
void forEachPlane(const Solid& solid, const GridMapping& m, const CellBounds& cb, PlaneFn&& plane) {
  int c0[detail::kChordPad], c1[detail::kChordPad];
  if (gridAligned(solid)) {
    // The same chord on every row of a rectangle of rows.
    const Vec3 half = solid.shape == SolidShape::kCube ? Vec3(solid.a, solid.a, solid.a) : Vec3(solid.a, solid.b, solid.c);
    int a[3], b[3];
    for (int e = 0; e < 3; ++e) {
      int local = 0;  // the local axis lying on world axis e
      while (solid.rotation(e, local) == 0.0) ++local;
      alignedRange(solid, m, cb, e, half[local], a[e], b[e]);
    }
    if (a[0] > b[0] || a[1] > b[1]) return;
    std::fill(c0, c0 + (b[1] - a[1] + 1), a[0]);
    std::fill(c1, c1 + (b[1] - a[1] + 1), b[0]);
    for (int k = a[2]; k <= b[2]; ++k) plane(k, a[1], b[1] - a[1] + 1, c0, c1);
    return;
  }
  const double h = m.voxelSize();
  const Vec3& g = cb.g;
  const double r2 = cb.r * cb.r;
  const bool sphere = solid.shape == SolidShape::kSphere;
  static const auto chords = detail::hasAvx2() ? detail::sphereChordsAvx2 : detail::sphereChordsScalar;
  const double ra2 = (solid.a / h) * (solid.a / h);
  // Other shapes: row (j, k) is the line origin(j, k) + t * (h, 0, 0), so t is the cell
  // index i. In the solid's local frame the origin is affine in (j, k): three vectors.
  const Mat3 Rt = solid.rotation.transpose();
  const Vec3 o00 = Rt * (m.toWorld(Vec3i(0, 0, 0)) - solid.centre);
  const Vec3 dj = Rt * Vec3(0, h, 0), dk = Rt * Vec3(0, 0, h), d = Rt * Vec3(h, 0, 0);
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
    if (sphere) {  // the common brush: a whole plane of chords at once
      chords(g.x(), g.y(), ek, r2, ra2, jlo, n, c0, c1);
    } else {
      for (int t = 0; t < n; ++t) {
        const int j = jlo + t;
        const double ej = j - g.y();
        double t0, t1;
        c0[t] = 1, c1[t] = 0;
        if (ej * ej + ek * ek > r2) continue;  // the row misses the bounding sphere
        if (!solid.lineIntervalLocal(o00 + double(j) * dj + double(k) * dk, d, t0, t1)) continue;
        c0[t] = toInt(std::ceil(t0)), c1[t] = toInt(std::floor(t1));
      }
    }
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
}

inline void CellMask::markRow(int j, int k, int i0, int i1) {
  detail::markPlaneScalar(row(j, k), 1, &i0, &i1, i0, i1);
}

void CellMask::add(const Solid& solid, const GridMapping& m) {
  const CellBounds cb(solid, m);
  bool any = false;
  if (solid.convex()) {
    static const auto mark = detail::hasAvx2() ? detail::markPlaneAvx2 : detail::markPlaneScalar;
    forEachPlane(solid, m, cb, [&](int k, int j0, int n, const int* c0, const int* c1) {
      any |= mark(row(j0, k), n, c0, c1, cb.lo[0], cb.hi[0]);
    });
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

// --- the sphere chord kernel ---------------------------------------------------

namespace detail {

void sphereChordsScalar(double gx, double gy, double ek, double r2, double ra2, int j0, int n, int* lo, int* hi) {
  const double ek2 = ek * ek;
  for (int t = 0; t < n; ++t) {
    const double ej = double(j0 + t) - gy;
    const double ej2 = ej * ej;
    const double w2 = (ra2 - ej2) - ek2;
    const bool ok = !(ej2 + ek2 > r2) && w2 >= 0;
    const double w = std::sqrt(std::max(w2, 0.0));
    lo[t] = ok ? toInt(std::ceil(gx - w)) : 1;
    hi[t] = ok ? toInt(std::floor(gx + w)) : 0;
  }
}

bool markPlaneScalar(std::uint64_t* rows, int n, const int* c0, const int* c1, int lo, int hi) {
  bool any = false;
  for (int t = 0; t < n; ++t) {
    const int i0 = std::max(lo, c0[t]), i1 = std::min(hi, c1[t]);
    if (i0 > i1) continue;
    any = true;
    std::uint64_t* w = rows + 4 * t;
    for (int q = 0; q < 3; ++q) {
      const int a = std::max(i0 - 64 * q, 0), b = std::min(i1 - 64 * q, 63);  // bits a..b of word q
      const std::uint64_t run = (~std::uint64_t(0) >> (63 - std::max(b - a, 0))) << std::min(a, 63);
      w[q] |= a <= b ? run : 0;
    }
  }
  return any;
}

#if defined(__x86_64__) || defined(__i386__)
__attribute__((target("avx2"))) void sphereChordsAvx2(double gx, double gy, double ek, double r2, double ra2, int j0,
                                                      int n, int* lo, int* hi) {
  const __m256d vgx = _mm256_set1_pd(gx), vgy = _mm256_set1_pd(gy), vek2 = _mm256_set1_pd(ek * ek);
  const __m256d vr2 = _mm256_set1_pd(r2), vra2 = _mm256_set1_pd(ra2), zero = _mm256_setzero_pd();
  const __m256d one = _mm256_set1_pd(1.0), lim = _mm256_set1_pd(1e9), nlim = _mm256_set1_pd(-1e9);
  // Lanes past n compute rows that are not asked for; the arrays are padded for them.
  for (int t = 0; t < n; t += 4) {
    const __m256d j = _mm256_add_pd(_mm256_set1_pd(double(j0 + t)), _mm256_setr_pd(0, 1, 2, 3));
    const __m256d ej = _mm256_sub_pd(j, vgy);
    const __m256d ej2 = _mm256_mul_pd(ej, ej);
    const __m256d w2 = _mm256_sub_pd(_mm256_sub_pd(vra2, ej2), vek2);
    const __m256d ok =
        _mm256_and_pd(_mm256_cmp_pd(_mm256_add_pd(ej2, vek2), vr2, _CMP_LE_OQ), _mm256_cmp_pd(w2, zero, _CMP_GE_OQ));
    const __m256d w = _mm256_sqrt_pd(_mm256_max_pd(w2, zero));
    const __m256d a = _mm256_blendv_pd(one, _mm256_ceil_pd(_mm256_sub_pd(vgx, w)), ok);
    const __m256d b = _mm256_blendv_pd(zero, _mm256_floor_pd(_mm256_add_pd(vgx, w)), ok);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(lo + t), _mm256_cvttpd_epi32(_mm256_min_pd(_mm256_max_pd(a, nlim), lim)));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(hi + t), _mm256_cvttpd_epi32(_mm256_min_pd(_mm256_max_pd(b, nlim), lim)));
  }
}
__attribute__((target("avx2"))) bool markPlaneAvx2(std::uint64_t* rows, int n, const int* c0, const int* c1, int lo,
                                                   int hi) {
  // Row t is the aligned words rows[4t .. 4t+3]: one vector load/OR/store per row
  // (the fourth lane, padding, is ORed with zero).
  const __m256i q64 = _mm256_setr_epi64x(0, 64, 128, 192), one = _mm256_set1_epi64x(1);
  bool any = false;
  for (int t = 0; t < n; ++t) {
    const int i0 = std::max(lo, c0[t]), i1 = std::min(hi, c1[t]);
    if (i0 > i1) continue;
    any = true;
    const __m256i a = _mm256_sub_epi64(_mm256_set1_epi64x(i0), q64);
    const __m256i b = _mm256_sub_epi64(_mm256_set1_epi64x(i1 + 1), q64);
    // Bits below x in each lane: 0 for x <= 0, all for x >= 64 (sllv gives 0 there, minus 1).
    const __m256i belowA =
        _mm256_andnot_si256(_mm256_cmpgt_epi64(one, a), _mm256_sub_epi64(_mm256_sllv_epi64(one, a), one));
    const __m256i belowB =
        _mm256_andnot_si256(_mm256_cmpgt_epi64(one, b), _mm256_sub_epi64(_mm256_sllv_epi64(one, b), one));
    const __m256i run = _mm256_andnot_si256(belowA, belowB);
    __m256i* w = reinterpret_cast<__m256i*>(rows + 4 * t);
    _mm256_store_si256(w, _mm256_or_si256(_mm256_load_si256(w), run));
  }
  return any;
}
bool hasAvx2() { return __builtin_cpu_supports("avx2"); }
#else
bool markPlaneAvx2(std::uint64_t* rows, int n, const int* c0, const int* c1, int lo, int hi) {
  return markPlaneScalar(rows, n, c0, c1, lo, hi);
}
void sphereChordsAvx2(double gx, double gy, double ek, double r2, double ra2, int j0, int n, int* lo, int* hi) {
  sphereChordsScalar(gx, gy, ek, r2, ra2, j0, n, lo, hi);
}
bool hasAvx2() { return false; }
#endif

}  // namespace detail
}  // namespace physketch::sketch
