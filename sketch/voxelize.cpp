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

// The field to name when an operation crosses the particle cap: what makes it big (a
// rope: its path, the samples).
std::string capField(const Operation& op, const std::vector<Material>& materials) {
  const int m = findMaterial(materials, op.material);
  const bool rope = m >= 0 && materials[static_cast<std::size_t>(m)].kind == MaterialKind::kRope;
  switch (op.kind) {
    case Operation::Kind::kStroke: return rope ? "samples" : "size";
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
void withinCap(const StrokeFile& file, const std::vector<Material>& materials, const Operation& op,
               const OperationSummary& sum, Apply&& apply) {
  try {
    apply();
  } catch (const CapReached&) {
    const std::string field = capField(op, materials);
    throw InputError(file.path, op.line, field,
                     sum.what + " crosses the particle cap of " + std::to_string(kMaxParticles) +
                         " (20 % of the 151^3 grid" + (sum.afterPlay ? ", creates after play included" : "") +
                         "); use " + (field == "samples" ? "a shorter rope" : "a smaller brush") + " or fewer strokes");
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
    sk.operations.push_back(sum);
  }
  const InputChecks checks(file.path, materials, mapping);
  for (const Operation& op : file.operations)  // ropes and cloth are one particle thick by design: no thin warning
    if (sk.operations[static_cast<std::size_t>(op.id)].active && !checks.strandKind(op))
      sk.operations[static_cast<std::size_t>(op.id)].minFeature = smallestFeature(op, mapping.voxelSize());
  checkBodyKinds(file, materials);
  Footprints footprints(mapping, threads);
  SketchCells cells(sk.grid);
  Strands strands;
  std::vector<int> createsLater;
  for (int id : file.active) {
    const Operation& op = file.operations[static_cast<std::size_t>(id)];
    OperationSummary& sum = sk.operations[static_cast<std::size_t>(id)];
    // Tool strokes start at or after play (sketch/strokes.cpp checks) and push material in the
    // solver: a RuntimeOp, never part of M (docs/formats.md, "Tool strokes").
    if (op.kind == Operation::Kind::kStroke && op.stroke.op == StrokeOp::kTool)
      strokeAfterPlay(op, play, checks, sum, sk.runtime);
    else if (!sum.afterPlay)
      withinCap(file, materials, op, sum, [&] { applyBeforePlay(op, footprints, checks, cells, strands, sum); });
    else if (createsParticles(op)) createsLater.push_back(id);
    else strokeAfterPlay(op, play, checks, sum, sk.runtime);
  }
  const BodyPlan plan = planBodies(file);
  const std::vector<int> planned = compactIntoBodies(cells, plan, sk);
  std::vector<CutBody> cuts = splitCutBodies(cells, plan, planned, file, sk);
  if (!strands.empty()) {
    for (const CutBody& cut : appendStrandBodies(strands, plan, file, sk)) cuts.push_back(cut);
    orderBodiesAsPlanned(plan, cuts, sk);
  }
  if (!createsLater.empty()) {
    CreatesAfterPlay later(footprints, checks, liveParticles(sk.particles));
    for (int id : createsLater) {
      const Operation& op = file.operations[static_cast<std::size_t>(id)];
      OperationSummary& sum = sk.operations[static_cast<std::size_t>(id)];
      withinCap(file, materials, op, sum, [&] { later.add(op, play, sum, sk.runtime); });
    }
  }
  std::stable_sort(sk.runtime.begin(), sk.runtime.end(),
                   [](const RuntimeOp& a, const RuntimeOp& b) { return a.start < b.start; });
  lint(file, materials, cuts, sk);
  return sk;
}

}  // namespace

std::int64_t liveParticles(const ParticleArrays& particles) {
  std::int64_t n = 0;
  for (std::uint32_t ph : particles.phase) n += !phase::has(ph, phase::kRemoved);
  return n;
}

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
