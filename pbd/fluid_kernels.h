// The per-pair loops of the PBF density iteration (pbd/fluid.h), internal to pbd/.
// Each kernel runs blocks [b0, b1) of 8 consecutive ranks against their blocked lists and
// writes only those ranks. The scalar and AVX2 forms do the same IEEE operations in the
// same order, per pair and in the per-particle finish (the AVX2 finish repeats the scalar
// one lane-wise, walls included), so they give equal bits.
#pragma once

#include <cstddef>
#include <cstdint>

namespace physketch::pbd::detail {

constexpr int kRecord = 8;  // floats per particle record
enum RecordField { kX = 0, kY, kZ, kNu, kW, kLambda, kFluid, kMass };
constexpr int kLanes = 8;   // ranks per list block
// Distances are clamped to this before dividing (coincident particles: no direction, the
// gradient term is 0 there because d = 0).
constexpr float kMinDistance = 1e-20f;

struct PairArgs {
  float* rec = nullptr;                // records, rank order (kernels write lambda only)
  const std::int32_t* bidx = nullptr;  // blocked lists
  const std::int32_t* boff = nullptr;
  const std::int32_t* bk = nullptr;
  float* dx = nullptr;                 // dp by rank (correction pass output)
  float* dy = nullptr;
  float* dz = nullptr;
  float* comp = nullptr;               // by rank (lambda pass output): max(C_i, 0) of a fluid particle, else 0
  std::size_t n = 0;                   // real particles (lanes >= n are not written)
  float h = 0, h2 = 0, h6 = 0;         // kernel radius (m) and its powers
  float cp = 0;                        // poly6 constant 315 / (64 pi h^9)
  float cs = 0;                        // spiky gradient constant 45 / (pi h^6)
  float epsK = 0;                      // eps_i = epsK * w_i
  float alphaK = 0;                    // XPBD: at_i = alphaK * w_i = w_i / (c h)^2; 0 = no compliance
  // Per rank (padded to whole blocks), or null for epsK / alphaK above: a scene of several fluids.
  const float* epsR = nullptr;
  const float* alphaR = nullptr;
  float* lambdaSum = nullptr;          // XPBD (alphaK > 0 or alphaR): lambda summed over the substep, by rank
  float invWdq = 0;                    // 1 / (h^2 - (dq h)^2)^3: W / W(dq) without cp
  float scorrK = 0;                    // k V h^2 / 2 (kg-free: times m_i + m_j), times the force scale
  int scorrN = 4;
  float scorrBeta = 0;                 // s_corr's balance (FluidSolver::scorrBeta_): k (q^n - beta q), q = W / W(dq)
  float wallLo[3] = {0, 0, 0};         // box for fluid centres (walls already moved in by r)
  float wallHi[3] = {0, 0, 0};
  float wallPlaneLo[3] = {0, 0, 0};    // the walls themselves (m)
  float wallPlaneHi[3] = {0, 0, 0};
  // A wall's density term B(y) and dB/dy at distances y = k / wallInvStep from the plane,
  // k < wallSamples (FluidSolver::wallTable_); 0 beyond h.
  const float* wallB = nullptr;
  const float* wallDB = nullptr;
  int wallSamples = 0;
  float wallInvStep = 0;
  // Where two or three walls meet, the ghosts their terms count twice or three times
  // (FluidSolver::buildWallTable): Q(y1, y2), dQ/dy1 on edgeSamples^2 samples and O(y1, y2,
  // y3), dO/dy1 on cornerSamples^3, row-major, y = index / invStep; 0 beyond h.
  const float* wallQ = nullptr;
  const float* wallDQ = nullptr;
  const float* wallO = nullptr;
  const float* wallDO = nullptr;
  // s_corr's push from the ghosts, on the same samples (FluidSolver::buildWallTable): per
  // plane S(y), edge QS(y1, y2) and corner OS(y1, y2, y3), the component along y1's axis.
  const float* wallS = nullptr;
  const float* wallQS = nullptr;
  const float* wallOS = nullptr;
  // The viscosity's weight of the ghosts, on the same samples: V(y), QV(y1, y2), OV(y1, y2, y3).
  const float* wallV = nullptr;
  const float* wallQV = nullptr;
  const float* wallOV = nullptr;
  int edgeSamples = 0, cornerSamples = 0;
  float edgeInvStep = 0, cornerInvStep = 0;
};

// The velocity passes (Alg. 1 line 22) over the same blocked lists, on records of their own:
//   x, y, z (m), nu (m^3; 0 for solids: they take no part), vx, vy, vz (m/s), |omega| (1/s)
enum VelocityField { kVX = 4, kVY, kVZ, kOmegaNorm };
struct VelocityArgs {
  float* vrec = nullptr;               // the smoothing pass writes |omega| (field 7) only
  const std::int32_t* bidx = nullptr;
  const std::int32_t* boff = nullptr;
  const std::int32_t* bk = nullptr;
  std::size_t n = 0;
  float h = 0, h2 = 0, cs = 0;
  float xsph = 0;                      // c * cp (XSPH, Eq. 17)
  float vortStep = 0;                  // eps * substep h (vorticity confinement, Eq. 16)
  // Per rank (padded to whole blocks), or null for the two above: c_i (times cp here) and
  // eps_i (times substepH here).
  const float* xsphR = nullptr;
  const float* vortR = nullptr;
  float cp = 0, substepH = 0;
  float* out[3] = {nullptr, nullptr, nullptr};    // smoothed velocities by rank
  float* omega[3] = {nullptr, nullptr, nullptr};  // vorticity by rank; null: confinement off
};
// v_i + c sum_j nu_j (v_j - v_i) W_ij, and omega_i = sum_j nu_j (v_j - v_i) x gradW_ij.
void smoothingBlocksScalar(const VelocityArgs& a, std::size_t b0, std::size_t b1);
void smoothingBlocksAvx2(const VelocityArgs& a, std::size_t b0, std::size_t b1);
// out_i += h eps (N x omega_i), N = eta / |eta|, eta = sum_j nu_j |omega_j| gradW_ij.
void confinementBlocksScalar(const VelocityArgs& a, std::size_t b0, std::size_t b1);
void confinementBlocksAvx2(const VelocityArgs& a, std::size_t b0, std::size_t b1);

void lambdaBlocksScalar(const PairArgs& a, std::size_t b0, std::size_t b1);
void correctionBlocksScalar(const PairArgs& a, std::size_t b0, std::size_t b1);
void lambdaBlocksAvx2(const PairArgs& a, std::size_t b0, std::size_t b1);
// The warm start's average (FluidSolver::warmStart) of the records' lambda over each fluid
// particle's fluid neighbours and itself, Shepard weights nu_j W_ij: out[i] by rank (0 for
// solids), ranks of blocks b0..b1 below a.n. Scalar and AVX2 give the same bits.
void smoothLambdaBlocksScalar(const PairArgs& a, std::size_t b0, std::size_t b1, float* out);
void smoothLambdaBlocksAvx2(const PairArgs& a, std::size_t b0, std::size_t b1, float* out);
void correctionBlocksAvx2(const PairArgs& a, std::size_t b0, std::size_t b1);

// The walls' density term at a fluid particle: sum of B over the walls within h, and its
// gradient (1/m).
struct WallTerm {
  float c = 0, g[3] = {0, 0, 0};
};
WallTerm wallTerm(const PairArgs& a, const float* p);
// The part of wallTerm for a particle within h of two or three walls (inclusion-exclusion
// of their ghosts): added to the planes' sum; 0 elsewhere.
WallTerm edgeTerm(const PairArgs& a, const float* p);
// The walls' ghosts' share of the viscosity's Laplacian weight at a fluid particle at p (the sum
// over the ghosts of their calibrated weight times Morris's no-slip factor; 0 beyond h of every
// wall): the planes' V, less QV for every two walls within h, plus OV for three, so a ghost
// behind two or three planes counts once, with the largest of its planes' factors.
float wallViscosity(const PairArgs& a, const float* p);
// s_corr between a fluid particle at p and the walls' ghosts (each of the fluid particle's own
// mass): its share of dp (m), added before the walls' clamp; 0 beyond h of every wall.
void wallScorr(const PairArgs& a, const float* p, float out[3]);

}  // namespace physketch::pbd::detail
