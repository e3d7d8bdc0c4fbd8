// logMany and expMany: loops over logLane and expLane (logexp.h) that GCC vectorizes, once for
// AVX2 (target attribute, chosen at run time) and once for the SSE2 baseline. Straight-line
// IEEE operations without contraction (-ffp-contract=off) round the same in any lane width,
// so both give each value the bits a scalar call gives it.
#include "mpm/logexp.h"

namespace physketch::mpm {
namespace {

__attribute__((target("avx2"))) void logAvx2(const float* __restrict x, float* __restrict y, std::size_t n) {
  for (std::size_t k = 0; k < n; ++k) y[k] = logLane(x[k]);
}
void logSse(const float* __restrict x, float* __restrict y, std::size_t n) {
  for (std::size_t k = 0; k < n; ++k) y[k] = logLane(x[k]);
}
__attribute__((target("avx2"))) void expAvx2(const float* __restrict x, float* __restrict y, std::size_t n) {
  for (std::size_t k = 0; k < n; ++k) y[k] = expLane(x[k]);
}
void expSse(const float* __restrict x, float* __restrict y, std::size_t n) {
  for (std::size_t k = 0; k < n; ++k) y[k] = expLane(x[k]);
}

bool haveAvx2() {
  static const bool have = __builtin_cpu_supports("avx2");
  return have;
}

}  // namespace

void logMany(const float* x, float* y, std::size_t n, bool avx2) {
  (avx2 && haveAvx2() ? logAvx2 : logSse)(x, y, n);
}

void expMany(const float* x, float* y, std::size_t n, bool avx2) {
  (avx2 && haveAvx2() ? expAvx2 : expSse)(x, y, n);
}

}  // namespace physketch::mpm
