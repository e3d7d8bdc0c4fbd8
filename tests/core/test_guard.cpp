// The stability guard names the first offender, its kind and the bound.
#include <gtest/gtest.h>

#include <cmath>

#include "core/guard.h"

using namespace physketch;

namespace {
ParticleArrays threeParticles() {
  ParticleArrays p;
  for (int i = 0; i < 3; ++i) p.push(0.0f, 1.0f, 0.0f, 0, 0);
  p.invMass.assign(3, 1.0f);  // dynamic
  return p;
}
}  // namespace

TEST(Guard, StableStatePasses) {
  auto p = threeParticles();
  GuardLimits lim;
  EXPECT_FALSE(checkParticles(p, lim, "update", 0).tripped());
}

TEST(Guard, NamesFirstNaNParticleAndPass) {
  auto p = threeParticles();
  p.vy[2] = std::nanf("");
  p.x[1] = std::nanf("");
  const GuardRecord r = checkParticles(p, GuardLimits{}, "shape_match", 7);
  EXPECT_EQ(r.kind, GuardKind::kNaN);
  EXPECT_EQ(r.particle, 1);
  EXPECT_EQ(r.pass, "shape_match");
  EXPECT_EQ(r.step, 7);
  EXPECT_NE(r.message().find("particle 1"), std::string::npos);
}

TEST(Guard, ExplosionAndPenetrationBounds) {
  auto p = threeParticles();
  GuardLimits lim;
  lim.maxSpeed = 10.0;
  p.vx[0] = 10.5f;
  GuardRecord r = checkParticles(p, lim, "update", 1);
  EXPECT_EQ(r.kind, GuardKind::kExplosion);
  EXPECT_NEAR(r.value, 10.5, 1e-6);
  EXPECT_DOUBLE_EQ(r.bound, 10.0);
  p.vx[0] = 0.0f;
  lim.groundY = 0.0;
  lim.particleRadius = 0.01;
  lim.maxPenetration = 0.01;
  p.y[2] = -0.001f;  // 0.011 below ground + radius
  r = checkParticles(p, lim, "update", 2);
  EXPECT_EQ(r.kind, GuardKind::kPenetration);
  EXPECT_EQ(r.particle, 2);
  p.y[2] = 0.0005f;  // 0.0095 deep: within the bound
  EXPECT_FALSE(checkParticles(p, lim, "update", 2).tripped());
}

TEST(Guard, PrescribedParticlesAreCheckedForNaNOnly) {
  auto p = threeParticles();
  GuardLimits lim;
  lim.maxSpeed = 10.0;
  lim.maxPenetration = 0.01;
  lim.particleRadius = 0.01;
  p.invMass[1] = 0.0f;  // kinematic: carried by a brush
  p.vx[1] = 500.0f;
  p.y[1] = -1.0f;
  EXPECT_FALSE(checkParticles(p, lim, "update", 0).tripped());
  p.z[1] = std::nanf("");
  EXPECT_EQ(checkParticles(p, lim, "update", 0).kind, GuardKind::kNaN);
}
