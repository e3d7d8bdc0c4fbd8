#include "mpm/world.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include <Eigen/Eigenvalues>
#include <tbb/parallel_for.h>

#include "core/error.h"
#include "core/lattice.h"
#include "core/material_table.h"
#include "mpm/constitutive.h"
#include "mpm/kernels.h"
#include "mpm/plasticity.h"

namespace physketch::mpm {

using namespace detail;

const PassSpec kMpmPasses[static_cast<int>(MpmPass::kCount)] = {
    {"p2g", Cadence::kPerSubstep,
     "sort particles by grid block; scatter mass and APIC momentum with the stress term -h V 4/dx^2 tau (Hu 2018 Eq. 16)"},
    {"grid_update", Cadence::kPerSubstep,
     "grid velocities v = mv/m + h g; held nodes, walls and ground (sticky, slip or separate with friction)"},
    {"g2p", Cadence::kPerSubstep,
     "particle v and affine C = 4/dx^2 sum w v (x_i - x_p)^T from the grid, x += h v, F <- (I + h C) F"},
    {"projection", Cadence::kPerSubstep, "particles past a wall or the ground put back on it (VR-Doh Alg. 1 line 4)"},
    {"plasticity", Cadence::kPerSubstep,
     "return maps on F: Drucker-Prager (sand), von Mises (plasticine), snow clamp with J_p hardening"},
    {"particle_shift", Cadence::kPerStep,
     "fluid particles closer than particle_shift spacings pushed apart (2 Jacobi sweeps), v += C dx (Xu et al. 2009)"},
    {"guard", Cadence::kPerStep, "first NaN, explosion, inverted F (J <= 0) or particle faster than a cell per substep"},
};

namespace {

constexpr int kPad = 3;          // grid cells beyond each wall: the B-spline stencil of a particle on the wall

void hashBytes(std::uint64_t& h, const void* data, std::size_t n) {
  const auto* b = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    h ^= b[i];
    h *= 1099511628211ull;  // FNV-1a
  }
}

Eigen::Matrix3f skew(const Vec3& w) {
  Eigen::Matrix3f m;
  m << 0.0f, float(-w.z()), float(w.y()), float(w.z()), 0.0f, float(-w.x()), float(-w.y()), float(w.x()), 0.0f;
  return m;
}

std::string num(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

}  // namespace

std::string wallsText(const WallKind (&walls)[6]) {
  static const char* kSides[6] = {"x-", "x+", "y-", "y+", "z-", "z+"};
  bool same = true;
  for (int k = 1; k < 6; ++k) same = same && walls[k] == walls[0];
  if (same) return std::string(toString(walls[0]));
  std::string out;
  for (int k = 0; k < 6; ++k) out += std::string(k ? ", " : "") + kSides[k] + " " + toString(walls[k]);
  return out;
}

const char* toString(WallKind kind) {
  switch (kind) {
    case WallKind::kSticky: return "sticky";
    case WallKind::kSlip: return "slip";
    case WallKind::kSeparate: return "separate";
  }
  return "?";
}

MpmParams paramsFromScene(const SceneDesc& scene, double spacing) {
  MpmParams p;
  p.dt = scene.dt;
  p.substeps = scene.substepsAuto ? 0 : scene.substeps;
  p.gravity = scene.gravity;
  p.groundY = scene.groundY;
  p.spacing = spacing;
  p.domainSize = scene.workspaceSize;
  p.domainMin = scene.workspaceCenter - Vec3::Constant(0.5 * scene.workspaceSize);
  p.dxPerSpacing = scene.gridDx;
  p.particleShift = scene.particleShift;
  p.waveCourant = p.velocityCourant = scene.cfl;
  for (int k = 0; k < 6; ++k)
    p.walls[k] = scene.walls[k] == SceneDesc::Wall::kSticky ? WallKind::kSticky
                 : scene.walls[k] == SceneDesc::Wall::kSlip ? WallKind::kSlip
                                                             : WallKind::kSeparate;
  return p;
}

// --- construction ------------------------------------------------------------------

MpmWorld::MpmWorld(ParticleArrays particles, const std::vector<BodyRange>& bodies, std::vector<Material> materials,
                   const MpmParams& params)
    : params_(params), parts_(std::move(particles)), materials_(std::move(materials)) {
  if (!(params_.dt > 0) || params_.substeps < 0 || params_.substeps > kMaxSubsteps || !(params_.spacing > 0) ||
      !(params_.dxPerSpacing > 0) || !(params_.domainSize > 0) || !params_.domainMin.allFinite() ||
      !params_.gravity.allFinite() || !std::isfinite(params_.groundY))
    throw RuntimeError("MpmWorld: dt, spacing, grid and domain must be positive and finite, substeps in [0, 1000]");
  if (!(params_.particleShift >= 0.0 && params_.particleShift <= 1.0))
    throw RuntimeError("MpmWorld: particleShift must be in [0, 1] particle spacings");
  for (const Material& m : materials_) {
    const SolverModel sm = solverModel(m.kind, SolverKind::kMpm);
    if (!sm.simulated) throw RuntimeError("MpmWorld: material '" + m.name + "' is kind " + toString(m.kind) + ", which mpm does not simulate");
    const Material r = asRunBy(m, SolverKind::kMpm);
    MatModel mm;
    mm.kind = r.kind;
    mm.elastic = r.elastic.model;
    const Lame l = lameFromYoungs(r.elastic.youngs, r.elastic.poisson);
    mm.mu = float(l.mu);
    mm.lambda = float(l.lambda);
    mm.mass = float(r.density * params_.spacing * params_.spacing * params_.spacing);
    mm.mus = float(r.staticFriction);
    mm.muk = float(r.dynamicFriction);
    mm.ownFriction = r.frictionRule == Material::FrictionRule::kOwn;
    mm.frictionDeg = float(r.sand.frictionAngleDeg);
    mm.hardeningDeg = float(r.sand.hardening);
    mm.klar = r.sand.klar;
    mm.h0 = float(r.sand.h0), mm.h1 = float(r.sand.h1), mm.h2 = float(r.sand.h2), mm.h3 = float(r.sand.h3);
    mm.alpha = float(druckerPragerAlpha(r.sand.frictionAngleDeg * kPi / 180.0));
    mm.shift = float(cohesionStrain(r.sand.cohesion, l.mu, l.lambda));
    mm.thetaC = float(r.snow.thetaC);
    mm.thetaS = float(r.snow.thetaS);
    mm.xi = float(r.snow.hardening);
    mm.yield = float(r.plasticine.yieldStress);
    mm.bulk = float(r.fluid.bulkModulus);
    mm.gamma = float(r.fluid.gamma);
    mm.viscosity = float(r.fluid.viscosity);
    mm.plastic = r.kind == MaterialKind::kSand || r.kind == MaterialKind::kSnow || r.kind == MaterialKind::kPlasticine;
    models_.push_back(mm);
  }
  initGrid();
  const std::size_t n = parts_.size();
  C_.assign(n, Eigen::Matrix3f::Zero());
  F_.assign(n, Eigen::Matrix3f::Identity());
  plastic_.assign(n, 0.0f);
  fluidJ_.assign(n, 1.0f);
  for (std::size_t i = 0; i < n; ++i) initParticle(i);
  for (const BodyRange& br : bodies) {
    if (br.first < 0 || br.count < 1 || std::size_t(br.first) + std::size_t(br.count) > n)
      throw RuntimeError("MpmWorld: body " + std::to_string(members_.size()) + " has an invalid particle range");
    std::vector<std::int32_t> ids(static_cast<std::size_t>(br.count));
    for (std::int32_t k = 0; k < br.count; ++k) ids[std::size_t(k)] = br.first + k;
    const int b = static_cast<int>(members_.size());
    members_.push_back(ids);
    mode_.push_back(BodyMode::kDynamic);
    carry_.push_back(Vec3::Zero());
    for (std::int32_t i : ids) parts_.phase[std::size_t(i)] = phase::make(b);
    recordRestLattice(ids);
    if (br.init.fixed) setMode(b, BodyMode::kFixed);
    else applyInit(ids, br.init);
  }
  syncFixedColliders();
  // Particles outside every body (none from the sketch) simulate as free material.
  if (params_.substeps > 0) {
    const StepBound b = waveBound();
    const double h = params_.dt / params_.substeps;
    if (b.material >= 0 && h > b.h) {
      const int need = int(std::ceil(params_.dt / b.h - 1e-9));
      warnings_.push_back("substeps " + std::to_string(params_.substeps) + ": h = dt/substeps = " + num(h) +
                          " s is above the explicit bound h <= C dx / c_p = " + num(b.h) + " s of material '" +
                          materials_[std::size_t(b.material)].name + "' (c_p = " + num(b.waveSpeed) + " m/s, C = " +
                          num(params_.waveCourant) + ", dx = " + num(dx_) + " m): raise substeps to " +
                          std::to_string(need) + " or write 'substeps auto'");
    }
  }
}

void MpmWorld::initGrid() {
  dx_ = params_.dxPerSpacing * params_.spacing;
  const int cells = int(std::ceil(params_.domainSize / dx_ - 1e-9));
  if (cells < 1 || cells > 4096) throw RuntimeError("MpmWorld: the domain spans " + std::to_string(cells) + " grid cells (1..4096)");
  n_ = cells + 2 * kPad + 1;
  n_ = (n_ + kBlock - 1) / kBlock * kBlock;
  nb_ = n_ / kBlock;
  origin_ = params_.domainMin - Vec3::Constant(kPad * dx_);
  const Vec3 lo = params_.domainMin, hi = params_.domainMin + Vec3::Constant(params_.domainSize);
  for (int a = 0; a < 3; ++a) {
    wallLo_[a] = int(std::floor((lo[a] - origin_[a]) / dx_ + 1e-4));
    wallHi_[a] = int(std::ceil((hi[a] - origin_[a]) / dx_ - 1e-4));
    lo_[a] = float(lo[a]);
    hi_[a] = float(hi[a]);
  }
  // The ground acts where it is inside the domain; below it, the floor wall does.
  if (params_.groundY > lo.y()) {
    const double g = std::min(params_.groundY, hi.y());
    groundNode_ = int(std::floor((g - origin_.y()) / dx_ + 1e-4));
    lo_[1] = float(g);
  }
  const std::size_t nodes = std::size_t(n_) * std::size_t(n_) * std::size_t(n_);
  grid_.assign(nodes, Node{0.0f, 0.0f, 0.0f, 0.0f});
  mixedFriction_ = false;
  uniformMus_ = models_.empty() ? 0.0f : models_[0].mus;
  uniformMuk_ = models_.empty() ? 0.0f : models_[0].muk;
  for (const MatModel& m : models_) mixedFriction_ |= m.mus != uniformMus_ || m.muk != uniformMuk_;
  if (mixedFriction_) {
    gfs_.assign(nodes, 0.0f);
    gfk_.assign(nodes, 0.0f);
  }
  jbar_.clear();
  for (const MatModel& m : models_)
    if (m.kind == MaterialKind::kFluid) jbar_.assign(2 * nodes, 0.0f);
  held_.assign(nodes, 0);
  nodeBlockMark_.assign(std::size_t(nb_) * nb_ * nb_, 0);
}

// Mass, state and a position inside the walls (the grid has no node outside them to write).
void MpmWorld::initParticle(std::size_t i) {
  const auto m = static_cast<std::size_t>(parts_.material[i]);
  if (m >= models_.size()) throw RuntimeError("MpmWorld: particle " + std::to_string(i) + " has an unknown material");
  parts_.mass[i] = models_[m].mass;
  C_[i].setZero();
  F_[i].setIdentity();
  plastic_[i] = models_[m].kind == MaterialKind::kSand ? 0.0f : 1.0f;  // q = 0; snow J_p = 1; fluid J = 1
  float* pos[3] = {&parts_.x[i], &parts_.y[i], &parts_.z[i]};
  for (int a = 0; a < 3; ++a) *pos[a] = std::clamp(*pos[a], lo_[a], hi_[a]);
}

Vec3 MpmWorld::centreOfMass(std::size_t b) const {
  double m = 0.0;
  Vec3 c = Vec3::Zero();
  for (std::int32_t i : members_[b]) {
    const auto k = std::size_t(i);
    m += parts_.mass[k];
    c += double(parts_.mass[k]) * Vec3(parts_.x[k], parts_.y[k], parts_.z[k]);
  }
  return m > 0.0 ? Vec3(c / m) : Vec3::Zero();
}

// v = v0 + w x (x - c) per particle, and C = [w]x: the APIC affine field of that motion.
void MpmWorld::applyInit(const std::vector<std::int32_t>& ids, const BodyInit& init) {
  const auto b = static_cast<std::size_t>(parts_.group(std::size_t(ids.front())));
  const Vec3 c = centreOfMass(b);
  const Eigen::Matrix3f W = skew(init.spin);
  for (std::int32_t i : ids) {
    const auto k = std::size_t(i);
    const Vec3 v = init.velocity + init.spin.cross(Vec3(parts_.x[k], parts_.y[k], parts_.z[k]) - c);
    parts_.vx[k] = float(v.x());
    parts_.vy[k] = float(v.y());
    parts_.vz[k] = float(v.z());
    C_[k] = W;
  }
}

// --- bodies ------------------------------------------------------------------------

BodyPose MpmWorld::pose(int body) const {
  BodyPose p;
  p.centre = p.restCentre = centreOfMass(std::size_t(body));
  return p;
}

Vec3 MpmWorld::velocity(int body) const {
  double m = 0.0;
  Vec3 p = Vec3::Zero();
  for (std::int32_t i : members_.at(std::size_t(body))) {
    const auto k = std::size_t(i);
    m += parts_.mass[k];
    p += double(parts_.mass[k]) * Vec3(parts_.vx[k], parts_.vy[k], parts_.vz[k]);
  }
  return m > 0.0 ? Vec3(p / m) : Vec3::Zero();
}

// w = I^-1 L about the centre of mass, from the particles as points (a rigid rotation w x r
// gives back w exactly); a body too thin for that (one particle, a line) adds each particle's
// own cube inertia m h^2/6 so that I stays invertible.
Vec3 MpmWorld::angularVelocity(int body) const {
  const Vec3 c = centreOfMass(std::size_t(body));
  Mat3 I = Mat3::Zero();
  Vec3 L = Vec3::Zero();
  double cube = 0.0;
  const double h2 = params_.spacing * params_.spacing;
  for (std::int32_t i : members_.at(std::size_t(body))) {
    const auto k = std::size_t(i);
    const double m = parts_.mass[k];
    const Vec3 r = Vec3(parts_.x[k], parts_.y[k], parts_.z[k]) - c;
    L += m * r.cross(Vec3(parts_.vx[k], parts_.vy[k], parts_.vz[k]));
    I += m * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
    cube += m * h2 / 6.0;
  }
  if (!(cube > 0.0)) return Vec3::Zero();
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(I);
  if (!(eig.eigenvalues().minCoeff() > 1e-6 * eig.eigenvalues().maxCoeff())) I += cube * Mat3::Identity();
  return I.ldlt().solve(L);
}

int MpmWorld::addBody(const ParticleArrays& p, const BodyRange& shape, bool kinematic) {
  energy_.reset();
  const BodyInit& init = shape.init;
  if (p.size() == 0) throw RuntimeError("MpmWorld::addBody: a body needs particles");
  const int b = static_cast<int>(members_.size());
  std::vector<std::int32_t> ids;
  ids.reserve(p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (p.material[i] < 0 || static_cast<std::size_t>(p.material[i]) >= models_.size())
      throw RuntimeError("MpmWorld::addBody: unknown material index");
    const std::int32_t id = parts_.push(p.x[i], p.y[i], p.z[i], p.stroke[i], p.material[i]);
    C_.push_back(Eigen::Matrix3f::Zero());
    F_.push_back(Eigen::Matrix3f::Identity());
    plastic_.push_back(1.0f);
    fluidJ_.push_back(1.0f);
    placeInColliders_ = true;
    initParticle(std::size_t(id));
    parts_.phase[std::size_t(id)] = phase::make(b);
    ids.push_back(id);
  }
  members_.push_back(ids);
  mode_.push_back(BodyMode::kDynamic);
  carry_.push_back(Vec3::Zero());
  recordRestLattice(ids);
  if (kinematic) setMode(b, BodyMode::kKinematic);
  else if (init.fixed) setMode(b, BodyMode::kFixed);
  else applyInit(ids, init);
  return b;
}

// Fixed and carried bodies are prescribed (infinite mass): they do not scatter to the grid;
// the nodes they touch take their velocity (sticky). A released carried body keeps the
// velocity of its last prescribed motion.
void MpmWorld::setMode(int body, BodyMode mode) {
  energy_.reset();
  const auto b = static_cast<std::size_t>(body);
  if (mode_.at(b) == BodyMode::kEmpty || mode == BodyMode::kEmpty) return;
  const BodyMode before = mode_[b];
  mode_[b] = mode;
  if (before == BodyMode::kFixed || mode == BodyMode::kFixed) fixedDirty_.push_back(body);
  const std::uint32_t flags = mode == BodyMode::kDynamic ? 0u : phase::kPrescribed;
  const Vec3 v = before == BodyMode::kKinematic && mode == BodyMode::kDynamic ? carry_[b] : Vec3::Zero();
  for (std::int32_t i : members_[b]) {
    const auto k = std::size_t(i);
    parts_.phase[k] = phase::make(body, flags);
    if (mode != BodyMode::kDynamic || before != BodyMode::kDynamic) {
      parts_.vx[k] = float(v.x());
      parts_.vy[k] = float(v.y());
      parts_.vz[k] = float(v.z());
      C_[k].setZero();
    }
  }
  carry_[b] = Vec3::Zero();
}

void MpmWorld::setVelocity(int body, const Vec3& velocity, const Vec3& angularVelocity) {
  energy_.reset();
  const auto b = static_cast<std::size_t>(body);
  if (mode_.at(b) != BodyMode::kDynamic) throw RuntimeError("MpmWorld::setVelocity: body is not dynamic");
  if (!velocity.allFinite() || !angularVelocity.allFinite()) throw RuntimeError("MpmWorld::setVelocity: not finite");
  if (members_[b].empty()) return;
  BodyInit init;
  init.velocity = velocity;
  init.spin = angularVelocity;
  applyInit(members_[b], init);
}

// The body's particles move by (centre - current centre of mass) over the next step.
void MpmWorld::setKinematicTarget(int body, const Vec3& centre) {
  const auto b = static_cast<std::size_t>(body);
  if (mode_.at(b) != BodyMode::kKinematic) throw RuntimeError("MpmWorld::setKinematicTarget: body is not kinematic");
  if (!centre.allFinite()) throw RuntimeError("MpmWorld::setKinematicTarget: not finite");
  const Vec3 v = (centre - centreOfMass(b)) / params_.dt;
  carry_[b] = v;
  for (std::int32_t i : members_[b]) {
    const auto k = std::size_t(i);
    parts_.vx[k] = float(v.x());
    parts_.vy[k] = float(v.y());
    parts_.vz[k] = float(v.z());
  }
}

// The cells of a new body's particles in its rest lattice (offsets from its first particle in
// spacings, rounded: they are sketched on the lattice) and its design pieces (their
// 26-connected components), kept for cuts.
void MpmWorld::recordRestLattice(const std::vector<std::int32_t>& ids) {
  restCell_.resize(parts_.size(), Vec3i::Zero());
  design_.resize(parts_.size(), 0);
  if (ids.empty()) return;
  const double inv = 1.0 / params_.spacing;
  const auto f = std::size_t(ids.front());
  std::vector<Vec3i> cells(ids.size());
  for (std::size_t k = 0; k < ids.size(); ++k) {
    const auto i = std::size_t(ids[k]);
    cells[k] = Vec3i(int(std::lround((double(parts_.x[i]) - parts_.x[f]) * inv)),
                     int(std::lround((double(parts_.y[i]) - parts_.y[f]) * inv)),
                     int(std::lround((double(parts_.z[i]) - parts_.z[f]) * inv)));
    restCell_[i] = cells[k];
  }
  const std::vector<std::int32_t> label = componentLabels26(cells);
  for (std::size_t k = 0; k < ids.size(); ++k) design_[std::size_t(ids[k])] = label[k];
}

// A body a removal disconnected in its rest lattice becomes several (core/lattice.h cutPieces,
// the rule of PBD's rigid bodies and of cuts before play): the pieces that stay whole keep the
// index, each fragment is appended as a body in the body's mode (a carried body's fragments are
// released with the carried velocity: only the piece on the brush stays on it). Fluid bodies
// are not split (a fluid has no shape to cut). Returns the bodies appended.
std::vector<int> MpmWorld::splitCut(int body) {
  const auto b = std::size_t(body);
  auto& mem = members_[b];
  if (mem.empty()) return {};
  bool solid = false;
  for (std::int32_t i : mem) solid = solid || models_[std::size_t(parts_.material[std::size_t(i)])].kind != MaterialKind::kFluid;
  if (!solid) return {};
  std::vector<Vec3i> cells(mem.size());
  for (std::size_t k = 0; k < mem.size(); ++k) cells[k] = restCell_[std::size_t(mem[k])];
  auto pieces = cutPieces(mem, cells, design_);
  if (pieces.size() == 1) return {};
  mem = std::move(pieces[0]);
  const BodyMode mode = mode_[b];
  std::vector<int> added;
  for (std::size_t p = 1; p < pieces.size(); ++p) {
    const int nb = static_cast<int>(members_.size());
    for (std::int32_t i : pieces[p]) {
      parts_.phase[std::size_t(i)] = phase::make(nb, parts_.phase[std::size_t(i)] & ~phase::kGroupMask);
      design_[std::size_t(i)] = 0;  // a fragment is one connected piece
    }
    members_.push_back(std::move(pieces[p]));
    mode_.push_back(mode);
    carry_.push_back(carry_[b]);
    if (mode == BodyMode::kKinematic) setMode(nb, BodyMode::kDynamic);
    added.push_back(nb);
  }
  return added;
}

std::vector<int> MpmWorld::removeParticles(const std::vector<std::int32_t>& ids) {
  energy_.reset();
  std::vector<int> changed;
  for (std::int32_t i : ids) {
    if (i < 0 || static_cast<std::size_t>(i) >= parts_.size() || !alive(i)) continue;
    const auto k = std::size_t(i);
    const int b = parts_.group(k);
    parts_.phase[k] = phase::make(-1, phase::kRemoved | phase::kPrescribed);
    parts_.vx[k] = parts_.vy[k] = parts_.vz[k] = 0.0f;
    if (b >= 0 && std::find(changed.begin(), changed.end(), b) == changed.end()) changed.push_back(b);
  }
  std::sort(changed.begin(), changed.end());
  std::vector<int> out = changed;
  for (int b : changed)
    if (mode_[std::size_t(b)] == BodyMode::kFixed) fixedDirty_.push_back(b);
  for (int b : changed) {
    auto& mem = members_[std::size_t(b)];
    mem.erase(std::remove_if(mem.begin(), mem.end(), [&](std::int32_t i) { return !alive(i); }), mem.end());
    if (mem.empty()) {
      mode_[std::size_t(b)] = BodyMode::kEmpty;
      continue;
    }
    const std::vector<int> added = splitCut(b);
    for (int nb : added)
      if (mode_[std::size_t(nb)] == BodyMode::kFixed) fixedDirty_.push_back(nb);
    out.insert(out.end(), added.begin(), added.end());
  }
  std::sort(out.begin(), out.end());
  return out;
}

// --- time step bounds --------------------------------------------------------------

// c_p = sqrt((lambda + 2 mu) / rho) for the solids (snow with its current largest hardening
// factor), sqrt(K / rho0 J_min^(1 - gamma)) for the Tait fluid (the sound speed at its most
// compressed particle), and the explicit viscous bound h <= rho dx^2 / (6 mu_v).
StepBound MpmWorld::waveBound() const {
  std::vector<char> used(models_.size(), 0);
  std::vector<float> snowFactor(models_.size(), 1.0f), fluidJ(models_.size(), 1.0f);
  for (std::size_t i = 0; i < parts_.size(); ++i) {
    if (!phase::dynamic(parts_.phase[i])) continue;
    const auto m = std::size_t(parts_.material[i]);
    used[m] = 1;
    if (models_[m].kind == MaterialKind::kSnow)
      snowFactor[m] = std::max(snowFactor[m], snowHardening(models_[m].xi, plastic_[i]));
    if (models_[m].kind == MaterialKind::kFluid) fluidJ[m] = std::min(fluidJ[m], std::max(fluidJ_[i], 1e-3f));  // the J its pressure takes
  }
  StepBound best;
  best.h = std::numeric_limits<double>::infinity();
  for (std::size_t m = 0; m < models_.size(); ++m) {
    if (!used[m]) continue;
    const MatModel& mm = models_[m];
    const double rho = materials_[m].density;
    double c2;
    double h = std::numeric_limits<double>::infinity();
    if (mm.kind == MaterialKind::kFluid) {
      c2 = double(mm.bulk) / rho * std::pow(double(fluidJ[m]), 1.0 - double(mm.gamma));
      if (mm.viscosity > 0.0f) h = rho * dx_ * dx_ / (6.0 * double(mm.viscosity));
    } else {
      c2 = double(snowFactor[m]) * (double(mm.lambda) + 2.0 * double(mm.mu)) / rho;
    }
    const double c = std::sqrt(c2);
    h = std::min(h, params_.waveCourant * dx_ / c);
    if (h < best.h) best = StepBound{h, c, int(m)};
  }
  return best;
}

int MpmWorld::substepsForNextStep() const {
  if (params_.substeps > 0) return params_.substeps;
  const StepBound b = waveBound();
  float vmax2 = 0.0f;
  for (std::size_t i = 0; i < parts_.size(); ++i) {
    if (!phase::dynamic(parts_.phase[i])) continue;
    const float v2 = parts_.vx[i] * parts_.vx[i] + parts_.vy[i] * parts_.vy[i] + parts_.vz[i] * parts_.vz[i];
    vmax2 = std::max(vmax2, v2);
  }
  // A carried body (a tool) holds the nodes it touches at its own velocity, so material there
  // moves at that speed: it counts like a particle's.
  for (std::size_t body = 0; body < mode_.size(); ++body)
    if (mode_[body] == BodyMode::kKinematic) vmax2 = std::max(vmax2, float(carry_[body].squaredNorm()));
  // The fastest particle may speed up by |g| dt within the step.
  const double vmax = std::sqrt(double(vmax2)) + params_.gravity.norm() * params_.dt;
  double h = b.h;
  if (vmax > 0.0) h = std::min(h, params_.velocityCourant * dx_ / vmax);
  if (!std::isfinite(h)) return 1;
  const double n = std::ceil(params_.dt / h - 1e-9);
  if (n > kMaxSubsteps) return 0;
  return std::max(1, int(n));
}

// --- the plan ----------------------------------------------------------------------

std::vector<bool> MpmWorld::work() const {
  std::vector<bool> on(static_cast<std::size_t>(MpmPass::kCount), false);
  bool dynamic = false, plastic = false, any = false, fluid = false;
  for (std::size_t i = 0; i < parts_.size(); ++i) {
    any = any || !phase::has(parts_.phase[i], phase::kRemoved);
    if (!phase::dynamic(parts_.phase[i])) continue;
    dynamic = true;
    const MatModel& m = models_[std::size_t(parts_.material[i])];
    plastic = plastic || m.plastic;
    fluid = fluid || m.kind == MaterialKind::kFluid;
  }
  const bool carried = std::count(mode_.begin(), mode_.end(), BodyMode::kKinematic) > 0;
  on[int(MpmPass::kP2G)] = dynamic;
  on[int(MpmPass::kGridUpdate)] = dynamic;
  on[int(MpmPass::kG2P)] = dynamic || carried;
  on[int(MpmPass::kProjection)] = dynamic;
  on[int(MpmPass::kPlasticity)] = plastic;
  on[int(MpmPass::kShift)] = fluid && params_.particleShift > 0.0;
  on[int(MpmPass::kGuard)] = any;
  return on;
}

std::string MpmWorld::reason(MpmPass pass, bool on) const {
  std::vector<std::string> names;
  for (std::size_t m = 0; m < models_.size(); ++m) {
    bool used = false;
    for (std::size_t i = 0; i < parts_.size() && !used; ++i)
      used = phase::dynamic(parts_.phase[i]) && std::size_t(parts_.material[i]) == m &&
             (pass != MpmPass::kPlasticity || models_[m].plastic) &&
             (pass != MpmPass::kShift || models_[m].kind == MaterialKind::kFluid);
    if (used) names.push_back(materials_[m].name + " (" + toString(models_[m].kind) + ")");
  }
  std::string list;
  for (const auto& s : names) list += (list.empty() ? "" : ", ") + s;
  switch (pass) {
    case MpmPass::kP2G:
    case MpmPass::kG2P: {
      if (!on) return "no dynamic particle (all fixed, held or removed)";
      std::string extra;
      if (!jbar_.empty()) extra += "; fluid J-bar (pressure from the grid-averaged J)";
      if (pass == MpmPass::kP2G && !side_.empty()) extra += "; collider side field (mass moment per node)";
      return "materials " + list + extra;
    }
    case MpmPass::kGridUpdate:
      return on ? std::string("gravity, ") + wallsText(params_.walls) +
                      " walls (friction: the materials' static/dynamic_friction), ground y = " + num(params_.groundY) +
                      collidersText()
                : "no dynamic particle";
    case MpmPass::kProjection:
      return on ? std::string("walls and ground (in g2p's particle loop: their time is g2p's)") +
                      (colliders_.empty() ? std::string() : "; then" + collidersText().substr(1))
                : "no dynamic particle";
    case MpmPass::kPlasticity:
      return on ? "plastic materials " + list : "no dynamic particle of a plastic kind (sand, snow, plasticine)";
    case MpmPass::kShift:
      if (on) return "particle_shift " + num(params_.particleShift) + " spacings: fluids " + list;
      return params_.particleShift > 0.0 ? "no dynamic fluid" : "particle_shift 0 (off; the scene's particle_shift record)";
    case MpmPass::kGuard: return on ? "checks every step" : "no particles";
    case MpmPass::kCount: break;
  }
  return "";
}

std::string MpmWorld::touches(MpmPass pass) const {
  long dyn = 0, plastic = 0, fluid = 0;
  for (std::size_t i = 0; i < parts_.size(); ++i) {
    if (!phase::dynamic(parts_.phase[i])) continue;
    ++dyn;
    plastic += models_[std::size_t(parts_.material[i])].plastic;
    fluid += models_[std::size_t(parts_.material[i])].kind == MaterialKind::kFluid;
  }
  const long cells = long(n_) * n_ * n_;
  switch (pass) {
    case MpmPass::kGridUpdate:
      return "the nodes near " + std::to_string(dyn) + " particles (grid " + std::to_string(n_) + "^3 = " +
             std::to_string(cells) + " nodes, dx = " + num(dx_) + " m)";
    case MpmPass::kPlasticity: return std::to_string(plastic) + " particles";
    case MpmPass::kShift: return std::to_string(fluid) + " particles";
    default: return std::to_string(dyn) + " particles";
  }
}

std::vector<PlanEntry> MpmWorld::planAll() const {
  std::vector<PlanEntry> out;
  const std::vector<bool> on = work();
  const int s = substepsForNextStep();
  std::string runs;
  if (params_.substeps > 0) {
    runs = "substeps = " + std::to_string(s);
  } else {
    const StepBound b = waveBound();
    runs = "substeps auto = " + (s > 0 ? std::to_string(s) : std::string("more than 1000")) + " now";
    if (b.material >= 0)
      runs += " (h <= C dx / c_p = " + num(b.h) + " s from material " + materials_[std::size_t(b.material)].name +
              ", C = " + num(params_.waveCourant) + ", c_p = " + num(b.waveSpeed) + " m/s)";
  }
  for (int k = 0; k < int(MpmPass::kCount); ++k) {
    const PassSpec& spec = kMpmPasses[k];
    PlanEntry e;
    e.pass = k;
    e.name = spec.name;
    e.does = spec.does;
    e.on = on[std::size_t(k)];
    e.runs = spec.cadence == Cadence::kPerSubstep ? runs : "once";
    e.perStep = e.on ? (spec.cadence == Cadence::kPerSubstep ? s : 1) : 0;
    e.reason = reason(MpmPass(k), e.on);
    if (e.on) e.touches = touches(MpmPass(k));
    e.heldBytes = passBytes(MpmPass(k));
    out.push_back(std::move(e));
  }
  return out;
}

std::vector<PlanEntry> MpmWorld::plan() const {
  std::vector<PlanEntry> out;
  for (PlanEntry& e : planAll())
    if (e.on) out.push_back(std::move(e));
  return out;
}

Mat3 MpmWorld::deformationGradient(std::int32_t i) const {
  const auto k = std::size_t(i);
  if (k >= parts_.size()) throw RuntimeError("MpmWorld::deformationGradient: no particle " + std::to_string(i));
  if (models_[std::size_t(parts_.material[k])].kind == MaterialKind::kFluid)
    return Mat3::Identity() * std::cbrt(double(plastic_[k]));
  return F_[k].cast<double>();
}

// P2G's mass transfer alone, for the given particles: the same stencil (stencilBase, the same
// float offsets and B-spline weights), summed in double in the order of `ids` on a dense box one
// node wider than the stencils on every side.
bool MpmWorld::massField(const std::vector<std::int32_t>& ids, NodeField& out) const {
  using detail::bsplineWeights;
  using detail::stencilBase;
  const float inv = float(1.0 / dx_);
  const float o[3] = {float(origin_.x()), float(origin_.y()), float(origin_.z())};
  const float* pos[3] = {parts_.x.data(), parts_.y.data(), parts_.z.data()};
  std::vector<std::int32_t> live;
  live.reserve(ids.size());
  Vec3i lo = Vec3i::Constant(n_), hi = Vec3i::Constant(-1);
  for (std::int32_t i : ids) {
    if (i < 0 || std::size_t(i) >= parts_.size() || !alive(i)) continue;
    live.push_back(i);
    for (int a = 0; a < 3; ++a) {
      const int base = stencilBase(pos[a][std::size_t(i)] - o[a], inv, n_);
      lo[a] = std::min(lo[a], base);
      hi[a] = std::max(hi[a], base + 2);
    }
  }
  out.spacing = dx_;
  out.values.clear();
  if (live.empty()) {
    out.origin = origin_;
    out.size = Vec3i::Zero();
    return true;
  }
  lo -= Vec3i::Ones();  // a node of zero mass past every stencil: the field closes inside the box
  hi += Vec3i::Ones();
  out.origin = origin_ + dx_ * lo.cast<double>();
  out.size = hi - lo + Vec3i::Ones();
  std::vector<double> acc(std::size_t(out.size.prod()), 0.0);
  for (std::int32_t i : live) {
    const auto k = std::size_t(i);
    int base[3];
    float w[3][3];
    for (int a = 0; a < 3; ++a) {
      base[a] = stencilBase(pos[a][k] - o[a], inv, n_);
      bsplineWeights((pos[a][k] - o[a]) * inv - float(base[a]), w[a]);
      base[a] -= lo[a];
    }
    const double m = parts_.mass[k];
    for (int c = 0; c < 3; ++c)
      for (int b = 0; b < 3; ++b)
        for (int a = 0; a < 3; ++a)
          acc[out.index(base[0] + a, base[1] + b, base[2] + c)] += m * double(w[0][a] * w[1][b] * w[2][c]);
  }
  out.values.assign(acc.begin(), acc.end());
  return true;
}

// The Tait equation of state of a fluid particle (plasticity.h, fluidKirchhoff): p = K / gamma
// (J^-gamma - 1), J the particle's volume ratio.
double MpmWorld::pressure(std::int32_t i) const {
  const auto k = std::size_t(i);
  if (k >= parts_.size() || !phase::dynamic(parts_.phase[k])) return std::numeric_limits<double>::quiet_NaN();
  const auto& m = models_[std::size_t(parts_.material[k])];
  if (m.kind != MaterialKind::kFluid) return std::numeric_limits<double>::quiet_NaN();
  return double(m.bulk) / double(m.gamma) * (std::pow(double(fluidJ_[k]), -double(m.gamma)) - 1.0);
}

// The buffers each pass owns, kept between steps (capacity): P2G the grid, the particle
// sort it scatters in and the jelly's rotations; the grid update the held (tool) nodes and the
// colliders' distance fields (and static ones' cell masks); G2P the particle state it writes
// (C, F and the plastic scalar: J for a fluid); plasticity the SVDs it leaves for P2G.
std::size_t MpmWorld::passBytes(MpmPass pass) const {
  switch (pass) {
    case MpmPass::kP2G: {
      std::size_t b = heldBytes(grid_, gfs_, gfk_, jbar_, side_, order_, blockStart_, blockKey_, activeNodeBlocks_, nodeBlockMark_,
                                particleBlocks_, keyChanged_, polarQ_);
      for (const auto& c : colourBlocks_) b += heldBytes(c);
      return b;
    }
    case MpmPass::kGridUpdate: {
      std::size_t b = heldBytes(held_, hx_, hy_, hz_, hn_, hmus_, hmuk_);
      for (const Collider& c : colliders_) b += c.sdf.bytes() + heldBytes(c.near);
      return b;
    }
    case MpmPass::kG2P: return heldBytes(C_, F_, plastic_, fluidJ_);
    case MpmPass::kPlasticity: return heldBytes(svdU_, svdLnS_);
    case MpmPass::kProjection: return heldBytes(blockTails_);
    case MpmPass::kShift:
      return heldBytes(shiftIds_, shiftX_, shiftY_, shiftZ_, shiftD_, shiftLists_.index, shiftLists_.count) +
             shiftGrid_.heldBytes();
    default: return 0;
  }
}

// --- the step and its guard ----------------------------------------------------------

GuardRecord MpmWorld::check(MpmPass pass) const {
  GuardRecord r = checkParticles(parts_, params_.maxSpeed);
  if (r.tripped()) return r;
  const auto fill = [&](std::size_t i, GuardKind kind, double value, double bound, const char* hint) {
    r.kind = kind;
    r.particle = static_cast<std::int32_t>(i);
    r.body = parts_.group(i);
    r.stroke = parts_.stroke[i];
    r.value = value;
    r.bound = bound;
    r.hint = hint;
  };
  // J is checked after the passes that change F (g2p, plasticity) and at the end of the step;
  // moving more than one cell per substep breaks the transfer's locality (Hu et al. 2018 §5).
  // Both in one parallel sweep: per chunk the first particle that fails each, then the lowest
  // over the chunks (the same particle for any thread count), an inversion before a speed.
  const bool checkJ = pass == MpmPass::kG2P || pass == MpmPass::kPlasticity || pass == MpmPass::kGuard;
  const bool checkCfl = lastSubsteps_ > 0 && (pass == MpmPass::kG2P || pass == MpmPass::kGuard);
  if (!checkJ && !checkCfl) return r;
  const double vmax = checkCfl ? dx_ / substepH_ : 0.0;
  const std::size_t n = parts_.size(), chunks = (n + kChunk - 1) / kChunk;
  // Snow whose plastic volume ratio J_p sits at its lower clamp (snowClamp): its hardening is
  // capped there, so further compression meets no more resistance (the volume is lost, not
  // resisted). The stretched side's clamp only caps softening (torn snow), which is harmless.
  std::vector<float> jpFloor(models_.size(), -1.0f);
  for (std::size_t m = 0; m < models_.size(); ++m)
    if (models_[m].kind == MaterialKind::kSnow) jpFloor[m] = float(snowJpMin(double(models_[m].xi)));
  std::vector<std::int64_t> firstJ(chunks, -1), firstCfl(chunks, -1), firstJp(chunks, -1);
  forRange(n, [&](std::size_t lo, std::size_t hi) {
    std::int64_t j = -1, c = -1, p = -1;
    for (std::size_t i = lo; i < hi && j < 0; ++i) {
      if (!phase::dynamic(parts_.phase[i])) continue;
      if (checkJ) {
        const auto m = std::size_t(parts_.material[i]);
        const bool fluid = models_[m].kind == MaterialKind::kFluid;
        const float J = fluid ? std::min(plastic_[i], fluidJ_[i]) : F_[i].determinant();
        if (!(J > 0.0f)) j = std::int64_t(i);
        if (p < 0 && plastic_[i] <= jpFloor[m]) p = std::int64_t(i);
      }
      if (checkCfl && c < 0) {
        const double v2 = double(parts_.vx[i]) * parts_.vx[i] + double(parts_.vy[i]) * parts_.vy[i] +
                          double(parts_.vz[i]) * parts_.vz[i];
        if (v2 > vmax * vmax) c = std::int64_t(i);
      }
    }
    firstJ[lo / kChunk] = j;
    firstCfl[lo / kChunk] = c;
    firstJp[lo / kChunk] = p;
  });
  const auto lowest = [](const std::vector<std::int64_t>& v) {
    for (std::int64_t i : v)
      if (i >= 0) return i;
    return std::int64_t(-1);
  };
  if (const std::int64_t i = lowest(firstJ); i >= 0) {
    const auto k = std::size_t(i);
    const bool fluid = models_[std::size_t(parts_.material[k])].kind == MaterialKind::kFluid;
    fill(k, GuardKind::kInverted, fluid ? std::min(plastic_[k], fluidJ_[k]) : F_[k].determinant(), 0.0,
         "The deformation gradient inverted (J <= 0).");
    return r;
  }
  if (const std::int64_t i = lowest(firstJp); i >= 0) {
    const auto k = std::size_t(i);
    fill(k, GuardKind::kCompression, plastic_[k], jpFloor[std::size_t(parts_.material[k])],
         "Snow's plastic volume ratio J_p reached its clamp, where its hardening e^(xi (1 - J_p)) stops "
         "growing (Stomakhin et al. 2013): compressed further, it gives up volume without resisting.");
    return r;
  }
  std::int64_t cfl = lowest(firstCfl);
  double cflV2 = 0.0;
  if (cfl >= 0) {
    const auto k = std::size_t(cfl);
    cflV2 = double(parts_.vx[k]) * parts_.vx[k] + double(parts_.vy[k]) * parts_.vy[k] + double(parts_.vz[k]) * parts_.vz[k];
  }
  // After g2p: also a particle the walls stopped in g2p's own loop (its speed before they did).
  if (pass == MpmPass::kG2P && checkCfl)
    for (const BlockTail& t : blockTails_)
      if (t.cflFirst >= 0 && (cfl < 0 || t.cflFirst <= cfl)) cfl = t.cflFirst, cflV2 = t.cflSpeed2;
  if (cfl >= 0)
    fill(std::size_t(cfl), GuardKind::kCfl, std::sqrt(cflV2), vmax,
         "A particle moves more than one grid cell per substep (speed above dx/h, Hu et al. 2018 §5).");
  return r;
}

template <class F>
bool MpmWorld::runPass(MpmPass pass, int substep, bool checkNow, F&& f) {
  {
    ScopedPass t(profile_, pass);
    f();
  }
  if (!checkNow) return true;
  GuardRecord r = check(pass);
  if (!r.tripped()) return true;
  r.pass = kMpmPasses[int(pass)].name;
  r.step = steps_;
  r.substep = substep;
  guard_ = std::move(r);
  return false;
}

bool MpmWorld::runStep(int substeps, bool checkEachPass) {
  // Under `substeps auto`, a snow's hardening and a fluid's compression raise their wave speed
  // within the step: the bound is taken again after each substep, and where the substep no
  // longer meets it the rest of the step is cut into more, shorter substeps (the count the
  // step started with is only the start's bound: snow thrown at the ground at 8 m/s hardened
  // within one step until it blew up, CFL at 57 m/s).
  const bool replan = params_.substeps == 0 && boundMayTighten();
  lastSubsteps_ = substeps;  // a replay starts over
  substepH_ = params_.dt / substeps;
  float h = float(substepH_);
  const auto runs = [&](MpmPass p) { return bool(work_[std::size_t(p)]); };
  svdCached_ = polarCached_ = false;  // see svdU_, polarQ_
  // The end-of-step guard's checks are summed by the last g2p where nothing moves a particle or
  // changes its F after it (StepSummary).
  const bool summarize =
      runs(MpmPass::kGuard) && colliders_.empty() && !runs(MpmPass::kPlasticity) && !runs(MpmPass::kShift);
  summary_.valid = false;
  double done = 0.0;  // s of the step behind
  int left = substeps;
  for (int s = 0; left > 0; ++s, --left) {
    lastH_ = h;
    if (!colliders_.empty()) poseColliders(double(steps_) * params_.dt + (replan ? done : double(s) * double(h)), double(h));
    if (runs(MpmPass::kP2G) && !runPass(MpmPass::kP2G, s, checkEachPass, [&] { p2g(h); })) return false;
    if (runs(MpmPass::kGridUpdate) && !runPass(MpmPass::kGridUpdate, s, checkEachPass, [&] { gridUpdate(h); }))
      return false;
    const bool last = left == 1;
    if (runs(MpmPass::kG2P) && !runPass(MpmPass::kG2P, s, checkEachPass, [&] { g2p(h, s, summarize && last); }))
      return false;
    if (runs(MpmPass::kProjection) && !runPass(MpmPass::kProjection, s, checkEachPass, [&] { projection(); }))
      return false;
    if (runs(MpmPass::kPlasticity) && !runPass(MpmPass::kPlasticity, s, checkEachPass, [&] { plasticity(); }))
      return false;
    done += substepH_;
    if (!replan || last) continue;
    const double bound = waveBound().h, rest = params_.dt - done;
    if (!(substepH_ > bound)) continue;
    // At most kMaxSubsteps in the step: past that, the next step's start names the material
    // (tooManySubsteps), and a substep still too long here is the guard's to catch.
    const double more = std::min(std::ceil(rest / bound - 1e-9), double(std::max(1, kMaxSubsteps - (s + 1))));
    left = int(more) + 1;  // the loop's decrement leaves `more`
    substepH_ = rest / more;
    h = float(substepH_);
    lastSubsteps_ = s + 1 + int(more);
  }
  if (runs(MpmPass::kShift) && !runPass(MpmPass::kShift, -1, checkEachPass, [&] { shiftFluid(); }))  // once a step: no substep
    return false;
  return true;
}

// Whether a material's wave speed can change within a step: snow (its hardening) and fluid
// (its compression); elastic, sand and plasticine keep theirs.
bool MpmWorld::boundMayTighten() const {
  for (std::size_t i = 0; i < parts_.size(); ++i) {
    if (!phase::dynamic(parts_.phase[i])) continue;
    const MaterialKind k = models_[std::size_t(parts_.material[i])].kind;
    if (k == MaterialKind::kSnow || k == MaterialKind::kFluid) return true;
  }
  return false;
}

// The guard's record for a step whose bound needs more than kMaxSubsteps substeps, naming the
// material that sets it.
GuardRecord MpmWorld::tooManySubsteps() const {
  const StepBound b = waveBound();
  GuardRecord r;
  r.kind = GuardKind::kCfl;
  r.pass = "guard";
  r.step = steps_;
  r.value = params_.dt / kMaxSubsteps;
  r.bound = b.h;
  if (b.material >= 0) r.material = materials_[std::size_t(b.material)].name;
  r.hint = "The time-step bound needs more than 1000 substeps per step: lower 'dt' (or the material's E).";
  return r;
}

bool MpmWorld::step() {
  if (guard_.tripped()) return false;
  work_ = work();
  fluidOnly_ = !jbar_.empty();
  for (std::size_t i = 0; i < parts_.size() && fluidOnly_; ++i)
    fluidOnly_ = !phase::dynamic(parts_.phase[i]) || models_[std::size_t(parts_.material[i])].kind == MaterialKind::kFluid;
  const int substeps = substepsForNextStep();
  if (substeps == 0) {
    // `substeps auto` would need more than kMaxSubsteps: name the material that sets the bound.
    guard_ = tooManySubsteps();
    return false;
  }
  lastSubsteps_ = substeps;
  // Material sketched within a collider (a pool drawn to the brim of a cup, overlapping the
  // cup's shell) starts on its surface: put there before the step, as the projection would
  // in the step's first substep, so that the energy reference below is taken after the move
  // (which lifts water out of a floor: otherwise an energy_growth trip at step 0).
  syncFixedColliders();
  if (placeInColliders_ && !colliders_.empty()) {
    poseColliders(double(steps_) * params_.dt, 0.0);
    for (std::size_t i = 0; i < parts_.size(); ++i)
      if (phase::dynamic(parts_.phase[i])) pushOutOfColliders(i, 0.0);
  }
  placeInColliders_ = false;
  // After an outside event the energy reference is taken here, before the step, so that
  // growth within the step is caught.
  if (work_[std::size_t(MpmPass::kGuard)] && !energy_.armed() && energyClosed())
    energy_.arm(energySums(parts_, params_.gravity), params_.gravity, params_.spacing);
  // The start of the step: to replay it with a check after every pass (naming the pass that
  // produced a bad value), and under policy warn to complete a step the guard stopped midway.
  Saved& start = start_;
  // Where every dynamic particle is a fluid nothing changes F (g2p updates a solid's only), so
  // it is neither kept nor restored.
  const bool keepF = !fluidOnly_;
  if (!validate_ || guardLog_.policy == GuardPolicy::kWarn) {
    // In three parts on the threads (C and F are 36 bytes a particle each, the rest 32; two
    // parts without F).
    forEach(keepF ? 3 : 2, [&](std::size_t part) {
      if (part == 0) {
        start.x = parts_.x, start.y = parts_.y, start.z = parts_.z;
        start.vx = parts_.vx, start.vy = parts_.vy, start.vz = parts_.vz;
        start.plastic = plastic_, start.fluidJ = fluidJ_;
      } else if (part == 1) {
        start.C = C_;
      } else {
        start.F = F_;
      }
    });
    start.atEdge = atEdge_, start.firstEdge = firstEdge_;
  }
  const auto restoreStart = [&] {
    parts_.x = start.x, parts_.y = start.y, parts_.z = start.z;
    parts_.vx = start.vx, parts_.vy = start.vy, parts_.vz = start.vz;
    plastic_ = start.plastic, fluidJ_ = start.fluidJ, C_ = start.C, atEdge_ = start.atEdge, firstEdge_ = start.firstEdge;
    if (keepF) F_ = start.F;
  };
  const bool checks = work_[std::size_t(MpmPass::kGuard)];
  const auto endChecks = [&] {
    ScopedPass t(profile_, MpmPass::kGuard);
    // From the last g2p's summary where it has one and it flags nothing; else (and to name the
    // particle) the sweeps.
    const StepSummary& sum = summary_;
    const bool clean = sum.valid && !sum.suspect && !sum.inverted && !sum.fast;
    GuardRecord r = clean ? GuardRecord{} : check(MpmPass::kGuard);
    if (!r.tripped()) r = checkEnergy(sum.valid ? &sum.energy : nullptr);
    return r;
  };
  // A carried body moved to its target: it stays there until given the next one.
  const auto settle = [&] {
    for (std::size_t b = 0; b < members_.size(); ++b)
      if (mode_[b] == BodyMode::kKinematic)
        for (std::int32_t i : members_[b]) parts_.vx[std::size_t(i)] = parts_.vy[std::size_t(i)] = parts_.vz[std::size_t(i)] = 0.0f;
  };
  const auto finish = [&] {
    if (guard_.particle >= 0)
      guard_.material = materials_[std::size_t(parts_.material[std::size_t(guard_.particle)])].name;
    if (guard_.kind == GuardKind::kCompression) {  // snow at its clamp: a material's limit, not the step's
      const auto m = std::size_t(parts_.material[std::size_t(guard_.particle)]);
      const double xi = double(models_[m].xi);
      guard_.hint += " Here the factor stops at e^" + num(xi * (1.0 - guard_.bound)) +
                     (xi * (1.0 - 0.01) < 10.0 ? std::string(" (the clamp's floor 0.01 holds at this xi)") : std::string()) +
                     ". Fix: a lighter load or impact, or a stiffer snow (E); above xi = 10.1 a lower 'hardening' also "
                     "lowers the clamp (J_p >= max(1 - 10 / xi, 0.01)).";
      return;
    }
    // Under `substeps auto` the step already meets its bounds: a fixed-corotated elastic that
    // inverts there was crushed faster than its waves carry the load away (a gel thrown at the
    // ground at twice its wave speed inverts at cfl 0.5, 0.25 and 0.1 alike), which a shorter
    // step does not change but neo-Hookean's pressure, unbounded as J -> 0, or a stiffer E does.
    if (guard_.kind == GuardKind::kInverted && params_.substeps == 0 && guard_.particle >= 0) {
      const auto m = std::size_t(parts_.material[std::size_t(guard_.particle)]);
      // Written as elastic: a rigid material runs as one too, but takes neither model= nor E=.
      if (materials_[m].kind == MaterialKind::kElastic && models_[m].elastic == ElasticModel::kCorotated) {
        const double c = std::sqrt((double(models_[m].lambda) + 2.0 * double(models_[m].mu)) / materials_[m].density);
        guard_.hint += " Fix: write model=neohookean for material '" + materials_[m].name +
                       "' (its pressure grows without bound as J -> 0), or raise its E (its wave speed c_p is " + num(c) +
                       " m/s; what crushed it came faster)";
        KnobState knobs;
        knobs.substeps = std::max(substeps, lastSubsteps_);
        knobs.substepsAuto = true;
        knobs.cfl = params_.waveCourant;
        guard_.hint += "; if a speed the step did not foresee did it, " + knobAdvice(guard_, knobs) + ".";
        return;
      }
    }
    KnobState knobs;
    knobs.substeps = std::max(substeps, lastSubsteps_);  // a step cut finer within (runStep) took more
    knobs.substepsAuto = params_.substeps == 0;
    knobs.cfl = params_.waveCourant;
    guard_.hint += " Fix: " + knobAdvice(guard_, knobs) + ".";
  };
  const long logged = guardLog_.total();
  if (!guardedStep(guard_, guardLog_, validate_, checks, steps_, [&](bool check) { return runStep(substeps, check); },
                   endChecks, [&] { return checkEnergy(); }, restoreStart, settle, finish))
    return false;
  if (guardLog_.total() != logged) energy_.reset();  // warned: a new reference next step
  ++steps_;
  return true;
}

// Energy growth while the system is closed (no carried body, no moving collider). step() adds the substep
// count to try.
bool MpmWorld::energyClosed() const {
  bool closed = true;
  for (BodyMode m : mode_) closed &= m != BodyMode::kKinematic;
  for (const Collider& c : colliders_) closed &= c.desc.keyframes.empty();  // a moving collider does work
  return closed;
}

GuardRecord MpmWorld::checkEnergy(const EnergySums* sums) {
  const bool closed = energyClosed();
  GuardRecord r = sums && closed ? energy_.check(*sums, parts_, params_.gravity, params_.spacing, true)
                                 : energy_.check(parts_, params_.gravity, params_.spacing, closed);
  if (r.tripped()) r.hint = "Energy grew in a closed system (nothing moved it from outside).";
  return r;
}

// --- mesh colliders -----------------------------------------------------------------

std::vector<std::string> MpmWorld::setColliders(const std::vector<MeshCollider>& descs,
                                                const std::vector<TriangleSoup>& meshes, double maxBandVoxels) {
  if (descs.size() != meshes.size()) throw RuntimeError("MpmWorld::setColliders: one mesh per collider");
  // The fixed bodies' fields go after the new mesh colliders.
  colliders_.erase(colliders_.begin(), colliders_.begin() + std::ptrdiff_t(meshColliderCount()));
  std::vector<Collider> fixed = std::move(colliders_);
  colliders_.clear();
  std::vector<std::string> notes(descs.size());
  for (std::size_t c = 0; c < descs.size(); ++c) {
    colliders_.push_back({descs[c], ColliderSdf(meshes[c], descs[c].scale, 0.5 * dx_, 1.5 * dx_, maxBandVoxels)});
    const ColliderSdf& f = colliders_.back().sdf;
    if (f.voxel() > 0.5 * dx_ * (1.0 + 1e-9))
      notes[c] = ("collider '" + descs[c].name + "': its surface of " + num(f.area()) +
                          " m^2 would need more than " + num(maxBandVoxels) +
                          " distance-field voxels at dx/2 = " + num(0.5 * dx_) + " m; the field uses " +
                          num(f.voxel()) + " m voxels instead (coarser contact; a smaller or cropped mesh keeps dx/2)");
  }
  for (Collider& c : fixed) colliders_.push_back(std::move(c));
  poseColliders(double(steps_) * params_.dt, 0.0);
  side_.clear();
  if (!colliders_.empty()) side_.assign(3 * grid_.size(), 0.0f);
  placeInColliders_ = true;
  energy_.reset();
  return notes;
}

std::size_t MpmWorld::meshColliderCount() const {
  std::size_t n = 0;
  while (n < colliders_.size() && colliders_[n].body < 0) ++n;
  return n;
}

std::string MpmWorld::collidersText() const {
  const std::size_t mesh = meshColliderCount(), fixed = colliders_.size() - mesh;
  std::string t;
  if (mesh > 0) t += ", " + std::to_string(mesh) + " mesh collider(s)";
  if (fixed > 0) t += ", " + std::to_string(fixed) + " fixed bod" + (fixed == 1 ? "y" : "ies") + " (as distance fields)";
  return t;
}

namespace {

// The closed surface of a set of voxels (cubes of side h centred on cell * h): the faces
// between a voxel and an empty neighbour, two triangles each, wound counter-clockwise seen
// from outside.
TriangleSoup voxelSurface(std::vector<Vec3i> cells, double h) {
  const auto less = [](const Vec3i& a, const Vec3i& b) {
    return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
  };
  std::sort(cells.begin(), cells.end(), less);
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  const auto occupied = [&](const Vec3i& c) { return std::binary_search(cells.begin(), cells.end(), c, less); };
  TriangleSoup s;
  for (const Vec3i& c : cells)
    for (int axis = 0; axis < 3; ++axis)
      for (int dir = -1; dir <= 1; dir += 2) {
        Vec3i n = c;
        n[axis] += dir;
        if (occupied(n)) continue;
        // The face's corners: centre + h/2 (dir e_axis +- e_u +- e_v), (u, v, axis) right-handed.
        const int u = (axis + 1) % 3, v = (axis + 2) % 3;
        const Vec3 centre = h * c.cast<double>();
        const auto corner = [&](int su, int sv) {
          Vec3 p = centre;
          p[axis] += 0.5 * h * dir;
          p[u] += 0.5 * h * su;
          p[v] += 0.5 * h * sv;
          return p;
        };
        const auto base = std::int32_t(s.vertices.size());
        s.vertices.push_back(corner(-1, -1));
        s.vertices.push_back(corner(1, -1));
        s.vertices.push_back(corner(1, 1));
        s.vertices.push_back(corner(-1, 1));
        if (dir > 0) {  // u x v = +e_axis: counter-clockwise seen from +axis
          s.triangles.push_back({base, base + 1, base + 2});
          s.triangles.push_back({base, base + 2, base + 3});
        } else {
          s.triangles.push_back({base, base + 2, base + 1});
          s.triangles.push_back({base, base + 3, base + 2});
        }
      }
  s.closed = true;
  return s;
}

}  // namespace

void MpmWorld::syncFixedColliders() {
  if (fixedDirty_.empty()) return;
  std::sort(fixedDirty_.begin(), fixedDirty_.end());
  fixedDirty_.erase(std::unique(fixedDirty_.begin(), fixedDirty_.end()), fixedDirty_.end());
  colliders_.erase(std::remove_if(colliders_.begin(), colliders_.end(),
                                  [&](const Collider& c) {
                                    return c.body >= 0 && std::binary_search(fixedDirty_.begin(), fixedDirty_.end(), c.body);
                                  }),
                   colliders_.end());
  const double h = params_.spacing;
  for (int b : fixedDirty_) {
    const auto& mem = members_[std::size_t(b)];
    if (mode_[std::size_t(b)] != BodyMode::kFixed || mem.empty()) continue;
    // The body's frame: its first particle's voxel centre; the others' cells at integer h.
    const auto first = std::size_t(mem.front());
    const Vec3 origin(parts_.x[first], parts_.y[first], parts_.z[first]);
    std::vector<Vec3i> cells;
    cells.reserve(mem.size());
    for (std::int32_t i : mem) {
      const auto k = std::size_t(i);
      const Vec3 d = (Vec3(parts_.x[k], parts_.y[k], parts_.z[k]) - origin) / h;
      cells.emplace_back(int(std::lround(d.x())), int(std::lround(d.y())), int(std::lround(d.z())));
    }
    MeshCollider desc;
    desc.name = "fixed body " + std::to_string(b);
    desc.position = origin;
    Collider c{desc, ColliderSdf(voxelSurface(std::move(cells), h), 1.0, 0.5 * h, 0.0)};
    c.body = b;
    double mus = 0.0, muk = 0.0;
    for (std::int32_t i : mem) {
      const MatModel& m = models_[std::size_t(parts_.material[std::size_t(i)])];
      mus += double(m.mus);
      muk += double(m.muk);
    }
    c.ownMus = float(mus / double(mem.size()));
    c.ownMuk = float(muk / double(mem.size()));
    if (c.sdf.voxel() > 0.5 * h * (1.0 + 1e-9))
      warnings_.push_back("fixed body " + std::to_string(b) + " (stroke " + std::to_string(parts_.stroke[first]) + "): its surface of " +
                          num(c.sdf.area()) + " m^2 needs a distance field coarser than h/2 = " + num(0.5 * h) + " m (" +
                          num(c.sdf.voxel()) + " m voxels): its contacts are that much coarser");
    const auto at = std::find_if(colliders_.begin(), colliders_.end(), [&](const Collider& o) { return o.body > b; });
    colliders_.insert(at, std::move(c));
  }
  fixedDirty_.clear();
  if (!colliders_.empty() && side_.empty()) side_.assign(3 * grid_.size(), 0.0f);
  if (colliders_.empty()) side_.clear();
  poseColliders(double(steps_) * params_.dt, 0.0);  // and the static ones' masks, for the plan
  placeInColliders_ = true;
}

// Poses at t0 and t0 + h, and the world box the end pose's field covers.
void MpmWorld::poseColliders(double t0, double h) {
  for (Collider& c : colliders_) {
    c.desc.poseAt(t0, c.R0, c.p0);
    c.desc.poseAt(t0 + h, c.R1, c.p1);
    c.lo = Vec3::Constant(std::numeric_limits<double>::infinity());
    c.hi = -c.lo;
    for (int k = 0; k < 8; ++k) {
      const Vec3 corner((k & 1) ? c.sdf.boundsMax().x() : c.sdf.boundsMin().x(),
                        (k & 2) ? c.sdf.boundsMax().y() : c.sdf.boundsMin().y(),
                        (k & 4) ? c.sdf.boundsMax().z() : c.sdf.boundsMin().z());
      const Vec3 w = c.R1 * corner + c.p1;
      c.lo = c.lo.cwiseMin(w);
      c.hi = c.hi.cwiseMax(w);
    }
    if (c.desc.keyframes.empty() && c.near.empty()) buildNearMask(c);
  }
}

// Samples the field at 8 points a cell (spacing dx/2: every point of the band lies within
// 0.44 dx of one, inside the band's 0.75 dx at least), marks the cells of those that answer,
// then grows the marks by the band's reach in cells, so a point the field answers for lies in
// a marked cell. A box of more than 2^22 cells gets no mask.
void MpmWorld::buildNearMask(Collider& c) const {
  Vec3i lo, hi;
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::max(0, int(std::floor((c.lo[a] - origin_[a]) / dx_)));
    hi[a] = std::min(n_ - 1, int(std::floor((c.hi[a] - origin_[a]) / dx_)));
    if (hi[a] < lo[a]) return;
  }
  const Vec3i dims = hi - lo + Vec3i::Ones();
  const std::size_t cells = std::size_t(dims.x()) * std::size_t(dims.y()) * std::size_t(dims.z());
  if (cells > (std::size_t(1) << 22)) return;
  const auto at = [&](int i, int j, int k) { return (std::size_t(i) * std::size_t(dims.y()) + std::size_t(j)) * std::size_t(dims.z()) + std::size_t(k); };
  std::vector<std::uint8_t> hit(cells, 0);
  Collider::Probe p;
  for (int i = 0; i < dims.x(); ++i)
    for (int j = 0; j < dims.y(); ++j)
      for (int k = 0; k < dims.z(); ++k)
        for (int s = 0; s < 8 && !hit[at(i, j, k)]; ++s) {
          const Vec3 x = origin_ + dx_ * Vec3(lo.x() + i + 0.25 + 0.5 * (s & 1), lo.y() + j + 0.25 + 0.5 * ((s >> 1) & 1),
                                               lo.z() + k + 0.25 + 0.5 * ((s >> 2) & 1));
          if (c.probe(x, p, true)) hit[at(i, j, k)] = 1;
        }
  // Grow by r cells along each axis in turn (a box of side 2r + 1 about each mark).
  const int r = int(std::ceil(c.sdf.reach() / dx_)) + 1;
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<std::uint8_t> grown(cells, 0);
    for (int i = 0; i < dims.x(); ++i)
      for (int j = 0; j < dims.y(); ++j)
        for (int k = 0; k < dims.z(); ++k) {
          if (!hit[at(i, j, k)]) continue;
          Vec3i q(i, j, k);
          const int from = std::max(0, q[axis] - r), to = std::min(dims[axis] - 1, q[axis] + r);
          for (int t = from; t <= to; ++t) {
            q[axis] = t;
            grown[at(q.x(), q.y(), q.z())] = 1;
          }
        }
    hit.swap(grown);
  }
  c.near = std::move(hit);
  c.nearLo = lo;
  c.nearDims = dims;
  c.gridOrigin = origin_;
  c.gridDx = dx_;
}

bool MpmWorld::Collider::probe(const Vec3& x, Probe& out, bool anywhere) const {
  if ((x.array() < lo.array()).any() || (x.array() > hi.array()).any()) return false;
  if (!near.empty()) {
    std::size_t cell = 0;
    for (int a = 0; a < 3; ++a) {
      const int q = int(std::floor((x[a] - gridOrigin[a]) / gridDx)) - nearLo[a];
      if (q < 0 || q >= nearDims[a]) return false;
      cell = cell * std::size_t(nearDims[a]) + std::size_t(q);
    }
    if (!near[cell]) return false;
  }
  out.local = R1.transpose() * (x - p1);
  Vec3 grad;
  if (!sdf.sample(out.local, out.phi, grad) || (out.phi >= 0.0 && !anywhere)) return false;
  const double g = grad.norm();
  out.hasNormal = g >= 1e-6;  // deep inside a solid the field is flat: no direction out
  out.normal = out.hasNormal ? Vec3(R1 * (grad / g)) : Vec3::Zero();
  return true;
}

void MpmWorld::collideNode(const Vec3& x, float v[3], float h, float mus, float muk, const float* side,
                           float m) const {
  Collider::Probe p;
  for (const Collider& c : colliders_) {
    const double half = c.sdf.halfThickness();
    const bool sided = side != nullptr && m > 0.0f;
    if (!c.probe(x, p, sided && half > 0.0)) continue;
    if (sided && p.hasNormal) {
      // The normal points to the nearest surface (a sheet's: away from it on the node's side).
      // The node's material, at x + side / m, lies behind that surface when its offset along
      // the normal is below the node's distance to the surface: a node just past a sheet, or
      // in the lower half of a thin closed floor, reached only by the water above. Then the
      // wall faces the material: the normal turns round (and a sheet acts anywhere in its band).
      const double offset = (double(side[0]) * p.normal.x() + double(side[1]) * p.normal.y() +
                             double(side[2]) * p.normal.z()) / double(m);
      if (p.phi + half + offset < 0.0) p.normal = -p.normal;
      else if (p.phi >= 0.0) continue;  // outside the shell on the material's side: free
    } else if (p.phi >= 0.0) {
      continue;
    }
    const Vec3 vc = c.velocityAt(x, p.local, double(h));
    Vec3 rel = Vec3(v[0], v[1], v[2]) - vc;
    if (!p.hasNormal) {
      rel.setZero();  // deep inside: no normal to slide along, so the node moves with the collider
    } else {
      const Vec3& n = p.normal;
      const double vn = rel.dot(n);
      if (vn < 0.0) {
        rel -= vn * n;
        const bool mean = !std::isnan(c.ownMus);  // a fixed body's material against the node's
        const double fs = c.desc.friction ? *c.desc.friction : mean ? 0.5 * double(mus + c.ownMus) : double(mus);
        const double fk = c.desc.friction ? *c.desc.friction : mean ? 0.5 * double(muk + c.ownMuk) : double(muk);
        rel *= coulombScale(rel.norm(), vn, fs, fk);
      }
    }
    const Vec3 out = rel + vc;
    v[0] = float(out.x());
    v[1] = float(out.y());
    v[2] = float(out.z());
  }
}

// --- observers -----------------------------------------------------------------------

std::vector<std::string> MpmWorld::runNotes() const {
  if (atEdge_ == 0 || firstEdge_.particle < 0) return {};
  static const char* const kWall[6] = {"x-", "x+", "y- (floor)", "y+", "z-", "z+"};
  const auto i = std::size_t(firstEdge_.particle);
  std::ostringstream o;
  o << "material reached the domain's edge (" << atEdge_ << " particle-substeps within 1.5 grid cells of a wall, "
    << "where the wall, not the scene, moves it); first: particle " << firstEdge_.particle << " (stroke " << parts_.stroke[i]
    << ", " << materials_[std::size_t(parts_.material[i])].name << ") at the " << kWall[std::size_t(firstEdge_.wall)]
    << " wall in step " << firstEdge_.step << " (substep " << firstEdge_.substep
    << ", pass g2p: within 1.5 dx = " << 1.5 * dx_
    << " m of the wall). The walls are the workspace's faces: enlarge 'workspace' if the material should go on.";
  return {o.str()};
}

double MpmWorld::gridMass() const {
  double m = 0.0;
  for (std::int32_t b : activeNodeBlocks_)
    for (std::size_t l = 0; l < 64; ++l) m += nodeMass(std::size_t(b) * 64 + l);
  return m;
}

Vec3 MpmWorld::gridMomentum() const {
  Vec3 p = Vec3::Zero();
  for (std::int32_t b : activeNodeBlocks_)
    for (std::size_t l = 0; l < 64; ++l) {
      const std::size_t k = std::size_t(b) * 64 + l;
      p += double(nodeMass(k)) * Vec3(grid_[k].x, grid_[k].y, grid_[k].z);
    }
  return p;
}

std::uint64_t MpmWorld::stateHash() const {
  std::uint64_t h = 1469598103934665603ull;
  for (const auto* a : {&parts_.x, &parts_.y, &parts_.z, &parts_.vx, &parts_.vy, &parts_.vz, &plastic_, &fluidJ_})
    hashBytes(h, a->data(), a->size() * sizeof(float));
  hashBytes(h, parts_.phase.data(), parts_.phase.size() * sizeof(std::uint32_t));
  for (const auto* a : {&C_, &F_})
    for (const Eigen::Matrix3f& m : *a) hashBytes(h, m.data(), sizeof(float) * 9);
  return h;
}

}  // namespace physketch::mpm
