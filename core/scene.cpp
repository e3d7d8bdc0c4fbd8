#include "core/scene.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <map>

#include "core/error.h"
#include "core/material_table.h"
#include "core/records.h"

namespace physketch {
namespace {

constexpr int kSceneVersion = 1;
constexpr std::size_t kMaxColliders = 1000;
constexpr std::size_t kMaxKeyframes = 100000;  // all colliders together
constexpr double kMaxTime = 3600.0;           // s, as 'duration'

std::string resolveRelative(const std::string& scenePath, const std::string& p) {
  namespace fs = std::filesystem;
  fs::path rel(p);
  if (rel.is_absolute()) return p;
  return (fs::path(scenePath).parent_path() / rel).lexically_normal().string();
}

// A collider's mesh: one of the formats the stamp loader reads, and a file that exists now
// (not when the simulation reaches it).
void checkMeshPath(const RecordFile& file, const FieldReader& f, std::size_t field, const std::string& resolved) {
  namespace fs = std::filesystem;
  std::string ext = fs::path(resolved).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  if (ext != ".obj" && ext != ".off" && ext != ".ply")
    f.fail(field, "mesh '" + f.word(field) + "' is not .obj, .off or .ply");
  std::error_code ec;
  if (!fs::is_regular_file(resolved, ec))
    f.fail(field, "mesh file '" + resolved + "' not found (paths are relative to the scene file's folder, " +
                      (fs::path(file.path).parent_path().empty() ? std::string(".") : fs::path(file.path).parent_path().string()) +
                      ")");
}

MeshCollider parseCollider(const RecordFile& file, const Record& r, const std::vector<MeshCollider>& existing,
                           bool& atGiven) {
  Record pos;
  const auto opts = splitOptions(file, r, pos, {"scale", "rot", "at", "friction"});
  FieldReader f(file, pos, {"name", "path"});
  MeshCollider c;
  c.name = f.word(0);
  c.line = r.line;
  for (const auto& other : existing)
    if (other.name == c.name) f.fail(0, "collider '" + c.name + "' defined twice (first on line " + std::to_string(other.line) + ")");
  if (existing.size() >= kMaxColliders) f.failLine("too many colliders (at most " + std::to_string(kMaxColliders) + ")");
  c.path = resolveRelative(file.path, f.word(1));
  checkMeshPath(file, f, 1, c.path);
  atGiven = false;
  for (const auto& o : opts) {
    if (o.key == "scale") {
      c.scale = parseNumberList(file, r.line, "scale", o.value, 1)[0];
      if (!(c.scale > 0) || c.scale > 1000.0)
        throw InputError(file.path, r.line, "scale", "must be in (0, 1000] (got " + o.value + ")");
    } else if (o.key == "rot") {
      c.rotation = parseRotation(file, r.line, "rot", o.value);
    } else if (o.key == "at") {
      c.position = parseVec3(file, r.line, "at", o.value, 1e6);
      atGiven = true;
    } else if (o.key == "friction") {
      const double mu = parseNumberList(file, r.line, "friction", o.value, 1)[0];
      if (!(mu >= 0 && mu <= 2)) throw InputError(file.path, r.line, "friction", "must be in [0, 2] (got " + o.value + ")");
      c.friction = mu;
    }
  }
  return c;
}

// keyframe NAME t x y z [rot=ax,ay,az,deg]: appended to its collider's keyframes.
void parseKeyframe(const RecordFile& file, const Record& r, std::vector<MeshCollider>& colliders,
                   std::size_t& keyframeCount) {
  Record pos;
  const auto opts = splitOptions(file, r, pos, {"rot"});
  FieldReader f(file, pos, {"name", "t", "x", "y", "z"});
  auto it = std::find_if(colliders.begin(), colliders.end(), [&](const MeshCollider& c) { return c.name == f.word(0); });
  if (it == colliders.end())
    f.fail(0, "unknown collider '" + f.word(0) + "' (a 'collider' record must define it before its keyframes)");
  if (++keyframeCount > kMaxKeyframes) f.failLine("too many keyframes (at most " + std::to_string(kMaxKeyframes) + ")");
  ColliderKeyframe k;
  k.t = f.nonNegative(1);
  if (k.t > kMaxTime) f.fail(1, "must be <= 3600 s (got " + f.word(1) + ")");
  if (!it->keyframes.empty() && !(k.t > it->keyframes.back().t))
    f.fail(1, "time " + f.word(1) + " does not increase (collider '" + it->name + "' has a keyframe at t = " +
                  std::to_string(it->keyframes.back().t) + " on line " + std::to_string(it->keyframes.back().line) + ")");
  k.position = Vec3(f.number(2), f.number(3), f.number(4));
  k.rotation = it->rotation;  // the collider's rot= unless the keyframe gives its own
  for (const auto& o : opts) k.rotation = parseRotation(file, r.line, o.key, o.value);
  k.line = r.line;
  it->keyframes.push_back(k);
}

// expect freefall | expect rest | expect height BODY Y | expect dam_break A | expect runout |
// expect hydrostatic | expect pendulum BODY PX PY PZ | expect sphere CX CY CZ R | expect viscous_spread
// (docs/formats.md, "Expected answers").
Expectation parseExpect(const RecordFile& file, const Record& r, const std::vector<Expectation>& existing) {
  const std::string first = r.tokens.size() > 1 ? r.tokens[1] : "";
  const std::vector<std::string> names = first == "dam_break"  ? std::vector<std::string>{"kind", "a"}
                                         : first == "pendulum" ? std::vector<std::string>{"kind", "body", "x", "y", "z"}
                                         : first == "sphere"   ? std::vector<std::string>{"kind", "x", "y", "z", "radius"}
                                                               : std::vector<std::string>{"kind", "body", "y"};
  FieldReader f(file, r, names, 1);
  Expectation e;
  e.line = r.line;
  const std::string& kind = f.word(0);
  const std::size_t want = kind == "height" ? 3 : kind == "dam_break" ? 2 : kind == "pendulum" || kind == "sphere" ? 5 : 1;
  if (kind == "freefall") e.kind = Expectation::Kind::kFreefall;
  else if (kind == "rest") e.kind = Expectation::Kind::kRest;
  else if (kind == "height") e.kind = Expectation::Kind::kHeight;
  else if (kind == "dam_break") e.kind = Expectation::Kind::kDamBreak;
  else if (kind == "runout") e.kind = Expectation::Kind::kRunout;
  else if (kind == "hydrostatic") e.kind = Expectation::Kind::kHydrostatic;
  else if (kind == "pendulum") e.kind = Expectation::Kind::kPendulum;
  else if (kind == "sphere") e.kind = Expectation::Kind::kSphere;
  else if (kind == "viscous_spread") e.kind = Expectation::Kind::kViscousSpread;
  else
    f.fail(0, "unknown expectation '" + kind +
                  "' (known: freefall, rest, height, dam_break, runout, hydrostatic, pendulum, sphere, viscous_spread)");
  if (f.count() < want)
    f.fail(f.count(), kind == "height"     ? "expect height needs BODY and Y (m): expect height NAME Y"
                      : kind == "pendulum" ? "expect pendulum needs BODY and the pivot (m): expect pendulum NAME PX PY PZ"
                      : kind == "sphere"   ? "expect sphere needs the centre and radius (m): expect sphere CX CY CZ R"
                                           : "expect dam_break needs the column's width A (m): expect dam_break A");
  if (f.count() > want)
    throw InputError(file.path, r.line, "#" + std::to_string(want + 1),
                     "extra field '" + f.word(want) + "' (expect " + kind + " takes " +
                         (want == 1   ? "no further field)"
                          : want == 2 ? "A only)"
                          : want == 3 ? "BODY and Y only)"
                          : kind == "sphere" ? "the centre's CX CY CZ and the radius R only)"
                                      : "BODY and the pivot's PX PY PZ only)"));
  if (e.kind == Expectation::Kind::kPendulum) {
    e.body = SceneDesc::expectedBodyName(f.word(1));
    e.point = Vec3(f.inRange(2, -1e6, 1e6), f.inRange(3, -1e6, 1e6), f.inRange(4, -1e6, 1e6));
  }
  if (e.kind == Expectation::Kind::kSphere) {
    e.point = Vec3(f.inRange(1, -1e6, 1e6), f.inRange(2, -1e6, 1e6), f.inRange(3, -1e6, 1e6));
    e.value = f.inRange(4, 0.0, 1e6);
    if (!(e.value > 0.0)) f.fail(4, "the sphere's radius R must be above 0 m");
  }
  if (e.kind == Expectation::Kind::kHeight) {
    e.body = SceneDesc::expectedBodyName(f.word(1));
    e.value = f.inRange(2, -1e6, 1e6);
  }
  if (e.kind == Expectation::Kind::kDamBreak) {
    e.value = f.inRange(1, 0.0, 1e6);
    if (!(e.value > 0.0)) f.fail(1, "the column's width A must be above 0 m");
  }
  for (const auto& o : existing) {
    const bool perBody = e.kind == Expectation::Kind::kHeight || e.kind == Expectation::Kind::kPendulum;
    const bool same = o.kind == e.kind && (!perBody || o.body == e.body);
    if (same) f.fail(perBody ? 1 : 0,
                     "expect " + kind + (e.body.empty() ? "" : " " + f.word(1)) + " given twice (first on line " +
                         std::to_string(o.line) + ")");
    // Free fall and rest of every dynamic body cannot both hold (unless nothing moves): one or the other.
    const bool clash = (o.kind == Expectation::Kind::kFreefall && e.kind == Expectation::Kind::kRest) ||
                       (o.kind == Expectation::Kind::kRest && e.kind == Expectation::Kind::kFreefall);
    if (clash) f.fail(0, "expect freefall and expect rest both speak of every dynamic body: give one (line " +
                             std::to_string(o.line) + " gives the other)");
  }
  return e;
}

// `scale k` (PhysGen3D §A.4): lengths are k times the real ones at the same time scale, so
// accelerations are k times larger (g' = k g) and, holding each body's mass fixed (density'
// = density / k^3), stresses are 1/k of the real ones (E' = E / k, as PhysGen3D states it):
// then E'/density' = k^2 E/density and every wave speed is k times the real one, as the
// motion is. Dynamic viscosity: mu' = mu / k (kinematic viscosity k^2). Friction, Poisson's
// ratio, angles and strains are dimensionless and unchanged.
void applyRealWorldScale(SceneDesc& s) {
  s.gravityUnscaled = s.gravity;
  s.materialsUnscaled = s.materials;
  if (s.scale == 1.0) return;
  const double k = s.scale;
  s.gravity = k * s.gravity;
  for (Material& m : s.materials) {
    m.density /= k * k * k;
    m.elastic.youngs /= k;
    m.fluid.bulkModulus /= k;
    m.fluid.viscosity /= k;
    m.sand.cohesion /= k;
    m.plasticine.yieldStress /= k;
  }
}

SceneDesc build(const RecordFile& file) {
  SceneDesc s;
  s.path = file.path;
  std::map<std::string, int> seen;  // keyword -> first line (each may appear once, except the repeatable ones)
  std::vector<int> colliderAtLine;  // per collider: its line when it gave at=, else 0
  std::size_t keyframeCount = 0;
  bool haveStrokes = false;
  int dtLine = 0, fpsLine = 0;
  for (const Record& r : file.records) {
    const std::string& kw = r.keyword();
    if (kw != "material" && kw != "collider" && kw != "keyframe" && kw != "expect") {
      auto [it, fresh] = seen.emplace(kw, r.line);
      if (!fresh)
        throw InputError(file.path, r.line, "record", "'" + kw + "' given twice (first given on line " +
                                                          std::to_string(it->second) + ")");
    }
    if (kw == "strokes") {
      FieldReader f(file, r, {"path"});
      s.strokesPath = resolveRelative(file.path, f.word(0));
      s.strokesLine = r.line;
      haveStrokes = true;
    } else if (kw == "workspace") {
      FieldReader f(file, r, {"cx", "cy", "cz", "size"});
      s.workspaceCenter = Vec3(f.number(0), f.number(1), f.number(2));
      s.workspaceSize = f.positive(3);
      if (s.workspaceSize > 1000.0) f.fail(3, "must be <= 1000 m (got " + f.word(3) + ")");
    } else if (kw == "solver") {
      FieldReader f(file, r, {"name"});
      if (!parseSolverKind(f.word(0), s.solver)) f.fail(0, "unknown solver '" + f.word(0) + "' (known: pbd, mpm)");
      s.solverLine = r.line;
    } else if (kw == "dt") {
      FieldReader f(file, r, {"seconds"});
      s.dt = f.positive(0);
      if (s.dt > 0.1) f.fail(0, "must be <= 0.1 s (got " + f.word(0) + ")");
      dtLine = r.line;
    } else if (kw == "substeps") {
      FieldReader f(file, r, {"count"});
      s.substepsLine = r.line;
      if (f.word(0) == "auto") s.substepsAuto = true;
      else s.substeps = static_cast<int>(f.integer(0, 1, 1000));
    } else if (kw == "iterations") {
      FieldReader f(file, r, {"count"});
      s.iterations = static_cast<int>(f.integer(0, 1, 1000));
    } else if (kw == "gravity") {
      FieldReader f(file, r, {"gx", "gy", "gz"});
      s.gravity = Vec3(f.inRange(0, -1000, 1000), f.inRange(1, -1000, 1000), f.inRange(2, -1000, 1000));
    } else if (kw == "walls") {
      // walls KIND [SIDE=KIND ...]: every wall KIND, then per side (x-, x+, y-, y+, z-, z+).
      if (r.tokens.size() < 2) throw InputError(file.path, r.line, "kind", "missing (walls KIND [SIDE=KIND ...])");
      const auto wallKind = [&](const std::string& w, const char* field, SceneDesc::Wall& out) {
        if (w == "sticky") out = SceneDesc::Wall::kSticky;
        else if (w == "slip") out = SceneDesc::Wall::kSlip;
        else if (w == "separate") out = SceneDesc::Wall::kSeparate;
        else throw InputError(file.path, r.line, field, "unknown wall kind '" + w + "' (known: sticky, slip, separate)");
      };
      SceneDesc::Wall all;
      wallKind(r.tokens[1], "kind", all);
      for (auto& w : s.walls) w = all;
      static const char* kSides[6] = {"x-", "x+", "y-", "y+", "z-", "z+"};
      bool given[6] = {false, false, false, false, false, false};
      for (std::size_t k = 2; k < r.tokens.size(); ++k) {
        const std::string& w = r.tokens[k];
        const std::size_t eq = w.find('=');
        const std::string side = w.substr(0, eq);
        const int at = int(std::find_if(std::begin(kSides), std::end(kSides), [&](const char* x) { return side == x; }) -
                           std::begin(kSides));
        if (eq == std::string::npos || at == 6)
          throw InputError(file.path, r.line, "side", "'" + w + "' is not SIDE=KIND with SIDE one of x-, x+, y-, y+, z-, z+");
        if (given[at]) throw InputError(file.path, r.line, "side", "wall " + side + " given twice");
        given[at] = true;
        wallKind(w.substr(eq + 1), "kind", s.walls[at]);
      }
      s.wallsLine = r.line;
    } else if (kw == "scale") {
      FieldReader f(file, r, {"k"});
      s.scale = f.inRange(0, 1e-3, 1e3);
      s.scaleLine = r.line;
    } else if (kw == "cfl") {
      FieldReader f(file, r, {"C"});
      s.cfl = f.inRange(0, 1e-3, 1.0);
      s.cflLine = r.line;
    } else if (kw == "grid_dx") {
      FieldReader f(file, r, {"spacings"});
      s.gridDx = f.inRange(0, 1.0, 4.0);
      s.gridDxLine = r.line;
    } else if (kw == "particle_shift") {
      FieldReader f(file, r, {"spacings"});
      s.particleShift = f.inRange(0, 0.0, 1.0);
      s.particleShiftLine = r.line;
    } else if (kw == "sleep") {
      // sleep off | sleep on | sleep SPEED [SECONDS]  (SPEED may be `auto`)
      FieldReader f(file, r, {"speed", "seconds"}, 1);
      s.sleepLine = r.line;
      if (f.word(0) == "off" || f.word(0) == "on") {
        if (f.count() > 1) f.fail(1, "'sleep " + f.word(0) + "' takes no seconds (sleep SPEED SECONDS sets both)");
        s.sleep = f.word(0) == "on";
      } else {
        s.sleepSpeed = f.word(0) == "auto" ? 0.0 : f.inRange(0, 1e-6, 10.0);
        if (f.count() > 1) s.sleepTime = f.inRange(1, 1e-3, 3600.0);
      }
    } else if (kw == "warm_start") {
      // warm_start F [AVERAGES]: F in [0, 0.9] (0 = off), AVERAGES 0..8 (default 4)
      FieldReader f(file, r, {"fraction", "averages"}, 1);
      s.warmStartLine = r.line;
      s.warmStart = f.inRange(0, 0.0, 0.9);
      if (f.count() > 1) s.warmSmoothing = static_cast<int>(f.integer(1, 0, 8));
    } else if (kw == "ground") {
      FieldReader f(file, r, {"y"});
      s.groundY = f.number(0);
    } else if (kw == "duration") {
      FieldReader f(file, r, {"seconds"});
      s.duration = f.positive(0);
      if (s.duration > 3600.0) f.fail(0, "must be <= 3600 s (got " + f.word(0) + ")");
    } else if (kw == "fps") {
      FieldReader f(file, r, {"frames_per_second"});
      s.fps = f.positive(0);
      if (s.fps > 1000.0) f.fail(0, "must be <= 1000 (got " + f.word(0) + ")");
      fpsLine = r.line;
    } else if (kw == "material") {
      Material m = parseMaterialRecord(file, r);
      const int prev = findMaterial(s.materials, m.name);
      if (prev >= 0)
        throw InputError(file.path, r.line, "name", "material '" + m.name + "' defined twice (first on line " +
                                                        std::to_string(s.materials[static_cast<std::size_t>(prev)].line) + ")");
      if (s.materials.size() >= 32000) throw InputError(file.path, r.line, "record", "too many materials");
      s.materials.push_back(std::move(m));
    } else if (kw == "collider") {
      bool atGiven = false;
      s.colliders.push_back(parseCollider(file, r, s.colliders, atGiven));
      colliderAtLine.push_back(atGiven ? r.line : 0);
    } else if (kw == "keyframe") {
      parseKeyframe(file, r, s.colliders, keyframeCount);
    } else if (kw == "expect") {
      s.expectations.push_back(parseExpect(file, r, s.expectations));
    } else if (kw == "camera") {
      FieldReader f(file, r, {"ex", "ey", "ez", "tx", "ty", "tz", "fov"});
      s.camera.eye = Vec3(f.number(0), f.number(1), f.number(2));
      s.camera.target = Vec3(f.number(3), f.number(4), f.number(5));
      s.camera.fovYDeg = f.inRange(6, 1.0, 170.0);
      const Vec3 dir = s.camera.target - s.camera.eye;
      if (dir.norm() < 1e-9) f.fail(3, "camera target equals its eye position");
      if (dir.normalized().cross(s.camera.up).norm() < 1e-6) f.fail(3, "camera looks straight up or down (along +y)");
    } else if (kw == "image") {
      FieldReader f(file, r, {"width", "height"});
      s.width = static_cast<int>(f.integer(0, 16, 8192));
      s.height = static_cast<int>(f.integer(1, 16, 8192));
    } else if (kw == "output") {
      FieldReader f(file, r, {"what", "what"}, 1);
      s.writeFrames = s.writeReport = false;
      for (std::size_t i = 0; i < f.count(); ++i) {
        if (f.word(i) == "frames") s.writeFrames = true;
        else if (f.word(i) == "report") s.writeReport = true;
        else f.fail(i, "unknown output '" + f.word(i) + "' (known: frames, report)");
      }
    } else {
      throw InputError(file.path, r.line, "record", "unknown record '" + kw +
                                                  "' (known: strokes workspace solver dt substeps iterations gravity "
                                                  "walls grid_dx particle_shift cfl scale sleep warm_start ground duration fps material collider keyframe expect camera image output)");
    }
  }
  if (!haveStrokes) throw InputError(file.path, 0, "strokes", "missing 'strokes PATH' record");
  if (s.substepsAuto && s.solver != SolverKind::kMpm)
    throw InputError(file.path, s.substepsLine, "count",
                     std::string("'substeps auto' needs solver mpm (this scene runs solver ") + toString(s.solver) +
                         "): give a count, 1-1000");
  for (std::size_t i = 0; i < s.colliders.size(); ++i)
    if (colliderAtLine[i] && !s.colliders[i].keyframes.empty())
      throw InputError(file.path, colliderAtLine[i], "at",
                       "collider '" + s.colliders[i].name + "' has keyframes (line " +
                           std::to_string(s.colliders[i].keyframes.front().line) +
                           "): its position comes from them; drop at=");
  // One frame interval must be a whole number of solver steps, so frames land on step boundaries.
  const double ratio = 1.0 / (s.fps * s.dt);
  if (std::abs(ratio - std::round(ratio)) > 1e-6 * ratio || std::round(ratio) < 1.0)
    throw InputError(file.path, fpsLine ? fpsLine : dtLine, fpsLine ? "frames_per_second" : "seconds",
                     "1/fps must be a whole multiple of dt (1/fps / dt = " + std::to_string(ratio) + ")");
  applyRealWorldScale(s);
  return s;
}

}  // namespace

void MeshCollider::poseAt(double t, Mat3& rotationOut, Vec3& positionOut) const {
  if (keyframes.empty()) {
    rotationOut = rotation;
    positionOut = position;
    return;
  }
  const auto next = std::upper_bound(keyframes.begin(), keyframes.end(), t,
                                     [](double v, const ColliderKeyframe& k) { return v < k.t; });
  if (next == keyframes.begin() || next == keyframes.end()) {
    const ColliderKeyframe& k = next == keyframes.begin() ? keyframes.front() : keyframes.back();
    rotationOut = k.rotation;
    positionOut = k.position;
    return;
  }
  const ColliderKeyframe& a = *(next - 1);
  const ColliderKeyframe& b = *next;
  const double u = (t - a.t) / (b.t - a.t);
  positionOut = (1.0 - u) * a.position + u * b.position;
  rotationOut = Quat(a.rotation).slerp(u, Quat(b.rotation)).toRotationMatrix();
}

const char* toString(Expectation::Kind kind) {
  switch (kind) {
    case Expectation::Kind::kFreefall: return "freefall";
    case Expectation::Kind::kRest: return "rest";
    case Expectation::Kind::kHeight: return "height";
    case Expectation::Kind::kDamBreak: return "dam_break";
    case Expectation::Kind::kRunout: return "runout";
    case Expectation::Kind::kPendulum: return "pendulum";
    case Expectation::Kind::kHydrostatic: return "hydrostatic";
    case Expectation::Kind::kSphere: return "sphere";
    case Expectation::Kind::kViscousSpread: return "viscous_spread";
  }
  return "?";
}

std::string SceneDesc::expectedBodyName(const std::string& field) {
  // Unnamed bodies are called "stroke N" (a space); a record field cannot hold one.
  if (field.rfind("stroke_", 0) == 0) return "stroke " + field.substr(7);
  return field;
}

int SceneDesc::stepsPerFrame() const { return static_cast<int>(std::lround(1.0 / (fps * dt))); }

int SceneDesc::frameCount() const { return static_cast<int>(std::floor(duration * fps + 1e-9)) + 1; }

SceneDesc loadScene(const std::string& path) { return build(readRecordFile(path, "physketch-scene", kSceneVersion)); }

SceneDesc parseScene(const std::string& text, const std::string& path) {
  return build(parseRecordText(text, path, "physketch-scene", kSceneVersion));
}

}  // namespace physketch
