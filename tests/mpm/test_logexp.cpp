// logLane and expLane (mpm/logexp.h), the return maps' ln and exp, against the C library's
// double-precision log and exp rounded to float (the oracle: within a float ulp of the true
// value's float), and logMany / expMany (vector lanes) against the scalar calls bit for bit.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "mpm/logexp.h"

namespace physketch::mpm {
namespace {

std::uint32_t bitsOf(float x) {
  std::uint32_t u;
  std::memcpy(&u, &x, sizeof u);
  return u;
}

// Distance in ulps between two finite floats of the same sign.
long ulps(float a, float b) { return std::labs(long(bitsOf(a)) - long(bitsOf(b))); }

// The positive floats from 1e-30 to 1e30 at a stride of 997 ulps (1.7 M values, each octave's
// mantissas 8,400 times over), plus the subnormals' octaves.
std::vector<float> logInputs() {
  std::vector<float> x;
  for (std::uint32_t u = bitsOf(1e-30f); u < bitsOf(1e30f); u += 997) {
    float v;
    std::memcpy(&v, &u, sizeof v);
    x.push_back(v);
  }
  for (float v = std::numeric_limits<float>::denorm_min(); v < std::numeric_limits<float>::min(); v *= 1.7f)
    x.push_back(v);
  return x;
}

// The logs are within one ulp of the double log's float (the float nearest the true value
// but for ties: the lane's result is within about 1e-12 relative before its one rounding), and
// for all but a few in a hundred thousand exactly it: a sloppier polynomial or a wrong
// exponent fails the first bound, a float-precision evaluation the second.
TEST(MpmLogExp, LogIsTheCorrectlyRoundedLogButForRareTies) {
  const std::vector<float> x = logInputs();
  long off = 0, worst = 0;
  for (const float v : x) {
    const float want = float(std::log(double(v)));
    const float got = logLane(v);
    if (got != want) ++off;
    worst = std::max(worst, ulps(got, want));
  }
  std::printf("log: %ld of %zu values differ from the double log's float, by at most %ld ulp\n", off, x.size(),
              worst);
  EXPECT_LE(worst, 1);
  EXPECT_LT(double(off), 1e-5 * double(x.size()));
}

TEST(MpmLogExp, ExpIsTheCorrectlyRoundedExpButForRareTies) {
  long off = 0, worst = 0, n = 0;
  // The floats in [-87, 88.7] (normal results) at a stride of 997 ulps on either side of 0.
  std::vector<float> x;
  for (std::uint32_t u = 0; u < bitsOf(88.7f); u += 997) {
    float v;
    std::memcpy(&v, &u, sizeof v);
    x.push_back(v);
    if (v < 87.0f) x.push_back(-v);
  }
  for (const float v : x) {
    const float want = float(std::exp(double(v)));
    const float got = expLane(v);
    ++n;
    if (got != want) ++off;
    worst = std::max(worst, ulps(got, want));
  }
  std::printf("exp: %ld of %ld values differ from the double exp's float, by at most %ld ulp\n", off, n, worst);
  EXPECT_LE(worst, 1);
  EXPECT_LT(double(off), 1e-5 * double(n));
  // Subnormal results (one rounding, from the double product) and the ends of the range.
  for (float v = -103.9f; v < -87.0f; v += 0.37f) EXPECT_LE(ulps(expLane(v), float(std::exp(double(v)))), 1) << v;
  EXPECT_EQ(expLane(-104.0f), 0.0f);
  EXPECT_EQ(expLane(88.8f), std::numeric_limits<float>::infinity());
}

TEST(MpmLogExp, SpecialValuesAreTheCLibrarys) {
  constexpr float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(logLane(1.0f), 0.0f);
  EXPECT_EQ(logLane(0.0f), -inf);
  EXPECT_EQ(logLane(-0.0f), -inf);
  EXPECT_EQ(logLane(inf), inf);
  EXPECT_TRUE(std::isnan(logLane(-1.0f)));
  EXPECT_TRUE(std::isnan(logLane(-inf)));
  EXPECT_TRUE(std::isnan(logLane(nan)));
  EXPECT_EQ(expLane(0.0f), 1.0f);
  EXPECT_EQ(expLane(-inf), 0.0f);
  EXPECT_EQ(expLane(inf), inf);
  EXPECT_EQ(expLane(1e30f), inf);
  EXPECT_EQ(expLane(-1e30f), 0.0f);
  EXPECT_TRUE(std::isnan(expLane(nan)));
}

// The lanes give each value the bits a scalar call gives it (this file is compiled with
// trapping math, logexp_many.cpp without), at every length (the vector loops' tails), AVX2
// and SSE2 alike: the return maps' batches and P2G's one-at-a-time logs must agree.
TEST(MpmLogExp, ManyAtOnceGivesEachValueTheBitsItGetsAlone) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> sigma(0.2f, 3.0f), strain(-5.0f, 5.0f);
  std::vector<float> x, y;
  for (int k = 0; k < 4000; ++k) {
    x.push_back(sigma(rng));
    y.push_back(strain(rng));
  }
  const float specials[] = {0.0f, -0.0f, -1.0f, std::numeric_limits<float>::infinity(),
                            std::numeric_limits<float>::denorm_min(), 1e-40f, 1e38f, -200.0f, 95.0f};
  for (const float s : specials) {
    x.push_back(s);
    y.push_back(s);
  }
  const auto same = [](float a, float b) { return bitsOf(a) == bitsOf(b) || (std::isnan(a) && std::isnan(b)); };
  for (const bool avx2 : {true, false}) {
    for (std::size_t n : {std::size_t(1), std::size_t(3), std::size_t(7), std::size_t(8), std::size_t(9),
                          std::size_t(31), std::size_t(192), x.size()}) {
      std::vector<float> lx(n), ey(n);
      logMany(x.data() + (x.size() - n), lx.data(), n, avx2);
      expMany(y.data() + (y.size() - n), ey.data(), n, avx2);
      for (std::size_t k = 0; k < n; ++k) {
        ASSERT_TRUE(same(lx[k], logLane(x[x.size() - n + k]))) << "log, avx2 " << avx2 << ", n " << n << ", k " << k;
        ASSERT_TRUE(same(ey[k], expLane(y[y.size() - n + k]))) << "exp, avx2 " << avx2 << ", n " << n << ", k " << k;
      }
    }
  }
}

}  // namespace
}  // namespace physketch::mpm
