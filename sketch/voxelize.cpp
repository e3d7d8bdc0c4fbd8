// The sketching stage in order: replay the operations before play (operations.h),
// make the bodies (bodies.h), turn the operations after play into RuntimeOps
// (after_play.h), then lint (lint.h).
#include "sketch/voxelize.h"

#include <algorithm>
#include <string>

#include <tbb/info.h>
#include <tbb/task_arena.h>

#include "core/error.h"
#include "sketch/after_play.h"
#include "sketch/bodies.h"
#include "sketch/lint.h"
#include "sketch/operations.h"

namespace physketch::sketch {
namespace {

// The field to name when an operation crosses the particle cap: what makes it big.
std::string capField(const Operation& op) {
  switch (op.kind) {
    case Operation::Kind::kStroke: return "size";
    case Operation::Kind::kStamp: return "scale";
    case Operation::Kind::kPrimitive: break;
  }
  // The primitive's largest dimension, by the parser's field names.
  static const char* const kDims[][3] = {{"sx", "sy", "sz"}, {"radius", "", ""}, {"rx", "ry", "rz"},
                                         {"radius", "length", ""}, {"radius", "length", ""},
                                         {"major_radius", "minor_radius", ""}};
  const auto& names = kDims[static_cast<int>(op.primitive.kind)];
  int best = 0;
  for (int d = 1; d < 3; ++d)
    if (*names[d] && op.primitive.dims[d] > op.primitive.dims[best]) best = d;
  return names[best];
}

// Runs `apply` (which creates particles for `op`), turning CapReached into an
// InputError naming the operation's line and field.
template <class Apply>
void withinCap(const StrokeFile& file, const Operation& op, const OperationSummary& sum, Apply&& apply) {
  try {
    apply();
  } catch (const CapReached&) {
    throw InputError(file.path, op.line, capField(op),
                     sum.what + " crosses the particle cap of " + std::to_string(kMaxParticles) +
                         " (20 % of the 151^3 grid" + (sum.afterPlay ? ", creates after play included" : "") +
                         "); use a smaller brush or fewer strokes");
  }
}

std::string describe(const Operation& op) {
  switch (op.kind) {
    case Operation::Kind::kStroke:
      return std::string("stroke ") + toString(op.stroke.op) + " " + toString(op.stroke.brush);
    case Operation::Kind::kPrimitive: return std::string("primitive ") + toString(op.primitive.kind);
    case Operation::Kind::kStamp: return "stamp " + op.stamp.path;
  }
  return "?";
}

Sketch replay(const StrokeFile& file, const GridMapping& mapping, const std::vector<Material>& materials, int threads) {
  Sketch sk(mapping);
  const double play = file.playTime();
  std::vector<bool> isActive(file.operations.size(), false);
  for (int id : file.active) isActive[static_cast<std::size_t>(id)] = true;
  for (const Operation& op : file.operations) {
    OperationSummary sum;
    sum.id = op.id;
    sum.line = op.line;
    sum.what = describe(op);
    sum.active = isActive[static_cast<std::size_t>(op.id)];
    sum.afterPlay = sum.active && op.startTime() > play;
    if (sum.active) sum.minFeature = smallestFeature(op, mapping.voxelSize());
    sk.operations.push_back(sum);
  }
  const InputChecks checks(file.path, materials, mapping);
  Footprints footprints(mapping, threads);
  SketchCells cells(sk.grid);
  std::vector<int> createsLater;
  for (int id : file.active) {
    const Operation& op = file.operations[static_cast<std::size_t>(id)];
    OperationSummary& sum = sk.operations[static_cast<std::size_t>(id)];
    // Tool strokes push material in the solver (docs/formats.md); the sketch never sees them.
    if (op.kind == Operation::Kind::kStroke && op.stroke.op == StrokeOp::kTool) continue;
    if (!sum.afterPlay) withinCap(file, op, sum, [&] { applyBeforePlay(op, footprints, checks, cells, sum); });
    else if (createsParticles(op)) createsLater.push_back(id);
    else strokeAfterPlay(op, play, checks, sum, sk.runtime);
  }
  const BodyPlan plan = planBodies(file);
  const std::vector<int> planned = compactIntoBodies(cells, plan, sk);
  const std::vector<CutBody> cuts = splitCutBodies(cells, plan, planned, file, sk);
  if (!createsLater.empty()) {
    CreatesAfterPlay later(footprints, checks, static_cast<std::int64_t>(sk.particles.size()));
    for (int id : createsLater) {
      const Operation& op = file.operations[static_cast<std::size_t>(id)];
      OperationSummary& sum = sk.operations[static_cast<std::size_t>(id)];
      withinCap(file, op, sum, [&] { later.add(op, play, sum, sk.runtime); });
    }
  }
  std::stable_sort(sk.runtime.begin(), sk.runtime.end(),
                   [](const RuntimeOp& a, const RuntimeOp& b) { return a.start < b.start; });
  lint(file, materials, cuts, sk);
  return sk;
}

}  // namespace

Sketch voxelize(const StrokeFile& file, const GridMapping& mapping, const std::vector<Material>& materials,
                const VoxelizeOptions& options) {
  if (options.threads < 0) throw RuntimeError("voxelize: threads must be >= 0 (0 = every core)");
  const int threads = options.threads > 0 ? options.threads : tbb::info::default_concurrency();
  // The parallel parts run in an arena of this many threads. The caller's arena is
  // used when it already has that many: entering a fresh arena hands the worker
  // threads over on every parallel step (measured: +10-20 % on 300k-particle
  // strokes with 2 threads). Either way the sketch is the same.
  if (threads == tbb::this_task_arena::max_concurrency()) return replay(file, mapping, materials, threads);
  tbb::task_arena arena(threads);
  return arena.execute([&] { return replay(file, mapping, materials, threads); });
}

}  // namespace physketch::sketch
