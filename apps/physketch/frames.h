// Frames: the renderer, one mesh set per body, drawing and PNG output. Rigid bodies
// are meshed once from their rest cells and moved by their pose every frame; a body
// that a cut or a new stroke reshapes is re-meshed once, at the next frame.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "core/profile.h"
#include "core/scene.h"
#include "core/solver.h"
#include "render/renderer.h"
#include "render/voxel_mesh.h"
#include "sketch/grid.h"

namespace physketch::app {

class FrameWriter {
 public:
  // Creates the EGL context (throws RuntimeError on failure: call before creating outputs).
  FrameWriter(const SceneDesc& scene, const sketch::GridMapping& mapping);

  // Marks bodies whose particles changed; they are re-meshed before the next frame.
  void markReshaped(const std::vector<int>& bodies);
  // Draws the solver's bodies (re-meshing marked ones first) and writes DIR/frame_NNNN.png.
  void write(const Solver& solver, const std::vector<Vec3i>& restCells, const std::string& path);

  const Profile& profile() const { return profile_; }
  std::size_t trianglesLastFrame() const { return trianglesLastFrame_; }
  std::size_t trianglesMeshed() const { return trianglesMeshed_; }
  std::size_t meshesLive() const;
  // Frames (0-based, in write order) where no body showed: the camera sees none of them.
  const std::vector<int>& framesWithNothingInView() const { return framesWithNothingInView_; }
  const std::string& device() const { return renderer_.deviceDescription(); }
  render::MeshStats gpuMeshes() const { return renderer_.meshStats(); }
  // Times meshBody ran (each body at most once per frame).
  long meshings() const { return profile_.entries()[std::size_t(passMesh_)].calls; }

 private:
  struct MeshPart {
    int handle;
    std::int16_t material;
    std::size_t triangles;
    render::SurfaceKind surface;
  };
  void meshBody(const Solver& solver, const std::vector<Vec3i>& restCells, int body);

  const SceneDesc& scene_;
  const sketch::GridMapping& mapping_;
  render::OffscreenRenderer renderer_;
  std::map<int, std::vector<MeshPart>> meshes_;  // body -> one mesh per material
  std::vector<int> dirty_;                       // bodies to (re)mesh before the next frame
  std::vector<int> deforming_;                   // bodies with a deforming surface: re-meshed every frame
  int meshedBodies_ = 0;                         // bodies 0..meshedBodies_-1 have been meshed once
  Profile profile_;
  int passMesh_, passDraw_, passPng_;
  std::size_t trianglesLastFrame_ = 0, trianglesMeshed_ = 0;
  int frames_ = 0;
  std::vector<int> framesWithNothingInView_;
};

std::string frameName(int index);
// How a material's particles become a surface under a solver: kinds it runs as rigid keep their rest mesh and move
// with the body pose; every other kind deforms and is meshed from its particles each frame.
render::SurfaceKind surfaceOf(MaterialKind kind, SolverKind solver = SolverKind::kPbd);

}  // namespace physketch::app
