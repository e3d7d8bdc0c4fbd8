// Lint: what a sketch does that its author may not have meant (docs/formats.md,
// "Lint warnings"). Warnings only; errors are thrown while voxelizing.
#pragma once

#include <vector>

#include "core/material.h"
#include "sketch/bodies.h"
#include "sketch/strokes.h"
#include "sketch/voxelize.h"

namespace physketch::sketch {

// Appends the sketch's warnings to sk.warnings ("file:line: text" where a line is meant).
// Needs the finished sketch: operations, bodies and runtime operations.
void lint(const StrokeFile& file, const std::vector<Material>& materials, const std::vector<CutBody>& cuts, Sketch& sk);

}  // namespace physketch::sketch
