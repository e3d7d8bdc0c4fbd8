#include "sketch/after_play.h"

#include <utility>

#include "core/error.h"
#include "sketch/bodies.h"

namespace physketch::sketch {

namespace {

// The cells of one copy (pass 0: as drawn; 1: the mirror copy).
void mirrored(std::vector<Vec3i>& cells, int pass, const Mirror& mirror, const GridMapping& m) {
  if (pass == 1)
    for (auto& c : cells) c = mirrorCell(c, mirror, m);
}

// Remove: the stamps of a segment happen when its end sample is reached. Each keeps
// only the cells its predecessor did not cover (as before play), so a long stroke with
// a big brush stores its swept volume once rather than once per stamp.
void removeAfterPlay(const Operation& op, double play, int pass, const GridMapping& m, OperationSummary& sum,
                     RuntimeOp& r) {
  const Stroke& s = op.stroke;
  const double h = m.voxelSize();
  r.kind = RuntimeOp::Kind::kRemove;
  StampDiff diff;
  std::vector<Vec3i> cells;
  for (const Stamp& st : stampsOf(s, h)) {
    diff.stamp(brushSolid(s, st.position, st.pressure, st.direction, h), m, cells);
    mirrored(cells, pass, op.mirror, m);
    if (!r.removals.empty() && r.removals.back().first == st.time - play)
      r.removals.back().second.insert(r.removals.back().second.end(), cells.begin(), cells.end());
    else
      r.removals.emplace_back(st.time - play, cells);
    ++sum.stamps;
  }
}

// Move: the cells under the brush at the first sample, and the brush's path.
void moveAfterPlay(const Operation& op, double play, int pass, const GridMapping& m, OperationSummary& sum,
                   RuntimeOp& r) {
  const Stroke& s = op.stroke;
  r.kind = RuntimeOp::Kind::kMove;
  const Sample& first = s.samples.front();
  Vec3 dir = s.axis;
  if (s.samples.size() > 1 && (s.samples.back().position - first.position).norm() > 0)
    dir = (s.samples.back().position - first.position).normalized();
  rasterize(brushSolid(s, first.position, first.pressure, dir, m.voxelSize()), m, r.grab);
  mirrored(r.grab, pass, op.mirror, m);
  for (const Sample& smp : s.samples)
    r.path.emplace_back(smp.t - play, pass == 1 ? mirrorPoint(smp.position, op.mirror) : smp.position);
  ++sum.stamps;
}

// Tool: the brush at its first sample as particles (voxel centres, Eq. 5) and the brush's path.
// Material -1 until the app gives the tool its own (prepare.cpp).
void toolAfterPlay(const Operation& op, double play, int pass, const GridMapping& m, OperationSummary& sum,
                   RuntimeOp& r) {
  moveAfterPlay(op, play, pass, m, sum, r);  // the cells under the brush at its first sample, and the path
  r.kind = RuntimeOp::Kind::kTool;
  r.cells = std::move(r.grab);
  r.grab.clear();
  r.friction = op.stroke.toolFriction;
  r.particles.reserve(r.cells.size());
  for (const Vec3i& c : r.cells) {
    const Vec3 q = m.toWorld(c);
    r.particles.push(static_cast<float>(q.x()), static_cast<float>(q.y()), static_cast<float>(q.z()), op.id, -1);
  }
}

}  // namespace

void strokeAfterPlay(const Operation& op, double play, const InputChecks& checks, OperationSummary& sum,
                     std::vector<RuntimeOp>& out) {
  checks.samplesInside(op.stroke);
  for (int pass = 0; pass < (op.mirror.axis >= 0 ? 2 : 1); ++pass) {
    RuntimeOp r;
    r.op = op.id;
    r.line = op.line;
    r.start = op.startTime() - play;
    r.end = op.endTime() - play;
    switch (op.stroke.op) {  // no default: a new stroke operation must be handled here (-Wswitch)
      case StrokeOp::kCreate: throw RuntimeError("strokeAfterPlay: creates after play go to CreatesAfterPlay");
      case StrokeOp::kRemove: removeAfterPlay(op, play, pass, checks.mapping(), sum, r); break;
      case StrokeOp::kMove: moveAfterPlay(op, play, pass, checks.mapping(), sum, r); break;
      case StrokeOp::kTool: toolAfterPlay(op, play, pass, checks.mapping(), sum, r); break;
    }
    if (r.kind == RuntimeOp::Kind::kTool && r.particles.size() == 0) continue;  // a brush too small for a voxel
    out.push_back(std::move(r));
  }
}

// A rope or cloth create after play: one new body per mirror copy, laid out as drawn.
void CreatesAfterPlay::addStrand(const Operation& op, MaterialKind kind, double play, OperationSummary& sum,
                                 std::vector<RuntimeOp>& out) {
  const std::string name = op.body.empty() ? "stroke " + std::to_string(op.id) : op.body;
  int copy = 0;
  for (const StrandShape& shape : strandCopies(op, kind, checks_, sum)) {
    cells_.admit(static_cast<std::int64_t>(shape.nodes.size()));
    RuntimeOp r;
    r.kind = RuntimeOp::Kind::kCreate;
    r.op = op.id;
    r.line = op.line;
    r.start = op.startTime() - play;
    r.end = op.endTime() - play;
    r.bodyName = copy++ == 0 ? name : name + " #" + std::to_string(copy);
    r.init = bodyInit(op);
    r.layout = shape.layout;
    r.rows = shape.layout == BodyLayout::kLattice ? shape.rows : 0;  // as BodyRange: kLattice only
    r.cols = shape.layout == BodyLayout::kLattice ? shape.cols : 0;
    r.radius = shape.radius;
    r.particles.reserve(shape.nodes.size());
    for (const Vec3& q : shape.nodes) {
      r.particles.push(static_cast<float>(q.x()), static_cast<float>(q.y()), static_cast<float>(q.z()), op.id,
                       sum.material);
      r.cells.push_back(checks_.mapping().discretize(  // of the position as stored
          Vec3(r.particles.x.back(), r.particles.y.back(), r.particles.z.back())));
    }
    out.push_back(std::move(r));
  }
  sum.remaining = sum.created;
}

void CreatesAfterPlay::add(const Operation& op, double play, OperationSummary& sum, std::vector<RuntimeOp>& out) {
  cells_.begin(sum);
  if (const std::optional<MaterialKind> kind = checks_.strandKind(op)) return addStrand(op, *kind, play, sum, out);
  const std::size_t from = cells_.cells().size();
  createIn(createFootprint(op, footprints_, checks_, sum), cells_);
  sum.remaining = sum.created;
  if (sum.created == 0) return;
  RuntimeOp r;
  r.kind = RuntimeOp::Kind::kCreate;
  r.op = op.id;
  r.line = op.line;
  r.start = op.startTime() - play;
  r.end = op.endTime() - play;
  r.bodyName = op.body.empty() ? "stroke " + std::to_string(op.id) : op.body;
  r.init = bodyInit(op);
  const std::vector<std::int32_t>& made = cells_.cells();
  r.particles.reserve(made.size() - from);
  r.cells.reserve(made.size() - from);
  for (std::size_t i = from; i < made.size(); ++i) {
    const Vec3i c = GridMapping::cellOf(made[i]);
    const Vec3 q = checks_.mapping().toWorld(c);  // Eq. 5
    r.particles.push(static_cast<float>(q.x()), static_cast<float>(q.y()), static_cast<float>(q.z()), op.id,
                     sum.material);
    r.cells.push_back(c);
  }
  out.push_back(std::move(r));
}

}  // namespace physketch::sketch

