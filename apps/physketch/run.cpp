// physketch run / plan: stroke file -> sketch -> PBD passes -> meshes -> PNG frames + report.json.
#include <unistd.h>

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

Prepared prepare(const std::string& scenePath) {
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
  p.sketch = std::make_unique<sketch::Sketch>(sketch::voxelize(p.strokes, mapping, p.scene.materials));
  // v1: each stroke that created particles is one rigid body.
  for (const auto& s : p.sketch->strokes) {
    if (s.count == 0) continue;
    p.bodies.push_back(BodyRange{s.first, s.count, s.material, s.id});
  }
  return p;
}

pbd::PbdParams pbdParams(const SceneDesc& s, const sketch::GridMapping& m) {
  pbd::PbdParams p;
  p.dt = s.dt;
  p.substeps = s.substeps;
  p.iterations = s.iterations;
  p.gravity = s.gravity;
  p.groundY = s.groundY;
  p.particleRadius = 0.5 * m.voxelSize();
  return p;
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

json planJson(const pbd::PbdWorld& world) {
  json a = json::array();
  for (const auto& p : world.plan()) a.push_back({{"pass", p.name}, {"runs", p.runs}, {"per_step", p.perStep}});
  return a;
}

}  // namespace

int printPlan(const std::string& scenePath) {
  try {
    Prepared p = prepare(scenePath);
    pbd::PbdWorld world(p.sketch->particles, p.bodies, p.scene.materials, pbdParams(p.scene, p.sketch->mapping));
    std::cout << "scene " << p.scene.path << ": " << p.sketch->particles.size() << " particles, " << p.bodies.size()
              << " rigid bodies; solver pbd, dt " << p.scene.dt << " s, " << p.scene.substeps << " substeps, "
              << p.scene.iterations << " iterations\n";
    std::cout << "per step:\n";
    for (const auto& pass : world.plan()) std::cout << "  " << pass.name << "  (" << pass.runs << ")\n";
    std::cout << "per frame: " << p.scene.stepsPerFrame() << " steps, then mesh transform, draw, png\n";
    return kExitOk;
  } catch (const InputError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitRuntime;
  }
}

int runScene(const RunOptions& opt) {
  const double tStart = nowSeconds();
  Prepared p;
  try {
    p = prepare(opt.scene);
  } catch (const InputError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitRuntime;
  }
  const double tPrepared = nowSeconds();

  try {
    const int threads = opt.threads > 0 ? opt.threads : tbb::info::default_concurrency();
    tbb::global_control threadLimit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
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
    std::vector<int> meshHandles;
    std::size_t triangles = 0;
    if (sc.writeFrames) {
      renderer = std::make_unique<render::OffscreenRenderer>(sc.width, sc.height);
      ScopedPass t(renderProfile, passMesh);
      // Rigid bodies keep their rest shape: mesh each body once in its rest pose
      // (particles are voxel centres, so the voxel set is exact) and move the mesh
      // with the body's pose every frame.
      const Vec3 origin = sk.mapping.toWorld(Vec3i(0, 0, 0));
      for (const auto& b : p.bodies) {
        std::vector<Vec3i> cells(sk.cells.begin() + b.first, sk.cells.begin() + b.first + b.count);
        render::TriangleMesh mesh = render::meshVoxels(cells, sk.mapping.voxelSize(), origin);
        triangles += mesh.triangleCount();
        meshHandles.push_back(renderer->uploadMesh(mesh));
      }
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
        for (std::size_t b = 0; b < p.bodies.size(); ++b) {
          const auto& m = sc.materials[static_cast<std::size_t>(p.bodies[b].material)];
          renderer->drawMesh(meshHandles[b], world.pose(static_cast<int>(b)).model(), m.color);
        }
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
        for (int s = 0; s < sc.stepsPerFrame(); ++s)
          if (!world.step()) break;
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
    json perStroke = json::array();
    std::map<std::string, std::int64_t> perMaterial;
    for (const auto& m : sc.materials) perMaterial[m.name] = 0;
    for (const auto& s : sk.strokes) {
      const std::string& mat = sc.materials[static_cast<std::size_t>(s.material)].name;
      perStroke.push_back({{"stroke", s.id}, {"line", s.line}, {"material", mat}, {"particles", s.count},
                           {"stamps", s.stamps}});
      perMaterial[mat] += s.count;
    }
    rep["particles"] = {{"total", sk.particles.size()}, {"per_stroke", perStroke}, {"per_material", perMaterial}};
    rep["bodies"] = p.bodies.size();
    rep["solver"] = {{"name", "pbd"},          {"dt", sc.dt},     {"substeps", sc.substeps},
                     {"iterations", sc.iterations}, {"steps", world.stepCount()}, {"simulated_s", world.time()},
                     {"plan", planJson(world)}};
    const double perFrame = written > 1 ? 1.0 / (written - 1) : 0.0;
    json passes = json::array();
    for (const auto& e : world.profile().entries())
      passes.push_back({{"pass", e.name}, {"calls", e.calls}, {"total_ms", e.seconds * 1e3},
                        {"ms_per_frame", e.seconds * 1e3 * perFrame}});
    const double renderFrames = written > 0 ? 1.0 / written : 0.0;
    for (const auto& e : renderProfile.entries())
      passes.push_back({{"pass", "render." + e.name}, {"calls", e.calls}, {"total_ms", e.seconds * 1e3},
                        {"ms_per_frame", e.name == "mesh" ? 0.0 : e.seconds * 1e3 * renderFrames}});
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
  } catch (const InputError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitRuntime;
  }
}

}  // namespace physketch::app
