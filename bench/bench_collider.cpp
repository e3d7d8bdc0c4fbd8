// Mesh collider queries (pbd/mesh_collider.h): 80,000 particles near a 10,000-triangle
// closed mesh (a torus, ring radius 0.3 m, tube 0.1 m, 100 x 50 quads split in two) at the
// sketch's particle size (h = 1/151 m, radius h/2). Each particle sits on the surface moved
// along its normal by a uniform offset in [-2, 4] radii, so about half touch it (a layer of
// fluid or sand resting on a collider) and some are inside. Rows (median of --repeats after
// one warm-up), for the particles in random order (case torus_10k_tris) and sorted by a
// 2 cm grid's cells (torus_10k_tris_cell_order: the BVH nodes a query walks stay in cache):
//   build_ms     ColliderSet construction (normals, Bullet's quantized BVH)
//   contacts_ms  ColliderSet::contacts for every particle (radius + margin = 2 radii)
//   sweep_ms     ColliderSet::sweep for every particle moving 2 radii towards the surface
//                (one call per particle in fixed chunks, as a solver would run it)
//   *_cpu_ms     the same, process CPU time (the work when the machine is shared; summed
//                over threads)
//   contacts     the number of contacts found (a check that the case is what it says)
//
//   bench_collider [--threads N] [--repeats R]
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include "bench/bench_common.h"
#include "core/profile.h"
#include "pbd/mesh_collider.h"

using namespace physketch;
using physketch::bench::median;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kRing = 0.3, kTube = 0.1;

double cpuSeconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

// Median wall and process CPU time (ms) of `repeats` runs after one warm-up. The CPU time
// is the work itself when the machine is shared (other builds on the 2 cores stretch the
// wall time); with 2 threads it is the sum over both.
struct Timing {
  double wallMs, cpuMs;
};
template <class F>
Timing medianMs(int repeats, F&& f) {
  f();
  std::vector<double> wall, cpu;
  for (int r = 0; r < repeats; ++r) {
    const double t0 = nowSeconds(), c0 = cpuSeconds();
    f();
    wall.push_back(1e3 * (nowSeconds() - t0));
    cpu.push_back(1e3 * (cpuSeconds() - c0));
  }
  return {median(wall), median(cpu)};
}

Vec3 torusPoint(double u, double v, double offset) {
  const Vec3 n(std::cos(v) * std::cos(u), std::sin(v), std::cos(v) * std::sin(u));
  const Vec3 centre(kRing * std::cos(u), 0, kRing * std::sin(u));
  return centre + (kTube + offset) * n;
}

TriangleSoup torus(int nu, int nv) {
  TriangleSoup s;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) s.vertices.push_back(torusPoint(2 * kPi * i / nu, 2 * kPi * j / nv, 0));
  auto id = [nu, nv](int i, int j) { return ((i + nu) % nu) * nv + (j + nv) % nv; };
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {  // outward: (du x dv) points away from the tube centre
      s.triangles.push_back({id(i, j), id(i, j + 1), id(i + 1, j + 1)});
      s.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i + 1, j)});
    }
  s.closed = true;
  return s;
}

struct Particles {
  std::vector<float> x, y, z;     // positions (m)
  std::vector<float> tx, ty, tz;  // where each moves in one substep (sweep targets)
  std::size_t size() const { return x.size(); }
};

// The same particles in the order of the cells of a 2 cm grid (z, y, x): what a solver that
// keeps its particles in cell order (the neighbour grid's) hands to the queries.
Particles inCellOrder(const Particles& p) {
  std::vector<std::size_t> order(p.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  auto cell = [](float v) { return static_cast<long>(std::floor((v + 1.0f) / 0.02f)); };
  auto key = [&](std::size_t i) { return (cell(p.z[i]) * 1000 + cell(p.y[i])) * 1000 + cell(p.x[i]); };
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return key(a) < key(b); });
  Particles q;
  for (std::size_t i : order) {
    q.x.push_back(p.x[i]), q.y.push_back(p.y[i]), q.z.push_back(p.z[i]);
    q.tx.push_back(p.tx[i]), q.ty.push_back(p.ty[i]), q.tz.push_back(p.tz[i]);
  }
  return q;
}

void runCase(const char* kase, const pbd::ColliderSet& set, const Particles& p, double radius, int threads,
             int repeats) {
  const std::size_t n = p.size();
  std::vector<pbd::MeshContact> contacts;
  const Timing contactsT =
      medianMs(repeats, [&] { set.contacts(p.x.data(), p.y.data(), p.z.data(), n, radius, radius, contacts); });
  std::vector<unsigned char> hit(n);
  const Timing sweepT = medianMs(repeats, [&] {
    const std::size_t chunk = pbd::ColliderSet::kChunk, chunks = (n + chunk - 1) / chunk;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t k = r.begin(); k != r.end(); ++k)
        for (std::size_t i = k * chunk; i < std::min(n, (k + 1) * chunk); ++i)
          hit[i] = set.sweep(Vec3(p.x[i], p.y[i], p.z[i]), Vec3(p.tx[i], p.ty[i], p.tz[i]), radius).hit;
    });
  });
  std::size_t hits = 0;
  for (unsigned char h : hit) hits += h;
  bench::row("collider", kase, n, threads, "contacts_ms", contactsT.wallMs, "ms");
  bench::row("collider", kase, n, threads, "contacts_cpu_ms", contactsT.cpuMs, "ms");
  bench::row("collider", kase, n, threads, "sweep_ms", sweepT.wallMs, "ms");
  bench::row("collider", kase, n, threads, "sweep_cpu_ms", sweepT.cpuMs, "ms");
  bench::row("collider", kase, n, threads, "contacts", double(contacts.size()), "count");
  bench::row("collider", kase, n, threads, "sweep_hits", double(hits), "count");
}

}  // namespace

int main(int argc, char** argv) {
  int threads = 2, repeats = 7;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) threads = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--repeats") && i + 1 < argc) repeats = std::atoi(argv[++i]);
    else {
      std::fprintf(stderr, "usage: bench_collider [--threads N] [--repeats R]\n");
      return 2;
    }
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));

  const std::size_t n = 80000;
  const double radius = 0.5 / 151.0;
  TriangleSoup soup = torus(100, 50);
  // The winding above is outward when (du x dv) . n > 0; flip otherwise (checked once).
  {
    const auto& t = soup.triangles[0];
    const Vec3 a = soup.vertices[t[0]], b = soup.vertices[t[1]], c = soup.vertices[t[2]];
    if ((b - a).cross(c - a).dot(a - Vec3(kRing, 0, 0)) < 0)
      for (auto& tri : soup.triangles) std::swap(tri[1], tri[2]);
  }
  MeshCollider desc;
  desc.name = "torus";
  std::vector<MeshCollider> descs{desc};
  std::vector<TriangleSoup> soups{soup};

  std::mt19937 rng(1);
  std::uniform_real_distribution<double> unit(0, 1);
  Particles random;
  for (std::size_t i = 0; i < n; ++i) {
    const double u = 2 * kPi * unit(rng), v = 2 * kPi * unit(rng), off = radius * (-2 + 6 * unit(rng));
    const Vec3 p = torusPoint(u, v, off), to = torusPoint(u, v, off - 2 * radius);
    random.x.push_back(float(p.x())), random.y.push_back(float(p.y())), random.z.push_back(float(p.z()));
    random.tx.push_back(float(to.x())), random.ty.push_back(float(to.y())), random.tz.push_back(float(to.z()));
  }

  const Timing build = medianMs(repeats, [&] { pbd::ColliderSet s(descs, soups); });
  bench::row("collider", "torus_10k_tris", n, threads, "build_ms", build.wallMs, "ms");
  const pbd::ColliderSet set(descs, soups);
  runCase("torus_10k_tris", set, random, radius, threads, repeats);
  runCase("torus_10k_tris_cell_order", set, inCellOrder(random), radius, threads, repeats);
  return 0;
}
