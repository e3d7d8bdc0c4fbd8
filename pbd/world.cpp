#include "pbd/world.h"

#include <algorithm>
#include <cmath>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.h"
#include "pbd/shape_matching.h"

namespace physketch::pbd {
namespace {

// Per-particle passes split into fixed chunks; below this size they run serially
// (threads cost more than they save on small scenes). Results do not depend on
// the split: every particle is written by exactly one task.
constexpr std::size_t kChunk = 4096;

template <class F>
void forParticles(std::size_t n, F&& f) {
  if (n <= kChunk) {
    f(std::size_t(0), n);
    return;
  }
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, kChunk),
                    [&](const tbb::blocked_range<std::size_t>& r) { f(r.begin(), r.end()); },
                    tbb::simple_partitioner());
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
  return p;
}

Mat4f BodyPose::model() const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  const Mat3 R = rotation.toRotationMatrix();
  m.topLeftCorner<3, 3>() = R;
  m.topRightCorner<3, 1>() = centre - R * restCentre;
  return m.cast<float>();
}

PbdWorld::PbdWorld(ParticleArrays particles, std::vector<BodyRange> bodies, std::vector<Material> materials,
                   const PbdParams& params)
    : params_(params), parts_(std::move(particles)), materials_(std::move(materials)) {
  if (!(params_.dt > 0) || params_.substeps < 1 || params_.iterations < 1 || !(params_.particleRadius > 0))
    throw RuntimeError("PbdWorld: dt, substeps, iterations and particle radius must be positive");
  const std::size_t n = parts_.size();
  px_ = parts_.x;
  py_ = parts_.y;
  pz_ = parts_.z;
  mass_.assign(n, 0.0f);
  rx_.assign(n, 0.0f);
  ry_.assign(n, 0.0f);
  rz_.assign(n, 0.0f);
  alive_.assign(n, 1);
  for (const BodyRange& br : bodies) {
    if (br.first < 0 || br.count < 1 || std::size_t(br.first) + std::size_t(br.count) > n)
      throw RuntimeError("PbdWorld: body " + std::to_string(bodies_.size()) + " has an invalid particle range");
    bodies_.push_back(br);
    appendBodyState(BodyMode::kDynamic);
  }
  passIntegrate_ = profile_.add("integrate");
  passKinematic_ = profile_.add("kinematic");
  passShape_ = profile_.add("shape_match");
  passContact_ = profile_.add("rigid_contact");
  passUpdate_ = profile_.add("update");
  passGuard_ = profile_.add("guard");
}

void PbdWorld::appendBodyState(BodyMode mode) {
  rot_.push_back(Quat::Identity());
  centre_.push_back(Vec3::Zero());
  restCentre_.push_back(Vec3::Zero());
  invMass_.push_back(0.0);
  invInertia_.push_back(Mat3::Zero());
  friction_.push_back(0.0);
  reach_.push_back(0.0);
  mode_.push_back(mode);
  rigid_.push_back(1);
  kinStart_.push_back(Vec3::Zero());
  kinTarget_.push_back(Vec3::Zero());
  const std::size_t b = bodies_.size() - 1;
  const BodyRange& br = bodies_[b];
  // Rest shape = the particles' current positions; the pose starts at identity.
  Vec3 c = Vec3::Zero();
  double m = 0.0;
  for (std::int32_t i = br.first; i < br.first + br.count; ++i) {
    // Per-particle material: one body may mix materials (a solid object with a soft part).
    const Material& mat = materials_.at(static_cast<std::size_t>(parts_.material[i]));
    const double spacing = 2.0 * params_.particleRadius;
    const double mi = mat.density * spacing * spacing * spacing;  // one voxel per particle
    mass_[i] = static_cast<float>(mi);
    parts_.body[i] = static_cast<std::int32_t>(b);
    c += mi * Vec3(parts_.x[i], parts_.y[i], parts_.z[i]);
    m += mi;
    rigid_[b] = rigid_[b] && mat.kind == MaterialKind::kRigid;
  }
  c /= m;
  for (std::int32_t i = br.first; i < br.first + br.count; ++i) {
    rx_[i] = static_cast<float>(parts_.x[i] - c.x());
    ry_[i] = static_cast<float>(parts_.y[i] - c.y());
    rz_[i] = static_cast<float>(parts_.z[i] - c.z());
  }
  centre_[b] = restCentre_[b] = kinStart_[b] = kinTarget_[b] = c;
  refreshMassProperties(b);
  setMode(static_cast<int>(b), mode);
}

// Mass, inertia, friction and reach of a body from its live particles' rest offsets.
void PbdWorld::refreshMassProperties(std::size_t b) {
  const BodyRange& br = bodies_[b];
  double m = 0.0, friction = 0.0, reach = 0.0;
  for (std::int32_t i = br.first; i < br.first + br.count; ++i) {
    if (!alive_[i]) continue;
    m += mass_[i];
    friction += mass_[i] * materials_[static_cast<std::size_t>(parts_.material[i])].friction;
    reach = std::max(reach, Vec3(rx_[i], ry_[i], rz_[i]).norm());
  }
  if (m <= 0.0) {
    mode_[b] = BodyMode::kEmpty;
    return;
  }
  const std::size_t f = static_cast<std::size_t>(br.first);
  BodyView v{br.count, &px_[f], &py_[f], &pz_[f], &rx_[f], &ry_[f], &rz_[f], &mass_[f]};
  invMass_[b] = 1.0 / m;
  invInertia_[b] = restInertia(v, 2.0 * params_.particleRadius).inverse();
  friction_[b] = friction / m;  // mass-weighted mean over the body's materials
  reach_[b] = reach + params_.particleRadius;
}

int PbdWorld::addBody(const ParticleArrays& p, bool kinematic) {
  if (p.size() == 0) throw RuntimeError("PbdWorld::addBody: a body needs particles");
  const auto first = static_cast<std::int32_t>(parts_.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (p.material[i] < 0 || static_cast<std::size_t>(p.material[i]) >= materials_.size())
      throw RuntimeError("PbdWorld::addBody: unknown material index");
    parts_.push(p.x[i], p.y[i], p.z[i], p.stroke[i], p.material[i]);
    px_.push_back(p.x[i]);
    py_.push_back(p.y[i]);
    pz_.push_back(p.z[i]);
    mass_.push_back(0.0f);
    rx_.push_back(0.0f);
    ry_.push_back(0.0f);
    rz_.push_back(0.0f);
    alive_.push_back(1);
  }
  BodyRange br;
  br.first = first;
  br.count = static_cast<std::int32_t>(p.size());
  br.material = p.material[0];
  br.stroke = p.stroke[0];
  bodies_.push_back(br);
  appendBodyState(kinematic ? BodyMode::kKinematic : BodyMode::kDynamic);
  return static_cast<int>(bodies_.size() - 1);
}

void PbdWorld::setMode(int body, BodyMode mode) {
  const auto b = static_cast<std::size_t>(body);
  if (mode_.at(b) == BodyMode::kEmpty) return;
  mode_[b] = mode;
  const BodyRange& br = bodies_[b];
  // Kinematic particles have infinite mass: the dynamic passes leave them alone.
  for (std::int32_t i = br.first; i < br.first + br.count; ++i)
    parts_.invMass[i] = (mode == BodyMode::kDynamic && alive_[i]) ? 1.0f / mass_[i] : 0.0f;
  kinStart_[b] = kinTarget_[b] = centre_[b];
}

void PbdWorld::setKinematicTarget(int body, const Vec3& centre) {
  const auto b = static_cast<std::size_t>(body);
  if (mode_.at(b) != BodyMode::kKinematic) throw RuntimeError("PbdWorld::setKinematicTarget: body is not kinematic");
  kinTarget_[b] = centre;
}

std::vector<int> PbdWorld::removeParticles(const std::vector<std::int32_t>& ids) {
  std::vector<int> changed;
  for (std::int32_t i : ids) {
    if (i < 0 || static_cast<std::size_t>(i) >= parts_.size() || !alive_[i]) continue;
    alive_[i] = 0;
    const int b = parts_.body[i];
    parts_.invMass[i] = 0.0f;
    parts_.vx[i] = parts_.vy[i] = parts_.vz[i] = 0.0f;
    parts_.body[i] = -1;
    mass_[i] = 0.0f;
    if (b >= 0 && std::find(changed.begin(), changed.end(), b) == changed.end()) changed.push_back(b);
  }
  std::sort(changed.begin(), changed.end());
  for (int b : changed) {
    // The rest frame moves to the remaining particles' centre of mass.
    const auto bb = static_cast<std::size_t>(b);
    const BodyRange& br = bodies_[bb];
    double m = 0.0;
    Vec3 cr = Vec3::Zero();
    for (std::int32_t i = br.first; i < br.first + br.count; ++i) {
      m += mass_[i];
      cr += double(mass_[i]) * Vec3(rx_[i], ry_[i], rz_[i]);
    }
    if (m > 0.0) {
      cr /= m;
      for (std::int32_t i = br.first; i < br.first + br.count; ++i) {
        rx_[i] = static_cast<float>(rx_[i] - cr.x());
        ry_[i] = static_cast<float>(ry_[i] - cr.y());
        rz_[i] = static_cast<float>(rz_[i] - cr.z());
      }
      centre_[bb] += rot_[bb].toRotationMatrix() * cr;
      restCentre_[bb] += cr;
      kinStart_[bb] = kinTarget_[bb] = centre_[bb];
    }
    refreshMassProperties(bb);
  }
  return changed;
}

BodyPose PbdWorld::pose(int body) const {
  BodyPose p;
  p.rotation = rot_.at(static_cast<std::size_t>(body));
  p.centre = centre_[static_cast<std::size_t>(body)];
  p.restCentre = restCentre_[static_cast<std::size_t>(body)];
  return p;
}

std::vector<PassInfo> PbdWorld::plan() const {
  std::vector<PassInfo> out;
  if (parts_.size() == 0) return out;
  const long s = params_.substeps, it = params_.iterations;
  out.push_back({"integrate", "substeps = " + std::to_string(s), s});
  if (std::count(mode_.begin(), mode_.end(), BodyMode::kKinematic) > 0)
    out.push_back({"kinematic", "substeps = " + std::to_string(s), s});
  if (std::count(mode_.begin(), mode_.end(), BodyMode::kDynamic) > 0) {
    out.push_back({"shape_match", "substeps = " + std::to_string(s), s});
    out.push_back({"rigid_contact", "substeps, up to " + std::to_string(it) + " sweeps each", s});
  }
  out.push_back({"update", "substeps = " + std::to_string(s), s});
  out.push_back({"guard", "once", 1});
  return out;
}

void PbdWorld::integrate(float h) {
  const float gx = static_cast<float>(params_.gravity.x()), gy = static_cast<float>(params_.gravity.y()),
              gz = static_cast<float>(params_.gravity.z());
  forParticles(parts_.size(), [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      if (parts_.invMass[i] == 0.0f) {
        px_[i] = parts_.x[i];
        py_[i] = parts_.y[i];
        pz_[i] = parts_.z[i];
        continue;
      }
      parts_.vx[i] += gx * h;
      parts_.vy[i] += gy * h;
      parts_.vz[i] += gz * h;
      px_[i] = parts_.x[i] + parts_.vx[i] * h;
      py_[i] = parts_.y[i] + parts_.vy[i] * h;
      pz_[i] = parts_.z[i] + parts_.vz[i] * h;
    }
  });
}

void PbdWorld::shapeMatch() {
  auto solve = [&](std::size_t k) {
    const std::size_t b = static_cast<std::size_t>(active_[k]);
    const BodyRange& br = bodies_[b];
    const std::size_t f = static_cast<std::size_t>(br.first);
    BodyView v{br.count, &px_[f], &py_[f], &pz_[f], &rx_[f], &ry_[f], &rz_[f], &mass_[f]};
    matchRigid(v, rot_[b], centre_[b]);  // goal positions R q_i + c are written by rigid_contact
  };
  if (active_.size() == 1) {
    solve(0);
  } else {
    tbb::parallel_for(std::size_t(0), active_.size(), solve);
  }
}

void PbdWorld::rigidContact() {
  const double floorY = params_.groundY + params_.particleRadius;
  const Vec3 up = Vec3::UnitY();
  auto solve = [&](std::size_t k) {
    const std::size_t b = static_cast<std::size_t>(active_[k]);
    const BodyRange& br = bodies_[b];
    RigidPose pose{centre_[b], rot_[b], invMass_[b], invInertia_[b]};
    const double mu = friction_[b];
    // Bounding-sphere test: a body whose lowest possible particle is above the
    // ground skips the sweeps (falling bodies cost one shape match per substep).
    const int sweeps = pose.c.y() - reach_[b] > params_.groundY ? 0 : params_.iterations;
    for (int it = 0; it < sweeps; ++it) {
      // One correction per sweep for the whole contact patch, applied at its
      // depth-weighted centroid: order-independent (a Gauss-Seidel pass over
      // single particles tilts the body towards whichever contact comes first
      // and makes a resting body creep). Exact for one corner and for a flat face.
      const Mat3 R = pose.q.toRotationMatrix();
      double wsum = 0.0, d2sum = 0.0;
      Vec3 psum = Vec3::Zero(), ssum = Vec3::Zero();
      for (std::int32_t i = br.first; i < br.first + br.count; ++i) {
        if (!alive_[i]) continue;
        const Vec3 p = R * Vec3(rx_[i], ry_[i], rz_[i]) + pose.c;
        const double d = floorY - p.y();  // penetration depth (m)
        if (d <= 0.0) continue;
        wsum += d;
        d2sum += d * d;
        psum += d * p;
        ssum += d * (p - Vec3(parts_.x[i], parts_.y[i], parts_.z[i]));  // motion over this substep
      }
      if (wsum == 0.0) break;
      const Vec3 pc = psum / wsum;     // contact point
      const double depth = d2sum / wsum;
      const Vec3 local = R.transpose() * (pc - pose.c);  // the contact point, fixed in the body
      applyPointCorrection(pose, pc, up, depth);
      // The normal correction rotates the body, which moves the contact point sideways too.
      const Vec3 pcAfter = pose.q.toRotationMatrix() * local + pose.c;
      // Static/kinetic friction at position level (Müller 2020 §3.5): undo the
      // tangential motion of the contact over this substep, fully inside the
      // friction cone mu*depth, else by mu*depth. mu_s = mu_k = material friction.
      Vec3 slide = ssum / wsum + (pcAfter - pc);
      slide.y() = 0.0;
      const double len = slide.norm();
      if (len > 0.0 && mu > 0.0) applyPointCorrection(pose, pcAfter, -slide / len, std::min(len, mu * depth));
    }
    centre_[b] = pose.c;
    rot_[b] = pose.q;
    const Mat3 R = pose.q.toRotationMatrix();
    for (std::int32_t i = br.first; i < br.first + br.count; ++i) {
      if (!alive_[i]) continue;
      const Vec3 g = R * Vec3(rx_[i], ry_[i], rz_[i]) + pose.c;
      px_[i] = static_cast<float>(g.x());
      py_[i] = static_cast<float>(g.y());
      pz_[i] = static_cast<float>(g.z());
    }
  };
  if (active_.size() == 1) {
    solve(0);
  } else {
    tbb::parallel_for(std::size_t(0), active_.size(), solve);
  }
}

void PbdWorld::update(float h) {
  const float invH = 1.0f / h;
  forParticles(parts_.size(), [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      if (!alive_[i]) continue;  // kinematic particles get their velocity from the prescribed motion
      parts_.vx[i] = (px_[i] - parts_.x[i]) * invH;
      parts_.vy[i] = (py_[i] - parts_.y[i]) * invH;
      parts_.vz[i] = (pz_[i] - parts_.z[i]) * invH;
      parts_.x[i] = px_[i];
      parts_.y[i] = py_[i];
      parts_.z[i] = pz_[i];
    }
  });
}

void PbdWorld::kinematic(int substep) {
  // Kinematic bodies move from their pose at the start of the step to their target,
  // linearly over the substeps, keeping their rotation.
  const double a = double(substep + 1) / params_.substeps;
  for (std::size_t b = 0; b < bodies_.size(); ++b) {
    if (mode_[b] != BodyMode::kKinematic) continue;
    centre_[b] = kinStart_[b] + a * (kinTarget_[b] - kinStart_[b]);
    const Mat3 R = rot_[b].toRotationMatrix();
    const BodyRange& br = bodies_[b];
    // The ground stops a carried body as it stops any other: a brush that dips below the
    // floor slides the body along it instead of pushing it through.
    double lowest = 1e300;
    for (std::int32_t i = br.first; i < br.first + br.count; ++i)
      if (alive_[i]) lowest = std::min(lowest, (R * Vec3(rx_[i], ry_[i], rz_[i])).y());
    const double floorY = params_.groundY + params_.particleRadius;
    if (centre_[b].y() + lowest < floorY) {
      const double lift = floorY - (centre_[b].y() + lowest);
      centre_[b].y() += lift;
      kinTarget_[b].y() = std::max(kinTarget_[b].y(), centre_[b].y());
    }
    for (std::int32_t i = br.first; i < br.first + br.count; ++i) {
      if (!alive_[i]) continue;
      const Vec3 g = R * Vec3(rx_[i], ry_[i], rz_[i]) + centre_[b];
      px_[i] = static_cast<float>(g.x());
      py_[i] = static_cast<float>(g.y());
      pz_[i] = static_cast<float>(g.z());
    }
  }
}

bool PbdWorld::step() {
  if (guard_.tripped()) return false;
  const float h = static_cast<float>(params_.dt / params_.substeps);
  active_.clear();
  bool anyKinematic = false;
  for (std::size_t b = 0; b < bodies_.size(); ++b) {
    if (mode_[b] == BodyMode::kDynamic && rigid_[b]) active_.push_back(static_cast<std::int32_t>(b));
    anyKinematic = anyKinematic || mode_[b] == BodyMode::kKinematic;
  }
  for (int s = 0; s < params_.substeps; ++s) {
    { ScopedPass t(profile_, passIntegrate_); integrate(h); }
    if (anyKinematic) { ScopedPass t(profile_, passKinematic_); kinematic(s); }
    if (!active_.empty()) {
      { ScopedPass t(profile_, passShape_); shapeMatch(); }
      { ScopedPass t(profile_, passContact_); rigidContact(); }
    }
    { ScopedPass t(profile_, passUpdate_); update(h); }
  }
  for (std::size_t b = 0; b < bodies_.size(); ++b) kinStart_[b] = kinTarget_[b] = centre_[b];
  {
    ScopedPass t(profile_, passGuard_);
    GuardLimits lim;
    lim.maxSpeed = params_.maxSpeed;
    lim.groundY = params_.groundY;
    lim.particleRadius = params_.particleRadius;
    lim.maxPenetration = params_.particleRadius;  // a centre below the ground plane
    guard_ = checkParticles(parts_, lim, "update", steps_);
  }
  ++steps_;
  return !guard_.tripped();
}

}  // namespace physketch::pbd
