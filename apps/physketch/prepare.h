// Everything that comes from input files, fully validated before any output is written.
#pragma once

#include <memory>
#include <string>

#include "core/scene.h"
#include "core/solver.h"
#include "sketch/voxelize.h"

namespace physketch::app {

struct Prepared {
  SceneDesc scene;
  sketch::StrokeFile strokes;
  std::unique_ptr<sketch::Sketch> sketch;
};

// Loads the scene and its stroke file and voxelizes the sketch. Throws InputError
// (file:line:field) for anything wrong in either file.
Prepared prepare(const std::string& scenePath);

// The solver the scene asks for (`solver` record), started on the sketch's particles
// and bodies. Throws InputError naming the scene's line when that solver cannot run it.
std::unique_ptr<Solver> makeSolver(const Prepared& p);

}  // namespace physketch::app
