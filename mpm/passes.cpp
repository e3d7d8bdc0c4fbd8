// The passes of one MPM substep (kMpmPasses): p2g with its block sort, grid_update, g2p,
// projection and plasticity. The step, the plan and the guard are in world.cpp.
#include <algorithm>
#include <cmath>
#include <limits>
#include <type_traits>
#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "mpm/constitutive.h"
#include "mpm/kernels.h"
#include "mpm/logexp.h"
#include "mpm/plasticity.h"
#include "mpm/world.h"

namespace physketch::mpm {

using namespace detail;

// --- the 27-node loops of P2G and G2P on a block's tile ----------------------------------
//
// A tile holds the 6^3 nodes a block's particles reach, z fastest, one F4 record per node;
// t0 points at a particle's stencil base. Two versions of each: SSE (4 lanes, one node at a
// time) and AVX2 (8 lanes: nodes c = 0 and 1 of a row at once, c = 2 alone). Every lane does
// the same IEEE operations in the same order in both, so they give bit-identical results
// (tests/mpm: MpmWorld.Avx2AndSseTransfersGiveBitIdenticalStates).

namespace {

constexpr int kT = kBlock + 2, kTile = kT * kT * kT;  // a block's tile: nodes per edge, nodes

// P2G: node (a, b, c) += wt (r_ab + Z_c), r_ab = (M + X_a) + Y_b, wt = (w0_a w1_b) w2_c; and
// where e0 is given, e0's node += wt E.
void scatterSse(F4* t0, F4* e0, const float (&w)[3][3], const F4 (&X)[3], const F4 (&Y)[3], const F4 (&Z)[3], F4 M,
                F4 E) {
  for (int a = 0; a < 3; ++a) {
    const F4 Ma = M + X[a];
    for (int b = 0; b < 3; ++b) {
      const float wab = w[0][a] * w[1][b];
      const F4 r = Ma + Y[b];
      const int row = (a * kT + b) * kT;
      for (int c = 0; c < 3; ++c) {
        const F4 wt = F4::splat(wab * w[2][c]);
        t0[row + c] = t0[row + c] + wt * (r + Z[c]);
        if (e0) e0[row + c] = e0[row + c] + wt * E;
      }
    }
  }
}

// Gather's sums past the rows: row b's S and T into its plane's (S, its d1 moment, T), and
// plane a's into the particle's (v, B0, B1, B2). Shared by both versions.
inline void addRow(const F4 (&W)[3][3], const F4 (&WD)[3][3], int b, F4 S, F4 T, F4 (&plane)[3]) {
  plane[0] = plane[0] + W[1][b] * S;
  plane[1] = plane[1] + WD[1][b] * S;
  plane[2] = plane[2] + W[1][b] * T;
}
inline void addPlane(const F4 (&W)[3][3], const F4 (&WD)[3][3], int a, const F4 (&plane)[3], F4 (&out)[4]) {
  out[0] = out[0] + W[0][a] * plane[0];
  out[1] = out[1] + WD[0][a] * plane[0];
  out[2] = out[2] + W[0][a] * plane[1];
  out[3] = out[3] + W[0][a] * plane[2];
}

// G2P: S = sum_c w2_c g_c and T = sum_c (w2 d2)_c g_c over a row's three nodes, then over
// b and a as g2p documents; returns v (out[0]) and B's columns (out[1..3]).
void gatherSse(const F4* t0, const F4 (&W)[3][3], const F4 (&WD)[3][3], F4 (&out)[4]) {
  out[0] = out[1] = out[2] = out[3] = F4::splat(0.0f);
  for (int a = 0; a < 3; ++a) {
    F4 plane[3] = {F4::splat(0.0f), F4::splat(0.0f), F4::splat(0.0f)};
    for (int b = 0; b < 3; ++b) {
      const F4* const g = t0 + (a * kT + b) * kT;
      const F4 S = (W[2][0] * g[0] + W[2][1] * g[1]) + W[2][2] * g[2];
      const F4 T = (WD[2][0] * g[0] + WD[2][1] * g[1]) + WD[2][2] * g[2];
      addRow(W, WD, b, S, T, plane);
    }
    addPlane(W, WD, a, plane, out);
  }
}

#if defined(__x86_64__) && defined(__SSE2__)
#define PHYSKETCH_MPM_AVX2 1
__attribute__((target("avx2"))) void scatterAvx2(F4* t0, F4* e0, const float (&w)[3][3], const F4 (&X)[3],
                                                 const F4 (&Y)[3], const F4 (&Z)[3], F4 M, F4 E) {
  const __m256 w01 = _mm256_setr_ps(w[2][0], w[2][0], w[2][0], w[2][0], w[2][1], w[2][1], w[2][1], w[2][1]);
  const __m256 z01 = _mm256_set_m128(Z[1].v, Z[0].v);
  const __m256 e2 = _mm256_set_m128(E.v, E.v);
  for (int a = 0; a < 3; ++a) {
    const F4 Ma = M + X[a];
    for (int b = 0; b < 3; ++b) {
      const float wab = w[0][a] * w[1][b];
      const F4 r = Ma + Y[b];
      const int row = (a * kT + b) * kT;
      float* const g = reinterpret_cast<float*>(t0 + row);
      const __m256 wt = _mm256_mul_ps(_mm256_set1_ps(wab), w01);
      const __m256 r2 = _mm256_set_m128(r.v, r.v);
      _mm256_storeu_ps(g, _mm256_add_ps(_mm256_loadu_ps(g), _mm256_mul_ps(wt, _mm256_add_ps(r2, z01))));
      const F4 wt2 = F4::splat(wab * w[2][2]);
      t0[row + 2] = t0[row + 2] + wt2 * (r + Z[2]);
      if (e0) {
        float* const e = reinterpret_cast<float*>(e0 + row);
        _mm256_storeu_ps(e, _mm256_add_ps(_mm256_loadu_ps(e), _mm256_mul_ps(wt, e2)));
        e0[row + 2] = e0[row + 2] + wt2 * E;
      }
    }
  }
}

__attribute__((target("avx2"))) void gatherAvx2(const F4* t0, const F4 (&W)[3][3], const F4 (&WD)[3][3], F4 (&out)[4]) {
  const __m256 w01 = _mm256_set_m128(W[2][1].v, W[2][0].v), wd01 = _mm256_set_m128(WD[2][1].v, WD[2][0].v);
  out[0] = out[1] = out[2] = out[3] = F4::splat(0.0f);
  for (int a = 0; a < 3; ++a) {
    F4 plane[3] = {F4::splat(0.0f), F4::splat(0.0f), F4::splat(0.0f)};
    for (int b = 0; b < 3; ++b) {
      const F4* const g = t0 + (a * kT + b) * kT;
      const __m256 g01 = _mm256_loadu_ps(reinterpret_cast<const float*>(g));
      const __m256 s01 = _mm256_mul_ps(w01, g01), t01 = _mm256_mul_ps(wd01, g01);
      const F4 S = F4{_mm_add_ps(_mm256_castps256_ps128(s01), _mm256_extractf128_ps(s01, 1))} + W[2][2] * g[2];
      const F4 T = F4{_mm_add_ps(_mm256_castps256_ps128(t01), _mm256_extractf128_ps(t01, 1))} + WD[2][2] * g[2];
      addRow(W, WD, b, S, T, plane);
    }
    addPlane(W, WD, a, plane, out);
  }
}
#endif

}  // namespace

bool MpmWorld::avx2Supported() {
#ifdef PHYSKETCH_MPM_AVX2
  static const bool yes = __builtin_cpu_supports("avx2");
  return yes;
#else
  return false;
#endif
}

// --- the passes --------------------------------------------------------------------

// Dynamic particles in block order (stable counting sort on their stencil's block, ids
// ascending within a block), and the blocks that hold any, by parity colour: blocks of one
// colour are two blocks apart, and a particle's 3^3 stencil reaches at most one block
// beyond its own, so blocks of one colour never write the same node and can run at once.
// The sum at each node then runs in a fixed order (colour, block, particle) whatever the
// thread count: bit-identical results without float atomics.
void MpmWorld::sortByBlock() {
  const std::size_t n = parts_.size();
  const std::size_t blocks = std::size_t(nb_) * nb_ * nb_;
  // The keys, and whether any differs from the last sort's: if none does, that sort's order
  // is this one's too (a stable sort of the same keys), and only the lists below are redone.
  const bool sameSize = blockKey_.size() == n && blockStart_.size() == blocks + 1;
  blockKey_.resize(n);
  keyChanged_.assign((n + kChunk - 1) / kChunk, 0);
  const float inv = float(1.0 / dx_);
  const float ox = float(origin_.x()), oy = float(origin_.y()), oz = float(origin_.z());
  forRange(n, [&](std::size_t lo, std::size_t hi) {
    std::uint8_t changed = 0;
    for (std::size_t i = lo; i < hi; ++i) {
      std::int32_t key = -1;
      if (phase::dynamic(parts_.phase[i])) {
        const int bx = stencilBase(parts_.x[i] - ox, inv, n_);
        const int by = stencilBase(parts_.y[i] - oy, inv, n_);
        const int bz = stencilBase(parts_.z[i] - oz, inv, n_);
        key = ((bx >> 2) * nb_ + (by >> 2)) * nb_ + (bz >> 2);
      }
      changed |= std::uint8_t(key != blockKey_[i]);
      blockKey_[i] = key;
    }
    keyChanged_[lo / kChunk] = changed;
  });
  const bool resort = !sameSize || std::any_of(keyChanged_.begin(), keyChanged_.end(), [](std::uint8_t c) { return c != 0; });
  if (resort) {
    blockStart_.assign(blocks + 1, 0);
    for (std::size_t i = 0; i < n; ++i)
      if (blockKey_[i] >= 0) ++blockStart_[std::size_t(blockKey_[i]) + 1];
    for (std::size_t b = 0; b < blocks; ++b) blockStart_[b + 1] += blockStart_[b];
    order_.resize(std::size_t(blockStart_[blocks]));
    std::vector<std::int32_t>& fill = blockFill_;
    fill.assign(blockStart_.begin(), blockStart_.end() - 1);
    for (std::size_t i = 0; i < n; ++i)
      if (blockKey_[i] >= 0) order_[std::size_t(fill[std::size_t(blockKey_[i])]++)] = static_cast<std::int32_t>(i);
  }
  for (auto& c : colourBlocks_) c.clear();
  particleBlocks_.clear();
  std::fill(nodeBlockMark_.begin(), nodeBlockMark_.end(), 0);
  const auto mark = [&](int bx, int by, int bz) {
    for (int a = 0; a < 2; ++a)
      for (int b = 0; b < 2; ++b)
        for (int c = 0; c < 2; ++c)
          if (bx + a < nb_ && by + b < nb_ && bz + c < nb_)
            nodeBlockMark_[(std::size_t(bx + a) * nb_ + std::size_t(by + b)) * nb_ + std::size_t(bz + c)] = 1;
  };
  for (std::size_t b = 0; b < blocks; ++b) {
    if (blockStart_[b + 1] == blockStart_[b]) continue;
    const int bx = int(b / (std::size_t(nb_) * nb_)), by = int(b / std::size_t(nb_) % std::size_t(nb_)),
              bz = int(b % std::size_t(nb_));
    colourBlocks_[((bx & 1) << 2) | ((by & 1) << 1) | (bz & 1)].push_back(static_cast<std::int32_t>(b));
    particleBlocks_.push_back(static_cast<std::int32_t>(b));
    mark(bx, by, bz);
  }
  // Carried bodies' particles hold the nodes of their stencils (fixed bodies are colliders:
  // their nodes matter only where dynamic material reaches, which marks them above).
  const std::size_t carriedScan = anyCarried() ? n : 0;
  for (std::size_t i = 0; i < carriedScan; ++i) {
    if (phase::dynamic(parts_.phase[i]) || phase::has(parts_.phase[i], phase::kRemoved)) continue;
    if (mode_[std::size_t(parts_.group(i))] != BodyMode::kKinematic) continue;
    const int bx = stencilBase(parts_.x[i] - ox, inv, n_);
    const int by = stencilBase(parts_.y[i] - oy, inv, n_);
    const int bz = stencilBase(parts_.z[i] - oz, inv, n_);
    mark(bx >> 2, by >> 2, bz >> 2);
  }
  activeNodeBlocks_.clear();
  for (std::size_t b = 0; b < blocks; ++b)
    if (nodeBlockMark_[b]) activeNodeBlocks_.push_back(static_cast<std::int32_t>(b));
}

// The Kirchhoff stress tau = P F^T of particle i (Pa), by its material's model.
Eigen::Matrix3f MpmWorld::kirchhoff(std::size_t i) {
  const MatModel& m = models_[std::size_t(parts_.material[i])];
  const Eigen::Matrix3f& F = F_[i];
  switch (m.kind) {
    case MaterialKind::kFluid: return fluidKirchhoff<float>(fluidJ_[i], C_[i], m.bulk, m.gamma, m.viscosity);
    case MaterialKind::kSand:
    case MaterialKind::kPlasticine: {
      if (svdCached_) return henckyKirchhoff<float>(svdU_[i], svdLnS_[i], m.mu, m.lambda);
      const Svd3<float> d = svd3<float>(F);
      const Eigen::Vector3f eps(logLane(d.sigma(0)), logLane(d.sigma(1)), logLane(d.sigma(2)));
      return henckyKirchhoff<float>(d.U, eps, m.mu, m.lambda);
    }
    case MaterialKind::kSnow: {
      const float s = snowHardening(m.xi, plastic_[i]);
      if (svdCached_) return corotatedKirchhoff<float>(F, svdU_[i], s * m.mu, s * m.lambda);
      return corotatedKirchhoff<float>(F, s * m.mu, s * m.lambda);
    }
    default: {
      if (m.elastic == ElasticModel::kNeoHookean) return neoHookeanKirchhoff<float>(F, m.mu, m.lambda);
      Eigen::Matrix3f R;
      if (polarCached_ && polarFrom(F, polarQ_[i], R)) return corotatedKirchhoff<float>(F, R, m.mu, m.lambda);
      const Svd3<float> d = svd3<float>(F);
      R = d.U * d.V.transpose();
      if (!polarQ_.empty()) {
        const Eigen::Quaternionf q(R);
        polarQ_[i] = Eigen::Vector4f(q.x(), q.y(), q.z(), q.w());
      }
      return corotatedKirchhoff<float>(F, R, m.mu, m.lambda);
    }
  }
}

void MpmWorld::p2g(float h) {
  sortByBlock();
  // A step's first P2G: its plastic particles' decompositions in batches (kirchhoff() then reads
  // them as it reads the return map's on later substeps).
  if (svdCacheOn_ && !svdCached_ && work_[std::size_t(MpmPass::kPlasticity)]) decomposePlastic();
  forEach(activeNodeBlocks_.size(), [&](std::size_t k) {
    const std::size_t first = std::size_t(activeNodeBlocks_[k]) * 64;
    std::fill_n(grid_.begin() + std::ptrdiff_t(first), 64, Node{0.0f, 0.0f, 0.0f, 0.0f});
    if (mixedFriction_) {
      std::fill_n(gfs_.begin() + std::ptrdiff_t(first), 64, 0.0f);
      std::fill_n(gfk_.begin() + std::ptrdiff_t(first), 64, 0.0f);
    }
    if (!jbar_.empty()) std::fill_n(jbar_.begin() + std::ptrdiff_t(2 * first), 128, 0.0f);
    if (!side_.empty()) std::fill_n(side_.begin() + std::ptrdiff_t(3 * first), 192, 0.0f);
    std::fill_n(held_.begin() + std::ptrdiff_t(first), 64, std::uint8_t(0));
  });
  const float inv = float(1.0 / dx_), dx = float(dx_);
  const float volume = float(params_.spacing * params_.spacing * params_.spacing);
  const float stressScale = -h * volume * 4.0f * inv * inv;  // Hu et al. 2018 Eq. 16: -h V_p 4/dx^2
  const float ox = float(origin_.x()), oy = float(origin_.y()), oz = float(origin_.z());
  // Each block's particles scatter into a tile of its own, the 6^3 nodes their stencils can
  // reach (bases in the block's 4 cells, plus 2), which stays in L1 and is indexed by fixed
  // strides; the tile is then added to the grid. Two records per tile node: the node's
  // (mass, momentum), and where needed (fluid mass, m J, m mu_s, m mu_k) for J-bar and
  // per-material friction, so that one 4-lane operation serves all four; where colliders are,
  // a third tile holds the nodes' sums of m (x_p - x_node).
  const bool extra = mixedFriction_ || !jbar_.empty();
  const bool avx2 = avx2_;
  bool corotated = false;
  for (const MatModel& m : models_)
    corotated |= m.kind != MaterialKind::kFluid && !m.plastic && m.elastic != ElasticModel::kNeoHookean;
  if (!(svdCacheOn_ && corotated)) {
    polarQ_.clear();
    polarCached_ = false;
  } else if (polarQ_.size() != parts_.size()) {
    polarQ_.resize(parts_.size());
    polarCached_ = false;  // new or renumbered particles: none has its rotation yet
  }
  // One block: scatter its particles into the tile, then add the tile to the grid (blocks of
  // one colour never share a node, so the adds need no lock and run in a fixed order).
  const auto block = [&](std::size_t b, F4* tile, F4* tileExtra, F4* tileSide) {
    int corner[3];
    blockCorner(b, nb_, corner);
    const int Bx = corner[0], By = corner[1], Bz = corner[2];
    std::fill_n(tile, kTile, F4::splat(0.0f));
    if (extra) std::fill_n(tileExtra, kTile, F4::splat(0.0f));
    float* const side = side_.empty() ? nullptr : side_.data();
    if (side) std::fill_n(tileSide, kTile, F4::splat(0.0f));
    for (std::int32_t o = blockStart_[b]; o < blockStart_[b + 1]; ++o) {
      const auto i = std::size_t(order_[std::size_t(o)]);
      const float p[3] = {parts_.x[i] - ox, parts_.y[i] - oy, parts_.z[i] - oz};
      const TileStencil st = tileStencil(p, inv, n_, corner, kT);
      const auto& f = st.f;
      const auto& w = st.w;
      const float mp = parts_.mass[i];
      const MatModel& mat = models_[std::size_t(parts_.material[i])];
      Eigen::Matrix3f A;
      if (fluidInline_ && mat.kind == MaterialKind::kFluid) {
        // A fluid's stress here, not through kirchhoff() (a call and a switch per particle: 15 %
        // of a fluid cube's P2G, bench_mpm), and for an inviscid fluid as the pressure alone:
        // tau = -J p I, the viscous term's zeros changing no sum (the same bits).
        const float J = fluidJ_[i];
        const Eigen::Matrix3f& C = C_[i];
        if (mat.viscosity == 0.0f) {
          A = mp * C;
          A.diagonal().array() += stressScale * (J * -taitPressure(J, mat.bulk, mat.gamma));
        } else {
          A = stressScale * fluidKirchhoff<float>(J, C, mat.bulk, mat.gamma, mat.viscosity) + mp * C;
        }
      } else {
        A = stressScale * kirchhoff(i) + mp * C_[i];
      }
      // Node (a, b, c) receives wt * (mp, mp v + A d) with d = ((a, b, c) - f) dx: per axis the
      // column of A times that axis's offset, as 4 lanes (mass lane 0), summed in the order
      // ((mp v + A_0 d_a) + A_1 d_b) + A_2 d_c.
      const F4 A0 = F4::set(0.0f, A(0, 0), A(1, 0), A(2, 0)), A1 = F4::set(0.0f, A(0, 1), A(1, 1), A(2, 1)),
               A2 = F4::set(0.0f, A(0, 2), A(1, 2), A(2, 2));
      F4 X[3], Y[3], Z[3];
      for (int k = 0; k < 3; ++k) {
        X[k] = A0 * F4::splat((float(k) - f[0]) * dx);
        Y[k] = A1 * F4::splat((float(k) - f[1]) * dx);
        Z[k] = A2 * F4::splat((float(k) - f[2]) * dx);
      }
      const F4 M = F4::set(mp, mp * parts_.vx[i], mp * parts_.vy[i], mp * parts_.vz[i]);
      // A fluid's mass and m J for J-bar (zero for other materials), mass times friction.
      const bool fluid = mat.kind == MaterialKind::kFluid;
      const F4 E = F4::set(fluid ? mp : 0.0f, fluid ? mp * plastic_[i] : 0.0f, mp * mat.mus, mp * mat.muk);
      F4* const t0 = tile + st.offset;
      F4* const e0 = extra ? tileExtra + (t0 - tile) : nullptr;
#ifdef PHYSKETCH_MPM_AVX2
      if (avx2) scatterAvx2(t0, e0, w, X, Y, Z, M, E);
      else
#endif
        scatterSse(t0, e0, w, X, Y, Z, M, E);
      // Where colliders are, a third tile of m (x_p - x_node) per axis (lanes 1-3): the same
      // scatter with M = 0 and per axis the offset's moment in its own lane, so node (a, b, c)
      // gets wt m ((f - (a, b, c)) dx).
      if (!side) continue;
      F4 SX[3], SY[3], SZ[3];
      for (int k = 0; k < 3; ++k) {
        SX[k] = F4::set(0.0f, mp * (f[0] - float(k)) * dx, 0.0f, 0.0f);
        SY[k] = F4::set(0.0f, 0.0f, mp * (f[1] - float(k)) * dx, 0.0f);
        SZ[k] = F4::set(0.0f, 0.0f, 0.0f, mp * (f[2] - float(k)) * dx);
      }
      F4* const s0 = tileSide + st.offset;
      const F4 zero = F4::splat(0.0f);
#ifdef PHYSKETCH_MPM_AVX2
      if (avx2) scatterAvx2(s0, nullptr, w, SX, SY, SZ, zero, zero);
      else
#endif
        scatterSse(s0, nullptr, w, SX, SY, SZ, zero, zero);
    }
    // The tile into the grid (nodes past the grid's last get nothing: stencils never reach them).
    const bool fluidJ = !jbar_.empty(), fluidOnly = fluidOnly_, mix = mixedFriction_;
    for (int a = 0; a < kT && Bx + a < n_; ++a)
      for (int bb = 0; bb < kT && By + bb < n_; ++bb)
        for (int c = 0; c < kT && Bz + c < n_; ++c) {
          const int gx = Bx + a, gy = By + bb, gz = Bz + c;
          const std::size_t node = blockMajorNode(gx, gy, gz, nb_);
          const int t = (a * kT + bb) * kT + c;
          Node* const g = &grid_[node];
          (F4::load(g) + tile[t]).store(g);
          if (side) {
            alignas(16) float m[4];
            tileSide[t].store(m);
            for (int axis = 0; axis < 3; ++axis) side[3 * node + std::size_t(axis)] += m[axis + 1];
          }
          if (!extra) continue;
          const F4 e = tileExtra[t];
          if (fluidJ) {
            if (!fluidOnly) jbar_[2 * node] += e.lane(0);
            jbar_[2 * node + 1] += e.lane(1);
          }
          if (mix) {
            gfs_[node] += e.lane(2);
            gfk_[node] += e.lane(3);
          }
        }
  };
  for (const auto& blocks : colourBlocks_)
    forEach(blocks.size(), [&](std::size_t k) {
      alignas(16) F4 tile[kTile];
      alignas(16) F4 tileExtra[kTile];
      alignas(16) F4 tileSide[kTile];
      block(std::size_t(blocks[k]), tile, tileExtra, tileSide);
    });
  polarCached_ = !polarQ_.empty();  // the next substeps' P2G starts from these rotations
  // Carried bodies (tools): the nodes of their particles' stencils move with them, in id order
  // (a node two bodies hold takes the later one's velocity), one-sided: they push and never
  // pull, along the normal sum w (x_node - x_p) over the carried particles reaching the node
  // (pointing away from the body; MPM's mass-gradient contact normal, Bardenhagen et al. 2000).
  // Fixed bodies are colliders (syncFixedColliders), not held nodes.
  const std::size_t carriedScan = anyCarried() ? parts_.size() : 0;
  for (std::size_t i = 0; i < carriedScan; ++i) {
    if (phase::dynamic(parts_.phase[i]) || phase::has(parts_.phase[i], phase::kRemoved)) continue;
    if (mode_[std::size_t(parts_.group(i))] != BodyMode::kKinematic) continue;
    if (hx_.empty()) {
      hx_.assign(grid_.size(), 0.0f);
      hy_.assign(grid_.size(), 0.0f);
      hz_.assign(grid_.size(), 0.0f);
      hn_.assign(3 * grid_.size(), 0.0f);
    }
    const MatModel& mat = models_[std::size_t(parts_.material[i])];
    const bool ownFriction = mat.ownFriction;  // a tool with friction=mu: its mu decides
    if (ownFriction && hmus_.empty()) {
      hmus_.assign(grid_.size(), std::numeric_limits<float>::quiet_NaN());
      hmuk_.assign(grid_.size(), std::numeric_limits<float>::quiet_NaN());
    }
    const Stencil st = makeStencil(parts_.x[i] - ox, parts_.y[i] - oy, parts_.z[i] - oz, inv, n_, nb_);
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b)
        for (int c = 0; c < 3; ++c) {
          const std::size_t node = st.node(a, b, c);
          if (held_[node] == 0) {
            if (!hmus_.empty()) hmus_[node] = hmuk_[node] = std::numeric_limits<float>::quiet_NaN();
            std::fill_n(hn_.begin() + std::ptrdiff_t(3 * node), 3, 0.0f);
          }
          if (ownFriction) hmus_[node] = mat.mus, hmuk_[node] = mat.muk;
          held_[node] = 1;
          hx_[node] = parts_.vx[i];
          hy_[node] = parts_.vy[i];
          hz_[node] = parts_.vz[i];
          const float wt = st.w[0][a] * st.w[1][b] * st.w[2][c];
          hn_[3 * node] += wt * (float(a) - st.f[0]);
          hn_[3 * node + 1] += wt * (float(b) - st.f[1]);
          hn_[3 * node + 2] += wt * (float(c) - st.f[2]);
        }
  }
}

void MpmWorld::gridUpdate(float h) {
  const float g[3] = {float(h * params_.gravity.x()), float(h * params_.gravity.y()), float(h * params_.gravity.z())};
  const WallKind(&kind)[6] = params_.walls;  // x-, x+, y-, y+, z-, z+
  const int floorNode = std::max(wallLo_[1], groundNode_);
  forEach(activeNodeBlocks_.size(), [&](std::size_t k) {
    const auto block = std::size_t(activeNodeBlocks_[k]);
    int corner[3];
    blockCorner(block, nb_, corner);
    const int bx = corner[0], by = corner[1], bz = corner[2];
    for (int l = 0; l < 64; ++l) {
      const std::size_t node = block * 64 + std::size_t(l);
      Node& gn = grid_[node];
      const float m = gn.m;
      if (!jbar_.empty()) {
        // J-bar: the node's fluid J, the mass-weighted mean over its fluid particles (0 without),
        // goes into the record's mass lane, where g2p's sum over the record makes J-bar along
        // with v; the mass moves to jbar_ (nodeMass).
        const float fluidMass = fluidOnly_ ? m : jbar_[2 * node];  // the same sum, in the same order
        gn.m = fluidMass > 0.0f ? jbar_[2 * node + 1] / fluidMass : 0.0f;
        jbar_[2 * node] = m;
      }
      if (!(m > 0.0f)) {
        gn.x = gn.y = gn.z = 0.0f;
        continue;
      }
      float v[3] = {gn.x / m + g[0], gn.y / m + g[1], gn.z / m + g[2]};
      if (held_[node] == 1) {
        // The tool's own friction where it names one, else the touched material's.
        const bool own = !hmus_.empty() && !std::isnan(hmus_[node]);
        const float mus = own ? hmus_[node] : mixedFriction_ ? gfs_[node] / m : uniformMus_;
        const float muk = own ? hmuk_[node] : mixedFriction_ ? gfk_[node] / m : uniformMuk_;
        pushOnly(v, hx_[node], hy_[node], hz_[node], &hn_[3 * node], mus, muk);
      }
      const int idx[3] = {bx + (l >> 4), by + ((l >> 2) & 3), bz + (l & 3)};
      if (!colliders_.empty()) {
        const Vec3 x = origin_ + dx_ * Vec3(idx[0], idx[1], idx[2]);
        collideNode(x, v, h, mixedFriction_ ? gfs_[node] / m : uniformMus_, mixedFriction_ ? gfk_[node] / m : uniformMuk_,
                    side_.empty() ? nullptr : &side_[3 * node], m);
      }
      for (int a = 0; a < 3; ++a) {
        const int lowest = a == 1 ? floorNode : wallLo_[a];
        const bool low = idx[a] <= lowest, high = idx[a] >= wallHi_[a];
        if (!low && !high) continue;
        const float mus = mixedFriction_ ? gfs_[node] / m : uniformMus_;
        const float muk = mixedFriction_ ? gfk_[node] / m : uniformMuk_;
        if (low) applyWall(v, a, 1.0f, kind[2 * a], mus, muk);
        else applyWall(v, a, -1.0f, kind[2 * a + 1], mus, muk);
      }
      gn.x = v[0];
      gn.y = v[1];
      gn.z = v[2];
    }
  });
}

void MpmWorld::g2p(float h, int substep, bool summarize) {
  const float inv = float(1.0 / dx_), dx = float(dx_);
  const float ox = float(origin_.x()), oy = float(origin_.y()), oz = float(origin_.z());
  // The walls' projection (see projection()): particles within 1.5 dx of a wall are at the
  // domain's edge, the ground is not an edge.
  const float margin = 1.5f * float(dx_);
  float edgeLo[3], edgeHi[3];
  for (int a = 0; a < 3; ++a) {
    edgeLo[a] = lo_[a] + margin;
    edgeHi[a] = hi_[a] - margin;
  }
  if (groundNode_ >= 0 || params_.groundY >= double(lo_[1])) edgeLo[1] = -std::numeric_limits<float>::infinity();
  // The guard's bounds (check and checkParticles), as they compute them.
  const double vmax = lastSubsteps_ > 0 ? dx_ / substepH_ : std::numeric_limits<double>::infinity();
  const float grx = float(params_.gravity.x()), gry = float(params_.gravity.y()), grz = float(params_.gravity.z());
  blockTails_.assign(particleBlocks_.size(), BlockTail{});
  // Block by block, as p2g: the 6^3 nodes a block's particles can reach are copied into a tile
  // that stays in L1 and is read with fixed strides.
  const bool avx2 = avx2_;
  const double vmax2 = vmax * vmax;
  const float near2 = float(0.99 * vmax2);  // below it no float rounding reaches vmax2
  const float lo[3] = {lo_[0], lo_[1], lo_[2]}, hi[3] = {hi_[0], hi_[1], hi_[2]};
  forEach(particleBlocks_.size(), [&](std::size_t k) {
    BlockTail& tail = blockTails_[k];
    // The block's energy in float, as the guard's own sums take blocks of 512 particles (a block
    // holds 512 at 8 a cell).
    float kinetic = 0.0f, potential = 0.0f, mass = 0.0f, lowest = std::numeric_limits<float>::infinity();
    const auto blk = std::size_t(particleBlocks_[k]);
    int corner[3];
    blockCorner(blk, nb_, corner);
    const int Bx = corner[0], By = corner[1], Bz = corner[2];
    alignas(16) F4 tile[kTile];
    for (int a = 0; a < kT; ++a)
      for (int bb = 0; bb < kT; ++bb)
        for (int c = 0; c < kT; ++c) {
          const int gx = Bx + a, gy = By + bb, gz = Bz + c;
          const int t = (a * kT + bb) * kT + c;
          if (gx >= n_ || gy >= n_ || gz >= n_) {  // past the grid's last node: no stencil reaches it
            tile[t] = F4::splat(0.0f);
            continue;
          }
          tile[t] = F4::load(&grid_[blockMajorNode(gx, gy, gz, nb_)]);
        }
    for (std::int32_t o = blockStart_[blk]; o < blockStart_[blk + 1]; ++o) {
      const auto i = std::size_t(order_[std::size_t(o)]);
      const float p[3] = {parts_.x[i] - ox, parts_.y[i] - oy, parts_.z[i] - oz};
      const TileStencil st = tileStencil(p, inv, n_, corner, kT);
      const auto& f = st.f;
      const auto& w = st.w;
      const F4* const t0 = tile + st.offset;
      // v = sum w g and B's columns sum w g d_axis over the nodes g (w = w0 w1 w2, d_axis
      // the node's offset along that axis), factored axis by axis: per row (a, b) the sums
      // over c of w2 g and w2 d2 g, then over b, then over a, so each node costs one load,
      // two products and two adds. Lane 0 carries the node's mass lane along, unused; where a
      // fluid is, its J_node, summed into J-bar.
      F4 W[3][3], WD[3][3];  // per axis: w_k, w_k d_k as 4 equal lanes
      for (int ax = 0; ax < 3; ++ax)
        for (int q = 0; q < 3; ++q) {
          W[ax][q] = F4::splat(w[ax][q]);
          WD[ax][q] = F4::splat(w[ax][q] * ((float(q) - f[ax]) * dx));
        }
      F4 sums[4];
#ifdef PHYSKETCH_MPM_AVX2
      if (avx2) gatherAvx2(t0, W, WD, sums);
      else
#endif
        gatherSse(t0, W, WD, sums);
      alignas(16) float out[16];  // v's record, then B's columns (lanes 1-3: rows; lane 0 unused)
      for (int q = 0; q < 4; ++q) sums[q].store(out + 4 * q);
      const bool fluid = models_[std::size_t(parts_.material[i])].kind == MaterialKind::kFluid;
      const float jbar = out[0];  // a fluid's J-bar: sum over nodes of w J_node
      const float v[3] = {out[1], out[2], out[3]};
      const float cScale = 4.0f * inv * inv;  // Hu et al. 2018 Eq. 17 with D^-1 = 4/dx^2
      Eigen::Matrix3f C;
      for (int c = 0; c < 3; ++c)
        for (int r = 0; r < 3; ++r) C(r, c) = cScale * out[4 * (c + 1) + r + 1];
      C_[i] = C;
      float J;  // the guard's: a fluid's smaller of its two J, a solid's det F
      if (fluid) {  // J only: a fluid has no rest shape
        const float grow = 1.0f + h * C.trace();
        const float own = ((1.0f - kJbarRelax) * plastic_[i] + kJbarRelax * jbar) * grow, grid = jbar * grow;
        fluidJ_[i] = grid;
        plastic_[i] = own;
        J = std::min(own, grid);
      } else {
        const Eigen::Matrix3f F = (Eigen::Matrix3f::Identity() + h * C) * F_[i];
        F_[i] = F;
        J = summarize ? F.determinant() : 1.0f;
      }
      // Speed past the CFL bound before the walls stop it (check(kG2P)), in double as check()
      // tests it, where float says it may be near.
      if (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] > near2) {
        const double v2 = double(v[0]) * v[0] + double(v[1]) * v[1] + double(v[2]) * v[2];
        if (v2 > vmax2 && (tail.cflFirst < 0 || std::int32_t(i) < tail.cflFirst)) tail.cflFirst = std::int32_t(i), tail.cflSpeed2 = v2;
      }
      // The projection's walls: put back on a wall it passed, its velocity into it dropped.
      float nx[3] = {parts_.x[i] + h * v[0], parts_.y[i] + h * v[1], parts_.z[i] + h * v[2]};
      float nv[3] = {v[0], v[1], v[2]};
      int wall = -1;  // 0..5: x-, x+, y-, y+, z-, z+
      for (int a = 0; a < 3; ++a) {
        if (nx[a] < lo[a]) {
          nx[a] = lo[a];
          nv[a] = std::max(nv[a], 0.0f);
        } else if (nx[a] > hi[a]) {
          nx[a] = hi[a];
          nv[a] = std::min(nv[a], 0.0f);
        }  // NaN compares false both ways: left for the guard to report
        if (nx[a] < edgeLo[a]) wall = 2 * a;
        else if (nx[a] > edgeHi[a]) wall = 2 * a + 1;
      }
      parts_.x[i] = nx[0], parts_.y[i] = nx[1], parts_.z[i] = nx[2];
      parts_.vx[i] = nv[0], parts_.vy[i] = nv[1], parts_.vz[i] = nv[2];
      if (wall >= 0) {
        ++tail.atEdge;
        if (tail.firstEdge < 0 || std::int32_t(i) < tail.firstEdge) tail.firstEdge = std::int32_t(i), tail.edgeSide = std::int8_t(wall);
      }
      if (!summarize) continue;
      // The guard's checks of the end state, the same tests as its sweeps.
      tail.nonFinite += (nx[0] - nx[0]) + (nx[1] - nx[1]) + (nx[2] - nx[2]) + (nv[0] - nv[0]) + (nv[1] - nv[1]) + (nv[2] - nv[2]);
      const float s2 = nv[0] * nv[0] + nv[1] * nv[1] + nv[2] * nv[2];
      tail.fastest2 = s2 > tail.fastest2 ? s2 : tail.fastest2;
      tail.inverted |= !(J > 0.0f);
      tail.fast |= s2 > near2 && double(nv[0]) * nv[0] + double(nv[1]) * nv[1] + double(nv[2]) * nv[2] > vmax2;
      const float m = parts_.mass[i], height = -(grx * nx[0] + gry * nx[1] + grz * nx[2]);
      kinetic += m * s2;
      potential += m * height;
      mass += m;
      lowest = std::min(lowest, height);
    }
    tail.energy.kinetic = 0.5 * double(kinetic);
    tail.energy.potential = double(potential);
    tail.energy.mass = double(mass);
    tail.energy.lowest = double(lowest);
  });
  // In block order (the lowest id and the sums do not depend on the threads).
  const bool firstWithAny = firstEdge_.particle < 0;
  StepSummary summary;
  const float max2 = float(params_.maxSpeed * params_.maxSpeed);
  float nonFinite = 0.0f, fastest2 = 0.0f;
  for (const BlockTail& t : blockTails_) {
    atEdge_ += t.atEdge;
    if (firstWithAny && t.firstEdge >= 0 && (firstEdge_.particle < 0 || t.firstEdge < firstEdge_.particle))
      firstEdge_ = {t.firstEdge, t.edgeSide, steps_, substep};
    nonFinite += t.nonFinite;
    fastest2 = std::max(fastest2, t.fastest2);
    summary.inverted |= t.inverted;
    summary.fast |= t.fast;
    summary.energy.add(t.energy);
  }
  // Carried bodies move with their prescribed velocity (fixed ones have none); the summary's
  // pre-check covers them too (fixed particles never change).
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (mode_[b] != BodyMode::kKinematic) continue;
    for (std::int32_t id : members_[b]) {
      const auto i = std::size_t(id);
      parts_.x[i] = std::clamp(parts_.x[i] + h * parts_.vx[i], lo_[0], hi_[0]);
      parts_.y[i] = std::clamp(parts_.y[i] + h * parts_.vy[i], lo_[1], hi_[1]);
      parts_.z[i] = std::clamp(parts_.z[i] + h * parts_.vz[i], lo_[2], hi_[2]);
      const float vx = parts_.vx[i], vy = parts_.vy[i], vz = parts_.vz[i];
      nonFinite += (parts_.x[i] - parts_.x[i]) + (parts_.y[i] - parts_.y[i]) + (parts_.z[i] - parts_.z[i]) + (vx - vx) +
                   (vy - vy) + (vz - vz);
      fastest2 = std::max(fastest2, vx * vx + vy * vy + vz * vz);
    }
  }
  summary.suspect = nonFinite != 0.0f || !(fastest2 <= max2 * 0.999f);  // as checkParticles' pre-check
  summary.valid = summarize;
  summary_ = summary;
}

// A particle the grid let past a wall or the ground is put back on it and loses its velocity
// into it: positions never leave [lo, hi], so P2G's stencil never leaves the grid.
// Particles at the domain's edge -- within 1.5 dx of one of its six walls, where the wall's
// nodes are in their stencil and the wall, not the scene, shapes their motion -- are counted
// (the ground is not an edge: it is a boundary the scene asks for), and the first (the lowest
// id in the first substep with any) is kept for the run's report. The walls' part runs in g2p's
// particle loop, on the values it has just written (a pass of its own over the particles cost
// 3 % of a fluid cube's step); this pass pushes particles out of the colliders after it, in the
// same order per particle as when both were here.
void MpmWorld::projection() {
  if (colliders_.empty()) return;
  forRange(order_.size(), [&](std::size_t lo, std::size_t hi) {
    for (std::size_t o = lo; o < hi; ++o) pushOutOfColliders(std::size_t(order_[o]), double(lastH_));
  });
}

// A particle inside a collider goes back to its surface along the normal and loses its
// velocity into it, relative to the collider (PhyVR's anti-penetration for its tools).
void MpmWorld::pushOutOfColliders(std::size_t i, double h) {
  Collider::Probe p;
  for (const Collider& c : colliders_) {
    const Vec3 x(parts_.x[i], parts_.y[i], parts_.z[i]);
    // Deep inside, no direction out: the grid moves it with the collider.
    if (!c.probe(x, p) || !p.hasNormal) continue;
    const Vec3& n = p.normal;
    const Vec3 to = x - p.phi * n;
    parts_.x[i] = float(to.x());
    parts_.y[i] = float(to.y());
    parts_.z[i] = float(to.z());
    const Vec3 vc = h > 0.0 ? c.velocityAt(to, p.local, h) : Vec3::Zero();
    const Vec3 rel = Vec3(parts_.vx[i], parts_.vy[i], parts_.vz[i]) - vc;
    const double vn = rel.dot(n);
    if (vn < 0.0) {
      const Vec3 v = rel - vn * n + vc;
      parts_.vx[i] = float(v.x());
      parts_.vy[i] = float(v.y());
      parts_.vz[i] = float(v.z());
    }
  }
}

// fn(idx, d, n) for every plastic particle of order_, in batches of up to kPlasticBatch: particle
// idx[k] with d[k] = svd3(F_idx[k]) bit for bit (a finite F), the decompositions taken by
// svd3Many (sixteen in vector lanes at once); in parallel ranges, each particle once.
template <class Fn>
void MpmWorld::forPlasticSvds(const Fn& fn) {
  forRange(order_.size(), [&](std::size_t lo, std::size_t hi) {
    std::size_t idx[kPlasticBatch];
    const Eigen::Matrix3f* trial[kPlasticBatch] = {};
    Svd3<float> d[kPlasticBatch];
    std::size_t nb = 0;
    const auto flush = [&] {
      if (nb == 0) return;
      svd3Many(trial, nb, d, avx2_);
      fn(idx, d, nb);
      nb = 0;
    };
    for (std::size_t o = lo; o < hi; ++o) {
      const auto i = std::size_t(order_[o]);
      if (!models_[std::size_t(parts_.material[i])].plastic) continue;
      idx[nb] = i;
      trial[nb] = &F_[i];
      if (++nb == kPlasticBatch) flush();
    }
    flush();
  });
}

// The batches' arrays are filled to 3 nb before logMany and expMany read that far; GCC cannot
// see that through the calls and warns of uninitialized reads (zeroing them cost 3 % of a
// falling sand cube's plasticity pass).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"

// The decompositions a step's first P2G needs for its plastic particles' stresses, taken as
// the return maps take theirs (svd3Many and logMany: the same bits as svd3 and logLane one at
// a time): U and ln(sigma) for the Hencky models, R = U V^T for snow, in svdU_ and svdLnS_ as
// the return map leaves them.
void MpmWorld::decomposePlastic() {
  if (svdU_.size() != parts_.size()) {
    svdU_.resize(parts_.size());
    svdLnS_.resize(parts_.size());
  }
  forPlasticSvds([&](const std::size_t* idx, const Svd3<float>* d, std::size_t nb) {
    float sigma[3 * kPlasticBatch], ln[3 * kPlasticBatch];
    for (std::size_t k = 0; k < nb; ++k) std::copy_n(d[k].sigma.data(), 3, sigma + 3 * k);
    logMany(sigma, ln, 3 * nb, avx2_);
    for (std::size_t k = 0; k < nb; ++k) {
      const std::size_t i = idx[k];
      if (models_[std::size_t(parts_.material[i])].kind == MaterialKind::kSnow) {
        svdU_[i] = d[k].U * d[k].V.transpose();
      } else {
        svdU_[i] = d[k].U;
        svdLnS_[i] = Eigen::Vector3f(ln + 3 * k);
      }
    }
  });
  svdCached_ = true;
}

// The return maps, a batch at a time: the trial F's decompositions (forPlasticSvds: svd3Many),
// the Hencky models' strains ln(sigma) (logMany), each particle's map in strain space
// (druckerPragerStrain, vonMisesStrain) or snow's clamp, and the projected strains'
// exponentials (expMany): the batch's logs and exponentials in vector lanes, each value the bits
// logLane and expLane give it alone. The next P2G's strain is the projected one itself (not
// ln(exp(strain)), a rounding away).
void MpmWorld::plasticity() {
  if (svdU_.size() != parts_.size()) {
    svdU_.resize(parts_.size());
    svdLnS_.resize(parts_.size());
  }
  forPlasticSvds([&](const std::size_t* idx, const Svd3<float>* d, std::size_t nb) {
    float sigma[3 * kPlasticBatch], lnS[3 * kPlasticBatch], lnOut[3 * kPlasticBatch], s[3 * kPlasticBatch];
    bool projected[kPlasticBatch];
    bool anyProjected = false;
    for (std::size_t k = 0; k < nb; ++k) std::copy_n(d[k].sigma.data(), 3, sigma + 3 * k);
    logMany(sigma, lnS, 3 * nb, avx2_);
    for (std::size_t k = 0; k < nb; ++k) {
      const std::size_t i = idx[k];
      const MatModel& m = models_[std::size_t(parts_.material[i])];
      const Eigen::Map<const Eigen::Vector3f> ln(lnS + 3 * k);
      Eigen::Vector3f out = Eigen::Vector3f::Zero();  // exponentiated whatever is projected
      projected[k] = false;
      if (m.kind == MaterialKind::kSand) {
        float alpha = m.alpha;
        if (m.klar) {  // Klár et al. 2016 §7.3, kept within [0, 80] degrees as the linear law is
          const float q = plastic_[i];
          const float deg = std::clamp(m.h0 + (m.h1 * q - m.h3) * std::exp(-m.h2 * q), 0.0f, 80.0f);
          alpha = float(druckerPragerAlpha(double(deg) * kPi / 180.0));
        } else if (m.hardeningDeg > 0.0f) {
          const float deg = std::min(80.0f, m.frictionDeg + m.hardeningDeg * plastic_[i]);
          alpha = float(druckerPragerAlpha(double(deg) * kPi / 180.0));
        }
        float dq = 0.0f;
        projected[k] = druckerPragerStrain<float>(ln, m.mu, m.lambda, alpha, m.shift, out, dq);
        plastic_[i] += dq;
      } else if (m.kind == MaterialKind::kPlasticine) {
        projected[k] = vonMisesStrain<float>(ln, m.mu, m.yield, out);
      }
      std::copy_n(out.data(), 3, lnOut + 3 * k);
      anyProjected = anyProjected || projected[k];
    }
    if (anyProjected) expMany(lnOut, s, 3 * nb, avx2_);  // at rest, often none
    for (std::size_t k = 0; k < nb; ++k) {
      const std::size_t i = idx[k];
      const MatModel& m = models_[std::size_t(parts_.material[i])];
      Eigen::Vector3f sk;
      if (m.kind == MaterialKind::kSnow) {
        sk = snowClamp<float>(d[k].sigma, m.thetaC, m.thetaS, m.xi, plastic_[i]);
        svdU_[i] = d[k].U * d[k].V.transpose();
      } else {
        sk = projected[k] ? Eigen::Vector3f(s + 3 * k) : d[k].sigma;
        svdU_[i] = d[k].U;
        svdLnS_[i] = Eigen::Vector3f(projected[k] ? lnOut + 3 * k : lnS + 3 * k);
      }
      F_[i] = d[k].U * sk.asDiagonal() * d[k].V.transpose();
    }
  });
  svdCached_ = svdCacheOn_;
}
#pragma GCC diagnostic pop

}  // namespace physketch::mpm

namespace physketch::mpm {

// particle_shift (MpmParams::particleShift), once a step after the substeps: the dynamic fluid
// particles closer than r0 = particleShift x spacing are pushed apart, each pair by half its
// overlap along the line between them (two coincident ones along x, the lower rank to -x), in
// two Jacobi sweeps whose moves are capped at a quarter spacing each, a particle at a rim, edge
// or corner dropping the outward part of its move; then every particle takes its affine field's
// velocity at the new place (v + C dx, APIC's field) and is held inside the walls and outside
// the colliders. In rank order of one neighbour grid, each rank writing its own move: the same
// bits for any thread count. A step that left a non-finite position is not shifted: the guard
// reports it after this pass.
void MpmWorld::shiftFluid() {
  shiftIds_.clear();
  for (std::size_t i = 0; i < parts_.size(); ++i) {
    if (!phase::dynamic(parts_.phase[i]) || models_[std::size_t(parts_.material[i])].kind != MaterialKind::kFluid) continue;
    if (!std::isfinite(parts_.x[i]) || !std::isfinite(parts_.y[i]) || !std::isfinite(parts_.z[i])) return;
    shiftIds_.push_back(std::int32_t(i));
  }
  const std::size_t n = shiftIds_.size();
  if (n < 2) return;
  shiftX_.resize(n), shiftY_.resize(n), shiftZ_.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    const auto i = std::size_t(shiftIds_[k]);
    shiftX_[k] = parts_.x[i], shiftY_[k] = parts_.y[i], shiftZ_[k] = parts_.z[i];
  }
  constexpr int kSweeps = 2;
  const float h = float(params_.spacing), r0 = float(params_.particleShift) * h, cap = 0.25f * h;
  // Neighbours within r0 and the two sweeps' moves (a pair may close by 2 cap before the last).
  const float reach = r0 + 2.0f * float(kSweeps - 1) * cap, invReach2 = 1.0f / (reach * reach);
  shiftGrid_.build(shiftX_.data(), shiftY_.data(), shiftZ_.data(), n, reach);
  int width = std::max(8, shiftLists_.width);
  for (;;) {
    shiftGrid_.buildNeighborLists(reach, width, shiftLists_);
    if (!shiftLists_.overflowed) break;
    width = (shiftLists_.maxCount + 7) / 8 * 8;
  }
  // Positions in rank order (x y z interleaved), then the moves.
  std::vector<float>& p = shiftD_;
  p.resize(6 * n);
  float* const pos = p.data();
  float* const move = p.data() + 3 * n;
  for (std::size_t r = 0; r < n; ++r)
    pos[3 * r] = shiftGrid_.sortedX()[r], pos[3 * r + 1] = shiftGrid_.sortedY()[r], pos[3 * r + 2] = shiftGrid_.sortedZ()[r];
  const std::int32_t* idx = shiftLists_.index.data();
  const std::size_t w = std::size_t(shiftLists_.width);
  for (int sweep = 0; sweep < kSweeps; ++sweep) {
    forRange(n, [&](std::size_t lo, std::size_t hi) {
      for (std::size_t r = lo; r < hi; ++r) {
        float m[3] = {0.0f, 0.0f, 0.0f}, out[3] = {0.0f, 0.0f, 0.0f}, wsum = 0.0f;
        for (std::int32_t k = 0; k < shiftLists_.count[r]; ++k) {
          const auto j = std::size_t(idx[r * w + std::size_t(k)]);
          const float e[3] = {pos[3 * r] - pos[3 * j], pos[3 * r + 1] - pos[3 * j + 1], pos[3 * r + 2] - pos[3 * j + 2]};
          const float d2 = (e[0] * e[0] + e[1] * e[1]) + e[2] * e[2], q = 1.0f - d2 * invReach2;
          const float wt = q > 0.0f ? q * q : 0.0f;  // smooth to 0 at the reach
          for (int a = 0; a < 3; ++a) out[a] += wt * e[a];
          wsum += wt;
          const float d = std::sqrt(d2);
          if (!(d < r0)) continue;
          if (d > 0.0f) {
            const float s = 0.5f * (r0 - d) / d;
            for (int a = 0; a < 3; ++a) m[a] += s * e[a];
          } else {
            m[0] += (r < j ? -0.5f : 0.5f) * r0;
          }
        }
        // Where its neighbours lie mostly to one side (their weighted mean offset over 0.3
        // spacings: a full lattice's is 0, a flat surface's 0.2 h, a sheet's rim, an edge's or
        // a corner's more) no move outwards (after Lind et al. 2012): a spreading sheet's rim
        // is not pushed out into spray. Measured on the 0.1 h and 0.2 h thresholds: the sheets
        // of ParticleShiftKeepsASpreadingSheetASheet stayed more gathered (0.505 h, 0.590 h).
        const float o2 = (out[0] * out[0] + out[1] * out[1]) + out[2] * out[2];
        if (o2 > (0.09f * h * h) * (wsum * wsum)) {
          const float on = (m[0] * out[0] + m[1] * out[1]) + m[2] * out[2];
          if (on > 0.0f)
            for (int a = 0; a < 3; ++a) m[a] -= (on / o2) * out[a];
        }
        const float len = std::sqrt((m[0] * m[0] + m[1] * m[1]) + m[2] * m[2]);
        const float f = len > cap ? cap / len : 1.0f;
        for (int a = 0; a < 3; ++a) move[3 * r + std::size_t(a)] = f * m[a];
      }
    });
    for (std::size_t k = 0; k < 3 * n; ++k) pos[k] += move[k];
  }
  const std::int32_t* order = shiftGrid_.order().data();
  const float lo[3] = {lo_[0], lo_[1], lo_[2]}, hi[3] = {hi_[0], hi_[1], hi_[2]};
  forRange(n, [&](std::size_t b, std::size_t e) {
    for (std::size_t r = b; r < e; ++r) {
      const auto i = std::size_t(shiftIds_[std::size_t(order[r])]);
      float x[3] = {pos[3 * r], pos[3 * r + 1], pos[3 * r + 2]};
      for (int a = 0; a < 3; ++a) x[a] = std::min(std::max(x[a], lo[a]), hi[a]);
      const Eigen::Vector3f d(x[0] - parts_.x[i], x[1] - parts_.y[i], x[2] - parts_.z[i]);
      const Eigen::Vector3f dv = C_[i] * d;
      parts_.vx[i] += dv.x(), parts_.vy[i] += dv.y(), parts_.vz[i] += dv.z();
      parts_.x[i] = x[0], parts_.y[i] = x[1], parts_.z[i] = x[2];
      if (!colliders_.empty()) pushOutOfColliders(i, double(lastH_));
    }
  });
}

}  // namespace physketch::mpm
