// The neighbour grid against independent oracles: an O(n^2) brute-force search with the
// documented float test, a std::stable_sort of ids by the documented cell formula,
// closed-form counts on a lattice, and 1 vs 2 threads compared bit for bit.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <tuple>
#include <vector>

#include <tbb/global_control.h>

#include "core/neighbor_grid.h"

using namespace physketch;

namespace {

struct Cloud {
  std::vector<float> x, y, z;
  std::size_t size() const { return x.size(); }
  void add(float px, float py, float pz) { x.push_back(px), y.push_back(py), z.push_back(pz); }
};

Cloud uniform(std::size_t n, float side, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-0.5f * side, 0.5f * side);
  Cloud c;
  for (std::size_t i = 0; i < n; ++i) {
    const float a = u(rng), b = u(rng);
    c.add(a, b, u(rng));
  }
  return c;
}

// A few tight Gaussian blobs: many particles per cell, many empty cells between.
Cloud clustered(std::size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> centre(-1.0f, 1.0f);
  std::normal_distribution<float> spread(0.0f, 0.03f);
  float cx[5], cy[5], cz[5];
  for (int k = 0; k < 5; ++k) cx[k] = centre(rng), cy[k] = centre(rng), cz[k] = centre(rng);
  Cloud c;
  for (std::size_t i = 0; i < n; ++i) {
    const int k = int(i % 5);
    const float a = cx[k] + spread(rng), b = cy[k] + spread(rng);
    c.add(a, b, cz[k] + spread(rng));
  }
  return c;
}

// The documented neighbour test, evaluated on every pair.
bool within(const Cloud& c, std::size_t i, std::size_t j, float radius) {
  const float dx = c.x[j] - c.x[i], dy = c.y[j] - c.y[i], dz = c.z[j] - c.z[i];
  return (dx * dx + dy * dy) + dz * dz <= radius * radius;
}

std::vector<std::vector<std::int32_t>> bruteForce(const Cloud& c, float radius) {
  std::vector<std::vector<std::int32_t>> nb(c.size());
  for (std::size_t i = 0; i < c.size(); ++i)
    for (std::size_t j = 0; j < c.size(); ++j)
      if (j != i && within(c, i, j, radius)) nb[i].push_back(std::int32_t(j));
  return nb;
}

// The cell of a point as the header defines it: floor((p - origin) / binWidth) with the
// bounding-box minimum as origin, computed here from the inputs alone.
std::vector<std::tuple<long, long, long>> expectedCells(const Cloud& c, float cellSize) {
  const double inv = 1.0 / (double(cellSize) * NeighborGrid::kBinMargin);
  const double ox = *std::min_element(c.x.begin(), c.x.end());
  const double oy = *std::min_element(c.y.begin(), c.y.end());
  const double oz = *std::min_element(c.z.begin(), c.z.end());
  std::vector<std::tuple<long, long, long>> cell;
  for (std::size_t i = 0; i < c.size(); ++i)
    cell.emplace_back(long(std::floor((c.z[i] - oz) * inv)), long(std::floor((c.y[i] - oy) * inv)),
                      long(std::floor((c.x[i] - ox) * inv)));  // (z, y, x): x fastest
  return cell;
}

// The order must be the ids stable-sorted by cell, x fastest; the cells must match.
void expectCellOrder(const NeighborGrid& g, const Cloud& c, float cellSize) {
  const auto cell = expectedCells(c, cellSize);
  std::vector<std::int32_t> ids(c.size());
  for (std::size_t i = 0; i < ids.size(); ++i) ids[i] = std::int32_t(i);
  std::stable_sort(ids.begin(), ids.end(), [&](std::int32_t a, std::int32_t b) { return cell[a] < cell[b]; });
  ASSERT_EQ(g.order(), ids);
  for (std::size_t r = 0; r < ids.size(); ++r) {
    ASSERT_EQ(g.rankOf(ids[r]), std::int32_t(r));
    const Vec3i cc = g.cellCoord(std::size_t(g.cellOfRank(std::int32_t(r))));
    ASSERT_EQ(std::make_tuple(long(cc.z()), long(cc.y()), long(cc.x())), cell[ids[r]]) << "rank " << r;
    ASSERT_GE(std::int32_t(r), g.cellBegin(std::size_t(g.cellOfRank(std::int32_t(r)))));
    ASSERT_LT(std::int32_t(r), g.cellEnd(std::size_t(g.cellOfRank(std::int32_t(r)))));
  }
  // Non-empty cells only, each a distinct cell.
  for (std::size_t k = 0; k < g.cellCount(); ++k) {
    ASSERT_LT(g.cellBegin(k), g.cellEnd(k));
    if (k) {
      ASSERT_NE(g.cellCoord(k), g.cellCoord(k - 1));
    }
  }
}

// forEachNeighbor and both list kernels against the brute force.
void expectNeighbors(const NeighborGrid& g, const Cloud& c, float radius) {
  const auto expected = bruteForce(c, radius);
  std::size_t most = 1;
  for (const auto& e : expected) most = std::max(most, e.size());
  for (NeighborGrid::Kernel kernel :
       {NeighborGrid::Kernel::kScalar, NeighborGrid::Kernel::kAvx2, NeighborGrid::Kernel::kAvx512}) {
    if (!NeighborGrid::cpuHas(kernel)) continue;  // a CPU without it cannot run it
    NeighborLists lists;
    g.buildNeighborLists(radius, int(most), lists, kernel);
    EXPECT_EQ(lists.overflowed, 0u);
    std::size_t maxCount = 0;
    for (std::size_t i = 0; i < c.size(); ++i) {
      const std::int32_t r = g.rankOf(std::int32_t(i));
      std::vector<std::int32_t> got;
      for (std::int32_t k = 0; k < lists.count[r]; ++k) {
        const std::int32_t j = lists.index[std::size_t(r) * most + k];
        if (k) {
          ASSERT_LT(lists.index[std::size_t(r) * most + k - 1], j) << "rows ascend by rank";
        }
        got.push_back(g.order()[j]);
      }
      for (std::size_t k = std::size_t(lists.count[r]); k < most; ++k) ASSERT_EQ(lists.index[r * most + k], r);
      std::sort(got.begin(), got.end());
      ASSERT_EQ(got, expected[i]) << "lists, particle " << i;
      maxCount = std::max(maxCount, expected[i].size());
    }
    EXPECT_EQ(std::size_t(lists.maxCount), maxCount);
  }
  for (std::size_t i = 0; i < c.size(); ++i) {
    std::vector<std::int32_t> got;
    std::int32_t lastRank = -1;
    g.forEachNeighbor(std::int32_t(i), radius, [&](std::int32_t j) {
      EXPECT_LT(lastRank, g.rankOf(j)) << "visits ascend by rank";
      lastRank = g.rankOf(j);
      got.push_back(j);
    });
    std::sort(got.begin(), got.end());
    ASSERT_EQ(got, expected[i]) << "forEachNeighbor, particle " << i;
  }
}

void expectAll(const Cloud& c, float cellSize, float radius) {
  NeighborGrid g;
  g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), cellSize);
  ASSERT_EQ(g.size(), c.size());
  expectCellOrder(g, c, cellSize);
  expectNeighbors(g, c, radius);
}

}  // namespace

TEST(NeighborGrid, UniformRandomMatchesBruteForce) {
  const Cloud c = uniform(3000, 1.0f, 1);
  expectAll(c, 0.1f, 0.1f);    // radius = cell size: the 27 cells just suffice
  expectAll(c, 0.1f, 0.063f);  // smaller radius
}

TEST(NeighborGrid, ClusteredMatchesBruteForce) { expectAll(clustered(2500, 2), 0.05f, 0.05f); }

TEST(NeighborGrid, AllPointsInOneCell) {
  const Cloud c = uniform(200, 0.05f, 3);
  NeighborGrid g;
  g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), 1.0f);
  EXPECT_EQ(g.cellCount(), 1u);
  expectCellOrder(g, c, 1.0f);
  expectNeighbors(g, c, 1.0f);  // every other point: 199 each
}

TEST(NeighborGrid, OnePointHasNoNeighbours) {
  Cloud c;
  c.add(0.3f, -2.0f, 7.0f);
  NeighborGrid g;
  g.build(c.x.data(), c.y.data(), c.z.data(), 1, 0.1f);
  EXPECT_EQ(g.cellCount(), 1u);
  EXPECT_EQ(g.order(), std::vector<std::int32_t>{0});
  NeighborLists lists;
  g.buildNeighborLists(0.1f, 4, lists);
  EXPECT_EQ(lists.count, std::vector<std::int32_t>{0});
  EXPECT_EQ(lists.index, std::vector<std::int32_t>(4, 0));
  int visits = 0;
  g.forEachNeighbor(0, 0.1f, [&](std::int32_t) { ++visits; });
  EXPECT_EQ(visits, 0);
}

TEST(NeighborGrid, ZeroPoints) {
  NeighborGrid g;
  g.build(nullptr, nullptr, nullptr, 0, 0.1f);
  EXPECT_EQ(g.size(), 0u);
  EXPECT_EQ(g.cellCount(), 0u);
  NeighborLists lists;
  g.buildNeighborLists(0.1f, 8, lists);
  EXPECT_TRUE(lists.index.empty());
  EXPECT_EQ(lists.overflowed, 0u);
  EXPECT_EQ(lists.maxCount, 0);
}

// A lattice of spacing = radius = cell size, exact in binary: the axis neighbours lie
// at exactly the radius (included), the diagonal ones at sqrt(2) radius (excluded). So a
// point has one neighbour per lattice direction it is not at the end of: 6 inside, 3 in
// a corner (closed form, not the brute force).
TEST(NeighborGrid, LatticeAtExactlyTheRadius) {
  const float s = 0.125f;
  const int m = 9;
  Cloud c;
  for (int k = 0; k < m; ++k)
    for (int j = 0; j < m; ++j)
      for (int i = 0; i < m; ++i) c.add(1.0f + s * i, s * j, -2.0f + s * k);
  NeighborGrid g;
  g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), s);
  NeighborLists lists;
  g.buildNeighborLists(s, 8, lists);
  EXPECT_EQ(lists.overflowed, 0u);
  EXPECT_EQ(lists.maxCount, 6);
  for (int k = 0; k < m; ++k)
    for (int j = 0; j < m; ++j)
      for (int i = 0; i < m; ++i) {
        const auto inner = [&](int a) { return (a > 0) + (a < m - 1); };
        const std::int32_t id = (k * m + j) * m + i;
        ASSERT_EQ(lists.count[g.rankOf(id)], inner(i) + inner(j) + inner(k)) << i << " " << j << " " << k;
      }
  expectNeighbors(g, c, s);
}

// Points on and one float step either side of the cell boundaries, at radius = cell
// size: pairs at and around the radius straddle two boundaries.
TEST(NeighborGrid, PointsOnCellBoundaries) {
  const float cell = 0.1f;
  const double w = double(cell) * NeighborGrid::kBinMargin;
  const double origin = 0.2f;  // the smallest coordinate below
  std::vector<float> v;
  for (int k = 0; k < 5; ++k) {
    const float b = float(origin + k * w);
    for (float p : {std::nextafter(b, -1.0f), b, std::nextafter(b, 2.0f)})
      if (p >= 0.2f) v.push_back(p);
    v.push_back(float(origin + k * w + cell));  // partner one cell size away
  }
  Cloud c;
  for (float a : v)
    for (float b : v)
      for (float d : v) c.add(a, b, d);
  expectAll(c, cell, cell);
}

// Without the bin margin this pair would be two cells apart although the float test
// accepts it: x_j - x_i = 1 + 2^-24 rounds to 1 = radius.
TEST(NeighborGrid, RoundedPairAtTheRadiusIsFound) {
  Cloud c;
  c.add(0.0f, 0.0f, 0.0f);  // sets the origin
  c.add(1.0f - std::ldexp(1.0f, -24), 0.0f, 0.0f);
  c.add(2.0f, 0.0f, 0.0f);
  ASSERT_TRUE(within(c, 1, 2, 1.0f));
  expectAll(c, 1.0f, 1.0f);
}

// One particle 1 km away: 10^5 cells of 1 cm along x, too many to count densely, so
// the sort takes several radix passes; the results must not change.
TEST(NeighborGrid, FarParticleTakesMoreRadixPassesSameResult) {
  Cloud c = uniform(2000, 0.2f, 4);
  c.add(1000.0f, 0.0f, 0.0f);
  c.add(1000.005f, 0.0f, 0.0f);
  NeighborGrid g;
  g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), 0.01f);
  EXPECT_GT(g.sortPasses(), 1);
  expectCellOrder(g, c, 0.01f);
  expectNeighbors(g, c, 0.01f);
}

TEST(NeighborGrid, TooManyCellsAlongAnAxisIsAnError) {
  Cloud c = uniform(100, 0.2f, 5);
  c.add(0.0f, 1e5f, 0.0f);  // 10^7 cells of 1 cm along y > 2^21
  NeighborGrid g;
  try {
    g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), 0.01f);
    FAIL() << "no error";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("along y"), std::string::npos) << e.what();
  }
}

TEST(NeighborGrid, OverflowIsReportedNotDropped) {
  const Cloud c = uniform(2000, 0.5f, 6);
  const float radius = 0.08f;
  const auto expected = bruteForce(c, radius);
  const int width = 4;
  std::size_t over = 0, most = 0;
  for (const auto& e : expected) over += e.size() > std::size_t(width), most = std::max(most, e.size());
  ASSERT_GT(over, 0u);
  NeighborGrid g;
  g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), 0.1f);
  NeighborLists lists;
  g.buildNeighborLists(radius, width, lists);
  EXPECT_EQ(lists.overflowed, over);
  EXPECT_EQ(std::size_t(lists.maxCount), most);
  for (std::size_t i = 0; i < c.size(); ++i) {
    const std::int32_t r = g.rankOf(std::int32_t(i));
    ASSERT_EQ(std::size_t(lists.count[r]), std::min(expected[i].size(), std::size_t(width)));
    for (std::int32_t k = 0; k < lists.count[r]; ++k) {
      const std::int32_t j = g.order()[lists.index[std::size_t(r) * width + k]];
      ASSERT_TRUE(std::binary_search(expected[i].begin(), expected[i].end(), j));
    }
  }
}

TEST(NeighborGrid, GatherScatterRoundTrip) {
  const Cloud c = clustered(5000, 7);
  NeighborGrid g;
  g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), 0.05f);
  std::vector<float> byRank(c.size()), back(c.size());
  g.gather(c.y.data(), byRank.data());
  for (std::size_t r = 0; r < c.size(); ++r) ASSERT_EQ(byRank[r], c.y[g.order()[r]]);
  EXPECT_TRUE(std::equal(byRank.begin(), byRank.end(), g.sortedY()));
  g.scatter(byRank.data(), back.data());
  EXPECT_EQ(back, c.y);
  std::vector<std::int32_t> ids(c.size()), idsByRank(c.size()), idsBack(c.size());
  for (std::size_t i = 0; i < ids.size(); ++i) ids[i] = std::int32_t(3 * i + 1);
  g.gather(ids.data(), idsByRank.data());
  g.scatter(idsByRank.data(), idsBack.data());
  EXPECT_EQ(idsBack, ids);
  std::vector<double> d(c.size()), dByRank(c.size()), dBack(c.size());
  for (std::size_t i = 0; i < d.size(); ++i) d[i] = 0.5 * double(i);
  g.gather(d.data(), dByRank.data());
  g.scatter(dByRank.data(), dBack.data());
  EXPECT_EQ(dBack, d);
}

// The MPM block sort: ids stable-sorted by the given integer cells, x fastest.
TEST(NeighborGrid, BuildFromCellsIsAStableSortByCell) {
  std::mt19937 rng(8);
  std::uniform_int_distribution<std::int32_t> u(-7, 5);
  const std::size_t n = 30000;
  std::vector<std::int32_t> cx(n), cy(n), cz(n);
  for (std::size_t i = 0; i < n; ++i) cx[i] = u(rng), cy[i] = u(rng) * 3, cz[i] = u(rng) - 100;
  NeighborGrid g;
  g.buildFromCells(cx.data(), cy.data(), cz.data(), n);
  std::vector<std::int32_t> ids(n);
  for (std::size_t i = 0; i < n; ++i) ids[i] = std::int32_t(i);
  std::stable_sort(ids.begin(), ids.end(), [&](std::int32_t a, std::int32_t b) {
    return std::make_tuple(cz[a], cy[a], cx[a]) < std::make_tuple(cz[b], cy[b], cx[b]);
  });
  ASSERT_EQ(g.order(), ids);
  for (std::size_t k = 0; k < g.cellCount(); ++k)
    for (std::int32_t r = g.cellBegin(k); r < g.cellEnd(k); ++r) {
      const std::int32_t i = g.order()[r];
      ASSERT_EQ(g.cellCoord(k), Vec3i(cx[i], cy[i], cz[i]));
    }
  NeighborLists lists;
  EXPECT_THROW(g.buildNeighborLists(1.0f, 8, lists), RuntimeError);  // no positions
  cx[5] = cx[6] + (1 << 21);
  EXPECT_THROW(g.buildFromCells(cx.data(), cy.data(), cz.data(), n), RuntimeError);
}

// Enough particles and cells for several work units, and long enough for both threads
// to be busy at once (a schedule-dependent placement was caught only from ~10^5 up):
// everything bit-identical, several runs of 2 threads against 1.
TEST(NeighborGrid, OneAndTwoThreadsBitIdentical) {
  const Cloud c = uniform(400000, 1.0f, 9);
  const float h = 0.02f;
  auto run = [&](int threads, NeighborGrid& g, NeighborLists& lists) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), h);
    g.buildNeighborLists(h, 48, lists);
  };
  NeighborGrid g1;
  NeighborLists l1;
  run(1, g1, l1);
  ASSERT_GT(g1.cellCount(), 4096u);
  for (int round = 0; round < 3; ++round) {
    NeighborGrid g2;
    NeighborLists l2;
    run(2, g2, l2);
    ASSERT_EQ(g1.order(), g2.order());
    ASSERT_EQ(g1.ranks(), g2.ranks());
    ASSERT_EQ(g1.cellStarts(), g2.cellStarts());
    ASSERT_TRUE(std::equal(g1.sortedX(), g1.sortedX() + c.size(), g2.sortedX()));
    ASSERT_EQ(l1.index, l2.index);
    ASSERT_EQ(l1.count, l2.count);
    ASSERT_EQ(l1.maxCount, l2.maxCount);
    ASSERT_EQ(l1.overflowed, l2.overflowed);
  }
}

TEST(NeighborGrid, BadInputIsAnError) {
  Cloud c = uniform(50, 1.0f, 10);
  NeighborGrid g;
  const float bad[] = {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(),
                       -std::numeric_limits<float>::infinity()};
  for (float b : bad) {
    Cloud d = c;
    d.z[37] = b;
    d.x[41] = b;
    try {
      g.build(d.x.data(), d.y.data(), d.z.data(), d.size(), 0.1f);
      FAIL() << "no error for " << b;
    } catch (const RuntimeError& e) {
      EXPECT_NE(std::string(e.what()).find("particle 37 "), std::string::npos) << e.what();
    }
  }
  for (float cell : {0.0f, -0.1f, bad[0], bad[1]})
    EXPECT_THROW(g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), cell), RuntimeError) << cell;
  g.build(c.x.data(), c.y.data(), c.z.data(), c.size(), 0.1f);
  NeighborLists lists;
  for (float radius : {0.0f, -0.05f, 0.10001f, bad[0], 1e-30f})
    EXPECT_THROW(g.buildNeighborLists(radius, 8, lists), RuntimeError) << radius;
  EXPECT_THROW(g.buildNeighborLists(0.1f, 0, lists), RuntimeError);
  EXPECT_THROW(g.forEachNeighbor(0, 0.2f, [](std::int32_t) {}), RuntimeError);
  EXPECT_THROW(g.forEachNeighbor(50, 0.1f, [](std::int32_t) {}), RuntimeError);
  EXPECT_THROW(g.forEachNeighbor(-1, 0.1f, [](std::int32_t) {}), RuntimeError);
}
