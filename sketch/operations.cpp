#include "sketch/operations.h"

#include <algorithm>
#include <cmath>
#include <unordered_set>
#include <utility>

#include <tbb/parallel_for.h>

#include "core/error.h"

namespace physketch::sketch {
namespace {

const char* kAxisNames[] = {"x", "y", "z"};

// Move (before play): grab the particles under the brush at the first sample and
// carry them by the brush's travel, rounded to whole cells so the voxel set is
// translated exactly; the mirror copy moves mirrored. Particles they land on are
// replaced. Carrying one out of the workspace names the last sample's line and
// the axis it leaves by.
// Move (before play), ropes and cloth: the brush at the first sample grabs every rope
// (every chain a remove left of one) and every cloth with a live node inside it (the mirror
// copy: inside its mirror image) and carries the whole of it by the same whole-voxel shift as
// the voxels (mirrored for the mirror copy), so a rope drawn on a body and moved with it
// stays where it was drawn on it.
void moveStrands(const Operation& op, const Solid& brush, const Vec3i& shift, const InputChecks& checks,
                 Strands& strands, SketchCells& cells) {
  std::vector<std::pair<Strands::Span, Vec3>> grabbed;  // both copies grab before either moves, like the voxels
  for (int pass = 0; pass < (op.mirror.axis >= 0 ? 2 : 1); ++pass) {
    Vec3i sh = shift;
    if (pass == 1) sh[op.mirror.axis] = -sh[op.mirror.axis];
    const Vec3 offset = sh.cast<double>() * checks.mapping().voxelSize();
    for (const Strands::Span& span :
         strands.spansWhere([&](const Vec3& p) { return brush.contains(pass == 0 ? p : mirrorPoint(p, op.mirror)); }))
      if (std::none_of(grabbed.begin(), grabbed.end(), [&](const auto& g) { return g.first == span; }))
        grabbed.emplace_back(span, offset);
  }
  for (const auto& [span, offset] : grabbed)
    for (std::int32_t i = span.first; i < span.end; ++i)
      if (strands.alive(i))
        checks.inside(strands.positions()[static_cast<std::size_t>(i)] + offset, op.stroke.samples.back().line,
                      "move carries a rope or cloth node");
  for (const auto& [span, offset] : grabbed) {
    strands.translate(span, offset);
    cells.carried(strands.aliveIn(span));
  }
}

// Alg. 2 by position for ropes and cloth: every live node inside the brush at any stamp
// of the stroke (or inside its mirror image) is removed.
std::int64_t removeStrands(const Operation& op, double h, Strands& strands) {
  std::vector<Solid> solids;
  Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);  // around every stamp: a cheap first test
  for (const Stamp& st : stampsOf(op.stroke, h)) {
    solids.push_back(brushSolid(op.stroke, st.position, st.pressure, st.direction, h));
    const double r = solids.back().boundingRadius();
    lo = lo.cwiseMin(st.position - Vec3::Constant(r));
    hi = hi.cwiseMax(st.position + Vec3::Constant(r));
  }
  auto under = [&](const Vec3& q) {
    if ((q.array() < lo.array()).any() || (q.array() > hi.array()).any()) return false;
    for (const Solid& s : solids)
      if ((q - s.centre).squaredNorm() <= s.boundingRadius() * s.boundingRadius() && s.contains(q)) return true;
    return false;
  };
  return strands.removeWhere(
      [&](const Vec3& p) { return under(p) || (op.mirror.axis >= 0 && under(mirrorPoint(p, op.mirror))); });
}

void applyMove(const Operation& op, const InputChecks& checks, SketchCells& cells, Strands& strands,
               OperationSummary& sum) {
  const GridMapping& m = checks.mapping();
  const double h = m.voxelSize();
  const Stroke& s = op.stroke;
  const Sample& first = s.samples.front();
  const Sample& last = s.samples.back();
  const Vec3 travel = last.position - first.position;
  const Vec3 dg = travel / h;
  const Vec3i shift(static_cast<int>(std::lround(dg.x())), static_cast<int>(std::lround(dg.y())),
                    static_cast<int>(std::lround(dg.z())));
  Vec3 firstDir = s.axis;
  if (s.samples.size() > 1 && travel.norm() > 0) firstDir = travel.normalized();
  std::vector<Vec3i> under;
  const Solid brush = brushSolid(s, first.position, first.pressure, firstDir, h);
  rasterize(brush, m, under);
  std::vector<std::pair<std::int32_t, Vec3i>> grabbed;
  std::unordered_set<std::int32_t> seen;
  const int copies = op.mirror.axis >= 0 ? 2 : 1;
  for (int pass = 0; pass < copies; ++pass) {
    Vec3i sh = shift;
    if (pass == 1) sh[op.mirror.axis] = -sh[op.mirror.axis];  // the mirrored brush moves mirrored
    for (const Vec3i& c0 : under) {
      const Vec3i c = pass == 0 ? c0 : mirrorCell(c0, op.mirror, m);
      if (!GridMapping::inGrid(c)) continue;
      const std::int32_t p = cells.particleAt(c);
      if (p < 0 || !seen.insert(p).second) continue;
      const Vec3i to = c + sh;
      if (!GridMapping::inGrid(to)) {
        int axis = 0;
        while (to[axis] >= 0 && to[axis] < kGridSize) ++axis;
        const Vec3 from = m.toWorld(c);
        const double lo = m.center()[axis] - 0.5 * m.size();
        throw InputError(checks.path(), last.line, kAxisNames[axis],
                         std::string("move carries particles outside the workspace: the one at (") +
                             std::to_string(from.x()) + ", " + std::to_string(from.y()) + ", " +
                             std::to_string(from.z()) + ") m would leave it (" + kAxisNames[axis] + " must stay in [" +
                             std::to_string(lo) + ", " + std::to_string(lo + m.size()) + "))");
      }
      grabbed.emplace_back(p, to);
    }
  }
  sum.stamps += copies;
  if (!strands.empty()) moveStrands(op, brush, shift, checks, strands, cells);
  cells.relocate(grabbed);
}

}  // namespace

std::int16_t InputChecks::material(const Operation& op) const {
  const int mat = findMaterial(materials_, op.material);
  if (mat < 0) {
    std::string known;
    for (const auto& m : materials_) known += (known.empty() ? "" : ", ") + m.name;
    throw InputError(path_, op.line, "material",
                     "unknown material '" + op.material + "' (the scene defines: " +
                         (known.empty() ? std::string("none") : known) + ")");
  }
  return static_cast<std::int16_t>(mat);
}

std::optional<MaterialKind> InputChecks::strandKind(const Operation& op) const {
  if (!createsParticles(op)) return std::nullopt;
  const int mat = findMaterial(materials_, op.material);
  if (mat < 0) return std::nullopt;
  const MaterialKind kind = materials_[static_cast<std::size_t>(mat)].kind;
  if (layoutOf(kind) == BodyLayout::kVoxels) return std::nullopt;
  return kind;
}

void InputChecks::inside(const Vec3& p, int line, const char* what) const {
  if (mapping_.contains(p)) return;
  const Vec3 g = mapping_.toGrid(p);
  int axis = 0;
  for (int a = 0; a < 3; ++a)
    if (g[a] < -0.5 || g[a] >= kGridSize - 0.5) {
      axis = a;
      break;
    }
  const double lo = mapping_.center()[axis] - 0.5 * mapping_.size();
  throw InputError(path_, line, kAxisNames[axis],
                   std::string(what) + " outside the workspace (" + kAxisNames[axis] + " must be in [" +
                       std::to_string(lo) + ", " + std::to_string(lo + mapping_.size()) + "))");
}

void InputChecks::samplesInside(const Stroke& s) const {
  for (const Sample& smp : s.samples) inside(smp.position, smp.line, "sample");
}

// The cells of all stamps of a stroke into mask_. A long stroke is cut into parts
// swept in parallel into masks of their own and ORed together: a union, so the
// result is the same bit for bit however many parts or threads there are.
void Footprints::sweep(const Stroke& s, const std::vector<Stamp>& stamps) {
  constexpr std::size_t kStampsPerPart = 1024;  // below this a part costs more than it saves
  const std::size_t parts =
      std::max<std::size_t>(1, std::min(static_cast<std::size_t>(threads_), stamps.size() / kStampsPerPart));
  const double h = mapping_.voxelSize();
  if (!mask_) mask_ = std::make_unique<CellMask>();
  mask_->clear();
  while (partMasks_.size() + 1 < parts) partMasks_.push_back(std::make_unique<CellMask>());
  auto sweepPart = [&](std::size_t part) {
    CellMask& m = part == 0 ? *mask_ : *partMasks_[part - 1];
    for (std::size_t i = stamps.size() * part / parts; i < stamps.size() * (part + 1) / parts; ++i)
      m.add(brushSolid(s, stamps[i].position, stamps[i].pressure, stamps[i].direction, h), mapping_);
  };
  if (parts == 1) return sweepPart(0);
  tbb::parallel_for(std::size_t(0), parts, sweepPart);
  for (std::size_t p = 1; p < parts; ++p) {
    mask_->merge(*partMasks_[p - 1]);
    partMasks_[p - 1]->clear();
  }
}

Footprint Footprints::stroke(const Operation& op) {
  // Consecutive stamps overlap almost entirely: the stroke's swept cells are
  // gathered in a bit mask and applied once each, in z, y, x order.
  const std::vector<Stamp> stamps = stampsOf(op.stroke, mapping_.voxelSize());
  sweep(op.stroke, stamps);
  const int copies = op.mirror.axis >= 0 ? 2 : 1;
  return Footprint(mask_.get(), nullptr, op.mirror, mapping_, static_cast<std::int64_t>(stamps.size()) * copies);
}

Footprint Footprints::primitive(const Operation& op) {
  rasterize(primitiveSolid(op.primitive), mapping_, cells_);
  return Footprint(nullptr, &cells_, op.mirror, mapping_, op.mirror.axis >= 0 ? 2 : 1);
}

Footprint Footprints::meshStamp(const Operation& op, const std::string& strokeFile) {
  try {
    auto it = meshes_.find(op.stamp.path);
    if (it == meshes_.end()) it = meshes_.emplace(op.stamp.path, StampMesh::load(op.stamp.path)).first;
    cells_ = voxelizeMesh(it->second, mapping_, op.stamp.scale, op.stamp.rotation, op.stamp.translation);
  } catch (const InputError& e) {
    // The mesh file's own error, reported against the stamp record that named it.
    throw InputError(strokeFile, op.line, "path", e.what());
  }
  return Footprint(nullptr, &cells_, op.mirror, mapping_, op.mirror.axis >= 0 ? 2 : 1);
}

Footprint createFootprint(const Operation& op, Footprints& footprints, const InputChecks& checks,
                          OperationSummary& sum) {
  auto made = [&](Footprint fp) {
    sum.stamps += fp.stamps();
    return fp;
  };
  switch (op.kind) {
    case Operation::Kind::kStroke:
      checks.samplesInside(op.stroke);
      sum.material = checks.material(op);
      return made(footprints.stroke(op));
    case Operation::Kind::kPrimitive:
      checks.inside(op.primitive.centre, op.line, "primitive centre");
      sum.material = checks.material(op);
      return made(footprints.primitive(op));
    case Operation::Kind::kStamp:
      sum.material = checks.material(op);
      return made(footprints.meshStamp(op, checks.path()));
  }
  throw RuntimeError("createFootprint: unknown operation kind");
}

std::vector<StrandShape> strandCopies(const Operation& op, MaterialKind kind, const InputChecks& checks,
                                      OperationSummary& sum) {
  if (op.kind == Operation::Kind::kStroke) checks.samplesInside(op.stroke);
  sum.material = checks.material(op);
  std::vector<StrandShape> out{strandOf(op, kind, checks.mapping().voxelSize(), checks.path())};
  if (op.mirror.axis >= 0) out.push_back(mirrored(out.front(), op.mirror));
  const char* what = kind == MaterialKind::kRope ? "rope particle" : "cloth node";
  for (const StrandShape& shape : out) {
    for (std::size_t i = 0; i < shape.nodes.size(); ++i) checks.inside(shape.nodes[i], shape.lines[i], what);
    sum.stamps += static_cast<std::int64_t>(shape.nodes.size());
  }
  return out;
}

void applyBeforePlay(const Operation& op, Footprints& footprints, const InputChecks& checks, SketchCells& cells,
                     Strands& strands, OperationSummary& sum) {
  cells.begin(sum);
  if (const std::optional<MaterialKind> kind = checks.strandKind(op)) {
    for (const StrandShape& shape : strandCopies(op, *kind, checks, sum)) {
      cells.admit(static_cast<std::int64_t>(shape.nodes.size()));
      strands.add(op.id, sum.material, shape);
    }
    return;
  }
  if (createsParticles(op)) return createIn(createFootprint(op, footprints, checks, sum), cells);
  checks.samplesInside(op.stroke);
  switch (op.stroke.op) {  // no default: a new stroke operation must be handled here (-Wswitch)
    case StrokeOp::kCreate: return;  // handled above
    case StrokeOp::kTool: throw RuntimeError("applyBeforePlay: tool strokes are the solver's (see replay)");
    case StrokeOp::kMove: return applyMove(op, checks, cells, strands, sum);
    case StrokeOp::kRemove: {
      // Alg. 2: free every cell under the brush at every stamp; ropes and cloth by position.
      const Footprint fp = footprints.stroke(op);
      sum.stamps += fp.stamps();
      fp.forEachCell([&](const Vec3i& c) { cells.drop(c); });
      if (!strands.empty()) cells.release(removeStrands(op, checks.mapping().voxelSize(), strands));
      return;
    }
  }
}

}  // namespace physketch::sketch
