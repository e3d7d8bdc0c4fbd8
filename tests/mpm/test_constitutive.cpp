// Stresses, the 3x3 SVD and return maps against independent oracles (Eigen's JacobiSVD in double for the SVD): the energy densities of the papers
// (differentiated by finite differences), the Drucker-Prager cone equation, and the closed
// forms of the snow clamp.
#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include "mpm/constitutive.h"
#include "mpm/plasticity.h"
#include "mpm/svd3.h"

using namespace physketch::mpm;
using M3 = Eigen::Matrix3d;
using V3 = Eigen::Vector3d;

namespace {

// Energy densities written from the papers, not from the solver's code.
// Fixed corotated, Stomakhin et al. 2012 Eq. 2: psi = mu sum (sigma_i - 1)^2 + lambda/2 (J - 1)^2.
double psiCorotated(const M3& F, double mu, double lambda) {
  Eigen::JacobiSVD<M3> svd(F);
  const V3 s = svd.singularValues();  // F has det > 0 in these tests: all sigma_i > 0 are the principal stretches
  const double J = F.determinant();
  return mu * ((s.array() - 1.0).square().sum()) + 0.5 * lambda * (J - 1.0) * (J - 1.0);
}
// Neo-Hookean, Bonet & Wood Eq. 6.27: psi = mu/2 (tr(F^T F) - 3) - mu ln J + lambda/2 (ln J)^2.
double psiNeoHookean(const M3& F, double mu, double lambda) {
  const double lnJ = std::log(F.determinant());
  return 0.5 * mu * ((F.transpose() * F).trace() - 3.0) - mu * lnJ + 0.5 * lambda * lnJ * lnJ;
}

// dpsi/dF by central differences, step e: truncation error O(e^2 psi''') ~ 1e-10 relative here.
template <class Psi>
M3 numericP(const M3& F, Psi psi) {
  const double e = 1e-6;
  M3 P;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      M3 a = F, b = F;
      a(r, c) += e;
      b(r, c) -= e;
      P(r, c) = (psi(a) - psi(b)) / (2.0 * e);
    }
  return P;
}

// Random deformation gradients with det F in about [0.6, 1.6]: rotation * stretch * rotation.
std::vector<M3> randomF(int n) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> s(0.8, 1.2), a(-3.0, 3.0);
  std::vector<M3> out;
  for (int k = 0; k < n; ++k) {
    const M3 R1 = Eigen::AngleAxisd(a(rng), V3(a(rng), a(rng), a(rng)).normalized()).toRotationMatrix();
    const M3 R2 = Eigen::AngleAxisd(a(rng), V3(a(rng), a(rng), a(rng)).normalized()).toRotationMatrix();
    out.push_back(R1 * V3(s(rng), s(rng), s(rng)).asDiagonal() * R2);
  }
  return out;
}

const double kMu = 3.0e5, kLambda = 4.5e5;  // Pa (E ~ 7.8e5, nu = 0.3)

}  // namespace

// P = tau F^-T must be dpsi/dF. Tolerance 1e-6 relative to |P|: the finite-difference error
// (e = 1e-6 on entries of order 1) and the cancellation in psi(a) - psi(b) (psi ~ 1e4 Pa,
// double eps 1e-16 -> 1e-12 / 2e-6 ~ 1e-6 Pa absolute) are both far below it.
TEST(MpmConstitutive, CorotatedKirchhoffIsTheDerivativeOfTheStomakhinEnergy) {
  for (const M3& F : randomF(50)) {
    const M3 P = corotatedKirchhoff<double>(F, kMu, kLambda) * F.inverse().transpose();
    const M3 ref = numericP(F, [](const M3& G) { return psiCorotated(G, kMu, kLambda); });
    EXPECT_LT((P - ref).norm(), 1e-6 * ref.norm() + 1e-3) << F;
  }
}

TEST(MpmConstitutive, NeoHookeanKirchhoffIsTheDerivativeOfTheBonetWoodEnergy) {
  for (const M3& F : randomF(50)) {
    const M3 P = neoHookeanKirchhoff<double>(F, kMu, kLambda) * F.inverse().transpose();
    const M3 ref = numericP(F, [](const M3& G) { return psiNeoHookean(G, kMu, kLambda); });
    EXPECT_LT((P - ref).norm(), 1e-6 * ref.norm() + 1e-3) << F;
  }
}

TEST(MpmConstitutive, StressVanishesAtRestAndLameMatchesTheTextbook) {
  const M3 I = M3::Identity();
  EXPECT_LT(corotatedKirchhoff<double>(I, kMu, kLambda).norm(), 1e-9);
  EXPECT_LT(neoHookeanKirchhoff<double>(I, kMu, kLambda).norm(), 1e-9);
  // A rotation is stress-free for both (frame indifference).
  const M3 R = Eigen::AngleAxisd(0.7, V3(1, 2, 3).normalized()).toRotationMatrix();
  EXPECT_LT(corotatedKirchhoff<double>(R, kMu, kLambda).norm(), 1e-6);
  EXPECT_LT(neoHookeanKirchhoff<double>(R, kMu, kLambda).norm(), 1e-6);
  const Lame l = lameFromYoungs(1.0e6, 0.25);  // mu = E/2.5, lambda = E * 0.25 / (1.25 * 0.5)
  EXPECT_DOUBLE_EQ(l.mu, 4.0e5);
  EXPECT_DOUBLE_EQ(l.lambda, 4.0e5);
}

// Drucker-Prager (Klar et al. 2016, Algorithm 2). Oracles: the cone's tip for a stretched
// state, the unchanged state inside the cone, and for a sheared compressed state a result on
// the cone surface |eps_hat| + (3 lambda + 2 mu)/(2 mu) tr(eps) alpha = 0 with tr(eps) kept.
TEST(MpmPlasticity, DruckerPragerStretchedGoesToTheTipCompressedInsideStays) {
  const double alpha = druckerPragerAlpha(30.0 * M_PI / 180.0);
  EXPECT_NEAR(alpha, std::sqrt(2.0 / 3.0) * 2.0 * 0.5 / 2.5, 1e-15);  // sin 30 = 1/2
  double dq = -1.0;
  const V3 stretched(1.10, 1.05, 1.02);
  const V3 tip = druckerPragerReturn<double>(stretched, kMu, kLambda, alpha, 0.0, dq);
  EXPECT_EQ(tip, V3(1, 1, 1));
  EXPECT_NEAR(dq, stretched.array().log().matrix().norm(), 1e-15);

  const V3 inside(0.95, 0.96, 0.97);  // tr(eps) = -0.1226, |eps_hat| = 0.0147 < 3.25 * 0.1226 * 0.3266
  EXPECT_EQ(druckerPragerReturn<double>(inside, kMu, kLambda, alpha, 0.0, dq), inside);
  EXPECT_EQ(dq, 0.0);
  const V3 pure(0.9, 0.9, 0.9);  // pure compression: eps_hat = 0, inside (not the tip)
  EXPECT_EQ(druckerPragerReturn<double>(pure, kMu, kLambda, alpha, 0.0, dq), pure);

  const V3 sheared(1.2, 0.9, 0.85);  // tr(eps) < 0 but far outside the cone
  const V3 out = druckerPragerReturn<double>(sheared, kMu, kLambda, alpha, 0.0, dq);
  const V3 e0 = sheared.array().log().matrix(), e1 = out.array().log().matrix();
  EXPECT_NEAR(e1.sum(), e0.sum(), 1e-12);
  const V3 dev = e1 - V3::Constant(e1.sum() / 3.0);
  EXPECT_NEAR(dev.norm() + (3.0 * kLambda + 2.0 * kMu) / (2.0 * kMu) * e1.sum() * alpha, 0.0, 1e-12);
  EXPECT_GT(dq, 0.0);
}

TEST(MpmPlasticity, CohesionLetsSandHoldTensionUpToIt) {
  const double alpha = druckerPragerAlpha(30.0 * M_PI / 180.0);
  // A hydrostatic stretch e per axis carries the mean Kirchhoff stress (2 mu + 3 lambda) e.
  const double c = 1.0e3;  // Pa
  const double shift = cohesionStrain(c, kMu, kLambda);
  const double eBelow = 0.5 * c / (2.0 * kMu + 3.0 * kLambda), eAbove = 2.0 * c / (2.0 * kMu + 3.0 * kLambda);
  double dq = 0.0;
  const V3 below = V3::Constant(std::exp(eBelow));
  EXPECT_EQ(druckerPragerReturn<double>(below, kMu, kLambda, alpha, shift, dq), below);
  const V3 above = druckerPragerReturn<double>(V3::Constant(std::exp(eAbove)), kMu, kLambda, alpha, shift, dq);
  EXPECT_NEAR(std::log(above(0)), shift, 1e-15);  // back to the shifted tip
}

TEST(MpmPlasticity, VonMisesKeepsVolumeAndStopsOnTheYieldSurface) {
  const double tauY = 1.0e3;
  const V3 small(1.0 + 1e-4, 1.0, 1.0 - 1e-4);  // |2 mu eps_hat| ~ 85 Pa < tau_Y
  EXPECT_EQ(vonMisesReturn<double>(small, kMu, tauY), small);
  const V3 big(1.1, 0.95, 0.97);
  const V3 r = vonMisesReturn<double>(big, kMu, tauY);
  const V3 e = r.array().log().matrix();
  EXPECT_NEAR(e.sum(), big.array().log().sum(), 1e-12);  // volume kept
  EXPECT_NEAR(2.0 * kMu * (e - V3::Constant(e.sum() / 3.0)).norm(), tauY, 1e-6);  // on the surface
}

// Stomakhin et al. 2013 §5: clamp to [1 - theta_c, 1 + theta_s], J_p takes what was removed.
TEST(MpmPlasticity, SnowClampMovesTheRemovedVolumeIntoJpAndNeverOverflows) {
  double jp = 1.0;
  const V3 s(1.1, 0.9, 1.0);
  const V3 c = snowClamp<double>(s, 0.025, 0.0075, 10.0, jp);
  EXPECT_EQ(c, V3(1.0075, 0.975, 1.0));
  EXPECT_NEAR(jp, 0.99 / (1.0075 * 0.975), 1e-15);  // J = J_e J_p is kept
  // Compressed without end: J_p stops at 1 - 10/xi, so the hardening factor stays <= e^10.
  for (const double xi : {10.0, 50.0, 100.0}) {
    float jpf = 1.0f;
    for (int k = 0; k < 10000; ++k) snowClamp<float>(Eigen::Vector3f::Constant(0.9f), 0.025f, 0.0075f, float(xi), jpf);
    const float factor = snowHardening(float(xi), jpf);
    EXPECT_TRUE(std::isfinite(factor)) << xi;
    EXPECT_LE(factor, std::exp(10.0f) * 1.0001f) << xi;
    EXPECT_GT(jpf, 0.0f) << xi;
  }
  // And stretched without end: the factor stays >= e^-10 (snow never loses all stiffness).
  float jpf = 1.0f;
  for (int k = 0; k < 10000; ++k) snowClamp<float>(Eigen::Vector3f::Constant(1.1f), 0.025f, 0.0075f, 10.0f, jpf);
  EXPECT_GE(snowHardening(10.0f, jpf), std::exp(-10.0f) * 0.9999f);
}

TEST(MpmPlasticity, TaitPressureIsZeroAtRestAndPushesBackWhenCompressed) {
  const Eigen::Matrix3f Z = Eigen::Matrix3f::Zero();
  EXPECT_LT(fluidKirchhoff<float>(1.0f, Z, 1e5f, 7.0f, 0.0f).norm(), 1e-6f);
  // J = 0.99: p = K/gamma (0.99^-7 - 1) = 1e5/7 * 0.07284 = 1040.6 Pa; tau = -J p I.
  const Eigen::Matrix3f t = fluidKirchhoff<float>(0.99f, Z, 1e5f, 7.0f, 0.0f);
  const double p = 1e5 / 7.0 * (std::pow(0.99, -7.0) - 1.0);
  EXPECT_NEAR(t(0, 0), -0.99 * p, 1e-3 * p);
  EXPECT_EQ(t(0, 1), 0.0f);
}

// invPow's squaring path against pow in double: whole exponents 1..16 and fractional ones
// (pow's path), J from strongly compressed to stretched. Within 1e-6 relative: float's
// rounding over at most 8 products and a division (a few ulp of 6e-8); a wrong exponent bit
// is off by a factor J^k, over 1 % here.
TEST(MpmPlasticity, InvPowMatchesPowForWholeAndFractionalExponents) {
  for (float gamma : {1.0f, 2.0f, 3.0f, 5.0f, 7.0f, 8.0f, 13.0f, 16.0f, 1.5f, 6.9f, 17.0f})
    for (float J : {0.5f, 0.8f, 0.97f, 0.999f, 1.0f, 1.003f, 1.2f, 1.9f}) {
      const double want = std::pow(double(J), -double(gamma));
      EXPECT_NEAR(invPow(J, gamma), want, 1e-6 * want) << "J " << J << " gamma " << gamma;
    }
}

// --- svd3 (mpm/svd3.h) against Eigen's JacobiSVD in double --------------------------------

namespace {

// Matrices that break 3x3 SVDs: general (half of them inverted), near the identity (three
// nearly equal singular values, MPM's common case), exactly repeated values, rank 1 and 2,
// zero, a 1e6 spread, and inverted stretches.
std::vector<M3> hardMatrices() {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0), a(-3.0, 3.0), s(0.2, 3.0);
  const auto rot = [&] { return M3(Eigen::AngleAxisd(a(rng), V3(u(rng), u(rng), u(rng)).normalized())); };
  std::vector<M3> out;
  for (int k = 0; k < 200; ++k) out.push_back(M3::NullaryExpr([&](Eigen::Index, Eigen::Index) { return u(rng); }));
  for (int k = 0; k < 100; ++k)
    out.push_back(M3::Identity() + 1e-4 * M3::NullaryExpr([&](Eigen::Index, Eigen::Index) { return u(rng); }));
  for (int k = 0; k < 50; ++k) out.push_back(rot() * V3(1.1, 1.1, 0.9).asDiagonal() * rot());
  for (int k = 0; k < 50; ++k) out.push_back(rot() * V3(s(rng), s(rng), s(rng)).asDiagonal() * rot());
  for (int k = 0; k < 50; ++k) out.push_back(rot() * V3(s(rng), s(rng), -s(rng)).asDiagonal() * rot());
  for (int k = 0; k < 50; ++k) out.push_back(rot() * V3(1e3, 1.0, 1e-3).asDiagonal() * rot());
  for (int k = 0; k < 50; ++k) out.push_back(rot() * V3(s(rng), s(rng), 0.0).asDiagonal() * rot());
  for (int k = 0; k < 50; ++k) out.push_back(rot() * V3(s(rng), 0.0, 0.0).asDiagonal() * rot());
  // Diagonal in every order, exact and within float round-off (svd3's shortcut for them).
  const V3 diag(0.9, 1.3, 1.1);
  int perm[3] = {0, 1, 2};
  do {
    const M3 D = V3(diag(perm[0]), diag(perm[1]), diag(perm[2])).asDiagonal();
    out.push_back(D);
    out.push_back(D + 1e-8 * M3::NullaryExpr([&](Eigen::Index, Eigen::Index) { return u(rng); }));
  } while (std::next_permutation(perm, perm + 3));
  out.push_back(M3::Zero());
  out.push_back(M3::Identity());
  out.push_back(-M3::Identity());
  return out;
}

// The decomposition holds to tol (relative to |A|): A = U diag(sigma) V^T, U and V proper
// rotations, |sigma| equal to the oracle's singular values and in its (descending) order,
// and sigma_2 < 0 where det A < 0 (beyond round-off).
template <class S>
void expectSvd(const M3& A, double tol) {
  const Eigen::Matrix<S, 3, 3> As = A.cast<S>();
  const Svd3<S> d = svd3<S>(As);
  const M3 U = d.U.template cast<double>(), V = d.V.template cast<double>();
  const V3 sigma = d.sigma.template cast<double>();
  const double scale = std::max(A.norm(), 1e-300);
  const V3 oracle = Eigen::JacobiSVD<M3>(A).singularValues();
  EXPECT_LE((U * sigma.asDiagonal() * V.transpose() - A).norm(), tol * scale) << A;
  EXPECT_LE((U.transpose() * U - M3::Identity()).norm(), tol) << A;
  EXPECT_LE((V.transpose() * V - M3::Identity()).norm(), tol) << A;
  EXPECT_NEAR(U.determinant(), 1.0, tol) << A;
  EXPECT_NEAR(V.determinant(), 1.0, tol) << A;
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(std::abs(sigma(k)), oracle(k), tol * scale) << A;
  EXPECT_GE(sigma(0), 0.0);
  EXPECT_GE(sigma(1), 0.0);
  const double det = A.determinant();
  if (std::abs(det) > 1e3 * tol * scale * scale * scale) {
    EXPECT_EQ(sigma(2) < 0.0, det < 0.0) << A;
  }
}

}  // namespace

// Tolerances: double 1e-12 and float 2e-6 relative to |A| (a few tens of units in the last
// place: the rotations and the QR each add a few ulp; A^T A's conditioning moves V but not
// the reconstruction, because the QR recovers sigma from A itself).
TEST(MpmSvd3, MatchesEigensJacobiSvdOnHardMatricesInDouble) {
  for (const M3& A : hardMatrices()) expectSvd<double>(A, 1e-12);
}

TEST(MpmSvd3, MatchesEigensJacobiSvdOnHardMatricesInFloat) {
  for (const M3& A : hardMatrices()) expectSvd<float>(A, 2e-6);
}

// svd3Many (the return maps' batches, sixteen matrices at a time in vector lanes) must give
// each matrix exactly the bits svd3<float> gives it alone (the oracle, itself held to Eigen's
// SVD above), whatever its batch-mates, its lane and the batch's length: the hard matrices in
// float, random ones, near-diagonal ones (svd3Many's shortcut), all-NaN ones and ones with an
// infinite or NaN entry (there only where the NaNs are, not their sign bits), shuffled, in calls of
// every length from 1 to 9 and of 15, 16, 17 and 40 (every lane filled), on the AVX2 path
// (where the CPU has it) and the SSE2 one.
TEST(MpmSvd3, ManyAtOnceGivesEachMatrixTheBitsItGetsAlone) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<Eigen::Matrix3f> As;
  for (const M3& A : hardMatrices()) As.push_back(A.cast<float>());
  for (int k = 0; k < 200; ++k) {
    As.push_back(Eigen::Matrix3f::NullaryExpr([&](Eigen::Index, Eigen::Index) { return u(rng); }));
    As.push_back(Eigen::Matrix3f::Identity() + 1e-9f * Eigen::Matrix3f::NullaryExpr([&](Eigen::Index, Eigen::Index) {
                   return u(rng);
                 }));
  }
  As.push_back(Eigen::Matrix3f::Constant(std::nanf("")));
  for (int k = 0; k < 9; ++k) {  // one entry infinite or NaN (of either sign)
    Eigen::Matrix3f A = Eigen::Matrix3f::Identity() + 0.05f * Eigen::Matrix3f::NullaryExpr([&](Eigen::Index, Eigen::Index) {
                          return u(rng);
                        });
    A(k / 3, k % 3) = k % 3 == 0 ? std::numeric_limits<float>::infinity() : k % 3 == 1 ? -std::nanf("") : std::nanf("");
    As.push_back(A);
  }
  std::shuffle(As.begin(), As.end(), rng);
  // Every bit of U, V and sigma; where a value is NaN only that it is (a NaN's sign bit follows
  // the order the compiler gave an operation's operands, which differs between registers).
  const auto bits = [](const Svd3<float>& d) {
    std::vector<float> b(d.U.data(), d.U.data() + 9);
    b.insert(b.end(), d.V.data(), d.V.data() + 9);
    b.insert(b.end(), d.sigma.data(), d.sigma.data() + 3);
    std::vector<std::uint32_t> w(b.size());
    std::memcpy(w.data(), b.data(), b.size() * sizeof(float));
    for (std::size_t k = 0; k < b.size(); ++k)
      if (std::isnan(b[k])) w[k] = 0x7fc00000u;
    return w;
  };
  int swept = 0;
  for (bool avx2 : {true, false}) {
    for (std::size_t len : {1, 2, 3, 4, 5, 6, 7, 8, 9, 15, 16, 17, 40}) {
      for (std::size_t first = 0; first < As.size(); first += len) {
        const std::size_t n = std::min(len, As.size() - first);
        std::vector<const Eigen::Matrix3f*> ptr;
        for (std::size_t k = 0; k < n; ++k) ptr.push_back(&As[first + k]);
        std::vector<Svd3<float>> out(n);
        svd3Many(ptr.data(), n, out.data(), avx2);
        for (std::size_t k = 0; k < n; ++k) {
          const Svd3<float> alone = svd3<float>(As[first + k]);
          ASSERT_EQ(bits(out[k]), bits(alone)) << "batch of " << len << ", avx2 " << avx2 << ":\n" << As[first + k];
          if (!alone.U.isIdentity(0.0f)) ++swept;
        }
      }
    }
  }
  EXPECT_GT(swept, 1000);  // most went through the lanes, not the near-diagonal shortcut
}

// polarFrom (P2G's fixed-corotated rotation by Newton's method from the substep before's):
// from the rotation of A times I + 1e-3 noise it converges to the closest proper rotation of
// A (the oracle as below, Eigen's SVD in double of A rounded to float) within 1e-6, about
// ten times float's round-off of R's entries, where R is well conditioned (gap >= 1e-2: R's
// condition number is 1 / gap); it declines inverted matrices, and guesses that are no
// unit quaternion.
TEST(MpmSvd3, PolarFromANearbyRotationConvergesToThePolarRotation) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int converged = 0;
  for (const M3& A0 : hardMatrices()) {
    const Eigen::Matrix3f Af = A0.cast<float>();
    const M3 A = Af.cast<double>();
    Eigen::JacobiSVD<M3> svd(A, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const V3 sv = svd.singularValues();
    M3 D = M3::Identity();
    D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
    const M3 oracle = svd.matrixU() * D * svd.matrixV().transpose();
    const M3 near = A * (M3::Identity() + 1e-3 * M3::NullaryExpr([&](Eigen::Index, Eigen::Index) { return u(rng); }));
    const Svd3<float> d = svd3<float>(near.cast<float>());
    const Eigen::Quaternionf q0(Eigen::Matrix3f(d.U * d.V.transpose()));
    Eigen::Vector4f q(q0.x(), q0.y(), q0.z(), q0.w());
    Eigen::Matrix3f R;
    const bool ok = polarFrom(Af, q, R);
    if (!(A.determinant() > 0.0)) {
      EXPECT_FALSE(ok) << A;
      continue;
    }
    const double gap = (sv(1) + D(2, 2) * sv(2)) / std::max(sv(0), 1e-300);
    if (gap < 1e-2) continue;
    ASSERT_TRUE(ok) << A;
    ++converged;
    EXPECT_LE((R.cast<double>() - oracle).norm(), 1e-6) << A;
    EXPECT_NEAR(q.norm(), 1.0, 1e-6);
  }
  EXPECT_GT(converged, 300);
  Eigen::Vector4f bad = Eigen::Vector4f::Constant(std::nanf("")), zero = Eigen::Vector4f::Zero();
  Eigen::Matrix3f R;
  EXPECT_FALSE(polarFrom(Eigen::Matrix3f::Identity(), bad, R));
  EXPECT_FALSE(polarFrom(Eigen::Matrix3f::Identity(), zero, R));
}

// The fixed-corotated stress needs only R = U V^T, the polar rotation: it must be the
// rotation closest to F (Eigen's polar decomposition from its SVD in double), also for an
// inverted F (there the reflection goes into the smallest singular value, not into R).
TEST(MpmSvd3, TheRotationIsTheClosestProperRotation) {
  for (const M3& F : hardMatrices()) {
    const Svd3<double> d = svd3<double>(F);
    const M3 R = d.U * d.V.transpose();
    Eigen::JacobiSVD<M3> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
    M3 D = M3::Identity();
    D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
    const M3 oracle = svd.matrixU() * D * svd.matrixV().transpose();  // argmax tr(R^T F) over SO(3)
    // R is unique where the two smallest signed singular values do not cancel; its condition
    // number is 1 / (sigma_1 + sigma_2) (Higham 2008, Thm. 8.9).
    const double gap = std::abs(svd.singularValues()(1)) + D(2, 2) * svd.singularValues()(2);
    if (gap < 1e-3 * std::max(svd.singularValues()(0), 1e-300)) continue;
    EXPECT_LE((R - oracle).norm(), 1e-12 * F.norm() / gap) << F;
  }
}
