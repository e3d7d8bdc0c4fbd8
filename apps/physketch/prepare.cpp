#include "apps/physketch/prepare.h"
#include "apps/physketch/runtime.h"

#include <cmath>
#include <fstream>
#include <iostream>
#include <sstream>

#include "core/error.h"
#include "core/material_table.h"
#include "sketch/mesh_stamp.h"
#include "mpm/world.h"
#include "pbd/world.h"

namespace physketch::app {

SolverSupport supportOf(SolverKind solver) {
  SolverSupport s;
  s.solver = solver;
  switch (solver) {
    case SolverKind::kPbd:
      // soft and elastic run as soft bodies (clustered shape matching), fluid as PBF,
      // rope and cloth as XPBD links along the sketch's chains and lattices.
      s.kinds = {MaterialKind::kRigid, MaterialKind::kSoft, MaterialKind::kFluid, MaterialKind::kRope,
                 MaterialKind::kCloth};
      s.initialMotion = true;
      s.fixedBodies = true;
      s.meshColliders = true;
      s.toolStrokes = true;  // kinematic bodies driven by the RuntimeDriver
      s.sleeping = true;
      s.fluidWarmStart = true;
      break;
    case SolverKind::kMpm:
      // Kinds as run (solverModel): rigid and soft run as elastic.
      s.kinds = {MaterialKind::kElastic, MaterialKind::kFluid, MaterialKind::kSand, MaterialKind::kSnow,
                 MaterialKind::kPlasticine};
      s.initialMotion = true;
      s.fixedBodies = true;
      s.domainGrid = true;
      s.meshColliders = true;  // distance fields on the grid (mpm/collider_sdf.h)
      s.toolStrokes = true;    // kinematic bodies: their particles hold the nodes of their stencils
      break;
  }
  return s;
}

namespace {

// Everything a solver simulates once complete: every kind solverModel gives it, every feature.
SolverSupport eventualSupportOf(SolverKind solver) {
  SolverSupport s;
  s.solver = solver;
  for (int k = 0; k < kMaterialKindCount; ++k) {
    const SolverModel model = solverModel(static_cast<MaterialKind>(k), solver);
    if (model.simulated) s.kinds.push_back(model.runsAs);
  }
  s.meshColliders = s.toolStrokes = s.initialMotion = s.fixedBodies = true;
  s.domainGrid = solver == SolverKind::kMpm;  // PBD has neither walls nor a grid, now or later
  s.sleeping = solver == SolverKind::kPbd;    // MPM has no bodies to put to sleep
  s.fluidWarmStart = solver == SolverKind::kPbd;  // MPM's fluid is explicit: nothing to carry
  return s;
}

}  // namespace

Prepared prepare(const std::string& scenePath, int threads, bool forLint,
                 const std::function<void(SceneDesc&)>& adjust) {
  Prepared p;
  p.scene = loadScene(scenePath);
  if (adjust) adjust(p.scene);
  // A stroke file that cannot be opened is the scene's error (its 'strokes' line).
  if (!std::ifstream(p.scene.strokesPath))
    throw InputError(p.scene.path, p.scene.strokesLine, "path", "cannot open stroke file '" + p.scene.strokesPath + "'");
  p.strokes = sketch::loadStrokes(p.scene.strokesPath);
  const SketchUses uses = sketch::usesOf(p.strokes);
  try {
    checkSupport(p.scene, uses, supportOf(p.scene.solver));
  } catch (const InputError& e) {
    if (!forLint) throw;
    checkSupport(p.scene, uses, eventualSupportOf(p.scene.solver));  // never simulated: still an error
    p.notYet = e.what();
  }
  const sketch::GridMapping mapping(p.scene.workspaceCenter, p.scene.workspaceSize);
  p.sketch = std::make_unique<sketch::Sketch>(sketch::voxelize(p.strokes, mapping, p.scene.materials, {threads}));
  addToolMaterials(p.scene.materials, *p.sketch);
  for (const MeshCollider& c : p.scene.colliders) {
    try {
      p.colliderMeshes.push_back(sketch::readTriangleSoup(c.path));
    } catch (const InputError& e) {
      throw InputError(p.scene.path, c.line, "path", "collider '" + c.name + "': " + e.what());
    }
  }
  return p;
}

namespace {

// The MPM world on the sketch's particles (one particle per voxel, grid spacing 2 h). A time
// step the explicit bound cannot meet within 1000 substeps is the scene's error, naming the
// material; a fixed substep count above the bound is a warning naming bound and material.
std::unique_ptr<Solver> makeMpm(const Prepared& p) {
  const SceneDesc& sc = p.scene;
  auto world = std::make_unique<mpm::MpmWorld>(p.sketch->particles, p.sketch->bodies, sc.materials,
                                               mpm::paramsFromScene(sc, p.sketch->mapping.voxelSize()));
  const mpm::StepBound b = world->waveBound();
  if (b.material >= 0 && sc.dt / b.h > mpm::MpmWorld::kMaxSubsteps + 1e-9) {
    const Material& m = sc.materials[static_cast<std::size_t>(b.material)];
    std::ostringstream os;  // %g-style: std::to_string printed the bound 2e-7 s as 0.000000
    os << "material '" << m.name << "' needs " << long(std::ceil(sc.dt / b.h)) << " MPM substeps per step of dt = " << sc.dt
       << " s (h <= C dx / c_p = " << b.h << " s, c_p = " << b.waveSpeed << " m/s), more than 1000: lower dt or the material's E";
    throw InputError(sc.path, m.line, "kind", os.str());
  }
  // The scene's 'substeps' line, or the file alone where it has none (the default of 4 applies).
  const std::string where = sc.path + (sc.substepsLine > 0 ? ":" + std::to_string(sc.substepsLine) : std::string());
  for (const std::string& w : world->warnings()) std::cerr << "warning: " << where << ": " << w << "\n";
  if (!sc.colliders.empty()) {
    const std::vector<std::string> notes = world->setColliders(sc.colliders, p.colliderMeshes);
    for (std::size_t c = 0; c < notes.size(); ++c)
      if (!notes[c].empty()) std::cerr << "warning: " << sc.path << ":" << sc.colliders[c].line << ": " << notes[c] << "\n";
  }
  return world;
}

}  // namespace

std::unique_ptr<Solver> makeSolver(const Prepared& p) {
  const SceneDesc& sc = p.scene;
  switch (sc.solver) {
    case SolverKind::kPbd: {
      auto world = std::make_unique<pbd::PbdWorld>(p.sketch->particles, p.sketch->bodies, sc.materials,
                                                   pbd::paramsFromScene(sc, 0.5 * p.sketch->mapping.voxelSize()));
      if (!sc.colliders.empty()) world->setColliders(pbd::ColliderSet(sc.colliders, p.colliderMeshes));
      return world;
    }
    case SolverKind::kMpm: return makeMpm(p);
  }
  throw InputError(sc.path, sc.solverLine, "name", std::string("solver ") + toString(sc.solver) + " is not available");
}

}  // namespace physketch::app
