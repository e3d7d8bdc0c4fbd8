// A 3x3 singular value decomposition for MPM's per-particle stresses and return maps.
//
// MLS-MPM needs F = U diag(sigma) V^T for every particle in every substep (the rotation of
// fixed-corotated, the Hencky strain of the plastic models). Eigen's general JacobiSVD costs
// thousands of cycles on a 3x3 and capped the solver near 1 M particle-steps/s (see
// ../shared/speed.md). This is the structure of McAdams et al. 2011 ("Computing the Singular
// Value Decomposition of 3x3 matrices with minimal branching and elementary floating point
// operations", UW-Madison TR1690), which is what MPM codes use (Taichi's `ti.svd`):
//   1. the symmetric eigenproblem of A^T A by cyclic Jacobi rotations, giving V;
//   2. B = A V, columns sorted by decreasing length (V's columns follow, one negated per swap
//      so that V stays a proper rotation);
//   3. B = U R by Givens rotations (QR), so U is a proper rotation; sigma = diag(R).
// Unlike McAdams, the Jacobi rotations are exact (Golub & Van Loan 2013, Alg. 8.5.1) and the
// sweeps stop once the off-diagonal is below round-off, so the result is as accurate as
// A^T A's conditioning allows; the QR step recovers small singular values from A itself.
//
// The convention is the one the constitutive models need (Irving et al. 2004 §5): U and V
// are rotations (det +1), sigma_0 >= sigma_1 >= |sigma_2|, and sigma_2 < 0 exactly when
// det A < 0 (an inverted element).
#pragma once

#include <cmath>
#include <limits>
#include <type_traits>
#include <utility>

#include <Eigen/Core>

namespace physketch::mpm {

template <class S>
struct Svd3 {
  Eigen::Matrix<S, 3, 3> U, V;
  Eigen::Matrix<S, 3, 1> sigma;
};

namespace detail {

// One Jacobi rotation in the (p, q) plane that zeroes the symmetric M(p, q); V follows.
// Skipped (returns false) when |M(p, q)| <= tol sqrt(M(p, p) M(q, q)): the relative criterion
// of Demmel & Veselic 1992, under which even the small eigenvalues keep their relative accuracy.
template <class S>
inline bool jacobiRotate(Eigen::Matrix<S, 3, 3>& M, Eigen::Matrix<S, 3, 3>& V, int p, int q, S tol) {
  const S apq = M(p, q);
  if (!(std::abs(apq) > tol * std::sqrt(std::abs(M(p, p) * M(q, q))))) return false;
  const S tau = (M(q, q) - M(p, p)) / (S(2) * apq);
  const S t = (tau >= S(0) ? S(1) : S(-1)) / (std::abs(tau) + std::sqrt(S(1) + tau * tau));
  const S c = S(1) / std::sqrt(S(1) + t * t), s = t * c;
  const int r = 3 - p - q;  // the third index
  M(p, p) -= t * apq;
  M(q, q) += t * apq;
  M(p, q) = M(q, p) = S(0);
  const S arp = M(r, p), arq = M(r, q);
  M(r, p) = M(p, r) = c * arp - s * arq;
  M(r, q) = M(q, r) = s * arp + c * arq;
  for (int k = 0; k < 3; ++k) {
    const S vp = V(k, p), vq = V(k, q);
    V(k, p) = c * vp - s * vq;
    V(k, q) = s * vp + c * vq;
  }
  return true;
}

// A Givens rotation of rows p and q of B (and columns p, q of U) that zeroes B(q, col)
// and leaves B(p, col) = hypot >= 0.
template <class S>
inline void givensZero(Eigen::Matrix<S, 3, 3>& B, Eigen::Matrix<S, 3, 3>& U, int p, int q, int col) {
  const S a = B(p, col), b = B(q, col);
  const S r = std::sqrt(a * a + b * b);
  if (!(r > S(0))) return;
  const S c = a / r, s = b / r;
  for (int k = 0; k < 3; ++k) {
    const S bp = B(p, k), bq = B(q, k);
    B(p, k) = c * bp + s * bq;
    B(q, k) = -s * bp + c * bq;
    const S up = U(k, p), uq = U(k, q);
    U(k, p) = c * up + s * uq;
    U(k, q) = -s * up + c * uq;
  }
}

// Swaps columns i and j of B and V and negates the new column j of both, which keeps
// det V = +1 and B = A V.
template <class S>
inline void swapColumns(Eigen::Matrix<S, 3, 3>& B, Eigen::Matrix<S, 3, 3>& V, S (&len)[3], int i, int j) {
  B.col(i).swap(B.col(j));
  V.col(i).swap(V.col(j));
  B.col(j) = -B.col(j);
  V.col(j) = -V.col(j);
  std::swap(len[i], len[j]);
}

// tol: the relative size of an off-diagonal entry of A^T A that ends the sweeps.
template <class S>
Svd3<S> svd3Impl(const Eigen::Matrix<S, 3, 3>& A, S tol) {
  using M3 = Eigen::Matrix<S, 3, 3>;
  M3 M = A.transpose() * A;
  M3 V = M3::Identity();
  for (int sweep = 0; sweep < 10; ++sweep) {  // quadratic convergence: 10 is never reached
    bool turned = jacobiRotate(M, V, 0, 1, tol);
    turned |= jacobiRotate(M, V, 0, 2, tol);
    turned |= jacobiRotate(M, V, 1, 2, tol);
    if (!turned) break;  // also on NaN: the guard reports those
  }
  M3 B = A * V;
  S len[3] = {B.col(0).squaredNorm(), B.col(1).squaredNorm(), B.col(2).squaredNorm()};
  if (len[0] < len[1]) swapColumns(B, V, len, 0, 1);
  if (len[0] < len[2]) swapColumns(B, V, len, 0, 2);
  if (len[1] < len[2]) swapColumns(B, V, len, 1, 2);
  M3 U = M3::Identity();
  givensZero(B, U, 0, 1, 0);
  givensZero(B, U, 0, 2, 0);
  givensZero(B, U, 1, 2, 1);
  return {U, V, Eigen::Matrix<S, 3, 1>(B(0, 0), B(1, 1), B(2, 2))};
}

// The SVD of an A whose off-diagonal entries are within tol of its positive diagonal
// (|a_ij| <= tol sqrt(a_ii a_jj)): sigma is the diagonal, sorted, and U = V = the permutation
// that sorts it (one column negated if odd, so both are rotations); U sigma V^T = diag(a_ii),
// within tol of A. MPM's F is the identity up to round-off wherever material moves rigidly,
// and Jacobi plus QR cost a hundred nanoseconds more there for nothing. False otherwise.
template <class S>
bool svd3NearDiagonal(const Eigen::Matrix<S, 3, 3>& A, S tol, Svd3<S>& out) {
  const S d[3] = {A(0, 0), A(1, 1), A(2, 2)};
  if (!(d[0] > S(0) && d[1] > S(0) && d[2] > S(0))) return false;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      if (i != j && !(std::abs(A(i, j)) <= tol * std::sqrt(d[i] * d[j]))) return false;
  int o[3] = {0, 1, 2};
  bool odd = false;
  const auto order = [&](int a, int b) {
    if (d[o[a]] < d[o[b]]) {
      std::swap(o[a], o[b]);
      odd = !odd;
    }
  };
  order(0, 1);
  order(1, 2);
  order(0, 1);
  out.U.setZero();
  for (int k = 0; k < 3; ++k) {
    out.U(o[k], k) = S(1);
    out.sigma(k) = d[o[k]];
  }
  if (odd) out.U.col(2) = -out.U.col(2);
  out.V = out.U;
  return true;
}

}  // namespace detail

// Computed in double whatever S is: A^T A squares A's condition number, which float cannot
// hold beyond a spread of about 1e3 between singular values (in float, a 1e6 spread
// reconstructed A only to 2e-5 relative, measured), and scalar double arithmetic costs about
// what float does here.
template <class S>
Svd3<S> svd3(const Eigen::Matrix<S, 3, 3>& A) {
  // Off-diagonals are rotated away until they are below S's precision (relative to their
  // diagonal), so a float F near the identity (MPM's common case) takes few or no rotations.
  const double tol = double(std::numeric_limits<S>::epsilon());
  Svd3<S> out;
  if (detail::svd3NearDiagonal<S>(A, S(tol), out)) return out;
  if constexpr (std::is_same_v<S, double>) {
    return detail::svd3Impl<double>(A, tol);
  } else {
    const Svd3<double> d = detail::svd3Impl<double>(A.template cast<double>(), tol);
    return {d.U.template cast<S>(), d.V.template cast<S>(), d.sigma.template cast<S>()};
  }
}

}  // namespace physketch::mpm
