// The shared guard checks name the first offender, its kind and the bound. (Which
// pass produced a bad value is the solver's to name: tests/pbd/test_rigid.cpp.)
#include <gtest/gtest.h>

#include <cmath>

#include "core/guard.h"

using namespace physketch;

namespace {
ParticleArrays threeParticles() {
  ParticleArrays p;
  for (int i = 0; i < 3; ++i) p.push(0.0f, 1.0f, 0.0f, 10 + i, 0);
  for (auto& ph : p.phase) ph = phase::make(4);  // dynamic, body 4
  return p;
}
}  // namespace

TEST(Guard, StableStatePasses) {
  auto p = threeParticles();
  EXPECT_FALSE(checkParticles(p, 100.0).tripped());
}

TEST(Guard, NamesFirstNaNParticleItsBodyAndStroke) {
  auto p = threeParticles();
  p.vy[2] = std::nanf("");
  p.x[1] = std::nanf("");
  const GuardRecord r = checkParticles(p, 100.0);
  EXPECT_EQ(r.kind, GuardKind::kNaN);
  EXPECT_EQ(r.particle, 1);
  EXPECT_EQ(r.body, 4);
  EXPECT_EQ(r.stroke, 11);
  EXPECT_NE(r.message().find("particle 1"), std::string::npos);
}

TEST(Guard, ExplosionBoundIsStrict) {
  auto p = threeParticles();
  p.vx[0] = 10.5f;
  GuardRecord r = checkParticles(p, 10.0);
  EXPECT_EQ(r.kind, GuardKind::kExplosion);
  EXPECT_NEAR(r.value, 10.5, 1e-6);
  EXPECT_DOUBLE_EQ(r.bound, 10.0);
  p.vx[0] = 6.0f;
  p.vy[0] = 8.0f;  // |v| = 10 exactly: on the bound is not above it
  EXPECT_FALSE(checkParticles(p, 10.0).tripped());
}

TEST(Guard, PrescribedParticlesAreCheckedForNaNOnlyAndRemovedOnesNotAtAll) {
  auto p = threeParticles();
  p.phase[1] = phase::make(4, phase::kPrescribed);  // kinematic: carried by a brush
  p.vx[1] = 500.0f;
  EXPECT_FALSE(checkParticles(p, 10.0).tripped());
  p.z[1] = std::nanf("");
  EXPECT_EQ(checkParticles(p, 10.0).kind, GuardKind::kNaN);
  p.phase[1] = phase::make(-1, phase::kRemoved | phase::kPrescribed);
  EXPECT_FALSE(checkParticles(p, 10.0).tripped());
}

TEST(Guard, MessageNamesPassSubstepAndMaterial) {
  GuardRecord r;
  r.kind = GuardKind::kPenetration;
  r.pass = "rigid_contact";
  r.step = 12;
  r.substep = 3;
  r.particle = 7;
  r.material = "wood";
  const std::string m = r.message();
  EXPECT_NE(m.find("'rigid_contact'"), std::string::npos);
  EXPECT_NE(m.find("substep 3"), std::string::npos);
  EXPECT_NE(m.find("material wood"), std::string::npos);
}

TEST(Phase, PacksGroupAndFlags) {
  const std::uint32_t ph = phase::make(123456, phase::kFluid | phase::kPrescribed);
  EXPECT_EQ(phase::group(ph), 123456);
  EXPECT_TRUE(phase::has(ph, phase::kFluid));
  EXPECT_FALSE(phase::has(ph, phase::kSelfCollide));
  EXPECT_FALSE(phase::dynamic(ph));
  EXPECT_EQ(phase::group(phase::make(-1)), -1);
  EXPECT_TRUE(phase::dynamic(phase::make(0)));
}
