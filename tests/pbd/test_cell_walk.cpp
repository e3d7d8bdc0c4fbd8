// pbd/cell_walk.h: the first taken cell a segment enters, against brute force.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <random>
#include <vector>

#include "pbd/cell_walk.h"

using namespace physketch;
using namespace physketch::pbd;

namespace {

// Where the segment a + t d, t in [0, 1], enters the unit box at `c` (slab method, exact up to
// rounding): the entry t, or 2 if it never does.
double entersBox(const Vec3& a, const Vec3& d, const Vec3i& c) {
  double lo = 0.0, hi = 1.0;
  for (int k = 0; k < 3; ++k) {
    if (d[k] == 0.0) {
      if (a[k] < c[k] || a[k] >= c[k] + 1) return 2.0;
      continue;
    }
    double t0 = (c[k] - a[k]) / d[k], t1 = (c[k] + 1 - a[k]) / d[k];
    if (t0 > t1) std::swap(t0, t1);
    lo = std::max(lo, t0), hi = std::min(hi, t1);
  }
  return lo <= hi ? lo : 2.0;
}

}  // namespace

// The oracle is brute force over every taken cell of a random 8^3 box (a third of it taken):
// the smallest entry fraction of the segment into any of them. 20,000 segments from random
// points of untaken cells, up to 6 cells long, a tenth of them along an axis (the walk's
// infinite steps). Tolerance 1e-12 in t: both sides divide the same differences, so they agree
// to a few ulps; a segment that only grazes a cell's edge is a measure-zero event the random
// points do not produce.
TEST(CellWalk, FirstTakenCellIsTheNearestTakenCellTheSegmentEnters) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> in(0.0, 8.0), len(-6.0, 6.0), u(0.0, 1.0);
  std::vector<char> taken(512);
  for (char& t : taken) t = u(rng) < 0.33;
  const auto filled = [&](const Vec3i& c) {
    return (c.array() >= 0).all() && (c.array() < 8).all() && taken[std::size_t(c.x() + 8 * (c.y() + 8 * c.z()))] != 0;
  };
  int hits = 0, tested = 0;
  while (tested < 20000) {
    const Vec3 a(in(rng), in(rng), in(rng));
    if (filled(Vec3i(int(a.x()), int(a.y()), int(a.z())))) continue;
    Vec3 d(len(rng), len(rng), len(rng));
    if (tested % 10 == 0) d = d[0] * Vec3::Unit(tested / 10 % 3);
    ++tested;
    double best = 2.0;
    for (int z = -1; z <= 8; ++z)
      for (int y = -1; y <= 8; ++y)
        for (int x = -1; x <= 8; ++x)
          if (filled(Vec3i(x, y, z))) best = std::min(best, entersBox(a, d, Vec3i(x, y, z)));
    const CellEntry e = firstTakenCell(a, d, filled);
    ASSERT_EQ(e.hit, best <= 1.0) << "a " << a.transpose() << " d " << d.transpose();
    if (!e.hit) continue;
    ++hits;
    ASSERT_NEAR(e.t, best, 1e-12);
    // The face it names: the point just past the entry is in a taken cell the step came into.
    const Vec3 past = a + (e.t + 1e-9) * d;
    const Vec3i cell(int(std::floor(past.x())), int(std::floor(past.y())), int(std::floor(past.z())));
    EXPECT_TRUE(filled(cell));
    EXPECT_EQ(e.dir, d[e.axis] > 0.0 ? 1 : -1);
    EXPECT_NEAR(a[e.axis] + e.t * d[e.axis], e.dir > 0 ? cell[e.axis] : cell[e.axis] + 1, 1e-9);
  }
  std::printf("cell walk: %d of %d segments entered a taken cell\n", hits, tested);
  EXPECT_GT(hits, 5000);  // the test sees both outcomes often
  EXPECT_LT(hits, 19000);
}

// A segment starting in a taken cell enters none (the particle was already inside: contacts,
// not the sweep, deal with it), and ends beyond 2^20 cells or not finite give none.
TEST(CellWalk, StartsInsideFarAndNotFiniteEnterNone) {
  const auto all = [](const Vec3i&) { return true; };
  EXPECT_FALSE(firstTakenCell(Vec3(0.5, 0.5, 0.5), Vec3(3, 0, 0), all).hit);
  const auto one = [](const Vec3i& c) { return c == Vec3i(2, 0, 0); };
  EXPECT_TRUE(firstTakenCell(Vec3(0.5, 0.5, 0.5), Vec3(3, 0, 0), one).hit);
  EXPECT_FALSE(firstTakenCell(Vec3(0.5, 0.5, 0.5), Vec3(4e6, 0, 0), one).hit);
  EXPECT_FALSE(firstTakenCell(Vec3(0.5, 0.5, 0.5), Vec3(std::nan(""), 0, 0), one).hit);
}
