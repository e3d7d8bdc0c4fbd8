// physketch run / plan: stroke file -> sketch -> PBD passes -> meshes -> PNG frames + report.json.
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <optional>

#include <nlohmann/json.hpp>
#include <tbb/global_control.h>
#include <tbb/info.h>

#include "apps/physketch/app.h"
#include "apps/physketch/runtime.h"
#include "core/error.h"
#include "core/profile.h"
#include "core/scene.h"
#include "pbd/world.h"
#include "render/renderer.h"
#include "render/voxel_mesh.h"
#include "sketch/voxelize.h"

namespace physketch::app {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Everything that comes from input files, fully validated before any output is written.
struct Prepared {
  SceneDesc scene;
  sketch::StrokeFile strokes;
  std::unique_ptr<sketch::Sketch> sketch;
  std::vector<BodyRange> bodies;
};

// `threads`: for voxelizing (0 = every core); the sketch does not depend on it.
Prepared prepare(const std::string& scenePath, int threads = 0) {
  Prepared p;
  p.scene = loadScene(scenePath);
  try {
    p.strokes = sketch::loadStrokes(p.scene.strokesPath);
  } catch (const InputError& e) {
    if (e.line() == 0 && e.reason() == "cannot open file")
      throw InputError(p.scene.path, p.scene.strokesLine, "path", "cannot open stroke file '" + p.scene.strokesPath + "'");
    throw;
  }
  const sketch::GridMapping mapping(p.scene.workspaceCenter, p.scene.workspaceSize);
  p.sketch = std::make_unique<sketch::Sketch>(sketch::voxelize(p.strokes, mapping, p.scene.materials, {threads}));
  p.bodies = p.sketch->bodies;
  return p;
}

pbd::PbdParams pbdParams(const SceneDesc& s, const sketch::GridMapping& m) {
  return pbd::paramsFromScene(s, 0.5 * m.voxelSize());
}

// Writes text to path atomically (temporary file + rename).
void writeFileAtomic(const fs::path& path, const std::string& text) {
  const fs::path tmp = path.string() + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw RuntimeError("cannot write " + tmp.string());
    out << text;
    out.flush();
    if (!out) throw RuntimeError("cannot write " + tmp.string() + " (disk full?)");
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) throw RuntimeError("cannot rename " + tmp.string() + " to " + path.string() + ": " + ec.message());
}

std::string frameName(int i) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "frame_%04d.png", i);
  return buf;
}

// Provenance of the sketch: particles per operation, per material and per body, and lint warnings.
json sketchJson(const Prepared& p) {
  const SceneDesc& sc = p.scene;
  const sketch::Sketch& sk = *p.sketch;
  json ops = json::array();
  for (const auto& o : sk.operations) {
    json j = {{"id", o.id},           {"line", o.line},       {"what", o.what},   {"active", o.active},
              {"created", o.created}, {"removed", o.removed}, {"moved", o.moved}, {"particles", o.remaining},
              {"stamps", o.stamps},   {"after_play", o.afterPlay}};
    j["material"] = o.material >= 0 ? json(sc.materials[static_cast<std::size_t>(o.material)].name) : json(nullptr);
    j["body"] = o.body >= 0 ? json(sk.bodyNames[static_cast<std::size_t>(o.body)]) : json(nullptr);
    ops.push_back(j);
  }
  std::map<std::string, std::int64_t> perMaterial;
  for (const auto& m : sc.materials) perMaterial[m.name] = 0;
  for (auto m : sk.particles.material) ++perMaterial[sc.materials[static_cast<std::size_t>(m)].name];
  json bodies = json::array();
  for (std::size_t b = 0; b < sk.bodies.size(); ++b)
    bodies.push_back({{"name", sk.bodyNames[b]}, {"particles", sk.bodies[b].count}, {"first", sk.bodies[b].first}});
  return {{"particles", sk.particles.size()},
          {"cap", sketch::kMaxParticles},
          {"play_time_s", p.strokes.playTime()},
          {"per_operation", ops},
          {"per_material", perMaterial},
          {"bodies", bodies},
          {"warnings", sk.warnings}};
}

// Bytes the run will hold per particle in the PBD solver and the sketch (SoA float arrays,
// cells, provenance), plus the 151^3 grid: the estimate `lint` prints.
double memoryEstimateMiB(std::size_t particles) {
  const double perParticle = 4.0 * (3 + 3 + 1 + 1)      // ParticleArrays hot: x, v, invMass, body
                             + 4.0 + 2.0                 // stroke, material
                             + 4.0 * (3 + 1 + 3)         // solver: predicted, mass, rest offsets
                             + 12.0;                     // grid cell per particle
  return (perParticle * double(particles) + 4.0 * double(sketch::kGridCells)) / (1024.0 * 1024.0);
}

json planJson(const pbd::PbdWorld& world) {
  json a = json::array();
  for (const auto& p : world.plan()) a.push_back({{"pass", p.name}, {"runs", p.runs}, {"per_step", p.perStep}});
  return a;
}

// Runs a subcommand body and maps its exceptions to the CLI's exit codes:
// InputError -> 1 (bad input, message names file:line:field), anything else -> 2.
template <class F>
int withExitCodes(F&& body) {
  try {
    return body();
  } catch (const InputError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitRuntime;
  }
}

}  // namespace

int lintScene(const std::string& scenePath) {
  return withExitCodes([&] {
    const Prepared p = prepare(scenePath);
    const SceneDesc& sc = p.scene;
    const sketch::Sketch& sk = *p.sketch;
    std::printf("scene   %s\nstrokes %s\n", sc.path.c_str(), sc.strokesPath.c_str());
    std::printf("grid    151^3 cells of %.6g m over a %.6g m workspace\n", sk.mapping.voxelSize(), sc.workspaceSize);
    std::printf("particles %zu of the %d cap (%.1f %%), %zu bodies, play at t = %.6g s\n", sk.particles.size(),
                sketch::kMaxParticles, 100.0 * double(sk.particles.size()) / sketch::kMaxParticles, sk.bodies.size(),
                p.strokes.playTime());
    std::printf("memory estimate %.1f MiB (solver arrays + sketch grid)\n", memoryEstimateMiB(sk.particles.size()));
    std::printf("operations:\n");
    for (const auto& o : sk.operations) {
      const std::string mat = o.material >= 0 ? sc.materials[static_cast<std::size_t>(o.material)].name : "-";
      const std::string body = o.body >= 0 ? sk.bodyNames[static_cast<std::size_t>(o.body)] : "-";
      if (o.afterPlay) {
        std::printf("  line %-5d %-26s %-10s after play: applied while the simulation runs%s\n", o.line,
                    o.what.c_str(), mat.c_str(), o.created ? (" (" + std::to_string(o.created) + " particles)").c_str() : "");
        continue;
      }
      std::printf("  line %-5d %-26s %-10s %s created %-7d removed %-7d moved %-7d remaining %-7d body %s\n", o.line,
                  o.what.c_str(), mat.c_str(), o.active ? "" : "(undone)", o.created, o.removed, o.moved, o.remaining,
                  body.c_str());
    }
    std::printf("materials:\n");
    std::map<std::string, std::int64_t> perMaterial;
    for (auto m : sk.particles.material) ++perMaterial[sc.materials[static_cast<std::size_t>(m)].name];
    for (const auto& m : sc.materials)
      std::printf("  %-12s %lld particles\n", m.name.c_str(), static_cast<long long>(perMaterial[m.name]));
    for (const auto& w : sk.warnings) std::printf("warning: %s\n", w.c_str());
    std::printf("%zu warning(s), no errors\n", sk.warnings.size());
    return kExitOk;
  });
}

int printPlan(const std::string& scenePath) {
  return withExitCodes([&] {
    Prepared p = prepare(scenePath);
    pbd::PbdWorld world(p.sketch->particles, p.bodies, p.scene.materials, pbdParams(p.scene, p.sketch->mapping));
    std::cout << "scene " << p.scene.path << ": " << p.sketch->particles.size() << " particles, " << p.bodies.size()
              << " rigid bodies; solver pbd, dt " << p.scene.dt << " s, " << p.scene.substeps << " substeps, "
              << p.scene.iterations << " iterations\n";
    std::cout << "per step:\n";
    for (const auto& pass : world.plan()) std::cout << "  " << pass.name << "  (" << pass.runs << ")\n";
    std::cout << "per frame: " << p.scene.stepsPerFrame() << " steps, then mesh transform, draw, png\n";
    if (!p.sketch->runtime.empty()) {
      int counts[3] = {0, 0, 0};
      for (const auto& op : p.sketch->runtime) ++counts[static_cast<int>(op.kind)];
      std::cout << "after play: " << counts[0] << " create(s) (a new body each, re-meshed once), " << counts[1]
                << " remove(s) (the cut bodies are rebuilt and re-meshed), " << counts[2]
                << " move(s) (the 'kinematic' pass runs while a body is carried)\n";
    }
    return kExitOk;
  });
}

int runScene(const RunOptions& opt) {
  const double tStart = nowSeconds();
  // One thread limit for the whole run: voxelizing (long strokes are swept in
  // parallel) as well as the solver and the meshing.
  const int threads = opt.threads > 0 ? opt.threads : tbb::info::default_concurrency();
  tbb::global_control threadLimit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  Prepared p;
  if (const int rc = withExitCodes([&] {
        p = prepare(opt.scene, threads);
        return kExitOk;
      });
      rc != kExitOk)
    return rc;
  const double tPrepared = nowSeconds();

  return withExitCodes([&] {
    const SceneDesc& sc = p.scene;
    const sketch::Sketch& sk = *p.sketch;
    const int frames = opt.frames > 0 ? opt.frames : sc.frameCount();
    const bool progress = !opt.quiet && isatty(STDERR_FILENO);

    pbd::PbdWorld world(sk.particles, p.bodies, sc.materials, pbdParams(sc, sk.mapping));

    // Rendering set-up before anything is written: an EGL failure leaves no output folder.
    Profile renderProfile;
    const int passMesh = renderProfile.add("mesh");
    const int passDraw = renderProfile.add("draw");
    const int passPng = renderProfile.add("png");
    std::unique_ptr<render::OffscreenRenderer> renderer;
    std::size_t triangles = 0;
    struct MeshPart {
      int body;
      std::int16_t material;
      int handle;
    };
    std::vector<MeshPart> meshParts;
    RuntimeDriver runtime(sk, world);
    // (Re)builds the meshes of one body from its live particles' rest cells: one mesh
    // per material (mixed-material bodies), all moving with the body's pose. Rigid
    // bodies keep their rest shape, so this runs once per body, and again only when
    // a remove stroke after play cuts the body.
    auto meshBody = [&](int b) {
      ScopedPass t(renderProfile, passMesh);
      meshParts.erase(std::remove_if(meshParts.begin(), meshParts.end(), [&](const MeshPart& m) { return m.body == b; }),
                      meshParts.end());
      const BodyRange& br = world.bodies()[static_cast<std::size_t>(b)];
      std::map<std::int16_t, std::vector<Vec3i>> parts;
      for (std::int32_t i = br.first; i < br.first + br.count; ++i)
        if (world.alive(i))
          parts[world.particles().material[static_cast<std::size_t>(i)]].push_back(
              runtime.restCells()[static_cast<std::size_t>(i)]);
      const Vec3 origin = sk.mapping.toWorld(Vec3i(0, 0, 0));
      for (const auto& [material, cells] : parts) {
        render::TriangleMesh mesh = render::meshVoxels(cells, sk.mapping.voxelSize(), origin);
        triangles += mesh.triangleCount();
        meshParts.push_back({b, material, renderer->uploadMesh(mesh)});
      }
    };
    if (sc.writeFrames) {
      renderer = std::make_unique<render::OffscreenRenderer>(sc.width, sc.height);
      // Rigid bodies keep their rest shape: mesh each body once in its rest pose
      // (particles are voxel centres, so the voxel set is exact) and move the mesh
      // with the body's pose every frame.
      for (std::size_t b = 0; b < p.bodies.size(); ++b) meshBody(static_cast<int>(b));
    }

    const fs::path out(opt.outDir);
    const fs::path framesDir = out / "frames";
    std::error_code ec;
    fs::create_directories(sc.writeFrames ? framesDir : out, ec);
    if (ec) throw RuntimeError("cannot create output folder " + out.string() + ": " + ec.message());
    // Frames of an earlier, longer run in the same folder would look like part of this one.
    if (sc.writeFrames)
      for (const auto& entry : fs::directory_iterator(framesDir)) {
        const std::string name = entry.path().filename().string();
        if (name.rfind("frame_", 0) == 0 && entry.path().extension() == ".png") fs::remove(entry.path());
      }

    const double groundHalf = std::max(sc.workspaceSize, 1e-3);
    auto renderFrame = [&](int f) {
      if (!renderer) return;
      {
        ScopedPass t(renderProfile, passDraw);
        renderer->beginFrame(sc.camera, {0.92f, 0.94f, 0.97f});
        renderer->drawGround(sc.groundY, sc.workspaceCenter.x(), sc.workspaceCenter.z(), groundHalf,
                             {0.55f, 0.57f, 0.55f});
        for (const MeshPart& part : meshParts)
          renderer->drawMesh(part.handle, world.pose(part.body).model(),
                             sc.materials[static_cast<std::size_t>(part.material)].color);
      }
      render::Image img;
      {
        ScopedPass t(renderProfile, passDraw);
        img = renderer->endFrame();
      }
      ScopedPass t(renderProfile, passPng);
      render::writePng((framesDir / frameName(f)).string(), img);
    };

    int written = 0;
    const double tSimStart = nowSeconds();
    for (int f = 0; f < frames; ++f) {
      if (f > 0) {
        for (int s = 0; s < sc.stepsPerFrame(); ++s) {
          const std::vector<int> reshaped = runtime.beforeStep();
          if (renderer)
            for (int b : reshaped) meshBody(b);
          if (!world.step()) break;
        }
        if (world.guard().tripped()) break;
      }
      renderFrame(f);
      ++written;
      if (progress)
        std::fprintf(stderr, "\rframe %d/%d  t = %.3f s  %.1f s elapsed", f + 1, frames, world.time(),
                     nowSeconds() - tSimStart);
    }
    if (progress) std::fprintf(stderr, "\n");
    const double tEnd = nowSeconds();

    // --- report ---------------------------------------------------------------
    json rep;
    rep["physketch"] = PHYSKETCH_VERSION;
    rep["scene"] = sc.path;
    rep["strokes_file"] = sc.strokesPath;
    rep["status"] = world.guard().tripped() ? "unstable" : "ok";
    if (world.guard().tripped()) {
      const auto& g = world.guard();
      rep["guard"] = {{"kind", toString(g.kind)}, {"pass", g.pass},   {"step", g.step}, {"particle", g.particle},
                      {"body", g.body},           {"value", g.value}, {"bound", g.bound}, {"hint", g.hint}};
    }
    rep["threads"] = threads;
    rep["grid"] = {{"cells_per_axis", sketch::kGridSize},
                   {"voxel_size_m", sk.mapping.voxelSize()},
                   {"workspace_center", {sc.workspaceCenter.x(), sc.workspaceCenter.y(), sc.workspaceCenter.z()}},
                   {"workspace_size_m", sc.workspaceSize}};
    rep["sketch"] = sketchJson(p);
    json rt = json::array();
    for (std::size_t k = 0; k < sk.runtime.size(); ++k) {
      const auto& op = sk.runtime[k];
      const auto& st = runtime.stats()[k];
      static const char* kKinds[] = {"create", "remove", "move"};
      rt.push_back({{"op", op.op}, {"line", op.line}, {"kind", kKinds[static_cast<int>(op.kind)]},
                    {"start_s", op.start}, {"end_s", op.end}, {"started", st.started}, {"finished", st.finished},
                    {"body", st.body}, {"grabbed_bodies", st.grabbed}, {"removed_particles", st.removed}});
    }
    rep["runtime"] = rt;
    rep["solver"] = {{"name", "pbd"},          {"dt", sc.dt},     {"substeps", sc.substeps},
                     {"iterations", sc.iterations}, {"steps", world.stepCount()}, {"simulated_s", world.time()},
                     {"plan", planJson(world)}};
    const double perFrame = written > 1 ? 1.0 / (written - 1) : 0.0;
    json passes = json::array();
    for (const auto& e : world.profile().entries())
      if (e.calls > 0)  // passes the scene did not need never ran: leave them out
        passes.push_back({{"pass", e.name}, {"calls", e.calls}, {"total_ms", e.seconds * 1e3},
                        {"ms_per_frame", e.seconds * 1e3 * perFrame}});
    const double renderFrames = written > 0 ? 1.0 / written : 0.0;
    for (const auto& e : renderProfile.entries())
      if (e.calls > 0)
        passes.push_back({{"pass", "render." + e.name}, {"calls", e.calls}, {"total_ms", e.seconds * 1e3},
                          {"ms_per_frame", e.seconds * 1e3 * renderFrames}});
    rep["passes"] = passes;
    rep["frames"] = {{"written", written}, {"requested", frames}, {"fps", sc.fps},
                     {"width", sc.width}, {"height", sc.height}, {"triangles", triangles},
                     {"folder", sc.writeFrames ? framesDir.string() : ""}};
    rep["timing_s"] = {{"prepare", tPrepared - tStart}, {"simulate_and_render", tEnd - tSimStart},
                       {"total", tEnd - tStart}};
    if (sc.writeReport) writeFileAtomic(out / "report.json", rep.dump(2) + "\n");

    if (world.guard().tripped()) {
      std::cerr << "error: " << world.guard().message() << "\n";
      return kExitRuntime;
    }
    if (!opt.quiet)
      std::cerr << "physketch: " << sk.particles.size() << " particles, " << p.bodies.size() << " bodies, " << written
                << " frames in " << (tEnd - tStart) << " s -> " << out.string() << "\n";
    return kExitOk;
  });
}

}  // namespace physketch::app
