// Sketching while the simulation runs (Phys-Sketch lets the user keep sketching
// while bodies move): applies the sketch's RuntimeOps to the solver at the steps
// they fall in. Lives in the app because it is the one place that knows both the
// sketch and the solver; it talks to the solver only through core/solver.h.
#pragma once

#include <vector>

#include "core/solver.h"
#include "sketch/voxelize.h"

namespace physketch::app {

// Each tool gets a material of its own, appended to `materials` (after the scene's, so no
// index the scene or the sketch uses moves): a rigid material named "tool N" (N its
// operation) with the stroke's friction= for static and dynamic friction, else the rigid
// defaults (0.5), and its particles take it. PBD contacts use the mean of the two sides'
// coefficients (pbd/world.cpp), so a contact of the tool uses the mean of friction= and the
// touching material's. Call before the solver is made; tools render grey.
void addToolMaterials(std::vector<Material>& materials, sketch::Sketch& sketch);

class RuntimeDriver {
 public:
  struct OpStats {
    bool started = false, finished = false;
    int body = -1;               // create: the body it made; tool: its kinematic body
    std::vector<int> grabbed;    // move: bodies it carries
    std::vector<BodyMode> modes; // move: each grabbed body's mode before it was grabbed
    std::int64_t removed = 0;    // remove: particles it removed
  };

  // `sketch` and `solver` must outlive the driver; the solver starts with the sketch's particles.
  RuntimeDriver(const sketch::Sketch& sketch, Solver& solver);

  // Applies everything that happens during the next step, [t, t + dt) with t the
  // solver's time. Returns the bodies created or reshaped (they need new meshes).
  std::vector<int> beforeStep();

  // Rest cell of every particle (sketch cells, then the cells of runtime creates).
  const std::vector<Vec3i>& restCells() const { return restCells_; }
  const std::vector<OpStats>& stats() const { return stats_; }

 private:
  void driveTool(std::size_t k, double t0, double t1, std::vector<int>& reshaped);
  Vec3 brushAt(const sketch::RuntimeOp& op, double t) const;
  std::vector<std::int32_t> particlesInCells(const std::vector<Vec3i>& cells) const;

  const sketch::Sketch& sketch_;
  Solver& solver_;
  std::vector<Vec3i> restCells_;
  std::vector<OpStats> stats_;
  std::vector<std::size_t> nextRemoval_;
  std::vector<std::vector<Vec3>> grabCentre_;  // per op: each grabbed body's centre when grabbed
};

}  // namespace physketch::app
