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
#include <cstddef>
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

// svd3Lanes and its steps are inlined into each caller, so that svd3Many's AVX2 entry compiles
// them with AVX2 (one out-of-line copy would be compiled for the baseline ISA).
#define PHYSKETCH_SVD3_INLINE __attribute__((always_inline)) inline

// The algorithm below is written once, over "lanes": V is a double (one matrix) or a vector of
// doubles (one matrix per lane, svd3Many in svd3_many.cpp), and Ops supplies what differs
// (select by a mask, sqrt, abs, any). Every lane decision is a select, not a branch, so each
// lane gets the bits it would get alone: IEEE +, -, *, / and sqrt round the same in a scalar
// and a vector register (the build turns FMA contraction off).
struct ScalarLaneOps {
  using V = double;
  using M = bool;
  static double sel(bool m, double a, double b) { return m ? a : b; }
  static double sqrt(double x) { return std::sqrt(x); }
  static double abs(double x) { return std::abs(x); }
  static bool any(bool m) { return m; }
  static double k(double x) { return x; }  // a constant in every lane
};

// One Jacobi rotation in the (p, q) plane that zeroes the symmetric M(p, q); V follows.
// Skipped (the lane's mask false) when |M(p, q)| <= tol sqrt(M(p, p) M(q, q)): the relative
// criterion of Demmel & Veselic 1992, under which even the small eigenvalues keep their
// relative accuracy; also on NaN.
template <class Ops, class V = typename Ops::V, class Mask = typename Ops::M>
PHYSKETCH_SVD3_INLINE Mask jacobiRotate(V (&M)[3][3], V (&R)[3][3], int p, int q, V tol) {
  const V apq = M[p][q];
  const Mask on = Ops::abs(apq) > tol * Ops::sqrt(Ops::abs(M[p][p] * M[q][q]));
  const V one = Ops::k(1.0);
  const V a = Ops::sel(on, apq, one);  // a skipped lane divides by 1
  const V tau = (M[q][q] - M[p][p]) / (Ops::k(2.0) * a);
  const V t = Ops::sel(tau >= Ops::k(0.0), one, Ops::k(-1.0)) / (Ops::abs(tau) + Ops::sqrt(one + tau * tau));
  const V c = one / Ops::sqrt(one + t * t), s = t * c;
  const int r = 3 - p - q;  // the third index
  M[p][p] = Ops::sel(on, M[p][p] - t * apq, M[p][p]);
  M[q][q] = Ops::sel(on, M[q][q] + t * apq, M[q][q]);
  M[p][q] = M[q][p] = Ops::sel(on, Ops::k(0.0), apq);
  const V arp = M[r][p], arq = M[r][q];
  M[r][p] = M[p][r] = Ops::sel(on, c * arp - s * arq, arp);
  M[r][q] = M[q][r] = Ops::sel(on, s * arp + c * arq, arq);
  for (int k = 0; k < 3; ++k) {
    const V vp = R[k][p], vq = R[k][q];
    R[k][p] = Ops::sel(on, c * vp - s * vq, vp);
    R[k][q] = Ops::sel(on, s * vp + c * vq, vq);
  }
  return on;
}

// A Givens rotation of rows p and q of B (and columns p, q of U) that zeroes B(q, col)
// and leaves B(p, col) = hypot >= 0; none where B(p, col) = B(q, col) = 0.
template <class Ops, class V = typename Ops::V>
PHYSKETCH_SVD3_INLINE void givensZero(V (&B)[3][3], V (&U)[3][3], int p, int q, int col) {
  const V a = B[p][col], b = B[q][col];
  const V r = Ops::sqrt(a * a + b * b);
  const auto on = r > Ops::k(0.0);
  const V rs = Ops::sel(on, r, Ops::k(1.0));
  const V c = a / rs, s = b / rs;
  for (int k = 0; k < 3; ++k) {
    const V bp = B[p][k], bq = B[q][k];
    B[p][k] = Ops::sel(on, c * bp + s * bq, bp);
    B[q][k] = Ops::sel(on, -s * bp + c * bq, bq);
    const V up = U[k][p], uq = U[k][q];
    U[k][p] = Ops::sel(on, c * up + s * uq, up);
    U[k][q] = Ops::sel(on, -s * up + c * uq, uq);
  }
}

// Where len[i] < len[j]: swaps columns i and j of B and V and negates the new column j of
// both, which keeps det V = +1 and B = A V.
template <class Ops, class V = typename Ops::V>
PHYSKETCH_SVD3_INLINE void sortColumns(V (&B)[3][3], V (&R)[3][3], V (&len)[3], int i, int j) {
  const auto on = len[i] < len[j];
  for (int k = 0; k < 3; ++k) {
    const V bi = B[k][i], bj = B[k][j], vi = R[k][i], vj = R[k][j];
    B[k][i] = Ops::sel(on, bj, bi);
    B[k][j] = Ops::sel(on, -bi, bj);
    R[k][i] = Ops::sel(on, vj, vi);
    R[k][j] = Ops::sel(on, -vi, vj);
  }
  const V li = len[i], lj = len[j];
  len[i] = Ops::sel(on, lj, li);
  len[j] = Ops::sel(on, li, lj);
}

// A = U diag(sigma) R^T, lane by lane. tol: the relative size of an off-diagonal entry of
// A^T A that ends the sweeps (a lane whose sweep turned nothing is unchanged by more sweeps,
// so lanes that converge at different sweeps get what they would alone).
template <class Ops, class V = typename Ops::V>
PHYSKETCH_SVD3_INLINE void svd3Lanes(const V (&A)[3][3], const V tol, V (&U)[3][3], V (&R)[3][3], V (&sigma)[3]) {
  V M[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) M[i][j] = A[0][i] * A[0][j] + A[1][i] * A[1][j] + A[2][i] * A[2][j];
  const V zero = Ops::k(0.0), one = Ops::k(1.0);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) R[i][j] = U[i][j] = i == j ? one : zero;
  for (int sweep = 0; sweep < 10; ++sweep) {  // quadratic convergence: 10 is never reached
    auto turned = jacobiRotate<Ops>(M, R, 0, 1, tol);
    turned = turned | jacobiRotate<Ops>(M, R, 0, 2, tol);
    turned = turned | jacobiRotate<Ops>(M, R, 1, 2, tol);
    if (!Ops::any(turned)) break;  // also on NaN: the guard reports those
  }
  V B[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) B[i][j] = A[i][0] * R[0][j] + A[i][1] * R[1][j] + A[i][2] * R[2][j];
  V len[3];
  for (int j = 0; j < 3; ++j) len[j] = B[0][j] * B[0][j] + B[1][j] * B[1][j] + B[2][j] * B[2][j];
  sortColumns<Ops>(B, R, len, 0, 1);
  sortColumns<Ops>(B, R, len, 0, 2);
  sortColumns<Ops>(B, R, len, 1, 2);
  givensZero<Ops>(B, U, 0, 1, 0);
  givensZero<Ops>(B, U, 0, 2, 0);
  givensZero<Ops>(B, U, 1, 2, 1);
  for (int k = 0; k < 3; ++k) sigma[k] = B[k][k];
}

// The scalar entry of svd3Lanes.
template <class S>
Svd3<S> svd3Impl(const Eigen::Matrix<S, 3, 3>& A, double tol) {
  double a[3][3], u[3][3], r[3][3], s[3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) a[i][j] = double(A(i, j));
  svd3Lanes<ScalarLaneOps>(a, tol, u, r, s);
  Svd3<S> out;
  for (int i = 0; i < 3; ++i) {
    out.sigma(i) = S(s[i]);
    for (int j = 0; j < 3; ++j) {
      out.U(i, j) = S(u[i][j]);
      out.V(i, j) = S(r[i][j]);
    }
  }
  return out;
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
  return detail::svd3Impl<S>(A, tol);
}

// The SVDs of n float matrices, out[k] bit for bit svd3<float>(*A[k]) (for a matrix with an
// infinite or NaN entry: NaNs in the same places, their sign bits may differ): those that need Jacobi
// sweeps are decomposed sixteen at a time, one per lane of AVX2 registers where the CPU has them
// (avx2 false: SSE2's, for tests; the same bits either way). For a pass over many particles
// (the return maps) this is about 5x faster than svd3 one at a time (docs/mpm.md).
void svd3Many(const Eigen::Matrix3f* const* A, std::size_t n, Svd3<float>* out, bool avx2 = true);

}  // namespace physketch::mpm
