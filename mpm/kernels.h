// The small kernels the MPM passes share (internal to mpm/): fixed-chunk parallel loops,
// quadratic B-spline weights, a particle's stencil base, and the wall conditions.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/parallel.h"
#include "mpm/world.h"

namespace physketch::mpm::detail {

constexpr double kPi = 3.14159265358979323846;
constexpr int kBlock = 4;        // cells per block edge (P2G's unit of work)
using physketch::forEach;   // fixed-chunk parallel loops (core/parallel.h): serial below one chunk
using physketch::forRange;
using physketch::kChunk;

// Quadratic B-spline weights (Hu et al. 2018 §5; Jiang et al. 2016 Eq. 123) of the three nodes
// base, base+1, base+2 for a particle at fractional offset f = x/dx - base in [0.5, 1.5).
inline void bsplineWeights(float f, float w[3]) {
  w[0] = 0.5f * (1.5f - f) * (1.5f - f);
  w[1] = 0.75f - (f - 1.0f) * (f - 1.0f);
  w[2] = 0.5f * (f - 0.5f) * (f - 0.5f);
}

// Four floats added and multiplied lane by lane: one grid node's record (mass, then three
// momentum or velocity components) as one SSE register. Each lane is the same IEEE operation
// as the scalar code it replaces, in the same order, so results are bit-identical to it and
// the scalar fallback (no SSE2) gives the same bits too.
struct F4 {
#if defined(__SSE2__)
  __m128 v;
  static F4 set(float a, float b, float c, float d) { return {_mm_setr_ps(a, b, c, d)}; }
  static F4 splat(float s) { return {_mm_set1_ps(s)}; }
  static F4 load(const void* p) { return {_mm_loadu_ps(static_cast<const float*>(p))}; }
  void store(void* p) const { _mm_storeu_ps(static_cast<float*>(p), v); }
  friend F4 operator+(F4 a, F4 b) { return {_mm_add_ps(a.v, b.v)}; }
  friend F4 operator*(F4 a, F4 b) { return {_mm_mul_ps(a.v, b.v)}; }
  float lane(int k) const {
    alignas(16) float t[4];
    _mm_store_ps(t, v);
    return t[k];
  }
#else
  float v[4];
  static F4 set(float a, float b, float c, float d) { return {{a, b, c, d}}; }
  static F4 splat(float s) { return {{s, s, s, s}}; }
  static F4 load(const void* p) {
    F4 r;
    std::memcpy(r.v, p, sizeof r.v);
    return r;
  }
  void store(void* p) const { std::memcpy(p, v, sizeof v); }
  friend F4 operator+(F4 a, F4 b) { return {{a.v[0] + b.v[0], a.v[1] + b.v[1], a.v[2] + b.v[2], a.v[3] + b.v[3]}}; }
  friend F4 operator*(F4 a, F4 b) { return {{a.v[0] * b.v[0], a.v[1] * b.v[1], a.v[2] * b.v[2], a.v[3] * b.v[3]}}; }
  float lane(int k) const { return v[k]; }
#endif
};

// Coulomb's law for a contact whose normal speed vn < 0 was removed: the factor on the
// tangential velocity of length t >= 0. It stops when t <= mus |vn| (static), else loses
// muk |vn| of its length (dynamic). t = 0 is static, so nothing divides by it. The one
// friction law of walls, ground, tools and mesh colliders.
template <class S>
S coulombScale(S t, S vn, S mus, S muk) {
  return t <= mus * (-vn) ? S(0) : std::max(S(0), S(1) - muk * (-vn) / t);
}

// Coulomb friction on a node velocity whose normal part vn < 0 along `axis` was removed.
inline void applyFriction(float v[3], int axis, float vn, float mus, float muk) {
  float t2 = 0.0f;
  for (int a = 0; a < 3; ++a)
    if (a != axis) t2 += v[a] * v[a];
  const float scale = coulombScale(std::sqrt(t2), vn, mus, muk);
  for (int a = 0; a < 3; ++a)
    if (a != axis) v[a] *= scale;
}

// A wall with inward normal +axis (side = +1) or -axis (side = -1) acting on a node velocity.
inline void applyWall(float v[3], int axis, float side, WallKind kind, float mus, float muk) {
  const float vn = side * v[axis];
  switch (kind) {
    case WallKind::kSticky: v[0] = v[1] = v[2] = 0.0f; break;
    case WallKind::kSlip: v[axis] = 0.0f; break;
    case WallKind::kSeparate:
      if (vn < 0.0f) {
        v[axis] = 0.0f;
        applyFriction(v, axis, vn, mus, muk);
      }
      break;
  }
}

// A carried body's one-sided boundary on a node velocity v: relative to the body's velocity
// (hx, hy, hz), the part along the normal n (not unit; away from the body) that moves into the
// body is removed, with Coulomb friction on the rest; material moving away is left alone (a
// tool pushes, never pulls: PhyVR's Algorithm 1 does this for its tools). A zero normal (the
// node inside the body) takes the body's velocity.
inline void pushOnly(float v[3], float hx, float hy, float hz, const float n[3], float mus, float muk) {
  const float hv[3] = {hx, hy, hz};
  const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  if (!(len > 1e-6f)) {
    for (int a = 0; a < 3; ++a) v[a] = hv[a];
    return;
  }
  float rel[3], vn = 0.0f;
  for (int a = 0; a < 3; ++a) {
    rel[a] = v[a] - hv[a];
    vn += rel[a] * n[a] / len;
  }
  if (vn >= 0.0f) return;
  float t2 = 0.0f;
  for (int a = 0; a < 3; ++a) {
    rel[a] -= vn * n[a] / len;
    t2 += rel[a] * rel[a];
  }
  const float scale = coulombScale(std::sqrt(t2), vn, mus, muk);
  for (int a = 0; a < 3; ++a) v[a] = hv[a] + scale * rel[a];
}

// The lowest node of a particle's 3-node stencil along one axis: floor(x/dx - 1/2), clamped
// so that base + 2 is still a node of the grid (nodes 0..n-1): no write ever leaves the grid.
// Truncation stands in for floor (SSE2 has no floor instruction): they differ only below 0,
// which is clamped to 0 first, as is NaN (the guard reports it); values past int's range are
// cut at 1e9 before the conversion.
inline int stencilBase(float fromOrigin, float invDx, int n) {
  const float u = fromOrigin * invDx - 0.5f;
  return !(u >= 0.0f) ? 0 : std::min(int(std::min(u, 1e9f)), n - 3);
}

// The index of node (x, y, z) on the block-major grid (4^3 nodes per block, nb blocks per axis).
inline std::size_t blockMajorNode(int x, int y, int z, int nb) {
  return ((std::size_t(x >> 2) * std::size_t(nb) + std::size_t(y >> 2)) * std::size_t(nb) + std::size_t(z >> 2)) * 64 +
         std::size_t(((x & 3) << 4) | ((y & 3) << 2) | (z & 3));
}

// Block b's first node along each axis.
inline void blockCorner(std::size_t b, int nb, int corner[3]) {
  corner[0] = int(b / (std::size_t(nb) * std::size_t(nb))) * kBlock;
  corner[1] = int(b / std::size_t(nb) % std::size_t(nb)) * kBlock;
  corner[2] = int(b % std::size_t(nb)) * kBlock;
}

// A particle's stencil in its block's tile (the nodes from the block's corner on, `edge` per
// axis, z fastest): the offsets f = x/dx - base and the B-spline weights per axis, and the
// tile index of its base node. p: the particle's position relative to the grid origin (m).
struct TileStencil {
  float f[3];
  float w[3][3];
  int offset;
};
// One axis of a stencil: its base node, the offset f = x/dx - base and the three weights.
inline int axisStencil(float fromOrigin, float invDx, int n, float& f, float w[3]) {
  const int base = stencilBase(fromOrigin, invDx, n);
  f = fromOrigin * invDx - float(base);
  bsplineWeights(f, w);
  return base;
}

inline TileStencil tileStencil(const float (&p)[3], float invDx, int n, const int (&corner)[3], int edge) {
  TileStencil s;
  int base[3];
  for (int a = 0; a < 3; ++a) base[a] = axisStencil(p[a], invDx, n, s.f[a], s.w[a]);
  s.offset = ((base[0] - corner[0]) * edge + (base[1] - corner[1])) * edge + (base[2] - corner[2]);
  return s;
}

// A particle's 3x3x3 stencil on the block-major grid (4^3 nodes per block, nb blocks per
// axis): the B-spline weights, the offsets f = x/dx - base, and per axis the part of each
// node's index that axis contributes, so that node (a, b, c) is ix[a] + iy[b] + iz[c] with no
// index arithmetic in the 27-node loops of P2G and G2P.
struct Stencil {
  float f[3];
  float w[3][3];
  std::size_t ix[3], iy[3], iz[3];
  std::size_t node(int a, int b, int c) const { return ix[a] + iy[b] + iz[c]; }
};

// x, y, z: the particle's position relative to the grid origin (m).
inline Stencil makeStencil(float x, float y, float z, float invDx, int n, int nb) {
  Stencil s;
  const float p[3] = {x, y, z};
  const std::size_t blockStride[3] = {std::size_t(nb) * std::size_t(nb) * 64, std::size_t(nb) * 64, 64};
  const int localShift[3] = {4, 2, 0};
  std::size_t* idx[3] = {s.ix, s.iy, s.iz};
  for (int a = 0; a < 3; ++a) {
    const int base = axisStencil(p[a], invDx, n, s.f[a], s.w[a]);
    for (int k = 0; k < 3; ++k) {
      const int node = base + k;
      idx[a][k] = std::size_t(node >> 2) * blockStride[a] + (std::size_t(node & 3) << localShift[a]);
    }
  }
  return s;
}

}  // namespace physketch::mpm::detail
