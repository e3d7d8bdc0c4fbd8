// 26-connected components against an independent brute force: union-find over every
// pair of cells whose coordinates differ by at most 1 on each axis.
#include <gtest/gtest.h>

#include <functional>
#include <map>
#include <random>
#include <tuple>

#include "core/lattice.h"

using namespace physketch;

namespace {
// Component labels by brute force (O(n^2) pair test + union-find), numbered like
// componentLabels26: by each component's smallest cell in z, y, x order.
std::vector<int> bruteForce(const std::vector<Vec3i>& cells) {
  const std::size_t n = cells.size();
  std::vector<std::size_t> parent(n);
  for (std::size_t i = 0; i < n; ++i) parent[i] = i;
  std::function<std::size_t(std::size_t)> find = [&](std::size_t i) { return parent[i] == i ? i : parent[i] = find(parent[i]); };
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = i + 1; j < n; ++j)
      if ((cells[i] - cells[j]).cwiseAbs().maxCoeff() <= 1) parent[find(i)] = find(j);
  const auto key = [](const Vec3i& c) { return std::make_tuple(c.z(), c.y(), c.x()); };
  std::map<std::size_t, std::tuple<int, int, int>> smallest;  // root -> smallest cell of its component
  for (std::size_t i = 0; i < n; ++i) {
    auto [it, fresh] = smallest.emplace(find(i), key(cells[i]));
    if (!fresh) it->second = std::min(it->second, key(cells[i]));
  }
  std::map<std::tuple<int, int, int>, int> rank;
  for (const auto& [root, k] : smallest) rank.emplace(k, 0);
  int next = 0;
  for (auto& [k, r] : rank) r = next++;
  std::vector<int> out(n);
  for (std::size_t i = 0; i < n; ++i) out[i] = rank[smallest[find(i)]];
  return out;
}
}  // namespace

TEST(Lattice, ComponentsMatchBruteForceOnRandomSparseSets) {
  std::mt19937 rng(11);
  for (int trial = 0; trial < 40; ++trial) {
    std::uniform_int_distribution<int> c(0, 4 + trial / 4);
    std::vector<Vec3i> cells(static_cast<std::size_t>(10 + trial * 5));
    for (auto& v : cells) v = Vec3i(c(rng), c(rng), c(rng));
    int count = 0;
    const auto got = componentLabels26(cells, &count);
    const auto want = bruteForce(cells);
    ASSERT_EQ(std::vector<int>(got.begin(), got.end()), want) << "trial " << trial;
    ASSERT_EQ(count, *std::max_element(want.begin(), want.end()) + 1);
  }
}

TEST(Lattice, CornerTouchingCellsAreOneComponentAndAGapSplits) {
  int count = 0;
  componentLabels26({Vec3i(0, 0, 0), Vec3i(1, 1, 1)}, &count);
  EXPECT_EQ(count, 1);
  componentLabels26({Vec3i(0, 0, 0), Vec3i(2, 0, 0)}, &count);
  EXPECT_EQ(count, 2);
  EXPECT_TRUE(componentLabels26({}, &count).empty());
  EXPECT_EQ(count, 0);
}

TEST(Lattice, ABoundingBoxTooLargeToAllocateGivesTheSameLabels) {
  // Two random clusters a million cells apart: the box has 10^6 x 10 x 10 slots... x10 in
  // y too, past the dense limit, so the sorted search runs; it must agree with brute force.
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> c(0, 6);
  std::vector<Vec3i> cells;
  for (int i = 0; i < 60; ++i) cells.emplace_back(c(rng), c(rng), c(rng));
  for (int i = 0; i < 60; ++i) cells.emplace_back(1000000 + c(rng), 200 + c(rng), -300 + c(rng));
  int count = 0;
  const auto got = componentLabels26(cells, &count);
  EXPECT_EQ(std::vector<int>(got.begin(), got.end()), bruteForce(cells));
}
