#include "sketch/strokes.h"

#include "core/error.h"
#include "core/records.h"

namespace physketch::sketch {
namespace {

constexpr int kStrokeVersion = 1;
constexpr double kMaxBrushSize = 1000.0;  // m; anything bigger is a typo, not a brush

StrokeFile build(const RecordFile& file) {
  StrokeFile out;
  out.path = file.path;
  double lastTime = -1e300;
  int lastTimeLine = 0;
  auto closeStroke = [&]() {
    if (!out.strokes.empty() && out.strokes.back().samples.empty())
      throw InputError(file.path, out.strokes.back().line, "", "stroke has no samples (add 'sample t x y z' lines)");
  };
  for (const Record& r : file.records) {
    const std::string& kw = r.keyword();
    if (kw == "stroke") {
      closeStroke();
      FieldReader f(file, r, {"op", "brush", "size", "material"});
      Stroke s;
      s.id = static_cast<int>(out.strokes.size());
      s.line = r.line;
      if (f.word(0) == "create") s.op = StrokeOp::kCreate;
      else f.fail(0, "unknown operation '" + f.word(0) + "' (this version knows: create)");
      if (f.word(1) == "sphere") s.brush = BrushShape::kSphere;
      else if (f.word(1) == "cube") s.brush = BrushShape::kCube;
      else f.fail(1, "unknown brush shape '" + f.word(1) + "' (known: sphere, cube)");
      s.size = f.positive(2);
      if (s.size > kMaxBrushSize) f.fail(2, "must be <= 1000 m (got " + f.word(2) + ")");
      s.material = f.word(3);
      out.strokes.push_back(std::move(s));
    } else if (kw == "sample") {
      FieldReader f(file, r, {"t", "x", "y", "z"});
      if (out.strokes.empty()) f.failLine("sample before any 'stroke' record");
      Sample smp;
      smp.t = f.nonNegative(0);
      smp.position = Vec3(f.number(1), f.number(2), f.number(3));
      smp.line = r.line;
      Stroke& s = out.strokes.back();
      // Within a stroke time strictly increases (Eq. 6 divides by it); across
      // strokes it never goes back (strokes are replayed in time order).
      if (!s.samples.empty() ? smp.t <= lastTime : smp.t < lastTime)
        f.fail(0, "time " + f.word(0) + " does not increase (previous sample at line " +
                      std::to_string(lastTimeLine) + ")");
      lastTime = smp.t;
      lastTimeLine = r.line;
      s.samples.push_back(smp);
    } else {
      throw InputError(file.path, r.line, "", "unknown record '" + kw + "' (known: stroke, sample)");
    }
  }
  closeStroke();
  return out;
}

}  // namespace

const char* toString(StrokeOp op) {
  switch (op) {
    case StrokeOp::kCreate: return "create";
  }
  return "?";
}

const char* toString(BrushShape shape) {
  switch (shape) {
    case BrushShape::kSphere: return "sphere";
    case BrushShape::kCube: return "cube";
  }
  return "?";
}

StrokeFile loadStrokes(const std::string& path) {
  return build(readRecordFile(path, "physketch-strokes", kStrokeVersion));
}

StrokeFile parseStrokes(const std::string& text, const std::string& path) {
  return build(parseRecordText(text, path, "physketch-strokes", kStrokeVersion));
}

}  // namespace physketch::sketch
