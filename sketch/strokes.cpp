#include "sketch/strokes.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "core/error.h"
#include "core/records.h"

namespace physketch::sketch {
namespace {

constexpr int kStrokeVersion = 1;
constexpr double kMaxSize = 1000.0;  // m; anything bigger is a typo, not a brush

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

  void stroke(const Record& r) {
    Record pos;
    const auto opts = splitOptions(f_, r, pos, {"orient", "axis", "length", "body"});
    FieldReader fr(f_, pos, {"op", "brush", "size", "material"}, 3);
    StrokeOp op;
    if (fr.word(0) == "create") op = StrokeOp::kCreate;
    else if (fr.word(0) == "remove") op = StrokeOp::kRemove;
    else if (fr.word(0) == "move") op = StrokeOp::kMove;
    else fr.fail(0, "unknown operation '" + fr.word(0) + "' (known: create, remove, move)");
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
      }
    }
    Operation& o = begin(Operation::Kind::kStroke, r, material, body);
    o.stroke = s;
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
    const auto opts = splitOptions(f_, r, pos, {"rot", "body"});
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
    Operation& op = begin(Operation::Kind::kPrimitive, r, fr.word(1), body);
    op.primitive = p;
  }

  void stamp(const Record& r) {
    Record pos;
    const auto opts = splitOptions(f_, r, pos, {"scale", "rot", "at", "body"});
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
    Operation& op = begin(Operation::Kind::kStamp, r, fr.word(1), body);
    op.stamp = m;
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
  for (int id : active) t = std::max(t, operations[static_cast<std::size_t>(id)].endTime());
  return t;
}

StrokeFile loadStrokes(const std::string& path) {
  return Parser(readRecordFile(path, "physketch-strokes", kStrokeVersion)).run();
}

StrokeFile parseStrokes(const std::string& text, const std::string& path) {
  return Parser(parseRecordText(text, path, "physketch-strokes", kStrokeVersion)).run();
}

}  // namespace physketch::sketch
