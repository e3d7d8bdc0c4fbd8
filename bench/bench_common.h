// What every benchmark shares: the median of repeated timings and the CSV row format
// `bench,case,particles,threads,metric,value,unit` (docs/benchmarks.md).
#pragma once

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <initializer_list>
#include <string>
#include <utility>
#include <vector>

#include "core/profile.h"

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

// `--name N` pairs of the command line into the named ints (names with their dashes); the
// rest is ignored, as the benches always did.
inline void intOptions(int argc, char** argv, std::initializer_list<std::pair<const char*, int*>> options) {
  for (int i = 1; i + 1 < argc; ++i)
    for (const auto& [name, value] : options)
      if (!std::strcmp(argv[i], name)) {
        *value = std::atoi(argv[++i]);
        break;
      }
}

// A PBD-style world's steps: `warmup` untimed, then `steps` timed one by one (ms each, in ms);
// false, after printing the guard's message after `name`, when a step fails.
template <class World>
bool timeSteps(World& w, int warmup, int steps, const char* name, std::vector<double>& ms) {
  for (int s = 0; s < warmup + steps; ++s) {
    const double t0 = nowSeconds();
    if (!w.step()) {
      std::fprintf(stderr, "%s: %s\n", name, w.guard().message().c_str());
      return false;
    }
    if (s >= warmup) ms.push_back(1e3 * (nowSeconds() - t0));
  }
  return true;
}

// A world with sleeping on, `steps` steps each timed (ms, appended to `ms`); allAsleepAt: when the
// last of its bodies fell asleep (s), or steps x dt when some body is awake at the end. False,
// after printing the guard's message after `name`, when a step fails.
template <class World>
bool timeStepsAsleep(World& w, int steps, const std::string& name, std::vector<double>& ms, double& allAsleepAt) {
  allAsleepAt = steps * w.dt();
  for (int s = 0; s < steps; ++s) {
    const double t0 = nowSeconds();
    if (!w.step()) {
      std::fprintf(stderr, "%s: %s\n", name.c_str(), w.guard().message().c_str());
      return false;
    }
    ms.push_back(1e3 * (nowSeconds() - t0));
    if (w.sleepingCount() < w.bodyCount()) allAsleepAt = steps * w.dt();
    else if (allAsleepAt == steps * w.dt()) allAsleepAt = (s + 1) * w.dt();
  }
  return true;
}

// The median step, then one row per pass of the world's profile (ms per step over all
// `stepsRun`), as `bench,kase[.pass],particles,threads,ms_per_step,...`.
template <class World>
void stepRows(const char* bench, const std::string& kase, std::size_t particles, int threads, const World& w,
              const std::vector<double>& ms, int stepsRun) {
  row(bench, kase.c_str(), particles, threads, "ms_per_step", median(ms), "ms");
  for (const auto& e : w.profile().entries())
    if (e.calls > 0) row(bench, (kase + "." + e.name).c_str(), particles, threads, "ms_per_step", 1e3 * e.seconds / stepsRun, "ms");
}

}  // namespace physketch::bench
