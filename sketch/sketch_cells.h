// The particles while an operation list is replayed, one per grid cell (Alg. 1
// and 2 on single cells). A particle is only the linear index of its cell here;
// positions (Eq. 5) and the SoA arrays are made once at the end (sketch/bodies.h).
#pragma once

#include <algorithm>
#include <cstdint>
#include <unordered_map>
#include <utility>
#include <vector>

#include "sketch/grid.h"
#include "sketch/rasterize.h"
#include "sketch/voxelize.h"

namespace physketch::sketch {

// Thrown when an operation would cross the particle cap; voxelize() turns it into
// an InputError naming the operation's line and field.
struct CapReached {};

// The particles one operation created are consecutive: a run.
struct OpRun {
  int op;
  std::int32_t first, end;  // particles [first, end)
};

// What both stores below share: a new particle per free cell, in creation order,
// counted against the cap and into the current operation's summary.
class CellLog {
 public:
  // `alreadyLive` particles exist elsewhere and count towards the cap.
  explicit CellLog(std::int64_t alreadyLive) : live_(alreadyLive) {}

  // What follows is done by `op`: particles it creates or removes are counted there.
  void begin(OperationSummary& op) { cur_ = &op; }
  // Cells holding a particle: "is this cell free" reads bits that stay in cache.
  CellMask& occupied() { return occ_; }
  // Room for `more` particles, growing geometrically (many small operations stay linear).
  void reserve(std::int64_t more) {
    const std::size_t want = cell_.size() + static_cast<std::size_t>(std::min<std::int64_t>(more, kMaxParticles));
    if (want > cell_.capacity()) cell_.reserve(std::max(want, 2 * cell_.capacity()));
  }
  // Particles kept outside the cells (ropes and cloth, sketch/strands.h): `n` more count
  // towards the cap and into the current operation's summary.
  void admit(std::int64_t n) {
    if (live_ + n > kMaxParticles) throw CapReached{};
    live_ += n;
    cur_->created += static_cast<std::int32_t>(n);
  }
  // ... and `n` of them removed, or carried by a move.
  void release(std::int64_t n) {
    live_ -= n;
    cur_->removed += static_cast<std::int32_t>(n);
  }
  void carried(std::int64_t n) { cur_->moved += static_cast<std::int32_t>(n); }
  // Per particle: the linear index of its cell; ~index (< 0) once removed.
  const std::vector<std::int32_t>& cells() const { return cell_; }
  const std::vector<OpRun>& runs() const { return runs_; }

 protected:
  // A new particle in cell c (free, already marked in occ_). Returns its index.
  std::int32_t append(const Vec3i& c) {
    if (live_ >= kMaxParticles) throw CapReached{};
    const auto p = static_cast<std::int32_t>(cell_.size());
    cell_.push_back(static_cast<std::int32_t>(GridMapping::linear(c)));
    if (runs_.empty() || runs_.back().op != cur_->id) runs_.push_back({cur_->id, p, p});
    ++runs_.back().end;
    ++live_;
    ++cur_->created;
    return p;
  }

  std::vector<std::int32_t> cell_;
  std::vector<OpRun> runs_;
  CellMask occ_;
  std::int64_t live_;
  OperationSummary* cur_ = nullptr;
};

// The sketch before play: particles that removes and moves can find by cell, via
// M (which holds each particle's index into cells() while sketching).
class SketchCells : public CellLog {
 public:
  explicit SketchCells(OccupancyGrid& grid) : CellLog(0), grid_(grid) {}

  std::int32_t particleAt(const Vec3i& c) const { return occ_.test(c) ? grid_.at(c) : -1; }
  // Alg. 1: a particle at the centre of c unless one is there (never two in a voxel).
  void take(const Vec3i& c) {
    if (occ_.test(c)) return;
    occ_.set(c);
    takeFree(c);
  }
  // take() of a cell known to be free and already marked in occupied().
  void takeFree(const Vec3i& c) { grid_.set(c, append(c)); }
  // Alg. 2: frees c and removes its particle, if any.
  void drop(const Vec3i& c) {
    const std::int32_t p = particleAt(c);
    if (p < 0) return;
    cell_[static_cast<std::size_t>(p)] = ~cell_[static_cast<std::size_t>(p)];  // keeps where it was (bodies.h)
    place(c, -1);
    --live_;
    ++cur_->removed;
  }
  // Move: each (particle, cell) pair carries the particle to the cell, all lifted
  // first; a particle already in a target cell is replaced (dropped).
  void relocate(const std::vector<std::pair<std::int32_t, Vec3i>>& moves) {
    for (const auto& [p, to] : moves) {
      (void)to;
      const std::int32_t from = cell_[static_cast<std::size_t>(p)];
      movedFrom_.emplace(p, from);  // the first move keeps the cell it was created in
      place(GridMapping::cellOf(from), -1);
    }
    for (const auto& [p, to] : moves) {
      drop(to);
      place(to, p);
      cell_[static_cast<std::size_t>(p)] = static_cast<std::int32_t>(GridMapping::linear(to));
      ++cur_->moved;
    }
  }
  // The cell particle p was created in (a removed or moved particle's too).
  std::int32_t bornCell(std::int32_t p) const {
    const auto it = movedFrom_.find(p);
    if (it != movedFrom_.end()) return it->second;
    const std::int32_t c = cell_[static_cast<std::size_t>(p)];
    return c >= 0 ? c : ~c;
  }
  // Particles a move carried (each once), by index.
  std::vector<std::int32_t> movedParticles() const {
    std::vector<std::int32_t> out;
    for (const auto& kv : movedFrom_) out.push_back(kv.first);
    std::sort(out.begin(), out.end());
    return out;
  }
  OccupancyGrid& grid() { return grid_; }

 private:
  void place(const Vec3i& c, std::int32_t p) {
    if (p >= 0) occ_.set(c);
    else occ_.reset(c);
    grid_.set(c, p);
  }
  OccupancyGrid& grid_;
  std::unordered_map<std::int32_t, std::int32_t> movedFrom_;  // particle -> linear cell it was created in
};

// Creates after play: the sketch's bodies have moved away from their voxels, so
// these are voxelized into a grid of their own, where they must not overlap each
// other; nothing removes or moves them here, so a bit mask of taken cells is all
// the grid they need.
class NewBodyCells : public CellLog {
 public:
  explicit NewBodyCells(std::int64_t sketchParticles) : CellLog(sketchParticles) {}
  void take(const Vec3i& c) {
    if (occ_.test(c)) return;
    occ_.set(c);
    append(c);
  }
  void takeFree(const Vec3i& c) { append(c); }
};

}  // namespace physketch::sketch
