#include "apps/physketch/frames.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "core/error.h"
#include "render/fluid_surface.h"
#include "render/voxel_mesh.h"

namespace physketch::app {
namespace {

// The particles of body b grouped by material (ascending ids within each).
std::map<std::int16_t, std::vector<std::int32_t>> byMaterial(const Solver& solver, int b) {
  const ParticleArrays& p = solver.particles();
  std::map<std::int16_t, std::vector<std::int32_t>> groups;
  for (std::int32_t i : solver.bodyParticles(b)) groups[p.material[static_cast<std::size_t>(i)]].push_back(i);
  return groups;
}

std::vector<Vec3> positionsOf(const ParticleArrays& p, const std::vector<std::int32_t>& ids) {
  std::vector<Vec3> pos;
  pos.reserve(ids.size());
  for (std::int32_t i : ids) {
    const auto k = static_cast<std::size_t>(i);
    pos.emplace_back(p.x[k], p.y[k], p.z[k]);
  }
  return pos;
}

// A rope is one particle across: a tube of its particles' contact radius (the brush's half
// size; h/2 where the solver has none) along each run of consecutive ids (neighbours on the
// chain; a cut leaves a gap in the ids).
render::TriangleMesh ropeTube(const Solver& solver, const std::vector<std::int32_t>& ids, const std::vector<Vec3>& pos,
                              double spacing) {
  std::vector<std::vector<Vec3>> chains(1);
  for (std::size_t k = 0; k < ids.size(); ++k) {
    if (k > 0 && ids[k] != ids[k - 1] + 1) chains.emplace_back();
    chains.back().push_back(pos[k]);
  }
  const double radius = ids.empty() ? 0.0 : solver.contactRadius(ids.front());
  return render::tubeMesh(chains, std::isfinite(radius) ? radius : 0.5 * spacing);
}

// A cloth with its lattice known to the solver: a sheet along the lattice (render::sheetMesh),
// as thick as its particles' contact radius (the disc's thickness; h/2 where the solver has
// none). False, and `out` untouched, where the solver keeps no lattice for the body.
bool clothSheet(const Solver& solver, int body, const std::vector<std::int32_t>& ids, const std::vector<Vec3>& pos,
                double spacing, render::TriangleMesh& out) {
  std::int32_t first = 0, rows = 0, cols = 0;
  if (ids.empty() || !solver.lattice(body, first, rows, cols)) return false;
  const std::size_t count = std::size_t(rows) * std::size_t(cols);
  std::vector<Vec3> nodes(count, Vec3::Zero());
  std::vector<std::uint8_t> alive(count, 0);
  for (std::size_t k = 0; k < ids.size(); ++k) {
    const std::int64_t at = std::int64_t(ids[k]) - first;
    if (at < 0 || std::size_t(at) >= count) return false;  // not the lattice's particles
    nodes[std::size_t(at)] = pos[k];
    alive[std::size_t(at)] = 1;
  }
  const double radius = solver.contactRadius(ids.front());
  out = render::sheetMesh(nodes, alive, rows, cols, std::isfinite(radius) ? radius : 0.5 * spacing);
  return true;
}

// What particles `ids` occupy now (m^3): spacing^3 times the sum of their volume ratios det F
// (1 where the solver keeps no F: pbd). The volume their surfaces are made to enclose.
double particleVolume(const Solver& solver, const std::vector<std::int32_t>& ids, double spacing) {
  double sumJ = 0.0;
  for (std::int32_t i : ids) sumJ += solver.deformationGradient(i).determinant();
  return sumJ * spacing * spacing * spacing;
}

// The surface of particles `ids` from the solver's grid mass (--solid-surface grid): the level
// of half their rest density, moved until the mesh encloses `target`, their particleVolume.
render::TriangleMesh gridMassMesh(const Solver& solver, const std::vector<std::int32_t>& ids, double spacing,
                                  double target) {
  NodeField field;
  if (!solver.massField(ids, field))
    throw RuntimeError(std::string("--solid-surface grid: solver ") + solver.name() + " has no grid mass");
  double mass = 0.0;
  for (std::int32_t i : ids) mass += double(solver.particles().mass[static_cast<std::size_t>(i)]);
  if (!(mass > 0.0) || !(target > 0.0)) return {};  // nothing to threshold
  return render::meshNodeField(field, gridMassLevel(mass, ids.size(), spacing, field.spacing), target);
}

}  // namespace

double gridMassLevel(double mass, std::size_t count, double particleSpacing, double spacing) {
  const double density = mass / (double(count) * std::pow(particleSpacing, 3));
  return 0.5 * density * std::pow(spacing, 3);
}

std::string frameName(int index) { return frameStem(index) + ".png"; }

std::string frameStem(int index) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "frame_%04d", index);
  return buf;
}

std::string bodyFileStem(int body, const std::string& name) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%04d_", body);
  return buf + render::fileSafeName(name);
}

std::vector<render::ExportMaterial> exportMaterials(const SceneDesc& scene) {
  std::vector<render::ExportMaterial> out;
  for (const Material& m : scene.materials) out.push_back({m.name, m.color, m.roughness});
  return out;
}

FrameWriter::FrameWriter(const SceneDesc& scene, const sketch::GridMapping& mapping, const FrameOptions& options)
    : scene_(scene), mapping_(mapping), options_(options) {
  if (options.draw) renderer_ = std::make_unique<render::OffscreenRenderer>(scene.width, scene.height, render::Looks{}, options.glDevice);
  passMesh_ = profile_.add("mesh");
  passDraw_ = profile_.add("draw");
  // Splats for every material (--look splats) or for those whose look is splats.
  for (const Material& m : scene.materials) anySplatLook_ = anySplatLook_ || m.look == Material::Look::kSplats;
  if (options.splats || anySplatLook_) passSplats_ = profile_.add("splats");
  passPng_ = profile_.add("png");
}

const std::string& FrameWriter::device() const {
  static const std::string none;
  return renderer_ ? renderer_->deviceDescription() : none;
}

render::MeshStats FrameWriter::gpuMeshes() const { return renderer_ ? renderer_->meshStats() : render::MeshStats{}; }

void FrameWriter::markReshaped(const std::vector<int>& bodies) { dirty_.insert(dirty_.end(), bodies.begin(), bodies.end()); }

std::size_t FrameWriter::meshesLive() const {
  std::size_t n = 0;
  for (const auto& [b, parts] : meshes_) n += parts.size();
  return n;
}

render::SurfaceKind surfaceOf(MaterialKind kind, SolverKind solver) {
  // What the solver runs decides: rigid under mpm is a stiff elastic that deforms.
  const MaterialKind runs = solverModel(kind, solver).simulated ? solverModel(kind, solver).runsAs : kind;
  if (runs == MaterialKind::kRigid) return render::SurfaceKind::kRigidRestMesh;
  return runs == MaterialKind::kFluid ? render::SurfaceKind::kFluid : render::SurfaceKind::kParticles;
}

// (Re)builds the meshes of one body: one mesh per material (mixed-material bodies). A
// rigid material's mesh comes from its particles' rest cells and moves with the body's
// pose; any other kind deforms, so its mesh is made from the current particle positions
// (and the body stays marked for re-meshing every frame). Existing GL meshes are updated
// in place; meshes of materials the body no longer has are freed.
void FrameWriter::meshBody(const Solver& solver, const std::vector<Vec3i>& restCells, int b) {
  ScopedPass t(profile_, passMesh_);
  const ParticleArrays& p = solver.particles();
  std::vector<MeshPart> old = std::move(meshes_[b]);
  meshes_[b].clear();
  bool deforming = false;
  const Vec3 origin = mapping_.toWorld(Vec3i(0, 0, 0));
  for (const auto& [material, ids] : byMaterial(solver, b)) {
    // A material drawn as splats needs no surface, unless --export mesh keeps the meshes.
    if (scene_.materials[static_cast<std::size_t>(material)].look == Material::Look::kSplats && !options_.keepMeshes)
      continue;
    const MaterialKind kind = scene_.materials[static_cast<std::size_t>(material)].kind;
    const render::SurfaceKind surface = surfaceOf(kind, scene_.solver);
    render::TriangleMesh mesh;
    if (surface == render::SurfaceKind::kRigidRestMesh) {
      std::vector<Vec3i> cells;
      cells.reserve(ids.size());
      for (std::int32_t i : ids) cells.push_back(restCells[static_cast<std::size_t>(i)]);
      mesh = render::meshVoxels(cells, mapping_.voxelSize(), origin);
    } else if (surface == render::SurfaceKind::kFluid && !options_.fluidCells) {
      deforming = true;
      render::FluidSurfaceReport report;
      render::FluidSurfaceOptions fo;
      fo.voxelFraction = options_.fluidVoxelFraction;
      mesh = render::meshFluid(positionsOf(p, ids), mapping_.voxelSize(), fo, &report);
      if (report.particleVolume > 0.0) fluid_.add((report.meshVolume - report.particleVolume) / report.particleVolume);
    } else if (options_.solidGrid && kind != MaterialKind::kRope && kind != MaterialKind::kCloth) {
      deforming = true;
      const double volume = particleVolume(solver, ids, mapping_.voxelSize());
      mesh = gridMassMesh(solver, ids, mapping_.voxelSize(), volume);
      if (volume > 0.0) solid_.add((render::enclosedVolume(mesh) - volume) / volume);
    } else {
      deforming = true;
      render::ParticleMeshOptions opt;
      opt.latticeOrigin = origin;
      opt.smoothIterations = options_.smoothIterations;
      render::SmoothingReport report;
      const std::vector<Vec3> pos = positionsOf(p, ids);
      if (kind == MaterialKind::kRope) {
        mesh = ropeTube(solver, ids, pos, mapping_.voxelSize());
      } else if (kind == MaterialKind::kCloth && clothSheet(solver, b, ids, pos, mapping_.voxelSize(), mesh)) {
        // the lattice's own sheet
      } else {
        // A cloth without a lattice from its solver is meshed from its cells, a sheet one
        // particle thick: held to its particles' volume it would thin into holes, so its cells'
        // surface is kept as it is.
        if (kind != MaterialKind::kCloth) opt.targetVolume = particleVolume(solver, ids, mapping_.voxelSize());
        mesh = render::meshParticles(pos, mapping_.voxelSize(), opt, &report);
        if (opt.targetVolume > 0.0) solid_.add((render::enclosedVolume(mesh) - opt.targetVolume) / opt.targetVolume);
      }
      if (options_.smoothIterations > 0 && report.volumeBefore > 0.0) smoothing_.add(report.relativeChange());
    }
    trianglesMeshed_ += mesh.triangleCount();
    int handle = -1;
    if (renderer_) {
      auto reuse = std::find_if(old.begin(), old.end(), [&](const MeshPart& m) { return m.material == material; });
      if (reuse != old.end()) {
        handle = reuse->handle;
        renderer_->updateMesh(handle, mesh);
        old.erase(reuse);
      } else {
        handle = renderer_->uploadMesh(mesh);
      }
    }
    const std::size_t triangles = mesh.triangleCount();
    meshes_[b].push_back({handle, material, triangles, surface,
                          options_.keepMeshes ? std::move(mesh) : render::TriangleMesh{}});
  }
  if (renderer_)
    for (const MeshPart& m : old) renderer_->freeMesh(m.handle);
  if (deforming) deforming_.push_back(b);
}

void FrameWriter::update(const Solver& solver, const std::vector<Vec3i>& restCells) {
  // Bodies new since the last frame, then bodies reshaped since: each meshed once per frame at most.
  for (; meshedBodies_ < solver.bodyCount(); ++meshedBodies_) dirty_.push_back(meshedBodies_);
  dirty_.insert(dirty_.end(), deforming_.begin(), deforming_.end());  // deforming bodies: every frame
  deforming_.clear();
  std::sort(dirty_.begin(), dirty_.end());
  dirty_.erase(std::unique(dirty_.begin(), dirty_.end()), dirty_.end());
  for (int b : dirty_) meshBody(solver, restCells, b);
  dirty_.clear();
}

std::vector<render::Splat> particleSplats(const SceneDesc& scene, const Solver& solver, double spacing, bool splatLookOnly,
                                          int detail) {
  if (detail < 1 || detail > kMaxSplatDetail)
    throw RuntimeError("particleSplats: detail " + std::to_string(detail) + " is outside 1.." + std::to_string(kMaxSplatDetail));
  const ParticleArrays& p = solver.particles();
  const double sigma0 = kSplatSigma * spacing;
  // A particle's appearance particles: detail^3 offsets on a lattice of spacing / detail across
  // its cell, in the rest frame (mapped by G below).
  std::vector<Vec3> offsets;
  const double step = spacing / detail, mid = 0.5 * (detail - 1);
  for (int c = 0; c < detail; ++c)
    for (int b = 0; b < detail; ++b)
      for (int a = 0; a < detail; ++a) offsets.push_back(step * Vec3(a - mid, b - mid, c - mid));
  std::vector<render::Splat> out;
  render::Splat s;
  s.opacity = kSplatOpacity;
  // A particle at x whose rest neighbourhood G maps to the current one: its splats at x + G o,
  // covariance (sigma0 / detail)^2 G G^T.
  const auto emit = [&](const Vec3& x, const Mat3& G, const Vec3& normal) {
    const Mat3 cov = (sigma0 / detail) * (sigma0 / detail) * G * G.transpose();
    s.covariance = cov.cast<float>();
    s.normal = normal.cast<float>();
    for (const Vec3& o : offsets) {
      s.centre = (x + G * o).cast<float>();
      out.push_back(s);
    }
  };
  for (int b = 0; b < solver.bodyCount(); ++b) {
    if (solver.mode(b) == BodyMode::kEmpty) continue;
    for (const auto& [material, ids] : byMaterial(solver, b)) {
      const Material& mat = scene.materials[static_cast<std::size_t>(material)];
      if (splatLookOnly && mat.look != Material::Look::kSplats) continue;
      s.color = mat.color;
      const std::vector<Vec3> pos = positionsOf(p, ids);
      if (surfaceOf(mat.kind, scene.solver) == render::SurfaceKind::kFluid) {
        const render::FluidKernels k = render::fluidKernels(pos, spacing);
        const std::vector<Vec3> normals = render::particleNormals(pos, spacing, Vec3::Zero(), &k.interior);
        const double scale = 1.0 / (render::FluidSurfaceOptions{}.kernelRadius * spacing);
        for (std::size_t j = 0; j < ids.size(); ++j) {
          if (k.interior[j]) continue;  // deep inside: hidden behind the splats around it
          emit(k.centre[j], scale * k.inverseAxes[j].inverse(), normals[j]);
        }
        continue;
      }
      // A particle whose cell has all six face neighbours occupied by this group is inside it:
      // the splats around it (opacity 0.9 each) hide it, so it is not drawn (a fifth to a third of
      // a solid's particles are drawn; llvmpipe's cost is the overdraw).
      const std::vector<std::uint8_t> hidden = render::enclosedParticles(pos, spacing, Vec3::Zero());
      const std::vector<Vec3> normals = render::particleNormals(pos, spacing, Vec3::Zero(), &hidden);
      for (std::size_t j = 0; j < ids.size(); ++j)
        if (!hidden[j]) emit(pos[j], solver.deformationGradient(ids[j]), normals[j]);
    }
  }
  return out;
}

void FrameWriter::write(const Solver& solver, const std::vector<Vec3i>& restCells, const std::string& path) {
  if (!renderer_) throw RuntimeError("FrameWriter::write: created without drawing");
  // Splats need no meshes; --export mesh still does.
  if (!options_.splats || options_.keepMeshes) update(solver, restCells);
  std::vector<render::Splat> splats;
  if (options_.splats || anySplatLook_) {
    ScopedPass t(profile_, passSplats_);
    splats = particleSplats(scene_, solver, mapping_.voxelSize(), /*splatLookOnly=*/!options_.splats, options_.splatDetail);
  }

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
    // A pale sky: bluer at the top of the image, near white at the bottom.
    const render::Background sky{{0.62f, 0.72f, 0.86f}, {0.94f, 0.95f, 0.97f}};
    renderer_->beginFrame(sc.camera, sky, render::clipRangeFor(sc.camera, box));
    renderer_->drawGround(sc.groundY, sc.workspaceCenter.x(), sc.workspaceCenter.z(), half, {0.55f, 0.57f, 0.55f});
    trianglesLastFrame_ = 0;
    // Opaque surfaces (bodies, colliders) first, then the splats, blended over them (depth-tested).
    for (const auto& [b, parts] : meshes_) {
      if (options_.splats) break;
      if (solver.mode(b) == BodyMode::kEmpty) continue;
      const Mat4f model = solver.pose(b).model();
      for (const MeshPart& m : parts) {
        const Material& mat = sc.materials[static_cast<std::size_t>(m.material)];
        if (mat.look == Material::Look::kSplats) continue;  // kept for --export mesh only
        // A deforming surface was meshed where the particles are: no pose to apply.
        renderer_->drawMesh(m.handle, m.surface == render::SurfaceKind::kRigidRestMesh ? model : Mat4f::Identity(),
                            mat.color, static_cast<float>(mat.roughness));
        trianglesLastFrame_ += m.triangles;
      }
    }
    for (std::size_t c = 0; c < colliderHandles_.size(); ++c) {
      Mat3 R;
      Vec3 at;
      sc.colliders[c].poseAt(solver.time(), R, at);
      Mat4f model = Mat4f::Identity();
      model.topLeftCorner<3, 3>() = R.cast<float>();
      model.topRightCorner<3, 1>() = at.cast<float>();
      renderer_->drawMesh(colliderHandles_[c], model, {0.6f, 0.62f, 0.66f});
    }
    if (!splats.empty()) renderer_->drawSplats(splats);  // last: blended over everything opaque
    img = renderer_->endFrame();
  }
  ++frames_;
  if (img.meshSamples == 0 && trianglesLastFrame_ > 0 && splats.empty()) framesWithNothingInView_.push_back(frames_ - 1);
  ScopedPass t(profile_, passPng_);
  render::writePng(path, img);
}

void FrameWriter::setColliders(const std::vector<TriangleSoup>& meshes) {
  if (!renderer_) return;
  for (std::size_t c = 0; c < meshes.size() && c < scene_.colliders.size(); ++c) {
    // Flat-shaded: three vertices per triangle with the face normal, in the collider's
    // local frame (file coordinates times its scale).
    const double scale = scene_.colliders[c].scale;
    render::TriangleMesh m;
    for (const auto& t : meshes[c].triangles) {
      const Vec3 a = scale * meshes[c].vertices[std::size_t(t[0])], b = scale * meshes[c].vertices[std::size_t(t[1])],
                 d = scale * meshes[c].vertices[std::size_t(t[2])];
      const Vec3 n = (b - a).cross(d - a).normalized();
      for (const Vec3& v : {a, b, d}) {
        m.indices.push_back(static_cast<std::uint32_t>(m.positions.size()));
        m.positions.push_back(v.cast<float>());
        m.normals.push_back(n.cast<float>());
      }
    }
    colliderHandles_.push_back(renderer_->uploadMesh(m));
  }
}

std::map<int, std::vector<render::MaterialMesh>> FrameWriter::worldMeshes(const Solver& solver) const {
  if (!options_.keepMeshes) throw RuntimeError("FrameWriter::worldMeshes: created without keepMeshes");
  std::map<int, std::vector<render::MaterialMesh>> bodies;
  for (const auto& [b, parts] : meshes_) {
    if (solver.mode(b) == BodyMode::kEmpty || parts.empty()) continue;
    const Mat4f model = solver.pose(b).model();
    const Eigen::Matrix3f rotation = model.topLeftCorner<3, 3>();
    std::vector<render::MaterialMesh>& out = bodies[b];
    for (const MeshPart& m : parts) {
      render::MaterialMesh part{m.material, m.mesh};
      if (m.surface == render::SurfaceKind::kRigidRestMesh) {
        // The pose is a rotation plus a translation: normals turn with the rotation.
        for (Vec3f& v : part.mesh.positions) v = rotation * v + model.topRightCorner<3, 1>();
        for (Vec3f& n : part.mesh.normals) n = rotation * n;
      }
      out.push_back(std::move(part));
    }
  }
  return bodies;
}

int FrameWriter::exportMeshes(const Solver& solver, const std::vector<std::string>& bodyNames, const std::string& dir,
                              const std::string& mtllib) const {
  if (!options_.keepMeshes) throw RuntimeError("FrameWriter::exportMeshes: created without keepMeshes");
  const std::vector<render::ExportMaterial> materials = exportMaterials(scene_);
  int written = 0;
  for (const auto& [b, out] : worldMeshes(solver)) {
    const std::string name = b < static_cast<int>(bodyNames.size()) ? bodyNames[static_cast<std::size_t>(b)] : "";
    const std::string stem = dir + "/" + bodyFileStem(b, name);
    render::writeBodyObj(stem + ".obj", name, out, materials, mtllib);
    render::writeBodyPly(stem + ".ply", name, out, materials);
    ++written;
  }
  return written;
}

render::ParticleCloud particleCloud(const SceneDesc& scene, const Solver& solver) {
  const ParticleArrays& p = solver.particles();
  std::vector<std::int32_t> bodyOf(p.size(), -1);
  for (int b = 0; b < solver.bodyCount(); ++b)
    for (std::int32_t i : solver.bodyParticles(b)) bodyOf[static_cast<std::size_t>(i)] = b;
  render::ParticleCloud cloud;
  for (const Material& m : scene.materials) cloud.materials.push_back(m.name);
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (phase::has(p.phase[i], phase::kRemoved)) continue;
    cloud.position.emplace_back(p.x[i], p.y[i], p.z[i]);
    cloud.velocity.emplace_back(p.vx[i], p.vy[i], p.vz[i]);
    cloud.body.push_back(bodyOf[i]);
    cloud.material.push_back(p.material[i]);
    cloud.stroke.push_back(p.stroke[i]);
  }
  return cloud;
}

void exportLevelSets(const SceneDesc& scene, const sketch::GridMapping& mapping, const Solver& solver,
                     const std::vector<Vec3i>& restCells, const std::vector<std::string>& bodyNames,
                     const FrameOptions& surfaces, const std::string& path) {
  const Vec3 origin = mapping.toWorld(Vec3i(0, 0, 0));
  const ParticleArrays& p = solver.particles();
  std::vector<render::LevelSetGrid> grids;
  for (int b = 0; b < solver.bodyCount(); ++b) {
    if (solver.mode(b) == BodyMode::kEmpty) continue;
    const std::string name = b < static_cast<int>(bodyNames.size()) ? bodyNames[static_cast<std::size_t>(b)] : "";
    const Mat4f model = solver.pose(b).model();
    for (const auto& [material, ids] : byMaterial(solver, b)) {
      const Material& mat = scene.materials[static_cast<std::size_t>(material)];
      render::LevelSetGrid g;
      g.name = bodyFileStem(b, name) + "/" + render::fileSafeName(mat.name);
      g.material = mat.name;
      const render::SurfaceKind surface = surfaceOf(mat.kind, scene.solver);
      if (surface == render::SurfaceKind::kRigidRestMesh) {
        for (std::int32_t i : ids) g.cells.push_back(restCells[static_cast<std::size_t>(i)]);
        g.model = model.cast<double>();
      } else if (surface == render::SurfaceKind::kFluid && !surfaces.fluidCells) {
        // The surface the frames show (meshFluid), turned into a level set.
        render::FluidSurfaceOptions fo;
        fo.voxelFraction = surfaces.fluidVoxelFraction;
        g.mesh = render::meshFluid(positionsOf(p, ids), mapping.voxelSize(), fo);
      } else if (mat.kind == MaterialKind::kRope) {
        g.mesh = ropeTube(solver, ids, positionsOf(p, ids), mapping.voxelSize());  // the frames' tube
      } else if (mat.kind == MaterialKind::kCloth && clothSheet(solver, b, ids, positionsOf(p, ids), mapping.voxelSize(), g.mesh)) {
        // the frames' sheet
      } else if (surfaces.solidGrid && mat.kind != MaterialKind::kCloth) {
        g.mesh = gridMassMesh(solver, ids, mapping.voxelSize(), particleVolume(solver, ids, mapping.voxelSize()));  // as the frames
      } else {
        // As meshParticles does it (render/voxel_mesh.h).
        const render::ParticleMeshOptions defaults;
        g.cells = render::particleCells(positionsOf(p, ids), mapping.voxelSize(), origin);
        g.surface = defaults.surface;
        g.smoothIterations = surfaces.smoothIterations;
        if (mat.kind != MaterialKind::kCloth) g.targetVolume = particleVolume(solver, ids, mapping.voxelSize());
      }
      grids.push_back(std::move(g));
    }
  }
  render::writeLevelSetsVdb(path, grids, mapping.voxelSize(), origin);
}

}  // namespace physketch::app
