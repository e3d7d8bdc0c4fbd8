// physketch run / plan / lint: stroke file -> sketch -> solver passes -> meshes -> PNG frames + report.json.
#include <unistd.h>

#include <algorithm>
#include <cmath>
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
#include "apps/physketch/frames.h"
#include "apps/physketch/prepare.h"
#include "apps/physketch/report.h"
#include "apps/physketch/runtime.h"
#include "apps/physketch/study.h"
#include "apps/physketch/video.h"
#include "core/atomic_file.h"
#include "core/error.h"
#include "core/profile.h"

namespace physketch::app {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Creates `sub` under DIR, removing what an earlier, longer run left there (entries named
// frame_* with the extension `ext`, "" for folders): they would look like part of this one.
void prepareFolder(const fs::path& folder, const std::string& ext) {
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec) throw RuntimeError("cannot create output folder " + folder.string() + ": " + ec.message());
  for (const auto& entry : fs::directory_iterator(folder)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("frame_", 0) != 0) continue;
    if (ext.empty() ? entry.is_directory() : entry.path().extension() == ext) fs::remove_all(entry.path());
  }
}

// Creates DIR and the folders of this run's outputs (DIR/frames and those of --export).
fs::path prepareOutput(const std::string& dir, bool frames, const RunOptions& opt) {
  const fs::path out(dir);
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) throw RuntimeError("cannot create output folder " + out.string() + ": " + ec.message());
  if (frames) {
    prepareFolder(out / "frames", ".png");
    fs::remove(out / "video.mp4", ec);  // made from an earlier run's frames
  }
  if (opt.exportMesh) prepareFolder(out / "meshes", "");
  if (opt.exportParticles) prepareFolder(out / "particles", ".ply");
  if (opt.exportVdb) prepareFolder(out / "vdb", ".vdb");
  return out;
}

// Body names as report.json gives them, for every body the solver has now.
std::vector<std::string> bodyNames(const sketch::Sketch& sk, const Solver& solver) {
  std::vector<std::string> names;
  for (int b = 0; b < solver.bodyCount(); ++b)
    names.push_back(b < int(sk.bodyNames.size()) ? sk.bodyNames[std::size_t(b)] : "after play " + std::to_string(b));
  return names;
}

// How the run's surfaces are meshed (--smooth, --fluid-surface, --mesh-resolution, --solid-surface, --look).
FrameOptions surfaceOptions(const RunOptions& opt) {
  FrameOptions fo;
  fo.smoothIterations = opt.smooth;
  fo.fluidCells = opt.fluidSurface == "cells";
  fo.fluidVoxelFraction = opt.meshResolution;
  fo.solidGrid = opt.solidSurface == "grid";
  fo.splats = opt.look == "splats";
  fo.splatDetail = opt.splatDetail;
  fo.glDevice = render::parseGlDevice(opt.glDevice);
  return fo;
}

// --export: this frame's files.
void writeExports(const RunOptions& opt, const Prepared& p, const Solver& solver, const FrameWriter* frameWriter,
                  const std::vector<Vec3i>& restCells, const fs::path& out, int frame) {
  const std::string stem = frameStem(frame);
  const std::vector<std::string> names = bodyNames(*p.sketch, solver);
  if (opt.exportMesh) {
    const fs::path dir = out / "meshes" / stem;
    fs::create_directories(dir);
    frameWriter->exportMeshes(solver, names, dir.string(), "../materials.mtl");
  }
  if (opt.exportParticles) render::writeParticlesPly((out / "particles" / (stem + ".ply")).string(), particleCloud(p.scene, solver));
  if (opt.exportVdb)
    exportLevelSets(p.scene, p.sketch->mapping, solver, restCells, names, surfaceOptions(opt), (out / "vdb" / (stem + ".vdb")).string());
}

// --video: DIR/video.mp4, or why there is none (said once on stderr; the run goes on).
json videoStep(const RunOptions& opt, const SceneDesc& sc, const fs::path& out, int written) {
  if (!opt.video) return nullptr;
  const char* path = std::getenv("PATH");
  const std::string ffmpeg = findOnPath("ffmpeg", path ? path : "");
  if (ffmpeg.empty()) {
    std::cerr << "physketch: --video: ffmpeg is not on PATH, so no video.mp4 was made (the frames are in "
              << (out / "frames").string() << ")\n";
    return {{"written", false}, {"reason", "ffmpeg is not on PATH"}};
  }
  const VideoResult v = makeVideo(ffmpeg, (out / "frames").string(), sc.fps, written, (out / "video.mp4").string());
  return {{"written", true}, {"file", (out / "video.mp4").string()}, {"codec", v.codec}, {"ffmpeg", ffmpeg}};
}

// Progress on stderr: a rewritten line on a terminal, a plain line every few seconds
// otherwise (a run whose output goes to a file still shows it is alive).
class Progress {
 public:
  explicit Progress(bool on) : on_(on), tty_(isatty(STDERR_FILENO) != 0), start_(nowSeconds()), last_(start_) {}
  void frame(int f, int frames, double t) {
    if (!on_) return;
    const double now = nowSeconds();
    if (tty_) {
      std::fprintf(stderr, "\rframe %d/%d  t = %.3f s  %.1f s elapsed", f + 1, frames, t, now - start_);
    } else if (now - last_ >= 5.0 || f + 1 == frames) {
      std::fprintf(stderr, "frame %d/%d  t = %.3f s  %.1f s elapsed\n", f + 1, frames, t, now - start_);
      last_ = now;
    }
  }
  void done() {
    if (on_ && tty_) std::fprintf(stderr, "\n");
  }

 private:
  bool on_, tty_;
  double start_, last_;
};

// `scale k`: the values the solver runs with, next to the scene's (docs/formats.md).
void printScale(const SceneDesc& sc) {
  std::printf("real-world scale k = %g (PhysGen3D: g' = k g; mass held, density / k^3; stresses / k):\n", sc.scale);
  std::printf("  gravity %g -> %g m/s^2\n", sc.gravityUnscaled.norm(), sc.gravity.norm());
  for (std::size_t i = 0; i < sc.materials.size() && i < sc.materialsUnscaled.size(); ++i) {
    const Material &a = sc.materialsUnscaled[i], &b = sc.materials[i];
    std::printf("  %s: density %g -> %g kg/m^3", a.name.c_str(), a.density, b.density);
    if (a.kind == MaterialKind::kFluid)
      std::printf(", bulk modulus %g -> %g Pa, viscosity %g -> %g Pa s", a.fluid.bulkModulus, b.fluid.bulkModulus,
                  a.fluid.viscosity, b.fluid.viscosity);
    else
      std::printf(", E %g -> %g Pa", a.elastic.youngs, b.elastic.youngs);
    if (a.kind == MaterialKind::kPlasticine) std::printf(", yield stress %g -> %g Pa", a.plasticine.yieldStress, b.plasticine.yieldStress);
    if (a.kind == MaterialKind::kSand && a.sand.cohesion > 0.0) std::printf(", cohesion %g -> %g Pa", a.sand.cohesion, b.sand.cohesion);
    std::printf("\n");
  }
  std::fflush(stdout);
}

}  // namespace

int lintScene(const std::string& scenePath) {
  return withExitCodes([&] {
    const Prepared p = prepare(scenePath, 0, /*forLint=*/true);
    const SceneDesc& sc = p.scene;
    const sketch::Sketch& sk = *p.sketch;
    const std::int64_t live = sketch::liveParticles(sk.particles);
    std::printf("scene   %s\nstrokes %s\n", sc.path.c_str(), sc.strokesPath.c_str());
    std::printf("grid    151^3 cells of %.6g m over a %.6g m workspace\n", sk.mapping.voxelSize(), sc.workspaceSize);
    std::printf("particles %lld of the %d cap (%.1f %%), %zu bodies, play at t = %.6g s\n",
                static_cast<long long>(live), sketch::kMaxParticles, 100.0 * double(live) / sketch::kMaxParticles,
                sk.bodies.size(), p.strokes.playTime());
    if (static_cast<std::size_t>(live) != sk.particles.size())
      std::printf("  and %lld holes of cut cloths (kept in their lattices, not simulated)\n",
                  static_cast<long long>(sk.particles.size()) - static_cast<long long>(live));
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
    std::map<std::string, std::int64_t> perMaterial = particlesPerMaterial(p);
    for (const auto& m : sc.materials)
      std::printf("  %-12s %lld particles\n", m.name.c_str(), static_cast<long long>(perMaterial[m.name]));
    std::printf("kinds:\n");
    for (const auto& [kind, n] : particlesPerKind(p))
      std::printf("  %-12s %lld particles\n", kind.c_str(), static_cast<long long>(n));
    for (const auto& w : sk.warnings) std::printf("warning: %s\n", w.c_str());
    if (!p.notYet.empty())
      std::printf("note: the sketch is fine, but 'physketch run' refuses this scene until its solver simulates it: %s\n",
                  p.notYet.c_str());
    std::printf("%zu warning(s), no errors\n", sk.warnings.size());
    return kExitOk;
  });
}

namespace {

// ms per frame of each pass in a finished run's report.json (physketch plan --after DIR).
// "0 B", "812 B", "56.3 KiB", "6.59 MiB".
std::string bytesText(std::size_t b) {
  char buf[32];
  if (b < 1024) std::snprintf(buf, sizeof buf, "%zu B", b);
  else if (b < 1024 * 1024) std::snprintf(buf, sizeof buf, "%.3g KiB", double(b) / 1024.0);
  else std::snprintf(buf, sizeof buf, "%.3g MiB", double(b) / (1024.0 * 1024.0));
  return buf;
}

// Per pass of a finished run: ms per frame, and the bytes it held at the end (-1: not recorded).
struct Measured {
  double ms = 0.0, heldBytes = -1.0;
};
std::map<std::string, Measured> measuredMs(const std::string& dir) {
  const fs::path path = fs::path(dir) / "report.json";
  std::ifstream in(path);
  if (!in) throw InputError(path.string(), 0, "", "cannot open the report of a run (physketch run SCENE --out DIR writes it)");
  json rep;
  try {
    in >> rep;
  } catch (const json::exception& e) {
    throw InputError(path.string(), 0, "", std::string("not a physketch report: ") + e.what());
  }
  std::map<std::string, Measured> ms;
  if (rep.contains("passes") && rep["passes"].is_array())
    for (const auto& p : rep["passes"])
      if (p.contains("pass") && p.contains("ms_per_frame") && p["ms_per_frame"].is_number()) {
        Measured& m = ms[p["pass"].get<std::string>()];
        m.ms = p["ms_per_frame"].get<double>();
        if (p.contains("held_bytes") && p["held_bytes"].is_number()) m.heldBytes = p["held_bytes"].get<double>();
      }
  return ms;
}

}  // namespace

int printPlan(const PlanOptions& opt) {
  return withExitCodes([&] {
    const Prepared p = prepare(opt.scene);
    const std::unique_ptr<Solver> solver = makeSolver(p);
    const SceneDesc& sc = p.scene;
    const std::map<std::string, Measured> ms = opt.afterDir.empty() ? std::map<std::string, Measured>{} : measuredMs(opt.afterDir);
    std::cout << "scene " << sc.path << ": " << p.sketch->particles.size() << " particles, " << solver->bodyCount()
              << " bodies; solver " << solver->name() << ", dt " << sc.dt << " s, " << (sc.substepsAuto ? std::string("auto") : std::to_string(sc.substeps)) << " substeps"
              << (sc.solver == SolverKind::kPbd ? ", " + std::to_string(sc.iterations) + " iterations" : std::string()) << "\n";
    if (sc.scale != 1.0) printScale(sc);
    std::cout << (opt.all ? "every pass of the step, at play:\n" : "per step, at play:\n");
    for (const auto& pass : opt.all ? solver->planAll() : solver->plan()) {
      std::cout << "  " << (opt.all ? (pass.on ? "on   " : "off  ") : "") << pass.name;
      if (pass.on) {
        std::cout << "  (" << pass.runs << "; " << pass.reason << ")";
        if (opt.all)
          std::cout << "\n        touches " << pass.touches << "; " << pass.does << "; holds " << bytesText(pass.heldBytes)
                    << " at play";
      } else {
        // What an off pass holds is measured, not assumed: nothing, for a pass that never ran.
        std::cout << "  (" << pass.reason << "; "
                  << (pass.heldBytes == 0 ? std::string("nothing allocated") : "holds " + bytesText(pass.heldBytes)) << ")";
      }
      if (const auto it = ms.find(pass.name); it != ms.end()) {
        std::printf("  measured %.3f ms/frame", it->second.ms);
        if (it->second.heldBytes >= 0) std::cout << ", held " << bytesText(std::size_t(it->second.heldBytes)) << " at the end";
      }
      std::cout << "\n";
      std::cout.flush();
    }
    for (const auto& [name, v] : ms)
      if (name.rfind("render.", 0) == 0) std::printf("  %s  measured %.3f ms/frame\n", name.c_str(), v.ms);
    // What a frame adds after its steps follows the scene's outputs (the run's --export and
    // --video options add their own writers; `physketch run --help`).
    std::cout << "per frame: " << sc.stepsPerFrame() << " steps, then "
              << (sc.writeFrames ? "mesh transform, draw, png (an off-screen GL context)"
                                 : "no meshes and no GL context (output has no 'frames')")
              << (sc.writeReport ? "; the report records the bodies' poses" : "") << "\n";
    if (!p.sketch->runtime.empty()) {
      // Strokes after play change the plan while the simulation runs: say which pass
      // they switch on, when and why.
      std::cout << "after play:\n";
      for (const auto& op : p.sketch->runtime) {
        const std::string where = p.strokes.path + ":" + std::to_string(op.line);
        switch (op.kind) {
          case sketch::RuntimeOp::Kind::kCreate:
            std::printf("  t %.4g-%.4g s  kinematic  (%s: a create; its new body is held while drawn, then "
                        "integrate, rigid_contact and update move it)\n", op.start, op.end, where.c_str());
            break;
          case sketch::RuntimeOp::Kind::kMove:
            std::printf("  t %.4g-%.4g s  kinematic  (%s: a move carries the bodies under the brush)\n", op.start,
                        op.end, where.c_str());
            break;
          case sketch::RuntimeOp::Kind::kRemove:
            std::printf("  t %.4g-%.4g s  (no pass)  (%s: a remove; cut bodies are rebuilt, split into pieces if cut "
                        "apart, and re-meshed at the next frame)\n", op.start, op.end, where.c_str());
            break;
          case sketch::RuntimeOp::Kind::kTool:
            std::printf("  t %.4g-%.4g s  kinematic  (%s: a tool pushes material along its path, then leaves)\n",
                        op.start, op.end, where.c_str());
            break;
        }
      }
      std::fflush(stdout);
    }
    return kExitOk;
  });
}

namespace {

// What --budget chose, on stderr before the run.
void printBudget(const BudgetChoice& b, double budgetMs, int threads) {
  if (b.source != "calibration") {
    std::fprintf(stderr, "budget: %s for %.4g ms per frame: %.4g ms per frame and an error of %.3g m expected (the whole "
                         "run, from the study in %s: %s)\n",
                 settingText(b.setting).c_str(), budgetMs, b.predictedMs, b.predictedError, b.source.c_str(), b.norm.c_str());
    if (b.studyThreads != threads)
      std::fprintf(stderr, "warning: the study ran with %d thread(s) per setting, this run with %d: its times do not "
                           "predict this run's (give --threads %d)\n", b.studyThreads, threads, b.studyThreads);
    if (!b.fits)
      std::fprintf(stderr, "warning: --budget %.4g ms: no setting of the study fits; running the fastest stable one\n", budgetMs);
    return;
  }
  std::fprintf(stderr,
               "budget: %s for %.4g ms per frame: %.4g ms per frame and an error of %.3g m expected (RMS of body "
               "centres over frames 1-%d against %s)\n",
               settingText(b.setting).c_str(), budgetMs, b.predictedMs, b.predictedError, b.calibrationFrames,
               settingText(b.reference).c_str());
  if (!b.fits)
    std::fprintf(stderr, "warning: --budget %.4g ms: no calibrated setting fits; running the fastest stable one\n",
                 budgetMs);
}

// A run's tally of surface volume changes, as report.json states it.
json volumeChangeJson(const VolumeChangeStats& st) {
  return {{"surfaces", st.meshes},
          {"max_volume_change_percent", 100.0 * st.maxAbsChange},
          {"mean_volume_change_percent", 100.0 * st.mean()}};
}

json budgetJson(const BudgetChoice& b, double budgetMs, double measuredMs, double measuredError) {
  json tried = json::array();
  for (const BudgetCandidate& c : b.candidates)
    tried.push_back({{"setting", settingText(c.setting)},
                     {"ms_per_frame", c.msPerFrame},
                     {"error_m", std::isfinite(c.error) ? json(c.error) : json(nullptr)},
                     {"status", c.status}});
  json j = {{"budget_ms_per_frame", budgetMs},
          {"source", b.source},
          {"setting", settingText(b.setting)},
          {"fits", b.fits},
          {"calibration_frames", b.calibrationFrames},
          {"reference", settingText(b.reference)},
          {"predicted_ms_per_frame", b.predictedMs},
          {"predicted_error_m", b.predictedError},
          {"measured_ms_per_frame", measuredMs},
          {"measured_over_budget", budgetMs > 0.0 ? measuredMs / budgetMs : 0.0},
          {"candidates", tried}};
  if (b.source != "calibration") {
    // A study's rows are whole runs: the prediction is checked against this run's own error.
    j.erase("calibration_frames");
    j["norm"] = b.norm;
    j["study_threads"] = b.studyThreads;
    j["measured_error_m"] = std::isfinite(measuredError) ? json(measuredError) : json(nullptr);
    j["measured_over_predicted_error"] =
        std::isfinite(measuredError) && b.predictedError > 0.0 ? json(measuredError / b.predictedError) : json(nullptr);
  }
  return j;
}

}  // namespace

int runScene(const RunOptions& opt) {
  const double tStart = nowSeconds();
  // One thread limit for the whole run: voxelizing as well as the solver and the meshing.
  const int threads = opt.threads > 0 ? opt.threads : tbb::info::default_concurrency();
  tbb::global_control threadLimit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  Prepared p;
  std::unique_ptr<Solver> solver;
  std::optional<BudgetChoice> budget;
  if (const int rc = withExitCodes([&] {
        if (opt.budgetMs > 0.0) {
          budget = opt.budgetFrom.empty() ? calibrateBudget(opt.scene, opt.budgetMs, threads, opt.quiet)
                                          : budgetFromStudy(loadScene(opt.scene), opt.budgetFrom, opt.budgetMs);
          p = prepare(opt.scene, threads, false, [&](SceneDesc& sc) { applySetting(budget->setting, sc, "--budget"); });
          printBudget(*budget, opt.budgetMs, threads);
        } else {
          p = prepare(opt.scene, threads);
        }
        solver = makeSolver(p);
        return kExitOk;
      });
      rc != kExitOk)
    return rc;
  const double tPrepared = nowSeconds();

  return withExitCodes([&] {
    const SceneDesc& sc = p.scene;
    const sketch::Sketch& sk = *p.sketch;
    const int frames = opt.frames > 0 ? opt.frames : sc.frameCount();
    solver->setValidate(opt.validate);
    solver->setGuardPolicy(opt.guard == "warn" ? GuardPolicy::kWarn : GuardPolicy::kStop);
    if (opt.solidSurface == "grid" && sc.solver != SolverKind::kMpm) {
      throw InputError(sc.path, sc.solverLine, "solver",
                       "--solid-surface grid meshes the MPM grid's mass, and this scene runs solver pbd, which has no "
                       "grid (use 'solver mpm' or --solid-surface cells)");
    }
    if (opt.video && !sc.writeFrames) {
      throw InputError(sc.path, 0, "output", "--video needs frames, and this scene's 'output' record leaves them out");
    }
    // Rendering set-up before anything is written: an EGL failure leaves no output folder.
    std::unique_ptr<FrameWriter> frameWriter;
    if (sc.writeFrames || opt.exportMesh) {
      FrameOptions fo = surfaceOptions(opt);
      fo.draw = sc.writeFrames;
      fo.keepMeshes = opt.exportMesh;
      frameWriter = std::make_unique<FrameWriter>(sc, sk.mapping, fo);
      frameWriter->setColliders(p.colliderMeshes);
    }
    const fs::path out = prepareOutput(opt.outDir, sc.writeFrames, opt);
    if (opt.exportMesh) render::writeMtl((out / "meshes" / "materials.mtl").string(), exportMaterials(sc));
    RuntimeDriver runtime(sk, *solver);

    json poses = json::array();
    Progress progress(!opt.quiet);
    int written = 0;
    double exportSeconds = 0.0;
    const double tSimStart = nowSeconds();
    double stepSeconds = 0.0;  // the solver's steps only (what --budget fits)
    // --budget --from-study: the run is recorded as the study recorded its rows, to measure its error.
    const bool measureError = budget && budget->source != "calibration";
    Trajectory trajectory;
    std::vector<Vec3> x0;
    if (measureError) {
      const ParticleArrays& ps = solver->particles();
      for (std::size_t i = 0; i < ps.size(); ++i) x0.emplace_back(ps.x[i], ps.y[i], ps.z[i]);
      observeStart(*solver, sk, trajectory);
    }
    // Under a solver's own substep choice (MPM `substeps auto`): the substeps each frame's steps
    // took, and the fewest and most of one step.
    long frameSubsteps = 0, totalSubsteps = 0;
    int fewestSubsteps = 0, mostSubsteps = 0;
    for (int f = 0; f < frames; ++f) {
      frameSubsteps = 0;
      if (f > 0) {
        for (int s = 0; s < sc.stepsPerFrame(); ++s) {
          const std::vector<int> reshaped = runtime.beforeStep();
          if (frameWriter) frameWriter->markReshaped(reshaped);
          const double t0 = nowSeconds();
          const bool ok = solver->step();
          stepSeconds += nowSeconds() - t0;
          if (!ok) break;
          if (const int n = solver->lastSubsteps(); n > 0) {
            frameSubsteps += n;
            fewestSubsteps = fewestSubsteps == 0 ? n : std::min(fewestSubsteps, n);
            mostSubsteps = std::max(mostSubsteps, n);
          }
        }
        if (solver->guard().tripped()) break;
      }
      totalSubsteps += frameSubsteps;
      if (measureError) observe(*solver, x0, sc, trajectory);
      if (frameWriter) {
        if (sc.writeFrames) {
          frameWriter->write(*solver, runtime.restCells(), (out / "frames" / frameName(f)).string());
        } else {
          frameWriter->update(*solver, runtime.restCells());
        }
      }
      const double tExport = nowSeconds();
      writeExports(opt, p, *solver, frameWriter.get(), runtime.restCells(), out, f);
      exportSeconds += nowSeconds() - tExport;
      poses.push_back({{"frame", f}, {"t", solver->time()}, {"bodies", posesJson(*solver)}});
      if (mostSubsteps > 0) poses.back()["substeps"] = frameSubsteps;
      ++written;
      progress.frame(f, frames, solver->time());
    }
    progress.done();
    const json video = solver->guard().tripped() ? json(nullptr) : videoStep(opt, sc, out, written);
    const double tEnd = nowSeconds();

    json rep;
    rep["physketch"] = PHYSKETCH_VERSION;
    rep["scene"] = sc.path;
    rep["strokes_file"] = sc.strokesPath;
    const GuardLog& guardLog = solver->guardLog();
    rep["status"] = solver->guard().tripped() ? "unstable" : guardLog.total() > 0 ? "warned" : "ok";
    rep["guard_policy"] = opt.guard;
    if (solver->guard().tripped()) rep["guard"] = guardJson(solver->guard(), sc.stepsPerFrame());
    if (guardLog.total() > 0) {
      json events = json::array();
      for (const GuardRecord& g : guardLog.first()) {
        json e = guardJson(g, sc.stepsPerFrame());
        e["steps_tripped"] = guardLog.count(g.kind);
        events.push_back(std::move(e));
      }
      rep["guard_warnings"] = std::move(events);
    }
    rep["threads"] = threads;
    rep["grid"] = {{"cells_per_axis", sketch::kGridSize},
                   {"voxel_size_m", sk.mapping.voxelSize()},
                   {"workspace_center", {sc.workspaceCenter.x(), sc.workspaceCenter.y(), sc.workspaceCenter.z()}},
                   {"workspace_size_m", sc.workspaceSize}};
    rep["sketch"] = sketchJson(p);
    rep["runtime"] = runtimeJson(sk, runtime);
    rep["solver"] = {{"name", solver->name()},  {"dt", sc.dt},         {"substeps", sc.substeps},
                     {"substeps_auto", sc.substepsAuto},
                     {"iterations", sc.iterations}, {"steps", solver->stepCount()}, {"simulated_s", solver->time()},
                     {"validate", opt.validate}, {"plan", planJson(solver->plan())}};
    if (mostSubsteps > 0)
      rep["solver"]["substeps_taken"] = {{"total", totalSubsteps}, {"fewest_in_a_step", fewestSubsteps},
                                         {"most_in_a_step", mostSubsteps}};
    rep["passes"] = passesJson(solver->profile(), frameWriter ? &frameWriter->profile() : nullptr, written,
                               solver->planAll());
    rep["frames"] = {{"written", written},
                     {"requested", frames},
                     {"fps", sc.fps},
                     {"width", sc.width},
                     {"height", sc.height},
                     {"triangles", frameWriter ? frameWriter->trianglesLastFrame() : 0},
                     {"triangles_meshed", frameWriter ? frameWriter->trianglesMeshed() : 0},
                     {"folder", sc.writeFrames ? (out / "frames").string() : ""},
                     {"device", frameWriter ? frameWriter->device() : ""},
                     {"gl_device", opt.glDevice}};
    if (opt.smooth > 0) {
      rep["frames"]["smoothing"] = volumeChangeJson(frameWriter ? frameWriter->smoothing() : VolumeChangeStats{});
      rep["frames"]["smoothing"]["iterations"] = opt.smooth;
    }
    if (frameWriter && frameWriter->fluidSurfaces().meshes > 0) {
      rep["frames"]["fluid_surface"] = volumeChangeJson(frameWriter->fluidSurfaces());
      rep["frames"]["fluid_surface"]["method"] = opt.fluidSurface;
    }
    if (frameWriter && frameWriter->solidSurfaces().meshes > 0) {
      rep["frames"]["solid_surface"] = volumeChangeJson(frameWriter->solidSurfaces());
      rep["frames"]["solid_surface"]["method"] = opt.solidSurface;
    }
    if (!video.is_null()) rep["frames"]["video"] = video;
    if (budget) {
      const double measuredMs = written > 1 ? 1e3 * stepSeconds / (written - 1) : 0.0;
      double measuredError = std::numeric_limits<double>::quiet_NaN();
      if (measureError && !solver->guard().tripped()) {
        try {
          measuredError = budgetRunError(*budget, trajectory, sc);
        } catch (const InputError& e) {  // the study measured it, so only a changed scene gets here
          std::fprintf(stderr, "warning: --from-study: the run's error cannot be measured: %s\n", e.what());
        }
        if (!opt.quiet)
          std::fprintf(stderr, "budget: measured %.4g ms per frame (predicted %.4g) and an error of %.3g m (predicted %.3g)\n",
                       measuredMs, budget->predictedMs, measuredError, budget->predictedError);
      }
      rep["budget"] = budgetJson(*budget, opt.budgetMs, measuredMs, measuredError);
    }
    if (opt.exportMesh || opt.exportParticles || opt.exportVdb) {
      json kinds = json::array();
      if (opt.exportMesh) kinds.push_back("mesh");
      if (opt.exportParticles) kinds.push_back("particles");
      if (opt.exportVdb) kinds.push_back("vdb");
      rep["exports"] = {{"kinds", kinds}, {"seconds", exportSeconds}};
    }
    json warnings = json::array();
    if (frameWriter && !frameWriter->framesWithNothingInView().empty()) {
      const auto& empty = frameWriter->framesWithNothingInView();
      warnings.push_back(std::to_string(empty.size()) + " of " + std::to_string(written) +
                         " frames show no body (first: frame " + std::to_string(empty.front()) +
                         "): the camera does not look at the sketch; check the scene's 'camera' record");
    }
    for (const std::string& note : solver->runNotes()) warnings.push_back(note);
    rep["warnings"] = warnings;
    // Body poses per frame, so trajectories can be checked without decoding images.
    json bodies = json::array();
    for (int b = 0; b < solver->bodyCount(); ++b)
      bodies.push_back({{"index", b},
                        {"name", b < int(sk.bodyNames.size()) ? sk.bodyNames[std::size_t(b)] : "after play " + std::to_string(b)},
                        {"particles", solver->bodyParticles(b).size()},
                        {"mode", toString(solver->mode(b))}});
    rep["bodies"] = bodies;
    rep["poses"] = poses;
    rep["timing_s"] = {{"prepare", tPrepared - tStart}, {"simulate_and_render", tEnd - tSimStart},
                       {"total", tEnd - tStart}};
    if (sc.writeReport) writeFileAtomic((out / "report.json").string(), rep.dump(1) + "\n");

    for (const GuardRecord& g : guardLog.first())
      std::cerr << "warning: frame " << guardFrame(g, sc.stepsPerFrame()) << ": " << g.message() << " (--guard warn: "
                << guardLog.count(g.kind) << " step(s) tripped '" << toString(g.kind) << "'; the run went on)\n";
    if (solver->guard().tripped()) {
      std::cerr << "error: frame " << guardFrame(solver->guard(), sc.stepsPerFrame()) << ": " << solver->guard().message()
                << "\n";
      return kExitRuntime;
    }
    for (const auto& w : warnings) std::cerr << "warning: " << w.get<std::string>() << "\n";
    if (!opt.quiet)
      std::cerr << "physketch: " << sk.particles.size() << " particles, " << solver->bodyCount() << " bodies, " << written
                << " frames in " << (tEnd - tStart) << " s -> " << out.string() << "\n";
    return kExitOk;
  });
}

}  // namespace physketch::app
