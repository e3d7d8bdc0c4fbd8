// The frame dump of issue 10: 80,000 particles in four deforming bodies at 1280 x 720, every
// stage counted (particles -> cells, level sets, smoothing, meshing, upload, draw, read-back,
// PNG), and the fluid surface of an 80,000-particle pool (anisotropic kernels against cells).
// Prints CSV rows `bench,case,particles,threads,metric,value,unit`; medians of repeated frames.
//
//   bench_render [--threads N] [--repeats R] [--smooth S] [--samples MSAA] [--no-shadows] [--gl-device cpu|gpu]
// (defaults: what `physketch run` draws, with 2 smoothing iterations)
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>

#include "bench/bench_common.h"
#include "core/error.h"
#include "core/profile.h"
#include "core/scene.h"
#include "render/fluid_surface.h"
#include "render/renderer.h"
#include "render/voxel_mesh.h"

using namespace physketch;
using physketch::bench::median;
using physketch::bench::row;

namespace {

constexpr double kH = 1.0 / 151.0;  // the sketch grid's spacing in a 1 m workspace

// A ball of `count` lattice particles (the nearest `count` lattice points to its centre), then
// deformed as a soft body would be mid-motion: twisted about y by up to 0.6 rad over its height,
// squashed 15 % in y and bulged sideways, with phase `t` so every frame's positions differ.
std::vector<Vec3> deformedBall(const Vec3& centre, std::size_t count, double t) {
  const int n = static_cast<int>(std::ceil(std::cbrt(3.0 * double(count) / (4.0 * 3.14159265)) + 2));
  std::vector<Vec3i> lattice;
  for (int k = -n; k <= n; ++k)
    for (int j = -n; j <= n; ++j)
      for (int i = -n; i <= n; ++i) lattice.emplace_back(i, j, k);
  std::stable_sort(lattice.begin(), lattice.end(),
                   [](const Vec3i& a, const Vec3i& b) { return a.squaredNorm() < b.squaredNorm(); });
  lattice.resize(count);
  const double r = n * kH;
  std::vector<Vec3> p;
  p.reserve(count);
  for (const Vec3i& c : lattice) {
    Vec3 q = kH * c.cast<double>();
    const double angle = 0.6 * std::sin(t) * q.y() / r;
    const double ca = std::cos(angle), sa = std::sin(angle);
    q = Vec3(ca * q.x() - sa * q.z(), q.y(), sa * q.x() + ca * q.z());
    const double bulge = 1.0 + 0.1 * (1.0 - (q.y() / r) * (q.y() / r));
    p.push_back(centre + Vec3(bulge * q.x(), 0.85 * q.y(), bulge * q.z()));
  }
  return p;
}

// The frame's tail, the same for meshes and splats: sky, ground, the bodies (`drawBodies`),
// draw, read-back and PNG, each stage's seconds appended to its series.
struct FrameTail {
  std::vector<double> draw, readBack, png;
  template <class DrawBodies>
  void run(render::OffscreenRenderer& renderer, const Camera& camera, const std::string& path, DrawBodies&& drawBodies) {
    const Eigen::AlignedBox3d box(Vec3(-0.6, 0.0, -0.6), Vec3(0.6, 0.4, 0.6));
    renderer.beginFrame(camera, render::Background{{0.62f, 0.72f, 0.86f}, {0.94f, 0.95f, 0.97f}},
                        render::clipRangeFor(camera, box));
    renderer.drawGround(0.0, 0.0, 0.0, 0.8, {0.55f, 0.57f, 0.55f});
    drawBodies();
    const render::Image image = renderer.endFrame();
    const double p0 = nowSeconds();
    render::writePng(path, image);
    draw.push_back(image.drawSeconds);
    readBack.push_back(image.readSeconds);
    png.push_back(nowSeconds() - p0);
  }
  void rows(const char* kase, std::size_t particles, int threads) const {
    row("render", kase, particles, threads, "draw_ms", 1e3 * median(draw), "ms");
    row("render", kase, particles, threads, "read_back_ms", 1e3 * median(readBack), "ms");
    row("render", kase, particles, threads, "png_ms", 1e3 * median(png), "ms");
  }
};

}  // namespace

int main(int argc, char** argv) {
  int threads = tbb::info::default_concurrency();
  int repeats = 7;
  int smooth = 2;
  render::Looks looks;
  render::GlDevice device = render::GlDevice::Cpu;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) threads = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--repeats") && i + 1 < argc) repeats = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--smooth") && i + 1 < argc) smooth = std::max(0, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--samples") && i + 1 < argc) looks.samples = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--no-shadows")) looks.shadows = false;
    else if (!std::strcmp(argv[i], "--gl-device") && i + 1 < argc && (!std::strcmp(argv[i + 1], "cpu") || !std::strcmp(argv[i + 1], "gpu")))
      device = render::parseGlDevice(argv[++i]);
    else {
      std::fprintf(stderr, "usage: bench_render [--threads N] [--repeats R] [--smooth S] [--samples MSAA] [--no-shadows] [--gl-device cpu|gpu]\n");
      return 1;
    }
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));

  // ---- Frame dump: four deforming bodies of 20,000 particles, 1280 x 720.
  const std::vector<Vec3> centres{{-0.25, 0.15, -0.2}, {0.2, 0.15, -0.25}, {-0.2, 0.15, 0.25}, {0.25, 0.15, 0.2}};
  const std::size_t perBody = 20000, particles = perBody * centres.size();
  Camera camera;
  camera.eye = Vec3(1.2, 0.9, 1.5);
  camera.target = Vec3(0.0, 0.1, 0.0);
  std::unique_ptr<render::OffscreenRenderer> made;
  try {
    made = std::make_unique<render::OffscreenRenderer>(1280, 720, looks, device);
  } catch (const RuntimeError& e) {
    std::fprintf(stderr, "bench_render: %s\n", e.what());
    return 1;
  }
  render::OffscreenRenderer& renderer = *made;
  std::fprintf(stderr, "bench_render: drawing with %s\n", renderer.deviceDescription().c_str());
  std::vector<int> handles;
  for (std::size_t b = 0; b < centres.size(); ++b) handles.push_back(renderer.uploadMesh(render::TriangleMesh{}));
  const auto png = std::filesystem::temp_directory_path() / "physketch_bench_render.png";
  std::vector<double> meshWall, cells, levelSet, smoothing, meshing, upload, total;
  FrameTail meshTail;
  std::size_t triangles = 0;
  for (int rep = 0; rep < repeats; ++rep) {
    render::MeshStageTimes sum;
    double up = 0.0;
    // The particles are the simulation's output, made before the frame dump starts (making them,
    // trigonometry per particle, took 12 ms on 1 thread inside the timed loop until 2026-11-29).
    std::vector<std::vector<Vec3>> bodies(centres.size());
    tbb::parallel_for(std::size_t{0}, centres.size(),
                      [&](std::size_t b) { bodies[b] = deformedBall(centres[b], perBody, 0.3 * rep + double(b)); });
    const double start = nowSeconds();
    triangles = 0;
    // Bodies are meshed side by side (as FrameWriter does), then uploaded in order.
    std::vector<render::TriangleMesh> meshes(centres.size());
    std::vector<render::MeshStageTimes> times(centres.size());
    tbb::parallel_for(std::size_t{0}, centres.size(), [&](std::size_t b) {
      const std::vector<Vec3>& pos = bodies[b];
      render::ParticleMeshOptions options;
      options.smoothIterations = smooth;
      options.targetVolume = double(pos.size()) * kH * kH * kH;  // as FrameWriter holds a body's surface
      meshes[b] = render::meshParticles(pos, kH, options, nullptr, &times[b]);
    });
    // Stage times are summed over bodies: with bodies in parallel they add up to more than the
    // wall time they took (mesh_wall_ms).
    const double meshed = nowSeconds();
    for (std::size_t b = 0; b < centres.size(); ++b) {
      sum.cells += times[b].cells;
      sum.levelSet += times[b].levelSet;
      sum.smoothing += times[b].smoothing;
      sum.meshing += times[b].meshing;
      renderer.updateMesh(handles[b], meshes[b]);
      triangles += meshes[b].triangleCount();
    }
    up = nowSeconds() - meshed;
    meshWall.push_back(meshed - start);
    meshTail.run(renderer, camera, png.string(), [&] {
      for (int h : handles) renderer.drawMesh(h, Mat4f::Identity(), {0.9f, 0.3f, 0.35f});
    });
    cells.push_back(sum.cells);
    levelSet.push_back(sum.levelSet);
    smoothing.push_back(sum.smoothing);
    meshing.push_back(sum.meshing);
    upload.push_back(up);
    total.push_back(nowSeconds() - start);
  }
  row("render", "frame_dump", particles, threads, "ms", 1e3 * median(total), "ms");
  row("render", "frame_dump", particles, threads, "mesh_wall_ms", 1e3 * median(meshWall), "ms");
  row("render", "frame_dump", particles, threads, "cells_ms", 1e3 * median(cells), "ms");
  row("render", "frame_dump", particles, threads, "level_set_ms", 1e3 * median(levelSet), "ms");
  row("render", "frame_dump", particles, threads, "smoothing_ms", 1e3 * median(smoothing), "ms");
  row("render", "frame_dump", particles, threads, "meshing_ms", 1e3 * median(meshing), "ms");
  row("render", "frame_dump", particles, threads, "upload_ms", 1e3 * median(upload), "ms");
  meshTail.rows("frame_dump", particles, threads);
  row("render", "frame_dump", particles, threads, "triangles", double(triangles), "count");
  row("render", "frame_dump", particles, threads, "smooth_iterations", double(smooth), "count");

  // ---- The same bodies as Gaussian splats (--look splats): one per particle, sigma0 = h/2,
  // stretched as the twist and squash stretch the body (F from the deformation above, applied
  // here as the bulge's 1.1 x 0.85 x 1.1), no meshing at all.
  std::vector<double> splatBuild, splatTotal;
  FrameTail splatTail;
  std::size_t drawn = 0;
  for (int rep = 0; rep < repeats; ++rep) {
    const double start = nowSeconds();
    std::vector<render::Splat> splats;
    splats.reserve(particles);
    Eigen::Matrix3f F = Eigen::Matrix3f::Identity();
    F(0, 0) = F(2, 2) = 1.1f;
    F(1, 1) = 0.85f;
    const float s0 = float(0.5 * kH);
    for (std::size_t b = 0; b < centres.size(); ++b) {
      const std::vector<Vec3> pos = deformedBall(centres[b], perBody, 0.3 * rep + double(b));
      const std::vector<std::uint8_t> hidden = render::enclosedParticles(pos, kH, Vec3::Zero());  // as --look splats
      for (std::size_t j = 0; j < pos.size(); ++j) {
        if (hidden[j]) continue;
        const Vec3& q = pos[j];
        render::Splat s;
        s.centre = q.cast<float>();
        s.covariance = s0 * s0 * F * F.transpose();
        s.color = {0.9f, 0.3f, 0.35f};
        s.opacity = 0.9f;
        splats.push_back(s);
      }
    }
    drawn = splats.size();
    const double built = nowSeconds();
    splatTail.run(renderer, camera, png.string(), [&] { renderer.drawSplats(splats); });
    splatBuild.push_back(built - start);
    splatTotal.push_back(nowSeconds() - start);
  }
  row("render", "splats", particles, threads, "ms", 1e3 * median(splatTotal), "ms");
  row("render", "splats", particles, threads, "build_ms", 1e3 * median(splatBuild), "ms");
  splatTail.rows("splats", particles, threads);
  row("render", "splats", particles, threads, "splats_drawn", double(drawn), "count");

  if (!std::getenv("KEEP_PNG")) std::filesystem::remove(png);

  // ---- Fluid surface of an 80,000-particle pool (80 x 10 x 100, jittered as at rest).
  std::mt19937 rng(5);
  auto u = [&rng] { return static_cast<double>(rng()) / 4294967295.0 - 0.5; };
  std::vector<Vec3> pool;
  for (int k = 0; k < 100; ++k)
    for (int j = 0; j < 10; ++j)
      for (int i = 0; i < 80; ++i) pool.push_back(kH * (Vec3(i, j, k) + 0.4 * Vec3(u(), u(), u())));
  std::vector<double> kernels, kernelsOnly, cellsMesh;
  std::size_t kernelTriangles = 0, cellTriangles = 0;
  for (int rep = 0; rep < std::max(3, repeats / 2); ++rep) {
    const double tk = nowSeconds();
    const render::FluidKernels fk = render::fluidKernels(pool, kH);  // the kernels alone: the first stage of meshFluid
    kernelsOnly.push_back(nowSeconds() - tk);
    if (fk.centre.size() != pool.size()) std::fprintf(stderr, "bench_render: fluidKernels lost particles\n");
    const double t0 = nowSeconds();
    kernelTriangles = render::meshFluid(pool, kH).triangleCount();
    const double t1 = nowSeconds();
    cellTriangles = render::meshParticles(pool, kH).triangleCount();
    const double t2 = nowSeconds();
    kernels.push_back(t1 - t0);
    cellsMesh.push_back(t2 - t1);
  }
  row("render", "fluid_surface_kernels", pool.size(), threads, "ms", 1e3 * median(kernels), "ms");
  row("render", "fluid_surface_kernels", pool.size(), threads, "ms_kernels", 1e3 * median(kernelsOnly), "ms");
  row("render", "fluid_surface_kernels", pool.size(), threads, "triangles", double(kernelTriangles), "count");
  row("render", "fluid_surface_cells", pool.size(), threads, "ms", 1e3 * median(cellsMesh), "ms");
  row("render", "fluid_surface_cells", pool.size(), threads, "triangles", double(cellTriangles), "count");

  // ---- The meshing knobs' error against time (issue 11; docs/accuracy.md, "Meshing knobs"): a
  // ball of radius 12 spacings on a lattice turned off its axes (as a deforming body's particles
  // are), meshed with each setting. Error: RMS over the mesh's vertices of their distance from
  // the sphere around the particles' centroid that fits them best (radius = their mean distance):
  // the shape's roughness (m); radius_bias: that radius minus the radius of the particles'
  // volume, N h^3 (m).
  const Eigen::Matrix3d turn = (Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized())).toRotationMatrix();
  std::vector<Vec3> ball;
  for (int k = -13; k <= 13; ++k)
    for (int j = -13; j <= 13; ++j)
      for (int i = -13; i <= 13; ++i)
        if (Vec3(i, j, k).norm() <= 12.0) ball.push_back(Vec3(0.1, 0.2, 0.3) + turn * (kH * Vec3(i, j, k)));
  Vec3 centroid = Vec3::Zero();
  for (const Vec3& q : ball) centroid += q;
  centroid /= double(ball.size());
  const double radius = std::cbrt(3.0 * double(ball.size()) / (4.0 * 3.14159265358979)) * kH;
  auto sphereError = [&](const render::TriangleMesh& m, double& bias) {
    double mean = 0.0, sum = 0.0;
    for (const Vec3f& v : m.positions) mean += (v.cast<double>() - centroid).norm();
    mean /= double(std::max<std::size_t>(1, m.positions.size()));
    for (const Vec3f& v : m.positions) {
      const double d = (v.cast<double>() - centroid).norm() - mean;
      sum += d * d;
    }
    bias = mean - radius;
    return m.positions.empty() ? 0.0 : std::sqrt(sum / double(m.positions.size()));
  };
  const int knobRepeats = std::max(3, repeats);
  auto knobRows = [&](const std::string& kase, auto&& mesh) {
    std::vector<double> ms;
    double error = 0.0, bias = 0.0;
    for (int rep = 0; rep < knobRepeats; ++rep) {
      const double t0 = nowSeconds();
      const render::TriangleMesh m = mesh();
      ms.push_back(1e3 * (nowSeconds() - t0));
      error = sphereError(m, bias);
    }
    row("render", kase.c_str(), ball.size(), threads, "ms", median(ms), "ms");
    row("render", kase.c_str(), ball.size(), threads, "rms_sphere_error", error, "m");
    row("render", kase.c_str(), ball.size(), threads, "radius_bias", bias, "m");
  };
  for (int s : {0, 1, 2, 4, 8}) {
    knobRows("mesh_smoothing_" + std::to_string(s), [&] {
      render::ParticleMeshOptions o;
      o.smoothIterations = s;
      o.targetVolume = double(ball.size()) * kH * kH * kH;
      return render::meshParticles(ball, kH, o);
    });
  }
  for (double f : {1.0, 0.5, 0.33, 0.25}) {
    char kase[64];
    std::snprintf(kase, sizeof kase, "fluid_mesh_resolution_%.2f", f);
    knobRows(kase, [&] {
      render::FluidSurfaceOptions o;
      o.voxelFraction = f;
      return render::meshFluid(ball, kH, o);
    });
  }
  return 0;
}
