// Rasterizing solids into the sketch grid (Phys-Sketch Alg. 1: a cell belongs to
// a solid when its centre is inside). Every function visits the cells row by row
// (z, then y, then x ascending), one interval of x per row of a convex solid found
// in closed form, so the cost is one small solve per row rather than one test per cell.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "core/math.h"
#include "sketch/grid.h"
#include "sketch/solids.h"

namespace physketch::sketch {

// The cells whose centres lie inside `solid`, in z, y, x order; when none does
// (a solid smaller than a cell), the cell containing its centre. Cells outside
// the grid are skipped (Alg. 1: "if p in M"). `out` is cleared first.
void rasterize(const Solid& solid, const GridMapping& mapping, std::vector<Vec3i>& out);

// A set of cells of the 151^3 grid, one bit per cell (a row of 151 cells in 3 words
// of 64 bits, padded to 4 so each row is one aligned 32-byte vector: 713 KiB).
// A stroke is thousands of stamps that overlap almost entirely: each stamp only ORs
// its row runs into the mask (a few word operations per row, no lookup per cell),
// and the operation then applies every covered cell once, in z, y, x order.
class CellMask {
 public:
  CellMask();
  CellMask(const CellMask&) = delete;
  CellMask& operator=(const CellMask&) = delete;

  // Marks the cells of `solid` (those rasterize() gives).
  void add(const Solid& solid, const GridMapping& mapping);
  // Calls f(cell) for every marked cell, in z, y, x order.
  template <class CellFn>
  void forEachCell(CellFn&& f) const {
    for (int k = k0_; k <= k1_; ++k)
      for (int j = j0_; j <= j1_; ++j) {
        const std::uint64_t* w = row(j, k);
        for (int q = 0; q < kWords; ++q)
          for (std::uint64_t b = w[q]; b; b &= b - 1) f(Vec3i(q * 64 + __builtin_ctzll(b), j, k));
      }
  }
  // Unmarks every cell (costs the rows marked since the last clear only).
  void clear();
  // Calls f(cell) for every cell marked here and not in `taken`, in z, y, x order,
  // and marks it in `taken` (a whole word of cells at a time).
  template <class CellFn>
  void forEachCellNotIn(CellMask& taken, CellFn&& f) const {
    for (int k = k0_; k <= k1_; ++k)
      for (int j = j0_; j <= j1_; ++j) {
        const std::uint64_t* w = row(j, k);
        std::uint64_t* t = taken.row(j, k);
        for (int q = 0; q < kWords; ++q) {
          std::uint64_t fresh = w[q] & ~t[q];
          if (!fresh) continue;
          taken.grow(Vec3i(0, j, k));
          t[q] |= fresh;
          for (; fresh; fresh &= fresh - 1) f(Vec3i(q * 64 + __builtin_ctzll(fresh), j, k));
        }
      }
  }
  // Marks every cell `other` marks.
  void merge(const CellMask& other);
  // Number of marked cells.
  std::int64_t count() const;

  // Single cells (c must be in the grid).
  bool test(const Vec3i& c) const { return (row(c.y(), c.z())[c.x() >> 6] >> (c.x() & 63)) & 1; }
  void set(const Vec3i& c) {
    grow(c);
    row(c.y(), c.z())[c.x() >> 6] |= std::uint64_t(1) << (c.x() & 63);
  }
  void reset(const Vec3i& c) {
    row(c.y(), c.z())[c.x() >> 6] &= ~(std::uint64_t(1) << (c.x() & 63));
    lastBox_[0] = 1, lastBox_[3] = 0;  // the last box may have lost a cell
  }

  static constexpr int kWords = (kGridSize + 63) / 64;  // words a row uses
  static constexpr int kStride = 4;                      // words a row takes

 private:
  void grow(const Vec3i& c) {
    k0_ = std::min(k0_, c.z()), k1_ = std::max(k1_, c.z()), j0_ = std::min(j0_, c.y()), j1_ = std::max(j1_, c.y());
  }
  std::uint64_t* row(int j, int k) { return base_ + (std::size_t(k) * kGridSize + std::size_t(j)) * kStride; }
  const std::uint64_t* row(int j, int k) const { return base_ + (std::size_t(k) * kGridSize + std::size_t(j)) * kStride; }
  void markRow(int j, int k, int i0, int i1);
  std::vector<std::uint64_t> bits_;
  std::uint64_t* base_;  // the first 32-byte aligned word of bits_
  int k0_, k1_, j0_, j1_;  // bounds of the rows marked since the last clear (empty: k0_ > k1_)
  int lastBox_[6] = {1, 0, 0, 0, 0, 0};  // a grid-aligned box whose cells are all marked: lo[3], hi[3]
};

// The previous stamp of a stroke, as row intervals: each stamp hands on only the
// cells its predecessor did not cover. Used for removals while the simulation runs,
// where a cell the brush comes back to must be removed again (bodies move in between),
// so the whole operation's cells cannot be masked.
class StampDiff {
 public:
  // Rasterizes `solid` and writes to `out` (cleared first) its cells outside the
  // previous stamp's, in z, y, x order; remembers this stamp's rows for the next.
  void stamp(const Solid& solid, const GridMapping& mapping, std::vector<Vec3i>& out);

 private:
  struct Rows {
    int j0 = 0, k0 = 0, nj = 0, nk = 0;
    std::vector<int> lo, hi;  // per row (j, k): interval [lo, hi]; empty when lo > hi
    void reset(int j0, int j1, int k0, int k1);
    std::size_t index(int j, int k) const { return std::size_t(k - k0) * std::size_t(nj) + std::size_t(j - j0); }
    bool has(int j, int k) const { return j >= j0 && k >= k0 && j < j0 + nj && k < k0 + nk; }
  };
  Rows prev_, next_;
};

}  // namespace physketch::sketch
