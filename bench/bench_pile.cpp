// Issue 8's rigid pile: 200 wooden boxes (5^3 particles each, 25,000 particles) dropped in 8
// layers of a 5 x 5 grid, each layer shifted half a box and turned, so they land on each other
// and settle into a pile; 8 substeps x 4 iterations, dt 1/60 s. Body-level rigid contact (one
// contact patch per body pair) is what this measures. Two cases:
//   pile        sleeping off, 180 steps (3 s): the contact solver's own cost
//   pile_sleep  sleeping on at 0.02 m/s (a scene's default: 2 spacings per second; `sleep`,
//               docs/formats.md), 480 steps (8 s): what a pile costs once its boxes fall asleep
// Rows: `pbd,CASE,25000,THREADS,ms_per_step,...` (median over the last 60 steps, the settled
// pile, where every body touches others), the median of the first 60 (falling, few contacts),
// one row per pass (ms per step over the whole run), the largest particle speed at the end
// (m/s), the lowest particle (m: nothing sinks into the ground), and for pile_sleep the bodies
// asleep at the end and the time when the last one fell asleep (s; the run's length if some
// never did).
//   build/bench/bench_pile [--threads N] [--substeps S] [--iterations I] [--only CASE]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include <tbb/global_control.h>
#include <tbb/info.h>

#include "bench/bench_common.h"
#include "core/material_table.h"
#include "core/profile.h"
#include "pbd/world.h"

using namespace physketch;
using physketch::bench::median;
using physketch::bench::row;

namespace {

int runCase(const char* name, int threads, int substeps, int iterations, double sleepSpeed, int steps) {
  constexpr double h = 0.01;
  constexpr int side = 5;  // particles per box edge
  Material wood = makeMaterial(MaterialKind::kRigid, "wood");
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  for (int layer = 0; layer < 8; ++layer) {
    const double turn = 0.35 * layer, shift = (layer % 2) * 0.5 * side * h;
    const Eigen::Matrix3d R = Eigen::AngleAxisd(turn, Vec3(0.3, 1.0, 0.2).normalized()).toRotationMatrix();
    for (int a = 0; a < 5; ++a)
      for (int c = 0; c < 5; ++c) {
        const Vec3 centre(shift + a * 1.6 * side * h, 0.05 + layer * 1.8 * side * h, shift + c * 1.6 * side * h);
        BodyRange b;
        b.first = static_cast<std::int32_t>(p.size());
        for (int k = 0; k < side; ++k)
          for (int j = 0; j < side; ++j)
            for (int i = 0; i < side; ++i) {
              const Vec3 x = centre + R * (h * (Vec3(i, j, k) - Vec3::Constant(0.5 * (side - 1))));
              p.push(float(x.x()), float(x.y()), float(x.z()), int(bodies.size()), 0);
            }
        b.count = side * side * side;
        b.stroke = int(bodies.size());
        bodies.push_back(b);
      }
  }
  pbd::PbdParams prm;
  prm.particleRadius = 0.5 * h;
  prm.substeps = substeps;
  prm.iterations = iterations;
  prm.sleepSpeed = sleepSpeed;
  pbd::PbdWorld w(p, bodies, {wood}, prm);
  std::vector<double> ms;
  double allAsleepAt = 0.0;
  if (!bench::timeStepsAsleep(w, steps, std::string("bench_pile: ") + name, ms, allAsleepAt)) return 1;
  const std::size_t n = p.size();
  row("pbd", name, n, threads, "ms_per_step", median(std::vector<double>(ms.end() - 60, ms.end())), "ms");
  row("pbd", name, n, threads, "ms_per_step_falling", median(std::vector<double>(ms.begin(), ms.begin() + 60)), "ms");
  for (const Profile::Entry& e : w.profile().entries())
    if (e.calls > 0) row("pbd", name, n, threads, (e.name + "_ms_per_step").c_str(), 1e3 * e.seconds / steps, "ms");
  const ParticleArrays& r = w.particles();
  double fastest = 0.0, lowest = 1e9;
  for (std::size_t i = 0; i < r.size(); ++i) {
    fastest = std::max(fastest, Vec3(r.vx[i], r.vy[i], r.vz[i]).norm());
    lowest = std::min(lowest, double(r.y[i]));
  }
  row("pbd", name, n, threads, "max_speed_end", fastest, "m/s");
  row("pbd", name, n, threads, "lowest_particle", lowest, "m");
  row("pbd", name, n, threads, "bodies", double(bodies.size()), "count");
  if (sleepSpeed > 0.0) {
    row("pbd", name, n, threads, "asleep_end", double(w.sleepingCount()), "count");
    row("pbd", name, n, threads, "all_asleep_at", allAsleepAt, "s");
  }
  // On stderr: a change meant to keep the results (a faster loop) must keep this hash.
  std::fprintf(stderr, "bench_pile: %s: state hash after %d steps %016llx\n", name, steps,
               static_cast<unsigned long long>(w.stateHash()));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  int threads = tbb::info::default_concurrency();
  int substeps = 8, iterations = 4;
  std::string only;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) threads = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--substeps") && i + 1 < argc) substeps = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--iterations") && i + 1 < argc) iterations = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--only") && i + 1 < argc) only = argv[++i];
    else {
      std::fprintf(stderr, "usage: bench_pile [--threads N] [--substeps S] [--iterations I] [--only pile|pile_sleep]\n");
      return 1;
    }
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  int rc = 0;
  if (only.empty() || only == "pile") rc |= runCase("pile", threads, substeps, iterations, 0.0, 180);
  if (only.empty() || only == "pile_sleep") rc |= runCase("pile_sleep", threads, substeps, iterations, 0.02, 480);
  return rc;
}
