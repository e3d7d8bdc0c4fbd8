// Position Based Fluids (Macklin & Müller 2013, "Position Based Fluids", Alg. 1) as a
// self-contained kernel the PBD world calls once per substep. It owns no particles: the
// caller gives predicted positions, inverse masses and a fluid flag per particle, and
// gets back position corrections and smoothed velocities. Data flow per substep:
//
//   begin(input)                 neighbour structure from the predicted positions p*
//                                (core/neighbor_grid.h: stable counting sort by cell,
//                                particles copied into cell order), built ONCE and reused
//   repeat `iterations` times:
//     densityIteration()         Jacobi: lambda_i for every fluid particle (Eq. 11), then
//                                dp_i for every particle in range (Eq. 12 + s_corr Eq. 13),
//                                box walls folded into the fluid particles' dp
//     applyCorrections()         p += dp for the particles the kernel owns (fluid); or
//     corrections(dx, dy, dz)    dp by id, for the caller to apply (solids: soft particles
//                                take it, rigid bodies sum m dp into an impulse) and then
//     setPositions(x, y, z)      ... hand the moved solids back before the next iteration
//   positions(x, y, z)           p by id; the caller sets v = (p - x) / h
//   velocityPasses(vx, vy, vz)   XSPH viscosity (Eq. 17), vorticity confinement (Eq. 15-16),
//                                cohesion (Akinci et al. 2013), each only when its parameter
//                                is > 0, on fluid particles only
//   densityError()               max and mean of rho/rho0 - 1 over fluid particles
//
// The density constraint (multi-fluid form). A particle of a fluid with rest density rho0
// and mass m has rest volume nu = m / rho0 (times a lattice calibration, see latticeScale_);
// every fluid is sampled at the same spacing, so the constraint is on number density
// (Solenthaler & Pajarola 2008, which keeps two fluids of different densities from pushing
// apart at their interface):
//     C_i = sum_j nu_j W(p_i - p_j, h) - 1          (j includes i; poly6 W)
// and a solid particle in range contributes its boundary volume nu_b = s / sum_k W_bk over
// its solid and fluid neighbours k and the walls' ghost samples (Akinci et al. 2012, Eq. 4,
// with the fluid counted: computeSolidVolumes; s =
// FluidParams::solidScale). The
// constraint is unilateral (only C_i > 0 is corrected: free surfaces are not pulled in).
// With inverse masses w the Jacobi step is (Macklin et al. 2014 §7.1)
//     lambda_i = -C_i / (w_i |sum_j nu_j gradW_ij|^2 + sum_j w_j nu_j^2 |gradW_ij|^2 + eps_i)
//     dp_i     = w_i sum_j (lambda_i nu_j + lambda_j nu_i + S_ij) gradW_ij
// so sum_k m_k dp_k = 0: a solid receives exactly the momentum the fluid loses (buoyancy
// and two-way coupling), and a solid with w = 0 does not move. S_ij is the artificial
// pressure (Eq. 13) between two fluid particles, -k (W_ij / W(dq))^n (m_i + m_j) V h^2 / 2,
// i.e. -k (W_ij / W(dq))^n V h^2 gradW_ij of displacement between equal masses (V = (2r)^3).
//
// Determinism: every pass writes only its own particles, reads the last pass's values
// (Jacobi) and runs over fixed chunks, so the result is the same bits for any thread count.
// The SIMD (AVX2) and scalar paths do the same IEEE operations per pair in the same order
// (no FMA: -ffp-contract=off) and give identical results (tested).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/neighbor_grid.h"

namespace physketch::pbd {

struct FluidParams {
  float particleRadius = 0.01f;  // r (m); spacing 2r, rest volume V = (2r)^3 per fluid particle
  float kernelRadius = 0.042f;   // h (m); 2.1 spacings gives ~30 neighbours
  // Constraint relaxation (Macklin & Müller 2013 Eq. 11's epsilon), dimensionless: eps_i =
  // relaxation * w_i * (V cs h^2)^2, i.e. relative to one neighbour's gradient term at
  // distance 0, cs = 45 / (pi h^6).
  float relaxation = 0.1f;
  // Artificial pressure s_corr = -k (W(r) / W(dq))^n (Eq. 13); dq in units of h. The paper's
  // s_corr is a displacement per iteration, so its push per second grew with the substeps
  // and iterations (a dam break's front RMSE grew from 0.07 to 1.96 at 32 substeps,
  // docs/accuracy.md). Given the substep h and the iterations I (FluidInput), each iteration
  // applies k min(1, (h / kScorrStep)^2 kScorrIterations / I): a force (h^2 per substep,
  // shared by the iterations) wherever h is below kScorrStep, the paper's displacement
  // (bounded, stable at one substep) above it.
  // Balanced: each pair's term is k ((W / W(dq))^n - beta W / W(dq)), beta fixed so that its
  // virial over the rest lattice is 0 (a short-range push, a longer-range pull: 21 % of the
  // paper's push at one spacing, 80 % of its stiffness there). The paper's term alone is a
  // positive pressure at rest that nothing balances in a unilateral constraint without
  // gravity: a zero-gravity sphere of water blew apart like a gas (0.24 m across -> 0.74 m in
  // 2 s) and a film rose off the floor; a dam break's front ran further ahead (docs/accuracy.md,
  // "s_corr's balance"). The walls' ghosts take part in it as fluid particles would.
  float scorrK = 0.01f;
  int scorrN = 4;                // 1..8
  float scorrDq = 0.3f;
  float xsph = 0.0f;             // XSPH c (Eq. 17), dimensionless; 0 = off
  float vorticity = 0.0f;        // vorticity confinement epsilon (Eq. 16), m/s; 0 = off
  float cohesion = 0.0f;         // Akinci 2013 cohesion gamma, m/s^2; 0 = off
  // Dynamic viscosity mu (Pa s), solved implicitly among the fluid particles (viscosity pass
  // below) wherever some fluid's kinematic mu / rho0 exceeds kNegligibleViscosity; 0 = off.
  float viscosity = 0.0f;
  float solidScale = 1.0f;       // s: scales a solid particle's boundary volume (Akinci 2012)
  // Warm start (FluidSolver::warmStart): a substep's density solve starts from this fraction
  // f of the last substep's multipliers (FluidInput::carried), each first averaged over its
  // fluid neighbours warmSmoothing times; f = 0 (the default) starts from zero, in [0, 1).
  float warmStart = 0.0f;
  int warmSmoothing = 4;         // 0..8
  // Axis-aligned box the fluid particles stay in (their centres stay r inside), m. The
  // ground is lo[1]; +-infinity leaves a side open.
  float wallLo[3] = {-1e30f, 0.0f, -1e30f};
  float wallHi[3] = {1e30f, 1e30f, 1e30f};
};

// One substep's particles, by id (the caller's order). Arrays of `count` entries; they
// must stay valid until begin() returns (the kernel copies them).
struct FluidInput {
  std::size_t count = 0;
  const float* x = nullptr;         // predicted positions p* (m)
  const float* y = nullptr;
  const float* z = nullptr;
  const float* invMass = nullptr;   // w (1/kg); 0 = fixed or kinematic
  const std::uint8_t* fluid = nullptr;  // 1: has a density constraint; 0: solid in range
  // Rest density (kg/m^3) per fluid particle: its rest volume is m / rho0 = 1 / (w rho0).
  // Ignored for solids. All fluid particles share the spacing 2r; rho0 differs by fluid.
  const float* restDensity = nullptr;
  // The substep h (s) and the density iterations it will run. With h > 0 the artificial
  // pressure acts as a force (see FluidParams::scorrK) and a sound speed may be given; 0
  // keeps the per-iteration displacement of Macklin & Muller 2013 (unit tests of one pass).
  float substep = 0.0f;
  int iterations = 0;
  // Sound speed c (m/s) of the XPBD compliance alpha_i = w_i / c^2 (needs substep > 0);
  // 0 = no compliance (the incompressible PBF of the paper). See autoSoundSpeed().
  float soundSpeed = 0.0f;
  // Per-particle parameters, by id, for a scene of several fluids (each particle takes its
  // fluid's): read for fluid particles only. Null takes FluidParams's value (soundSpeed
  // above) for every particle. Each acts on particle i's own equation, so a particle's
  // lambda and velocity passes are those of a scene of its fluid alone (tested); at an
  // interface of two viscosities each side smooths with its own XSPH c.
  const float* relaxation = nullptr;   // FluidParams::relaxation, >= 0
  const float* xsph = nullptr;         // FluidParams::xsph, [0, 1]
  const float* vorticity = nullptr;    // FluidParams::vorticity, >= 0
  const float* cohesion = nullptr;     // FluidParams::cohesion, >= 0
  const float* viscosity = nullptr;    // FluidParams::viscosity (Pa s), >= 0
  const float* soundSpeeds = nullptr;  // m/s, >= 0 (0: no compliance for that particle); needs substep > 0
  // The last substep's multipliers by id (FluidSolver::multipliers(), <= 0 and finite), for
  // FluidParams::warmStart; null, or a warm start of 0, starts from zero. Read for fluid
  // particles with a compliance only.
  const float* carried = nullptr;
};

// The solids a viscosity drags back (two-way coupling), for velocityPasses. Without it every
// solid particle in range is a fixed velocity (one way: honey sticks to a stone, the stone
// does not feel the honey). With it, each solid particle has a role, by id (FluidInput's
// order; fluid particles' entries unread):
//   kFixed   a fixed velocity (fixed or kinematic solids, bodies asleep);
//   kFree    a particle of its own, of mass 1 / FluidInput::invMass (soft, rope, cloth);
//   b >= 0   a point of rigid body b: its velocity is v_b + w_b x (p - c_b), and the body's
//            six velocities are unknowns of the same solve (momentum is exchanged exactly).
// Body b's mass (kg), world-frame inertia tensor about c_b (kg m^2, row-major), centre c_b (m),
// and velocities v_b (m/s), w_b (rad/s), which the solve reads and overwrites.
struct ViscousSolids {
  static constexpr std::int32_t kFixed = -2, kFree = -1;
  const std::int32_t* role = nullptr;
  std::size_t bodies = 0;
  const double* mass = nullptr;     // per body
  const double* inertia = nullptr;  // 9 per body
  const double* centre = nullptr;   // 3 per body
  double* v = nullptr;              // 3 per body
  double* w = nullptr;              // 3 per body
};

struct DensityError {
  float maxCompression = 0.0f;   // max over fluid particles of max(rho/rho0 - 1, 0)
  float meanCompression = 0.0f;  // mean of the same
  float meanAbs = 0.0f;          // mean of |rho/rho0 - 1| (includes the free surface's deficit)
  std::size_t fluidCount = 0;
};

class FluidSolver {
 public:
  // Where k of s_corr is the paper's displacement per iteration (FluidParams::scorrK): a
  // 1/240 s substep (a 60 Hz step in 4 substeps) of 8 iterations, the tests' tuning.
  static constexpr float kScorrStep = 1.0f / 240.0f;
  static constexpr int kScorrIterations = 8;
  // The sound speed of a weakly compressible fluid, after Monaghan 1994's rule for SPH (ten
  // times the fastest flow, so that density varies by about 1 %): c = 15 max(sqrt(2 g H),
  // v_max), H (m) the fluid's height, v_max (m/s) its fastest particle, g = max(|gravity|,
  // 9.81) (a fluid in zero gravity keeps the stiffness of one on Earth). Its hydrostatic
  // compression g H / c^2 is at most 1/450 = 0.22 %. 15, not 10: at 10 a resting column kept
  // oscillating at 0.013 m/s (FluidRest.ColumnAtRestStaysStill's bound is 0.01), at 20 and
  // above the front of a dam break at 32 substeps ran ahead again (RMSE 0.108 at 20, 0.147
  // at 30; FluidDamBreak.FrontConvergesWithSubsteps's bound is 0.10).
  static float autoSoundSpeed(float gravity, float height, float vmax);
  // Below this kinematic viscosity (m^2/s, ten times water's) the viscosity pass does not run:
  // water's own viscosity damps a 5 cm wave by 1.6 % a second, far less than XSPH's smoothing
  // and the solver's own dissipation, and the solve costs a velocity pass per CG iteration.
  static constexpr float kNegligibleViscosity = 1e-5f;
  // Whether a fluid of dynamic viscosity mu (Pa s) and rest density rho0 (kg/m^3) is solved.
  static bool viscosityMatters(double mu, double rho0) { return mu / rho0 > double(kNegligibleViscosity); }
  // The viscosity solve's stopping rule: relative residual (in the Jacobi-weighted norm) and
  // the most CG iterations a substep runs.
  static constexpr float kViscosityTolerance = 1e-4f;
  static constexpr int kViscosityMaxIterations = 200;
  // The tolerance is relative to each particle's momentum m |v|, or m times this speed (m/s)
  // where it is slower: a fluid at rest is not solved to round-off.
  static constexpr float kViscosityFloorSpeed = 1e-3f;

  // Which pair kernel densityIteration runs; kAuto takes AVX2 where the CPU has it. All
  // give identical bits (tested).
  enum class Kernel { kAuto, kScalar, kAvx2 };

  // Throws RuntimeError for a non-finite or out-of-range parameter (naming it).
  explicit FluidSolver(const FluidParams& params);
  const FluidParams& params() const { return params_; }
  void setKernel(Kernel k);

  // Builds the neighbour structure from the predicted positions and copies the particles
  // into cell order. Throws RuntimeError for a non-finite position, a fluid particle with a
  // non-positive inverse mass or rest density, or a particle with a negative inverse mass.
  void begin(const FluidInput& in);

  // One Jacobi density iteration (lambda pass, then dp pass); corrections stay inside until
  // applied or read. Walls are folded into fluid particles' dp. With a sound speed c the
  // lambda pass is XPBD's (Macklin et al. 2016, Eq. 18) for the unilateral constraint:
  //     dlambda_i = (-C_i - at_i lambda_i) / (denominator above + at_i),  at_i = w_i / (c h)^2,
  // lambda_i (summed over this substep's iterations) kept <= 0 and updated only where C_i > 0
  // (unilateral as above: updating it where C_i <= 0 too pulled particles back together and a
  // resting column jittered at 0.42 m/s), and dp uses dlambda: the
  // constraint's energy is K V C^2 / 2 with K = rho0 c^2, so the fluid's stiffness is a
  // bulk modulus, the same for any substeps and iterations. Without it the stiffness is
  // whatever the iterations reach per substep: a volume error (presumably a disordered
  // packing reading denser than the lattice; not verified) is released faster the more
  // iterations run per second, and a dam break's front ran further ahead the more substeps
  // it had (docs/accuracy.md).
  void densityIteration();
  // Warm start (FluidParams::warmStart, before the first iteration; Macklin et al. 2016 XPBD
  // multipliers carried as contact impulses are in rigid-body solvers): each fluid particle's
  // multiplier sum starts at f times its carried one, averaged warmSmoothing times over its
  // fluid neighbours (Shepard weights nu_j W_ij, itself included), and its correction (s_corr
  // off) is left as the corrections, to be applied or read as an iteration's. Returns false,
  // and changes nothing, when there is nothing to carry (f = 0, no carried multipliers, no
  // compliance).
  //
  // Why: with Jacobi iterations a particle learns of the weight above it a kernel radius per
  // iteration, so 8 iterations cannot rebuild a 50-particle column's hydrostatic pressure
  // from zero every substep (bench_pbf: 5.3 % mean compression at one substep). Carried, the
  // iterations only correct its change. Why averaged: carried as they are, the multipliers
  // also carry the packing's particle-scale rearrangements from substep to substep, which
  // the iterations would otherwise damp, and a resting column never comes to rest (at 2
  // substeps, f = 0.6: 0.04 m/s unaveraged, 0.0014 with the default 4 averages, 0.0018
  // cold); the hydrostatic part is smooth and passes the averages (docs/benchmarks.md).
  bool warmStart();
  // By id: each particle's multiplier summed over this substep's iterations (0 without a
  // compliance, and for solids), for the next substep's FluidInput::carried.
  void multipliers(float* lambda) const;
  void lambdaPass();       // the two halves, for benchmarks and tests
  void correctionPass();
  // p += dp for fluid particles (the ones the kernel owns); solids too when asked.
  void applyCorrections(bool solidsToo = false);

  // By id (arrays of count()): the last dp, the lambdas, the current positions.
  void corrections(float* dx, float* dy, float* dz) const;
  void lambdas(float* lambda) const;
  // The volumes the density sums use (m^3): a fluid particle's rest volume, a solid's boundary
  // volume (computeSolidVolumes).
  void volumes(float* nu) const;
  void positions(float* x, float* y, float* z) const;
  // Replaces the positions (by id) of every particle, e.g. after the caller moved solids.
  void setPositions(const float* x, const float* y, const float* z);

  // XSPH, vorticity confinement, cohesion and viscosity on the fluid particles' velocities
  // (m/s, by id, read and written; solids' entries untouched), with the substep h (s). Uses
  // the current positions and the neighbour structure of begin().
  //
  // Viscosity: backward Euler of m_i dv_i/dt = V_i mu lap(v)_i with the SPH Laplacian in
  // Brookshaw's form (1985): lap(v)_i = 2 sum_j V_j (v_j - v_i)
  // |gradW_ij| r_ij / (r_ij^2 + 0.01 h^2) (times a calibration that makes it exact for
  // quadratic fields on the sketch's lattice), mu_ij the mean of the two particles' mu. The
  // pair weights are symmetric (every fluid particle has the same volume V), so the system
  // (M + h K) v' = M v is symmetric positive definite, conserves the fluid's momentum
  // among its own particles and is solved by
  // Jacobi-preconditioned CG to kViscosityTolerance: stable for any viscosity and substep,
  // where an explicit step of honey's would need substeps of microseconds. Solid particles
  // and the walls (their ghost lattice, as for the density) take part as fixed velocities
  // (the walls' 0): honey sticks to the ground and to a moving spoon. Given `solids`, the
  // dynamic solids are dragged back (ViscousSolids): a free solid particle's row is
  // m_s v_s' + h sum_j K_sj (v_s' - v_j') = m_s v_s over its fluid neighbours j, and a rigid
  // body's six rows are M v' + F = M v, I w' + T = I w with F, T the sums of its points'
  // h K (u_s' - v_j') and r_s x of them, u_s' = v' + w' x r_s: the system stays symmetric
  // positive definite (block-Jacobi on the bodies' 6x6 blocks), and the solve conserves
  // the linear momentum of fluid and solids together, walls and fixed solids aside (not the
  // angular: Brookshaw's pair forces lie along v_j - v_i, not along the pair). Free solids'
  // velocities are written back too.
  void velocityPasses(float* vx, float* vy, float* vz, float h, const ViscousSolids* solids = nullptr);
  // CG iterations the last viscosity solve took (0: none ran).
  int lastViscosityIterations() const { return viscIterations_; }

  // rho / rho0 - 1 over fluid particles at the current positions.
  DensityError densityError() const;
  // Mean over fluid particles of max(rho/rho0 - 1, 0) as the last lambda pass saw it (the
  // start of the last density iteration): what the stability guard checks every step, at
  // the cost of a sum, where densityError() is another neighbour sweep.
  float lastMeanCompression() const;

  std::size_t count() const { return n_; }
  const NeighborGrid& grid() const { return grid_; }
  const NeighborLists& lists() const { return lists_; }
  // Bytes held between substeps: the neighbour structure (grid and lists) and the rest
  // (records, corrections, blocked lists, velocity passes).
  std::size_t neighborBytes() const;
  std::size_t solverBytes() const;

 private:
  void checkInput(const FluidInput& in) const;
  void loadRecords(const FluidInput& in);
  void buildBlockedLists();
  void computeSolidVolumes();
  void buildWallTable();
  void buildCornerTables();
  void loadParticleParams(const FluidInput& in);
  bool useSimd() const;
  void cohesionPass(float* vx, float* vy, float* vz, float h) const;
  void viscosityPass(float h, const ViscousSolids* solids);

  FluidParams params_;
  Kernel kernel_ = Kernel::kAuto;
  std::size_t n_ = 0;
  NeighborGrid grid_;
  NeighborLists lists_;
  int listWidth_ = 48;
  // nu = latticeScale m / rho0: the cubic lattice of spacing 2r (how the sketch and the
  // tests place fluid particles) is exactly at rest, C = 0, so a sketched volume keeps its
  // size (SPH's sum of V W over a lattice is 1 only in the continuum limit).
  float latticeScale_ = 1.0f;
  // s_corr's balance: the pair's artificial pressure is k (q^n - beta q), q = W / W(dq), beta
  // such that its virial over the lattice is 0 (FluidParams::scorrK).
  float scorrBeta_ = 0.0f;
  float laplaceScale_ = 1.0f;  // the viscosity's Laplacian, exact for quadratics on that lattice
  static constexpr int kWallSamples = 256;
  // The walls' density term (buildWallTable): B(y) and dB/dy on kWallSamples samples; where
  // walls meet, the ghosts two walls' terms both count, Q(y1, y2) and dQ/dy1 on
  // kEdgeSamples^2 samples, and the ghosts all three count, O(y1, y2, y3) and dO/dy1 on
  // kCornerSamples^3 (Q and O are symmetric in their arguments).
  static constexpr int kEdgeSamples = 64, kCornerSamples = 24;
  // The same for s_corr's push from the ghosts (the pairs' term, normal to the plane, summed
  // over a plane's, an edge's and a corner's ghosts): S(y), QS(y1, y2) and OS(y1, y2, y3),
  // each the component along the first argument's axis.
  // And the walls' share of the viscosity's Laplacian weight: sum over ghost samples g of
  // nu_g |gradW| r / (r^2 + 0.01 h^2) (calibrated) times Morris's no-slip factor, by distance
  // from the plane V(y), and where walls meet QV(y1, y2) and OV(y1, y2, y3) (detail::wallViscosity).
  enum WallTable { kB, kDB, kQ, kDQ, kO, kDO, kS, kQS, kOS, kV, kQV, kOV, kWallTables };
  std::vector<float> walls_[kWallTables];
  // Per particle, in rank (cell) order, one 32-byte record so that a neighbour's data is
  // one load (the SIMD kernel transposes 8 records into 8 lanes, no gathers):
  //   x, y, z (m), nu (m^3, rest volume), w (1/kg), lambda, fluid (0/1), m (kg; 0 for solids)
  // plus padding records up to a multiple of 8 and one ghost far away that padded list
  // slots point to.
  std::vector<float> rec_;
  std::vector<float> dx_, dy_, dz_;   // dp by rank (m)
  std::vector<float> comp_;           // by rank: max(C_i, 0) of fluid particles in the last lambda pass
  std::vector<float> lambdaSum_;      // by rank: XPBD's lambda summed over this substep's iterations
  std::vector<float> carried_;        // by rank: f times FluidInput::carried (empty: no warm start)
  std::vector<float> warmFluidFlag_;  // warmStart(): the records' fluid flags while the averages skip some
  bool scorrOff_ = false;             // the warm start's correction pass runs without s_corr
  // By rank (padded to whole blocks with 0), from FluidInput's per-particle arrays; empty when
  // not given: eps coefficient relaxation_i * (V cs h^2)^2, compliance 1 / (c_i h)^2 (0: none),
  // XSPH c_i, vorticity epsilon_i (m/s), cohesion gamma_i (m/s^2).
  std::vector<float> epsR_, alphaR_, xsphR_, vortR_, cohR_;
  // Whether any fluid particle has XSPH, vorticity, cohesion or viscosity (the velocity
  // passes' gates).
  bool xsphOn_ = false, vortOn_ = false, cohOn_ = false, viscOn_ = false;
  // The viscosity solve: mu by rank (empty when off), pair weights h K_ij by list slot, the
  // diagonal, CG's vectors (3 components each) and per-chunk partial sums.
  std::vector<float> muR_, viscK_, viscDiag_, viscExtra_, viscRhs_[3], cgR_[3], cgZ_[3], cgP_[3], cgQ_[3], cgX_;
  std::vector<double> partial_;
  // Two-way coupling (ViscousSolids), by rank: kRoleFluid, ViscousSolids::kFixed / kFree, or a
  // body; the mass of a row's own unknown (0 for bodies' points and fixed solids); the ranks
  // of bodies' points with a fluid neighbour, in rank order (their rows are summed into
  // the bodies' in that order); the bodies' CG vectors (6 each: v, w) and 6x6 blocks' inverses.
  static constexpr std::int32_t kRoleFluid = -3;
  std::vector<std::int32_t> roleR_, pointRanks_;
  std::vector<float> viscMass_;
  std::vector<double> bodyX_, bodyR_, bodyZ_, bodyP_, bodyQ_, bodyPrec_;
  int viscIterations_ = 0;
  float substep_ = 0.0f, soundSpeed_ = 0.0f;
  int iterations_ = 0;
  // Neighbour lists in blocks of 8 ranks, slot-major: the k-th neighbour of rank 8b + l is
  // bidx_[(boff_[b] + k) * 8 + l], k < bk_[b] = the block's largest count; the rest of a
  // shorter row points to the ghost.
  std::vector<std::int32_t> bidx_, boff_, bk_;
  std::int32_t ghost_ = 0;
  // Velocity passes (rank order): records x y z nu(fluid) vx vy vz |omega|, the smoothed
  // velocities and the vorticity.
  std::vector<float> vrec_, v_[3], omega_[3];
};

}  // namespace physketch::pbd
