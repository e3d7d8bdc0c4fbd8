// Neighbour grid speed (core/neighbor_grid.h): building the grid (the counting sort by
// cell) and one full neighbour pass, for an 80,000-particle block of fluid (the PBF
// target) and for 688,590 particles (the sketch cap). Particles sit on a lattice of
// spacing d jittered by +-0.1 d (a settled fluid is not a perfect lattice), with the
// kernel radius h = 2.1 d = cell size: 30.7 neighbours on average (printed; h = 2 d
// gives 27.5, a perfect lattice's shells make the count jump around 2 d).
// Prints CSV rows `bench,case,particles,threads,metric,value,unit` with the median of
// --repeats runs (after one warm-up run, as a solver reuses the grid every step).
//
//   bench_neighbor [--threads N] [--repeats R] [--only SUBSTRING]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include <tbb/global_control.h>

#include "bench/bench_common.h"
#include "core/neighbor_grid.h"
#include "core/profile.h"

using namespace physketch;
using physketch::bench::median;

namespace {

template <class F>
double medianMs(int repeats, F&& f) {
  f();  // warm-up: first touch of the grid's buffers
  std::vector<double> t;
  for (int r = 0; r < repeats; ++r) {
    const double t0 = nowSeconds();
    f();
    t.push_back(1e3 * (nowSeconds() - t0));
  }
  return median(t);
}

struct Block {
  std::vector<float> x, y, z;
};

// The first n points of an nx-wide, ny-high lattice of spacing d (filled x, then z, then
// y: a dam-break column), each moved by a uniform jitter of +-0.1 d; ids in fill order.
Block fluidBlock(std::size_t n, int nx, int nz, float d) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> jitter(-0.1f * d, 0.1f * d);
  Block b;
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t ix = i % std::size_t(nx), iz = i / std::size_t(nx) % std::size_t(nz);
    const std::size_t iy = i / (std::size_t(nx) * std::size_t(nz));
    b.x.push_back(d * float(ix) + jitter(rng));
    b.y.push_back(d * float(iy) + jitter(rng));
    b.z.push_back(d * float(iz) + jitter(rng));
  }
  return b;
}

// The same points with ids in random order: the sort moves every particle far.
Block shuffled(const Block& b) {
  std::vector<std::size_t> p(b.x.size());
  std::iota(p.begin(), p.end(), std::size_t(0));
  std::shuffle(p.begin(), p.end(), std::mt19937(2));
  Block s;
  for (std::size_t i : p) s.x.push_back(b.x[i]), s.y.push_back(b.y[i]), s.z.push_back(b.z[i]);
  return s;
}

void runCase(const char* name, const Block& b, float d, int threads, int repeats) {
  const std::size_t n = b.x.size();
  const float h = 2.1f * d;  // kernel radius = cell size (m)
  auto row = [&](const char* metric, double value, const char* unit) {
    std::printf("neighbor,%s,%zu,%d,%s,%.4g,%s\n", name, n, threads, metric, value, unit);
  };
  NeighborGrid grid;
  row("build_ms", medianMs(repeats, [&] { grid.build(b.x.data(), b.y.data(), b.z.data(), n, h); }), "ms");
  const Block s = shuffled(b);
  NeighborGrid mixed;
  row("build_shuffled_ms", medianMs(repeats, [&] { mixed.build(s.x.data(), s.y.data(), s.z.data(), n, h); }), "ms");
  row("sort_passes", grid.sortPasses(), "count");
  row("cells", double(grid.cellCount()), "count");

  // Size the lists from a first pass, as a solver would after an overflow: a multiple of 16.
  NeighborLists lists;
  grid.buildNeighborLists(h, 1, lists);
  const int width = (lists.maxCount + 15) / 16 * 16;
  row("lists_ms", medianMs(repeats, [&] { grid.buildNeighborLists(h, width, lists); }), "ms");
  // The other kernels (kAuto takes AVX-512 where the CPU has it), for machines without it.
  if (NeighborGrid::cpuHas(NeighborGrid::Kernel::kAvx512) && NeighborGrid::cpuHas(NeighborGrid::Kernel::kAvx2))
    row("lists_avx2_ms",
        medianMs(repeats, [&] { grid.buildNeighborLists(h, width, lists, NeighborGrid::Kernel::kAvx2); }), "ms");
  row("lists_scalar_ms",
      medianMs(repeats, [&] { grid.buildNeighborLists(h, width, lists, NeighborGrid::Kernel::kScalar); }), "ms");
  double total = 0;
  for (std::int32_t c : lists.count) total += c;
  row("list_width", width, "count");
  row("mean_neighbors", total / double(n), "count");
  row("max_neighbors", lists.maxCount, "count");
  row("overflowed", double(lists.overflowed), "count");

  // The same neighbours through the per-particle callback (serial; for contacts).
  std::vector<std::int32_t> counted(n);
  row("foreach_count_ms", medianMs(repeats, [&] {
        for (std::size_t i = 0; i < n; ++i) {
          std::int32_t k = 0;
          grid.forEachNeighbor(std::int32_t(i), h, [&](std::int32_t) { ++k; });
          counted[i] = k;
        }
      }),
      "ms");
  std::vector<float> byRank(n), byId(n);
  row("gather_scatter_ms", medianMs(repeats, [&] {
        grid.gather(b.x.data(), byRank.data());
        grid.scatter(byRank.data(), byId.data());
      }),
      "ms");
}

}  // namespace

int main(int argc, char** argv) {
  int repeats = 7, threads = 1;
  std::string only;  // run only the cases whose name contains this
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--repeats") && i + 1 < argc) repeats = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) threads = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--only") && i + 1 < argc) only = argv[++i];
    else {
      std::fprintf(stderr, "usage: bench_neighbor [--threads N] [--repeats R] [--only SUBSTRING]\n");
      return 1;
    }
  }
  tbb::global_control threadLimit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  const float d = 0.01f;  // lattice spacing (m)
  if (std::string("fluid80k").find(only) != std::string::npos)
    runCase("fluid80k", fluidBlock(80000, 40, 40, d), d, threads, repeats);  // 40 x 40 x 50
  if (std::string("cap688k").find(only) != std::string::npos)
    runCase("cap688k", fluidBlock(688590, 88, 88, d), d, threads, repeats);  // 88 x 88 x 89 (last layer partial)
  return 0;
}
