// MLS-MPM speed (mpm/world.h): particle-steps per second and ms per pass for cubes of
// particles built through the solver API (not the sketch), so that results compare with
// the peers' scripts (../shared/peers/mpm3d_taichi.py): a unit box, particles at spacing
// dx/2 (8 per cell), dt = 0.0128 / grid cells (the peers' default: 2e-4 s at 64^3, 1e-4 s at 128^3),
// one substep per step.
//   fluid_cube / corotated_cube: 64,000 particles (40^3) on a 64^3 grid, the peers' constants
//     (rho = 1; fluid E = 400 as the bulk modulus, gamma = 1; fixed corotated E = 1000, nu = 0.2);
//   fluid_cube / elastic_cube / sand_cube: 262,144 particles (64^3) on a 128^3 grid (the fluid as
//     above; the solids E = 1e3, nu = 0.2, rho = 1: the peers' solid; the earlier E = 1e4 broke
//     the explicit bound 5-fold and inverted at step 12).
//   fluid_shift: fluid_cube (64,000) with particle_shift 0.8, whose pass runs once a step (here
//     every substep): ms_particle_shift is what a neighbour search of 64,000 fluid particles and
//     two shifting sweeps cost (a scene pays it once per dt, not per substep).
//   svd3: the 3x3 SVD alone on one thread, 131,072 trial F of a deforming solid (the identity
//     plus uniform noise of +-0.05 per entry, as in a return map), ns per matrix: svd3 one at a
//     time against svd3Many (the return maps' batches) on the same matrices.
//   logexp: the return maps' ln and exp alone on one thread, 192 values a call (a batch of 64
//     particles' singular values, in [0.5, 1.5]; strains in [-0.7, 0.4]), ns per value: the C
//     library's logf / expf one at a time against logMany / expMany (mpm/logexp.h).
// Prints CSV rows `bench,case,particles,threads,metric,value,unit`: particle_steps_per_s (the
// median of --repeats timed runs of --steps steps, after one warm-up step), ms_<pass> per
// step, and the process's peak resident memory after the case.
//
//   bench_mpm [--threads N] [--steps S] [--repeats R] [--only SUBSTRING]
#include <sys/resource.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include <tbb/global_control.h>

#include "bench/bench_common.h"
#include "core/material_table.h"
#include "core/profile.h"
#include "mpm/logexp.h"
#include "mpm/svd3.h"
#include "mpm/world.h"

using namespace physketch;
using physketch::bench::median;
using physketch::bench::row;

namespace {

struct Case {
  const char* name;
  int side;       // particles per cube edge
  int gridCells;  // grid cells across the unit box
  Material material;
  double particleShift = 0.0;  // MpmParams::particleShift (the fluid_shift case)
};

Material peerMaterial(MaterialKind kind, double E, double nu) {
  Material m = makeMaterial(kind, "m");
  m.density = 1.0;
  m.elastic.youngs = E;
  m.elastic.poisson = nu;
  m.fluid.bulkModulus = E;  // mpm3d's fluid: p = E (1 - J), i.e. K = E, gamma = 1
  m.fluid.gamma = 1.0;
  m.fluid.viscosity = 0.0;
  return m;
}

double peakRssMiB() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_maxrss) / 1024.0;
}

void runCase(const Case& c, int threads, int steps, int repeats) {
  const double dx = 1.0 / c.gridCells, h = 0.5 * dx;
  ParticleArrays p;
  BodyRange body;
  const double lo = 0.5 - 0.5 * c.side * h;  // a centred cube, like the peers' (they start at 0.25..0.3)
  for (int i = 0; i < c.side; ++i)
    for (int j = 0; j < c.side; ++j)
      for (int k = 0; k < c.side; ++k)
        p.push(float(lo + (i + 0.5) * h), float(lo + (j + 0.5) * h), float(lo + (k + 0.5) * h), 0, 0);
  body.count = static_cast<std::int32_t>(p.size());
  mpm::MpmParams q;
  q.dt = 0.0128 / c.gridCells;
  q.substeps = 1;
  q.spacing = h;
  q.domainMin = Vec3::Zero();
  q.domainSize = 1.0;
  q.maxSpeed = 1e3;
  q.particleShift = c.particleShift;
  std::vector<double> rates;
  std::vector<double> passMs;
  std::vector<std::string> passNames;
  for (int r = 0; r < repeats; ++r) {
    mpm::MpmWorld w(p, {body}, {c.material}, q);
    w.step();  // warm-up: first touch of the grid
    const double t0 = nowSeconds();
    for (int s = 0; s < steps; ++s)
      if (!w.step()) {
        std::fprintf(stderr, "bench_mpm %s: %s\n", c.name, w.guard().message().c_str());
        std::exit(2);
      }
    const double t = nowSeconds() - t0;
    rates.push_back(double(p.size()) * steps / t);
    // The state after the run, on stderr: a change made for speed alone must leave it as it was.
    if (r == 0) std::fprintf(stderr, "bench_mpm %s: state hash after %d steps %016llx\n", c.name, steps + 1,
                             static_cast<unsigned long long>(w.stateHash()));
    if (r == 0) {
      for (const auto& e : w.profile().entries()) {
        passNames.push_back(e.name);
        passMs.push_back(e.calls > 0 ? 1e3 * e.seconds / double(steps + 1) : 0.0);
      }
    }
  }
  row("mpm", c.name, p.size(), threads, "particle_steps_per_s", median(rates), "1/s");
  for (std::size_t k = 0; k < passNames.size(); ++k)
    if (passMs[k] > 0.0) row("mpm", c.name, p.size(), threads, ("ms_" + passNames[k]).c_str(), passMs[k], "ms");
  row("mpm", c.name, p.size(), threads, "peak_rss", peakRssMiB(), "MiB");
}

void runSvd(int repeats) {
  const std::size_t n = 131072;
  std::vector<Eigen::Matrix3f> F(n);
  std::uint32_t seed = 12345;
  const auto noise = [&] {  // a fixed LCG: the same matrices on every run
    seed = seed * 1664525u + 1013904223u;
    return 0.05f * (float(seed >> 8) / float(1u << 24) * 2.0f - 1.0f);
  };
  for (auto& f : F) f = Eigen::Matrix3f::Identity() + Eigen::Matrix3f::NullaryExpr([&](Eigen::Index, Eigen::Index) {
                          return noise();
                        });
  std::vector<const Eigen::Matrix3f*> ptr(n);
  for (std::size_t k = 0; k < n; ++k) ptr[k] = &F[k];
  std::vector<mpm::Svd3<float>> out(n);
  std::vector<double> one, many;
  float sink = 0.0f;
  for (int r = 0; r < repeats; ++r) {
    double t0 = nowSeconds();
    for (std::size_t k = 0; k < n; ++k) out[k] = mpm::svd3<float>(F[k]);
    one.push_back(1e9 * (nowSeconds() - t0) / double(n));
    sink += out[n / 2].sigma(0);
    t0 = nowSeconds();
    mpm::svd3Many(ptr.data(), n, out.data());
    many.push_back(1e9 * (nowSeconds() - t0) / double(n));
    sink += out[n / 2].sigma(0);
  }
  if (!(sink > 0.0f)) std::fprintf(stderr, "bench_mpm svd3: unexpected result\n");
  row("mpm", "svd3", n, 1, "ns_per_svd_one_at_a_time", median(one), "ns");
  row("mpm", "svd3", n, 1, "ns_per_svd_many", median(many), "ns");
}

void runLogExp(int repeats) {
  constexpr std::size_t kN = 192, kCalls = 20000;
  std::vector<float> x(kN), e(kN), y(kN);
  for (std::size_t k = 0; k < kN; ++k) {
    x[k] = 0.5f + float(k) / float(kN);
    e[k] = -0.7f + 1.1f * float(k) / float(kN);
  }
  std::vector<double> libLog, lanesLog, libExp, lanesExp;
  float sink = 0.0f;
  const auto time = [&](std::vector<double>& into, auto&& body) {
    const double t0 = nowSeconds();
    for (std::size_t c = 0; c < kCalls; ++c) {
      body();
      sink += y[c % kN];
    }
    into.push_back(1e9 * (nowSeconds() - t0) / double(kCalls * kN));
  };
  for (int r = 0; r < repeats; ++r) {
    time(libLog, [&] { for (std::size_t k = 0; k < kN; ++k) y[k] = std::log(x[k]); });
    time(lanesLog, [&] { mpm::logMany(x.data(), y.data(), kN); });
    time(libExp, [&] { for (std::size_t k = 0; k < kN; ++k) y[k] = std::exp(e[k]); });
    time(lanesExp, [&] { mpm::expMany(e.data(), y.data(), kN); });
  }
  if (!std::isfinite(sink)) std::fprintf(stderr, "bench_mpm logexp: unexpected result\n");
  row("mpm", "logexp", kN, 1, "ns_per_logf", median(libLog), "ns");
  row("mpm", "logexp", kN, 1, "ns_per_log_many", median(lanesLog), "ns");
  row("mpm", "logexp", kN, 1, "ns_per_expf", median(libExp), "ns");
  row("mpm", "logexp", kN, 1, "ns_per_exp_many", median(lanesExp), "ns");
}

}  // namespace

int main(int argc, char** argv) {
  int threads = 1, steps = 20, repeats = 3;
  std::string only;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool more = i + 1 < argc;
    if (a == "--threads" && more) threads = std::atoi(argv[++i]);
    else if (a == "--steps" && more) steps = std::atoi(argv[++i]);
    else if (a == "--repeats" && more) repeats = std::atoi(argv[++i]);
    else if (a == "--only" && more) only = argv[++i];
    else {
      std::fprintf(stderr, "usage: bench_mpm [--threads N] [--steps S] [--repeats R] [--only SUBSTRING]\n");
      return 1;
    }
  }
  if (threads < 1 || steps < 1 || repeats < 1) {
    std::fprintf(stderr, "bench_mpm: --threads, --steps and --repeats must be >= 1\n");
    return 1;
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
  const std::vector<Case> cases = {
      {"fluid_cube", 40, 64, peerMaterial(MaterialKind::kFluid, 400.0, 0.2)},
      {"corotated_cube", 40, 64, peerMaterial(MaterialKind::kElastic, 1000.0, 0.2)},
      {"fluid_cube", 64, 128, peerMaterial(MaterialKind::kFluid, 400.0, 0.2)},
      {"elastic_cube", 64, 128, peerMaterial(MaterialKind::kElastic, 1e3, 0.2)},
      {"sand_cube", 64, 128, peerMaterial(MaterialKind::kSand, 1e3, 0.2)},
      {"fluid_shift", 40, 64, peerMaterial(MaterialKind::kFluid, 400.0, 0.2), 0.8},
  };
  for (const Case& c : cases)
    if (only.empty() || std::string(c.name).find(only) != std::string::npos) runCase(c, threads, steps, repeats);
  if (only.empty() || std::string("svd3").find(only) != std::string::npos) runSvd(std::max(repeats, 5));
  if (only.empty() || std::string("logexp").find(only) != std::string::npos) runLogExp(std::max(repeats, 5));
  return 0;
}
