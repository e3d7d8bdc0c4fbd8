// The passes of one MPM substep (kMpmPasses): p2g with its block sort, grid_update, g2p,
// projection and plasticity. The step, the plan and the guard are in world.cpp.
#include <algorithm>
#include <cmath>

#include "mpm/constitutive.h"
#include "mpm/kernels.h"
#include "mpm/plasticity.h"
#include "mpm/world.h"

namespace physketch::mpm {

using namespace detail;

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
  blockKey_.resize(n);
  const float inv = float(1.0 / dx_);
  const float ox = float(origin_.x()), oy = float(origin_.y()), oz = float(origin_.z());
  forRange(n, [&](std::size_t lo, std::size_t hi) {
    for (std::size_t i = lo; i < hi; ++i) {
      if (!phase::dynamic(parts_.phase[i])) {
        blockKey_[i] = -1;
        continue;
      }
      const int bx = stencilBase(parts_.x[i] - ox, inv, n_);
      const int by = stencilBase(parts_.y[i] - oy, inv, n_);
      const int bz = stencilBase(parts_.z[i] - oz, inv, n_);
      blockKey_[i] = ((bx >> 2) * nb_ + (by >> 2)) * nb_ + (bz >> 2);
    }
  });
  blockStart_.assign(blocks + 1, 0);
  for (std::size_t i = 0; i < n; ++i)
    if (blockKey_[i] >= 0) ++blockStart_[std::size_t(blockKey_[i]) + 1];
  for (std::size_t b = 0; b < blocks; ++b) blockStart_[b + 1] += blockStart_[b];
  order_.resize(std::size_t(blockStart_[blocks]));
  std::vector<std::int32_t> fill(blockStart_.begin(), blockStart_.end() - 1);
  for (std::size_t i = 0; i < n; ++i)
    if (blockKey_[i] >= 0) order_[std::size_t(fill[std::size_t(blockKey_[i])]++)] = static_cast<std::int32_t>(i);
  for (auto& c : colourBlocks_) c.clear();
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
    mark(bx, by, bz);
  }
  // Prescribed particles hold the nodes of their stencils.
  for (std::size_t i = 0; i < n; ++i) {
    if (phase::dynamic(parts_.phase[i]) || phase::has(parts_.phase[i], phase::kRemoved)) continue;
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
Eigen::Matrix3f MpmWorld::kirchhoff(std::size_t i) const {
  const MatModel& m = models_[std::size_t(parts_.material[i])];
  const Eigen::Matrix3f& F = F_[i];
  switch (m.kind) {
    case MaterialKind::kFluid: return fluidKirchhoff<float>(plastic_[i], C_[i], m.bulk, m.gamma, m.viscosity);
    case MaterialKind::kSand:
    case MaterialKind::kPlasticine: return henckyKirchhoff<float>(svd3<float>(F), m.mu, m.lambda);
    case MaterialKind::kSnow: {
      const float s = snowHardening(m.xi, plastic_[i]);
      return corotatedKirchhoff<float>(F, s * m.mu, s * m.lambda);
    }
    default:
      return m.elastic == ElasticModel::kNeoHookean ? neoHookeanKirchhoff<float>(F, m.mu, m.lambda)
                                                    : corotatedKirchhoff<float>(F, m.mu, m.lambda);
  }
}

void MpmWorld::p2g(float h) {
  sortByBlock();
  forEach(activeNodeBlocks_.size(), [&](std::size_t k) {
    const std::size_t first = std::size_t(activeNodeBlocks_[k]) * 64;
    std::fill_n(gm_.begin() + std::ptrdiff_t(first), 64, 0.0f);
    std::fill_n(gx_.begin() + std::ptrdiff_t(first), 64, 0.0f);
    std::fill_n(gy_.begin() + std::ptrdiff_t(first), 64, 0.0f);
    std::fill_n(gz_.begin() + std::ptrdiff_t(first), 64, 0.0f);
    std::fill_n(gfs_.begin() + std::ptrdiff_t(first), 64, 0.0f);
    std::fill_n(gfk_.begin() + std::ptrdiff_t(first), 64, 0.0f);
    std::fill_n(held_.begin() + std::ptrdiff_t(first), 64, std::uint8_t(0));
  });
  const float inv = float(1.0 / dx_), dx = float(dx_);
  const float volume = float(params_.spacing * params_.spacing * params_.spacing);
  const float stressScale = -h * volume * 4.0f * inv * inv;  // Hu et al. 2018 Eq. 16: -h V_p 4/dx^2
  const float ox = float(origin_.x()), oy = float(origin_.y()), oz = float(origin_.z());
  const auto scatter = [&](std::size_t i) {
    const float fxr = (parts_.x[i] - ox) * inv, fyr = (parts_.y[i] - oy) * inv, fzr = (parts_.z[i] - oz) * inv;
    const int bx = stencilBase(parts_.x[i] - ox, inv, n_);
    const int by = stencilBase(parts_.y[i] - oy, inv, n_);
    const int bz = stencilBase(parts_.z[i] - oz, inv, n_);
    const float f[3] = {fxr - float(bx), fyr - float(by), fzr - float(bz)};
    float w[3][3];
    for (int a = 0; a < 3; ++a) bsplineWeights(f[a], w[a]);
    const float mp = parts_.mass[i];
    const MatModel& mat = models_[std::size_t(parts_.material[i])];
    const float ms = mp * mat.mus, mk = mp * mat.muk;
    const Eigen::Matrix3f A = stressScale * kirchhoff(i) + mp * C_[i];
    const float mv[3] = {mp * parts_.vx[i], mp * parts_.vy[i], mp * parts_.vz[i]};
    for (int a = 0; a < 3; ++a) {
      const float dxa = (float(a) - f[0]) * dx;
      for (int b = 0; b < 3; ++b) {
        const float dyb = (float(b) - f[1]) * dx;
        const float wab = w[0][a] * w[1][b];
        for (int c = 0; c < 3; ++c) {
          const float dzc = (float(c) - f[2]) * dx;
          const float wt = wab * w[2][c];
          const std::size_t node = nodeIndex(bx + a, by + b, bz + c);
          gm_[node] += wt * mp;
          gfs_[node] += wt * ms;
          gfk_[node] += wt * mk;
          gx_[node] += wt * (mv[0] + A(0, 0) * dxa + A(0, 1) * dyb + A(0, 2) * dzc);
          gy_[node] += wt * (mv[1] + A(1, 0) * dxa + A(1, 1) * dyb + A(1, 2) * dzc);
          gz_[node] += wt * (mv[2] + A(2, 0) * dxa + A(2, 1) * dyb + A(2, 2) * dzc);
        }
      }
    }
  };
  for (const auto& blocks : colourBlocks_)
    forEach(blocks.size(), [&](std::size_t k) {
      const auto b = std::size_t(blocks[k]);
      for (std::int32_t o = blockStart_[b]; o < blockStart_[b + 1]; ++o) scatter(std::size_t(order_[std::size_t(o)]));
    });
  // Fixed and carried bodies: the nodes of their particles' stencils move with them, in id
  // order (a node two bodies hold takes the later one's velocity).
  for (std::size_t i = 0; i < parts_.size(); ++i) {
    if (phase::dynamic(parts_.phase[i]) || phase::has(parts_.phase[i], phase::kRemoved)) continue;
    if (hx_.empty()) {
      hx_.assign(gm_.size(), 0.0f);
      hy_.assign(gm_.size(), 0.0f);
      hz_.assign(gm_.size(), 0.0f);
    }
    const int bx = stencilBase(parts_.x[i] - ox, inv, n_);
    const int by = stencilBase(parts_.y[i] - oy, inv, n_);
    const int bz = stencilBase(parts_.z[i] - oz, inv, n_);
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b)
        for (int c = 0; c < 3; ++c) {
          const std::size_t node = nodeIndex(bx + a, by + b, bz + c);
          held_[node] = 1;
          hx_[node] = parts_.vx[i];
          hy_[node] = parts_.vy[i];
          hz_[node] = parts_.vz[i];
        }
  }
}

void MpmWorld::gridUpdate(float h) {
  const float g[3] = {float(h * params_.gravity.x()), float(h * params_.gravity.y()), float(h * params_.gravity.z())};
  const WallKind(&kind)[6] = params_.walls;  // x-, x+, y-, y+, z-, z+
  const int floorNode = std::max(wallLo_[1], groundNode_);
  forEach(activeNodeBlocks_.size(), [&](std::size_t k) {
    const auto block = std::size_t(activeNodeBlocks_[k]);
    const int bx = int(block / (std::size_t(nb_) * nb_)) * kBlock, by = int(block / std::size_t(nb_) % std::size_t(nb_)) * kBlock,
              bz = int(block % std::size_t(nb_)) * kBlock;
    for (int l = 0; l < 64; ++l) {
      const std::size_t node = block * 64 + std::size_t(l);
      const float m = gm_[node];
      if (!(m > 0.0f)) {
        gx_[node] = gy_[node] = gz_[node] = 0.0f;
        continue;
      }
      float v[3] = {gx_[node] / m + g[0], gy_[node] / m + g[1], gz_[node] / m + g[2]};
      if (held_[node]) {
        v[0] = hx_[node];
        v[1] = hy_[node];
        v[2] = hz_[node];
      } else {
        const int idx[3] = {bx + (l >> 4), by + ((l >> 2) & 3), bz + (l & 3)};
        for (int a = 0; a < 3; ++a) {
          const int lowest = a == 1 ? floorNode : wallLo_[a];
          if (idx[a] <= lowest) applyWall(v, a, 1.0f, kind[2 * a], gfs_[node] / m, gfk_[node] / m);
          else if (idx[a] >= wallHi_[a]) applyWall(v, a, -1.0f, kind[2 * a + 1], gfs_[node] / m, gfk_[node] / m);
        }
      }
      gx_[node] = v[0];
      gy_[node] = v[1];
      gz_[node] = v[2];
    }
  });
}

void MpmWorld::g2p(float h) {
  const float inv = float(1.0 / dx_), dx = float(dx_);
  const float ox = float(origin_.x()), oy = float(origin_.y()), oz = float(origin_.z());
  forRange(order_.size(), [&](std::size_t lo, std::size_t hi) {
    for (std::size_t o = lo; o < hi; ++o) {
      const auto i = std::size_t(order_[o]);
      const float fxr = (parts_.x[i] - ox) * inv, fyr = (parts_.y[i] - oy) * inv, fzr = (parts_.z[i] - oz) * inv;
      const int bx = stencilBase(parts_.x[i] - ox, inv, n_);
      const int by = stencilBase(parts_.y[i] - oy, inv, n_);
      const int bz = stencilBase(parts_.z[i] - oz, inv, n_);
      const float f[3] = {fxr - float(bx), fyr - float(by), fzr - float(bz)};
      float w[3][3];
      for (int a = 0; a < 3; ++a) bsplineWeights(f[a], w[a]);
      float v[3] = {0, 0, 0};
      Eigen::Matrix3f B = Eigen::Matrix3f::Zero();
      for (int a = 0; a < 3; ++a) {
        const float d0 = (float(a) - f[0]) * dx;
        for (int b = 0; b < 3; ++b) {
          const float d1 = (float(b) - f[1]) * dx;
          for (int c = 0; c < 3; ++c) {
            const float d2 = (float(c) - f[2]) * dx;
            const float wt = w[0][a] * w[1][b] * w[2][c];
            const std::size_t node = nodeIndex(bx + a, by + b, bz + c);
            const float u[3] = {wt * gx_[node], wt * gy_[node], wt * gz_[node]};
            for (int r = 0; r < 3; ++r) {
              v[r] += u[r];
              B(r, 0) += u[r] * d0;
              B(r, 1) += u[r] * d1;
              B(r, 2) += u[r] * d2;
            }
          }
        }
      }
      const Eigen::Matrix3f C = (4.0f * inv * inv) * B;  // Hu et al. 2018 Eq. 17 with D^-1 = 4/dx^2
      parts_.vx[i] = v[0];
      parts_.vy[i] = v[1];
      parts_.vz[i] = v[2];
      parts_.x[i] += h * v[0];
      parts_.y[i] += h * v[1];
      parts_.z[i] += h * v[2];
      C_[i] = C;
      if (models_[std::size_t(parts_.material[i])].kind == MaterialKind::kFluid)
        plastic_[i] *= 1.0f + h * C.trace();  // J only: a fluid has no rest shape
      else
        F_[i] = (Eigen::Matrix3f::Identity() + h * C) * F_[i];
    }
  });
  // Carried bodies move with their prescribed velocity (fixed ones have none).
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (mode_[b] != BodyMode::kKinematic) continue;
    for (std::int32_t id : members_[b]) {
      const auto i = std::size_t(id);
      parts_.x[i] = std::clamp(parts_.x[i] + h * parts_.vx[i], lo_[0], hi_[0]);
      parts_.y[i] = std::clamp(parts_.y[i] + h * parts_.vy[i], lo_[1], hi_[1]);
      parts_.z[i] = std::clamp(parts_.z[i] + h * parts_.vz[i], lo_[2], hi_[2]);
    }
  }
}

// A particle the grid let past a wall or the ground is put back on it and loses its velocity
// into it: positions never leave [lo, hi], so P2G's stencil never leaves the grid.
void MpmWorld::projection() {
  std::vector<std::int64_t> counts((order_.size() + kChunk - 1) / kChunk, 0);
  forRange(order_.size(), [&](std::size_t lo, std::size_t hi) {
    std::int64_t stopped = 0;
    for (std::size_t o = lo; o < hi; ++o) {
      const auto i = std::size_t(order_[o]);
      float* x[3] = {&parts_.x[i], &parts_.y[i], &parts_.z[i]};
      float* v[3] = {&parts_.vx[i], &parts_.vy[i], &parts_.vz[i]};
      bool hit = false;
      for (int a = 0; a < 3; ++a) {
        if (*x[a] < lo_[a]) {
          *x[a] = lo_[a];
          *v[a] = std::max(*v[a], 0.0f);
          hit = true;
        } else if (*x[a] > hi_[a]) {
          *x[a] = hi_[a];
          *v[a] = std::min(*v[a], 0.0f);
          hit = true;
        } else if (!(*x[a] == *x[a])) {
          continue;  // NaN: left for the guard to report
        }
      }
      stopped += hit;
    }
    counts[lo / kChunk] = stopped;
  });
  for (std::int64_t c : counts) stopped_ += c;
}

void MpmWorld::plasticity() {
  forRange(order_.size(), [&](std::size_t lo, std::size_t hi) {
    for (std::size_t o = lo; o < hi; ++o) {
      const auto i = std::size_t(order_[o]);
      const MatModel& m = models_[std::size_t(parts_.material[i])];
      if (!m.plastic) continue;
      const Svd3<float> d = svd3<float>(F_[i]);
      Eigen::Vector3f s;
      if (m.kind == MaterialKind::kSand) {
        float alpha = m.alpha;
        if (m.hardeningDeg > 0.0f) {
          const float deg = std::min(80.0f, m.frictionDeg + m.hardeningDeg * plastic_[i]);
          alpha = float(druckerPragerAlpha(double(deg) * kPi / 180.0));
        }
        float dq = 0.0f;
        s = druckerPragerReturn<float>(d.sigma, m.mu, m.lambda, alpha, m.shift, dq);
        plastic_[i] += dq;
      } else if (m.kind == MaterialKind::kPlasticine) {
        s = vonMisesReturn<float>(d.sigma, m.mu, m.yield);
      } else {
        s = snowClamp<float>(d.sigma, m.thetaC, m.thetaS, m.xi, plastic_[i]);
      }
      F_[i] = d.U * s.asDiagonal() * d.V.transpose();
    }
  });
}

}  // namespace physketch::mpm
