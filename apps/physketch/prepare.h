// Everything that comes from input files, fully validated before any output is written.
#pragma once

#include <functional>
#include <memory>
#include <string>

#include "core/scene.h"
#include "core/triangle_soup.h"
#include "core/solver.h"
#include "core/support.h"
#include "sketch/voxelize.h"

namespace physketch::app {

struct Prepared {
  SceneDesc scene;
  sketch::StrokeFile strokes;
  std::unique_ptr<sketch::Sketch> sketch;
  // One triangle soup per scene collider, in the scene's order (read and checked by prepare).
  std::vector<TriangleSoup> colliderMeshes;
  // prepare(..., forLint): what the scene's solver does not simulate yet (the error `run`
  // gives), or empty.
  std::string notYet;
};

// What each solver simulates today (core/support.h): anything else a scene asks for is
// an error at load time naming the record, never silently ignored.
SolverSupport supportOf(SolverKind solver);

// Loads the scene and its stroke file, checks that its solver simulates everything they
// ask for, and voxelizes the sketch. Throws InputError
// (file:line:field) for anything wrong in either file.
// `threads`: for voxelizing (0 = every core); the sketch does not depend on it.
// `forLint`: a kind or feature the solver will simulate but does not yet (a rope under pbd
// before the PBD issue lands) is not an error but recorded in Prepared::notYet, so a sketch
// can be checked before its solver is complete; what the solver never simulates (sand
// under pbd) stays an error.
// `adjust`: changes the scene before the stroke file is read and voxelized (physketch study's
// knobs); it may throw InputError.
Prepared prepare(const std::string& scenePath, int threads = 0, bool forLint = false,
                 const std::function<void(SceneDesc&)>& adjust = {});

// The solver the scene asks for (`solver` record), started on the sketch's particles
// and bodies. Throws InputError naming the scene's line when that solver cannot run it.
std::unique_ptr<Solver> makeSolver(const Prepared& p);

}  // namespace physketch::app
