#include "pbd/fluid_kernels.h"

#include <immintrin.h>

#include <algorithm>
#include <cmath>

namespace physketch::pbd::detail {

// ---- per-particle finish (the scalar reference; the AVX2 finish repeats it lane-wise) ---

WallTerm wallTerm(const PairArgs& a, const float* p) {
  WallTerm t;
  bool near = false;  // most particles are further than h from every wall
  for (int k = 0; k < 3; ++k) near |= (p[k] - a.wallPlaneLo[k] < a.h) | (a.wallPlaneHi[k] - p[k] < a.h);
  if (!near) return t;
  for (int k = 0; k < 3; ++k)
    for (int side = 0; side < 2; ++side) {
      const float y = side ? a.wallPlaneHi[k] - p[k] : p[k] - a.wallPlaneLo[k];  // distance to the plane
      if (!(y < a.h)) continue;
      const float u = std::max(y, 0.0f) * a.wallInvStep;
      const int s = std::min(int(u), a.wallSamples - 2);
      const float f = u - float(s);
      t.c += a.wallB[s] + f * (a.wallB[s + 1] - a.wallB[s]);
      const float db = a.wallDB[s] + f * (a.wallDB[s + 1] - a.wallDB[s]);
      t.g[k] += side ? -db : db;  // d/dp of B(y(p))
    }
  const WallTerm e = edgeTerm(a, p);
  t.c = t.c + e.c;
  for (int k = 0; k < 3; ++k) t.g[k] = t.g[k] + e.g[k];
  return t;
}

namespace {

// Bilinear and trilinear interpolation of row-major tables of n samples per axis at
// fractional indices u (u >= 0).
inline float lerp2(const float* t, int n, float u, float v) {
  const int i = std::min(int(u), n - 2), j = std::min(int(v), n - 2);
  const float f = u - float(i), g = v - float(j);
  const float* r0 = t + (std::size_t(i) * std::size_t(n) + std::size_t(j));
  const float* r1 = r0 + n;
  const float a0 = r0[0] + g * (r0[1] - r0[0]), a1 = r1[0] + g * (r1[1] - r1[0]);
  return a0 + f * (a1 - a0);
}
inline float lerp3(const float* t, int n, float u, float v, float w) {
  const int i = std::min(int(u), n - 2);
  const float f = u - float(i);
  const std::size_t plane = std::size_t(n) * std::size_t(n);
  const float a0 = lerp2(t + std::size_t(i) * plane, n, v, w), a1 = lerp2(t + std::size_t(i + 1) * plane, n, v, w);
  return a0 + f * (a1 - a0);
}

// Per axis, the walls within h of p: distance y (at least 0) and the sign of dy/dp.
struct NearWalls {
  float y[3][2], sgn[3][2];
  int count[3] = {0, 0, 0}, axes = 0;  // axes: how many axes have a wall within h
  NearWalls(const PairArgs& a, const float* p) {
    for (int k = 0; k < 3; ++k) {
      const float lo = p[k] - a.wallPlaneLo[k], hi = a.wallPlaneHi[k] - p[k];
      if (lo < a.h) y[k][count[k]] = std::max(lo, 0.0f), sgn[k][count[k]++] = 1.0f;
      if (hi < a.h) y[k][count[k]] = std::max(hi, 0.0f), sgn[k][count[k]++] = -1.0f;
      axes += count[k] > 0;
    }
  }
};

}  // namespace

WallTerm edgeTerm(const PairArgs& a, const float* p) {
  WallTerm e;
  const NearWalls near(a, p);
  const auto& y = near.y;
  const auto& sgn = near.sgn;
  const auto& count = near.count;
  const int axes = near.axes;
  if (axes < 2) return e;
  const int E = a.edgeSamples;
  for (int k0 = 0; k0 < 3; ++k0)
    for (int k1 = k0 + 1; k1 < 3; ++k1)
      for (int s0 = 0; s0 < count[k0]; ++s0)
        for (int s1 = 0; s1 < count[k1]; ++s1) {  // ghosts behind both planes: counted twice
          const float u0 = y[k0][s0] * a.edgeInvStep, u1 = y[k1][s1] * a.edgeInvStep;
          e.c = e.c - lerp2(a.wallQ, E, u0, u1);
          e.g[k0] = e.g[k0] - sgn[k0][s0] * lerp2(a.wallDQ, E, u0, u1);
          e.g[k1] = e.g[k1] - sgn[k1][s1] * lerp2(a.wallDQ, E, u1, u0);
        }
  if (axes < 3) return e;
  const int C = a.cornerSamples;
  for (int s0 = 0; s0 < count[0]; ++s0)
    for (int s1 = 0; s1 < count[1]; ++s1)
      for (int s2 = 0; s2 < count[2]; ++s2) {  // behind all three: counted 3 times, taken off 3 times
        const float u0 = y[0][s0] * a.cornerInvStep, u1 = y[1][s1] * a.cornerInvStep, u2 = y[2][s2] * a.cornerInvStep;
        e.c = e.c + lerp3(a.wallO, C, u0, u1, u2);
        e.g[0] = e.g[0] + sgn[0][s0] * lerp3(a.wallDO, C, u0, u1, u2);
        e.g[1] = e.g[1] + sgn[1][s1] * lerp3(a.wallDO, C, u1, u0, u2);
        e.g[2] = e.g[2] + sgn[2][s2] * lerp3(a.wallDO, C, u2, u0, u1);
      }
  return e;
}

float wallViscosity(const PairArgs& a, const float* p) {
  const NearWalls near(a, p);
  const auto& y = near.y;
  const auto& count = near.count;
  const int axes = near.axes;
  float sum = 0.0f;
  for (int k = 0; k < 3; ++k)
    for (int s = 0; s < count[k]; ++s) {
      const float u = y[k][s] * a.wallInvStep;
      const int i = std::min(int(u), a.wallSamples - 2);
      const float f = u - float(i);
      sum = sum + (a.wallV[i] + f * (a.wallV[i + 1] - a.wallV[i]));
    }
  const int E = a.edgeSamples, C = a.cornerSamples;
  for (int k0 = 0; axes >= 2 && k0 < 3; ++k0)
    for (int k1 = k0 + 1; k1 < 3; ++k1)
      for (int s0 = 0; s0 < count[k0]; ++s0)
        for (int s1 = 0; s1 < count[k1]; ++s1)  // ghosts behind both planes: counted twice
          sum = sum - lerp2(a.wallQV, E, y[k0][s0] * a.edgeInvStep, y[k1][s1] * a.edgeInvStep);
  for (int s0 = 0; axes == 3 && s0 < count[0]; ++s0)
    for (int s1 = 0; s1 < count[1]; ++s1)
      for (int s2 = 0; s2 < count[2]; ++s2)  // behind all three
        sum = sum + lerp3(a.wallOV, C, y[0][s0] * a.cornerInvStep, y[1][s1] * a.cornerInvStep, y[2][s2] * a.cornerInvStep);
  return sum;
}

void wallScorr(const PairArgs& a, const float* p, float out[3]) {
  out[0] = out[1] = out[2] = 0.0f;
  if (!(a.scorrK > 0.0f)) return;
  const NearWalls near(a, p);
  const auto& y = near.y;
  const auto& sgn = near.sgn;
  const auto& count = near.count;
  const int axes = near.axes;
  if (axes == 0) return;
  float sum[3] = {0.0f, 0.0f, 0.0f};
  for (int k = 0; k < 3; ++k)
    for (int s = 0; s < count[k]; ++s) {  // each plane's ghosts push along its normal
      const float u = y[k][s] * a.wallInvStep;
      const int i = std::min(int(u), a.wallSamples - 2);
      const float f = u - float(i);
      sum[k] = sum[k] + sgn[k][s] * (a.wallS[i] + f * (a.wallS[i + 1] - a.wallS[i]));
    }
  const int E = a.edgeSamples, C = a.cornerSamples;
  for (int k0 = 0; axes >= 2 && k0 < 3; ++k0)
    for (int k1 = k0 + 1; k1 < 3; ++k1)
      for (int s0 = 0; s0 < count[k0]; ++s0)
        for (int s1 = 0; s1 < count[k1]; ++s1) {  // ghosts behind both planes: counted twice
          const float u0 = y[k0][s0] * a.edgeInvStep, u1 = y[k1][s1] * a.edgeInvStep;
          sum[k0] = sum[k0] - sgn[k0][s0] * lerp2(a.wallQS, E, u0, u1);
          sum[k1] = sum[k1] - sgn[k1][s1] * lerp2(a.wallQS, E, u1, u0);
        }
  for (int s0 = 0; axes == 3 && s0 < count[0]; ++s0)
    for (int s1 = 0; s1 < count[1]; ++s1)
      for (int s2 = 0; s2 < count[2]; ++s2) {  // behind all three
        const float u0 = y[0][s0] * a.cornerInvStep, u1 = y[1][s1] * a.cornerInvStep, u2 = y[2][s2] * a.cornerInvStep;
        sum[0] = sum[0] + sgn[0][s0] * lerp3(a.wallOS, C, u0, u1, u2);
        sum[1] = sum[1] + sgn[1][s1] * lerp3(a.wallOS, C, u1, u0, u2);
        sum[2] = sum[2] + sgn[2][s2] * lerp3(a.wallOS, C, u2, u0, u1);
      }
  // dp_i = -cs w_i sum_g coef g d with coef = -scorrK (q^n - beta q) (m_i + m_g), m_g = m_i,
  // w_i m_i = 1: 2 cs scorrK sum_g (q^n - beta q) g d.
  const float factor = 2.0f * a.cs * a.scorrK;
  for (int k = 0; k < 3; ++k) out[k] = factor * sum[k];
}

namespace {

// Accumulators of one lane, finished per particle.
struct LambdaAcc {
  float rho, gx, gy, gz, den;
};
struct CorrectionAcc {
  float x, y, z;
};

// The scalar kernels' per-particle finish: lambda from the sums (Macklin & Müller 2013
// Eq. 11, multi-fluid form of pbd/fluid.h), and dp with the walls.
void finishLambda(const PairArgs& a, std::size_t i, const LambdaAcc& acc) {
  if (i >= a.n) return;
  float* ri = a.rec + i * kRecord;
  float lambda = 0.0f, compression = 0.0f;
  if (ri[kFluid] != 0.0f) {
    // C_i = sum_j nu_j W_ij + walls - 1 with the particle's own W(0) = cp h^6.
    const WallTerm wall = wallTerm(a, ri);
    const float c = (a.cp * (acc.rho + ri[kNu] * a.h6) + wall.c) - 1.0f;
    compression = std::max(c, 0.0f);
    if (c > 0.0f) {
      // grad_i C_i = -cs sum_j nu_j g_ij d_ij + the walls' gradient
      const float gx = wall.g[0] - a.cs * acc.gx, gy = wall.g[1] - a.cs * acc.gy, gz = wall.g[2] - a.cs * acc.gz;
      const float grad2 = (gx * gx + gy * gy) + gz * gz;
      const float denom = (ri[kW] * grad2 + (a.cs * a.cs) * acc.den) + (a.epsR ? a.epsR[i] : a.epsK) * ri[kW];
      const float alphaK = a.alphaR ? a.alphaR[i] : a.alphaK;
      if (alphaK > 0.0f) {  // XPBD with compliance at = w / (c h)^2, the substep's sum kept <= 0 (pbd/fluid.h)
        const float at = alphaK * ri[kW];
        const float before = a.lambdaSum[i];
        const float after = std::min(before + (-c - at * before) / (denom + at), 0.0f);
        lambda = after - before;
        a.lambdaSum[i] = after;
      } else {
        lambda = -c / denom;
      }
    }
  }
  ri[kLambda] = lambda;
  if (a.comp) a.comp[i] = compression;
}

void finishCorrection(const PairArgs& a, std::size_t i, const CorrectionAcc& acc) {
  if (i >= a.n) return;
  const float* ri = a.rec + i * kRecord;
  // dp_i = w_i sum_j coef_ij gradW_ij with gradW_ij = -cs g_ij d_ij.
  const float s = -a.cs * ri[kW];
  float d[3] = {s * acc.x, s * acc.y, s * acc.z};
  if (ri[kFluid] != 0.0f && ri[kLambda] != 0.0f) {  // the walls' share of lambda_i's correction
    const WallTerm wall = wallTerm(a, ri);
    const float wl = ri[kW] * ri[kLambda];
    for (int k = 0; k < 3; ++k) d[k] = d[k] + wl * wall.g[k];
  }
  if (ri[kFluid] != 0.0f) {  // s_corr against the walls' ghosts (0 beyond h of every wall)
    float sw[3];
    wallScorr(a, ri, sw);
    for (int k = 0; k < 3; ++k) d[k] = d[k] + sw[k];
  }
  if (ri[kFluid] != 0.0f)
    for (int k = 0; k < 3; ++k) {  // walls: the corrected centre stays r inside the box
      const float p = ri[k] + d[k];
      d[k] = std::min(std::max(p, a.wallLo[k]), a.wallHi[k]) - ri[k];
    }
  a.dx[i] = d[0], a.dy[i] = d[1], a.dz[i] = d[2];
}

}  // namespace

// ---- scalar kernels: the reference -------------------------------------------------

namespace {

// The operations of one pair, written once; the AVX2 kernel below repeats them lane-wise.
struct Pair {
  float dx, dy, dz, r2, g, w;  // d = p_i - p_j; g = (h - r)^2 / r; w = (h^2 - r^2)^3 (0 outside h)
};
template <class Args>
inline Pair pairTerms(const Args& a, float xi, float yi, float zi, const float* rj) {
  Pair p;
  p.dx = xi - rj[kX], p.dy = yi - rj[kY], p.dz = zi - rj[kZ];
  p.r2 = (p.dx * p.dx + p.dy * p.dy) + p.dz * p.dz;
  const bool in = p.r2 < a.h2;
  const float r = std::sqrt(p.r2);
  const float t = a.h - r, s = a.h2 - p.r2;
  const float g = (t * t) / std::max(r, kMinDistance);
  const float w = (s * s) * s;
  p.g = in ? g : 0.0f;
  p.w = in ? w : 0.0f;
  return p;
}

}  // namespace

void lambdaBlocksScalar(const PairArgs& a, std::size_t b0, std::size_t b1) {
  for (std::size_t b = b0; b < b1; ++b) {
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (int l = 0; l < kLanes; ++l) {
      const std::size_t i = b * kLanes + std::size_t(l);
      const float* ri = a.rec + i * kRecord;
      LambdaAcc acc{0, 0, 0, 0, 0};
      for (std::int32_t k = 0; k < a.bk[b]; ++k) {
        const float* rj = a.rec + std::size_t(ids[k * kLanes + l]) * kRecord;
        const Pair p = pairTerms(a, ri[kX], ri[kY], ri[kZ], rj);
        const float nu = rj[kNu], w = rj[kW];
        const float gn = nu * p.g;
        acc.rho = acc.rho + nu * p.w;
        acc.gx = acc.gx + gn * p.dx;
        acc.gy = acc.gy + gn * p.dy;
        acc.gz = acc.gz + gn * p.dz;
        acc.den = acc.den + w * ((gn * gn) * p.r2);
      }
      finishLambda(a, i, acc);
    }
  }
}

void smoothLambdaBlocksScalar(const PairArgs& a, std::size_t b0, std::size_t b1, float* out) {
  for (std::size_t b = b0; b < b1; ++b) {
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (int l = 0; l < kLanes; ++l) {
      const std::size_t i = b * kLanes + std::size_t(l);
      if (i >= a.n) break;
      const float* ri = a.rec + i * kRecord;
      const float self = ri[kNu] * a.h6;
      float num = self * ri[kLambda], den = self;
      for (std::int32_t k = 0; k < a.bk[b]; ++k) {
        const float* rj = a.rec + std::size_t(ids[k * kLanes + l]) * kRecord;
        const float dx = ri[kX] - rj[kX], dy = ri[kY] - rj[kY], dz = ri[kZ] - rj[kZ];
        const float r2 = (dx * dx + dy * dy) + dz * dz;
        const float s = a.h2 - r2;
        const float w = r2 < a.h2 ? (s * s) * s : 0.0f;
        const float wf = w * (rj[kNu] * rj[kFluid]);
        num = num + wf * rj[kLambda];
        den = den + wf;
      }
      out[i] = ri[kFluid] != 0.0f ? num / den : 0.0f;
    }
  }
}

void correctionBlocksScalar(const PairArgs& a, std::size_t b0, std::size_t b1) {
  for (std::size_t b = b0; b < b1; ++b) {
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (int l = 0; l < kLanes; ++l) {
      const std::size_t i = b * kLanes + std::size_t(l);
      const float* ri = a.rec + i * kRecord;
      CorrectionAcc acc{0, 0, 0};
      for (std::int32_t k = 0; k < a.bk[b]; ++k) {
        const float* rj = a.rec + std::size_t(ids[k * kLanes + l]) * kRecord;
        const Pair p = pairTerms(a, ri[kX], ri[kY], ri[kZ], rj);
        // s_corr (Eq. 13) between fluid particles, balanced: (W / W(dq))^n - beta W / W(dq),
        // mass-symmetric.
        const float q = p.w * a.invWdq;
        float qn = q;
        for (int m = 1; m < a.scorrN; ++m) qn = qn * q;
        const float sm = (ri[kMass] + rj[kMass]) * (ri[kFluid] * rj[kFluid]);
        const float coef = (ri[kLambda] * rj[kNu] + rj[kLambda] * ri[kNu]) - (a.scorrK * (qn - a.scorrBeta * q)) * sm;
        const float cg = coef * p.g;
        acc.x = acc.x + cg * p.dx;
        acc.y = acc.y + cg * p.dy;
        acc.z = acc.z + cg * p.dz;
      }
      finishCorrection(a, i, acc);
    }
  }
}

// ---- velocity passes, scalar --------------------------------------------------------

namespace {

// Per-particle finishes of the scalar velocity passes (the AVX2 ones repeat them lane-wise).
void finishSmoothing(const VelocityArgs& a, std::size_t i, const float sum[3], const float w[3]) {
  if (i >= a.n) return;
  float* vi = a.vrec + i * kRecord;
  if (!(vi[kNu] > 0.0f)) return;  // solids keep their velocity
  const float xsph = a.xsphR ? a.xsphR[i] * a.cp : a.xsph;
  for (int k = 0; k < 3; ++k) a.out[k][i] = vi[kVX + k] + xsph * sum[k];
  if (!a.omega[0]) return;
  const float o[3] = {-a.cs * w[0], -a.cs * w[1], -a.cs * w[2]};
  for (int k = 0; k < 3; ++k) a.omega[k][i] = o[k];
  vi[kOmegaNorm] = std::sqrt((o[0] * o[0] + o[1] * o[1]) + o[2] * o[2]);
}

void finishConfinement(const VelocityArgs& a, std::size_t i, const float acc[3]) {
  if (i >= a.n || !(a.vrec[i * kRecord + kNu] > 0.0f)) return;
  const float eta[3] = {-a.cs * acc[0], -a.cs * acc[1], -a.cs * acc[2]};
  const float len = std::sqrt((eta[0] * eta[0] + eta[1] * eta[1]) + eta[2] * eta[2]);
  if (!(len > 1e-12f)) return;
  const float nn[3] = {eta[0] / len, eta[1] / len, eta[2] / len};
  const float w[3] = {a.omega[0][i], a.omega[1][i], a.omega[2][i]};
  const float step = a.vortR ? a.vortR[i] * a.substepH : a.vortStep;
  a.out[0][i] += step * (nn[1] * w[2] - nn[2] * w[1]);
  a.out[1][i] += step * (nn[2] * w[0] - nn[0] * w[2]);
  a.out[2][i] += step * (nn[0] * w[1] - nn[1] * w[0]);
}

}  // namespace

void smoothingBlocksScalar(const VelocityArgs& a, std::size_t b0, std::size_t b1) {
  for (std::size_t b = b0; b < b1; ++b) {
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (int l = 0; l < kLanes; ++l) {
      const std::size_t i = b * kLanes + std::size_t(l);
      const float* vi = a.vrec + i * kRecord;
      float sum[3] = {0, 0, 0}, w[3] = {0, 0, 0};
      for (std::int32_t k = 0; k < a.bk[b]; ++k) {
        const float* vj = a.vrec + std::size_t(ids[k * kLanes + l]) * kRecord;
        const Pair p = pairTerms(a, vi[kX], vi[kY], vi[kZ], vj);
        const float ux = vj[kVX] - vi[kVX], uy = vj[kVY] - vi[kVY], uz = vj[kVZ] - vi[kVZ];
        const float nw = vj[kNu] * p.w, gn = vj[kNu] * p.g;
        sum[0] = sum[0] + nw * ux, sum[1] = sum[1] + nw * uy, sum[2] = sum[2] + nw * uz;
        w[0] = w[0] + gn * (uy * p.dz - uz * p.dy);
        w[1] = w[1] + gn * (uz * p.dx - ux * p.dz);
        w[2] = w[2] + gn * (ux * p.dy - uy * p.dx);
      }
      finishSmoothing(a, i, sum, w);
    }
  }
}

void confinementBlocksScalar(const VelocityArgs& a, std::size_t b0, std::size_t b1) {
  for (std::size_t b = b0; b < b1; ++b) {
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (int l = 0; l < kLanes; ++l) {
      const std::size_t i = b * kLanes + std::size_t(l);
      const float* vi = a.vrec + i * kRecord;
      float acc[3] = {0, 0, 0};
      for (std::int32_t k = 0; k < a.bk[b]; ++k) {
        const float* vj = a.vrec + std::size_t(ids[k * kLanes + l]) * kRecord;
        const Pair p = pairTerms(a, vi[kX], vi[kY], vi[kZ], vj);
        const float e = (vj[kNu] * vj[kOmegaNorm]) * p.g;
        acc[0] = acc[0] + e * p.dx, acc[1] = acc[1] + e * p.dy, acc[2] = acc[2] + e * p.dz;
      }
      finishConfinement(a, i, acc);
    }
  }
}

// ---- AVX2: 8 lanes = the 8 ranks of a block; a neighbour slot is 8 record loads and an
// 8x8 transpose (no gathers) -----------------------------------------------------------

#define PHYSKETCH_AVX2 __attribute__((target("avx2"), always_inline)) inline

namespace {

// Loads the records of the 8 given ranks and transposes them: out[f] holds field f of
// each lane. Pure data movement: no rounding, so lanes see the scalar kernel's values.
PHYSKETCH_AVX2 void loadTransposed(const float* rec, const std::int32_t* ids, __m256 out[8]) {
  __m256 r[8];
  for (int l = 0; l < 8; ++l) r[l] = _mm256_loadu_ps(rec + std::size_t(ids[l]) * kRecord);
  const __m256 t0 = _mm256_unpacklo_ps(r[0], r[1]), t1 = _mm256_unpackhi_ps(r[0], r[1]);
  const __m256 t2 = _mm256_unpacklo_ps(r[2], r[3]), t3 = _mm256_unpackhi_ps(r[2], r[3]);
  const __m256 t4 = _mm256_unpacklo_ps(r[4], r[5]), t5 = _mm256_unpackhi_ps(r[4], r[5]);
  const __m256 t6 = _mm256_unpacklo_ps(r[6], r[7]), t7 = _mm256_unpackhi_ps(r[6], r[7]);
  const __m256 u0 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256 u1 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(3, 2, 3, 2));
  const __m256 u2 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256 u3 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(3, 2, 3, 2));
  const __m256 u4 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256 u5 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(3, 2, 3, 2));
  const __m256 u6 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256 u7 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(3, 2, 3, 2));
  out[0] = _mm256_permute2f128_ps(u0, u4, 0x20);
  out[1] = _mm256_permute2f128_ps(u1, u5, 0x20);
  out[2] = _mm256_permute2f128_ps(u2, u6, 0x20);
  out[3] = _mm256_permute2f128_ps(u3, u7, 0x20);
  out[4] = _mm256_permute2f128_ps(u0, u4, 0x31);
  out[5] = _mm256_permute2f128_ps(u1, u5, 0x31);
  out[6] = _mm256_permute2f128_ps(u2, u6, 0x31);
  out[7] = _mm256_permute2f128_ps(u3, u7, 0x31);
}

struct Pair8 {
  __m256 dx, dy, dz, r2, g, w;
};
struct Consts8 {
  __m256 h, h2, rmin;
};
PHYSKETCH_AVX2 Pair8 pairTerms8(const Consts8& c, const __m256 i[3], const __m256 j[8]) {
  Pair8 p;
  p.dx = _mm256_sub_ps(i[0], j[kX]), p.dy = _mm256_sub_ps(i[1], j[kY]), p.dz = _mm256_sub_ps(i[2], j[kZ]);
  p.r2 = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(p.dx, p.dx), _mm256_mul_ps(p.dy, p.dy)), _mm256_mul_ps(p.dz, p.dz));
  const __m256 in = _mm256_cmp_ps(p.r2, c.h2, _CMP_LT_OQ);
  const __m256 r = _mm256_sqrt_ps(p.r2);
  const __m256 t = _mm256_sub_ps(c.h, r), s = _mm256_sub_ps(c.h2, p.r2);
  const __m256 g = _mm256_div_ps(_mm256_mul_ps(t, t), _mm256_max_ps(c.rmin, r));
  const __m256 w = _mm256_mul_ps(_mm256_mul_ps(s, s), s);
  p.g = _mm256_and_ps(in, g);
  p.w = _mm256_and_ps(in, w);
  return p;
}

PHYSKETCH_AVX2 Consts8 consts8(const PairArgs& a) {
  return {_mm256_set1_ps(a.h), _mm256_set1_ps(a.h2), _mm256_set1_ps(kMinDistance)};
}

// wallTerm for 8 lanes, operation for operation: a lane further than h from a plane adds
// +0 (c + 0 = c and g + 0 = g: neither sum is ever -0), so every lane gets the scalar bits.
struct Wall8 {
  __m256 c, g[3];
};
PHYSKETCH_AVX2 Wall8 wallTerm8(const PairArgs& a, const __m256 ri[8]) {
  const __m256 zero = _mm256_setzero_ps(), h = _mm256_set1_ps(a.h), invStep = _mm256_set1_ps(a.wallInvStep);
  const __m256 sign = _mm256_set1_ps(-0.0f);
  const __m256i last = _mm256_set1_epi32(a.wallSamples - 2), first = _mm256_setzero_si256(), one = _mm256_set1_epi32(1);
  Wall8 t{zero, {zero, zero, zero}};
  for (int k = 0; k < 3; ++k)
    for (int side = 0; side < 2; ++side) {
      const __m256 y = side ? _mm256_sub_ps(_mm256_set1_ps(a.wallPlaneHi[k]), ri[k])
                            : _mm256_sub_ps(ri[k], _mm256_set1_ps(a.wallPlaneLo[k]));
      const __m256 in = _mm256_cmp_ps(y, h, _CMP_LT_OQ);
      if (_mm256_testz_ps(in, in)) continue;
      const __m256 u = _mm256_mul_ps(_mm256_max_ps(zero, y), invStep);  // std::max(y, 0): y on ties
      // Lanes out of range index sample 0 (their u may not fit an int); the gathers skip them.
      const __m256i s = _mm256_max_epi32(first, _mm256_min_epi32(_mm256_cvttps_epi32(_mm256_and_ps(in, u)), last));
      const __m256 f = _mm256_sub_ps(u, _mm256_cvtepi32_ps(s));
      const __m256i s1 = _mm256_add_epi32(s, one);
      const __m256 b0 = _mm256_mask_i32gather_ps(zero, a.wallB, s, in, 4);
      const __m256 b1 = _mm256_mask_i32gather_ps(zero, a.wallB, s1, in, 4);
      const __m256 d0 = _mm256_mask_i32gather_ps(zero, a.wallDB, s, in, 4);
      const __m256 d1 = _mm256_mask_i32gather_ps(zero, a.wallDB, s1, in, 4);
      t.c = _mm256_add_ps(t.c, _mm256_and_ps(in, _mm256_add_ps(b0, _mm256_mul_ps(f, _mm256_sub_ps(b1, b0)))));
      __m256 db = _mm256_add_ps(d0, _mm256_mul_ps(f, _mm256_sub_ps(d1, d0)));
      if (side) db = _mm256_xor_ps(db, sign);
      t.g[k] = _mm256_add_ps(t.g[k], _mm256_and_ps(in, db));
    }
  // Lanes within h of two or three walls: the scalar edgeTerm, lane by lane (rare; the same
  // bits by construction). Other lanes add +0, as the scalar does (its sums are never -0).
  const __m256 h2 = _mm256_set1_ps(a.h);
  __m256i axes = _mm256_setzero_si256();
  for (int k = 0; k < 3; ++k) {
    const __m256 near = _mm256_or_ps(_mm256_cmp_ps(_mm256_sub_ps(ri[k], _mm256_set1_ps(a.wallPlaneLo[k])), h2, _CMP_LT_OQ),
                                     _mm256_cmp_ps(_mm256_sub_ps(_mm256_set1_ps(a.wallPlaneHi[k]), ri[k]), h2, _CMP_LT_OQ));
    axes = _mm256_sub_epi32(axes, _mm256_castps_si256(near));  // near lanes are all ones: -1
  }
  const __m256i two = _mm256_cmpgt_epi32(axes, _mm256_set1_epi32(1));
  if (!_mm256_testz_si256(two, two)) {
    alignas(32) float px[3][8], ec[8], eg[3][8];
    for (int k = 0; k < 3; ++k) _mm256_store_ps(px[k], ri[k]);
    for (int l = 0; l < 8; ++l) {
      const float pl[3] = {px[0][l], px[1][l], px[2][l]};
      const WallTerm e = edgeTerm(a, pl);
      ec[l] = e.c, eg[0][l] = e.g[0], eg[1][l] = e.g[1], eg[2][l] = e.g[2];
    }
    t.c = _mm256_add_ps(t.c, _mm256_load_ps(ec));
    for (int k = 0; k < 3; ++k) t.g[k] = _mm256_add_ps(t.g[k], _mm256_load_ps(eg[k]));
  }
  return t;
}

// finishLambda for the 8 lanes of block b, operation for operation, so the bits are the
// scalar finish's (its wall term is wallTerm8's).
PHYSKETCH_AVX2 void finishLambda8(const PairArgs& a, std::size_t b, const __m256 ri[8], __m256 rho, __m256 gx,
                                  __m256 gy, __m256 gz, __m256 den) {
  const __m256 zero = _mm256_setzero_ps(), cs = _mm256_set1_ps(a.cs);
  const Wall8 wall = wallTerm8(a, ri);
  const __m256 c = _mm256_sub_ps(
      _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(a.cp), _mm256_add_ps(rho, _mm256_mul_ps(ri[kNu], _mm256_set1_ps(a.h6)))),
                    wall.c),
      _mm256_set1_ps(1.0f));
  const __m256 x = _mm256_sub_ps(wall.g[0], _mm256_mul_ps(cs, gx));
  const __m256 y = _mm256_sub_ps(wall.g[1], _mm256_mul_ps(cs, gy));
  const __m256 z = _mm256_sub_ps(wall.g[2], _mm256_mul_ps(cs, gz));
  const __m256 grad2 = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(x, x), _mm256_mul_ps(y, y)), _mm256_mul_ps(z, z));
  const std::size_t i0 = b * kLanes;  // per-rank arrays are padded to whole blocks
  const __m256 eps = a.epsR ? _mm256_loadu_ps(a.epsR + i0) : _mm256_set1_ps(a.epsK);
  const __m256 denom = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(ri[kW], grad2), _mm256_mul_ps(_mm256_mul_ps(cs, cs), den)),
                                     _mm256_mul_ps(eps, ri[kW]));
  const __m256 fluidLane = _mm256_cmp_ps(ri[kFluid], zero, _CMP_NEQ_UQ);
  const __m256 on = _mm256_and_ps(fluidLane, _mm256_cmp_ps(c, zero, _CMP_GT_OQ));
  const __m256 negC = _mm256_xor_ps(c, _mm256_set1_ps(-0.0f));
  __m256 lambda;
  if (a.alphaK > 0.0f || a.alphaR) {  // XPBD, as the scalar finish: min_ps(0, x) is std::min(x, 0.0f)
    const __m256 alpha = a.alphaR ? _mm256_loadu_ps(a.alphaR + i0) : _mm256_set1_ps(a.alphaK);
    // Lanes without compliance (alpha 0, only with per-rank alphas) take the plain step below.
    const __m256 xpbd = _mm256_and_ps(on, _mm256_cmp_ps(alpha, zero, _CMP_GT_OQ));
    const __m256 at = _mm256_mul_ps(alpha, ri[kW]);
    float* sum = a.lambdaSum + i0;
    const __m256 before = _mm256_loadu_ps(sum);
    const __m256 step = _mm256_div_ps(_mm256_sub_ps(negC, _mm256_mul_ps(at, before)), _mm256_add_ps(denom, at));
    const __m256 after = _mm256_min_ps(zero, _mm256_add_ps(before, step));
    lambda = _mm256_and_ps(on, _mm256_blendv_ps(_mm256_div_ps(negC, denom), _mm256_sub_ps(after, before), xpbd));
    _mm256_storeu_ps(sum, _mm256_blendv_ps(before, after, xpbd));
  } else {
    lambda = _mm256_and_ps(on, _mm256_div_ps(negC, denom));
  }
  alignas(32) float l8[8], c8[8];
  _mm256_store_ps(l8, lambda);
  // max(C, 0) of the fluid lanes, as std::max(c, 0.0f): c itself on a tie.
  _mm256_store_ps(c8, _mm256_and_ps(fluidLane, _mm256_max_ps(zero, c)));
  for (int l = 0; l < 8; ++l) {
    const std::size_t i = b * kLanes + std::size_t(l);
    if (i >= a.n) break;
    a.rec[i * kRecord + kLambda] = l8[l];
    if (a.comp) a.comp[i] = c8[l];
  }
}

// finishCorrection for the 8 lanes of block b, the same way (max_ps(lo, p) and min_ps(hi, p)
// return p on ties, as std::max(p, lo) and std::min(p, hi) do, so even signed zeros agree).
PHYSKETCH_AVX2 void finishCorrection8(const PairArgs& a, std::size_t b, const __m256 ri[8], __m256 ax, __m256 ay,
                                      __m256 az) {
  const __m256 zero = _mm256_setzero_ps();
  const __m256 s = _mm256_mul_ps(_mm256_sub_ps(zero, _mm256_set1_ps(a.cs)), ri[kW]);
  const __m256 fluid = _mm256_cmp_ps(ri[kFluid], zero, _CMP_NEQ_UQ);
  // The walls' share of lambda_i's correction, on fluid lanes with lambda != 0 only.
  const __m256 walled = _mm256_and_ps(fluid, _mm256_cmp_ps(ri[kLambda], zero, _CMP_NEQ_UQ));
  const bool anyWall = !_mm256_testz_ps(walled, walled);
  Wall8 wall{};
  if (anyWall) wall = wallTerm8(a, ri);
  const __m256 wl = _mm256_mul_ps(ri[kW], ri[kLambda]);
  const __m256 acc[3] = {ax, ay, az};
  // s_corr against the walls' ghosts: the scalar wallScorr lane by lane where a fluid lane is
  // within h of a wall (the same bits); every fluid lane adds it, 0 or not, as the scalar does.
  alignas(32) float sw[3][8] = {};
  const __m256 h = _mm256_set1_ps(a.h);
  __m256 nearWall = zero;
  for (int k = 0; k < 3; ++k)
    nearWall = _mm256_or_ps(nearWall, _mm256_or_ps(_mm256_cmp_ps(_mm256_sub_ps(ri[k], _mm256_set1_ps(a.wallPlaneLo[k])), h, _CMP_LT_OQ),
                                                   _mm256_cmp_ps(_mm256_sub_ps(_mm256_set1_ps(a.wallPlaneHi[k]), ri[k]), h, _CMP_LT_OQ)));
  nearWall = _mm256_and_ps(nearWall, fluid);
  if (a.scorrK > 0.0f && !_mm256_testz_ps(nearWall, nearWall)) {
    alignas(32) float px[3][8];
    for (int k = 0; k < 3; ++k) _mm256_store_ps(px[k], ri[k]);
    const int lanes = _mm256_movemask_ps(nearWall);
    for (int l = 0; l < 8; ++l) {
      if (!(lanes >> l & 1)) continue;
      const float pl[3] = {px[0][l], px[1][l], px[2][l]};
      float o[3];
      wallScorr(a, pl, o);
      sw[0][l] = o[0], sw[1][l] = o[1], sw[2][l] = o[2];
    }
  }
  __m256 d[3];
  for (int k = 0; k < 3; ++k) {
    __m256 v = _mm256_mul_ps(s, acc[k]);
    if (anyWall) v = _mm256_blendv_ps(v, _mm256_add_ps(v, _mm256_mul_ps(wl, wall.g[k])), walled);
    v = _mm256_blendv_ps(v, _mm256_add_ps(v, _mm256_load_ps(sw[k])), fluid);
    const __m256 p = _mm256_add_ps(ri[k], v);
    const __m256 c = _mm256_sub_ps(
        _mm256_min_ps(_mm256_set1_ps(a.wallHi[k]), _mm256_max_ps(_mm256_set1_ps(a.wallLo[k]), p)), ri[k]);
    d[k] = _mm256_blendv_ps(v, c, fluid);
  }
  const std::size_t i0 = b * kLanes;  // dx_ .. dz_ are padded to whole blocks
  _mm256_storeu_ps(a.dx + i0, d[0]), _mm256_storeu_ps(a.dy + i0, d[1]), _mm256_storeu_ps(a.dz + i0, d[2]);
}

// Lanes of block b that hold a fluid particle (i < n, nu > 0): the ones the velocity passes
// write, as a store mask.
PHYSKETCH_AVX2 __m256 liveLanes(std::size_t n, std::size_t b, __m256 nu) {
  const __m256i lane = _mm256_add_epi32(_mm256_set1_epi32(std::int32_t(b * kLanes)), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
  const __m256 inRange = _mm256_castsi256_ps(_mm256_cmpgt_epi32(_mm256_set1_epi32(std::int32_t(n)), lane));
  return _mm256_and_ps(inRange, _mm256_cmp_ps(nu, _mm256_setzero_ps(), _CMP_GT_OQ));
}

// finishSmoothing for the 8 lanes of block b, operation for operation.
PHYSKETCH_AVX2 void finishSmoothing8(const VelocityArgs& a, std::size_t b, const __m256 vi[8], const __m256 sum[3],
                                     const __m256 w[3]) {
  const __m256 live = liveLanes(a.n, b, vi[kNu]);
  const int mask = _mm256_movemask_ps(live);
  if (!mask) return;
  const __m256i store = _mm256_castps_si256(live);
  const std::size_t i0 = b * kLanes;
  const __m256 xsph =
      a.xsphR ? _mm256_mul_ps(_mm256_loadu_ps(a.xsphR + i0), _mm256_set1_ps(a.cp)) : _mm256_set1_ps(a.xsph);
  for (int k = 0; k < 3; ++k)
    _mm256_maskstore_ps(a.out[k] + i0, store, _mm256_add_ps(vi[kVX + k], _mm256_mul_ps(xsph, sum[k])));
  if (!a.omega[0]) return;
  const __m256 ncs = _mm256_set1_ps(-a.cs);
  const __m256 o[3] = {_mm256_mul_ps(ncs, w[0]), _mm256_mul_ps(ncs, w[1]), _mm256_mul_ps(ncs, w[2])};
  for (int k = 0; k < 3; ++k) _mm256_maskstore_ps(a.omega[k] + i0, store, o[k]);
  alignas(32) float norm[8];
  _mm256_store_ps(norm, _mm256_sqrt_ps(_mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(o[0], o[0]), _mm256_mul_ps(o[1], o[1])),
                                                     _mm256_mul_ps(o[2], o[2]))));
  for (int l = 0; l < 8; ++l)
    if (mask >> l & 1) a.vrec[(i0 + std::size_t(l)) * kRecord + kOmegaNorm] = norm[l];
}

// finishConfinement for the 8 lanes of block b, operation for operation.
PHYSKETCH_AVX2 void finishConfinement8(const VelocityArgs& a, std::size_t b, const __m256 vi[8], const __m256 acc[3]) {
  const __m256 live = liveLanes(a.n, b, vi[kNu]);
  if (_mm256_testz_ps(live, live)) return;
  const __m256 ncs = _mm256_set1_ps(-a.cs);
  const __m256 eta[3] = {_mm256_mul_ps(ncs, acc[0]), _mm256_mul_ps(ncs, acc[1]), _mm256_mul_ps(ncs, acc[2])};
  const __m256 len = _mm256_sqrt_ps(
      _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(eta[0], eta[0]), _mm256_mul_ps(eta[1], eta[1])), _mm256_mul_ps(eta[2], eta[2])));
  const __m256 ok = _mm256_and_ps(live, _mm256_cmp_ps(len, _mm256_set1_ps(1e-12f), _CMP_GT_OQ));
  if (_mm256_testz_ps(ok, ok)) return;
  const std::size_t i0 = b * kLanes;
  const __m256 nn[3] = {_mm256_div_ps(eta[0], len), _mm256_div_ps(eta[1], len), _mm256_div_ps(eta[2], len)};
  const __m256 w[3] = {_mm256_loadu_ps(a.omega[0] + i0), _mm256_loadu_ps(a.omega[1] + i0), _mm256_loadu_ps(a.omega[2] + i0)};
  const __m256 step =
      a.vortR ? _mm256_mul_ps(_mm256_loadu_ps(a.vortR + i0), _mm256_set1_ps(a.substepH)) : _mm256_set1_ps(a.vortStep);
  const __m256 cross[3] = {_mm256_sub_ps(_mm256_mul_ps(nn[1], w[2]), _mm256_mul_ps(nn[2], w[1])),
                           _mm256_sub_ps(_mm256_mul_ps(nn[2], w[0]), _mm256_mul_ps(nn[0], w[2])),
                           _mm256_sub_ps(_mm256_mul_ps(nn[0], w[1]), _mm256_mul_ps(nn[1], w[0]))};
  const __m256i store = _mm256_castps_si256(ok);
  for (int k = 0; k < 3; ++k)
    _mm256_maskstore_ps(a.out[k] + i0, store, _mm256_add_ps(_mm256_loadu_ps(a.out[k] + i0), _mm256_mul_ps(step, cross[k])));
}

}  // namespace

__attribute__((target("avx2"))) void lambdaBlocksAvx2(const PairArgs& a, std::size_t b0, std::size_t b1) {
  const Consts8 c = consts8(a);
  std::int32_t self[8];
  for (std::size_t b = b0; b < b1; ++b) {
    for (int l = 0; l < 8; ++l) self[l] = std::int32_t(b * kLanes) + l;
    __m256 ri[8];
    loadTransposed(a.rec, self, ri);
    __m256 rho = _mm256_setzero_ps(), gx = rho, gy = rho, gz = rho, den = rho;
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (std::int32_t k = 0; k < a.bk[b]; ++k) {
      __m256 rj[8];
      loadTransposed(a.rec, ids + k * kLanes, rj);
      const Pair8 p = pairTerms8(c, ri, rj);
      const __m256 gn = _mm256_mul_ps(rj[kNu], p.g);
      rho = _mm256_add_ps(rho, _mm256_mul_ps(rj[kNu], p.w));
      gx = _mm256_add_ps(gx, _mm256_mul_ps(gn, p.dx));
      gy = _mm256_add_ps(gy, _mm256_mul_ps(gn, p.dy));
      gz = _mm256_add_ps(gz, _mm256_mul_ps(gn, p.dz));
      den = _mm256_add_ps(den, _mm256_mul_ps(rj[kW], _mm256_mul_ps(_mm256_mul_ps(gn, gn), p.r2)));
    }
    finishLambda8(a, b, ri, rho, gx, gy, gz, den);
  }
}

__attribute__((target("avx2"))) void smoothLambdaBlocksAvx2(const PairArgs& a, std::size_t b0, std::size_t b1,
                                                               float* out) {
  const __m256 h2 = _mm256_set1_ps(a.h2), h6 = _mm256_set1_ps(a.h6), zero = _mm256_setzero_ps();
  std::int32_t self[8];
  for (std::size_t b = b0; b < b1; ++b) {
    for (int l = 0; l < 8; ++l) self[l] = std::int32_t(b * kLanes) + l;
    __m256 ri[8];
    loadTransposed(a.rec, self, ri);
    const __m256 own = _mm256_mul_ps(ri[kNu], h6);
    __m256 num = _mm256_mul_ps(own, ri[kLambda]), den = own;
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (std::int32_t k = 0; k < a.bk[b]; ++k) {
      __m256 rj[8];
      loadTransposed(a.rec, ids + k * kLanes, rj);
      const __m256 dx = _mm256_sub_ps(ri[kX], rj[kX]), dy = _mm256_sub_ps(ri[kY], rj[kY]), dz = _mm256_sub_ps(ri[kZ], rj[kZ]);
      const __m256 r2 = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)), _mm256_mul_ps(dz, dz));
      const __m256 s = _mm256_sub_ps(h2, r2);
      const __m256 w = _mm256_and_ps(_mm256_cmp_ps(r2, h2, _CMP_LT_OQ), _mm256_mul_ps(_mm256_mul_ps(s, s), s));
      const __m256 wf = _mm256_mul_ps(w, _mm256_mul_ps(rj[kNu], rj[kFluid]));
      num = _mm256_add_ps(num, _mm256_mul_ps(wf, rj[kLambda]));
      den = _mm256_add_ps(den, wf);
    }
    // Solid lanes and padding (nu 0: 0 / 0) are masked out before the store.
    const __m256 fluid = _mm256_cmp_ps(ri[kFluid], zero, _CMP_NEQ_UQ);
    alignas(32) float v[8];
    _mm256_store_ps(v, _mm256_and_ps(fluid, _mm256_div_ps(num, den)));
    for (int l = 0; l < 8; ++l) {
      const std::size_t i = b * kLanes + std::size_t(l);
      if (i >= a.n) break;
      out[i] = v[l];
    }
  }
}

__attribute__((target("avx2"))) void correctionBlocksAvx2(const PairArgs& a, std::size_t b0, std::size_t b1) {
  const Consts8 c = consts8(a);
  const __m256 invWdq = _mm256_set1_ps(a.invWdq), scorrK = _mm256_set1_ps(a.scorrK), beta = _mm256_set1_ps(a.scorrBeta);
  std::int32_t self[8];
  for (std::size_t b = b0; b < b1; ++b) {
    for (int l = 0; l < 8; ++l) self[l] = std::int32_t(b * kLanes) + l;
    __m256 ri[8];
    loadTransposed(a.rec, self, ri);
    __m256 ax = _mm256_setzero_ps(), ay = ax, az = ax;
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (std::int32_t k = 0; k < a.bk[b]; ++k) {
      __m256 rj[8];
      loadTransposed(a.rec, ids + k * kLanes, rj);
      const Pair8 p = pairTerms8(c, ri, rj);
      const __m256 q = _mm256_mul_ps(p.w, invWdq);
      __m256 qn = q;
      for (int m = 1; m < a.scorrN; ++m) qn = _mm256_mul_ps(qn, q);
      const __m256 sm = _mm256_mul_ps(_mm256_add_ps(ri[kMass], rj[kMass]), _mm256_mul_ps(ri[kFluid], rj[kFluid]));
      const __m256 coef = _mm256_sub_ps(
          _mm256_add_ps(_mm256_mul_ps(ri[kLambda], rj[kNu]), _mm256_mul_ps(rj[kLambda], ri[kNu])),
          _mm256_mul_ps(_mm256_mul_ps(scorrK, _mm256_sub_ps(qn, _mm256_mul_ps(beta, q))), sm));
      const __m256 cg = _mm256_mul_ps(coef, p.g);
      ax = _mm256_add_ps(ax, _mm256_mul_ps(cg, p.dx));
      ay = _mm256_add_ps(ay, _mm256_mul_ps(cg, p.dy));
      az = _mm256_add_ps(az, _mm256_mul_ps(cg, p.dz));
    }
    finishCorrection8(a, b, ri, ax, ay, az);
  }
}

__attribute__((target("avx2"))) void smoothingBlocksAvx2(const VelocityArgs& a, std::size_t b0, std::size_t b1) {
  const Consts8 c = {_mm256_set1_ps(a.h), _mm256_set1_ps(a.h2), _mm256_set1_ps(kMinDistance)};
  std::int32_t self[8];
  for (std::size_t b = b0; b < b1; ++b) {
    for (int l = 0; l < 8; ++l) self[l] = std::int32_t(b * kLanes) + l;
    __m256 vi[8];
    loadTransposed(a.vrec, self, vi);
    __m256 s0 = _mm256_setzero_ps(), s1 = s0, s2 = s0, w0 = s0, w1 = s0, w2 = s0;
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (std::int32_t k = 0; k < a.bk[b]; ++k) {
      __m256 vj[8];
      loadTransposed(a.vrec, ids + k * kLanes, vj);
      const Pair8 p = pairTerms8(c, vi, vj);
      const __m256 ux = _mm256_sub_ps(vj[kVX], vi[kVX]), uy = _mm256_sub_ps(vj[kVY], vi[kVY]);
      const __m256 uz = _mm256_sub_ps(vj[kVZ], vi[kVZ]);
      const __m256 nw = _mm256_mul_ps(vj[kNu], p.w), gn = _mm256_mul_ps(vj[kNu], p.g);
      s0 = _mm256_add_ps(s0, _mm256_mul_ps(nw, ux));
      s1 = _mm256_add_ps(s1, _mm256_mul_ps(nw, uy));
      s2 = _mm256_add_ps(s2, _mm256_mul_ps(nw, uz));
      w0 = _mm256_add_ps(w0, _mm256_mul_ps(gn, _mm256_sub_ps(_mm256_mul_ps(uy, p.dz), _mm256_mul_ps(uz, p.dy))));
      w1 = _mm256_add_ps(w1, _mm256_mul_ps(gn, _mm256_sub_ps(_mm256_mul_ps(uz, p.dx), _mm256_mul_ps(ux, p.dz))));
      w2 = _mm256_add_ps(w2, _mm256_mul_ps(gn, _mm256_sub_ps(_mm256_mul_ps(ux, p.dy), _mm256_mul_ps(uy, p.dx))));
    }
    const __m256 sum[3] = {s0, s1, s2}, w[3] = {w0, w1, w2};
    finishSmoothing8(a, b, vi, sum, w);
  }
}

__attribute__((target("avx2"))) void confinementBlocksAvx2(const VelocityArgs& a, std::size_t b0, std::size_t b1) {
  const Consts8 c = {_mm256_set1_ps(a.h), _mm256_set1_ps(a.h2), _mm256_set1_ps(kMinDistance)};
  std::int32_t self[8];
  for (std::size_t b = b0; b < b1; ++b) {
    for (int l = 0; l < 8; ++l) self[l] = std::int32_t(b * kLanes) + l;
    __m256 vi[8];
    loadTransposed(a.vrec, self, vi);
    __m256 e0 = _mm256_setzero_ps(), e1 = e0, e2 = e0;
    const std::int32_t* ids = a.bidx + std::size_t(a.boff[b]) * kLanes;
    for (std::int32_t k = 0; k < a.bk[b]; ++k) {
      __m256 vj[8];
      loadTransposed(a.vrec, ids + k * kLanes, vj);
      const Pair8 p = pairTerms8(c, vi, vj);
      const __m256 e = _mm256_mul_ps(_mm256_mul_ps(vj[kNu], vj[kOmegaNorm]), p.g);
      e0 = _mm256_add_ps(e0, _mm256_mul_ps(e, p.dx));
      e1 = _mm256_add_ps(e1, _mm256_mul_ps(e, p.dy));
      e2 = _mm256_add_ps(e2, _mm256_mul_ps(e, p.dz));
    }
    const __m256 acc[3] = {e0, e1, e2};
    finishConfinement8(a, b, vi, acc);
  }
}

#undef PHYSKETCH_AVX2

}  // namespace physketch::pbd::detail
