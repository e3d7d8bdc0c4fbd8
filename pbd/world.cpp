#include "pbd/world.h"

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>

#include <Eigen/Eigenvalues>


#include "core/error.h"
#include "core/lattice.h"
#include "core/neighbor_grid.h"
#include "pbd/parallel.h"
#include "pbd/shape_matching.h"

namespace physketch::pbd {

const PassSpec kPbdPasses[static_cast<int>(PbdPass::kCount)] = {
    {"integrate", Cadence::kPerSubstep, "dynamic rigid bodies: v += g h, gyroscopic w update, c += v h, q += h/2 [w,0] q"},
    {"predict", Cadence::kPerSubstep, "soft, rope, cloth and fluid particles: v += g h, p = x + v h (Macklin 2014 Alg. 1)"},
    {"kinematic", Cadence::kPerSubstep, "held or carried bodies follow their brush path"},
    {"find_contacts", Cadence::kPerSubstep, "per dynamic rigid body near the ground: its particles within a margin of it"},
    {"find_neighbors", Cadence::kPerSubstep, "predicted moves that cross a rigid body stop at its face; particle pairs within reach (one NeighborGrid per substep), reused by every iteration"},
    {"find_colliders", Cadence::kPerSubstep, "mesh colliders: swept spheres stop fast particles and bodies, then contacts within reach (Bullet BVH)"},
    {"fluid_neighbors", Cadence::kPerSubstep, "fluids: the PBF neighbour structure over fluid particles and the solids in range"},
    {"cluster_match", Cadence::kPerIteration, "soft bodies: clustered shape matching with XPBD compliance (Müller 2005, Macklin 2016)"},
    {"particle_contact", Cadence::kPerIteration, "particle pairs and the ground: projection and Coulomb friction (Macklin 2014 §6)"},
    {"density", Cadence::kPerIteration, "fluids: PBF density constraint, Jacobi lambda and dp (Macklin & Müller 2013 Eq. 11-13)"},
    {"distance", Cadence::kPerIteration, "rope and cloth: XPBD stretch and bending, attachments to bodies, tethers"},
    {"rigid_contact", Cadence::kPerSubstep, "ground contact and friction at body level, `iterations` sweeps"},
    {"body_contact", Cadence::kPerSubstep, "bodies whose particles touch: two-body corrections and friction, `iterations` sweeps; then the ground lifts out what they pressed into it; then shock propagation, from the ground up"},
    {"collider_contact", Cadence::kPerSubstep, "rigid bodies against mesh colliders at body level, `iterations` sweeps, with friction"},
    {"update", Cadence::kPerSubstep, "rigid velocities from the pose change: v = dc/h, w = 2 vec(dq)/h"},
    {"particle_update", Cadence::kPerSubstep, "moves that cross a rigid body or collider stop at its face; particle velocities v = (p - x)/h, x = p; restitution off the ground, bodies and colliders; soft bodies bounce at their centre of mass"},
    {"fluid_velocity", Cadence::kPerSubstep, "fluids: XSPH viscosity, vorticity confinement, cohesion (Eq. 15-17), implicit viscosity (dragging solids), when set"},
    {"plasticity", Cadence::kPerSubstep, "soft clusters strained past plastic_yield: rest shapes creep (Müller 2005 §4.4)"},
    {"restitution", Cadence::kPerSubstep, "bodies that touched the ground or each other leave at e times their approach speed (Müller 2020 Eq. 34; a pair: the mean of their e)"},
    {"write_particles", Cadence::kPerStep, "particle positions and velocities from the body poses"},
    {"guard", Cadence::kPerStep, "first NaN, explosion or ground penetration"},
};

namespace {

// q <- exp(dtheta / 2) q: the rotation by the vector dtheta (rad, world axes), exactly,
// so that update()'s w = 2 log(q q_prev^-1) / h gives back the w that integrate used.
Quat rotateBy(const Quat& q, const Vec3& dtheta) {
  const double a = dtheta.norm();
  if (a == 0.0) return q;
  return (Quat(Eigen::AngleAxisd(a, dtheta / a)) * q).normalized();
}

// Coulomb's law on position impulses (Müller 2020 §3.5): the tangential impulse that would
// stop the contact point (`stop`) is applied whole while it is within mu_s lambda_n
// (static), else mu_k lambda_n opposes the sliding (dynamic, never more than `stop`).
double coulomb(double stop, double lambdaN, double mus, double muk) {
  return stop <= mus * lambdaN ? stop : std::min(stop, muk * lambdaN);
}

// The rotation vector of a unit quaternion (the inverse of rotateBy from identity).
Vec3 rotationVector(Quat dq) {
  if (dq.w() < 0.0) dq.coeffs() = -dq.coeffs();
  const double s = dq.vec().norm();
  if (s == 0.0) return Vec3::Zero();
  return (2.0 * std::atan2(s, dq.w()) / s) * dq.vec();
}

// Implicit gyroscopic step (Catto 2015, "Numerical methods", one Newton step on
// f(w) = I (w - w0) + h w x I w = 0, in the body frame): an explicit w x I w term gains
// energy for a spinning body; this one is stable and conserves |L| to O(h^2).
Vec3 gyroscopicStep(const Mat3& I, const Vec3& w0, double h) {
  const auto skew = [](const Vec3& v) {
    Mat3 m;
    m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
    return m;
  };
  const Vec3 f = h * w0.cross(I * w0);
  const Mat3 J = I + h * (skew(w0) * I - skew(I * w0));
  return w0 - J.lu().solve(f);
}

void hashBytes(std::uint64_t& h, const void* data, std::size_t n) {
  const auto* b = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    h ^= b[i];
    h *= 1099511628211ull;  // FNV-1a
  }
}

}  // namespace

PbdParams paramsFromScene(const SceneDesc& scene, double particleRadius) {
  PbdParams p;
  p.dt = scene.dt;
  p.substeps = scene.substeps;
  p.iterations = scene.iterations;
  p.gravity = scene.gravity;
  p.groundY = scene.groundY;
  p.particleRadius = particleRadius;
  p.sleepSpeed = !scene.sleep ? 0.0 : scene.sleepSpeed > 0.0 ? scene.sleepSpeed : 4.0 * particleRadius;  // auto: 2 spacings / s
  p.sleepTime = scene.sleepTime;
  p.warmStart = scene.warmStart;
  p.warmSmoothing = scene.warmSmoothing;
  return p;
}

PbdWorld::PbdWorld(ParticleArrays particles, const std::vector<BodyRange>& bodies, std::vector<Material> materials,
                   const PbdParams& params)
    : params_(params), parts_(std::move(particles)), materials_(std::move(materials)) {
  if (!(params_.dt > 0) || params_.substeps < 1 || params_.iterations < 1 || !(params_.particleRadius > 0))
    throw RuntimeError("PbdWorld: dt, substeps, iterations and particle radius must be positive");
  const std::size_t n = parts_.size();
  rx_.assign(n, 0.0f);
  ry_.assign(n, 0.0f);
  rz_.assign(n, 0.0f);
  design_.assign(n, 0);
  surfaceNormal_.assign(n, Eigen::Vector3f::Zero());
  sheetFace_.assign(n, 0);
  const double spacing = 2.0 * params_.particleRadius;
  for (std::size_t i = 0; i < n; ++i) {
    const auto m = static_cast<std::size_t>(parts_.material[i]);
    if (m >= materials_.size()) throw RuntimeError("PbdWorld: particle " + std::to_string(i) + " has an unknown material");
    parts_.mass[i] = static_cast<float>(materials_[m].density * spacing * spacing * spacing);  // one voxel per particle
  }
  for (const BodyRange& br : bodies) {
    if (br.first < 0 || br.count < 1 || std::size_t(br.first) + std::size_t(br.count) > n)
      throw RuntimeError("PbdWorld: body " + std::to_string(members_.size()) + " has an invalid particle range");
    const float thick = strandMassScale(br, spacing);
    if (thick != 1.0f)
      for (std::int32_t k = 0; k < br.count; ++k) parts_.mass[std::size_t(br.first + k)] *= thick;
    // A cloth cut before play keeps its lattice with holes (removed nodes): not members.
    std::vector<std::int32_t> ids;
    for (std::int32_t k = 0; k < br.count; ++k)
      if (!phase::has(parts_.phase[std::size_t(br.first + k)], phase::kRemoved)) ids.push_back(br.first + k);
    if (ids.empty()) throw RuntimeError("PbdWorld: body " + std::to_string(members_.size()) + " has no particles");
    const MaterialKind kind = kindOf(parts_.material[std::size_t(ids.front())]);
    appendBody(std::move(ids), br.init, br.init.fixed ? BodyMode::kFixed : BodyMode::kDynamic, kind);
    if (kind != MaterialKind::kRigid) {
      ensureParticleLevel();
      setupParticleBody(members_.size() - 1, br);
    }
  }
  // Strands attach to what they touch once every body exists (a rope drawn from a fixed
  // beam to a bucket hangs from the beam and carries the bucket).
  for (std::size_t b = 0; b < members_.size(); ++b)
    if (kind_[b] == MaterialKind::kRope || kind_[b] == MaterialKind::kCloth) attachStrandEnds(b);
  for (std::size_t b = 0; b < members_.size(); ++b) refreshInverseMasses(b);
  makeFluidSolver();
  contacts_.planes.push_back(Plane{Vec3::UnitY(), params_.groundY});
  writeParticles();
}

// The per-particle arrays of the particle-level passes (predicted positions, inverse masses,
// pins, ground approach), made when the first soft, rope, cloth or fluid body is: a scene of
// rigid bodies holds none of them (issue 11: nothing allocated for a pass that is off).
void PbdWorld::ensureParticleLevel() {
  if (particleLevel_) return;
  const std::size_t n = parts_.size();
  px_ = parts_.x, py_ = parts_.y, pz_ = parts_.z;
  invMassP_.assign(n, 0.0f);
  pinned_.assign(n, 0);
  contactSkip_.assign(n, -1);
  groundApproach_.assign(n, 0.0f);
  bounceNoted_.assign(n, 0);
  particleLevel_ = true;
}

MaterialKind PbdWorld::kindOf(std::int16_t material) const {
  const SolverModel model = solverModel(materials_.at(static_cast<std::size_t>(material)).kind, SolverKind::kPbd);
  if (!model.simulated)
    throw RuntimeError(std::string("PbdWorld: material '") + materials_[std::size_t(material)].name + "' is kind " +
                       toString(materials_[std::size_t(material)].kind) + ", which solver pbd does not simulate");
  return model.runsAs;
}

// Appends one slot to every per-body array; mass properties are filled by refreshMassProperties.
std::size_t PbdWorld::pushBodySlot(std::vector<std::int32_t> members, const Motion& motion, const Vec3& restCentre,
                                   BodyMode mode, MaterialKind kind) {
  ++bodyEdits_;
  members_.push_back(std::move(members));
  normalsStale_.push_back(1);
  restCells_.emplace_back();
  kind_.push_back(kind);
  strandRadius_.push_back(0.0f);
  lattice_.push_back({0, 0, 0});
  motion_.push_back(motion);
  restCentre_.push_back(restCentre);
  invMass_.push_back(0.0);
  inertiaRest_.push_back(Mat3::Zero());
  invInertiaRest_.push_back(Mat3::Zero());
  staticFriction_.push_back(0.0);
  dynamicFriction_.push_back(0.0);
  frictionRule_.push_back(Material::FrictionRule::kMean);
  restitution_.push_back(0.0);
  reach_.push_back(0.0);
  restBox_.emplace_back();
  mode_.push_back(mode);
  return members_.size() - 1;
}

void PbdWorld::appendBody(std::vector<std::int32_t> members, const BodyInit& init, BodyMode mode, MaterialKind kind) {
  const std::size_t b = pushBodySlot(std::move(members), Motion{}, Vec3::Zero(), BodyMode::kDynamic, kind);
  // Rest shape = the particles' current positions; the pose starts at identity.
  const Vec3 c = restShapeFromParticles(b);
  Motion& mo = motion_[b];
  mo.c = mo.cPrev = mo.kinStart = mo.kinTarget = restCentre_[b] = c;
  if (kind == MaterialKind::kRigid) labelDesignPieces(b);
  refreshMassProperties(b);
  setMode(static_cast<int>(b), mode);
  if (mode_[b] == BodyMode::kDynamic) {
    mo.v = init.velocity;
    mo.w = init.spin;
    if (kind != MaterialKind::kRigid) {
      // A particle-level body starts with the rigid velocity field of vel= and spin=.
      for (std::int32_t i : members_[b]) {
        const auto k = std::size_t(i);
        const Vec3 u = init.velocity + init.spin.cross(Vec3(rx_[k], ry_[k], rz_[k]));
        parts_.vx[k] = float(u.x()), parts_.vy[k] = float(u.y()), parts_.vz[k] = float(u.z());
      }
    }
  }
}

Material PbdWorld::bodyFriction(std::size_t b) const {
  Material m;
  m.staticFriction = staticFriction_[b], m.dynamicFriction = dynamicFriction_[b], m.frictionRule = frictionRule_[b];
  return m;
}

void PbdWorld::bodyPairFriction(std::size_t a, std::size_t b, double& mus, double& muk) const {
  pairFriction(bodyFriction(a), bodyFriction(b), mus, muk);
}

// Mass, inertia, friction and reach of a body from its members' rest offsets.
void PbdWorld::refreshMassProperties(std::size_t b) {
  ++bodyEdits_;  // members or rest offsets changed: body-pair lists are made afresh
  const auto& mem = members_[b];
  double m = 0.0, mus = 0.0, muk = 0.0, e = 0.0, reach = 0.0;
  Eigen::AlignedBox3d box;
  bool firstMember = true;
  for (std::int32_t i : mem) {
    const auto k = std::size_t(i);
    const double mi = parts_.mass[k];
    const Material& mat = materials_[static_cast<std::size_t>(parts_.material[k])];
    if (firstMember) frictionRule_[b] = mat.frictionRule;
    else if (frictionRule_[b] != mat.frictionRule) frictionRule_[b] = Material::FrictionRule::kMean;
    firstMember = false;
    m += mi;
    mus += mi * mat.staticFriction;
    muk += mi * mat.dynamicFriction;
    e += mi * mat.restitution;
    reach = std::max(reach, Vec3(rx_[k], ry_[k], rz_[k]).norm());
    box.extend(Vec3(rx_[k], ry_[k], rz_[k]));
  }
  normalsStale_[b] = 1;
  restCells_[b].stale = true;
  if (mem.empty() || !(m > 0.0)) {
    mode_[b] = BodyMode::kEmpty;
    return;
  }
  BodyView v{static_cast<std::int32_t>(mem.size()), mem.data(), parts_.x.data(), parts_.y.data(), parts_.z.data(),
             rx_.data(), ry_.data(), rz_.data(), parts_.mass.data()};
  invMass_[b] = 1.0 / m;
  inertiaRest_[b] = restInertia(v, 2.0 * params_.particleRadius);
  invInertiaRest_[b] = inertiaRest_[b].inverse();
  staticFriction_[b] = mus / m;
  dynamicFriction_[b] = muk / m;
  restitution_[b] = e / m;
  reach_[b] = reach + params_.particleRadius;
  box.min().array() -= params_.particleRadius;
  box.max().array() += params_.particleRadius;
  restBox_[b] = box;
}

// surfaceNormal_ for a rigid body's particles from its rest lattice: the direction of the one
// face neighbour a particle lacks. Edges and corners (two or more) keep none: there the line of
// centres is the body's rounded surface, and a face's normal would push water resting beside
// the edge off it. A one-particle sheet's particle lacks two opposite neighbours: it keeps that
// axis with sheetFace_ set, and the contact takes the side the fluid comes from.
void PbdWorld::refreshSurfaceNormals(std::size_t b) {
  normalsStale_[b] = 0;
  const auto& mem = members_[b];
  for (std::int32_t i : mem) surfaceNormal_[std::size_t(i)].setZero(), sheetFace_[std::size_t(i)] = 0;
  if (!isRigid(b) || mem.empty() || mode_[b] == BodyMode::kEmpty) return;
  const std::vector<Vec3i> cells = restCells(b);
  Vec3i lo = cells.front(), hi = cells.front();
  for (const Vec3i& c : cells) lo = lo.cwiseMin(c), hi = hi.cwiseMax(c);
  // The body's cells as sorted keys (21 bits an axis; a body of the API may reach beyond the
  // sketch grid, where a dense box could be huge). One beyond 2^21 cells across keeps no normals.
  const Vec3i size = hi - lo + Vec3i::Ones();
  if (size.maxCoeff() >= (1 << 21)) return;
  const auto key = [&](const Vec3i& c) {
    return (std::uint64_t(c.x() - lo.x()) << 42) | (std::uint64_t(c.y() - lo.y()) << 21) | std::uint64_t(c.z() - lo.z());
  };
  std::vector<std::uint64_t> keys(cells.size());
  for (std::size_t k = 0; k < cells.size(); ++k) keys[k] = key(cells[k]);
  std::sort(keys.begin(), keys.end());
  const auto has = [&](const Vec3i& c) {
    return (c.array() >= lo.array()).all() && (c.array() <= hi.array()).all() &&
           std::binary_search(keys.begin(), keys.end(), key(c));
  };
  const Vec3i faces[6] = {Vec3i(1, 0, 0), Vec3i(-1, 0, 0), Vec3i(0, 1, 0), Vec3i(0, -1, 0), Vec3i(0, 0, 1), Vec3i(0, 0, -1)};
  for (std::size_t k = 0; k < cells.size(); ++k) {
    int missing = 0;
    Vec3i face = Vec3i::Zero(), other = Vec3i::Zero();
    for (const Vec3i& f : faces)
      if (!has(cells[k] + f)) ++missing, other = face, face = f;
    const bool sheet = missing == 2 && other == -face;
    if (missing == 1 || sheet) surfaceNormal_[std::size_t(mem[k])] = face.cast<float>();
    sheetFace_[std::size_t(mem[k])] = sheet;
  }
}

double PbdWorld::bodyMass(int body) const {
  const double im = invMass_.at(std::size_t(body));
  return im > 0.0 ? 1.0 / im : 0.0;
}

bool PbdWorld::lattice(int body, std::int32_t& first, std::int32_t& rows, std::int32_t& cols) const {
  const auto b = std::size_t(body);
  if (b >= lattice_.size() || lattice_[b][1] < 1 || mode_[b] == BodyMode::kEmpty) return false;
  first = lattice_[b][0], rows = lattice_[b][1], cols = lattice_[b][2];
  return true;
}

float strandMassScale(const BodyRange& range, double spacing) {
  if (!(range.radius > 0.0f)) return 1.0f;
  const double across = 2.0 * double(range.radius) / spacing;  // 1 for the default one-voxel brush
  if (range.layout == BodyLayout::kChain) return float(across * across);
  if (range.layout == BodyLayout::kLattice) return float(across);
  return 1.0f;
}

Mat3 PbdWorld::bodyInertiaRest(int body) const { return inertiaRest_.at(std::size_t(body)); }

int PbdWorld::addBody(const ParticleArrays& p, const BodyRange& shape, bool kinematic) {
  const BodyInit& init = shape.init;
  if (p.size() == 0) throw RuntimeError("PbdWorld::addBody: a body needs particles");
  const double spacing = 2.0 * params_.particleRadius;
  std::vector<std::int32_t> ids;
  ids.reserve(p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (p.material[i] < 0 || static_cast<std::size_t>(p.material[i]) >= materials_.size())
      throw RuntimeError("PbdWorld::addBody: unknown material index");
    const std::int32_t id = parts_.push(p.x[i], p.y[i], p.z[i], p.stroke[i], p.material[i]);
    parts_.mass.back() =
        static_cast<float>(materials_[static_cast<std::size_t>(p.material[i])].density * spacing * spacing * spacing) *
        strandMassScale(shape, spacing);
    rx_.push_back(0.0f);
    ry_.push_back(0.0f);
    rz_.push_back(0.0f);
    design_.push_back(0);
    surfaceNormal_.emplace_back(Eigen::Vector3f::Zero());
    sheetFace_.push_back(0);
    if (particleLevel_) {
      px_.push_back(p.x[i]), py_.push_back(p.y[i]), pz_.push_back(p.z[i]);
      invMassP_.push_back(0.0f);
      pinned_.push_back(0);
      contactSkip_.push_back(-1);
      groundApproach_.push_back(0.0f);
      bounceNoted_.push_back(0);
    }
    ids.push_back(id);
  }
  const BodyMode mode = kinematic ? BodyMode::kKinematic : init.fixed ? BodyMode::kFixed : BodyMode::kDynamic;
  const MaterialKind kind = kindOf(p.material[0]);
  appendBody(std::move(ids), init, mode, kind);
  energy_.reset();
  const std::size_t b = members_.size() - 1;
  if (kind != MaterialKind::kRigid) {
    ensureParticleLevel();
    BodyRange range = shape;
    range.first = members_[b].front();
    range.count = static_cast<std::int32_t>(members_[b].size());
    setupParticleBody(b, range);
    if (kind == MaterialKind::kRope || kind == MaterialKind::kCloth) attachStrandEnds(b);
    refreshInverseMasses(b);
    makeFluidSolver();
  }
  return static_cast<int>(b);
}

void PbdWorld::setMode(int body, BodyMode mode) {
  const auto b = static_cast<std::size_t>(body);
  if (mode_.at(b) == BodyMode::kEmpty || mode == BodyMode::kEmpty) return;
  mode_[b] = mode;
  energy_.reset();
  wakeAll();
  // Prescribed particles have infinite mass: the dynamic passes leave them alone.
  const std::int32_t group = static_cast<std::int32_t>(b);
  const std::uint32_t flags = mode == BodyMode::kDynamic ? 0u : phase::kPrescribed;
  const std::uint32_t fluid = kind_[b] == MaterialKind::kFluid ? phase::kFluid : 0u;
  for (std::int32_t i : members_[b])
    parts_.phase[std::size_t(i)] = phase::make(group, flags | fluid | (pinnedAt(std::size_t(i)) ? phase::kPrescribed : 0u));
  if (!isRigid(b)) refreshInverseMasses(b);
  if (!isRigid(b) && (mode == BodyMode::kFixed || mode == BodyMode::kKinematic)) holdShape(b);
  Motion& mo = motion_[b];
  mo.kinStart = mo.kinTarget = mo.c;
  // No motion yet in its new mode: the contacts take a body's start pose from these (a body
  // made fixed kept its last moving substep's, and a sheet's side was judged from it).
  mo.cPrev = mo.c, mo.qPrev = mo.q;
  if (mode == BodyMode::kFixed) mo.v = mo.w = Vec3::Zero();
  if (mode == BodyMode::kKinematic) mo.w = Vec3::Zero();  // carried bodies keep their rotation
}

void PbdWorld::setVelocity(int body, const Vec3& velocity, const Vec3& angularVelocity) {
  const auto b = static_cast<std::size_t>(body);
  if (mode_.at(b) != BodyMode::kDynamic) throw RuntimeError("PbdWorld::setVelocity: body is not dynamic");
  motion_[b].v = velocity;
  motion_[b].w = angularVelocity;
  energy_.reset();
  wakeAll();
}

void PbdWorld::setKinematicTarget(int body, const Vec3& centre) {
  const auto b = static_cast<std::size_t>(body);
  if (mode_.at(b) != BodyMode::kKinematic) throw RuntimeError("PbdWorld::setKinematicTarget: body is not kinematic");
  motion_[b].kinTarget = centre;
}

// Rest offsets of body b from its particles as they are now, about their centre of mass, which
// it returns (the origin for a body without mass, which refreshMassProperties then empties).
Vec3 PbdWorld::restShapeFromParticles(std::size_t b) {
  const Vec3 c = massMean(b, parts_.x, parts_.y, parts_.z);
  for (std::int32_t i : members_[b]) {
    const auto k = std::size_t(i);
    rx_[k] = static_cast<float>(parts_.x[k] - c.x());
    ry_[k] = static_cast<float>(parts_.y[k] - c.y());
    rz_[k] = static_cast<float>(parts_.z[k] - c.z());
  }
  return c;
}

// A particle-level body that no longer moves by itself (fixed, or carried by a stroke, which
// translates its particles as they are) meets rigid bodies at body level (mayTouch), through
// rigidPoint(): its rest frame becomes its particles' shape now, centred on their centre of
// mass, unrotated.
void PbdWorld::holdShape(std::size_t b) {
  const Vec3 c = restShapeFromParticles(b);
  Motion& mo = motion_[b];
  mo.c = mo.cPrev = c;
  mo.q = mo.qPrev = Quat::Identity();
  refreshMassProperties(b);  // reach and box of the held shape
}

// Moves a body's rest frame to its members' centre of mass, keeping every particle where it is.
void PbdWorld::recentre(std::size_t b) {
  ++bodyEdits_;
  double m = 0.0;
  Vec3 cr = Vec3::Zero();
  for (std::int32_t i : members_[b]) {
    const auto k = std::size_t(i);
    m += parts_.mass[k];
    cr += double(parts_.mass[k]) * Vec3(rx_[k], ry_[k], rz_[k]);
  }
  if (!(m > 0.0)) return;
  cr /= m;
  for (std::int32_t i : members_[b]) {
    const auto k = std::size_t(i);
    rx_[k] = static_cast<float>(rx_[k] - cr.x());
    ry_[k] = static_cast<float>(ry_[k] - cr.y());
    rz_[k] = static_cast<float>(rz_[k] - cr.z());
  }
  Motion& mo = motion_[b];
  const Vec3 shift = mo.q.toRotationMatrix() * cr;
  // The new centre of mass moves with the rigid velocity field at its place.
  mo.v += mo.w.cross(shift);
  mo.c += shift;
  mo.cPrev += motion_[b].qPrev.toRotationMatrix() * cr;
  mo.kinStart += shift;
  mo.kinTarget += shift;
  restCentre_[b] += cr;
}

// A body's particles in its rest lattice (rest offsets are whole multiples of the particle
// spacing apart: offsets from the first member, rounded; float rounding is far below
// half a spacing).
std::vector<Vec3i> PbdWorld::restCells(std::size_t b) const {
  const auto& mem = members_[b];
  const double inv = 1.0 / (2.0 * params_.particleRadius);
  const auto f = std::size_t(mem.front());
  std::vector<Vec3i> cells(mem.size());
  for (std::size_t k = 0; k < mem.size(); ++k) {
    const auto i = std::size_t(mem[k]);
    cells[k] = Vec3i(int(std::lround((double(rx_[i]) - rx_[f]) * inv)), int(std::lround((double(ry_[i]) - ry_[f]) * inv)),
                     int(std::lround((double(rz_[i]) - rz_[f]) * inv)));
  }
  return cells;
}

// The bodies a body with fewer particles becomes: core/lattice.h's cutPieces on its rest lattice.
std::vector<std::vector<std::int32_t>> PbdWorld::pieces(std::size_t b) const {
  return cutPieces(members_[b], restCells(b), design_);
}

// Labels the design pieces of a body as it is now (when it is made, or a fragment of one).
void PbdWorld::labelDesignPieces(std::size_t b) {
  const std::vector<std::int32_t> label = componentLabels26(restCells(b));
  const auto& mem = members_[b];
  for (std::size_t k = 0; k < mem.size(); ++k) design_[std::size_t(mem[k])] = label[k];
}

std::vector<int> PbdWorld::removeParticles(const std::vector<std::int32_t>& ids) {
  std::vector<int> changed;
  wakeAll();  // a sketch edit wakes every body; a soft sleeper's saved rest offsets follow its members
  ++bodyEdits_;
  energy_.reset();
  for (std::int32_t i : ids) {
    if (i < 0 || static_cast<std::size_t>(i) >= parts_.size() || !alive(i)) continue;
    const auto k = std::size_t(i);
    const int b = parts_.group(k);
    parts_.phase[k] = phase::make(-1, phase::kRemoved | phase::kPrescribed);
    parts_.vx[k] = parts_.vy[k] = parts_.vz[k] = 0.0f;
    surfaceNormal_[k].setZero();
    sheetFace_[k] = 0;
    if (b >= 0 && std::find(changed.begin(), changed.end(), b) == changed.end()) changed.push_back(b);
  }
  std::sort(changed.begin(), changed.end());
  std::vector<int> out = changed;
  for (int b : changed) {
    const auto bb = static_cast<std::size_t>(b);
    auto& mem = members_[bb];
    if (bb < groundCache_.size()) groundCache_[bb].valid = false;
    mem.erase(std::remove_if(mem.begin(), mem.end(), [&](std::int32_t i) { return !alive(i); }), mem.end());
    if (!isRigid(bb)) {
      // Particle-level bodies keep their index: their constraints to removed particles go
      // (a cut rope hangs in two pieces; a cloth tears), their clusters lose the members.
      refreshMassProperties(bb);
      continue;
    }
    if (mem.empty()) {
      refreshMassProperties(bb);
      continue;
    }
    // A cut that disconnects the body leaves one rigid body per piece: each keeps the
    // body's pose and rigid velocity field, with its own mass, centre and inertia.
    auto parts = pieces(bb);
    const Motion before = motion_[bb];
    const Vec3 restBefore = restCentre_[bb];
    const BodyMode mode = mode_[bb];
    mem = std::move(parts[0]);
    recentre(bb);
    refreshMassProperties(bb);
    for (std::size_t k = 1; k < parts.size(); ++k) {
      // Offsets are still relative to the old rest centre: start from the old frame.
      const std::size_t nb = pushBodySlot(std::move(parts[k]), before, restBefore, mode);
      recentre(nb);
      labelDesignPieces(nb);  // a fragment is one connected piece
      refreshMassProperties(nb);
      const Vec3 v = motion_[nb].v, w = motion_[nb].w;
      // A carried body keeps only its largest piece on the brush; the others fall.
      setMode(static_cast<int>(nb), mode == BodyMode::kKinematic ? BodyMode::kDynamic : mode);
      motion_[nb].v = v;
      motion_[nb].w = w;
      out.push_back(static_cast<int>(nb));
    }
    setMode(b, mode);
  }
  std::sort(out.begin(), out.end());
  bool loose = false;
  for (int b : changed) loose = loose || !isRigid(std::size_t(b));
  if (loose) {
    for (std::int32_t i : ids)
      if (i >= 0 && std::size_t(i) < parts_.size()) invMassP_[std::size_t(i)] = 0.0f;
    dropRemovedConstraints();
    looseDirty_ = true;
  }
  return out;
}

BodyPose PbdWorld::pose(int body) const {
  const Motion& mo = motion_.at(static_cast<std::size_t>(body));
  BodyPose p;
  p.rotation = mo.q;
  p.centre = mo.c;
  p.restCentre = restCentre_[static_cast<std::size_t>(body)];
  return p;
}

// --- the step -------------------------------------------------------------------

bool PbdWorld::anyBouncyRigid() const {
  for (std::size_t b = 0; b < mode_.size(); ++b) {
    if (isRigid(b) && mode_[b] != BodyMode::kEmpty && restitution_[b] > 0.0) return true;
  }
  return false;
}

PbdWorld::Census PbdWorld::census() const {
  Census c;
  const bool bouncy = anyBouncyRigid();
  for (std::size_t b = 0; b < mode_.size(); ++b) {
    const BodyMode m = mode_[b];
    if (m == BodyMode::kEmpty) continue;
    ++c.bodies;
    const bool dyn = m == BodyMode::kDynamic;
    const auto count = [&](long& n, std::vector<std::size_t>& list, bool yes) {
      if (!yes) return;
      ++n;
      list.push_back(b);
    };
    if (isRigid(b)) {
      // A sleeper is not simulated (the passes treat it as fixed) until something touches it.
      const bool awake = dyn && !asleep(int(b));
      c.asleep += dyn && !awake;
      count(c.rigidDynamic, c.rigidBodies, awake);
      count(c.bouncy, c.bouncyBodies, awake && bouncy);
    } else {
      // A soft body, rope or cloth asleep is held like a fixed one (sleepLoose) until it wakes.
      const bool awake = dyn && !asleep(int(b));
      c.looseAsleep += dyn && !awake;
      count(c.looseDynamic, c.looseBodies, awake);
      count(c.soft, c.softBodies, awake && kind_[b] == MaterialKind::kSoft);
      count(c.strands, c.strandBodies, awake && (kind_[b] == MaterialKind::kRope || kind_[b] == MaterialKind::kCloth));
      count(c.fluid, c.fluidBodies, awake && kind_[b] == MaterialKind::kFluid);
    }
    count(c.kinematic, c.kinematicBodies, m == BodyMode::kKinematic);
    c.kinematicLoose += m == BodyMode::kKinematic && !isRigid(b);
  }
  for (std::size_t k = 0; k < clusters_.creep.size(); ++k)
    c.plastic += clusters_.creep[k] > 0.0f && moving(std::size_t(clusters_.body[k]));
  for (std::size_t k = 0; k < distances_.size() && !c.distances; ++k)
    c.distances = invMassP_[std::size_t(distances_.i[k])] > 0.0f || invMassP_[std::size_t(distances_.j[k])] > 0.0f;
  c.distances = c.distances || !attachments_.empty() || !tethers_.empty();
  return c;
}

std::vector<bool> PbdWorld::work() const {
  std::vector<bool> on(static_cast<std::size_t>(PbdPass::kCount), false);
  const Census c = census();
  // Sleepers count as moving only where a carried body or particle-level material may wake one
  // within the step (which then needs every rigid pass from that substep on); otherwise a pile
  // asleep runs no rigid pass.
  const bool kinematic = c.kinematic > 0;
  const bool loose = c.looseDynamic > 0;
  const bool rigid = c.rigidDynamic > 0 || (c.asleep > 0 && (kinematic || loose));
  on[int(PbdPass::kIntegrate)] = rigid;
  on[int(PbdPass::kPredict)] = loose;
  on[int(PbdPass::kKinematic)] = kinematic;
  on[int(PbdPass::kFindContacts)] = rigid;
  // Particle pairs exist only with something to touch: another body, or a fluid's own particles.
  on[int(PbdPass::kFindNeighbors)] = loose && c.bodies > 1;
  on[int(PbdPass::kParticleContact)] = loose;
  on[int(PbdPass::kFluidNeighbors)] = c.fluid > 0;
  const bool anyColliders = colliders_ && colliders_->size() > 0;
  on[int(PbdPass::kFindColliders)] = anyColliders && (rigid || loose);
  on[int(PbdPass::kColliderContact)] = anyColliders && rigid;
  on[int(PbdPass::kDensity)] = c.fluid > 0;
  on[int(PbdPass::kFluidVelocity)] = c.fluid > 0 && fluidVelocity_;
  on[int(PbdPass::kClusterMatch)] = c.soft > 0;
  on[int(PbdPass::kDistance)] = loose && c.distances;
  on[int(PbdPass::kRigidContact)] = rigid;
  on[int(PbdPass::kBodyContact)] = rigid && bodiesMayTouch();
  on[int(PbdPass::kUpdate)] = rigid || c.kinematic > c.kinematicLoose;
  on[int(PbdPass::kParticleUpdate)] = loose || c.kinematicLoose > 0;
  on[int(PbdPass::kPlasticity)] = c.plastic > 0;
  on[int(PbdPass::kRestitution)] = c.bouncy > 0;
  on[int(PbdPass::kWriteParticles)] = rigid || loose || kinematic;
  on[int(PbdPass::kGuard)] = parts_.size() > 0;
  return on;
}

std::string PbdWorld::whichStrokes(const std::vector<std::size_t>& bodies) const {
  constexpr std::size_t kMaxNamed = 6;
  std::vector<std::pair<std::int16_t, std::vector<int>>> byMaterial;  // in order of first appearance
  for (std::size_t k = 0; k < std::min(bodies.size(), kMaxNamed); ++k) {
    const auto first = std::size_t(members_[bodies[k]].front());
    const std::int16_t mat = parts_.material[first];
    auto it = std::find_if(byMaterial.begin(), byMaterial.end(), [&](const auto& e) { return e.first == mat; });
    if (it == byMaterial.end()) it = byMaterial.insert(byMaterial.end(), {mat, {}});
    it->second.push_back(parts_.stroke[first]);
  }
  std::string out = bodies.size() == 1 ? "stroke " : "strokes ";
  for (std::size_t m = 0; m < byMaterial.size(); ++m) {
    if (m > 0) out += "; ";
    for (std::size_t k = 0; k < byMaterial[m].second.size(); ++k)
      out += (k > 0 ? ", " : "") + std::to_string(byMaterial[m].second[k]);
    out += " (" + materials_[std::size_t(byMaterial[m].first)].name + ")";
  }
  if (bodies.size() > kMaxNamed) out += " and " + std::to_string(bodies.size() - kMaxNamed) + " more";
  return out;
}

std::string PbdWorld::reason(PbdPass pass, bool on) const {
  const Census c = census();
  const auto n = [&](long k, const char* what) {
    const std::vector<std::size_t>* list = nullptr;
    switch (pass) {
      case PbdPass::kIntegrate:
      case PbdPass::kFindContacts:
      case PbdPass::kRigidContact:
      case PbdPass::kColliderContact: list = &c.rigidBodies; break;
      case PbdPass::kKinematic: list = &c.kinematicBodies; break;
      case PbdPass::kPredict:
      case PbdPass::kParticleContact: list = &c.looseBodies; break;
      case PbdPass::kClusterMatch: list = &c.softBodies; break;
      case PbdPass::kFluidNeighbors:
      case PbdPass::kDensity: list = &c.fluidBodies; break;
      case PbdPass::kDistance: list = &c.strandBodies; break;
      case PbdPass::kRestitution: list = &c.bouncyBodies; break;
      default: break;
    }
    std::string out = std::to_string(k) + " " + what;
    if (list && !list->empty()) out += ": " + whichStrokes(*list);
    return out;
  };
  const std::string asleepNote = c.asleep > 0 ? " (and " + std::to_string(c.asleep) + " asleep)" : "";
  const std::string looseAsleepNote = c.looseAsleep > 0 ? " (and " + std::to_string(c.looseAsleep) + " asleep)" : "";
  switch (pass) {
    case PbdPass::kIntegrate:
    case PbdPass::kFindContacts:
    case PbdPass::kRigidContact:
      return on ? n(c.rigidDynamic, "dynamic rigid bodies") + asleepNote
                : c.asleep > 0 ? std::to_string(c.asleep) + " dynamic rigid bodies, all asleep (sleep)"
                               : "no dynamic rigid body (none, or all fixed, held or emptied)";
    case PbdPass::kBodyContact:
      return on ? "a dynamic rigid body and another rigid, fixed or carried body within reach of each other"
                : (c.rigidDynamic == 0 ? "no dynamic rigid body"
                                       : "no rigid body is within reach of another rigid, fixed or carried one");
    case PbdPass::kKinematic:
      return on ? n(c.kinematic, "bodies held or carried by a stroke")
                : "no body is held while drawn or carried by a move now";
    case PbdPass::kUpdate:
      return on ? n(c.rigidDynamic + c.kinematic - c.kinematicLoose, "moving rigid bodies") : "no rigid body moves";
    case PbdPass::kPredict:
    case PbdPass::kParticleContact:
      return on ? n(c.looseDynamic, "dynamic soft, rope, cloth or fluid bodies") + looseAsleepNote
                : c.looseAsleep > 0 ? std::to_string(c.looseAsleep) + " soft, rope or cloth bodies, all asleep (sleep)"
                                    : "no soft, rope, cloth or fluid material in the scene (or all of it fixed)";
    case PbdPass::kParticleUpdate:
      return on ? n(c.looseDynamic + c.kinematicLoose, "moving soft, rope, cloth or fluid bodies")
                : "no soft, rope, cloth or fluid material moves";
    case PbdPass::kFindNeighbors:
      return on ? "particle-level material and another body it can touch"
                : (c.looseDynamic == 0 ? (c.looseAsleep > 0 ? "no awake particle-level material (sleep)" : "no dynamic particle-level material")
                                       : "a single body with nothing else to touch");
    case PbdPass::kClusterMatch:
      return on ? n(c.soft, "dynamic soft bodies") + looseAsleepNote
                : c.looseAsleep > 0 ? "no dynamic soft body awake (sleep)" : "no dynamic soft body";
    case PbdPass::kFindColliders:
      return on ? std::to_string(colliders_->size()) + " mesh colliders and moving material"
                : (colliders_ && colliders_->size() > 0 ? "nothing moves near the colliders" : "no mesh collider in the scene");
    case PbdPass::kColliderContact:
      return on ? n(c.rigidDynamic, "dynamic rigid bodies and mesh colliders")
                : (colliders_ && colliders_->size() > 0 ? "no dynamic rigid body" : "no mesh collider in the scene");
    case PbdPass::kFluidNeighbors: return on ? n(c.fluid, "dynamic fluid bodies") : "no fluid in the scene (or all of it fixed)";
    case PbdPass::kDensity: {
      if (!on) return "no fluid in the scene (or all of it fixed)";
      std::string why = n(c.fluid, "dynamic fluid bodies") + fluidSoundText();  // the compliance's sound speed (pbd/fluid.h)
      if (params_.warmStart > 0.0) {
        char w[96];
        std::snprintf(w, sizeof w, "; warm start %.2g of the last substep's multipliers, ", params_.warmStart);
        why += w + (params_.warmSmoothing > 0 ? "averaged " + std::to_string(params_.warmSmoothing) + " times" : std::string("unaveraged"));
      }
      return why;
    }
    case PbdPass::kFluidVelocity: {
      if (!on)
        return c.fluid == 0 ? "no fluid in the scene"
                            : "its fluids set no xsph_viscosity, vorticity or cohesion, and no viscosity above 10x water's";
      std::string why = "a fluid sets xsph_viscosity, vorticity, cohesion or a viscosity above 10x water's (implicit solve)";
      const int it = fluid_ ? fluid_->lastViscosityIterations() : 0;
      if (it >= FluidSolver::kViscosityMaxIterations)
        why += "; the viscosity's CG stopped at its cap of " + std::to_string(it) +
               " iterations last substep, short of its tolerance: more substeps make each solve easier";
      else if (it > 0)
        why += "; the viscosity's CG took " + std::to_string(it) + " iterations last substep";
      if (it > 0 && (viscousBodies_ > 0 || viscousLoose_ > 0))
        why += ", dragging back " + std::to_string(viscousBodies_) + (viscousBodies_ == 1 ? " rigid body" : " rigid bodies") +
               " and " + std::to_string(viscousLoose_) + (viscousLoose_ == 1 ? " soft, rope or cloth particle" : " soft, rope or cloth particles");
      return why;
    }
    case PbdPass::kDistance:
      return on ? n(c.strands, "dynamic ropes or cloths (or attachments)") : "no rope or cloth moves";
    case PbdPass::kPlasticity:
      return on ? n(c.plastic, "soft clusters with plastic_creep > 0") : "no soft material has plastic_creep > 0";
    case PbdPass::kWriteParticles: return on ? "bodies move" : "no body moves";
    case PbdPass::kRestitution:
      return on ? n(c.bouncy, "dynamic rigid bodies that can bounce (restitution > 0, theirs or another rigid body's)")
                : "no rigid body's material has restitution > 0 (or no rigid body moves)";
    case PbdPass::kGuard: return on ? "checks every step" : "no particles";
    case PbdPass::kCount: break;
  }
  return "";
}

std::string PbdWorld::touches(PbdPass pass) const {
  long particles = 0, bodies = 0;
  const bool bouncy = pass == PbdPass::kRestitution && anyBouncyRigid();
  for (std::size_t b = 0; b < mode_.size(); ++b) {
    const BodyMode m = mode_[b];
    const bool rigid = isRigid(b), dyn = moving(b);  // a sleeper is not touched
    bool counts = false;
    switch (pass) {
      case PbdPass::kIntegrate:
      case PbdPass::kFindContacts:
      case PbdPass::kRigidContact: counts = rigid && dyn; break;
      case PbdPass::kBodyContact:
        counts = rigid ? m != BodyMode::kEmpty : (m == BodyMode::kFixed || m == BodyMode::kKinematic || asleep(int(b)));
        break;
      case PbdPass::kRestitution: counts = rigid && dyn && bouncy; break;
      case PbdPass::kKinematic: counts = m == BodyMode::kKinematic; break;
      case PbdPass::kUpdate: counts = rigid && (dyn || m == BodyMode::kKinematic); break;
      case PbdPass::kPredict:
      case PbdPass::kParticleContact: counts = !rigid && dyn; break;
      case PbdPass::kFindNeighbors: counts = m != BodyMode::kEmpty; break;
      case PbdPass::kParticleUpdate: counts = !rigid && (dyn || m == BodyMode::kKinematic); break;
      case PbdPass::kClusterMatch:
      case PbdPass::kPlasticity: counts = dyn && kind_[b] == MaterialKind::kSoft; break;
      case PbdPass::kFindColliders: counts = dyn; break;
      case PbdPass::kColliderContact: counts = rigid && dyn; break;
      case PbdPass::kFluidNeighbors:
      case PbdPass::kDensity:
      case PbdPass::kFluidVelocity: counts = dyn && kind_[b] == MaterialKind::kFluid; break;
      case PbdPass::kDistance:
        counts = dyn && (kind_[b] == MaterialKind::kRope || kind_[b] == MaterialKind::kCloth);
        break;
      case PbdPass::kWriteParticles: counts = dyn || m == BodyMode::kKinematic; break;
      case PbdPass::kGuard: counts = m != BodyMode::kEmpty; break;
      case PbdPass::kCount: break;
    }
    if (!counts) continue;
    ++bodies;
    particles += long(members_[b].size());
  }
  std::string t = std::to_string(particles) + " particles in " + std::to_string(bodies) + " bodies";
  if (pass == PbdPass::kFindContacts || pass == PbdPass::kRigidContact)
    t += " (the sweeps touch only particles near the ground)";
  if (pass == PbdPass::kClusterMatch) t += ", " + std::to_string(clusters_.members.size()) + " clusters";
  if (pass == PbdPass::kDistance)
    t += ", " + std::to_string(distances_.size()) + " distance constraints, " + std::to_string(attachments_.size()) +
         " attachments, " + std::to_string(tethers_.size()) + " tethers";
  if (pass == PbdPass::kFindNeighbors) t = "particle-level particles and the rigid particles near them";
  return t;
}

std::vector<PlanEntry> PbdWorld::planAll() const {
  std::vector<PlanEntry> out;
  const std::vector<bool> on = work();
  const long s = params_.substeps;
  for (int k = 0; k < int(PbdPass::kCount); ++k) {
    const PassSpec& spec = kPbdPasses[k];
    PlanEntry e;
    e.pass = k;
    e.name = spec.name;
    e.does = spec.does;
    e.on = on[std::size_t(k)];
    const long it = params_.iterations;
    switch (spec.cadence) {
      case Cadence::kPerStep: e.runs = "once"; break;
      case Cadence::kPerSubstep: e.runs = "substeps = " + std::to_string(s); break;
      case Cadence::kPerIteration:
        e.runs = "substeps x iterations = " + std::to_string(s) + " x " + std::to_string(it);
        break;
    }
    if (PbdPass(k) == PbdPass::kRigidContact || PbdPass(k) == PbdPass::kBodyContact)
      e.runs += ", up to " + std::to_string(it) + " sweeps each";
    const long calls = spec.cadence == Cadence::kPerStep ? 1 : spec.cadence == Cadence::kPerSubstep ? s : s * it;
    e.perStep = e.on ? calls : 0;
    e.reason = reason(PbdPass(k), e.on);
    if (e.on) e.touches = touches(PbdPass(k));
    e.heldBytes = passBytes(PbdPass(k));
    out.push_back(std::move(e));
  }
  return out;
}

// The buffers each pass owns, kept between steps (capacity). The state every pass shares
// (particle arrays, body poses) is no pass's; scratch a pass frees before it returns (a contact
// search's local NeighborGrid) is not counted.
std::size_t PbdWorld::passBytes(PbdPass pass) const {
  const auto& bp = contacts_.bodyPlane;
  const auto& pp = contacts_.bodyPair;
  const auto surface = [](const ParticleSurfaceContacts& c) { return heldBytes(c.i, c.surface, c.point, c.normal); };
  switch (pass) {
    case PbdPass::kPredict: return heldBytes(px_, py_, pz_, invMassP_, pinned_, loose_);
    case PbdPass::kFindContacts: {
      std::size_t b = heldBytes(groundCache_);
      for (const GroundCache& g : groundCache_) b += heldBytes(g.candidates);
      return b;
    }
    case PbdPass::kRigidContact:
      return heldBytes(bp.body, bp.plane, bp.first, bp.count, bp.candidates, bp.touched, bp.point, bp.approachSpeed,
                       bp.normalImpulse);
    case PbdPass::kBodyContact: return heldBytes(pp.a, pp.b, pp.first, pp.count, pp.pa, pp.pb);
    case PbdPass::kRestitution: return heldBytes(pairHits_, bodyTouches_);
    case PbdPass::kFindNeighbors: {  // the pairs, and the rigid bodies' rest cells the sweeps walk
      std::size_t cells = 0;
      for (const RestCells& rc : restCells_) cells += rc.bits.capacity() * sizeof(std::uint64_t);
      return heldBytes(contacts_.particlePair.i, contacts_.particlePair.j) + cells;
    }
    case PbdPass::kParticleContact: return surface(contacts_.particlePlane);
    case PbdPass::kFluidNeighbors: return fluid_ ? fluid_->neighborBytes() : 0;
    case PbdPass::kDensity: return (fluid_ ? fluid_->solverBytes() : 0) + heldBytes(fluidIds_, fx_, fy_, fz_, fw_, frho_, fdx_, fdy_, fdz_, fflag_, fsample_);
    case PbdPass::kClusterMatch: {
      const SoftClusters& c = clusters_;
      // (offset starts as {0}, one entry, before any cluster: not the pass's.)
      std::size_t b = (c.members.size() > 0 ? heldBytes(c.members.offset) : 0) +
                      heldBytes(c.members.index, c.members.stiffness, c.qx, c.qy, c.qz, c.lambda,
                                c.compliance, c.rotation, c.body, c.restCentre, c.extent, clusterCells_);
      for (const auto& colour : clusterCells_) {
        b += heldBytes(colour);
        for (const auto& cell : colour) b += heldBytes(cell);
      }
      return b;
    }
    case PbdPass::kPlasticity: return heldBytes(clusters_.yield, clusters_.creep);
    case PbdPass::kDistance:
      return heldBytes(distances_.i, distances_.j, distances_.rest, distances_.compliance, distances_.lambda,
                       distances_.colour, distanceVia_, attachments_, tethers_);
    case PbdPass::kFindColliders: {
      std::size_t b = heldBytes(looseHits_, bodyHits_);
      for (const auto& h : bodyHits_) b += heldBytes(h.particle, h.contact);
      return b;
    }
    case PbdPass::kColliderContact: return surface(contacts_.particleMesh);
    case PbdPass::kParticleUpdate:
      return heldBytes(groundApproach_, bounceNoted_) + heldBytes(softBounce_) + heldBytes(partnerHits_) +
             heldBytes(particleBounces_, bounceImpulse_);
    case PbdPass::kWriteParticles: return heldBytes(rx_, ry_, rz_);
    default: return 0;
  }
}

std::vector<PlanEntry> PbdWorld::plan() const {
  std::vector<PlanEntry> out;
  for (PlanEntry& e : planAll())
    if (e.on) out.push_back(std::move(e));
  return out;
}

template <class F>
bool PbdWorld::runPass(PbdPass pass, int substep, bool check, F&& f) {
  {
    ScopedPass t(profile_, pass);
    f();
  }
  if (!check) return true;
  // Penetration is checked where it must have been resolved: after the contact pass
  // (and at the end of the step), not after integrate, where a landing body is
  // routinely inside the ground until rigid_contact lifts it.
  const bool penetration = pass == PbdPass::kRigidContact || pass == PbdPass::kWriteParticles;
  GuardRecord r = checkImplied(pass != PbdPass::kWriteParticles, penetration);
  if (!r.tripped() && pass == PbdPass::kDensity) r = checkCompression();
  if (!r.tripped()) return true;
  r.pass = kPbdPasses[int(pass)].name;
  r.step = steps_;
  r.substep = kPbdPasses[int(pass)].cadence == Cadence::kPerSubstep ? substep : -1;
  guard_ = std::move(r);
  return false;
}

bool PbdWorld::runStep(bool checkEachPass) {
  const std::vector<bool>& on = work_;
  // Made here, not in step(): a replay starts again from the step's sleepers.
  active_.clear();
  for (std::size_t b = 0; b < mode_.size(); ++b)
    if (moving(b) && isRigid(b)) active_.push_back(static_cast<std::int32_t>(b));
  const double h = params_.dt / params_.substeps;
  const auto runs = [&](PbdPass p) { return bool(on[std::size_t(p)]); };
  for (int s = 0; s < params_.substeps; ++s) {
    substepStamp_ = steps_ * params_.substeps + s;
    if (runs(PbdPass::kIntegrate) && !runPass(PbdPass::kIntegrate, s, checkEachPass, [&] { integrate(h); })) return false;
    if (runs(PbdPass::kPredict) && !runPass(PbdPass::kPredict, s, checkEachPass, [&] { predict(h); })) return false;
    if (runs(PbdPass::kKinematic) && !runPass(PbdPass::kKinematic, s, checkEachPass, [&] { kinematic(s); }))
      return false;
    if (runs(PbdPass::kFindContacts) && !runPass(PbdPass::kFindContacts, s, checkEachPass, [&] { findContacts(); }))
      return false;
    if (runs(PbdPass::kFindNeighbors) && !runPass(PbdPass::kFindNeighbors, s, checkEachPass, [&] { findNeighbors(); }))
      return false;
    if (runs(PbdPass::kFindColliders) && !runPass(PbdPass::kFindColliders, s, checkEachPass, [&] { findColliders(s); }))
      return false;
    if (runs(PbdPass::kFluidNeighbors) &&
        !runPass(PbdPass::kFluidNeighbors, s, checkEachPass, [&] { fluidNeighbors(); }))
      return false;
    // Shape matching before the contacts, so that the contacts have the last word on a soft body
    // in each iteration: after them, the clusters pulled a soft body resting on a rigid one back
    // into it (a stiff cube 0.31 spacings into a slab's particles; a stiff ball down to a
    // table's face, half a spacing, where particle_update's sweep held it), not a spacing off
    // the body's particles, where the contacts hold it.
    for (int it = 0; it < params_.iterations; ++it) {
      if (runs(PbdPass::kClusterMatch) && !runPass(PbdPass::kClusterMatch, s, checkEachPass, [&] { clusterMatch(h); }))
        return false;
      if (runs(PbdPass::kParticleContact) &&
          !runPass(PbdPass::kParticleContact, s, checkEachPass, [&] { particleContact(); }))
        return false;
      if (runs(PbdPass::kDensity) && !runPass(PbdPass::kDensity, s, checkEachPass, [&] { density(); })) return false;
      if (runs(PbdPass::kDistance) && !runPass(PbdPass::kDistance, s, checkEachPass, [&] { distanceConstraints(h); }))
        return false;
    }
    if (runs(PbdPass::kRigidContact) && !runPass(PbdPass::kRigidContact, s, checkEachPass, [&] { rigidContact(); }))
      return false;
    if (runs(PbdPass::kBodyContact) && !runPass(PbdPass::kBodyContact, s, checkEachPass, [&] { bodyContact(); }))
      return false;
    if (runs(PbdPass::kColliderContact) &&
        !runPass(PbdPass::kColliderContact, s, checkEachPass, [&] { rigidColliderContact(); }))
      return false;
    if (runs(PbdPass::kUpdate) && !runPass(PbdPass::kUpdate, s, checkEachPass, [&] { update(h); })) return false;
    if (runs(PbdPass::kParticleUpdate) &&
        !runPass(PbdPass::kParticleUpdate, s, checkEachPass, [&] { particleUpdate(h); }))
      return false;
    if (runs(PbdPass::kFluidVelocity) &&
        !runPass(PbdPass::kFluidVelocity, s, checkEachPass, [&] { fluidVelocity(h); }))
      return false;
    if (runs(PbdPass::kPlasticity) && !runPass(PbdPass::kPlasticity, s, checkEachPass, [&] { plasticity(h); }))
      return false;
    if (runs(PbdPass::kRestitution) && !runPass(PbdPass::kRestitution, s, checkEachPass, [&] { restitution(h); }))
      return false;
  }
  if (runs(PbdPass::kWriteParticles) &&
      !runPass(PbdPass::kWriteParticles, -1, checkEachPass, [&] { writeParticles(); }))
    return false;
  return true;
}

bool PbdWorld::step() {
  if (guard_.tripped()) return false;
  // Contacts found in an earlier step must not outlive it: a pass that finds them may be off
  // now (a removed tool leaves one body: find_neighbors is off, particle_contact still on).
  contacts_.particlePair.clear();
  pairHits_.clear();
  bodyTouches_.clear();
  looseHits_.clear();
  bodyHits_.clear();
  asleep_.resize(members_.size(), 0);
  stillFor_.resize(members_.size(), 0.0);
  stillRef_.resize(members_.size());
  sleepAllowed_ = params_.sleepSpeed > 0.0 && sleepPossible();
  // Bodies added, cut or reshaped since the last step wake everything (as does setMode, setVelocity
  // and setColliders): a sleeper's support may be gone.
  if (!sleepAllowed_ || bodyEdits_ != sleepEdits_) wakeAll();
  wakeLooseSleepers();  // before the plan: a woken one runs its passes from the first substep
  sleepEdits_ = bodyEdits_;
  work_ = work();  // once per step: the replay below restores the same start, so the same passes
  if (looseDirty_) {
    loose_.clear();
    for (std::size_t b = 0; b < members_.size(); ++b)
      if (!isRigid(b)) loose_.insert(loose_.end(), members_[b].begin(), members_[b].end());
    std::sort(loose_.begin(), loose_.end());
    looseDirty_ = false;
  }
  // After an outside event the energy reference is taken here, before the step, so that
  // growth within the step is caught (loose_ is current: rebuilt above).
  if (work_[std::size_t(PbdPass::kGuard)] && !energy_.armed() && energyClosed())
    energy_.arm(energyNow(), params_.gravity, 2.0 * params_.particleRadius);
  // Bodies a rope or cloth is tied to never sleep (touchedByLoose wakes one that does, here, before
  // the start is kept); the particle pairs mark the others during the step.
  const auto markTied = [&] {
    looseTouch_.assign(members_.size(), 0);
    for (const Attachment& a : attachments_) touchedByLoose(std::size_t(a.body));
  };
  markTied();
  // The start of the step: to replay it with a check after every pass (naming the pass that
  // produced a bad value), and under policy warn to complete a step the guard stopped midway.
  // Members, copied into: they keep their capacity, so a step allocates nothing (a fresh
  // copy of an 80k-particle fluid's state page-faulted 1.9 MB every step).
  std::vector<Motion>& start = startMotion_;
  std::vector<GroundCache>& cacheStart = startCache_;
  std::vector<float>& looseStart = startLoose_;  // particle-level state (only when there is some)
  if (!validate_ || guardLog_.policy == GuardPolicy::kWarn) {
    start = motion_;  // per body: cheap to keep
    cacheStart = groundCache_;
    startAsleep_ = asleep_;
    startStill_ = stillFor_;
    startStillRef_ = stillRef_;
    startSoundSpeed_ = fluidSoundSpeed_;
    startCarry_ = fluidCarry_;
    startCarryIds_ = fluidCarryIds_;
    startCarryStamp_ = fluidCarryStamp_;
    startColdStarts_ = fluidColdStarts_;
    looseStart.resize(6 * loose_.size());
    std::size_t at = 0;
    for (const auto* a : {&parts_.x, &parts_.y, &parts_.z, &parts_.vx, &parts_.vy, &parts_.vz})
      for (std::int32_t i : loose_) looseStart[at++] = (*a)[std::size_t(i)];
  }
  const auto restoreStart = [&] {
    motion_ = start;
    groundCache_ = cacheStart;
    asleep_ = startAsleep_;
    stillFor_ = startStill_;
    stillRef_ = startStillRef_;
    fluidSoundSpeed_ = startSoundSpeed_;
    fluidCarry_ = startCarry_;
    fluidCarryIds_ = startCarryIds_;
    fluidCarryStamp_ = startCarryStamp_;
    fluidColdStarts_ = startColdStarts_;
    markTied();
    std::size_t at = 0;
    for (auto* a : {&parts_.x, &parts_.y, &parts_.z, &parts_.vx, &parts_.vy, &parts_.vz})
      for (std::int32_t i : loose_) (*a)[std::size_t(i)] = looseStart[at++];
  };
  const bool checks = work_[std::size_t(PbdPass::kGuard)];
  const auto endChecks = [&] {
    ScopedPass t(profile_, PbdPass::kGuard);
    GuardRecord r;
    // write_particles summarized what it wrote: scan particle by particle only when that summary
    // is suspect (or nothing was written this step).
    if (writtenSuspect_ || !work_[std::size_t(PbdPass::kWriteParticles)]) r = checkImplied(false, true);
    if (!r.tripped() && work_[std::size_t(PbdPass::kDensity)]) r = checkCompression();
    if (!r.tripped()) r = checkEnergy();
    return r;
  };
  const auto settle = [&] {
    for (Motion& mo : motion_) mo.kinStart = mo.kinTarget = mo.c;
  };
  const auto finish = [&] {
    if (guard_.particle >= 0)
      guard_.material = materials_[std::size_t(parts_.material[std::size_t(guard_.particle)])].name;
    KnobState knobs;
    knobs.substeps = params_.substeps;
    knobs.iterations = params_.iterations;
    guard_.hint += " Fix: " + knobAdvice(guard_, knobs) + ".";
  };
  const long logged = guardLog_.total();
  if (!guardedStep(guard_, guardLog_, validate_, checks, steps_, [&](bool check) { return runStep(check); }, endChecks,
                   [&] { return checkEnergy(); }, restoreStart, settle, finish))
    return false;
  if (guardLog_.total() != logged) energy_.reset();  // warned: a new reference next step
  updateSleep();
  ++steps_;
  return true;
}

// Energy growth while the system is closed: no carried body (tools included) and no collider
// moving along keyframes. The hint names the substep count to try: substeps damp the growth
// where iterations do not (docs/accuracy.md, Small Steps).
bool PbdWorld::energyClosed() const {
  bool closed = true;
  for (BodyMode m : mode_) closed &= m != BodyMode::kKinematic;
  if (colliders_)
    for (std::size_t c = 0; c < colliders_->size(); ++c) closed &= !colliders_->moving(c);
  return closed;
}

// Rigid bodies from their centre-of-mass motion (exact for a rigid body: sum m |v + w x r|^2 / 2 =
// M v^2 / 2 + w . I w / 2), so that the check costs O(bodies) for them, not a pass over their
// particles; their lowest point from the centre and the body's reach (a bound: it can only
// raise the energy allowed, by at most M |g| reach). Particle-level bodies from their particles.
EnergySums PbdWorld::energyNow() const {
  EnergySums sums;
  const double gn = params_.gravity.norm();
  for (std::size_t b = 0; b < mode_.size(); ++b) {
    if (mode_[b] != BodyMode::kDynamic || !isRigid(b) || invMass_[b] <= 0.0) continue;
    const Motion& mo = motion_[b];
    const double m = 1.0 / invMass_[b];
    const Mat3 R = mo.q.toRotationMatrix();
    const double h = -params_.gravity.dot(mo.c);
    EnergySums body;
    body.kinetic = 0.5 * m * mo.v.squaredNorm() + 0.5 * mo.w.dot(R * inertiaRest_[b] * R.transpose() * mo.w);
    body.potential = m * h;
    body.mass = m;
    body.lowest = h - reach_[b] * gn;
    sums.add(body);
  }
  if (!loose_.empty()) sums.add(energySums(parts_, params_.gravity, loose_));
  return sums;
}

// Energy growth while the system is closed: no carried body (tools included) and no collider
// moving along keyframes. step() adds the knob to try: substeps damp the growth where
// iterations do not (docs/accuracy.md, Small Steps).
GuardRecord PbdWorld::checkEnergy() {
  const bool closed = energyClosed();
  GuardRecord r = energy_.check(closed ? energyNow() : EnergySums{}, parts_, params_.gravity,
                                2.0 * params_.particleRadius, closed);
  if (r.tripped()) r.hint = "Energy grew in a closed system (nothing moved it from outside).";
  return r;
}

// The particle state the bodies imply (or, for write_particles, the particle arrays
// themselves), checked against the shared bounds and the ground.
GuardRecord PbdWorld::checkImplied(bool bodiesOnly, bool penetration) const {
  GuardRecord r;
  const double floorY = params_.groundY + params_.particleRadius;
  const double bound = params_.particleRadius;  // a dynamic particle's centre below the ground plane
  if (!bodiesOnly) {
    r = checkParticles(parts_, params_.maxSpeed);
    if (r.tripped() || !penetration) return r;
    // Cheap test first (a vectorized minimum over every particle); the scan below finds
    // the first dynamic offender only when some particle is that deep.
    float lowest = 3.4e38f;
    for (float y : parts_.y) lowest = y < lowest ? y : lowest;
    if (!(double(lowest) < floorY - bound)) return r;
  }
  const double maxSpeed2 = params_.maxSpeed * params_.maxSpeed;
  for (std::size_t b = 0; b < members_.size(); ++b) {
    const BodyMode m = mode_[b];
    if (m == BodyMode::kEmpty || m == BodyMode::kFixed) continue;
    const Motion& mo = motion_[b];
    const Mat3 R = mo.q.toRotationMatrix();
    const bool rigid = isRigid(b);
    for (std::int32_t i : members_[b]) {
      const auto k = std::size_t(i);
      Vec3 p, v;
      if (!rigid) {
        // Particle-level: mid-step, the predicted positions are the state.
        p = bodiesOnly ? Vec3(px_[k], py_[k], pz_[k]) : Vec3(parts_.x[k], parts_.y[k], parts_.z[k]);
        v = Vec3(parts_.vx[k], parts_.vy[k], parts_.vz[k]);
        if (pinnedAt(k)) v = Vec3::Zero();
      } else if (bodiesOnly) {
        const Vec3 r0 = R * Vec3(rx_[k], ry_[k], rz_[k]);
        p = r0 + mo.c;
        v = mo.v + mo.w.cross(r0);
      } else {
        if (!penetration) continue;  // the particle arrays passed checkParticles already
        p = Vec3(parts_.x[k], parts_.y[k], parts_.z[k]);
        v = Vec3::Zero();
      }
      const auto fill = [&](GuardKind kind, double value, double bnd, const char* hint) {
        r.kind = kind;
        r.particle = i;
        r.body = static_cast<std::int32_t>(b);
        r.stroke = parts_.stroke[k];
        r.value = value;
        r.bound = bnd;
        r.hint = hint;
      };
      if (!p.allFinite() || !v.allFinite()) {
        fill(GuardKind::kNaN, std::nan(""), 0.0,
             "A non-finite value usually comes from a degenerate constraint.");
        return r;
      }
      if (m != BodyMode::kDynamic || pinnedAt(k)) continue;  // the input moves it: only NaN is the solver's
      if (bodiesOnly && v.squaredNorm() > maxSpeed2) {
        fill(GuardKind::kExplosion, v.norm(), params_.maxSpeed,
             "Speed above the bound.");
        return r;
      }
      if (penetration && floorY - p.y() > bound) {
        fill(GuardKind::kPenetration, floorY - p.y(), bound,
             "Particle deep in the ground.");
        return r;
      }
    }
  }
  return r;
}

void PbdWorld::integrate(double h) {
  const Vec3 g = params_.gravity;
  forEach(active_.size(), [&](std::size_t k) {
    const auto b = std::size_t(active_[k]);
    Motion& mo = motion_[b];
    mo.cPrev = mo.c;
    mo.qPrev = mo.q;
    mo.v += h * g;
    // Free rotation keeps the angular momentum L = I w, not w: the gyroscopic term.
    const Mat3 R = mo.q.toRotationMatrix();
    mo.w = R * gyroscopicStep(inertiaRest_[b], R.transpose() * mo.w, h);
    mo.c += h * mo.v;
    mo.q = rotateBy(mo.q, h * mo.w);
  });
}

void PbdWorld::kinematic(int substep) {
  // Kinematic bodies move from their pose at the start of the step to their target,
  // linearly over the substeps, keeping their rotation.
  const double a = double(substep + 1) / params_.substeps;
  const double floorY = params_.groundY + params_.particleRadius;
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (mode_[b] != BodyMode::kKinematic) continue;
    Motion& mo = motion_[b];
    mo.cPrev = mo.c;
    mo.qPrev = mo.q;
    mo.c = mo.kinStart + a * (mo.kinTarget - mo.kinStart);
    if (!isRigid(b)) {
      kinematicParticles(b, mo.c - mo.cPrev);
      continue;
    }
    // The ground stops a carried body as it stops any other: a brush that dips below the
    // floor slides the body along it instead of pushing it through.
    const Mat3 R = mo.q.toRotationMatrix();
    double lowest = 1e300;
    for (std::int32_t i : members_[b]) {
      const auto k = std::size_t(i);
      lowest = std::min(lowest, (R * Vec3(rx_[k], ry_[k], rz_[k])).y());
    }
    if (mo.c.y() + lowest < floorY) {
      mo.c.y() = floorY - lowest;
      mo.kinTarget.y() = std::max(mo.kinTarget.y(), mo.c.y());
    }
  }
}

// Candidates for the ground: a body whose bounding sphere is above it has none (falling
// bodies cost one test here); otherwise its particles within a margin of the plane. The
// margin covers what the sweeps can bring down: one particle spacing, twice the deepest
// penetration now (a lift at the patch centroid can tilt the body by about that much at
// its far end) and the rotation over a substep, plus an allowance of kReuse that lets
// the next substeps reuse the list while the body has moved (rotation x reach + height
// change) less than half of it. A particle that still ends below is found by the next
// full scan.
void PbdWorld::findContacts() {
  // Per body, made when the pass first runs: a scene without dynamic rigid bodies holds none.
  if (groundCache_.size() < members_.size()) groundCache_.resize(members_.size());
  BodyPlaneContacts& bp = contacts_.bodyPlane;
  contacts_.clearFound();
  const double r = params_.particleRadius, h = params_.dt / params_.substeps;
  const double reuse = 4.0 * r;
  const Plane& ground = contacts_.planes[0];
  const double floorY = ground.offset + r;
  // Body pairs first: a pair may wake a sleeper, which joins active_ for the ground scan below.
  if (work_[std::size_t(PbdPass::kBodyContact)]) findBodyPairs();
  forEach(active_.size(), [&](std::size_t k) {
    const auto b = std::size_t(active_[k]);
    const Motion& mo = motion_[b];
    GroundCache& cache = groundCache_[b];
    if (mo.c.y() - reach_[b] > floorY + 2.0 * r) {
      cache.valid = false;
      return;
    }
    if (cache.valid) {
      const double turned = 2.0 * std::acos(std::min(1.0, std::abs(mo.q.dot(cache.q)))) * reach_[b];
      if (turned + std::abs(mo.c.y() - cache.cy) < 0.5 * reuse) return;
    }
    const Mat3 R = mo.q.toRotationMatrix();
    const auto& mem = members_[b];
    std::vector<double> ys(mem.size());
    double lowest = 1e300;
    for (std::size_t m = 0; m < ys.size(); ++m) {
      const auto i = std::size_t(mem[m]);
      ys[m] = R.row(1).dot(Vec3(rx_[i], ry_[i], rz_[i])) + mo.c.y();
      lowest = std::min(lowest, ys[m]);
    }
    const double margin = 2.0 * r + 2.0 * std::max(0.0, floorY - lowest) + mo.w.norm() * reach_[b] * h + reuse;
    cache.candidates.clear();
    for (std::size_t m = 0; m < ys.size(); ++m)
      if (ys[m] < floorY + margin) cache.candidates.push_back(mem[m]);
    cache.valid = true;
    cache.q = mo.q;
    cache.cy = mo.c.y();
  });
  for (std::size_t k = 0; k < active_.size(); ++k) {
    const GroundCache& cache = groundCache_[std::size_t(active_[k])];
    if (!cache.valid || cache.candidates.empty()) continue;
    bp.body.push_back(active_[k]);
    bp.plane.push_back(0);
    bp.first.push_back(static_cast<std::int32_t>(bp.candidates.size()));
    bp.count.push_back(static_cast<std::int32_t>(cache.candidates.size()));
    bp.touched.push_back(0);
    bp.point.push_back(Vec3::Zero());
    bp.approachSpeed.push_back(0.0);
    bp.normalImpulse.push_back(0.0);
    bp.candidates.insert(bp.candidates.end(), cache.candidates.begin(), cache.candidates.end());
  }
}

// Whether bodies a and b can touch within `horizon` seconds: one of them is dynamic, and
// their bounding spheres (reach plus one particle spacing), each grown by how far the body
// can travel in that time (speed, spin times reach, and gravity), overlap. The step decides
// whether body_contact runs with horizon dt, so a body that comes within reach during the
// step is not missed; find_contacts looks one substep ahead.
bool PbdWorld::mayTouch(std::size_t a, std::size_t b, double horizon) const {
  if (mode_[a] == BodyMode::kEmpty || mode_[b] == BodyMode::kEmpty) return false;
  // One of them moves: a dynamic body awake, or a carried one next to a sleeper it would wake.
  const auto carriedToSleeper = [&](std::size_t k, std::size_t o) {
    return mode_[k] == BodyMode::kKinematic && mode_[o] == BodyMode::kDynamic;
  };
  if (!moving(a) && !moving(b) && !carriedToSleeper(a, b) && !carriedToSleeper(b, a)) return false;
  // Particle-level bodies touch through particle_contact, but a fixed, carried or sleeping one moves only
  // as a whole (not at all, or translated by its stroke): to a rigid body it is a fixed or
  // carried body like any other, met at body level (holdShape: its particles are rigidPoint()'s).
  // Particle pairs never join a particle without inverse mass to a rigid body, so a block fell
  // through a fixed jelly slab and a carried jelly passed through a box; keeping those pairs made
  // a block landing on the slab take each pair's correction in turn and tumble.
  // A soft body, rope or cloth asleep is held the same way (sleepLoose).
  const auto bodyLevel = [&](std::size_t k) {
    return isRigid(k) || mode_[k] == BodyMode::kFixed || mode_[k] == BodyMode::kKinematic || asleep(int(k));
  };
  if (!bodyLevel(a) || !bodyLevel(b)) return false;
  const double g = params_.gravity.norm();
  const auto travel = [&](std::size_t k) {
    const Motion& m = motion_[k];
    // A held or carried body goes where its stroke takes it this step, whatever its v: what
    // is left of that path bounds it (a fast tool was missed by the once-per-step test and
    // passed through a box with body_contact off).
    if (mode_[k] == BodyMode::kKinematic) return (m.kinTarget - m.c).norm() + horizon * m.w.norm() * reach_[k];
    return horizon * (m.v.norm() + m.w.norm() * reach_[k] + g * horizon);
  };
  return (motion_[a].c - motion_[b].c).norm() <
         reach_[a] + reach_[b] + 2.0 * params_.particleRadius + travel(a) + travel(b);
}

// O(bodies^2) sphere tests: once per step, from work().
bool PbdWorld::bodiesMayTouch() const {
  for (std::size_t a = 0; a < members_.size(); ++a)
    for (std::size_t b = a + 1; b < members_.size(); ++b)
      if (mayTouch(a, b, params_.dt)) return true;
  return false;
}

// For every pair of bodies that may touch: the particle pairs (one of each body) closer
// than one spacing plus a margin. Each body pair keeps a list made with a NeighborGrid over
// the particles of each body within the other's reach, at the radius plus a skin of one
// spacing (PairCache); while the two bodies have moved less than the skin since, every pair
// now within the radius is on that list, and the substep only filters it (a pile at rest
// makes its lists once, not every substep). Pairs are in a fixed order (body pair, then
// (a's particle, b's particle) ascending) made from the positions now, whatever list they
// come from: the same for any thread count, and for a replayed step.
void PbdWorld::findBodyPairs(bool mayWake) {
  BodyPairContacts& pairs = contacts_.bodyPair;
  const double r = params_.particleRadius, margin = 2.0 * r, h = params_.dt / params_.substeps;
  const double skin = 2.0 * r;
  const float radius = static_cast<float>(2.0 * r + margin), r2 = radius * radius;
  const float cacheRadius = static_cast<float>(2.0 * r + margin + skin);
  // The body pairs that may touch this substep (sphere tests, cheap), then their particle
  // pairs, each body pair on its own (in parallel, in units of 8 pairs with their own grid
  // and scratch), concatenated in pair order: the list does not depend on the threads.
  std::vector<std::pair<std::int32_t, std::int32_t>> candidates;
  for (std::size_t a = 0; a < members_.size(); ++a)
    for (std::size_t b = a + 1; b < members_.size(); ++b)
      if (mayTouch(a, b, h)) candidates.emplace_back(static_cast<std::int32_t>(a), static_cast<std::int32_t>(b));
  ++usedClock_;
  std::vector<PairCache*> cache(candidates.size());
  for (std::size_t c = 0; c < candidates.size(); ++c) {
    PairCache& e = pairCache_[std::uint64_t(candidates[c].first) << 32 | std::uint64_t(candidates[c].second)];
    e.used = usedClock_;
    cache[c] = &e;
  }
  // How far any particle of body k can have moved since a list made at pose (c, q).
  const auto moved = [&](std::size_t k, const Vec3& c, const Quat& q) {
    const Motion& m = motion_[k];
    return (m.c - c).norm() + 2.0 * std::acos(std::min(1.0, std::abs(m.q.dot(q)))) * reach_[k];
  };
  std::vector<std::vector<std::int32_t>> found(candidates.size());  // per candidate: pa, pb interleaved
  forChunks(candidates.size(), 8, [&](std::size_t lo, std::size_t hi) {
    std::vector<float> x, y, z;
    std::vector<std::int32_t> id;
    std::vector<std::uint64_t> sorted;
    NeighborGrid grid;
    for (std::size_t c = lo; c < hi; ++c) {
      const auto a = std::size_t(candidates[c].first), b = std::size_t(candidates[c].second);
      PairCache& e = *cache[c];
      if (!e.valid || e.edits != bodyEdits_ || moved(a, e.ca, e.qa) + moved(b, e.cb, e.qb) >= skin) {
        x.clear(), y.clear(), z.clear(), id.clear();
        std::size_t na = 0;
        for (int side = 0; side < 2; ++side) {
          const std::size_t self = side ? b : a, other = side ? a : b;
          const Motion& m = motion_[self];
          const Mat3 R = m.q.toRotationMatrix();
          // A particle of this body within the radius of one of the other's now is within
          // reach + 3 r of its centre now, so within reach + 5 r when the list is made.
          const double within = reach_[other] + margin + 2.0 * skin;
          for (std::int32_t i : members_[self]) {
            const auto k = std::size_t(i);
            const Vec3 p = R * Vec3(rx_[k], ry_[k], rz_[k]) + m.c;
            if ((p - motion_[other].c).norm() > within) continue;
            x.push_back(float(p.x())), y.push_back(float(p.y())), z.push_back(float(p.z()));
            id.push_back(i);
          }
          if (side == 0) na = id.size();
        }
        sorted.clear();
        if (na > 0 && na < id.size()) {
          grid.build(x.data(), y.data(), z.data(), x.size(), cacheRadius);
          for (std::size_t k = 0; k < na; ++k)
            grid.forEachNeighbor(static_cast<std::int32_t>(k), cacheRadius, [&](std::int32_t j) {
              if (std::size_t(j) < na) return;  // a particle of the same body
              sorted.push_back(std::uint64_t(std::uint32_t(id[k])) << 32 | std::uint32_t(id[std::size_t(j)]));
            });
        }
        std::sort(sorted.begin(), sorted.end());
        e.pairs.clear();
        for (std::uint64_t key : sorted) {
          e.pairs.push_back(static_cast<std::int32_t>(key >> 32));
          e.pairs.push_back(static_cast<std::int32_t>(key & 0xffffffffu));
        }
        e.ca = motion_[a].c, e.qa = motion_[a].q, e.cb = motion_[b].c, e.qb = motion_[b].q;
        e.edits = bodyEdits_;
        e.valid = true;
      }
      // The listed pairs within the radius now, tested in b's rest frame: a's particle taken
      // there by the relative pose (float), against b's rest offset. The same test whichever
      // list the pair comes from.
      if (e.pairs.empty()) continue;
      const Motion &ma = motion_[a], &mb = motion_[b];
      const Mat3 RbT = mb.q.toRotationMatrix().transpose();
      const Eigen::Matrix3f Rab = (RbT * ma.q.toRotationMatrix()).cast<float>();
      const Eigen::Vector3f t = (RbT * (ma.c - mb.c)).cast<float>();
      std::vector<std::int32_t>& out = found[c];
      for (std::size_t k = 0; k < e.pairs.size(); k += 2) {
        const auto i = std::size_t(e.pairs[k]), j = std::size_t(e.pairs[k + 1]);
        const float xi = rx_[i], yi = ry_[i], zi = rz_[i];
        const float dx = ((Rab(0, 0) * xi + Rab(0, 1) * yi) + Rab(0, 2) * zi + t.x()) - rx_[j];
        const float dy = ((Rab(1, 0) * xi + Rab(1, 1) * yi) + Rab(1, 2) * zi + t.y()) - ry_[j];
        const float dz = ((Rab(2, 0) * xi + Rab(2, 1) * yi) + Rab(2, 2) * zi + t.z()) - rz_[j];
        if ((dx * dx + dy * dy) + dz * dz > r2) continue;
        out.push_back(e.pairs[k]);
        out.push_back(e.pairs[k + 1]);
      }
    }
  });
  // Lists no candidate asked for this substep go (a pair that parts and meets again starts afresh).
  for (auto it = pairCache_.begin(); it != pairCache_.end();)
    it = it->second.used == usedClock_ ? std::next(it) : pairCache_.erase(it);
  // A sleeper touched by a carried body, or by an awake one moving faster than four times the sleep
  // speed at the end of the last substep (v less this substep's gravity), wakes now, before the
  // pair is solved: it then takes its share of the impact. A body woken here has not moved yet
  // and wakes nothing itself this substep (what it does next wakes its neighbours).
  if (sleepAllowed_ && mayWake) {
    const double wakeSpeed = 4.0 * params_.sleepSpeed;
    const Vec3 gh = h * params_.gravity;
    std::vector<std::int32_t> woken;
    const auto wakes = [&](std::size_t k) {
      if (mode_[k] == BodyMode::kKinematic) return true;
      if (!moving(k) || std::find(woken.begin(), woken.end(), std::int32_t(k)) != woken.end()) return false;
      return pointSpeed(k, motion_[k].v - gh) > wakeSpeed;
    };
    // (A soft body, rope or cloth asleep wakes only between steps: wakeLooseSleepers.)
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      if (found[c].empty()) continue;
      const auto a = std::size_t(candidates[c].first), b = std::size_t(candidates[c].second);
      if (asleep(int(a)) && isRigid(a) && wakes(b)) wake(a), woken.push_back(std::int32_t(a));
      if (asleep(int(b)) && isRigid(b) && wakes(a)) wake(b), woken.push_back(std::int32_t(b));
    }
    if (!woken.empty()) {
      active_.insert(active_.end(), woken.begin(), woken.end());
      std::sort(active_.begin(), active_.end());
    }
  }
  for (std::size_t c = 0; c < candidates.size(); ++c) {
    const std::vector<std::int32_t>& f = found[c];
    if (f.empty()) continue;
    const std::size_t first = pairs.pa.size();
    for (std::size_t k = 0; k < f.size(); k += 2) {
      pairs.pa.push_back(f[k]);
      pairs.pb.push_back(f[k + 1]);
    }
    pairs.a.push_back(candidates[c].first);
    pairs.b.push_back(candidates[c].second);
    pairs.first.push_back(static_cast<std::int32_t>(first));
    pairs.count.push_back(static_cast<std::int32_t>(pairs.pa.size() - first));
  }
}

// Sleeping. Bodies fall asleep at the end of a step (after the guard passed it), wake in
// findBodyPairs when something moving touches them, and all wake on any outside change (a
// body added, cut, moved, set moving or held; colliders set).
bool PbdWorld::sleepPossible() const {
  // A touch at body level wakes a rigid sleeper (findBodyPairs), as does a particle-level one
  // (findNeighbors, touchedByLoose); a soft, rope or cloth sleeper wakes between steps
  // (wakeLooseSleepers, updateSleep). Colliders moving along keyframes do not look for sleepers,
  // so their scenes keep every body awake.
  if (colliders_)
    for (std::size_t c = 0; c < colliders_->size(); ++c)
      if (colliders_->moving(c)) return false;
  return true;
}

void PbdWorld::wake(std::size_t b) {
  const bool wasAsleep = asleep_[b] != 0;
  asleep_[b] = 0;
  stillFor_[b] = 0.0;
  Motion& mo = motion_[b];
  if (!isRigid(b)) {
    if (!wasAsleep) return;
    // A soft body, rope or cloth: its own rest offsets back (holdShape took the shape it slept
    // in), and its particles' inverse masses; it goes on from where it lies, at rest.
    const auto& mem = members_[b];
    const std::vector<float>& saved = sleepRest_[b];
    for (std::size_t k = 0; k < mem.size(); ++k) {
      const auto i = std::size_t(mem[k]);
      rx_[i] = saved[3 * k], ry_[i] = saved[3 * k + 1], rz_[i] = saved[3 * k + 2];
    }
    std::vector<float>().swap(sleepRest_[b]);
    reholdRestFrame(b, [&] { refreshMassProperties(b); });
    refreshInverseMasses(b);
    mo.q = mo.qPrev = Quat::Identity();
    mo.cPrev = mo.c;
    // What it is tied to (ropes' links to it or from it, distance constraints across bodies)
    // fell asleep with it and wakes with it. (A rigid body it fell asleep with wakes once their
    // particle pairs are found: touchedByLoose.)
    for (std::size_t o : tiePartners(b))
      if (asleep_[o]) wake(o);
    return;
  }
  stillRef_[b] = StillRef{mo.c, mo.q};
  mo.cPrev = mo.c;  // it joins the substep after integrate: no motion yet
  mo.qPrev = mo.q;
  groundCache_.resize(members_.size());
  groundCache_[b].valid = false;
}

// Whether particle-level body b may fall asleep: a dynamic soft body, rope or cloth awake (a
// fluid never sleeps), every rigid body it is attached to fixed.
bool PbdWorld::looseMaySleep(std::size_t b) const {
  if (isRigid(b) || !moving(b) || kind_[b] == MaterialKind::kFluid) return false;
  // (Attachments tie a strand to a rigid body; ties between particle-level bodies are distance
  // constraints, whose two bodies fall asleep together: updateSleep.)
  for (const Attachment& a : attachments_)
    if (parts_.group(std::size_t(a.particle)) == std::int32_t(b) && mode_[std::size_t(a.body)] != BodyMode::kFixed) return false;
  return true;
}

// Particle-level body b falls asleep: its particles at rest, without inverse mass (every pass
// then leaves them where they are, as a fixed body's), and held at body level against rigid
// bodies in the shape it lies in (holdShape, as setMode does for a fixed one); its own rest
// offsets are kept for its waking.
void PbdWorld::sleepLoose(std::size_t b) {
  const auto& mem = members_[b];
  sleepRest_.resize(members_.size());
  sleepBox_.resize(members_.size());
  std::vector<float>& saved = sleepRest_[b];
  saved.resize(3 * mem.size());
  Eigen::AlignedBox3d box;
  for (std::size_t k = 0; k < mem.size(); ++k) {
    const auto i = std::size_t(mem[k]);
    saved[3 * k] = rx_[i], saved[3 * k + 1] = ry_[i], saved[3 * k + 2] = rz_[i];
    parts_.vx[i] = parts_.vy[i] = parts_.vz[i] = 0.0f;
    box.extend(Vec3(parts_.x[i], parts_.y[i], parts_.z[i]));
  }
  sleepBox_[b] = box;
  asleep_[b] = 1;
  refreshInverseMasses(b);
  reholdRestFrame(b, [&] { holdShape(b); });
  motion_[b].v = motion_[b].w = Vec3::Zero();
}

// A sleeping or waking particle-level body's rest frame is remade (sleepLoose, wake): not an edit
// of the scene, so bodyEdits_ is left alone (it wakes everything, and cold-starts a fluid's warm
// start), and only the body-pair lists with this body in them are made afresh.
template <class Remake>
void PbdWorld::reholdRestFrame(std::size_t b, Remake&& remake) {
  const std::uint64_t edits = bodyEdits_;
  remake();
  bodyEdits_ = edits;
  for (auto it = pairCache_.begin(); it != pairCache_.end();)
    it = (it->first >> 32) == b || (it->first & 0xffffffffu) == b ? pairCache_.erase(it) : std::next(it);
}

const std::vector<std::pair<std::int32_t, std::int32_t>>& PbdWorld::crossTies() {
  if (crossTiesEdits_ == bodyEdits_ && crossTiesCount_ == distances_.size()) return crossTies_;
  crossTies_.clear();
  for (std::size_t k = 0; k < distances_.size(); ++k) {
    const std::int32_t gi = parts_.group(std::size_t(distances_.i[k])), gj = parts_.group(std::size_t(distances_.j[k]));
    if (gi != gj && gi >= 0 && gj >= 0) crossTies_.emplace_back(std::min(gi, gj), std::max(gi, gj));
  }
  std::sort(crossTies_.begin(), crossTies_.end());
  crossTies_.erase(std::unique(crossTies_.begin(), crossTies_.end()), crossTies_.end());
  crossTiesEdits_ = bodyEdits_;
  crossTiesCount_ = distances_.size();
  return crossTies_;
}

// The particle-level bodies body b is tied to by distance constraints across bodies (a rope's end
// linked to a soft body, rope or cloth: attachStrandEnds), in body order.
std::vector<std::size_t> PbdWorld::tiePartners(std::size_t b) {
  std::vector<std::size_t> out;
  for (const auto& [l, r] : crossTies()) {
    if (std::size_t(l) == b) out.push_back(std::size_t(r));
    if (std::size_t(r) == b) out.push_back(std::size_t(l));
  }
  std::sort(out.begin(), out.end());
  return out;
}

// At the start of a step, before its plan is made: a soft body, rope or cloth asleep wakes when
// something moving faster than four times the sleep speed may reach it within the step — a
// carried body whose path comes within reach, an awake rigid body whose bounding sphere, grown
// by how far it can travel in dt, reaches the sleeper's box, or an awake particle-level particle
// whose own travel does — so that it takes the blow as the soft body it is. (Waking one within
// the step would change the passes a step runs midway; a rigid sleeper is woken there, by the
// contact itself.) Serial, in body order: the same for any thread count.
void PbdWorld::wakeLooseSleepers() {
  std::vector<std::size_t> sleepers;
  for (std::size_t b = 0; b < asleep_.size(); ++b)
    if (asleep_[b] && !isRigid(b)) sleepers.push_back(b);
  if (sleepers.empty()) return;
  const double dt = params_.dt, g = params_.gravity.norm();
  const double wakeSpeed = 4.0 * params_.sleepSpeed;
  const double near = 2.0 * largestContactRadius() + params_.particleRadius;  // touching, and half a spacing
  // Per awake particle-level body: the box of its particles faster than the wake speed, grown by
  // the farthest one of them travels in dt.
  std::vector<Eigen::AlignedBox3d> fast(members_.size());
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (isRigid(b) || !moving(b)) continue;
    double vmax = 0.0;
    for (std::int32_t i : members_[b]) {
      const auto k = std::size_t(i);
      const double s = Vec3(parts_.vx[k], parts_.vy[k], parts_.vz[k]).norm();
      if (!(s > wakeSpeed)) continue;
      fast[b].extend(Vec3(parts_.x[k], parts_.y[k], parts_.z[k]));
      vmax = std::max(vmax, s);
    }
    if (fast[b].isEmpty()) continue;
    fast[b].min().array() -= vmax * dt + g * dt * dt;
    fast[b].max().array() += vmax * dt + g * dt * dt;
  }
  for (std::size_t s : sleepers) {
    Eigen::AlignedBox3d box = sleepBox_[s];
    box.min().array() -= near;
    box.max().array() += near;
    bool wakes = false;
    if (s < sleepPartners_.size())
      for (std::int32_t r : sleepPartners_[s]) wakes = wakes || moving(std::size_t(r));
    for (std::size_t o = 0; o < members_.size() && !wakes; ++o) {
      if (o == s || mode_[o] == BodyMode::kEmpty) continue;
      const Motion& m = motion_[o];
      if (mode_[o] == BodyMode::kKinematic) {
        wakes = box.exteriorDistance(m.c) < reach_[o] + (m.kinTarget - m.c).norm();
      } else if (isRigid(o) && moving(o)) {
        wakes = pointSpeed(o, m.v) > wakeSpeed &&
                box.exteriorDistance(m.c) < reach_[o] + dt * (m.v.norm() + m.w.norm() * reach_[o] + g * dt);
      } else if (!isRigid(o) && moving(o) && !fast[o].isEmpty() && fast[o].intersects(box)) {
        for (std::int32_t i : members_[o]) {
          const auto k = std::size_t(i);
          const double v = Vec3(parts_.vx[k], parts_.vy[k], parts_.vz[k]).norm();
          if (v > wakeSpeed && box.exteriorDistance(Vec3(parts_.x[k], parts_.y[k], parts_.z[k])) < v * dt + g * dt * dt) {
            wakes = true;
            break;
          }
        }
      }
    }
    if (wakes) wake(s);
  }
}

void PbdWorld::touchedByLoose(std::size_t b) {
  looseTouch_[b] = 1;
  if (!asleep(int(b))) return;
  wake(b);
  const auto id = std::int32_t(b);
  active_.insert(std::upper_bound(active_.begin(), active_.end(), id), id);
}

void PbdWorld::wakeAll() {
  stillRef_.resize(asleep_.size());
  for (std::size_t b = 0; b < asleep_.size(); ++b)
    if (asleep_[b]) wake(b);
  std::fill(stillFor_.begin(), stillFor_.end(), 0.0);
}

long PbdWorld::sleepingCount() const { return static_cast<long>(std::count(asleep_.begin(), asleep_.end(), char(1))); }

// Once per step, after it passed the guard. Each awake dynamic rigid body is still while every
// point of it stays within D = sleepSpeed x sleepTime of where it was when its still time began
// (the centre's displacement plus the turn times the reach); a body that leaves that ball starts
// again from where it is now. By displacement, not speed: a body in a resting pile that jitters
// in place (a tenth of a millimetre per substep, speeds that flick to 2-4 cm/s) sleeps, a body
// creeping steadily at the sleep speed does not. A body still for the sleep time falls asleep
// unless it touches a carried body (the last substep's body pairs), which would wake it again at
// once. It may fall asleep next to an awake body: a sleeper that an awake body touches wakes when
// that body leaves its ball (a support sliding away slowly, a neighbour tipping over) or touches
// it faster than four times the sleep speed (findBodyPairs), so the sleeper lags what moves it by
// at most the ball. Waiting instead for every neighbour to be still (islands, as Box2D does) let
// bench_pile's 200 boxes, whose jitter moves from box to box, all sleep only after 5.75 s
// against 2.67 s: a sleeper is a firm support and calms the jitter of what rests on it. Soft
// bodies, ropes and cloths the same way, particle by particle (below), with three differences:
// fluid or a carried body touching one keeps it awake (and fluid coming to touch a sleeper wakes
// it), one falls asleep only together with the rigid bodies and the particle-level bodies tied to
// it that it touches, and one sleeping is woken by something moving only between steps
// (wakeLooseSleepers). In body and pair order: the same for any thread count.
void PbdWorld::updateSleep() {
  if (!sleepAllowed_) return;
  const std::size_t n = members_.size();
  const double ball = params_.sleepSpeed * params_.sleepTime;
  std::vector<char> ready(n, 0), restless(n, 0);
  for (std::size_t b = 0; b < n; ++b) {
    if (!moving(b) || !isRigid(b)) continue;
    const Motion& mo = motion_[b];
    StillRef& ref = stillRef_[b];
    const double turn = 2.0 * std::acos(std::min(1.0, std::abs(mo.q.dot(ref.q))));
    if (stillFor_[b] == 0.0 || (mo.c - ref.c).norm() + turn * reach_[b] > ball) {
      restless[b] = stillFor_[b] > 0.0;
      ref = StillRef{mo.c, mo.q};
      stillFor_[b] = 0.0;
    }
    stillFor_[b] += params_.dt;
    // Still time is a sum of dt: compared with half a step to spare against round-off.
    ready[b] = stillFor_[b] >= params_.sleepTime - 0.5 * params_.dt;
  }
  // Soft bodies, ropes and cloths by the same ball, particle by particle (a jelly wobbling in
  // place sleeps, one creeping or sagging does not); also those that may not sleep (a rope tied
  // to a dynamic body), whose leaving the ball wakes a sleeper they touch.
  const std::size_t np = parts_.size();
  if (stillX_.size() < np) stillX_.resize(np), stillY_.resize(np), stillZ_.resize(np);
  const auto ball2 = static_cast<float>(ball * ball);
  for (std::size_t b = 0; b < n; ++b) {
    if (isRigid(b) || !moving(b) || kind_[b] == MaterialKind::kFluid) continue;
    const auto& mem = members_[b];
    bool left = stillFor_[b] == 0.0;
    for (std::size_t k = 0; k < mem.size() && !left; ++k) {
      const auto i = std::size_t(mem[k]);
      const float dx = parts_.x[i] - stillX_[i], dy = parts_.y[i] - stillY_[i], dz = parts_.z[i] - stillZ_[i];
      left = !((dx * dx + dy * dy) + dz * dz <= ball2);
    }
    if (left) {
      restless[b] = stillFor_[b] > 0.0;
      for (std::int32_t i : mem) {
        const auto k = std::size_t(i);
        stillX_[k] = parts_.x[k], stillY_[k] = parts_.y[k], stillZ_[k] = parts_.z[k];
      }
      stillFor_[b] = 0.0;
    }
    stillFor_[b] += params_.dt;
    ready[b] = looseMaySleep(b) && stillFor_[b] >= params_.sleepTime - 0.5 * params_.dt;
  }
  const BodyPairContacts& pairs = contacts_.bodyPair;
  std::vector<char> held(n, 0);  // touches a carried body (or, for a soft body, rope or cloth, fluid)
  for (std::size_t c = 0; c < pairs.size(); ++c) {
    const auto a = std::size_t(pairs.a[c]), b = std::size_t(pairs.b[c]);
    if (mode_[b] == BodyMode::kKinematic) held[a] = 1;
    if (mode_[a] == BodyMode::kKinematic) held[b] = 1;
    if (asleep_[a] && restless[b]) wake(a);
    if (asleep_[b] && restless[a]) wake(b);
  }
  // The last substep's particle pairs: a particle-level body touching a carried body or a fluid
  // stays awake (fluid never sleeps, and a body it holds up would no longer float), and a sleeper
  // that fluid comes to touch, or an awake soft body, rope or cloth that left its ball, wakes.
  // Pairs joining a particle-level body to a dynamic rigid one are kept as links (below), as are
  // ties across particle-level bodies (distance constraints: a rope linked to a jelly).
  const ParticlePairContacts& pp = contacts_.particlePair;
  std::vector<std::pair<std::int32_t, std::int32_t>> links;  // (particle-level body, other body)
  for (std::size_t c = 0; c < pp.size(); ++c) {
    const auto i = std::size_t(pp.i[c]), j = std::size_t(pp.j[c]);
    const auto bi = std::size_t(parts_.group(i)), bj = std::size_t(parts_.group(j));
    const bool fluidI = phase::has(parts_.phase[i], phase::kFluid), fluidJ = phase::has(parts_.phase[j], phase::kFluid);
    if (mode_[bj] == BodyMode::kKinematic || fluidJ) held[bi] = 1;
    if (mode_[bi] == BodyMode::kKinematic || fluidI) held[bj] = 1;
    if (asleep_[bi] && (restless[bj] || fluidJ)) wake(bi);
    if (asleep_[bj] && (restless[bi] || fluidI)) wake(bj);
    if (isRigid(bj) && mode_[bj] == BodyMode::kDynamic) links.emplace_back(std::int32_t(bi), std::int32_t(bj));
  }
  const auto& ties = crossTies();
  links.insert(links.end(), ties.begin(), ties.end());
  std::sort(links.begin(), links.end());
  links.erase(std::unique(links.begin(), links.end()), links.end());
  // Who falls asleep now: every body ready and not held, except a rigid body a rope or cloth is
  // tied to, or one particle-level material touched this step but not in its last substep (it
  // may come back). A soft body, rope or cloth and a rigid body it touches fall asleep only
  // together, both ready: a box on a jelly asleep meets it at body level, at the contact distance,
  // where the particle pairs let it sink in (2 mm under the box of scenes/jelly.scene, which
  // popped up by that much when the jelly slept first); so do two particle-level bodies tied
  // together. Links whose two ends disagree take both out, until none do. A particle-level body
  // keeps the rigid bodies it fell asleep with (sleepPartners_): one of them woken wakes it
  // (wakeLooseSleepers), before the body-level contact would lift it by the depth the pairs
  // allowed.
  std::vector<char> falls(n, 0), tied(n, 0), linked(n, 0);
  for (const Attachment& a : attachments_) tied[std::size_t(a.body)] = 1;
  for (const auto& l : links) linked[std::size_t(l.second)] = 1;
  for (std::size_t b = 0; b < n; ++b) {
    const bool touched = b < looseTouch_.size() && looseTouch_[b];
    falls[b] = ready[b] && !held[b] && !(isRigid(b) && (tied[b] || (touched && !linked[b])));
  }
  for (bool changed = true; changed;) {
    changed = false;
    for (const auto& [l, r] : links)
      if (falls[std::size_t(l)] != falls[std::size_t(r)]) falls[std::size_t(l)] = falls[std::size_t(r)] = 0, changed = true;
  }
  sleepPartners_.resize(n);
  for (std::size_t b = 0; b < n; ++b) {
    if (!falls[b]) continue;
    if (!isRigid(b)) {
      sleepPartners_[b].clear();
      for (const auto& [l, r] : links)
        if (std::size_t(l) == b && isRigid(std::size_t(r))) sleepPartners_[b].push_back(r);
      sleepLoose(b);
      continue;
    }
    asleep_[b] = 1;
    Motion& mo = motion_[b];
    mo.v = mo.w = Vec3::Zero();
    for (std::int32_t i : members_[b]) {
      const auto k = std::size_t(i);
      parts_.vx[k] = parts_.vy[k] = parts_.vz[k] = 0.0f;
    }
  }
}

const BodyPairContacts& PbdWorld::bodyPairsNow() {
  contacts_.bodyPair.clear();
  findBodyPairs(/*mayWake=*/false);  // a look, not a step: wakes nobody
  return contacts_.bodyPair;
}

// Body against body (Müller et al. 2020, positional constraints between two bodies, at
// body level as for the ground): per pair and sweep, the touching particle pairs (closer
// than one spacing) form a patch; one correction of the patch's deepest overlap along its
// depth-weighted normal at its depth-weighted centre, split between the two bodies by
// their generalized inverse masses (a fixed or carried body has none), then Coulomb
// friction on impulses with the mean of the two bodies' coefficients. Pairs are swept colour
// by colour (Gauss-Seidel; a colour's pairs share no dynamic body and run in parallel), so
// the result does not depend on threads.
namespace {
struct TouchingPair {
  double depth;
  Vec3 mid, start;  // the pair's midpoint now, its direction at the substep's start
};
}  // namespace

void PbdWorld::bodyContact() {
  const BodyPairContacts& pairs = contacts_.bodyPair;
  const double touch = 2.0 * params_.particleRadius;
  const bool bounce = work_[std::size_t(PbdPass::kRestitution)];
  pairHits_.clear();
  bodyTouches_.clear();
  // Graph colouring: pairs of one colour share no dynamic body, so they are solved in
  // parallel, colour after colour (Gauss-Seidel across colours, Jacobi-free within: each
  // pair reads and writes only its own two bodies). Greedy in pair order: the colours
  // depend on the pairs alone, never on the threads. Past 64 colours, the rest serially.
  const std::size_t npairs = pairs.size();
  std::vector<std::vector<std::int32_t>> colours;
  std::vector<std::int32_t> serial;
  {
    std::vector<std::uint64_t> used(members_.size(), 0);
    for (std::size_t c = 0; c < npairs; ++c) {
      const auto a = std::size_t(pairs.a[c]), b = std::size_t(pairs.b[c]);
      const bool da = moving(a), db = moving(b);
      const std::uint64_t taken = (da ? used[a] : 0) | (db ? used[b] : 0);
      if (~taken == 0) {
        serial.push_back(static_cast<std::int32_t>(c));
        continue;
      }
      int k = 0;
      while (taken & (std::uint64_t(1) << k)) ++k;
      if (std::size_t(k) >= colours.size()) colours.resize(std::size_t(k) + 1);
      colours[std::size_t(k)].push_back(static_cast<std::int32_t>(c));
      if (da) used[a] |= std::uint64_t(1) << k;
      if (db) used[b] |= std::uint64_t(1) << k;
    }
  }
  std::vector<PairHit> hits(bounce ? npairs : 0);
  std::vector<char> hit(bounce ? npairs : 0, 0);
  std::vector<char> pairTouches(npairs, 0);
  std::vector<Vec3> touchNormal(bounce ? npairs : 0, Vec3::Zero());  // the first touch's normal, from b towards a
  // Each pair's normal corrections this substep, summed (kg m), and its friction corrections,
  // summed as vectors (on body a): opposite corrections of successive sweeps cancel.
  std::vector<double> pairNormal(npairs, 0.0);
  std::vector<Vec3> pairFriction(npairs, Vec3::Zero());
  // The largest friction correction along unit u (at most `stop`) that keeps the pair's summed
  // friction within mu_s (static), else mu_k, times its summed normal correction.
  const auto within = [&](std::size_t c, const Vec3& u, double stop, double mus, double muk) {
    const Vec3& f = pairFriction[c];
    const double cap = mus * pairNormal[c];
    if ((f + stop * u).squaredNorm() <= cap * cap) return stop;
    const double kin = muk * pairNormal[c], fu = f.dot(u), disc = fu * fu - f.squaredNorm() + kin * kin;
    return disc < 0.0 ? 0.0 : std::clamp(-fu + std::sqrt(disc), 0.0, stop);
  };
  // `frozenA`/`frozenB`: the shock-propagation sweep below holds the lower body still.
  const auto solve = [&](std::size_t c, int it, bool frozenA, bool frozenB) {
      const auto a = std::size_t(pairs.a[c]), b = std::size_t(pairs.b[c]);
      Motion &ma = motion_[a], &mb = motion_[b];
      const bool da = moving(a) && !frozenA, db = moving(b) && !frozenB;
      RigidPose pa{ma.c, ma.q, invMass_[a], invInertiaRest_[a]}, pb{mb.c, mb.q, invMass_[b], invInertiaRest_[b]};
      const Mat3 Ra = pa.q.toRotationMatrix(), Rb = pb.q.toRotationMatrix();
      const Mat3 RaPrev = ma.qPrev.toRotationMatrix(), RbPrev = mb.qPrev.toRotationMatrix();
      // Each particle pair's normal is its direction at the start of the substep, and its
      // depth is how far it is inside `touch` along that normal now. Within a substep a
      // body can move more than a spacing (a fast tool: 1.2 spacings per substep at 15 m/s
      // and 32 substeps) and end interleaved with the other's particles, where the current
      // directions point every way; the start directions still say which side each
      // particle came from, and the depth along a fixed normal shrinks as the correction
      // moves the bodies apart, so the sweeps converge instead of pushing the full depth
      // again each sweep (which threw a box off at twice the tool's speed).
      double wsum = 0.0;
      Vec3 psum = Vec3::Zero(), nsum = Vec3::Zero(), ssum = Vec3::Zero();
      const std::int32_t k0 = pairs.first[c], k1 = pairs.first[c] + pairs.count[c];
      const auto pairDepth = [&](std::int32_t k, Vec3& pi, Vec3& pj, Vec3& slide, Vec3& nk) {
        const auto i = std::size_t(pairs.pa[std::size_t(k)]), j = std::size_t(pairs.pb[std::size_t(k)]);
        const Vec3 ri(rx_[i], ry_[i], rz_[i]), rj(rx_[j], ry_[j], rz_[j]);
        pi = Ra * ri + pa.c, pj = Rb * rj + pb.c;
        const Vec3 start = (RaPrev * ri + ma.cPrev) - (RbPrev * rj + mb.cPrev);
        slide = (pi - pj) - start;  // the pair's relative motion over this substep
        const double len = start.norm();
        if (len == 0.0) return 0.0;
        nk = start / len;
        return touch - nk.dot(pi - pj);
      };
      // The touching pairs (depth, midpoint, start direction), kept for the two loops below:
      // evaluating the pairs once instead of three times halved body_contact (bench_pile).
      thread_local std::vector<TouchingPair> touchingPairs;
      touchingPairs.clear();
      for (std::int32_t k = k0; k < k1; ++k) {
        Vec3 pi, pj, motion, nk;
        const double d = pairDepth(k, pi, pj, motion, nk);
        if (d <= 0.0) continue;
        wsum += d;
        psum += d * 0.5 * (pi + pj);
        nsum += d * nk;
        ssum += d * motion;
        touchingPairs.push_back({d, 0.5 * (pi + pj), nk});
      }
      if (wsum == 0.0 || nsum.norm() == 0.0) return;
      Vec3 n = nsum.normalized();  // from b towards a
      // A flat patch (face on face) takes its normal from the plane through its pair
      // midpoints, not from the pair directions: those tilt by offset / spacing where the
      // two lattices do not line up (a particle face is bumpy), which pushed aligned boxes
      // sideways off each other like balls stacked on balls.
      bool flat = false;
      {
        const Vec3 pc0 = psum / wsum;
        Mat3 cov = Mat3::Zero();
        int touching = 0;
        for (const TouchingPair& t : touchingPairs) {
          const Vec3 m = t.mid - pc0;
          cov += t.depth * m * m.transpose();
          ++touching;
        }
        const Eigen::SelfAdjointEigenSolver<Mat3> eig(cov / wsum);
        const Vec3 ev = eig.eigenvalues();  // ascending
        // Flat: at least 3 x 3 touching pairs spread over the plane (the middle variance of
        // a patch three particles wide, (2/3) touch^2, is above touch^2 / 8) and thin across
        // it (a tenth of that).
        flat = touching >= 9 && ev(1) > 0.125 * touch * touch && ev(0) < 0.1 * ev(1);
        if (flat) n = eig.eigenvectors().col(0).dot(n) < 0.0 ? Vec3(-eig.eigenvectors().col(0)) : Vec3(eig.eigenvectors().col(0));
      }
      // The patch's depth along n: each pair's depth times how much of it moving along n
      // resolves.
      double dmax = 0.0;
      for (const TouchingPair& t : touchingPairs) dmax = std::max(dmax, t.depth * t.start.dot(n));
      if (dmax <= 0.0) return;
      pairTouches[c] = 1;
      if (bounce && touchNormal[c].isZero()) touchNormal[c] = n;
      const Vec3 pc = psum / wsum;
      const double wa = da ? generalizedInverseMass(pa, pc, n) : 0.0, wb = db ? generalizedInverseMass(pb, pc, n) : 0.0;
      if (wa + wb <= 0.0) return;
      const double lambdaN = dmax / (wa + wb);
      pairNormal[c] += lambdaN;
      // For restitution: the pair's contact, and its normal speed before the solve (the
      // velocities are the substep's predicted ones until update).
      if (bounce && it == 0 && restitution_[a] + restitution_[b] > 0.0) {
        const Vec3 va = ma.v + ma.w.cross(pc - ma.c), vb = mb.v + mb.w.cross(pc - mb.c);
        hits[c] = {pairs.a[c], pairs.b[c], pc, n, n.dot(va - vb)};
        hit[c] = 1;
      }
      // The contact point as a point of each body, to follow it through the normal correction.
      const Vec3 localA = pa.q.conjugate() * (pc - pa.c), localB = pb.q.conjugate() * (pc - pb.c);
      if (da) applyPointCorrection(pa, pc, n, lambdaN * wa);
      if (db) applyPointCorrection(pb, pc, -n, lambdaN * wb);
      // The shock-propagation sweep, on a flat patch: friction holds the upper body's centre
      // where the frozen lower body carried it over the substep (its motion seen in the lower
      // body's frame, less the part along n), a shift of the centre alone. Measured at the patch
      // centroid and applied there with its torque, as for a small patch, the top boxes of a
      // 10-box stack rocked and walked 2-16 mm within 10 s; the slip at the centroid includes the
      // turns that the normal corrections make about an off-centre patch, which this leaves alone.
      // Only for a body resting on top (a patch facing up within 60 degrees): a tool pushing
      // a box's side keeps the torque of its friction.
      const double g = params_.gravity.norm();
      if (flat && (frozenA || frozenB) && (da || db) && g > 0.0 && (da ? n : Vec3(-n)).dot(params_.gravity) < -0.5 * g) {
        RigidPose& up = da ? pa : pb;
        const Motion& mu = da ? ma : mb;
        const Motion& ml = da ? mb : ma;
        const Vec3 carried = ml.q * (ml.qPrev.conjugate() * (mu.cPrev - ml.cPrev)) + ml.c;
        Vec3 slip = up.c - carried;
        slip -= n.dot(slip) * n;
        const double len = slip.norm();
        if (len > 0.0) {
          double mus = 0.0, muk = 0.0;
          bodyPairFriction(a, b, mus, muk);
          const Vec3 onA = (da ? -1.0 : 1.0) * slip / len;  // the correction's direction on a
          const double lambdaT = within(c, onA, len / up.invMass, mus, muk);
          pairFriction[c] += lambdaT * onA;
          up.c -= (lambdaT * up.invMass / len) * slip;
        }
        if (da) ma.c = pa.c, ma.q = pa.q;
        if (db) mb.c = pb.c, mb.q = pb.q;
        return;
      }
      // The normal correction turns the bodies about their centres, which slides the contact
      // point of one over the other (by the turn times the centre's height above the patch);
      // friction must undo that slide too, as rigid_contact does against the ground. Left
      // out, a stack's tilt corrections became sideways slips that fed a growing
      // tilt-and-slide mode, and a 10-box stack fell after 2 s from round-off.
      const Vec3 slipA = (pa.q * localA + pa.c) - pc, slipB = (pb.q * localB + pb.c) - pc;
      Vec3 slide = ssum / wsum + (slipA - slipB);
      slide -= n.dot(slide) * n;
      const double len = slide.norm();
      if (len > 0.0) {
        const Vec3 t = -slide / len;  // against a's motion relative to b
        // (stacked: a flat patch between two dynamic bodies; see the friction below)
        const bool stacked = flat && da && db;
        const double wta = !da ? 0.0 : stacked ? pa.invMass : generalizedInverseMass(pa, pc, t);
        const double wtb = !db ? 0.0 : stacked ? pb.invMass : generalizedInverseMass(pb, pc, t);
        double mus = 0.0, muk = 0.0;
        bodyPairFriction(a, b, mus, muk);
        if (wta + wtb > 0.0) {
          // The shock-propagation sweep (it == iterations) finds the depth mostly resolved:
          // its friction may use what the pair's whole normal impulse of the substep allows
          // beyond the friction already applied (`within`), or the sideways slip the
          // iterations left would stay in the poses, substep after substep. The budget is
          // what keeps a tool's friction its own: with the whole budget at every repeat, a
          // tool dragged a box with mu 0.5 as far as with mu 2 (RuntimeTool test).
          const double stop = len / (wta + wtb);
          const double lambdaT = it < params_.iterations ? coulomb(stop, lambdaN, mus, muk) : within(c, t, stop, mus, muk);
          pairFriction[c] += lambdaT * t;
          // On a flat patch friction acts through the bodies' centres: its torque about the
          // centre is taken by the pressure across the face, which one normal correction at
          // the patch centroid cannot represent (it answers only once the body has tilted).
          // Applied at the centroid it turned each tilt correction into a rocking that grew
          // from round-off, x13 every 4 frames, until a stack of 3 boxes fell (measured).
          // A small patch (a corner, an edge, a ball) keeps the torque: that is what rolls a
          // ball; so does a patch against a fixed or carried body (a tool pushing a box low
          // on its side must tip it, not press it into the ground).
          const Vec3 atA = stacked ? pa.c : pc, atB = stacked ? pb.c : pc;
          if (da && lambdaT > 0.0) applyPointCorrection(pa, atA, t, lambdaT * wta);
          if (db && lambdaT > 0.0) applyPointCorrection(pb, atB, -t, lambdaT * wtb);
        }
      }
      if (da) ma.c = pa.c, ma.q = pa.q;
      if (db) mb.c = pb.c, mb.q = pb.q;
  };
  for (int it = 0; it < params_.iterations; ++it) {
    for (const auto& colour : colours)
      forEach(colour.size(), [&](std::size_t k) { solve(std::size_t(colour[k]), it, false, false); });
    for (std::int32_t c : serial) solve(std::size_t(c), it, false, false);
  }
  for (std::size_t c = 0; c < hit.size(); ++c)
    if (hit[c]) pairHits_.push_back(hits[c]);
  for (std::size_t c = 0; c < touchNormal.size(); ++c) {
    if (!pairTouches[c]) continue;
    const auto a = std::size_t(pairs.a[c]), b = std::size_t(pairs.b[c]);
    if (mode_[a] == BodyMode::kDynamic) bodyTouches_.push_back({pairs.a[c], pairs.b[c], touchNormal[c]});
    if (mode_[b] == BodyMode::kDynamic) bodyTouches_.push_back({pairs.b[c], pairs.a[c], -touchNormal[c]});
  }
  groundLastWord();
  shockPropagation(pairTouches, [&](std::size_t c, bool frozenA, bool frozenB) {
    solve(c, params_.iterations, frozenA, frozenB);
  });
}

// Shock propagation (Guendelman, Bridson & Fedkiw 2003 §7): one last sweep over the touching
// pairs from the ground up, each body held still once its level is done (the flat-patch
// friction of that sweep: in bodyContact's solve). A body's level is
// its distance in touching pairs from the ground or a fixed or carried body (those are level
// 0; bodies reached from none are left out). Level by level, the pairs whose upper body is on
// that level are solved with the lower body frozen: the upper body alone takes the whole
// correction and, through static friction, the lower body's whole motion over the substep.
// Without it, the ground (rigid_contact, then groundLastWord) turned back a lower box that a
// load set off its centre had tilted, without the box on top, which friction had carried
// along: offset stacks crept off and fell (2 cm/s measured), while the same box stood still
// on a fixed box. Pairs within one level are solved normally, level-0 pairs not at all (the
// iterations did, and the ground keeps the last word). Serial, in level then pair order:
// deterministic.
template <typename Solve>
void PbdWorld::shockPropagation(const std::vector<char>& touching, Solve&& solve) {
  const BodyPairContacts& pairs = contacts_.bodyPair;
  const std::size_t nb = members_.size(), npairs = pairs.size();
  constexpr int kUnreached = std::numeric_limits<int>::max();
  std::vector<int>& level = shockLevel_;
  level.assign(nb, kUnreached);
  std::vector<std::int32_t>& queue = shockQueue_;
  queue.clear();
  const auto reach = [&](std::size_t b, int l) {
    if (level[b] != kUnreached) return;
    level[b] = l;
    queue.push_back(static_cast<std::int32_t>(b));
  };
  for (std::size_t c = 0; c < contacts_.bodyPlane.size(); ++c) reach(std::size_t(contacts_.bodyPlane.body[c]), 0);
  for (std::size_t c = 0; c < npairs; ++c) {
    if (!touching[c]) continue;
    if (!moving(std::size_t(pairs.a[c]))) reach(std::size_t(pairs.a[c]), 0);
    if (!moving(std::size_t(pairs.b[c]))) reach(std::size_t(pairs.b[c]), 0);
  }
  if (queue.empty()) return;
  // Breadth first over the touching pairs (adjacency in pair order).
  std::vector<std::int32_t>& first = shockFirst_;
  std::vector<std::int32_t>& next = shockNext_;
  first.assign(nb + 1, 0);
  for (std::size_t c = 0; c < npairs; ++c)
    if (touching[c]) ++first[std::size_t(pairs.a[c]) + 1], ++first[std::size_t(pairs.b[c]) + 1];
  for (std::size_t b = 0; b < nb; ++b) first[b + 1] += first[b];
  next.assign(std::size_t(first[nb]), 0);
  {
    std::vector<std::int32_t> fill(first.begin(), first.end() - 1);
    for (std::size_t c = 0; c < npairs; ++c)
      if (touching[c]) {
        next[std::size_t(fill[std::size_t(pairs.a[c])]++)] = static_cast<std::int32_t>(c);
        next[std::size_t(fill[std::size_t(pairs.b[c])]++)] = static_cast<std::int32_t>(c);
      }
  }
  for (std::size_t q = 0; q < queue.size(); ++q) {
    const auto b = std::size_t(queue[q]);
    for (std::int32_t k = first[b]; k < first[b + 1]; ++k) {
      const auto c = std::size_t(next[std::size_t(k)]);
      const auto o = std::size_t(pairs.a[c]) == b ? std::size_t(pairs.b[c]) : std::size_t(pairs.a[c]);
      reach(o, level[b] + 1);
    }
  }
  // Pairs by the level of their upper body, then in pair order (a stable counting sort).
  const int top = level[std::size_t(queue.back())];
  std::vector<std::int32_t>& order = shockOrder_;
  std::vector<std::int32_t> start(std::size_t(top) + 2, 0);
  const auto upper = [&](std::size_t c) {
    const int la = level[std::size_t(pairs.a[c])], lb = level[std::size_t(pairs.b[c])];
    return (la == kUnreached || lb == kUnreached) ? 0 : std::max(la, lb);
  };
  for (std::size_t c = 0; c < npairs; ++c)
    if (touching[c] && upper(c) > 0) ++start[std::size_t(upper(c)) + 1];
  for (int l = 0; l <= top; ++l) start[std::size_t(l) + 1] += start[std::size_t(l)];
  order.assign(std::size_t(start[std::size_t(top) + 1]), 0);
  for (std::size_t c = 0; c < npairs; ++c)
    if (touching[c] && upper(c) > 0) order[std::size_t(start[std::size_t(upper(c))]++)] = static_cast<std::int32_t>(c);
  // Each pair is solved `iterations` times in a row (its normal and friction corrections
  // settle together; one solve let a zigzag stack of four fall). Serially: solving a level's
  // pairs in parallel colours (tried before the flat-patch friction: bench_pile 1.3x faster)
  // changed the order enough to change the landing pile of
  // APileLandingOnItsBottomLayerDoesNotPressItIntoTheGround (0.62 m/s after 2 s; pair order
  // 0.1 m/s, in a pile that then still twitched).
  for (std::int32_t c : order) {
    const int la = level[std::size_t(pairs.a[std::size_t(c)])], lb = level[std::size_t(pairs.b[std::size_t(c)])];
    for (int it = 0; it < params_.iterations; ++it) solve(std::size_t(c), la < lb, lb < la);
  }
}

namespace {

// Friction of a body's ground patch (rigid_contact, and the ground's last word in
// body_contact): the tangential slide of the contact point over the substep — the patch
// particles' mean motion `meanSlip` plus what the normal correction's turn moved the point
// (`local`, fixed in the body, was at `pc`) — is undone by the distance `limit(len, wt)` returns
// (len the slide, wt the generalized inverse mass along it; 0: none).
template <class Limit>
void slidePatch(RigidPose& pose, const Vec3& pc, const Vec3& local, const Vec3& meanSlip, const Vec3& up, Limit&& limit) {
  const Vec3 pcAfter = pose.q.toRotationMatrix() * local + pose.c;
  Vec3 slide = meanSlip + (pcAfter - pc);
  slide -= up.dot(slide) * up;  // tangential part
  const double len = slide.norm();
  if (!(len > 0.0)) return;
  const Vec3 t = -slide / len;
  const double distance = limit(len, generalizedInverseMass(pose, pcAfter, t));
  if (distance > 0.0) applyPointCorrection(pose, pcAfter, t, distance);
}

}  // namespace

// The ground has the last word: body_contact, solved after rigid_contact, may press a body
// into the ground (a box under a landing pile). One sweep lifts every body in ground contact
// by its deepest penetration at the patch's depth-weighted centroid, as rigid_contact's normal
// correction does, then stops what body_contact slid it sideways (static friction only:
// rigid_contact has applied the kinetic). Independent per body: parallel.
void PbdWorld::groundLastWord() {
  const BodyPlaneContacts& bp = contacts_.bodyPlane;
  forEach(bp.size(), [&](std::size_t c) {
    const auto b = std::size_t(bp.body[c]);
    if (!moving(b)) return;
    const Plane& plane = contacts_.planes[std::size_t(bp.plane[c])];
    const double floorY = plane.offset + params_.particleRadius;
    const Vec3 up = plane.normal;
    const std::int32_t* cand = bp.candidates.data() + bp.first[c];
    Motion& mo = motion_[b];
    RigidPose pose{mo.c, mo.q, invMass_[b], invInertiaRest_[b]};
    const Mat3 R = pose.q.toRotationMatrix(), Rprev = mo.qPrev.toRotationMatrix();
    double wsum = 0.0, dmax = 0.0;
    Vec3 psum = Vec3::Zero(), ssum = Vec3::Zero();
    for (std::int32_t m = 0; m < bp.count[c]; ++m) {
      const auto j = std::size_t(cand[m]);
      const Vec3 rr(rx_[j], ry_[j], rz_[j]);
      const Vec3 p = R * rr + pose.c;
      const double d = floorY - up.dot(p);
      if (d <= 0.0) continue;
      wsum += d;
      dmax = std::max(dmax, d);
      psum += d * p;
      ssum += d * (p - (Rprev * rr + mo.cPrev));
    }
    if (wsum == 0.0) return;
    const Vec3 pc = psum / wsum;
    const Vec3 local = R.transpose() * (pc - pose.c);
    const double lambdaN = applyPointCorrection(pose, pc, up, dmax);
    // Static friction, again: rigid_contact's friction stopped the patch, and body_contact has
    // pushed it sideways since (a load on a tilted patch). Left alone, that push stayed in the
    // pose every substep, and a stack walked across the floor at 6 mm/s. Bounded by the
    // substep's whole normal impulse at the ground (rigid_contact's and this lift's); past it,
    // the body slides and rigid_contact's kinetic friction has acted.
    const double bound = staticFriction_[b] * (bp.normalImpulse[c] + lambdaN);
    slidePatch(pose, pc, local, ssum / wsum, up, [&](double len, double wt) { return len / wt <= bound ? len : 0.0; });
    mo.c = pose.c;
    mo.q = pose.q;
  });
}

void PbdWorld::rigidContact() {
  BodyPlaneContacts& bp = contacts_.bodyPlane;  // each task writes only its own contact's entries
  forEach(bp.size(), [&](std::size_t c) {
    const auto b = std::size_t(bp.body[c]);
    const Plane& plane = contacts_.planes[std::size_t(bp.plane[c])];
    const double floorY = plane.offset + params_.particleRadius;
    const Vec3 up = plane.normal;
    const std::int32_t* cand = bp.candidates.data() + bp.first[c];
    const std::int32_t ncand = bp.count[c];
    Motion& mo = motion_[b];
    RigidPose pose{mo.c, mo.q, invMass_[b], invInertiaRest_[b]};
    const double mus = staticFriction_[b], muk = dynamicFriction_[b];
    const Mat3 Rprev = mo.qPrev.toRotationMatrix();
    for (int it = 0; it < params_.iterations; ++it) {
      // One correction per sweep for the whole contact patch, applied at its
      // depth-weighted centroid: order-independent (a Gauss-Seidel pass over
      // single particles tilts the body towards whichever contact comes first
      // and makes a resting body creep). Exact for one corner and for a flat face.
      const Mat3 R = pose.q.toRotationMatrix();
      double wsum = 0.0, dmax = 0.0;
      Vec3 psum = Vec3::Zero(), ssum = Vec3::Zero();
      for (std::int32_t m = 0; m < ncand; ++m) {
        const auto j = std::size_t(cand[m]);
        const Vec3 rr(rx_[j], ry_[j], rz_[j]);
        const Vec3 p = R * rr + pose.c;
        const double d = floorY - up.dot(p);  // penetration depth (m)
        if (d <= 0.0) continue;
        wsum += d;
        dmax = std::max(dmax, d);
        psum += d * p;
        ssum += d * (p - (Rprev * rr + mo.cPrev));  // the point's motion over this substep
      }
      if (wsum == 0.0) break;
      const Vec3 pc = psum / wsum;  // contact point
      if (it == 0) {
        // For restitution: the point's normal speed before the solve, and where it is on the body.
        bp.touched[c] = 1;
        bp.approachSpeed[c] = up.dot(mo.v + mo.w.cross(pc - pose.c));
        bp.point[c] = R.transpose() * (pc - pose.c);  // body frame until the solve ends
      }
      // Lift the patch by its deepest penetration, at its depth-weighted centroid: one
      // sweep then resolves a landing (a mean depth left a third of it, which compounded
      // into a guard trip at 1-2 iterations), and the centroid keeps the lift from
      // tilting the body towards whichever particle is deepest.
      const double depth = dmax;
      const Vec3 local = R.transpose() * (pc - pose.c);  // the contact point, fixed in the body
      const double lambdaN = applyPointCorrection(pose, pc, up, depth);
      bp.normalImpulse[c] += lambdaN;
      // Coulomb friction at position level (Müller 2020 §3.5), on impulses: undo the
      // tangential motion of the contact over this substep fully when that takes an
      // impulse within mu_s lambda_n (static), else apply mu_k lambda_n against it.
      if (lambdaN > 0.0) {
        slidePatch(pose, pc, local, ssum / wsum, up, [&](double len, double wt) {
          const double lambdaT = coulomb(len / wt, lambdaN, mus, muk);
          return lambdaT > 0.0 ? lambdaT * wt : 0.0;
        });
      }
    }
    mo.c = pose.c;
    mo.q = pose.q;
    if (bp.touched[c]) bp.point[c] = pose.q.toRotationMatrix() * bp.point[c] + pose.c;
  });
}

// Restitution (Müller et al. 2020 §3.6, Eq. 34, at body level): a contact point that
// approached the plane at normal speed u < 0 before the solve leaves it at -e u; the
// velocity update has left it at about 0, so a velocity impulse along the normal at the
// contact point, through the body's generalized inverse mass, makes up the difference.
// Slow contacts (|u| <= 2 |g| h, a body at rest or rolling) get none, so resting bodies
// do not jitter.
void PbdWorld::restitution(double h) {
  const BodyPlaneContacts& bp = contacts_.bodyPlane;
  const double slow = 2.0 * params_.gravity.norm() * h;
  bodyRestitution(slow);
  forEach(bp.size(), [&](std::size_t c) {
    const auto b = std::size_t(bp.body[c]);
    if (!bp.touched[c] || restitution_[b] <= 0.0 || !moving(b)) return;
    const double u = bp.approachSpeed[c];
    if (u >= -slow) return;
    Motion& mo = motion_[b];
    const Vec3 n = contacts_.planes[std::size_t(bp.plane[c])].normal;
    const Vec3 r = bp.point[c] - mo.c;
    const double vn = n.dot(mo.v + mo.w.cross(r));
    const double dv = -restitution_[b] * u - vn;
    if (dv <= 0.0) return;  // already leaving faster than that
    const RigidPose pose{mo.c, mo.q, invMass_[b], invInertiaRest_[b]};
    const double p = dv / generalizedInverseMass(pose, bp.point[c], n);  // impulse (N s)
    const Mat3 R = mo.q.toRotationMatrix();
    mo.v += (p * invMass_[b]) * n;
    mo.w += R * invInertiaRest_[b] * R.transpose() * r.cross(p * n);
  });
}

// A depth-first search down the stack: b is held if a plane, a fixed or sleeping body holds it,
// or a dynamic body it rests on (against d) is held in turn. Each body is visited once, so a
// ring of touching bodies ends; the touches are few (the pairs that touched this substep).
bool PbdWorld::heldAgainst(std::size_t b, const Vec3& d) const {
  const BodyPlaneContacts& bp = contacts_.bodyPlane;
  const auto onPlane = [&](std::size_t x) {
    for (std::size_t c = 0; c < bp.size(); ++c)
      if (std::size_t(bp.body[c]) == x && bp.touched[c] && contacts_.planes[std::size_t(bp.plane[c])].normal.dot(d) <= -0.5)
        return true;
    return false;
  };
  std::vector<char> seen(members_.size(), 0);
  std::vector<std::size_t> todo{b};
  seen[b] = 1;
  while (!todo.empty()) {
    const std::size_t x = todo.back();
    todo.pop_back();
    if (onPlane(x)) return true;
    for (const BodyTouch& t : bodyTouches_) {
      if (std::size_t(t.body) != x || t.normal.dot(d) > -0.5) continue;
      const auto o = std::size_t(t.other);
      if (mode_[o] == BodyMode::kFixed || (mode_[o] == BodyMode::kDynamic && !moving(o))) return true;
      if (mode_[o] == BodyMode::kDynamic && !seen[o]) seen[o] = 1, todo.push_back(o);
    }
  }
  return false;
}

// Between two rigid bodies, the same law with the mean of their restitutions (as friction
// takes the mean of theirs): the pair's contact point leaves at -e u relative to the other body,
// through both bodies' generalized inverse masses. A body held against its share by the ground
// or a fixed body, directly or through a stack (heldAgainst), takes none: what holds it takes it (without that, a ball dropped
// on a slab lying on the ground bounced off it as off a free body, a fifth as high, and the
// slab, driven into the ground, bounced off the ground). In pair order, serially:
// deterministic.
void PbdWorld::bodyRestitution(double slow) {
  for (const PairHit& hit : pairHits_) {
    const auto a = std::size_t(hit.a), b = std::size_t(hit.b);
    const double e = 0.5 * (restitution_[a] + restitution_[b]);
    if (e <= 0.0 || hit.approach >= -slow) continue;
    Motion &ma = motion_[a], &mb = motion_[b];
    const bool da = moving(a), db = moving(b);
    const Vec3& n = hit.normal;  // from b towards a
    const Vec3 ra = hit.point - ma.c, rb = hit.point - mb.c;
    const double vn = n.dot((ma.v + ma.w.cross(ra)) - (mb.v + mb.w.cross(rb)));
    const double dv = -e * hit.approach - vn;
    if (dv <= 0.0) continue;  // already leaving faster than that
    const RigidPose pa{ma.c, ma.q, invMass_[a], invInertiaRest_[a]}, pb{mb.c, mb.q, invMass_[b], invInertiaRest_[b]};
    const bool ha = da && heldAgainst(a, n), hb = db && heldAgainst(b, -n);  // a takes +p n, b -p n
    const double wa = da && !ha ? generalizedInverseMass(pa, hit.point, n) : 0.0;
    const double wb = db && !hb ? generalizedInverseMass(pb, hit.point, n) : 0.0;
    if (wa + wb <= 0.0) continue;
    const double p = dv / (wa + wb);  // impulse (N s), on a along n and on b against it
    if (da && !ha) {
      const Mat3 R = ma.q.toRotationMatrix();
      ma.v += (p * invMass_[a]) * n;
      ma.w += R * invInertiaRest_[a] * R.transpose() * ra.cross(p * n);
    }
    if (db && !hb) {
      const Mat3 R = mb.q.toRotationMatrix();
      mb.v -= (p * invMass_[b]) * n;
      mb.w -= R * invInertiaRest_[b] * R.transpose() * rb.cross(p * n);
    }
  }
}

void PbdWorld::velocitiesFromPoses(std::size_t b, double h) {
  Motion& mo = motion_[b];
  mo.v = (mo.c - mo.cPrev) / h;
  mo.w = rotationVector(mo.q * mo.qPrev.conjugate()) / h;
}

void PbdWorld::update(double h) {
  for (std::size_t b = 0; b < members_.size(); ++b) {
    Motion& mo = motion_[b];
    if (!isRigid(b)) continue;
    if (moving(b)) {
      velocitiesFromPoses(b, h);
    } else if (mode_[b] == BodyMode::kKinematic) {
      mo.v = (mo.c - mo.cPrev) / h;
      mo.w = Vec3::Zero();
    }
  }
}

// Also summarizes what it wrote for the guard, while the values are in registers: any
// non-finite value ((x - x) is NaN exactly then), and for dynamic bodies the largest
// speed and the lowest particle. Each chunk keeps its own summary and they are combined
// in chunk order; min, max and "any NaN" do not depend on that order anyway.
void PbdWorld::writeParticles() {
  struct Summary {
    float nonFinite = 0.0f, maxV2 = 0.0f, minY = 3.4e38f;
  };
  const float floorY = static_cast<float>(params_.groundY + params_.particleRadius);
  const float bound = static_cast<float>(params_.particleRadius);
  const float max2 = static_cast<float>(params_.maxSpeed * params_.maxSpeed);
  bool suspect = false;
  for (std::size_t b = 0; b < members_.size(); ++b) {
    // Fixed bodies never move: written once, when the world starts.
    if (mode_[b] == BodyMode::kEmpty || (mode_[b] == BodyMode::kFixed && steps_ > 0)) continue;
    if (asleep(int(b))) continue;  // its particles were left at rest when it fell asleep
    if (!isRigid(b)) {
      // Particle-level bodies live in the particle arrays: only their summary is made here.
      suspect = summarizeLoose(b) || suspect;
      continue;
    }
    const Motion& mo = motion_[b];
    // The particles are the body's float32 image: R r in float loses nothing the float
    // output keeps (|r| <= reach, relative error 1e-7), and runs as plain SoA loops.
    const Eigen::Matrix3f R = mo.q.toRotationMatrix().cast<float>();
    const Eigen::Vector3f w = mo.w.cast<float>(), v = mo.v.cast<float>();
    const Vec3 c = mo.c;
    const auto& mem = members_[b];
    std::vector<Summary> chunks((mem.size() + kChunk - 1) / kChunk);
    // A body made by the sketch is a contiguous id range until a cut: then the loop runs
    // on ids directly (no gather or scatter, so the compiler vectorizes it).
    const bool contiguous = !mem.empty() && std::size_t(mem.back() - mem.front()) + 1 == mem.size();
    const std::size_t first = mem.empty() ? 0 : std::size_t(mem.front());
    const auto body = [&](auto id, std::size_t lo, std::size_t hi) {
      Summary sum;
      for (std::size_t k = lo; k < hi; ++k) {
        const std::size_t i = id(k);
        const float ax = rx_[i], ay = ry_[i], az = rz_[i];
        const float r0 = R(0, 0) * ax + R(0, 1) * ay + R(0, 2) * az;
        const float r1 = R(1, 0) * ax + R(1, 1) * ay + R(1, 2) * az;
        const float r2 = R(2, 0) * ax + R(2, 1) * ay + R(2, 2) * az;
        const auto px = static_cast<float>(c.x() + r0), py = static_cast<float>(c.y() + r1),
                   pz = static_cast<float>(c.z() + r2);
        const float ux = v.x() + (w.y() * r2 - w.z() * r1), uy = v.y() + (w.z() * r0 - w.x() * r2),
                    uz = v.z() + (w.x() * r1 - w.y() * r0);
        parts_.x[i] = px;
        parts_.y[i] = py;
        parts_.z[i] = pz;
        parts_.vx[i] = ux;
        parts_.vy[i] = uy;
        parts_.vz[i] = uz;
        sum.nonFinite += (px - px) + (py - py) + (pz - pz) + (ux - ux) + (uy - uy) + (uz - uz);
        const float v2 = ux * ux + uy * uy + uz * uz;
        sum.maxV2 = v2 > sum.maxV2 ? v2 : sum.maxV2;
        sum.minY = py < sum.minY ? py : sum.minY;
      }
      chunks[lo / kChunk] = sum;  // forRange's chunks start at multiples of kChunk
    };
    forRange(mem.size(), [&](std::size_t lo, std::size_t hi) {
      if (contiguous) body([&](std::size_t k) { return first + k; }, lo, hi);
      else body([&](std::size_t k) { return std::size_t(mem[k]); }, lo, hi);
    });
    const bool dynamic = mode_[b] == BodyMode::kDynamic;
    for (const Summary& s : chunks)
      suspect = suspect || s.nonFinite != 0.0f ||
                (dynamic && (!(s.maxV2 <= 0.999f * max2) || !(s.minY >= floorY - bound)));
  }
  writtenSuspect_ = suspect;
}

std::uint64_t PbdWorld::stateHash() const {
  std::uint64_t h = 1469598103934665603ull;
  for (const auto* a : {&parts_.x, &parts_.y, &parts_.z, &parts_.vx, &parts_.vy, &parts_.vz})
    hashBytes(h, a->data(), a->size() * sizeof(float));
  hashBytes(h, parts_.phase.data(), parts_.phase.size() * sizeof(std::uint32_t));
  for (const Motion& mo : motion_) {
    const double d[13] = {mo.c.x(), mo.c.y(), mo.c.z(), mo.q.w(), mo.q.x(), mo.q.y(), mo.q.z(),
                          mo.v.x(), mo.v.y(), mo.v.z(), mo.w.x(), mo.w.y(), mo.w.z()};
    hashBytes(h, d, sizeof d);
  }
  return h;
}

}  // namespace physketch::pbd

namespace physketch::pbd {

void PbdWorld::setColliders(ColliderSet colliders) {
  colliders_ = std::make_unique<ColliderSet>(std::move(colliders));
  wakeAll();
}

// Mesh colliders, once per substep, at the poses of [t0, t1]. Particle-level particles that
// move more than half a radius are swept from where they were to where they are predicted
// (a one-triangle-thick wall stops them at any speed), then every one within a radius of a
// surface gets a contact. A dynamic rigid body near a collider (its centre within reach of a
// surface) that moves more than half a radius is swept particle by particle and stopped at
// the first touch (its motion of this substep scaled back to that fraction), then its
// particles within reach get contacts, solved at body level by collider_contact.
void PbdWorld::findColliders(int substep) {
  const double h = params_.dt / params_.substeps, r = params_.particleRadius;
  const double t0 = double(steps_) * params_.dt + substep * h;
  colliders_->setSubstep(t0, t0 + h);
  // Particle-level.
  looseHits_.clear();
  std::vector<std::int32_t> ids;
  std::vector<float> x, y, z;
  for (std::int32_t i : loose_) {
    const auto k = std::size_t(i);
    if (invMassP_[k] == 0.0f) continue;
    Vec3 p(px_[k], py_[k], pz_[k]);
    const Vec3 from(parts_.x[k], parts_.y[k], parts_.z[k]);
    if ((p - from).norm() > 0.5 * r) {
      const SweepHit hit = colliders_->sweep(from, p, radiusOf(k));
      if (hit.hit) {
        p = hit.centre;
        px_[k] = float(p.x()), py_[k] = float(p.y()), pz_[k] = float(p.z());
      }
    }
    ids.push_back(i);
    x.push_back(float(p.x())), y.push_back(float(p.y())), z.push_back(float(p.z()));
  }
  if (!ids.empty()) {
    // Every particle within reach of its own radius (looseColliderContact keeps those touching).
    colliders_->contacts(x.data(), y.data(), z.data(), ids.size(), largestContactRadius(), r, looseHits_);
    for (MeshContact& c : looseHits_) c.particle = ids[std::size_t(c.particle)];
  }
  // Rigid bodies.
  bodyHits_.clear();
  for (std::int32_t bb : active_) {
    const auto b = std::size_t(bb);
    Motion& mo = motion_[b];
    const double travel = (mo.c - mo.cPrev).norm() + 2.0 * std::acos(std::min(1.0, std::abs(mo.q.dot(mo.qPrev)))) * reach_[b];
    MeshContact probe;
    if (!colliders_->closest(mo.c, reach_[b] + travel + 2.0 * r, probe)) continue;
    const auto& mem = members_[b];
    if (travel > 0.5 * r) {
      const Mat3 R0 = mo.qPrev.toRotationMatrix(), R1 = mo.q.toRotationMatrix();
      double first = 1.0;
      for (std::int32_t i : mem) {
        const auto k = std::size_t(i);
        const Vec3 rr(rx_[k], ry_[k], rz_[k]);
        const SweepHit hit = colliders_->sweep(R0 * rr + mo.cPrev, R1 * rr + mo.c, r);
        if (hit.hit) first = std::min(first, hit.fraction);
      }
      if (first < 1.0) {
        mo.c = mo.cPrev + first * (mo.c - mo.cPrev);
        mo.q = mo.qPrev.slerp(first, mo.q).normalized();
      }
    }
    const Mat3 R = mo.q.toRotationMatrix();
    x.assign(mem.size(), 0.0f), y.assign(mem.size(), 0.0f), z.assign(mem.size(), 0.0f);
    for (std::size_t m = 0; m < mem.size(); ++m) {
      const auto k = std::size_t(mem[m]);
      const Vec3 p = R * Vec3(rx_[k], ry_[k], rz_[k]) + mo.c;
      x[m] = float(p.x()), y[m] = float(p.y()), z[m] = float(p.z());
    }
    BodyColliderContacts bc;
    bc.body = bb;
    std::vector<MeshContact> found;
    colliders_->contacts(x.data(), y.data(), z.data(), mem.size(), r, r, found);
    for (MeshContact& c : found) {
      bc.particle.push_back(mem[std::size_t(c.particle)]);
      bc.contact.push_back(c);
    }
    if (!bc.particle.empty()) bodyHits_.push_back(std::move(bc));
  }
}

// Body-level contact with mesh colliders, as for the ground: per body and sweep, its
// particles' penetrations of the contact planes (point, normal) found this substep form a
// patch, corrected once at its depth-weighted centroid along its depth-weighted normal by
// the deepest penetration, then Coulomb friction against the collider surface's motion.
void PbdWorld::rigidColliderContact() {
  const double r = params_.particleRadius, h = params_.dt / params_.substeps;
  forEach(bodyHits_.size(), [&](std::size_t j) {
    const BodyColliderContacts& bc = bodyHits_[j];
    const auto b = std::size_t(bc.body);
    Motion& mo = motion_[b];
    RigidPose pose{mo.c, mo.q, invMass_[b], invInertiaRest_[b]};
    const Mat3 Rprev = mo.qPrev.toRotationMatrix();
    for (int it = 0; it < params_.iterations; ++it) {
      const Mat3 R = pose.q.toRotationMatrix();
      double wsum = 0.0, dmax = 0.0, mus = 0.0, muk = 0.0;
      Vec3 psum = Vec3::Zero(), nsum = Vec3::Zero(), ssum = Vec3::Zero();
      for (std::size_t k = 0; k < bc.particle.size(); ++k) {
        const auto i = std::size_t(bc.particle[k]);
        const MeshContact& c = bc.contact[k];
        const Vec3 rr(rx_[i], ry_[i], rz_[i]);
        const Vec3 p = R * rr + pose.c;
        const double pen = r - (p - c.point).dot(c.normal);
        if (pen <= 0.0) continue;
        wsum += pen;
        dmax = std::max(dmax, pen);
        psum += pen * p;
        nsum += pen * c.normal;
        const Vec3 surface = colliders_->surfaceVelocity(std::size_t(c.collider), c.point) * h;
        ssum += pen * ((p - (Rprev * rr + mo.cPrev)) - surface);
        const Material& m = materials_[std::size_t(parts_.material[i])];
        const auto& fr = colliders_->collider(std::size_t(c.collider)).friction;
        mus += pen * (fr ? *fr : m.staticFriction);
        muk += pen * (fr ? *fr : m.dynamicFriction);
      }
      if (wsum == 0.0 || nsum.norm() == 0.0) break;
      const Vec3 n = nsum.normalized(), pc = psum / wsum;
      const double wn = generalizedInverseMass(pose, pc, n);
      const double lambdaN = applyPointCorrection(pose, pc, n, dmax);
      Vec3 slide = ssum / wsum;
      slide -= n.dot(slide) * n;
      const double len = slide.norm();
      if (len > 0.0 && wn > 0.0) {
        const Vec3 t = -slide / len;
        const double wt = generalizedInverseMass(pose, pc, t);
        const double lambdaT = coulomb(len / wt, lambdaN, mus / wsum, muk / wsum);
        if (lambdaT > 0.0) applyPointCorrection(pose, pc, t, lambdaT * wt);
      }
    }
    mo.c = pose.c, mo.q = pose.q;
  });
}

}  // namespace physketch::pbd
