// Applying one operation of the stroke file to the particles (Alg. 1 and 2):
// the input checks an operation needs, its footprint (the cells it covers, with
// its mirror copy) and what a create, a remove or a move does with it.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/material.h"
#include "sketch/brush.h"
#include "sketch/mesh_stamp.h"
#include "sketch/rasterize.h"
#include "sketch/sketch_cells.h"
#include "sketch/strands.h"
#include "sketch/strokes.h"

namespace physketch::sketch {

// The checks of an operation against the scene: each throws InputError naming the
// stroke file, the line and the field.
class InputChecks {
 public:
  InputChecks(std::string strokeFile, const std::vector<Material>& materials, const GridMapping& mapping)
      : path_(std::move(strokeFile)), materials_(materials), mapping_(mapping) {}
  // The index of the operation's material in the scene (field 'material').
  std::int16_t material(const Operation& op) const;
  // The kind of a create's material when it makes a rope or a cloth (sketch/strands.h);
  // nothing for a voxel kind or an unknown material (material() reports that).
  std::optional<MaterialKind> strandKind(const Operation& op) const;
  // A point that must lie in the workspace (field: the axis it leaves by, 'x', 'y' or 'z').
  void inside(const Vec3& p, int line, const char* what) const;
  // Every sample of a stroke.
  void samplesInside(const Stroke& s) const;
  const std::string& path() const { return path_; }
  const GridMapping& mapping() const { return mapping_; }

 private:
  std::string path_;
  const std::vector<Material>& materials_;
  const GridMapping& mapping_;
};

// The cells an operation covers before its mirror copy (a stroke's swept stamps
// in a bit mask, or a list), and the mirror that copies them.
class Footprint {
 public:
  Footprint(const CellMask* mask, const std::vector<Vec3i>* cells, const Mirror& mirror, const GridMapping& mapping,
            std::int64_t stamps)
      : mask_(mask), cells_(cells), mirror_(mirror), mapping_(mapping), stamps_(stamps) {}

  // Calls f(cell) for each cell, then for each cell of the mirror copy that lies in the grid.
  template <class CellFn>
  void forEachCell(CellFn&& f) const {
    for (int pass = 0; pass < copies(); ++pass) {
      auto visit = [&](const Vec3i& c0) {
        const Vec3i c = pass == 0 ? c0 : mirrorCell(c0, mirror_, mapping_);
        if (GridMapping::inGrid(c)) f(c);
      };
      if (mask_) mask_->forEachCell(visit);
      else
        for (const Vec3i& c : *cells_) visit(c);
    }
  }
  int copies() const { return mirror_.axis >= 0 ? 2 : 1; }
  // Cells of both copies (an upper bound: the copies may overlap).
  std::int64_t count() const { return (mask_ ? mask_->count() : static_cast<std::int64_t>(cells_->size())) * copies(); }
  const CellMask* mask() const { return mask_; }
  // Brush positions stamped, mirror copies included.
  std::int64_t stamps() const { return stamps_; }

 private:
  const CellMask* mask_;
  const std::vector<Vec3i>* cells_;
  Mirror mirror_;
  const GridMapping& mapping_;
  std::int64_t stamps_;
};

// Makes footprints. Owns the bit masks strokes are swept into and the mesh stamps
// loaded so far, so a footprint is valid until the next one is made.
class Footprints {
 public:
  // `threads`: the parts a long stroke is cut into (>= 1); the result does not depend on it.
  Footprints(const GridMapping& mapping, int threads) : mapping_(mapping), threads_(threads) {}

  // A create or remove stroke: every stamp (Eq. 6-7).
  Footprint stroke(const Operation& op);
  Footprint primitive(const Operation& op);
  // A mesh stamp; a bad mesh file is reported against the stamp record's 'path'.
  Footprint meshStamp(const Operation& op, const std::string& strokeFile);

 private:
  void sweep(const Stroke& s, const std::vector<Stamp>& stamps);

  const GridMapping& mapping_;
  int threads_;
  std::unique_ptr<CellMask> mask_;                    // the current stroke's cells (made on the first stroke)
  std::vector<std::unique_ptr<CellMask>> partMasks_;  // the other parts of a stroke swept in parallel
  std::vector<Vec3i> cells_;                          // the current primitive's or mesh stamp's cells
  std::map<std::string, StampMesh> meshes_;           // stamp meshes by path, loaded once
};

// Alg. 1: a particle in every free cell of the footprint, in z, y, x order (then
// the mirror copy). `Store` is SketchCells (before play) or NewBodyCells (after).
template <class Store>
void createIn(const Footprint& fp, Store& store) {
  store.reserve(fp.count());
  if (fp.mask() && fp.copies() == 1)  // the common case: a word of free cells at a time
    fp.mask()->forEachCellNotIn(store.occupied(), [&](const Vec3i& c) { store.takeFree(c); });
  else
    fp.forEachCell([&](const Vec3i& c) { store.take(c); });
}

// Checks a create operation's input and makes its footprint; records its material
// and stamps in `sum`.
Footprint createFootprint(const Operation& op, Footprints& footprints, const InputChecks& checks,
                          OperationSummary& sum);

// Checks a rope or cloth create's input and makes its shapes: the drawn one, then its
// mirror copy; every node must lie in the workspace (an error names its sample's line and
// the axis). Records its material and nodes (as stamps) in `sum`.
std::vector<StrandShape> strandCopies(const Operation& op, MaterialKind kind, const InputChecks& checks,
                                      OperationSummary& sum);

// Applies an operation that starts before play to the sketch: voxels go to `cells`, ropes
// and cloth to `strands` (counted against the cap in `cells`); removes and moves act on both.
void applyBeforePlay(const Operation& op, Footprints& footprints, const InputChecks& checks, SketchCells& cells,
                     Strands& strands, OperationSummary& sum);

}  // namespace physketch::sketch
