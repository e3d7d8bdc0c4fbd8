// Sleeping rigid bodies (PbdParams::sleepSpeed, the scene's `sleep` record): a body that has
// stayed within sleepSpeed x sleepTime of one pose for sleepTime seconds, with what it touches,
// stops being simulated; something moving that touches it wakes it, and every outside change
// wakes all. Oracles: the definition's arithmetic (when a steady drift may and may not sleep),
// conservation of momentum (a woken body takes its share of an impact), the ground contact's
// resting height, and a floating box that must fall once its support is carried away.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include <tbb/global_control.h>

#include "core/material_table.h"
#include "core/scene.h"
#include "pbd/mesh_collider.h"
#include "pbd/world.h"
#include "tests/pbd/builders.h"

using namespace physketch;
using namespace physketch::pbd;
using namespace physketch::pbd::test;

namespace {

constexpr double kSleepSpeed = 0.02;  // m/s: a scene's default at this spacing (2 spacings / s)

PbdParams sleepy(int substeps = 8, double groundY = 0.0) {
  PbdParams p;
  p.dt = 1.0 / 60.0;
  p.substeps = substeps;
  p.iterations = 4;
  p.groundY = groundY;
  p.particleRadius = kRadius;
  p.sleepSpeed = kSleepSpeed;
  p.sleepTime = 0.5;
  return p;
}

double lowestOf(const PbdWorld& w, int body) {
  double y = 1e300;
  for (std::int32_t i : w.bodyParticles(body)) y = std::min(y, double(w.particles().y[std::size_t(i)]));
  return y;
}

// A 6x4x6 box on the ground with a 4x4x4 box on it (bodies 0 and 1), and a 3x3x6 pusher (body 2,
// carried once the world is made) on the ground at x = pusherX, clear of the lower box.
std::vector<BodyRange> stackAndPusher(ParticleArrays& p, double pusherX) {
  return {addBox(p, Vec3(0.0, kRadius, 0.0), 6, 4, 6, 0), addBox(p, Vec3(0.01, kRadius + 4 * kSpacing, 0.01), 4, 4, 4, 1),
          addBox(p, Vec3(pusherX, kRadius, 0.0), 3, 3, 6, 2)};
}

// Makes body 2 a carried pusher, held still, and runs 1.5 s: both boxes must be asleep.
void settleAsleep(PbdWorld& w) {
  w.setMode(2, BodyMode::kKinematic);
  for (int s = 0; s < 90; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  ASSERT_TRUE(w.asleep(0));
  ASSERT_TRUE(w.asleep(1));
}

}  // namespace

// A box dropped 2 cm onto the ground lands at 0.06 s and then rests: it must be asleep within
// 0.5 s of resting (by step 60, 1 s) and not before it has been at rest for the sleep time
// (step 30 is 0.5 s from the start, less than 0.06 s + 0.5 s). Asleep, its particles' velocities
// are exactly 0 and its particles stay bit for bit where they are, at the resting height the
// ground contact gives (lowest particle r above the ground; 5 % of r covers the contact's
// leftover, which is far smaller).
TEST(Sleep, ABoxAtRestFallsAsleepWithNoVelocityAndStaysBitForBit) {
  ParticleArrays p;
  std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, kRadius + 0.02, 0.0), 6, 4, 6)};
  PbdWorld w(p, bodies, rigidMaterial(0.5), sleepy());
  const int fellAsleep = stepUntilAsleep(w, 0, 60);
  ASSERT_GE(fellAsleep, 0) << "not asleep after 1 s at rest; " << w.guard().message();
  EXPECT_GT(fellAsleep, 30);
  EXPECT_EQ(w.sleepingCount(), 1);
  const ParticleArrays before = w.particles();
  ASSERT_TRUE(allExactlyAtRest(before));
  EXPECT_NEAR(lowestOf(w, 0), kRadius, 0.05 * kRadius);
  for (int s = 0; s < 60; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  EXPECT_TRUE(w.asleep(0));
  EXPECT_EQ(w.particles().x, before.x);
  EXPECT_EQ(w.particles().y, before.y);
  EXPECT_EQ(w.particles().z, before.z);
  // Nothing left to simulate: the plan runs no rigid pass while the only body sleeps.
  int checked = 0;
  for (const PlanEntry& e : w.planAll())
    if (e.name == "integrate" || e.name == "rigid_contact") {
      EXPECT_FALSE(e.on) << e.name << ": " << e.reason;
      ++checked;
    }
  EXPECT_EQ(checked, 2);
}

// Stillness by displacement: a body drifting steadily (zero gravity, nothing in reach) at v
// stays within the ball D = sleepSpeed x sleepTime for the sleep time exactly when v < sleepSpeed.
// At 0.5 x sleepSpeed it is asleep after 1 s; at 1.5 x it never sleeps in 3 s, nor does a body
// spinning so that its farthest point moves at 1.5 x sleepSpeed.
TEST(Sleep, ABodyDriftingSlowerThanTheSleepSpeedSleepsAndOneFasterNever) {
  ParticleArrays p;
  std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, 1.0, 0.0), 4, 4, 4, 0), addBox(p, Vec3(1.0, 1.0, 0.0), 4, 4, 4, 1),
                                addBox(p, Vec3(2.0, 1.0, 0.0), 4, 4, 4, 2)};
  bodies[0].init.velocity = Vec3(0.5 * kSleepSpeed, 0.0, 0.0);
  bodies[1].init.velocity = Vec3(0.0, 0.0, 1.5 * kSleepSpeed);
  PbdParams prm = sleepy(4, -100.0);
  prm.gravity = Vec3::Zero();
  PbdWorld w(p, bodies, rigidMaterial(), prm);
  // The spinning box: its reach is the farthest particle's distance from the centre plus r.
  double reach = 0.0;
  for (std::int32_t i : w.bodyParticles(2)) {
    const Vec3 x(p.x[std::size_t(i)], p.y[std::size_t(i)], p.z[std::size_t(i)]);
    reach = std::max(reach, (x - w.pose(2).centre).norm() + kRadius);
  }
  w.setVelocity(2, Vec3::Zero(), Vec3(0.0, 1.5 * kSleepSpeed / reach, 0.0));
  for (int s = 0; s < 180; ++s) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    if (s == 20) {
      EXPECT_FALSE(w.asleep(0)) << "asleep before the sleep time";
    }
    if (s == 60) {
      EXPECT_TRUE(w.asleep(0)) << "a drift at half the sleep speed did not sleep";
    }
    ASSERT_FALSE(w.asleep(1)) << "a drift at 1.5 x the sleep speed fell asleep at step " << s;
    ASSERT_FALSE(w.asleep(2)) << "a spin at 1.5 x the sleep speed fell asleep at step " << s;
  }
}

// A sleeper hit by a moving body wakes before the contact is solved and takes its share of the
// impact: in zero gravity the total momentum stays the thrower's (1e-12 kg m/s: double rounding
// of the poses, as in AZeroGravityCollisionConservesMomentumAndLosesEnergy). Left asleep, it
// would act as a fixed wall: the thrower would stop and the momentum vanish.
TEST(Sleep, ASleeperHitByAMovingBodyWakesAndMomentumIsConserved) {
  ParticleArrays p;
  std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, 1.0, 0.0), 5, 5, 5, 0), addBox(p, Vec3(-0.65, 1.01, 0.005), 5, 5, 5, 1)};
  const double v0 = 0.5;
  bodies[1].init.velocity = Vec3(v0, 0.0, 0.0);
  PbdParams prm = sleepy(8, -100.0);
  prm.gravity = Vec3::Zero();
  PbdWorld w(p, bodies, rigidMaterial(), prm);
  const double m = w.bodyMass(0);
  ASSERT_DOUBLE_EQ(w.bodyMass(1), m);
  for (int s = 0; s < 60; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  ASSERT_TRUE(w.asleep(0)) << "the resting box should sleep before the other arrives (at about 1.2 s)";
  ASSERT_GT(w.pose(0).centre.x() - w.pose(1).centre.x(), 0.1);  // not there yet (they touch at 0.05)
  for (int s = 0; s < 60; ++s) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    ASSERT_LT((m * (w.velocity(0) + w.velocity(1)) - Vec3(m * v0, 0.0, 0.0)).norm(), 1e-12) << "step " << s;
  }
  EXPECT_FALSE(w.asleep(0));
  EXPECT_GT(w.velocity(0).x(), 0.25 * v0);  // it was hit and moves off
}

// A box asleep on another sleeping box: a carried pusher (a tool) shoves the lower box out at
// 2 m/s, faster than friction can take the upper one along (mu g = 4.9 m/s^2 for the 0.03 s the
// lower box needs to leave: at most 0.15 m/s, 4 mm). The pusher wakes the lower box; the lower
// box, moving, wakes the upper one, which must fall to the ground (lowest particle r above it,
// within 20 % of r) instead of staying where it slept, 4 spacings up in the air.
TEST(Sleep, ABoxWhoseSupportIsPushedAwayWakesAndFalls) {
  ParticleArrays p;
  PbdWorld w(p, stackAndPusher(p, -0.08), rigidMaterial(0.5), sleepy());
  settleAsleep(w);
  if (HasFatalFailure()) return;
  const double upperY = lowestOf(w, 1);
  ASSERT_GT(upperY, kRadius + 3.5 * kSpacing);
  const double speed = 2.0;
  for (int s = 0; s < 150; ++s) {
    if (s < 12) w.setKinematicTarget(2, w.pose(2).centre + Vec3(speed * w.dt(), 0.0, 0.0));
    ASSERT_TRUE(w.step()) << w.guard().message();
  }
  EXPECT_GT(w.pose(0).centre.x(), 0.2);  // the lower box was pushed out
  EXPECT_NEAR(lowestOf(w, 1), kRadius, 0.2 * kRadius) << "the upper box stayed at " << upperY;
}

// The same stack, the lower box pushed slowly (0.05 m/s: above the sleep speed, below the 0.08 m/s
// at which a touch wakes a sleeper by its speed). The lower box leaves its still ball (one
// spacing) within 0.2 s and then wakes the box asleep on it, which static friction then carries
// along (mu 0.5 against an acceleration of ~0): after 3 s of pushing both have moved about 0.14 m,
// the upper box less by what the lower one moved before it woke, at most the ball (1 cm; 2 mm
// more for the pusher's first touch, which jolts the lower box), and the upper box still
// rests on the lower (its lowest particle one spacing above the lower box's top layer, within
// 20 % of r). Left asleep, it would hang in the air where it fell asleep.
TEST(Sleep, ASleeperOnASlowlyPushedBoxWakesAndIsCarriedAlong) {
  ParticleArrays p;
  PbdWorld w(p, stackAndPusher(p, -0.04), rigidMaterial(0.5), sleepy());
  settleAsleep(w);
  if (HasFatalFailure()) return;
  const Vec3 lower0 = w.pose(0).centre, upper0 = w.pose(1).centre;
  const double speed = 0.05;
  for (int s = 0; s < 180; ++s) {
    w.setKinematicTarget(2, w.pose(2).centre + Vec3(speed * w.dt(), 0.0, 0.0));
    ASSERT_TRUE(w.step()) << w.guard().message();
  }
  const double lowerMoved = w.pose(0).centre.x() - lower0.x(), upperMoved = w.pose(1).centre.x() - upper0.x();
  EXPECT_GT(lowerMoved, 0.1);
  EXPECT_NEAR(upperMoved, lowerMoved, kSleepSpeed * 0.5 + 0.002);
  EXPECT_NEAR(lowestOf(w, 1) - lowestOf(w, 0), 4 * kSpacing, 0.2 * kRadius);
}

// bodyPairsNow() is a look at the pairs, not a step: it must wake nobody. At one substep the
// check a step makes (the toucher's speed less this substep's gravity, g h = 0.16 m/s) would,
// between steps, read a resting toucher as moving at g h, twice the touch-wake speed (0.08 m/s).
// A box held awake by a carried body beside it rests on a sleeping box: a world that asks for the
// pairs after every step must run bit-identically to one that does not, its lower box asleep.
TEST(Sleep, AskingForTheBodyPairsWakesNobody) {
  const auto run = [](bool ask, std::vector<std::uint64_t>& hashes) {
    ParticleArrays p;
    std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, kRadius, 0.0), 6, 4, 6, 0),
                                  addBox(p, Vec3(0.01, kRadius + 4 * kSpacing, 0.01), 3, 3, 3, 1),
                                  addBox(p, Vec3(-0.0195, kRadius + 5 * kSpacing, 0.01), 2, 3, 3, 2)};
    PbdWorld w(p, bodies, rigidMaterial(0.5), sleepy(1));
    w.setMode(2, BodyMode::kKinematic);
    for (int s = 0; s < 90; ++s) {
      EXPECT_TRUE(w.step()) << w.guard().message();
      if (ask) w.bodyPairsNow();
      hashes.push_back(w.stateHash());
    }
    EXPECT_TRUE(w.asleep(0)) << (ask ? "asking" : "not asking");
    EXPECT_FALSE(w.asleep(1)) << "the box beside the carried body must stay awake";
  };
  std::vector<std::uint64_t> plain, asked;
  run(false, plain);
  run(true, asked);
  ASSERT_EQ(plain.size(), asked.size());
  for (std::size_t s = 0; s < plain.size(); ++s) ASSERT_EQ(plain[s], asked[s]) << "diverged at step " << s;
}

// Sleeping decides nothing that depends on threads: a landing pile (2 layers of 3 x 3 boxes, each
// layer turned) gives bit-identical states for 1 and 2 threads at every step while its boxes fall
// asleep (some must, or the test would not test it).
TEST(Sleep, SameStateForOneAndTwoThreadsWhileAPileFallsAsleep) {
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  const int side = 5;
  for (int layer = 0; layer < 2; ++layer) {
    const Mat3 R = Eigen::AngleAxisd(0.35 * layer, Vec3(0.3, 1.0, 0.2).normalized()).toRotationMatrix();
    for (int a = 0; a < 3; ++a)
      for (int c = 0; c < 3; ++c)
        addTurnedCube(p, bodies, Vec3(a * 1.6 * side * kSpacing, 0.05 + layer * 1.8 * side * kSpacing, c * 1.6 * side * kSpacing), R,
                      side);
  }
  auto run = [&](int threads, long& mostAsleep) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
    PbdWorld w(p, bodies, rigidMaterial(), sleepy(4));
    std::vector<std::uint64_t> hashes;
    mostAsleep = 0;
    for (int s = 0; s < 150; ++s) {
      EXPECT_TRUE(w.step()) << w.guard().message();
      hashes.push_back(w.stateHash());
      mostAsleep = std::max(mostAsleep, w.sleepingCount());
    }
    return hashes;
  };
  long asleep1 = 0, asleep2 = 0;
  const auto one = run(1, asleep1), two = run(2, asleep2);
  for (std::size_t s = 0; s < one.size(); ++s) ASSERT_EQ(one[s], two[s]) << "diverged at step " << s;
  EXPECT_GE(asleep1, 9);
  EXPECT_EQ(asleep1, asleep2);
}

// Mesh colliders moving along keyframes do not look for sleepers to wake, so with one in the
// scene a resting box stays awake. Without it the same box sleeps (the control). (Particle-level
// material no longer keeps every body awake: test_particles.cpp, SleepBeside.)
TEST(Sleep, ScenesWithMovingCollidersKeepEveryBodyAwake) {
  const auto restingBox = [](ParticleArrays& p) { return addBox(p, Vec3(0.0, kRadius, 0.0), 4, 4, 4, 0); };
  {
    ParticleArrays p;
    std::vector<BodyRange> bodies{restingBox(p)};
    PbdWorld w(p, bodies, rigidMaterial(), sleepy());
    for (int s = 0; s < 90; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    EXPECT_TRUE(w.asleep(0)) << "control: alone, the box sleeps";
  }
  {
    ParticleArrays p;
    std::vector<BodyRange> bodies{restingBox(p)};
    PbdWorld w(p, bodies, rigidMaterial(), sleepy());
    MeshCollider c;
    c.name = "mover";
    c.keyframes.push_back({10.0, Vec3(5.0, 0.0, 0.0), Mat3::Identity(), 1});
    c.keyframes.push_back({11.0, Vec3(6.0, 0.0, 0.0), Mat3::Identity(), 2});
    TriangleSoup tri;
    tri.vertices = {Vec3(0, 0, 0), Vec3(0.1, 0, 0), Vec3(0, 0.1, 0)};
    tri.triangles = {{0, 1, 2}};
    w.setColliders(ColliderSet({c}, {tri}));
    for (int s = 0; s < 90; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    EXPECT_FALSE(w.asleep(0)) << "a collider moving along keyframes in the scene";
  }
}

// The scene's `sleep` record reaches the solver: on by default at two particle spacings per second
// (so a body still for the default 0.5 s stays within one spacing), `sleep off` turns it off, and
// `sleep SPEED SECONDS` sets both.
TEST(Sleep, TheScenesSleepRecordSetsTheSolversSleepSpeedAndTime) {
  const double r = 0.004;
  const auto paramsOf = [&](const std::string& line) {
    return paramsFromScene(parseScene("physketch-scene 1\nstrokes a.strokes\n" + line, "t.scene"), r);
  };
  EXPECT_DOUBLE_EQ(paramsOf("").sleepSpeed, 4.0 * r);
  EXPECT_DOUBLE_EQ(paramsOf("").sleepTime, 0.5);
  EXPECT_DOUBLE_EQ(paramsOf("sleep on\n").sleepSpeed, 4.0 * r);
  EXPECT_DOUBLE_EQ(paramsOf("sleep auto 2\n").sleepSpeed, 4.0 * r);
  EXPECT_DOUBLE_EQ(paramsOf("sleep auto 2\n").sleepTime, 2.0);
  EXPECT_EQ(paramsOf("sleep off\n").sleepSpeed, 0.0);
  EXPECT_DOUBLE_EQ(paramsOf("sleep 0.05 1.5\n").sleepSpeed, 0.05);
  EXPECT_DOUBLE_EQ(paramsOf("sleep 0.05 1.5\n").sleepTime, 1.5);
}
