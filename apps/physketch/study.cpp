// physketch study: runs a scene once per setting, measures error and wall time per frame,
// and writes study.csv, study.md and study.png (docs/accuracy.md says what each number is).
//
// Every setting's run becomes one "part" (a JSON object, written as OUT/part.json by
// --only): the direct run, --jobs and --emit-commands + --collect all assemble the outputs
// from the same parts, so they give the same numbers.
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <mutex>
#include <sstream>
#include <thread>

#include <nlohmann/json.hpp>
#include <tbb/info.h>
#include <tbb/task_arena.h>

#include "apps/physketch/app.h"
#include "apps/physketch/frames.h"
#include "apps/physketch/prepare.h"
#include "apps/physketch/runtime.h"
#include "apps/physketch/study.h"
#include "core/atomic_file.h"
#include "core/error.h"
#include "core/profile.h"

namespace physketch::app {

// printf-formats one number (study.h).
std::string fmt(const char* f, double v) {
  if (std::isnan(v)) return "nan";
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

// The state a study needs from the run at one frame: centres of every body, and the
// largest particle displacement from t = 0 and speed (for expect rest).
void observe(const Solver& solver, const std::vector<Vec3>& x0, const SceneDesc& scene, Trajectory& tr) {
  std::vector<Vec3> centres;
  for (int b = 0; b < solver.bodyCount(); ++b) centres.push_back(solver.pose(b).centre);
  tr.centres.push_back(std::move(centres));
  tr.t.push_back(solver.time());
  const ParticleArrays& p = solver.particles();
  double front = -std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (!solver.alive(static_cast<std::int32_t>(i))) continue;
    const Vec3 x(p.x[i], p.y[i], p.z[i]);
    if (i < x0.size()) tr.maxDisplacement = std::max(tr.maxDisplacement, (x - x0[i]).norm());
    tr.maxSpeed = std::max(tr.maxSpeed, Vec3(p.vx[i], p.vy[i], p.vz[i]).norm());
    if (phase::dynamic(p.phase[i])) front = std::max(front, x.x());
  }
  tr.front.push_back(front);
  const bool hydrostatic = std::any_of(scene.expectations.begin(), scene.expectations.end(),
                                       [](const Expectation& e) { return e.kind == Expectation::Kind::kHydrostatic; });
  if (hydrostatic) tr.hydrostatic.push_back(hydrostaticError(solver, scene, tr.spacing));
}

// What the norms need at t = 0: velocity, bounding-sphere reach, mode and name per body.
void observeStart(const Solver& solver, const sketch::Sketch& sk, Trajectory& tr) {
  const ParticleArrays& p = solver.particles();
  tr.spacing = sk.mapping.voxelSize();
  // The extent of the dynamic particles at t = 0 (a dam-break or granular column's box).
  const double inf = std::numeric_limits<double>::infinity();
  tr.lo0 = Vec3::Constant(inf);
  tr.hi0 = Vec3::Constant(-inf);
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (!solver.alive(static_cast<std::int32_t>(i)) || !phase::dynamic(p.phase[i])) continue;
    const Vec3 x(p.x[i], p.y[i], p.z[i]);
    tr.lo0 = tr.lo0.cwiseMin(x);
    tr.hi0 = tr.hi0.cwiseMax(x);
    ++tr.dynamic0Count;
  }
  for (int b = 0; b < solver.bodyCount(); ++b) {
    const Vec3 c = solver.pose(b).centre;
    double reach = 0.0;
    for (std::int32_t i : solver.bodyParticles(b)) {
      const auto k = static_cast<std::size_t>(i);
      reach = std::max(reach, (Vec3(p.x[k], p.y[k], p.z[k]) - c).norm());
    }
    tr.reach.push_back(reach + 0.5 * tr.spacing);
    tr.velocity0.push_back(solver.velocity(b));
    tr.dynamic0.push_back(solver.mode(b) == BodyMode::kDynamic);
    tr.names.push_back(b < int(sk.bodyNames.size()) ? sk.bodyNames[std::size_t(b)] : "after play " + std::to_string(b));
  }
}

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// 2: trajectories carry the front, the t = 0 extent and the hydrostatic error (expect dam_break, runout, hydrostatic).
// 3: and the last frame's surface (meshing knobs, expect sphere).
// 4: and the count of dynamic particles at t = 0 (expect viscous_spread).
constexpr int kPartVersion = 4;

// --- one run ------------------------------------------------------------------------

std::string machine() {
  std::ifstream in("/proc/cpuinfo");
  std::string line, cpu = "unknown CPU";
  while (std::getline(in, line))
    if (line.rfind("model name", 0) == 0 && line.find(':') != std::string::npos) {
      cpu = line.substr(line.find(':') + 2);
      break;
    }
  return cpu + ", " + std::to_string(std::thread::hardware_concurrency()) + " logical cores";
}

json vec(const Vec3& v) { return json::array({v.x(), v.y(), v.z()}); }
// JSON has no infinity: an extent over no particle is written as null.
json finiteVec(const Vec3& v) { return v.allFinite() ? vec(v) : json(nullptr); }
json finiteList(const std::vector<double>& v) {
  json a = json::array();
  for (double x : v) a.push_back(std::isfinite(x) ? json(x) : json(nullptr));
  return a;
}
Vec3 vec(const json& j) { return Vec3(j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>()); }

// A mesh as flat lists: positions x y z ..., triangles i j k ... (normals are not kept).
json surfaceJson(const render::TriangleMesh& m) {
  std::vector<float> xyz;
  xyz.reserve(3 * m.positions.size());
  for (const Vec3f& v : m.positions) xyz.insert(xyz.end(), {v.x(), v.y(), v.z()});
  return {{"positions", xyz}, {"indices", m.indices}};
}

render::TriangleMesh surfaceFrom(const json& j) {
  render::TriangleMesh m;
  const auto xyz = j.at("positions").get<std::vector<float>>();
  for (std::size_t i = 0; i + 2 < xyz.size(); i += 3) m.positions.emplace_back(xyz[i], xyz[i + 1], xyz[i + 2]);
  m.indices = j.at("indices").get<std::vector<std::uint32_t>>();
  for (std::uint32_t i : m.indices)
    if (i >= m.positions.size()) throw RuntimeError("study part: a surface triangle indexes past its vertices");
  return m;
}

json trajectoryJson(const Trajectory& tr) {
  json centres = json::array();
  for (const auto& frame : tr.centres) {
    json f = json::array();
    for (const auto& c : frame) f.push_back(vec(c));
    centres.push_back(f);
  }
  json v0 = json::array();
  for (const auto& v : tr.velocity0) v0.push_back(vec(v));
  return {{"t", tr.t},           {"centres", centres},   {"velocity0", v0},
          {"reach", tr.reach},   {"dynamic0", tr.dynamic0}, {"names", tr.names},
          {"max_displacement_m", tr.maxDisplacement}, {"max_speed_mps", tr.maxSpeed}, {"spacing_m", tr.spacing},
          {"front_x", tr.front}, {"lo0", finiteVec(tr.lo0)}, {"hi0", finiteVec(tr.hi0)}, {"dynamic0_count", tr.dynamic0Count},
          {"hydrostatic_m", finiteList(tr.hydrostatic)}, {"surface", surfaceJson(tr.surface)}};
}

Trajectory trajectoryFrom(const json& j) {
  Trajectory tr;
  tr.t = j.at("t").get<std::vector<double>>();
  for (const auto& f : j.at("centres")) {
    std::vector<Vec3> frame;
    for (const auto& c : f) frame.push_back(vec(c));
    tr.centres.push_back(std::move(frame));
  }
  for (const auto& v : j.at("velocity0")) tr.velocity0.push_back(vec(v));
  tr.reach = j.at("reach").get<std::vector<double>>();
  tr.dynamic0 = j.at("dynamic0").get<std::vector<bool>>();
  tr.names = j.at("names").get<std::vector<std::string>>();
  tr.maxDisplacement = j.at("max_displacement_m").get<double>();
  tr.maxSpeed = j.at("max_speed_mps").get<double>();
  tr.spacing = j.at("spacing_m").get<double>();
  for (const auto& f : j.at("front_x")) tr.front.push_back(f.is_null() ? -std::numeric_limits<double>::infinity() : f.get<double>());
  tr.lo0 = j.at("lo0").is_null() ? Vec3::Constant(std::numeric_limits<double>::infinity()) : vec(j.at("lo0"));
  for (const auto& x : j.at("hydrostatic_m"))
    tr.hydrostatic.push_back(x.is_null() ? std::numeric_limits<double>::quiet_NaN() : x.get<double>());
  tr.hi0 = j.at("hi0").is_null() ? Vec3::Constant(-std::numeric_limits<double>::infinity()) : vec(j.at("hi0"));
  tr.dynamic0Count = j.at("dynamic0_count").get<std::size_t>();
  tr.surface = surfaceFrom(j.at("surface"));
  return tr;
}

json settingJson(const Setting& s) {
  json a = json::array();
  for (const auto& [k, v] : s) a.push_back({k, v});
  return a;
}

Setting settingFrom(const json& j) {
  Setting s;
  for (const auto& kv : j) s.emplace_back(kv.at(0).get<std::string>(), kv.at(1).get<double>());
  return s;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// expect freefall and rest speak of the bodies made before play: refuse what they cannot judge.
void checkExpectations(const Prepared& p) {
  for (const Expectation& e : p.scene.expectations)
    if (e.kind != Expectation::Kind::kHeight && !p.sketch->runtime.empty())
      throw InputError(p.scene.path, e.line, "kind",
                       std::string("expect ") + toString(e.kind) + " needs a sketch with nothing drawn after play (" +
                           p.strokes.path + " draws " + std::to_string(p.sketch->runtime.size()) + " operation(s) after play)");
}

bool expectsSurface(const SceneDesc& scene) {
  return std::any_of(scene.expectations.begin(), scene.expectations.end(),
                     [](const Expectation& e) { return e.kind == Expectation::Kind::kSphere; });
}

// A meshing knob that would change nothing in this scene is an error (as an MPM knob under
// pbd): smoothing needs a surface meshed from cells (a deforming body: soft, an MPM solid, ...;
// a rope is a tube and a cloth a sheet along its lattice), mesh_resolution a fluid's kernel
// surface.
void checkMeshingKnobs(const Setting& setting, const SceneDesc& scene, const Solver& solver, const std::string& option) {
  bool cells = false, kernels = false;
  for (int b = 0; b < solver.bodyCount(); ++b)
    for (std::int32_t i : solver.bodyParticles(b)) {
      const Material& m = scene.materials[std::size_t(solver.particles().material[std::size_t(i)])];
      const render::SurfaceKind k = surfaceOf(m.kind, scene.solver);
      kernels |= k == render::SurfaceKind::kFluid;
      cells |= k == render::SurfaceKind::kParticles && m.kind != MaterialKind::kRope && m.kind != MaterialKind::kCloth;
    }
  const std::string where = option + " '" + settingText(setting) + "'";
  for (const auto& [knob, v] : setting) {
    if (knob == "smoothing" && !cells)
      throw InputError(where, 0, knob, "knob 'smoothing' smooths surfaces meshed from particles' cells (soft bodies, "
                                       "MPM solids); nothing in " + scene.path + " is meshed that way");
    if (knob == "mesh_resolution" && !kernels)
      throw InputError(where, 0, knob, "knob 'mesh_resolution' sets the voxels of fluid surfaces; " + scene.path +
                                           " has no fluid");
  }
}

// Every body's surfaces at one frame as one mesh (indices offset), for the surface norms.
render::TriangleMesh joinedSurface(const std::map<int, std::vector<render::MaterialMesh>>& bodies) {
  render::TriangleMesh out;
  for (const auto& [b, parts] : bodies)
    for (const render::MaterialMesh& m : parts) {
      const auto base = static_cast<std::uint32_t>(out.positions.size());
      out.positions.insert(out.positions.end(), m.mesh.positions.begin(), m.mesh.positions.end());
      out.normals.insert(out.normals.end(), m.mesh.normals.begin(), m.mesh.normals.end());
      for (std::uint32_t i : m.mesh.indices) out.indices.push_back(base + i);
    }
  return out;
}

// Runs the scene with one setting `repeats` times (each from a fresh solver; the state after
// every repeat must be the same) and returns its part. `analytic`: measure the error against
// the scene's expect records here.
json runSetting(const std::string& scenePath, const Setting& setting, int repeats, int threads, bool analytic,
                const std::string& option, int maxFrames) {
  tbb::task_arena arena(threads);
  json part;
  arena.execute([&] {
    Prepared p;
    try {
      p = prepare(scenePath, threads, false, [&](SceneDesc& sc) { applySetting(setting, sc, option); });
    } catch (const InputError& e) {
      // A voxel knob can push a stroke out of the workspace or past the particle cap: say which setting.
      throw InputError(e.file(), e.line(), e.field(), e.reason() + " (with " + settingText(setting) + ")");
    }
    if (analytic) checkExpectations(p);
    const SceneDesc& sc = p.scene;
    const int frames = maxFrames > 0 ? std::min(maxFrames, sc.frameCount()) : sc.frameCount();
    const MeshingSetting meshing = meshingOf(setting);
    const bool meshes = meshing.varied || expectsSurface(sc);
    Trajectory tr;
    std::vector<double> msPerFrame, meshMsPerFrame;
    std::uint64_t hash = 0;
    std::string status = "ok";
    for (int r = 0; r < repeats; ++r) {
      const std::unique_ptr<Solver> solver = makeSolver(p);
      RuntimeDriver runtime(*p.sketch, *solver);
      if (r == 0 && meshing.varied) checkMeshingKnobs(setting, sc, *solver, option);
      std::unique_ptr<FrameWriter> frameWriter;
      if (meshes) {
        FrameOptions fo;
        fo.draw = false;
        fo.keepMeshes = true;
        fo.smoothIterations = meshing.smoothing;
        fo.fluidVoxelFraction = meshing.fluidVoxelFraction;
        frameWriter = std::make_unique<FrameWriter>(sc, p.sketch->mapping, fo);
      }
      const bool record = r == 0;
      std::vector<Vec3> x0;
      if (record) {
        const ParticleArrays& ps = solver->particles();
        for (std::size_t i = 0; i < ps.size(); ++i) x0.emplace_back(ps.x[i], ps.y[i], ps.z[i]);
        observeStart(*solver, *p.sketch, tr);
        observe(*solver, x0, sc, tr);
      }
      double simulated = 0.0;  // s of wall time in steps only: observing is not the solver's cost
      double meshed = 0.0;     // s of wall time meshing frames (a meshing study)
      for (int f = 1; f < frames && !solver->guard().tripped(); ++f) {
        const double t0 = nowSeconds();
        for (int s = 0; s < sc.stepsPerFrame(); ++s) {
          runtime.beforeStep();
          if (!solver->step()) break;
        }
        simulated += nowSeconds() - t0;
        if (frameWriter && !solver->guard().tripped()) {
          const double m0 = nowSeconds();
          frameWriter->update(*solver, runtime.restCells());
          meshed += nowSeconds() - m0;
        }
        if (record && !solver->guard().tripped()) observe(*solver, x0, sc, tr);
      }
      if (solver->guard().tripped()) status = "unstable: " + solver->guard().message();
      if (record && frameWriter && status == "ok") tr.surface = joinedSurface(frameWriter->worldMeshes(*solver));
      msPerFrame.push_back(frames > 1 ? 1000.0 * (simulated + meshed) / (frames - 1) : 0.0);
      meshMsPerFrame.push_back(frames > 1 ? 1000.0 * meshed / (frames - 1) : 0.0);
      if (r == 0) hash = solver->stateHash();
      else if (solver->stateHash() != hash)
        throw RuntimeError("setting " + settingText(setting) + ": repeat " + std::to_string(r + 1) +
                           " ended in another state than the first (the run is not deterministic)");
    }
    part["physketch_study_part"] = kPartVersion;
    part["scene"] = scenePath;
    part["setting"] = settingJson(setting);
    part["particles"] = p.sketch->particles.size();
    part["threads"] = threads;
    part["frames"] = frames;
    part["repeats"] = repeats;
    part["ms_per_frame_repeats"] = msPerFrame;
    part["ms_per_frame"] = median(msPerFrame);
    if (meshes) part["mesh_ms_per_frame"] = median(meshMsPerFrame);
    part["status"] = status;
    part["machine"] = machine();
    if (analytic) {
      part["error_m"] = status == "ok" ? json(analyticError(tr, sc)) : json(nullptr);
      tr.surface = {};  // measured: only a fine reference needs the surfaces (they can be megabytes)
    }
    part["trajectory"] = trajectoryJson(tr);
  });
  return part;
}

// --- reference and options ----------------------------------------------------------

struct Plan {
  std::vector<KnobValues> knobs;
  std::vector<Setting> settings;
  bool analytic = true;
  Setting reference;              // fine: the reference run's setting
  std::ptrdiff_t referenceIndex = -1;  // fine: its index among the settings, or -1 (an extra run)
};

bool finestIsLargest(const std::string& knob) { return knob == "iterations" || knob == "substeps"; }

Plan makePlan(const StudyOptions& opt, const SceneDesc& scene) {
  Plan plan;
  for (const auto& v : opt.vary) plan.knobs.push_back(parseVary(v));
  checkDistinctKnobs(plan.knobs);
  plan.settings = cartesianProduct(plan.knobs);
  std::string mode = opt.reference;
  if (mode.empty()) mode = scene.expectations.empty() ? "fine" : "analytic";
  if (mode != "analytic" && mode != "fine")
    throw InputError("--reference '" + mode + "'", 0, "reference", "unknown reference (known: analytic, fine)");
  plan.analytic = mode == "analytic";
  if (plan.analytic && scene.expectations.empty())
    throw InputError(scene.path, 0, "expect",
                     "the scene declares no answer ('expect freefall', 'expect rest', 'expect height BODY Y'): "
                     "add one or use --reference fine");
  if (plan.analytic && !opt.referenceAt.empty())
    throw InputError("--reference-at", 0, "reference", "--reference-at names the fine reference: use it with --reference fine");
  if (!plan.analytic) {
    for (const auto& k : plan.knobs) {
      const auto [lo, hi] = std::minmax_element(k.values.begin(), k.values.end());
      plan.reference.emplace_back(k.knob, finestIsLargest(k.knob) ? *hi : *lo);
    }
    const Setting at = opt.referenceAt.empty() ? Setting{} : parseSetting(opt.referenceAt, "--reference-at");
    for (const auto& k : plan.knobs)
      if (k.knob == "smoothing" &&
          std::none_of(at.begin(), at.end(), [](const auto& kv) { return kv.first == "smoothing"; }))
        throw InputError("--vary", 0, "smoothing",
                         "knob 'smoothing' has no finest value (more smoothing is rounder, not nearer the truth): "
                         "declare the answer (expect sphere CX CY CZ R) or name the reference with --reference-at smoothing=N");
    if (!opt.referenceAt.empty())
      for (const auto& [knob, v] : at) {
        auto it = std::find_if(plan.reference.begin(), plan.reference.end(), [&](const auto& kv) { return kv.first == knob; });
        if (it != plan.reference.end()) it->second = v;
        else plan.reference.emplace_back(knob, v);
      }
    for (std::size_t i = 0; i < plan.settings.size(); ++i)
      if (settingText(plan.settings[i]) == settingText(plan.reference)) plan.referenceIndex = std::ptrdiff_t(i);
  }
  return plan;
}

// --- assembling the outputs -----------------------------------------------------------

struct Row {
  Setting setting;
  double error = NAN, ms = NAN;
  long long particles = 0;
  int threads = 0, repeats = 0;
  std::string status;
  bool front = false;
};

// Rows in order of their knob values (the order --vary gave the knobs), so a direct run and a
// collected one list them alike whatever order the parts came in.
std::vector<Row> makeRows(const std::vector<json>& parts, const json* reference, bool analytic) {
  std::vector<Row> rows;
  Trajectory ref;
  if (!analytic) ref = trajectoryFrom(reference->at("trajectory"));
  for (const json& p : parts) {
    Row r;
    r.setting = settingFrom(p.at("setting"));
    r.status = p.at("status").get<std::string>();
    const bool ok = r.status == "ok" && (analytic || reference->at("status") == "ok");
    if (ok) r.error = analytic ? p.at("error_m").get<double>() : fineError(trajectoryFrom(p.at("trajectory")), ref);
    r.ms = p.at("ms_per_frame").get<double>();
    r.particles = p.at("particles").get<long long>();
    r.threads = p.at("threads").get<int>();
    r.repeats = p.at("repeats").get<int>();
    rows.push_back(std::move(r));
  }
  std::sort(rows.begin(), rows.end(), [](const Row& a, const Row& b) {
    for (std::size_t k = 0; k < a.setting.size() && k < b.setting.size(); ++k)
      if (a.setting[k].second != b.setting[k].second) return a.setting[k].second < b.setting[k].second;
    return false;
  });
  std::vector<CostPoint> pts;
  for (const Row& r : rows) pts.push_back({r.ms, r.error});
  const std::vector<bool> front = paretoFront(pts);
  for (std::size_t i = 0; i < rows.size(); ++i) rows[i].front = front[i];
  return rows;
}

std::string csvText(const std::vector<Row>& rows) {
  std::string s;
  for (const auto& kv : rows.front().setting) s += kv.first + ",";
  s += "error_m,ms_per_frame,particles,threads,repeats,status,pareto\n";
  for (const Row& r : rows) {
    for (const auto& kv : r.setting) s += fmt("%.10g", kv.second) + ",";
    std::string status = r.status;
    std::replace(status.begin(), status.end(), ',', ';');
    std::replace(status.begin(), status.end(), '\n', ' ');
    s += fmt("%.6e", r.error) + "," + fmt("%.4f", r.ms) + "," + std::to_string(r.particles) + "," +
         std::to_string(r.threads) + "," + std::to_string(r.repeats) + "," + status + "," + (r.front ? "1" : "0") + "\n";
  }
  return s;
}

std::string normText(bool analytic, const SceneDesc* scene, const std::string& referenceText, bool surfaces) {
  if (!analytic && surfaces)
    return "symmetric RMS distance between the last frame's surfaces and the reference run's: the square root of the "
           "mean, over the vertices of both, of the squared distance to the other surface's triangles (m); reference: " +
           referenceText;
  if (!analytic)
    return "RMS over frames 1.. and the bodies dynamic at t = 0 of the distance between each body's centre of "
           "mass and the reference run's (m); reference: " + referenceText;
  std::string s;
  if (scene)
    for (const Expectation& e : scene->expectations) {
      s += s.empty() ? "" : "; ";
      switch (e.kind) {
        case Expectation::Kind::kFreefall:
          s += "expect freefall: RMS over dynamic bodies and the frames before each comes within one particle "
               "spacing of the ground or another body of |c(t) - (c0 + v0 t + g t^2/2)| (m)";
          break;
        case Expectation::Kind::kRest: s += "expect rest: largest particle displacement from t = 0 (m)"; break;
        case Expectation::Kind::kHeight:
          s += "expect height " + e.body + " " + fmt("%g", e.value) + ": |final centre height - " + fmt("%g", e.value) + "| (m)";
          break;
        case Expectation::Kind::kDamBreak:
          s += "expect dam_break " + fmt("%g", e.value) + ": a x RMS over Martin & Moyce 1952's rows with T <= 3 of "
               "Z(T) - Z_published, Z = front distance from the back wall / a, T = t sqrt(2 g / a) (m)";
          break;
        case Expectation::Kind::kRunout:
          s += "expect runout: |final run-out - Lube et al. 2005's run-out for the column's aspect ratio| (m)";
          break;
        case Expectation::Kind::kHydrostatic:
          s += "expect hydrostatic: RMS over fluid particles at the last frame of (p - p_hydrostatic(depth)) / (rho0 g), "
               "Tait's equation of state integrated down the column (m of head)";
          break;
        case Expectation::Kind::kPendulum:
          s += "expect pendulum " + e.body + ": RMS over frames 1.. of |c(t) - the simple pendulum's bob| about the "
               "pivot, length |c0 - pivot|, released as at t = 0, theta'' = -(g/L) sin theta integrated (m)";
          break;
        case Expectation::Kind::kSphere:
          s += "expect sphere: RMS over the last frame's surface vertices of |v - C| - R, C = (" + fmt("%g", e.point.x()) +
               ", " + fmt("%g", e.point.y()) + ", " + fmt("%g", e.point.z()) + "), R = " + fmt("%g", e.value) + " (m)";
          break;
        case Expectation::Kind::kViscousSpread:
          s += "expect viscous_spread: RMS over the frames of the second half of the run of r(t) - Huppert 1982's "
               "r_N = 0.894 (rho g V^3 t / (3 mu))^(1/8), r = the front's x + h/2 - the column's initial centre (m)";
          break;
      }
    }
  return s + (s.find(';') != std::string::npos ? "; the error is the largest of these" : "");
}

std::string markdown(const std::vector<Row>& rows, const std::vector<json>& parts, const std::string& scene,
                     const std::string& norm, int jobs, bool surfaces) {
  std::ostringstream md;
  md << "# physketch study: " << scene << "\n\n";
  md << "- error: " << norm << "\n";
  md << (surfaces ? "- wall time: the solver's steps and the meshing of every frame's surfaces (no drawing), per simulated "
                    "frame, median of the repeats\n"
                  : "- wall time: the solver's steps only, per simulated frame, median of the repeats\n");
  std::vector<std::string> machines;
  for (const json& p : parts) {
    const std::string m = p.at("machine").get<std::string>();
    if (std::find(machines.begin(), machines.end(), m) == machines.end()) machines.push_back(m);
  }
  for (const auto& m : machines) md << "- machine: " << m << "\n";
  if (jobs > 1) md << "- " << jobs << " settings ran side by side (--jobs): their times include that contention\n";
  md << "- Pareto front: no other setting is both as fast and as accurate, and better in one (marked `*`)\n\n";
  md << "|";
  for (const auto& kv : rows.front().setting) md << " " << kv.first << " |";
  md << " error (m) | ms/frame | particles | threads | front | status |\n|";
  for (std::size_t k = 0; k < rows.front().setting.size() + 6; ++k) md << " --- |";
  md << "\n";
  for (const Row& r : rows) {
    md << "|";
    for (const auto& kv : r.setting) md << " " << fmt("%.10g", kv.second) << " |";
    md << " " << fmt("%.3e", r.error) << " | " << fmt("%.3f", r.ms) << " | " << r.particles << " | " << r.threads
       << " | " << (r.front ? "*" : "") << " | " << r.status << " |\n";
  }
  return md.str();
}

void writeOutputs(const fs::path& out, const std::vector<json>& parts, const json* reference, bool analytic,
                  const SceneDesc* scene, const std::string& referenceText, int jobs) {
  const std::vector<Row> rows = makeRows(parts, reference, analytic);
  const std::string scenePath = parts.front().at("scene").get<std::string>();
  const bool surfaces = parts.front().contains("mesh_ms_per_frame");
  const std::string norm = normText(analytic, scene, referenceText, surfaces);
  std::vector<PlotPoint> pts;
  for (const Row& r : rows) pts.push_back({r.ms, r.error, r.front, settingText(r.setting)});
  const std::string title = "physketch study: " + fs::path(scenePath).filename().string() + " (error against " +
                            (analytic ? std::string("the scene's expect") : "a fine run: " + referenceText) + ")";
  const std::string yLabel = analytic   ? "error against the expected answer (m)"
                             : surfaces ? "RMS surface distance to the fine run (m)"
                                        : "RMS centre distance to the fine run (m)";
  const std::string png = studyPlotPng(pts, title, yLabel);
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) throw RuntimeError("cannot create output folder " + out.string() + ": " + ec.message());
  writeFileAtomic((out / "study.csv").string(), csvText(rows));
  writeFileAtomic((out / "study.md").string(), markdown(rows, parts, scenePath, norm, jobs, surfaces));
  writeFileAtomic((out / "study.png").string(), png);
  // For run --budget --from-study: the rows, which scene they measured, and (fine) the reference.
  json j;
  j["physketch_study"] = kStudyJsonVersion;
  j["scene"] = scenePath;
  j["scene_digest"] = scene ? sceneDigest(*scene) : "";
  j["reference"] = analytic ? "analytic" : "fine";
  j["norm"] = norm;
  if (!analytic) {
    j["reference_setting"] = referenceText;
    j["reference_trajectory"] = reference->at("trajectory");
  }
  j["rows"] = json::array();
  for (const Row& r : rows)
    j["rows"].push_back({{"setting", settingJson(r.setting)},
                         {"error_m", std::isfinite(r.error) ? json(r.error) : json(nullptr)},
                         {"ms_per_frame", r.ms},
                         {"threads", r.threads},
                         {"particles", r.particles},
                         {"status", r.status}});
  writeFileAtomic((out / "study.json").string(), j.dump(1) + "\n");
}

// --- the modes ------------------------------------------------------------------------

std::string quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

int defaultThreads(int jobs) { return std::max(1, tbb::info::default_concurrency() / std::max(1, jobs)); }

// Runs every setting (and an extra reference run), `jobs` at a time, each in a TBB arena of
// its own threads; progress on stderr, one line per finished setting.
std::vector<json> runAll(const StudyOptions& opt, const std::vector<Setting>& settings, bool analytic, int threads) {
  std::vector<json> parts(settings.size());
  std::atomic<std::size_t> next{0}, done{0};
  std::mutex mutex;
  std::exception_ptr failure;
  std::atomic<bool> stop{false};
  const double start = nowSeconds();
  auto worker = [&] {
    for (;;) {
      const std::size_t i = next++;
      if (i >= settings.size() || stop) return;
      try {
        parts[i] = runSetting(opt.scene, settings[i], opt.repeat, threads, analytic, "setting", 0);
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex);
        if (!failure) failure = std::current_exception();
        stop = true;
        return;
      }
      const std::size_t d = ++done;
      if (opt.quiet) continue;
      const double elapsed = nowSeconds() - start;
      std::lock_guard<std::mutex> lock(mutex);
      std::string err;
      if (analytic && parts[i].contains("error_m") && parts[i]["error_m"].is_number())
        err = "  error " + fmt("%.3e", parts[i]["error_m"].get<double>()) + " m";
      std::fprintf(stderr, "study: setting %zu/%zu %s%s  %.3f ms/frame  %.1f s elapsed, ETA %.0f s\n", d,
                   settings.size(), settingText(settings[i]).c_str(), err.c_str(),
                   parts[i]["ms_per_frame"].get<double>(), elapsed, elapsed / double(d) * double(settings.size() - d));
    }
  };
  std::vector<std::thread> pool;
  for (int j = 1; j < opt.jobs; ++j) pool.emplace_back(worker);
  worker();
  for (auto& t : pool) t.join();
  if (failure) std::rethrow_exception(failure);
  return parts;
}

int emitCommands(const StudyOptions& opt, const Plan& plan, int threads) {
  // Absolute paths, so the list runs from any folder (a Slurm job starts in its own). A program
  // found on PATH (no '/') stays a bare name.
  const fs::path out = fs::absolute(opt.outDir);
  const std::string scene = fs::absolute(opt.scene).string();
  const std::string program =
      opt.program.find('/') == std::string::npos ? opt.program : fs::absolute(opt.program).lexically_normal().string();
  const int width = int(std::to_string(plan.settings.size()).size());
  std::string common = " --reference " + std::string(plan.analytic ? "analytic" : "fine");
  if (!plan.analytic) common += " --reference-at " + quote(settingText(plan.reference));
  common += " --repeat " + std::to_string(opt.repeat) + " --threads " + std::to_string(threads) + " --quiet";
  json planJson;
  planJson["physketch_study_plan"] = kPartVersion;
  planJson["scene"] = scene;
  planJson["reference"] = plan.analytic ? "analytic" : "fine";
  planJson["settings"] = json::array();
  auto command = [&](const Setting& s, const std::string& dir) {
    return quote(program) + " study " + quote(scene) + " --only " + quote(settingText(s)) + common + " --out " +
           quote((out / "parts" / dir).string());
  };
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) throw RuntimeError("cannot create output folder " + out.string() + ": " + ec.message());
  for (std::size_t i = 0; i < plan.settings.size(); ++i) {
    char dir[32];
    std::snprintf(dir, sizeof dir, "%0*zu", width, i + 1);
    planJson["settings"].push_back({{"dir", dir}, {"setting", settingText(plan.settings[i])}});
    std::cout << command(plan.settings[i], dir) << "\n";
  }
  if (!plan.analytic && plan.referenceIndex < 0) {
    planJson["settings"].push_back({{"dir", "ref"}, {"setting", settingText(plan.reference)}});
    std::cout << command(plan.reference, "ref") << "\n";
  }
  writeFileAtomic((out / "plan.json").string(), planJson.dump(1) + "\n");
  std::cout.flush();
  return kExitOk;
}

json readJsonFile(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw InputError(path.string(), 0, "", "cannot open");
  try {
    return json::parse(in);
  } catch (const json::exception& e) {
    throw InputError(path.string(), 0, "", std::string("not JSON: ") + e.what());
  }
}

int collect(const StudyOptions& opt) {
  const fs::path dir(opt.collect);
  const fs::path planPath = dir / "plan.json";
  if (!fs::is_regular_file(planPath))
    throw InputError(planPath.string(), 0, "", "no plan: run 'physketch study SCENE --vary ... --emit-commands --out " +
                                                   dir.string() + "' first, then its commands");
  const json plan = readJsonFile(planPath);
  const bool analytic = plan.at("reference") == "analytic";
  std::vector<json> parts;
  json reference;
  std::string referenceText;
  std::vector<std::string> missing;
  for (const auto& entry : plan.at("settings")) {
    const std::string sub = entry.at("dir").get<std::string>();
    const fs::path partPath = dir / "parts" / sub / "part.json";
    if (!fs::is_regular_file(partPath)) {
      missing.push_back(sub + " (" + entry.at("setting").get<std::string>() + ")");
      continue;
    }
    json part = readJsonFile(partPath);
    if (!part.contains("physketch_study_part") || part["physketch_study_part"] != kPartVersion)
      throw InputError(partPath.string(), 0, "", "not a physketch study part of version " + std::to_string(kPartVersion) +
                                                       " (made by another physketch? run its setting again)");
    if (settingText(settingFrom(part.at("setting"))) != entry.at("setting").get<std::string>())
      throw InputError(partPath.string(), 0, "setting", "holds setting " + settingText(settingFrom(part.at("setting"))) +
                                                            ", the plan says " + entry.at("setting").get<std::string>());
    if (!analytic && part.value("is_reference", false)) {
      reference = part;
      referenceText = settingText(settingFrom(part.at("setting")));
    }
    if (sub != "ref") parts.push_back(std::move(part));
  }
  if (!missing.empty()) {
    std::string list;
    for (const auto& m : missing) list += (list.empty() ? "" : ", ") + m;
    throw InputError((dir / "parts").string(), 0, "", std::to_string(missing.size()) + " part(s) missing: " + list +
                                                          " (run their commands from --emit-commands)");
  }
  if (!analytic && reference.is_null())
    throw InputError((dir / "parts").string(), 0, "", "no part holds the fine reference run");
  std::unique_ptr<SceneDesc> scene;
  const std::string scenePath = plan.at("scene").get<std::string>();
  if (fs::is_regular_file(scenePath)) scene = std::make_unique<SceneDesc>(loadScene(scenePath));
  writeOutputs(dir, parts, analytic ? nullptr : &reference, analytic, scene.get(), referenceText, 1);
  if (!opt.quiet) std::cerr << "physketch study: " << parts.size() << " parts -> " << (dir / "study.csv").string() << "\n";
  return kExitOk;
}

}  // namespace

Trajectory calibrationRun(const std::string& scenePath, const Setting& setting, int threads, int maxFrames,
                          double& msPerFrame, std::string& status) {
  const json part = runSetting(scenePath, setting, 1, threads, false, "--budget", maxFrames);
  msPerFrame = part.at("ms_per_frame").get<double>();
  status = part.at("status").get<std::string>();
  return trajectoryFrom(part.at("trajectory"));
}

int runStudy(const StudyOptions& opt) {
  return withExitCodes([&] {
    if (!opt.collect.empty()) return collect(opt);
    if (opt.scene.empty()) throw InputError("study", 0, "scene", "missing SCENE (or --collect DIR)");
    const int threads = opt.threads > 0 ? opt.threads : defaultThreads(opt.jobs);
    const SceneDesc scene = loadScene(opt.scene);
    if (!opt.only.empty()) {
      // One part of a study run elsewhere (--emit-commands): OUT/part.json.
      StudyOptions one = opt;
      const Setting s = parseSetting(opt.only, "--only");
      one.vary.clear();
      for (const auto& [k, v] : s) one.vary.push_back(settingText({{k, v}}));
      const Plan plan = makePlan(one, scene);
      json part = runSetting(opt.scene, s, opt.repeat, threads, plan.analytic, "--only", 0);
      if (!plan.analytic) {
        part["reference_setting"] = settingJson(plan.reference);
        part["is_reference"] = settingText(s) == settingText(plan.reference);
      }
      std::error_code ec;
      fs::create_directories(opt.outDir, ec);
      if (ec) throw RuntimeError("cannot create output folder " + opt.outDir + ": " + ec.message());
      writeFileAtomic((fs::path(opt.outDir) / "part.json").string(), part.dump() + "\n");
      return kExitOk;
    }
    const Plan plan = makePlan(opt, scene);
    if (opt.emitCommands) return emitCommands(opt, plan, threads);
    std::vector<Setting> runs = plan.settings;
    if (!plan.analytic && plan.referenceIndex < 0) runs.push_back(plan.reference);
    // Bad input in any setting (a dt that does not divide a frame, a voxel that leaves strokes
    // outside the workspace) is found before hours of runs: prepare each once, cheaply.
    for (const Setting& s : runs) {
      SceneDesc sc = scene;
      applySetting(s, sc, "setting");
    }
    std::vector<json> parts = runAll(opt, runs, plan.analytic, threads);
    json reference;
    if (!plan.analytic) {
      reference = plan.referenceIndex >= 0 ? parts[std::size_t(plan.referenceIndex)] : parts.back();
      if (plan.referenceIndex < 0) parts.pop_back();
    }
    writeOutputs(opt.outDir, parts, plan.analytic ? nullptr : &reference, plan.analytic, &scene,
                 settingText(plan.reference), opt.jobs);
    if (!opt.quiet)
      std::cerr << "physketch study: " << parts.size() << " settings -> " << (fs::path(opt.outDir) / "study.csv").string()
                << ", study.md, study.png\n";
    return kExitOk;
  });
}

std::string sceneDigest(const SceneDesc& scene) {
  std::uint64_t h = 1469598103934665603ull;  // FNV-1a 64
  for (const std::string& path : {scene.path, scene.strokesPath}) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path, 0, "", "cannot read (to tell which scene a study measured)");
    for (std::istreambuf_iterator<char> it(in), end; it != end; ++it) {
      h ^= static_cast<unsigned char>(*it);
      h *= 1099511628211ull;
    }
    h ^= 0xff;  // the boundary between the files
    h *= 1099511628211ull;
  }
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(h));
  return hex;
}

BudgetChoice budgetFromStudy(const SceneDesc& scene, const std::string& dir, double budgetMs) {
  if (!(budgetMs > 0.0) || !std::isfinite(budgetMs))
    throw InputError("--budget", 0, "budget", "must be a positive number of milliseconds per frame");
  const fs::path path = fs::path(dir) / "study.json";
  if (!fs::is_regular_file(path))
    throw InputError(path.string(), 0, "", "no study here: run 'physketch study " + scene.path +
                                               " --vary ... --out " + dir + "' first");
  const json j = readJsonFile(path);
  BudgetChoice out;
  try {
    if (j.at("physketch_study").get<int>() != kStudyJsonVersion)
      throw InputError(path.string(), 0, "physketch_study", "written by another physketch: run the study again");
    const std::string digest = j.at("scene_digest").get<std::string>();
    if (digest != sceneDigest(scene))
      throw InputError(path.string(), 0, "scene_digest",
                       "the study measured " + j.at("scene").get<std::string>() + " as it was then; " + scene.path +
                           " or its stroke file differs: run the study again");
    out.source = dir;
    out.analytic = j.at("reference") == "analytic";
    out.norm = j.at("norm").get<std::string>();
    if (!out.analytic) {
      out.reference = parseSetting(j.at("reference_setting").get<std::string>(), "study.json");
      out.referenceTrajectory = trajectoryFrom(j.at("reference_trajectory"));
    }
    for (const json& r : j.at("rows")) {
      BudgetCandidate c;
      c.setting = settingFrom(r.at("setting"));
      for (const auto& [knob, v] : c.setting)
        if (isMeshingKnob(knob))
          throw InputError(path.string(), 0, knob, "the study varied meshing knob '" + knob +
                                                       "'; --budget fits the solver's time per frame: use a study of "
                                                       "solver knobs (iterations, substeps, dt, voxel, grid_dx, cfl)");
      c.msPerFrame = r.at("ms_per_frame").get<double>();
      c.error = r.at("error_m").is_null() ? std::numeric_limits<double>::quiet_NaN() : r.at("error_m").get<double>();
      c.status = r.at("status").get<std::string>();
      out.studyThreads = r.at("threads").get<int>();
      out.candidates.push_back(std::move(c));
    }
  } catch (const json::exception& e) {
    throw InputError(path.string(), 0, "", std::string("not a study.json: ") + e.what());
  }
  if (out.candidates.empty()) throw InputError(path.string(), 0, "rows", "the study has no rows");
  const std::ptrdiff_t pick = chooseWithinBudget(out.candidates, budgetMs, out.fits);
  if (pick < 0) throw RuntimeError("--budget: every setting of the study in " + dir + " was stopped by the stability guard");
  const BudgetCandidate& c = out.candidates[std::size_t(pick)];
  out.setting = c.setting;
  out.predictedMs = c.msPerFrame;
  out.predictedError = c.error;
  return out;
}

double budgetRunError(const BudgetChoice& b, const Trajectory& run, const SceneDesc& scene) {
  if (b.analytic) return analyticError(run, scene);
  if (b.referenceTrajectory) return fineError(run, *b.referenceTrajectory);
  return std::numeric_limits<double>::quiet_NaN();
}

}  // namespace physketch::app
