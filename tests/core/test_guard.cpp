// The shared guard checks name the first offender, its kind and the bound. (Which
// pass produced a bad value is the solver's to name: tests/pbd/test_rigid.cpp.)
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

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

// EnergyWatch against energies summed by hand: masses 1, 2, 3 kg at heights 1, 2, 0.5 m,
// g = 10 m/s^2, spacing 0.1 m, at rest. E_ref = 10 (1 + 4 + 1.5) = 65 J; available = 65 - 6 kg
// x 10 x 0.5 m = 35 J; floor = 6 x 0.25 / 2 + 6 x 10 x 2 x 0.1 = 12.75 J: bound 112.75 J.
TEST(Guard, EnergyGrowthTripsAboveTheAvailableEnergyAndOnlyWhileClosed) {
  ParticleArrays p;
  const float heights[3] = {1.0f, 2.0f, 0.5f};
  for (int i = 0; i < 3; ++i) {
    p.push(0.0f, heights[i], 0.0f, 10 + i, 0);
    p.mass[std::size_t(i)] = float(i + 1);
  }
  for (auto& ph : p.phase) ph = phase::make(4);
  const Vec3 g(0.0, -10.0, 0.0);
  EnergyWatch w;
  EXPECT_FALSE(w.check(p, g, 0.1, true).tripped());  // arms
  ASSERT_TRUE(w.armed());
  EXPECT_NEAR(w.reference(), 65.0, 1e-5);
  EXPECT_NEAR(w.bound(), 112.75, 1e-5);
  // 47 J of kinetic energy on the 3 kg particle: 112 J, inside the bound.
  p.vy[2] = float(std::sqrt(2.0 * 47.0 / 3.0));
  EXPECT_FALSE(w.check(p, g, 0.1, true).tripped());
  // 48 J: 113 J, above it; the record names the particle with the most kinetic energy.
  p.vy[2] = float(std::sqrt(2.0 * 48.0 / 3.0));
  const GuardRecord r = w.check(p, g, 0.1, true);
  ASSERT_TRUE(r.tripped());
  EXPECT_EQ(r.kind, GuardKind::kEnergyGrowth);
  EXPECT_EQ(r.particle, 2);
  EXPECT_EQ(r.stroke, 12);
  EXPECT_NEAR(r.value, 113.0, 1e-4);
  EXPECT_NEAR(r.bound, 112.75, 1e-5);
  EXPECT_NE(r.message().find("energy_growth"), std::string::npos);
  // A prescribed particle's motion is the input's: it is not counted.
  p.vy[2] = 0.0f;
  p.phase[0] = phase::make(4, phase::kPrescribed);
  p.vx[0] = 1000.0f;
  EXPECT_FALSE(w.check(p, g, 0.1, true).tripped());
  // Open (a body carried): never trips, and the next closed check takes a new reference.
  p.vy[2] = 100.0f;
  EXPECT_FALSE(w.check(p, g, 0.1, false).tripped());
  EXPECT_FALSE(w.armed());
  EXPECT_FALSE(w.check(p, g, 0.1, true).tripped());
  EXPECT_TRUE(w.armed());
  EXPECT_GT(w.reference(), 1e4);
}

// The vectorized sum against a plain double sum (the oracle), over 1,237 particles: more than
// two blocks of 512 and a tail shorter than a lane group. Tolerance 1e-5 relative: float within
// a block of 512 terms of one sign loses at most ~512 x 6e-8 = 3e-5 of the block in the worst
// case and ~1e-6 typically; the guard's bound is a doubling. A prescribed particle with a NaN
// velocity (the input's) and a removed one with an infinite position are not summed.
TEST(Guard, EnergySumMatchesADoubleSumOverManyBlocks) {
  ParticleArrays p;
  std::uint32_t seed = 12345u;
  auto uniform = [&seed](double lo, double hi) {
    seed = seed * 1664525u + 1013904223u;
    return lo + (hi - lo) * double(seed >> 8) / double(1u << 24);
  };
  const Vec3 g(0.3, -9.81, 0.1);
  double kinetic = 0.0, potential = 0.0;
  for (int i = 0; i < 1237; ++i) {
    p.push(float(uniform(-1, 1)), float(uniform(0, 2)), float(uniform(-1, 1)), i, 0);
    const std::size_t k = std::size_t(i);
    p.mass[k] = float(uniform(0.001, 0.01));
    p.vx[k] = float(uniform(-3, 3));
    p.vy[k] = float(uniform(-3, 3));
    p.vz[k] = float(uniform(-3, 3));
    p.phase[k] = phase::make(i % 7);
    if (i == 700) {
      p.phase[k] = phase::make(i % 7, phase::kPrescribed);
      p.vx[k] = std::numeric_limits<float>::quiet_NaN();
      continue;
    }
    if (i == 1236) {
      p.phase[k] = phase::make(i % 7, phase::kRemoved);
      p.y[k] = std::numeric_limits<float>::infinity();
      continue;
    }
    const double m = p.mass[k];
    kinetic += 0.5 * m * (double(p.vx[k]) * p.vx[k] + double(p.vy[k]) * p.vy[k] + double(p.vz[k]) * p.vz[k]);
    potential -= m * (g.x() * p.x[k] + g.y() * p.y[k] + g.z() * p.z[k]);
  }
  EnergyWatch w;
  EXPECT_FALSE(w.check(p, g, 0.01, true).tripped());
  ASSERT_TRUE(w.armed());
  EXPECT_NEAR(w.reference(), kinetic + potential, 1e-5 * (kinetic + std::abs(potential)));
}

// The advice names the knob with this run's values, worked by hand: a CFL record at 1.7 cells
// per substep needs ceil(4 x 1.7) = 7 substeps; every other kind a factor 2; 'substeps auto'
// is told the Courant number instead; fluid compression the iterations first.
TEST(Guard, KnobAdviceNamesTheKnobWithThisRunsValues) {
  GuardRecord cfl;
  cfl.kind = GuardKind::kCfl;
  cfl.value = 3.4;
  cfl.bound = 2.0;
  KnobState mpm;
  mpm.substeps = 4;
  EXPECT_EQ(knobAdvice(cfl, mpm), "raise 'substeps' from 4 to at least 7, or write 'substeps auto'");
  KnobState autoMpm;
  autoMpm.substeps = 12;
  autoMpm.substepsAuto = true;
  autoMpm.cfl = 0.5;
  GuardRecord nan;
  nan.kind = GuardKind::kNaN;
  EXPECT_EQ(knobAdvice(nan, autoMpm), "lower 'cfl' from 0.5 to 0.25 or less ('substeps auto' chose 12 substeps for this step)");
  EXPECT_EQ(knobAdvice(cfl, autoMpm), "lower 'cfl' from 0.5 to 0.294 or less ('substeps auto' chose 12 substeps for this step)");
  KnobState pbd;
  pbd.substeps = 3;
  pbd.iterations = 4;
  GuardRecord fast;
  fast.kind = GuardKind::kExplosion;
  EXPECT_EQ(knobAdvice(fast, pbd),
            "raise 'substeps' from 3 to at least 6 (more substeps damp what more iterations do not), or 'iterations' "
            "from 4 to 8");
  GuardRecord squeezed;
  squeezed.kind = GuardKind::kCompression;
  EXPECT_EQ(knobAdvice(squeezed, pbd), "raise 'iterations' from 4 to at least 8, or 'substeps' from 3 to at least 6");
  // A CFL record just over its bound still asks for one more substep, not the same count.
  cfl.value = 2.0001;
  mpm.substeps = 1;
  EXPECT_EQ(knobAdvice(cfl, mpm), "raise 'substeps' from 1 to at least 2, or write 'substeps auto'");
}

namespace physketch {
namespace {

// The warn policy's log: only recoverable kinds are logged (NaN and inverted elements stop), only
// under kWarn, the first record of each kind is kept in full in the order the kinds first came, and
// every later one is counted.
TEST(GuardLog, KeepsTheFirstRecordOfEachRecoverableKindAndCountsTheRest) {
  GuardLog log;
  for (GuardKind k : {GuardKind::kExplosion, GuardKind::kNaN, GuardKind::kInverted}) EXPECT_FALSE(log.warns(k));
  log.policy = GuardPolicy::kWarn;
  const GuardKind recoverableKinds[] = {GuardKind::kExplosion, GuardKind::kPenetration, GuardKind::kCfl,
                                        GuardKind::kCompression, GuardKind::kEnergyGrowth};
  for (GuardKind k : recoverableKinds) EXPECT_TRUE(log.warns(k)) << toString(k);
  for (GuardKind k : {GuardKind::kNone, GuardKind::kNaN, GuardKind::kInverted}) EXPECT_FALSE(log.warns(k)) << toString(k);
  GuardRecord a;
  a.kind = GuardKind::kPenetration;
  a.step = 13;
  GuardRecord b = a;
  b.step = 14;
  GuardRecord c;
  c.kind = GuardKind::kEnergyGrowth;
  c.step = 20;
  EXPECT_FALSE(log.seen(GuardKind::kPenetration));
  log.add(a);
  log.add(b);
  log.add(c);
  EXPECT_TRUE(log.seen(GuardKind::kPenetration));
  EXPECT_EQ(log.count(GuardKind::kPenetration), 2);
  EXPECT_EQ(log.count(GuardKind::kEnergyGrowth), 1);
  EXPECT_EQ(log.total(), 3);
  ASSERT_EQ(log.first().size(), 2u);
  EXPECT_EQ(log.first()[0].step, 13);  // the first penetration, not the second
  EXPECT_EQ(log.first()[1].kind, GuardKind::kEnergyGrowth);
}

}  // namespace
}  // namespace physketch
