// ln and exp of floats, written once as straight-line code (every decision a select) so that
// a loop over an array of them vectorizes, and a value gets the same bits from a vector lane
// as from a scalar call: the return maps take the Hencky strain of many particles at once
// (logMany, expMany) and P2G one particle at a time (logLane), and the two must agree bit for
// bit (MpmWorld's decomposition cache). Each is evaluated in double and rounded once to float:
// within about 1e-11 relative of the exact value before that rounding (ln 1.3e-12, exp 1e-11),
// so the float is the correctly rounded one but for values that close to a tie (none in the
// millions the tests sample), never more than one ulp off. IEEE special cases as std::log and std::exp: log(0) = -inf, log(x < 0) = NaN,
// log(inf) = inf, exp overflows to inf and underflows through the float subnormals to 0, NaN
// gives NaN.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>

namespace physketch::mpm {

#if defined(__GNUC__)
#define PHYSKETCH_LOGEXP_INLINE inline __attribute__((always_inline))
#else
#define PHYSKETCH_LOGEXP_INLINE inline
#endif

PHYSKETCH_LOGEXP_INLINE float logLane(float x) {
  constexpr double kLn2 = 0.69314718055994530942;
  // Subnormals (and +0) are scaled by 2^25 first; their exponent then says 25 too much.
  std::uint32_t u;
  std::memcpy(&u, &x, sizeof u);
  const bool sub = u < 0x00800000u;
  const float xs = sub ? x * 33554432.0f : x;
  std::uint32_t us;
  std::memcpy(&us, &xs, sizeof us);
  const int e0 = int((us >> 23) & 0xffu) - (sub ? 152 : 127);
  // x = 2^e m with m in [sqrt(1/2), sqrt(2)).
  const std::uint32_t mb = (us & 0x007fffffu) | 0x3f800000u;
  float m1;
  std::memcpy(&m1, &mb, sizeof m1);
  const bool high = m1 > 1.41421356f;
  const double m = high ? double(m1) * 0.5 : double(m1);
  const int e = high ? e0 + 1 : e0;
  // ln(m) = 2 atanh(s), s = (m - 1) / (m + 1), |s| <= 0.1716: the series to s^13 leaves
  // s^15 / 15 < 1.3e-12 relative.
  const double f = m - 1.0;
  const double s = f / (2.0 + f);
  const double s2 = s * s;
  const double p =
      1.0 + s2 * (1.0 / 3 + s2 * (1.0 / 5 + s2 * (1.0 / 7 + s2 * (1.0 / 9 + s2 * (1.0 / 11 + s2 * (1.0 / 13))))));
  float r = float(double(e) * kLn2 + 2.0 * s * p);
  constexpr float kInf = std::numeric_limits<float>::infinity();
  r = x == 0.0f ? -kInf : r;
  r = x == kInf ? kInf : r;
  r = !(x >= 0.0f) ? std::numeric_limits<float>::quiet_NaN() : r;  // negative or NaN
  return r;
}

PHYSKETCH_LOGEXP_INLINE float expLane(float y) {
  constexpr double kLn2 = 0.69314718055994530942, kInvLn2 = 1.44269504088896340736;
  constexpr double kShifter = 6755399441055744.0;  // 1.5 * 2^52: adding it rounds to an integer
  // Past +-200 every float result is inf or 0 already; NaN passes the clamps unchanged.
  double d = double(y);
  d = d > 200.0 ? 200.0 : d;
  d = d < -200.0 ? -200.0 : d;
  // y = k ln2 + r, |r| <= ln2 / 2, and exp(r) by its series to r^9 (the rest, about
  // r^10 / 10!, is below 6.9e-12 of 1 and 9.7e-12 of e^r).
  const double t = d * kInvLn2 + kShifter;
  const double k = t - kShifter;
  const double r = d - k * kLn2;
  const double p =
      1.0 +
      r * (1.0 + r * (1.0 / 2 +
                      r * (1.0 / 6 +
                           r * (1.0 / 24 +
                                r * (1.0 / 120 +
                                     r * (1.0 / 720 + r * (1.0 / 5040 + r * (1.0 / 40320 + r * (1.0 / 362880)))))))));
  // 2^k from t's low bits (k = bits(t) - bits(1.5 * 2^52), |k| <= 289: a normal double).
  std::uint64_t tb;  // unsigned: a NaN's bits wrap instead of shifting a negative number
  std::memcpy(&tb, &t, sizeof tb);
  const std::uint64_t bits = (tb - 0x4338000000000000ULL + 1023u) << 52;
  double scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return float(p * scale);  // the one rounding: to inf, a float subnormal or 0 where it must
}

// y[k] = logLane(x[k]) / expLane(x[k]) for k < n, in vector lanes (AVX2 where the CPU has it
// and avx2 is true, else SSE2; the same bits either way). x and y must not overlap.
void logMany(const float* x, float* y, std::size_t n, bool avx2 = true);
void expMany(const float* x, float* y, std::size_t n, bool avx2 = true);

}  // namespace physketch::mpm
