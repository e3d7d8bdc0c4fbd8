// Hyperelastic stresses for MLS-MPM, as small pure functions of the deformation gradient F.
//
// The solver needs the Kirchhoff stress tau = P F^T (MLS-MPM's P2G, Hu et al. 2018 Eq. 16,
// uses P F^T; no F^-T is ever formed). Every formula is checked against the primary
// literature, not against the VR-Doh supplement, whose Eq. 8 labels the Kirchhoff stress as P
// and whose Eq. 7 calls the fixed-corotated model StVK:
//
//  fixed corotated (Stomakhin et al. 2012, Eq. 2-3; Sifakis & Barbic 2012 course notes):
//    psi = mu sum_i (sigma_i - 1)^2 + lambda/2 (J - 1)^2
//    P   = 2 mu (F - R) + lambda (J - 1) J F^-T            (R from the polar decomposition F = R S)
//    tau = 2 mu (F - R) F^T + lambda (J - 1) J I
//  neo-Hookean (Bonet & Wood 2008, Eq. 6.27-6.28):
//    psi = mu/2 (tr(F^T F) - 3) - mu ln J + lambda/2 (ln J)^2
//    P   = mu (F - F^-T) + lambda ln J F^-T
//    tau = mu (F F^T - I) + lambda ln J I
//  StVK in Hencky strain (Klar et al. 2016, Eq. 26; used with the plastic return maps, which
//  work on eps = ln(Sigma) with F = U Sigma V^T):
//    psi = mu tr(eps^2) + lambda/2 tr(eps)^2
//    tau = U (2 mu eps + lambda tr(eps) I) U^T
//
// Units: stresses in Pa, mu and lambda in Pa.
#pragma once

#include <cmath>

#include <Eigen/Core>

#include "mpm/svd3.h"

namespace physketch::mpm {

// Lame parameters (Pa) from Young's modulus E (Pa) and Poisson's ratio nu in (0, 0.5).
struct Lame {
  double mu = 0.0;
  double lambda = 0.0;
};
inline Lame lameFromYoungs(double E, double nu) {
  return {E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))};
}

// Fixed-corotated Kirchhoff stress, given the rotation R of F's polar decomposition (R = U V^T).
template <class S>
Eigen::Matrix<S, 3, 3> corotatedKirchhoff(const Eigen::Matrix<S, 3, 3>& F, const Eigen::Matrix<S, 3, 3>& R, S mu,
                                          S lambda) {
  const S J = F.determinant();
  return S(2) * mu * (F - R) * F.transpose() + (lambda * (J - S(1)) * J) * Eigen::Matrix<S, 3, 3>::Identity();
}

template <class S>
Eigen::Matrix<S, 3, 3> corotatedKirchhoff(const Eigen::Matrix<S, 3, 3>& F, S mu, S lambda) {
  const Svd3<S> d = svd3(F);
  return corotatedKirchhoff<S>(F, d.U * d.V.transpose(), mu, lambda);
}

// Neo-Hookean Kirchhoff stress. Requires J = det F > 0 (ln J); the solver's guard stops a
// run before an inverted element reaches it.
template <class S>
Eigen::Matrix<S, 3, 3> neoHookeanKirchhoff(const Eigen::Matrix<S, 3, 3>& F, S mu, S lambda) {
  const S J = F.determinant();
  const Eigen::Matrix<S, 3, 3> I = Eigen::Matrix<S, 3, 3>::Identity();
  return mu * (F * F.transpose() - I) + (lambda * std::log(J)) * I;
}

// StVK-Hencky Kirchhoff stress from F's SVD (singular values > 0).
template <class S>
Eigen::Matrix<S, 3, 3> henckyKirchhoff(const Svd3<S>& d, S mu, S lambda) {
  const Eigen::Matrix<S, 3, 1> eps = d.sigma.array().log().matrix();
  const S tr = eps.sum();
  const Eigen::Matrix<S, 3, 1> t = (S(2) * mu) * eps + Eigen::Matrix<S, 3, 1>::Constant(lambda * tr);
  return d.U * t.asDiagonal() * d.U.transpose();
}

}  // namespace physketch::mpm
