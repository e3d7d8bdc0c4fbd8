// XPBD distance constraints against closed forms: an inextensible link is restored in one
// sweep with the mass-weighted split; a hanging mass on a compliant link settles at the
// spring's static extension m g alpha whatever the iteration count (XPBD's point). The member
// loops of clustered shape matching against a double brute force, and their two forms' bits.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>
#include <random>
#include <vector>

#include <Eigen/Geometry>

#include "pbd/cluster_kernels.h"
#include "pbd/constraints.h"

using namespace physketch::pbd;

TEST(Constraints, InextensibleLinkIsRestoredInOneSweepSplitByInverseMass) {
  // Stretched from 1.0 to 1.3 along x; w_a = 1, w_b = 2: a moves 0.1, b moves 0.2.
  float px[2] = {0.0f, 1.3f}, py[2] = {0, 0}, pz[2] = {0, 0};
  const float w[2] = {1.0f, 2.0f};
  DistanceConstraints c;
  c.add(0, 1, 1.0f, 0.0f);
  solveDistances(c, px, py, pz, w, 0.01);
  EXPECT_NEAR(px[0], 0.1f, 1e-6);
  EXPECT_NEAR(px[1], 1.1f, 1e-6);
  EXPECT_NEAR(px[1] - px[0], 1.0f, 1e-6);
}

TEST(Constraints, HangingMassSettlesAtTheSpringExtensionWhateverTheIterations) {
  // A 0.2 kg particle hangs 0.5 m under a fixed one on a link of compliance alpha: the
  // static extension is m g' alpha (k = 1/alpha), g' = 0.995 g because the test damps the
  // velocity by 0.5 % per substep (the equilibrium's predicted step is 0.995 g h^2). XPBD
  // makes the stiffness independent of the iteration count; plain PBD's grows with it.
  // 10 s of damped motion settles well below the tolerance, 0.5 % of the extension.
  const double m = 0.2, g = 9.81, alpha = 0.01, h = 1.0 / 600.0;
  const double expect = m * 0.995 * g * alpha;  // 19.5 mm
  for (int iterations : {1, 10}) {
    float x[2] = {0, 0}, y[2] = {1.0f, 0.5f}, z[2] = {0, 0};
    float vy = 0.0f;
    const float w[2] = {0.0f, float(1.0 / m)};
    DistanceConstraints c;
    c.add(0, 1, 0.5f, float(alpha));
    for (int s = 0; s < 6000; ++s) {
      vy = 0.995f * (vy - float(g * h));
      float px[2] = {x[0], x[1]}, py[2] = {y[0], float(y[1] + vy * h)}, pz[2] = {0, 0};
      c.resetMultipliers();
      for (int it = 0; it < iterations; ++it) solveDistances(c, px, py, pz, w, h);
      vy = float((py[1] - y[1]) / h);
      y[1] = py[1];
      (void)z;
    }
    EXPECT_NEAR(y[0] - y[1] - 0.5, expect, 0.005 * expect) << iterations << " iterations";
  }
}

TEST(Constraints, ClustersAreOverlappingIndexLists) {
  Clusters c;
  c.add({0, 1, 2}, 1.0f);
  c.add({2, 3}, 0.5f);
  ASSERT_EQ(c.size(), 2u);
  EXPECT_EQ(c.offset, (std::vector<std::int32_t>{0, 3, 5}));
  EXPECT_EQ(c.index[3], 2);  // particle 2 is in both
}

// --- clustered shape matching's member loops (pbd/cluster_kernels.h) ----------------------

namespace {

// Random clusters of 1-40 members (every tail length of the 8-lane groups) about 0.5 m with
// offsets of a few cm, as a soft body's; a few members fixed (w = 0).
struct KernelCase {
  std::vector<std::int32_t> idx;
  std::vector<float> qx, qy, qz, lambda, x, y, z, mass, w;
  std::vector<float> dx, dy, dz;  // per member of the cluster: the corrections clusterCorrections writes
  float p0[3] = {0, 0, 0};
  float R[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
  float o[3] = {0, 0, 0};
  float alpha = 0;
  int lo = 0;  // the cluster's first membership
};

KernelCase kernelCase(int members, std::mt19937& rng) {
  std::uniform_real_distribution<float> u(-0.03f, 0.03f), m(1e-3f, 2e-3f), l(-1e-4f, 1e-4f);
  KernelCase c;
  const int particles = members + 5;  // members index a shuffled subset
  for (int i = 0; i < particles; ++i) {
    c.x.push_back(0.5f + u(rng)), c.y.push_back(0.4f + u(rng)), c.z.push_back(0.6f + u(rng));
    c.mass.push_back(m(rng));
    c.w.push_back(i % 7 == 3 ? 0.0f : 1.0f / c.mass.back());
  }
  std::vector<std::int32_t> ids(static_cast<std::size_t>(particles));
  std::iota(ids.begin(), ids.end(), 0);
  std::shuffle(ids.begin(), ids.end(), rng);
  // The cluster starts at membership lo = members % 5 (a world's clusters lie one after another
  // in the membership arrays): lo earlier memberships belong to another cluster.
  c.lo = members % 5;
  for (int k = 0; k < c.lo + members; ++k) {
    c.idx.push_back(ids[static_cast<std::size_t>(k % members)]);
    c.qx.push_back(u(rng)), c.qy.push_back(u(rng)), c.qz.push_back(u(rng));
    c.lambda.push_back(l(rng));
  }
  const auto f = static_cast<std::size_t>(c.idx[std::size_t(c.lo)]);
  c.p0[0] = c.x[f], c.p0[1] = c.y[f], c.p0[2] = c.z[f];
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  for (int e = 0; e < 9; ++e) c.R[e] = float(R(e / 3, e % 3));
  c.o[0] = u(rng), c.o[1] = u(rng), c.o[2] = u(rng);
  c.alpha = 0.3f;
  c.dx.assign(std::size_t(members), -1.0f), c.dy = c.dx, c.dz = c.dx;  // -1: not written
  return c;
}

detail::ClusterView view(KernelCase& c) {
  detail::ClusterView v;
  v.idx = c.idx.data();
  v.qx = c.qx.data(), v.qy = c.qy.data(), v.qz = c.qz.data();
  v.lambda = c.lambda.data();
  v.x = c.x.data(), v.y = c.y.data(), v.z = c.z.data();
  v.mass = c.mass.data(), v.w = c.w.data();
  v.dx = c.dx.data(), v.dy = c.dy.data(), v.dz = c.dz.data();
  v.lo = c.lo, v.hi = static_cast<std::int32_t>(c.idx.size());
  return v;
}

}  // namespace

TEST(ClusterKernels, MomentsAndCorrectionsMatchADoubleBruteForce) {
  // The oracle: the sums and the XPBD update of cluster_kernels.h written out member by member
  // in double. Tolerance 1e-5 of the sum of the terms' magnitudes: the lanes work in float
  // (6e-8 relative per operation) over at most 5 members a lane, then add the lanes in double.
  std::mt19937 rng(21);
  for (int members = 1; members <= 40; ++members) {
    KernelCase c = kernelCase(members, rng);
    const std::vector<float> lambda0 = c.lambda;
    const KernelCase before = c;
    detail::ClusterView v = view(c);
    // The moments read neither w nor lambda (plasticity's view has neither).
    detail::ClusterView bare = v;
    bare.w = nullptr, bare.lambda = nullptr;
    const detail::ClusterMoments mo = detail::clusterMoments(bare, c.p0, false);
    double m = 0, s[3] = {0, 0, 0}, qs[3] = {0, 0, 0}, a[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0}, scale = 0;
    for (int k = c.lo; k < c.lo + members; ++k) {
      const auto i = static_cast<std::size_t>(c.idx[std::size_t(k)]);
      const double mi = c.mass[i];
      const double d[3] = {double(c.x[i]) - c.p0[0], double(c.y[i]) - c.p0[1], double(c.z[i]) - c.p0[2]};
      const double q[3] = {c.qx[std::size_t(k)], c.qy[std::size_t(k)], c.qz[std::size_t(k)]};
      m += mi;
      for (int r = 0; r < 3; ++r) {
        s[r] += mi * d[r], qs[r] += mi * q[r];
        for (int e = 0; e < 3; ++e) a[3 * r + e] += mi * d[r] * q[e];
        scale += mi * 0.03;
      }
    }
    const double tol = 1e-5 * scale;
    EXPECT_NEAR(mo.m, m, 1e-6 * m) << members;
    for (int r = 0; r < 3; ++r) {
      EXPECT_NEAR(mo.s[r], s[r], tol) << members;
      EXPECT_NEAR(mo.qs[r], qs[r], tol) << members;
    }
    for (int e = 0; e < 9; ++e) EXPECT_NEAR(mo.a[e], a[e], tol * 0.03) << members << " a" << e;

    double net[3], mDyn = 0;
    detail::clusterCorrections(v, c.p0, c.R, c.o, c.alpha, net, mDyn, false);
    double rnet[3] = {0, 0, 0}, rm = 0;
    for (int k = c.lo; k < c.lo + members; ++k) {
      const auto kk = std::size_t(k);
      const auto i = static_cast<std::size_t>(c.idx[kk]);
      const double wi = c.w[i];
      const auto at = std::size_t(k - c.lo);
      const double got[3] = {c.dx[at], c.dy[at], c.dz[at]};
      EXPECT_EQ(c.x, before.x) << "the positions are the caller's to move";
      if (wi == 0.0) {
        EXPECT_EQ(got[0], 0.0) << members;
        EXPECT_EQ(got[1], 0.0) << members;
        EXPECT_EQ(got[2], 0.0) << members;
        EXPECT_EQ(c.lambda[kk], lambda0[kk]) << members;
        continue;
      }
      const double q[3] = {c.qx[kk], c.qy[kk], c.qz[kk]};
      const double p[3] = {double(before.x[i]) - c.p0[0], double(before.y[i]) - c.p0[1], double(before.z[i]) - c.p0[2]};
      double d[3], C2 = 0;
      for (int r = 0; r < 3; ++r) {
        d[r] = p[r] - (double(c.R[3 * r]) * q[0] + double(c.R[3 * r + 1]) * q[1] + double(c.R[3 * r + 2]) * q[2] + c.o[r]);
        C2 += d[r] * d[r];
      }
      const double C = std::sqrt(C2);
      const double dl = (-C - double(c.alpha) * lambda0[kk]) / (wi + c.alpha);
      EXPECT_NEAR(c.lambda[kk], lambda0[kk] + dl, 1e-5 * (std::abs(lambda0[kk]) + std::abs(dl))) << members;
      for (int r = 0; r < 3; ++r) {
        const double want = wi * dl / C * d[r];
        EXPECT_NEAR(got[r], want, 1e-5 * C) << members << " member " << k;
        rnet[r] += c.mass[i] * want;
      }
      rm += c.mass[i];
    }
    for (int k = 0; k < c.lo; ++k) EXPECT_EQ(c.lambda[std::size_t(k)], lambda0[std::size_t(k)]) << "another cluster's";
    EXPECT_NEAR(mDyn, rm, 1e-6 * rm) << members;
    for (int r = 0; r < 3; ++r) EXPECT_NEAR(net[r], rnet[r], 1e-5 * rm * 0.1) << members;
  }
}

TEST(ClusterKernels, Avx2AndSseFormsGiveEqualBits) {
  // The two forms must do the same IEEE operations lane for lane (PbdWorld picks one by the CPU;
  // a scene's result must not depend on which).
  if (!__builtin_cpu_supports("avx2")) GTEST_SKIP() << "no AVX2 on this CPU";
  std::mt19937 rng(4);
  for (int members = 1; members <= 40; ++members) {
    KernelCase a = kernelCase(members, rng), b = a;
    const detail::ClusterView va = view(a), vb = view(b);
    const detail::ClusterMoments ma = detail::clusterMoments(va, a.p0, true), mb = detail::clusterMoments(vb, b.p0, false);
    EXPECT_EQ(std::memcmp(&ma, &mb, sizeof ma), 0) << members;
    double na[3], nb[3], da = 0, db = 0;
    detail::clusterCorrections(va, a.p0, a.R, a.o, a.alpha, na, da, true);
    detail::clusterCorrections(vb, b.p0, b.R, b.o, b.alpha, nb, db, false);
    EXPECT_EQ(std::memcmp(na, nb, sizeof na), 0) << members;
    EXPECT_EQ(da, db) << members;
    const auto same = [](const std::vector<float>& p, const std::vector<float>& q) {  // bits, not ==
      return p.size() == q.size() && std::memcmp(p.data(), q.data(), p.size() * sizeof(float)) == 0;
    };
    EXPECT_TRUE(same(a.dx, b.dx)) << members;
    EXPECT_TRUE(same(a.dy, b.dy)) << members;
    EXPECT_TRUE(same(a.dz, b.dz)) << members;
    EXPECT_TRUE(same(a.lambda, b.lambda)) << members;
  }
}
