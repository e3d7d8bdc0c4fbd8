// The cloth case: an 80,000-particle cloth (a 283 x 283 lattice built through the
// API, 1 cm spacing) hanging from a fixed bar along its top edge, self-contact off (a cloth's
// own particles never collide), 5 substeps per 1/60 s step of 1 iteration each (the issue's
// setting; `--iterations` for more). Links are solved by family and colour (stable at 1
// iteration, each colour in parallel chunks).
// Prints `pbd,cloth,80089,T,ms_per_step,...` (median over the timed steps) and one row per pass.
//   build/bench/bench_cloth [--threads N] [--steps S] [--n N] [--iterations K]
#include <cstdio>
#include <string>
#include <vector>

#include <tbb/global_control.h>

#include "bench/bench_common.h"
#include "core/material_table.h"
#include "pbd/world.h"

using namespace physketch;

int main(int argc, char** argv) {
  int threads = 1, steps = 20, n = 283, iterations = 1;
  bench::intOptions(argc, argv, {{"--threads", &threads}, {"--steps", &steps}, {"--n", &n}, {"--iterations", &iterations}});
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));

  const double h = 0.01, r = 0.5 * h;
  Material bar = makeMaterial(MaterialKind::kRigid, "bar");
  Material linen = makeMaterial(MaterialKind::kCloth, "linen");
  linen.density = 300.0;
  ParticleArrays p;
  BodyRange barRange;
  barRange.first = 0;
  for (int c = 0; c < n; ++c) p.push(float(c * h), float(4.0 + h), 0.0f, 0, 0);
  barRange.count = n;
  barRange.init.fixed = true;
  BodyRange cloth;
  cloth.first = static_cast<std::int32_t>(p.size());
  for (int row = 0; row < n; ++row)
    for (int c = 0; c < n; ++c) p.push(float(c * h), float(4.0 - row * h), 0.0f, 1, 1);
  cloth.count = n * n;
  cloth.rows = cloth.cols = n;
  cloth.layout = BodyLayout::kLattice;
  pbd::PbdParams prm;
  prm.substeps = 5;
  prm.iterations = iterations;
  prm.particleRadius = r;
  pbd::PbdWorld w(p, {barRange, cloth}, {bar, linen}, prm);
  std::vector<double> ms;
  if (!bench::timeSteps(w, 3, steps, "bench_cloth", ms)) return 1;
  bench::stepRows("pbd", "cloth", std::size_t(n) * std::size_t(n), threads, w, ms, steps + 3);
  return 0;
}
