// Issue 11, "cost follows content": a scene pays only for the passes its content needs.
// Case rigid_only: 64 wooden boxes (6^3 particles each, 13,824 particles) resting on the
// ground, 4 substeps x 4 iterations. Case rigid_plus_fluid: the same boxes and a 20^3 block
// of water (8,000 particles) beside them, not touching. The fluid adds its own passes
// (predict, density, ...); every pass the rigid scene already ran may grow by no more than
// the added particles' share of the passes it touches (all particles for write_particles and
// guard, none for the rigid passes), plus 10 %. Both cases run in alternating rounds so that
// the shared machine's noise falls on both; medians over rounds.
// Rows: `plan,CASE,PARTICLES,THREADS,PASS,ms_per_step,ms`, then per pass the growth
// `plan,growth,...,PASS,ratio,1` and the allowed ratio, and a summary row
// `plan,rigid_plus_fluid,...,passes_within_share,K,count` (of passes_compared), and the
// guard's share of each case's step in percent.
//   build/bench/bench_plan [--threads N] [--steps S] [--rounds R]
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <string>
#include <vector>

#include <tbb/global_control.h>

#include "bench/bench_common.h"
#include "core/material_table.h"
#include "core/profile.h"
#include "pbd/world.h"

using namespace physketch;

namespace {

constexpr double kSpacing = 0.01, kRadius = 0.5 * kSpacing;

BodyRange addBox(ParticleArrays& p, const Vec3& corner, int nx, int ny, int nz, int stroke, std::int16_t material) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        const Vec3 x = corner + kSpacing * Vec3(i, j, k);
        p.push(float(x.x()), float(x.y()), float(x.z()), stroke, material);
      }
  b.count = nx * ny * nz;
  b.stroke = stroke;
  return b;
}

// ms per step of each pass that ran, over `steps` steps after 5 warm-up steps.
std::map<std::string, double> runCase(bool withFluid, int steps, std::size_t& particles) {
  Material wood = makeMaterial(MaterialKind::kRigid, "wood");
  Material water = makeMaterial(MaterialKind::kFluid, "water");
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  for (int a = 0; a < 8; ++a)
    for (int c = 0; c < 8; ++c)
      bodies.push_back(addBox(p, Vec3(0.1 * a, kRadius, 0.1 * c), 6, 6, 6, int(bodies.size()), 0));
  if (withFluid) bodies.push_back(addBox(p, Vec3(1.2, kRadius, 0.0), 20, 20, 20, int(bodies.size()), 1));
  particles = p.size();
  pbd::PbdParams prm;
  prm.substeps = 4;
  prm.iterations = 4;
  prm.particleRadius = kRadius;
  pbd::PbdWorld w(p, bodies, {wood, water}, prm);
  for (int s = 0; s < 5; ++s) w.step();
  const std::vector<Profile::Entry> warm = w.profile().entries();
  for (int s = 0; s < steps; ++s)
    if (!w.step()) {
      std::fprintf(stderr, "bench_plan: %s\n", w.guard().message().c_str());
      std::exit(1);
    }
  std::map<std::string, double> ms;
  const std::vector<Profile::Entry>& all = w.profile().entries();
  for (std::size_t k = 0; k < all.size(); ++k)
    if (all[k].calls > warm[k].calls) ms[all[k].name] = 1e3 * (all[k].seconds - warm[k].seconds) / steps;
  return ms;
}

}  // namespace

int main(int argc, char** argv) {
  int threads = 1, steps = 20, rounds = 3;
  for (int i = 1; i + 1 < argc; ++i) {
    if (!std::strcmp(argv[i], "--threads")) threads = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--steps")) steps = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--rounds")) rounds = std::atoi(argv[++i]);
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
  std::map<std::string, std::vector<double>> rigid, mixed;
  std::size_t nRigid = 0, nMixed = 0;
  for (int r = 0; r < rounds; ++r) {
    for (const auto& [pass, ms] : runCase(false, steps, nRigid)) rigid[pass].push_back(ms);
    for (const auto& [pass, ms] : runCase(true, steps, nMixed)) mixed[pass].push_back(ms);
  }
  for (const auto& [pass, v] : rigid) bench::row("plan", "rigid_only", nRigid, threads, pass.c_str(), bench::median(v), "ms");
  for (const auto& [pass, v] : mixed)
    bench::row("plan", "rigid_plus_fluid", nMixed, threads, pass.c_str(), bench::median(v), "ms");
  // Passes over every particle grow with all of them; the rigid passes touch only the boxes.
  const double share = double(nMixed) / double(nRigid);
  int within = 0, total = 0;
  for (const auto& [pass, v] : rigid) {
    const auto it = mixed.find(pass);
    if (it == mixed.end()) continue;
    const bool allParticles = pass == "write_particles" || pass == "guard";
    const double allowed = 1.10 * (allParticles ? share : 1.0);
    const double a = bench::median(v), b = bench::median(it->second);
    // Passes under 0.1 ms per step in the mixed case are timer noise: they count as within.
    const double ratio = a > 0.0 ? b / a : 1.0;
    const bool ok = ratio <= allowed || b < 0.1;
    within += ok;
    ++total;
    bench::row("plan", "growth", nMixed, threads, (pass + "_ratio").c_str(), ratio, "1");
    bench::row("plan", "growth", nMixed, threads, (pass + "_allowed").c_str(), allowed, "1");
  }
  // The stability guard's share of a step (issue 11: at most 5 %).
  for (const auto* c : {&rigid, &mixed}) {
    double step = 0.0;
    for (const auto& [pass, v] : *c) step += bench::median(v);
    const auto g = c->find("guard");
    const double guard = g == c->end() ? 0.0 : bench::median(g->second);
    bench::row("plan", c == &rigid ? "rigid_only" : "rigid_plus_fluid", c == &rigid ? nRigid : nMixed, threads,
               "guard_share_of_step", 100.0 * guard / step, "percent");
  }
  bench::row("plan", "rigid_plus_fluid", nMixed, threads, "passes_within_share", within, "count");
  bench::row("plan", "rigid_plus_fluid", nMixed, threads, "passes_compared", total, "count");
  return 0;
}
