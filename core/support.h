// What a solver simulates today, and the load-time check that a scene asks for nothing
// more: a kind, a parameter or a feature the chosen solver does not simulate (yet) is an
// error naming file:line:field, never silently ignored (docs/formats.md, "Solvers").
#pragma once

#include <string>
#include <vector>

#include "core/material.h"
#include "core/scene.h"

namespace physketch {

// Where the sketch first uses something: file, line and field (line 0: not used).
struct FirstUse {
  std::string file;
  int line = 0;
  std::string field;
  bool used() const { return line > 0; }
};

struct MaterialUse {
  std::string material;  // a material name as the stroke file gives it
  FirstUse at;
};

// What a stroke file uses, for checkSupport (sketch::usesOf builds it from a StrokeFile:
// operations in effect after undo/redo only).
struct SketchUses {
  std::vector<MaterialUse> materials;  // each name once, at its first use, in first-use order
  FirstUse toolStroke;                 // a `stroke tool`
  FirstUse velocity;                   // vel= or spin= on a create operation
  FirstUse fixedBody;                  // the `fixed` flag
};

// The kinds and features one solver simulates now. The app fills one per solver (today:
// pbd = rigid with vel/spin/fixed; mpm = nothing yet) and widens it as the solvers grow.
struct SolverSupport {
  SolverKind solver = SolverKind::kPbd;
  std::vector<MaterialKind> kinds;  // kinds as run (solverModel's runsAs)
  bool meshColliders = false;       // scene `collider` records
  bool toolStrokes = false;         // `stroke tool`
  bool initialMotion = false;       // vel= and spin=
  bool fixedBodies = false;         // the `fixed` flag
  bool domainGrid = false;          // scene `walls` and `grid_dx` (a background grid in a walled domain)
  bool sleeping = false;            // scene `sleep` (rigid bodies at rest stop being simulated)
  bool fluidWarmStart = false;      // scene `warm_start` (PBF's multipliers carried between substeps)
  // Material parameters the solver's kinds have in the table but the solver does not
  // simulate yet: setting one is an error naming it, never silently ignored.
  std::vector<std::string> paramsNotYet;
  bool simulates(MaterialKind kind) const;
};

// Throws InputError for the first thing `uses` or `scene` asks of `support.solver` that it
// does not give, in this order: a material the scene does not define; a kind the solver
// never simulates (naming the solver that does); a parameter the solver does not use; a
// kind it does not simulate yet; mesh colliders; tool strokes; vel/spin; fixed. Material
// errors name the material's scene line and field and say where it is first used.
// Precondition: support.solver == scene.solver (std::invalid_argument otherwise).
void checkSupport(const SceneDesc& scene, const SketchUses& uses, const SolverSupport& support);

}  // namespace physketch
