#include "sketch/strokes.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>

#include "core/error.h"
#include "core/records.h"

namespace physketch::sketch {
namespace {

constexpr int kStrokeVersion = 1;
constexpr double kMaxSize = 1000.0;  // m; anything bigger is a typo, not a brush
constexpr double kMaxSpeed = 1000.0;  // m/s, |vel=|
constexpr double kMaxSpin = 1e4;      // rad/s, |spin=|

// vel=, spin= and fixed as one create record gives them.
struct Motion {
  std::optional<Vec3> velocity, spin;
  bool fixed = false;
};

Vec3 snapTo(const Vec3& p, double step) {
  if (step <= 0.0) return p;
  return Vec3(std::round(p.x() / step) * step, std::round(p.y() / step) * step, std::round(p.z() / step) * step);
}

double sizeField(const FieldReader& r, std::size_t i) {
  const double v = r.positive(i);
  if (v > kMaxSize) r.fail(i, "must be <= 1000 m (got " + r.word(i) + ")");
  return v;
}

class Parser {
 public:
  explicit Parser(const RecordFile& f) : f_(f) { out_.path = f.path; }

  StrokeFile run() {
    for (const Record& r : f_.records) record(r);
    closeStroke();
    mergeBodyMotion();
    checkToolsAfterPlay();
    return std::move(out_);
  }

 private:
  void record(const Record& r) {
    const std::string& kw = r.keyword();
    static const char* const kKnown[] = {"stroke", "sample", "primitive", "stamp", "mirror",
                                         "snap",   "undo",   "redo",      "play"};
    if (std::find(std::begin(kKnown), std::end(kKnown), kw) == std::end(kKnown))
      throw InputError(f_.path, r.line, "record",
                       "unknown record '" + kw + "' (known: stroke, sample, primitive, stamp, mirror, snap, undo, redo, play)");
    if (kw != "sample") closeStroke();
    if (kw == "stroke") stroke(r);
    else if (kw == "sample") sample(r);
    else if (kw == "primitive") primitive(r);
    else if (kw == "stamp") stamp(r);
    else if (kw == "mirror") mirror(r);
    else if (kw == "snap") snap(r);
    else if (kw == "undo" || kw == "redo") undoRedo(r);
    else play(r);
  }

  // Time checks: never back in time across the file.
  void checkTime(const FieldReader& fr, std::size_t i, double t, bool strictly) {
    if (strictly ? t <= lastTime_ : t < lastTime_)
      fr.fail(i, "time " + fr.word(i) + " does not increase (previous time " + std::to_string(lastTime_) +
                     " on line " + std::to_string(lastTimeLine_) + ")");
    lastTime_ = t;
    lastTimeLine_ = fr.line();
  }

  Operation& begin(Operation::Kind kind, const Record& r, const std::string& material, const std::string& body) {
    Operation op;
    op.kind = kind;
    op.id = static_cast<int>(out_.operations.size());
    op.line = r.line;
    op.material = material;
    op.body = body;
    op.mirror = mirror_;
    out_.operations.push_back(std::move(op));
    // A new operation ends the redo history, as in every editor.
    redo_.clear();
    out_.active.push_back(out_.operations.back().id);
    return out_.operations.back();
  }

  // vel=, spin=, fixed: only create operations make bodies, and a fixed body does not move.
  Motion motion(const Record& r, const std::vector<RecordOption>& opts, bool creates, const std::string& what) const {
    Motion m;
    for (const auto& o : opts) {
      if (o.key != "vel" && o.key != "spin" && o.key != "fixed") continue;
      if (!creates)
        throw InputError(f_.path, r.line, o.key,
                         "only create operations make bodies: '" + what + "' takes no " + (o.flag ? o.key : o.key + "="));
      if (o.key == "vel") m.velocity = parseVec3(f_, r.line, "vel", o.value, kMaxSpeed);
      else if (o.key == "spin") m.spin = parseVec3(f_, r.line, "spin", o.value, kMaxSpin);
      else m.fixed = true;
    }
    if (m.fixed && (m.velocity || m.spin))
      throw InputError(f_.path, r.line, m.velocity ? "vel" : "spin",
                       "a fixed body does not move: give vel= and spin=, or fixed, not both");
    return m;
  }

  static void setMotion(Operation& op, const Motion& m) {
    op.velocity = m.velocity;
    op.spin = m.spin;
    op.fixed = m.fixed;
    op.written.velocity = m.velocity.has_value();
    op.written.spin = m.spin.has_value();
    op.written.fixed = m.fixed;
  }

  void stroke(const Record& r) {
    Record pos;
    const auto opts =
        splitOptions(f_, r, pos, {"orient", "axis", "length", "body", "vel", "spin", "friction"}, {"fixed"});
    FieldReader fr(f_, pos, {"op", "brush", "size", "material"}, 3);
    StrokeOp op;
    if (fr.word(0) == "create") op = StrokeOp::kCreate;
    else if (fr.word(0) == "remove") op = StrokeOp::kRemove;
    else if (fr.word(0) == "move") op = StrokeOp::kMove;
    else if (fr.word(0) == "tool") op = StrokeOp::kTool;
    else fr.fail(0, "unknown operation '" + fr.word(0) + "' (known: create, remove, move, tool)");
    Stroke s;
    s.op = op;
    const std::string& b = fr.word(1);
    if (b == "sphere") s.brush = BrushShape::kSphere;
    else if (b == "cube") s.brush = BrushShape::kCube;
    else if (b == "cylinder") s.brush = BrushShape::kCylinder;
    else if (b == "disc") s.brush = BrushShape::kDisc;
    else if (b == "capsule") s.brush = BrushShape::kCapsule;
    else fr.fail(1, "unknown brush shape '" + b + "' (known: sphere, cube, cylinder, disc, capsule)");
    s.size = sizeField(fr, 2);
    std::string material;
    if (op == StrokeOp::kCreate) {
      if (fr.count() < 4) fr.fail(3, "missing (create needs a material)");
      material = fr.word(3);
    } else if (fr.count() > 3) {
      fr.fail(3, std::string("'") + toString(op) + "' takes no material (got '" + fr.word(3) + "')");
    }
    std::string body;
    for (const auto& o : opts) {
      if (o.key == "orient") {
        if (o.value == "fixed") s.orient = Orientation::kFixed;
        else if (o.value == "follow") s.orient = Orientation::kFollow;
        else throw InputError(f_.path, r.line, "orient", "must be 'fixed' or 'follow' (got '" + o.value + "')");
      } else if (o.key == "axis") {
        const auto v = parseNumberList(f_, r.line, "axis", o.value, 3);
        const Vec3 a(v[0], v[1], v[2]);
        if (a.norm() < 1e-12) throw InputError(f_.path, r.line, "axis", "axis is zero");
        s.axis = a.normalized();
      } else if (o.key == "length") {
        const auto v = parseNumberList(f_, r.line, "length", o.value, 1);
        if (!(v[0] > 0) || v[0] > kMaxSize)
          throw InputError(f_.path, r.line, "length", "must be in (0, 1000] m (got " + o.value + ")");
        s.length = v[0];
      } else if (o.key == "body") {
        if (op != StrokeOp::kCreate) throw InputError(f_.path, r.line, "body", "only 'create' strokes belong to a body");
        body = o.value;
      } else if (o.key == "friction") {
        if (op != StrokeOp::kTool)
          throw InputError(f_.path, r.line, "friction",
                           "only tool strokes take friction= (a material's friction is set in the scene)");
        const double mu = parseNumberList(f_, r.line, "friction", o.value, 1)[0];
        if (!(mu >= 0 && mu <= 2)) throw InputError(f_.path, r.line, "friction", "must be in [0, 2] (got " + o.value + ")");
        s.toolFriction = mu;
      }
    }
    const Motion m = motion(r, opts, op == StrokeOp::kCreate, std::string("stroke ") + toString(op));
    Operation& o = begin(Operation::Kind::kStroke, r, material, body);
    o.stroke = s;
    setMotion(o, m);
    openStroke_ = true;
  }

  void sample(const Record& r) {
    FieldReader fr(f_, r, {"t", "x", "y", "z", "pressure"}, 4);
    if (!openStroke_) fr.failLine("sample outside a stroke (samples follow a 'stroke' record)");
    Operation& op = out_.operations.back();
    Sample smp;
    smp.t = fr.nonNegative(0);
    checkTime(fr, 0, smp.t, !op.stroke.samples.empty());
    smp.position = snapTo(Vec3(fr.number(1), fr.number(2), fr.number(3)), snap_);
    if (fr.count() == 5) {
      smp.pressure = fr.number(4);
      if (!(smp.pressure > 0.0 && smp.pressure <= 1.0)) fr.fail(4, "must be in (0, 1] (got " + fr.word(4) + ")");
    }
    smp.line = r.line;
    op.stroke.samples.push_back(smp);
  }

  void closeStroke() {
    if (openStroke_ && out_.operations.back().stroke.samples.empty())
      throw InputError(f_.path, out_.operations.back().line, "samples",
                       "stroke has no samples (add 'sample t x y z' lines after it)");
    openStroke_ = false;
  }

  void primitive(const Record& r) {
    Record pos;
    const auto opts = splitOptions(f_, r, pos, {"rot", "body", "vel", "spin"}, {"fixed"});
    if (pos.tokens.size() < 2) FieldReader(f_, pos, {"kind"});
    const std::string& kind = pos.tokens[1];
    Primitive p;
    std::vector<std::string> dimNames;
    if (kind == "box") { p.kind = PrimitiveKind::kBox; dimNames = {"sx", "sy", "sz"}; }
    else if (kind == "sphere") { p.kind = PrimitiveKind::kSphere; dimNames = {"radius"}; }
    else if (kind == "ellipsoid") { p.kind = PrimitiveKind::kEllipsoid; dimNames = {"rx", "ry", "rz"}; }
    else if (kind == "cylinder") { p.kind = PrimitiveKind::kCylinder; dimNames = {"radius", "length"}; }
    else if (kind == "capsule") { p.kind = PrimitiveKind::kCapsule; dimNames = {"radius", "length"}; }
    else if (kind == "torus") { p.kind = PrimitiveKind::kTorus; dimNames = {"major_radius", "minor_radius"}; }
    else throw InputError(f_.path, r.line, "kind", "unknown primitive '" + kind + "' (known: box, sphere, ellipsoid, cylinder, capsule, torus)");
    // Schema: kind material t cx cy cz dims...
    static const char* const kNames[] = {"kind", "material", "t", "cx", "cy", "cz"};
    std::vector<std::string> names(std::begin(kNames), std::end(kNames));
    names.insert(names.end(), dimNames.begin(), dimNames.end());
    FieldReader fr(f_, pos, names);
    p.t = fr.nonNegative(2);
    checkTime(fr, 2, p.t, false);
    p.centre = snapTo(Vec3(fr.number(3), fr.number(4), fr.number(5)), snap_);
    for (std::size_t i = 0; i < dimNames.size(); ++i) p.dims[static_cast<int>(i)] = sizeField(fr, 6 + i);
    if (p.kind == PrimitiveKind::kTorus && !(p.dims[1] < p.dims[0]))
      fr.fail(7, "minor radius must be smaller than the major radius");
    std::string body;
    for (const auto& o : opts) {
      if (o.key == "rot") p.rotation = parseRotation(f_, r.line, "rot", o.value);
      else if (o.key == "body") body = o.value;
    }
    const Motion m = motion(r, opts, true, "primitive");
    Operation& op = begin(Operation::Kind::kPrimitive, r, fr.word(1), body);
    op.primitive = p;
    setMotion(op, m);
  }

  void stamp(const Record& r) {
    Record pos;
    const auto opts = splitOptions(f_, r, pos, {"scale", "rot", "at", "body", "vel", "spin"}, {"fixed"});
    FieldReader fr(f_, pos, {"path", "material", "t"});
    MeshStamp m;
    namespace fs = std::filesystem;
    const fs::path rel(fr.word(0));
    m.path = rel.is_absolute() ? rel.string() : (fs::path(f_.path).parent_path() / rel).lexically_normal().string();
    m.t = fr.nonNegative(2);
    checkTime(fr, 2, m.t, false);
    std::string body;
    for (const auto& o : opts) {
      if (o.key == "scale") {
        m.scale = parseNumberList(f_, r.line, "scale", o.value, 1)[0];
        if (!(m.scale > 0) || m.scale > kMaxSize)
          throw InputError(f_.path, r.line, "scale", "must be in (0, 1000] (got " + o.value + ")");
      } else if (o.key == "rot") {
        m.rotation = parseRotation(f_, r.line, "rot", o.value);
      } else if (o.key == "at") {
        const auto v = parseNumberList(f_, r.line, "at", o.value, 3);
        m.translation = snapTo(Vec3(v[0], v[1], v[2]), snap_);
      } else if (o.key == "body") {
        body = o.value;
      }
    }
    const Motion mo = motion(r, opts, true, "stamp");
    Operation& op = begin(Operation::Kind::kStamp, r, fr.word(1), body);
    op.stamp = m;
    setMotion(op, mo);
  }

  void mirror(const Record& r) {
    FieldReader fr(f_, r, {"axis", "offset"}, 1);
    const std::string& a = fr.word(0);
    if (a == "off") {
      if (fr.count() > 1) fr.fail(1, "'mirror off' takes no offset");
      mirror_ = Mirror{};
      return;
    }
    Mirror m;
    if (a == "x") m.axis = 0;
    else if (a == "y") m.axis = 1;
    else if (a == "z") m.axis = 2;
    else fr.fail(0, "must be x, y, z or off (got '" + a + "')");
    m.offset = fr.count() > 1 ? fr.number(1) : 0.0;
    m.line = r.line;
    mirror_ = m;
  }

  void snap(const Record& r) {
    FieldReader fr(f_, r, {"step"});
    if (fr.word(0) == "off") {
      snap_ = 0.0;
      return;
    }
    snap_ = sizeField(fr, 0);
  }

  void undoRedo(const Record& r) {
    FieldReader fr(f_, r, {"count"}, 0);
    const long n = fr.count() ? fr.integer(0, 1, 1000000) : 1;
    for (long i = 0; i < n; ++i) {
      if (r.keyword() == "undo") {
        if (out_.active.empty())
          fr.fail(0, "undo past the beginning (only " + std::to_string(i) + " operation(s) to undo)");
        redo_.push_back(out_.active.back());
        out_.active.pop_back();
      } else {
        if (redo_.empty()) fr.fail(0, "nothing to redo (only " + std::to_string(i) + " undone operation(s) left)");
        out_.active.push_back(redo_.back());
        redo_.pop_back();
      }
    }
  }

  void play(const Record& r) {
    FieldReader fr(f_, r, {"t"});
    if (out_.play) fr.failLine("'play' given twice (first on line " + std::to_string(out_.playLine) + ")");
    const double t = fr.nonNegative(0);
    checkTime(fr, 0, t, false);
    out_.play = t;
    out_.playLine = r.line;
  }

  // vel=, spin= and fixed describe a whole body: the parts of a named body in effect agree
  // (a value given on one part holds for all), and every part then carries the body's values.
  void mergeBodyMotion() {
    struct Merged {
      const Operation* velocity = nullptr;
      const Operation* spin = nullptr;
      const Operation* fixed = nullptr;
    };
    std::map<std::string, Merged> bodies;
    auto text = [](const Vec3& v) {
      return std::to_string(v.x()) + "," + std::to_string(v.y()) + "," + std::to_string(v.z());
    };
    auto agree = [&](const Operation* first, const Operation& op, const std::optional<Vec3> Operation::*field,
                     const char* key) {
      if (first && *(first->*field) != *(op.*field))
        throw InputError(f_.path, op.line, key,
                         "body '" + op.body + "' already has " + key + "=" + text(*(first->*field)) + " (line " +
                             std::to_string(first->line) + "): give a body's " + key +
                             "= on one of its parts, or the same on each");
    };
    for (int id : out_.active) {
      const Operation& op = out_.operations[static_cast<std::size_t>(id)];
      if (op.body.empty()) continue;
      Merged& b = bodies[op.body];
      if (op.written.velocity) {
        agree(b.velocity, op, &Operation::velocity, "vel");
        if (!b.velocity) b.velocity = &op;
      }
      if (op.written.spin) {
        agree(b.spin, op, &Operation::spin, "spin");
        if (!b.spin) b.spin = &op;
      }
      if (op.written.fixed && !b.fixed) b.fixed = &op;
      const Operation* moving = b.velocity ? b.velocity : b.spin;
      if (b.fixed && moving)
        throw InputError(f_.path, op.line, op.written.fixed ? "fixed" : (op.written.velocity ? "vel" : "spin"),
                         "body '" + op.body + "' is fixed (line " + std::to_string(b.fixed->line) + ") and moves (line " +
                             std::to_string(moving->line) + "): a fixed body does not move");
    }
    for (int id : out_.active) {
      Operation& op = out_.operations[static_cast<std::size_t>(id)];
      if (op.body.empty()) continue;
      const Merged& b = bodies[op.body];
      if (b.velocity) op.velocity = b.velocity->velocity;
      if (b.spin) op.spin = b.spin->spin;
      op.fixed = b.fixed != nullptr;
    }
  }

  // Tools act while the simulation runs: a tool stroke in effect starts at or after play.
  void checkToolsAfterPlay() const {
    const double play = out_.playTime();
    for (int id : out_.active) {
      const Operation& op = out_.operations[static_cast<std::size_t>(id)];
      if (op.kind != Operation::Kind::kStroke || op.stroke.op != StrokeOp::kTool || op.startTime() >= play) continue;
      const Sample& first = op.stroke.samples.front();
      throw InputError(f_.path, first.line, "t",
                       "a tool stroke acts while the simulation runs: this one starts at t = " + std::to_string(first.t) +
                           " s, before play (t = " + std::to_string(play) + " s" +
                           (out_.play ? ", line " + std::to_string(out_.playLine) : std::string(", the end of the sketch")) +
                           ")");
    }
  }

  const RecordFile& f_;
  StrokeFile out_;
  Mirror mirror_;
  double snap_ = 0.0;
  bool openStroke_ = false;
  std::vector<int> redo_;
  double lastTime_ = 0.0;
  int lastTimeLine_ = 0;
};

}  // namespace

const char* toString(StrokeOp op) {
  switch (op) {
    case StrokeOp::kCreate: return "create";
    case StrokeOp::kRemove: return "remove";
    case StrokeOp::kMove: return "move";
    case StrokeOp::kTool: return "tool";
  }
  return "?";
}

const char* toString(BrushShape shape) {
  switch (shape) {
    case BrushShape::kSphere: return "sphere";
    case BrushShape::kCube: return "cube";
    case BrushShape::kCylinder: return "cylinder";
    case BrushShape::kDisc: return "disc";
    case BrushShape::kCapsule: return "capsule";
  }
  return "?";
}

const char* toString(PrimitiveKind kind) {
  switch (kind) {
    case PrimitiveKind::kBox: return "box";
    case PrimitiveKind::kSphere: return "sphere";
    case PrimitiveKind::kEllipsoid: return "ellipsoid";
    case PrimitiveKind::kCylinder: return "cylinder";
    case PrimitiveKind::kCapsule: return "capsule";
    case PrimitiveKind::kTorus: return "torus";
  }
  return "?";
}

double Operation::startTime() const {
  switch (kind) {
    case Kind::kStroke: return stroke.samples.front().t;
    case Kind::kPrimitive: return primitive.t;
    case Kind::kStamp: return stamp.t;
  }
  return 0.0;
}

double Operation::endTime() const {
  return kind == Kind::kStroke ? stroke.samples.back().t : startTime();
}

double StrokeFile::playTime() const {
  if (play) return *play;
  double t = 0.0;
  for (int id : active) {
    const Operation& op = operations[static_cast<std::size_t>(id)];
    if (op.kind == Operation::Kind::kStroke && op.stroke.op == StrokeOp::kTool) continue;
    t = std::max(t, op.endTime());
  }
  return t;
}

SketchUses usesOf(const StrokeFile& file) {
  SketchUses u;
  auto mark = [&](FirstUse& use, const Operation& op, const char* field) {
    if (!use.used()) use = FirstUse{file.path, op.line, field};
  };
  for (int id : file.active) {  // in file order: the first use is the first in the file
    const Operation& op = file.operations[static_cast<std::size_t>(id)];
    const bool isStroke = op.kind == Operation::Kind::kStroke;
    if (!isStroke || op.stroke.op == StrokeOp::kCreate) {
      const bool seen = std::any_of(u.materials.begin(), u.materials.end(),
                                    [&](const MaterialUse& m) { return m.material == op.material; });
      if (!seen) u.materials.push_back({op.material, FirstUse{file.path, op.line, "material"}});
    }
    if (isStroke && op.stroke.op == StrokeOp::kTool) mark(u.toolStroke, op, "op");
    if (op.written.velocity) mark(u.velocity, op, "vel");
    if (op.written.spin) mark(u.velocity, op, "spin");
    if (op.written.fixed) mark(u.fixedBody, op, "fixed");
  }
  return u;
}

StrokeFile loadStrokes(const std::string& path) {
  return Parser(readRecordFile(path, "physketch-strokes", kStrokeVersion)).run();
}

StrokeFile parseStrokes(const std::string& text, const std::string& path) {
  return Parser(parseRecordText(text, path, "physketch-strokes", kStrokeVersion)).run();
}

}  // namespace physketch::sketch
