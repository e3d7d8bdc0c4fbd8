// svd3Many: svd3Lanes (svd3.h) on eight matrices at once, in a GCC vector of eight doubles:
// two AVX2 registers (four SSE2 ones) per value, so that two or four independent chains of
// the rotations' divisions and square roots overlap (one register's chain alone left the
// CPU waiting on their latency).
// Compiled with -Wno-psabi (mpm/CMakeLists.txt): the lane helpers take and return 32-byte
// vectors, which GCC warns changes the ABI of a function compiled without AVX; they are
// always inlined and never cross a call.
#include <cmath>
#include <cstdint>
#include <limits>

#include "mpm/svd3.h"

namespace physketch::mpm {
namespace {

typedef double D4 __attribute__((vector_size(32)));
typedef std::int64_t M4 __attribute__((vector_size(32)));

// Two registers' worth of lanes: each operation is done on both halves, side by side. (GCC's
// own 64-byte vectors lowered the selects lane by lane on AVX2; this keeps every operation a
// single vector instruction per half.)
template <class T>
struct Two {
  T a, b;
};
#define PHYSKETCH_TWO_OP(op)                                                         \
  template <class T>                                                                 \
  PHYSKETCH_SVD3_INLINE auto operator op(const Two<T>& x, const Two<T>& y) {         \
    return Two<decltype(x.a op y.a)>{x.a op y.a, x.b op y.b};                        \
  }
PHYSKETCH_TWO_OP(+)
PHYSKETCH_TWO_OP(-)
PHYSKETCH_TWO_OP(*)
PHYSKETCH_TWO_OP(/)
PHYSKETCH_TWO_OP(<)
PHYSKETCH_TWO_OP(>)
PHYSKETCH_TWO_OP(>=)
PHYSKETCH_TWO_OP(|)
#undef PHYSKETCH_TWO_OP
template <class T>
PHYSKETCH_SVD3_INLINE Two<T> operator-(const Two<T>& x) {
  return {-x.a, -x.b};
}

using V8 = Two<D4>;
using M8 = Two<M4>;
constexpr int kLanes = 8;

struct LaneOps {
  using V = V8;
  using M = M8;
  PHYSKETCH_SVD3_INLINE static V8 sel(const M8& m, const V8& x, const V8& y) {
    return {m.a ? x.a : y.a, m.b ? x.b : y.b};
  }
  PHYSKETCH_SVD3_INLINE static D4 sqrt4(D4 x) {
    D4 r;
    for (int l = 0; l < 4; ++l) r[l] = std::sqrt(x[l]);  // one vsqrtpd (-fno-math-errno)
    return r;
  }
  PHYSKETCH_SVD3_INLINE static V8 sqrt(const V8& x) { return {sqrt4(x.a), sqrt4(x.b)}; }
  PHYSKETCH_SVD3_INLINE static D4 abs4(D4 x) {  // clears the sign bit, as std::abs does
    return reinterpret_cast<D4>(reinterpret_cast<M4>(x) & std::int64_t(0x7fffffffffffffffLL));
  }
  PHYSKETCH_SVD3_INLINE static V8 abs(const V8& x) { return {abs4(x.a), abs4(x.b)}; }
  PHYSKETCH_SVD3_INLINE static bool any(const M8& m) {
    const M4 o = m.a | m.b;
    return (o[0] | o[1] | o[2] | o[3]) != 0;
  }
  PHYSKETCH_SVD3_INLINE static V8 k(double x) { return {D4{x, x, x, x}, D4{x, x, x, x}}; }
  PHYSKETCH_SVD3_INLINE static double& lane(V8& v, int l) { return l < 4 ? v.a[l] : v.b[l - 4]; }
};

// Lanes past n hold the identity (no sweeps) and are not written back.
PHYSKETCH_SVD3_INLINE void lanes(const Eigen::Matrix3f* const* A, const std::size_t* idx, int n, Svd3<float>* out) {
  V8 a[3][3], u[3][3], r[3][3], s[3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int l = 0; l < kLanes; ++l) LaneOps::lane(a[i][j], l) = l < n ? double((*A[idx[l]])(i, j)) : (i == j ? 1.0 : 0.0);
  // svd3<float>'s tolerance: float's epsilon.
  detail::svd3Lanes<LaneOps>(a, LaneOps::k(double(std::numeric_limits<float>::epsilon())), u, r, s);
  for (int l = 0; l < n; ++l) {
    Svd3<float>& o = out[idx[l]];
    for (int i = 0; i < 3; ++i) {
      o.sigma(i) = float(LaneOps::lane(s[i], l));
      for (int j = 0; j < 3; ++j) {
        o.U(i, j) = float(LaneOps::lane(u[i][j], l));
        o.V(i, j) = float(LaneOps::lane(r[i][j], l));
      }
    }
  }
}

__attribute__((target("avx2"))) void manyAvx2(const Eigen::Matrix3f* const* A, const std::size_t* idx, int n,
                                              Svd3<float>* out) {
  lanes(A, idx, n, out);
}

void manySse(const Eigen::Matrix3f* const* A, const std::size_t* idx, int n, Svd3<float>* out) { lanes(A, idx, n, out); }

}  // namespace

void svd3Many(const Eigen::Matrix3f* const* A, std::size_t n, Svd3<float>* out, bool avx2) {
  static const bool haveAvx2 = __builtin_cpu_supports("avx2");
  const auto run = avx2 && haveAvx2 ? manyAvx2 : manySse;
  const float tol = std::numeric_limits<float>::epsilon();
  std::size_t pending[kLanes];
  int np = 0;
  for (std::size_t k = 0; k < n; ++k) {
    if (detail::svd3NearDiagonal<float>(*A[k], tol, out[k])) continue;
    pending[np++] = k;
    if (np == kLanes) {
      run(A, pending, kLanes, out);
      np = 0;
    }
  }
  if (np > 0) run(A, pending, np, out);
}

}  // namespace physketch::mpm
