#include "sketch/voxelize.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <queue>
#include <unordered_set>
#include <utility>

#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include "core/error.h"
#include "sketch/mesh_stamp.h"
#include "sketch/rasterize.h"

namespace physketch::sketch {
namespace {

// Thrown when the particle cap is reached; voxelize() turns it into an InputError naming the operation.
struct CapReached {};

const char* kAxisNames[] = {"x", "y", "z"};

// How a body starts, from the create options of the operation that made it (every part
// of a named body carries the body's values: sketch/strokes.h).
BodyInit bodyInit(const Operation& op) {
  BodyInit init;
  init.velocity = op.velocity.value_or(Vec3::Zero());
  init.spin = op.spin.value_or(Vec3::Zero());
  init.fixed = op.fixed;
  return init;
}

class Builder {
 public:
  // `alreadyLive` particles exist elsewhere and count towards the cap (the sketch's,
  // when this builder voxelizes the creates that happen after play).
  Builder(const StrokeFile& file, const std::vector<Material>& materials, const GridMapping& mapping,
          std::int64_t alreadyLive = 0)
      : file_(file), materials_(materials), sk_(mapping), h_(mapping.voxelSize()),
        live_(alreadyLive) {}

  Sketch run() {
    const double play = file_.playTime();
    std::vector<bool> isActive(file_.operations.size(), false);
    for (int id : file_.active) isActive[static_cast<std::size_t>(id)] = true;
    for (const Operation& op : file_.operations) {
      OperationSummary sum;
      sum.id = op.id;
      sum.line = op.line;
      sum.what = describe(op);
      sum.active = isActive[static_cast<std::size_t>(op.id)];
      sk_.operations.push_back(sum);
    }
    std::vector<int> runtimeCreates;
    for (const Operation& op : file_.operations) {
      if (!isActive[static_cast<std::size_t>(op.id)]) continue;
      // Tool strokes push material in the solver (docs/formats.md); the sketch never sees them.
      if (op.kind == Operation::Kind::kStroke && op.stroke.op == StrokeOp::kTool) continue;
      cur_ = &sk_.operations[static_cast<std::size_t>(op.id)];
      if (op.startTime() > play) {
        cur_->afterPlay = true;
        const bool creates = op.kind != Operation::Kind::kStroke || op.stroke.op == StrokeOp::kCreate;
        if (creates) runtimeCreates.push_back(op.id);
        else runtimeStroke(op, play);
        continue;
      }
      try {
        apply(op);
      } catch (const CapReached&) {
        throw InputError(file_.path, op.line, "",
                         "operation " + std::to_string(op.id) + " (" + cur_->what + ") crosses the particle cap of " +
                             std::to_string(kMaxParticles) + " (20 % of the 151^3 grid); use a smaller brush or fewer strokes");
      }
    }
    finalize();
    if (!runtimeCreates.empty()) runtimeCreate(runtimeCreates, play);
    std::stable_sort(sk_.runtime.begin(), sk_.runtime.end(),
                     [](const RuntimeOp& a, const RuntimeOp& b) { return a.start < b.start; });
    return std::move(sk_);
  }

  // Creates after play: voxelized in file order into a grid of their own (the sketch's
  // bodies have moved by then), each one a new body.
  void runtimeCreate(const std::vector<int>& ids, double play) {
    StrokeFile rt;
    rt.path = file_.path;
    rt.operations = file_.operations;
    rt.active = ids;
    rt.play = 1e300;
    for (int id : ids) rt.operations[static_cast<std::size_t>(id)].body.clear();  // one body per operation
    Sketch made = Builder(rt, materials_, sk_.mapping, static_cast<std::int64_t>(sk_.particles.size())).run();
    for (std::size_t b = 0; b < made.bodies.size(); ++b) {
      const BodyRange& br = made.bodies[b];
      const Operation& op = file_.operations[static_cast<std::size_t>(br.stroke)];
      RuntimeOp r;
      r.kind = RuntimeOp::Kind::kCreate;
      r.op = op.id;
      r.line = op.line;
      r.start = op.startTime() - play;
      r.end = op.endTime() - play;
      r.bodyName = op.body.empty() ? "stroke " + std::to_string(op.id) : op.body;
      r.init = br.init;
      r.particles.reserve(static_cast<std::size_t>(br.count));
      for (std::int32_t i = br.first; i < br.first + br.count; ++i) {
        const auto k = static_cast<std::size_t>(i);
        r.particles.push(made.particles.x[k], made.particles.y[k], made.particles.z[k], made.particles.stroke[k],
                         made.particles.material[k]);
        r.cells.push_back(made.cells[k]);
      }
      auto& sum = sk_.operations[static_cast<std::size_t>(op.id)];
      sum.created = made.operations[static_cast<std::size_t>(op.id)].created;
      sum.remaining = sum.created;
      sum.material = made.operations[static_cast<std::size_t>(op.id)].material;
      sum.stamps = made.operations[static_cast<std::size_t>(op.id)].stamps;
      sk_.runtime.push_back(std::move(r));
    }
  }

  // Remove and move strokes after play: the cells under the brush and when, for the simulation to apply.
  void runtimeStroke(const Operation& op, double play) {
    const Stroke& s = op.stroke;
    for (const Sample& smp : s.samples) checkInside(smp.position, smp.line, "sample");
    std::vector<Vec3i> cells;
    for (int pass = 0; pass < (op.mirror.axis >= 0 ? 2 : 1); ++pass) {
      auto mirrored = [&](std::vector<Vec3i>& cs) {
        if (pass == 0) return;
        for (auto& c : cs) c = mirrorCell(c, op.mirror, sk_.mapping);
      };
      auto mirrorPoint = [&](Vec3 p) {
        if (pass == 1) p[op.mirror.axis] = 2.0 * op.mirror.offset - p[op.mirror.axis];
        return p;
      };
      RuntimeOp r;
      r.op = op.id;
      r.line = op.line;
      r.start = op.startTime() - play;
      r.end = op.endTime() - play;
      if (s.op == StrokeOp::kRemove) {
        r.kind = RuntimeOp::Kind::kRemove;
        // The stamps of a segment happen when its end sample is reached. Each keeps only
        // the cells its predecessor did not cover (as before play), so a long stroke with a
        // big brush stores its swept volume once rather than once per stamp.
        StampDiff diff;
        for (const Stamp& st : stampsOf(s)) {
          diff.stamp(brushSolid(s, st.position, st.pressure, st.direction, h_), sk_.mapping, cells);
          mirrored(cells);
          if (!r.removals.empty() && r.removals.back().first == st.time - play)
            r.removals.back().second.insert(r.removals.back().second.end(), cells.begin(), cells.end());
          else
            r.removals.emplace_back(st.time - play, cells);
          ++cur_->stamps;
        }
      } else {
        r.kind = RuntimeOp::Kind::kMove;
        const Sample& first = s.samples.front();
        Vec3 dir = s.axis;
        if (s.samples.size() > 1 && (s.samples.back().position - first.position).norm() > 0)
          dir = (s.samples.back().position - first.position).normalized();
        rasterize(brushSolid(s, first.position, first.pressure, dir, h_), sk_.mapping, cells);
        mirrored(cells);
        r.grab = cells;
        for (const Sample& smp : s.samples) r.path.emplace_back(smp.t - play, mirrorPoint(smp.position));
        ++cur_->stamps;
      }
      sk_.runtime.push_back(std::move(r));
    }
  }

 private:
  static std::string describe(const Operation& op) {
    switch (op.kind) {
      case Operation::Kind::kStroke:
        return std::string("stroke ") + toString(op.stroke.op) + " " + toString(op.stroke.brush);
      case Operation::Kind::kPrimitive: return std::string("primitive ") + toString(op.primitive.kind);
      case Operation::Kind::kStamp: return "stamp " + op.stamp.path;
    }
    return "?";
  }

  std::int16_t resolveMaterial(const Operation& op) {
    const int mat = findMaterial(materials_, op.material);
    if (mat < 0) {
      std::string known;
      for (const auto& m : materials_) known += (known.empty() ? "" : ", ") + m.name;
      throw InputError(file_.path, op.line, "material",
                       "unknown material '" + op.material + "' (the scene defines: " +
                           (known.empty() ? std::string("none") : known) + ")");
    }
    return static_cast<std::int16_t>(mat);
  }

  void checkInside(const Vec3& p, int line, const char* what) {
    if (sk_.mapping.contains(p)) return;
    const Vec3 g = sk_.mapping.toGrid(p);
    int axis = 0;
    for (int a = 0; a < 3; ++a)
      if (g[a] < -0.5 || g[a] >= kGridSize - 0.5) {
        axis = a;
        break;
      }
    const double lo = sk_.mapping.center()[axis] - 0.5 * sk_.mapping.size();
    throw InputError(file_.path, line, kAxisNames[axis],
                     std::string(what) + " outside the workspace (" + kAxisNames[axis] + " must be in [" +
                         std::to_string(lo) + ", " + std::to_string(lo + sk_.mapping.size()) + "))");
  }

  // --- Alg. 1 and Alg. 2 on single cells ------------------------------------
  // While sketching, M holds each particle's index in protoCell_, and occ_ marks
  // the taken cells: the common question "is this cell free" reads bits that stay
  // in cache rather than the 13.8 MB grid.
  std::int32_t particleAt(const Vec3i& c) const { return occ_.test(c) ? sk_.grid.at(c) : -1; }
  void place(const Vec3i& c, std::int32_t p) {
    if (p >= 0) occ_.set(c);
    else occ_.reset(c);
    sk_.grid.set(c, p);
  }

  void take(const Vec3i& c) {
    if (occ_.test(c)) return;  // one particle per voxel, never two at one place
    occ_.set(c);
    takeFree(c);
  }
  // take() of a cell known to be free and already marked in occ_.
  void takeFree(const Vec3i& c) {
    if (live_ >= kMaxParticles) throw CapReached{};
    // A compact record while sketching; positions (Eq. 5) and the SoA arrays are built once in finalize().
    const auto p = static_cast<std::int32_t>(protoCell_.size());
    sk_.grid.set(c, p);
    protoCell_.push_back(static_cast<std::int32_t>(GridMapping::linear(c)));
    if (opRuns_.empty() || opRuns_.back().op != cur_->id) opRuns_.push_back({cur_->id, p, p});
    ++opRuns_.back().end;
    ++live_;
    ++cur_->created;
  }

  void drop(const Vec3i& c) {
    const std::int32_t p = particleAt(c);
    if (p < 0) return;
    protoCell_[static_cast<std::size_t>(p)] = -1;
    place(c, -1);
    --live_;
    ++cur_->removed;
  }

  // Room for `more` particles, growing geometrically (many small operations stay linear).
  void reserveProtos(std::int64_t more) {
    const std::size_t want = protoCell_.size() + static_cast<std::size_t>(std::min<std::int64_t>(more, kMaxParticles));
    if (want > protoCell_.capacity()) protoCell_.reserve(std::max(want, 2 * protoCell_.capacity()));
  }

  // Applies create or remove to cells and their mirror image.
  // `forEach(f)` calls f(cell) for each cell (a vector's or a CellMask's).
  template <class ForEach>
  void applyEach(ForEach&& forEach, const Mirror& mirror, bool create) {
    for (int pass = 0; pass < (mirror.axis >= 0 ? 2 : 1); ++pass)
      forEach([&](const Vec3i& c0) {
        const Vec3i c = pass == 0 ? c0 : mirrorCell(c0, mirror, sk_.mapping);
        if (!GridMapping::inGrid(c)) return;
        if (create) take(c);
        else drop(c);
      });
  }
  void applyCells(const std::vector<Vec3i>& cells, const Mirror& mirror, bool create) {
    if (create) reserveProtos(static_cast<std::int64_t>(cells.size()) * (mirror.axis >= 0 ? 2 : 1));
    applyEach([&](auto&& f) { for (const Vec3i& c : cells) f(c); }, mirror, create);
  }

  // Brush positions of a stroke (Eq. 6-7), with pressure and travel direction per stamp.
  struct Stamp {
    Vec3 position, direction;
    double pressure;
    double time;  // s: the sample time at the end of the stamp's segment
  };
  std::vector<Stamp> stampsOf(const Stroke& s) {
    std::vector<Stamp> out;
    std::vector<Vec3> pts;
    const auto& sm = s.samples;
    Vec3 firstDir = s.axis;
    for (std::size_t k = 1; k < sm.size(); ++k) {
      const Vec3 d = sm[k].position - sm[k - 1].position;
      if (d.norm() > 0) {
        firstDir = d.normalized();
        break;
      }
    }
    Vec3 dir = firstDir;
    for (std::size_t k = 0; k < sm.size(); ++k) {
      if (k == 0) {
        out.push_back({sm[0].position, dir, sm[0].pressure, sm[0].t});
        continue;
      }
      const Vec3 seg = sm[k].position - sm[k - 1].position;
      const double len = seg.norm();
      if (len > 0) dir = seg / len;
      interpolateSegment(sm[k - 1].position, sm[k].position, h_, pts);
      for (std::size_t i = 0; i < pts.size(); ++i) {
        // Pressure varies linearly along the segment, like the position.
        const double a = len > 0 ? std::min(1.0, double(i) * h_ / len) : 0.0;
        out.push_back({pts[i], dir, sm[k].pressure + a * (sm[k - 1].pressure - sm[k].pressure), sm[k].t});
      }
    }
    return out;
  }

  // The cells of all stamps of a stroke into mask_. A long stroke is cut into parts
  // swept in parallel into masks of their own and ORed together: a union, so the
  // result is the same bit for bit however many parts or threads there are.
  void sweep(const Stroke& s, const std::vector<Stamp>& stamps) {
    constexpr std::size_t kStampsPerPart = 1024;  // below this a part costs more than it saves
    const std::size_t threads = tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
    const std::size_t parts = std::max<std::size_t>(1, std::min(threads, stamps.size() / kStampsPerPart));
    if (!mask_) mask_ = std::make_unique<CellMask>();
    mask_->clear();
    while (partMasks_.size() + 1 < parts) partMasks_.push_back(std::make_unique<CellMask>());
    auto sweepPart = [&](std::size_t part) {
      CellMask& m = part == 0 ? *mask_ : *partMasks_[part - 1];
      for (std::size_t i = stamps.size() * part / parts; i < stamps.size() * (part + 1) / parts; ++i)
        m.add(brushSolid(s, stamps[i].position, stamps[i].pressure, stamps[i].direction, h_), sk_.mapping);
    };
    if (parts == 1) return sweepPart(0);
    tbb::parallel_for(std::size_t(0), parts, sweepPart);
    for (std::size_t p = 1; p < parts; ++p) {
      mask_->merge(*partMasks_[p - 1]);
      partMasks_[p - 1]->clear();
    }
  }

  void apply(const Operation& op) {
    std::vector<Vec3i> cells;
    switch (op.kind) {
      case Operation::Kind::kStroke: {
        const Stroke& s = op.stroke;
        for (const Sample& smp : s.samples) checkInside(smp.position, smp.line, "sample");
        cur_->minFeature = s.size * std::min_element(s.samples.begin(), s.samples.end(), [](auto& a, auto& b) {
                                      return a.pressure < b.pressure;
                                    })->pressure;
        // A disc that follows the stroke sweeps a solid; a fixed one dragged sideways leaves a sheet.
        if (s.brush == BrushShape::kCylinder || s.brush == BrushShape::kCapsule ||
            (s.brush == BrushShape::kDisc && s.orient == Orientation::kFixed))
          cur_->minFeature = std::min(cur_->minFeature, s.length > 0 ? s.length : (s.brush == BrushShape::kDisc ? h_ : s.size));
        if (s.op == StrokeOp::kMove) {
          move(op);
          return;
        }
        const std::int16_t mat = s.op == StrokeOp::kCreate ? resolveMaterial(op) : std::int16_t(-1);
        cur_->material = mat;
        // Consecutive stamps overlap almost entirely: the stroke's swept cells are
        // gathered in a bit mask and applied once each, in z, y, x order.
        const std::vector<Stamp> stamps = stampsOf(s);
        sweep(s, stamps);
        cur_->stamps += static_cast<std::int64_t>(stamps.size()) * (op.mirror.axis >= 0 ? 2 : 1);
        if (mat >= 0) reserveProtos(mask_->count() * (op.mirror.axis >= 0 ? 2 : 1));
        if (mat >= 0 && op.mirror.axis < 0)  // the common case, a word of free cells at a time
          mask_->forEachCellNotIn(occ_, [&](const Vec3i& c) { takeFree(c); });
        else
          applyEach([&](auto&& f) { mask_->forEachCell(f); }, op.mirror, mat >= 0);
        return;
      }
      case Operation::Kind::kPrimitive: {
        const Primitive& p = op.primitive;
        checkInside(p.centre, op.line, "primitive centre");
        const std::int16_t mat = resolveMaterial(op);
        cur_->material = mat;
        Solid solid;
        solid.centre = p.centre;
        solid.rotation = p.rotation;
        switch (p.kind) {
          case PrimitiveKind::kBox:
            solid.shape = SolidShape::kBox;
            solid.a = 0.5 * p.dims.x(), solid.b = 0.5 * p.dims.y(), solid.c = 0.5 * p.dims.z();
            cur_->minFeature = p.dims.minCoeff();
            break;
          case PrimitiveKind::kSphere:
            solid.shape = SolidShape::kSphere, solid.a = p.dims.x();
            cur_->minFeature = 2 * p.dims.x();
            break;
          case PrimitiveKind::kEllipsoid:
            solid.shape = SolidShape::kEllipsoid;
            solid.a = p.dims.x(), solid.b = p.dims.y(), solid.c = p.dims.z();
            cur_->minFeature = 2 * p.dims.minCoeff();
            break;
          case PrimitiveKind::kCylinder:
            solid.shape = SolidShape::kCylinder, solid.a = p.dims.x(), solid.b = 0.5 * p.dims.y();
            cur_->minFeature = std::min(2 * p.dims.x(), p.dims.y());
            break;
          case PrimitiveKind::kCapsule:
            solid.shape = SolidShape::kCapsule, solid.a = p.dims.x(), solid.b = 0.5 * p.dims.y();
            cur_->minFeature = 2 * p.dims.x();
            break;
          case PrimitiveKind::kTorus:
            solid.shape = SolidShape::kTorus, solid.a = p.dims.x(), solid.b = p.dims.y();
            cur_->minFeature = 2 * p.dims.y();
            break;
        }
        rasterize(solid, sk_.mapping, cells);
        applyCells(cells, op.mirror, true);
        cur_->stamps += op.mirror.axis >= 0 ? 2 : 1;
        return;
      }
      case Operation::Kind::kStamp: {
        const std::int16_t mat = resolveMaterial(op);
        cur_->material = mat;
        try {
          auto it = meshes_.find(op.stamp.path);
          if (it == meshes_.end()) it = meshes_.emplace(op.stamp.path, StampMesh::load(op.stamp.path)).first;
          cells = voxelizeMesh(it->second, sk_.mapping, op.stamp.scale, op.stamp.rotation, op.stamp.translation);
        } catch (const InputError& e) {
          // The mesh file's own error, reported against the stamp record that named it.
          throw InputError(file_.path, op.line, "path", e.what());
        }
        cur_->minFeature = 1e300;
        applyCells(cells, op.mirror, true);
        cur_->stamps += op.mirror.axis >= 0 ? 2 : 1;
        return;
      }
    }
  }

  // Move (before play): grab the particles under the brush at the first sample
  // and carry them by the brush's travel, rounded to whole cells so the voxel
  // set is translated exactly. Particles they land on are replaced.
  void move(const Operation& op) {
    const Stroke& s = op.stroke;
    const Sample& first = s.samples.front();
    const Sample& last = s.samples.back();
    const Vec3 travel = last.position - first.position;
    const Vec3 dg = travel / h_;
    const Vec3i shift(static_cast<int>(std::lround(dg.x())), static_cast<int>(std::lround(dg.y())),
                      static_cast<int>(std::lround(dg.z())));
    Vec3 firstDir = s.axis;
    if (s.samples.size() > 1 && travel.norm() > 0) firstDir = travel.normalized();
    std::vector<Vec3i> under;
    rasterize(brushSolid(s, first.position, first.pressure, firstDir, h_), sk_.mapping, under);
    struct Grab {
      std::int32_t particle;
      Vec3i to;
    };
    std::vector<Grab> grabbed;
    std::unordered_set<std::int32_t> seen;
    for (int pass = 0; pass < (op.mirror.axis >= 0 ? 2 : 1); ++pass) {
      Vec3i sh = shift;
      if (pass == 1) sh[op.mirror.axis] = -sh[op.mirror.axis];  // the mirrored brush moves mirrored
      for (const Vec3i& c0 : under) {
        const Vec3i c = pass == 0 ? c0 : mirrorCell(c0, op.mirror, sk_.mapping);
        if (!GridMapping::inGrid(c)) continue;
        const std::int32_t p = particleAt(c);
        if (p < 0 || !seen.insert(p).second) continue;
        const Vec3i to = c + sh;
        if (!GridMapping::inGrid(to))
          throw InputError(file_.path, last.line, "", "move carries particle " + std::to_string(p) +
                                                          " outside the workspace");
        grabbed.push_back({p, to});
      }
    }
    cur_->stamps += op.mirror.axis >= 0 ? 2 : 1;
    for (const Grab& g : grabbed) place(GridMapping::cellOf(protoCell_[static_cast<std::size_t>(g.particle)]), -1);
    for (const Grab& g : grabbed) {
      drop(g.to);  // a particle in the way is replaced (counted as removed by this move)
      place(g.to, g.particle);
      protoCell_[static_cast<std::size_t>(g.particle)] = static_cast<std::int32_t>(GridMapping::linear(g.to));
      ++cur_->moved;
    }
  }

  // Compacts away removed particles and groups the rest by body (stable), so
  // every body is a contiguous range; rebuilds M with the final indices.
  void finalize() {
    // Body of each operation: named bodies share one index, unnamed creates get their own.
    std::vector<int> bodyOfOp(file_.operations.size(), -1);
    std::map<std::string, int> named;
    std::vector<std::string> names;
    for (const Operation& op : file_.operations) {
      const bool creates = op.kind != Operation::Kind::kStroke || op.stroke.op == StrokeOp::kCreate;
      if (!creates) continue;
      if (op.body.empty()) {
        bodyOfOp[static_cast<std::size_t>(op.id)] = static_cast<int>(names.size());
        names.push_back("stroke " + std::to_string(op.id));
      } else {
        auto [it, fresh] = named.emplace(op.body, static_cast<int>(names.size()));
        if (fresh) names.push_back(op.body);
        bodyOfOp[static_cast<std::size_t>(op.id)] = it->second;
      }
    }
    // Particles grouped by body (in body order), in creation order within a body:
    // each body takes the runs of its operations in the order they were applied.
    // The runs are cut into pieces; counting the live particles of every piece fixes
    // where each piece writes, so the pieces are written in parallel and the result
    // does not depend on the threads. (A fresh output array costs a page fault per
    // 4 KiB, which two threads take twice as fast.)
    constexpr std::int32_t kPiece = 1 << 14;
    struct Piece {
      int op;
      std::int32_t first, end;  // particles [first, end) of protoCell_
      std::size_t out = 0;      // live particles, then their first output index
    };
    std::vector<Piece> pieces;
    std::vector<std::size_t> firstPiece(names.size() + 1, 0);  // the pieces of body b: [firstPiece[b], firstPiece[b+1])
    for (std::size_t b = 0; b < names.size(); ++b) {
      firstPiece[b] = pieces.size();
      for (const OpRun& run : opRuns_)
        if (bodyOfOp[static_cast<std::size_t>(run.op)] == static_cast<int>(b))
          for (std::int32_t f = run.first; f < run.end; f += kPiece) pieces.push_back({run.op, f, std::min(run.end, f + kPiece)});
    }
    firstPiece[names.size()] = pieces.size();
    tbb::parallel_for(std::size_t(0), pieces.size(), [&](std::size_t p) {
      for (std::int32_t i = pieces[p].first; i < pieces[p].end; ++i) pieces[p].out += protoCell_[static_cast<std::size_t>(i)] >= 0;
    });
    std::size_t total = 0;
    for (Piece& pc : pieces) {
      sk_.operations[static_cast<std::size_t>(pc.op)].remaining += static_cast<std::int32_t>(pc.out);
      total += std::exchange(pc.out, total);
    }
    // At rest and prescribed: static while sketched (Phys-Sketch §4); the values of ParticleArrays::resize.
    ParticleArrays out;
    std::vector<Vec3i> cells;
    tbb::parallel_invoke([&] { out.x.resize(total), out.vx.resize(total), out.mass.resize(total), out.stroke.resize(total); },
                         [&] { out.y.resize(total), out.vy.resize(total), out.phase.resize(total, phase::make(-1, phase::kPrescribed)), out.material.resize(total); },
                         [&] { out.z.resize(total), out.vz.resize(total), cells.resize(total); });
    out.resize(total);  // sizes any array the lines above do not name (none now; a no-op for the rest)
    tbb::parallel_for(std::size_t(0), pieces.size(), [&](std::size_t p) {
      const Piece& pc = pieces[p];
      const std::int16_t material = sk_.operations[static_cast<std::size_t>(pc.op)].material;
      std::size_t j = pc.out;
      for (std::int32_t i = pc.first; i < pc.end; ++i) {
        const std::int32_t l = protoCell_[static_cast<std::size_t>(i)];
        if (l < 0) continue;  // removed
        const Vec3i c = GridMapping::cellOf(l);
        const Vec3 q = sk_.mapping.toWorld(c);  // Eq. 5: the particle sits at its voxel centre
        out.x[j] = static_cast<float>(q.x());
        out.y[j] = static_cast<float>(q.y());
        out.z[j] = static_cast<float>(q.z());
        out.stroke[j] = pc.op;
        out.material[j] = material;
        cells[j] = c;
        // M with the final indices (removed particles' cells are empty already).
        if (i != static_cast<std::int32_t>(j)) sk_.grid.set(c, static_cast<std::int32_t>(j));
        ++j;
      }
    });
    std::vector<std::int64_t> start(names.size() + 1, static_cast<std::int64_t>(total));
    for (std::size_t b = 0; b < names.size(); ++b)
      if (firstPiece[b] < pieces.size()) start[b] = static_cast<std::int64_t>(pieces[firstPiece[b]].out);
    for (std::size_t b = names.size(); b-- > 0;)  // a body without pieces starts where the next one does
      if (firstPiece[b] == firstPiece[b + 1]) start[b] = start[b + 1];
    std::vector<int> newBody(names.size(), -1);
    for (std::size_t b = 0; b < names.size(); ++b) {
      const std::int64_t c = start[b + 1] - start[b];
      if (c == 0) continue;
      newBody[b] = static_cast<int>(sk_.bodies.size());
      BodyRange r;
      r.first = static_cast<std::int32_t>(start[b]);
      r.count = static_cast<std::int32_t>(c);
      r.stroke = out.stroke[static_cast<std::size_t>(start[b])];
      r.init = bodyInit(file_.operations[static_cast<std::size_t>(r.stroke)]);
      sk_.bodies.push_back(r);
      sk_.bodyNames.push_back(names[b]);
    }
    for (auto& sum : sk_.operations) {
      const int b = bodyOfOp[static_cast<std::size_t>(sum.id)];
      sum.body = b >= 0 ? newBody[static_cast<std::size_t>(b)] : -1;
    }
    sk_.particles = std::move(out);
    sk_.cells = std::move(cells);
    lint(named);
  }

  void lint(const std::map<std::string, int>& named) {
    auto warn = [&](int line, const std::string& text) {
      sk_.warnings.push_back(file_.path + ":" + std::to_string(line) + ": " + text);
    };
    for (const auto& s : sk_.operations) {
      if (!s.active) continue;
      if (s.minFeature > 0 && s.minFeature < 2 * h_)
        warn(s.line, s.what + ": feature of " + std::to_string(s.minFeature) +
                         " m is thinner than two particle spacings (" + std::to_string(2 * h_) + " m)");
      if (s.created > 0 && s.remaining == 0) warn(s.line, s.what + ": every particle it created is removed later");
      if (s.material >= 0 && s.created == 0 && s.moved == 0)
        warn(s.line, s.what + ": creates no particle (all its voxels were already taken)");
    }
    std::vector<bool> used(materials_.size(), false);
    for (auto m : sk_.particles.material) used[static_cast<std::size_t>(m)] = true;
    for (std::size_t m = 0; m < materials_.size(); ++m)
      if (!used[m]) sk_.warnings.push_back("material '" + materials_[m].name + "' is never used");
    // A named body whose strokes do not touch is one rigid body held together by nothing.
    for (const auto& [name, unused] : named) {
      (void)unused;
      for (std::size_t b = 0; b < sk_.bodies.size(); ++b) {
        if (sk_.bodyNames[b] != name) continue;
        const int parts = components(sk_.bodies[b]);
        if (parts > 1)
          sk_.warnings.push_back("body '" + name + "' is made of " + std::to_string(parts) +
                                 " pieces that do not touch; it still moves as one rigid body");
      }
    }
  }

  // 26-connected components of a body's cells.
  int components(const BodyRange& b) const {
    std::vector<char> seen(static_cast<std::size_t>(b.count), 0);
    int parts = 0;
    for (std::int32_t s = 0; s < b.count; ++s) {
      if (seen[static_cast<std::size_t>(s)]) continue;
      ++parts;
      std::queue<std::int32_t> q;
      q.push(s);
      seen[static_cast<std::size_t>(s)] = 1;
      while (!q.empty()) {
        const Vec3i c = sk_.cells[static_cast<std::size_t>(b.first + q.front())];
        q.pop();
        for (int dz = -1; dz <= 1; ++dz)
          for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) {
              const Vec3i nb = c + Vec3i(dx, dy, dz);
              if (!GridMapping::inGrid(nb)) continue;
              const std::int32_t p = sk_.grid.at(nb) - b.first;
              if (p < 0 || p >= b.count || seen[static_cast<std::size_t>(p)]) continue;
              seen[static_cast<std::size_t>(p)] = 1;
              q.push(p);
            }
      }
    }
    return parts;
  }

  const StrokeFile& file_;
  const std::vector<Material>& materials_;
  std::map<std::string, StampMesh> meshes_;  // stamp meshes by path, loaded once
  std::unique_ptr<CellMask> mask_;           // cells the current stroke has covered (made on the first stroke)
  std::vector<std::unique_ptr<CellMask>> partMasks_;  // the other parts of a stroke swept in parallel
  Sketch sk_;
  double h_;
  // Particles while sketching, in creation order: the linear grid cell of each, -1
  // once removed. The particles one operation created are consecutive: a run.
  std::vector<std::int32_t> protoCell_;
  struct OpRun {
    int op;
    std::int32_t first, end;  // particles [first, end)
  };
  std::vector<OpRun> opRuns_;
  CellMask occ_;  // cells holding a particle (see take())
  std::int64_t live_;  // particles alive now, including those counted in from elsewhere
  OperationSummary* cur_ = nullptr;
};

}  // namespace

void interpolateSegment(const Vec3& prev, const Vec3& cur, double particleDiameter, std::vector<Vec3>& out) {
  out.clear();
  const Vec3 travel = cur - prev;  // V * dt
  const double dist = travel.norm();
  if (dist == 0.0 || particleDiameter <= 0.0) {
    out.push_back(cur);
    return;
  }
  const Vec3 dir = travel / dist;
  const long iMax = std::lround(dist / particleDiameter);  // Eq. 6
  out.reserve(static_cast<std::size_t>(iMax) + 1);
  for (long i = 0; i <= iMax; ++i) out.push_back(cur - double(i) * particleDiameter * dir);  // Eq. 7
}

Solid brushSolid(const Stroke& s, const Vec3& position, double pressure, const Vec3& direction, double voxelSize) {
  Solid b;
  b.centre = position;
  const double size = s.size * pressure;
  const Vec3 axis = s.orient == Orientation::kFollow ? direction : s.axis;
  b.rotation = frameFromAxis(axis);
  switch (s.brush) {
    case BrushShape::kSphere:
      b.shape = SolidShape::kSphere, b.a = 0.5 * size;
      break;
    case BrushShape::kCube:
      b.shape = SolidShape::kCube, b.a = 0.5 * size;  // with the default axis (y) the frame is an axis permutation
      break;
    case BrushShape::kCylinder:
      b.shape = SolidShape::kCylinder, b.a = 0.5 * size, b.b = 0.5 * (s.length > 0 ? s.length : size);
      break;
    case BrushShape::kDisc:
      // A disc is a cylinder one cell thick unless given a thickness: the "extrusion plane" of §4.2.
      b.shape = SolidShape::kCylinder, b.a = 0.5 * size, b.b = 0.5 * (s.length > 0 ? s.length : voxelSize);
      break;
    case BrushShape::kCapsule:
      b.shape = SolidShape::kCapsule, b.a = 0.5 * size, b.b = 0.5 * (s.length > 0 ? s.length : size);
      break;
  }
  return b;
}

Vec3i mirrorCell(const Vec3i& cell, const Mirror& mirror, const GridMapping& m) {
  if (mirror.axis < 0) return cell;
  Vec3 p = m.center();
  p[mirror.axis] = mirror.offset;
  const long twice = std::lround(2.0 * m.toGrid(p)[mirror.axis]);  // plane at a cell centre or face
  Vec3i out = cell;
  out[mirror.axis] = static_cast<int>(twice - cell[mirror.axis]);
  return out;
}

Sketch voxelize(const StrokeFile& file, const GridMapping& mapping, const std::vector<Material>& materials) {
  return Builder(file, materials, mapping).run();
}

}  // namespace physketch::sketch
