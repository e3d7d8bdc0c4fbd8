#include "core/support.h"

#include <utility>

#include <stdexcept>

#include "core/error.h"
#include "core/material_table.h"

namespace physketch {
namespace {

std::string where(const FirstUse& u) { return u.file + ":" + std::to_string(u.line); }

// "solver pbd (line 3)" or "solver pbd (the default)": the record the user would change.
std::string solverText(const SceneDesc& scene) {
  return std::string("solver ") + toString(scene.solver) +
         (scene.solverLine > 0 ? " (line " + std::to_string(scene.solverLine) + ")" : " (the default)");
}

void checkMaterial(const SceneDesc& scene, const MaterialUse& use, const SolverSupport& support) {
  const int index = findMaterial(scene.materials, use.material);
  if (index < 0) {
    std::string names;
    for (const Material& m : scene.materials) names += (names.empty() ? "" : ", ") + m.name;
    throw InputError(use.at.file, use.at.line, use.at.field,
                     "unknown material '" + use.material + "' (" + scene.path + " defines: " +
                         (names.empty() ? std::string("none") : names) + ")");
  }
  const Material& m = scene.materials[static_cast<std::size_t>(index)];
  const std::string kind = toString(m.kind);
  const std::string firstUse = " (first used at " + where(use.at) + ")";
  const SolverModel model = solverModel(m.kind, scene.solver);
  if (!model.simulated)
    throw InputError(scene.path, m.line, "kind",
                     "material '" + m.name + "' is kind " + kind + ": " + solverText(scene) + " does not simulate " +
                         kind + "; solver " + toString(model.simulatedBy) + " does" + firstUse);
  for (const std::string& key : m.given) {
    const ParamSpec* spec = findParam(m.kind, key);
    if (spec && !usedBy(spec->solvers, scene.solver))
      throw InputError(scene.path, m.line, key,
                       "material '" + m.name + "': " + kind + " parameter " + key + " is used by solver " +
                           toString(spec->solvers) + " only, and this scene runs " + solverText(scene) +
                           ": drop it or change the solver" + firstUse);
  }
  for (const std::string& key : m.given)
    for (const std::string& notYet : support.paramsNotYet)
      if (key == notYet)
        throw InputError(scene.path, m.line, key,
                         "material '" + m.name + "': solver " + toString(scene.solver) + " does not simulate " + key +
                             " yet; drop it" + firstUse);
  if (!support.simulates(model.runsAs)) {
    const std::string as = model.runsAs == m.kind ? "" : ", which it runs as " + std::string(toString(model.runsAs));
    throw InputError(scene.path, m.line, "kind",
                     "material '" + m.name + "' is kind " + kind + as + ": solver " + toString(scene.solver) +
                         " does not simulate " + toString(model.runsAs) + " yet" + firstUse);
  }
}

void checkFeature(const FirstUse& use, bool supported, const SceneDesc& scene, const std::string& what) {
  if (use.used() && !supported)
    throw InputError(use.file, use.line, use.field,
                     "solver " + std::string(toString(scene.solver)) + " does not simulate " + what + " yet (" +
                         scene.path + " chooses " + solverText(scene) + ")");
}

}  // namespace

bool SolverSupport::simulates(MaterialKind kind) const {
  for (MaterialKind k : kinds)
    if (k == kind) return true;
  return false;
}

void checkSupport(const SceneDesc& scene, const SketchUses& uses, const SolverSupport& support) {
  if (support.solver != scene.solver)
    throw std::invalid_argument(std::string("checkSupport: support set of solver ") + toString(support.solver) +
                                " for a scene that runs " + toString(scene.solver));
  for (const MaterialUse& use : uses.materials) checkMaterial(scene, use, support);
  if (!support.meshColliders && !scene.colliders.empty()) {
    const MeshCollider& c = scene.colliders.front();
    throw InputError(scene.path, c.line, "record",
                     "collider '" + c.name + "': " + solverText(scene) + " does not simulate mesh colliders yet");
  }
  if (!support.domainGrid) {
    // The records only a background grid gives meaning to, the first one given.
    const std::pair<int, const char*> gridRecords[] = {
        {scene.wallsLine, "walls"}, {scene.gridDxLine, "grid_dx"}, {scene.particleShiftLine, "particle_shift"},
        {scene.scaleLine, "scale"},    {scene.cflLine, "cfl"}};
    for (const auto& [line, name] : gridRecords)
      if (line > 0)
        throw InputError(scene.path, line, "record",
                         std::string(name) + ": " + solverText(scene) +
                             " has no domain walls or background grid (the record is for solver mpm)");
  }
  if (!support.sleeping && scene.sleepLine > 0)
    throw InputError(scene.path, scene.sleepLine, "record",
                     "sleep: " + solverText(scene) + " has no bodies to put to sleep (the record is for solver pbd)");
  if (!support.fluidWarmStart && scene.warmStartLine > 0)
    throw InputError(scene.path, scene.warmStartLine, "record",
                     "warm_start: " + solverText(scene) +
                         " has no density multipliers to carry (the record is for solver pbd's fluids)");
  checkFeature(uses.toolStroke, support.toolStrokes, scene, "tool strokes");
  checkFeature(uses.velocity, support.initialMotion, scene, "initial velocities (vel=, spin=)");
  checkFeature(uses.fixedBody, support.fixedBodies, scene, "fixed bodies");
}

}  // namespace physketch
