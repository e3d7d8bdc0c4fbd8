// Smooth fluid surfaces from particles: anisotropic kernels (Yu & Turk 2013) with PhyVR's hybrid
// particle-grid variant (../shared/papers/001_47d90fa71c879e78.txt §4.2): no neighbour search.
// Particles splat their count onto a grid of one particle spacing with quadratic B-spline weights;
// each particle then reads that grid back around itself to
//   1. move towards the weighted mean of the cells around it (position smoothing, Eq. 9-12), and
//   2. take the weighted covariance of those cells' positions around its new position (Eq. 13),
//      whose principal axes and singular values (Eq. 14-15), corrected (Eq. 16-19), stretch its
//      kernel: wide along the surface, thin across it, where the cells around it are half empty.
// The kernels are summed into a scalar field on a sparse OpenVDB grid and meshed at half the
// value a particle deep inside the fluid sees, so a resting pool meshes flat, not as a heap of balls.
#pragma once

#include <cstdint>
#include <vector>

#include "core/math.h"
#include "render/mesh.h"

namespace physketch::render {

struct FluidSurfaceOptions {
  // false: every kernel is a ball of radius kernelRadius at the particle (no smoothing, no
  // stretching): the isotropic surface Yu & Turk compare against.
  bool anisotropic = true;
  double kernelRadius = 2.0;   // support radius of an undeformed kernel, in particle spacings
  double voxelFraction = 0.5;  // edge of the field's voxels, in particle spacings
  // The neighbourhood a particle reads from the count grid: nodes within `reach` spacings,
  // each weighted by its count times 1 - (r / reach)^3 (Yu & Turk's weight with cells standing
  // in for neighbours; PhyVR's Eq. 9 adds a B-spline term to the count instead, whose stencil
  // jumps when a particle crosses a cell, which we measured to roughen a resting surface).
  double reach = 3.0;
  // Position smoothing (PhyVR Eq. 10, 12): the step to the weighted mean is scaled by ka, then
  // blended with the old position by lambda. PhyVR's 2.3 and 0.7 were tuned for its weights;
  // with these a jittered resting slab (tests/render/test_fluid_surface.cpp) measured, as the
  // spread of its top normals against isotropic kernels: ka 1, lambda 0.4, reach 3: 0.21x
  // (lambda 0.5: 0.13x, but the level hit its clamp and 3.5 % of the volume was lost); with
  // reach 2 and PhyVR's ka 2.3, lambda 0.7: 0.72x and 6 % of the volume lost.
  double ka = 1.0;
  double lambda = 0.4;
  // Singular-value corrections, relative to the covariance of a particle deep inside: Eq. 16
  // as Yu & Turk mean it (clamp each value into [sigmaMin, sigmaMax]; printed in PhyVR as a
  // max/min pair that would set every value to sigmaMax), then Eq. 17 (no value below the
  // largest / ratio).
  double sigmaMin = 0.5;
  double sigmaMax = 1.5;
  double ratio = 3.0;
  // A particle whose cells hold less than this share of what a particle deep inside sees is
  // spray (Yu & Turk's N < N_eps): its kernel is a ball of half the radius carrying the same
  // mass (8x the weight), so a lone drop still shows instead of falling under the threshold.
  double sprayFullness = 0.4;
  // Mesh the level whose inside holds particles * spacing^3 (the fluid's volume at rest
  // density) instead of half the interior field: the position smoothing pulls the surface
  // layer inwards (a quarter spacing on a flat pool), and this gives it back. The level is
  // lowered by at most half, so spray never swells past 1.3 spacing^3 a drop.
  bool keepVolume = true;
  // Skip the neighbourhood of particles deep inside (see FluidKernels::interior): they cannot
  // shape the surface, and skipping them halves the cost of a thick pool. false gathers and
  // sums every kernel (the reference the tests compare the shortcut against).
  bool skipDeep = true;
};

// One kernel per particle: the field it adds at x is weight * (1 - |u|^2)^3 for |u| < 1, with
// u = inverseAxes * (x - centre). Undeformed kernels have inverseAxes = I / (kernelRadius * h).
struct FluidKernels {
  std::vector<Vec3> centre;
  std::vector<Mat3> inverseAxes;
  std::vector<double> weight;
  // 1 for a particle deep inside (every cell within its neighbourhood full): its kernel is the
  // undeformed ball and cannot reach the surface, so the field only needs to stay above the
  // level there; meshKernelField fills its cell and the cells next to it instead of summing it.
  std::vector<std::uint8_t> interior;
  // Field value deep inside a uniform fluid of one particle per spacing^3 (a lattice sum of
  // the undeformed kernel); the surface is meshed at half of it.
  double interiorField = 0.0;
  // Half the edge of the cube an interior particle fills (m): one particle spacing.
  double fillRadius = 0.0;
};

// The kernels of these particles (one per position, same order). Throws RuntimeError on a
// non-finite position or spacing or an option out of range. Deterministic: a pure function of
// the positions, in any thread count.
FluidKernels fluidKernels(const std::vector<Vec3>& positions, double spacing, const FluidSurfaceOptions& options = {});

struct FluidSurfaceReport {
  double particleVolume = 0.0;  // particles * spacing^3 (m^3)
  double meshVolume = 0.0;      // enclosed by the mesh (m^3)
  double level = 0.0;           // the field level meshed, as a fraction of the interior field
};

// The surface of these fluid particles (spacing: their rest distance, m): fluidKernels summed on
// a grid of voxelFraction * spacing and meshed with volumeToMesh at interiorField / 2 (or the
// level keepVolume picks). A closed mesh, normals outward, byte-identical for the same
// positions in any thread count.
TriangleMesh meshFluid(const std::vector<Vec3>& positions, double spacing, const FluidSurfaceOptions& options = {},
                       FluidSurfaceReport* report = nullptr);

// Implemented in vdb_bridge.cpp: sums the kernels into a sparse grid of `voxelSize` and meshes
// the level field == iso (inside where the field is larger). With targetVolume > 0 (m^3) the
// level is lowered from iso, by at most half, until the inside holds that volume (counted in
// voxels); isoUsed, when given, receives the level meshed.
TriangleMesh meshKernelField(const FluidKernels& kernels, double voxelSize, double iso, double targetVolume = 0.0,
                             double* isoUsed = nullptr);

}  // namespace physketch::render
