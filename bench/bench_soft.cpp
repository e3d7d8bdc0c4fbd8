// Soft bodies (clustered shape matching): two jelly cubes of 20^3 particles (1 cm spacing,
// E = 3e3 Pa, the default cluster radius 3 and spacing 2 spacings) dropped 5 cm onto the
// ground, and between them a plastic clay cube of 10^3 (plastic_creep 20, yield 0.02): 17,000
// particles; 8 substeps x 4 iterations per 1/60 s step, the settings of scenes/jelly.scene.
// 60 steps (1 s: the fall, the squash and the wobble).
// Prints `pbd,soft,N,T,ms_per_step,...` (median over the steps after 3 warm-up steps) and one
// row per pass (ms per step, mean over all steps).
//   build/bench/bench_soft [--threads N] [--steps S] [--n N] [--iterations K]
#include <cstdio>
#include <string>
#include <vector>

#include <tbb/global_control.h>

#include "bench/bench_common.h"
#include "core/material_table.h"
#include "pbd/world.h"

using namespace physketch;

int main(int argc, char** argv) {
  int threads = 1, steps = 60, n = 20, iterations = 4;
  bench::intOptions(argc, argv, {{"--threads", &threads}, {"--steps", &steps}, {"--n", &n}, {"--iterations", &iterations}});
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
  const double h = 0.01, r = 0.5 * h;
  Material jelly = makeMaterial(MaterialKind::kSoft, "jelly");
  jelly.density = 1050.0;
  jelly.elastic.youngs = 3e3;
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
  pbd::PbdWorld w(p, bodies, {jelly, clay}, prm);
  std::vector<double> ms;
  if (!bench::timeSteps(w, 3, steps, "bench_soft", ms)) return 1;
  bench::stepRows("pbd", "soft", p.size(), threads, w, ms, steps + 3);
  return 0;
}
