// Soft bodies (clustered shape matching): two jelly cubes of 20^3 particles (1 cm spacing,
// E = 3e3 Pa, the default cluster radius 3 and spacing 2 spacings) dropped 5 cm onto the
// ground, and between them a plastic clay cube of 10^3 (plastic_creep 20, yield 0.02): 17,000
// particles; 8 substeps x 4 iterations per 1/60 s step, the settings of scenes/jelly.scene.
// Two cases (both by default, or --only NAME):
//   soft        sleeping off, 60 steps (1 s: the fall, the squash and the wobble): the median step
//               after 3 warm-up steps, and one row per pass (ms per step, mean over all steps)
//   soft_sleep  sleeping on at 0.02 m/s (a scene's default at this spacing: 2 spacings per
//               second; `sleep`, docs/formats.md) and the jelly at E = 1e4 Pa (at 3e3 its 20 cm
//               cubes sag by 69 % of their height and walk on, never still: docs/accuracy.md);
//               480 steps (8 s): the median of the last 60 (what the bodies cost once settled),
//               the bodies asleep at the end and when the last one fell asleep (s; the run's
//               length if some never did)
// Prints `pbd,CASE,N,T,ms_per_step,...` and the rows above.
//   build/bench/bench_soft [--threads N] [--steps S] [--n N] [--iterations K] [--only soft|soft_sleep]
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include <tbb/global_control.h>

#include "bench/bench_common.h"
#include "core/material_table.h"
#include "pbd/world.h"

using namespace physketch;

namespace {

int runCase(bool sleep, int threads, int steps, int n, int iterations) {
  const double h = 0.01, r = 0.5 * h;
  Material jelly = makeMaterial(MaterialKind::kSoft, "jelly");
  jelly.density = 1050.0;
  jelly.elastic.youngs = sleep ? 1e4 : 3e3;
  Material clay = makeMaterial(MaterialKind::kSoft, "clay");
  clay.density = 1800.0;
  clay.elastic.youngs = 2e3;
  clay.soft.plasticYield = 0.02;
  clay.soft.plasticCreep = 20.0;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  const double gap = (n + 2) * h;
  for (int b = 0; b < 3; ++b) {
    BodyRange range;
    range.first = static_cast<std::int32_t>(p.size());
    const double x0 = (b - 1) * gap;
    const int side = b == 1 ? n / 2 : n;  // the clay cube is half as wide
    for (int i = 0; i < side; ++i)
      for (int j = 0; j < side; ++j)
        for (int k = 0; k < side; ++k)
          p.push(float(x0 + i * h), float(0.05 + r + j * h), float(k * h), b, b == 1 ? 1 : 0);
    range.count = side * side * side;
    bodies.push_back(range);
  }
  pbd::PbdParams prm;
  prm.substeps = 8;
  prm.iterations = iterations;
  prm.particleRadius = r;
  prm.sleepSpeed = sleep ? 0.02 : 0.0;
  pbd::PbdWorld w(p, bodies, {jelly, clay}, prm);
  std::vector<double> ms;
  if (!sleep) {
    if (!bench::timeSteps(w, 3, steps, "bench_soft", ms)) return 1;
    bench::stepRows("pbd", "soft", p.size(), threads, w, ms, steps + 3);
    return 0;
  }
  const int total = 480;
  double allAsleepAt = 0.0;
  if (!bench::timeStepsAsleep(w, total, "bench_soft", ms, allAsleepAt)) return 1;
  bench::stepRows("pbd", "soft_sleep", p.size(), threads, w, std::vector<double>(ms.end() - 60, ms.end()), total);
  bench::row("pbd", "soft_sleep", p.size(), threads, "asleep_end", double(w.sleepingCount()), "count");
  bench::row("pbd", "soft_sleep", p.size(), threads, "all_asleep_at", allAsleepAt, "s");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  int threads = 1, steps = 60, n = 20, iterations = 4;
  bench::intOptions(argc, argv, {{"--threads", &threads}, {"--steps", &steps}, {"--n", &n}, {"--iterations", &iterations}});
  std::string only;
  for (int i = 1; i + 1 < argc; ++i)
    if (!std::strcmp(argv[i], "--only")) only = argv[i + 1];
  if (!only.empty() && only != "soft" && only != "soft_sleep") {
    std::fprintf(stderr, "usage: bench_soft [--threads N] [--steps S] [--n N] [--iterations K] [--only soft|soft_sleep]\n");
    return 2;
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
  int rc = 0;
  if (only.empty() || only == "soft") rc |= runCase(false, threads, steps, n, iterations);
  if (only.empty() || only == "soft_sleep") rc |= runCase(true, threads, steps, n, iterations);
  return rc;
}
