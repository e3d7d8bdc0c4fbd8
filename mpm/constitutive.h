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
#include <Eigen/Geometry>

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

// The rotation of F's polar decomposition (the R in SO(3) that maximizes tr(R^T F), which is
// svd3's U V^T), by Newton's method on SO(3) from the unit quaternion q (x y z w; in and out) of
// a nearby F's rotation: with M = R^T F, its skew part t = vee(M - M^T) and H = tr(M) I - sym(M)
// (the gradient and Hessian of tr((R e^[d])^T F) at d = 0), R turns by d = H^-1 t in its own
// frame. The iteration of Mueller et al. 2016 ("A Robust Method to Extract the Rotational Part
// of Deformations") is this with H replaced by tr(M) I: a third of the error left per turn where
// Newton squares it, so from a substep's change (1e-3 rad) two turns reach float's round-off.
// Returns false, q untouched, unless det F > 0, q is a unit quaternion, H stays positive
// definite and a turn fell below 1e-6 rad (its error then ~1e-12) within maxIter turns: the
// caller then takes the SVD (an inverted F's rotation keeps the reflection in sigma_2).
inline bool polarFrom(const Eigen::Matrix3f& F, Eigen::Vector4f& q, Eigen::Matrix3f& R, int maxIter = 6) {
  const Eigen::Matrix3d A = F.cast<double>();
  if (!(A.determinant() > 0.0)) return false;
  Eigen::Quaterniond p(double(q.w()), double(q.x()), double(q.y()), double(q.z()));
  if (!(std::abs(p.squaredNorm() - 1.0) < 1e-3)) return false;  // not a rotation's (NaN, unset)
  p.normalize();
  for (int it = 0; it < maxIter; ++it) {
    const Eigen::Matrix3d Rm = p.toRotationMatrix();
    const Eigen::Matrix3d M = Rm.transpose() * A;
    const Eigen::Vector3d t(M(2, 1) - M(1, 2), M(0, 2) - M(2, 0), M(1, 0) - M(0, 1));
    // H is symmetric: its adjugate from six cofactors, d = adj(H) t / det H.
    const double tr = M.trace();
    const double h00 = tr - M(0, 0), h11 = tr - M(1, 1), h22 = tr - M(2, 2);
    const double h01 = -0.5 * (M(0, 1) + M(1, 0)), h02 = -0.5 * (M(0, 2) + M(2, 0)), h12 = -0.5 * (M(1, 2) + M(2, 1));
    const double c00 = h11 * h22 - h12 * h12, c01 = h02 * h12 - h01 * h22, c02 = h01 * h12 - h02 * h11;
    const double c11 = h00 * h22 - h02 * h02, c12 = h01 * h02 - h00 * h12, c22 = h00 * h11 - h01 * h01;
    const double det = h00 * c00 + h01 * c01 + h02 * c02, scale = h00 + h11 + h22;
    if (!(det > 1e-12 * scale * scale * scale)) return false;
    const Eigen::Vector3d d = Eigen::Vector3d(c00 * t.x() + c01 * t.y() + c02 * t.z(), c01 * t.x() + c11 * t.y() + c12 * t.z(),
                                              c02 * t.x() + c12 * t.y() + c22 * t.z()) /
                              det;
    p = p * Eigen::Quaterniond(1.0, 0.5 * d.x(), 0.5 * d.y(), 0.5 * d.z());
    p.normalize();
    if (d.squaredNorm() < 1e-12) {
      q = Eigen::Vector4f(float(p.x()), float(p.y()), float(p.z()), float(p.w()));
      R = p.toRotationMatrix().cast<float>();
      return true;
    }
  }
  return false;
}

// Neo-Hookean Kirchhoff stress. Requires J = det F > 0 (ln J); the solver's guard stops a
// run before an inverted element reaches it.
template <class S>
Eigen::Matrix<S, 3, 3> neoHookeanKirchhoff(const Eigen::Matrix<S, 3, 3>& F, S mu, S lambda) {
  const S J = F.determinant();
  const Eigen::Matrix<S, 3, 3> I = Eigen::Matrix<S, 3, 3>::Identity();
  return mu * (F * F.transpose() - I) + (lambda * std::log(J)) * I;
}

// StVK-Hencky Kirchhoff stress tau = U (2 mu eps + lambda tr(eps) I) U^T from F's left
// singular vectors U and its Hencky strain eps = ln(sigma) (singular values > 0).
template <class S>
Eigen::Matrix<S, 3, 3> henckyKirchhoff(const Eigen::Matrix<S, 3, 3>& U, const Eigen::Matrix<S, 3, 1>& eps, S mu,
                                       S lambda) {
  const S tr = eps.sum();
  const Eigen::Matrix<S, 3, 1> t = (S(2) * mu) * eps + Eigen::Matrix<S, 3, 1>::Constant(lambda * tr);
  return U * t.asDiagonal() * U.transpose();
}

}  // namespace physketch::mpm
