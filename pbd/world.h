// The PBD world: unified particle solver (v1: rigid bodies by shape matching on a
// ground plane). One step is a fixed list of passes (Macklin et al. 2014,
// "Unified particle physics", Alg. 1, restricted to what the scene contains):
//
//   for each substep (h = dt / substeps):
//     integrate      v += g h;  p = x + v h                          (predict)
//     kinematic      bodies held or carried by a move stroke follow their path
//     shape_match    per rigid body: (R, c) = best rigid fit of p     (Müller 2005)
//     rigid_contact  per rigid body, `iterations` Gauss-Seidel sweeps over its
//                    particles: each particle below ground + r gets an exact
//                    rigid position correction (normal, then Coulomb friction)
//                    through the body's mass and inertia (Müller 2020); then
//                    p_i = R q_i + c
//     update         v = (p - x) / h;  x = p
//   guard            first NaN / explosion / penetration, once per step
//
// Contact is solved at body level rather than per particle followed by shape
// matching: shape matching spreads a particle's correction over the whole body,
// so per-particle contact converges at a rate of (contact particles / body
// particles) per iteration and a resting body sinks.
// A pass with no items (no rigid body) is not in the plan.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/guard.h"
#include "core/material.h"
#include "core/math.h"
#include "core/particles.h"
#include "core/profile.h"
#include "core/scene.h"

namespace physketch::pbd {

struct PbdParams {
  double dt = 1.0 / 60.0;     // s per step
  int substeps = 4;
  int iterations = 4;         // per substep
  Vec3 gravity{0.0, -9.81, 0.0};
  double groundY = 0.0;       // m
  double particleRadius = 0.0;  // m; half the particle spacing
  double maxSpeed = 100.0;    // m/s; the guard's explosion bound
};

// The solver settings a scene file asks for; the radius is half the sketch's voxel size.
PbdParams paramsFromScene(const SceneDesc& scene, double particleRadius);

// Pose of a rigid body: world = R (rest - restCentre) + centre.
struct BodyPose {
  Quat rotation = Quat::Identity();
  Vec3 centre = Vec3::Zero();
  Vec3 restCentre = Vec3::Zero();
  Mat4f model() const;  // the 4x4 rest->world matrix, for rendering
};

// How a body moves: by the solver, along a prescribed path (grabbed by a move
// stroke, or held while it is being drawn), or not at all (all particles removed).
enum class BodyMode { kDynamic, kKinematic, kEmpty };

struct PassInfo {
  std::string name;
  std::string runs;  // how often per step, e.g. "substeps x iterations = 16"
  long perStep = 0;
};

class PbdWorld {
 public:
  // particles: positions at rest (velocities are kept); bodies: contiguous ranges.
  // Masses come from material density and the particle spacing (2 r)^3.
  PbdWorld(ParticleArrays particles, std::vector<BodyRange> bodies, std::vector<Material> materials,
           const PbdParams& params);

  // Advances one step of dt. Returns false (and does nothing) once the guard has tripped.
  bool step();

  // --- changes while the simulation runs (sketching after play) -------------
  // Appends a body made of `particles` (positions at rest, stroke and material set);
  // returns its index. A kinematic body stays where it is until released.
  int addBody(const ParticleArrays& particles, bool kinematic);
  // Switches a body between dynamic and kinematic. A released body keeps the
  // velocity of its prescribed motion.
  void setMode(int body, BodyMode mode);
  BodyMode mode(int body) const { return mode_.at(static_cast<std::size_t>(body)); }
  // Where a kinematic body's centre of mass must be at the end of the next step.
  void setKinematicTarget(int body, const Vec3& centre);
  // Removes particles from the simulation; their bodies are rebuilt from the rest.
  // Returns the bodies that changed, in ascending order.
  std::vector<int> removeParticles(const std::vector<std::int32_t>& ids);
  bool alive(std::int32_t particle) const { return alive_[static_cast<std::size_t>(particle)] != 0; }

  const ParticleArrays& particles() const { return parts_; }
  const std::vector<BodyRange>& bodies() const { return bodies_; }
  BodyPose pose(int body) const;
  const PbdParams& params() const { return params_; }
  std::int64_t stepCount() const { return steps_; }
  double time() const { return double(steps_) * params_.dt; }

  std::vector<PassInfo> plan() const;
  const Profile& profile() const { return profile_; }
  Profile& profile() { return profile_; }
  const GuardRecord& guard() const { return guard_; }

 private:
  void integrate(float h);
  void kinematic(int substep);
  void shapeMatch();
  void rigidContact();
  void appendBodyState(BodyMode mode);
  void refreshMassProperties(std::size_t body);
  void update(float h);

  PbdParams params_;
  ParticleArrays parts_;
  std::vector<BodyRange> bodies_;
  std::vector<Material> materials_;
  // Solver-owned particle arrays (same indexing as parts_).
  std::vector<float> px_, py_, pz_;  // predicted positions (m); written by integrate/contact/shape_match
  std::vector<float> mass_;          // kg
  std::vector<float> rx_, ry_, rz_;  // rest offsets from the body's rest centre of mass (m)
  std::vector<std::uint8_t> alive_;  // 0 once removed by a remove stroke after play
  // Per body.
  std::vector<Quat> rot_;
  std::vector<Vec3> centre_, restCentre_;
  std::vector<double> invMass_;      // 1/kg, whole body
  std::vector<Mat3> invInertia_;     // rest-frame inverse inertia
  std::vector<double> friction_;     // Coulomb coefficient against the ground
  std::vector<double> reach_;        // m, max |rest offset| + particle radius: no contact while c.y - reach > ground
  std::vector<BodyMode> mode_;
  std::vector<std::uint8_t> rigid_;   // all of the body's materials are rigid
  std::vector<Vec3> kinStart_, kinTarget_;  // kinematic centre at the start / end of the step
  std::vector<std::int32_t> active_;  // dynamic rigid bodies this step (shape_match, rigid_contact)
  std::int64_t steps_ = 0;
  Profile profile_;
  int passIntegrate_, passKinematic_, passShape_, passContact_, passUpdate_, passGuard_;
  GuardRecord guard_;
};

}  // namespace physketch::pbd
