#include "core/scene.h"

#include <cmath>
#include <filesystem>
#include <map>

#include "core/error.h"
#include "core/records.h"

namespace physketch {
namespace {

constexpr int kSceneVersion = 1;

std::string resolveRelative(const std::string& scenePath, const std::string& p) {
  namespace fs = std::filesystem;
  fs::path rel(p);
  if (rel.is_absolute()) return p;
  return (fs::path(scenePath).parent_path() / rel).lexically_normal().string();
}

SceneDesc build(const RecordFile& file) {
  SceneDesc s;
  s.path = file.path;
  std::map<std::string, int> seen;  // keyword -> first line (each may appear once, except material)
  bool haveStrokes = false;
  int dtLine = 0, fpsLine = 0;
  for (const Record& r : file.records) {
    const std::string& kw = r.keyword();
    if (kw != "material") {
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
      if (f.word(0) != "pbd") f.fail(0, "unknown solver '" + f.word(0) + "' (this build has: pbd)");
      s.solver = SolverKind::kPbd;
    } else if (kw == "dt") {
      FieldReader f(file, r, {"seconds"});
      s.dt = f.positive(0);
      if (s.dt > 0.1) f.fail(0, "must be <= 0.1 s (got " + f.word(0) + ")");
      dtLine = r.line;
    } else if (kw == "substeps") {
      FieldReader f(file, r, {"count"});
      s.substeps = static_cast<int>(f.integer(0, 1, 1000));
    } else if (kw == "iterations") {
      FieldReader f(file, r, {"count"});
      s.iterations = static_cast<int>(f.integer(0, 1, 1000));
    } else if (kw == "gravity") {
      FieldReader f(file, r, {"gx", "gy", "gz"});
      s.gravity = Vec3(f.inRange(0, -1000, 1000), f.inRange(1, -1000, 1000), f.inRange(2, -1000, 1000));
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
      FieldReader f(file, r, {"name", "kind", "density", "friction", "r", "g", "b"});
      Material m;
      m.name = f.word(0);
      if (findMaterial(s.materials, m.name) >= 0) f.fail(0, "material '" + m.name + "' defined twice");
      if (!parseMaterialKind(f.word(1), m.kind)) f.fail(1, "unknown material kind '" + f.word(1) + "' (known: rigid)");
      m.density = f.positive(2);
      if (m.density > 1e5) f.fail(2, "must be <= 1e5 kg/m^3 (got " + f.word(2) + ")");
      m.friction = f.inRange(3, 0.0, 2.0);
      for (int c = 0; c < 3; ++c) m.color[c] = static_cast<float>(f.inRange(4 + c, 0.0, 1.0));
      if (s.materials.size() >= 32000) f.failLine("too many materials");
      s.materials.push_back(m);
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
                                                  "ground duration fps material camera image output)");
    }
  }
  if (!haveStrokes) throw InputError(file.path, 0, "strokes", "missing 'strokes PATH' record");
  // One frame interval must be a whole number of solver steps, so frames land on step boundaries.
  const double ratio = 1.0 / (s.fps * s.dt);
  if (std::abs(ratio - std::round(ratio)) > 1e-6 * ratio || std::round(ratio) < 1.0)
    throw InputError(file.path, fpsLine ? fpsLine : dtLine, fpsLine ? "frames_per_second" : "seconds",
                     "1/fps must be a whole multiple of dt (1/fps / dt = " + std::to_string(ratio) + ")");
  return s;
}

}  // namespace

int SceneDesc::stepsPerFrame() const { return static_cast<int>(std::lround(1.0 / (fps * dt))); }

int SceneDesc::frameCount() const { return static_cast<int>(std::floor(duration * fps + 1e-9)) + 1; }

SceneDesc loadScene(const std::string& path) { return build(readRecordFile(path, "physketch-scene", kSceneVersion)); }

SceneDesc parseScene(const std::string& text, const std::string& path) {
  return build(parseRecordText(text, path, "physketch-scene", kSceneVersion));
}

}  // namespace physketch
