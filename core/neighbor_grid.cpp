#include "core/neighbor_grid.h"

#include <immintrin.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <limits>

#include "core/parallel.h"
#include "core/profile.h"

namespace physketch {
namespace {

// Work is cut into fixed units whose boundaries depend only on the sizes, never on the
// thread count; each unit writes its own elements, so any schedule gives the same bits.
constexpr std::size_t kParticleChunk = 8192;  // particles per unit of the per-particle maps
constexpr std::size_t kCellChunk = 512;       // cells per unit of the row and list passes

std::size_t chunkCount(std::size_t n, std::size_t chunk) { return (n + chunk - 1) / chunk; }

void checkCount(std::size_t n, const char* who) {
  if (n > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
    throw RuntimeError(std::string(who) + ": " + std::to_string(n) + " particles (at most 2^31 - 1)");
}

// The bits of a float as an int32 that orders like the float: integer min/max loops
// vectorize where float ones (NaN rules) do not. The non-finite floats land at the ends:
// +inf and NaN at >= 0x7f800000, -inf and -NaN at <= -0x7f800001.
inline std::int32_t orderedBits(float f) {
  std::int32_t b;
  std::memcpy(&b, &f, sizeof b);
  return b ^ ((b >> 31) & 0x7fffffff);
}
inline float fromOrderedBits(std::int32_t o) {
  const std::int32_t b = o ^ ((o >> 31) & 0x7fffffff);
  float f;
  std::memcpy(&f, &b, sizeof f);
  return f;
}
constexpr std::int32_t kFiniteMax = 0x7f7fffff, kFiniteMin = -0x7f800000;  // orderedBits(+-FLT_MAX)

bool finite3(const float* const p[3], std::size_t i) {
  return std::isfinite(p[0][i]) && std::isfinite(p[1][i]) && std::isfinite(p[2][i]);
}

// Bounding box of the points; throws for a non-finite coordinate, naming the lowest id.
struct Box {
  float lo[3], hi[3];
};
Box boundsOf(const float* const p[3], std::size_t n) {
  const std::size_t units = chunkCount(n, kParticleChunk);
  std::vector<std::int32_t> lo(3 * units), hi(3 * units);
  forChunks(n, kParticleChunk, [&](std::size_t b, std::size_t e) {
    const std::size_t u = b / kParticleChunk;
    for (int a = 0; a < 3; ++a) {
      std::int32_t l = orderedBits(p[a][b]), h = l;
      for (std::size_t i = b; i < e; ++i) {
        const std::int32_t o = orderedBits(p[a][i]);
        l = std::min(l, o), h = std::max(h, o);
      }
      lo[3 * u + a] = l, hi[3 * u + a] = h;
    }
  });
  Box box{};
  for (std::size_t u = 0; u < units; ++u)
    for (int a = 0; a < 3; ++a) {
      if (lo[3 * u + a] < kFiniteMin || hi[3 * u + a] > kFiniteMax) {
        std::size_t i = u * kParticleChunk;
        while (finite3(p, i)) ++i;
        throw RuntimeError("NeighborGrid::build: particle " + std::to_string(i) + " has a non-finite position (" +
                           std::to_string(p[0][i]) + ", " + std::to_string(p[1][i]) + ", " +
                           std::to_string(p[2][i]) + ")");
      }
      box.lo[a] = fromOrderedBits(u ? std::min(orderedBits(box.lo[a]), lo[3 * u + a]) : lo[a]);
      box.hi[a] = fromOrderedBits(u ? std::max(orderedBits(box.hi[a]), hi[3 * u + a]) : hi[a]);
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

// A radix pass's chunks: a power of two up to 8 (so 1, 2, 4 or 8 threads share them
// evenly), about 32k particles or more each; one histogram per chunk.
std::size_t sortChunk(std::size_t n) {
  std::size_t chunks = 1;
  while (chunks < 8 && chunks * 32768 < n) chunks *= 2;
  return std::max<std::size_t>(1, chunkCount(n, chunks));
}

// One stable counting-sort pass of (key, id) by the digit (key >> shift) & mask, whose
// values are < buckets. idIn == nullptr means ids 0..n-1. Chunks count in parallel, one
// histogram each; a chunk's offsets for a digit follow those of the chunks before it,
// so equal digits keep their input order whatever the schedule. On return start[d] is
// the first output place of digit d (buckets + 1 entries). `carry`, when not null, moves
// three float arrays along with the ids (the positions, on the last pass: no gather).
struct Carry {
  const float* in[3];
  float* out[3];
};
void countingPass(const std::uint64_t* keyIn, const std::int32_t* idIn, std::uint64_t* keyOut,
                  std::int32_t* idOut, std::size_t n, int shift, std::uint64_t mask, std::size_t buckets,
                  std::vector<std::uint32_t>& hist, std::vector<std::uint32_t>& start, const Carry* carry) {
  const std::size_t chunk = sortChunk(n), chunks = chunkCount(n, chunk);
  hist.assign(chunks * buckets, 0);
  forChunks(n, chunk, [&](std::size_t b, std::size_t e) {
    std::uint32_t* h = &hist[b / chunk * buckets];
    for (std::size_t i = b; i < e; ++i) ++h[(keyIn[i] >> shift) & mask];
  });
  // Row by row (vectorizes): bucket totals, their exclusive scan, then each chunk's offsets.
  start.assign(buckets + 1, 0);
  for (std::size_t c = 0; c < chunks; ++c)
    for (std::size_t d = 0; d < buckets; ++d) start[d + 1] += hist[c * buckets + d];
  for (std::size_t d = 0; d < buckets; ++d) start[d + 1] += start[d];
  std::vector<std::uint32_t> run(start.begin(), start.end() - 1);
  for (std::size_t c = 0; c < chunks; ++c)
    for (std::size_t d = 0; d < buckets; ++d) {
      const std::uint32_t t = hist[c * buckets + d];
      hist[c * buckets + d] = run[d];
      run[d] += t;
    }
  forChunks(n, chunk, [&](std::size_t b, std::size_t e) {
    std::uint32_t* h = &hist[b / chunk * buckets];
    for (std::size_t i = b; i < e; ++i) {
      const std::uint32_t at = h[(keyIn[i] >> shift) & mask]++;
      const std::int32_t id = idIn ? idIn[i] : static_cast<std::int32_t>(i);
      keyOut[at] = keyIn[i];
      idOut[at] = id;
      if (carry)
        for (int a = 0; a < 3; ++a) carry->out[a][at] = carry->in[a][id];
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
  // Cell i along an axis holds q = (p - origin) * (1 / binWidth) in [i, i+1). q is
  // computed in double from float inputs: monotone in p and within 2^-31 cells of exact
  // below 2^21 cells, which the 2^-18 margin of binWidth absorbs.
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
    for (std::size_t i = b; i < e; ++i) {  // q < 2^21: int32 conversions (they vectorize)
      const std::int32_t kx = static_cast<std::int32_t>((double(x[i]) - ox) * inv) + 1;
      const std::int32_t ky = static_cast<std::int32_t>((double(y[i]) - oy) * inv) + 1;
      const std::int32_t kz = static_cast<std::int32_t>((double(z[i]) - oz) * inv) + 1;
      keys_[i] = std::uint64_t(kx) + dimX * std::uint64_t(ky) + dimXY * std::uint64_t(kz);
    }
  });
  sortKeys(x, y, z);
  findCells();
  hasPositions_ = true;
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
  sortKeys(nullptr, nullptr, nullptr);
  findCells();
  xs_.clear(), ys_.clear(), zs_.clear(), rows_.clear();
}

// Cell coordinates lo..hi per axis map to key digits 1..hi-lo+1; digits 0 and hi-lo+2
// are empty padding, so the rows around any cell need no bounds test.
void NeighborGrid::setKeySpace(const std::int64_t lo[3], const std::int64_t hi[3]) {
  for (int a = 0; a < 3; ++a) cellOffset_[a] = lo[a] - 1;
  dimX_ = std::uint64_t(hi[0] - lo[0] + 3);
  dimXY_ = dimX_ * std::uint64_t(hi[1] - lo[1] + 3);
  maxKey_ = dimXY_ * std::uint64_t(hi[2] - lo[2] + 3) - 1;  // the last padding key
}

// Stable LSD radix sort of keys_ (ids 0..n-1): order_ gets the ids in key order, keys_
// the sorted keys and xs_, ys_, zs_ the positions x, y, z in that order (when given).
// A stable sort has one result, so it is thread-count free.
void NeighborGrid::sortKeys(const float* x, const float* y, const float* z) {
  const std::size_t n = keys_.size();
  if (x) xs_.resize(n), ys_.resize(n), zs_.resize(n);
  const Carry positions{{x, y, z}, {xs_.data(), ys_.data(), zs_.data()}};
  const Carry* carry = x ? &positions : nullptr;
  const RadixPlan plan = planRadix(maxKey_, n, chunkCount(n, sortChunk(n)));
  sortPasses_ = plan.passes;
  keysTmp_.resize(n), idsTmp_.resize(n), order_.resize(n);
  // Alternate between the buffers so that the last pass writes order_.
  std::vector<std::int32_t>* ids[2] = {&order_, &idsTmp_};
  std::vector<std::uint64_t>* keys[2] = {&keys_, &keysTmp_};
  int src = 0, dst = plan.passes % 2 ? 0 : 1;  // ids: the last pass writes ids[0]
  const std::int32_t* idIn = nullptr;
  for (int pass = 0; pass < plan.passes; ++pass) {
    const int shift = pass * plan.bits;
    const bool single = plan.passes == 1;
    const std::uint64_t mask = single ? ~std::uint64_t(0) : (std::uint64_t(1) << plan.bits) - 1;
    const std::size_t buckets = std::size_t(std::min(maxKey_ >> shift, mask)) + 1;
    countingPass(keys[src]->data(), idIn, keys[1 - src]->data(), ids[dst]->data(), n, shift, mask, buckets, hist_,
                 keyStart_, pass + 1 == plan.passes ? carry : nullptr);
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

// The 9 rows of every cell: row (dy, dz) holds the keys lo .. lo + 2 with
// lo = key + dy * dimX + dz * dimXY - 1, i.e. the ranks [first rank with key >= lo,
// first rank with key > lo + 2). After a one-pass sort keyStart_ answers that directly;
// after several passes a forward walk over the sorted cell keys does (for a fixed
// (dy, dz), lo rises with the cell's key).
void NeighborGrid::buildRows() {
  const std::size_t cells = cellCount();
  rows_.resize(18 * cells);
  std::uint64_t offset[9];  // lo - key, modulo 2^64 (the padding keeps lo >= 0)
  for (int k = 0; k < 9; ++k)
    offset[k] = std::uint64_t(std::int64_t(k / 3 - 1) * std::int64_t(dimXY_) +
                              std::int64_t(k % 3 - 1) * std::int64_t(dimX_) - 1);
  if (sortPasses_ == 1) {
    forChunks(cells, kCellChunk, [&](std::size_t b, std::size_t e) {
      for (std::size_t c = b; c < e; ++c)
        for (int k = 0; k < 9; ++k) {
          const std::uint64_t lo = cellKey_[c] + offset[k];  // <= maxKey_ - 2: padding
          rows_[18 * c + 2 * k] = std::int32_t(keyStart_[lo]);
          rows_[18 * c + 2 * k + 1] = std::int32_t(keyStart_[lo + 3]);
        }
    });
    return;
  }
  forChunks(cells, kCellChunk, [&](std::size_t b, std::size_t e) {
    for (int k = 0; k < 9; ++k) {
      const auto rowLo = [&](std::size_t c) { return cellKey_[c] + offset[k]; };
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

// The candidates of one cell: its 9 rows copied into contiguous arrays, shared by all
// the particles of the cell, padded to whole vectors with points at infinity (never
// within any radius), so the inner loop runs on full vectors without tail masks.
struct Candidates {
  std::vector<float> x, y, z;
  std::vector<std::int32_t> rank;
  std::int32_t count = 0;   // real candidates
  std::int32_t padded = 0;  // count rounded up to a multiple of 16

  void fill(const float* xs, const float* ys, const float* zs, const std::int32_t* rows) {
    count = 0;
    for (int k = 0; k < 9; ++k) count += rows[2 * k + 1] - rows[2 * k];
    padded = (count + 15) / 16 * 16;
    if (x.size() < std::size_t(padded)) x.resize(padded), y.resize(padded), z.resize(padded), rank.resize(padded);
    float *cx = x.data(), *cy = y.data(), *cz = z.data();
    std::int32_t* cr = rank.data();
    std::int32_t m = 0;
    for (int k = 0; k < 9; ++k) {
      const std::int32_t b = rows[2 * k], len = rows[2 * k + 1] - b;
      std::memcpy(cx + m, xs + b, sizeof(float) * std::size_t(len));
      std::memcpy(cy + m, ys + b, sizeof(float) * std::size_t(len));
      std::memcpy(cz + m, zs + b, sizeof(float) * std::size_t(len));
      for (std::int32_t t = 0; t < len; ++t) cr[m + t] = b + t;
      m += len;
    }
    std::fill(cx + m, cx + padded, std::numeric_limits<float>::infinity());
    std::fill(cy + m, cy + padded, 0.0f);
    std::fill(cz + m, cz + padded, 0.0f);
    std::fill(cr + m, cr + padded, -1);
  }
};

// One cell's worth of list building: particles [ib, ie) (ranks) against its candidates.
struct CellJob {
  const float *xs, *ys, *zs;
  const Candidates* cand;
  std::int32_t ib, ie;
  float r2;
  int width;
  std::int32_t* index;  // lists, n * width
  std::int32_t* count;  // n
  std::int32_t* tmp;    // room for 2 * cand->padded + 16 entries (two particles' hits)
};
struct ListStats {
  std::size_t overflowed = 0;
  std::int32_t maxCount = 0;
};

// Stores the first `width` of the cnt neighbours found for rank i; pads with i. (memcpy
// + fill measured 25 % faster for the whole list build than one select loop.)
inline void storeList(const CellJob& job, std::int32_t i, std::int32_t cnt, ListStats& s) {
  const std::int32_t kept = std::min(cnt, job.width);
  std::int32_t* dst = job.index + std::size_t(i) * std::size_t(job.width);
  const std::int32_t* src = job.tmp;
  std::memcpy(dst, src, sizeof(std::int32_t) * std::size_t(kept));
  std::fill(dst + kept, dst + job.width, i);
  job.count[i] = kept;
  s.overflowed += cnt > job.width;
  s.maxCount = std::max(s.maxCount, cnt);
}

void listCellScalar(const CellJob& job, ListStats& s) {
  const float *cx = job.cand->x.data(), *cy = job.cand->y.data(), *cz = job.cand->z.data();
  const std::int32_t* cr = job.cand->rank.data();
  const std::int32_t count = job.cand->count;
  std::int32_t* tmp = job.tmp;
  for (std::int32_t i = job.ib; i < job.ie; ++i) {
    const float xi = job.xs[i], yi = job.ys[i], zi = job.zs[i];
    std::int32_t cnt = 0;
    for (std::int32_t k = 0; k < count; ++k) {
      const float dx = cx[k] - xi, dy = cy[k] - yi, dz = cz[k] - zi;
      tmp[cnt] = cr[k];  // branch-free append
      cnt += ((dx * dx + dy * dy) + dz * dz <= job.r2) & (cr[k] != i);
    }
    storeList(job, i, cnt, s);
  }
}

// The same test 16 candidates at a time: the same IEEE operations in the same order
// (sub, mul, add, add; no FMA), the hits packed in order by a compress into a register
// and stored whole (a compress straight to memory is microcoded and slow on Zen 4).
#define PHYSKETCH_AVX512 __attribute__((target("avx512f,popcnt"), always_inline)) inline

struct Probe512 {  // one particle, broadcast
  __m512 x, y, z;
  __m512i self;
};
PHYSKETCH_AVX512 Probe512 probe512(const CellJob& job, std::int32_t i) {
  return {_mm512_set1_ps(job.xs[i]), _mm512_set1_ps(job.ys[i]), _mm512_set1_ps(job.zs[i]), _mm512_set1_epi32(i)};
}
// Appends to out[cnt..] the candidates js (at px, py, pz) within r2 of p; returns the new cnt.
PHYSKETCH_AVX512 std::int32_t appendHits512(const Probe512& p, __m512 px, __m512 py, __m512 pz, __m512i js, __m512 r2,
                                            std::int32_t* out, std::int32_t cnt) {
  const __m512 dx = _mm512_sub_ps(px, p.x), dy = _mm512_sub_ps(py, p.y), dz = _mm512_sub_ps(pz, p.z);
  const __m512 d2 = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(dx, dx), _mm512_mul_ps(dy, dy)), _mm512_mul_ps(dz, dz));
  const __mmask16 hit = _mm512_cmp_ps_mask(d2, r2, _CMP_LE_OQ) & _mm512_cmpneq_epi32_mask(js, p.self);
  _mm512_storeu_si512(out + cnt, _mm512_maskz_compress_epi32(hit, js));
  return cnt + std::int32_t(_mm_popcnt_u32(hit));
}

// Two particles per sweep over the candidates share its loads (~15 % faster than one).
__attribute__((target("avx512f,popcnt"))) void listCellAvx512(const CellJob& job, ListStats& s) {
  // Raw pointers: through the vectors the compiler reloads them after every store.
  const float *cx = job.cand->x.data(), *cy = job.cand->y.data(), *cz = job.cand->z.data();
  const std::int32_t* cr = job.cand->rank.data();
  const std::int32_t padded = job.cand->padded;
  CellJob second = job;
  second.tmp = job.tmp + padded + 16;
  const __m512 r2 = _mm512_set1_ps(job.r2);
  std::int32_t i = job.ib;
  for (; i + 1 < job.ie; i += 2) {
    const Probe512 a = probe512(job, i), b = probe512(job, i + 1);
    std::int32_t na = 0, nb = 0;
    for (std::int32_t k = 0; k < padded; k += 16) {
      const __m512 px = _mm512_loadu_ps(cx + k), py = _mm512_loadu_ps(cy + k), pz = _mm512_loadu_ps(cz + k);
      const __m512i js = _mm512_loadu_si512(cr + k);
      na = appendHits512(a, px, py, pz, js, r2, job.tmp, na);
      nb = appendHits512(b, px, py, pz, js, r2, second.tmp, nb);
    }
    storeList(job, i, na, s);
    storeList(second, i + 1, nb, s);
  }
  if (i < job.ie) {
    const Probe512 a = probe512(job, i);
    std::int32_t na = 0;
    for (std::int32_t k = 0; k < padded; k += 16)
      na = appendHits512(a, _mm512_loadu_ps(cx + k), _mm512_loadu_ps(cy + k), _mm512_loadu_ps(cz + k),
                         _mm512_loadu_si512(cr + k), r2, job.tmp, na);
    storeList(job, i, na, s);
  }
}
#undef PHYSKETCH_AVX512

// The AVX2 form, 8 candidates at a time. AVX2 has no compress: a table gives, for each
// 8-bit hit mask, the lanes to pack (3 bits each), expanded by variable shifts.
struct PackTable {
  std::uint32_t lanes[256];
  constexpr PackTable() : lanes() {
    for (int m = 0; m < 256; ++m) {
      std::uint32_t packed = 0;
      for (int lane = 0, k = 0; lane < 8; ++lane)
        if (m >> lane & 1) packed |= std::uint32_t(lane) << (4 * k++);
      lanes[m] = packed;
    }
  }
};
constexpr PackTable kPack;

#define PHYSKETCH_AVX2 __attribute__((target("avx2,popcnt"), always_inline)) inline

struct Probe256 {  // one particle, broadcast
  __m256 x, y, z;
  __m256i self;
};
PHYSKETCH_AVX2 Probe256 probe256(const CellJob& job, std::int32_t i) {
  return {_mm256_set1_ps(job.xs[i]), _mm256_set1_ps(job.ys[i]), _mm256_set1_ps(job.zs[i]), _mm256_set1_epi32(i)};
}
PHYSKETCH_AVX2 std::int32_t appendHits256(const Probe256& p, __m256 px, __m256 py, __m256 pz, __m256i js, __m256 r2,
                                          std::int32_t* out, std::int32_t cnt) {
  const __m256 dx = _mm256_sub_ps(px, p.x), dy = _mm256_sub_ps(py, p.y), dz = _mm256_sub_ps(pz, p.z);
  const __m256 d2 = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)), _mm256_mul_ps(dz, dz));
  const int within = _mm256_movemask_ps(_mm256_cmp_ps(d2, r2, _CMP_LE_OQ));
  const int self = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(js, p.self)));
  const unsigned hit = unsigned(within & ~self);
  const __m256i shifts = _mm256_setr_epi32(0, 4, 8, 12, 16, 20, 24, 28);
  const __m256i lanes = _mm256_and_si256(_mm256_srlv_epi32(_mm256_set1_epi32(int(kPack.lanes[hit])), shifts),
                                         _mm256_set1_epi32(7));
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + cnt), _mm256_permutevar8x32_epi32(js, lanes));
  return cnt + std::int32_t(_mm_popcnt_u32(hit));
}

__attribute__((target("avx2,popcnt"))) void listCellAvx2(const CellJob& job, ListStats& s) {
  const float *cx = job.cand->x.data(), *cy = job.cand->y.data(), *cz = job.cand->z.data();
  const std::int32_t* cr = job.cand->rank.data();
  const std::int32_t padded = job.cand->padded;
  CellJob second = job;
  second.tmp = job.tmp + padded + 16;
  const __m256 r2 = _mm256_set1_ps(job.r2);
  std::int32_t i = job.ib;
  for (; i + 1 < job.ie; i += 2) {
    const Probe256 a = probe256(job, i), b = probe256(job, i + 1);
    std::int32_t na = 0, nb = 0;
    for (std::int32_t k = 0; k < padded; k += 8) {
      const __m256 px = _mm256_loadu_ps(cx + k), py = _mm256_loadu_ps(cy + k), pz = _mm256_loadu_ps(cz + k);
      const __m256i js = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(cr + k));
      na = appendHits256(a, px, py, pz, js, r2, job.tmp, na);
      nb = appendHits256(b, px, py, pz, js, r2, second.tmp, nb);
    }
    storeList(job, i, na, s);
    storeList(second, i + 1, nb, s);
  }
  if (i < job.ie) {
    const Probe256 a = probe256(job, i);
    std::int32_t na = 0;
    for (std::int32_t k = 0; k < padded; k += 8)
      na = appendHits256(a, _mm256_loadu_ps(cx + k), _mm256_loadu_ps(cy + k), _mm256_loadu_ps(cz + k),
                         _mm256_loadu_si256(reinterpret_cast<const __m256i*>(cr + k)), r2, job.tmp, na);
    storeList(job, i, na, s);
  }
}
#undef PHYSKETCH_AVX2

}  // namespace

bool NeighborGrid::cpuHas(Kernel kernel) {
  switch (kernel) {
    case Kernel::kAvx512: return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("popcnt");
    case Kernel::kAvx2: return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("popcnt");
    default: return true;
  }
}

void NeighborGrid::buildNeighborLists(float radius, int width, NeighborLists& out, Kernel kernel) const {
  checkQuery(radius);
  if (width < 1) throw RuntimeError("NeighborGrid::buildNeighborLists: width " + std::to_string(width) + " must be >= 1");
  if (!cpuHas(kernel)) throw RuntimeError("NeighborGrid::buildNeighborLists: this CPU lacks the requested SIMD kernel");
  if (kernel == Kernel::kAuto)
    kernel = cpuHas(Kernel::kAvx512) ? Kernel::kAvx512 : cpuHas(Kernel::kAvx2) ? Kernel::kAvx2 : Kernel::kScalar;
  void (*const listCell)(const CellJob&, ListStats&) = kernel == Kernel::kAvx512 ? listCellAvx512
                                                       : kernel == Kernel::kAvx2 ? listCellAvx2
                                                                                 : listCellScalar;
  const std::size_t n = size(), cells = cellCount();
  out.width = width, out.radius = radius;
  out.index.resize(n * std::size_t(width));
  out.count.resize(n);
  std::vector<ListStats> stats(chunkCount(cells, kCellChunk));
  forChunks(cells, kCellChunk, [&](std::size_t b, std::size_t e) {
    Candidates cand;
    std::vector<std::int32_t> tmp;
    ListStats& s = stats[b / kCellChunk];
    for (std::size_t c = b; c < e; ++c) {
      cand.fill(xs_.data(), ys_.data(), zs_.data(), &rows_[18 * c]);
      if (tmp.size() < 2 * std::size_t(cand.padded) + 16) tmp.resize(2 * std::size_t(cand.padded) + 16);
      const CellJob job{xs_.data(), ys_.data(), zs_.data(), &cand, cellStart_[c], cellStart_[c + 1],
                        radius * radius, width, out.index.data(), out.count.data(), tmp.data()};
      listCell(job, s);
    }
  });
  out.overflowed = 0, out.maxCount = 0;
  for (const ListStats& s : stats) out.overflowed += s.overflowed, out.maxCount = std::max(out.maxCount, s.maxCount);
}

std::size_t NeighborGrid::heldBytes() const {
  return physketch::heldBytes(order_, rank_, cellStart_, cellKey_, cellOfRank_, xs_, ys_, zs_, rows_, keys_, keysTmp_,
                              idsTmp_, hist_, keyStart_);
}

}  // namespace physketch
