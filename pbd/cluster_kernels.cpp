// Clustered shape matching's member loops (cluster_kernels.h), eight members a lane group.
// Compiled with -Wno-psabi (pbd/CMakeLists.txt): the lane helpers take 32-byte vectors, which
// GCC notes changes the ABI of a function compiled without AVX; they are always inlined and
// never cross a call.
#include "pbd/cluster_kernels.h"

// The two forms give equal bits only with IEEE operations kept as written (the project builds
// with -ffp-contract=off); -ffast-math would let GCC reassociate them differently in each.
#ifdef __FAST_MATH__
#error "cluster_kernels.cpp needs IEEE arithmetic: build without -ffast-math"
#endif

#include <cmath>
#include <cstring>

namespace physketch::pbd::detail {
namespace {

typedef float F8 __attribute__((vector_size(32)));
typedef std::int32_t I8 __attribute__((vector_size(32)));
constexpr int kL = 8;

#define PHYSKETCH_CLUSTER_INLINE __attribute__((always_inline)) inline

PHYSKETCH_CLUSTER_INLINE F8 splat(float s) { return F8{s, s, s, s, s, s, s, s}; }

// Eight values by index, built in registers (a store of scalars then a vector load would stall
// on store forwarding).
PHYSKETCH_CLUSTER_INLINE F8 gather(const float* a, const std::int32_t (&i)[kL]) {
  return F8{a[i[0]], a[i[1]], a[i[2]], a[i[3]], a[i[4]], a[i[5]], a[i[6]], a[i[7]]};
}
// Eight consecutive values from k on, 0 past hi.
PHYSKETCH_CLUSTER_INLINE F8 run(const float* a, std::int32_t k, std::int32_t hi) {
  F8 r;
  if (k + kL <= hi) {
    std::memcpy(&r, a + k, sizeof r);
    return r;
  }
  float t[kL] = {};
  for (std::int32_t j = 0; j < hi - k; ++j) t[j] = a[k + j];
  std::memcpy(&r, t, sizeof r);
  return r;
}
PHYSKETCH_CLUSTER_INLINE void store(float* a, std::int32_t k, std::int32_t hi, F8 r) {
  if (k + kL <= hi) {
    std::memcpy(a + k, &r, sizeof r);
    return;
  }
  for (std::int32_t j = 0; j < hi - k; ++j) a[k + j] = r[j];
}

// Members [k, k + 8) clipped at hi: their particles' fields and their own, 0 in lanes past hi
// (which read the first member's particle, then masked).
struct Lanes {
  F8 x, y, z, m, w, qx, qy, qz;
  I8 live;  // -1 in lanes of real members
};
// kWithW: the inverse masses too (the corrections'; the moments never read w, which a view for
// them may leave null).
template <bool kWithW>
PHYSKETCH_CLUSTER_INLINE Lanes load(const ClusterView& v, std::int32_t k, const float (&p0)[3]) {
  std::int32_t i[kL];
  I8 live;
  for (int j = 0; j < kL; ++j) {
    const bool in = k + j < v.hi;
    i[j] = v.idx[in ? k + j : v.lo];
    live[j] = in ? -1 : 0;
  }
  const F8 zero = splat(0.0f);
  Lanes l;
  l.live = live;
  l.x = live ? gather(v.x, i) - splat(p0[0]) : zero;
  l.y = live ? gather(v.y, i) - splat(p0[1]) : zero;
  l.z = live ? gather(v.z, i) - splat(p0[2]) : zero;
  l.m = live ? gather(v.mass, i) : zero;
  l.w = zero;
  if (kWithW) l.w = live ? gather(v.w, i) : zero;
  l.qx = run(v.qx, k, v.hi);
  l.qy = run(v.qy, k, v.hi);
  l.qz = run(v.qz, k, v.hi);
  return l;
}

PHYSKETCH_CLUSTER_INLINE double laneSum(F8 s) {
  double t = 0.0;
  for (int j = 0; j < kL; ++j) t += double(s[j]);
  return t;
}

PHYSKETCH_CLUSTER_INLINE ClusterMoments momentsLanes(const ClusterView& v, const float (&p0)[3]) {
  const F8 zero = splat(0.0f);
  F8 m = zero, s[3] = {zero, zero, zero}, qs[3] = {zero, zero, zero};
  F8 a[9] = {zero, zero, zero, zero, zero, zero, zero, zero, zero};
  for (std::int32_t k = v.lo; k < v.hi; k += kL) {
    const Lanes l = load<false>(v, k, p0);
    const F8 d[3] = {l.m * l.x, l.m * l.y, l.m * l.z};
    const F8 q[3] = {l.qx, l.qy, l.qz};
    m += l.m;
    for (int r = 0; r < 3; ++r) {
      s[r] += d[r];
      qs[r] += l.m * q[r];
      for (int c = 0; c < 3; ++c) a[3 * r + c] += d[r] * q[c];
    }
  }
  ClusterMoments out;
  out.m = laneSum(m);
  for (int r = 0; r < 3; ++r) {
    out.s[r] = laneSum(s[r]);
    out.qs[r] = laneSum(qs[r]);
  }
  for (int e = 0; e < 9; ++e) out.a[e] = laneSum(a[e]);
  return out;
}

PHYSKETCH_CLUSTER_INLINE void correctionsLanes(const ClusterView& v, const float (&p0)[3], const float (&R)[9],
                                               const float (&o)[3], float alpha, double (&net)[3], double& mDyn) {
  const F8 zero = splat(0.0f), al = splat(alpha);
  F8 n[3] = {zero, zero, zero}, md = zero;
  for (std::int32_t k = v.lo; k < v.hi; k += kL) {
    const Lanes l = load<true>(v, k, p0);
    F8 d[3];
    const F8 q[3] = {l.qx, l.qy, l.qz};
    const F8 p[3] = {l.x, l.y, l.z};
    for (int r = 0; r < 3; ++r)
      d[r] = p[r] - ((splat(R[3 * r]) * q[0] + splat(R[3 * r + 1]) * q[1] + splat(R[3 * r + 2]) * q[2]) + splat(o[r]));
    const F8 c2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    F8 C;
    for (int j = 0; j < kL; ++j) C[j] = std::sqrt(c2[j]);  // one vsqrtps (-fno-math-errno)
    const I8 dyn = l.live & (l.w > zero);
    const I8 act = dyn & (C > zero);
    // Lanes without a correction divide by 1 and are masked to 0 after.
    const F8 lam = run(v.lambda, k, v.hi);
    const F8 one = splat(1.0f);
    const F8 den = act ? l.w + al : one;
    const F8 dl = (-C - al * lam) / den;
    const F8 sc = act ? l.w * dl / (act ? C : one) : zero;
    const F8 lamNew = act ? lam + dl : lam;
    md += dyn ? l.m : zero;
    for (int r = 0; r < 3; ++r) {
      const F8 dp = sc * d[r];
      n[r] += l.m * dp;
      d[r] = dp;
    }
    store(v.lambda, k, v.hi, lamNew);
    for (std::int32_t j = 0; j < kL && k + j < v.hi; ++j) {
      const std::size_t at = std::size_t(k + j - v.lo);
      v.dx[at] = dyn[j] ? d[0][j] : 0.0f;
      v.dy[at] = dyn[j] ? d[1][j] : 0.0f;
      v.dz[at] = dyn[j] ? d[2][j] : 0.0f;
    }
  }
  for (int r = 0; r < 3; ++r) net[r] = laneSum(n[r]);
  mDyn = laneSum(md);
}

__attribute__((target("avx2"))) ClusterMoments momentsAvx2(const ClusterView& v, const float (&p0)[3]) {
  return momentsLanes(v, p0);
}
ClusterMoments momentsSse(const ClusterView& v, const float (&p0)[3]) { return momentsLanes(v, p0); }

__attribute__((target("avx2"))) void correctionsAvx2(const ClusterView& v, const float (&p0)[3], const float (&R)[9],
                                                     const float (&o)[3], float alpha, double (&net)[3], double& mDyn) {
  correctionsLanes(v, p0, R, o, alpha, net, mDyn);
}
void correctionsSse(const ClusterView& v, const float (&p0)[3], const float (&R)[9], const float (&o)[3], float alpha,
                    double (&net)[3], double& mDyn) {
  correctionsLanes(v, p0, R, o, alpha, net, mDyn);
}

}  // namespace

Vec3 ClusterMoments::offset() const { return Vec3(s[0], s[1], s[2]) / m; }

Mat3 ClusterMoments::matrix() const {
  const Vec3 o = offset();
  Mat3 A;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) A(r, k) = a[3 * r + k] - o[r] * qs[k];
  return A;
}

ClusterMoments clusterMoments(const ClusterView& v, const float (&p0)[3], bool avx2) {
  return avx2 ? momentsAvx2(v, p0) : momentsSse(v, p0);
}

void clusterCorrections(const ClusterView& v, const float (&p0)[3], const float (&R)[9], const float (&o)[3], float alpha,
                        double (&net)[3], double& mDyn, bool avx2) {
  if (avx2) correctionsAvx2(v, p0, R, o, alpha, net, mDyn);
  else correctionsSse(v, p0, R, o, alpha, net, mDyn);
}

}  // namespace physketch::pbd::detail
