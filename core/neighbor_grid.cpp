#include "core/neighbor_grid.h"

#include <immintrin.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <limits>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace physketch {
namespace {

// Work is cut into fixed units whose boundaries depend only on the sizes, never on the
// thread count; each unit writes its own elements, so any schedule gives the same bits.
constexpr std::size_t kParticleChunk = 8192;  // particles per unit of the per-particle maps
constexpr std::size_t kCellChunk = 512;       // cells per unit of the row and list passes
constexpr std::size_t kMaxSortChunks = 16;    // units of a radix pass (one histogram each)

std::size_t chunkCount(std::size_t n, std::size_t chunk) { return (n + chunk - 1) / chunk; }

// Calls f(begin, end) for the fixed units [c * chunk, min(n, (c + 1) * chunk)).
template <class F>
void forChunks(std::size_t n, std::size_t chunk, F&& f) {
  const std::size_t units = chunkCount(n, chunk);
  if (units <= 1) {
    if (n) f(std::size_t(0), n);
    return;
  }
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, units, 1),
      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t u = r.begin(); u != r.end(); ++u) f(u * chunk, std::min(n, (u + 1) * chunk));
      },
      tbb::simple_partitioner());
}

void checkCount(std::size_t n, const char* who) {
  if (n > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
    throw RuntimeError(std::string(who) + ": " + std::to_string(n) + " particles (at most 2^31 - 1)");
}

// Bounding box of the points; throws for a non-finite coordinate, naming the lowest id.
struct Box {
  float lo[3], hi[3];
};
Box boundsOf(const float* const p[3], std::size_t n) {
  const std::size_t units = chunkCount(n, kParticleChunk);
  std::vector<Box> part(units);
  std::vector<std::size_t> bad(units, n);
  forChunks(n, kParticleChunk, [&](std::size_t b, std::size_t e) {
    bool finite = true;
    for (std::size_t i = b; i < e; ++i) finite &= std::isfinite(p[0][i]) & std::isfinite(p[1][i]) & std::isfinite(p[2][i]);
    for (std::size_t i = b; i < e && !finite; ++i)
      if (!(std::isfinite(p[0][i]) && std::isfinite(p[1][i]) && std::isfinite(p[2][i]))) {
        bad[b / kParticleChunk] = i;
        return;
      }
    Box& box = part[b / kParticleChunk];
    for (int a = 0; a < 3; ++a) {
      float lo = p[a][b], hi = p[a][b];
      for (std::size_t i = b; i < e; ++i) lo = std::min(lo, p[a][i]), hi = std::max(hi, p[a][i]);
      box.lo[a] = lo, box.hi[a] = hi;
    }
  });
  Box box = part.empty() ? Box{{0, 0, 0}, {0, 0, 0}} : part[0];
  for (std::size_t u = 0; u < units; ++u) {
    if (bad[u] < n) {
      const std::size_t i = bad[u];
      throw RuntimeError("NeighborGrid::build: particle " + std::to_string(i) + " has a non-finite position (" +
                         std::to_string(p[0][i]) + ", " + std::to_string(p[1][i]) + ", " + std::to_string(p[2][i]) +
                         ")");
    }
    for (int a = 0; a < 3; ++a) {
      box.lo[a] = std::min(box.lo[a], part[u].lo[a]);
      box.hi[a] = std::max(box.hi[a], part[u].hi[a]);
    }
  }
  return box;
}

// LSD radix sort plan: `passes` stable counting sorts of `bits` bits each (the first
// digits least significant). One pass is a plain counting sort over all keys.
struct RadixPlan {
  int passes = 1;
  int bits = 1;
};
// Cost model: a pass reads and scatters every particle (~5 units each) and clears and
// scans one histogram per sort chunk (~2 units per bucket). Depends only on the sizes.
RadixPlan planRadix(std::uint64_t maxKey, std::size_t n, std::size_t chunks) {
  int keyBits = 1;
  while (keyBits < 64 && (maxKey >> keyBits)) ++keyBits;
  RadixPlan best;
  double bestCost = std::numeric_limits<double>::infinity();
  for (int passes = 1; passes <= keyBits; ++passes) {
    const int bits = (keyBits + passes - 1) / passes;
    if (bits > 20) continue;  // histograms of 2^20+ buckets per chunk: never worth it
    const double buckets = passes == 1 ? double(maxKey) + 1 : std::ldexp(1.0, bits);
    const double cost = passes * (5.0 * double(n) + 2.0 * double(chunks) * buckets);
    if (cost < bestCost) bestCost = cost, best = {passes, bits};
  }
  return best;
}

// One stable counting-sort pass of (key, id) by the digit (key >> shift) & mask, whose
// values are < buckets. idIn == nullptr means ids 0..n-1. Chunks count in parallel, one
// histogram each; the offsets are then laid out bucket by bucket, chunk by chunk, so
// equal digits keep their input order whatever the schedule.
void countingPass(const std::uint64_t* keyIn, const std::int32_t* idIn, std::uint64_t* keyOut,
                  std::int32_t* idOut, std::size_t n, int shift, std::uint64_t mask, std::size_t buckets,
                  std::size_t chunk, std::vector<std::uint32_t>& hist) {
  const std::size_t chunks = chunkCount(n, chunk);
  hist.assign(chunks * buckets, 0);
  forChunks(n, chunk, [&](std::size_t b, std::size_t e) {
    std::uint32_t* h = &hist[b / chunk * buckets];
    for (std::size_t i = b; i < e; ++i) ++h[(keyIn[i] >> shift) & mask];
  });
  std::uint32_t run = 0;
  for (std::size_t d = 0; d < buckets; ++d)
    for (std::size_t c = 0; c < chunks; ++c) {
      const std::uint32_t t = hist[c * buckets + d];
      hist[c * buckets + d] = run;
      run += t;
    }
  forChunks(n, chunk, [&](std::size_t b, std::size_t e) {
    std::uint32_t* h = &hist[b / chunk * buckets];
    for (std::size_t i = b; i < e; ++i) {
      const std::uint32_t at = h[(keyIn[i] >> shift) & mask]++;
      keyOut[at] = keyIn[i];
      idOut[at] = idIn ? idIn[i] : static_cast<std::int32_t>(i);
    }
  });
}

template <class T>
void gatherBy(const std::vector<std::int32_t>& order, const T* byId, T* byRank) {
  forChunks(order.size(), kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t r = b; r < e; ++r) byRank[r] = byId[order[r]];
  });
}
template <class T>
void scatterBy(const std::vector<std::int32_t>& order, const T* byRank, T* byId) {
  forChunks(order.size(), kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t r = b; r < e; ++r) byId[order[r]] = byRank[r];
  });
}

}  // namespace

// ---- building --------------------------------------------------------------------

void NeighborGrid::build(const float* x, const float* y, const float* z, std::size_t n, float cellSize) {
  checkCount(n, "NeighborGrid::build");
  if (!(cellSize > 0.0f) || !std::isfinite(cellSize))
    throw RuntimeError("NeighborGrid::build: cell size " + std::to_string(cellSize) + " must be positive and finite");
  const float* const p[3] = {x, y, z};
  const Box box = boundsOf(p, n);
  cellSize_ = cellSize;
  binWidth_ = double(cellSize) * kBinMargin;
  origin_ = Vec3(box.lo[0], box.lo[1], box.lo[2]);
  const double inv = 1.0 / binWidth_;
  // Cell i along an axis holds q = (p - origin) / binWidth in [i, i+1). q is computed in
  // double from float inputs: monotone in p and within 2^-31 cells of exact below 2^21
  // cells, which the 2^-18 margin of binWidth absorbs.
  std::int64_t lo[3] = {0, 0, 0}, hi[3];
  const char axis[3] = {'x', 'y', 'z'};
  for (int a = 0; a < 3; ++a) {
    const double qMax = (double(box.hi[a]) - origin_[a]) * inv;
    if (!(qMax < double(kMaxAxisCells - 2)))
      throw RuntimeError("NeighborGrid::build: the points span " + std::to_string(qMax) + " cells of " +
                         std::to_string(cellSize) + " m along " + axis[a] + " (from " + std::to_string(box.lo[a]) +
                         " to " + std::to_string(box.hi[a]) + " m; at most 2^21 - 2): a particle has escaped " +
                         "or the cell size is too small");
    hi[a] = static_cast<std::int64_t>(qMax);
  }
  setKeySpace(lo, hi);
  keys_.resize(n);
  const double ox = origin_.x(), oy = origin_.y(), oz = origin_.z();
  const std::uint64_t dimX = dimX_, dimXY = dimXY_;
  forChunks(n, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      const auto kx = static_cast<std::uint64_t>((double(x[i]) - ox) * inv) + 1;
      const auto ky = static_cast<std::uint64_t>((double(y[i]) - oy) * inv) + 1;
      const auto kz = static_cast<std::uint64_t>((double(z[i]) - oz) * inv) + 1;
      keys_[i] = kx + dimX * ky + dimXY * kz;
    }
  });
  sortKeys((std::uint64_t(hi[2]) + 1) * dimXY + (std::uint64_t(hi[1]) + 1) * dimX + std::uint64_t(hi[0]) + 1);
  findCells();
  hasPositions_ = true;
  xs_.resize(n), ys_.resize(n), zs_.resize(n);
  gatherBy(order_, x, xs_.data());
  gatherBy(order_, y, ys_.data());
  gatherBy(order_, z, zs_.data());
  buildRows();
}

void NeighborGrid::buildFromCells(const std::int32_t* cx, const std::int32_t* cy, const std::int32_t* cz,
                                  std::size_t n) {
  checkCount(n, "NeighborGrid::buildFromCells");
  const std::int32_t* const c[3] = {cx, cy, cz};
  std::int64_t lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  for (int a = 0; a < 3 && n; ++a) {
    const auto mm = std::minmax_element(c[a], c[a] + n);
    lo[a] = *mm.first, hi[a] = *mm.second;
    if (hi[a] - lo[a] + 1 > kMaxAxisCells - 2)
      throw RuntimeError("NeighborGrid::buildFromCells: cells span " + std::to_string(hi[a] - lo[a] + 1) +
                         " along axis " + std::to_string(a) + " (at most 2^21 - 2)");
  }
  hasPositions_ = false;
  cellSize_ = 0.0f, binWidth_ = 0.0, origin_ = Vec3::Zero();
  setKeySpace(lo, hi);
  keys_.resize(n);
  const std::uint64_t dimX = dimX_, dimXY = dimXY_;
  forChunks(n, kParticleChunk, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i)
      keys_[i] = std::uint64_t(cx[i] - lo[0] + 1) + dimX * std::uint64_t(cy[i] - lo[1] + 1) +
                 dimXY * std::uint64_t(cz[i] - lo[2] + 1);
  });
  sortKeys((std::uint64_t(hi[2] - lo[2]) + 1) * dimXY + (std::uint64_t(hi[1] - lo[1]) + 1) * dimX +
           std::uint64_t(hi[0] - lo[0]) + 1);
  findCells();
  xs_.clear(), ys_.clear(), zs_.clear(), rows_.clear();
}

// Cell coordinates lo..hi per axis map to key digits 1..hi-lo+1; digits 0 and hi-lo+2
// are empty padding, so the rows around any cell need no bounds test.
void NeighborGrid::setKeySpace(const std::int64_t lo[3], const std::int64_t hi[3]) {
  for (int a = 0; a < 3; ++a) cellOffset_[a] = lo[a] - 1;
  dimX_ = std::uint64_t(hi[0] - lo[0] + 3);
  dimXY_ = dimX_ * std::uint64_t(hi[1] - lo[1] + 3);
}

// Stable LSD radix sort of keys_ (ids 0..n-1): order_ gets the ids in key order and
// keys_ the sorted keys. A stable sort has one result, so it is thread-count free.
void NeighborGrid::sortKeys(std::uint64_t maxKey) {
  const std::size_t n = keys_.size();
  const std::size_t chunk = std::max<std::size_t>(8192, chunkCount(n, kMaxSortChunks));
  const RadixPlan plan = planRadix(maxKey, n, chunkCount(n, chunk));
  sortPasses_ = plan.passes;
  keysTmp_.resize(n), idsTmp_.resize(n), order_.resize(n);
  // Alternate between the buffers so that the last pass writes order_.
  std::vector<std::int32_t>* ids[2] = {&order_, &idsTmp_};
  std::vector<std::uint64_t>* keys[2] = {&keys_, &keysTmp_};
  int src = 0, dst = plan.passes % 2 ? 0 : 1;  // ids: the last pass writes ids[0]
  const std::int32_t* idIn = nullptr;
  for (int pass = 0; pass < plan.passes; ++pass) {
    const int shift = pass * plan.bits;
    const std::uint64_t top = maxKey >> shift;
    const bool single = plan.passes == 1;
    const std::uint64_t mask = single ? ~std::uint64_t(0) : (std::uint64_t(1) << plan.bits) - 1;
    const std::size_t buckets = single ? std::size_t(maxKey) + 1 : std::size_t(std::min<std::uint64_t>(top, mask) + 1);
    countingPass(keys[src]->data(), idIn, keys[1 - src]->data(), ids[dst]->data(), n, shift, mask, buckets, chunk,
                 hist_);
    idIn = ids[dst]->data();
    src = 1 - src, dst = 1 - dst;
  }
  if (src == 1) keys_.swap(keysTmp_);
}

// rank_, the non-empty cells (cellStart_, cellKey_) and cellOfRank_ from the sorted keys.
void NeighborGrid::findCells() {
  const std::size_t n = keys_.size();
  rank_.resize(n), cellOfRank_.resize(n);
  const std::size_t units = chunkCount(n, kParticleChunk);
  std::vector<std::int32_t> firstCell(units + 1, 0);
  forChunks(n, kParticleChunk, [&](std::size_t b, std::size_t e) {
    std::int32_t starts = 0;
    for (std::size_t r = b; r < e; ++r) {
      rank_[order_[r]] = static_cast<std::int32_t>(r);
      starts += r == 0 || keys_[r] != keys_[r - 1];
    }
    firstCell[b / kParticleChunk + 1] = starts;
  });
  for (std::size_t u = 0; u < units; ++u) firstCell[u + 1] += firstCell[u];
  const std::size_t cells = std::size_t(firstCell[units]);
  cellStart_.resize(cells + 1), cellKey_.resize(cells);
  cellStart_[cells] = static_cast<std::int32_t>(n);
  forChunks(n, kParticleChunk, [&](std::size_t b, std::size_t e) {
    std::int32_t c = firstCell[b / kParticleChunk] - 1;
    for (std::size_t r = b; r < e; ++r) {
      if (r == 0 || keys_[r] != keys_[r - 1]) {
        ++c;
        cellStart_[std::size_t(c)] = static_cast<std::int32_t>(r);
        cellKey_[std::size_t(c)] = keys_[r];
      }
      cellOfRank_[r] = c;
    }
  });
}

// The 9 rows of every cell. For a fixed (dy, dz) the row's first key rises with the
// cell's key, so one forward walk over the sorted cell keys finds them all.
void NeighborGrid::buildRows() {
  const std::size_t cells = cellCount();
  rows_.resize(18 * cells);
  std::int64_t offset[9];
  for (int k = 0; k < 9; ++k)
    offset[k] = std::int64_t(k / 3 - 1) * std::int64_t(dimXY_) + std::int64_t(k % 3 - 1) * std::int64_t(dimX_) - 1;
  forChunks(cells, kCellChunk, [&](std::size_t b, std::size_t e) {
    for (int k = 0; k < 9; ++k) {
      const auto rowLo = [&](std::size_t c) { return cellKey_[c] + static_cast<std::uint64_t>(offset[k]); };
      std::size_t p = std::size_t(std::lower_bound(cellKey_.begin(), cellKey_.end(), rowLo(b)) - cellKey_.begin());
      for (std::size_t c = b; c < e; ++c) {
        const std::uint64_t lo = rowLo(c);
        while (p < cells && cellKey_[p] < lo) ++p;
        std::size_t q = p;
        while (q < cells && cellKey_[q] <= lo + 2) ++q;
        rows_[18 * c + 2 * k] = cellStart_[p];
        rows_[18 * c + 2 * k + 1] = cellStart_[q];
      }
    }
  });
}

Vec3i NeighborGrid::cellCoord(std::size_t c) const {
  const std::uint64_t key = cellKey_[c];
  const std::uint64_t dimY = dimXY_ / dimX_;
  return Vec3i(int(std::int64_t(key % dimX_) + cellOffset_[0]), int(std::int64_t(key / dimX_ % dimY) + cellOffset_[1]),
               int(std::int64_t(key / dimXY_) + cellOffset_[2]));
}

// ---- permutation helpers -----------------------------------------------------------

void NeighborGrid::gather(const float* byId, float* byRank) const { gatherBy(order_, byId, byRank); }
void NeighborGrid::gather(const double* byId, double* byRank) const { gatherBy(order_, byId, byRank); }
void NeighborGrid::gather(const std::int32_t* byId, std::int32_t* byRank) const { gatherBy(order_, byId, byRank); }
void NeighborGrid::scatter(const float* byRank, float* byId) const { scatterBy(order_, byRank, byId); }
void NeighborGrid::scatter(const double* byRank, double* byId) const { scatterBy(order_, byRank, byId); }
void NeighborGrid::scatter(const std::int32_t* byRank, std::int32_t* byId) const { scatterBy(order_, byRank, byId); }

// ---- queries -----------------------------------------------------------------------

void NeighborGrid::checkQuery(float radius) const {
  if (!hasPositions_)
    throw RuntimeError("NeighborGrid: neighbour queries need build() with positions, not buildFromCells()");
  const float r2 = radius * radius;
  if (!(radius > 0.0f) || !(radius <= cellSize_) || !std::isfinite(r2) || r2 < FLT_MIN)
    throw RuntimeError("NeighborGrid: query radius " + std::to_string(radius) + " m must be in (0, cellSize = " +
                       std::to_string(cellSize_) + " m] with a normal float square");
}

namespace {

// One cell's worth of list building: particles [ib, ie) (ranks) against the cell's rows.
struct CellJob {
  const float *xs, *ys, *zs;
  const std::int32_t* rows;  // 18 entries
  std::int32_t ib, ie;
  float r2;
  int width;
  std::int32_t* index;  // lists, n * width
  std::int32_t* count;  // n
  std::int32_t* tmp;    // room for all candidates + 16
};
struct ListStats {
  std::size_t overflowed = 0;
  std::int32_t maxCount = 0;
};

// Stores the first `width` of the cnt neighbours found for rank i; pads with i.
inline void storeList(const CellJob& job, std::int32_t i, std::int32_t cnt, ListStats& s) {
  const std::int32_t kept = std::min(cnt, job.width);
  std::int32_t* dst = job.index + std::size_t(i) * std::size_t(job.width);
  std::memcpy(dst, job.tmp, sizeof(std::int32_t) * std::size_t(kept));
  std::fill(dst + kept, dst + job.width, i);
  job.count[i] = kept;
  s.overflowed += cnt > job.width;
  s.maxCount = std::max(s.maxCount, cnt);
}

void listCellScalar(const CellJob& job, ListStats& s) {
  for (std::int32_t i = job.ib; i < job.ie; ++i) {
    const float xi = job.xs[i], yi = job.ys[i], zi = job.zs[i];
    std::int32_t cnt = 0;
    for (int k = 0; k < 9; ++k)
      for (std::int32_t j = job.rows[2 * k]; j < job.rows[2 * k + 1]; ++j) {
        const float dx = job.xs[j] - xi, dy = job.ys[j] - yi, dz = job.zs[j] - zi;
        job.tmp[cnt] = j;  // branch-free append
        cnt += ((dx * dx + dy * dy) + dz * dz <= job.r2) & (j != i);
      }
    storeList(job, i, cnt, s);
  }
}

// The same test 16 candidates at a time: the same IEEE operations in the same order
// (sub, mul, add, add; no FMA), the hits packed in order by a compress into a register
// and stored whole (a compress straight to memory is microcoded and slow on Zen 4).
__attribute__((target("avx512f,popcnt"))) void listCellAvx512(const CellJob& job, ListStats& s) {
  const __m512i lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512 r2 = _mm512_set1_ps(job.r2);
  for (std::int32_t i = job.ib; i < job.ie; ++i) {
    const __m512 xi = _mm512_set1_ps(job.xs[i]), yi = _mm512_set1_ps(job.ys[i]), zi = _mm512_set1_ps(job.zs[i]);
    const __m512i self = _mm512_set1_epi32(i);
    std::int32_t cnt = 0;
    for (int k = 0; k < 9; ++k) {
      const std::int32_t end = job.rows[2 * k + 1];
      for (std::int32_t j = job.rows[2 * k]; j < end; j += 16) {
        const __mmask16 in = end - j >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (end - j)) - 1);
        const __m512 dx = _mm512_sub_ps(_mm512_maskz_loadu_ps(in, job.xs + j), xi);
        const __m512 dy = _mm512_sub_ps(_mm512_maskz_loadu_ps(in, job.ys + j), yi);
        const __m512 dz = _mm512_sub_ps(_mm512_maskz_loadu_ps(in, job.zs + j), zi);
        const __m512 d2 = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(dx, dx), _mm512_mul_ps(dy, dy)), _mm512_mul_ps(dz, dz));
        const __m512i js = _mm512_add_epi32(_mm512_set1_epi32(j), lane);
        const __mmask16 hit = _mm512_mask_cmp_ps_mask(in, d2, r2, _CMP_LE_OQ) & _mm512_cmpneq_epi32_mask(js, self);
        _mm512_storeu_si512(job.tmp + cnt, _mm512_maskz_compress_epi32(hit, js));
        cnt += _mm_popcnt_u32(hit);
      }
    }
    storeList(job, i, cnt, s);
  }
}

}  // namespace

bool NeighborGrid::cpuHasAvx512() { return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("popcnt"); }

void NeighborGrid::buildNeighborLists(float radius, int width, NeighborLists& out, Kernel kernel) const {
  checkQuery(radius);
  if (width < 1) throw RuntimeError("NeighborGrid::buildNeighborLists: width " + std::to_string(width) + " must be >= 1");
  if (kernel == Kernel::kAvx512 && !cpuHasAvx512())
    throw RuntimeError("NeighborGrid::buildNeighborLists: this CPU has no AVX-512");
  const bool avx512 = kernel == Kernel::kAvx512 || (kernel == Kernel::kAuto && cpuHasAvx512());
  const std::size_t n = size(), cells = cellCount();
  out.width = width, out.radius = radius;
  out.index.resize(n * std::size_t(width));
  out.count.resize(n);
  std::vector<ListStats> stats(chunkCount(cells, kCellChunk));
  forChunks(cells, kCellChunk, [&](std::size_t b, std::size_t e) {
    std::vector<std::int32_t> tmp;
    ListStats& s = stats[b / kCellChunk];
    for (std::size_t c = b; c < e; ++c) {
      const std::int32_t* rows = &rows_[18 * c];
      std::size_t candidates = 0;
      for (int k = 0; k < 9; ++k) candidates += std::size_t(rows[2 * k + 1] - rows[2 * k]);
      if (tmp.size() < candidates + 16) tmp.resize(candidates + 16);
      const CellJob job{xs_.data(), ys_.data(), zs_.data(), rows, cellStart_[c], cellStart_[c + 1],
                        radius * radius, width, out.index.data(), out.count.data(), tmp.data()};
      avx512 ? listCellAvx512(job, s) : listCellScalar(job, s);
    }
  });
  out.overflowed = 0, out.maxCount = 0;
  for (const ListStats& s : stats) out.overflowed += s.overflowed, out.maxCount = std::max(out.maxCount, s.maxCount);
}

}  // namespace physketch
