#include "pbd/fluid.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>

#include <Eigen/Dense>

#include "core/error.h"
#include "core/parallel.h"
#include "core/profile.h"
#include "pbd/fluid_kernels.h"

namespace physketch::pbd {
namespace {

using namespace detail;

constexpr float kPi = 3.14159265358979f;
constexpr float kGhostCoord = 1e18f;  // far from everything; its squared distance stays finite
// Fixed work units (boundaries depend only on the sizes, never on the thread count).
constexpr std::size_t kBlockChunk = 64;      // list blocks (x 8 ranks) per unit
constexpr std::size_t kParticleChunk = 2048;

void require(bool ok, const std::string& what) {
  if (!ok) throw RuntimeError("FluidSolver: " + what);
}

// Akinci et al. 2013 cohesion spline C(r) (Eq. 2) without its 32 / (pi h^9) factor.
float cohesionSpline(float r, float h) {
  if (r >= h || r <= 0.0f) return 0.0f;
  const float a = (h - r) * (h - r) * (h - r) * r * r * r;
  return 2.0f * r > h ? a : 2.0f * a - h * h * h * h * h * h / 64.0f;
}

}  // namespace

FluidSolver::FluidSolver(const FluidParams& p) : params_(p) {
  const auto positive = [](float v) { return std::isfinite(v) && v > 0.0f; };
  const auto nonNegative = [](float v) { return std::isfinite(v) && v >= 0.0f; };
  require(positive(p.particleRadius), "particleRadius must be positive and finite");
  require(positive(p.kernelRadius) && p.kernelRadius > 2.0f * p.particleRadius,
          "kernelRadius must be finite and larger than the spacing 2 * particleRadius");
  require(nonNegative(p.relaxation), "relaxation must be >= 0 and finite");
  require(nonNegative(p.scorrK), "scorrK must be >= 0 and finite");
  require(p.scorrN >= 1 && p.scorrN <= 8, "scorrN must be in 1..8");
  require(std::isfinite(p.scorrDq) && p.scorrDq >= 0.0f && p.scorrDq < 1.0f, "scorrDq must be in [0, 1)");
  require(nonNegative(p.xsph) && p.xsph <= 1.0f, "xsph must be in [0, 1]");
  require(nonNegative(p.vorticity), "vorticity must be >= 0 and finite");
  require(nonNegative(p.cohesion), "cohesion must be >= 0 and finite");
  require(nonNegative(p.viscosity), "viscosity must be >= 0 and finite");
  require(nonNegative(p.solidScale), "solidScale must be >= 0 and finite");
  require(nonNegative(p.warmStart) && p.warmStart < 1.0f, "warmStart must be in [0, 1)");
  require(p.warmSmoothing >= 0 && p.warmSmoothing <= 8, "warmSmoothing must be in 0..8");
  for (int k = 0; k < 3; ++k)
    require(!std::isnan(p.wallLo[k]) && !std::isnan(p.wallHi[k]) &&
                p.wallHi[k] - p.wallLo[k] > 2.0f * p.particleRadius,
            "walls: wallHi - wallLo must exceed 2 * particleRadius on every axis");
  // sum_j V W(x_j) over the cubic lattice of spacing d = 2r, in double.
  const double d = 2.0 * p.particleRadius, h = p.kernelRadius, cp = 315.0 / (64.0 * 3.14159265358979323846 * std::pow(h, 9));
  const int reach = int(std::ceil(h / d));
  double sum = 0.0;
  for (int i = -reach; i <= reach; ++i)
    for (int j = -reach; j <= reach; ++j)
      for (int k = -reach; k <= reach; ++k) {
        const double s = h * h - d * d * double(i * i + j * j + k * k);
        if (s > 0.0) sum += cp * s * s * s;
      }
  latticeScale_ = float(1.0 / (sum * d * d * d));
  // The viscosity's Laplacian, calibrated the same way: on the lattice it gives exactly 1 for
  // the field (e . x)^2 / 2, i.e. sum_j nu cs |gradW| r / (r^2 + 0.01 h^2) (x_j . e)^2 = 1
  // (uncalibrated, Brookshaw's form with the spiky gradient read 0.90 of a shear wave's
  // viscous decay rate).
  double second = 0.0;
  const double cs = 45.0 / (3.14159265358979323846 * std::pow(h, 6)), nu = double(latticeScale_) * d * d * d;
  for (int i = -reach; i <= reach; ++i)
    for (int j = -reach; j <= reach; ++j)
      for (int k = -reach; k <= reach; ++k) {
        const double r2 = d * d * double(i * i + j * j + k * k), r = std::sqrt(r2);
        if (r > 0.0 && r < h) second += nu * cs * (h - r) * (h - r) * r / (r2 + 0.01 * h * h) * (d * i) * (d * i);
      }
  laplaceScale_ = float(1.0 / second);
  // s_corr's balance (scorrBeta_ in fluid.h): beta with sum_j (q_j^n - beta q_j) |gradW_j| r_j
  // = 0 over the lattice's neighbours j, q = W / W(dq), |gradW| r = cs (h - r)^2.
  {
    const double sdq = h * h - std::pow(double(p.scorrDq) * h, 2), wdq = sdq * sdq * sdq;
    double push = 0.0, pull = 0.0;
    for (int i = -reach; i <= reach; ++i)
      for (int j = -reach; j <= reach; ++j)
        for (int k = -reach; k <= reach; ++k) {
          const double r2 = d * d * double(i * i + j * j + k * k), r = std::sqrt(r2);
          if (!(r > 0.0 && r < h)) continue;
          const double q = std::pow(h * h - r2, 3) / wdq, virial = (h - r) * (h - r);
          push += std::pow(q, p.scorrN) * virial, pull += q * virial;
        }
    scorrBeta_ = float(push / pull);
  }
  buildWallTable();
}

// A wall is the fluid's own lattice continued beyond its plane (Akinci et al. 2012's
// boundary particles, summed once instead of stored): a fluid particle at distance y from
// the plane sees ghost layers at y + r + k d, each a square lattice of spacing d aligned
// with it, of volume latticeScale d^3. So a particle of a lattice fluid touching a wall
// has exactly the density of one inside it, and the particle deficiency that makes plain
// PBF particles crowd and slide along walls is gone. B(y) = sum nu W, dB/dy its derivative.
void FluidSolver::buildWallTable() {
  const double d = 2.0 * params_.particleRadius, h = params_.kernelRadius, r = params_.particleRadius;
  const double cp = 315.0 / (64.0 * 3.14159265358979323846 * std::pow(h, 9));
  const double nu = double(latticeScale_) * d * d * d;
  const int reach = int(std::ceil(h / d));
  const double cs = 45.0 / (3.14159265358979323846 * std::pow(h, 6));
  std::vector<float>&tableB = walls_[kB], &tableDB = walls_[kDB];
  std::vector<float>& tableV = walls_[kV];
  tableB.assign(kWallSamples, 0.0f), tableDB.assign(kWallSamples, 0.0f), tableV.assign(kWallSamples, 0.0f);
  for (int s = 0; s < kWallSamples; ++s) {
    const double y = h * double(s) / double(kWallSamples - 1);
    double b = 0, db = 0, v = 0;
    for (int k = 0;; ++k) {
      const double z = y + r + double(k) * d;  // normal distance to ghost layer k
      if (z >= h) break;
      for (int i = -reach; i <= reach; ++i)
        for (int j = -reach; j <= reach; ++j) {
          const double q = h * h - z * z - d * d * double(i * i + j * j);
          if (q <= 0) continue;
          b += nu * cp * q * q * q;
          db += nu * cp * 3.0 * q * q * (-2.0 * z);  // dz/dy = 1
          const double r2 = h * h - q, rr = std::sqrt(r2);  // distance to the ghost sample
          // No-slip at the plane (Morris et al. 1997): the ghost at depth z - y takes the
          // velocity -(z - y) / y u_i that continues a shear profile through zero at the wall,
          // so its weight counts 1 + (z - y) / y times on the diagonal (y at least r / 2: a
          // particle pressed into the wall is not pinned by an unbounded weight). With the
          // ghosts at rest instead, the profile reached zero half a spacing below the plane.
          const double morris = 1.0 + (z - y) / std::max(y, 0.5 * r);
          v += nu * cs * (h - rr) * (h - rr) * rr / (r2 + 0.01 * h * h) * laplaceScale_ * morris;
        }
    }
    tableB[s] = float(b), tableDB[s] = float(db), tableV[s] = float(v);
  }
  buildCornerTables();
}

// Where two walls meet, each wall's term counts the ghosts beyond both planes (the quarter
// space behind the edge), so a fluid particle in the edge counted them twice and read over-
// dense (a lattice filling a 6 x 5 x 7 box: up to C = +10.9 % in its corners, 1.3 % on average;
// a film filling a box's floor rose off it at 4.5 cm/s in zero gravity). Inclusion-
// exclusion: the union of the ghost half-spaces is sum B - sum Q + O, with Q the ghosts in the
// quarter space behind two planes and O those in the octant behind three, each on the lattice
// continued from the particle's distances to the planes (ghost layers at y + r + k d behind
// every plane, the lattice's spacing d along the edge): exact for a particle on the lattice,
// smooth for any other. Only the interpolation's error remains (tested against explicit ghosts).
// The same sums give s_corr's push from the ghosts (S, QS, OS; detail::wallScorr): the
// balanced s_corr is pressure-free inside the fluid, but without the walls as partners the
// fluid beside them pressed itself into them (a zero-gravity film in a box rose at 3.9 cm/s).
void FluidSolver::buildCornerTables() {
  const double d = 2.0 * params_.particleRadius, h = params_.kernelRadius, r = params_.particleRadius;
  const double cp = 315.0 / (64.0 * 3.14159265358979323846 * std::pow(h, 9));
  const double nu = double(latticeScale_) * d * d * d;
  const int reach = int(std::ceil(h / d));
  // sum over ghosts at normal distances z[k] = y[k] + r + m_k d (m_k >= 0) behind `axes` planes,
  // and the lattice (spacing d, aligned with the particle) along the other axes: the term and
  // its derivative by y[0].
  // s_corr's pair term (FluidParams::scorrK, balanced by scorrBeta_) without its constants:
  // (q^n - beta q) g(r) z0, q = W / W(dq), g = (h - r)^2 / r, z0 the ghost's distance along the
  // first axis.
  const double sdq = h * h - std::pow(double(params_.scorrDq) * h, 2), wdq = sdq * sdq * sdq;
  const auto scorr = [&](double w, double dist, double z0) {
    const double q = w / wdq;
    return (std::pow(q, params_.scorrN) - double(scorrBeta_) * q) * (h - dist) * (h - dist) / dist * z0;
  };
  // The viscosity's weight of a ghost at distance dist (calibrated, buildWallTable's) times the
  // no-slip factor: for a ghost behind several planes the largest of theirs, so that the planes'
  // tables less the edges' plus the corners' count it once with it (max(a, b) = a + b - min(a, b);
  // max(a, b, c) = sum - pairs' mins + min(a, b, c)); the edge and corner tables hold the mins.
  const double cs = 45.0 / (3.14159265358979323846 * std::pow(h, 6));
  const auto viscous = [&](double dist, const double* y, const double* z, int axes) {
    double morris = 1e300;
    for (int k = 0; k < axes; ++k) morris = std::min(morris, 1.0 + (z[k] - y[k]) / std::max(y[k], 0.5 * r));
    return nu * cs * (h - dist) * (h - dist) * dist / (dist * dist + 0.01 * h * h) * double(laplaceScale_) * morris;
  };
  const auto sum = [&](const double* y, int axes, double& term, double& d0, double& push, double& visc) {
    term = 0, d0 = 0, push = 0, visc = 0;
    int m[3] = {0, 0, 0};
    for (m[0] = 0; m[0] <= reach; ++m[0])
      for (m[1] = axes >= 2 ? 0 : -reach; m[1] <= reach; ++m[1])
        for (m[2] = axes == 3 ? 0 : -reach; m[2] <= reach; ++m[2]) {
          double z[3], q = h * h;
          for (int k = 0; k < 3; ++k) {
            z[k] = k < axes ? y[k] + r + double(m[k]) * d : double(m[k]) * d;
            q -= z[k] * z[k];
          }
          if (q <= 0) continue;
          term += nu * cp * q * q * q;
          d0 += nu * cp * 3.0 * q * q * (-2.0 * z[0]);
          push += scorr(q * q * q, std::sqrt(h * h - q), z[0]);
          visc += viscous(std::sqrt(h * h - q), y, z, axes);
        }
  };
  const int E = kEdgeSamples, C = kCornerSamples;
  const int S = kWallSamples;
  walls_[kS].assign(std::size_t(S), 0.0f);
  for (int i = 0; i < S; ++i) {
    const double y[3] = {h * i / (S - 1), 0.0, 0.0};
    double term, d0, push, visc;
    sum(y, 1, term, d0, push, visc);
    walls_[kS][std::size_t(i)] = float(push);
  }
  walls_[kQ].assign(std::size_t(E) * E, 0.0f), walls_[kDQ].assign(std::size_t(E) * E, 0.0f);
  walls_[kQS].assign(std::size_t(E) * E, 0.0f), walls_[kQV].assign(std::size_t(E) * E, 0.0f);
  for (int i = 0; i < E; ++i)
    for (int j = 0; j < E; ++j) {
      const double y[3] = {h * i / (E - 1), h * j / (E - 1), 0.0};
      double term, d0, push, visc;
      sum(y, 2, term, d0, push, visc);
      const std::size_t at = std::size_t(i) * E + j;
      walls_[kQ][at] = float(term), walls_[kDQ][at] = float(d0), walls_[kQS][at] = float(push);
      walls_[kQV][at] = float(visc);
    }
  walls_[kO].assign(std::size_t(C) * C * C, 0.0f), walls_[kDO].assign(std::size_t(C) * C * C, 0.0f);
  walls_[kOS].assign(std::size_t(C) * C * C, 0.0f), walls_[kOV].assign(std::size_t(C) * C * C, 0.0f);
  for (int i = 0; i < C; ++i)
    for (int j = 0; j < C; ++j)
      for (int k = 0; k < C; ++k) {
        const double y[3] = {h * i / (C - 1), h * j / (C - 1), h * k / (C - 1)};
        double term, d0, push, visc;
        sum(y, 3, term, d0, push, visc);
        const std::size_t at = (std::size_t(i) * C + j) * C + k;
        walls_[kO][at] = float(term), walls_[kDO][at] = float(d0), walls_[kOS][at] = float(push);
        walls_[kOV][at] = float(visc);
      }
}

void FluidSolver::setKernel(Kernel k) {
  if (k == Kernel::kAvx2 && !__builtin_cpu_supports("avx2"))
    throw RuntimeError("FluidSolver: this CPU lacks AVX2");
  kernel_ = k;
}

void FluidSolver::checkInput(const FluidInput& in) const {
  require(in.count < (std::size_t(1) << 30), "too many particles (" + std::to_string(in.count) + ")");
  if (!in.count) return;
  require(std::isfinite(in.substep) && in.substep >= 0.0f, "substep must be >= 0 and finite");
  require(in.iterations >= 0, "iterations must be >= 0");
  require(std::isfinite(in.soundSpeed) && in.soundSpeed >= 0.0f, "soundSpeed must be >= 0 and finite");
  require(in.soundSpeed == 0.0f || in.substep > 0.0f, "a soundSpeed needs the substep");
  require(in.x && in.y && in.z && in.invMass && in.fluid && in.restDensity, "an input array is null");
  require(!in.soundSpeeds || in.substep > 0.0f, "per-particle soundSpeeds need the substep");
  if (in.carried)
    for (std::size_t i = 0; i < in.count; ++i)
      if (in.fluid && in.fluid[i] && !(std::isfinite(in.carried[i]) && in.carried[i] <= 0.0f))
        require(false, "fluid particle " + std::to_string(i) + ": carried multiplier " + std::to_string(in.carried[i]) +
                           " must be finite and <= 0");
  struct PerParticle {
    const float* v;
    const char* name;
    float hi;
  };
  const PerParticle per[] = {{in.relaxation, "relaxation", 1e30f},
                             {in.xsph, "xsph", 1.0f},
                             {in.vorticity, "vorticity", 1e30f},
                             {in.cohesion, "cohesion", 1e30f},
                             {in.viscosity, "viscosity", 1e30f},
                             {in.soundSpeeds, "soundSpeed", 1e30f}};
  for (const PerParticle& q : per)
    if (q.v)
      for (std::size_t i = 0; i < in.count; ++i)
        if (in.fluid[i] && !(std::isfinite(q.v[i]) && q.v[i] >= 0.0f && q.v[i] <= q.hi))
          require(false, "fluid particle " + std::to_string(i) + ": " + q.name + " " + std::to_string(q.v[i]) +
                             " must be finite, >= 0" + (q.hi < 1e30f ? " and <= " + std::to_string(q.hi) : std::string()));
  for (std::size_t i = 0; i < in.count; ++i) {  // messages built only on failure (80k per substep)
    const float w = in.invMass[i];
    if (!(std::isfinite(w) && w >= 0.0f))
      require(false, "particle " + std::to_string(i) + ": inverse mass " + std::to_string(w) + " must be finite and >= 0");
    if (in.fluid[i] && !(w > 0.0f && std::isfinite(in.restDensity[i]) && in.restDensity[i] > 0.0f))
      require(false, "fluid particle " + std::to_string(i) + ": needs inverse mass > 0 and rest density > 0 (got " +
                         std::to_string(w) + ", " + std::to_string(in.restDensity[i]) + ")");
  }
}

void FluidSolver::begin(const FluidInput& in) {
  checkInput(in);
  n_ = in.count;
  substep_ = in.substep, iterations_ = in.iterations, soundSpeed_ = in.soundSpeed;
  if (!n_) {
    rec_.clear(), bidx_.clear(), boff_.assign(1, 0), bk_.clear();
    return;
  }
  // One neighbour structure per substep from p* (Macklin & Müller 2013, Alg. 1 line 5).
  grid_.build(in.x, in.y, in.z, n_, params_.kernelRadius);
  loadRecords(in);
  for (;;) {
    grid_.buildNeighborLists(params_.kernelRadius, listWidth_, lists_);
    if (!lists_.overflowed) break;
    listWidth_ = (lists_.maxCount + 7) / 8 * 8;  // a compressed region: wider lists, once
  }
  buildBlockedLists();
  computeSolidVolumes();
  loadParticleParams(in);
  // The carried multipliers of fluid particles with a compliance (the others keep no sum).
  carried_.clear();
  const bool compliance = soundSpeed_ > 0.0f || in.soundSpeeds;
  if (params_.warmStart > 0.0f && in.carried && compliance && substep_ > 0.0f) {
    carried_.assign(std::size_t(ghost_), 0.0f);
    const std::int32_t* order = grid_.order().data();
    for (std::size_t r = 0; r < n_; ++r) {
      const bool on = rec_[r * kRecord + kFluid] != 0.0f && (alphaR_.empty() || alphaR_[r] > 0.0f);
      if (on) carried_[r] = params_.warmStart * in.carried[order[r]];
    }
  }
}

namespace {
// (V cs h^2)^2: one neighbour's |nu gradW|^2 at distance 0 (1/m^2); eps_i = relaxation * this * w_i.
float epsScale(const FluidParams& p) {
  const float h = p.kernelRadius, spacing = 2.0f * p.particleRadius;
  const float ref = (spacing * spacing * spacing) * (45.0f / (kPi * std::pow(h, 6.0f))) * (h * h);
  return ref * ref;
}
// 1 / (c h)^2 of XPBD's compliance, 0 without a sound speed.
float complianceScale(float c, float substep) {
  const float ch = c * substep;
  return c > 0.0f ? 1.0f / (ch * ch) : 0.0f;
}
}  // namespace

// The per-particle parameters by rank (FluidInput's per-particle arrays), and which velocity
// passes any fluid particle needs.
void FluidSolver::loadParticleParams(const FluidInput& in) {
  const std::size_t nPad = std::size_t(ghost_);
  const std::int32_t* order = grid_.order().data();
  const auto byRank = [&](const float* v, std::vector<float>& out, float scale, bool& any) {
    any = false;
    if (!v) return out.clear();
    out.assign(nPad, 0.0f);
    for (std::size_t r = 0; r < n_; ++r)
      if (rec_[r * kRecord + kFluid] != 0.0f) {
        out[r] = v[order[r]] * scale;
        any |= out[r] > 0.0f;
      }
  };
  bool unused = false;
  byRank(in.relaxation, epsR_, epsScale(params_), unused);
  byRank(in.xsph, xsphR_, 1.0f, xsphOn_);
  byRank(in.vorticity, vortR_, 1.0f, vortOn_);
  byRank(in.cohesion, cohR_, 1.0f, cohOn_);
  alphaR_.clear();
  if (in.soundSpeeds) {
    alphaR_.assign(nPad, 0.0f);
    for (std::size_t r = 0; r < n_; ++r)
      if (rec_[r * kRecord + kFluid] != 0.0f) alphaR_[r] = complianceScale(in.soundSpeeds[order[r]], substep_);
  }
  // Viscosity: mu by rank when some fluid's mu / rho0 is above the negligible one.
  viscOn_ = false;
  for (std::size_t i = 0; i < n_ && !viscOn_; ++i)
    viscOn_ = in.fluid[i] && viscosityMatters(in.viscosity ? in.viscosity[i] : params_.viscosity, in.restDensity[i]);
  muR_.clear();
  if (viscOn_) {
    muR_.assign(n_, 0.0f);
    for (std::size_t r = 0; r < n_; ++r)
      if (rec_[r * kRecord + kFluid] != 0.0f) muR_[r] = in.viscosity ? in.viscosity[order[r]] : params_.viscosity;
  }
  if (!in.xsph) xsphOn_ = params_.xsph > 0.0f;
  if (!in.vorticity) vortOn_ = params_.vorticity > 0.0f;
  if (!in.cohesion) cohOn_ = params_.cohesion > 0.0f;
}

void FluidSolver::loadRecords(const FluidInput& in) {
  const std::size_t nPad = (n_ + kLanes - 1) / kLanes * kLanes;
  ghost_ = std::int32_t(nPad);
  rec_.assign((nPad + 1) * kRecord, 0.0f);
  for (std::size_t r = n_; r <= nPad; ++r)
    rec_[r * kRecord + kX] = rec_[r * kRecord + kY] = rec_[r * kRecord + kZ] = kGhostCoord;
  dx_.assign(nPad, 0.0f), dy_.assign(nPad, 0.0f), dz_.assign(nPad, 0.0f);
  comp_.assign(nPad, 0.0f);
  lambdaSum_.assign(nPad, 0.0f);
  const float* sx = grid_.sortedX();
  const float* sy = grid_.sortedY();
  const float* sz = grid_.sortedZ();
  const std::int32_t* order = grid_.order().data();
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t r = b; r < e; ++r) {
      const std::size_t id = std::size_t(order[r]);
      float* p = &rec_[r * kRecord];
      const float w = in.invMass[id];
      const bool fluid = in.fluid[id] != 0;
      p[kX] = sx[r], p[kY] = sy[r], p[kZ] = sz[r];
      p[kW] = w;
      p[kLambda] = 0.0f;
      p[kFluid] = fluid ? 1.0f : 0.0f;
      p[kMass] = fluid ? 1.0f / w : 0.0f;
      p[kNu] = fluid ? latticeScale_ / (w * in.restDensity[id]) : 0.0f;  // solids: computeSolidVolumes
    }
  });
}

void FluidSolver::buildBlockedLists() {
  const std::size_t blocks = (n_ + kLanes - 1) / kLanes;
  const int width = lists_.width;
  bk_.assign(blocks, 0);
  boff_.assign(blocks + 1, 0);
  for (std::size_t b = 0; b < blocks; ++b) {
    std::int32_t m = 0;
    for (std::size_t i = b * kLanes; i < std::min(n_, (b + 1) * kLanes); ++i) m = std::max(m, lists_.count[i]);
    bk_[b] = m;
    boff_[b + 1] = boff_[b] + m;
  }
  bidx_.resize(std::size_t(boff_[blocks]) * kLanes);
  forChunks(blocks, kBlockChunk, [&](std::size_t b0, std::size_t b1) {
    for (std::size_t b = b0; b < b1; ++b) {
      // data() + offset: with no neighbour anywhere (a lone particle) bidx_ is empty.
      std::int32_t* out = bidx_.data() + std::size_t(boff_[b]) * kLanes;
      const std::int32_t* row[kLanes];
      std::int32_t cnt[kLanes];
      for (int l = 0; l < kLanes; ++l) {
        const std::size_t i = std::min(b * kLanes + std::size_t(l), n_ - 1);  // lanes past n: no slots
        row[l] = lists_.index.data() + i * std::size_t(width);
        cnt[l] = b * kLanes + std::size_t(l) < n_ ? lists_.count[i] : 0;
      }
      // Slot by slot, so the writes stream (lane by lane they were 8 strided streams).
      for (std::int32_t k = 0; k < bk_[b]; ++k, out += kLanes)
        for (int l = 0; l < kLanes; ++l) out[l] = k < cnt[l] ? row[l][k] : ghost_;
    }
  });
}

namespace {
// Four floats in one vector register (GCC's vector extension: SSE on x86-64, whatever the
// target has elsewhere); the operations act per component, rounding as scalar ones do.
typedef float Float4 __attribute__((vector_size(16)));
inline Float4 load4(const float* p) {
  Float4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
PairArgs pairArgs(const FluidParams& p, const std::vector<float>* walls, float* rec,
                  const std::vector<std::int32_t>& bidx, const std::vector<std::int32_t>& boff,
                  const std::vector<std::int32_t>& bk, float* dx, float* dy, float* dz, std::size_t n);
}  // namespace

// A solid particle's boundary volume nu_b = s / sum_k W_bk over the samples k in range, itself
// included (Akinci et al. 2012, Eq. 4, a number density): the solid particles, the walls'
// ghost layers (the ground under a sketched wall is boundary too: without it the wall's bottom
// row counted too few samples and took 1.26 times the volume, so a lattice of fluid in the
// corner where the wall meets the ground was 14 % over-dense and a resting tank shot corner
// particles up at 0.19 m/s) and the fluid particles. Akinci counts boundary samples only,
// which gives the face of a solid as thick as the kernel 1.26 times a lattice particle's
// volume, as if the fluid side were missing solid: a lattice of fluid against it read 8.1 %
// over-dense. Counted with the fluid in front of it the face reads a full neighbourhood and
// takes a lattice particle's volume, so fluid resting on a solid is at rest density (a film
// under a 2- to 5-layer plate: at most 2.0 % over, against 8.1 %; under a single layer, whose
// back is empty, 8.1 % against 18.6 %).
// A solid with nothing beside it keeps Akinci's larger volume, where the fluid is not.
void FluidSolver::computeSolidVolumes() {
  const float h = params_.kernelRadius, h2 = h * h, cp = 315.0f / (64.0f * kPi * std::pow(h, 9.0f));
  const int width = lists_.width;
  const PairArgs walls =
      pairArgs(params_, walls_, rec_.data(), bidx_, boff_, bk_, dx_.data(), dy_.data(), dz_.data(), n_);
  // The wall term is sum nu_g W over ghost samples of volume nu_g = latticeScale d^3; as a sum
  // of W / cp (this loop's units) it is that over nu_g cp. Fluid neighbours count as samples
  // (all fluids share the spacing: a number density).
  const float d = 2.0f * params_.particleRadius;
  const float perGhost = 1.0f / (latticeScale_ * d * d * d * cp);
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      float* ri = &rec_[i * kRecord];
      if (ri[kFluid] != 0.0f) continue;
      float sum = h2 * h2 * h2;
      for (std::int32_t k = 0; k < lists_.count[i]; ++k) {
        const float* rj = &rec_[std::size_t(lists_.index[i * std::size_t(width) + std::size_t(k)]) * kRecord];
        const float dx = ri[kX] - rj[kX], dy = ri[kY] - rj[kY], dz = ri[kZ] - rj[kZ];
        const float s = h2 - ((dx * dx + dy * dy) + dz * dz);
        if (s > 0.0f) sum += (s * s) * s;
      }
      sum += wallTerm(walls, ri).c * perGhost;
      ri[kNu] = params_.solidScale / (cp * sum);
    }
  });
}

namespace {

// walls: the tables of buildWallTable, in WallTable order (B, dB, Q, dQ, O, dO, S, QS, OS, V, QV, OV).
PairArgs pairArgs(const FluidParams& p, const std::vector<float>* walls, float* rec,
                  const std::vector<std::int32_t>& bidx,
                  const std::vector<std::int32_t>& boff, const std::vector<std::int32_t>& bk, float* dx, float* dy,
                  float* dz, std::size_t n) {
  PairArgs a;
  a.rec = rec, a.bidx = bidx.data(), a.boff = boff.data(), a.bk = bk.data();
  a.dx = dx, a.dy = dy, a.dz = dz, a.n = n;
  const float h = p.kernelRadius;
  a.h = h, a.h2 = h * h, a.h6 = a.h2 * a.h2 * a.h2;
  a.cp = 315.0f / (64.0f * kPi * std::pow(h, 9.0f));
  a.cs = 45.0f / (kPi * std::pow(h, 6.0f));
  const float spacing = 2.0f * p.particleRadius;
  const float volume = spacing * spacing * spacing;
  a.epsK = p.relaxation * epsScale(p);
  const float sdq = a.h2 - (p.scorrDq * h) * (p.scorrDq * h);
  a.invWdq = 1.0f / ((sdq * sdq) * sdq);
  a.scorrK = p.scorrK * volume * a.h2 * 0.5f;
  a.scorrN = p.scorrN;
  const std::vector<float>&wallB = walls[0], &wallQ = walls[2], &wallO = walls[4];
  a.wallB = wallB.data(), a.wallDB = walls[1].data();
  a.wallSamples = int(wallB.size());
  a.wallInvStep = float(wallB.size() - 1) / h;
  a.wallQ = wallQ.data(), a.wallDQ = walls[3].data(), a.wallO = wallO.data(), a.wallDO = walls[5].data();
  a.wallS = walls[6].data(), a.wallQS = walls[7].data(), a.wallOS = walls[8].data();
  a.wallV = walls[9].data(), a.wallQV = walls[10].data(), a.wallOV = walls[11].data();
  a.edgeSamples = int(std::lround(std::sqrt(double(wallQ.size()))));
  a.cornerSamples = int(std::lround(std::cbrt(double(wallO.size()))));
  a.edgeInvStep = float(a.edgeSamples - 1) / h;
  a.cornerInvStep = float(a.cornerSamples - 1) / h;
  for (int k = 0; k < 3; ++k) {
    a.wallLo[k] = p.wallLo[k] + p.particleRadius;
    a.wallHi[k] = p.wallHi[k] - p.particleRadius;
    a.wallPlaneLo[k] = p.wallLo[k], a.wallPlaneHi[k] = p.wallHi[k];
  }
  return a;
}

}  // namespace

void FluidSolver::lambdaPass() {
  PairArgs a = pairArgs(params_, walls_, rec_.data(), bidx_, boff_, bk_, dx_.data(), dy_.data(), dz_.data(), n_);
  a.comp = comp_.data();
  if (!epsR_.empty()) a.epsR = epsR_.data();
  a.alphaK = complianceScale(soundSpeed_, substep_);
  if (!alphaR_.empty()) a.alphaR = alphaR_.data();
  if (a.alphaK > 0.0f || a.alphaR) a.lambdaSum = lambdaSum_.data();
  const bool simd = useSimd();
  forChunks(bk_.size(), kBlockChunk, [&](std::size_t b0, std::size_t b1) {
    simd ? lambdaBlocksAvx2(a, b0, b1) : lambdaBlocksScalar(a, b0, b1);
  });
}

float FluidSolver::autoSoundSpeed(float gravity, float height, float vmax) {
  const float g = std::max(std::fabs(gravity), 9.81f);
  return 15.0f * std::max(std::sqrt(2.0f * g * std::max(height, 0.0f)), std::fabs(vmax));
}

void FluidSolver::correctionPass() {
  PairArgs a =
      pairArgs(params_, walls_, rec_.data(), bidx_, boff_, bk_, dx_.data(), dy_.data(), dz_.data(), n_);
  a.scorrBeta = scorrBeta_;
  if (scorrOff_) a.scorrK = 0.0f;
  if (substep_ > 0.0f && iterations_ > 0) {  // s_corr as a force below kScorrStep (FluidParams::scorrK)
    const float r = substep_ / kScorrStep;
    a.scorrK *= std::min(1.0f, (r * r) * (float(kScorrIterations) / float(iterations_)));
  }
  const bool simd = useSimd();
  forChunks(bk_.size(), kBlockChunk, [&](std::size_t b0, std::size_t b1) {
    simd ? correctionBlocksAvx2(a, b0, b1) : correctionBlocksScalar(a, b0, b1);
  });
}

bool FluidSolver::warmStart() {
  if (carried_.empty() || !n_) return false;
  for (std::size_t r = 0; r < n_; ++r) rec_[r * kRecord + kLambda] = carried_[r];
  // Shepard averages over the neighbours that carry (fluid with a compliance), Jacobi (each
  // pass reads the last pass's values from the records), the same bits for any threads and
  // either kernel. A fluid particle without a compliance keeps no multiplier sum: it carries
  // 0 and is left out of its neighbours' averages (the kernels weigh by the fluid flag, here
  // cleared for it until the averages are done), which it would otherwise dilute.
  bool someDont = false;  // a fluid particle without a compliance (solids' entries have none either)
  for (std::size_t r = 0; r < n_ && !alphaR_.empty() && !someDont; ++r)
    someDont = rec_[r * kRecord + kFluid] != 0.0f && !(alphaR_[r] > 0.0f);
  if (someDont) {
    warmFluidFlag_.resize(n_);
    for (std::size_t r = 0; r < n_; ++r) {
      warmFluidFlag_[r] = rec_[r * kRecord + kFluid];
      if (!(alphaR_[r] > 0.0f)) rec_[r * kRecord + kFluid] = 0.0f;
    }
  }
  PairArgs a = pairArgs(params_, walls_, rec_.data(), bidx_, boff_, bk_, dx_.data(), dy_.data(), dz_.data(), n_);
  const bool simd = useSimd();
  for (int pass = 0; pass < params_.warmSmoothing; ++pass) {
    forChunks(bk_.size(), kBlockChunk, [&](std::size_t b0, std::size_t b1) {
      simd ? smoothLambdaBlocksAvx2(a, b0, b1, carried_.data()) : smoothLambdaBlocksScalar(a, b0, b1, carried_.data());
    });
    for (std::size_t r = 0; r < n_; ++r) rec_[r * kRecord + kLambda] = carried_[r];
  }
  for (std::size_t r = 0; someDont && r < n_; ++r) rec_[r * kRecord + kFluid] = warmFluidFlag_[r];
  std::copy(carried_.begin(), carried_.begin() + std::ptrdiff_t(n_), lambdaSum_.begin());
  scorrOff_ = true;
  correctionPass();
  scorrOff_ = false;
  return true;
}

void FluidSolver::multipliers(float* lambda) const {
  const std::int32_t* order = grid_.order().data();
  for (std::size_t r = 0; r < n_; ++r) lambda[order[r]] = lambdaSum_[r];
}

void FluidSolver::densityIteration() {
  lambdaPass();
  correctionPass();
}

void FluidSolver::applyCorrections(bool solidsToo) {
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t r = b; r < e; ++r) {
      float* p = &rec_[r * kRecord];
      if (p[kFluid] == 0.0f && !solidsToo) continue;
      p[kX] += dx_[r], p[kY] += dy_[r], p[kZ] += dz_[r];
    }
  });
}

void FluidSolver::corrections(float* dx, float* dy, float* dz) const {
  grid_.scatter(dx_.data(), dx);
  grid_.scatter(dy_.data(), dy);
  grid_.scatter(dz_.data(), dz);
}

void FluidSolver::volumes(float* nu) const {
  const std::int32_t* order = grid_.order().data();
  for (std::size_t r = 0; r < n_; ++r) nu[order[r]] = rec_[r * kRecord + kNu];
}

void FluidSolver::lambdas(float* lambda) const {
  const std::int32_t* order = grid_.order().data();
  for (std::size_t r = 0; r < n_; ++r) lambda[order[r]] = rec_[r * kRecord + kLambda];
}

void FluidSolver::positions(float* x, float* y, float* z) const {
  const std::int32_t* order = grid_.order().data();
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t r = b; r < e; ++r) {
      const std::size_t id = std::size_t(order[r]);
      x[id] = rec_[r * kRecord + kX], y[id] = rec_[r * kRecord + kY], z[id] = rec_[r * kRecord + kZ];
    }
  });
}

void FluidSolver::setPositions(const float* x, const float* y, const float* z) {
  const std::int32_t* order = grid_.order().data();
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t r = b; r < e; ++r) {
      const std::size_t id = std::size_t(order[r]);
      rec_[r * kRecord + kX] = x[id], rec_[r * kRecord + kY] = y[id], rec_[r * kRecord + kZ] = z[id];
    }
  });
}

// ---- velocity passes (once per substep; scalar, over the row lists) -----------------

bool FluidSolver::useSimd() const {
  return kernel_ == Kernel::kAvx2 || (kernel_ == Kernel::kAuto && __builtin_cpu_supports("avx2"));
}

// Alg. 1 line 22 over the blocked lists: one loop for XSPH (Eq. 17, SPH-normalised) and the
// vorticity omega (Eq. 15), both from the same velocities (Jacobi), then one for the
// confinement (Eq. 16), then cohesion. Solids take no part and keep their velocities.
void FluidSolver::velocityPasses(float* vx, float* vy, float* vz, float h, const ViscousSolids* solids) {
  viscIterations_ = 0;
  if (!n_ || !(xsphOn_ || vortOn_ || cohOn_ || viscOn_)) return;
  require(std::isfinite(h) && h > 0.0f, "velocityPasses: substep h must be positive");
  const std::size_t nPad = std::size_t(ghost_);
  const std::int32_t* order = grid_.order().data();
  vrec_.assign((nPad + 1) * kRecord, 0.0f);
  for (int k = 0; k < 3; ++k) v_[k].resize(nPad), omega_[k].resize(nPad);
  forChunks(nPad + 1, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t r = b; r < e; ++r) {
      const float* p = &rec_[r * kRecord];
      float* q = &vrec_[r * kRecord];
      q[kX] = p[kX], q[kY] = p[kY], q[kZ] = p[kZ];
      q[kNu] = p[kFluid] != 0.0f ? p[kNu] : 0.0f;
      if (r >= n_) continue;
      const std::size_t id = std::size_t(order[r]);
      q[kVX] = v_[0][r] = vx[id], q[kVY] = v_[1][r] = vy[id], q[kVZ] = v_[2][r] = vz[id];
    }
  });
  if (xsphOn_ || vortOn_) {
    VelocityArgs a;
    a.vrec = vrec_.data(), a.bidx = bidx_.data(), a.boff = boff_.data(), a.bk = bk_.data(), a.n = n_;
    const float kh = params_.kernelRadius;
    a.h = kh, a.h2 = kh * kh;
    a.cs = 45.0f / (kPi * std::pow(kh, 6.0f));
    a.cp = 315.0f / (64.0f * kPi * std::pow(kh, 9.0f));
    a.xsph = params_.xsph * a.cp;
    a.vortStep = params_.vorticity * h;
    a.substepH = h;
    if (!xsphR_.empty()) a.xsphR = xsphR_.data();
    if (!vortR_.empty()) a.vortR = vortR_.data();
    for (int k = 0; k < 3; ++k) a.out[k] = v_[k].data(), a.omega[k] = vortOn_ ? omega_[k].data() : nullptr;
    const bool simd = useSimd();
    forChunks(bk_.size(), kBlockChunk, [&](std::size_t b0, std::size_t b1) {
      simd ? smoothingBlocksAvx2(a, b0, b1) : smoothingBlocksScalar(a, b0, b1);
    });
    if (a.omega[0])
      forChunks(bk_.size(), kBlockChunk, [&](std::size_t b0, std::size_t b1) {
        simd ? confinementBlocksAvx2(a, b0, b1) : confinementBlocksScalar(a, b0, b1);
      });
  }
  if (cohOn_) cohesionPass(v_[0].data(), v_[1].data(), v_[2].data(), h);
  if (viscOn_) viscosityPass(h, solids);
  const bool freeSolids = viscOn_ && solids;  // their velocities were solved too
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t r = b; r < e; ++r)
      if (rec_[r * kRecord + kFluid] != 0.0f || (freeSolids && roleR_[r] == ViscousSolids::kFree)) {
        const std::size_t id = std::size_t(order[r]);
        vx[id] = v_[0][r], vy[id] = v_[1][r], vz[id] = v_[2][r];
      }
  });
}

// Cohesion (Akinci et al. 2013, Eq. 1 without the curvature term): a_i = -gamma sum_j
// V C(r) (p_i - p_j) / r over fluid j, C the cohesion spline with 32 / (pi h^9), V = (2r)^3.
void FluidSolver::cohesionPass(float* vx, float* vy, float* vz, float h) const {
  const float kh = params_.kernelRadius, spacing = 2.0f * params_.particleRadius;
  const float unit = spacing * spacing * spacing * 32.0f / (kPi * std::pow(kh, 9.0f));
  const int width = lists_.width;
  std::vector<float> a(3 * n_, 0.0f);
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      const float* ri = &rec_[i * kRecord];
      if (ri[kFluid] == 0.0f) continue;
      const float scale = (cohR_.empty() ? params_.cohesion : cohR_[i]) * unit;
      if (!(scale > 0.0f)) continue;
      for (std::int32_t k = 0; k < lists_.count[i]; ++k) {
        const std::size_t j = std::size_t(lists_.index[i * std::size_t(width) + std::size_t(k)]);
        const float* rj = &rec_[j * kRecord];
        if (rj[kFluid] == 0.0f) continue;
        const float d[3] = {ri[kX] - rj[kX], ri[kY] - rj[kY], ri[kZ] - rj[kZ]};
        const float r = std::sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2]);
        if (r <= kMinDistance) continue;
        const float f = -scale * cohesionSpline(r, kh) / r;
        for (int c = 0; c < 3; ++c) a[3 * i + std::size_t(c)] += f * d[c];
      }
    }
  });
  for (std::size_t i = 0; i < n_; ++i) vx[i] += h * a[3 * i], vy[i] += h * a[3 * i + 1], vz[i] += h * a[3 * i + 2];
}

// The implicit viscosity step (velocityPasses, pbd/fluid.h) on v_ by rank: preconditioned
// CG on (M + h K) v' = M v + h K_b v_b (fixed solids and walls), the three components one
// vector of 3n unknowns (one matrix, shared step sizes), plus six per coupled rigid body
// (ViscousSolids). Fixed solids' and bodies' points' rows are empty (their entries stay 0
// in r, p, q; a point's velocity is its body's, written into the sweep's input). Dot
// products sum fixed chunks into partial_ and the partials in chunk order, then the bodies
// in body order; bodies' points are summed into their bodies serially in rank order: the
// same bits for any thread count.
void FluidSolver::viscosityPass(float h, const ViscousSolids* solids) {
  const float kh = params_.kernelRadius, kh2 = kh * kh, eta2 = 0.01f * kh2;
  const float cs = 45.0f / (kPi * std::pow(kh, 6.0f));
  const std::size_t width = std::size_t(lists_.width);
  const std::size_t nb = solids ? solids->bodies : 0;
  viscK_.resize(n_ * width), viscDiag_.resize(n_), viscExtra_.resize(n_), viscMass_.resize(n_), roleR_.resize(n_);
  for (int k = 0; k < 3; ++k)
    cgR_[k].resize(n_), cgZ_[k].resize(n_), cgP_[k].resize(n_), cgQ_[k].resize(n_), viscRhs_[k].resize(n_);
  const std::int32_t* order = grid_.order().data();
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      const float* ri = &rec_[i * kRecord];
      std::int32_t role = ViscousSolids::kFixed;
      if (ri[kFluid] != 0.0f) {
        role = kRoleFluid;
      } else if (solids && ri[kW] > 0.0f) {
        role = solids->role[order[i]];
        require(role == ViscousSolids::kFixed || role == ViscousSolids::kFree || (role >= 0 && std::size_t(role) < nb),
                "velocityPasses: a solid's role must be kFixed, kFree or a body index below ViscousSolids::bodies");
      }
      roleR_[i] = role;
      viscMass_[i] = role == kRoleFluid ? ri[kMass] : role == ViscousSolids::kFree ? 1.0f / ri[kW] : 0.0f;
    }
  });
  const PairArgs walls = pairArgs(params_, walls_, nullptr, bidx_, boff_, bk_, nullptr, nullptr, nullptr, n_);
  // h K_ij = h 2 nu_i nu_j mu_ij |gradW_ij| r / (r^2 + 0.01 h^2), |gradW| = cs (h - r)^2,
  // between a fluid particle and a fluid or coupled solid neighbour (viscK_; a solid's mu is
  // its fluid neighbour's, so both rows hold the same bits); a fixed solid neighbour and the
  // walls' ghost samples are fixed velocities (no-slip, one way): their weights go to the
  // diagonal (viscExtra_) and, times v_j, to the right-hand side (walls: v = 0).
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      const float* ri = &rec_[i * kRecord];
      const std::int32_t role = roleR_[i];
      const bool isFluid = role == kRoleFluid;
      float extra = 0.0f, rhs[3] = {0.0f, 0.0f, 0.0f};
      for (std::size_t k = 0; k < std::size_t(lists_.count[i]); ++k) {
        const std::size_t j = std::size_t(lists_.index[i * width + k]);
        const float* rj = &rec_[j * kRecord];
        const bool jFluid = rj[kFluid] != 0.0f;
        float w = 0.0f;
        if (isFluid || (role != ViscousSolids::kFixed && jFluid)) {
          const float dx = ri[kX] - rj[kX], dy = ri[kY] - rj[kY], dz = ri[kZ] - rj[kZ];
          const float r2 = (dx * dx + dy * dy) + dz * dz, r = std::sqrt(r2);
          if (r < kh) {
            const float t = kh - r;
            const float mu = isFluid && jFluid ? 0.5f * (muR_[i] + muR_[j]) : isFluid ? muR_[i] : muR_[j];
            w = h * 2.0f * (ri[kNu] * rj[kNu]) * mu * cs * (t * t) * r / (r2 + eta2) * laplaceScale_;
          }
        }
        if (!jFluid && roleR_[j] == ViscousSolids::kFixed) {
          extra += w;
          for (int c = 0; c < 3; ++c) rhs[c] += w * v_[c][j];
          w = 0.0f;
        }
        viscK_[i * width + k] = w;
      }
      if (isFluid) extra += h * 2.0f * ri[kNu] * muR_[i] * detail::wallViscosity(walls, ri);
      viscExtra_[i] = extra;
      for (int c = 0; c < 3; ++c) viscRhs_[c][i] = rhs[c];
      // Fluid and free rows: their diagonal, for Jacobi (the row's weights are still in
      // cache); a body's point: its row sum (for the body's block).
      float d = viscMass_[i] + extra;
      for (std::size_t k = 0; k < std::size_t(lists_.count[i]); ++k) d += viscK_[i * width + k];
      viscDiag_[i] = role == ViscousSolids::kFixed ? 1.0f : d;
    }
  });
  // The bodies' points that touch the fluid, in rank order, and the bodies' 6x6 blocks:
  //   [ (M + S) I   -C        ]   S = sum_s W_s, C = sum_s W_s [r_s]x,
  //   [ C           I_b + Q   ]   Q = sum_s W_s (|r_s|^2 I - r_s r_s^T), W_s = h sum_j K_sj
  pointRanks_.clear();
  using Vec3d = Eigen::Vector3d;
  using Mat6 = Eigen::Matrix<double, 6, 6>;
  std::vector<Mat6> block(nb);
  const auto centre = [&](std::size_t body) -> Vec3d { return Vec3d(solids->centre + 3 * body); };
  const auto arm = [&](std::size_t i) -> Vec3d {
    return Vec3d(rec_[i * kRecord + kX], rec_[i * kRecord + kY], rec_[i * kRecord + kZ]) - centre(std::size_t(roleR_[i]));
  };
  for (std::size_t body = 0; body < nb; ++body) {
    block[body].setZero();
    block[body].topLeftCorner<3, 3>() = solids->mass[body] * Eigen::Matrix3d::Identity();
    block[body].bottomRightCorner<3, 3>() = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(solids->inertia + 9 * body);
  }
  for (std::size_t i = 0; nb > 0 && i < n_; ++i) {  // a serial pass: only where there are bodies
    if (roleR_[i] < 0 || !(viscDiag_[i] > 0.0f)) continue;
    pointRanks_.push_back(std::int32_t(i));
    const double W = viscDiag_[i];
    const Vec3d r = arm(i);
    Eigen::Matrix3d cross;
    cross << 0, -r.z(), r.y(), r.z(), 0, -r.x(), -r.y(), r.x(), 0;
    Mat6& B = block[std::size_t(roleR_[i])];
    B.topLeftCorner<3, 3>() += W * Eigen::Matrix3d::Identity();
    B.topRightCorner<3, 3>() -= W * cross;
    B.bottomLeftCorner<3, 3>() += W * cross;
    B.bottomRightCorner<3, 3>() += W * (r.squaredNorm() * Eigen::Matrix3d::Identity() - r * r.transpose());
  }
  bodyPrec_.assign(36 * nb, 0.0);
  for (std::size_t body = 0; body < nb; ++body)
    Eigen::Map<Mat6>(bodyPrec_.data() + 36 * body) = block[body].inverse();
  bodyX_.assign(6 * nb, 0.0), bodyR_.assign(6 * nb, 0.0), bodyZ_.assign(6 * nb, 0.0);
  bodyP_.assign(6 * nb, 0.0), bodyQ_.assign(6 * nb, 0.0);
  for (std::size_t body = 0; body < nb; ++body)
    for (int c = 0; c < 3; ++c) bodyX_[6 * body + c] = solids->v[3 * body + c], bodyX_[6 * body + 3 + c] = solids->w[3 * body + c];
  const auto bodyMomentum = [&](const double* x, std::size_t body, double* mom) {  // (M v, I w)
    const double* I = solids->inertia + 9 * body;
    for (int r = 0; r < 3; ++r) {
      mom[r] = solids->mass[body] * x[r];
      mom[3 + r] = (I[3 * r] * x[3] + I[3 * r + 1] * x[4]) + I[3 * r + 2] * x[5];
    }
  };

  const std::size_t units = (n_ + kParticleChunk - 1) / kParticleChunk;
  partial_.resize(units);
  const auto sum = [&](auto&& term, const std::vector<double>& bu, const std::vector<double>& bv) {
    // sum over ranks of term(i), in fixed chunk order, then the bodies' bu . bv
    forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
      double s = 0.0;
      for (std::size_t i = b; i < e; ++i) s += term(i);
      partial_[b / kParticleChunk] = s;
    });
    double s = 0.0;
    for (double x : partial_) s += x;
    for (std::size_t k = 0; k < bu.size(); ++k) s += bu[k] * bv[k];
    return s;
  };
  const auto active = [&](std::size_t i) { return roleR_[i] == kRoleFluid || roleR_[i] == ViscousSolids::kFree; };
  const auto precondition = [&] {  // z = P^-1 r for the bodies
    for (std::size_t body = 0; body < nb; ++body)
      Eigen::Map<Eigen::Matrix<double, 6, 1>>(bodyZ_.data() + 6 * body) =
          Eigen::Map<const Mat6>(bodyPrec_.data() + 36 * body) * Eigen::Map<const Eigen::Matrix<double, 6, 1>>(bodyR_.data() + 6 * body);
  };
  // out = A in on the active rows and the bodies. The neighbours' values are read from an
  // interleaved copy (x y z of a rank in one cache line, not three): the sweep's cost is
  // those reads. A body's point reads its body's velocity there.
  cgX_.resize(3 * n_ + 1);  // + 1: the last rank's x y z read as four floats
  cgX_[3 * n_] = 0.0f;
  const auto apply = [&](std::vector<float>* in, const std::vector<double>& bodyIn, std::vector<float>* out,
                         std::vector<double>& bodyOut) {
    forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
      for (std::size_t i = b; i < e; ++i) {
        if (roleR_[i] >= 0) {
          const std::size_t body = std::size_t(roleR_[i]);
          const Vec3d u = Vec3d(&bodyIn[6 * body]) + Vec3d(&bodyIn[6 * body + 3]).cross(arm(i));
          for (int c = 0; c < 3; ++c) cgX_[3 * i + std::size_t(c)] = float(u[c]);
        } else {
          for (int c = 0; c < 3; ++c) cgX_[3 * i + std::size_t(c)] = in[c][i];
        }
      }
    });
    const float* x = cgX_.data();
    forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
      for (std::size_t i = b; i < e; ++i) {
        if (roleR_[i] == ViscousSolids::kFixed) {
          for (int c = 0; c < 3; ++c) out[c][i] = 0.0f;
          continue;
        }
        // x y z (and a fourth float, unused) in one vector: per component the same
        // operations as three scalar sums, in one register (the sweep was bound by the
        // three loads and nine scalar operations a neighbour).
        const float m = viscMass_[i] + viscExtra_[i];
        const Float4 xi = load4(x + 3 * i);
        Float4 acc = m * xi;
        const float* w = &viscK_[i * width];
        const std::int32_t* nbr = &lists_.index[i * width];
        for (std::size_t k = 0; k < std::size_t(lists_.count[i]); ++k)  // a fixed solid's w is 0: it adds 0
          acc = acc + w[k] * (xi - load4(x + 3 * std::size_t(nbr[k])));
        for (int c = 0; c < 3; ++c) out[c][i] = acc[c];
      }
    });
    for (std::size_t body = 0; body < nb; ++body) bodyMomentum(&bodyIn[6 * body], body, &bodyOut[6 * body]);
    // F and T, in rank order; the points' rows are then cleared (the other points of a body
    // have no fluid neighbour and no mass: their rows are 0 already).
    for (const std::int32_t s : pointRanks_) {
      const auto i = std::size_t(s);
      const Vec3d f(out[0][i], out[1][i], out[2][i]), t = arm(i).cross(f);
      double* o = &bodyOut[6 * std::size_t(roleR_[i])];
      for (int c = 0; c < 3; ++c) o[c] += f[c], o[3 + c] += t[c], out[c][i] = 0.0f;
    }
  };
  // r = b - A x0 (x0 = v), z = P^-1 r, p = z.
  apply(v_, bodyX_, cgQ_, bodyQ_);
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i)
      for (int c = 0; c < 3; ++c) {
        const bool on = active(i);
        cgR_[c][i] = on ? (viscMass_[i] * v_[c][i] + viscRhs_[c][i]) - cgQ_[c][i] : 0.0f;
        cgP_[c][i] = cgZ_[c][i] = on ? cgR_[c][i] / viscDiag_[i] : 0.0f;
      }
  });
  for (std::size_t body = 0; body < nb; ++body) {
    double mom[6];
    bodyMomentum(&bodyX_[6 * body], body, mom);
    for (int c = 0; c < 6; ++c) bodyR_[6 * body + std::size_t(c)] = mom[c] - bodyQ_[6 * body + std::size_t(c)];
  }
  precondition();
  bodyP_ = bodyZ_;
  // The scale: |M v| in the same weighted norm (b^T D^-1 b), each particle's at least its
  // mass times kViscosityFloorSpeed; the bodies' linear momenta likewise. (A floor of 1 m/s
  // left slow flows undamped: a plate sliding at 5 cm/s on honey changes by less than 1e-4
  // m/s a substep, under that tolerance, and the solve stopped running at all.)
  const double floor2 = double(kViscosityFloorSpeed) * kViscosityFloorSpeed;
  std::vector<double> bodyScale(nb, 0.0);
  for (std::size_t body = 0; body < nb; ++body) {
    const double M = solids->mass[body], v2 = Vec3d(solids->v + 3 * body).squaredNorm();
    bodyScale[body] = std::max(M * M * v2, M * M * floor2) / block[body](0, 0);
  }
  const std::vector<double> ones(nb, 1.0);
  const double bnorm = sum(
      [&](std::size_t i) {
        if (!active(i)) return 0.0;
        const double m = viscMass_[i];
        double s = 0.0;
        for (int c = 0; c < 3; ++c) s += (m * v_[c][i]) * (m * v_[c][i]);
        return std::max(s, m * m * floor2) / viscDiag_[i];
      },
      bodyScale, ones);
  const double tol2 = double(kViscosityTolerance) * kViscosityTolerance * bnorm;
  const auto dot = [&](std::vector<float>* a, std::vector<float>* b, const std::vector<double>& ba, const std::vector<double>& bb) {
    return sum([&](std::size_t i) { return double(a[0][i]) * b[0][i] + double(a[1][i]) * b[1][i] + double(a[2][i]) * b[2][i]; },
               ba, bb);
  };
  double rz = dot(cgR_, cgZ_, bodyR_, bodyZ_);
  int it = 0;
  while (it < kViscosityMaxIterations && rz > tol2) {
    apply(cgP_, bodyP_, cgQ_, bodyQ_);
    const double pq = dot(cgP_, cgQ_, bodyP_, bodyQ_);
    if (!(pq > 0.0)) break;
    const float alpha = float(rz / pq);
    // Per component over the chunk, through local pointers: the vectors' element accesses
    // inside one loop over i were reloaded on every store (they may alias), which made this
    // update 11 % of a viscous dam break's step (bench_pbf --viscosity 50).
    forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
      const std::int32_t* const role = roleR_.data();
      const float* const diag = viscDiag_.data();
      for (int c = 0; c < 3; ++c) {
        float* __restrict const v = v_[c].data();
        float* __restrict const r = cgR_[c].data();
        float* __restrict const z = cgZ_[c].data();
        const float* __restrict const p = cgP_[c].data();
        const float* __restrict const q = cgQ_[c].data();
        for (std::size_t i = b; i < e; ++i) {
          if (role[i] != kRoleFluid && role[i] != ViscousSolids::kFree) continue;  // active(i)
          v[i] += alpha * p[i];
          r[i] -= alpha * q[i];
          z[i] = r[i] / diag[i];
        }
      }
    });
    for (std::size_t k = 0; k < 6 * nb; ++k) bodyX_[k] += double(alpha) * bodyP_[k], bodyR_[k] -= double(alpha) * bodyQ_[k];
    precondition();
    const double rzNew = dot(cgR_, cgZ_, bodyR_, bodyZ_);
    const float beta = float(rzNew / rz);
    rz = rzNew;
    forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
      for (int c = 0; c < 3; ++c) {
        float* __restrict const p = cgP_[c].data();
        const float* __restrict const z = cgZ_[c].data();
        for (std::size_t i = b; i < e; ++i) p[i] = z[i] + beta * p[i];
      }
    });
    for (std::size_t k = 0; k < 6 * nb; ++k) bodyP_[k] = bodyZ_[k] + double(beta) * bodyP_[k];
    ++it;
  }
  viscIterations_ = it;
  for (std::size_t body = 0; body < nb; ++body)
    for (int c = 0; c < 3; ++c) solids->v[3 * body + c] = bodyX_[6 * body + c], solids->w[3 * body + c] = bodyX_[6 * body + 3 + c];
}

// ---- density error -------------------------------------------------------------------

float FluidSolver::lastMeanCompression() const {
  const std::size_t units = (n_ + kParticleChunk - 1) / kParticleChunk;
  std::vector<double> sum(units, 0.0);
  std::vector<std::size_t> count(units, 0);
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    const std::size_t u = b / kParticleChunk;
    for (std::size_t r = b; r < e; ++r)
      if (rec_[r * kRecord + kFluid] != 0.0f) sum[u] += comp_[r], ++count[u];
  });
  double total = 0.0;
  std::size_t fluid = 0;
  for (std::size_t u = 0; u < units; ++u) total += sum[u], fluid += count[u];  // fixed order
  return fluid ? float(total / double(fluid)) : 0.0f;
}

DensityError FluidSolver::densityError() const {
  DensityError out;
  if (!n_) return out;
  const float h = params_.kernelRadius, h2 = h * h, cp = 315.0f / (64.0f * kPi * std::pow(h, 9.0f));
  const int width = lists_.width;
  struct Part {
    double sumComp = 0, sumAbs = 0;
    float maxComp = 0;
    std::size_t count = 0;
  };
  const std::size_t units = (n_ + kParticleChunk - 1) / kParticleChunk;
  std::vector<Part> parts(units);
  const PairArgs walls = pairArgs(params_, walls_, nullptr, bidx_, boff_, bk_, nullptr, nullptr, nullptr, n_);
  forChunks(n_, kParticleChunk, [&](std::size_t b, std::size_t e) {
    Part& p = parts[b / kParticleChunk];
    for (std::size_t i = b; i < e; ++i) {
      const float* ri = &rec_[i * kRecord];
      if (ri[kFluid] == 0.0f) continue;
      // Positions moved since the lists were built: a pair may have come within h
      // unseen. The lists' skin is zero, as in the solver itself (Macklin & Müller 2013).
      float rho = ri[kNu] * h2 * h2 * h2;
      for (std::int32_t k = 0; k < lists_.count[i]; ++k) {
        const float* rj = &rec_[std::size_t(lists_.index[i * std::size_t(width) + std::size_t(k)]) * kRecord];
        const float dx = ri[kX] - rj[kX], dy = ri[kY] - rj[kY], dz = ri[kZ] - rj[kZ];
        const float s = h2 - ((dx * dx + dy * dy) + dz * dz);
        if (s > 0.0f) rho += rj[kNu] * ((s * s) * s);
      }
      const float c = (cp * rho + wallTerm(walls, ri).c) - 1.0f;
      p.sumComp += std::max(c, 0.0f), p.sumAbs += std::fabs(c);
      p.maxComp = std::max(p.maxComp, c);
      ++p.count;
    }
  });
  double comp = 0, abs = 0;
  for (const Part& p : parts) {
    comp += p.sumComp, abs += p.sumAbs;
    out.maxCompression = std::max(out.maxCompression, p.maxComp);
    out.fluidCount += p.count;
  }
  if (out.fluidCount) {
    out.meanCompression = float(comp / double(out.fluidCount));
    out.meanAbs = float(abs / double(out.fluidCount));
  }
  return out;
}

std::size_t FluidSolver::neighborBytes() const {
  return grid_.heldBytes() + heldBytes(lists_.index, lists_.count);
}

std::size_t FluidSolver::solverBytes() const {
  return heldBytes(walls_[kB], walls_[kDB], walls_[kQ], walls_[kDQ], walls_[kO], walls_[kDO], walls_[kS],
                   walls_[kQS], walls_[kOS], rec_, dx_, dy_, dz_, comp_, lambdaSum_, bidx_, boff_, bk_, vrec_, v_[0], v_[1], v_[2], omega_[0],
                   omega_[1], omega_[2]);
}

}  // namespace physketch::pbd
