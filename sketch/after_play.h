// Operations that start after `play` happen while the simulation runs: they become
// RuntimeOps, which the app applies to the solver at their times (docs/formats.md).
#pragma once

#include <optional>
#include <vector>

#include "sketch/operations.h"
#include "sketch/voxelize.h"

namespace physketch::sketch {

// A remove or move stroke after play: the cells under the brush and when, one
// RuntimeOp per mirror copy, appended to `out`. Times are seconds after `play`.
void strokeAfterPlay(const Operation& op, double play, const InputChecks& checks, OperationSummary& sum,
                     std::vector<RuntimeOp>& out);

// Creates after play, voxelized in file order into a grid of their own (the sketch's
// bodies have moved away from their voxels by then), so they never overlap each
// other; each becomes a new body (one RuntimeOp; none when it creates nothing).
// A rope or cloth becomes one body per mirror copy, laid out as before play
// (sketch/strands.h), and takes no cells of that grid.
// Their particles count towards the cap with the sketch's `sketchParticles` (live ones).
class CreatesAfterPlay {
 public:
  CreatesAfterPlay(Footprints& footprints, const InputChecks& checks, std::int64_t sketchParticles)
      : footprints_(footprints), checks_(checks), cells_(sketchParticles) {}
  // Throws CapReached when the cap is crossed.
  void add(const Operation& op, double play, OperationSummary& sum, std::vector<RuntimeOp>& out);

 private:
  void addStrand(const Operation& op, MaterialKind kind, double play, OperationSummary& sum,
                 std::vector<RuntimeOp>& out);

  Footprints& footprints_;
  const InputChecks& checks_;
  NewBodyCells cells_;
};

}  // namespace physketch::sketch
