// What every benchmark shares: the median of repeated timings and the CSV row format
// `bench,case,particles,threads,metric,value,unit` (docs/benchmarks.md).
#pragma once

#include <algorithm>
#include <cstdio>
#include <vector>

namespace physketch::bench {

inline double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

inline void row(const char* bench, const char* kase, std::size_t particles, int threads, const char* metric,
                double value, const char* unit) {
  std::printf("%s,%s,%zu,%d,%s,%.6g,%s\n", bench, kase, particles, threads, metric, value, unit);
}

}  // namespace physketch::bench
