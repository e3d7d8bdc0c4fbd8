#include "sketch/raster_kernels.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

namespace physketch::sketch::kernels {

// --- the sphere ------------------------------------------------------------------

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


// --- other convex solids --------------------------------------------------------

ConvexRows::ConvexRows(const Solid& solid, const GridMapping& m) {
  const double h = m.voxelSize();
  const Mat3 Rt = solid.rotation.transpose();
  const Vec3 o = Rt * (m.toWorld(Vec3i(0, 0, 0)) - solid.centre);
  const Vec3 vj = Rt * Vec3(0, h, 0), vk = Rt * Vec3(0, 0, h), vd = Rt * Vec3(h, 0, 0);
  for (int i = 0; i < 3; ++i) o00[i] = o[i], dj[i] = vj[i], dk[i] = vk[i], d[i] = vd[i];
  switch (solid.shape) {
    case SolidShape::kCube: shape = Shape::kBox, half[0] = half[1] = half[2] = solid.a; break;
    case SolidShape::kBox: shape = Shape::kBox, half[0] = solid.a, half[1] = solid.b, half[2] = solid.c; break;
    case SolidShape::kEllipsoid:
      shape = Shape::kEllipsoid, r2 = 1.0;
      w[0] = 1.0 / (solid.a * solid.a), w[1] = 1.0 / (solid.b * solid.b), w[2] = 1.0 / (solid.c * solid.c);
      break;
    case SolidShape::kCylinder: shape = Shape::kCylinder, r2 = solid.a * solid.a, half[2] = solid.b; break;
    case SolidShape::kCapsule: shape = Shape::kCapsule, r2 = solid.a * solid.a, half[2] = solid.b; break;
    case SolidShape::kSphere:
    case SolidShape::kTorus:
      throw std::logic_error("ConvexRows: the sphere and the torus have rasterizers of their own");
  }
  for (int i = 0; i < 3; ++i) {
    flatD[i] = std::abs(d[i]) < 1e-300;
    invD[i] = flatD[i] ? 0.0 : 1.0 / d[i];
  }
  A = shape == Shape::kEllipsoid ? (w[0] * d[0] * d[0] + w[1] * d[1] * d[1]) + w[2] * d[2] * d[2]
                                 : d[0] * d[0] + d[1] * d[1];
  flatA = A < 1e-300;
  invA = flatA ? 0.0 : 1.0 / A;
  A3 = (d[0] * d[0] + d[1] * d[1]) + d[2] * d[2];
  invA3 = 1.0 / A3;
}

namespace {

constexpr double kBig = 1e300;  // an unbounded chord end; (kBig, -kBig) is the empty chord

// min/max as the SSE/AVX instructions define them, so both forms round alike.
inline double vmin(double a, double b) { return a < b ? a : b; }
inline double vmax(double a, double b) { return a > b ? a : b; }

// The chord where |o_i + t d_i| <= half, intersected into [t0, t1].
inline void slab(const ConvexRows& c, int i, double oi, double& t0, double& t1) {
  double a, b;
  if (c.flatD[i]) {
    const bool in = std::abs(oi) <= c.half[i];
    a = in ? -kBig : kBig, b = in ? kBig : -kBig;
  } else {
    const double ta = (-c.half[i] - oi) * c.invD[i], tb = (c.half[i] - oi) * c.invD[i];
    a = vmin(ta, tb), b = vmax(ta, tb);
  }
  t0 = vmax(t0, a), t1 = vmin(t1, b);
}

// The roots of A t^2 + 2 hB t + C = 0 (the chord where the quadric is <= 0), or the
// empty chord. `flat`: A is zero, the chord is everything or nothing.
inline void roots(double hB, double C, double A, double invA, bool flat, double& a, double& b) {
  if (flat) {
    const bool in = C <= 0;
    a = in ? -kBig : kBig, b = in ? kBig : -kBig;
    return;
  }
  const double disc = hB * hB - A * C;
  const double s = std::sqrt(vmax(disc, 0.0));
  const bool in = disc >= 0;
  const double nhB = 0.0 - hB;  // as the AVX2 form computes it (-0.0 and 0 - 0 differ in sign)
  a = in ? (nhB - s) * invA : kBig, b = in ? (nhB + s) * invA : -kBig;
}

inline void convexChord(const ConvexRows& c, const double o[3], double& t0, double& t1) {
  t0 = -kBig, t1 = kBig;
  switch (c.shape) {
    case ConvexRows::Shape::kBox:
      for (int i = 0; i < 3; ++i) slab(c, i, o[i], t0, t1);
      return;
    case ConvexRows::Shape::kEllipsoid: {
      const double wo0 = c.w[0] * o[0], wo1 = c.w[1] * o[1], wo2 = c.w[2] * o[2];
      const double hB = (wo0 * c.d[0] + wo1 * c.d[1]) + wo2 * c.d[2];
      const double C = ((wo0 * o[0] + wo1 * o[1]) + wo2 * o[2]) - c.r2;
      roots(hB, C, c.A, c.invA, false, t0, t1);
      return;
    }
    case ConvexRows::Shape::kCylinder:
    case ConvexRows::Shape::kCapsule: {
      const double hB = o[0] * c.d[0] + o[1] * c.d[1];
      const double C = (o[0] * o[0] + o[1] * o[1]) - c.r2;
      roots(hB, C, c.A, c.invA, c.flatA, t0, t1);
      slab(c, 2, o[2], t0, t1);
      if (c.shape == ConvexRows::Shape::kCylinder) return;
      // The capsule is the hull of the side and two end caps: one chord, their union
      // (the side's chord made the canonical empty one first if the slab emptied it).
      const bool sideEmpty = t0 > t1;
      t0 = sideEmpty ? kBig : t0, t1 = sideEmpty ? -kBig : t1;
      for (const double zc : {-c.half[2], c.half[2]}) {
        const double oz = o[2] - zc;
        const double hB3 = hB + oz * c.d[2];
        const double C3 = ((o[0] * o[0] + o[1] * o[1]) + oz * oz) - c.r2;
        double a, b;
        roots(hB3, C3, c.A3, c.invA3, false, a, b);
        t0 = vmin(t0, a), t1 = vmax(t1, b);
      }
      return;
    }
  }
}


}  // namespace

void convexChordsScalar(const ConvexRows& c, int k, int j0, int n, int* lo, int* hi) {
  const double ob[3] = {c.o00[0] + double(k) * c.dk[0], c.o00[1] + double(k) * c.dk[1], c.o00[2] + double(k) * c.dk[2]};
  for (int t = 0; t < n; ++t) {
    const double j = double(j0 + t);
    const double o[3] = {ob[0] + j * c.dj[0], ob[1] + j * c.dj[1], ob[2] + j * c.dj[2]};
    double t0, t1;
    convexChord(c, o, t0, t1);
    lo[t] = toInt(std::ceil(t0)), hi[t] = toInt(std::floor(t1));
  }
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

namespace {

using V = __m256d;
#define PHYSKETCH_AVX2 __attribute__((target("avx2"), always_inline)) inline

PHYSKETCH_AVX2 V set1(double x) { return _mm256_set1_pd(x); }
PHYSKETCH_AVX2 V absV(V x) { return _mm256_andnot_pd(_mm256_set1_pd(-0.0), x); }

PHYSKETCH_AVX2 void slabV(const ConvexRows& c, int i, V oi, V& t0, V& t1) {
  V a, b;
  if (c.flatD[i]) {
    const V in = _mm256_cmp_pd(absV(oi), set1(c.half[i]), _CMP_LE_OQ);
    a = _mm256_blendv_pd(set1(kBig), set1(-kBig), in), b = _mm256_blendv_pd(set1(-kBig), set1(kBig), in);
  } else {
    const V ta = _mm256_mul_pd(_mm256_sub_pd(set1(-c.half[i]), oi), set1(c.invD[i]));
    const V tb = _mm256_mul_pd(_mm256_sub_pd(set1(c.half[i]), oi), set1(c.invD[i]));
    a = _mm256_min_pd(ta, tb), b = _mm256_max_pd(ta, tb);
  }
  t0 = _mm256_max_pd(t0, a), t1 = _mm256_min_pd(t1, b);
}

PHYSKETCH_AVX2 void rootsV(V hB, V C, double A, double invA, bool flat, V& a, V& b) {
  if (flat) {
    const V in = _mm256_cmp_pd(C, _mm256_setzero_pd(), _CMP_LE_OQ);
    a = _mm256_blendv_pd(set1(kBig), set1(-kBig), in), b = _mm256_blendv_pd(set1(-kBig), set1(kBig), in);
    return;
  }
  const V disc = _mm256_sub_pd(_mm256_mul_pd(hB, hB), _mm256_mul_pd(set1(A), C));
  const V s = _mm256_sqrt_pd(_mm256_max_pd(disc, _mm256_setzero_pd()));
  const V in = _mm256_cmp_pd(disc, _mm256_setzero_pd(), _CMP_GE_OQ);
  const V nhB = _mm256_sub_pd(_mm256_setzero_pd(), hB);
  a = _mm256_blendv_pd(set1(kBig), _mm256_mul_pd(_mm256_sub_pd(nhB, s), set1(invA)), in);
  b = _mm256_blendv_pd(set1(-kBig), _mm256_mul_pd(_mm256_add_pd(nhB, s), set1(invA)), in);
}

PHYSKETCH_AVX2 void convexChordV(const ConvexRows& c, const V o[3], V& t0, V& t1) {
  t0 = set1(-kBig), t1 = set1(kBig);
  switch (c.shape) {
    case ConvexRows::Shape::kBox:
      for (int i = 0; i < 3; ++i) slabV(c, i, o[i], t0, t1);
      return;
    case ConvexRows::Shape::kEllipsoid: {
      const V wo0 = _mm256_mul_pd(set1(c.w[0]), o[0]), wo1 = _mm256_mul_pd(set1(c.w[1]), o[1]);
      const V wo2 = _mm256_mul_pd(set1(c.w[2]), o[2]);
      const V hB = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(wo0, set1(c.d[0])), _mm256_mul_pd(wo1, set1(c.d[1]))),
                                 _mm256_mul_pd(wo2, set1(c.d[2])));
      const V C = _mm256_sub_pd(
          _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(wo0, o[0]), _mm256_mul_pd(wo1, o[1])), _mm256_mul_pd(wo2, o[2])),
          set1(c.r2));
      rootsV(hB, C, c.A, c.invA, false, t0, t1);
      return;
    }
    case ConvexRows::Shape::kCylinder:
    case ConvexRows::Shape::kCapsule: {
      const V hB = _mm256_add_pd(_mm256_mul_pd(o[0], set1(c.d[0])), _mm256_mul_pd(o[1], set1(c.d[1])));
      const V rho2 = _mm256_add_pd(_mm256_mul_pd(o[0], o[0]), _mm256_mul_pd(o[1], o[1]));
      rootsV(hB, _mm256_sub_pd(rho2, set1(c.r2)), c.A, c.invA, c.flatA, t0, t1);
      slabV(c, 2, o[2], t0, t1);
      if (c.shape == ConvexRows::Shape::kCylinder) return;
      const V sideEmpty = _mm256_cmp_pd(t0, t1, _CMP_GT_OQ);
      t0 = _mm256_blendv_pd(t0, set1(kBig), sideEmpty), t1 = _mm256_blendv_pd(t1, set1(-kBig), sideEmpty);
      for (const double zc : {-c.half[2], c.half[2]}) {
        const V oz = _mm256_sub_pd(o[2], set1(zc));
        const V hB3 = _mm256_add_pd(hB, _mm256_mul_pd(oz, set1(c.d[2])));
        const V C3 = _mm256_sub_pd(_mm256_add_pd(rho2, _mm256_mul_pd(oz, oz)), set1(c.r2));
        V a, b;
        rootsV(hB3, C3, c.A3, c.invA3, false, a, b);
        t0 = _mm256_min_pd(t0, a), t1 = _mm256_max_pd(t1, b);
      }
      return;
    }
  }
}

PHYSKETCH_AVX2 __m128i toIntV(V x) {
  return _mm256_cvttpd_epi32(_mm256_min_pd(_mm256_max_pd(x, set1(-1e9)), set1(1e9)));
}

#undef PHYSKETCH_AVX2
}  // namespace

__attribute__((target("avx2"))) void convexChordsAvx2(const ConvexRows& c, int k, int j0, int n, int* lo, int* hi) {
  const double kk = double(k);
  const V ob[3] = {set1(c.o00[0] + kk * c.dk[0]), set1(c.o00[1] + kk * c.dk[1]), set1(c.o00[2] + kk * c.dk[2])};
  // Lanes past n compute rows that are not asked for; the arrays are padded for them.
  for (int t = 0; t < n; t += 4) {
    const V j = _mm256_add_pd(set1(double(j0 + t)), _mm256_setr_pd(0, 1, 2, 3));
    const V o[3] = {_mm256_add_pd(ob[0], _mm256_mul_pd(j, set1(c.dj[0]))),
                    _mm256_add_pd(ob[1], _mm256_mul_pd(j, set1(c.dj[1]))),
                    _mm256_add_pd(ob[2], _mm256_mul_pd(j, set1(c.dj[2])))};
    V t0, t1;
    convexChordV(c, o, t0, t1);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(lo + t), toIntV(_mm256_ceil_pd(t0)));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(hi + t), toIntV(_mm256_floor_pd(t1)));
  }
}
#else
bool markPlaneAvx2(std::uint64_t* rows, int n, const int* c0, const int* c1, int lo, int hi) {
  return markPlaneScalar(rows, n, c0, c1, lo, hi);
}
void sphereChordsAvx2(double gx, double gy, double ek, double r2, double ra2, int j0, int n, int* lo, int* hi) {
  sphereChordsScalar(gx, gy, ek, r2, ra2, j0, n, lo, hi);
}
void convexChordsAvx2(const ConvexRows& c, int k, int j0, int n, int* lo, int* hi) {
  convexChordsScalar(c, k, j0, n, lo, hi);
}
bool hasAvx2() { return false; }
#endif


}  // namespace physketch::sketch::kernels
