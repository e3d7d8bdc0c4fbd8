// XPBD distance constraints against closed forms: an inextensible link is restored in one
// sweep with the mass-weighted split; a hanging mass on a compliant link settles at the
// spring's static extension m g alpha whatever the iteration count (XPBD's point).
#include <gtest/gtest.h>

#include <cmath>

#include "pbd/constraints.h"

using namespace physketch::pbd;

TEST(Constraints, InextensibleLinkIsRestoredInOneSweepSplitByInverseMass) {
  // Stretched from 1.0 to 1.3 along x; w_a = 1, w_b = 2: a moves 0.1, b moves 0.2.
  float px[2] = {0.0f, 1.3f}, py[2] = {0, 0}, pz[2] = {0, 0};
  const float w[2] = {1.0f, 2.0f};
  DistanceConstraints c;
  c.add(0, 1, 1.0f, 0.0f);
  solveDistances(c, px, py, pz, w, 0.01);
  EXPECT_NEAR(px[0], 0.1f, 1e-6);
  EXPECT_NEAR(px[1], 1.1f, 1e-6);
  EXPECT_NEAR(px[1] - px[0], 1.0f, 1e-6);
}

TEST(Constraints, HangingMassSettlesAtTheSpringExtensionWhateverTheIterations) {
  // A 0.2 kg particle hangs 0.5 m under a fixed one on a link of compliance alpha: the
  // static extension is m g' alpha (k = 1/alpha), g' = 0.995 g because the test damps the
  // velocity by 0.5 % per substep (the equilibrium's predicted step is 0.995 g h^2). XPBD
  // makes the stiffness independent of the iteration count; plain PBD's grows with it.
  // 10 s of damped motion settles well below the tolerance, 0.5 % of the extension.
  const double m = 0.2, g = 9.81, alpha = 0.01, h = 1.0 / 600.0;
  const double expect = m * 0.995 * g * alpha;  // 19.5 mm
  for (int iterations : {1, 10}) {
    float x[2] = {0, 0}, y[2] = {1.0f, 0.5f}, z[2] = {0, 0};
    float vy = 0.0f;
    const float w[2] = {0.0f, float(1.0 / m)};
    DistanceConstraints c;
    c.add(0, 1, 0.5f, float(alpha));
    for (int s = 0; s < 6000; ++s) {
      vy = 0.995f * (vy - float(g * h));
      float px[2] = {x[0], x[1]}, py[2] = {y[0], float(y[1] + vy * h)}, pz[2] = {0, 0};
      c.resetMultipliers();
      for (int it = 0; it < iterations; ++it) solveDistances(c, px, py, pz, w, h);
      vy = float((py[1] - y[1]) / h);
      y[1] = py[1];
      (void)z;
    }
    EXPECT_NEAR(y[0] - y[1] - 0.5, expect, 0.005 * expect) << iterations << " iterations";
  }
}

TEST(Constraints, ClustersAreOverlappingIndexLists) {
  Clusters c;
  c.add({0, 1, 2}, 1.0f);
  c.add({2, 3}, 0.5f);
  ASSERT_EQ(c.size(), 2u);
  EXPECT_EQ(c.offset, (std::vector<std::int32_t>{0, 3, 5}));
  EXPECT_EQ(c.index[3], 2);  // particle 2 is in both
}
