// Stresses and return maps against independent oracles: the energy densities of the papers
// (differentiated by finite differences), the Drucker-Prager cone equation, and the closed
// forms of the snow clamp.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include <Eigen/Geometry>

#include "mpm/constitutive.h"
#include "mpm/plasticity.h"

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
