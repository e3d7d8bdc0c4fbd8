// Frames: the renderer, one mesh set per body, drawing and PNG output. Rigid bodies
// are meshed once from their rest cells and moved by their pose every frame; a body
// that a cut or a new stroke reshapes is re-meshed once, at the next frame.
#pragma once

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "core/profile.h"
#include "core/scene.h"
#include "core/triangle_soup.h"
#include "core/solver.h"
#include "render/export.h"
#include "render/fluid_surface.h"
#include "render/renderer.h"
#include "render/voxel_mesh.h"
#include "sketch/grid.h"

namespace physketch::app {

struct FrameOptions {
  bool draw = true;         // render PNG frames (creates the EGL context)
  bool keepMeshes = false;  // keep each body's meshes in memory for exportMeshes
  int smoothIterations = 0; // the smoothing knob of deforming surfaces (ParticleMeshOptions)
  bool fluidCells = false;  // --fluid-surface cells: fluids meshed as deforming cells, not kernels
  bool splats = false;      // --look splats: every body drawn as Gaussian splats, one per particle
  // --mesh-resolution: the edge of a fluid surface's field voxels, in particle spacings
  // (render::FluidSurfaceOptions::voxelFraction), 0.1..1
  double fluidVoxelFraction = render::FluidSurfaceOptions{}.voxelFraction;
  // --solid-surface grid: deforming solids (not fluids, ropes or cloth) meshed from the solver's
  // grid mass (Solver::massField, PhyVR §4.1) at half the particles' rest density; needs a solver
  // with a grid (mpm). Off: from the particles' cells (meshParticles).
  bool solidGrid = false;
  int splatDetail = 1;  // --splat-detail: appearance particles per particle along each axis (particleSplats)
  render::GlDevice glDevice = render::GlDevice::Cpu;  // --gl-device: which EGL display draws
};

// Half the mass a node of `spacing` holds inside material of the particles' rest density
// (mass / (count * particleSpacing^3)): the level meshNodeField meshes a grid-mass field at.
double gridMassLevel(double mass, std::size_t count, double particleSpacing, double spacing);

// Gaussian splats of every body's particles (--look splats), in body and id order: centre at the
// particle, covariance sigma0^2 F F^T with sigma0 = kSplatSigma spacings and F the solver's
// deformation gradient (PhysGaussian's Sigma' = F Sigma F^T); a fluid's splats take their
// kernel's shape instead (render/fluid_surface.h: thin across its surface, wide along it),
// scaled so an undeformed kernel is the same ball. Colour: the material's; opacity kSplatOpacity;
// normal: render::particleNormals of the group's particles (lit; zero, unlit, where it has none).
// Particles inside a body (all six neighbour cells occupied; a fluid's deep particles) are hidden
// behind the others and get no splat.
// detail (--splat-detail, 1..kMaxSplatDetail): appearance particles per simulation particle along
// each axis (VR-Doh's decoupling of the two): each drawn particle becomes detail^3 splats at
// x + F o, o on a lattice of spacing / detail centred in its cell, each of covariance
// (sigma0 / detail)^2 F F^T (a fluid's: its kernel's shape in place of F). Throws RuntimeError
// for a detail out of range.
constexpr double kSplatSigma = 0.5;
constexpr float kSplatOpacity = 0.9f;
constexpr int kMaxSplatDetail = 4;
// splatLookOnly: only the materials whose look is splats (`look=splats`), for a frame that draws
// the others as surfaces.
std::vector<render::Splat> particleSplats(const SceneDesc& scene, const Solver& solver, double spacing,
                                          bool splatLookOnly = false, int detail = 1);

// How far the surfaces of one kind meshed in a run were from a reference volume: a fluid's
// kernels and a deforming solid's surface (cells or grid mass) from the particles' (spacing^3
// each, times det F), the smoothing knob from the surface before it.
struct VolumeChangeStats {
  long meshes = 0;
  double maxAbsChange = 0.0;  // largest |mesh - reference| / reference
  double sumChange = 0.0;     // sum of (mesh - reference) / reference, for the mean
  void add(double change) {
    ++meshes;
    maxAbsChange = std::max(maxAbsChange, std::abs(change));
    sumChange += change;
  }
  double mean() const { return meshes > 0 ? sumChange / double(meshes) : 0.0; }
};

class FrameWriter {
 public:
  // With options.draw, creates the EGL context (throws RuntimeError on failure: call before
  // creating outputs).
  FrameWriter(const SceneDesc& scene, const sketch::GridMapping& mapping, const FrameOptions& options = {});

  // Marks bodies whose particles changed; they are re-meshed before the next frame.
  void markReshaped(const std::vector<int>& bodies);
  // The scene's mesh colliders (one soup per collider, in scene order), drawn at their pose
  // at each frame's time in a neutral grey.
  void setColliders(const std::vector<TriangleSoup>& meshes);
  // Meshes bodies that are new, marked or deforming (each at most once per frame).
  void update(const Solver& solver, const std::vector<Vec3i>& restCells);
  // update(), then draws the solver's bodies and writes the PNG at `path` (needs options.draw).
  void write(const Solver& solver, const std::vector<Vec3i>& restCells, const std::string& path);
  // Writes DIR/BODY.obj and DIR/BODY.ply for every body with a surface, as last meshed by
  // update() (needs options.keepMeshes): rigid meshes moved by the body's pose, deforming ones
  // as meshed. `mtllib`: the OBJ's material library line. Returns the number of bodies written.
  int exportMeshes(const Solver& solver, const std::vector<std::string>& bodyNames, const std::string& dir,
                   const std::string& mtllib) const;
  // Every body's surfaces as last meshed by update() (needs options.keepMeshes), in world
  // coordinates: rigid meshes moved by the body's pose. Body index -> one mesh per material.
  std::map<int, std::vector<render::MaterialMesh>> worldMeshes(const Solver& solver) const;
  const VolumeChangeStats& smoothing() const { return smoothing_; }
  const VolumeChangeStats& fluidSurfaces() const { return fluid_; }
  // Deforming solids' surfaces (cells or grid) against their particles' volume.
  const VolumeChangeStats& solidSurfaces() const { return solid_; }

  const Profile& profile() const { return profile_; }
  std::size_t trianglesLastFrame() const { return trianglesLastFrame_; }
  std::size_t trianglesMeshed() const { return trianglesMeshed_; }
  std::size_t meshesLive() const;
  // Frames (0-based, in write order) where no body showed: the camera sees none of them.
  const std::vector<int>& framesWithNothingInView() const { return framesWithNothingInView_; }
  const std::string& device() const;
  render::MeshStats gpuMeshes() const;
  // Times meshBody ran (each body at most once per frame).
  long meshings() const { return profile_.entries()[std::size_t(passMesh_)].calls; }

 private:
  std::vector<int> colliderHandles_;  // GL meshes of the scene's colliders, in scene order
  struct MeshPart {
    int handle;  // GL mesh, -1 without a renderer
    std::int16_t material;
    std::size_t triangles;
    render::SurfaceKind surface;
    render::TriangleMesh mesh;  // kept only with options.keepMeshes
  };
  void meshBody(const Solver& solver, const std::vector<Vec3i>& restCells, int body);

  const SceneDesc& scene_;
  const sketch::GridMapping& mapping_;
  FrameOptions options_;
  std::unique_ptr<render::OffscreenRenderer> renderer_;  // null without options.draw
  VolumeChangeStats smoothing_, fluid_, solid_;
  std::map<int, std::vector<MeshPart>> meshes_;  // body -> one mesh per material
  std::vector<int> dirty_;                       // bodies to (re)mesh before the next frame
  std::vector<int> deforming_;                   // bodies with a deforming surface: re-meshed every frame
  int meshedBodies_ = 0;                         // bodies 0..meshedBodies_-1 have been meshed once
  Profile profile_;
  int passMesh_, passDraw_, passPng_, passSplats_ = -1;
  bool anySplatLook_ = false;  // some material's look is splats
  std::size_t trianglesLastFrame_ = 0, trianglesMeshed_ = 0;
  int frames_ = 0;
  std::vector<int> framesWithNothingInView_;
};

std::string frameName(int index);  // "frame_NNNN.png"
std::string frameStem(int index);  // "frame_NNNN"
// Body b's file name stem in exports: "NNNN_NAME" with NAME made file-safe (render::fileSafeName).
std::string bodyFileStem(int body, const std::string& name);
// The scene's materials as the export files name them.
std::vector<render::ExportMaterial> exportMaterials(const SceneDesc& scene);
// Every live particle with its velocity, body, material and stroke (--export particles).
render::ParticleCloud particleCloud(const SceneDesc& scene, const Solver& solver);
// The level set of every body's surface, one grid per body and material, as meshed for frames
// (rigid: rest cells moved by the pose; deforming: the particles' cells, smoothed, or the grid-mass
// surface; fluids: their kernel surface), as `surfaces` says, written to one .vdb file (--export
// vdb). Grids are named "NNNN_NAME/MATERIAL".
void exportLevelSets(const SceneDesc& scene, const sketch::GridMapping& mapping, const Solver& solver,
                     const std::vector<Vec3i>& restCells, const std::vector<std::string>& bodyNames,
                     const FrameOptions& surfaces, const std::string& path);
// How a material's particles become a surface under a solver: kinds it runs as rigid keep their rest mesh and move
// with the body pose; kinds it runs as fluid are meshed from anisotropic kernels each frame; every other kind deforms
// and is meshed from its particles' cells each frame.
render::SurfaceKind surfaceOf(MaterialKind kind, SolverKind solver = SolverKind::kPbd);

}  // namespace physketch::app
