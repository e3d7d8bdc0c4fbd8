// physketch study: the knobs (--vary), the settings they span and how a setting changes a scene.
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "apps/physketch/study.h"
#include "core/error.h"
#include "sketch/grid.h"

namespace physketch::app {
namespace {

struct KnobSpec {
  const char* name;
  double lo, hi;  // inclusive range
  bool integer;
  const char* what;
  bool meshing = false;  // changes how frames are meshed, not the simulation
};

// The knobs a study varies today; their ranges are the scene records' (docs/formats.md).
constexpr KnobSpec kKnobs[] = {
    {"iterations", 1, 1000, true, "contact iterations per substep (scene record 'iterations')"},
    {"substeps", 1, 1000, true, "substeps per step (scene record 'substeps')"},
    {"dt", 1e-7, 0.1, false, "s per solver step (scene record 'dt'); 1/fps must stay a whole number of steps"},
    {"voxel", 1e-6, 1000.0 / sketch::kGridSize, false,
     "voxel size = particle spacing (m); the workspace edge becomes 151 voxels, centred as in the scene"},
    {"grid_dx", 1.0, 4.0, false, "solver mpm: grid spacing in particle spacings (scene record 'grid_dx')"},
    {"cfl", 1e-3, 1.0, false, "solver mpm with 'substeps auto': the Courant number C (scene record 'cfl')"},
    {"particle_shift", 0, 1.0, false,
     "solver mpm: fluid particles closer than this many spacings pushed apart once a step, 0 = off (scene record "
     "'particle_shift')"},
    {"sleep", 0, 10, false, "solver pbd: the sleep speed in m/s, 0 = off (scene record 'sleep'; its time stays the scene's)"},
    {"warm_start", 0, 0.9, false,
     "solver pbd: the fraction of the fluids' density multipliers carried between substeps, 0 = off (scene record "
     "'warm_start'; its averages stay the scene's)"},
    {"smoothing", 0, 100, true, "mean-curvature smoothing iterations of deforming surfaces meshed from cells (run --smooth)",
     true},
    {"mesh_resolution", 0.1, 1.0, false,
     "voxel edge of fluid surfaces' kernel field, in particle spacings (run --mesh-resolution)", true},
};

// Knobs the issue names that arrive with later work: a clear refusal, never "unknown".
struct Reserved {
  const char* name;
  const char* why;
};
constexpr Reserved kReserved[] = {
    {"grid", "MPM grid resolution: write grid_dx (grid spacing in particle spacings) or voxel"},
};

std::string knownKnobs() {
  std::string s;
  for (const auto& k : kKnobs) s += (s.empty() ? "" : ", ") + std::string(k.name);
  return s;
}

const KnobSpec& knobSpec(const std::string& name, const std::string& where) {
  for (const auto& k : kKnobs)
    if (name == k.name) return k;
  for (const auto& r : kReserved)
    if (name == r.name) throw InputError(where, 0, name, std::string("knob '") + name + "' (" + r.why + ")");
  throw InputError(where, 0, name.empty() ? "knob" : name,
                   "unknown knob '" + name + "' (known: " + knownKnobs() + ")");
}

double parseValue(const KnobSpec& k, const std::string& text, const std::string& where) {
  if (text.empty()) throw InputError(where, 0, k.name, "empty value (write KNOB=V1,V2,... with no empty entry)");
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(text.c_str(), &end);
  if (end == text.c_str() || *end != '\0') throw InputError(where, 0, k.name, "value '" + text + "' is not a number");
  if (!std::isfinite(v) || errno == ERANGE) throw InputError(where, 0, k.name, "value '" + text + "' is not a finite number");
  if (k.integer && v != std::floor(v))
    throw InputError(where, 0, k.name, "value '" + text + "' is not a whole number (" + k.what + ")");
  if (v < k.lo || v > k.hi) {
    char range[96];
    std::snprintf(range, sizeof range, "%.6g..%.6g", k.lo, k.hi);
    throw InputError(where, 0, k.name, "value '" + text + "' is out of range " + range + " (" + k.what + ")");
  }
  return v;
}

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::size_t start = 0;
  for (;;) {
    const std::size_t at = s.find(sep, start);
    out.push_back(s.substr(start, at == std::string::npos ? std::string::npos : at - start));
    if (at == std::string::npos) return out;
    start = at + 1;
  }
}

}  // namespace

KnobValues parseVary(const std::string& arg) {
  const std::string where = "--vary '" + arg + "'";
  const std::size_t eq = arg.find('=');
  if (eq == std::string::npos) throw InputError(where, 0, "knob", "expected KNOB=V1,V2,... (e.g. substeps=1,2,4)");
  KnobValues kv;
  kv.knob = arg.substr(0, eq);
  const KnobSpec& spec = knobSpec(kv.knob, where);
  const std::string list = arg.substr(eq + 1);
  if (list.empty()) throw InputError(where, 0, kv.knob, "no values (write KNOB=V1,V2,...)");
  for (const std::string& text : split(list, ',')) {
    const double v = parseValue(spec, text, where);
    for (double w : kv.values)
      if (w == v) throw InputError(where, 0, kv.knob, "value '" + text + "' given twice");
    kv.values.push_back(v);
  }
  return kv;
}

void checkDistinctKnobs(const std::vector<KnobValues>& knobs) {
  if (knobs.empty()) throw InputError("--vary", 0, "knob", "nothing to vary: give at least one --vary KNOB=V1,V2,...");
  for (std::size_t i = 0; i < knobs.size(); ++i)
    for (std::size_t j = 0; j < i; ++j)
      if (knobs[i].knob == knobs[j].knob)
        throw InputError("--vary", 0, knobs[i].knob, "knob varied twice: give all its values in one --vary");
}

Setting parseSetting(const std::string& arg, const std::string& option) {
  const std::string where = option + " '" + arg + "'";
  Setting s;
  if (arg.empty()) throw InputError(where, 0, "knob", "empty setting (write KNOB=V,KNOB=V)");
  for (const std::string& part : split(arg, ',')) {
    const std::size_t eq = part.find('=');
    if (eq == std::string::npos) throw InputError(where, 0, "knob", "'" + part + "' is not KNOB=V");
    const std::string knob = part.substr(0, eq);
    const KnobSpec& spec = knobSpec(knob, where);
    for (const auto& kv : s)
      if (kv.first == knob) throw InputError(where, 0, knob, "knob given twice");
    s.emplace_back(knob, parseValue(spec, part.substr(eq + 1), where));
  }
  return s;
}

bool isMeshingKnob(const std::string& knob) {
  for (const auto& k : kKnobs)
    if (knob == k.name) return k.meshing;
  return false;
}

MeshingSetting meshingOf(const Setting& s) {
  MeshingSetting m;
  for (const auto& [knob, v] : s) {
    if (knob == "smoothing") m.smoothing = static_cast<int>(v), m.varied = true;
    if (knob == "mesh_resolution") m.fluidVoxelFraction = v, m.varied = true;
  }
  return m;
}

std::vector<Setting> cartesianProduct(const std::vector<KnobValues>& knobs) {
  std::size_t n = 1;
  for (const auto& k : knobs) {
    n *= k.values.size();
    if (n > kMaxSettings)
      throw InputError("--vary", 0, k.knob, "more than " + std::to_string(kMaxSettings) +
                                                " settings: split the study (--emit-commands runs parts elsewhere)");
  }
  std::vector<Setting> out;
  out.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    Setting s(knobs.size());
    std::size_t rest = i;
    for (std::size_t k = knobs.size(); k-- > 0;) {  // the last knob varies fastest
      s[k] = {knobs[k].knob, knobs[k].values[rest % knobs[k].values.size()]};
      rest /= knobs[k].values.size();
    }
    out.push_back(std::move(s));
  }
  return out;
}

std::string settingText(const Setting& s) {
  std::string out;
  char buf[64];
  for (const auto& [knob, v] : s) {
    // Short when that reads back exactly, else every digit: a setting's text runs it again.
    std::snprintf(buf, sizeof buf, "%.10g", v);
    if (std::strtod(buf, nullptr) != v) std::snprintf(buf, sizeof buf, "%.17g", v);
    out += (out.empty() ? "" : ",") + knob + "=" + buf;
  }
  return out;
}

void applySetting(const Setting& s, SceneDesc& scene, const std::string& option) {
  const std::string where = option + " '" + settingText(s) + "'";
  for (const auto& [knob, v] : s) {
    if (knob == "iterations") scene.iterations = static_cast<int>(v);
    else if (knob == "substeps") scene.substeps = static_cast<int>(v);
    else if (knob == "voxel") scene.workspaceSize = v * sketch::kGridSize;
    else if (isMeshingKnob(knob)) continue;  // frames' meshing, not the scene: meshingOf()
    else if (knob == "grid_dx" || knob == "cfl") {
      // MPM's: under pbd they would change nothing, and a study of nothing is an error.
      if (scene.solver != SolverKind::kMpm)
        throw InputError(where, 0, knob, "knob '" + knob + "' is solver mpm's; the scene runs solver " + toString(scene.solver));
      if (knob == "cfl" && !scene.substepsAuto)
        throw InputError(where, 0, knob, "knob 'cfl' acts through 'substeps auto'; the scene fixes substeps");
      (knob == "cfl" ? scene.cfl : scene.gridDx) = v;
    }
    else if (knob == "sleep") {
      if (scene.solver != SolverKind::kPbd)
        throw InputError(where, 0, knob, std::string("knob 'sleep' is solver pbd's; the scene runs solver ") + toString(scene.solver));
      scene.sleep = v > 0.0;
      scene.sleepSpeed = v;
    } else if (knob == "particle_shift") {
      if (scene.solver != SolverKind::kMpm)
        throw InputError(where, 0, knob,
                         std::string("knob 'particle_shift' is solver mpm's; the scene runs solver ") + toString(scene.solver));
      scene.particleShift = v;
    } else if (knob == "warm_start") {
      if (scene.solver != SolverKind::kPbd)
        throw InputError(where, 0, knob,
                         std::string("knob 'warm_start' is solver pbd's; the scene runs solver ") + toString(scene.solver));
      scene.warmStart = v;
    } else if (knob == "dt") {
      // Frames land on step boundaries (as the scene file checks for its own dt).
      const double ratio = 1.0 / (scene.fps * v);
      if (std::abs(ratio - std::round(ratio)) > 1e-6 * ratio || std::round(ratio) < 1.0)
        throw InputError(where, 0, "dt", "1/fps must be a whole multiple of dt (the scene's fps " +
                                             std::to_string(scene.fps) + " gives 1/fps / dt = " + std::to_string(ratio) + ")");
      scene.dt = v;
    } else {
      knobSpec(knob, where);  // throws: not a knob
    }
  }
}

}  // namespace physketch::app
