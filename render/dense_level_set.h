// The narrow-band level set of a set of lattice cells, built and smoothed on a dense box with
// the same finite-difference updates OpenVDB's tools apply to its sparse tree:
//   fromCells      = tools::topologyToLevelSet (closing, step field, 3 x halfWidth first-order
//                    renormalization sweeps, trim, its box-mean smoothing step),
//   meanCurvature  = tools::LevelSetFilter::meanCurvature (a flow step, then the tracker's
//                    one-voxel dilation, renormalization and trim),
//   normalize      = tools::LevelSetTracker::normalize (FIRST_BIAS, TVD_RK1),
//   measure        = tools::LevelSetMeasure's area and volume (the smeared Dirac delta; summed
//                    in another order, so equal to rounding, where the others are bit for bit).
// Why: OpenVDB reaches each band voxel through accessors and stencil objects, about 50 ns a
// voxel a sweep here; a meshed body's level set runs ~17 such sweeps, most of a frame dump's
// time (docs/benchmarks.md). The same arithmetic over a flat array of the box costs a few ns a
// voxel. test_render checks the two agree voxel by voxel; vdb_bridge.cpp keeps OpenVDB's path
// for boxes too large to hold densely, and turns the result into an OpenVDB grid for meshing and
// export. No OpenVDB header here.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "core/math.h"

namespace physketch::render {

class DenseLevelSet {
 public:
  // The box a level set of these cells needs (cells' bounds plus the band and its growth), in
  // voxels (saturating at 2^64 - 1 for boxes over 2^40); compare against a budget before
  // calling fromCells. 0 for no cells.
  static std::uint64_t boxVoxels(const std::vector<Vec3i>& cells, int halfWidth, int closingSteps);

  // topologyToLevelSet(cells, halfWidth, closingSteps, dilation 0, smoothingSteps) on voxels of
  // edge voxelSize (distances in metres). Throws std::invalid_argument for no cells or a box of
  // more than 2^32 voxels.
  static DenseLevelSet fromCells(const std::vector<Vec3i>& cells, double voxelSize, int halfWidth, int closingSteps,
                                 int smoothingSteps);

  // `sweeps` Jacobi sweeps of |grad phi| = 1 over the active band (first-order upwind, Euler
  // steps of 0.3 voxel), as LevelSetTracker::normalize.
  void normalize(int sweeps);
  // Band voxels at or beyond the background (+-halfWidth voxels) leave the band, set to it.
  void trim();
  // Adds the six face neighbours of every band voxel to the band (their values stay +-background).
  void dilate();
  // LevelSetTracker::track with `sweeps` renormalization sweeps.
  void track(int sweeps) {
    dilate();
    normalize(sweeps);
    trim();
  }
  // One step of LevelSetFilter::meanCurvature (dt = h^2 / 3), then track(sweeps).
  void meanCurvature(int sweeps);
  // Adds d (m) to every band voxel: the surface moves by -d along its normal.
  void offset(float d);
  // LevelSetMeasure's area (m^2) and enclosed volume (m^3).
  void measure(double& area, double& volume) const;

  // The box: voxel (x, y, z) of the arrays is lattice cell lo + (x, y, z), at index
  // x + dims.x * (y + dims.y * z). Voxels off the band hold +-background().
  const Vec3i& lo() const { return lo_; }
  const Vec3i& dims() const { return dims_; }
  std::size_t index(int x, int y, int z) const {
    return std::size_t(x) + std::size_t(dims_.x()) * (std::size_t(y) + std::size_t(dims_.y()) * std::size_t(z));
  }
  const std::vector<float>& values() const { return phi_; }
  bool active(std::size_t i) const { return active_[i] != 0; }
  const std::vector<std::uint32_t>& band() const { return band_; }
  float background() const { return background_; }
  // True once a dilation reached the box's outer layer, where the band could not grow as
  // OpenVDB's would: from then on the two may differ (the caller falls back to OpenVDB). The
  // margin keeps a surface that moves by a few voxels well inside.
  bool reachedBorder() const { return reachedBorder_; }

 private:
  // Jacobi: the new band values, computed into scratch_ in band order, replace the old ones.
  void applyScratch();
  void rebuildBand();  // band_ from active_
  void rebuildRuns();  // runs_ from band_
  // Three passes of a 3-voxel box mean along one axis each, as LevelSetFilter::mean(1).
  void boxMean();

  Vec3i lo_ = Vec3i::Zero(), dims_ = Vec3i::Zero();
  double h_ = 0.0;  // the voxel size as the grid's transform holds it
  float dx_ = 0.0f, background_ = 0.0f;  // as LevelSetTracker holds it (float)
  bool reachedBorder_ = false;
  std::vector<float> phi_;
  std::vector<std::uint8_t> active_;
  std::vector<std::uint8_t> border_;  // the box's outer layer, never on the band
  std::vector<std::uint32_t> band_;  // active voxels' indices, ascending
  // Runs of consecutive indices in band_ (a row's voxels along x): first position, length.
  std::vector<std::pair<std::uint32_t, std::uint32_t>> runs_;
  std::vector<float> scratch_;
};

}  // namespace physketch::render
