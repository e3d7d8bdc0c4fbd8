// 26-connected components against an independent brute force: union-find over every
// pair of cells whose coordinates differ by at most 1 on each axis.
#include <gtest/gtest.h>

#include <functional>
#include <map>
#include <random>

#include "core/lattice.h"

using namespace physketch;

namespace {
// Component labels by brute force (O(n^2) pair test + union-find), renumbered in order
// of first appearance like componentLabels26.
std::vector<int> bruteForce(const std::vector<Vec3i>& cells) {
  const std::size_t n = cells.size();
  std::vector<std::size_t> parent(n);
  for (std::size_t i = 0; i < n; ++i) parent[i] = i;
  std::function<std::size_t(std::size_t)> find = [&](std::size_t i) { return parent[i] == i ? i : parent[i] = find(parent[i]); };
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = i + 1; j < n; ++j)
      if ((cells[i] - cells[j]).cwiseAbs().maxCoeff() <= 1) parent[find(i)] = find(j);
  std::map<std::size_t, int> id;
  std::vector<int> out(n);
  for (std::size_t i = 0; i < n; ++i) {
    auto [it, fresh] = id.emplace(find(i), int(id.size()));
    out[i] = it->second;
  }
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
