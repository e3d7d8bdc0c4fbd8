// The per-member loops of clustered shape matching (PbdWorld::clusterMatch), internal to pbd/:
// a cluster's mass moments, and its members' XPBD corrections towards their goals. Both run
// eight members at a time in float lanes (GCC vectors: one AVX2 register where the CPU has it,
// two SSE ones otherwise), each lane the same IEEE operations in the same order either way, so
// the two forms give equal bits for finite values (a NaN's sign or payload may differ); the
// lanes' sums are added into doubles in lane order.
#pragma once

#include <cstdint>

#include "core/math.h"

namespace physketch::pbd::detail {

// One cluster's members [lo, hi) of the membership arrays, and the particles they index.
struct ClusterView {
  const std::int32_t* idx = nullptr;  // per membership: particle id
  const float* qx = nullptr;          // per membership: rest offset from the cluster's rest centre (m)
  const float* qy = nullptr;
  const float* qz = nullptr;
  float* lambda = nullptr;            // per membership: XPBD multiplier of this substep
  const float* x = nullptr;           // per particle: predicted position (m)
  const float* y = nullptr;
  const float* z = nullptr;
  const float* mass = nullptr;        // per particle (kg)
  const float* w = nullptr;           // per particle: inverse mass (1/kg), 0 = not moved (clusterCorrections only)
  // Per membership from lo (clusterCorrections only): the member's correction dp, 0 for a fixed
  // member. The caller adds it to the position together with the net-momentum shift.
  float* dx = nullptr;
  float* dy = nullptr;
  float* dz = nullptr;
  std::int32_t lo = 0, hi = 0;
};

// Relative to a reference point p0 (the caller's: the first member's position):
//   m = sum m_k, s = sum m_k (p_k - p0), qs = sum m_k q_k, a(r, c) = sum m_k (p_k - p0)_r q_k,c
// so that the centre is p0 + s / m and A = sum m (p - centre) q^T = a - (s / m) qs^T.
struct ClusterMoments {
  double m = 0.0;
  double s[3] = {0.0, 0.0, 0.0};
  double qs[3] = {0.0, 0.0, 0.0};
  double a[9] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};  // row-major
  Vec3 offset() const;  // the centre relative to p0: s / m
  Mat3 matrix() const;  // A = a - offset() qs^T
};
// v.lambda and v.w may be null here.
ClusterMoments clusterMoments(const ClusterView& v, const float (&p0)[3], bool avx2);

// Per member k with w > 0: d = (p_k - p0) - (R q_k + o), C = |d|, and where C > 0
//   dlambda = (-C - alpha lambda_k) / (w + alpha), lambda_k += dlambda, dp_k = (w dlambda / C) d
// (0 elsewhere), written to v.dx, v.dy, v.dz; the positions are not moved. The corrections are
// computed from the same positions (Jacobi within the cluster). R row-major, o = centre - p0,
// alpha = compliance / h^2. Returns in net the sum of m_k dp_k and in mDyn the mass of the
// members with w > 0.
void clusterCorrections(const ClusterView& v, const float (&p0)[3], const float (&R)[9], const float (&o)[3], float alpha,
                        double (&net)[3], double& mDyn, bool avx2);

}  // namespace physketch::pbd::detail
