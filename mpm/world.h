// The MPM world: MLS-MPM (Hu et al. 2018) with APIC transfers (Jiang et al. 2015) and
// quadratic B-splines on a background grid over the scene's workspace. One step runs the
// passes of kMpmPasses, substeps times (VR-Doh supplement Algorithm 1), then the guard:
//
//   for each substep (h = dt / substeps):
//     p2g          particles sorted by 4^3 block; mass and momentum scattered to the grid
//                  block colour by block colour (no float atomics):
//                    m_i += w_ip m_p,
//                    (m v)_i += w_ip (m_p v_p + (m_p C_p - h V_p 4/dx^2 tau_p)(x_i - x_p))
//                  (Hu et al. 2018 Eq. 16-17; tau = P F^T the Kirchhoff stress)
//     grid_update  v_i = (m v)_i / m_i + h g; nodes a carried body (a tool) holds push with its
//                  velocity; nodes inside a mesh collider or a fixed body (as a distance
//                  field) and at the walls and ground: sticky, slip or separate with friction
//     g2p          v_p = sum w v_i, C_p = 4/dx^2 sum w v_i (x_i - x_p)^T, x_p += h v_p,
//                  F_p <- (I + h C_p) F_p (fluid: J_p <- (1 + h tr C_p) J_p)
//     projection   particles the grid let past a wall or the ground are put back on it and
//                  lose their velocity into it (never outside the grid)
//     plasticity   return maps on F: Drucker-Prager (sand), von Mises (plasticine), snow clamp
//   guard          first NaN, explosion, inverted F (J <= 0) or CFL violation, once per step
//
// Particles keep their ids (ParticleArrays); the solver visits them through a permutation
// sorted by grid block, rebuilt every substep with a stable counting sort.
#pragma once

#include <algorithm>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/material.h"
#include "core/math.h"
#include "core/neighbor_grid.h"
#include "core/scene.h"
#include "core/solver.h"
#include "core/triangle_soup.h"
#include "mpm/collider_sdf.h"

namespace physketch::mpm {

// How a domain wall or the ground acts on grid velocities (VR-Doh supplement §1.1):
// sticky: v = 0; slip: the normal component into the wall removed; separate: as slip, and
// only while moving into the wall, with Coulomb friction on the tangential part: each node's
// coefficients are the mass-weighted means of the materials whose particles reach it
// (static_friction, dynamic_friction).
enum class WallKind { kSticky, kSlip, kSeparate };
const char* toString(WallKind kind);
// "separate" when every wall is, else "x- sticky, x+ slip, ..." in that order.
std::string wallsText(const WallKind (&walls)[6]);

struct MpmParams {
  double dt = 1.0 / 60.0;  // s per step
  int substeps = 0;        // per step; 0 = auto: the fewest that meet the bounds, chosen every step
  Vec3 gravity{0.0, -9.81, 0.0};
  double groundY = 0.0;    // m, the ground plane y = groundY (below the domain: none)
  double spacing = 0.0;    // m, particle spacing h (the sketch's voxel size); volume h^3 per particle
  double dxPerSpacing = 2.0;  // grid spacing dx = dxPerSpacing * h (2: eight particles per cell)
  Vec3 domainMin = Vec3(-0.5, 0.0, -0.5);  // m, corner of the simulated cube (the workspace)
  double domainSize = 1.0;                 // m, its edge
  // The domain walls x-, x+, y-, y+, z-, z+ (y-: the floor, and the ground plane inside the domain).
  WallKind walls[6] = {WallKind::kSeparate, WallKind::kSeparate, WallKind::kSeparate,
                       WallKind::kSeparate, WallKind::kSeparate, WallKind::kSeparate};
  double waveCourant = 0.5;    // C in h <= C dx / c_p (c_p the material's P-wave speed)
  double velocityCourant = 0.5;  // h <= velocityCourant dx / |v|max
  double maxSpeed = 100.0;     // m/s, the guard's explosion bound
  // Fluid particle shifting (the particle_shift pass, once a step): dynamic fluid particles
  // closer than particleShift x spacing are pushed apart, each pair by half its overlap, in two
  // Jacobi sweeps of at most spacing / 4 each (never outwards at a sheet's rim, an edge or a
  // corner); a particle takes its affine field's velocity at its new place (v + C dx). 0 = off.
  // MLS-MPM's grid cannot see a particle arrangement finer than a cell, so in a fluid sheet
  // thinner than a cell particles gather onto one another (Xu et al. 2009's shifting for SPH;
  // docs/mpm.md).
  double particleShift = 0.0;
};

// The solver settings a scene asks for; `spacing` is the sketch's voxel size.
MpmParams paramsFromScene(const SceneDesc& scene, double spacing);

enum class MpmPass : int { kP2G, kGridUpdate, kG2P, kProjection, kPlasticity, kShift, kGuard, kCount };
extern const PassSpec kMpmPasses[static_cast<int>(MpmPass::kCount)];

// The explicit time-step bound of a material: h <= waveCourant dx / c_p.
struct StepBound {
  double h = 0.0;          // s, the largest stable substep
  double waveSpeed = 0.0;  // m/s, c_p
  int material = -1;       // the material that sets it
};

class MpmWorld final : public Solver {
 public:
  // particles: positions at rest; bodies: contiguous ranges (one group each). Masses are
  // density * h^3; velocities start from each body's BodyInit (vel=, spin=).
  MpmWorld(ParticleArrays particles, const std::vector<BodyRange>& bodies, std::vector<Material> materials,
           const MpmParams& params);

  const char* name() const override { return "mpm"; }
  bool step() override;
  std::vector<PlanEntry> plan() const override;
  std::vector<PlanEntry> planAll() const override;
  const Profile& profile() const override { return profile_; }
  const GuardRecord& guard() const override { return guard_; }
  void setValidate(bool on) override { validate_ = on; }
  // P2G's and G2P's node loops and the return maps' SVDs (svd3Many) in AVX2 where the CPU has
  // it (the default), else SSE; both give bit-identical results. False forces SSE (tests
  // compare the two).
  void setAvx2(bool on) { avx2_ = on && avx2Supported(); }
  // P2G computes a fluid's stress in its own loop (the default) or through kirchhoff(), as every
  // other material's: the same bits either way (a test holds them to it).
  void setFluidStressInline(bool on) { fluidInline_ = on; }
  // P2G's stress for plastic materials from the return map's SVD of the substep before, and
  // for fixed-corotated ones from their rotation of the substep before (the default; see svdU_
  // and polarQ_), or from an SVD of its own (false: tests compare the two).
  void setSvdCache(bool on) { svdCacheOn_ = on; }
  static bool avx2Supported();
  void setGuardPolicy(GuardPolicy policy) override { guardLog_.policy = policy; }
  const GuardLog& guardLog() const override { return guardLog_; }

  // A particle's affine velocity C (APIC / MLS-MPM, 1/s): its velocity field about it is
  // v + C (x - x_p). With the quadratic B-splines' D = dx^2/4 I, its angular momentum beyond
  // m x_p x v_p is m dx^2/4 (C_zy - C_yz, C_xz - C_zx, C_yx - C_xy) (Jiang et al. 2015).
  const Eigen::Matrix3f& affineVelocity(std::size_t i) const { return C_.at(i); }
  const ParticleArrays& particles() const override { return parts_; }
  int bodyCount() const override { return static_cast<int>(members_.size()); }
  const std::vector<std::int32_t>& bodyParticles(int body) const override { return members_.at(std::size_t(body)); }
  // MPM bodies deform: the pose is the identity placed at the body's centre of mass.
  BodyPose pose(int body) const override;
  BodyMode mode(int body) const override { return mode_.at(static_cast<std::size_t>(body)); }
  Vec3 velocity(int body) const override;
  Vec3 angularVelocity(int body) const override;
  std::int64_t stepCount() const override { return steps_; }
  double dt() const override { return params_.dt; }
  std::uint64_t stateHash() const override;
  // The energy sums of the dynamic particles the last step's guard read (summed in the step's
  // last g2p, StepSummary), or nullptr where that step's guard swept them itself (colliders,
  // plasticity) or no step ran.
  const EnergySums* lastStepEnergy() const { return summary_.valid ? &summary_.energy : nullptr; }

  int addBody(const ParticleArrays& particles, const BodyRange& shape, bool kinematic) override;
  void setMode(int body, BodyMode mode) override;
  void setKinematicTarget(int body, const Vec3& centre) override;
  void setVelocity(int body, const Vec3& velocity, const Vec3& angularVelocity) override;
  // Marks the particles removed; a body they disconnect in its rest lattice is split as
  // Solver::removeParticles says (fluid bodies are not split). Returns the bodies changed or
  // created, ascending.
  std::vector<int> removeParticles(const std::vector<std::int32_t>& ids) override;

  // The scene's mesh colliders (static or keyframed), meshes[i] for descs[i]: each becomes a
  // distance field (mpm/collider_sdf.h, voxel dx/2) that grid_update imposes on the nodes inside
  // it (separate, with Coulomb friction, relative to the collider's motion) and projection on
  // the particles inside it (pushed out along the normal). An open sheet is a shell 1.5 dx thick.
  // Returns, per collider, a warning where its field had to be coarser than dx/2 (a mesh too
  // large for maxBandVoxels at dx/2), else an empty string.
  std::vector<std::string> setColliders(const std::vector<MeshCollider>& descs, const std::vector<TriangleSoup>& meshes,
                                        double maxBandVoxels = ColliderSdf::kMaxBandVoxels);
  int colliderCount() const { return int(meshColliderCount()); }  // the scene's mesh colliders

  const MpmParams& params() const { return params_; }
  double dx() const { return dx_; }
  // The tightest explicit bound over the materials of the dynamic particles (h = +inf when none).
  StepBound waveBound() const;
  // Substeps the next step runs: the fixed count, or (auto) the fewest meeting the wave and
  // velocity bounds; 0 when auto would need more than kMaxSubsteps.
  int substepsForNextStep() const;
  bool boundMayTighten() const;
  GuardRecord tooManySubsteps() const;
  int lastSubsteps() const override { return params_.substeps == 0 ? lastSubsteps_ : 0; }
  // Warnings about the settings (a fixed substep count above the bound), once, at start.
  const std::vector<std::string>& warnings() const { return warnings_; }
  // Per particle: deformation gradient (row-major 3x3) and the plastic scalar (snow J_p,
  // sand's accumulated plastic strain q, fluid J).
  Eigen::Matrix3f deformation(std::int32_t i) const { return F_.at(std::size_t(i)); }
  Mat3 deformationGradient(std::int32_t i) const override;
  bool massField(const std::vector<std::int32_t>& ids, NodeField& out) const override;
  float plasticScalar(std::int32_t i) const { return plastic_.at(std::size_t(i)); }
  // Particle-substeps at the domain's edge (within 1.5 dx of one of its six walls, where the
  // wall's nodes act on the particle; a ground the scene sets is not an edge), since the start,
  // and the first particle there (a particle the grid would move out is stopped at the wall).
  std::int64_t atDomainEdge() const { return atEdge_; }
  struct EdgeHit {
    std::int32_t particle = -1;  // the first particle there (lowest id in the first substep with any)
    std::int8_t wall = -1;       // 0..5: x-, x+, y-, y+, z-, z+
    std::int64_t step = -1;
    int substep = -1;
  };
  const EdgeHit& firstAtEdge() const { return firstEdge_; }
  std::vector<std::string> runNotes() const override;
  double pressure(std::int32_t i) const override;
  // Total mass (kg) and momentum (kg m/s) on the grid after the last P2G, and of the particles now.
  double gridMass() const;
  Vec3 gridMomentum() const;

  static constexpr int kMaxSubsteps = 1000;

 private:
  // Per material, what the passes read (precomputed from Material).
  struct MatModel {
    MaterialKind kind = MaterialKind::kElastic;  // as run
    ElasticModel elastic = ElasticModel::kCorotated;
    float mu = 0.0f, lambda = 0.0f;    // Pa
    float mass = 0.0f;                 // kg per particle, density * h^3
    float mus = 0.0f, muk = 0.0f;      // static and dynamic friction against walls and ground
    float alpha = 0.0f, shift = 0.0f;  // sand: Drucker-Prager alpha and cohesion strain
    float frictionDeg = 0.0f, hardeningDeg = 0.0f;
    bool klar = false;                 // sand: Klár et al. 2016's hardening law, angle h0 + (h1 q - h3) e^(-h2 q)
    float h0 = 0.0f, h1 = 0.0f, h2 = 0.0f, h3 = 0.0f;  // degrees, but h2 (per unit q)
    float thetaC = 0.0f, thetaS = 0.0f, xi = 0.0f;  // snow
    float yield = 0.0f;                // plasticine: tau_Y
    float bulk = 0.0f, gamma = 7.0f, viscosity = 0.0f;  // fluid
    bool plastic = false;
    bool ownFriction = false;          // Material::FrictionRule::kOwn: its mus/muk decide its contacts (a tool with friction=)
  };
  // The state a step changes, for the guard's replay. A member, copied into at each step's
  // start: its arrays keep their capacity, so a step allocates nothing (a fresh copy per step
  // cost a page fault per 4 KiB of state, 11 % of a 64k-particle step).
  struct Saved {
    std::vector<float> x, y, z, vx, vy, vz, plastic, fluidJ;
    std::vector<Eigen::Matrix3f> C, F;
    std::int64_t atEdge = 0;
    EdgeHit firstEdge;
  };
  Saved start_;

  void initGrid();
  void initParticle(std::size_t i);
  void applyInit(const std::vector<std::int32_t>& ids, const BodyInit& init);
  void recordRestLattice(const std::vector<std::int32_t>& ids);
  std::vector<int> splitCut(int body);
  Vec3 centreOfMass(std::size_t body) const;
  std::vector<bool> work() const;
  std::string reason(MpmPass pass, bool on) const;
  std::string touches(MpmPass pass) const;
  bool runStep(int substeps, bool checkEachPass);
  template <class F>
  bool runPass(MpmPass pass, int substep, bool check, F&& f);
  GuardRecord check(MpmPass pass) const;
  GuardRecord checkEnergy(const EnergySums* sums = nullptr);
  bool energyClosed() const;

  void sortByBlock();
  void p2g(float h);
  void gridUpdate(float h);
  // g2p also puts particles past a wall or the ground back on it (the projection's walls: see
  // projection()), and, with `summarize`, sums the end-of-step guard's checks (StepSummary).
  void g2p(float h, int substep, bool summarize);
  void projection();
  void shiftFluid();
  void plasticity();
  template <class Fn>
  void forPlasticSvds(const Fn& fn);
  static constexpr std::size_t kPlasticBatch = 64;
  void decomposePlastic();
  Eigen::Matrix3f kirchhoff(std::size_t i);
  std::size_t passBytes(MpmPass pass) const;

  MpmParams params_;
  ParticleArrays parts_;
  std::vector<Material> materials_;  // as the scene gives them (names for messages)
  std::vector<MatModel> models_;     // per material, as MPM runs it
  // Per particle (ids as parts_): affine velocity C (1/s), deformation gradient F, plastic scalar.
  std::vector<Eigen::Matrix3f> C_, F_;
  // Plastic materials: the SVD the return map made of each particle's F in the last substep
  // (F = U diag(s) V^T is what it wrote), which the next substep's P2G stress needs again: U and
  // the Hencky strain ln(s) for the Hencky models (sand, plasticine: the return map's projected
  // strain, or logLane's bits of s where it kept sigma), R = U V^T
  // in svdU_ for snow. Valid within a
  // step (svdCached_): a step's first P2G fills them from the step's start state
  // (decomposePlastic, the same bits as an SVD of its own), so a step depends on its start state
  // alone (the guard's replays repeat it bit for bit). Sized to the particles when a plastic
  // material exists.
  std::vector<Eigen::Matrix3f> svdU_;
  std::vector<Eigen::Vector3f> svdLnS_;
  bool svdCached_ = false;
  bool svdCacheOn_ = true;
  // Fixed-corotated elastic materials: each particle's polar rotation of the substep before, as
  // a unit quaternion (x y z w), where P2G's next one starts (polarFrom: a turn or two, not an
  // SVD). Valid from a step's first P2G to the step's end (polarCached_), like svdU_.
  std::vector<Eigen::Vector4f> polarQ_;
  bool polarCached_ = false;
  std::vector<float> plastic_;
  // Per particle, fluids: the J its pressure is computed from -- J-bar, the B-spline average
  // through the grid of its neighbours' J, advanced by the substep's divergence. A particle's
  // own J (plastic_) has modes the grid does not see (8 particles per cell, one node): next to
  // a held node or a collider one layer kept J = 1 and the next took its load, and a collider's
  // position projection drove single particles' J anywhere in 0.3..2 (pool in an open cup).
  // The own J relaxes towards J-bar by kJbarRelax per substep, which bounds that drift.
  std::vector<float> fluidJ_;
  static constexpr float kJbarRelax = 0.05f;
  // Per body.
  std::vector<std::vector<std::int32_t>> members_;
  std::vector<Vec3i> restCell_;          // per particle: its cell in its body's rest lattice (cuts)
  std::vector<std::int32_t> design_;     // per particle: its design piece within its body (cuts)
  std::vector<BodyMode> mode_;
  std::vector<Vec3> carry_;  // m/s, a kinematic body's velocity this step (kept when released)

  // Grid: nodes n_ per axis (a multiple of 4), stored block-major (4^3 nodes per block) so a
  // block's nodes are contiguous. Node (i,j,k) sits at origin_ + dx_ (i,j,k).
  double dx_ = 0.0;
  Vec3 origin_ = Vec3::Zero();
  int n_ = 0, nb_ = 0;  // nodes and blocks per axis
  Eigen::Vector3i wallLo_, wallHi_;  // nodes with index <= wallLo or >= wallHi are wall nodes
  int groundNode_ = -1;              // nodes with j <= groundNode are ground nodes
  float lo_[3] = {0, 0, 0}, hi_[3] = {0, 0, 0};  // the walls (m), for the projection
  // particle_shift's buffers (MpmParams::particleShift): the fluid's ids, their neighbours.
  std::vector<std::int32_t> shiftIds_;
  std::vector<float> shiftX_, shiftY_, shiftZ_, shiftD_;
  NeighborGrid shiftGrid_;
  NeighborLists shiftLists_;
  // A node's mass (kg) and momentum (kg m/s), then velocity (m/s): one 16-byte record, so
  // that P2G's and G2P's 27 nodes touch one cache line each, not four.
  struct Node {
    float m, x, y, z;
  };
  std::vector<Node> grid_;
  // Wall friction per node, where materials differ in it: mass times static / dynamic friction
  // (kg), scattered like the mass. Where all materials share it, it is uniformMus_/Muk_ and
  // these stay empty (P2G scatters four values per node, not six).
  bool mixedFriction_ = false;
  float uniformMus_ = 0.0f, uniformMuk_ = 0.0f;
  std::vector<float> gfs_, gfk_;
  // J-bar for fluids: per node the fluid mass and mass times J (kg), interleaved, scattered like
  // the mass (after grid_update: the node's mass, and unused); empty without a fluid material.
  // See fluidJ_.
  std::vector<float> jbar_;
  // Every dynamic particle is a fluid (set each step): a node's fluid mass is its mass, so p2g
  // scatters m J alone and grid_update divides by the node's mass.
  bool fluidOnly_ = false;
  // A node's mass after grid_update (a fluid scene's record carries J_node in its mass lane then).
  float nodeMass(std::size_t node) const { return jbar_.empty() ? grid_[node].m : jbar_[2 * node]; }
  // Per node 3, where a mesh collider exists (else empty): sum of w m (x_p - x_node) (kg m),
  // scattered like the mass: which side of a collider's surface the node's material is on. A
  // sheet has two sides and no inside, and a thin closed wall's far half has its normals
  // pointing away from the material: there a node's normal turns to face its material, so a
  // node just past a floor, reached only by the water above it, holds that water up instead
  // of letting it through (collideNode).
  std::vector<float> side_;
  // Mesh colliders, and their poses at the start (0) and end (1) of the current substep.
  struct Collider {
    MeshCollider desc;
    ColliderSdf sdf;
    Mat3 R0 = Mat3::Identity(), R1 = Mat3::Identity();
    Vec3 p0 = Vec3::Zero(), p1 = Vec3::Zero();
    Vec3 lo = Vec3::Zero(), hi = Vec3::Zero();  // world bounds at the end pose (m)
    // A world point x inside the collider at the end pose (phi < 0): its point in the
    // collider's frame, its depth phi (m), and the unit outward normal in the world where the
    // field has a gradient (hasNormal). False outside (or outside its bounds).
    struct Probe {
      Vec3 local = Vec3::Zero(), normal = Vec3::Zero();
      double phi = 0.0;
      bool hasNormal = false;
    };
    // anywhere: also where phi >= 0 within the narrow band (an open sheet's far side).
    bool probe(const Vec3& x, Probe& out, bool anywhere = false) const;
    // The collider's velocity at a world point now at x whose local point is `local`: where
    // that material point was at the substep's start, over the substep h.
    Vec3 velocityAt(const Vec3& x, const Vec3& local, double h) const { return (x - (R0 * local + p0)) / h; }
    int body = -1;  // the fixed body this collider stands for; -1: a scene mesh collider
    // A fixed body's own friction (static, dynamic: the mean over its particles' materials):
    // a contact with it takes the mean of these and the touching material's, as between two
    // scene materials (docs/formats.md). NaN: a mesh collider (its friction=, else the material's).
    float ownMus = std::numeric_limits<float>::quiet_NaN(), ownMuk = std::numeric_limits<float>::quiet_NaN();
    // A static collider's cells (of the MPM grid, over its world bounds) that its field may
    // answer in (within its band or inside), grown by the band's reach: probe skips the field
    // elsewhere (most of a pool's particles, every substep). Empty: no mask (a moving collider).
    std::vector<std::uint8_t> near{};
    Vec3i nearLo = Vec3i::Zero(), nearDims = Vec3i::Zero();
    Vec3 gridOrigin = Vec3::Zero();
    double gridDx = 0.0;
  };
  void buildNearMask(Collider& c) const;
  // The scene's mesh colliders, then one per fixed body (ascending body id).
  std::vector<Collider> colliders_;
  // A fixed body is a collider, not a set of held grid nodes: its particles' voxels (cubes of
  // side spacing around them) become a closed surface and its distance field (voxel spacing/2,
  // aligned to the voxels' faces). Holding every node of its particles' stencils (as it once
  // did) made the body a grid cell thicker on each side: a sketched cup with a 10-voxel
  // interior held water only 7 voxels wide. The bodies whose field is out of date (made or
  // unmade fixed, or cut) are rebuilt before the next step (and at construction, for the plan).
  std::vector<int> fixedDirty_;
  // Whether any body is carried (a tool): only then do the passes look for held nodes.
  bool anyCarried() const { return std::find(mode_.begin(), mode_.end(), BodyMode::kKinematic) != mode_.end(); }
  void syncFixedColliders();
  std::size_t meshColliderCount() const;
  std::string collidersText() const;  // ", 2 mesh collider(s), 1 fixed body (...)" for the plan
  void poseColliders(double t0, double h);
  // Imposes the colliders on a node (world position x) of velocity v; mus, muk: the node's
  // material friction (a collider's friction= replaces it).
  // side: the node's sum of w m (x_p - x_node) over its particles (kg m) and m its mass, where
  // sheets exist (else null): which side of a sheet the node's material is on.
  void collideNode(const Vec3& x, float v[3], float h, float mus, float muk, const float* side = nullptr,
                   float m = 0.0f) const;
  // h: the substep the colliders' poses span (0: they stand still, before a step).
  void pushOutOfColliders(std::size_t i, double h);
  bool placeInColliders_ = false;  // particles or colliders came: push material out before the next step
  float lastH_ = 0.0f;  // s, the current substep
  std::vector<std::uint8_t> held_;        // 1: a node a carried body holds (one-sided)
  std::vector<float> hx_, hy_, hz_;       // m/s, the held velocity (allocated when first needed)
  std::vector<float> hn_;                 // per node 3: a carried body's outward normal (not unit)
  // Per node held by a carried body whose material's friction decides its contacts (a tool with
  // friction=mu): that mu (static, dynamic); NaN elsewhere. Allocated with the first such body.
  std::vector<float> hmus_, hmuk_;
  // Sorting: dynamic particles by block, and the blocks that have any, by colour.
  std::vector<std::int32_t> order_, blockStart_, blockKey_, blockFill_;
  std::vector<std::uint8_t> keyChanged_;  // per chunk of particles: a block key changed since the last sort
  std::vector<std::int32_t> colourBlocks_[8];
  std::vector<std::int32_t> particleBlocks_;  // the blocks that hold dynamic particles, ascending
  std::vector<std::int32_t> activeNodeBlocks_;
  std::vector<std::uint8_t> nodeBlockMark_;

  std::int64_t steps_ = 0;
  std::int64_t atEdge_ = 0;
  EdgeHit firstEdge_;
  // Per block of g2p's loop (particleBlocks_ order): the walls' projection there (particles at
  // the domain's edge, the lowest id among them and its wall) and, on a summarized substep, the
  // guard's per-particle checks: any non-finite position or velocity and the fastest particle
  // (checkParticles' pre-check), an inversion (J <= 0) and a speed past the CFL bound (check's),
  // and the energy sums (checkEnergy's).
  struct BlockTail {
    std::int64_t atEdge = 0;
    std::int32_t firstEdge = -1;
    std::int8_t edgeSide = -1;
    float nonFinite = 0.0f, fastest2 = 0.0f;
    bool inverted = false, fast = false;
    EnergySums energy;
    // Every substep: the lowest id faster than the CFL bound before the walls stopped it, and
    // its speed squared (check(kG2P) reads it: the transfer's locality broke, wall or not).
    std::int32_t cflFirst = -1;
    double cflSpeed2 = 0.0;
  };
  std::vector<BlockTail> blockTails_;
  // The end-of-step guard's checks as the step's last g2p summed them, while the particles were in
  // registers (the guard's three sweeps over every particle cost 6 % of a fluid cube's step). Valid
  // only where nothing moves a particle or changes its F after that g2p: no collider's push-out
  // and no plasticity (their scenes keep the sweeps). Where it flags anything, the sweeps run
  // (and the step's replay names the pass) as they always did.
  struct StepSummary {
    bool valid = false;
    bool suspect = false;  // a non-finite value, or a speed near or above maxSpeed
    bool inverted = false, fast = false;
    EnergySums energy;
  };
  StepSummary summary_;
  int lastSubsteps_ = 0;  // the last step's substeps (more than it started with where runStep cut the rest finer)
  double substepH_ = 0.0;  // s, the current substep (as double: the CFL bound dx / h)
  bool validate_ = false;
  bool avx2_ = avx2Supported();
  bool fluidInline_ = true;
  GuardLog guardLog_;  // the events a run continued past (policy warn)
  std::vector<bool> work_;
  std::vector<std::string> warnings_;
  Profile profile_{kMpmPasses};
  GuardRecord guard_;
  EnergyWatch energy_;  // energy growth while closed; reset by every outside event
};

}  // namespace physketch::mpm
