#include "pbd/shape_matching.h"

#include <cmath>

#include <Eigen/Cholesky>

namespace physketch::pbd {

// Each iteration turns q by omega (q <- exp(omega) q) to raise f = tr(R^T A). With M = A R^T,
// f's gradient in omega is g = sum_i r_i x a_i (r_i, a_i the columns of R and A) and its
// Hessian is Msym - tr(M) I. Müller et al. take omega = g / |tr M|, which converges linearly
// (about a third of the angle left per iteration for a near-isotropic stretch, slower for an
// anisotropic one: jelly clusters took 11 iterations on average and often hit the cap). The
// Newton step omega = (tr(M) I - Msym)^-1 g converges quadratically near the answer, where that
// matrix is positive definite (its eigenvalues are sums of two of A's singular values). It is
// taken only where its Cholesky factorization succeeds and it is at most 20 times as long as
// Müller's step (a Hessian no worse conditioned than that); elsewhere (an inverted A far from
// the answer, where the Hessian is indefinite, or a linear body's free axis, where it is
// singular) Müller's step is taken as before. 20: with 4, stretches of singular-value ratio 30
// still fell back to Müller's steps near the answer (test_rigid).
Quat extractRotation(const Mat3& A, Quat q, int maxIterations) {
  for (int iter = 0; iter < maxIterations; ++iter) {
    const Mat3 R = q.toRotationMatrix();
    const Vec3 g = R.col(0).cross(A.col(0)) + R.col(1).cross(A.col(1)) + R.col(2).cross(A.col(2));
    const double tr = R.col(0).dot(A.col(0)) + R.col(1).dot(A.col(1)) + R.col(2).dot(A.col(2));
    Vec3 omega = g / (std::abs(tr) + 1.0e-9);
    if (tr > 0.0) {
      const Mat3 M = A * R.transpose();
      const Mat3 H = tr * Mat3::Identity() - 0.5 * (M + M.transpose());
      const Eigen::LLT<Mat3> llt(H);
      if (llt.info() == Eigen::Success) {
        const Vec3 newton = llt.solve(g);
        if (newton.allFinite() && newton.norm() <= 20.0 * omega.norm()) omega = newton;
      }
    }
    const double w = omega.norm();
    if (w < 1.0e-9) break;
    q = Quat(Eigen::AngleAxisd(w, omega / w)) * q;
    q.normalize();
  }
  return q;
}

}  // namespace physketch::pbd

namespace physketch::pbd {

void matchRigid(const BodyView& b, Quat& q, Vec3& c) {
  double mass = 0.0;
  Vec3 mp = Vec3::Zero();
  for (std::int32_t k = 0; k < b.n; ++k) {
    const std::size_t i = b.at(k);
    const double m = b.mass[i];
    mass += m;
    mp += m * Vec3(b.px[i], b.py[i], b.pz[i]);
  }
  c = mp / mass;
  Mat3 A = Mat3::Zero();
  for (std::int32_t k = 0; k < b.n; ++k) {
    const std::size_t i = b.at(k);
    const double m = b.mass[i];
    const Vec3 d = Vec3(b.px[i], b.py[i], b.pz[i]) - c;
    const Vec3 r(b.rx[i], b.ry[i], b.rz[i]);
    A += m * d * r.transpose();
  }
  q = extractRotation(A, q);
}

}  // namespace physketch::pbd

namespace physketch::pbd {

Mat3 restInertia(const BodyView& b, double spacing) {
  Mat3 I = Mat3::Zero();
  for (std::int32_t k = 0; k < b.n; ++k) {
    const std::size_t i = b.at(k);
    const double m = b.mass[i];
    const Vec3 r(b.rx[i], b.ry[i], b.rz[i]);
    I += m * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
    I += m * spacing * spacing / 6.0 * Mat3::Identity();
  }
  return I;
}

double generalizedInverseMass(const RigidPose& b, const Vec3& p, const Vec3& n) {
  const Mat3 R = b.q.toRotationMatrix();
  const Vec3 rn = (p - b.c).cross(n);
  return b.invMass + rn.dot(R * b.invInertiaRest * R.transpose() * rn);
}

double applyPointCorrection(RigidPose& b, const Vec3& p, const Vec3& dir, double magnitude) {
  const Mat3 R = b.q.toRotationMatrix();
  const Mat3 invI = R * b.invInertiaRest * R.transpose();
  const Vec3 r = p - b.c;
  const Vec3 rn = r.cross(dir);
  const double w = b.invMass + rn.dot(invI * rn);
  if (!(w > 0.0)) return 0.0;
  const double lambda = magnitude / w;  // position impulse (kg m)
  b.c += (lambda * b.invMass) * dir;
  const Vec3 dtheta = invI * (lambda * rn);
  // q <- q + 1/2 [dtheta, 0] q  (Müller 2020 Eq. 9)
  const Quat dq(0.0, dtheta.x(), dtheta.y(), dtheta.z());
  Quat qn = b.q;
  qn.coeffs() += 0.5 * (dq * b.q).coeffs();
  b.q = qn.normalized();
  return lambda;
}

}  // namespace physketch::pbd
