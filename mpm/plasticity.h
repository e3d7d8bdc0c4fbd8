// Plastic return maps for MLS-MPM, as pure functions of the singular values of the trial
// elastic deformation gradient F = U diag(sigma) V^T (VR-Doh supplement §2.2, "Apply_Plasticity",
// checked against the primary sources named at each function). Each returns the projected
// singular values; the caller rebuilds F = U diag(sigma') V^T.
#pragma once

#include <algorithm>
#include <cmath>

#include <Eigen/Core>

namespace physketch::mpm {

// The Drucker-Prager cone coefficient alpha = sqrt(2/3) 2 sin(phi) / (3 - sin(phi))
// (Klar et al. 2016, §7.3, after Eq. 27), phi the friction angle in radians.
inline double druckerPragerAlpha(double frictionAngleRad) {
  const double s = std::sin(frictionAngleRad);
  return std::sqrt(2.0 / 3.0) * 2.0 * s / (3.0 - s);
}

// The cone apex's strain shift for cohesion c (Pa): a hydrostatic Hencky strain e per axis
// carries the mean Kirchhoff stress (2 mu + 3 lambda) e (StVK-Hencky), so shifting the cone by
// e_c = c / (2 mu + 3 lambda) lets the material hold a mean tension up to c.
inline double cohesionStrain(double cohesion, double mu, double lambda) { return cohesion / (2.0 * mu + 3.0 * lambda); }

// Drucker-Prager return map in Hencky strain (Klar et al. 2016, Algorithm 2 "projection",
// Eq. 27-28): eps = ln(sigma), eps_hat its deviatoric part,
//   delta_gamma = |eps_hat| + (3 lambda + 2 mu) / (2 mu) tr(eps) alpha.
//  - delta_gamma <= 0: inside the cone, unchanged (tested first: a pure compression has
//    eps_hat = 0 and stays);
//  - tr(eps) > 0 (the material is pulled apart) or eps_hat = 0: project to the cone's tip,
//    sigma' = 1 (the VR-Doh supplement's Eq. 10 omits this case), plastic strain |eps|;
//  - else: eps' = eps - delta_gamma eps_hat / |eps_hat|, plastic strain delta_gamma.
// `shift` is cohesionStrain(): the return is done on eps - shift and shift added back.
// `plastic` receives the plastic strain increment delta_q (for hardening).
//
// The map in strain space: given lnSigma = ln(sigma), false where sigma stays (plastic 0);
// else true with lnOut the projected ln(sigma') (the batched pass, MpmWorld::plasticity, takes
// the logs and exponentials of many particles at once around it).
template <class S>
bool druckerPragerStrain(const Eigen::Matrix<S, 3, 1>& lnSigma, S mu, S lambda, S alpha, S shift,
                         Eigen::Matrix<S, 3, 1>& lnOut, S& plastic) {
  using V = Eigen::Matrix<S, 3, 1>;
  const V eps = lnSigma - V::Constant(shift);
  const S tr = eps.sum();
  const V dev = eps - V::Constant(tr / S(3));
  const S devNorm = dev.norm();
  const S dgamma = devNorm + (S(3) * lambda + S(2) * mu) / (S(2) * mu) * tr * alpha;
  if (dgamma <= S(0)) {  // Case I first: pure compression (eps_hat = 0, tr < 0) stays elastic
    plastic = S(0);
    return false;
  }
  if (tr > S(0) || devNorm == S(0)) {
    plastic = eps.norm();
    lnOut = V::Constant(shift);
    return true;
  }
  plastic = dgamma;
  lnOut = (eps - (dgamma / devNorm) * dev).array() + shift;
  return true;
}

template <class S>
Eigen::Matrix<S, 3, 1> druckerPragerReturn(const Eigen::Matrix<S, 3, 1>& sigma, S mu, S lambda, S alpha, S shift,
                                           S& plastic) {
  Eigen::Matrix<S, 3, 1> lnOut;
  if (!druckerPragerStrain<S>(sigma.array().log().matrix(), mu, lambda, alpha, shift, lnOut, plastic)) return sigma;
  return lnOut.array().exp().matrix();
}

// von Mises return map in Hencky strain (VR-Doh supplement Eq. 11-12; Mises' criterion on
// the deviatoric Kirchhoff stress 2 mu eps_hat of StVK-Hencky): delta_gamma = |eps_hat| -
// tau_Y / (2 mu); when positive, eps' = eps - delta_gamma eps_hat / |eps_hat| (volume kept).
// In strain space as druckerPragerStrain: false where sigma stays, else lnOut = ln(sigma').
template <class S>
bool vonMisesStrain(const Eigen::Matrix<S, 3, 1>& lnSigma, S mu, S yieldStress, Eigen::Matrix<S, 3, 1>& lnOut) {
  using V = Eigen::Matrix<S, 3, 1>;
  const V dev = lnSigma - V::Constant(lnSigma.sum() / S(3));
  const S devNorm = dev.norm();
  const S dgamma = devNorm - yieldStress / (S(2) * mu);
  if (dgamma <= S(0)) return false;
  lnOut = lnSigma - (dgamma / devNorm) * dev;
  return true;
}

template <class S>
Eigen::Matrix<S, 3, 1> vonMisesReturn(const Eigen::Matrix<S, 3, 1>& sigma, S mu, S yieldStress) {
  Eigen::Matrix<S, 3, 1> lnOut;
  if (!vonMisesStrain<S>(sigma.array().log().matrix(), mu, yieldStress, lnOut)) return sigma;
  return lnOut.array().exp().matrix();
}

// Snow (Stomakhin et al. 2013, §5 and Eq. 1): the elastic singular values are clamped to
// [1 - theta_c, 1 + theta_s]; what the clamp removes goes into the plastic volume ratio
// J_p <- J_p det(Sigma) / det(Sigma') (J = J_e J_p). The hardening factor e^{xi (1 - J_p)}
// then scales mu and lambda. J_p is kept in [snowJpMin(xi), snowJpMax(xi)], so that the
// exponent xi (1 - J_p) stays within +-kSnowMaxExponent: the factor stays in
// [e^-10, e^10] ~ [4.5e-5, 2.2e4] and never overflows, however long snow is compressed.
constexpr double kSnowMaxExponent = 10.0;
inline double snowJpMin(double xi) { return xi > 0.0 ? std::max(1.0 - kSnowMaxExponent / xi, 1e-2) : 1e-2; }
inline double snowJpMax(double xi) { return xi > 0.0 ? 1.0 + kSnowMaxExponent / xi : 1e2; }

template <class S>
Eigen::Matrix<S, 3, 1> snowClamp(const Eigen::Matrix<S, 3, 1>& sigma, S thetaC, S thetaS, S xi, S& jp) {
  Eigen::Matrix<S, 3, 1> c;
  for (int k = 0; k < 3; ++k) c(k) = std::clamp(sigma(k), S(1) - thetaC, S(1) + thetaS);
  const S jpNew = jp * (sigma.prod() / c.prod());
  jp = std::clamp(jpNew, S(snowJpMin(double(xi))), S(snowJpMax(double(xi))));
  return c;
}

// The snow hardening factor e^{xi (1 - J_p)} (Stomakhin et al. 2013, Eq. 1).
template <class S>
S snowHardening(S xi, S jp) {
  return std::exp(xi * (S(1) - jp));
}

// Weakly compressible fluid (Tait equation of state; Becker & Teschner 2007, Eq. 6, with
// rho / rho0 = 1 / J): p = K / gamma (J^-gamma - 1) (Pa), and the Kirchhoff stress of a
// Newtonian fluid tau = J (-p I + mu_v (grad v + grad v^T)), grad v ~ C (APIC's affine
// velocity, Jiang et al. 2015). Returns tau.
// J^-gamma: by repeated squaring where gamma is a whole number up to 16 (water's 7, the
// peers' 1: a few ulp from pow, a fifth of its time), else pow.
template <class S>
S invPow(S J, S gamma) {
  if (!(gamma >= S(1) && gamma <= S(16) && gamma == std::floor(gamma))) return std::pow(J, -gamma);
  S r = S(1), b = J;
  for (int e = int(gamma); e > 0; e >>= 1) {
    if (e & 1) r *= b;
    b *= b;
  }
  return S(1) / r;
}

// Tait's pressure p = K / gamma (J^-gamma - 1) (Pa).
template <class S>
S taitPressure(S J, S bulk, S gamma) {
  return bulk / gamma * (invPow(J, gamma) - S(1));
}

template <class S>
Eigen::Matrix<S, 3, 3> fluidKirchhoff(S J, const Eigen::Matrix<S, 3, 3>& C, S bulk, S gamma, S viscosity) {
  const S p = taitPressure(J, bulk, gamma);
  return J * (-p * Eigen::Matrix<S, 3, 3>::Identity() + viscosity * (C + C.transpose()));
}

}  // namespace physketch::mpm
