// The walking skeleton's own figures: voxelize, PBD step, mesh, render, PNG per frame.
// Prints CSV rows `bench,case,particles,threads,metric,value,unit`; medians of repeated runs.
//
//   bench_pipeline [--threads N] [--repeats R] [--scene PATH]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include <tbb/global_control.h>
#include <tbb/info.h>

#include "bench/bench_common.h"
#include "core/profile.h"
#include "core/scene.h"
#include "pbd/world.h"
#include "render/renderer.h"
#include "render/voxel_mesh.h"
#include "sketch/voxelize.h"

using namespace physketch;
using physketch::bench::median;
using physketch::bench::row;

namespace {

}  // namespace

int main(int argc, char** argv) {
  int threads = tbb::info::default_concurrency();
  int repeats = 5;
  std::string scenePath = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.scene";
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) threads = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--repeats") && i + 1 < argc) repeats = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--scene") && i + 1 < argc) scenePath = argv[++i];
    else {
      std::fprintf(stderr, "usage: bench_pipeline [--threads N] [--repeats R] [--scene PATH]\n");
      return 1;
    }
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  const SceneDesc sc = loadScene(scenePath);
  // The rows' case names start with the scene's name (hello for the default scene).
  const std::string name = std::filesystem::path(scenePath).stem().string();
  const auto strokes = sketch::loadStrokes(sc.strokesPath);
  const sketch::GridMapping mapping(sc.workspaceCenter, sc.workspaceSize);

  // Voxelize (includes allocating and clearing the 13.8 MB grid).
  std::vector<double> tv;
  std::unique_ptr<sketch::Sketch> sk;
  for (int r = 0; r < repeats; ++r) {
    const double t0 = nowSeconds();
    sk = std::make_unique<sketch::Sketch>(sketch::voxelize(strokes, mapping, sc.materials, {threads}));
    tv.push_back(nowSeconds() - t0);
  }
  const std::size_t n = sk->particles.size();
  row("pipeline", name.c_str(), n, threads, "voxelize_ms", 1e3 * median(tv), "ms");

  const std::vector<BodyRange>& bodies = sk->bodies;
  const pbd::PbdParams pp = pbd::paramsFromScene(sc, 0.5 * mapping.voxelSize());
  pbd::PbdWorld world(sk->particles, bodies, sc.materials, pp);
  std::vector<double> ts;
  const int steps = static_cast<int>(sc.duration / sc.dt);
  for (int s = 0; s < steps; ++s) {
    const double t0 = nowSeconds();
    world.step();
    ts.push_back(nowSeconds() - t0);
  }
  const std::string kaseName = name + "_s" + std::to_string(sc.substeps) + "_i" + std::to_string(sc.iterations);
  const char* const kase = kaseName.c_str();
  row("pbd", kase, n, threads, "ms_per_step", 1e3 * median(ts), "ms");
  for (const auto& e : world.profile().entries())
    if (e.calls > 0) {
      std::string m = e.name + "_ms_per_step";
      row("pbd", kase, n, threads, m.c_str(), 1e3 * e.seconds / steps, "ms");
    }

  // Mesh every body once (rest pose), then render and encode frames.
  std::vector<double> tm;
  std::vector<render::TriangleMesh> meshes;
  for (int r = 0; r < repeats; ++r) {
    meshes.clear();
    const double t0 = nowSeconds();
    for (const auto& b : bodies) {
      std::vector<Vec3i> cells(sk->cells.begin() + b.first, sk->cells.begin() + b.first + b.count);
      meshes.push_back(render::meshVoxels(cells, mapping.voxelSize(), mapping.toWorld(Vec3i(0, 0, 0))));
    }
    tm.push_back(nowSeconds() - t0);
  }
  std::size_t tris = 0;
  for (const auto& m : meshes) tris += m.triangleCount();
  row("render", (name + "_mesh").c_str(), n, threads, "mesh_all_bodies_ms", 1e3 * median(tm), "ms");
  row("render", (name + "_mesh").c_str(), n, threads, "triangles", double(tris), "count");

  render::OffscreenRenderer renderer(sc.width, sc.height);
  std::vector<int> handles;
  for (const auto& m : meshes) handles.push_back(renderer.uploadMesh(m));
  const auto tmp = std::filesystem::temp_directory_path() / "physketch_bench_frame.png";
  std::vector<double> td, tp;
  for (int r = 0; r < std::max(repeats, 5); ++r) {
    const double t0 = nowSeconds();
    renderer.beginFrame(sc.camera, {0.92f, 0.94f, 0.97f});
    renderer.drawGround(sc.groundY, sc.workspaceCenter.x(), sc.workspaceCenter.z(), sc.workspaceSize, {0.5f, 0.5f, 0.5f});
    for (std::size_t b = 0; b < bodies.size(); ++b)
      renderer.drawMesh(handles[b], world.pose(static_cast<int>(b)).model(),
                        sc.materials[static_cast<std::size_t>(sk->particles.material[std::size_t(bodies[b].first)])].color);
    const render::Image img = renderer.endFrame();
    const double t1 = nowSeconds();
    render::writePng(tmp.string(), img);
    tp.push_back(nowSeconds() - t1);
    td.push_back(t1 - t0);
  }
  std::filesystem::remove(tmp);
  const std::string resName = name + "_" + std::to_string(sc.width) + "x" + std::to_string(sc.height);
  const char* const res = resName.c_str();
  row("render", res, n, threads, "draw_readback_ms_per_frame", 1e3 * median(td), "ms");
  row("render", res, n, threads, "png_ms_per_frame", 1e3 * median(tp), "ms");
  return 0;
}
