// DenseLevelSet: OpenVDB's level-set updates (TopologyToLevelSet.h, LevelSetTracker.h,
// LevelSetFilter.h, LevelSetMeasure.h, Stencils.h of OpenVDB 10) on a flat array. Each update
// keeps OpenVDB's float and double operations in their order, so the two builds of a level set
// agree to rounding (test_render's DenseLevelSet tests); comments name the OpenVDB function.
#include "render/dense_level_set.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace physketch::render {
namespace {

// Band voxels per parallel chunk: each chunk writes its own slots of the scratch buffer (a
// Jacobi update), so the result does not depend on the thread count.
constexpr std::size_t kChunk = 4096;

template <typename F>
void forChunks(std::size_t n, const F& f) {
  if (n <= kChunk) {
    f(std::size_t{0}, n);
    return;
  }
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, kChunk),
                    [&](const tbb::blocked_range<std::size_t>& r) { f(r.begin(), r.end()); });
}

// math::GodunovsNormSqrd: the upwind |grad phi|^2 (index space) from the backward (m) and
// forward (p) differences.
inline float godunovNormSqrd(bool outside, float xm, float xp, float ym, float yp, float zm, float zp) {
  const float zero = 0.0f;
  auto sq = [](float v) { return v * v; };
  float len2;
  if (outside) {
    len2 = std::max(sq(std::max(xm, zero)), sq(std::min(xp, zero)));
    len2 += std::max(sq(std::max(ym, zero)), sq(std::min(yp, zero)));
    len2 += std::max(sq(std::max(zm, zero)), sq(std::min(zp, zero)));
  } else {
    len2 = std::max(sq(std::min(xm, zero)), sq(std::max(xp, zero)));
    len2 += std::max(sq(std::min(ym, zero)), sq(std::max(yp, zero)));
    len2 += std::max(sq(std::min(zm, zero)), sq(std::max(zp, zero)));
  }
  return len2;
}

// 6-neighbour morphology on a box mask (tools::dilateActiveValues / erodeActiveValues with
// NN_FACE); voxels beyond the box count as off, and dilation leaves the box's outer layer off.
// Bytes are 0 or 1 and each row's inner voxels are one branch-free loop, which the compiler
// vectorizes.
void dilateMask(std::vector<std::uint8_t>& mask, const Vec3i& dims) {
  const std::vector<std::uint8_t> in = mask;
  const std::size_t sy = std::size_t(dims.x()), sz = sy * std::size_t(dims.y());
  for (int z = 1; z + 1 < dims.z(); ++z)
    for (int y = 1; y + 1 < dims.y(); ++y) {
      const std::size_t row = sy * (std::size_t(y) + std::size_t(dims.y()) * std::size_t(z));
      const std::uint8_t* c = in.data() + row;
      std::uint8_t* out = mask.data() + row;
      for (std::size_t x = 1; x + 1 < sy; ++x)
        out[x] = c[x] | c[x - 1] | c[x + 1] | c[x - sy] | c[x + sy] | c[x - sz] | c[x + sz];
    }
}

void erodeMask(std::vector<std::uint8_t>& mask, const Vec3i& dims) {
  const std::vector<std::uint8_t> in = mask;
  const std::size_t sy = std::size_t(dims.x()), sz = sy * std::size_t(dims.y());
  for (int z = 0; z < dims.z(); ++z)
    for (int y = 0; y < dims.y(); ++y) {
      const std::size_t row = sy * (std::size_t(y) + std::size_t(dims.y()) * std::size_t(z));
      std::uint8_t* out = mask.data() + row;
      out[0] = out[sy - 1] = 0;
      if (z == 0 || y == 0 || z + 1 == dims.z() || y + 1 == dims.y()) {
        std::fill(out, out + sy, std::uint8_t{0});
        continue;
      }
      const std::uint8_t* c = in.data() + row;
      for (std::size_t x = 1; x + 1 < sy; ++x)
        out[x] = c[x] & c[x - 1] & c[x + 1] & c[x - sy] & c[x + sy] & c[x - sz] & c[x + sz];
    }
}

// The box's margin around the cells: the closing, the band, and room for the band to follow a
// surface that smoothing and volume offsets move by a voxel or two; dilate() never reaches the
// outer layer, so every stencil of a band voxel stays inside the box.
int margin(int halfWidth, int closingSteps) { return closingSteps + halfWidth + 4; }

}  // namespace

std::uint64_t DenseLevelSet::boxVoxels(const std::vector<Vec3i>& cells, int halfWidth, int closingSteps) {
  if (cells.empty()) return 0;
  Vec3i lo = cells[0], hi = cells[0];
  for (const Vec3i& c : cells) {
    lo = lo.cwiseMin(c);
    hi = hi.cwiseMax(c);
  }
  // In int64 and saturated: cells may lie 2^31 apart, whose box's voxel count overflows 64 bits.
  const std::int64_t m = margin(std::max(halfWidth, 1), std::max(closingSteps, 0));
  constexpr std::uint64_t kTooMany = std::numeric_limits<std::uint64_t>::max();
  std::uint64_t n = 1;
  for (int a = 0; a < 3; ++a) {
    const std::uint64_t extent = std::uint64_t(std::int64_t(hi[a]) - lo[a] + 1 + 2 * m);
    if (extent > (std::uint64_t(1) << 31)) return kTooMany;
    n *= extent;
    if (n > (std::uint64_t(1) << 40)) return kTooMany;
  }
  return n;
}

DenseLevelSet DenseLevelSet::fromCells(const std::vector<Vec3i>& cells, double voxelSize, int halfWidth,
                                       int closingSteps, int smoothingSteps) {
  if (cells.empty()) throw std::invalid_argument("DenseLevelSet::fromCells: no cells");
  halfWidth = std::max(halfWidth, 1);
  closingSteps = std::max(closingSteps, 0);
  DenseLevelSet ls;
  Vec3i lo = cells[0], hi = cells[0];
  for (const Vec3i& c : cells) {
    lo = lo.cwiseMin(c);
    hi = hi.cwiseMax(c);
  }
  const int m = margin(halfWidth, closingSteps);
  // Band positions are 32-bit indices into the box.
  if (boxVoxels(cells, halfWidth, closingSteps) > std::numeric_limits<std::uint32_t>::max())
    throw std::invalid_argument("DenseLevelSet::fromCells: the cells' box holds more than 2^32 voxels");
  ls.lo_ = lo.array() - m;
  ls.dims_ = (hi - lo).array() + 1 + 2 * m;
  ls.h_ = voxelSize;
  ls.dx_ = float(voxelSize);  // LevelSetTracker's mDx
  // topologyToLevelSet: background = float(voxelSize) * float(halfWidth).
  ls.background_ = float(voxelSize) * float(halfWidth);
  const std::size_t n = std::size_t(ls.dims_.x()) * std::size_t(ls.dims_.y()) * std::size_t(ls.dims_.z());

  // The cells, closed (dilate, then erode, closingSteps times).
  std::vector<std::uint8_t> mask(n, 0);
  for (const Vec3i& c : cells) {
    const Vec3i r = c - ls.lo_;
    mask[ls.index(r.x(), r.y(), r.z())] = 1;
  }
  for (int i = 0; i < closingSteps; ++i) dilateMask(mask, ls.dims_);
  for (int i = 0; i < closingSteps; ++i) erodeMask(mask, ls.dims_);

  // The step field (-background inside, +background outside), active from halfWidth outside
  // the surface to halfWidth inside it.
  ls.phi_.resize(n);
  for (std::size_t i = 0; i < n; ++i) ls.phi_[i] = mask[i] ? -ls.background_ : ls.background_;
  std::vector<std::uint8_t> outer = mask, inner = mask;
  for (int i = 0; i < halfWidth; ++i) {
    dilateMask(outer, ls.dims_);
    erodeMask(inner, ls.dims_);
  }
  ls.active_.assign(n, 0);
  for (std::size_t i = 0; i < n; ++i) ls.active_[i] = outer[i] && !inner[i];
  ls.border_.assign(n, 0);
  for (int z = 0; z < ls.dims_.z(); ++z)
    for (int y = 0; y < ls.dims_.y(); ++y)
      for (int x = 0; x < ls.dims_.x(); ++x)
        ls.border_[ls.index(x, y, z)] = x == 0 || y == 0 || z == 0 || x + 1 == ls.dims_.x() || y + 1 == ls.dims_.y() ||
                                        z + 1 == ls.dims_.z();
  ls.rebuildBand();

  // ttls_internal::normalizeLevelSet: 3 x halfWidth sweeps, then the tracker's prune.
  ls.normalize(3 * halfWidth);
  ls.trim();

  // ttls_internal::smoothLevelSet: box means on a copy (each followed by the tracker's track),
  // then min(phi, copy - h/2) where the copy has a leaf, then halfWidth sweeps and a prune.
  if (smoothingSteps > 0) {
    DenseLevelSet copy = ls;
    for (int i = 0; i < smoothingSteps; ++i) {
      copy.boxMean();
      copy.track(3);  // a fresh LevelSetFilter renormalizes with its default 3 sweeps
    }
    // The copy's leaves: pruneLevelSet replaced every 8^3 block without a band voxel by a tile,
    // and OffsetAndMinComp skips voxels whose block the copy has no leaf for.
    const Vec3i b0(ls.lo_.x() >> 3, ls.lo_.y() >> 3, ls.lo_.z() >> 3);
    const Vec3i bn = Vec3i((ls.lo_.x() + ls.dims_.x() - 1) >> 3, (ls.lo_.y() + ls.dims_.y() - 1) >> 3,
                           (ls.lo_.z() + ls.dims_.z() - 1) >> 3) -
                     b0 + Vec3i::Ones();
    std::vector<std::uint8_t> leaf(std::size_t(bn.x()) * std::size_t(bn.y()) * std::size_t(bn.z()), 0);
    auto eachVoxel = [&](const auto& f) {
      std::size_t i = 0;
      for (int z = 0; z < ls.dims_.z(); ++z)
        for (int y = 0; y < ls.dims_.y(); ++y) {
          const std::size_t row = std::size_t(((ls.lo_.y() + y) >> 3) - b0.y()) +
                                  std::size_t(bn.y()) * std::size_t(((ls.lo_.z() + z) >> 3) - b0.z());
          for (int x = 0; x < ls.dims_.x(); ++x, ++i) f(i, std::size_t(((ls.lo_.x() + x) >> 3) - b0.x()) + std::size_t(bn.x()) * row);
        }
    };
    eachVoxel([&](std::size_t i, std::size_t block) {
      if (copy.active_[i]) leaf[block] = 1;
    });
    const float offset = -float(0.5 * voxelSize);  // OffsetAndMinComp's -offset
    eachVoxel([&](std::size_t i, std::size_t block) {
      if (ls.active_[i] && leaf[block]) ls.phi_[i] = std::min(ls.phi_[i], offset + copy.phi_[i]);
    });
    ls.normalize(halfWidth);
    ls.trim();
    ls.reachedBorder_ = ls.reachedBorder_ || copy.reachedBorder_;
  }
  return ls;
}

void DenseLevelSet::rebuildBand() {
  band_.clear();
  const std::size_t n = active_.size();
  for (std::size_t i = 0; i < n; ++i) {
    // Most of the box is off the band: skip it eight bytes at a time.
    if ((i & 7) == 0 && i + 8 <= n) {
      std::uint64_t word;
      std::memcpy(&word, active_.data() + i, 8);
      if (word == 0) {
        i += 7;
        continue;
      }
    }
    if (active_[i]) band_.push_back(std::uint32_t(i));
  }
  rebuildRuns();
}

void DenseLevelSet::rebuildRuns() {
  runs_.clear();
  for (std::size_t k = 0; k < band_.size(); ++k) {
    if (k > 0 && band_[k - 1] + 1 == band_[k]) {
      ++runs_.back().second;
    } else {
      runs_.emplace_back(std::uint32_t(k), 1u);
    }
  }
}

namespace {

// Normalizer<FIRST_BIAS, TVD_RK1>::eval at one voxel (p: its value in the box, strides sy, sz).
inline float normalized(const float* p, std::ptrdiff_t sy, std::ptrdiff_t sz, float dt, float invDx) {
  const float p0 = p[0];
  const float normSq =
      godunovNormSqrd(p0 > 0.0f, p0 - p[-1], p[1] - p0, p0 - p[-sy], p[sy] - p0, p0 - p[-sz], p[sz] - p0);
  float v = p0 / (std::sqrt(p0 * p0 + normSq) + 1e-8f);  // + math::Tolerance<float>
  return p0 - dt * v * (std::sqrt(normSq) * invDx - 1.0f);
}

#if defined(__SSE2__)
// The same at four voxels in a row, the same IEEE operations lane by lane (SSE's min, max,
// sqrt and divide round as the scalar ones do; a max's choice between +0 and -0 is squared
// away), so the values are the scalar loop's bits.
inline __m128 normalized4(const float* p, std::ptrdiff_t sy, std::ptrdiff_t sz, __m128 dt, __m128 invDx) {
  const __m128 zero = _mm_setzero_ps(), p0 = _mm_loadu_ps(p);
  const __m128 outside = _mm_cmpgt_ps(p0, zero);
  auto select = [&](__m128 a, __m128 b) { return _mm_or_ps(_mm_and_ps(outside, a), _mm_andnot_ps(outside, b)); };
  auto axis = [&](std::ptrdiff_t s) {
    const __m128 m = _mm_sub_ps(p0, _mm_loadu_ps(p - s)), q = _mm_sub_ps(_mm_loadu_ps(p + s), p0);
    const __m128 a = select(_mm_max_ps(m, zero), _mm_min_ps(m, zero));
    const __m128 b = select(_mm_min_ps(q, zero), _mm_max_ps(q, zero));
    return _mm_max_ps(_mm_mul_ps(a, a), _mm_mul_ps(b, b));
  };
  __m128 normSq = axis(1);
  normSq = _mm_add_ps(normSq, axis(sy));
  normSq = _mm_add_ps(normSq, axis(sz));
  __m128 v = _mm_div_ps(p0, _mm_add_ps(_mm_sqrt_ps(_mm_add_ps(_mm_mul_ps(p0, p0), normSq)), _mm_set1_ps(1e-8f)));
  const __m128 g = _mm_sub_ps(_mm_mul_ps(_mm_sqrt_ps(normSq), invDx), _mm_set1_ps(1.0f));
  return _mm_sub_ps(p0, _mm_mul_ps(_mm_mul_ps(dt, v), g));
}
#endif

}  // namespace

void DenseLevelSet::normalize(int sweeps) {
  // Normalizer<FIRST_BIAS, TVD_RK1>::eval: mDt = voxelSize * 0.3f, mInvDx = 1 / voxelSize.
  const float dt = dx_ * 0.3f, invDx = 1.0f / dx_;
  const std::ptrdiff_t sy = dims_.x(), sz = sy * dims_.y();
  scratch_.resize(band_.size());
  for (int s = 0; s < sweeps; ++s) {
    // Runs of band voxels consecutive along x, so four at a time load as one vector.
    forChunks(runs_.size(), [&](std::size_t b, std::size_t e) {
      for (std::size_t r = b; r < e; ++r) {
        const std::size_t k0 = runs_[r].first, n = runs_[r].second;
        const float* p = phi_.data() + band_[k0];
        float* out = scratch_.data() + k0;
        std::size_t j = 0;
#if defined(__SSE2__)
        const __m128 dt4 = _mm_set1_ps(dt), invDx4 = _mm_set1_ps(invDx);
        for (; j + 4 <= n; j += 4) _mm_storeu_ps(out + j, normalized4(p + j, sy, sz, dt4, invDx4));
        if (j < n) {
          // The run's last one to three voxels with the voxels after them (which the box holds:
          // a band voxel is at least a layer and a row from its end), keeping only theirs.
          alignas(16) float tail[4];
          _mm_store_ps(tail, normalized4(p + j, sy, sz, dt4, invDx4));
          for (std::size_t t = 0; j < n; ++j, ++t) out[j] = tail[t];
        }
#endif
        for (; j < n; ++j) out[j] = normalized(p + j, sy, sz, dt, invDx);
      }
    });
    applyScratch();
  }
}

void DenseLevelSet::applyScratch() {
  forChunks(band_.size(), [&](std::size_t b, std::size_t e) {
    for (std::size_t k = b; k < e; ++k) phi_[band_[k]] = scratch_[k];
  });
}

void DenseLevelSet::trim() {
  // LevelSetTracker::Trim<kAll>: |phi| >= background leaves the band, set to +-background.
  std::size_t kept = 0;
  for (std::uint32_t i : band_) {
    const float v = phi_[i];
    if (v <= -background_) {
      active_[i] = 0;
      phi_[i] = -background_;
    } else if (v >= background_) {
      active_[i] = 0;
      phi_[i] = background_;
    } else {
      band_[kept++] = i;
    }
  }
  band_.resize(kept);
  rebuildRuns();
}

void DenseLevelSet::dilate() {
  const std::size_t sy = std::size_t(dims_.x()), sz = sy * std::size_t(dims_.y());
  for (const std::size_t i : band_)
    for (const std::size_t j : {i - 1, i + 1, i - sy, i + sy, i - sz, i + sz}) {
      if (border_[j]) {
        reachedBorder_ = true;  // OpenVDB's band would grow here; this box cannot follow
      } else {
        active_[j] = 1;
      }
    }
  rebuildBand();
}

void DenseLevelSet::boxMean() {
  // LevelSetFilter::Filter::box(1): boxXImpl (axis 0), boxYImpl (Avg<2>, axis z), boxZImpl
  // (Avg<1>, axis y), each a Jacobi pass over the band, then the tracker's track().
  const std::ptrdiff_t sy = dims_.x(), sz = sy * dims_.y();
  const float frac = 1.0f / 3.0f;  // 1 / ValueType(2 w + 1)
  scratch_.resize(band_.size());
  for (std::ptrdiff_t s : {std::ptrdiff_t(1), sz, sy}) {
    forChunks(band_.size(), [&](std::size_t b, std::size_t e) {
      for (std::size_t k = b; k < e; ++k) {
        const float* p = phi_.data() + band_[k];
        float sum = 0.0f;
        sum += p[-s];
        sum += p[0];
        sum += p[s];
        scratch_[k] = sum * frac;
      }
    });
    applyScratch();
  }
}

void DenseLevelSet::meanCurvature(int sweeps) {
  // Filter::meanCurvatureImpl: phi + dt * CurvatureStencil::meanCurvatureNormGrad(), dt = dx^2/3.
  const float dt = dx_ * dx_ / 3.0f;
  const float inv2Dx = float(0.5 / double(dx_));
  const float invDx2 = float(4.0 * inv2Dx * inv2Dx);
  const std::ptrdiff_t sy = dims_.x(), sz = sy * dims_.y();
  scratch_.resize(band_.size());
  forChunks(band_.size(), [&](std::size_t b, std::size_t e) {
    for (std::size_t k = b; k < e; ++k) {
      const float* p = phi_.data() + band_[k];
      const float v0 = p[0];
      // CurvatureStencil's differences: float operations, then widened (Real = double).
      const double Dx = 0.5 * (p[1] - p[-1]), Dy = 0.5 * (p[sy] - p[-sy]), Dz = 0.5 * (p[sz] - p[-sz]);
      const double Dx2 = Dx * Dx, Dy2 = Dy * Dy, Dz2 = Dz * Dz, normGrad2 = Dx2 + Dy2 + Dz2;
      float kappa = 0.0f;
      if (normGrad2 > 1e-15) {  // math::Tolerance<double>
        const double Dxx = p[1] - 2 * v0 + p[-1], Dyy = p[sy] - 2 * v0 + p[-sy], Dzz = p[sz] - 2 * v0 + p[-sz];
        const double Dxy = 0.25 * (p[1 + sy] - p[1 - sy] + p[-1 - sy] - p[-1 + sy]);
        const double Dxz = 0.25 * (p[1 + sz] - p[1 - sz] + p[-1 - sz] - p[-1 + sz]);
        const double Dyz = 0.25 * (p[sy + sz] - p[sy - sz] + p[-sy - sz] - p[-sy + sz]);
        const double alpha = Dx2 * (Dyy + Dzz) + Dy2 * (Dxx + Dzz) + Dz2 * (Dxx + Dyy) -
                             2 * (Dx * (Dy * Dxy + Dz * Dxz) + Dy * Dz * Dyz);
        const double normGrad = std::sqrt(normGrad2);
        kappa = float(alpha * invDx2 / (2 * (normGrad * normGrad)));
      }
      scratch_[k] = v0 + dt * kappa;
    }
  });
  applyScratch();
  track(sweeps);
}

void DenseLevelSet::offset(float d) {
  for (std::uint32_t i : band_) phi_[i] = phi_[i] + d;
}

void DenseLevelSet::measure(double& area, double& volume) const {
  // LevelSetMeasure::MeasureArea: a Dirac delta 3 voxels wide, the central gradient in world
  // units (GradStencil, float), positions in index space.
  const double dx = h_, invDx = 1.0 / dx;  // LevelSetMeasure's mDx: grid.voxelSize()[0], double
  const double c = 0.5 / 1.5, d = 2 * 3.141592653589793 * c;
  const float inv2Dx = float(0.5 / dx);
  const std::ptrdiff_t sy = dims_.x(), sz = sy * dims_.y();
  double sumA = 0.0, sumV = 0.0;
  for (std::uint32_t i : band_) {
    const double u = invDx * phi_[i];
    if (std::abs(u) > 1.5) continue;
    const double dd = c * (1 + std::cos(d * u));
    if (!(dd > 0.0)) continue;
    const float* p = phi_.data() + i;
    const float gx = (p[1] - p[-1]) * inv2Dx, gy = (p[sy] - p[-sy]) * inv2Dx, gz = (p[sz] - p[-sz]) * inv2Dx;
    const std::size_t x = i % std::size_t(sy), y = (i / std::size_t(sy)) % std::size_t(dims_.y()), z = i / std::size_t(sz);
    sumA += dd * std::sqrt(gx * gx + gy * gy + gz * gz);
    sumV += dd * (gx * double(lo_.x() + int(x)) + gy * double(lo_.y() + int(y)) + gz * double(lo_.z() + int(z)));
  }
  // As LevelSetMeasure scales them (Pow2, Pow3); its sums run leaf by leaf and add the sorted
  // leaf sums, so the two agree to rounding, not bit for bit.
  area = sumA * (dx * dx);
  volume = sumV / 3.0 * (dx * dx * dx);
}

}  // namespace physketch::render
