// Voxel set or particle cloud -> closed triangle surface, through OpenVDB:
//   lattice voxels -> narrow-band level set (tools::topologyToLevelSet's updates, run on a dense
//   box by render/dense_level_set.h, or OpenVDB's own tools) -> tools::volumeToMesh.
// Implemented in vdb_bridge.cpp, the translation unit that includes OpenVDB for these.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/math.h"
#include "core/node_field.h"
#include "render/mesh.h"

namespace physketch::render {

struct VoxelMeshOptions {
  int halfWidth = 3;        // narrow-band half width of the level set (voxels)
  int closingSteps = 0;     // dilate/erode steps that close small gaps (voxels)
  int smoothingSteps = 1;   // level-set smoothing steps; 0 keeps the blocky "legolized" look
  double adaptivity = 0.0;  // volumeToMesh adaptivity; 0 gives watertight, non-self-intersecting meshes
  // How the level set is built and smoothed before volumeToMesh: true, OpenVDB's updates
  // (topologyToLevelSet, LevelSetFilter, LevelSetMeasure) run on a dense box around the cells
  // (render/dense_level_set.h: the same arithmetic, several times faster); false, OpenVDB's own
  // tools on its tree, which a box of more than kDenseLevelSetVoxels voxels also takes.
  bool denseLevelSet = true;
};

// The largest box (voxels) a level set is built on densely: 4 Mi voxels hold 36 MiB of work
// arrays (about twice that at the peak: the smoothing step's copy and the closing's masks), and
// the whole 151^3 sketch grid fits.
constexpr std::uint64_t kDenseLevelSetVoxels = std::uint64_t(1) << 22;

// voxels: integer lattice coordinates of occupied cells; the centre of cell (i,j,k)
// is origin + h*(i,j,k) in metres. Returns a closed mesh around the union of the
// cells (each cell a cube of edge h), normals outward, triangles counter-clockwise.
// An empty voxel list gives an empty mesh.
TriangleMesh meshVoxels(const std::vector<Vec3i>& voxels, double voxelSize, const Vec3& origin,
                        const VoxelMeshOptions& options = {});

struct ParticleMeshOptions {
  // One closing step (dilate, then erode, by one cell): particles off the lattice leave some
  // cells empty and put two particles in others (a ball's lattice rotated by 0.7 rad marks
  // 18% fewer cells than it has particles); closing fills such one-cell holes, which would
  // otherwise become small inner surfaces.
  VoxelMeshOptions surface{/*halfWidth=*/3, /*closingSteps=*/1, /*smoothingSteps=*/1, /*adaptivity=*/0.0};
  // A lattice point (m). Pass the centre of the sketch grid's cell (0,0,0) so particles still
  // at their sketched positions land exactly on cell centres, one particle per cell.
  Vec3 latticeOrigin = Vec3::Zero();
  // The smoothing knob (physketch run --smooth N): N iterations of mean-curvature flow on the
  // level set (OpenVDB LevelSetFilter::meanCurvature), which flattens the voxel staircase, then
  // a dilation that gives back the volume the flow took (below). 0: no filter.
  int smoothIterations = 0;
  // > 0 (m^3): before smoothing, the level set is moved along its normal until it encloses this
  // volume (the particles' own, spacing^3 each, times their volume ratio). The union of marked
  // cells of particles off the lattice holds more than they do (closing fills gaps, and a
  // rotated lattice marks cells partly), 7 % more for a spinning ball. After meshing, a mesh
  // still 0.2 % or more off it is moved by the difference over its area (the dual mesh cuts
  // the level set's corners: -1.3 % of a ball): its vertices along their normals when that is
  // outwards and under a quarter of a cell, else by meshing once more at that isovalue. 0: the
  // cells' surface as it is.
  double targetVolume = 0.0;
};

// The volume (m^3) enclosed by a level set before and after smoothIterations, measured on the
// level set (OpenVDB levelSetVolume). Mean-curvature flow moves a convex surface inwards, so
// the filter shrinks the solid; the dilation afterwards offsets the surface outwards by
// (before - after) / area, twice (the second pass corrects the first to second order), so
// `after` is the volume of what is meshed. Both 0 when smoothIterations is 0.
struct SmoothingReport {
  double volumeBefore = 0.0;
  double volumeAfter = 0.0;
  // (after - before) / before, 0 when nothing was smoothed.
  double relativeChange() const { return volumeBefore > 0.0 ? (volumeAfter - volumeBefore) / volumeBefore : 0.0; }
};

// Where meshParticles' time went (s), for benchmarks and reports.
struct MeshStageTimes {
  double cells = 0.0;      // particles -> lattice cells
  double levelSet = 0.0;   // cells -> narrow-band level set (topologyToLevelSet's steps, the volume target)
  double smoothing = 0.0;  // the smoothing knob (0 when off)
  double meshing = 0.0;    // volumeToMesh and assembly into a TriangleMesh
  bool denseLevelSet = false;  // the level set was built on a dense box (VoxelMeshOptions), not by OpenVDB's tools
};

// A closed surface around particles that no longer sit on the voxel lattice (soft bodies,
// fluids, MPM): each particle marks the lattice cell whose centre is nearest to it (cells of
// edge particleSpacing, centres at latticeOrigin + particleSpacing*(i,j,k)), and the union of
// the marked cells is meshed exactly as meshVoxels does. Each particle stands for the volume
// of one cell, so the surface encloses about (particle count) * spacing^3 when the particles
// are about one spacing apart; stretched regions (particles over a cell apart) leave holes,
// which options.surface.closingSteps closes up to that many cells wide. The result depends
// only on the set of marked cells: the same for any particle order and thread count.
// Throws RuntimeError on a non-finite position or spacing, or a position beyond +-2^30 cells.
// `report`, when given, receives the volume change of the smoothing.
// `times`, when given, receives the time of each stage.
TriangleMesh meshParticles(const std::vector<Vec3>& positions, double particleSpacing,
                           const ParticleMeshOptions& options = {}, SmoothingReport* report = nullptr,
                           MeshStageTimes* times = nullptr);

// The lattice cells meshParticles marks for these particles (nearest cell centre, ties upward).
// Throws RuntimeError as meshParticles does.
std::vector<Vec3i> particleCells(const std::vector<Vec3>& positions, double particleSpacing, const Vec3& latticeOrigin);

// 1 for each particle whose lattice cell (as particleCells) has all six face neighbours marked
// by other particles of the list: it is enclosed, and a look that draws particles (Gaussian
// splats) can leave it out. Throws RuntimeError as particleCells does.
std::vector<std::uint8_t> enclosedParticles(const std::vector<Vec3>& positions, double particleSpacing,
                                            const Vec3& latticeOrigin);

// The surface where a node field (an MPM grid's mass, Solver::massField) crosses `iso`, inside
// where it is larger: PhyVR §4.1's surface of elastic objects straight from the grid mass (a
// node's mass over a particle's is a particle count; nodes above the threshold are inside). The
// field is copied into an OpenVDB grid of the field's spacing (nodes at voxel centres) and meshed
// by volumeToMesh (adaptivity 0), whose edge interpolation places the surface between nodes. A
// field that is below iso on its box's faces gives a closed mesh, normals outward. A pure
// function of the values: the same field gives the same mesh for any thread count.
// With targetVolume > 0 (m^3), the level is moved within [iso / 2, 3 iso / 2] until the mesh
// encloses that volume (to 0.2 %, by regula falsi on the meshed volume: a few more meshings):
// the half-density level rounds a body's edges and corners off, which loses volume (7 % of a
// cube 10 nodes wide). levelUsed, when given, receives the level meshed.
// Throws RuntimeError for a spacing or iso that is not finite and > 0, a non-finite origin or
// value, a negative target, or a value count that is not size.prod().
TriangleMesh meshNodeField(const NodeField& field, double iso, double targetVolume = 0.0, double* levelUsed = nullptr);

// Per particle, the direction out of the particles' surface there: the normalised sum of the unit
// directions to the empty cells among its 26 neighbour cells (cells as particleCells marks them).
// Zero where no neighbour cell is empty (inside) or the empty ones cancel (a lone particle, a
// sheet one cell thick), and for the particles `skip` marks (not computed). For lit splats.
// Throws RuntimeError as particleCells does, or for a skip list of another length.
std::vector<Vec3> particleNormals(const std::vector<Vec3>& positions, double particleSpacing, const Vec3& latticeOrigin,
                                  const std::vector<std::uint8_t>* skip = nullptr);

// One level set of a .vdb file: the union of `cells` (centres at origin + h * cell) turned into a
// signed distance field exactly as meshVoxels / meshParticles do before meshing, placed in the
// world by `model` (a rigid body's pose, rest -> world; identity for a deforming surface, whose
// cells are already where the particles are).
struct LevelSetGrid {
  std::string name;      // the grid's name in the file (unique within it)
  std::string material;  // stored as the grid's string metadata "material"
  std::vector<Vec3i> cells;
  // Instead of cells: a closed surface in world coordinates (a fluid's meshFluid), turned into the
  // level set by OpenVDB's meshToLevelSet on the same lattice; model must stay the identity.
  TriangleMesh mesh;
  Eigen::Matrix4d model = Eigen::Matrix4d::Identity();  // rigid: rotation + translation only
  VoxelMeshOptions surface;
  int smoothIterations = 0;  // as ParticleMeshOptions::smoothIterations
  double targetVolume = 0.0; // as ParticleMeshOptions::targetVolume
};

// Writes the level sets as one OpenVDB file (FloatGrids of class level set, float32, world units:
// each grid's transform is the affine map model * (translate(origin) * scale(h)), so Blender and
// Houdini place them where the frame shows them), atomically (temporary file, then rename).
// Returns each grid's active voxel count, in order. An empty cell list gives an empty grid.
// Throws RuntimeError naming the path (I/O) or the grid (bad arguments).
std::vector<std::uint64_t> writeLevelSetsVdb(const std::string& path, const std::vector<LevelSetGrid>& grids,
                                             double voxelSize, const Vec3& origin);

// How a particle group's surface is made; the app tags each group with one.
enum class SurfaceKind {
  // Meshed once from the group's rest cells (meshVoxels) and moved every frame by the body
  // pose (model matrix [R | c - R c0]): exact and cheap for rigid bodies, whose particles keep
  // their rest offsets.
  kRigidRestMesh,
  // Re-meshed from the current particle positions every frame (meshParticles, then
  // OffscreenRenderer::updateMesh, drawn with the identity model matrix): for groups that
  // deform (soft bodies, cloth, ropes, MPM solids).
  kParticles,
  // Re-meshed every frame from anisotropic kernels (meshFluid, render/fluid_surface.h), so a
  // resting pool is flat: for fluids. Drawn like kParticles.
  kFluid,
};

}  // namespace physketch::render
