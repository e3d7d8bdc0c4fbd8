// Stroke file v1 (docs/formats.md): what the artist drew.
//
//   physketch-strokes 1
//   stroke create sphere 0.06 wood     # op brush size(m) material
//   sample 0.00  -0.2 0.4 0.0          # t(s) x y z (m)
//   sample 0.05   0.2 0.4 0.0
#pragma once

#include <string>
#include <vector>

#include "core/math.h"

namespace physketch::sketch {

enum class StrokeOp { kCreate };
enum class BrushShape { kSphere, kCube };
const char* toString(StrokeOp op);
const char* toString(BrushShape shape);

struct Sample {
  double t = 0.0;  // s, absolute time of the sketching session
  Vec3 position;   // m, world frame
  int line = 0;    // line in the stroke file
};

struct Stroke {
  int id = 0;      // 0-based order in the file
  int line = 0;    // line of the 'stroke' record
  StrokeOp op = StrokeOp::kCreate;
  BrushShape brush = BrushShape::kSphere;
  double size = 0.0;      // m: sphere diameter or cube edge
  std::string material;   // resolved against the scene's materials when voxelized
  std::vector<Sample> samples;
};

struct StrokeFile {
  std::string path;
  std::vector<Stroke> strokes;
};

// Parses a stroke file. Throws InputError (file:line:field) on any bad record:
// unknown record, missing/extra field, non-finite or non-positive size, a sample
// before any stroke, a stroke without samples, times that do not increase.
StrokeFile loadStrokes(const std::string& path);
StrokeFile parseStrokes(const std::string& text, const std::string& path);

}  // namespace physketch::sketch
