#include "apps/physketch/frames.h"

#include <algorithm>
#include <cstdio>

#include "render/voxel_mesh.h"

namespace physketch::app {

std::string frameName(int index) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "frame_%04d.png", index);
  return buf;
}

FrameWriter::FrameWriter(const SceneDesc& scene, const sketch::GridMapping& mapping)
    : scene_(scene), mapping_(mapping), renderer_(scene.width, scene.height) {
  passMesh_ = profile_.add("mesh");
  passDraw_ = profile_.add("draw");
  passPng_ = profile_.add("png");
}

void FrameWriter::markReshaped(const std::vector<int>& bodies) { dirty_.insert(dirty_.end(), bodies.begin(), bodies.end()); }

std::size_t FrameWriter::meshesLive() const {
  std::size_t n = 0;
  for (const auto& [b, parts] : meshes_) n += parts.size();
  return n;
}

render::SurfaceKind surfaceOf(MaterialKind kind, SolverKind solver) {
  // What the solver runs decides: rigid under mpm is a stiff elastic that deforms.
  const MaterialKind runs = solverModel(kind, solver).simulated ? solverModel(kind, solver).runsAs : kind;
  return runs == MaterialKind::kRigid ? render::SurfaceKind::kRigidRestMesh : render::SurfaceKind::kParticles;
}

// (Re)builds the meshes of one body: one mesh per material (mixed-material bodies). A
// rigid material's mesh comes from its particles' rest cells and moves with the body's
// pose; any other kind deforms, so its mesh is made from the current particle positions
// (and the body stays marked for re-meshing every frame). Existing GL meshes are updated
// in place; meshes of materials the body no longer has are freed.
void FrameWriter::meshBody(const Solver& solver, const std::vector<Vec3i>& restCells, int b) {
  ScopedPass t(profile_, passMesh_);
  const ParticleArrays& p = solver.particles();
  std::map<std::int16_t, std::vector<std::int32_t>> byMaterial;
  for (std::int32_t i : solver.bodyParticles(b)) byMaterial[p.material[static_cast<std::size_t>(i)]].push_back(i);
  std::vector<MeshPart> old = std::move(meshes_[b]);
  meshes_[b].clear();
  bool deforming = false;
  const Vec3 origin = mapping_.toWorld(Vec3i(0, 0, 0));
  for (const auto& [material, ids] : byMaterial) {
    const render::SurfaceKind surface = surfaceOf(scene_.materials[static_cast<std::size_t>(material)].kind, scene_.solver);
    render::TriangleMesh mesh;
    if (surface == render::SurfaceKind::kRigidRestMesh) {
      std::vector<Vec3i> cells;
      cells.reserve(ids.size());
      for (std::int32_t i : ids) cells.push_back(restCells[static_cast<std::size_t>(i)]);
      mesh = render::meshVoxels(cells, mapping_.voxelSize(), origin);
    } else {
      deforming = true;
      std::vector<Vec3> pos;
      pos.reserve(ids.size());
      for (std::int32_t i : ids) {
        const auto k = static_cast<std::size_t>(i);
        pos.emplace_back(p.x[k], p.y[k], p.z[k]);
      }
      render::ParticleMeshOptions opt;
      opt.latticeOrigin = origin;
      mesh = render::meshParticles(pos, mapping_.voxelSize(), opt);
    }
    trianglesMeshed_ += mesh.triangleCount();
    auto reuse = std::find_if(old.begin(), old.end(), [&](const MeshPart& m) { return m.material == material; });
    int handle;
    if (reuse != old.end()) {
      handle = reuse->handle;
      renderer_.updateMesh(handle, mesh);
      old.erase(reuse);
    } else {
      handle = renderer_.uploadMesh(mesh);
    }
    meshes_[b].push_back({handle, material, mesh.triangleCount(), surface});
  }
  for (const MeshPart& m : old) renderer_.freeMesh(m.handle);
  if (deforming) deforming_.push_back(b);
}

void FrameWriter::write(const Solver& solver, const std::vector<Vec3i>& restCells, const std::string& path) {
  // Bodies new since the last frame, then bodies reshaped since: each meshed once per frame at most.
  for (; meshedBodies_ < solver.bodyCount(); ++meshedBodies_) dirty_.push_back(meshedBodies_);
  dirty_.insert(dirty_.end(), deforming_.begin(), deforming_.end());  // deforming bodies: every frame
  deforming_.clear();
  std::sort(dirty_.begin(), dirty_.end());
  dirty_.erase(std::unique(dirty_.begin(), dirty_.end()), dirty_.end());
  for (int b : dirty_) meshBody(solver, restCells, b);
  dirty_.clear();

  render::Image img;
  {
    ScopedPass t(profile_, passDraw_);
    const SceneDesc& sc = scene_;
    // Near and far planes around everything drawable: the workspace, the ground patch and
    // every particle (bodies may leave the workspace), so a far camera still sees the scene.
    const double half = std::max(sc.workspaceSize, 1e-3);
    Eigen::AlignedBox3d box(sc.workspaceCenter - Vec3::Constant(0.5 * sc.workspaceSize),
                            sc.workspaceCenter + Vec3::Constant(0.5 * sc.workspaceSize));
    box.extend(Vec3(sc.workspaceCenter.x() - half, sc.groundY, sc.workspaceCenter.z() - half));
    box.extend(Vec3(sc.workspaceCenter.x() + half, sc.groundY, sc.workspaceCenter.z() + half));
    const ParticleArrays& p = solver.particles();
    for (std::size_t i = 0; i < p.size(); ++i)
      if (!phase::has(p.phase[i], phase::kRemoved)) box.extend(Vec3(p.x[i], p.y[i], p.z[i]));
    box.extend(box.min() - Vec3::Constant(mapping_.voxelSize()));  // particles are cubes of one voxel
    box.extend(box.max() + Vec3::Constant(mapping_.voxelSize()));
    renderer_.beginFrame(sc.camera, {0.92f, 0.94f, 0.97f}, render::clipRangeFor(sc.camera, box));
    renderer_.drawGround(sc.groundY, sc.workspaceCenter.x(), sc.workspaceCenter.z(), half, {0.55f, 0.57f, 0.55f});
    trianglesLastFrame_ = 0;
    for (const auto& [b, parts] : meshes_) {
      if (solver.mode(b) == BodyMode::kEmpty) continue;
      const Mat4f model = solver.pose(b).model();
      for (const MeshPart& m : parts) {
        // A deforming surface was meshed where the particles are: no pose to apply.
        renderer_.drawMesh(m.handle, m.surface == render::SurfaceKind::kRigidRestMesh ? model : Mat4f::Identity(),
                           sc.materials[static_cast<std::size_t>(m.material)].color);
        trianglesLastFrame_ += m.triangles;
      }
    }
    img = renderer_.endFrame();
  }
  ++frames_;
  if (img.meshSamples == 0 && !meshes_.empty()) framesWithNothingInView_.push_back(frames_ - 1);
  ScopedPass t(profile_, passPng_);
  render::writePng(path, img);
}

}  // namespace physketch::app
