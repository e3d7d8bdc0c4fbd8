// The PBD world: unified particle solver (Macklin et al. 2014, "Unified particle
// physics", Alg. 1), today rigid bodies on a ground plane. One step runs the passes
// of kPbdPasses, in that order, each only when it has work (see plan()):
//
//   for each substep (h = dt / substeps):
//     integrate      dynamic bodies: v += g h; w += h I^-1 (-w x I w) (gyroscopic);
//                    c += v h; q += h/2 [w, 0] q                (Müller et al. 2020, Alg. 2)
//     kinematic      bodies held or carried by a move stroke follow their path
//     find_contacts  per dynamic body near the ground: its particles within a margin of it
//     rigid_contact  per body near the ground, `iterations` sweeps over those: one exact rigid
//                    position correction at the contact patch's depth-weighted
//                    centroid, then static/dynamic Coulomb friction (Müller 2020 §3.5)
//     body_contact   pairs of bodies whose particles touch, `iterations` Gauss-Seidel sweeps:
//                    one two-body correction per pair and sweep, then friction
//     update         v = (c - c_prev) / h; w = 2 vec(q q_prev^-1) / h   (Müller 2020, Alg. 2)
//     restitution    bodies that touched: the contact point leaves at e times its approach
//                    speed (Müller 2020 §3.6, Eq. 34), only when some material bounces
//   write_particles  x_i = R r_i + c, v_i = v + w x R r_i, once per step
//   guard            first NaN / explosion / penetration, once per step
//
// Sleeping (PbdParams::sleepSpeed; updateSleep): after a step, a dynamic rigid body that has
// stayed within sleepSpeed x sleepTime of one pose for sleepTime falls asleep: v = w = 0, its
// particles at rest, and every pass treats it as fixed (moving() is false) until find_contacts
// finds something moving touching it (a carried body, or an awake one faster than 4 x sleepSpeed)
// or an awake body touching it leaves its still ball, or find_neighbors finds a particle-level one
// touching it (looseTouch_); any outside change wakes all. Soft bodies, ropes and cloths sleep
// too (updateSleep: every particle within the same ball): a sleeper is held as a fixed body is
// (holdShape; its particles without inverse mass), and wakes at the start of a step when
// something moving may reach it within the step (wakeLooseSleepers), never within one.
//
// Soft bodies, ropes and cloth (and fluids) are simulated particle by particle, in the
// same substeps (Macklin et al. 2014, Alg. 1, with XPBD compliance, Macklin et al. 2016):
//     predict          v += g h, p = x + v h for their dynamic particles
//     find_neighbors   particle pairs within reach (one NeighborGrid per substep): theirs
//                      against each other and against rigid bodies' particles
//     fluid_neighbors  fluids: the PBF kernel's neighbour structure (pbd/fluid.h), fluid
//                      particles and the solid particles in their range
//     per iteration:   cluster_match (soft: clustered shape matching), particle_contact
//                      (pairs and ground, Coulomb friction; a rigid body takes its share
//                      through its generalized inverse mass), density (PBF: Jacobi lambda and
//                      dp; solids in range take their share, rigid bodies as an impulse, so a
//                      light body floats) and distance (rope and cloth stretch and bending,
//                      attachments to bodies, tethers)
//     particle_update  moves across rigid bodies and colliders stopped, the ground's last
//                      word; v = (p - x) / h, x = p; ground restitution; soft bodies' restitution
//     fluid_velocity   XSPH viscosity, vorticity confinement, cohesion, the implicit
//                      viscosity (which drags solids in the fluid too), when set
//     plasticity       soft materials with plastic_creep > 0: cluster rest shapes creep
//
// Rigid bodies are integrated as bodies, in double precision: a particle-level
// v = (p - x)/h in float32 loses gravity once the per-substep displacement drops
// below the float spacing of the position (1000 substeps: g h^2 = 2.7e-9 m, while
// positions near 0.5 m resolve 6e-8 m). Contact is solved at body level: shape
// matching after per-particle projection converges at a rate of (contact particles /
// body particles) per iteration and a resting body sinks.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "core/material.h"
#include "core/math.h"
#include "core/scene.h"
#include "core/solver.h"
#include "pbd/constraints.h"
#include "pbd/contacts.h"
#include "pbd/fluid.h"
#include "pbd/mesh_collider.h"

namespace physketch::pbd {

namespace detail {
struct ClusterView;
struct ClusterMoments;
}  // namespace detail

struct PbdParams {
  double dt = 1.0 / 60.0;     // s per step
  int substeps = 4;
  int iterations = 4;         // contact sweeps per substep
  Vec3 gravity{0.0, -9.81, 0.0};
  double groundY = 0.0;       // m
  double particleRadius = 0.0;  // m; half the particle spacing
  double maxSpeed = 100.0;    // m/s; the guard's explosion bound
  double maxCompression = 0.1;  // the guard's bound on a fluid's mean rho/rho0 - 1 (10 %: sloshing
                                // water stays near 1 %; beyond this the fluid visibly shrinks)
  // Sleeping (docs/formats.md, `sleep`): a dynamic rigid, soft, rope or cloth body none of whose
  // points has moved farther than sleepSpeed x sleepTime in sleepTime seconds (m/s, s) stops being
  // simulated until something wakes it (updateSleep). 0 = no body sleeps (the API's default; a
  // scene file's default is on, paramsFromScene).
  double sleepSpeed = 0.0;
  double sleepTime = 0.5;     // s
  // Fluids' warm start (docs/formats.md `warm_start`, FluidParams::warmStart): the fraction
  // of each substep's density multipliers the next substep starts from, and how often they
  // are averaged over neighbours first. 0 = off (the default).
  double warmStart = 0.0;
  int warmSmoothing = 4;
};

// The solver settings a scene file asks for; the radius is half the sketch's voxel size.
PbdParams paramsFromScene(const SceneDesc& scene, double particleRadius);

// The passes of one step, in the order they run (the pass table: kPbdPasses[k] describes pass k).
enum class PbdPass : int {
  kIntegrate,
  kPredict,
  kKinematic,
  kFindContacts,
  kFindNeighbors,
  kFindColliders,
  kFluidNeighbors,
  kClusterMatch,
  kParticleContact,
  kDensity,
  kDistance,
  kRigidContact,
  kBodyContact,
  kColliderContact,
  kUpdate,
  kParticleUpdate,
  kFluidVelocity,
  kPlasticity,
  kRestitution,
  kWriteParticles,
  kGuard,
  kCount
};
extern const PassSpec kPbdPasses[static_cast<int>(PbdPass::kCount)];

// A rope's or cloth's particle mass over a voxel particle's (density x spacing^3): a rope as
// thick as its brush (radius R, BodyRange::radius) is (2R / spacing)^2 voxel chains, a cloth
// 2R / spacing voxel sheets; 1 for the default one-voxel brush (R = spacing / 2) and for every
// other layout. So a rope drawn thick is as much heavier as it looks.
float strandMassScale(const BodyRange& range, double spacing);

class PbdWorld final : public Solver {
 public:
  // particles: positions at rest (velocities ignored; bodies start with their BodyInit);
  // bodies: contiguous ranges. Masses come from material density and the particle spacing (2 r)^3.
  PbdWorld(ParticleArrays particles, const std::vector<BodyRange>& bodies, std::vector<Material> materials,
           const PbdParams& params);

  const char* name() const override { return "pbd"; }
  bool step() override;
  std::vector<PlanEntry> plan() const override;
  std::vector<PlanEntry> planAll() const override;
  const Profile& profile() const override { return profile_; }
  const GuardRecord& guard() const override { return guard_; }
  double contactRadius(std::int32_t i) const override { return radiusOf(std::size_t(i)); }
  bool lattice(int body, std::int32_t& first, std::int32_t& rows, std::int32_t& cols) const override;
  void setValidate(bool on) override { validate_ = on; }
  void setGuardPolicy(GuardPolicy policy) override { guardLog_.policy = policy; }
  const GuardLog& guardLog() const override { return guardLog_; }

  const ParticleArrays& particles() const override { return parts_; }
  int bodyCount() const override { return static_cast<int>(members_.size()); }
  const std::vector<std::int32_t>& bodyParticles(int body) const override { return members_.at(std::size_t(body)); }
  BodyPose pose(int body) const override;
  BodyMode mode(int body) const override { return mode_.at(static_cast<std::size_t>(body)); }
  Vec3 velocity(int body) const override { return motion_.at(std::size_t(body)).v; }
  Vec3 angularVelocity(int body) const override { return motion_.at(std::size_t(body)).w; }
  std::int64_t stepCount() const override { return steps_; }
  double dt() const override { return params_.dt; }
  std::uint64_t stateHash() const override;

  int addBody(const ParticleArrays& particles, const BodyRange& shape, bool kinematic) override;
  void setMode(int body, BodyMode mode) override;
  void setKinematicTarget(int body, const Vec3& centre) override;
  void setVelocity(int body, const Vec3& velocity, const Vec3& angularVelocity) override;
  std::vector<int> removeParticles(const std::vector<std::int32_t>& ids) override;

  const PbdParams& params() const { return params_; }
  // The scene's mesh colliders (pbd/mesh_collider.h); none until set.
  void setColliders(ColliderSet colliders);
  // The fluids' density error rho/rho0 - 1 at the end of the last substep's iterations
  // (fluidCount 0 when the scene has no moving fluid).
  DensityError fluidDensityError() const;
  // With the warm start on (PbdParams::warmStart), how many substeps' density solves were
  // handed no carried multipliers: the first, and the first after any body edit (a sketch edit,
  // a cut, a new body) or after a time when no fluid particle was dynamic. (A fluid without a
  // compliance is handed them but carries none: FluidSolver::warmStart.)
  long fluidColdStarts() const { return fluidColdStarts_; }
  // A cloth particle's normal to its sheet (at the predicted positions; for tests and tools).
  Vec3 clothNormal(std::int32_t i) const { return sheetNormal(std::size_t(i)); }
  // The particle pairs of the body pairs that may touch, at the poses now: what find_contacts
  // hands body_contact (for tests and tools; it refreshes the kept lists and wakes no sleeper,
  // so it never changes what a later step does).
  const BodyPairContacts& bodyPairsNow();
  // Whether a body is asleep (params().sleepSpeed): not simulated until something wakes it.
  bool asleep(int body) const { return std::size_t(body) < asleep_.size() && asleep_[std::size_t(body)] != 0; }
  // Bodies asleep now.
  long sleepingCount() const;
  // Total mass (kg) and rest-frame inertia tensor (kg m^2) of a body.
  double bodyMass(int body) const;
  Mat3 bodyInertiaRest(int body) const;

 private:
  // What a step changes for one body; saved at the start of each step so a tripped
  // guard can replay the step pass by pass.
  struct Motion {
    Vec3 c = Vec3::Zero();      // centre of mass (m)
    Quat q = Quat::Identity();  // rest -> world rotation
    Vec3 v = Vec3::Zero();      // m/s
    Vec3 w = Vec3::Zero();      // rad/s, world frame
    Vec3 cPrev = Vec3::Zero();  // pose at the start of the substep
    Quat qPrev = Quat::Identity();
    Vec3 kinStart = Vec3::Zero(), kinTarget = Vec3::Zero();  // kinematic centre at the start / end of the step
  };
  // What the bodies are now, counted once for work(), reason() and touches().
  struct Census {
    long bodies = 0;        // not emptied
    long rigidDynamic = 0, looseDynamic = 0, kinematic = 0, kinematicLoose = 0;
    long asleep = 0;        // dynamic rigid bodies asleep (not in rigidDynamic)
    long looseAsleep = 0;   // dynamic soft, rope and cloth bodies asleep (not in looseDynamic)
    long soft = 0, strands = 0, fluid = 0;  // dynamic particle-level bodies by kind
    long bouncy = 0;        // dynamic rigid bodies that may bounce (anyBouncyRigid)
    long plastic = 0;       // clusters of dynamic soft bodies with plastic_creep > 0
    bool distances = false; // a distance constraint, attachment or tether with a dynamic end
    // The bodies behind the counts, for reasons that name their strokes and materials.
    std::vector<std::size_t> rigidBodies, looseBodies, softBodies, strandBodies, fluidBodies, bouncyBodies,
        kinematicBodies;
  };
  // "strokes 0, 3 (wood); 5 (water)": the first stroke of each body, grouped by material
  // (at most 6 strokes, then how many more).
  std::string whichStrokes(const std::vector<std::size_t>& bodies) const;
  Census census() const;
  // Which passes have work in the current state (the plan and the step both read it).
  std::vector<bool> work() const;
  bool mayTouch(std::size_t a, std::size_t b, double horizon) const;
  bool bodiesMayTouch() const;
  std::string reason(PbdPass pass, bool on) const;
  std::string touches(PbdPass pass) const;
  std::size_t passBytes(PbdPass pass) const;
  bool runStep(bool checkEachPass);
  template <class F>
  bool runPass(PbdPass pass, int substep, bool check, F&& f);
  GuardRecord checkImplied(bool bodiesOnly, bool penetration) const;
  GuardRecord checkCompression() const;
  GuardRecord checkEnergy();
  // Rigid body pairs that touched in this substep's body_contact (first sweep), for restitution.
  struct PairHit {
    std::int32_t a = 0, b = 0;
    Vec3 point = Vec3::Zero(), normal = Vec3::Zero();  // normal from b towards a
    double approach = 0.0;  // n . (v_a - v_b) at the point before the solve (m/s, < 0 approaching)
  };
  std::vector<PairHit> pairHits_;
  // Scratch of shockPropagation, kept for its capacity.
  std::vector<int> shockLevel_;
  std::vector<std::int32_t> shockQueue_, shockFirst_, shockNext_, shockOrder_;
  void bodyRestitution(double slow);
  // Whether rigid body b, pushed along the unit direction d, is held by what it touched this
  // substep on the side d points to (the contact normal opposing d within 60 degrees): a plane,
  // a fixed or sleeping body, or a dynamic body itself held against d. A body resting on the
  // ground, on a fixed table or on a stack standing on either, hit from above, passes the blow on
  // instead of taking it.
  bool heldAgainst(std::size_t b, const Vec3& d) const;
  // Rigid body pairs that touched in this substep's body_contact with a dynamic body on at least
  // one side, once per dynamic side: the body, what it touched and the contact normal pointing
  // into the body (for heldAgainst; only when restitution runs).
  struct BodyTouch {
    std::int32_t body = 0, other = 0;
    Vec3 normal = Vec3::Zero();
  };
  std::vector<BodyTouch> bodyTouches_;
  bool energyClosed() const;
  EnergySums energyNow() const;

  void integrate(double h);
  void kinematic(int substep);
  void findContacts();
  void rigidContact();
  void findBodyPairs(bool mayWake = true);  // mayWake: wake the sleepers it finds touched (a step's, not bodyPairsNow's)
  // Per body pair that may touch: the particle pairs within the pair radius plus kPairSkin of
  // each other when the list was made, and the two bodies' poses then. A later substep
  // reuses the list while the two bodies together have moved less than the skin since (no
  // pair now within the radius can be missing from it) and filters it by the radius.
  struct PairCache {
    Vec3 ca = Vec3::Zero(), cb = Vec3::Zero();
    Quat qa = Quat::Identity(), qb = Quat::Identity();
    std::uint64_t edits = 0;    // bodyEdits_ when made
    std::int64_t used = -1;     // the substep (usedClock_) that last asked for it
    bool valid = false;
    std::vector<std::int32_t> pairs;  // pa, pb interleaved, sorted by (pa, pb)
  };
  std::unordered_map<std::uint64_t, PairCache> pairCache_;
  std::int64_t usedClock_ = 0;
  std::uint64_t bodyEdits_ = 0;  // bumped whenever a body's members or rest offsets change
  void bodyContact();
  void update(double h);
  void restitution(double h);
  void writeParticles();

  // Particle-level kinds (pbd/world_particles.cpp).
  bool isRigid(std::size_t body) const { return kind_[body] == MaterialKind::kRigid; }
  // A particle's contact radius (m; contactRadius): a rope's or cloth's from its brush
  // (strandRadius_), every other particle's the voxel's half spacing. Pairs touch at the sum of their radii; the
  // ground and mesh colliders hold a particle's centre at its radius.
  double radiusOf(std::size_t i) const {
    const float s = strandRadius_[std::size_t(parts_.group(i))];
    return s > 0.0f ? double(s) : params_.particleRadius;
  }
  // The largest contact radius of a live particle-level body (at least the half spacing).
  double largestContactRadius() const;
  // Whether any rigid body (fixed, carried or dynamic) has restitution > 0. A rigid pair bounces
  // at the mean of its two restitutions, so then every dynamic rigid body may bounce (the
  // restitution pass): one of e = 0 off a body of e > 0, and one of e > 0 off anything.
  bool anyBouncyRigid() const;
  void setupParticleBody(std::size_t body, const BodyRange& range);
  void buildClusters(std::size_t body);
  void buildStrand(std::size_t body, const BodyRange& range);
  void attachStrandEnds(std::size_t body);
  void refreshInverseMasses(std::size_t body);
  void dropRemovedConstraints();
  bool hasLoose() const;
  void predict(double h);
  void kinematicParticles(std::size_t body, const Vec3& delta);
  void findNeighbors();
  void groundLastWord();
  template <typename Solve>
  void shockPropagation(const std::vector<char>& touching, Solve&& solve);
  void particleContact();
  void clusterMatch(double h);
  detail::ClusterView clusterView(std::size_t cluster, const float* x, const float* y, const float* z);
  detail::ClusterMoments clusterMoments(const detail::ClusterView& v, float (&p0)[3]) const;
  void plasticCreep(std::size_t cluster, double h);
  void distanceConstraints(double h);
  void particleUpdate(double h);
  void plasticity(double h);
  void fluidNeighbors();
  void findColliders(int substep);
  void rigidColliderContact();
  void looseColliderContact();
  void density();
  void fluidVelocity(double h);
  // Centre and mean velocity of a particle-level body (its pose and velocity()); true when
  // some particle may fail the guard (non-finite, too fast, below the ground).
  bool summarizeLoose(std::size_t body);
  Vec3 rigidPoint(std::size_t i) const;  // world position of rigid particle i at its body's current pose

  std::size_t pushBodySlot(std::vector<std::int32_t> members, const Motion& motion, const Vec3& restCentre,
                           BodyMode mode, MaterialKind kind = MaterialKind::kRigid);
  MaterialKind kindOf(std::int16_t material) const;
  void appendBody(std::vector<std::int32_t> members, const BodyInit& init, BodyMode mode, MaterialKind kind);
  void refreshMassProperties(std::size_t body);
  void recentre(std::size_t body);
  void holdShape(std::size_t body);
  Vec3 restShapeFromParticles(std::size_t body);  // rest frame := the particles now (a fixed or carried particle-level body)
  std::vector<Vec3i> restCells(std::size_t body) const;
  std::vector<std::vector<std::int32_t>> pieces(std::size_t body) const;
  void labelDesignPieces(std::size_t body);

  PbdParams params_;
  ParticleArrays parts_;
  std::vector<Material> materials_;
  // Per particle (same ids as parts_): rest offset from its body's rest centre of mass (m).
  std::vector<float> rx_, ry_, rz_;
  // Per particle: its design piece within its body (the connected part it was made in).
  std::vector<std::int32_t> design_;
  // Per particle of a rigid body (refreshSurfaceNormals): the outward unit normal of its body's
  // face there, in the rest frame, where it lacks exactly one face neighbour (zero inside, on
  // edges and corners, and in a sheet one particle thick). Fluid particles touching such a
  // particle from outside are pushed along it (the signed-distance gradient FleX keeps on rigid particles,
  // Macklin et al. 2014 §5.1), so a wall's lattice acts as its face, not as spheres with gaps
  // between them that pressure squeezes water through.
  // Made lazily: a body's normals are marked stale when its rest shape changes and refreshed
  // before contacts are found, only in a world with fluid (they cost a third of a 681k-particle
  // box's run, which has none).
  std::vector<Eigen::Vector3f> surfaceNormal_;
  std::vector<char> sheetFace_;  // per particle: surfaceNormal_ is a one-particle sheet's axis (two-sided)
  std::vector<char> normalsStale_;  // per body
  void refreshSurfaceNormals(std::size_t b);
  // Per rigid body: which cells of its rest lattice (one spacing, centred on its particles) it
  // fills, as a bit box, for looseBodySweep. Made lazily, the first substep a particle-level
  // particle's path comes near the body after its rest shape changed (`stale`); `onLattice`
  // false for a body whose particles do not sit on one lattice (one built through the API
  // turned), which keeps contacts alone.
  struct RestCells {
    bool stale = true, onLattice = false;
    Vec3 origin = Vec3::Zero();  // rest offset of cell (0, 0, 0)'s centre (m)
    Vec3i lo = Vec3i::Zero(), size = Vec3i::Zero();
    std::vector<std::uint64_t> bits;  // x fastest, then y, then z, from lo
    bool filled(const Vec3i& c) const;
  };
  std::vector<RestCells> restCells_;
  void refreshRestCells(std::size_t b);
  // A particle-level particle whose move of the substep, relative to a rigid body, enters a
  // cell that body fills stops outside that cell's face (continuous collision against sketched
  // solids: water thrown at a wall one particle thick, faster than contacts can catch); a
  // dynamic body takes its share of the stop. h: the substep (s); a particle and body whose moves
  // add up to less than minMove (m) are not tried.
  void looseBodySweep(double h, double minMove);
  // A rigid body's velocities from its pose now and at the substep's start (update()).
  void velocitiesFromPoses(std::size_t b, double h);
  // Per body.
  std::vector<std::vector<std::int32_t>> members_;  // particle ids, ascending
  std::vector<Motion> motion_;
  std::vector<Vec3> restCentre_;
  std::vector<double> invMass_;             // 1/kg, whole body
  std::vector<Mat3> inertiaRest_, invInertiaRest_;  // rest frame (kg m^2 and inverse)
  std::vector<double> staticFriction_, dynamicFriction_;  // mass-weighted means over the body's materials
  // The body's Material::FrictionRule when all its materials share one (a tool's), else kMean.
  std::vector<Material::FrictionRule> frictionRule_;
  // A material holding only body b's friction (its members' means and rule), and a pair's
  // coefficients at body level (pairFriction on two of them).
  Material bodyFriction(std::size_t b) const;
  void bodyPairFriction(std::size_t a, std::size_t b, double& mus, double& muk) const;
  std::vector<double> restitution_;         // mass-weighted mean over the body's materials
  std::vector<double> reach_;               // m, max |rest offset| + particle radius
  std::vector<Eigen::AlignedBox3d> restBox_;  // per body: the box of its rest offsets (m), grown by r
  std::vector<BodyMode> mode_;
  std::vector<std::int32_t> active_;        // dynamic bodies awake this substep, ascending
  // Sleeping (PbdParams::sleepSpeed). Per body: asleep (its v and w are 0, its particles' velocities
  // 0; the passes treat it as fixed) and how long it has been slower than the sleep speed (s).
  // sleepAllowed_: this step, whether any body may sleep (no collider moving along keyframes:
  // moving colliders do not wake sleepers).
  std::vector<char> asleep_;
  // Per rigid body, this step: awake particle-level material (soft, rope, cloth, fluid) touched it
  // (a particle pair in find_neighbors) or a rope or cloth is tied to it. Such a body falls asleep
  // only with the soft bodies, ropes and cloths it touches (updateSleep), never when fluid touches
  // it or a strand is tied to it, and a rigid sleeper found so wakes before the contacts are
  // solved: the particle-level passes never meet a rigid sleeper, and one meets them only as the
  // fixed solid it is at rest (a fluid's density).
  std::vector<char> looseTouch_;
  void touchedByLoose(std::size_t b);
  std::vector<double> stillFor_;
  // Per body: the pose its still time is measured from (Jolt's sleep test, by displacement): a body
  // counts as still while every point stays within sleepSpeed x sleepTime of where it was then, so
  // a body jittering in place sleeps and one creeping steadily does not.
  struct StillRef {
    Vec3 c = Vec3::Zero();
    Quat q = Quat::Identity();
  };
  std::vector<StillRef> stillRef_;
  bool sleepAllowed_ = false;
  std::uint64_t sleepEdits_ = 0;  // bodyEdits_ when the last step began
  bool moving(std::size_t b) const { return mode_[b] == BodyMode::kDynamic && !(b < asleep_.size() && asleep_[b]); }
  double pointSpeed(std::size_t b, const Vec3& v) const { return v.norm() + motion_[b].w.norm() * reach_[b]; }
  bool sleepPossible() const;
  void wake(std::size_t b);
  void wakeAll();
  void updateSleep();
  // Sleeping particle-level bodies (soft, rope, cloth; fluid never sleeps). Per particle: where
  // its still time began (stillX_..). Per body asleep: its rest offsets before holdShape took the
  // shape it fell asleep in (given back when it wakes: a cut or a later hold reads them), and the
  // box of its particles.
  std::vector<float> stillX_, stillY_, stillZ_;
  std::vector<std::vector<float>> sleepRest_;
  std::vector<Eigen::AlignedBox3d> sleepBox_;
  std::vector<std::vector<std::int32_t>> sleepPartners_;  // per body asleep: the rigid bodies it fell asleep with
  bool looseMaySleep(std::size_t b) const;
  void sleepLoose(std::size_t b);
  void wakeLooseSleepers();
  template <class Remake>
  void reholdRestFrame(std::size_t b, Remake&& remake);
  std::vector<std::size_t> tiePartners(std::size_t b);
  // The pairs of particle-level bodies tied by distance constraints (lower body first, sorted,
  // unique), remade when a body is edited or constraints are added.
  const std::vector<std::pair<std::int32_t, std::int32_t>>& crossTies();
  std::vector<std::pair<std::int32_t, std::int32_t>> crossTies_;
  std::uint64_t crossTiesEdits_ = ~std::uint64_t(0);
  std::size_t crossTiesCount_ = 0;
  ContactSet contacts_;                     // found once per substep
  // Per body: the ground candidates of the last full scan, reused while the body has
  // moved less than half the scan's extra margin (a resting body is scanned once).
  struct GroundCache {
    bool valid = false;
    Quat q = Quat::Identity();
    double cy = 0.0;
    std::vector<std::int32_t> candidates;
  };
  std::vector<GroundCache> groundCache_;
  // The state at the start of the current step, for the guard's replay (step()).
  std::vector<Motion> startMotion_;
  std::vector<GroundCache> startCache_;
  std::vector<float> startLoose_;
  std::vector<char> startAsleep_;
  std::vector<double> startStill_;
  std::vector<StillRef> startStillRef_;
  // --- particle-level kinds -------------------------------------------------
  std::vector<MaterialKind> kind_;  // per body: what it runs as (solverModel(kind, pbd).runsAs)
  std::vector<float> strandRadius_;  // per body: a rope's or cloth's radius from the brush (m), else 0
  std::vector<std::array<std::int32_t, 3>> lattice_;  // per body: a cloth's first id, rows, cols; else rows 0
  std::vector<float> px_, py_, pz_;  // per particle: predicted position this substep (particle-level kinds)
  std::vector<float> invMassP_;      // per particle: 1/kg for a dynamic particle-level particle, else 0
  std::vector<std::uint8_t> pinned_; // per particle: held where it was drawn (a rope end or cloth on a fixed body)
  // Per particle: the body it does not touch (-1: none): a rope's particles within its contact
  // distance of an end tied to a body (pinned, attached or linked) overlap that body where they
  // are tied, and pushing them out of it would fight the tie (a thick rope kinked).
  std::vector<std::int32_t> contactSkip_;
  std::vector<std::int32_t> loose_;  // alive particles of particle-level bodies (ascending), rebuilt by refresh
  // Soft bodies: clusters of radius R, centres at least dC apart (Phys-Sketch Fig. 3).
  struct SoftClusters {
    Clusters members;                 // particle ids per cluster
    std::vector<float> qx, qy, qz;    // per membership: rest offset from the cluster's rest centre (m)
    std::vector<float> lambda;        // per membership: XPBD multiplier of this substep
    std::vector<float> compliance;    // per cluster (m/N)
    // per cluster: plasticity (Müller 2005 §4.4); empty while no cluster is plastic
    std::vector<float> yield, creep;
    std::vector<Quat> rotation;       // per cluster: warm start of the polar decomposition
    std::vector<std::int32_t> body;   // per cluster
    std::vector<Vec3> restCentre;     // per cluster: centre of its members where they were made (m)
    std::vector<float> extent;        // per cluster: farthest member from restCentre then (m)
  } clusters_;
  DistanceConstraints distances_;     // rope and cloth stretch and bending
  std::int32_t nextColour_ = 0;  // the next unused DistanceConstraints colour
  std::vector<std::int32_t> distanceVia_;  // per distance constraint: the node a bending link spans, else -1
  // Clusters in 8 colours for parallel matching: colour = parity of the cell (edge twice the
  // largest cluster extent) of the cluster's rest centre. Clusters of one colour in different
  // cells share no particle; those of one cell are matched in order by one task.
  std::vector<std::vector<std::vector<std::int32_t>>> clusterCells_;  // [colour][cell] -> clusters
  bool clusterColoursDirty_ = true;
  void colourClusters();
  // A strand particle held to a point of a dynamic rigid body (a rope end on a bucket).
  struct Attachment {
    std::int32_t particle = 0, body = 0;
    Vec3 local = Vec3::Zero();  // the point in the body's rest frame, relative to its rest centre
    std::int32_t anchor = -1;   // the pinned particle the strand hangs from, if any (a tether, below)
    float length = 0.0f;        // rest length along the strand from the anchor (m)
  };
  std::vector<Attachment> attachments_;
  // Long-range attachments (Kim et al. 2012, FleX): a strand particle is never farther from
  // its pinned anchor than the rest length along the strand, so a heavy bob cannot stretch
  // a rope that the Gauss-Seidel sweeps converge on slowly.
  struct Tether {
    std::int32_t particle = 0, anchor = 0;
    float length = 0.0f;
  };
  std::vector<Tether> tethers_;
  std::vector<float> groundApproach_;
  // Soft bodies that bounce (dynamic, restitution > 0): contact is resolved particle by particle,
  // which stops the touching layer and lets shape matching average the rest, so they would not
  // bounce; restitution acts on the body instead (Müller 2020 Eq. 34 at the centre of mass, as
  // for rigid bodies). Per body, this substep: the centre-of-mass velocity after predict, and
  // the contacts with the ground, static or keyframed colliders, fixed bodies and dynamic rigid
  // bodies (the sum of their normals, of the pair's e and of the surface's velocity, and their
  // count). Sized to the bodies while some soft body bounces, else empty.
  struct SoftBounce {
    Vec3 vBefore = Vec3::Zero();
    Vec3 nSum = Vec3::Zero(), vSurface = Vec3::Zero();
    double eSum = 0.0;
    int count = 0;
    std::int32_t softPartner = -1;  // another soft body touched (-2: several)
    int softCount = 0;
  };
  std::vector<SoftBounce> softBounce_;
  // The dynamic rigid bodies a bouncing soft body hit this substep (a share of its SoftBounce's
  // sums and count), one entry per pair in the order first hit: the partner's contact points and
  // point velocities when recorded (before the solve).
  struct PartnerHit {
    std::int32_t soft = -1, body = -1;
    int count = 0;
    Vec3 points = Vec3::Zero(), vBefore = Vec3::Zero(), nSum = Vec3::Zero();
    double eSum = 0.0;
  };
  std::vector<PartnerHit> partnerHits_;
  // A contact takes part in a soft body's bounce only while the particle approaches the surface
  // faster than 2 |g| h (relative velocity before the solve, normal towards the particle): a
  // ball sliding on the ground into a wall bounces off the wall alone, the ground it rests on
  // neither tilting the bounce nor making it a contact with "a dynamic body and something else".
  bool approaching(const Vec3& relativeVelocity, const Vec3& normal) const {
    return relativeVelocity.dot(normal) < -2.0 * params_.gravity.norm() * params_.dt / params_.substeps;
  }
  // Particle by particle (rope, cloth, fluid and soft bodies that do not bounce as a whole): the
  // first contact of this substep with a rigid body, a collider or a particle of another such
  // body whose restitution e (the pair's mean with a body or particle, the particle's own
  // against a collider) is > 0, with the normal (from the surface to the particle) and the
  // normal approach speed before the solve (< 0).
  // particle_update lets the particle leave at e times it, as it does at the ground. Recorded
  // in the serial contact sweeps (a fixed order); bounceNoted_ marks the particles recorded.
  struct ParticleBounce {
    std::int32_t particle = 0;
    std::int32_t body = -1;   // the rigid body touched, -1: a collider, -2: another such particle
    std::int32_t other = 0;   // the body's particle at the contact, the collider's index, or the particle
    Vec3 normal = Vec3::Zero();
    Vec3 point = Vec3::Zero();  // a collider's contact point (m)
    double approach = 0.0;      // m/s, < 0
    double e = 0.0;
  };
  std::vector<ParticleBounce> particleBounces_;
  std::vector<double> bounceImpulse_;  // particleRestitution's accumulated impulse per record
  std::vector<std::uint8_t> bounceNoted_;
  void noteParticleBounce(const ParticleBounce& b);
  void particleRestitution(double h);
  bool dynamicSoft(std::size_t b) const { return kind_[b] == MaterialKind::kSoft && moving(b); }
  // A dynamic soft body bounces as a whole (softBodyRestitution) when its material has e > 0 or
  // anything it can hit does: a pair bounces at the mean of its two restitutions, so a soft body
  // of e = 0 leaves a slab of e = 0.8 at 0.4. anyBouncy_: some body's restitution is > 0 (set by
  // predict, every substep).
  bool bouncySoft(std::size_t b) const { return dynamicSoft(b) && (restitution_[b] > 0.0 || anyBouncy_); }
  bool anyBouncy_ = false;
  Vec3 centreVelocity(std::size_t b) const;
  Vec3 massMean(std::size_t b, const std::vector<float>& x, const std::vector<float>& y, const std::vector<float>& z) const;
  void softBodyRestitution(double h);
  // The surfaces a soft body hit this substep, as one contact: the ground, colliders, fixed
  // bodies and partners held against the blow (sums of their normals, e, count, and surface
  // velocities before the solve and now).
  struct SurfaceHits {
    Vec3 nSum = Vec3::Zero(), before = Vec3::Zero(), after = Vec3::Zero();
    double eSum = 0.0;
    int count = 0;
  };
  template <class Kick>
  void bounceOffPartners(std::size_t b, double mass, double slow, const SurfaceHits& surfaces,
                         const std::vector<const PartnerHit*>& partners, Kick&& kick);
  bool particleLevel_ = false;  // the arrays above (px_ .. groundApproach_) exist: some body is particle-level
  void ensureParticleLevel();
  bool pinnedAt(std::size_t k) const { return particleLevel_ && pinned_[k]; }
  // Fluids: the PBF kernel (pbd/fluid.h), made when the first fluid body is, and the
  // particles it works on this substep (fluid first, then solids in range), by kernel id.
  std::unique_ptr<FluidSolver> fluid_;
  // Mesh colliders and the contacts found this substep: particle-level particles (index into
  // loose_) and rigid bodies' particles (by body, positions at the substep's predicted pose).
  std::unique_ptr<ColliderSet> colliders_;
  std::vector<MeshContact> looseHits_;
  struct BodyColliderContacts {
    std::int32_t body = 0;
    std::vector<std::int32_t> particle;  // particle ids
    std::vector<MeshContact> contact;    // contact k of particle[k]
  };
  std::vector<BodyColliderContacts> bodyHits_;
  std::vector<std::int32_t> fluidIds_;
  std::size_t fluidCount_ = 0;
  // The fluid's sound speed (m/s): the material's, or the largest autoSoundSpeed so far (it
  // only rises: a stiffness that rose and fell with the fluid's height would pump energy).
  float fluidSoundSpeed_ = 0.0f, startSoundSpeed_ = 0.0f;
  bool fluidSoundAuto_ = true;  // some fluid material leaves sound_speed unset
  // The fluid materials in the scene (indices into materials_, by first appearance); with
  // more than one parameter set among them (fluidMixed_) the kernel takes per-particle
  // parameters (FluidInput), else one set.
  std::vector<std::size_t> fluidMaterials_;
  bool fluidMixed_ = false;
  // Some fluid material sets xsph_viscosity, vorticity, cohesion or a viscosity above
  // FluidSolver::kNegligibleViscosity.
  bool fluidVelocity_ = false;
  // What the last viscous solve dragged back: dynamic rigid bodies, loose solid particles.
  std::size_t viscousBodies_ = 0, viscousLoose_ = 0;
  float fluidSoundOf(const Material& m) const;
  std::string fluidSoundText() const;
  std::vector<float> fx_, fy_, fz_, fw_, frho_, fdx_, fdy_, fdz_;
  // The warm start (PbdParams::warmStart): the fluid particles' multipliers at the end of the
  // last substep, with their ids (the first fluidCount_ of fluidIds_ then), kept at the start
  // of a step for the guard's replay; carried only while the fluid's particles are the same.
  std::vector<float> fluidCarry_, startCarry_, fcarried_;
  std::vector<std::int32_t> fluidCarryIds_, startCarryIds_;
  std::uint64_t fluidCarryEdits_ = 0;  // bodyEdits_ when the carry was kept (bodyEdits_ is not replayed)
  // The running substep's number (steps_ x substeps + s) and the one whose multipliers the carry
  // holds: a carry is used only in the substep right after it was kept.
  std::int64_t substepStamp_ = 0, fluidCarryStamp_ = -2, startCarryStamp_ = -2;
  long fluidColdStarts_ = 0, startColdStarts_ = 0;  // fluidColdStarts(); at the start of a step, for the replay
  int densityIteration_ = 0;  // density passes run this substep
  // A thick rope's particle enters the fluid kernel as n x n solid samples filling its square
  // cross-section (n = round(2 radius / spacing), the cross-section its mass is), a thick
  // cloth's as n samples across its sheet (along sheetNormal), each with its offset from the
  // particle (m) and its share of the particle's mass (1 / n^2, 1 / n); every other entry has
  // offset 0 and share 1 (fluidNeighbors).
  // Kept for the solid entries only (index k - fluidCount_): fluid entries are never samples.
  struct FluidSample {
    float x, y, z, share;
  };
  std::vector<FluidSample> fsample_;
  Vec3 sampleOffset(std::size_t k) const {
    if (k < fluidCount_) return Vec3::Zero();
    const FluidSample& s = fsample_[k - fluidCount_];
    return Vec3(s.x, s.y, s.z);
  }
  float sampleShare(std::size_t k) const { return k < fluidCount_ ? 1.0f : fsample_[k - fluidCount_].share; }
  int strandSamples(std::size_t i) const;
  Vec3 strandTangent(std::size_t i) const;
  Vec3 sheetNormal(std::size_t i) const;
  void loadFluidPositions();
  void applyFluidCorrections();
  std::vector<float> frelax_, fxsph_, fvort_, fcoh_, fsound_, fmu_;  // per kernel particle, fluidMixed_ only
  std::vector<std::uint8_t> fflag_;
  void makeFluidSolver();
  bool looseDirty_ = true;             // loose_ must be rebuilt before the next step  // per particle: vy before the solve when it touched the ground, else 0
  std::int64_t steps_ = 0;
  bool validate_ = false;
  GuardLog guardLog_;  // the events a run continued past (policy warn)
  std::vector<bool> work_;      // the passes this step runs (work() at its start)
  bool writtenSuspect_ = true;  // write_particles' summary: some particle may fail the guard
  Profile profile_{kPbdPasses};
  GuardRecord guard_;
  EnergyWatch energy_;  // energy growth while closed; reset by every outside event
};

}  // namespace physketch::pbd
