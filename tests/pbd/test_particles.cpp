// PBD particle-level kinds (soft, rope, cloth) and their coupling with rigid bodies.
// Each test checks against an independent oracle (a closed-form period, conservation of
// momentum, XPBD's iteration independence, the rest state) with its tolerance and why.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <string>

#include <tbb/global_control.h>

#include "core/material_table.h"
#include "pbd/world.h"
#include "tests/pbd/builders.h"

using namespace physketch;
using namespace physketch::pbd;
using namespace physketch::pbd::test;

namespace {

Material makeKind(const char* name, MaterialKind kind, double density = kDensity) {
  Material m = makeMaterial(kind);
  m.name = name;
  m.density = density;
  return m;
}

PbdParams params(int substeps, int iterations, Vec3 gravity = Vec3(0, -9.81, 0)) {
  PbdParams p;
  p.substeps = substeps;
  p.iterations = iterations;
  p.particleRadius = kRadius;
  p.gravity = gravity;
  return p;
}

// A straight chain of n particles from `start` along unit `dir`, one spacing apart.
BodyRange addChain(ParticleArrays& p, const Vec3& start, const Vec3& dir, int n, std::int16_t material) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  for (int k = 0; k < n; ++k) {
    const Vec3 x = start + (k * kSpacing) * dir;
    p.push(float(x.x()), float(x.y()), float(x.z()), 1, material);
  }
  b.count = n;
  b.stroke = 1;
  b.layout = BodyLayout::kChain;
  return b;
}

// A rows x cols lattice, rows going down (-y) from `topLeft` (or along `rowDir`), cols along +x.
BodyRange addSheet(ParticleArrays& p, const Vec3& topLeft, int rows, int cols, std::int16_t material,
                   const Vec3& rowDir = Vec3(0, -1, 0)) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const Vec3 x = topLeft + kSpacing * (Vec3(c, 0, 0) + r * rowDir);
      p.push(float(x.x()), float(x.y()), float(x.z()), 2, material);
    }
  b.count = rows * cols;
  b.rows = rows;
  b.cols = cols;
  b.stroke = 2;
  b.layout = BodyLayout::kLattice;
  return b;
}

// A static mesh collider "floor": the rectangle [x0, x1] x [z0, z1] at height y, facing up.
ColliderSet floorSquare(double x0, double x1, double z0, double z1, double y) {
  TriangleSoup soup;
  soup.vertices = {Vec3(x0, y, z0), Vec3(x1, y, z0), Vec3(x1, y, z1), Vec3(x0, y, z1)};
  soup.triangles = {{0, 2, 1}, {0, 3, 2}};
  MeshCollider c;
  c.name = "floor";
  return ColliderSet({c}, {soup});
}

std::vector<std::string> planNames(const PbdWorld& w) {
  std::vector<std::string> out;
  for (const PlanEntry& e : w.plan()) out.push_back(e.name);
  return out;
}

bool has(const std::vector<std::string>& v, const char* s) { return std::find(v.begin(), v.end(), s) != v.end(); }

Vec3 momentum(const PbdWorld& w) {
  Vec3 m = Vec3::Zero();
  const ParticleArrays& p = w.particles();
  for (int b = 0; b < w.bodyCount(); ++b)
    for (std::int32_t i : w.bodyParticles(b)) {
      const auto k = std::size_t(i);
      m += double(p.mass[k]) * Vec3(p.vx[k], p.vy[k], p.vz[k]);
    }
  return m;
}

// The kinetic energy of every body's particles (a rigid body's carry its rigid motion) (J).
double kineticEnergy(const PbdWorld& w) {
  double k = 0.0;
  const ParticleArrays& q = w.particles();
  for (int b = 0; b < w.bodyCount(); ++b)
    for (std::int32_t i : w.bodyParticles(b)) {
      const auto n = std::size_t(i);
      k += 0.5 * double(q.mass[n]) * Vec3(q.vx[n], q.vy[n], q.vz[n]).squaredNorm();
    }
  return k;
}

}  // namespace

// A rope hanging from a fixed beam carries a bob 22.6x its mass; released at 0.1 rad it
// swings with the period of a simple pendulum of length L (pivot to the bob's centre),
// T0 = 2 pi sqrt(L/g). Tolerance 3 % (the issue's): the rope's own mass shortens the
// period by about 0.4 % (a rigid rod of 1/22.6 of the mass) and the bob's size lengthens it
// by 0.1 %, the amplitude by 0.06 %; a stretching rope (weak tethers, slow Gauss-Seidel
// convergence under a 1:1000 mass ratio per particle) would lengthen it by far more.
TEST(Rope, PendulumPeriodMatchesTheSimplePendulum) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("beam", MaterialKind::kRigid), makeKind("rope", MaterialKind::kRope, 100.0),
                                makeKind("bob", MaterialKind::kRigid)};
  mats[1].strand.bendCompliance = 1.0;
  const double theta0 = 0.1;
  const Vec3 dir(std::sin(theta0), -std::cos(theta0), 0.0);
  BodyRange beam = addBox(p, Vec3(-0.01, 1.0, -0.01), 3, 1, 3, 0, 0);
  beam.init.fixed = true;
  const Vec3 pivot = Vec3(0.0, 1.0, 0.0) + kSpacing * dir;  // the rope's first particle, one spacing below the beam
  const int n = 50;
  BodyRange rope = addChain(p, pivot, dir, n, 1);
  const int bobCells = 3;  // radius 0.03 m
  const Vec3 bobCentre = pivot + ((n - 1) * kSpacing + kSpacing + bobCells * kSpacing) * dir;
  BodyRange bob = addBall(p, bobCentre, bobCells, 3, 2);
  const double ropeMass = n * 100.0 * std::pow(kSpacing, 3), bobMass = bob.count * kDensity * std::pow(kSpacing, 3);
  ASSERT_GE(bobMass, 20.0 * ropeMass);
  PbdParams prm = params(20, 2);
  PbdWorld w(p, {beam, rope, bob}, mats, prm);
  const double L = (bobCentre - pivot).norm();
  const double T0 = 2.0 * M_PI * std::sqrt(L / 9.81);
  // Upward crossings of the bob's x through the pivot's, interpolated linearly in time.
  std::vector<double> ups;
  double prev = w.pose(2).centre.x() - pivot.x();
  const int steps = int(4.0 * T0 / prm.dt);
  for (int s = 0; s < steps; ++s) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    const double x = w.pose(2).centre.x() - pivot.x();
    if (prev < 0.0 && x >= 0.0) ups.push_back(w.time() - prm.dt * x / (x - prev));
    prev = x;
  }
  ASSERT_GE(ups.size(), 3u) << "the bob did not swing";
  const double T = (ups.back() - ups.front()) / double(ups.size() - 1);
  EXPECT_NEAR(T / T0, 1.0, 0.03) << "T = " << T << " s, T0 = " << T0 << " s";
  // The rope held: the bob's centre stays within 1 % of L from the pivot.
  EXPECT_NEAR((w.pose(2).centre - pivot).norm() / L, 1.0, 0.01);
}

// XPBD (Macklin et al. 2016): with a compliant stretch constraint, the converged stretch
// is set by the compliance, not by the iteration count. A cloth hanging from a fixed bar
// stretches by the same amount at 4 and 32 iterations: within 5 % (the issue's bound).
// Plain PBD's stiffness k(1-(1-k)^n) depends on n and would differ by far more.
TEST(Cloth, HangingStretchDoesNotDependOnIterations) {
  const auto stretchAt = [](int iterations) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("bar", MaterialKind::kRigid), makeKind("cloth", MaterialKind::kCloth)};
    // m/N: compliant enough (alpha / h^2 = 3600 > 1/m = 1000) that 4 Gauss-Seidel sweeps
    // converge; a stiffer cloth at 4 iterations is limited by iterations, not compliance.
    mats[1].strand.stretchCompliance = 1e-2;
    BodyRange bar = addBox(p, Vec3(0.0, 0.51, 0.0), 12, 1, 1, 0, 0);
    bar.init.fixed = true;
    BodyRange sheet = addSheet(p, Vec3(0.0, 0.50, 0.0), 16, 12, 1);
    PbdParams prm = params(10, iterations);
    PbdWorld w(p, {bar, sheet}, mats, prm);
    const auto length = [&] {
      const ParticleArrays& q = w.particles();
      double top = 0.0, bottom = 0.0;
      for (int c = 0; c < 12; ++c) {
        top += q.y[std::size_t(sheet.first + c)];
        bottom += q.y[std::size_t(sheet.first + 15 * 12 + c)];
      }
      return (top - bottom) / 12.0;
    };
    // Average over the last second: the undamped cloth still bounces a little.
    double sum = 0.0;
    int count = 0;
    for (int s = 0; s < 180; ++s) {
      EXPECT_TRUE(w.step());
      if (s >= 120) sum += length(), ++count;
    }
    return sum / count / (15 * kSpacing) - 1.0;
  };
  const double s4 = stretchAt(4), s32 = stretchAt(32);
  EXPECT_GT(s32, 0.01) << "the cloth should visibly stretch under its weight";
  EXPECT_NEAR(s4 / s32, 1.0, 0.05) << "stretch at 4 iterations " << s4 << ", at 32 " << s32;
}

// Free fall of a loose sheet at 256 substeps per 1/60 s step: nothing constrains it, so its
// centre falls g t^2 / 2 exactly, up to the discrete integrator's h g t / 2 (0.02 % here).
// Tolerance 0.5 %: float positions round each substep's motion to 6e-8 m at 0.5 m, more than
// the first substeps' g h^2 = 4e-8 m; a velocity taken as (p - x) / h lost or doubled that
// motion, and the sheet fell 28 % short (0.098 m for 0.136 m; a hanging cloth lost its weight).
TEST(Cloth, FreeFallAtManySubstepsKeepsItsAcceleration) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("cloth", MaterialKind::kCloth, 300.0)};
  BodyRange sheet = addSheet(p, Vec3(0.0, 0.5, 0.0), 10, 10, 0);
  PbdWorld w(p, {sheet}, mats, params(256, 1));
  const double y0 = w.pose(0).centre.y();
  for (int s = 0; s < 10; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const double t = w.time(), drop = y0 - w.pose(0).centre.y();
  EXPECT_NEAR(drop / (0.5 * 9.81 * t * t), 1.0, 0.005) << "fell " << drop << " m in " << t << " s";
}

// Macklin et al. 2019 ("Small Steps"): many substeps of one iteration each are stable for
// an inextensible cloth. A horizontal 40 x 40 sheet pinned at the two corners of one edge
// by small fixed posts swings down under gravity. Position-based projection only removes
// energy, so the sheet's energy (kinetic plus potential) never rises above its start.
// Tolerance: 2 % of the potential energy the swing releases (M g L / 2, L the sheet's
// side); links solved node by node instead of by family gained it many times over
// within a second at 30 x 1 (100 m/s, a guard trip).
TEST(Cloth, PinnedAtTwoCornersLosesEnergyAtOneIterationPerSubstep) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("post", MaterialKind::kRigid), makeKind("cloth", MaterialKind::kCloth, 300.0)};
  mats[1].strand.stretchCompliance = 0.0;
  mats[1].strand.bendCompliance = 1.0;
  const int n = 40;
  BodyRange postA = addBox(p, Vec3(-0.03, 0.49, -0.03), 3, 3, 3, 0, 0);
  BodyRange postB = addBox(p, Vec3((n - 1) * kSpacing + 0.01, 0.49, -0.03), 3, 3, 3, 3, 0);
  postA.init.fixed = postB.init.fixed = true;
  BodyRange sheet;
  sheet.first = static_cast<std::int32_t>(p.size());
  for (int r = 0; r < n; ++r)  // rows along +z, columns along +x, at y = 0.5
    for (int c = 0; c < n; ++c) p.push(float(c * kSpacing), 0.5f, float(r * kSpacing), 2, 1);
  sheet.count = n * n;
  sheet.rows = sheet.cols = n;
  sheet.stroke = 2;
  sheet.layout = BodyLayout::kLattice;
  PbdWorld w(p, {postA, postB, sheet}, mats, params(30, 1));
  const auto energy = [&](double& lowest) {
    const ParticleArrays& q = w.particles();
    double e = 0.0;
    for (std::int32_t i : w.bodyParticles(2)) {
      const auto k = std::size_t(i);
      const double v2 = double(q.vx[k]) * q.vx[k] + double(q.vy[k]) * q.vy[k] + double(q.vz[k]) * q.vz[k];
      e += q.mass[k] * (0.5 * v2 + 9.81 * q.y[k]);
      lowest = std::min(lowest, double(q.y[k]));
    }
    return e;
  };
  double lowest = 1.0;
  const double e0 = energy(lowest);
  const double released = n * n * 300.0 * std::pow(kSpacing, 3) * 9.81 * 0.5 * (n - 1) * kSpacing;
  double rise = -1e300;
  for (int s = 0; s < 90; ++s) {  // 1.5 s: the sheet swings down and back
    ASSERT_TRUE(w.step()) << w.guard().message();
    rise = std::max(rise, energy(lowest) - e0);
  }
  EXPECT_LT(lowest, 0.3) << "the sheet should swing down from its pins";
  EXPECT_LT(rise, 0.02 * released) << "energy rose by " << rise / released << " of the released potential energy";
}

// Two soft cubes fly at each other in zero gravity: particle contacts push both sides by
// equal and opposite impulses, and each cluster's corrections carry no net momentum, so
// the total momentum is conserved, at every step. Tolerance: 1e-3 of the initial momentum: the
// state is float32, and every position write rounds by up to 3e-8 m at 0.5 m (7e-6 m/s over a
// 4 ms substep); about 1e5 writes per step (pairs and 14 clusters per particle, 4 iterations)
// add up, as a random walk over 240 substeps, to about 5e-4 of it (measured at most 6.0e-4).
// A one-sided contact or cluster correction would be of the order of the exchanged momentum.
// Until 2026-11-29 the clusters' net-momentum shift was subtracted from the positions apart
// from the corrections: a shift under half the float spacing of a position at 0.5 m
// (3e-8 m) was lost from every member alike, a bias, not a random walk, and the momentum wandered
// by up to 6.5e-3 of it (4.3e-3 with today's pass order; it happened to end at 2e-3 when only the
// last step was checked).
TEST(Soft, ZeroGravityCollisionConservesMomentum) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft)};
  BodyRange a = addBox(p, Vec3(0.0, 0.5, 0.0), 6, 6, 6, 0, 0);
  BodyRange b = addBox(p, Vec3(0.09, 0.52, 0.01), 6, 6, 6, 1, 0);
  a.init.velocity = Vec3(0.5, 0.0, 0.0);
  b.init.velocity = Vec3(-0.3, 0.05, 0.0);
  PbdWorld w(p, {a, b}, mats, params(4, 4, Vec3::Zero()));
  const Vec3 m0 = momentum(w);
  bool touched = false;
  double worst = 0.0;
  for (int s = 0; s < 60; ++s) {
    ASSERT_TRUE(w.step());
    touched = touched || has(planNames(w), "find_neighbors");
    worst = std::max(worst, (momentum(w) - m0).norm());
  }
  EXPECT_TRUE(touched);
  // They did collide: the first body no longer moves at 0.5 m/s.
  EXPECT_LT(w.velocity(0).x(), 0.45);
  std::printf("largest momentum change %.3g of the initial momentum\n", worst / m0.norm());
  EXPECT_LT(worst, 1e-3 * m0.norm());
}

// A soft cube spinning at 3 rad/s about a tilted axis in zero gravity turns as a whole: each
// cluster's goals turn with the best-fit rotation of its members, the one whose goals exert no
// net torque on them (the polar factor's optimality). Angular momentum is not kept exactly:
// XPBD's per-member multipliers weight the members' corrections unequally after the first
// iteration, so they carry some torque, and 1 s (half a turn) at 4 x 4 loses 3.3 % (the same
// with the double-precision loops before the float lanes; 2.9 % at 8 substeps). Tolerance 6 %;
// a rotation reversed about one axis (R's (0,1) and (1,0) swapped) loses 21 %. The radius of
// gyration within 1e-4 (measured 1.2e-6: the centrifugal stretch of a 3e3 Pa jelly at 3 rad/s).
TEST(Soft, ASpinningCubeInZeroGravityKeepsItsAngularMomentumAndSize) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft)};
  BodyRange a = addBox(p, Vec3(0.0, 0.5, 0.0), 7, 7, 7, 0, 0);
  a.init.spin = 3.0 * Vec3(0.3, 1.0, 0.2).normalized();
  PbdWorld w(p, {a}, mats, params(4, 4, Vec3::Zero()));
  const auto state = [&](Vec3& L, double& gyration) {
    const ParticleArrays& q = w.particles();
    double m = 0.0;
    Vec3 c = Vec3::Zero();
    for (std::int32_t i : w.bodyParticles(0)) {
      m += q.mass[std::size_t(i)];
      c += double(q.mass[std::size_t(i)]) * Vec3(q.x[std::size_t(i)], q.y[std::size_t(i)], q.z[std::size_t(i)]);
    }
    c /= m;
    L = Vec3::Zero();
    gyration = 0.0;
    for (std::int32_t i : w.bodyParticles(0)) {
      const auto k = std::size_t(i);
      const Vec3 r = Vec3(q.x[k], q.y[k], q.z[k]) - c;
      L += double(q.mass[k]) * r.cross(Vec3(q.vx[k], q.vy[k], q.vz[k]));
      gyration += double(q.mass[k]) * r.squaredNorm();
    }
    gyration = std::sqrt(gyration / m);
  };
  Vec3 L0, L1;
  double g0 = 0.0, g1 = 0.0;
  state(L0, g0);
  ASSERT_GT(L0.norm(), 0.0);
  for (int s = 0; s < 60; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  state(L1, g1);
  EXPECT_LT((L1 - L0).norm(), 0.06 * L0.norm()) << "L0 " << L0.transpose() << " L1 " << L1.transpose();
  EXPECT_NEAR(g1, g0, 1e-4 * g0);
}

// `fixed` works for every kind: a fixed jelly slab or a fixed cloth is a fixed support, and a
// block dropped on it lands as on a fixed rigid slab of the same particles. Before, a rigid
// body met particle-level material only through particle pairs, which drop pairs where neither
// side can move, so the block fell through the fixed jelly to the ground (and, with those pairs
// kept, took each pair's correction in turn and tumbled over). The oracle: the same drop onto
// the slab as a fixed rigid body: the block's rest height within 1e-6 m (the same body-level
// contact on the same particles; float positions), and no tilt.
TEST(Soft, AFixedSoftSlabOrClothHoldsUpABlockAsAFixedRigidSlabDoes) {
  const auto drop = [](MaterialKind slabKind) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("slab", slabKind), makeKind("wood", MaterialKind::kRigid)};
    BodyRange slab;
    if (slabKind == MaterialKind::kCloth) {
      slab = addSheet(p, Vec3(-0.1, 0.2, -0.1), 21, 21, 0, Vec3(0, 0, 1));
    } else {
      slab = addBox(p, Vec3(-0.1, 0.18, -0.1), 21, 3, 21, 0, 0);
    }
    slab.init.fixed = true;
    BodyRange block = addBox(p, Vec3(-0.02, 0.3, -0.02), 5, 5, 5, 1, 1);
    PbdWorld w(p, {slab, block}, mats, params(8, 4));
    for (int s = 0; s < 60; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    return std::make_pair(w.pose(1).centre, w.pose(1).rotation);
  };
  const auto [rigidC, rigidQ] = drop(MaterialKind::kRigid);
  EXPECT_NEAR(rigidC.y(), 0.2 + kSpacing / 2 + 0.02 + kSpacing / 2, 0.5 * kRadius)
      << "the oracle itself: the block rests on the slab's top row";
  for (MaterialKind kind : {MaterialKind::kSoft, MaterialKind::kCloth}) {
    const auto [c, q] = drop(kind);
    EXPECT_NEAR(c.y(), rigidC.y(), 1e-6) << (kind == MaterialKind::kSoft ? "soft" : "cloth");
    EXPECT_NEAR(c.x(), rigidC.x(), 1e-6);
    EXPECT_NEAR(c.z(), rigidC.z(), 1e-6);
    EXPECT_LT(q.angularDistance(rigidQ), 1e-5);
  }
}

// A soft body carried by a move stroke pushes a box ahead of it, as a carried rigid body does
// (RigidBody.ACarriedBodyPushesABoxAtItsOwnSpeed): the pusher is not pushed back, the box leaves
// at about its speed and stays in front. Before, the particle passes did not run for a carried
// particle-level body beside rigid ones, and the pairs they would have found (a carried
// particle has no inverse mass, a rigid one is not particle-level) were dropped: the jelly
// passed through the box. The carried body meets the box at body level, as the shape it has
// when grabbed (holdShape): here the jelly first drifts 3 cm up to the box's level and turns
// 45 degrees about z (zero gravity, 0.3 m/s and 7.85 rad/s for 0.1 s), so it pushes with an
// edge. Then 0.5 m/s along x for 0.5 s after the first touch. Bounds as the rigid test's
// ([0.8, 1.25] x the speed along x, under 0.05 m/s across), and the box's centre ahead of the
// jelly's by what the turned shape reaches: half the box's particle span (0.02 m), one spacing
// of contact, and the jelly's corner at 0.02 sqrt 2 = 0.0283 m: 0.0583, within [0.055, 0.065]
// (the jelly's own give; measured 0.0605). Met as the shape it was made in (unturned), the gap
// was 0.0500.
TEST(Soft, ACarriedSoftBodyPushesABoxAheadOfIt) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("wood", MaterialKind::kRigid)};
  BodyRange box = addBox(p, Vec3(0.0, 0.5, 0.0), 5, 5, 5, 0, 1);
  BodyRange jelly = addBox(p, Vec3(-0.1, 0.47, 0.0), 5, 5, 5, 1, 0);
  jelly.init.velocity = Vec3(0.0, 0.3, 0.0);
  jelly.init.spin = Vec3(0.0, 0.0, 0.25 * 3.14159265358979 / 0.1);  // 45 degrees by the grab
  PbdWorld w(p, {box, jelly}, mats, params(8, 4, Vec3::Zero()));
  for (int s = 0; s < 6; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  w.setMode(1, BodyMode::kKinematic);
  const double speed = 0.5, dt = w.params().dt;
  for (int s = 0; s < 40; ++s) {  // 0.1 m to cover the gap, then 0.23 m of pushing
    w.setKinematicTarget(1, w.pose(1).centre + Vec3(speed * dt, 0.0, 0.0));
    ASSERT_TRUE(w.step()) << w.guard().message();
  }
  const Vec3 v = w.velocity(0);
  EXPECT_GT(v.x(), 0.8 * speed);
  EXPECT_LT(v.x(), 1.25 * speed);
  EXPECT_LT(Vec3(0.0, v.y(), v.z()).norm(), 0.05);
  const double gap = w.pose(0).centre.x() - w.pose(1).centre.x();
  EXPECT_GT(gap, 0.055);
  EXPECT_LT(gap, 0.065);
}

// The same with a rigid body: a soft cube hits a rigid box; the rigid body takes its share
// through its generalized inverse mass, so the momentum of both together is conserved
// (tolerance as above: float32 rounding of the soft side's positions).
TEST(Soft, CollisionWithARigidBodyConservesMomentum) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("box", MaterialKind::kRigid)};
  BodyRange a = addBox(p, Vec3(0.0, 0.5, 0.0), 5, 5, 5, 0, 0);
  BodyRange b = addBox(p, Vec3(0.08, 0.51, 0.0), 5, 5, 5, 1, 1);
  a.init.velocity = Vec3(0.6, 0.0, 0.0);
  PbdWorld w(p, {a, b}, mats, params(4, 4, Vec3::Zero()));
  const auto total = [&] { return momentum(w); };
  const Vec3 m0 = total();
  for (int s = 0; s < 60; ++s) ASSERT_TRUE(w.step());
  EXPECT_GT(w.velocity(1).x(), 0.05) << "the rigid box was pushed";
  EXPECT_LT((total() - m0).norm(), 2e-3 * m0.norm());
}

// A soft cube resting on the ground stays on it (no sinking, no NaN, no drift) and keeps
// its height: within 2 % for E = 5e5 Pa (a linear static sag of rho g H^2 / 2E = 6e-5 m, far
// below a particle spacing); a cube of E = 500 Pa sags by at least a spacing (linear theory
// says 6.3 cm of its 8, a mean strain of 0.39: far outside its range; measured, its top falls
// to 3.1 cm above the ground at 0.17 s and rings about 1.5 cm below where it started). Heights
// are averaged over the last second: the cluster springs are undamped.
TEST(Soft, CubeOnTheGroundKeepsItsShapeAndSoftOneSags) {
  const auto restingHeight = [](double E) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft)};
    mats[0].elastic.youngs = E;
    BodyRange a = addBox(p, Vec3(0.0, kRadius, 0.0), 8, 8, 8, 0, 0);
    PbdWorld w(p, {a}, mats, params(4, 4));
    const Vec3 c0 = w.pose(0).centre;
    double sum = 0.0;
    int count = 0;
    for (int s = 0; s < 180; ++s) {
      EXPECT_TRUE(w.step()) << w.guard().message();
      const auto [lo, hi] = std::minmax_element(w.particles().y.begin(), w.particles().y.end());
      EXPECT_GT(*lo, kRadius - 0.2 * kRadius) << "sank into the ground";
      if (s >= 120) sum += double(*hi - *lo) + kSpacing, ++count;
    }
    // The stiff cube must not slide (2 mm over 3 s: it is at rest). The soft one still
    // walks a few cm while its undamped clusters ring (friction ratchets the wobble; soft
    // damping is open work in issue 8), so it is held only to staying near its place.
    const Vec3 drift = w.pose(0).centre - c0;
    EXPECT_LT(std::hypot(drift.x(), drift.z()), E > 1e5 ? 2e-3 : 0.1) << "slid on the ground";
    return sum / count;
  };
  const double stiff = restingHeight(5e5), soft = restingHeight(5e2);
  EXPECT_NEAR(stiff, 8 * kSpacing, 0.02 * 8 * kSpacing);
  EXPECT_LT(soft, stiff - kSpacing) << "E = 500 Pa should sag by a spacing or more";
}


// A stiff soft ball lands on the ground (issue 8's open item "stiff soft balls tripping the
// guard"). A lattice ball of radius 4 spacings of each preset (E = 5e4, 5e5, 5e6 Pa, e = 0)
// dropped 0.32 m at 4 substeps x 4 iterations (the format's defaults) and at 8 x 4: the guard
// must not stop it, no particle goes into the ground, and the ground gives no energy (the ball's
// kinetic plus potential energy never above its start, within 0.5 % for the particles' float
// positions: a loose check, an impact loses far more). After 2 s it keeps its shape: the rest
// lattice's best rigid fit to it misfits by under 0.05 of its size (the rest strain rho g R / E is
// under 1 % for the softest; measured 0.002-0.021). Before the contacts followed the clusters in
// each iteration and the ground had the last word in particle_update, the clusters' last
// correction pulled the landing ball's lowest layer back into the ground, by up to 2.6 radii, and
// the guard stopped every preset at 4 x 4 and the stiffer two at 8 x 4 (either change alone lands
// them; Rope.AThickRopeTouchesAtItsBrushRadius needs the ground's last word, and
// Soft.ASoftBodyRestsOnARigidOneAtTheContactDistance the order).
TEST(Soft, AStiffBallOfEveryPresetLandsOnTheGround) {
  for (const double E : {5e4, 5e5, 5e6})
    for (const int substeps : {4, 8}) {
      ParticleArrays p;
      std::vector<Material> mats = {makeKind("ball", MaterialKind::kSoft, 1100.0)};
      mats[0].elastic.youngs = E;
      const BodyRange a = addBall(p, Vec3(0.5, 0.32 + 4 * kSpacing + kRadius, 0.5), 4);
      PbdWorld w(p, {a}, mats, params(substeps, 4));
      const auto energy = [&] {
        const ParticleArrays& q = w.particles();
        double e = kineticEnergy(w);
        for (std::size_t n = 0; n < q.size(); ++n) e += double(q.mass[n]) * 9.81 * double(q.y[n]);
        return e;
      };
      const double e0 = energy();
      double most = e0, lowest = 1.0;
      for (int s = 0; s < 120; ++s) {
        ASSERT_TRUE(w.step()) << "E " << E << ", " << substeps << " substeps: " << w.guard().message();
        most = std::max(most, energy());
        for (float y : w.particles().y) lowest = std::min(lowest, double(y));
      }
      // The shape: the rest lattice's best rigid fit to the particles (Kabsch), its rms misfit
      // over the rest offsets' rms.
      const ParticleArrays& q = w.particles();
      const auto at = [](const ParticleArrays& r, std::size_t n) { return Vec3(r.x[n], r.y[n], r.z[n]); };
      Vec3 c0 = Vec3::Zero(), c = Vec3::Zero();
      for (std::size_t n = 0; n < q.size(); ++n) c0 += at(p, n), c += at(q, n);
      c0 /= double(q.size()), c /= double(q.size());
      Mat3 A = Mat3::Zero();
      for (std::size_t n = 0; n < q.size(); ++n) A += (at(q, n) - c) * (at(p, n) - c0).transpose();
      const Mat3 R = polarRotation(A);
      double misfit = 0.0, size = 0.0;
      for (std::size_t n = 0; n < q.size(); ++n)
        misfit += (at(q, n) - c - R * (at(p, n) - c0)).squaredNorm(), size += (at(p, n) - c0).squaredNorm();
      const double strain = std::sqrt(misfit / size);
      std::printf("E %.0e, %d substeps: lowest %.5f m (radius %.4f), energy at most %.5f of the start's, shape misfit %.4f\n",
                  E, substeps, lowest, kRadius, most / e0, strain);
      EXPECT_GE(lowest, kRadius - 1e-6) << "E " << E << ", " << substeps << " substeps: went into the ground";
      EXPECT_LT(most, 1.005 * e0) << "E " << E << ", " << substeps << " substeps: the ground gave energy";
      EXPECT_LT(strain, 0.05) << "E " << E << ", " << substeps << " substeps";
    }
}

// A soft body resting on a fixed rigid slab rests on its particles at the contact distance (the
// oracle: two particle spheres of radius r touch at 2 r; over a hollow between four of a square
// lattice's particles at sqrt(2) r above their centres). A 6^3 soft cube (E = 5e5 Pa) set down
// on a 21 x 3 x 21 fixed slab, its lattice over the slab's or half a spacing off it in x and z,
// at 4 x 4; its lowest particle after 2 s, above the slab's top centres: 0.95-1.05 and 0.70-0.75
// spacings (1 and 0.707, less a margin for what the load presses in, and not held off above
// them). Measured 1.000 / 0.710.
// Until the clusters ran before the contacts in each iteration, their last correction pulled
// the bottom layer back into the slab: 0.690 over the slab's lattice (a third of a spacing into
// its particles), and a 4 cm ball of E = 5e5 or 5e6 rested on a table's face, half a spacing
// deep, where particle_update's sweep held it. The half-off case guards the hollows' geometry
// (the old order also read 0.690 there).
TEST(Soft, ASoftBodyRestsOnARigidOneAtTheContactDistance) {
  for (const double off : {0.0, 0.5}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("slab", MaterialKind::kRigid)};
    mats[0].elastic.youngs = 5e5;
    const double top = 0.1 + 2 * kSpacing;
    std::vector<BodyRange> bodies{addBox(p, Vec3(0.45 + off * kSpacing, top + 1.5 * kSpacing, 0.45 + off * kSpacing), 6, 6, 6, 0, 0),
                                  addBox(p, Vec3(0.4, 0.1, 0.4), 21, 3, 21, 1, 1)};
    bodies[1].init.fixed = true;
    PbdWorld w(p, bodies, mats, params(4, 4));
    for (int s = 0; s < 120; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    double lowest = 1.0;
    for (std::int32_t k = 0; k < bodies[0].count; ++k) lowest = std::min(lowest, double(w.particles().y[std::size_t(k)]));
    const double gap = (lowest - top) / kSpacing;
    std::printf("lattice %s the slab's: lowest particle %.3f spacings above its top centres\n", off == 0.0 ? "over" : "half off", gap);
    EXPECT_GE(gap, off == 0.0 ? 0.95 : 0.70) << "offset " << off;
    EXPECT_LE(gap, off == 0.0 ? 1.05 : 0.75) << "offset " << off;
  }
}

// The drop scenes of the bounce tests: body 0 (material `falling`, made by `add` with its lowest
// particle centre 0.2 m above its landing height `floor`) over the ground, a fixed rigid slab
// 21 x 4 x 21 (material e = slabE) or a static mesh floor at 0.2 m. Returns the top of its first
// bounce above where it touched (firstBounceApex; -1 if it did not bounce).
enum class Under { kGround, kSlab, kMesh };
double dropApex(const Material& falling, Under under, double slabE,
                const std::function<BodyRange(ParticleArrays&, double floor)>& add) {
  ParticleArrays p;
  std::vector<Material> mats = {falling, makeKind("slab", MaterialKind::kRigid)};
  mats[1].restitution = slabE;
  const double floor = under == Under::kSlab ? 0.1 + 3 * kSpacing + kRadius : under == Under::kMesh ? 0.2 : 0.0;
  std::vector<BodyRange> bodies{add(p, floor)};
  if (under == Under::kSlab) {
    bodies.push_back(addBox(p, Vec3(0.4, 0.1, 0.4), 21, 4, 21, 1, 1));
    bodies[1].init.fixed = true;
  }
  PbdWorld w(p, bodies, mats, params(8, 4, Vec3(0, -9.81, 0)));
  if (under == Under::kMesh) {
    w.setColliders(floorSquare(0.2, 0.8, 0.2, 0.8, 0.2));
  }
  return firstBounceApex(w, 0, w.pose(0).centre.y() - 0.2, /*rising=*/0.05);
}

// The bounce tests' check (body 0 of e = 0.8 dropped h0 = 0.2 m, see dropApex): it rises to
// e^2 h0 off the ground, a slab of e = 0.8 (the pair's mean 0.8) and the mesh floor (its own
// e), and to 0.4^2 h0 off a slab of e = 0 (mean 0.4). Tolerance 3 % of h0 (the approach is read
// before a substep's solve; the slab's lattice is bumpy).
void expectBouncesToESquared(const char* what, const Material& falling,
                             const std::function<BodyRange(ParticleArrays&, double floor)>& add) {
  const auto apex = [&](Under under, double slabE) { return dropApex(falling, under, slabE, add); };
  const double ground = apex(Under::kGround, 0.0), slab = apex(Under::kSlab, 0.8), mesh = apex(Under::kMesh, 0.0),
               dull = apex(Under::kSlab, 0.0);
  std::printf("%s e 0.8 from 0.2 m: apex %.4f (ground), %.4f (slab e 0.8), %.4f (mesh floor), %.4f (slab e 0; "
              "closed forms 0.128 and 0.032)\n",
              what, ground, slab, mesh, dull);
  EXPECT_NEAR(ground, 0.64 * 0.2, 0.03 * 0.2) << what;
  EXPECT_NEAR(slab, 0.64 * 0.2, 0.03 * 0.2) << what;
  EXPECT_NEAR(mesh, 0.64 * 0.2, 0.03 * 0.2) << what;
  EXPECT_NEAR(dull, 0.16 * 0.2, 0.03 * 0.2) << what;
}

// Restitution of soft bodies (issue 8: "a ball bounces", every kind). A stiff soft ball
// (E = 5e5 Pa) of e = 0.8 dropped h0 = 0.2 m rises to e^2 h0 (closed form, as a rigid ball):
// off the ground, off a fixed rigid slab of e = 0.8 (the pair's e is the mean, 0.8), off a
// static mesh floor (the ball's own e), and off a slab of e = 0 (mean 0.4: 0.032 m). Tolerance
// 3 % of h0, the rigid pair test's (the approach is read before a substep's solve; the
// slab's lattice is bumpy). Measured 0.1241 m for e = 0.8 and 0.0290 m for 0.4. Without
// restitution at the body the ball did not bounce at all (contact stops the touching layer,
// shape matching averages it away): measured no apex on the ground, 0.012 m on the slab.
TEST(Soft, ASoftBallBouncesOffTheGroundABodyAndAMeshFloor) {
  Material jelly = makeKind("jelly", MaterialKind::kSoft);
  jelly.elastic.youngs = 5e5;
  jelly.restitution = 0.8;
  expectBouncesToESquared("soft ball", jelly, [](ParticleArrays& p, double floor) {
    return addBall(p, Vec3(0.5, floor + 0.2 + 6 * kSpacing + kRadius, 0.5), 6, 0, 0);
  });
}

// A dynamic slab lying on the ground is a surface like a fixed one when a soft body lands on it:
// the ground holds it against the blow. A stiff soft ball (e = 0.8) dropped h0 = 0.2 m onto a
// 21 x 4 x 21 slab of e = 0.8 resting on the ground rises to e^2 h0, and so does a soft bar
// dropped across that slab and a fixed one beside it (it hits both at once). Tolerance 4 % of
// h0: the fixed slab's 3 %, and the slab between the ball and the ground gives a little under
// the blow within the substep's iterations (measured 0.121 m for the ball, 0.124 on a fixed
// slab; the bar 0.126). Before the ground held the slab, the ball bounced off it as off a free
// body (0.059 m) and the bar, hitting a dynamic body and something else at once, hardly at all
// (0.012 m).
TEST(Soft, ASoftBodyBouncesOffASlabLyingOnTheGroundAsOffAFixedOne) {
  Material jelly = makeKind("jelly", MaterialKind::kSoft);
  jelly.elastic.youngs = 5e5;
  jelly.restitution = 0.8;
  const double top = kRadius + 3 * kSpacing;  // the slabs' top particle centres
  const auto drop = [&](bool bar) {
    ParticleArrays p;
    std::vector<Material> mats = {jelly, makeKind("slab", MaterialKind::kRigid)};
    mats[1].restitution = 0.8;
    const double lowest = top + kSpacing + 0.2;  // the falling body's lowest particle centre
    std::vector<BodyRange> bodies{bar ? addBox(p, Vec3(0.35, lowest, 0.46), 30, 4, 6, 0, 0)
                                      : addBall(p, Vec3(0.5, lowest + 6 * kSpacing, 0.5), 6, 0, 0)};
    bodies.push_back(addBox(p, Vec3(bar ? 0.505 : 0.4, kRadius, 0.4), bar ? 10 : 21, 4, 21, 1, 1));  // on the ground
    if (bar) {
      bodies.push_back(addBox(p, Vec3(0.395, kRadius, 0.4), 10, 4, 21, 2, 1));  // beside it, fixed
      bodies.back().init.fixed = true;
    }
    PbdWorld w(p, bodies, mats, params(8, 4, Vec3(0, -9.81, 0)));
    return firstBounceApex(w, 0, w.pose(0).centre.y() - 0.2, /*rising=*/0.05);
  };
  const double ball = drop(false), bar = drop(true);
  std::printf("soft ball on a slab lying on the ground: apex %.4f; soft bar across it and a fixed slab: %.4f "
              "(closed form 0.128)\n", ball, bar);
  EXPECT_NEAR(ball, 0.64 * 0.2, 0.04 * 0.2);
  EXPECT_NEAR(bar, 0.64 * 0.2, 0.04 * 0.2);
}

// Against a dynamic rigid body the pair shares the bounce (zero gravity, head-on): a stiff soft
// ball of e = 0.8 at 1 m/s hits a resting rigid box of e = 0.8 (the pair's e: 0.8); afterwards
// they separate at e times the approach speed (Newton's law of restitution, closed form;
// tolerance 5 % of it: the ball's own elastic ringing moves its centre's speed by a few %) and
// momentum is kept (the box took the opposite impulse; 2e-3 relative, the inelastic test's).
// Restitution only adds speed: this contact alone (e = 0) already separates at 0.49 m/s (the
// ball's clusters store and give back part of the impact), so e is tested above that.
TEST(Soft, ASoftBallAndADynamicBodySeparateAtETimesTheirApproachSpeed) {
  for (double e : {0.8, 0.65}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("box", MaterialKind::kRigid)};
    mats[0].elastic.youngs = 5e5;
    mats[0].restitution = e;
    mats[1].restitution = e;
    BodyRange ball = addBall(p, Vec3(0.0, 0.5, 0.0), 4, 0, 0);
    BodyRange box = addBox(p, Vec3(0.06, 0.46, -0.04), 9, 9, 9, 1, 1);
    ball.init.velocity = Vec3(1.0, 0.0, 0.0);
    PbdWorld w(p, {ball, box}, mats, params(8, 4, Vec3::Zero()));
    const Vec3 m0 = momentum(w);
    for (int s = 0; s < 30; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    const double separation = w.velocity(1).x() - w.velocity(0).x();
    std::printf("e %.2f: separation speed %.4f m/s (closed form %.2f)\n", e, separation, e);
    EXPECT_NEAR(separation, e * 1.0, 0.05) << "e " << e;
    EXPECT_LT((momentum(w) - m0).norm(), 2e-3 * m0.norm());
  }
}

// Two soft balls (e 0.8 and 0.8, zero gravity) meeting head-on at 1 m/s separate at e times
// that (Newton's law; 5 %, as above), momentum kept (2e-3 relative).
TEST(Soft, TwoSoftBallsSeparateAtETimesTheirApproachSpeed) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft)};
  mats[0].elastic.youngs = 5e5;
  mats[0].restitution = 0.8;
  BodyRange a = addBall(p, Vec3(0.0, 0.5, 0.0), 4, 0, 0);
  BodyRange b = addBall(p, Vec3(0.1, 0.5, 0.0), 4, 1, 0);
  a.init.velocity = Vec3(0.5, 0.0, 0.0);
  b.init.velocity = Vec3(-0.5, 0.0, 0.0);
  PbdWorld w(p, {a, b}, mats, params(8, 4, Vec3::Zero()));
  const Vec3 m0 = momentum(w);
  const double scale = 0.5 * double(w.bodyParticles(0).size()) * kParticleMass;  // |each body's momentum|
  for (int s = 0; s < 30; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const double separation = w.velocity(1).x() - w.velocity(0).x();
  std::printf("two soft balls: separation speed %.4f m/s (closed form 0.80)\n", separation);
  EXPECT_NEAR(separation, 0.8, 0.05);
  EXPECT_LT((momentum(w) - m0).norm(), 2e-3 * scale);
}

// A flat cloth in the x-z plane, rows along +z from `corner`.
BodyRange addFlatSheet(ParticleArrays& p, const Vec3& corner, int rows, int cols, std::int16_t material) {
  return addSheet(p, corner, rows, cols, material, Vec3(0, 0, 1));
}

// Restitution particle by particle (issue 8: every kind bounces, against everything): a flat
// cloth of e = 0.8 (no friction), dropped h0 = 0.2 m level, hits with every particle at once,
// so it bounces as one plate and rises to e^2 h0 (closed form, the balls' tests') with e the
// pair's: off the ground (the particle's own e), a fixed rigid slab of e = 0.8 (mean 0.8), a
// static mesh floor (own e) and a slab of e = 0 (mean 0.4: 0.032 m). Tolerance 3 % of h0, the
// soft ball's (the approach is read before a substep's solve). Before this, the cloth bounced
// only off the ground: on the slab and the mesh it stopped dead (no apex).
TEST(Cloth, AFallingClothBouncesOffTheGroundABodyAndAMeshFloor) {
  Material cloth = makeKind("cloth", MaterialKind::kCloth);
  cloth.restitution = 0.8;
  cloth.staticFriction = cloth.dynamicFriction = 0.0;
  expectBouncesToESquared("cloth", cloth, [](ParticleArrays& p, double floor) {
    return addFlatSheet(p, Vec3(0.42, floor + 0.2 + kRadius, 0.42), 12, 12, 0);
  });
}

// Against a dynamic body (zero gravity): a flat cloth moving at 1 m/s hits the face of a resting
// rigid box head-on, both of e = 0.8, then both of e = 1. They separate at e times the approach
// speed (Newton's law; 3 %, the soft tests' margin), momentum is kept (the box takes each
// particle's impulse at its contact point; 2e-3 relative, float32 rounding) and at e = 1 the
// kinetic energy does not grow (0.1 %). The 36 particles' impulses are solved together
// (Gauss-Seidel sweeps): applied once each in turn, the first left against a box the others had
// not pushed yet, and the cloth separated at 0.845 m/s for e = 0.8 (energy would grow at e = 1).
TEST(Cloth, AClothAndADynamicBodySeparateAtETimesTheirApproachSpeed) {
  for (double e : {0.8, 1.0}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("cloth", MaterialKind::kCloth), makeKind("box", MaterialKind::kRigid)};
    mats[0].restitution = mats[1].restitution = e;
    mats[0].staticFriction = mats[0].dynamicFriction = 0.0;
    BodyRange sheet = addFlatSheet(p, Vec3(-0.03, 0.5, -0.03), 6, 6, 0);
    BodyRange box = addBox(p, Vec3(-0.04, 0.3, -0.04), 8, 8, 8, 1, 1);  // top face at 0.37 + r
    sheet.init.velocity = Vec3(0.0, -1.0, 0.0);
    PbdWorld w(p, {sheet, box}, mats, params(8, 4, Vec3::Zero()));
    const Vec3 m0 = momentum(w);
    const double k0 = kineticEnergy(w);
    for (int s = 0; s < 20; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    const double separation = w.velocity(0).y() - w.velocity(1).y();
    std::printf("cloth on a dynamic box, e %.1f: separation speed %.4f m/s (closed form %.1f), energy %.4f of before\n",
                e, separation, e, kineticEnergy(w) / k0);
    EXPECT_LT(w.velocity(1).y(), -0.05) << "the box was pushed";
    EXPECT_NEAR(separation, e, 0.03 * e);
    EXPECT_LT((momentum(w) - m0).norm(), 2e-3 * m0.norm());
    EXPECT_LT(kineticEnergy(w), 1.001 * k0) << "e " << e;
  }
}

// A soft ball sliding on the ground (no friction anywhere) into a wall bounces back at e times
// its speed (e = 0.8 both sides; Newton's law, 5 % as the head-on tests): the ground it rests
// on is a contact too, but one it does not approach, so it takes no part in the bounce. Off a
// fixed wall the ball returns at 0.8 m/s; off a free box resting on the same ground the two
// separate at 0.8 m/s and keep their momentum along x (2e-3 relative; the ground pushes only
// up). Before, the resting contacts were averaged into the bounce's normal (fixed wall) or made
// it inelastic (a dynamic body and something else).
TEST(Soft, ASoftBallSlidingIntoAWallOrABoxBounces) {
  for (bool fixedWall : {true, false}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("box", MaterialKind::kRigid)};
    mats[0].elastic.youngs = 5e5;
    for (Material& m : mats) m.restitution = 0.8, m.staticFriction = m.dynamicFriction = 0.0;
    BodyRange ball = addBall(p, Vec3(0.1, 4 * kSpacing + kRadius, 0.0), 4, 0, 0);
    // 9 particles tall: the box's centre is at the ball's height, so the impulse turns neither.
    BodyRange box = addBox(p, Vec3(0.2, kRadius, -0.06), 6, 9, 12, 1, 1);
    ball.init.velocity = Vec3(1.0, 0.0, 0.0);
    box.init.fixed = fixedWall;
    PbdWorld w(p, {ball, box}, mats, params(8, 4));
    const double m0x = momentum(w).x();
    for (int s = 0; s < 12; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    const double separation = w.velocity(1).x() - w.velocity(0).x();
    std::printf("soft ball into a %s box: separation speed %.4f m/s (closed form 0.80)\n", fixedWall ? "fixed" : "free",
                separation);
    EXPECT_NEAR(separation, 0.8, 0.05) << (fixedWall ? "fixed wall" : "free box");
    if (!fixedWall) {
      EXPECT_LT(std::abs(momentum(w).x() - m0x), 2e-3 * std::abs(m0x));
    }
  }
}

namespace {

// A stiff jelly (5e5 Pa) and wood, both of e = 0.8 and without friction: the corner tests below.
std::vector<Material> bouncyJellyAndWood() {
  std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("wood", MaterialKind::kRigid)};
  mats[0].elastic.youngs = 5e5;
  for (Material& m : mats) m.restitution = 0.8, m.staticFriction = m.dynamicFriction = 0.0;
  return mats;
}

}  // namespace

// A soft ball hitting a free dynamic body and a fixed one in the same substep bounces off both
// (zero gravity, no friction, e = 0.8 everywhere): thrown at (1, -1, 0) m/s into the corner between
// a fixed floor slab (normal +y) and a free box floating beside it (normal -x, its centre at the
// contact's height), it reaches both at once. Closed form, the two contacts being orthogonal: the
// floor sends the ball up at 0.8 m/s, and the ball and box separate along x at 0.8 m/s with their
// x momentum kept (Newton's law for each contact; 5 %, the soft tests' margin; momentum 2e-3
// relative). Before, a body that hit a free partner and something else at once stayed inelastic:
// the ball left the floor at 0.32 m/s and the box at 0.49 m/s (its clusters' own rebound alone).
TEST(Soft, ASoftBallHittingAFreeBoxAndTheFloorAtOnceBouncesOffBoth) {
  ParticleArrays p;
  const std::vector<Material> mats = bouncyJellyAndWood();
  // Floor: top layer at y = 0.33; box: left face at x = 0.10, y 0.35..0.41 (centre 0.38), clear
  // of the floor by a spacing. The ball (radius 4 spacings) touches both with its centre at
  // (0.05, 0.38); it starts 4.9 cm back along both axes (5 cm would reach both exactly at the end
  // of a substep, where round-off picks one contact for each of two substeps).
  BodyRange floor = addBox(p, Vec3(-0.2, 0.30, -0.1), 41, 4, 21, 1, 1);
  floor.init.fixed = true;
  BodyRange box = addBox(p, Vec3(0.10, 0.35, -0.06), 6, 7, 13, 2, 1);
  BodyRange ball = addBall(p, Vec3(0.001, 0.429, 0.0), 4, 0, 0);
  ball.init.velocity = Vec3(1.0, -1.0, 0.0);
  PbdWorld w(p, {ball, floor, box}, mats, params(8, 4, Vec3::Zero()));
  const double m0x = momentum(w).x();
  for (int s = 0; s < 9; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const Vec3 vBall = w.velocity(0), vBox = w.velocity(2);
  std::printf("ball %.4f %.4f m/s, box %.4f m/s: up %.4f (closed form 0.80), apart along x %.4f (0.80)\n", vBall.x(),
              vBall.y(), vBox.x(), vBall.y(), vBox.x() - vBall.x());
  EXPECT_NEAR(vBall.y(), 0.8, 0.05);
  EXPECT_NEAR(vBox.x() - vBall.x(), 0.8, 0.05);
  EXPECT_LT(std::abs(momentum(w).x() - m0x), 2e-3 * std::abs(m0x));
}

// The same corner with both sides free: the slab under the ball floats too (its centre under the
// contact, so neither impulse turns a body). The two contacts are orthogonal, so each is a
// collision of two free bodies along its own axis (closed form: Newton's law for each contact,
// apart at 0.8 m/s along y from the slab and along x from the box, and each axis's momentum kept;
// 5 %, the soft tests' margin; momentum 2e-3 relative). Before, a soft body that hit two free
// partners at once stayed inelastic: apart at 0.57 m/s from the slab and 0.55 m/s from the box
// (its clusters' own rebound alone).
TEST(Soft, ASoftBallHittingTwoFreeBodiesAtOnceBouncesOffBoth) {
  ParticleArrays p;
  const std::vector<Material> mats = bouncyJellyAndWood();
  // As above, with the slab's centre (x 0.05, z 0) under the ball's contact point.
  BodyRange slab = addBox(p, Vec3(-0.15, 0.30, -0.1), 41, 4, 21, 1, 1);
  BodyRange box = addBox(p, Vec3(0.10, 0.35, -0.06), 6, 7, 13, 2, 1);
  BodyRange ball = addBall(p, Vec3(0.001, 0.429, 0.0), 4, 0, 0);
  ball.init.velocity = Vec3(1.0, -1.0, 0.0);
  PbdWorld w(p, {ball, slab, box}, mats, params(8, 4, Vec3::Zero()));
  const Vec3 m0 = momentum(w);
  for (int s = 0; s < 9; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const Vec3 vBall = w.velocity(0), vSlab = w.velocity(1), vBox = w.velocity(2);
  std::printf("ball (%.4f, %.4f), slab y %.4f, box x %.4f m/s: apart along y %.4f, along x %.4f (closed form 0.80)\n",
              vBall.x(), vBall.y(), vSlab.y(), vBox.x(), vBall.y() - vSlab.y(), vBox.x() - vBall.x());
  EXPECT_NEAR(vBall.y() - vSlab.y(), 0.8, 0.05);
  EXPECT_NEAR(vBox.x() - vBall.x(), 0.8, 0.05);
  EXPECT_LT((momentum(w) - m0).norm(), 2e-3 * m0.norm());
}

// Two free boxes side by side (a spacing apart in z), hit face on and at once by a soft slab
// that covers both faces (zero gravity, no friction, e = 0.8): the contacts share a normal, so
// each impulse moves the slab away from the other box too (the coupled case of the
// complementarity problem). The slab's contact covers each box's whole face, through its
// centre, so neither turns much. Closed form (Newton's law at each contact, momentum kept, the boxes
// alike): each box leaves at m (1 + e) u / (m + 2 M), the slab at that less e u, with m and M
// the slab's and a box's mass from their particle counts (5 %, the soft tests' margin).
// Before, inelastic: boxes 0.52, slab 0.42 m/s against 0.84 and 0.04.
TEST(Soft, ASoftSlabHittingTwoFreeBoxesSideBySideBouncesOffBoth) {
  ParticleArrays p;
  const std::vector<Material> mats = bouncyJellyAndWood();
  BodyRange slab = addBox(p, Vec3(0.0, 0.29, -0.125), 4, 11, 26, 0, 0);  // y 0.29..0.39, z -0.125..0.125
  BodyRange boxA = addBox(p, Vec3(0.07, 0.30, 0.005), 6, 9, 12, 1, 1);    // y 0.30..0.38, z 0.005..0.115
  BodyRange boxB = addBox(p, Vec3(0.07, 0.30, -0.115), 6, 9, 12, 2, 1);   // z -0.115..-0.005
  slab.init.velocity = Vec3(1.0, 0.0, 0.0);
  PbdWorld w(p, {slab, boxA, boxB}, mats, params(8, 4, Vec3::Zero()));
  const double m = slab.count * kParticleMass, M = boxA.count * kParticleMass, e = 0.8, u = 1.0;
  const double vBox = m * (1.0 + e) * u / (m + 2.0 * M), vSlab = vBox - e * u;
  for (int s = 0; s < 8; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  std::printf("soft slab into two free boxes: slab %.4f, boxes %.4f and %.4f m/s (closed form %.4f, %.4f)\n",
              w.velocity(0).x(), w.velocity(1).x(), w.velocity(2).x(), vSlab, vBox);
  EXPECT_NEAR(w.velocity(1).x(), vBox, 0.05 * vBox);
  EXPECT_NEAR(w.velocity(2).x(), vBox, 0.05 * vBox);
  EXPECT_NEAR(w.velocity(0).x(), vSlab, 0.05 * u);
  // Neither turns much: its corners (7 cm from its centre) move at under 2 % of its speed
  // (measured 0.10 rad/s: the contact solve's order, not the bounce).
  for (int box : {1, 2}) EXPECT_LT(w.angularVelocity(box).norm() * 0.07, 0.02 * vBox) << "box " << box;
}

// Two particle-level bodies (zero gravity): two straight ropes of e 0.8 and 0.6 (the pair's e:
// 0.7), one above the other and moving towards each other at 0.5 m/s each, meet along their
// whole length and separate at e times their approach speed (Newton's law, closed form: 0.7
// m/s; 3 %, every particle of a rope hits at once, so it moves as one body), momentum kept
// (2e-3 relative). Before particle pairs bounced, they stopped against each other.
TEST(Rope, TwoRopesSeparateAtETimesTheirApproachSpeed) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("rope a", MaterialKind::kRope), makeKind("rope b", MaterialKind::kRope)};
  mats[0].restitution = 0.8, mats[1].restitution = 0.6;
  for (Material& m : mats) m.staticFriction = m.dynamicFriction = 0.0;
  BodyRange a = addChain(p, Vec3(0.0, 0.5, 0.0), Vec3(1, 0, 0), 20, 0);
  BodyRange b = addChain(p, Vec3(0.0, 0.55, 0.0), Vec3(1, 0, 0), 20, 1);
  a.stroke = 0, b.stroke = 1;
  a.init.velocity = Vec3(0.0, 0.5, 0.0);
  b.init.velocity = Vec3(0.0, -0.5, 0.0);
  PbdWorld w(p, {a, b}, mats, params(8, 4, Vec3::Zero()));
  const Vec3 m0 = momentum(w);
  const double scale = 0.5 * 20 * kParticleMass;  // |each rope's momentum|
  for (int s = 0; s < 10; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const double separation = w.velocity(1).y() - w.velocity(0).y();
  std::printf("two ropes: separation speed %.4f m/s (closed form 0.70)\n", separation);
  EXPECT_NEAR(separation, 0.7, 0.03 * 0.7);
  EXPECT_LT((momentum(w) - m0).norm(), 2e-3 * scale);
}

// A rope's contact radius is its brush's half size (BodyRange::radius; docs/formats.md), not
// the voxel's. Straight 20-particle ropes of radius R = 2 spacings (R / r = 4) fall 5 cm and
// settle, each on something else: the ground, a fixed slab (a rope right above a row of its
// particles), a mesh collider floor (a square of two triangles at y = 0.2), and another rope
// of radius R lying on the ground across it. They rest where geometry puts a sphere of radius
// R: centres R above the ground and above the mesh floor, R + r above the slab's top particle
// centres, 2R above the other rope's. Tolerance 0.5 mm (a tenth of the r they would rest at were the
// radius ignored, 3 r lower): PBD leaves a resting particle in a contact exactly at its
// distance after the substep's projection, so what remains is the last substep's gravity sag
// (g h^2 = 4 um at 8 substeps of 1/60 s) and the dimples between the particles below (the rope
// sits right above them, and friction holds it there). (The rope below is thick too: under a
// rope 16 times heavier a thin one gave way by 1.8 mm at 4 iterations, the mass ratio's slow
// Gauss-Seidel convergence, not the radius.)
TEST(Rope, AThickRopeTouchesAtItsBrushRadius) {
  const double R = 2.0 * kSpacing;
  enum class On { kGround, kSlab, kMesh, kRope };
  for (On under : {On::kGround, On::kSlab, On::kMesh, On::kRope}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("thick", MaterialKind::kRope), makeKind("slab", MaterialKind::kRigid),
                                  makeKind("thin", MaterialKind::kRope)};
    // The level the rope's centres should come to rest at, the oracle.
    const double rest = under == On::kGround ? R
                        : under == On::kSlab ? 0.1 + 3 * kSpacing + kRadius + R
                        : under == On::kMesh ? 0.2 + R
                                                : 3.0 * R;
    BodyRange thick = addChain(p, Vec3(0.3, rest + 0.05, 0.5), Vec3(1, 0, 0), 20, 0);
    thick.radius = float(R);
    std::vector<BodyRange> bodies{thick};
    if (under == On::kSlab) {
      bodies.push_back(addBox(p, Vec3(0.25, 0.1, 0.4), 30, 4, 21, 1, 1));
      bodies[1].init.fixed = true;
    } else if (under == On::kRope) {
      // Across the falling one's middle, on the ground: its particle at x = 0.4 is right below.
      bodies.push_back(addChain(p, Vec3(0.4, R, 0.4), Vec3(0, 0, 1), 21, 2));
      bodies[1].stroke = 2;
      bodies[1].radius = float(R);
    }
    PbdWorld w(p, bodies, mats, params(8, 4, Vec3(0, -9.81, 0)));
    if (under == On::kMesh) {
      w.setColliders(floorSquare(0.1, 0.8, 0.3, 0.7, 0.2));
    }
    // No centre of a rope ever ends a step below R, the ground's contact height for it. The links
    // run after the contacts, and where one rope lies across the other they pressed a centre
    // 0.13 mm into the ground before particle_update gave the ground the last word.
    double lowestEver = 1e30;
    for (int s = 0; s < 60; ++s) {
      ASSERT_TRUE(w.step()) << w.guard().message();
      for (std::size_t b = 0; b < bodies.size(); ++b) {
        if (b == 1 && under == On::kSlab) continue;
        for (std::int32_t i : w.bodyParticles(int(b))) lowestEver = std::min(lowestEver, double(w.particles().y[std::size_t(i)]));
      }
    }
    std::printf("lowest centre ever %.3e m from R\n", lowestEver - R);
    EXPECT_GE(lowestEver, R - 1e-6) << "a rope went into the ground";
    const ParticleArrays& q = w.particles();
    double lowest = 1e30, highest = -1e30;
    for (std::int32_t i : w.bodyParticles(0)) {
      if (under == On::kRope && std::abs(q.x[std::size_t(i)] - 0.4) > 0.5 * kSpacing) continue;  // the crossing
      lowest = std::min(lowest, double(q.y[std::size_t(i)]));
      highest = std::max(highest, double(q.y[std::size_t(i)]));
    }
    std::printf("thick rope on %d: centres at %.5f-%.5f m, geometry %.5f m\n", int(under), lowest, highest, rest);
    EXPECT_NEAR(lowest, rest, 5e-4) << int(under);
    if (under != On::kRope) {
      EXPECT_NEAR(highest, rest, 5e-4) << int(under);  // lying flat
    }
  }
}

// A thick rope is tied where it was drawn touching: its first particle to a fixed beam (pinned),
// its last to a ball (attached). Its particles near the ties overlap the beam and the ball (the
// rope is thicker than the gap it was drawn across) and must not be pushed out of them, or the
// ties and the contacts fight: a rope of radius 2 spacings hanging a ball from a beam was
// pushed 19 mm sideways (its ends out of the beam and the ball). Statics is the oracle: a rope under
// tension hangs straight down from its pin (every particle within 0.5 mm of the vertical
// through it, a twentieth of the rope's 4-spacing thickness) and as long as drawn (end to end
// within 1 %: it is inextensible, stretch compliance 0).
TEST(Rope, AThickRopeHangsStraightFromWhereItIsTied) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("beam", MaterialKind::kRigid), makeKind("rope", MaterialKind::kRope, 100.0),
                                makeKind("bob", MaterialKind::kRigid)};
  const double R = 2.0 * kSpacing;
  BodyRange beam = addBox(p, Vec3(-0.02, 1.0, -0.02), 5, 1, 5, 0, 0);
  beam.init.fixed = true;
  const Vec3 pivot(0.0, 1.0 - kSpacing, 0.0);  // one spacing below the beam's middle particle
  const int n = 30;
  BodyRange rope = addChain(p, pivot, Vec3(0, -1, 0), n, 1);
  rope.radius = float(R);
  const int bobCells = 3;
  const Vec3 bobCentre = pivot - ((n - 1) * kSpacing + kSpacing + bobCells * kSpacing) * Vec3::UnitY();
  BodyRange bob = addBall(p, bobCentre, bobCells, 3, 2);
  PbdWorld w(p, {beam, rope, bob}, mats, params(8, 4));
  for (int s = 0; s < 120; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const ParticleArrays& q = w.particles();
  const auto& ids = w.bodyParticles(1);
  double sideways = 0.0;
  for (std::int32_t i : ids)
    sideways = std::max(sideways, std::hypot(q.x[std::size_t(i)] - pivot.x(), q.z[std::size_t(i)] - pivot.z()));
  const auto pos = [&](std::int32_t i) { return Vec3(q.x[std::size_t(i)], q.y[std::size_t(i)], q.z[std::size_t(i)]); };
  const double length = (pos(ids.back()) - pos(ids.front())).norm(), drawn = (n - 1) * kSpacing;
  std::printf("thick hanging rope: %.5f m sideways at most, end to end %.5f m of %.5f\n", sideways, length, drawn);
  EXPECT_LT(sideways, 5e-4);
  EXPECT_NEAR(length / drawn, 1.0, 0.01);
}

// A rope drawn thick is as much heavier as its cross-section (strandMassScale: (2R / spacing)^2
// voxel chains). Zero gravity: a rope of radius R = one spacing (4 voxel chains' mass) moving up
// at 0.5 m/s meets a thin one (radius r, one chain) moving down at 0.5 m/s along their whole
// length, e = 0.8 and no friction. Newton's law of restitution with momentum kept (closed form,
// m_A = 4 m_B): v_A' = (4 (0.5) - 0.5 - 0.8 (1.0)) / 5 = 0.14 m/s, v_B' = v_A' + 0.8 = 0.94 m/s;
// tolerance 3 % of the approach speed, as in the equal ropes' test. Ropes of equal mass would
// leave at -0.4 and +0.4 m/s.
TEST(Rope, AThickRopeIsAsHeavyAsItsCrossSection) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("thick", MaterialKind::kRope), makeKind("thin", MaterialKind::kRope)};
  for (Material& m : mats) m.staticFriction = m.dynamicFriction = 0.0, m.restitution = 0.8;
  BodyRange a = addChain(p, Vec3(0.0, 0.5, 0.0), Vec3(1, 0, 0), 20, 0);
  BodyRange b = addChain(p, Vec3(0.0, 0.55, 0.0), Vec3(1, 0, 0), 20, 1);
  a.stroke = 0, b.stroke = 1;
  a.radius = float(kSpacing);
  a.init.velocity = Vec3(0.0, 0.5, 0.0);
  b.init.velocity = Vec3(0.0, -0.5, 0.0);
  PbdWorld w(p, {a, b}, mats, params(8, 4, Vec3::Zero()));
  EXPECT_FLOAT_EQ(w.particles().mass[0], float(4.0 * kParticleMass));
  for (int s = 0; s < 10; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  std::printf("thick and thin rope: %.4f and %.4f m/s (closed form 0.14 and 0.94)\n", w.velocity(0).y(), w.velocity(1).y());
  EXPECT_NEAR(w.velocity(0).y(), 0.14, 0.03);
  EXPECT_NEAR(w.velocity(1).y(), 0.94, 0.03);
}

// A bounce is kept per particle, once per substep, from its first contact worth one. A rope A
// of e = 0.8 (16 particles) lies along a bar C of e = 0 (8 x 2 x 2 particles, centred on it;
// A's ends are 4 spacings past the bar, beyond the reach at which a rope's ends attach to a
// body), touching it (one spacing apart), and both fall h0 = 0.2 m onto a fixed slab of e = 0.8
// with no friction anywhere. Each hits with all of itself at once: A, off the slab at the pair's
// e of 0.8, rises to 0.8^2 h0 = 0.128 m, and C, at the mean e of 0.4, to 0.4^2 h0 = 0.032 m
// (closed forms, the cloth and ball tests'; tolerance 3 % of h0, as there). C is a rigid bar,
// then a stiff soft one (a particle-level body, as a second rope would be, but one whose ends
// do not attach). What this caught: the contact between A and the soft C, which neither
// approaches, used up A's bounce (a contact was marked before it was known to be worth one),
// so A rose 0.050 m in the three cases where C's contact came first; and a body of e = 0 did
// not bounce off one of e > 0 (the rigid bar: not at all; the soft bar, bouncing particle by
// particle, 0.005 m), since only bodies whose own e > 0 were given a bounce. Both orders of
// the particle ids and both sides of A are run, so whichever contact comes first is covered.
TEST(Rope, ATouchingNeighbourThatDoesNotBounceLeavesARopesBounceAlone) {
  const double floor = 0.1 + 3 * kSpacing + kRadius;  // the slab's top particle centre + a spacing
  for (MaterialKind cKind : {MaterialKind::kRigid, MaterialKind::kSoft})
    for (bool cFirst : {true, false})
      for (double side : {1.0, -1.0}) {
        ParticleArrays p;
        std::vector<Material> mats = {makeKind("a", MaterialKind::kRope), makeKind("c", cKind),
                                      makeKind("slab", MaterialKind::kRigid)};
        mats[0].restitution = 0.8, mats[1].restitution = 0.0, mats[2].restitution = 0.8;
        mats[1].elastic.youngs = 5e5;  // the soft bar: stiff, so it keeps its shape as it lands
        for (Material& m : mats) m.staticFriction = m.dynamicFriction = 0.0;
        const Vec3 startA(0.45, floor + 0.2, 0.5);
        // The bar's near row is one spacing from A (touching it), on the side `side`; its far
        // row beyond it.
        const Vec3 cornerC = startA + Vec3(4 * kSpacing, 0.0, side > 0 ? kSpacing : -2 * kSpacing);
        std::vector<BodyRange> bodies;
        if (cFirst) bodies.push_back(addBox(p, cornerC, 8, 2, 2, 1, 1));
        bodies.push_back(addChain(p, startA, Vec3(1, 0, 0), 16, 0));
        if (!cFirst) bodies.push_back(addBox(p, cornerC, 8, 2, 2, 1, 1));
        bodies.push_back(addBox(p, Vec3(0.4, 0.1, 0.4), 21, 4, 21, 2, 2));
        bodies.back().init.fixed = true;
        const int a = cFirst ? 1 : 0, c = 1 - a;
        bodies[std::size_t(a)].stroke = 0, bodies[std::size_t(c)].stroke = 1;
        // firstBounceApex follows one body: run the same start twice, following each.
        const auto apex = [&](int body) {
          PbdWorld w(p, bodies, mats, params(8, 4, Vec3(0, -9.81, 0)));
          return firstBounceApex(w, body, w.pose(body).centre.y() - 0.2, 0.05);
        };
        const double apexA = apex(a), apexC = apex(c);
        const char* what = cKind == MaterialKind::kRigid ? "rigid" : "soft";
        std::printf("rope along a %s bar (bar %s, side %+.0f z): apex rope %.4f (closed form 0.128), bar %.4f (0.032)\n",
                    what, cFirst ? "first" : "second", side, apexA, apexC);
        EXPECT_NEAR(apexA, 0.64 * 0.2, 0.03 * 0.2) << what << " bar first " << cFirst << ", side " << side;
        EXPECT_NEAR(apexC, 0.16 * 0.2, 0.03 * 0.2) << what << " bar first " << cFirst << ", side " << side;
      }
}

// Only what the scene calls for: a soft body runs the particle passes and cluster
// matching but no rigid or strand pass; a rope adds the distance pass.
TEST(Soft, PlanListsOnlyTheParticlePassesItNeeds) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft)};
  BodyRange a = addBox(p, Vec3(0.0, 0.1, 0.0), 4, 4, 4, 0, 0);
  PbdWorld w(p, {a}, mats, params(2, 2));
  const auto names = planNames(w);
  for (const char* on : {"predict", "particle_contact", "cluster_match", "particle_update", "write_particles", "guard"})
    EXPECT_TRUE(has(names, on)) << on;
  for (const char* off : {"integrate", "rigid_contact", "body_contact", "distance", "find_neighbors", "plasticity"})
    EXPECT_FALSE(has(names, off)) << off;
  // No plastic_creep: the plasticity pass holds nothing (its per-cluster parameters are not kept).
  for (const PlanEntry& e : w.planAll())
    if (e.name == "plasticity") {
      EXPECT_FALSE(e.on);
      EXPECT_EQ(e.heldBytes, 0u);
    }
  // The plan is the step: every planned pass ran perStep times.
  ASSERT_TRUE(w.step());
  for (const PlanEntry& e : w.plan()) EXPECT_EQ(w.profile().entries()[std::size_t(e.pass)].calls, e.perStep) << e.name;
}

// Cutting a rope (a remove after play) drops the constraints across the cut: the part
// below falls freely while the part above still hangs.
// Issue 11: a pass says which strokes and materials need it. A jelly (stroke 0), a stone
// (stroke 1) and water (stroke 2): density names the water's stroke and material and not
// the others, cluster_match the jelly's, integrate the stone's.
TEST(Particles, PlanReasonsNameTheStrokesAndMaterialsThatNeedAPass) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("stone", MaterialKind::kRigid),
                                makeKind("water", MaterialKind::kFluid)};
  BodyRange jelly = addBox(p, Vec3(0.0, 0.1, 0.0), 4, 4, 4, 0, 0);
  BodyRange stone = addBox(p, Vec3(0.2, 0.1, 0.0), 3, 3, 3, 1, 1);
  BodyRange water = addBox(p, Vec3(0.4, 0.1, 0.0), 4, 4, 4, 2, 2);
  PbdWorld w(p, {jelly, stone, water}, mats, params(2, 2));
  const auto reasonOf = [&](const char* name) {
    for (const PlanEntry& e : w.plan())
      if (e.name == name) return e.reason;
    return std::string("(off)");
  };
  EXPECT_EQ(reasonOf("density"), "1 dynamic fluid bodies: stroke 2 (water); sound speed auto, 15 max(sqrt(2 g H), v_max)");
  EXPECT_EQ(reasonOf("cluster_match"), "1 dynamic soft bodies: stroke 0 (jelly)");
  EXPECT_EQ(reasonOf("integrate"), "1 dynamic rigid bodies: stroke 1 (stone)");
  EXPECT_EQ(reasonOf("particle_contact"), "2 dynamic soft, rope, cloth or fluid bodies: strokes 0 (jelly); 2 (water)");
}

TEST(Rope, RemovingAParticleCutsTheRope) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("beam", MaterialKind::kRigid), makeKind("rope", MaterialKind::kRope)};
  BodyRange beam = addBox(p, Vec3(-0.01, 1.0, -0.01), 3, 1, 3, 0, 0);
  beam.init.fixed = true;
  BodyRange rope = addChain(p, Vec3(0.0, 0.99, 0.0), Vec3(0, -1, 0), 30, 1);
  PbdWorld w(p, {beam, rope}, mats, params(8, 2));
  for (int s = 0; s < 30; ++s) ASSERT_TRUE(w.step());
  const double lastY = w.particles().y[std::size_t(rope.first + 29)];
  w.removeParticles({rope.first + 15});
  for (int s = 0; s < 12; ++s) ASSERT_TRUE(w.step());
  // 0.2 s of free fall: 0.196 m (allow 20 % for the cut's first substeps and the bending links).
  EXPECT_LT(w.particles().y[std::size_t(rope.first + 29)], lastY - 0.8 * 0.5 * 9.81 * 0.04);
  // The top half still hangs where it was (within a spacing).
  EXPECT_NEAR(w.particles().y[std::size_t(rope.first + 10)], 0.99 - 10 * kSpacing, kSpacing);
}

// Plastic creep: a soft cube with plastic_creep keeps part of the squash of a hard landing;
// the same cube without it recovers its height.
TEST(Soft, PlasticCubeKeepsPartOfItsDeformation) {
  const auto restHeight = [](double creep) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("clay", MaterialKind::kSoft)};
    mats[0].elastic.youngs = 2e3;
    mats[0].soft.plasticYield = 0.02;
    mats[0].soft.plasticCreep = creep;
    BodyRange a = addBox(p, Vec3(0.0, 0.4, 0.0), 8, 8, 8, 0, 0);
    PbdWorld w(p, {a}, mats, params(4, 4));
    for (int s = 0; s < 150; ++s) EXPECT_TRUE(w.step());
    const auto [lo, hi] = std::minmax_element(w.particles().y.begin(), w.particles().y.end());
    return double(*hi - *lo);
  };
  const double elastic = restHeight(0.0), plastic = restHeight(50.0);
  EXPECT_LT(plastic, elastic - 0.5 * kSpacing) << "elastic " << elastic << " m, plastic " << plastic << " m";
}

// Deterministic for any thread count: soft, rope, cloth and fluid together (more than one chunk
// of particles, so the parallel loops split) give bit-identical states on 1 and 2 threads.
TEST(Particles, SameStateForOneAndTwoThreads) {
  const auto run = [](int threads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("rope", MaterialKind::kRope),
                                  makeKind("cloth", MaterialKind::kCloth), makeKind("beam", MaterialKind::kRigid)};
    // Plastic (yield 0: every cluster creeps every substep): the plasticity pass's 1,000+
    // clusters run in parallel units.
    mats[0].soft.plasticCreep = 5.0;
    mats[0].soft.plasticYield = 0.0;
    BodyRange jelly = addBox(p, Vec3(0.0, 0.05, 0.0), 17, 17, 17, 0, 0);
    BodyRange beam = addBox(p, Vec3(0.3, 0.6, 0.0), 20, 1, 3, 3, 3);
    beam.init.fixed = true;
    BodyRange rope = addChain(p, Vec3(0.31, 0.59, 0.01), Vec3(0, -1, 0), 40, 1);
    // 100 x 100: each colour of its links (5,000) spans more than one parallel chunk.
    BodyRange cloth = addSheet(p, Vec3(-0.5, 1.6, 0.3), 100, 100, 2);
    mats.push_back(makeKind("water", MaterialKind::kFluid));
    BodyRange water = addBox(p, Vec3(0.2, 0.3, 0.2), 10, 10, 10, 4, 4);
    PbdWorld w(p, {jelly, beam, rope, cloth, water}, mats, params(4, 4));
    for (int s = 0; s < 20; ++s) EXPECT_TRUE(w.step());
    return w.stateHash();
  };
  EXPECT_EQ(run(1), run(2));
}

namespace {

// A fixed open-topped tank of rigid voxels around [0, inner) x [0, inner) in x and z,
// `height` layers tall, standing on the ground.
BodyRange addTank(ParticleArrays& p, int inner, int height, std::int16_t material) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  for (int j = 0; j < height; ++j)
    for (int k = -1; k <= inner; ++k)
      for (int i = -1; i <= inner; ++i) {
        if (i >= 0 && i < inner && k >= 0 && k < inner) continue;
        const Vec3 x = Vec3(kRadius, kRadius, kRadius) + kSpacing * Vec3(i, j, k);
        p.push(float(x.x()), float(x.y()), float(x.z()), 9, material);
      }
  b.count = static_cast<std::int32_t>(p.size()) - b.first;
  b.init.fixed = true;
  return b;
}

}  // namespace

// Fluid at rest in a fixed tank: after settling, the PBF density constraint holds the mean
// compression below 1 % at 8 iterations (the issue's bound; measured 0.6 %), and nothing
// moves faster than 0.1 m/s, a quarter of what a particle falling one spacing reaches
// (0.44 m/s): no particle rains or pops. Measured 2-5 cm/s of jitter against the tank's
// particle walls, where the kernel alone between analytic walls rests at 4e-5 m/s
// (test_fluid.cpp): the particle-wall boundary is open work in issue 8.
TEST(Fluid, AtRestInATankKeepsItsDensity) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("tank", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
  BodyRange tank = addTank(p, 14, 16, 0);
  BodyRange water = addBox(p, Vec3(kRadius, kRadius, kRadius), 14, 10, 14, 1, 1);
  PbdWorld w(p, {tank, water}, mats, params(3, 8));
  const auto names = planNames(w);
  for (const char* on : {"predict", "fluid_neighbors", "density", "particle_update"}) EXPECT_TRUE(has(names, on)) << on;
  for (const char* off : {"cluster_match", "distance", "integrate"}) EXPECT_FALSE(has(names, off)) << off;
  for (int s = 0; s < 120; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const DensityError e = w.fluidDensityError();
  ASSERT_GT(e.fluidCount, 0u);
  EXPECT_LT(e.meanCompression, 0.01f);
  float vmax = 0.0f;
  const ParticleArrays& q = w.particles();
  for (std::int32_t i = water.first; i < water.first + water.count; ++i)
    vmax = std::max(vmax, std::hypot(q.vx[std::size_t(i)], q.vy[std::size_t(i)], q.vz[std::size_t(i)]));
  EXPECT_LT(vmax, 0.1f);
}

// The warm start in the world (PbdParams::warmStart, scene record `warm_start`): the tank
// above at 2 substeps instead of 3. Cold, 8 iterations leave it over the 1 % bound (measured
// 1.37 %); carrying 0.6 of the multipliers brings it under (0.59 %) with nothing faster than
// the same 0.1 m/s (the fastest particle over the 30 steps after 4.5 s, a noisy statistic of
// the packing's settling: measured 0.034 at 2 s before the tank's one-particle walls met fluid
// as planes (particleContact), 0.185 at 2 s since, when its packing still rearranges, cold as
// well as warm (0.109 cold), and 0.02-0.05 in every 30-step window after 4 s).
// The carry follows the particles' ids, so 1 and 2 threads stay bit-identical.
TEST(Fluid, AWarmStartHoldsATankAtFewerSubsteps) {
  const auto run = [](double warm, int threads, std::uint64_t* hash) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("tank", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
    BodyRange tank = addTank(p, 14, 16, 0);
    BodyRange water = addBox(p, Vec3(kRadius, kRadius, kRadius), 14, 10, 14, 1, 1);
    PbdParams pp = params(2, 8);
    pp.warmStart = warm;
    PbdWorld w(p, {tank, water}, mats, pp);
    for (const PlanEntry& e : w.plan()) {  // the plan says what the density pass carries
      if (e.name == std::string("density")) {
        const bool said = e.reason.find("warm start 0.6 of the last substep's multipliers, averaged 4 times") != std::string::npos;
        EXPECT_EQ(said, warm > 0.0) << e.reason;
      }
    }
    float vmax = 0.0f;
    for (int s = 0; s < 300; ++s) {
      EXPECT_TRUE(w.step()) << w.guard().message();
      if (s < 270) continue;
      const ParticleArrays& q = w.particles();
      for (std::int32_t i = water.first; i < water.first + water.count; ++i)
        vmax = std::max(vmax, std::hypot(q.vx[std::size_t(i)], q.vy[std::size_t(i)], q.vz[std::size_t(i)]));
    }
    if (hash) *hash = w.stateHash();
    return std::make_pair(w.fluidDensityError().meanCompression, vmax);
  };
  std::uint64_t one = 0, two = 0;
  const auto cold = run(0.0, 2, nullptr), warm = run(0.6, 2, &two);
  run(0.6, 1, &one);
  std::printf("tank at 2 substeps: cold %.3f %% compressed, fastest %.4f m/s; warm %.3f %%, %.4f m/s\n",
              100.0 * cold.first, cold.second, 100.0 * warm.first, warm.second);
  EXPECT_GT(cold.first, 0.01f) << "the case no longer needs the warm start";
  EXPECT_LT(warm.first, 0.01f);
  EXPECT_LT(warm.second, 0.1f);
  EXPECT_EQ(one, two) << "1 and 2 threads differ with the warm start";
}

// The warm start's carried multipliers belong to the fluid as it was: a body edit (here a cut
// of one tank particle, which leaves the fluid's particles the same) or a time when no fluid
// particle is dynamic (the water fixed for a step, then freed) starts the next substep's solve
// from zero, and otherwise the carry goes on. Oracle: that rule (docs/formats.md,
// `warm_start`), counted by the world as cold starts. With the edit check removed the cut
// starts warm (count 1, not 2); without the clearing, the freed water does (2, not 3).
TEST(Fluid, AWarmStartStartsColdAfterAnEditOrAFrozenFluid) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("tank", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
  BodyRange tank = addTank(p, 8, 8, 0);
  BodyRange water = addBox(p, Vec3(kRadius, kRadius, kRadius), 8, 5, 8, 1, 1);
  PbdParams pp = params(2, 8);
  pp.warmStart = 0.6;
  PbdWorld w(p, {tank, water}, mats, pp);
  const auto steps = [&](int n) {
    for (int s = 0; s < n; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    return w.fluidColdStarts();
  };
  EXPECT_EQ(steps(3), 1) << "only the first substep starts cold";
  w.removeParticles({tank.first});  // a corner of the tank's bottom layer, away from the water
  EXPECT_EQ(steps(1), 2) << "a body edit starts the solve from zero";
  EXPECT_EQ(steps(2), 2);
  w.setMode(1, BodyMode::kFixed);
  EXPECT_EQ(steps(1), 2) << "no dynamic fluid, no solve";
  w.setMode(1, BodyMode::kDynamic);
  EXPECT_EQ(steps(1), 3) << "freed water starts from zero";
  EXPECT_EQ(steps(2), 3);
  PbdWorld cold(p, {tank, water}, mats, params(2, 8));  // the warm start off: nothing is counted
  cold.step();
  EXPECT_EQ(cold.fluidColdStarts(), 0);
}

namespace {
// A rope or cloth of `density` (material 2) laid on a 12 x layers x 12 pool of water in a fixed
// tank `tankLayers` high, stepped `steps` times at 3 substeps x 8 iterations: its particles' mean
// height (m), and the state's hash in `hash` when asked. `strand` adds the body's particles.
template <class Strand>
double strandOnAPool(MaterialKind kind, double density, int layers, int tankLayers, int steps, std::uint64_t* hash,
                     Strand&& strand) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("tank", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid),
                                makeKind("strand", kind, density)};
  BodyRange tank = addTank(p, 12, tankLayers, 0);
  BodyRange water = addBox(p, Vec3(kRadius, kRadius, kRadius), 12, layers, 12, 1, 1);
  BodyRange body = strand(p);
  PbdWorld w(p, {tank, water, body}, mats, params(3, 8));
  for (int s = 0; s < steps; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
  if (hash) *hash = w.stateHash();
  double y = 0.0;
  for (std::int32_t i = body.first; i < body.first + body.count; ++i) y += w.particles().y[std::size_t(i)];
  return y / body.count;
}
}  // namespace

// A thick rope floats or sinks by its density, as a rigid body does (Archimedes): its particles
// weigh a square cross-section 2R x 2R of the material, and the fluid sees them as n x n solid
// samples filling that square (PbdWorld::strandSamples). A rope of radius R = 2 spacings (4
// voxels across) of 300 kg/m^3 laid on a pool must float with 0.3 of its 4 spacings below the
// surface (its axis 0.8 spacings above), one of 3000 kg/m^3 sink to the floor. Before the
// samples the fluid saw one voxel of boundary per particle, held off the tube by contacts
// alone, and the 300 kg/m^3 rope sank to the floor (axis at 0.02 m). Bounds: the light one's
// axis within half a spacing of Archimedes' height (measured 0.7 mm off; the particle walls'
// packing and the free surface's deficit), the heavy one's within a spacing of resting on the
// floor (axis at R).
TEST(Fluid, AThickRopeFloatsOrSinksByItsDensity) {
  const int layers = 7;
  const double surface = layers * kSpacing, radius = 2.0 * kSpacing;
  const auto axisHeight = [&](double density, int steps, std::uint64_t* hash = nullptr) {
    return strandOnAPool(MaterialKind::kRope, density, layers, layers + 6, steps, hash, [&](ParticleArrays& p) {
      BodyRange rope = addChain(p, Vec3(0.03 + kRadius, surface + radius + kRadius, 0.06 + kRadius), Vec3(1, 0, 0), 6, 2);
      rope.radius = float(radius);
      rope.stroke = 2;
      return rope;
    });
  };
  std::uint64_t one = 0, two = 0;  // the samples' corrections summed in a fixed order
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    axisHeight(300.0, 20, &one);
  }
  axisHeight(300.0, 20, &two);
  EXPECT_EQ(one, two) << "1 and 2 threads differ with a thick rope in the fluid";
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "the 5.5 s of floating and sinking are too slow under AddressSanitizer; make test runs them";
#endif
  // 4 s: the light rope bobs down to its line in about 3 s (0.0780, 0.0759, 0.0725, 0.0723 m
  // at 1, 2, 3, 4 s); the heavy one is on the floor within 1.5 s.
  const double light = axisHeight(300.0, 240), heavy = axisHeight(3000.0, 90);
  const double archimedes = surface - kRadius + radius - 0.3 * 2.0 * radius;  // the water's top is r under its top centres
  std::printf("thick rope: 300 kg/m^3 axis at %.4f m (Archimedes %.4f), 3000 kg/m^3 at %.4f m (surface %.4f)\n", light,
              archimedes, heavy, surface);
  EXPECT_NEAR(light, archimedes, 0.5 * kSpacing);
  EXPECT_LT(heavy, radius + kSpacing);
}

// A thick cloth floats or sinks by its density as the thick rope does: a cloth particle weighs
// density x spacing^2 x 2R, and the fluid sees it as n = 2R / spacing solid samples across its
// sheet (along PbdWorld::sheetNormal). A 6 x 6 raft of radius R = 2 spacings (4 voxels thick)
// of 300 kg/m^3 laid flat on a 12 x 12 pool 7 cells deep must float with 0.3 of its thickness
// under water; the pool's level rises by the water it displaces (36 cells x 1.2 spacings over
// 144 cells: 0.3 spacings), so its mid-plane stands at 7 s + 0.3 s - 1.2 s + R. One of
// 3000 kg/m^3 sinks to the floor. A raft tilted 29 degrees about x settles to the same height.
// Measured 1.7 mm above that line, 1.9 mm tilted (the free surface's deficit; it is there within 0.5 s). With
// one sample per particle the light raft rode 5.5 mm under it (held up by the contacts alone,
// the water beside it reading under-dense), with its samples along a fixed axis (x) instead of
// the lattice's normal 4.7 mm under. Bounds: 0.3 spacings of Archimedes' height, a spacing of
// resting on the floor (the rope's).
TEST(Fluid, AThickClothFloatsOrSinksByItsDensity) {
  const int layers = 7, side = 6;
  const double radius = 2.0 * kSpacing;
  const auto midPlane = [&](double density, int steps, double tilt, std::uint64_t* hash = nullptr) {
    return strandOnAPool(MaterialKind::kCloth, density, layers, layers + 8, steps, hash, [&](ParticleArrays& p) {
      const Vec3 corner(0.03 + kRadius, layers * kSpacing + radius + kRadius, 0.03 + kRadius);
      BodyRange raft = addSheet(p, corner, side, side, 2, Vec3(0, std::sin(tilt), std::cos(tilt)));
      raft.radius = float(radius);
      return raft;
    });
  };
  std::uint64_t one = 0, two = 0;  // the samples' corrections summed in a fixed order
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    midPlane(300.0, 20, 0.0, &one);
  }
  midPlane(300.0, 20, 0.0, &two);
  EXPECT_EQ(one, two) << "1 and 2 threads differ with a thick cloth in the fluid";
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "the seconds of floating and sinking are too slow under AddressSanitizer; make test runs them";
#endif
  const double light = midPlane(300.0, 60, 0.0), tilted = midPlane(300.0, 60, 0.5), heavy = midPlane(3000.0, 60, 0.0);
  const double submerged = 0.3 * 2.0 * radius, rise = submerged * (side * side) / (12.0 * 12.0);
  const double archimedes = layers * kSpacing + rise - submerged + radius;
  std::printf("thick cloth: 300 kg/m^3 mid-plane at %.4f m (tilted: %.4f; Archimedes %.4f), 3000 kg/m^3 at %.4f m\n",
              light, tilted, archimedes, heavy);
  EXPECT_NEAR(light, archimedes, 0.3 * kSpacing);
  EXPECT_NEAR(tilted, archimedes, 0.3 * kSpacing);
  EXPECT_LT(heavy, radius + kSpacing);
}

// A cloth particle's samples lie along its sheet's normal (PbdWorld::sheetNormal), which the
// rafts above, flat on the water, do not tell from +y. Oracle: the plane's own normal, row
// direction x column direction, for a 5 x 6 lattice laid level, upright (rows down -y) and
// tilted 0.7 rad, at a corner, an edge and an inner particle, after a step in zero gravity (the
// sheet at rest: its predicted positions are its lattice). Within 1e-6 in |n . expected|.
TEST(Cloth, ItsNormalIsItsLatticesPlanes) {
  for (const Vec3& rowDir : {Vec3(0, 0, 1), Vec3(0, -1, 0), Vec3(0, std::sin(0.7), std::cos(0.7))}) {
    ParticleArrays p;
    BodyRange sheet = addSheet(p, Vec3(0.3, 0.5, 0.3), 5, 6, 0, rowDir);
    PbdWorld w(p, {sheet}, {makeKind("linen", MaterialKind::kCloth)}, params(2, 4, Vec3::Zero()));
    ASSERT_TRUE(w.step()) << w.guard().message();
    const Vec3 expected = Vec3::UnitX().cross(rowDir).normalized();
    for (const std::int32_t i : {0, 3, 7, 14, 29}) {
      const Vec3 n = w.clothNormal(sheet.first + i);
      EXPECT_NEAR(std::fabs(n.dot(expected)), 1.0, 1e-6) << "particle " << i << ", rows along " << rowDir.transpose();
    }
  }
}

// A blob of water floating in zero gravity, far from every wall, holds together in the world
// as in the kernel alone (FluidRest.ABlobInZeroGravityHoldsTogether, test_fluid.cpp): the
// world's s_corr (scaled as a force at its substep) is balanced too. Oracle: Newton's first
// law, nothing acts on it. With s_corr unbalanced this 14^3 blob spread like a gas (median
// radius +339 %, rms speed 0.12 m/s after 2 s; now +0.4 %, 0.007 m/s). Bounds: rms speed below
// 0.03 m/s and the median radius within 5 % (the block rounds off).
TEST(Fluid, ABlobInZeroGravityHoldsTogether) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("water", MaterialKind::kFluid)};
  BodyRange water = addBox(p, Vec3(0.2, 0.5, 0.2), 14, 14, 14, 1, 0);
  PbdWorld w(p, {water}, mats, params(4, 4, Vec3::Zero()));
  const auto medianRadius = [&] {
    const ParticleArrays& q = w.particles();
    double c[3] = {0, 0, 0};
    for (std::size_t i = 0; i < q.size(); ++i) c[0] += q.x[i], c[1] += q.y[i], c[2] += q.z[i];
    for (double& v : c) v /= double(q.size());
    std::vector<double> r(q.size());
    for (std::size_t i = 0; i < q.size(); ++i) r[i] = std::hypot(q.x[i] - c[0], q.y[i] - c[1], q.z[i] - c[2]);
    std::nth_element(r.begin(), r.begin() + std::ptrdiff_t(r.size() / 2), r.end());
    return r[r.size() / 2];
  };
  const double r0 = medianRadius();
  for (int s = 0; s < 120; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const ParticleArrays& q = w.particles();
  double v2 = 0.0;
  for (std::size_t i = 0; i < q.size(); ++i) v2 += q.vx[i] * q.vx[i] + q.vy[i] * q.vy[i] + q.vz[i] * q.vz[i];
  const double rms = std::sqrt(v2 / double(q.size())), grown = medianRadius() / r0 - 1.0;
  std::printf("zero-g blob in the world after 2 s: rms speed %.4f m/s, median radius %+.2f %%\n", rms, 100.0 * grown);
  EXPECT_LT(rms, 0.03);
  EXPECT_LT(std::fabs(grown), 0.05);
}

// Water thrown down at a fixed slab stays above it. Three mechanisms hold it, each found
// missing by this test: a particle fast enough to be predicted past a slab particle's centre in
// one substep is pushed back the way it came (the normal where it first touched), not on through
// along the line of centres; one touching a particle of the slab's face from outside is held off
// the face along its normal (PbdWorld::surfaceNormal_), not along the line of centres, which at
// the gap between four face particles points along the face and let the blob's pressure squeeze
// water into the slab; and a particle whose whole move of the substep still enters a cell of the
// slab stops outside it (PbdWorld::looseBodySweep), however far it came. Water poured into
// scenes/mix.scene's cup at 2 m/s (0.85 spacings a substep) left through the cup's floor and
// walls: with the line of centres 263 of 3,600 particles ended outside the cup, 136 of them over
// 0.3 m away; with the swept normal 103 and 20, 15 more inside its walls; with the face normals
// none inside the walls and 148 and 30 outside, splashed over the rim (the impact splash is an
// open item, docs/accuracy.md). Here a 10^3 blob hits a 40 x T x 40 slab at 1 to 8 m/s; the
// oracle is that a solid is not crossed: over 0.2 s no particle over the slab is ever below the
// centres of its top layer. Before the sweep, three thick at 3 m/s and 4 substeps (1.25 spacings
// a substep) was the limit: at 4 m/s particles were there 278 times, at 8 m/s 3,100; one thick
// (a sheet, which then had no face normals) leaked from 2 m/s at 2 substeps (3,897 times) and at
// 8 m/s (6.7 spacings a substep) 10,107 times.
TEST(Fluid, WaterThrownAtAThinSlabDoesNotPassThroughIt) {
  struct Case {
    double speed;
    int substeps, thickness;
  };
  for (const Case& c : {Case{1.0, 4, 3}, {2.0, 4, 3}, {3.0, 4, 3}, {4.0, 4, 3}, {8.0, 4, 3}, {2.0, 2, 1}, {4.0, 2, 1},
                        {8.0, 2, 1}, {8.0, 4, 1}}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("slab", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
    BodyRange slab = addBox(p, Vec3(0.1, 0.3, 0.1), 40, c.thickness, 40, 0, 0);
    slab.init.fixed = true;
    const double top = 0.3 + kSpacing * (c.thickness - 1);  // the top layer's centres (m)
    BodyRange water = addBox(p, Vec3(0.25, top + 0.02, 0.25), 10, 10, 10, 1, 1);
    water.init.velocity = Vec3(0.0, -c.speed, 0.0);
    PbdWorld w(p, {slab, water}, mats, params(c.substeps, 4));
    int below = 0;
    for (int s = 0; s < 12; ++s) {
      ASSERT_TRUE(w.step()) << w.guard().message();
      const ParticleArrays& q = w.particles();
      for (std::int32_t i = water.first; i < water.first + water.count; ++i) {
        const auto k = std::size_t(i);
        const bool over = q.x[k] > 0.11f && q.x[k] < 0.48f && q.z[k] > 0.11f && q.z[k] < 0.48f;
        below += over && q.y[k] < float(top);
      }
    }
    std::printf("water at %.0f m/s, %d substeps, onto a slab %d thick: %d particle-steps below its top layer\n",
                c.speed, c.substeps, c.thickness, below);
    EXPECT_EQ(below, 0) << c.speed << " m/s, " << c.substeps << " substeps, " << c.thickness << " thick";
  }
}

// A 10^3 blob of water thrown at 2 m/s in zero gravity at a fixed slab (three particles thick)
// and at a sheet (one thick) stops on it and spreads; it does not come back. The oracle: an
// incompressible, inviscid fluid meeting a wall takes an impulse that only removes its normal
// momentum (pressure-impulse theory, Cooker & Peregrine 1995), after which it flows along the
// wall, so the blob's mean velocity away from the wall 0.4 s later is 0. The bound, 3 % of the
// impact speed, is what the same blob thrown at the ground (its clamp and ghost wall) leaves
// with here, 0.1-0.8 %, plus PBF's own compressibility at 4 iterations (measured 0.7-2.1 %).
// Before a face's particles met the fluid as a plane (particleContact), the fluid sank into the
// hollows between them and was pushed back out as it flowed over the face: the blob left the
// slab at 7 % of its speed at 4 substeps and 27 % at 16 (the sheet, whose particles were then
// spheres: 5 and 7 %).
TEST(Fluid, ABlobThrownAtASlabOrASheetDoesNotComeBack) {
  struct Case {
    int thickness, substeps;
    double side;  // +1 thrown down at the top face, -1 up at the bottom one
  };
  for (const Case& c : {Case{3, 4, 1.0}, {3, 16, 1.0}, {1, 4, 1.0}, {1, 16, 1.0}, {1, 16, -1.0}}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("slab", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
    BodyRange slab = addBox(p, Vec3(0.1, 0.3, 0.1), 40, c.thickness, 40, 0, 0);
    slab.init.fixed = true;
    const double top = 0.3 + kSpacing * (c.thickness - 1);
    BodyRange water = addBox(p, Vec3(0.25, c.side > 0.0 ? top + 0.03 : 0.3 - 0.03 - 9 * kSpacing, 0.25), 10, 10, 10, 1, 1);
    const double speed = 2.0;
    water.init.velocity = Vec3(0.0, -c.side * speed, 0.0);
    PbdWorld w(p, {slab, water}, mats, params(c.substeps, 4, Vec3::Zero()));
    bool through = false;  // the sheet's other side: a particle over it ends past its centres
    for (int s = 0; s < 24; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    const ParticleArrays& q = w.particles();
    double away = 0.0;
    for (std::int32_t i = water.first; i < water.first + water.count; ++i) {
      const auto k = std::size_t(i);
      away += c.side * q.vy[k];
      const bool over = q.x[k] > 0.1f && q.x[k] < 0.49f && q.z[k] > 0.1f && q.z[k] < 0.49f;
      through |= over && (c.side > 0.0 ? q.y[k] < float(top) : q.y[k] > 0.3f);
    }
    away /= water.count;
    std::printf("blob at %.0f m/s at a slab %d thick (%s), %d substeps: leaves at %+.1f %% of its speed\n", speed,
                c.thickness, c.side > 0.0 ? "top" : "bottom", c.substeps, 100.0 * away / speed);
    EXPECT_LT(away, 0.03 * speed) << c.thickness << " thick, " << c.substeps << " substeps, side " << c.side;
    EXPECT_FALSE(through) << c.thickness << " thick, " << c.substeps << " substeps, side " << c.side;
  }
}

// Water resting in a fixed cup whose floor is three particles thick (a face) and whose walls are
// one thick (sheets) stays at rest: after 4 s of settling, the rms speed of its particles is
// below 0.01 m/s (the bound of FluidRest.ColumnAtRestStaysStill) and none moves faster than
// 0.1 m/s, a quarter of what a particle falling one spacing reaches. Measured 0.005 and 0.02-0.03
// at 4 and 6 substeps. Gated by the sphere of reach around each face particle, the face pushed a
// particle from the hollow between its particles (a quarter spacing above them) up to reach at
// once as it came within reach of one: the pool kept boiling at 0.06-0.09 m/s rms with particles
// at 0.35-0.6 m/s; the mix scene's cup of water moved at 4 cm/s after 2 s.
TEST(Fluid, WaterRestingInACupWithAThickFloorStaysAtRest) {
  for (const int substeps : {4, 6}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("cup", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
    const int inner = 12, floor = 3, height = 10;
    BodyRange cup;
    cup.first = std::int32_t(p.size());
    for (int j = 0; j < height; ++j)
      for (int k = -1; k <= inner; ++k)
        for (int i = -1; i <= inner; ++i) {
          if (j >= floor && i >= 0 && i < inner && k >= 0 && k < inner) continue;
          const Vec3 x = Vec3(0.1, kRadius, 0.1) + kSpacing * Vec3(i, j, k);
          p.push(float(x.x()), float(x.y()), float(x.z()), 0, 0);
        }
    cup.count = std::int32_t(p.size()) - cup.first;
    cup.init.fixed = true;
    BodyRange water = addBox(p, Vec3(0.1, kRadius + kSpacing * floor, 0.1), inner, 4, inner, 1, 1);
    PbdWorld w(p, {cup, water}, mats, params(substeps, 4));
    double rms = 0.0;
    float fastest = 0.0f;
    for (int s = 0; s < 270; ++s) {
      ASSERT_TRUE(w.step()) << w.guard().message();
      if (s < 240) continue;
      const ParticleArrays& q = w.particles();
      double v2 = 0.0;
      for (std::int32_t i = water.first; i < water.first + water.count; ++i) {
        const auto k = std::size_t(i);
        const float v = std::hypot(q.vx[k], q.vy[k], q.vz[k]);
        v2 += double(v) * v;
        fastest = std::max(fastest, v);
      }
      rms = std::max(rms, std::sqrt(v2 / water.count));
    }
    std::printf("water resting in a cup at %d substeps: rms speed %.4f m/s (worst step), fastest %.3f m/s\n", substeps,
                rms, fastest);
    EXPECT_LT(rms, 0.01) << substeps << " substeps";
    EXPECT_LT(fastest, 0.1f) << substeps << " substeps";
  }
}

// A rope and a jelly cube thrown down at a fixed sheet one particle thick at 4 and 8 m/s (3.3 and
// 6.7 spacings a substep at 2 substeps) stay above it: the oracle, as for the water above, is that
// a solid is not crossed, so no particle over the sheet is ever below its centres. Contacts are
// found at the predicted positions within a spacing and a half, so before the sweep
// (PbdWorld::looseBodySweep) the whole 25-particle rope went through at either speed (500
// particle-steps below in 20 steps), and the jelly's 512 particles 5,880 and 1,536 times before
// the guard stopped it, deep in the ground.
TEST(Sweep, ARopeAndAJellyThrownAtASheetOneParticleThickStayAbove) {
  for (const MaterialKind kind : {MaterialKind::kRope, MaterialKind::kSoft})
    for (const double speed : {4.0, 8.0}) {
      ParticleArrays p;
      std::vector<Material> mats = {makeKind("sheet", MaterialKind::kRigid), makeKind("thrown", kind)};
      BodyRange sheet = addBox(p, Vec3(0.1, 0.3, 0.1), 40, 1, 40, 0, 0);
      sheet.init.fixed = true;
      BodyRange thrown = kind == MaterialKind::kRope ? addChain(p, Vec3(0.15, 0.35, 0.253), Vec3::UnitX(), 25, 1)
                                                     : addBox(p, Vec3(0.25, 0.33, 0.253), 8, 8, 8, 1, 1);
      thrown.init.velocity = Vec3(0.0, -speed, 0.0);
      PbdWorld w(p, {sheet, thrown}, mats, params(2, 4));
      int below = 0;
      for (int s = 0; s < 20; ++s) {
        ASSERT_TRUE(w.step()) << w.guard().message();
        const ParticleArrays& q = w.particles();
        for (std::int32_t i = thrown.first; i < thrown.first + thrown.count; ++i) below += q.y[std::size_t(i)] < 0.3f;
      }
      std::printf("%s at %.0f m/s onto a sheet one particle thick: %d particle-steps below it\n", toString(kind), speed,
                  below);
      EXPECT_EQ(below, 0) << toString(kind) << " at " << speed << " m/s";
    }
}

// The sweep's stop is a contact: a free plate takes its share. In zero gravity, far from the
// ground, a 10^3 blob of water or jelly thrown at 6 m/s (2.5 spacings a substep at 4 substeps)
// at a free plate one particle thick and 40 x 40 across (1.6 times the blob's mass) keeps the
// pair's momentum (oracle: conservation; 1e-3 relative, the soft body's own cluster solve keeps
// it to 1e-4) and pushes the plate on, none of it passing through. Stopped one way (the particle alone moved), 30 % of the
// water's momentum and 29 % of the jelly's were lost in 8 steps.
TEST(Sweep, WaterAndJellyThrownAtAFreePlateKeepTheirMomentum) {
  for (const MaterialKind kind : {MaterialKind::kFluid, MaterialKind::kSoft}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("plate", MaterialKind::kRigid), makeKind("thrown", kind)};
    BodyRange plate = addBox(p, Vec3(0.1, 2.3, 0.1), 40, 1, 40, 0, 0);
    BodyRange thrown = addBox(p, Vec3(0.25, 2.33, 0.25), 10, 10, 10, 1, 1);
    thrown.init.velocity = Vec3(0.0, -6.0, 0.0);
    PbdWorld w(p, {plate, thrown}, mats, params(4, 4, Vec3::Zero()));
    const Vec3 m0 = momentum(w);
    for (int s = 0; s < 8; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    const Vec3 m1 = momentum(w);
    std::printf("%s at 6 m/s onto a free plate: momentum y %.5f -> %.5f, plate at %.3f m/s\n", toString(kind), m0.y(),
                m1.y(), w.velocity(0).y());
    EXPECT_LT((m1 - m0).norm(), 1e-3 * m0.norm()) << toString(kind);
    EXPECT_LT(w.velocity(0).y(), -1.0) << toString(kind);  // the plate was pushed (2.7 and 3.0 m/s)
    // And nothing went through it (the split leaves each stop outside the moved plate, to first
    // order in the plate's move; a centred hit here).
    const ParticleArrays& q = w.particles();
    const Vec3 c = w.pose(0).centre;
    int through = 0;
    for (std::int32_t i = thrown.first; i < thrown.first + thrown.count; ++i) {
      const auto k = std::size_t(i);
      const bool over = std::abs(q.x[k] - c.x()) < 0.19 && std::abs(q.z[k] - c.z()) < 0.19;
      through += over && q.y[k] < c.y();
    }
    EXPECT_EQ(through, 0) << toString(kind);
  }
}

// Water thrown at 45 degrees at a fixed sheet one particle thick, fast enough (6 m/s: 2.5
// spacings a substep across the sheet at 2 substeps) that the sweep stops it (looseBodySweep),
// slides on along the sheet: the sheet pushes only along its normal, so without friction the
// blob's mean velocity along the sheet is kept (to 2 %: the packing's own rearrangements), and
// with friction mu = 0.5 it loses at most mu times what the sheet took of its normal velocity
// (Coulomb's bound on the impulses, 10 % over for the substeps' discrete normal impulses). Stopped
// on its path, the particle lost its move along the face too: frictionless water kept 19 % of
// its speed along the sheet at 6 m/s and 80 % at 2 m/s; with friction it lost 3.4 m/s of 4.2
// against Coulomb's 2.2.
TEST(Sweep, WaterThrownObliquelyAtASheetSlidesAlongIt) {
  for (const double mu : {0.0, 0.5})
    for (const double speed : {2.0, 6.0}) {
      ParticleArrays p;
      std::vector<Material> mats = {makeKind("sheet", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
      for (Material& m : mats) m.staticFriction = m.dynamicFriction = mu;
      BodyRange sheet = addBox(p, Vec3(0.0, 0.3, 0.1), 90, 1, 40, 0, 0);
      sheet.init.fixed = true;
      BodyRange water = addBox(p, Vec3(0.1, 0.32, 0.25), 8, 8, 8, 1, 1);
      const double v = speed / std::sqrt(2.0);
      water.init.velocity = Vec3(v, -v, 0.0);
      PbdWorld w(p, {sheet, water}, mats, params(2, 4, Vec3::Zero()));
      for (int s = 0; s < 6; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
      const ParticleArrays& q = w.particles();
      Vec3 mean = Vec3::Zero();
      for (std::int32_t i = water.first; i < water.first + water.count; ++i)
        mean += Vec3(q.vx[std::size_t(i)], q.vy[std::size_t(i)], q.vz[std::size_t(i)]);
      mean /= water.count;
      const double lost = v - mean.x(), normal = mean.y() + v;  // along the sheet; the normal velocity taken
      std::printf("water at %.0f m/s, 45 degrees, mu %.1f: along the sheet %.3f of %.3f m/s (lost %.3f, mu x normal %.3f)\n",
                  speed, mu, mean.x(), v, lost, mu * normal);
      if (mu == 0.0) {
        EXPECT_LT(std::abs(lost), 0.02 * v) << speed << " m/s";
      } else {
        EXPECT_LT(lost, 1.1 * mu * normal) << speed << " m/s";
      }
    }
}

// A 6^3 jelly and a 6^3 blob of water thrown at 6 m/s (5 spacings a substep at 2 substeps) at
// the corner of a free plate a fifth of their mass, in zero gravity, turn it and push it on
// without making energy: the collision is inelastic (restitution 0), so the kinetic energy of
// all particles (the plate's carry its rigid motion) after 20 steps is at most what it was, and
// the momentum is kept to 1e-3 of itself (float round-off and the contacts' order). The sweep's
// stops on the plate were split against the pose they were found at, each adding its whole
// share: the jelly threw the plate off at 38 m/s and 290 rad/s in the first step (kinetic
// energy 3.9 -> 30.6 J) and the guard stopped it; shared one after another against the moved
// plate, it turns at 44 rad/s, as at 4 and 8 substeps (47 and 58 rad/s).
TEST(Sweep, AJellyAndWaterThrownAtALightPlatesCornerMakeNoEnergy) {
  for (const MaterialKind kind : {MaterialKind::kSoft, MaterialKind::kFluid}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("plate", MaterialKind::kRigid, 100.0), makeKind("thrown", kind)};
    BodyRange plate = addBox(p, Vec3(0.1, 2.3, 0.1), 20, 1, 20, 0, 0);
    BodyRange thrown = addBox(p, Vec3(0.1, 2.33, 0.1), 6, 6, 6, 1, 1);
    thrown.init.velocity = Vec3(0.0, -6.0, 0.0);
    PbdWorld w(p, {plate, thrown}, mats, params(2, 4, Vec3::Zero()));
    const double e0 = kineticEnergy(w);
    const Vec3 m0 = momentum(w);
    for (int s = 0; s < 20; ++s) ASSERT_TRUE(w.step()) << toString(kind) << ": " << w.guard().message();
    const double e1 = kineticEnergy(w);
    const Vec3 m1 = momentum(w);
    std::printf("%s at a light plate's corner: kinetic energy %.3f -> %.3f J, momentum y %.5f -> %.5f, plate %.1f rad/s\n",
                toString(kind), e0, e1, m0.y(), m1.y(), w.angularVelocity(0).norm());
    EXPECT_LE(e1, e0) << toString(kind);
    EXPECT_LT((m1 - m0).norm(), 1e-3 * m0.norm()) << toString(kind);
    EXPECT_GT(w.angularVelocity(0).norm(), 1.0) << toString(kind);  // the hit turned the plate
  }
}

// Water riding a falling sheet (one particle thick) that is made fixed mid-fall (setMode) stays on
// it: a body's start pose is reset when its mode changes, so the contacts judge which side of
// the sheet the water started on from where the sheet is, not from where it was in its last
// moving substep (2.45 spacings higher: fixed bodies never update it). With the stale pose the
// water on the sheet counted as below it, was pushed down through it by the face's plane, held
// by the sweep, and crushed: the guard stopped the run 20 steps later at 47 % compression.
TEST(Sweep, WaterOnASheetMadeFixedMidFallStaysOnIt) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("sheet", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
  BodyRange sheet = addBox(p, Vec3(0.1, 1.0, 0.1), 30, 1, 30, 0, 0);
  BodyRange water = addBox(p, Vec3(0.15, 1.0 + kSpacing, 0.15), 10, 4, 10, 1, 1);
  PbdWorld w(p, {sheet, water}, mats, params(4, 4));
  for (int s = 0; s < 18; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  w.setMode(0, BodyMode::kFixed);
  const Vec3 c = w.pose(0).centre;
  int inside = 0;  // over the sheet's middle, within 3 cm under its centres
  for (int s = 0; s < 60; ++s) {
    ASSERT_TRUE(w.step()) << "step " << s << " after the freeze: " << w.guard().message();
    const ParticleArrays& q = w.particles();
    for (std::int32_t i = water.first; i < water.first + water.count; ++i) {
      const auto k = std::size_t(i);
      const bool middle = std::abs(q.x[k] - c.x()) < 0.1 && std::abs(q.z[k] - c.z()) < 0.1;
      inside += middle && q.y[k] < c.y() && q.y[k] > c.y() - 0.03;
    }
  }
  EXPECT_EQ(inside, 0);
}

// A stone ball dropped into a tank of water sinks to the floor without pushing water into the
// ground: the sweep stops a particle the stone comes down on outside the stone's face, and that
// stop is never below the ground (the ground's plane is where every particle's contact holds
// it). Carried down with the stone, water under it ended 3.8 mm into the ground, past the
// guard's bound, and the guard stopped scenes/honey.scene at frame 6.
TEST(Sweep, AStoneSinkingThroughWaterPushesNoneIntoTheGround) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("glass", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid),
                                makeKind("stone", MaterialKind::kRigid, 2500.0)};
  BodyRange tank = addTank(p, 16, 14, 0);
  BodyRange water = addBox(p, Vec3(kRadius, kRadius, kRadius), 16, 8, 16, 1, 1);
  BodyRange stone = addBall(p, Vec3(0.08, 0.2, 0.08), 3, 2, 2);
  PbdWorld w(p, {tank, water, stone}, mats, params(4, 4));
  double lowest = 1.0;
  for (int s = 0; s < 40; ++s) {
    ASSERT_TRUE(w.step()) << "step " << s << ": " << w.guard().message();
    const ParticleArrays& q = w.particles();
    for (std::int32_t i = water.first; i < water.first + water.count; ++i) lowest = std::min(lowest, double(q.y[std::size_t(i)]));
  }
  std::printf("stone through water: stone at %.3f m, lowest water %.5f m (its contact height %.5f)\n", w.pose(2).centre.y(),
              lowest, kRadius);
  EXPECT_LT(w.pose(2).centre.y(), 0.05);  // it reached the floor
  EXPECT_GT(lowest, kRadius - 1e-4);
}

// The sweep's stops are found in parallel units and shared with the body serially: an 18^3 blob
// of water (two units of the loop, its bottom layer in both) thrown at 6 m/s at a free plate,
// straight on and at 45 degrees (its stops slide along the plate), gives bit-identical states on
// 1 and 2 threads.
TEST(Sweep, SameStateForOneAndTwoThreads) {
  const auto run = [](int threads, const Vec3& velocity) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("plate", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
    BodyRange plate = addBox(p, Vec3(0.1, 2.3, 0.1), 40, 1, 40, 0, 0);
    BodyRange water = addBox(p, Vec3(0.2, 2.33, 0.2), 18, 18, 18, 1, 1);
    water.init.velocity = velocity;
    PbdWorld w(p, {plate, water}, mats, params(4, 4, Vec3::Zero()));
    for (int s = 0; s < 6; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    return w.stateHash();
  };
  for (const Vec3& v : {Vec3(0.0, -6.0, 0.0), Vec3(4.24, -4.24, 0.0)}) EXPECT_EQ(run(1, v), run(2, v)) << v.transpose();
}

// A particle stops once, at the body it meets first along its path, whatever the bodies' order:
// water thrown at 8 and 12 m/s (3.3 and 5 spacings a substep at 2 substeps, zero gravity) at a
// fixed sheet one particle thick, with a small free block 4 cm under it, listed before or after
// the sheet. No particle over the sheet is ever below it (oracle: a solid is not crossed).
// Before, the block listed first kept a stop the particle never made (it was found on the path
// before the sheet shortened it), took a share of it, and the particle, giving its share back,
// was moved through the sheet: 96 particle-steps below it at 12 m/s (found in review).
TEST(Sweep, AParticleStopsAtTheFirstBodyOnItsPathWhateverTheBodiesOrder) {
  for (const bool blockFirst : {true, false})
    for (const double speed : {8.0, 12.0}) {
      ParticleArrays p;
      std::vector<Material> mats = {makeKind("rigid", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
      std::vector<BodyRange> bodies;
      const auto addBlock = [&] { bodies.push_back(addBox(p, Vec3(0.28, 0.26, 0.28), 2, 1, 2, 0, 0)); };
      const auto addSheet = [&] {
        bodies.push_back(addBox(p, Vec3(0.1, 0.3, 0.1), 40, 1, 40, 1, 0));
        bodies.back().init.fixed = true;
      };
      if (blockFirst) addBlock(), addSheet();
      else addSheet(), addBlock();
      BodyRange water = addBox(p, Vec3(0.25, 0.32, 0.25), 8, 4, 8, 2, 1);
      water.init.velocity = Vec3(0.0, -speed, 0.0);
      bodies.push_back(water);
      PbdWorld w(p, bodies, mats, params(2, 4, Vec3::Zero()));
      int below = 0;
      for (int s = 0; s < 6; ++s) {
        ASSERT_TRUE(w.step()) << w.guard().message();
        const ParticleArrays& q = w.particles();
        for (std::int32_t i = water.first; i < water.first + water.count; ++i) below += q.y[std::size_t(i)] < 0.3f;
      }
      std::printf("block %s the sheet, water at %.0f m/s: %d particle-steps below the sheet\n", blockFirst ? "before" : "after",
                  speed, below);
      EXPECT_EQ(below, 0) << (blockFirst ? "block first, " : "sheet first, ") << speed << " m/s";
    }
}

// What the water never reaches it does not push: water thrown at 4, 8 and 12 m/s (zero gravity,
// 2 substeps) at a fixed sheet one particle thick, with a free 2 x 1 x 2 block 4 cm under it.
// The block stays at rest (oracle: nothing touches it; 1e-6 m/s, round-off). Before the
// predicted moves were swept (find_neighbors), pairs found at predicted positions past the sheet
// pushed the block: 1.15 m/s and 6.4 rad/s at 8 m/s, 0.42 m/s at 12 (found in review).
TEST(Sweep, ABodyHiddenBehindASheetIsNotPushed) {
  for (const double speed : {4.0, 8.0, 12.0}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("rigid", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
    BodyRange block = addBox(p, Vec3(0.28, 0.26, 0.28), 2, 1, 2, 0, 0);
    BodyRange sheet = addBox(p, Vec3(0.1, 0.3, 0.1), 40, 1, 40, 1, 0);
    sheet.init.fixed = true;
    BodyRange water = addBox(p, Vec3(0.25, 0.32, 0.25), 8, 4, 8, 2, 1);
    water.init.velocity = Vec3(0.0, -speed, 0.0);
    PbdWorld w(p, {block, sheet, water}, mats, params(2, 4, Vec3::Zero()));
    for (int s = 0; s < 6; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    std::printf("water at %.0f m/s at a sheet: the block behind it at %.3g m/s, %.3g rad/s\n", speed,
                w.velocity(0).norm(), w.angularVelocity(0).norm());
    EXPECT_LT(w.velocity(0).norm(), 1e-6) << speed << " m/s";
    EXPECT_LT(w.angularVelocity(0).norm(), 1e-6) << speed << " m/s";
  }
}

// The cells a body is swept against follow its shape: a hole cut in a sheet after play (remove)
// lets water through. Zero gravity: a blob thrown at 4 m/s at a fixed sheet one particle thick
// from 10 cm above it, the sheet's cells built in the first step (a drop resting under the
// sheet's far corner puts the sheet within the paths' box), then a 16 x 16 patch under the blob
// cut out before the blob arrives. Oracle: nothing is where the hole is, so the whole blob,
// narrower than the hole, passes below the sheet within 10 steps. With the cells kept from
// before the cut (the stale mark removed) it stopped at the cells no longer there: 0 of 256.
TEST(Sweep, WaterPassesThroughAHoleCutInASheet) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("sheet", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
  BodyRange sheet = addBox(p, Vec3(0.1, 0.3, 0.1), 40, 1, 40, 0, 0);
  sheet.init.fixed = true;
  BodyRange water = addBox(p, Vec3(0.25, 0.40, 0.25), 8, 4, 8, 1, 1);
  water.init.velocity = Vec3(0.0, -4.0, 0.0);
  BodyRange drop = addBox(p, Vec3(0.45, 0.2925, 0.45), 2, 1, 2, 2, 1);
  PbdWorld w(p, {sheet, water, drop}, mats, params(2, 4, Vec3::Zero()));
  ASSERT_TRUE(w.step()) << w.guard().message();
  std::vector<std::int32_t> hole;
  for (std::int32_t i : w.bodyParticles(0)) {
    const auto k = std::size_t(i);
    const float x = w.particles().x[k], z = w.particles().z[k];
    if (x > 0.205f && x < 0.365f && z > 0.205f && z < 0.365f) hole.push_back(i);
  }
  ASSERT_EQ(hole.size(), 256u);
  w.removeParticles(hole);
  for (int s = 0; s < 10; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  int below = 0;
  for (std::int32_t i = water.first; i < water.first + water.count; ++i) below += w.particles().y[std::size_t(i)] < 0.29f;
  std::printf("water through a hole cut in a sheet: %d of %d particles below it\n", below, water.count);
  EXPECT_EQ(below, water.count);
}

// A carried paddle one particle thick (1 x 20 x 10) driven through a pool at 3 and 6 m/s (2.5 and
// 5 spacings a substep at 2 substeps) pushes the water ahead of it: the move is swept relative to
// the body, from its pose at the substep's start to its pose now, so a body that jumps past a
// particle meets it as a particle thrown at it. The oracle: the paddle is a solid, so no particle
// over its face (within its height and width) is ever found ahead of it one step and behind it
// the next. Before the sweep, 524 and 911 particles crossed in 0.33 s.
TEST(Sweep, APaddleDrivenThroughWaterPushesItAhead) {
  for (const double speed : {3.0, 6.0}) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("paddle", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
    BodyRange water = addBox(p, Vec3(0.2, kRadius, 0.2), 20, 12, 20, 0, 1);
    PbdWorld w(p, {water}, mats, params(2, 4));
    ParticleArrays more;
    const int paddle = w.addBody(more, addBox(more, Vec3(0.15, 0.02, 0.25), 1, 20, 10, 1, 0), true);
    std::vector<int> side(std::size_t(water.count), -1);  // 1 ahead, 0 behind, -1 not over the face
    int crossed = 0;
    for (int s = 0; s < 20; ++s) {
      w.setKinematicTarget(paddle, w.pose(paddle).centre + Vec3(speed * w.params().dt, 0.0, 0.0));
      ASSERT_TRUE(w.step()) << w.guard().message();
      const ParticleArrays& q = w.particles();
      const double face = w.pose(paddle).centre.x();
      for (std::int32_t i = 0; i < water.count; ++i) {
        const auto k = std::size_t(water.first + i);
        const bool over = q.y[k] > 0.025f && q.y[k] < 0.205f && q.z[k] > 0.255f && q.z[k] < 0.335f;
        const int now = over ? int(q.x[k] > face) : -1;
        crossed += side[std::size_t(i)] == 1 && now == 0;
        side[std::size_t(i)] = now;
      }
    }
    std::printf("paddle at %.0f m/s through water: %d particles crossed it\n", speed, crossed);
    EXPECT_EQ(crossed, 0) << speed << " m/s";
  }
}

// The material's sound_speed reaches the density constraint: water of c = 4 m/s resting
// in the tank is compressed as a fluid of bulk modulus rho0 c^2, a mean of g H / (2 c^2)
// over its depth H (closed form; FluidRest.CompressionIsTheBulkModulusForAnySubsteps checks
// the kernel alone). Tolerance 25 %: the tank's particle walls read up to 7.5 % over-dense
// at its edges (Akinci's boundary, pbd/fluid.cpp) and the top layer reads no compression.
TEST(Fluid, TheMaterialsSoundSpeedSetsItsCompression) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("tank", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
  const double c = 4.0;
  mats[1].fluid.soundSpeed = c;
  BodyRange tank = addTank(p, 14, 16, 0);
  BodyRange water = addBox(p, Vec3(kRadius, kRadius, kRadius), 14, 10, 14, 1, 1);
  PbdWorld w(p, {tank, water}, mats, params(3, 8));
  for (const PlanEntry& e : w.plan()) {  // the plan names the sound speed the density pass uses
    if (e.name == "density") {
      EXPECT_NE(e.reason.find("sound speed 4 m/s"), std::string::npos) << e.reason;
    }
  }
  for (int s = 0; s < 120; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  float top = 0.0f;
  const ParticleArrays& q = w.particles();
  for (std::int32_t i = water.first; i < water.first + water.count; ++i) top = std::max(top, q.y[std::size_t(i)]);
  const double depth = double(top) + kRadius;  // the pool's surface above the ground (m)
  const double expected = 9.81 * depth / (2.0 * c * c);
  const DensityError e = w.fluidDensityError();
  std::printf("pool of c = %.1f m/s: mean compression %.3f %% against g H / (2 c^2) = %.3f %%\n", c,
              100.0 * e.meanCompression, 100.0 * expected);
  EXPECT_NEAR(e.meanCompression / expected, 1.0, 0.25);
}

// Too soft by choice: water of c = 1.5 m/s in the same pool would rest at g H / (2 c^2) = 22 %
// mean compression, over the guard's 10 %; the guard's diagnosis names the material's
// sound_speed as the cause (raising iterations would not help a compliant constraint).
TEST(Fluid, TheGuardNamesATooLowSoundSpeed) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("tank", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid)};
  mats[1].fluid.soundSpeed = 1.5;
  BodyRange tank = addTank(p, 14, 16, 0);
  BodyRange water = addBox(p, Vec3(kRadius, kRadius, kRadius), 14, 10, 14, 1, 1);
  PbdWorld w(p, {tank, water}, mats, params(3, 8));
  bool stopped = false;
  for (int s = 0; s < 60 && !stopped; ++s) stopped = !w.step();
  ASSERT_TRUE(stopped);
  EXPECT_NE(w.guard().message().find("sound_speed 1.5 m/s"), std::string::npos) << w.guard().message();
}

// Two fluids of different viscosity in one scene, far apart (0.5 m, a dozen kernel radii):
// each collapsing cube spreads as it does in a scene of its own (the oracle: the same cube
// alone, whose material is then the only one). Before, every fluid took the first fluid
// material's xsph_viscosity, so the honey spread like water. Both set sound_speed so that
// neither's stiffness depends on the other's height or speed (the automatic one is the
// scene's). Tolerance 5 % of each spread: the runs may differ in rounding (a neighbour grid
// of another origin can sum in another order), which a collapse amplifies, but not to 5 %
// in 24 steps (measured: equal to 4 digits); the two fluids' spreads differ by 28 %. The
// same with the dynamic viscosity (implicit, pbd/fluid.h): honey of 20 Pa s beside water
// (its front advanced 0.10 m against the water's 0.27 m).
TEST(Fluid, EachFluidMaterialKeepsItsOwnViscosity) {
  for (const bool dynamic : {false, true}) {
    SCOPED_TRACE(dynamic ? "viscosity" : "xsph_viscosity");
    std::vector<Material> mats = {makeKind("water", MaterialKind::kFluid), makeKind("honey", MaterialKind::kFluid)};
    mats[0].fluid.xsphViscosity = 0.0, mats[1].fluid.xsphViscosity = dynamic ? 0.0 : 1.0;
    if (dynamic) mats[1].fluid.viscosity = 20.0;
    for (Material& m : mats) m.fluid.soundSpeed = 20.0;
    const int side = 12;
    const auto spreads = [&](bool water, bool honey) {
      ParticleArrays p;
      std::vector<BodyRange> bodies;
      if (water) bodies.push_back(addBox(p, Vec3(kRadius, kRadius, kRadius), side, side, side, 1, 0));
      if (honey) bodies.push_back(addBox(p, Vec3(kRadius, kRadius, 0.5 + kRadius), side, side, side, 2, 1));
      PbdWorld w(p, bodies, mats, params(2, 4));
      for (int s = 0; s < 24; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
      std::vector<double> out;  // each body's largest x (its front, from x = side spacings at the start)
      for (const BodyRange& b : bodies) {
        float x = -1e30f;
        for (std::int32_t i = b.first; i < b.first + b.count; ++i) x = std::max(x, w.particles().x[std::size_t(i)]);
        out.push_back(double(x) - side * kSpacing);
      }
      return out;
    };
    const std::vector<double> both = spreads(true, true), water = spreads(true, false), honey = spreads(false, true);
    std::printf("front advance (m): water %.4f alone %.4f; honey %.4f alone %.4f\n", both[0], water[0], both[1], honey[0]);
    ASSERT_GT(water[0] - honey[0], 0.15 * water[0]) << "the viscosities make no difference: the test cannot tell";
    EXPECT_NEAR(both[0], water[0], 0.05 * water[0]);
    EXPECT_NEAR(both[1], honey[0], 0.05 * honey[0]);
  }
}

// A viscous fluid spreading on the ground against Huppert 1982's similarity solution for an
// axisymmetric viscous gravity current of constant volume V on a rigid no-slip surface at low
// Reynolds number: r_N(t) = 0.894 (rho g V^3 t / (3 mu))^(1/8) (J. Fluid Mech. 121, 43-58). A
// 16^3-particle cube of honey (1400 kg/m^3) let go on the ground; the front is the particle
// centre furthest from the axis. It needs the implicit viscosity and the walls' no-slip (with
// the ground slipping the pool spreads like water). Returns the ratio to Huppert's front at
// 1 s and 2 s (the cube has spread to 3 times its half width and the similarity solution
// holds; Re = rho U H / mu is below 0.1).
std::vector<double> huppertRatios(double mu, int substeps) {
  std::vector<Material> mats = {makeKind("honey", MaterialKind::kFluid, 1400.0)};
  mats[0].fluid.viscosity = mu;
  const int side = 16;
  ParticleArrays p;
  std::vector<BodyRange> bodies = {addBox(p, Vec3(kRadius, kRadius, kRadius), side, side, side, 1, 0)};
  PbdWorld w(p, bodies, mats, params(substeps, 4));
  const double V = std::pow(side * kSpacing, 3), c = 0.5 * side * kSpacing;
  std::vector<double> out;
  int steps = 0;
  for (const double t : {1.0, 2.0}) {
    for (; steps < int(std::lround(t * 60.0)); ++steps) {
      EXPECT_TRUE(w.step()) << w.guard().message();
      if (::testing::Test::HasFailure()) return out;
    }
    double r = 0.0;
    for (std::int32_t i = 0; i < bodies[0].count; ++i) {
      const auto k = std::size_t(i);
      r = std::max(r, std::hypot(double(w.particles().x[k]) - c, double(w.particles().z[k]) - c));
    }
    const double huppert = 0.894 * std::pow(1400.0 * 9.81 * V * V * V * t / (3.0 * mu), 1.0 / 8.0);
    std::printf("mu %g Pa s, %d substeps, t %.0f s: front %.4f m, Huppert %.4f m (ratio %.3f)\n", mu, substeps, t, r,
                huppert, r / huppert);
    out.push_back(r / huppert);
  }
  bool planned = false;  // the plan tells how hard the viscous solve was
  for (const PlanEntry& pe : w.plan())
    if (pe.name == "fluid_velocity") {
      planned = true;
      EXPECT_NE(pe.reason.find("the viscosity's CG took"), std::string::npos) << pe.reason;
    }
  EXPECT_TRUE(planned);
  return out;
}

// 50 Pa s at 4 substeps: within 10 % of Huppert's front (measured 1.038 at 1 s, 1.056 at 2 s;
// PBF's pressure acts through position corrections outside the viscous step, a splitting
// error of first order in the substep, below).
TEST(Fluid, AViscousPoolSpreadsAsHuppertsGravityCurrent) {
  for (double ratio : huppertRatios(50.0, 4)) EXPECT_NEAR(ratio, 1.0, 0.10);
}

// The splitting error shrinks with the substep: at 200 Pa s the front at 2 s runs 21 % ahead
// of Huppert's with 2 substeps and 7 % with 8 (measured 1.208 and 1.066). Asserted: 8
// substeps' error below half of 2 substeps', and within 12 %.
TEST(Fluid, AVeryViscousPoolConvergesToHuppertWithSubsteps) {
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "too slow under AddressSanitizer; make test runs it (the other Huppert test covers the code)";
#endif
  const std::vector<double> coarse = huppertRatios(200.0, 2), fine = huppertRatios(200.0, 8);
  ASSERT_EQ(coarse.size(), 2u);
  ASSERT_EQ(fine.size(), 2u);
  EXPECT_LT(std::fabs(fine[1] - 1.0), 0.5 * std::fabs(coarse[1] - 1.0));
  EXPECT_NEAR(fine[1], 1.0, 0.12);
}

// The solid's side of the viscosity, in the world: in zero gravity, far from the ground, a
// 4^3 cube (3000 kg/m^3; rigid, then soft: six unknowns of the solve, then 64 free
// particles) moves at 0.5 m/s through the middle of a 14^3 blob of honey
// (1400 kg/m^3). Oracle: nothing outside acts, so the momentum of stone and honey together
// stays (the density pass exchanges it exactly, the viscous solve to its CG tolerance, 1e-4
// of the momenta a substep; bound 2 % of the stone's after 0.5 s = 120 substeps), and with
// honey's 50 Pa s (diffusion time of the blob L^2 / nu ~ 0.5 s) stone and honey end near
// their common velocity P / (M + m): within 0.01 m/s of it, a fiftieth of the stone's start
// (measured 0.003). One way, the solid kept its speed while the honey took momentum from
// nowhere: both fail. Third, the same volume as a thick rope moving along its axis: 4
// particles of radius 2 spacings, whose 4 x 4 samples each fill the cube's cross-section
// (PbdWorld::strandSamples), each particle one unknown of the solve. Fourth, as a thick cloth
// moving along its sheet: a 4 x 4 lattice of radius 2 spacings, 4 samples across it each.
// Also: the same scene in water (whose viscosity is not solved) leaves the stone faster.
TEST(Fluid, AStoneInHoneyHandsItsMomentumToTheHoney) {
  // Returns the solid's speed; total: the momentum of everything at the end (kg m/s), from
  // the particles (a rigid body's carry v + w x r: their sum is M v).
  const auto run = [](MaterialKind kind, double mu, double& P0, double& total, double& common) {
    std::vector<Material> mats = {makeKind("honey", MaterialKind::kFluid, 1400.0), makeKind("solid", kind, 3000.0)};
    mats[0].fluid.viscosity = mu;
    ParticleArrays p;
    const Vec3 corner(kRadius, 0.5, kRadius);
    const auto inSolid = [](int a, int b, int c) { return a >= 5 && a < 9 && b >= 5 && b < 9 && c >= 5 && c < 9; };
    BodyRange honey;
    honey.first = std::int32_t(p.size());
    for (int a = 0; a < 14; ++a)
      for (int b = 0; b < 14; ++b)
        for (int c = 0; c < 14; ++c) {
          if (inSolid(a, b, c)) continue;
          const Vec3 x = corner + kSpacing * Vec3(a, b, c);
          p.push(float(x.x()), float(x.y()), float(x.z()), 1, 0);
        }
    honey.count = std::int32_t(p.size()) - honey.first;
    BodyRange solid = kind == MaterialKind::kRope    ? addChain(p, corner + kSpacing * Vec3(5, 6.5, 6.5), Vec3(1, 0, 0), 4, 1)
                      : kind == MaterialKind::kCloth ? addFlatSheet(p, corner + kSpacing * Vec3(5, 6.5, 5), 4, 4, 1)
                                                     : addBox(p, corner + kSpacing * Vec3(5, 5, 5), 4, 4, 4, 2, 1);
    if (kind == MaterialKind::kRope || kind == MaterialKind::kCloth) solid.radius = float(2.0 * kSpacing), solid.stroke = 2;
    solid.init.velocity = Vec3(0.5, 0.0, 0.0);
    PbdWorld w(p, {honey, solid}, mats, params(4, 4, Vec3::Zero()));
    const auto momentum = [&](std::int32_t first, std::int32_t count, double& mass) {
      double P = 0.0;
      mass = 0.0;
      for (std::int32_t i = first; i < first + count; ++i) {
        const auto k = std::size_t(i);
        P += double(w.particles().mass[k]) * w.particles().vx[k], mass += w.particles().mass[k];
      }
      return P;
    };
    double M = 0.0, m = 0.0;
    P0 = momentum(solid.first, solid.count, M) + momentum(honey.first, honey.count, m);
    for (int s = 0; s < 30; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    if (mu > 1.0) {  // the plan says what the viscosity drags
      bool planned = false;
      for (const PlanEntry& pe : w.plan()) {
        if (pe.name != "fluid_velocity") continue;
        planned = true;
        const char* want = kind == MaterialKind::kRigid   ? "dragging back 1 rigid body and 0 soft, rope or cloth particles"
                           : kind == MaterialKind::kRope  ? "dragging back 0 rigid bodies and 4 soft, rope or cloth particles"
                           : kind == MaterialKind::kCloth ? "dragging back 0 rigid bodies and 16 soft, rope or cloth particles"
                                                          : "dragging back 0 rigid bodies and 64 soft, rope or cloth particles";
        EXPECT_NE(pe.reason.find(want), std::string::npos) << pe.reason;
      }
      EXPECT_TRUE(planned);
    }
    const double Ps = momentum(solid.first, solid.count, M);
    total = Ps + momentum(honey.first, honey.count, m);
    common = P0 / (M + m);
    std::printf("a %s cube through %g Pa s in zero gravity, 0.5 s: 0.5 -> %.4f m/s (common velocity %.4f), momentum %.5f -> "
                "%.5f kg m/s\n",
                kind == MaterialKind::kRigid  ? "rigid"
                : kind == MaterialKind::kRope  ? "rope"
                : kind == MaterialKind::kCloth ? "cloth"
                                               : "soft",
                mu, Ps / M, common, P0,
                total);
    return Ps / M;
  };
  for (const MaterialKind kind : {MaterialKind::kRigid, MaterialKind::kSoft, MaterialKind::kRope, MaterialKind::kCloth}) {
    double P0 = 0.0, total = 0.0, common = 0.0, waterP0 = 0.0, waterTotal = 0.0, waterCommon = 0.0;
    const double inHoney = run(kind, 50.0, P0, total, common);
    EXPECT_NEAR(total, P0, 0.02 * P0);
    EXPECT_NEAR(inHoney, common, 0.01);
    EXPECT_GT(run(kind, 1e-3, waterP0, waterTotal, waterCommon), inHoney + 0.05);  // water's viscosity is not solved
  }
}

// Several fluids, one of them soft by choice: oil (auto sound speed) floats on water of
// c = 1.5 m/s, which its own weight compresses by g H / (2 c^2) ~ 20 %, over the guard's
// 10 %. The plan names each fluid's sound speed, and the guard names the water's, though the
// oil is the scene's first fluid (before, every fluid took the first's sound speed: the
// water was stiff and nothing stopped).
TEST(Fluid, TheGuardNamesTheSoftFluidAmongSeveral) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("tank", MaterialKind::kRigid), makeKind("oil", MaterialKind::kFluid, 800.0),
                                makeKind("water", MaterialKind::kFluid)};
  mats[2].fluid.soundSpeed = 1.5;
  BodyRange tank = addTank(p, 14, 16, 0);
  BodyRange oil = addBox(p, Vec3(kRadius, kRadius + 10 * kSpacing, kRadius), 14, 3, 14, 1, 1);
  BodyRange water = addBox(p, Vec3(kRadius, kRadius, kRadius), 14, 10, 14, 2, 2);
  PbdWorld w(p, {tank, oil, water}, mats, params(3, 8));
  bool planned = false;
  for (const PlanEntry& e : w.plan())
    if (e.name == "density") {
      planned = true;
      EXPECT_NE(e.reason.find("sound speed oil auto"), std::string::npos) << e.reason;
      EXPECT_NE(e.reason.find("water 1.5 m/s"), std::string::npos) << e.reason;
    }
  EXPECT_TRUE(planned);
  bool stopped = false;
  for (int s = 0; s < 60 && !stopped; ++s) stopped = !w.step();
  ASSERT_TRUE(stopped) << "the soft water did not trip the guard's compression bound";
  EXPECT_NE(w.guard().message().find("'water' has sound_speed 1.5 m/s"), std::string::npos) << w.guard().message();
}

// Two-way coupling: a wooden cube (400 kg/m^3) dropped on water floats with its centre near
// the surface (Archimedes: 40 % submerged puts the centre 0.1 edge above the surface; the
// window, -0.3 to +0.5 edge, allows for the wave it makes and the coarse particles); a
// stone cube (3000 kg/m^3) sinks to the bottom half.
TEST(Fluid, ALightBodyFloatsAndAHeavyOneSinks) {
  const auto finalHeight = [](double density) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("tank", MaterialKind::kRigid), makeKind("water", MaterialKind::kFluid),
                                  makeKind("cube", MaterialKind::kRigid, density)};
    BodyRange tank = addTank(p, 16, 20, 0);
    BodyRange water = addBox(p, Vec3(kRadius, kRadius, kRadius), 16, 10, 16, 1, 1);
    BodyRange cube = addBox(p, Vec3(0.05 + kRadius, 0.11 + kRadius, 0.05 + kRadius), 6, 6, 6, 2, 2);
    PbdWorld w(p, {tank, water, cube}, mats, params(3, 8));
    for (int s = 0; s < 150; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    return w.pose(2).centre.y();
  };
  const double surface = 10 * kSpacing, edge = 6 * kSpacing;
  const double wood = finalHeight(400.0), stone = finalHeight(3000.0);
  EXPECT_GT(wood, surface - 0.3 * edge) << "the wooden cube sank";
  EXPECT_LT(wood, surface + 0.5 * edge) << "the wooden cube did not settle into the water";
  EXPECT_LT(stone, 0.5 * surface) << "the stone cube floated";
}

namespace {

// An open square sheet of two triangles in the plane x = wallX, spanning y and z in
// [lo, hi] (m): a wall one triangle thick, no inside.
ColliderSet wallAt(double wallX, double lo, double hi) {
  MeshCollider c;
  c.name = "wall";
  TriangleSoup s;
  s.vertices = {Vec3(wallX, lo, lo), Vec3(wallX, hi, lo), Vec3(wallX, hi, hi), Vec3(wallX, lo, hi)};
  s.triangles = {{0, 1, 2}, {0, 2, 3}};
  s.closed = false;
  return ColliderSet({c}, {s});
}

}  // namespace

// A ball thrown at a one-triangle-thick mesh wall never gets a particle past it: at 2 and
// at 20 particle radii per substep (the sweep stops fast material at the first touch),
// rigid (body level) and soft (particle level). Zero gravity, so only the wall acts.
TEST(Colliders, ABallThrownAtAThinMeshWallNeverCrossesIt) {
  for (const MaterialKind kind : {MaterialKind::kRigid, MaterialKind::kSoft})
    for (const double radiiPerSubstep : {2.0, 20.0}) {
      ParticleArrays p;
      std::vector<Material> mats = {makeKind("ball", kind)};
      BodyRange ball = addBall(p, Vec3(0.2, 0.5, 0.5), 4, 0, 0);
      PbdParams prm = params(4, 4, Vec3::Zero());
      const double h = prm.dt / prm.substeps;
      ball.init.velocity = Vec3(radiiPerSubstep * kRadius / h, 0.0, 0.0);
      const double wallX = 0.3;
      PbdWorld w(p, {ball}, mats, prm);
      w.setColliders(wallAt(wallX, 0.2, 0.8));
      bool turned = false;
      for (int s = 0; s < 60; ++s) {
        ASSERT_TRUE(w.step()) << w.guard().message();
        const ParticleArrays& q = w.particles();
        for (std::int32_t i = ball.first; i < ball.first + ball.count; ++i)
          ASSERT_LT(q.x[std::size_t(i)], wallX) << toString(kind) << " at " << radiiPerSubstep << " radii per substep, step " << s;
        turned = turned || w.velocity(0).x() < 0.5 * ball.init.velocity.x();
      }
      EXPECT_TRUE(turned) << "the wall did not stop the " << toString(kind) << " ball";
    }
}

// A rigid box dropped on a mesh floor (a sheet at y = 0.2 m) rests on it like on the
// ground: its lowest particle a radius above the sheet, within a fifth of a radius.
TEST(Colliders, ABoxRestsOnAMeshFloor) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("box", MaterialKind::kRigid)};
  BodyRange box = addBox(p, Vec3(0.45, 0.3, 0.45), 6, 6, 6, 0, 0);
  MeshCollider c;
  c.name = "floor";
  TriangleSoup s;
  s.vertices = {Vec3(0.2, 0.2, 0.2), Vec3(0.8, 0.2, 0.2), Vec3(0.8, 0.2, 0.8), Vec3(0.2, 0.2, 0.8)};
  s.triangles = {{0, 2, 1}, {0, 3, 2}};
  PbdWorld w(p, {box}, mats, params(4, 4));
  w.setColliders(ColliderSet({c}, {s}));
  for (int k = 0; k < 90; ++k) ASSERT_TRUE(w.step()) << w.guard().message();
  const ParticleArrays& q = w.particles();
  const float lowest = *std::min_element(q.y.begin(), q.y.end());
  EXPECT_NEAR(lowest, 0.2 + kRadius, 0.2 * kRadius);
  EXPECT_LT(w.velocity(0).norm(), 0.01);
}

// The guard learns the fluid's failure: a block of water dropped from 30 cm with one
// substep of one iteration at 1/20 s steps is crushed on landing far beyond the 10 % mean
// compression bound; the guard stops the run and names the kind (compression), the pass
// (density) and the fluid's material. With 4 substeps of 8 iterations the same drop passes.
TEST(Fluid, TheGuardNamesACompressedFluid) {
  const auto run = [](int substeps, int iterations) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("water", MaterialKind::kFluid)};
    BodyRange water = addBox(p, Vec3(0.0, 0.3, 0.0), 12, 12, 12, 0, 0);
    PbdParams prm = params(substeps, iterations);
    prm.dt = 1.0 / 20.0;
    PbdWorld w(p, {water}, mats, prm);
    for (int s = 0; s < 40; ++s)
      if (!w.step()) break;
    return w.guard();
  };
  const GuardRecord bad = run(1, 1);
  ASSERT_TRUE(bad.tripped());
  EXPECT_EQ(bad.kind, GuardKind::kCompression) << bad.message();
  EXPECT_EQ(bad.pass, "density");
  EXPECT_EQ(bad.material, "water");
  EXPECT_GT(bad.value, 0.1);
  EXPECT_FALSE(run(4, 8).tripped()) << run(4, 8).message();
  // With the warm start the multipliers carried into the failing step are part of its start:
  // the replay that names the pass (validate off) restores them, so it finds what a run
  // checked pass by pass from the first step (validate on) finds, to the bit.
  GuardRecord warm[2];
  for (int validate = 0; validate < 2; ++validate) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("water", MaterialKind::kFluid)};
    BodyRange water = addBox(p, Vec3(0.0, 0.3, 0.0), 12, 12, 12, 0, 0);
    PbdParams prm = params(1, 1);
    prm.dt = 1.0 / 20.0;
    prm.warmStart = 0.6;
    PbdWorld w(p, {water}, mats, prm);
    w.setValidate(validate != 0);
    for (int s = 0; s < 40; ++s)
      if (!w.step()) break;
    warm[validate] = w.guard();
  }
  ASSERT_TRUE(warm[0].tripped());
  EXPECT_EQ(warm[0].kind, GuardKind::kCompression) << warm[0].message();
  EXPECT_EQ(warm[0].pass, "density");
  EXPECT_EQ(warm[0].step, warm[1].step);
  EXPECT_EQ(warm[0].particle, warm[1].particle);
  EXPECT_EQ(warm[0].value, warm[1].value) << warm[0].message() << " / " << warm[1].message();
}

namespace physketch::pbd {

// A stone ball (R = 4.5 spacings, 3000 kg/m^3) sinking through honey (1400 kg/m^3, 50 Pa s)
// in a 24 x 24 tank: Re = rho U 2R / mu ~ 0.1, Stokes' regime. Its weight less its buoyancy,
// (rho_s - rho) g V with V its voxels' volume, against Stokes' drag 6 pi mu a U, a the radius
// of its no-slip surface: its boundary particles' centres, half a spacing inside its voxels'
// faces (FluidViscosity.APlateOnAFilmSlowsAtStokesRate measures that independently), so
// a = R - r. The walls slow it: the square tank lies between its inscribed and circumscribed
// cylinders, and a narrower container only slows a sphere more (Stokes flow dissipates least
// in the larger domain), so Haberman and Sayre's factor for a sphere on the axis of a
// cylinder, 1 - 2.105 k + 2.0865 k^3 - 1.7068 k^5 + 0.72603 k^6 over 1 - 0.75857 k^5 (k =
// a / R_c), brackets it: the circumscribed one's the upper bound; the inscribed one's times
// Lorentz's factor for the ground under it, 1 / (1 + 9/8 a / h) (h the centre's height), the
// lower. Asserted: the mean speed from 0.5 to 0.7 s within that bracket, 0.047 to 0.085 m/s
// (measured 0.070). Before the stone felt the honey (one way) it sank at 0.11 m/s from 0.4 to
// 0.7 s, outside the bracket. (With Akinci's boundary volumes, which left the fluid at the
// stone's face 8 % over-dense, it sank at 0.050.)
TEST(Fluid, AStoneSinksThroughHoneyAtStokesSpeedBetweenTheWalls) {
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "too slow under AddressSanitizer; make test runs it (the plate and momentum tests cover the code)";
#endif
  const double mu = 50.0, rho = 1400.0, rhoS = 3000.0;
  const int inner = 24, height = 30, R = 4;
  std::vector<Material> mats = {makeKind("tank", MaterialKind::kRigid), makeKind("honey", MaterialKind::kFluid, rho),
                                makeKind("stone", MaterialKind::kRigid, rhoS)};
  mats[1].fluid.viscosity = mu;
  ParticleArrays p;
  BodyRange tank = addTank(p, inner, height + 2, 0);
  const Vec3 centre = Vec3(kRadius, kRadius, kRadius) + kSpacing * Vec3(inner / 2 - 0.5, height - R - 3, inner / 2 - 0.5);
  const auto inBall = [&](const Vec3& x) { return (x - centre).norm() < (R + 0.5) * kSpacing; };
  BodyRange honey;
  honey.first = std::int32_t(p.size());
  for (int a = 0; a < inner; ++a)
    for (int b = 0; b < height; ++b)
      for (int c = 0; c < inner; ++c) {
        const Vec3 x = Vec3(kRadius, kRadius, kRadius) + kSpacing * Vec3(a, b, c);
        if (!inBall(x)) p.push(float(x.x()), float(x.y()), float(x.z()), 1, 1);
      }
  honey.count = std::int32_t(p.size()) - honey.first;
  BodyRange ball;
  ball.first = std::int32_t(p.size());
  for (int a = -R; a <= R; ++a)
    for (int b = -R; b <= R; ++b)
      for (int c = -R; c <= R; ++c) {
        const Vec3 x = centre + kSpacing * Vec3(a, b, c);
        if (inBall(x)) p.push(float(x.x()), float(x.y()), float(x.z()), 2, 2);
      }
  ball.count = std::int32_t(p.size()) - ball.first;
  PbdWorld w(p, {tank, honey, ball}, mats, params(4, 4));
  double y0 = 0.0, y1 = 0.0;
  for (int s = 1; s <= 42; ++s) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    if (s == 30) y0 = w.pose(2).centre.y();
  }
  y1 = w.pose(2).centre.y();
  const double pi = 3.14159265358979, speed = (y0 - y1) / 0.2, volume = ball.count * std::pow(kSpacing, 3);
  const double Rb = std::cbrt(3.0 * volume / (4.0 * pi)) - kRadius;  // the no-slip radius a
  const double stokes = (rhoS - rho) * 9.81 * volume / (6.0 * pi * mu * Rb);
  const auto haberman = [](double k) {
    return (1.0 - 2.105 * k + 2.0865 * std::pow(k, 3) - 1.7068 * std::pow(k, 5) + 0.72603 * std::pow(k, 6)) /
           (1.0 - 0.75857 * std::pow(k, 5));
  };
  const double half = 0.5 * inner * kSpacing;
  const double hi = stokes * haberman(Rb / (half * std::sqrt(2.0)));
  const double lo = stokes * haberman(Rb / half) / (1.0 + 9.0 / 8.0 * Rb / (0.5 * (y0 + y1)));
  std::printf("stone ball (a %.4f m) in honey: sinks at %.4f m/s from 0.5 to 0.7 s; Stokes %.4f m/s, between the tank's "
              "walls %.4f to %.4f m/s\n",
              Rb, speed, stokes, lo, hi);
  EXPECT_GT(speed, lo);
  EXPECT_LT(speed, hi);
}

}  // namespace physketch::pbd

// Sleeping beside particle-level material (PbdParams::sleepSpeed). A rigid body that an awake
// soft, rope, cloth or fluid particle touches (a particle pair) or a strand is tied to stays awake;
// soft bodies, ropes and cloths at rest sleep too (since 2026-11-29), so a box under a jelly sleeps
// once the jelly does, and a rope tied to a dynamic box keeps both awake. Until 2026-11-28 any
// particle-level material in a scene kept every body awake. Oracles: the sleep rule (each body is
// at rest after 1 s and sleeps 0.5 s later) and the exceptions it names.
TEST(SleepBeside, RestingBodiesSleepTogetherAndOnesTiedToADynamicBodyStayAwake) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("wood", MaterialKind::kRigid), makeKind("jelly", MaterialKind::kSoft),
                                makeKind("rope", MaterialKind::kRope, 100.0), makeKind("cloth", MaterialKind::kCloth, 100.0)};
  mats[1].elastic.youngs = 5e4;
  std::vector<BodyRange> bodies;
  bodies.push_back(addBox(p, Vec3(0.0, kRadius, 0.0), 6, 4, 6, 0, 0));     // 0: alone
  bodies.push_back(addBox(p, Vec3(0.3, kRadius, 0.0), 6, 4, 6, 0, 0));     // 1: a jelly on it
  bodies.push_back(addBox(p, Vec3(0.31, kRadius + 4 * kSpacing, 0.01), 4, 4, 4, 0, 1));  // 2: that jelly
  bodies.push_back(addBox(p, Vec3(-0.3, kRadius, 0.0), 6, 4, 6, 0, 0));    // 3: a rope tied to it
  bodies.push_back(addChain(p, Vec3(-0.3 - kSpacing, kRadius, 0.02), Vec3(-1, 0, 0), 20, 2));  // 4: that rope, on the ground
  bodies.push_back(addBox(p, Vec3(0.6, kRadius, 0.3), 4, 4, 4, 0, 1));     // 5: a jelly alone
  bodies.push_back(addChain(p, Vec3(0.0, kRadius, 0.4), Vec3(1, 0, 0), 20, 2));  // 6: a rope alone, on the ground
  bodies.push_back(addSheet(p, Vec3(0.4, kRadius, 0.5), 8, 8, 3, Vec3(0, 0, 1)));  // 7: a cloth lying flat
  for (std::size_t b = 0; b < bodies.size(); ++b) bodies[b].stroke = int(b);
  PbdParams prm = params(8, 4);
  prm.sleepSpeed = 0.02, prm.sleepTime = 0.5;
  PbdWorld w(p, bodies, mats, prm);
  for (int s = 0; s < 120; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  EXPECT_TRUE(w.asleep(0)) << "nothing particle-level touches it";
  EXPECT_TRUE(w.asleep(2)) << "a jelly resting on a box";
  EXPECT_TRUE(w.asleep(1)) << "the box under a sleeping jelly";
  EXPECT_FALSE(w.asleep(3)) << "a rope is tied to it";
  EXPECT_FALSE(w.asleep(4)) << "a rope tied to a dynamic box";
  EXPECT_TRUE(w.asleep(5)) << "a jelly alone";
  EXPECT_TRUE(w.asleep(6)) << "a rope alone";
  EXPECT_TRUE(w.asleep(7)) << "a cloth alone";
  EXPECT_EQ(w.sleepingCount(), 6);
}

namespace {

// A jelly (6 x 6 x 6, E = 5e4 Pa) on the ground, dropped 1 cm; body 0. With `box`, a 4 x 4 x 4
// wooden box resting on it (body 1).
PbdWorld jellyOnGround(bool box, double sleepSpeed, double youngs = 5e4) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("wood", MaterialKind::kRigid), makeKind("jelly", MaterialKind::kSoft)};
  mats[1].elastic.youngs = youngs;
  std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, kRadius + 0.01, 0.0), 6, 6, 6, 0, 1)};
  if (box) bodies.push_back(addBox(p, Vec3(0.01, kRadius + 0.01 + 6 * kSpacing, 0.01), 4, 4, 4, 1, 0));
  PbdParams prm = params(8, 4);
  prm.sleepSpeed = sleepSpeed, prm.sleepTime = 0.5;
  return PbdWorld(p, bodies, mats, prm);
}

}  // namespace

// A jelly at rest on the ground falls asleep, not before it has been still for the sleep time
// (it lands at about 0.05 s: not at 0.5 s) and within 1.5 s. Asleep, its particles' velocities
// are exactly 0, they stay bit for bit where they are, and the plan runs no particle-level pass:
// a resting jelly costs what a resting box does.
TEST(SleepBeside, AJellyAtRestFallsAsleepStaysBitForBitAndRunsNoParticlePass) {
  PbdWorld w = jellyOnGround(false, 0.02);
  const int fellAsleep = stepUntilAsleep(w, 0, 90);
  ASSERT_GE(fellAsleep, 0) << "not asleep after 1.5 s; " << w.guard().message();
  EXPECT_GT(fellAsleep, 30);
  const ParticleArrays before = w.particles();
  ASSERT_TRUE(allExactlyAtRest(before));
  for (int s = 0; s < 60; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  EXPECT_TRUE(w.asleep(0));
  EXPECT_EQ(w.particles().x, before.x);
  EXPECT_EQ(w.particles().y, before.y);
  EXPECT_EQ(w.particles().z, before.z);
  int checked = 0;
  for (const PlanEntry& e : w.planAll())
    if (e.name == "predict" || e.name == "cluster_match" || e.name == "particle_update") {
      EXPECT_FALSE(e.on) << e.name << ": " << e.reason;
      ++checked;
    }
  EXPECT_EQ(checked, 3);
}

// A sketch edit wakes a sleeping jelly (as it wakes every body): a jelly asleep on the ground is cut
// (its top layer removed after play); the next step it is awake, with its remaining particles,
// and it settles and sleeps again within 1.5 s. Its top layer's particles are gone from it.
TEST(SleepBeside, ACutWakesASleepingJelly) {
  PbdWorld w = jellyOnGround(false, 0.02);
  ASSERT_GE(stepUntilAsleep(w, 0, 90), 0) << w.guard().message();
  const std::size_t before = w.bodyParticles(0).size();
  float top = -1e30f;
  for (std::int32_t i : w.bodyParticles(0)) top = std::max(top, w.particles().y[std::size_t(i)]);
  std::vector<std::int32_t> cut;
  for (std::int32_t i : w.bodyParticles(0))
    if (w.particles().y[std::size_t(i)] > top - 0.5f * float(kSpacing)) cut.push_back(i);
  ASSERT_EQ(cut.size(), 36u);  // the 6 x 6 top layer
  w.removeParticles(cut);
  ASSERT_TRUE(w.step()) << w.guard().message();
  EXPECT_FALSE(w.asleep(0));
  EXPECT_EQ(w.bodyParticles(0).size(), before - cut.size());
  EXPECT_GE(stepUntilAsleep(w, 0, 90), 0) << w.guard().message();
}

// A box resting on a soft jelly (E = 2e4 Pa) falls asleep with it, in the same step. Had the
// jelly slept first (it is still before the box is), the box would meet it at body level, as a
// fixed body, at the contact distance 2 r, above where the particle pairs let it sink in (2.7 mm
// here), and pop up by that much before sleeping in turn. Oracle: the box's height the step before
// the first of them falls asleep, which the box must keep, asleep, 60 steps after both are (within
// 1 % of r: the still box moves by 6e-6 m in a step), the two staying bit for bit meanwhile.
TEST(SleepBeside, ABoxOnAJellyFallsAsleepWithItWithoutAJump) {
  PbdWorld w = jellyOnGround(true, 0.02, 2e4);
  double before = 0.0;
  int first = -1;
  for (int s = 0; s < 150 && first < 0; ++s) {
    before = w.pose(1).centre.y();
    ASSERT_TRUE(w.step()) << w.guard().message();
    if (w.asleep(0) || w.asleep(1)) first = s;
  }
  ASSERT_GE(first, 0) << "neither slept in 2.5 s";
  for (int s = 0; s < 150 && !(w.asleep(0) && w.asleep(1)); ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  ASSERT_TRUE(w.asleep(0) && w.asleep(1));
  const std::vector<float> y = w.particles().y;
  for (int s = 0; s < 60; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  EXPECT_TRUE(w.asleep(0) && w.asleep(1));
  EXPECT_EQ(w.particles().y, y);
  const double after = w.pose(1).centre.y();
  std::printf("first asleep at step %d; the box then moved %.3g m\n", first, after - before);
  EXPECT_NEAR(after, before, 0.01 * kRadius);
}

// An awake rigid body meets a sleeping jelly at body level, as a fixed body (a sleeper's particles
// have no inverse mass, so no particle pair joins them to a rigid body): in zero gravity a box
// drifting at 0.05 m/s (slower than the 0.08 m/s that wakes a sleeper at once) comes within the
// body pairs' reach of a jelly asleep since 0.5 s, and the pairs between them are listed while the
// jelly sleeps (bodyPairsNow, which wakes nobody). The box never comes closer than the contact
// distance 2 r (within r / 4): the body-level contact, then the particle pairs once the moving box
// has woken the jelly (it left its still ball beside it). Without the body-level contact the pairs
// are missing, as they were for a fixed jelly until c416137.
TEST(SleepBeside, ASlowBoxMeetsASleepingJellyAtBodyLevel) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("wood", MaterialKind::kRigid), makeKind("jelly", MaterialKind::kSoft)};
  mats[1].elastic.youngs = 5e4;
  std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, 0.5, 0.0), 5, 5, 5, 0, 1), addBox(p, Vec3(0.15, 0.5, 0.0), 4, 4, 4, 1, 0)};
  bodies[1].init.velocity = Vec3(-0.05, 0.0, 0.0);
  PbdParams prm = params(8, 4, Vec3::Zero());
  prm.sleepSpeed = 0.02, prm.sleepTime = 0.5;
  PbdWorld w(p, bodies, mats, prm);
  const auto gap = [&] {
    float jelly = -1e30f, box = 1e30f;
    for (std::int32_t i : w.bodyParticles(0)) jelly = std::max(jelly, w.particles().x[std::size_t(i)]);
    for (std::int32_t i : w.bodyParticles(1)) box = std::min(box, w.particles().x[std::size_t(i)]);
    return double(box) - double(jelly);
  };
  double closest = 1e30;
  long pairsWhileAsleep = 0;
  for (int s = 0; s < 240; ++s) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    closest = std::min(closest, gap());
    if (w.asleep(0) && !w.asleep(1)) pairsWhileAsleep += long(w.bodyPairsNow().pa.size());
  }
  std::printf("closest %.6f m (2 r = %.6f); %ld body-level particle pairs listed while the jelly slept\n", closest,
              2 * kRadius, pairsWhileAsleep);
  EXPECT_GT(pairsWhileAsleep, 0);
  EXPECT_NEAR(closest, 2 * kRadius, 0.25 * kRadius);
}

// Fluid that comes to touch a sleeping jelly wakes it, however slowly it comes (fluid never sleeps,
// and no body sleeps in water it touches): in zero gravity a 5^3 block of water drifting at
// 0.05 m/s reaches a jelly asleep since 0.5 s at about 1.5 s, when the water's own particles have
// calmed below the 0.08 m/s that wakes a sleeper from afar (up to 0.16 m/s at first, as the block
// settles). The jelly is awake at the end and pushed along -x, at the speed the same run without
// sleep gives within 20 % (it wakes at the end of the step the water first touches it, and takes
// that step's push late). Not woken, it stays a fixed wall and the water bounces back off it.
TEST(SleepBeside, SlowFluidReachingASleepingJellyWakesIt) {
  const auto run = [](bool sleep, bool& slept) {
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("water", MaterialKind::kFluid)};
    mats[0].elastic.youngs = 5e4;
    std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, 0.5, 0.0), 5, 5, 5, 0, 0), addBox(p, Vec3(0.14, 0.5, 0.0), 5, 5, 5, 1, 1)};
    bodies[1].init.velocity = Vec3(-0.05, 0.0, 0.0);
    PbdParams prm = params(8, 4, Vec3::Zero());
    if (sleep) prm.sleepSpeed = 0.02, prm.sleepTime = 0.5;
    PbdWorld w(p, bodies, mats, prm);
    slept = false;
    for (int s = 0; s < 210; ++s) {
      EXPECT_TRUE(w.step()) << w.guard().message();
      slept = slept || w.asleep(0);
    }
    EXPECT_FALSE(w.asleep(0));
    return w.velocity(0).x();
  };
  bool sleptA = false, sleptB = false;
  const double with = run(true, sleptA), without = run(false, sleptB);
  std::printf("jelly pushed by slow water: %.4f m/s with sleep, %.4f without\n", with, without);
  EXPECT_TRUE(sleptA) << "the jelly never slept";
  EXPECT_LT(without, -0.005) << "the water should push the jelly";
  EXPECT_NEAR(with, without, 0.2 * std::abs(without));
}

// A rope tied to a jelly (its end touching the jelly at play: a distance constraint across the two
// bodies) sleeps and wakes with it. Both lie on the ground: they fall asleep in the same step (never
// one without the other), and a box sliding (no friction) at 1 m/s into the rope's far end, 30 cm
// from the jelly, wakes the rope, and the jelly with it in the same step, though nothing moving
// comes near the jelly. Woken alone, the rope would hang on a frozen jelly.
TEST(SleepBeside, ARopeTiedToAJellySleepsAndWakesWithIt) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft), makeKind("rope", MaterialKind::kRope, 100.0),
                                makeKind("box", MaterialKind::kRigid)};
  mats[0].elastic.youngs = 5e4;
  mats[2].staticFriction = mats[2].dynamicFriction = 0.0;
  std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, kRadius, 0.0), 6, 6, 6, 0, 0),
                                addChain(p, Vec3(0.06, kRadius, 0.02), Vec3(1, 0, 0), 30, 1),
                                addBox(p, Vec3(1.9, kRadius, 0.0), 4, 4, 4, 2, 2)};
  for (std::size_t b = 0; b < bodies.size(); ++b) bodies[b].stroke = int(b);
  bodies[2].init.velocity = Vec3(-1.0, 0.0, 0.0);
  PbdParams prm = params(8, 4);
  prm.sleepSpeed = 0.02, prm.sleepTime = 0.5;
  PbdWorld w(p, bodies, mats, prm);
  int bothAsleep = -1, wokeTogether = -1;
  for (int s = 0; s < 150; ++s) {
    const bool before = w.asleep(0) && w.asleep(1);
    ASSERT_TRUE(w.step()) << w.guard().message();
    ASSERT_EQ(w.asleep(0), w.asleep(1)) << "step " << s << ": the jelly and its rope apart";
    if (bothAsleep < 0 && w.asleep(0)) bothAsleep = s;
    if (before && !w.asleep(1) && wokeTogether < 0) wokeTogether = s;
  }
  std::printf("rope and jelly asleep at step %d, woken together at step %d\n", bothAsleep, wokeTogether);
  EXPECT_GE(bothAsleep, 0);
  EXPECT_GT(wokeTogether, bothAsleep);
}

// Soft sleeping decides nothing that depends on threads: a jelly at rest in zero gravity falls
// asleep, a jelly thrown at it wakes it at about 0.9 s, and both then move (2 s in all); the states
// are bit-identical for 1 and 2 threads at every step.
TEST(SleepBeside, SameStateForOneAndTwoThreadsWhileAJellySleepsAndWakes) {
  const auto run = [](int threads, bool& slept) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    ParticleArrays p;
    std::vector<Material> mats = {makeKind("jelly", MaterialKind::kSoft)};
    mats[0].elastic.youngs = 5e4;
    // 17^3 = 4,913 particles: more than one of forRange's chunks (kChunk), so the particle passes split.
    std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, 0.5, 0.0), 17, 17, 17, 0, 0), addBox(p, Vec3(1.1, 0.56, 0.06), 4, 4, 4, 1, 0)};
    bodies[1].init.velocity = Vec3(-1.0, 0.0, 0.0);
    PbdParams prm = params(8, 4, Vec3::Zero());
    prm.sleepSpeed = 0.02, prm.sleepTime = 0.5;
    PbdWorld w(p, bodies, mats, prm);
    std::vector<std::uint64_t> hashes;
    slept = false;
    for (int s = 0; s < 120; ++s) {
      EXPECT_TRUE(w.step()) << w.guard().message();
      slept = slept || w.asleep(0);
      hashes.push_back(w.stateHash());
    }
    return hashes;
  };
  bool slept1 = false, slept2 = false;
  const auto one = run(1, slept1), two = run(2, slept2);
  EXPECT_TRUE(slept1 && slept2);
  for (std::size_t s = 0; s < one.size(); ++s) ASSERT_EQ(one[s], two[s]) << "diverged at step " << s;
}

namespace {

// Two bodies in zero gravity, 8 substeps x 4 iterations, 120 steps: body 0, a cube of `side`^3
// particles of material `restingMaterial` (0 wood, 1 jelly of E = 5e4 Pa) at rest at (0, 0.5, 0),
// and body 1, a 4^3 cube of `thrownMaterial` at x0 thrown along -x at `speed`; with `sleep`, the
// sleep speed 0.02 m/s and time 0.5 s. The bodies' centres and velocities at the end, whether
// body 0 slept at some step and whether it is asleep at the end.
struct ThrowEnd {
  Vec3 centre[2], velocity[2];
  bool slept = false, asleepAtEnd = false;
  double momentumDrift = 0.0;  // the largest change of the total momentum at a step's end, over its start value's size
};
ThrowEnd throwAtRestingBody(std::int16_t restingMaterial, int side, std::int16_t thrownMaterial, double x0, double speed,
                            bool sleep) {
  ParticleArrays p;
  std::vector<Material> mats = {makeKind("wood", MaterialKind::kRigid), makeKind("jelly", MaterialKind::kSoft)};
  mats[1].elastic.youngs = 5e4;
  std::vector<BodyRange> bodies{addBox(p, Vec3(0.0, 0.5, 0.0), side, side, side, 0, restingMaterial),
                                addBox(p, Vec3(x0, 0.5, 0.0), 4, 4, 4, 1, thrownMaterial)};
  bodies[1].init.velocity = Vec3(-speed, 0.0, 0.0);
  PbdParams prm = params(8, 4, Vec3::Zero());
  if (sleep) prm.sleepSpeed = 0.02, prm.sleepTime = 0.5;
  PbdWorld w(p, bodies, mats, prm);
  ThrowEnd end;
  const Vec3 p0 = momentum(w);
  for (int s = 0; s < 120; ++s) {
    EXPECT_TRUE(w.step()) << w.guard().message();
    end.slept = end.slept || w.asleep(0);
    end.momentumDrift = std::max(end.momentumDrift, (momentum(w) - p0).norm() / p0.norm());
  }
  end.asleepAtEnd = w.asleep(0);
  for (int b = 0; b < 2; ++b) end.centre[b] = w.pose(b).centre, end.velocity[b] = w.velocity(b);
  return end;
}

}  // namespace

// Something moving that reaches a sleeping jelly wakes it before the contact, so that it takes the
// blow as a jelly: in zero gravity a jelly at rest sleeps after 0.5 s, and a box (rigid) or a second
// jelly thrown at it at 6 m/s hits it at about 1 s: 6 cm apart at the end of one step, touching
// within the next (10 cm a step: a step passes the contact searches' margins, so a wake at the end
// of the step whose contacts first found the other would come too late). Both then move as in the same run without
// sleep, where the jelly at rest never moved: the jelly wakes at the start of a step in which the
// thrown body may reach it (two steps before the blow here), as it lay. Before the blow the runs
// differ by float round-off only (the unslept jelly's particles drift by 3e-9 m: its cluster
// corrections and rotations' warm start keep running). A box's blow amplifies that to 4e-7 m, so
// its bounds are 5e-4 m and 5e-4 m/s. Two jellies meeting at 6 m/s (1.25 spacings a substep)
// are chaotic: moving the thrown jelly 1e-7 m sideways in the run without sleep moves where it
// ends by 2 cm (6 mm before the clusters ran ahead of the contacts), so their bounds are 0.1 m
// and 0.1 m/s (measured 0.035 m and 0.035 m/s), and the momentum of the two is checked too. Not
// woken, the sleeping jelly is a fixed wall: the thrown body bounces back off it (1.4 m/s the
// other way; 1.5-2.5 m apart at 2 s; the momentum changes by 1.0-1.2 of itself).
TEST(SleepBeside, ABodyThrownAtASleepingJellyWakesItAndBothMoveAsWithoutSleep) {
  for (const bool rigidThrown : {true, false}) {
    const ThrowEnd with = throwAtRestingBody(1, 5, rigidThrown ? 0 : 1, 6.0, 6.0, true);
    const ThrowEnd without = throwAtRestingBody(1, 5, rigidThrown ? 0 : 1, 6.0, 6.0, false);
    SCOPED_TRACE(rigidThrown ? "a box thrown" : "a jelly thrown");
    EXPECT_TRUE(with.slept) << "the jelly never slept";
    EXPECT_FALSE(with.asleepAtEnd);
    EXPECT_FALSE(without.slept);
    const Vec3 dc = with.centre[1] - without.centre[1], dv = with.velocity[1] - without.velocity[1];
    std::printf("%s: after the blow %.6f m/s with sleep, %.6f without; centres %.3g m apart\n",
                rigidThrown ? "box" : "jelly", with.velocity[1].x(), without.velocity[1].x(), dc.norm());
    EXPECT_GT(without.velocity[1].x(), -5.4) << "the jelly should slow the thrown body";
    const double bound = rigidThrown ? 5e-4 : 0.1;
    EXPECT_NEAR(dc.norm(), 0.0, bound);
    EXPECT_NEAR(dv.norm(), 0.0, bound);
    // Chaos or not, a jelly woken in time is no wall: the momentum of the two stays what the
    // throw gave them (1e-3 of it; the float round-off of Soft.ZeroGravityCollisionConservesMomentum).
    std::printf("%s: momentum changed by at most %.3g of it with sleep\n", rigidThrown ? "box" : "jelly", with.momentumDrift);
    EXPECT_LT(with.momentumDrift, 1e-3);
  }
}

// A jelly thrown in zero gravity at a box asleep (alone and still for 0.5 s) wakes it on contact,
// and both then move as in the same run without sleep: the box had no motion to lose, and it wakes
// in the substep the contact is found, before it is solved, so the runs agree to round-off (1e-9
// m). With the sleeper not woken the box stays put and the jelly bounces off a wall.
TEST(SleepBeside, AJellyThrownAtASleepingBoxWakesItAndBothMoveAsWithoutSleep) {
  // The gap of 0.76 m closes after 0.76 s; at 1 m/s the jelly crosses the pairs' search margin
  // (half a spacing) within the step that finds the pair, so the box is pushed in the step it wakes.
  const ThrowEnd with = throwAtRestingBody(0, 4, 1, 0.8, 1.0, true);
  const ThrowEnd without = throwAtRestingBody(0, 4, 1, 0.8, 1.0, false);
  const Vec3 withSleep = with.centre[0], without0 = without.centre[0];
  const Vec3 vWith = with.velocity[0], vWithout = without.velocity[0];
  EXPECT_TRUE(with.slept) << "the box never slept";
  EXPECT_FALSE(without.slept);
  std::printf("box after the blow: %.6f m/s with sleep, %.6f without\n", vWith.x(), vWithout.x());
  EXPECT_LT(vWithout.x(), -0.01) << "the jelly should push the box";
  EXPECT_NEAR((withSleep - without0).norm(), 0.0, 1e-9);
  EXPECT_NEAR((vWith - vWithout).norm(), 0.0, 1e-9);
}
