// The one interface the app drives a solver through (PBD today, MPM next): step,
// plan, profile, guard, particles, body poses, and the changes sketching after play
// makes. `runScene` and the RuntimeDriver name no concrete solver; adding a solver
// is one more implementation of this class and one line in the app's factory.
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "core/guard.h"
#include "core/node_field.h"
#include "core/particles.h"
#include "core/profile.h"

namespace physketch {

class Solver {
 public:
  virtual ~Solver() = default;

  virtual const char* name() const = 0;
  // Advances one step of dt. Returns false (and does nothing) once the guard has tripped.
  virtual bool step() = 0;
  // The passes one step runs in the current state, in order: exactly what step() runs.
  virtual std::vector<PlanEntry> plan() const = 0;
  // Every pass of the solver's table, in order: those of plan() and the ones that are off,
  // each with why (physketch plan --all). An off pass is neither run nor allocated.
  virtual std::vector<PlanEntry> planAll() const = 0;
  virtual const Profile& profile() const = 0;
  virtual const GuardRecord& guard() const = 0;
  // Check after every pass, not only once per step (physketch run --validate).
  virtual void setValidate(bool on) = 0;
  // Stop at the first trip (default), or continue past recoverable kinds and log them
  // (physketch run --guard warn). A step the guard tripped in under warn is completed as if
  // unchecked; the energy watch takes a new reference after it.
  virtual void setGuardPolicy(GuardPolicy policy) = 0;
  virtual const GuardLog& guardLog() const = 0;

  virtual const ParticleArrays& particles() const = 0;
  bool alive(std::int32_t i) const { return !phase::has(particles().phase[static_cast<std::size_t>(i)], phase::kRemoved); }
  virtual int bodyCount() const = 0;
  // The particles of a body, ascending ids (empty once all were removed).
  virtual const std::vector<std::int32_t>& bodyParticles(int body) const = 0;
  virtual BodyPose pose(int body) const = 0;
  virtual BodyMode mode(int body) const = 0;
  // Linear (m/s) and angular (rad/s) velocity of a body's centre of mass.
  virtual Vec3 velocity(int body) const = 0;
  virtual Vec3 angularVelocity(int body) const = 0;

  virtual std::int64_t stepCount() const = 0;
  virtual double dt() const = 0;
  // The substeps the last step took where the solver chooses them per step (MPM's `substeps
  // auto`); 0 where the scene's count is used as written.
  virtual int lastSubsteps() const { return 0; }
  double time() const { return double(stepCount()) * dt(); }
  // A hash of the whole state (positions, velocities, poses): equal states, equal hashes.
  virtual std::uint64_t stateHash() const = 0;
  // What the run did that its user should hear about though nothing failed (e.g. MPM material
  // stopped at the domain's walls), one sentence each: the CLI prints them as warnings and
  // writes them into report.json.
  virtual std::vector<std::string> runNotes() const { return {}; }
  // The pressure (Pa) at particle i where the solver keeps one as state (MPM fluid: its
  // equation of state at the particle's J); NaN elsewhere (PBD's fluids hold density as a
  // constraint, not a pressure).
  virtual double pressure(std::int32_t /*i*/) const { return std::numeric_limits<double>::quiet_NaN(); }
  // The radius (m) particle i touches others with and is drawn with where it differs from the
  // voxel's half spacing (pbd: a rope's or cloth's, from its brush); NaN: the half spacing.
  virtual double contactRadius(std::int32_t /*i*/) const { return std::numeric_limits<double>::quiet_NaN(); }
  // Where body `body` is a cloth lattice: its first particle's id and its rows x cols (node
  // (r, c) is particle first + r * cols + c; a removed node is not in bodyParticles). False for
  // every other body and solver.
  virtual bool lattice(int /*body*/, std::int32_t& /*first*/, std::int32_t& /*rows*/, std::int32_t& /*cols*/) const {
    return false;
  }
  // How the material around particle i is deformed from its rest shape (the deformation gradient
  // F), for looks that follow it (Gaussian splats: Sigma = F Sigma0 F^T). Identity where the
  // solver keeps none (pbd); solver mpm: F, and J^(1/3) I for fluids (which keep only J).
  virtual Mat3 deformationGradient(std::int32_t /*i*/) const { return Mat3::Identity(); }
  // The mass (kg) the solver's background grid receives from particles `ids` alone, as its own
  // particle-to-grid transfer weighs it (MPM: quadratic B-splines on nodes dx apart), on a box of
  // nodes that reaches one node past every stencil (so the field is 0 on the box's faces). The
  // renderer meshes a level of it (PhyVR §4.1: grid mass over particle mass is a particle count,
  // thresholded). Returns false, leaving `out` alone, where the solver has no grid (pbd).
  virtual bool massField(const std::vector<std::int32_t>& /*ids*/, NodeField& /*out*/) const { return false; }

  // --- changes while the simulation runs (sketching after play) -------------
  // Appends a body made of `particles` (positions at rest, stroke and material set; a rope's
  // or cloth's nodes in layout order) with the start, layout and radius of `shape` (its first
  // and count are ignored); returns its index. A kinematic body stays where it is until released.
  virtual int addBody(const ParticleArrays& particles, const BodyRange& shape, bool kinematic) = 0;
  // Switches a body between dynamic and kinematic. A released body keeps the
  // velocity of its prescribed motion.
  virtual void setMode(int body, BodyMode mode) = 0;
  // Sets a dynamic body's linear (m/s) and angular (rad/s) velocity (a create after play
  // released with vel= or spin=).
  virtual void setVelocity(int body, const Vec3& velocity, const Vec3& angularVelocity) = 0;
  // Where a kinematic body's centre of mass must be at the end of the next step.
  virtual void setKinematicTarget(int body, const Vec3& centre) = 0;
  // Removes particles from the simulation. A body that loses particles is rebuilt
  // from the rest (mass, centre, inertia), and a body the removal cuts (26-connectivity in
  // its rest lattice) is split as docs/formats.md says: the design pieces still whole keep
  // the index, each fragment of a broken one is appended as a body of its own. Returns
  // every body changed or created, ascending.
  virtual std::vector<int> removeParticles(const std::vector<std::int32_t>& ids) = 0;
};

}  // namespace physketch
