// Sketch speed: voxelizing a 10,000-sample stroke for several brush sizes and shapes,
// and the primitives. Prints CSV rows `bench,case,particles,threads,metric,value,unit`
// with the median of --repeats runs.
//
//   bench_sketch [--threads N] [--repeats R] [--only SUBSTRING]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "bench/bench_common.h"
#include "core/profile.h"
#include "sketch/mesh_stamp.h"
#include "sketch/voxelize.h"

#include <filesystem>
#include <fstream>

#include <tbb/global_control.h>

using namespace physketch;
using physketch::bench::median;
using namespace physketch::sketch;

namespace {

// A 10,000-sample helix through the workspace, sampled at 90 Hz: about 0.7 voxel per sample.
std::string helixStroke(const std::string& brush, int samples) {
  std::string s = "physketch-strokes 1\nstroke create " + brush + "\n";
  char line[128];
  for (int i = 0; i < samples; ++i) {
    const double u = double(i) / samples;
    const double a = 12.0 * M_PI * u;
    std::snprintf(line, sizeof line, "sample %.6f %.6f %.6f %.6f\n", i / 90.0, 0.3 * std::cos(a), 0.15 + 0.7 * u,
                  0.3 * std::sin(a));
    s += line;
  }
  return s;
}

// A closed UV sphere of radius r with `stacks` x `slices` quads split in two (poles as fans).
void writeUvSphere(const std::string& path, double r, int stacks, int slices) {
  std::ofstream out(path);
  out << "v 0 " << r << " 0\n";
  for (int i = 1; i < stacks; ++i) {
    const double th = M_PI * i / stacks;
    for (int j = 0; j < slices; ++j) {
      const double ph = 2 * M_PI * j / slices;
      out << "v " << r * std::sin(th) * std::cos(ph) << " " << r * std::cos(th) << " " << r * std::sin(th) * std::sin(ph)
          << "\n";
    }
  }
  out << "v 0 " << -r << " 0\n";
  auto idx = [&](int ring, int j) { return 2 + (ring - 1) * slices + (j % slices); };
  const int south = 2 + (stacks - 1) * slices;
  for (int j = 0; j < slices; ++j) out << "f 1 " << idx(1, j + 1) << " " << idx(1, j) << "\n";
  for (int i = 1; i + 1 < stacks; ++i)
    for (int j = 0; j < slices; ++j) {
      out << "f " << idx(i, j) << " " << idx(i, j + 1) << " " << idx(i + 1, j + 1) << "\n";
      out << "f " << idx(i, j) << " " << idx(i + 1, j + 1) << " " << idx(i + 1, j) << "\n";
    }
  for (int j = 0; j < slices; ++j) out << "f " << south << " " << idx(stacks - 1, j) << " " << idx(stacks - 1, j + 1) << "\n";
}

}  // namespace

int main(int argc, char** argv) {
  int repeats = 5, threads = 1;
  std::string only;  // run only the cases whose name contains this (for profiling one case)
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--repeats") && i + 1 < argc) repeats = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) threads = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--only") && i + 1 < argc) only = argv[++i];
    else {
      std::fprintf(stderr, "usage: bench_sketch [--threads N] [--repeats R] [--only SUBSTRING]\n");
      return 1;
    }
  }
  // Long strokes are swept in parallel parts (sketch::voxelize is given the count); the
  // result does not depend on it. The process limit holds anything else TBB runs to it.
  threads = std::max(1, threads);
  tbb::global_control threadLimit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  const GridMapping map(Vec3(0, 0.5, 0), 1.0);
  Material wood;
  wood.name = "wood";
  const std::vector<Material> mats{wood};
  const char* brushes[] = {"sphere 0.02 wood", "sphere 0.05 wood", "sphere 0.1 wood", "cube 0.1 wood",
                           "capsule 0.05 wood orient=follow", "disc 0.1 wood orient=follow"};
  for (const char* brush : brushes) {
    std::string kase = std::string("stroke10k_") + brush;
    std::replace(kase.begin(), kase.end(), ' ', '_');
    std::replace(kase.begin(), kase.end(), ',', ';');
    if (kase.find(only) == std::string::npos) continue;
    const StrokeFile f = parseStrokes(helixStroke(brush, 10000), "bench.strokes");
    std::vector<double> t;
    std::size_t n = 0;
    long stamps = 0;
    for (int r = 0; r < repeats; ++r) {
      const double t0 = nowSeconds();
      const Sketch sk = voxelize(f, map, mats, {threads});
      t.push_back(nowSeconds() - t0);
      n = sk.particles.size();
      stamps = sk.operations[0].stamps;
    }
    std::printf("sketch,%s,%zu,%d,voxelize_ms,%.3f,ms\n", kase.c_str(), n, threads, 1e3 * median(t));
    std::printf("sketch,%s,%zu,%d,stamps,%ld,count\n", kase.c_str(), n, threads, stamps);
  }
  // Stamping a 100k-triangle closed mesh (radius 0.2 m: 40 % of the workspace width).
  if (std::string("stamp_sphere").find(only) == std::string::npos) return 0;
  const std::string meshPath = (std::filesystem::temp_directory_path() / "physketch_bench_sphere.obj").string();
  writeUvSphere(meshPath, 1.0, 224, 224);
  std::vector<double> tl, tv;
  std::size_t faces = 0, cells = 0;
  for (int r = 0; r < repeats; ++r) {
    const double t0 = nowSeconds();
    const StampMesh mesh = StampMesh::load(meshPath);
    const double t1 = nowSeconds();
    cells = voxelizeMesh(mesh, map, 0.2, Mat3::Identity(), Vec3(0.0, 0.5, 0.0)).size();
    tv.push_back(nowSeconds() - t1);
    tl.push_back(t1 - t0);
    faces = mesh.faceCount();
  }
  std::filesystem::remove(meshPath);
  char kase[64];
  std::snprintf(kase, sizeof kase, "stamp_sphere_%zutris", faces);
  std::printf("sketch,%s,%zu,%d,load_ms,%.3f,ms\n", kase, cells, threads, 1e3 * median(tl));
  std::printf("sketch,%s,%zu,%d,voxelize_ms,%.3f,ms\n", kase, cells, threads, 1e3 * median(tv));
  return 0;
}
