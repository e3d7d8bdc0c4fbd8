// svd3Many: svd3Lanes (svd3.h) on sixteen matrices at once, four GCC vectors of four doubles
// per value (AVX2 registers, or pairs of SSE2 ones).
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

// Four registers' worth of lanes: each operation is done on the four side by side, so that
// four independent chains of the rotations' divisions and square roots overlap (per matrix:
// one register about 150 ns, two 87, four 73). GCC's own 64-byte vectors lowered the selects
// lane by lane on AVX2, and an array of four registers was spilled (88-95 ns); four named
// members keep every operation one vector instruction per register.
template <class T>
struct Four {
  T a, b, c, d;
};
#define PHYSKETCH_FOUR_OP(op)                                                              \
  template <class T>                                                                       \
  PHYSKETCH_SVD3_INLINE auto operator op(const Four<T>& x, const Four<T>& y) {             \
    return Four<decltype(x.a op y.a)>{x.a op y.a, x.b op y.b, x.c op y.c, x.d op y.d};     \
  }
PHYSKETCH_FOUR_OP(+)
PHYSKETCH_FOUR_OP(-)
PHYSKETCH_FOUR_OP(*)
PHYSKETCH_FOUR_OP(/)
PHYSKETCH_FOUR_OP(<)
PHYSKETCH_FOUR_OP(>)
PHYSKETCH_FOUR_OP(>=)
PHYSKETCH_FOUR_OP(|)
#undef PHYSKETCH_FOUR_OP
template <class T>
PHYSKETCH_SVD3_INLINE Four<T> operator-(const Four<T>& x) {
  return {-x.a, -x.b, -x.c, -x.d};
}

using VL = Four<D4>;
using ML = Four<M4>;
constexpr int kLanes = 16;

PHYSKETCH_SVD3_INLINE D4 sqrt4(D4 x) {
  D4 r;
  for (int l = 0; l < 4; ++l) r[l] = std::sqrt(x[l]);  // one vsqrtpd (-fno-math-errno)
  return r;
}
PHYSKETCH_SVD3_INLINE D4 abs4(D4 x) {  // clears the sign bit, as std::abs does
  return reinterpret_cast<D4>(reinterpret_cast<M4>(x) & std::int64_t(0x7fffffffffffffffLL));
}

struct LaneOps {
  using V = VL;
  using M = ML;
  PHYSKETCH_SVD3_INLINE static VL sel(const ML& m, const VL& x, const VL& y) {
    return {m.a ? x.a : y.a, m.b ? x.b : y.b, m.c ? x.c : y.c, m.d ? x.d : y.d};
  }
  PHYSKETCH_SVD3_INLINE static VL sqrt(const VL& x) { return {sqrt4(x.a), sqrt4(x.b), sqrt4(x.c), sqrt4(x.d)}; }
  PHYSKETCH_SVD3_INLINE static VL abs(const VL& x) { return {abs4(x.a), abs4(x.b), abs4(x.c), abs4(x.d)}; }
  PHYSKETCH_SVD3_INLINE static bool any(const ML& m) {
    const M4 o = (m.a | m.b) | (m.c | m.d);
    return (o[0] | o[1] | o[2] | o[3]) != 0;
  }
  PHYSKETCH_SVD3_INLINE static VL k(double x) {
    const D4 v{x, x, x, x};
    return {v, v, v, v};
  }
  PHYSKETCH_SVD3_INLINE static double& lane(VL& v, int l) {
    D4& r = l < 8 ? (l < 4 ? v.a : v.b) : (l < 12 ? v.c : v.d);
    return r[l % 4];
  }
};

// Lanes past n hold the identity (no sweeps) and are not written back.
PHYSKETCH_SVD3_INLINE void lanes(const Eigen::Matrix3f* const* A, const std::size_t* idx, int n, Svd3<float>* out) {
  VL a[3][3], u[3][3], r[3][3], s[3];
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
