// The MPM world against closed forms and conservation laws: free fall, P2G/G2P mass and
// momentum, a block resting on the ground, a dam break, and bitwise determinism.
#include <gtest/gtest.h>

#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <memory>
#include <string>
#include <random>

#include <Eigen/SVD>

#include "core/error.h"
#include "mpm/kernels.h"
#include "mpm_test_util.h"

using namespace physketch;
using namespace physketch::mpm;
using physketch::mpm::test::addBox;
using physketch::mpm::test::unitDomain;

namespace {

Material elastic(double E, ElasticModel model = ElasticModel::kCorotated) {
  Material m = makeMaterial(MaterialKind::kElastic, "jelly");
  m.elastic.youngs = E;
  m.elastic.model = model;
  return m;
}

double comY(const MpmWorld& w, int body) { return w.pose(body).centre.y(); }

// The height of a body's lowest particle (m).
float lowestOf(const MpmWorld& w, int body) {
  float lowest = std::numeric_limits<float>::infinity();
  for (std::int32_t i : w.bodyParticles(body)) lowest = std::min(lowest, w.particles().y[std::size_t(i)]);
  return lowest;
}

// Steps w until its time reaches t; false, with a failure naming the guard's diagnosis, where a
// step is refused.
bool runUntil(MpmWorld& w, double t) {
  while (w.time() < t)
    if (!w.step()) {
      ADD_FAILURE() << w.guard().message();
      return false;
    }
  return true;
}

}  // namespace

// Quadratic B-splines: partition of unity, zero first moment (so sum of gradients is 0 and
// P2G's affine term carries no net momentum), and second moment 1/4 per axis: D_p = dx^2/4,
// the 4/dx^2 of MLS-MPM's affine matrix (Jiang et al. 2016 §10.1). Over every offset f in
// [0.5, 1.5) on a fine sweep; float rounding tolerance 1e-6.
TEST(MpmKernels, BSplineWeightsSumToOneWithZeroFirstMomentAndQuarterSecondMoment) {
  for (int k = 0; k <= 1000; ++k) {
    const float f = 0.5f + 0.999f * float(k) / 1000.0f;
    float w[3];
    detail::bsplineWeights(f, w);
    double s0 = 0, s1 = 0, s2 = 0;
    for (int i = 0; i < 3; ++i) {
      EXPECT_GE(w[i], 0.0f);
      s0 += w[i];
      s1 += w[i] * (i - double(f));
      s2 += w[i] * (i - double(f)) * (i - double(f));
    }
    EXPECT_NEAR(s0, 1.0, 1e-6) << f;
    EXPECT_NEAR(s1, 0.0, 1e-6) << f;
    EXPECT_NEAR(s2, 0.25, 1e-6) << f;
  }
  // The stencil never leaves a grid of n nodes, wherever the particle is (even outside).
  for (float x : {-5.0f, -0.01f, 0.0f, 0.7f, 63.2f, 64.0f, 1e6f}) {
    const int b = detail::stencilBase(x, 1.0f, 64);
    EXPECT_GE(b, 0);
    EXPECT_LE(b + 2, 63);
  }
}

// With no stress (F = I) and a uniform velocity, P2G/G2P pass v through unchanged (weights
// sum to 1, sum w (x_i - x_p) = 0), so each particle follows symplectic Euler exactly:
// v_k = -g h k, y_n = y_0 - g h^2 n (n + 1) / 2. Tolerance 2e-5 m: float32 positions near
// 0.7 m resolve 6e-8 m, and 500 substeps of rounding in x += h v accumulate to at most 3e-5 m
// (half an ulp each), typically sqrt(500) * 3e-8 ~ 1e-6 m.
TEST(MpmWorld, FreeFallMatchesTheDiscreteSolution) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.45, 0.7, 0.45), 6, 6, 6, h, 0);
  // 50 substeps: h = 3.3e-4 s, within the explicit bound 0.5 dx / c_p = 3.8e-4 s of E = 5e5.
  MpmParams q = unitDomain(h, 50);
  MpmWorld w(p, bodies, {elastic(5e5)}, q);
  ASSERT_TRUE(w.warnings().empty());
  const std::vector<float> y0 = w.particles().y;
  const int steps = 10;
  for (int s = 0; s < steps; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const double hs = q.dt / q.substeps, n = steps * q.substeps, g = 9.81;
  const double drop = g * hs * hs * n * (n + 1.0) / 2.0;  // 0.137 m: still far above the ground
  double worst = 0.0;
  for (std::size_t i = 0; i < y0.size(); ++i) worst = std::max(worst, std::abs(w.particles().y[i] - (y0[i] - drop)));
  EXPECT_LT(worst, 2e-5) << "drop " << drop;
  EXPECT_NEAR(w.particles().vy[0], -g * hs * n, 1e-4);
}

// P2G then G2P in zero gravity, away from the walls: the grid holds the particles' mass and
// momentum, and G2P hands the same momentum back (APIC conserves it; the stress term's
// moments vanish as sum_i w_ip (x_i - x_p) = 0 for quadratic B-splines). Closed form: mass
// and momentum are conserved, also while two blocks of different size collide and deform.
// Tolerance 1e-5 relative per step: float32 sums of ~1e4 terms (eps 6e-8 each, of one sign).
TEST(MpmWorld, TransfersConserveMassAndMomentum) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  BodyInit right, left;
  right.velocity = Vec3(1.0, 0.2, 0.0);
  right.spin = Vec3(0.0, 0.0, 4.0);
  left.velocity = Vec3(-1.0, 0.0, 0.3);
  addBox(p, bodies, Vec3(0.30, 0.40, 0.40), 16, 16, 16, h, 0, right);
  addBox(p, bodies, Vec3(0.48, 0.42, 0.42), 10, 10, 10, h, 0, left);
  MpmParams q = unitDomain(h, 0, 1.0 / 240.0);
  q.gravity = Vec3::Zero();
  MpmWorld w(p, bodies, {elastic(1e5)}, q);
  const ParticleArrays& a = w.particles();
  const auto momentum = [&] {
    Vec3 m = Vec3::Zero();
    for (std::size_t i = 0; i < a.size(); ++i) m += double(a.mass[i]) * Vec3(a.vx[i], a.vy[i], a.vz[i]);
    return m;
  };
  double mass = 0.0;
  for (float m : a.mass) mass += m;
  const Vec3 mom = momentum();
  const double scale = mass * 1.0;  // kg * (m/s): speeds are O(1)
  for (int s = 0; s < 12; ++s) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    EXPECT_NEAR(w.gridMass(), mass, 1e-6 * mass);
    EXPECT_LT((w.gridMomentum() - mom).norm(), 1e-5 * scale * (s + 1)) << w.gridMomentum().transpose() << " vs " << mom.transpose();
    EXPECT_LT((momentum() - mom).norm(), 1e-5 * scale * (s + 1)) << momentum().transpose() << " vs " << mom.transpose();
  }
  // They did collide: the stress term was at work (the small block turned back).
  EXPECT_GT(w.velocity(1).x(), -0.9);
  EXPECT_EQ(w.atDomainEdge(), 0);
}

namespace {

// A column of nx x ny x nz particles (h = 1 cm) of elastic(E) set on the ground, run for 10 s
// under `substeps auto`. Returns how far its top layer sank (m), averaged over the last second
// and over the second before, and checks on the way that it does not drift sideways or ring
// up, and that nothing inverts (the guard would stop the run on a NaN or J <= 0).
struct Settled {
  double sinkLast = 0.0, sinkBefore = 0.0, drift = 0.0;
  double speedSecond = 0.0, speedLast = 0.0;  // largest body speed in 1-2 s and in 9-10 s
};
Settled settleColumn(int nx, int ny, int nz, double E) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.45, 0.5 * h, 0.45), nx, ny, nz, h, 0);
  MpmWorld w(p, bodies, {elastic(E)}, unitDomain(h, 0));
  std::vector<std::int32_t> top;
  for (std::int32_t i : w.bodyParticles(0))
    if (p.y[std::size_t(i)] > (double(ny) - 1.0) * h) top.push_back(i);
  const auto topY = [&] {
    double s = 0.0;
    for (std::int32_t i : top) s += w.particles().y[std::size_t(i)];
    return s / double(top.size());
  };
  const double y0 = topY(), x0 = w.pose(0).centre.x();
  Settled out;
  for (int s = 0; s < 600; ++s) {
    if (!w.step()) {
      ADD_FAILURE() << w.guard().message();
      return out;
    }
    if (s >= 480) (s < 540 ? out.sinkBefore : out.sinkLast) += (y0 - topY()) / 60.0;
    if (s >= 60 && s < 120) out.speedSecond = std::max(out.speedSecond, w.velocity(0).norm());
    if (s >= 540) out.speedLast = std::max(out.speedLast, w.velocity(0).norm());
    out.drift = std::max(out.drift, std::abs(w.pose(0).centre.x() - x0));
  }
  for (std::size_t i = 0; i < w.particles().size(); ++i) EXPECT_GT(w.deformation(std::int32_t(i)).determinant(), 0.0f);
  return out;
}

}  // namespace

// An elastic block (the soft preset, E = 5e4 Pa, no damping) set on the ground settles by its
// self-weight compression and then stays put for 10 s. Under uniaxial stress with free sides
// the strain at height y is rho g (H - y) / E, so its top sinks by rho g H^2 / (2 E) = 0.98 mm
// here (the top layer's centres, 0.95 H up, by 2 z/H - (z/H)^2 = 0.9975 of that). Averaged over
// the last second the sink must be within 15 % of it (issue 9's tolerance; measured +0.7 %); no
// drift between the last two seconds (< 0.01 h, measured 1.2e-7 m), none sideways (< 0.01 h,
// measured 4e-6 m), and no ringing up (the body's speed in the last second no more than in the
// second).
TEST(MpmWorld, AnElasticBlockOnTheGroundSettlesBySelfWeightAndStaysPutFor10s) {
  const double h = 0.01, H = 0.1, E = 5e4, rho = 1000.0;
  const Settled s = settleColumn(10, 10, 10, E);
  const double sink = 0.9975 * rho * 9.81 * H * H / (2.0 * E);
  std::printf("block: top sank %.4e m (%.4f of rho g H^2 / 2E), last two seconds apart %.2e m, drift %.2e m\n",
              s.sinkLast, s.sinkLast / sink, std::abs(s.sinkLast - s.sinkBefore), s.drift);
  EXPECT_NEAR(s.sinkLast, sink, 0.15 * sink);
  EXPECT_LT(std::abs(s.sinkLast - s.sinkBefore), 0.01 * h);
  EXPECT_LT(s.drift, 0.01 * h);
  EXPECT_LE(s.speedLast, s.speedSecond);
}

// An elastic column (6 x 20 x 6 particles, H = 0.2 m) under its own weight compresses by
// rho g H^2 / (2 E) whatever E is: the sink times E is the same for E = 5e4 and 2e5 Pa, and
// each sink is within 5 % of the closed form after 10 s (measured -0.4 % and +2.0 %, their
// products 2.4 % apart; a grid cell is 2 cm, ten times the stiffer column's 1 mm sink).
TEST(MpmWorld, AnElasticColumnCompressesUnderItsOwnWeightAsOneOverE) {
  const double H = 0.2, rho = 1000.0;
  double scaled[2] = {0.0, 0.0};
  int k = 0;
  for (const double E : {5e4, 2e5}) {
    const Settled s = settleColumn(6, 20, 6, E);
    const double sink = (1.0 - 0.025 * 0.025) * rho * 9.81 * H * H / (2.0 * E);  // top layer 0.975 H up: 2 z/H - (z/H)^2
    std::printf("column E %.0e: top sank %.4e m (%.4f of rho g H^2 / 2E)\n", E, s.sinkLast, s.sinkLast / sink);
    EXPECT_NEAR(s.sinkLast, sink, 0.05 * sink) << "E " << E;
    scaled[k++] = s.sinkLast * E;
  }
  EXPECT_NEAR(scaled[1], scaled[0], 0.05 * scaled[0]);
}

// A water column of width a and height 2a against the x = 0 wall, spanning the domain in z
// between slip walls (a 2-D dam break), spreads: its front at T = t sqrt(2 g / a) = 2.5 must
// be within 30 % of Martin & Moyce 1952's Z = 3.0 (../shared/data/martin-moyce-1952-front.csv).
// A loose gate for the first increment: the grid has only 5 cells across a.
TEST(MpmWorld, AWaterColumnSpreadsLikeMartinAndMoyce) {
  const double h = 0.01, a = 0.1;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  MpmParams q = unitDomain(h, 0, 1.0 / 600.0);
  q.domainSize = 0.5;
  for (WallKind& k : q.walls) k = WallKind::kSlip;
  addBox(p, bodies, Vec3(0.5 * h, 0.5 * h, 0.5 * h), int(a / h), int(2 * a / h), int(q.domainSize / h), h, 0);
  Material water = makeMaterial(MaterialKind::kFluid, "water");
  water.fluid.bulkModulus = 2e5;  // c = 14 m/s, 5x the front speed 2 sqrt(g a): weakly compressible
  MpmWorld w(p, bodies, {water}, q);
  const double tEnd = 2.5 / std::sqrt(2.0 * 9.81 / a);
  while (w.time() < tEnd) ASSERT_TRUE(w.step()) << w.guard().message();
  float front = 0.0f;
  for (float x : w.particles().x) front = std::max(front, x);
  const double Z = (front + 0.5 * h) / a;
  EXPECT_NEAR(Z, 3.0, 0.9) << "front at " << front << " m";
}

// A pool at rest: its pressure (the Tait equation of state at each particle's J, the state the
// study's expect hydrostatic reads) is hydrostatic, p = rho0 g d at depth d below the surface
// (the closed form; compressibility adds (rho0 g d)^2 / (2 K), 0.1 % of the head at the bottom
// here). Released unstressed, the pool first rings (bottom head 0.017-0.067 m in the first
// 0.3 s against 0.04) and has settled by 1.5 s (vertical speed RMS 1e-4 m/s). Tolerance: RMS
// over particles 10 % of the depth; measured 7 % with J-bar. Before it, 16 %: two layers share a
// grid cell (dx = 2 h) and particles at different places in the cell held different J (the
// layer on the sticky floor kept J = 1 and the one above took its load). A pool without
// gravity, or a pressure of the wrong sign, is off by 100 %; the bouncing pool at 1 s with
// K = 2e4 was off by 28 %.
TEST(MpmWorld, ARestingPoolsPressureIsHydrostatic) {
  const double h = 0.005;
  const int layers = 8;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  MpmParams q = unitDomain(h, 0);
  q.domainSize = 0.1;
  for (WallKind& k : q.walls) k = WallKind::kSlip;
  q.walls[2] = WallKind::kSticky;  // the floor
  addBox(p, bodies, Vec3(0.5 * h, 0.5 * h, 0.5 * h), 20, layers, 20, h, 0);
  Material water = makeMaterial(MaterialKind::kFluid, "water");
  water.fluid.bulkModulus = 2e5;
  MpmWorld w(p, bodies, {water}, q);
  while (w.time() < 1.5) ASSERT_TRUE(w.step()) << w.guard().message();
  const ParticleArrays& r = w.particles();
  float top = 0.0f;
  for (float y : r.y) top = std::max(top, y);
  const double surface = top + 0.5 * h, depth = layers * h, rho0 = water.density, g = 9.81;
  double sum = 0.0;
  for (std::size_t i = 0; i < r.size(); ++i) {
    const double head = w.pressure(std::int32_t(i)) / (rho0 * g), d = surface - r.y[i];
    sum += (head - d) * (head - d);
  }
  const double rms = std::sqrt(sum / double(r.size()));
  std::printf("resting pool: pressure head RMS error %.4g m (depth %.3g m)\n", rms, depth);
  EXPECT_LT(rms, 0.1 * depth);
}

// The same mixed scene (elastic, sand, snow, plasticine, fluid) with 1 and 2 threads: the
// same state hash after every step (P2G has no atomics; work units are fixed).
TEST(MpmWorld, OneAndTwoThreadsGiveBitIdenticalStates) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  std::vector<Material> mats = {elastic(5e4), makeMaterial(MaterialKind::kSand, "grit"),
                                makeMaterial(MaterialKind::kSnow, "snow"), makeMaterial(MaterialKind::kPlasticine, "clay"),
                                makeMaterial(MaterialKind::kFluid, "water"), elastic(5e4, ElasticModel::kNeoHookean)};
  for (auto& m : mats) m.elastic.youngs = 5e4;
  BodyInit spin;
  spin.velocity = Vec3(0.5, -1.0, 0.2);
  spin.spin = Vec3(0, 3, 0);
  for (int k = 0; k < 6; ++k)
    addBox(p, bodies, Vec3(0.1 + 0.14 * k, 0.05 + 0.05 * (k % 2), 0.3), 11, 11, 11, h, std::int16_t(k), k == 0 ? spin : BodyInit{});
  const auto run = [&](int threads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    MpmWorld w(p, bodies, mats, unitDomain(h, 0));
    std::vector<std::uint64_t> hashes;
    for (int s = 0; s < 12; ++s) {
      EXPECT_TRUE(w.step()) << w.guard().message();
      hashes.push_back(w.stateHash());
    }
    return hashes;
  };
  EXPECT_EQ(run(1), run(2));
}

// P2G's and G2P's node loops in AVX2 and in SSE (MpmWorld::setAvx2): the same mixed scene,
// with per-material friction, J-bar and (a fixed slab being a collider) the sums of
// m (x_p - x_node) scattered beside the momentum, gives the same state hash after every step
// (each lane does the same IEEE operations in both).
TEST(MpmWorld, Avx2AndSseTransfersGiveBitIdenticalStates) {
  if (!MpmWorld::avx2Supported()) GTEST_SKIP() << "no AVX2";
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  std::vector<Material> mats = {elastic(5e4), makeMaterial(MaterialKind::kSand, "grit"),
                                makeMaterial(MaterialKind::kFluid, "water")};
  for (auto& m : mats) m.elastic.youngs = 5e4;
  mats[1].staticFriction = 0.9;  // materials that differ in friction: scattered per node
  BodyInit spin;
  spin.velocity = Vec3(0.5, -1.0, 0.2);
  spin.spin = Vec3(0, 3, 0);
  for (int k = 0; k < 3; ++k)
    addBox(p, bodies, Vec3(0.1 + 0.2 * k, 0.05 + 0.05 * (k % 2), 0.3), 11, 11, 11, h, std::int16_t(k), k == 0 ? spin : BodyInit{});
  // A fixed slab with water falling on it: a collider, so P2G also scatters the nodes' sums of
  // m (x_p - x_node) for every particle.
  BodyInit fixed;
  fixed.fixed = true;
  addBox(p, bodies, Vec3(0.7, 0.15, 0.3), 20, 2, 11, h, 0, fixed);
  addBox(p, bodies, Vec3(0.72, 0.2, 0.32), 8, 8, 8, h, 2);
  const auto run = [&](bool avx2) {
    MpmWorld w(p, bodies, mats, unitDomain(h, 0));
    w.setAvx2(avx2);
    std::vector<std::uint64_t> hashes;
    for (int s = 0; s < 12; ++s) {
      EXPECT_TRUE(w.step()) << w.guard().message();
      hashes.push_back(w.stateHash());
    }
    return hashes;
  };
  EXPECT_EQ(run(true), run(false));
}

// P2G computes a fluid's Kirchhoff stress in its own loop, not through kirchhoff(), and skips the
// viscous term's zeros for an inviscid fluid. Oracle: the kirchhoff() path (fluidKirchhoff, as
// every other material's stress), which must give the same bits: inviscid water (mu = 0), water
// (1e-3 Pa s) and a viscous fluid (50 Pa s), each a block thrown spinning at the floor and one
// dropped on it, 12 steps, state hashes after every step. A flipped sign of the inline pressure
// changes them (the viscous term itself: AViscousFluidResistsShearButNotRotation).
TEST(MpmWorld, TheInlineFluidStressGivesTheSameBitsAsKirchhoff) {
  const double h = 0.01;
  for (const double mu : {0.0, 1e-3, 50.0}) {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    Material fluid = makeMaterial(MaterialKind::kFluid, "fluid");
    fluid.fluid.viscosity = mu;
    BodyInit spin;
    spin.velocity = Vec3(0.5, -1.0, 0.2);
    spin.spin = Vec3(1, 3, 0);
    addBox(p, bodies, Vec3(0.1, 0.1, 0.3), 10, 10, 10, h, 0, spin);
    addBox(p, bodies, Vec3(0.5, 0.05, 0.3), 10, 10, 10, h, 0);
    const auto run = [&](bool inlined) {
      MpmWorld w(p, bodies, {fluid}, unitDomain(h, 0));
      w.setFluidStressInline(inlined);
      std::vector<std::uint64_t> hashes;
      for (int s = 0; s < 12; ++s) {
        EXPECT_TRUE(w.step()) << w.guard().message();
        hashes.push_back(w.stateHash());
      }
      return hashes;
    };
    EXPECT_EQ(run(true), run(false)) << "viscosity " << mu;
  }
}

// A fluid's viscous stress is mu (C + C^T): it resists shear, not rotation. A block of a very
// viscous fluid (50 Pa s, nu = 0.05 m^2/s, so a shear across its 8 cm decays in about 0.1 s)
// spinning at 4 rad/s in zero gravity keeps its angular momentum about its centre, the particles'
// sum of m (x - c) x v (a symmetric stress exerts no torque; within 2 % over 0.5 s, measured
// +0.6 %; its spin rate falls to 3.87 rad/s as the block rounds off and its inertia grows), while two such blocks
// sliding past each other at +-0.5 m/s, touching along a face, are dragged towards their common
// velocity 0: each below 40 % of its speed after 0.3 s (measured 28 %), where the same blocks of
// an inviscid fluid keep over 60 % (measured 70 %; they lose the rest to the grid's own shear
// resistance and to rounding off). A viscous term of the wrong sign, or none, fails the sliding
// blocks.
TEST(MpmWorld, AViscousFluidResistsShearButNotRotation) {
  const double h = 0.01;
  Material honey = makeMaterial(MaterialKind::kFluid, "honey");
  honey.fluid.viscosity = 50.0;
  MpmParams q = unitDomain(h, 0);
  q.gravity = Vec3::Zero();
  {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit spin;
    spin.spin = Vec3(0.0, 0.0, 4.0);
    addBox(p, bodies, Vec3(0.46, 0.46, 0.46), 8, 8, 8, h, 0, spin);
    MpmWorld w(p, bodies, {honey}, q);
    const auto angular = [&] {  // L_z about the centre of mass, and the moment of inertia about z
      const ParticleArrays& s = w.particles();
      double m = 0, cx = 0, cy = 0;
      for (std::size_t i = 0; i < s.size(); ++i) m += s.mass[i], cx += s.mass[i] * s.x[i], cy += s.mass[i] * s.y[i];
      cx /= m, cy /= m;
      double L = 0, I = 0;
      for (std::size_t i = 0; i < s.size(); ++i) {
        const double dx = s.x[i] - cx, dy = s.y[i] - cy;
        L += s.mass[i] * (dx * s.vy[i] - dy * s.vx[i]);
        I += s.mass[i] * (dx * dx + dy * dy);
      }
      return std::pair{L, L / I};
    };
    const auto [L0, w0] = angular();
    for (int s = 0; s < 30; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    const auto [L1, w1] = angular();
    std::printf("spinning honey: L %.6g -> %.6g, spin %.3f -> %.3f rad/s\n", L0, L1, w0, w1);
    EXPECT_NEAR(L1 / L0, 1.0, 0.02);
  }
  for (const double mu : {50.0, 0.0}) {
    honey.fluid.viscosity = mu;
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit right, left;
    right.velocity = Vec3(0.5, 0.0, 0.0), left.velocity = Vec3(-0.5, 0.0, 0.0);
    addBox(p, bodies, Vec3(0.4, 0.5, 0.46), 12, 6, 8, h, 0, right);
    addBox(p, bodies, Vec3(0.46, 0.5 - 6 * h, 0.46), 12, 6, 8, h, 0, left);
    MpmWorld w(p, bodies, {honey}, q);
    for (int s = 0; s < 18; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    const double upper = w.velocity(0).x(), lower = w.velocity(1).x();
    std::printf("sliding blocks, mu %.0f: %.3f / %.3f m/s after 0.3 s\n", mu, upper, lower);
    if (mu > 0.0) {
      EXPECT_LT(std::abs(upper), 0.4 * 0.5);
      EXPECT_LT(std::abs(lower), 0.4 * 0.5);
    } else {
      EXPECT_GT(upper, 0.6 * 0.5);
      EXPECT_LT(lower, -0.6 * 0.5);
    }
  }
}

// P2G's stress for sand, plasticine and snow from the return map's SVD of the substep before,
// and for fixed-corotated jelly from the rotation of the substep before by Newton's method
// (MpmWorld::setSvdCache), against an SVD of P2G's own: the same motion within round-off, 10
// steps of four boxes thrown at the floor (positions within 1e-4 m, 1 % of the spacing; a
// wrong U, s or R in the cache moves them by centimetres), and not the same bits (so the
// caches were used).
namespace {
// Sand, snow and plasticine (and, with `elastic`, a jelly) at E = 5e4 Pa, one 10 x 8 x 10 box
// of each thrown spinning at the floor from height y (the cache tests below).
std::vector<Material> throwPlasticBoxes(ParticleArrays& p, std::vector<BodyRange>& bodies, double h, double y,
                                        bool withElastic) {
  std::vector<Material> mats = {makeMaterial(MaterialKind::kSand, "grit"), makeMaterial(MaterialKind::kSnow, "snow"),
                                makeMaterial(MaterialKind::kPlasticine, "clay")};
  if (withElastic) mats.push_back(elastic(5e4));
  for (auto& m : mats) m.elastic.youngs = 5e4;
  BodyInit thrown;
  thrown.velocity = Vec3(0.5, -2.0, 0.2);
  thrown.spin = Vec3(0, 3, 1);
  for (std::size_t k = 0; k < mats.size(); ++k)
    addBox(p, bodies, Vec3(0.1 + 0.22 * double(k), y, 0.3), 10, 8, 10, h, std::int16_t(k), thrown);
  return mats;
}
}  // namespace

TEST(MpmWorld, StressFromTheSubstepBeforesDecompositionsMatchesItsOwnSvd) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  const std::vector<Material> mats = throwPlasticBoxes(p, bodies, h, 0.04, true);
  const auto run = [&](bool cache) {
    MpmWorld w(p, bodies, mats, unitDomain(h, 0));
    w.setSvdCache(cache);
    for (int s = 0; s < 10; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    return w.particles();
  };
  const ParticleArrays a = run(true), b = run(false);
  double worst = 0.0, moved = 0.0;
  bool identical = true;
  for (std::size_t i = 0; i < a.size(); ++i) {
    worst = std::max({worst, double(std::abs(a.x[i] - b.x[i])), double(std::abs(a.y[i] - b.y[i])),
                      double(std::abs(a.z[i] - b.z[i]))});
    moved = std::max(moved, double(std::abs(a.y[i] - p.y[i])));
    identical = identical && a.x[i] == b.x[i] && a.y[i] == b.y[i] && a.z[i] == b.z[i];
  }
  std::printf("cached vs own SVD: largest position difference %.3g m (largest fall %.3g m)\n", worst, moved);
  EXPECT_GT(moved, 0.02);  // the boxes hit the floor and deform
  EXPECT_LT(worst, 1e-4);
  EXPECT_FALSE(identical);
}

// With one substep a step, every P2G is a step's first, whose plastic stresses come from
// decomposePlastic (the return maps' batched SVDs, svd3Many) with the cache on and from an SVD
// of their own (svd3, one at a time) with it off: the same bits, so the runs must be identical.
// Sand, snow and plasticine (the elastic material's cached rotation is another matter:
// left out) thrown at the floor, 10 steps of 1/2400 s.
TEST(MpmWorld, AStepsFirstDecompositionsAreTheBitsOfItsOwnSvd) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  const std::vector<Material> mats = throwPlasticBoxes(p, bodies, h, 0.012, false);
  const auto run = [&](bool cache) {
    MpmWorld w(p, bodies, mats, unitDomain(h, 1, 1.0 / 2400.0));
    w.setSvdCache(cache);
    for (int s = 0; s < 10; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    return w.stateHash();
  };
  EXPECT_EQ(run(true), run(false));
}

// The return maps leave every sand and plasticine particle on or inside its yield surface, by
// the criteria themselves (Klar et al. 2016's cone, Mises' cylinder in Hencky strain) taken from
// each particle's F through Eigen's SVD in double; and the load is enough that many sit on the
// surface (the maps did act). Four boxes thrown at the floor, 12 steps. Tolerance 2e-5 in strain:
// F is stored in float (1.2e-7 relative per entry), so its recomputed strains are a few 1e-7
// off; a return map skipped or undone leaves strains 1e-2 past the surface.
TEST(MpmWorld, ReturnMapsLeaveEveryParticleOnOrInsideItsYieldSurface) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  std::vector<Material> mats = throwPlasticBoxes(p, bodies, h, 0.04, false);
  mats[2].plasticine.yieldStress = 1e3;  // a bound of 0.026 in deviatoric strain: the impact passes it
  MpmWorld w(p, bodies, mats, unitDomain(h, 0));
  const double E = 5e4, nu = mats[0].elastic.poisson;
  const double mu = E / (2.0 * (1.0 + nu)), lambda = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
  const double sinPhi = std::sin(mats[0].sand.frictionAngleDeg * 3.14159265358979323846 / 180.0);
  const double alpha = std::sqrt(2.0 / 3.0) * 2.0 * sinPhi / (3.0 - sinPhi);
  const double misesBound = mats[2].plasticine.yieldStress / (2.0 * mu);
  constexpr double kTol = 2e-5;
  std::size_t onCone = 0, onCylinder = 0;
  for (int step = 0; step < 12; ++step) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    for (std::int32_t i = 0; i < std::int32_t(w.particles().size()); ++i) {
      const int m = w.particles().material[std::size_t(i)];
      if (m == 1) continue;  // snow: its clamp has its own test (test_constitutive.cpp)
      const Eigen::Matrix3d F = w.deformation(i).cast<double>();
      const Eigen::Vector3d sigma = Eigen::JacobiSVD<Eigen::Matrix3d>(F).singularValues();
      const Eigen::Vector3d eps = sigma.array().log().matrix();
      const Eigen::Vector3d dev = eps - Eigen::Vector3d::Constant(eps.sum() / 3.0);
      if (m == 0) {  // sand, no cohesion: inside the cone, never pulled apart
        const double dgamma = dev.norm() + (3.0 * lambda + 2.0 * mu) / (2.0 * mu) * eps.sum() * alpha;
        ASSERT_LE(dgamma, kTol) << "sand particle " << i << " outside the cone in step " << step;
        ASSERT_LE(eps.sum(), kTol) << "sand particle " << i << " in tension in step " << step;
        if (dgamma > -1e-4 && dev.norm() > 1e-3) ++onCone;
      } else {
        ASSERT_LE(dev.norm(), misesBound + kTol) << "clay particle " << i << " outside Mises' cylinder, step " << step;
        if (dev.norm() > misesBound - 1e-4) ++onCylinder;
      }
    }
  }
  std::printf("particle-steps on the cone %zu, on the cylinder %zu\n", onCone, onCylinder);
  EXPECT_GT(onCone, 1000u);
  EXPECT_GT(onCylinder, 1000u);
}

namespace {

// A 10 x 8 x 10 sand box (h = 1 cm, E = 5e4 Pa) thrown at the floor, as the return-map tests
// throw theirs, and the Drucker-Prager cone it is judged by: Klár et al. 2016's alpha of an
// angle and delta-gamma of a Hencky strain (<= 0: on or inside the cone).
struct ThrownSand {
  MpmWorld world;
  double mu, lambda;
  explicit ThrownSand(const Material& grit) : world(make(grit)) {
    const double E = grit.elastic.youngs, nu = grit.elastic.poisson;
    mu = E / (2.0 * (1.0 + nu)), lambda = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
  }
  static MpmWorld make(const Material& grit) {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit thrown;
    thrown.velocity = Vec3(0.5, -2.0, 0.2);
    addBox(p, bodies, Vec3(0.3, 0.04, 0.3), 10, 8, 10, 0.01, 0, thrown);
    return MpmWorld(p, bodies, {grit}, unitDomain(0.01, 0));
  }
  static double alphaOf(double deg) {
    const double sinPhi = std::sin(deg * 3.14159265358979323846 / 180.0);
    return std::sqrt(2.0 / 3.0) * 2.0 * sinPhi / (3.0 - sinPhi);
  }
  double dgamma(const Eigen::Vector3d& eps, double alpha) const {
    const Eigen::Vector3d dev = eps - Eigen::Vector3d::Constant(eps.sum() / 3.0);
    return dev.norm() + (3.0 * lambda + 2.0 * mu) / (2.0 * mu) * eps.sum() * alpha;
  }
  // Particle i's Hencky strain, from F through Eigen's SVD in double.
  Eigen::Vector3d strain(std::int32_t i) const {
    const Eigen::Vector3d s = Eigen::JacobiSVD<Eigen::Matrix3d>(world.deformation(i).cast<double>()).singularValues();
    return s.array().log().matrix();
  }
};

}  // namespace

// Sand's hardening (docs/formats.md `hardening`: the friction angle grows with the accumulated
// plastic strain q, phi = friction_angle + hardening q, capped at 80 degrees): a sand box thrown
// at the floor with hardening 200 degrees per unit q. After each step every particle's Hencky
// strain (from F through Eigen's SVD in double) lies on or inside the cone of the angle its q
// gives now (its last return used a q no larger, so a cone no wider), many lie outside the cone
// of the base angle (the hardened cones are wider: the hardening acted), and q never decreases.
// Tolerance 2e-5 in strain, as for the return maps above.
TEST(MpmWorld, SandsFrictionAngleGrowsWithItsPlasticStrain) {
  Material grit = makeMaterial(MaterialKind::kSand, "grit");
  grit.elastic.youngs = 5e4;
  grit.sand.hardening = 200.0;
  ThrownSand sand(grit);
  MpmWorld& w = sand.world;
  constexpr double kTol = 2e-5;
  std::vector<float> qBefore(w.particles().size(), 0.0f);
  std::size_t pastBase = 0;
  double qMost = 0.0;
  for (int step = 0; step < 12; ++step) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    for (std::int32_t i = 0; i < std::int32_t(w.particles().size()); ++i) {
      const double q = w.plasticScalar(i);
      ASSERT_GE(q, double(qBefore[std::size_t(i)])) << "particle " << i << " step " << step;
      qBefore[std::size_t(i)] = float(q);
      qMost = std::max(qMost, q);
      const Eigen::Vector3d eps = sand.strain(i);
      const double deg = std::min(80.0, grit.sand.frictionAngleDeg + grit.sand.hardening * q);
      ASSERT_LE(sand.dgamma(eps, ThrownSand::alphaOf(deg)), kTol) << "particle " << i << " outside its hardened cone in step " << step;
      if (sand.dgamma(eps, ThrownSand::alphaOf(grit.sand.frictionAngleDeg)) > 1e-4) ++pastBase;
    }
  }
  std::printf("sand hardening: largest q %.4f (angle %.1f deg); particle-steps outside the base cone %zu\n", qMost,
              std::min(80.0, grit.sand.frictionAngleDeg + grit.sand.hardening * qMost), pastBase);
  EXPECT_GT(pastBase, 1000u);
}

// Klár et al. 2016's hardening law (§7.3, `hardening_law=klar`): phi(q) = h0 + (h1 q - h3)
// e^(-h2 q), with their values 25 degrees at q = 0, rising to 48 at q = 6.1 and settling to 35.
// The same thrown sand box: after each step every particle's strain lies on or inside the cone
// of the widest angle the law gives over the q it had during the step (q only grows: its last
// return used one in between), many lie outside the cone of 25 degrees (the angle grew) and
// outside h0's 35 (past q = h3 / h1 = 1.1, the law's rise), and many at yield sit on the cone
// of the law's angle at their q (read back from their strain, to 0.5 degree). Read as the linear
// law's 30 degrees, the first steps' particles would lie outside the law's 25-degree cone; with
// h2 doubled none sits on the law's cone (3,012 particle-steps do).
TEST(MpmWorld, SandUnderKlarsLawFollowsItsFrictionAngle) {
  Material grit = makeMaterial(MaterialKind::kSand, "grit");
  grit.elastic.youngs = 5e4;
  grit.sand.klar = true;
  ThrownSand sand(grit);
  MpmWorld& w = sand.world;
  const double mu = sand.mu, lambda = sand.lambda;
  const double h0 = 35.0, h1 = 9.0, h2 = 0.2, h3 = 10.0;  // Klár et al. 2016's values, in degrees
  const auto law = [&](double q) { return std::clamp(h0 + (h1 * q - h3) * std::exp(-h2 * q), 0.0, 80.0); };
  const auto alphaOf = ThrownSand::alphaOf;
  const auto dgamma = [&](const Eigen::Vector3d& eps, double alpha) { return sand.dgamma(eps, alpha); };
  constexpr double kTol = 2e-5;
  std::vector<double> qBefore(w.particles().size(), 0.0);
  std::size_t past25 = 0, past35 = 0, onCone = 0;
  for (int step = 0; step < 12; ++step) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    for (std::int32_t i = 0; i < std::int32_t(w.particles().size()); ++i) {
      const double q0 = qBefore[std::size_t(i)], q = w.plasticScalar(i);
      ASSERT_GE(q, q0);
      qBefore[std::size_t(i)] = q;
      double widest = std::max(law(q0), law(q));
      const double qPeak = (h1 / h2 + h3) / h1;  // 6.11: the law's peak
      if (q0 < qPeak && q > qPeak) widest = std::max(widest, law(qPeak));
      const Eigen::Vector3d eps = sand.strain(i);
      ASSERT_LE(dgamma(eps, alphaOf(widest)), kTol) << "particle " << i << " (q " << q << ") outside its cone in step " << step;
      past25 += dgamma(eps, alphaOf(25.0)) > 1e-4;
      past35 += dgamma(eps, alphaOf(35.0)) > 1e-4;
      // At yield on the cone of the angle the law gives at q (its angle read back from the
      // strain: alpha = |dev| / (-k tr eps), where tr eps is clearly negative), to 0.5 degree:
      // a law of another shape (h2 doubled: 1.8 degrees narrower at q = 2, more beyond) does not reach it.
      const double tr = eps.sum();
      if (q > 2.0 && tr < -5e-4) {
        const double a = (eps - Eigen::Vector3d::Constant(tr / 3.0)).norm() / (-(3.0 * lambda + 2.0 * mu) / (2.0 * mu) * tr);
        // alpha = sqrt(2/3) 2 s / (3 - s), s = sin(phi): s = 3 a / (2 sqrt(2/3) + a)
        const double s = 3.0 * a / (2.0 * std::sqrt(2.0 / 3.0) + a);
        if (s < 1.0) onCone += std::abs(std::asin(s) * 180.0 / 3.14159265358979323846 - law(q)) < 0.5;
      }
    }
  }
  std::printf("Klar's law: particle-steps outside the 25-degree cone %zu, outside 35 degrees %zu, on the law's cone %zu\n",
              past25, past35, onCone);
  EXPECT_GT(past25, 1000u);
  EXPECT_GT(past35, 100u);
  EXPECT_GT(onCone, 1000u);
}

TEST(MpmWorld, ParticlesNeverLeaveTheDomain) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  BodyInit fast;
  fast.velocity = Vec3(6.0, 0.0, 0.0);  // towards the x = 1 wall
  addBox(p, bodies, Vec3(0.85, 0.3, 0.45), 6, 6, 6, h, 0, fast);
  addBox(p, bodies, Vec3(1.02, 0.3, 0.2), 2, 2, 2, h, 0);  // given outside: put on the wall
  MpmWorld w(p, bodies, {elastic(5e4)}, unitDomain(h, 0));
  for (int s = 0; s < 20; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  for (std::size_t i = 0; i < w.particles().size(); ++i) {
    EXPECT_LE(w.particles().x[i], 1.0f);
    EXPECT_GE(w.particles().y[i], 0.0f);
  }
  // Far too fast for a fixed substep count: the guard stops the run (a particle moved more
  // than a cell per substep) at the pass that made it, before the next P2G.
  BodyInit faster;
  faster.velocity = Vec3(90.0, 0.0, 0.0);
  ParticleArrays p2;
  std::vector<BodyRange> b2;
  addBox(p2, b2, Vec3(0.5, 0.3, 0.45), 4, 4, 4, h, 0, faster);
  MpmWorld v(p2, b2, {elastic(5e4)}, unitDomain(h, 2));
  v.setValidate(true);  // once per step, the wall has stopped it by then: check every pass
  EXPECT_FALSE(v.step());
  EXPECT_EQ(v.guard().kind, GuardKind::kCfl) << v.guard().message();
  EXPECT_EQ(v.guard().pass, "g2p");
  EXPECT_EQ(v.guard().material, "jelly");
  EXPECT_FALSE(v.step());  // a tripped world refuses to step
}

// The guard's checks run in parallel chunks of 4,096 particles; it names the lowest-id
// particle that fails, whichever chunk finishes first: two fast boxes, the first in the
// second chunk and the second in the fourth, behind slow ones (ids counted by hand).
TEST(MpmWorld, TheGuardNamesTheLowestFailingParticleAcrossChunks) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> b;
  BodyInit fast;
  fast.velocity = Vec3(90.0, 0.0, 0.0);
  addBox(p, b, Vec3(0.1, 0.1, 0.1), 17, 17, 17, h, 0);        // ids 0..4912, at rest
  addBox(p, b, Vec3(0.3, 0.5, 0.5), 4, 4, 4, h, 0, fast);     // 4913..4976: chunk 1
  addBox(p, b, Vec3(0.6, 0.1, 0.6), 20, 20, 20, h, 0);        // 4977..12976
  addBox(p, b, Vec3(0.3, 0.7, 0.2), 4, 4, 4, h, 0, fast);     // 12977..13040: chunk 3
  ASSERT_EQ(p.size(), 13041u);
  MpmWorld w(p, b, {elastic(5e4)}, unitDomain(h, 2));
  w.setValidate(true);
  EXPECT_FALSE(w.step());
  EXPECT_EQ(w.guard().kind, GuardKind::kCfl) << w.guard().message();
  EXPECT_GE(w.guard().particle, 4913);
  EXPECT_LT(w.guard().particle, 4977);
}

TEST(MpmWorld, FixedBodiesHoldStillAndPlanListsOnlyPassesWithWork) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  BodyInit fixed;
  fixed.fixed = true;
  addBox(p, bodies, Vec3(0.4, 0.2, 0.4), 10, 2, 10, h, 0, fixed);  // a table top
  addBox(p, bodies, Vec3(0.42, 0.3, 0.42), 5, 5, 5, h, 0);         // a block falling onto its middle
  MpmWorld w(p, bodies, {elastic(5e4)}, unitDomain(h, 0));
  const std::vector<float> y0(w.particles().y.begin(), w.particles().y.begin() + 200);
  for (int s = 0; s < 120; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  for (std::size_t i = 0; i < 200; ++i) EXPECT_EQ(w.particles().y[i], y0[i]);
  EXPECT_EQ(w.mode(0), BodyMode::kFixed);
  EXPECT_GT(comY(w, 1), 0.2 + 2 * h);  // held up by the table, not fallen through to the ground
  // At rest (2 s) on the table's top face, not a grid cell above it: the table is a distance
  // field at its voxels' faces. Its lowest particle rests within a voxel (half a grid cell)
  // above the face (measured 6.5 mm: the grid holds it at the node inside the table) and not
  // below it. When the table held its particles' whole stencils the block stood 1.5 dx out.
  const float lowest = lowestOf(w, 1);
  const double top = 0.2 + 1.5 * h;
  std::printf("block on a fixed table: lowest particle %.4f m, the table's top face %.4f m\n", lowest, top);
  EXPECT_GT(lowest, top - 1e-4);
  EXPECT_LT(lowest, top + h);
  bool plasticity = false;
  for (const PlanEntry& e : w.plan()) plasticity = plasticity || e.name == "plasticity";
  EXPECT_FALSE(plasticity);  // all elastic: the pass is off
  for (const PlanEntry& e : w.planAll())
    if (e.name == "plasticity") {
      EXPECT_NE(e.reason.find("no dynamic particle of a plastic kind"), std::string::npos);
    }
}

// A fixed body's field follows the sketch: with the table top erased (every particle removed)
// the block that rested on it falls to the ground, and with a table released (made dynamic) the
// block no longer rests on a field where the table was: both fall. The ground is at y = 0, the
// table's top face at 0.215 m: the block's centre below 0.1 m (at its lowest: it bounces) means
// it went down past it.
TEST(MpmWorld, AFixedBodyCutOrReleasedAfterPlayNoLongerHoldsWhatRestedOnIt) {
  const double h = 0.01;
  for (const bool cut : {true, false}) {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit fixed;
    fixed.fixed = true;
    addBox(p, bodies, Vec3(0.4, 0.2, 0.4), 10, 2, 10, h, 0, fixed);
    addBox(p, bodies, Vec3(0.42, 0.24, 0.42), 5, 5, 5, h, 0);
    MpmWorld w(p, bodies, {elastic(5e4)}, unitDomain(h, 0));
    for (int s = 0; s < 30; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    ASSERT_GT(comY(w, 1), 0.2);
    if (cut) {
      std::vector<std::int32_t> top(200);
      for (std::int32_t i = 0; i < 200; ++i) top[std::size_t(i)] = i;
      w.removeParticles(top);
    } else {
      w.setMode(0, BodyMode::kDynamic);
    }
    double lowest = 1.0;  // the soft block bounces on the ground: its lowest centre
    for (int s = 0; s < 40; ++s) {
      ASSERT_TRUE(w.step()) << w.guard().message();
      lowest = std::min(lowest, comY(w, 1));
    }
    EXPECT_LT(lowest, 0.1) << (cut ? "cut" : "released");
  }
}

// A fixed body drawn after play is a collider from the next step: a block falling from 0.4 m
// onto a table top drawn at 0.2 m after 5 steps (the block still 0.34 m up) rests on its top
// face (its lowest particle within a voxel above 0.215 m), not on the ground.
TEST(MpmWorld, AFixedBodyDrawnAfterPlayHoldsWhatFallsOnIt) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.42, 0.4, 0.42), 5, 5, 5, h, 0);
  MpmWorld w(p, bodies, {elastic(5e4)}, unitDomain(h, 0));
  for (int s = 0; s < 5; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  ParticleArrays top;
  std::vector<BodyRange> unused;
  addBox(top, unused, Vec3(0.4, 0.2, 0.4), 10, 2, 10, h, 0);
  BodyRange shape;
  shape.init.fixed = true;
  const int table = w.addBody(top, shape, /*kinematic=*/false);
  EXPECT_EQ(w.mode(table), BodyMode::kFixed);
  for (int s = 0; s < 120; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const float lowest = lowestOf(w, 0);
  EXPECT_GT(lowest, 0.215f - 1e-4f);
  EXPECT_LT(lowest, 0.215f + float(h));
}

TEST(MpmWorld, AFixedSubstepCountAboveTheBoundIsAWarningNamingTheMaterial) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.45, 0.5, 0.45), 4, 4, 4, h, 0);
  // E = 5e6, rho = 1000, nu = 0.3: c_p = sqrt(E (1-nu)/((1+nu)(1-2nu)) / rho) = 82.0 m/s;
  // h <= 0.5 * 0.02 / 82.0 = 1.22e-4 s: 137 substeps for dt = 1/60.
  MpmWorld w(p, bodies, {elastic(5e6)}, unitDomain(h, 4));
  ASSERT_EQ(w.warnings().size(), 1u);
  EXPECT_NE(w.warnings()[0].find("material 'jelly'"), std::string::npos) << w.warnings()[0];
  // mu and lambda are kept in float: 1e-6 relative.
  const double c = std::sqrt(5e6 * 0.7 / (1.3 * 0.4) / 1000.0);
  EXPECT_NEAR(w.waveBound().waveSpeed, c, 1e-6 * c);
  EXPECT_NEAR(w.waveBound().h, 0.5 * 0.02 / c, 1e-6 * 0.5 * 0.02 / c);
  MpmWorld autoW(p, bodies, {elastic(5e6)}, unitDomain(h, 0));
  EXPECT_TRUE(autoW.warnings().empty());
  EXPECT_EQ(autoW.substepsForNextStep(), int(std::ceil((1.0 / 60.0) / autoW.waveBound().h)));
}

TEST(MpmWorld, RemovedParticlesLeaveTheirBodyAndTheSimulation) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.45, 0.5, 0.45), 4, 4, 4, h, 0);
  MpmWorld w(p, bodies, {elastic(5e4)}, unitDomain(h, 0));
  EXPECT_EQ(w.removeParticles({0, 1, 2}), std::vector<int>{0});
  EXPECT_EQ(w.bodyParticles(0).size(), 61u);
  EXPECT_FALSE(w.alive(1));
  const float x1 = w.particles().x[1];
  ASSERT_TRUE(w.step());
  EXPECT_EQ(w.particles().x[1], x1);
  std::vector<std::int32_t> all(w.bodyParticles(0).begin(), w.bodyParticles(0).end());
  w.removeParticles(all);
  EXPECT_EQ(w.mode(0), BodyMode::kEmpty);
}

// A cut that disconnects a body splits it (the PBD rule, core/lattice.h cutPieces): a bar of
// 12 x 4 x 4 particles loses its slab at x index 6; one design piece broke, so the larger part
// (x 0-5, 96 particles) keeps body 0 and the other (x 7-11, 80) becomes body 1, its particles
// in group 1. A carried (kinematic) body cut in two keeps the larger piece on the brush; the
// other is released and falls. A fluid body is not split.
TEST(MpmWorld, ACutThatDisconnectsABodySplitsItAndOnlyTheLargerPieceStaysCarried) {
  const double h = 0.01;
  const auto slab = [](int first) {
    std::vector<std::int32_t> ids;
    for (int j = 0; j < 4; ++j)
      for (int k = 0; k < 4; ++k) ids.push_back(first + (6 * 4 + j) * 4 + k);  // addBox order: i, then j, then k
    return ids;
  };
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.405, 0.505, 0.405), 12, 4, 4, h, 0);
  addBox(p, bodies, Vec3(0.405, 0.305, 0.605), 12, 4, 4, h, 1);  // water
  MpmWorld w(p, bodies, {elastic(5e4), makeMaterial(MaterialKind::kFluid, "water")}, unitDomain(h, 0));
  w.setMode(0, BodyMode::kKinematic);
  EXPECT_EQ(w.removeParticles(slab(0)), (std::vector<int>{0, 2}));
  ASSERT_EQ(w.bodyCount(), 3);
  EXPECT_EQ(w.bodyParticles(0).size(), 96u);
  EXPECT_EQ(w.bodyParticles(2).size(), 80u);
  EXPECT_EQ(w.bodyParticles(0).back(), 6 * 16 - 1);  // x index 5's last particle
  EXPECT_EQ(w.bodyParticles(2).front(), 7 * 16);
  EXPECT_EQ(w.particles().group(std::size_t(7 * 16)), 2);
  EXPECT_EQ(w.mode(0), BodyMode::kKinematic);
  EXPECT_EQ(w.mode(2), BodyMode::kDynamic);
  const float y0 = w.particles().y[0], y2 = w.particles().y[7 * 16];
  w.setKinematicTarget(0, w.pose(0).centre);
  for (int s = 0; s < 6; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  EXPECT_EQ(w.particles().y[0], y0);        // held on the brush
  EXPECT_LT(w.particles().y[7 * 16], y2 - 0.005f);  // released: falls (g t^2 / 2 = 0.02 m in 0.1 s)
  // The water bar cut the same way stays one body.
  EXPECT_EQ(w.removeParticles(slab(192)), (std::vector<int>{1}));
  EXPECT_EQ(w.bodyCount(), 3);
  EXPECT_EQ(w.bodyParticles(1).size(), 176u);
}

// The grid mass field of one body (Solver::massField, for the renderer): P2G's mass transfer of
// that body alone. Oracles: mass conservation (the B-spline weights of a particle sum to 1, so
// the nodes hold the body's mass; float weights: 1e-6 relative), the closed-form interior value
// (particles at dx/2 on each axis: sum over particles of a 1-D B-spline sampled every half node
// is exactly 2 at any offset, so a node deep inside holds 8 m_p = rho dx^3; 1e-5 relative for the
// float weights), zero on the box's faces (the field closes inside its box), and a removed
// particle's mass leaving the field.
TEST(MpmWorld, TheMassFieldOfABodyHoldsItsMassAndRhoDx3Inside) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.305, 0.405, 0.305), 12, 10, 8, h, 0);
  addBox(p, bodies, Vec3(0.425, 0.405, 0.305), 4, 4, 4, h, 0);  // next to body 0's x+ side
  MpmWorld w(p, bodies, {elastic(5e4)}, unitDomain(h, 0));
  const auto& ids = w.bodyParticles(0);
  const double mp = w.particles().mass[0];
  NodeField f;
  ASSERT_TRUE(w.massField(ids, f));
  EXPECT_DOUBLE_EQ(f.spacing, w.dx());
  double sum = 0.0, faces = 0.0, peak = 0.0;
  for (int k = 0; k < f.size.z(); ++k)
    for (int j = 0; j < f.size.y(); ++j)
      for (int i = 0; i < f.size.x(); ++i) {
        sum += f.at(i, j, k);
        peak = std::max(peak, double(f.at(i, j, k)));
        if (i == 0 || j == 0 || k == 0 || i == f.size.x() - 1 || j == f.size.y() - 1 || k == f.size.z() - 1)
          faces += f.at(i, j, k);
      }
  EXPECT_NEAR(sum, mp * double(ids.size()), 1e-6 * mp * double(ids.size()));  // body 1's mass left out
  EXPECT_EQ(faces, 0.0);
  // Body 0 spans 0.305-0.415, 0.405-0.495, 0.305-0.375: the node at (0.36, 0.46, 0.34) has all
  // its stencil's reach (1.5 dx = 0.03) inside it.
  const Vec3 node = (Vec3(0.36, 0.46, 0.34) - f.origin) / f.spacing;
  const Vec3i n = node.array().round().cast<int>();
  ASSERT_LT((node - n.cast<double>()).norm(), 1e-6);
  EXPECT_NEAR(f.at(n.x(), n.y(), n.z()), 8.0 * mp, 1e-5 * 8.0 * mp);
  EXPECT_NEAR(peak, 8.0 * mp, 1e-5 * 8.0 * mp);
  w.removeParticles({ids[0], ids[1], ids[2]});
  NodeField g;
  ASSERT_TRUE(w.massField(w.bodyParticles(0), g));
  double after = 0.0;
  for (float v : g.values) after += v;
  EXPECT_NEAR(sum - after, 3.0 * mp, 1e-5 * sum);
}

// Sketching after play through the Solver interface: a body being drawn is held (kinematic:
// it does not fall), a carried body moves to its target in one step, a released one keeps
// the velocity of its carried motion, and vel=/spin= come back as the body's velocity and
// angular velocity (a rigid field v + w x r, exactly: the particles are points).
TEST(MpmWorld, BodiesAddedHeldCarriedAndReleasedAfterPlay) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.2, 0.05, 0.2), 4, 4, 4, h, 0);
  MpmWorld w(p, bodies, {elastic(5e4)}, unitDomain(h, 0));
  ParticleArrays drawn;
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j)
      for (int k = 0; k < 5; ++k) drawn.push(float(0.6 + i * h), float(0.5 + j * h), float(0.5 + k * h), 7, 0);
  const int b = w.addBody(drawn, BodyRange{}, /*kinematic=*/true);
  ASSERT_EQ(b, 1);
  EXPECT_EQ(w.mode(b), BodyMode::kKinematic);
  const Vec3 c0 = w.pose(b).centre;
  ASSERT_TRUE(w.step());
  EXPECT_EQ(w.pose(b).centre, c0);  // held where it is drawn
  const Vec3 target = c0 + Vec3(0.05, 0.0, -0.02);
  w.setKinematicTarget(b, target);
  ASSERT_TRUE(w.step());
  EXPECT_LT((w.pose(b).centre - target).norm(), 1e-6);  // float positions near 0.6 m
  w.setKinematicTarget(b, target + Vec3(0.01, 0.0, 0.0));
  w.setMode(b, BodyMode::kDynamic);  // released: keeps the carried velocity dx / dt
  EXPECT_LT((w.velocity(b) - Vec3(0.01 * 60.0, 0.0, 0.0)).norm(), 1e-4);
  w.setVelocity(b, Vec3(0.5, 1.0, 0.0), Vec3(0.0, 2.0, 1.0));
  EXPECT_LT((w.velocity(b) - Vec3(0.5, 1.0, 0.0)).norm(), 1e-5);
  EXPECT_LT((w.angularVelocity(b) - Vec3(0.0, 2.0, 1.0)).norm(), 1e-4);
  EXPECT_THROW(w.setKinematicTarget(b, target), RuntimeError);  // only a carried body has a target
  ASSERT_TRUE(w.step());
}

// Checking after every pass (--validate) changes nothing but the checks: the same states.
// And a step far above the explicit bound (E = 5e6 with one substep of 1/60 s, 137 needed)
// is stopped by the guard, which names a pass of the table (found by the replay), the
// particle's material and the knob to change; the world then refuses to step.
TEST(MpmWorld, ValidateGivesTheSameStatesAndTheGuardNamesPassAndMaterial) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  BodyInit down;
  down.velocity = Vec3(0.0, -2.0, 0.0);
  addBox(p, bodies, Vec3(0.4, 0.05, 0.4), 8, 8, 8, h, 0, down);
  std::vector<std::uint64_t> hashes[2];
  for (int v = 0; v < 2; ++v) {
    MpmWorld w(p, bodies, {elastic(5e4)}, unitDomain(h, 0));
    w.setValidate(v == 1);
    for (int s = 0; s < 10; ++s) {
      ASSERT_TRUE(w.step()) << w.guard().message();
      hashes[v].push_back(w.stateHash());
    }
  }
  EXPECT_EQ(hashes[0], hashes[1]);
  MpmWorld w(p, bodies, {elastic(5e6)}, unitDomain(h, 1));
  ASSERT_FALSE(w.warnings().empty());
  bool ran = true;
  for (int s = 0; s < 50 && ran; ++s) ran = w.step();
  ASSERT_FALSE(ran);
  const GuardRecord& g = w.guard();
  EXPECT_NE(g.pass, "guard") << g.message();
  bool known = false;
  for (const PassSpec& spec : kMpmPasses) known = known || g.pass == spec.name;
  EXPECT_TRUE(known) << g.message();
  EXPECT_EQ(g.material, "jelly");
  EXPECT_GE(g.particle, 0);
  // The advice names the knob with this run's value (1 substep).
  EXPECT_NE(g.hint.find("Fix: raise 'substeps' from 1 to at least "), std::string::npos) << g.message();
  EXPECT_FALSE(w.step());
}

// Under --guard warn a step the guard stopped is run again from its saved start, so it ends as
// the same step checked after every pass (--validate) does: a jelly block and a water block thrown
// at 12 m/s break the velocity CFL (1.25 cells a substep of 1/480 s, a recoverable kind) at once. Every state
// the step changes must be restored, the jelly's deformation gradients among them (skipping F
// is right only where every dynamic particle is a fluid, which g2p never gives an F); the water
// alone checks that skip.
TEST(MpmWorld, AStepTheGuardStoppedUnderWarnEndsAsTheValidatedStepDoes) {
  const double h = 0.01;
  for (const bool withJelly : {true, false}) {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit thrown;
    thrown.velocity = Vec3(12.0, 0.0, 0.0);
    addBox(p, bodies, Vec3(0.2, 0.3, 0.3), 6, 6, 6, h, 1, thrown);
    if (withJelly) addBox(p, bodies, Vec3(0.2, 0.3, 0.6), 6, 6, 6, h, 0, thrown);
    Material water = makeMaterial(MaterialKind::kFluid, "water");
    std::vector<std::uint64_t> hashes[2];
    long warned[2] = {0, 0};
    for (int v = 0; v < 2; ++v) {
      MpmWorld w(p, bodies, {elastic(5e4), water}, unitDomain(h, 2, 1.0 / 240.0));
      w.setGuardPolicy(GuardPolicy::kWarn);
      w.setValidate(v == 1);
      for (int s = 0; s < 4; ++s) {
        ASSERT_TRUE(w.step()) << w.guard().message();
        hashes[v].push_back(w.stateHash());
      }
      warned[v] = w.guardLog().total();
    }
    EXPECT_GT(warned[0], 0) << "the throw should break the velocity CFL";
    // The CFL record's bound is a cell a substep: dx / h = 0.02 m / (1/480 s) = 9.6 m/s.
    MpmWorld w(p, bodies, {elastic(5e4), water}, unitDomain(h, 2, 1.0 / 240.0));
    w.setGuardPolicy(GuardPolicy::kWarn);
    for (int s = 0; s < 4; ++s) ASSERT_TRUE(w.step());
    bool cfl = false;
    for (const GuardRecord& g : w.guardLog().first())
      if (g.kind == GuardKind::kCfl) {
        cfl = true;
        EXPECT_NEAR(g.bound, 0.02 * 480.0, 1e-9) << g.message();
        EXPECT_GT(g.value, g.bound) << g.message();
        EXPECT_EQ(g.stroke, w.particles().stroke[std::size_t(g.particle)]) << g.message();
      }
    EXPECT_TRUE(cfl);
    EXPECT_EQ(warned[0], warned[1]);
    EXPECT_EQ(hashes[0], hashes[1]) << (withJelly ? "water and jelly" : "water alone");
  }
}

// The guard's end-of-step checks read what the step's last g2p summed while it wrote the
// particles, not sweeps of their own (StepSummary); where the summary flags anything the sweeps
// run and the step is replayed to name the pass. Oracle: the same run validated after every
// pass, whose checks sweep the particles. Two blocks of water, then of jelly, colliding at 1 m/s
// each in zero gravity (2 substeps, CFL bound 2.4 m/s: they invert), and a jelly block thrown at
// 5 m/s through the middle of the domain (the CFL bound): both runs stop in the same step with
// the same record (kind, particle, pass, substep, value). Ignoring the summary's speed flag fails
// it (the thrown block runs on). Its J and non-finite flags mirror the sweeps' tests, but no end
// state failing only them could be built: an inversion needs a velocity jump of about dx/h
// across a cell, and the stress that follows passes the CFL bound in the same substep (the
// colliding blocks trip both), and a NaN comes only from such a blow-up. And the energy the
// summary gives the energy check is the particles' own, summed here in double: within 1e-5 of
// it (float sums over blocks of 512, as the guard's sweeps take them; a kinetic sum of 0 fails).
TEST(MpmWorld, TheGuardsEndOfStepSummaryTripsAsItsSweepsDo) {
  const double h = 0.01;
  struct Case {
    bool water;
    double v;
    bool collide;
  };
  for (const Case& c : {Case{true, 1.0, true}, Case{false, 1.0, true}, Case{false, 5.0, false}}) {
    GuardRecord record[2];
    for (int validate = 0; validate < 2; ++validate) {
      ParticleArrays p;
      std::vector<BodyRange> bodies;
      BodyInit a, b;
      a.velocity = Vec3(c.v, 0.0, 0.0), b.velocity = Vec3(-c.v, 0.0, 0.0);
      addBox(p, bodies, Vec3(0.3, 0.4, 0.4), 8, 8, 8, h, 0, a);
      if (c.collide) addBox(p, bodies, Vec3(0.3 + 8 * h, 0.4, 0.4), 8, 8, 8, h, 0, b);
      MpmParams q = unitDomain(h, 2);
      q.gravity = Vec3::Zero();
      MpmWorld w(p, bodies, {c.water ? makeMaterial(MaterialKind::kFluid, "water") : elastic(5e4)}, q);
      w.setValidate(validate == 1);
      for (int s = 0; s < 10 && w.step(); ++s) {
      }
      record[validate] = w.guard();
    }
    const std::string what = std::string(c.water ? "water" : "jelly") + (c.collide ? " colliding" : " thrown");
    ASSERT_TRUE(record[1].tripped()) << what;
    EXPECT_EQ(record[1].kind, c.collide ? GuardKind::kInverted : GuardKind::kCfl) << what << ": " << record[1].message();
    EXPECT_EQ(record[0].kind, record[1].kind) << what << ": " << record[0].message();
    EXPECT_EQ(record[0].particle, record[1].particle) << what;
    EXPECT_EQ(record[0].pass, record[1].pass) << what;
    EXPECT_EQ(record[0].step, record[1].step) << what;
    EXPECT_EQ(record[0].substep, record[1].substep) << what;
    EXPECT_EQ(record[0].value, record[1].value) << what;
  }
  // The energy: a jelly block falling and spinning, 5 steps.
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  BodyInit spin;
  spin.velocity = Vec3(0.3, -0.5, 0.1), spin.spin = Vec3(0.0, 2.0, 1.0);
  addBox(p, bodies, Vec3(0.4, 0.5, 0.4), 8, 8, 8, h, 0, spin);
  MpmWorld w(p, bodies, {elastic(5e4)}, unitDomain(h, 0));  // substeps auto
  EXPECT_EQ(w.lastStepEnergy(), nullptr);  // no step yet
  for (int s = 0; s < 5; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  const EnergySums* e = w.lastStepEnergy();
  ASSERT_NE(e, nullptr);
  double kinetic = 0.0, potential = 0.0, mass = 0.0;
  const ParticleArrays& q = w.particles();
  for (std::size_t i = 0; i < q.size(); ++i) {
    const double m = q.mass[i];
    kinetic += 0.5 * m * (double(q.vx[i]) * q.vx[i] + double(q.vy[i]) * q.vy[i] + double(q.vz[i]) * q.vz[i]);
    potential += m * 9.81 * double(q.y[i]);
    mass += m;
  }
  EXPECT_NEAR(e->kinetic / kinetic, 1.0, 1e-5);
  EXPECT_NEAR(e->potential / potential, 1.0, 1e-5);
  EXPECT_NEAR(e->mass / mass, 1.0, 1e-6);
}

// Walls and ground take their friction from the materials touching them (static_friction,
// dynamic_friction, mass-weighted per node). A block sliding at 2 m/s on the ground: without
// friction it keeps its speed; with mu = 0.5 Coulomb's law slows it by mu g t (0.98 m/s in
// 0.2 s): within 10 % (the grid applies friction to the nodes at the ground, and the block
// is an elastic body, not a point; measured: 0.6 %).
TEST(MpmWorld, GroundFrictionComesFromTheMaterial) {
  const double h = 0.01;
  const auto slide = [&](double mu) {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit push;
    push.velocity = Vec3(2.0, 0.0, 0.0);
    addBox(p, bodies, Vec3(0.2, 0.5 * h, 0.45), 8, 8, 8, h, 0, push);
    Material m = elastic(1e5);
    m.staticFriction = m.dynamicFriction = mu;
    MpmWorld w(p, bodies, {m}, unitDomain(h, 0));
    for (int s = 0; s < 12; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    return w.velocity(0).x();
  };
  const double free = slide(0.0), rough = slide(0.5);
  EXPECT_NEAR(free, 2.0, 0.05);
  EXPECT_NEAR(2.0 - rough, 0.5 * 9.81 * 0.2, 0.1 * 0.5 * 9.81 * 0.2);
}

// A fixed body's friction is the mean of its material's and the touching material's, as between
// any two scene materials (docs/formats.md): the same block (mu = 0.5) sliding at 2 m/s on a
// fixed slab of mu = 0 slows by Coulomb's mu g t with the mean 0.25, 0.49 m/s in 0.2 s, within
// 10 % as on the ground (measured 0.503). Taking only the block's friction it would slow as on a
// slab of mu = 0.5, which takes more: Coulomb says 0.98 m/s, measured 0.79 (the slab's face lies
// between grid nodes, and the one node layer inside it that carries the friction sticks with
// less momentum than mu N would take; on the ground, whose node is at the surface, 0.6 %), so
// that one is only bounded to slow it at least 0.2 m/s more.
TEST(MpmWorld, AFixedBodysFrictionIsTheMeanOfBothMaterials) {
  const double h = 0.01;
  const auto slide = [&](double slabMu) {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit fixed, push;
    fixed.fixed = true;
    push.velocity = Vec3(2.0, 0.0, 0.0);
    addBox(p, bodies, Vec3(0.1, 0.2, 0.3), 80, 2, 40, h, 1, fixed);  // a slab, top face at 0.215 m
    addBox(p, bodies, Vec3(0.2, 0.215 + 0.5 * h, 0.45), 8, 8, 8, h, 0, push);  // on its face
    Material block = elastic(1e5), slab = elastic(1e5);
    block.staticFriction = block.dynamicFriction = 0.5;
    slab.staticFriction = slab.dynamicFriction = slabMu;
    MpmWorld w(p, bodies, {block, slab}, unitDomain(h, 0));
    for (int s = 0; s < 12; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    return w.velocity(1).x();
  };
  const double rough = slide(0.5), smooth = slide(0.0);
  std::printf("block on a fixed slab: %.3f m/s (slab mu 0.5), %.3f m/s (slab mu 0)\n", rough, smooth);
  EXPECT_NEAR(2.0 - smooth, 0.25 * 9.81 * 0.2, 0.1 * 0.25 * 9.81 * 0.2);
  EXPECT_LT(rough, smooth - 0.2);
}

// Per-wall kinds (scene `walls`): the same block sliding at 2 m/s with friction 0.5. A slip
// floor keeps its speed whatever the friction (slip removes only the normal component: within
// 2.5 %, as the frictionless block above); a sticky floor holds the nodes it touches at rest,
// so the block, gripped at its base, slows far below the frictional 1.02 m/s (it tumbles:
// below 0.7 m/s); a separate floor gives Coulomb's 2 - mu g t. Each case sets only y- (index
// 2) and makes every other wall the opposite kind, so a wrong side index shows.
TEST(MpmWorld, EachWallActsAsItsKindSays) {
  const double h = 0.01;
  const auto slide = [&](WallKind floor, WallKind others) {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit push;
    push.velocity = Vec3(2.0, 0.0, 0.0);
    addBox(p, bodies, Vec3(0.2, 0.5 * h, 0.45), 8, 8, 8, h, 0, push);
    Material m = elastic(1e5);
    m.staticFriction = m.dynamicFriction = 0.5;
    MpmParams q = unitDomain(h, 0);
    for (WallKind& k : q.walls) k = others;
    q.walls[2] = floor;
    MpmWorld w(p, bodies, {m}, q);
    for (int s = 0; s < 12; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    return w.velocity(0).x();
  };
  EXPECT_NEAR(slide(WallKind::kSlip, WallKind::kSticky), 2.0, 0.05);
  EXPECT_LT(slide(WallKind::kSticky, WallKind::kSlip), 0.7);
  EXPECT_NEAR(2.0 - slide(WallKind::kSeparate, WallKind::kSticky), 0.5 * 9.81 * 0.2, 0.1 * 0.5 * 9.81 * 0.2);
}

// grid_dx: the grid spacing is that multiple of the particle spacing. Free fall does not
// depend on it: with F = I and a uniform velocity, P2G and G2P pass the velocity through on
// any grid (the B-spline weights sum to 1 and their first moments vanish), so the block's
// centre follows symplectic Euler, y0 - g hs^2 n (n + 1) / 2, on grids of 1.5 and 3 spacings
// as on 2. Tolerance 3e-5 m, as for the free fall above (float32 rounding over 500 substeps).
TEST(MpmWorld, AFinerOrCoarserGridStillFallsFreely) {
  const double h = 0.01;
  for (double dxPer : {1.5, 2.0, 3.0}) {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    addBox(p, bodies, Vec3(0.45, 0.7, 0.45), 6, 6, 6, h, 0);
    MpmParams q = unitDomain(h, 50);
    q.dxPerSpacing = dxPer;
    MpmWorld w(p, bodies, {elastic(1e5)}, q);
    EXPECT_DOUBLE_EQ(w.dx(), dxPer * h);
    const double y0 = w.pose(0).centre.y();
    for (int s = 0; s < 10; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    const double hs = q.dt / q.substeps, n = 10.0 * q.substeps;
    EXPECT_NEAR(w.pose(0).centre.y(), y0 - 9.81 * hs * hs * n * (n + 1.0) / 2.0, 3e-5) << "grid_dx " << dxPer;
  }
}

// Martin & Moyce 1952 at the published gate: the front Z(T) of the same 2-D dam break,
// sampled every step, against every row of tests/pbd/data/martin-moyce-1952-front.csv with
// T <= 3 (the run's Z interpolated linearly in T): RMSE <= 10 % of the mean Z. Measured: 0.216
// against 0.225 (the front lags the experiment by up to 0.4 a at T = 3: MPM's grid transfer
// damps the surge at 5 cells across a). Deterministic, so the small margin cannot flake; a
// column only 4 particles deep in z spreads sideways too and lags twice as much.
TEST(MpmWorld, ADamBreakFrontMeetsMartinAndMoyceRmse) {
  // Also with particle_shift 0.8 (ParticleShiftKeepsASpreadingSheetASheet): it pushes a
  // gathered front apart, which runs a little ahead (RMSE 0.036 -> 0.038).
  for (const double shift : {0.0, 0.8}) {
    SCOPED_TRACE(shift > 0.0 ? "particle_shift 0.8" : "no particle_shift");
    const double h = 0.01, a = 0.1;
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    MpmParams q = unitDomain(h, 0, 1.0 / 600.0);
    q.domainSize = 0.5;
    q.particleShift = shift;
    for (WallKind& k : q.walls) k = WallKind::kSlip;
    addBox(p, bodies, Vec3(0.5 * h, 0.5 * h, 0.5 * h), int(a / h), int(2 * a / h), int(q.domainSize / h), h, 0);
    Material water = makeMaterial(MaterialKind::kFluid, "water");
    water.fluid.bulkModulus = 2e5;
    MpmWorld w(p, bodies, {water}, q);
    const double tScale = std::sqrt(2.0 * 9.81 / a);
    std::vector<double> T{0.0}, Z{1.0};
    while (w.time() * tScale < 3.1) {
      ASSERT_TRUE(w.step()) << w.guard().message();
      float front = 0.0f;
      for (float x : w.particles().x) front = std::max(front, x);
      T.push_back(w.time() * tScale);
      Z.push_back((front + 0.5 * h) / a);
    }
    std::ifstream csv(std::string(PHYSKETCH_SOURCE_DIR) + "/tests/pbd/data/martin-moyce-1952-front.csv");
    ASSERT_TRUE(csv) << "the published data file";
    std::string line;
    double sum = 0.0, sumZ = 0.0;
    int n = 0;
    while (std::getline(csv, line)) {
      double t = 0, z = 0;
      if (line.empty() || line[0] == '#' || std::sscanf(line.c_str(), "%lf,%lf", &t, &z) != 2 || t > 3.0) continue;
      const auto it = std::lower_bound(T.begin(), T.end(), t);
      const std::size_t j = std::size_t(std::max<std::ptrdiff_t>(1, it - T.begin()));
      const double f = (t - T[j - 1]) / (T[j] - T[j - 1]);
      const double zr = Z[j - 1] + f * (Z[j] - Z[j - 1]);
      sum += (zr - z) * (zr - z), sumZ += z, ++n;
    }
    ASSERT_GE(n, 10);
    const double rmse = std::sqrt(sum / n), meanZ = sumZ / n;
    std::printf("dam break, particle_shift %.1f: front RMSE %.3f (mean Z %.3f, %d rows)\n", shift, rmse, meanZ, n);
    EXPECT_LE(rmse, 0.1 * meanZ);
  }
}

// A water column spreading over the floor into a sheet thinner than a grid cell gathers into
// lines: the grid cannot see an arrangement finer than a cell, and particles sharing a cell share
// its velocity (docs/mpm.md, "Filaments"). particle_shift pushes fluid particles closer than
// its distance apart once a step. Oracle: the particles' own spacing, by brute force over all
// pairs: a 12 x 16 x 12 column of water (bulk modulus 2e4 Pa, scenes/mpm.scene's) spread for
// 0.6 s over a unit floor, most of it within 2 spacings of the floor; its tenth-percentile
// nearest-neighbour distance without shifting below 0.3 spacings (the case gathers; measured
// 0.094), with particle_shift 0.8 above 0.5 (measured 0.687). Also: the pass in the plan only
// where a fluid moves and the record asks for it; a rim is not pushed outwards (after Lind et
// al. 2012): a crowded square sheet (spacing 0.6 h, at rest in zero gravity, one step) keeps its
// outline within 0.05 spacings (measured 0; without the rule its edges moved out by 0.15); the
// same bits on 1 and 2 threads for a crowded block of 10,648 particles (over two of the parallel
// loops' 4,096-particle chunks, so a race between chunks would show); and a step that blows up
// with the pass on is the guard's to report, not an exception from the neighbour grid.
TEST(MpmWorld, ParticleShiftKeepsASpreadingSheetASheet) {
  const double h = 0.01;
  Material water = makeMaterial(MaterialKind::kFluid, "water");
  water.fluid.bulkModulus = 2e4;
  const auto run = [&](double shift, int threads, std::uint64_t* hash) {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    MpmParams q = unitDomain(h, 0);
    q.particleShift = shift;
    addBox(p, bodies, Vec3(0.44, 0.5 * h, 0.44), 12, 16, 12, h, 0);
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    MpmWorld w(p, bodies, {water}, q);
    bool planned = false;
    for (const PlanEntry& e : w.plan()) planned = planned || e.name == std::string("particle_shift");
    EXPECT_EQ(planned, shift > 0.0);
    for (int s = 0; s < 36; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
    if (hash) *hash = w.stateHash();
    const ParticleArrays& r = w.particles();
    const std::size_t n = r.size();
    std::vector<double> nearest(n, 1e9);
    std::size_t low = 0;
    for (std::size_t i = 0; i < n; ++i) {
      low += r.y[i] < 2.0 * h;
      for (std::size_t j = 0; j < n; ++j) {
        if (j == i) continue;
        const double d = std::hypot(double(r.x[i]) - r.x[j], double(r.y[i]) - r.y[j], double(r.z[i]) - r.z[j]);
        nearest[i] = std::min(nearest[i], d);
      }
    }
    std::nth_element(nearest.begin(), nearest.begin() + std::ptrdiff_t(n / 10), nearest.end());
    const double tenth = nearest[n / 10] / h, thin = double(low) / double(n);
    std::printf("spreading sheet, particle_shift %.1f: tenth-percentile spacing %.3f h, %.0f %% within 2 h of the floor\n",
                shift, tenth, 100.0 * thin);
    EXPECT_GT(thin, 0.5) << "the water did not spread into a thin sheet: the case tests nothing";
    return tenth;
  };
  EXPECT_LT(run(0.0, 2, nullptr), 0.3) << "without shifting the sheet no longer gathers: the case tests nothing";
  EXPECT_GT(run(0.8, 2, nullptr), 0.5);
  {
    const auto crowded = [&](int threads) {
      ParticleArrays p;
      for (int a = 0; a < 22; ++a)
        for (int b = 0; b < 22; ++b)
          for (int c = 0; c < 22; ++c) p.push(float(0.4 + 0.6 * h * a), float(0.3 + 0.6 * h * b), float(0.4 + 0.6 * h * c), 0, 0);
      BodyRange block;
      block.first = 0, block.count = std::int32_t(p.size());
      MpmParams q = unitDomain(h, 2);
      q.particleShift = 0.8;
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
      MpmWorld w(p, {block}, {water}, q);
      const std::uint64_t start = w.stateHash();
      for (int s = 0; s < 2; ++s) EXPECT_TRUE(w.step()) << w.guard().message();
      EXPECT_NE(w.stateHash(), start);
      return w.stateHash();
    };
    EXPECT_EQ(crowded(1), crowded(2)) << "particle_shift differs on 1 and 2 threads";
  }
  {  // blown up: a NaN position reaches the pass (g2p leaves it to the guard)
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit right, left;  // two blocks that meet: their momenta sum to inf - inf
    right.velocity = Vec3(1e38, 0.0, 0.0), left.velocity = Vec3(-1e38, 0.0, 0.0);
    addBox(p, bodies, Vec3(0.3, 0.3, 0.3), 4, 4, 4, h, 0, right);
    addBox(p, bodies, Vec3(0.3 + 4 * h, 0.3, 0.3), 4, 4, 4, h, 0, left);
    MpmParams q = unitDomain(h, 2);  // substep 1 makes C infinite, substep 2 the positions NaN
    q.particleShift = 0.8;
    MpmWorld w(p, bodies, {water}, q);
    bool stepped = true;
    EXPECT_NO_THROW(stepped = w.step());
    EXPECT_FALSE(stepped);
    EXPECT_TRUE(w.guard().tripped()) << "the guard names the blow-up";
  }
  {
    ParticleArrays p;
    for (int a = 0; a < 10; ++a)
      for (int c = 0; c < 10; ++c) p.push(float(0.45 + 0.6 * h * a), 0.5f, float(0.45 + 0.6 * h * c), 0, 0);
    BodyRange sheet;
    sheet.first = 0, sheet.count = std::int32_t(p.size());
    MpmParams q = unitDomain(h, 1);
    q.gravity = Vec3::Zero();
    q.particleShift = 0.8;
    MpmWorld w(p, {sheet}, {water}, q);
    ASSERT_TRUE(w.step()) << w.guard().message();
    const ParticleArrays& r = w.particles();
    float lo[2] = {1e9f, 1e9f}, hi[2] = {-1e9f, -1e9f};
    double nearest = 1e9;
    for (std::size_t i = 0; i < r.size(); ++i) {
      lo[0] = std::min(lo[0], r.x[i]), hi[0] = std::max(hi[0], r.x[i]);
      lo[1] = std::min(lo[1], r.z[i]), hi[1] = std::max(hi[1], r.z[i]);
      for (std::size_t j = 0; j < i; ++j)
        nearest = std::min(nearest, std::hypot(double(r.x[i]) - r.x[j], double(r.y[i]) - r.y[j], double(r.z[i]) - r.z[j]));
    }
    std::printf("crowded sheet after a shift: outline x %.5f..%.5f, z %.5f..%.5f (was 0.45..%.5f); nearest %.3f h\n",
                lo[0], hi[0], lo[1], hi[1], 0.45 + 5.4 * h, nearest / h);
    for (int a = 0; a < 2; ++a) {
      EXPECT_GE(lo[a], float(0.45 - 0.05 * h));
      EXPECT_LE(hi[a], float(0.45 + 5.45 * h));
    }
  }
  // No fluid, no pass: an elastic block with the record set.
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  MpmParams q = unitDomain(h, 0);
  q.particleShift = 0.8;
  addBox(p, bodies, Vec3(0.44, 0.1, 0.44), 4, 4, 4, h, 0);
  MpmWorld w(p, bodies, {elastic(5e4)}, q);
  for (const PlanEntry& e : w.plan()) EXPECT_NE(e.name, std::string("particle_shift"));
}

// An elastic ball (soft preset, E = 5e4 Pa, radius 6 spacings) dropped from 0.3 m onto a
// frictionless (slip) floor bounces without gaining energy: its centre never rises above the
// height it was dropped from (a bounce can at most return all of it; tolerance 1 mm, a tenth of
// a spacing, for the ball's own wobble of its centre), and it does rebound (the top of the
// first bounce is above 20 % of the drop: MPM elastic contact is not perfectly inelastic;
// measured: back to 78 % of the drop height).
TEST(MpmWorld, AnElasticBallReboundsWithoutGainingEnergy) {
  const double h = 0.01, r = 6.0;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  BodyRange ball;
  ball.first = 0;
  const Vec3 c(0.5, 0.3, 0.5);
  for (int i = -6; i <= 6; ++i)
    for (int j = -6; j <= 6; ++j)
      for (int k = -6; k <= 6; ++k)
        if (i * i + j * j + k * k <= r * r) p.push(float(c.x() + i * h), float(c.y() + j * h), float(c.z() + k * h), 0, 0);
  ball.count = static_cast<std::int32_t>(p.size());
  bodies.push_back(ball);
  MpmParams q = unitDomain(h, 0);
  for (WallKind& k : q.walls) k = WallKind::kSlip;
  MpmWorld w(p, bodies, {elastic(5e4)}, q);
  const double y0 = w.pose(0).centre.y(), drop = y0 - r * h;  // the ball's bottom starts 0.24 m up
  double highest = y0, lowest = y0, topAfter = 0.0;
  bool bounced = false;
  for (int s = 0; s < 90; ++s) {  // 1.5 s: fall (0.22 s), bounce, rise and fall again
    ASSERT_TRUE(w.step()) << w.guard().message();
    const double y = w.pose(0).centre.y();
    if (s > 0) highest = std::max(highest, y);
    lowest = std::min(lowest, y);
    if (!bounced && w.velocity(0).y() > 0.0 && y < r * h + 0.05) bounced = true;
    if (bounced) topAfter = std::max(topAfter, y);
  }
  EXPECT_TRUE(bounced);
  EXPECT_LT(highest, y0 + 1e-3);
  EXPECT_GT(topAfter - r * h, 0.2 * drop) << "lowest " << lowest;
}

// Material that reaches the domain's edge is reported (issue 9): a block thrown at the x+ wall
// gets there, and the report names that wall and a particle of the block's leading layer (the
// block moves as one, so its front is the first within 1.5 dx of the wall); no particle ever
// leaves the domain. A block resting on a ground above the domain floor is never at the edge
// (the ground is a boundary the scene asks for), and that run has no note.
TEST(MpmWorld, MaterialAtTheDomainEdgeIsReportedWithTheWallAndTheFirstParticle) {
  const double h = 0.01;
  const int n = 8;
  {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit throwIt;
    throwIt.velocity = Vec3(3.0, 0.0, 0.0);
    addBox(p, bodies, Vec3(0.85, 0.45, 0.45), n, n, n, h, 0, throwIt);
    MpmParams q = unitDomain(h, 0);
    q.gravity = Vec3::Zero();
    for (WallKind& k : q.walls) k = WallKind::kSlip;
    MpmWorld w(p, bodies, {elastic(1e5)}, q);
    EXPECT_TRUE(w.runNotes().empty());
    for (int s = 0; s < 10; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    ASSERT_GT(w.atDomainEdge(), 0);
    const MpmWorld::EdgeHit& first = w.firstAtEdge();
    EXPECT_EQ(first.wall, 1);  // x+
    ASSERT_GE(first.particle, 0);
    EXPECT_EQ(first.particle / (n * n), n - 1) << "particle " << first.particle << " is not in the leading layer";
    for (std::size_t i = 0; i < p.size(); ++i) EXPECT_LE(w.particles().x[i], 1.0f);
    ASSERT_EQ(w.runNotes().size(), 1u);
    const std::string note = w.runNotes()[0];
    EXPECT_NE(note.find("x+ wall"), std::string::npos) << note;
    // It names the particle, its stroke and material, the pass and the bound (1.5 dx = 0.03 m).
    EXPECT_NE(note.find("particle " + std::to_string(first.particle) + " (stroke 0, jelly)"), std::string::npos) << note;
    EXPECT_NE(note.find("pass g2p: within 1.5 dx = 0.03 m"), std::string::npos) << note;
    EXPECT_NE(note.find("enlarge 'workspace'"), std::string::npos) << note;
  }
  {
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    addBox(p, bodies, Vec3(0.45, 0.1 + 0.5 * h, 0.45), n, n, n, h, 0);
    MpmParams q = unitDomain(h, 0);
    q.groundY = 0.1;
    MpmWorld w(p, bodies, {elastic(1e5)}, q);
    for (int s = 0; s < 30; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
    EXPECT_EQ(w.atDomainEdge(), 0);
    EXPECT_TRUE(w.runNotes().empty());
  }
}

// --- mesh colliders (issue 9): distance fields imposed on the grid --------------------------

namespace {

// An axis-aligned box as a closed triangle mesh (12 triangles, counter-clockwise seen from outside).
TriangleSoup boxSoup(const Vec3& lo, const Vec3& hi) {
  TriangleSoup s;
  for (int k = 0; k < 8; ++k)
    s.vertices.emplace_back((k & 1) ? hi.x() : lo.x(), (k & 2) ? hi.y() : lo.y(), (k & 4) ? hi.z() : lo.z());
  s.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  s.closed = true;
  return s;
}

// A horizontal square sheet at height y: open, two triangles.
TriangleSoup sheetSoup(double x0, double x1, double y, double z0, double z1) {
  TriangleSoup s;
  s.vertices = {Vec3(x0, y, z0), Vec3(x1, y, z0), Vec3(x0, y, z1), Vec3(x1, y, z1)};
  s.triangles = {{0, 2, 1}, {1, 2, 3}};
  s.closed = false;
  return s;
}

MeshCollider colliderDesc(const std::string& name) {
  MeshCollider c;
  c.name = name;
  return c;
}

// An 8^3 elastic block (h = 1 cm) dropped from y = startY onto whatever the colliders make, for
// `seconds`: its centre height and lowest particle at the end, and the lowest any particle got.
struct Drop {
  double centre = 0.0, lowest = 0.0, lowestEver = 1e9;
};
Drop dropBlock(const std::vector<MeshCollider>& descs, const std::vector<TriangleSoup>& meshes, double seconds,
               double startY) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.465, startY, 0.465), 8, 8, 8, h, 0);
  MpmParams q = unitDomain(h, 0);
  MpmWorld w(p, bodies, {elastic(1e5)}, q);
  if (!descs.empty()) w.setColliders(descs, meshes);
  Drop d;
  const auto lowestNow = [&] {
    double lowest = 1e9;
    for (float y : w.particles().y) lowest = std::min(lowest, double(y));
    return lowest;
  };
  const int steps = int(std::lround(seconds / q.dt));
  for (int s = 0; s < steps; ++s) {
    EXPECT_TRUE(w.step()) << w.guard().message();
    d.lowestEver = std::min(d.lowestEver, lowestNow());
  }
  d.centre = comY(w, 0);
  d.lowest = lowestNow();
  return d;
}

}  // namespace

// A block dropped on a closed box collider (a table, top at y = 0.4) from 0.6 m never goes
// through its top (the boundary acts on nodes inside the field, and projection puts back a
// particle found inside: lowest ever within 5 mm of the top); set down 1 cm above it, it rests
// there: its bottom on the top within the reach of the grid's boundary (a particle's stencil
// reaches 1.5 dx = 3 cm, so the bottom rests 0-2.5 cm above), its centre 3.5 cm above its
// bottom (not squashed). Control: without the collider the block falls past y = 0.3 in 0.3 s.
TEST(MpmWorld, ABlockRestsOnAClosedMeshColliderAndFallsThroughWithoutIt) {
  const std::vector<MeshCollider> table = {colliderDesc("table")};
  const std::vector<TriangleSoup> mesh = {boxSoup(Vec3(0.3, 0.0, 0.3), Vec3(0.7, 0.4, 0.7))};
  EXPECT_GT(dropBlock(table, mesh, 1.0, 0.6).lowestEver, 0.395);
  const Drop rest = dropBlock(table, mesh, 0.6, 0.41);
  EXPECT_GT(rest.lowest, 0.398);
  EXPECT_LT(rest.lowest, 0.425);
  EXPECT_NEAR(rest.centre - rest.lowest, 0.035, 0.005);
  EXPECT_LT(dropBlock({}, {}, 0.3, 0.6).lowest, 0.3);
}

// An open sheet has no inside: it is a shell 1.5 dx thick (its upper surface 1.5 cm above
// y = 0.4 here). Dropped from 0.6 m the block never reaches the sheet's plane; set down on it,
// it rests on the shell (bottom 0.415 + 0-2.5 cm).
TEST(MpmWorld, ABlockRestsOnAnOpenSheetCollider) {
  const std::vector<MeshCollider> sheet = {colliderDesc("sheet")};
  const std::vector<TriangleSoup> mesh = {sheetSoup(0.3, 0.7, 0.4, 0.3, 0.7)};
  EXPECT_GT(dropBlock(sheet, mesh, 1.0, 0.6).lowestEver, 0.405);
  const Drop rest = dropBlock(sheet, mesh, 0.6, 0.43);
  EXPECT_GT(rest.lowest, 0.41);
  EXPECT_LT(rest.lowest, 0.44);
  EXPECT_NEAR(rest.centre - rest.lowest, 0.035, 0.005);
}

// A cup 0.3 m square, its floor at y = 0.1: either an open sheet (a box's floor and four walls,
// no lid; a sheet is a shell 0.75 dx either side of it) or a closed solid with walls and floor
// 0.03 m (1.5 dx) thick, whose cavity starts where the sheet's shell ends (0.015 m inside).
TriangleSoup cupSoup(bool closed) {
  const double x0 = 0.35, x1 = 0.65, y0 = 0.1, y1 = 0.4;
  TriangleSoup s;
  s.closed = closed;
  const auto quad = [&s](int a, int b, int c, int d) {
    s.triangles.push_back({a, b, c});
    s.triangles.push_back({a, c, d});
  };
  const auto box = [&s](double lo, double hi, double ylo, double yhi) {  // 8 corners, k = x + 2y + 4z
    for (int k = 0; k < 8; ++k) s.vertices.emplace_back((k & 1) ? hi : lo, (k & 2) ? yhi : ylo, (k & 4) ? hi : lo);
  };
  if (!closed) {
    box(x0, x1, y0, y1);
    quad(0, 1, 5, 4);  // floor
    quad(0, 2, 3, 1);  // z-
    quad(4, 5, 7, 6);  // z+
    quad(0, 4, 6, 2);  // x-
    quad(1, 3, 7, 5);  // x+
    return s;
  }
  box(x0 - 0.015, x1 + 0.015, y0 - 0.015, y1);          // outside: 0..7
  box(x0 + 0.015, x1 - 0.015, y0 + 0.015, y1);          // cavity: 8..15
  quad(0, 1, 5, 4);                                       // outside, facing out
  quad(0, 2, 3, 1);
  quad(4, 5, 7, 6);
  quad(0, 4, 6, 2);
  quad(1, 3, 7, 5);
  quad(8, 12, 13, 9);                                     // cavity, facing in (out of the solid)
  quad(8, 9, 11, 10);
  quad(12, 14, 15, 13);
  quad(8, 10, 14, 12);
  quad(9, 13, 15, 11);
  quad(2, 6, 14, 10);                                     // the rim at y1, facing up
  quad(6, 7, 15, 14);
  quad(7, 3, 11, 15);
  quad(3, 2, 10, 11);
  return s;
}

// A pool of water 8 layers deep (K = 2e4 Pa), left at rest for 1.5 s in the cup: the RMS of its
// pressure head p / (rho0 g) against Tait's column at the particle's depth below the surface
// (the closed form of dp/dz = rho g with p = K/gamma (J^-gamma - 1)) (m), and its most crowded
// horizontal slab one spacing thick, in layers (27 x 27 particles a layer).
struct CupPool {
  double headRms = 1e9, crowdedLayers = 1e9;
};
CupPool cupPool(bool closed) {
  const double h = 0.01, inner = 0.35 + 0.0155;
  const int across = 27;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(inner + 0.5 * h, 0.1155 + 0.5 * h, inner + 0.5 * h), across, 8, across, h, 0);
  Material water = makeMaterial(MaterialKind::kFluid, "water");
  water.fluid.bulkModulus = 2e4;
  MpmWorld w(p, bodies, {water}, unitDomain(h, 0));
  w.setColliders({colliderDesc("cup")}, {cupSoup(closed)});
  CupPool out;
  if (!runUntil(w, 1.5)) return out;
  const ParticleArrays& r = w.particles();
  float top = 0.0f;
  for (float y : r.y) top = std::max(top, y);
  const double surface = top + 0.5 * h, rho0 = water.density, g = 9.81;
  const double K = water.fluid.bulkModulus, gamma = water.fluid.gamma;
  double sum = 0.0;
  std::vector<int> slab(100, 0);
  for (std::size_t i = 0; i < r.size(); ++i) {
    const double x = rho0 * g * (surface - r.y[i]) / K;
    const double tait = K / gamma * (std::pow(1.0 + (gamma - 1.0) * x, gamma / (gamma - 1.0)) - 1.0);
    const double err = (w.pressure(std::int32_t(i)) - tait) / (rho0 * g);
    sum += err * err;
    ++slab[std::size_t(std::clamp(int(r.y[i] / h), 0, 99))];
  }
  out.headRms = std::sqrt(sum / double(r.size()));
  out.crowdedLayers = double(*std::max_element(slab.begin(), slab.end())) / (across * across);
  return out;
}

// Water at rest in a mesh-collider cup has hydrostatic pressure: head RMS error within 20 % of
// the depth in the open cup (measured 0.0117 m) and 25 % in the closed one (0.0146 m). The
// bounds allow for the surface being taken at the highest particle (a partial top layer puts it
// up to a spacing above the mean surface: about 0.006 m of the error), for the pool still moving
// a little at 1.5 s, and for the lowest particles crowding onto the collider's surface: the
// projection puts a particle found inside on it (a sheet's shell is 0.75 dx thick), above
// where the grid holds the water, so 2.1 (open) and 2.3 (closed) layers' worth sit in one slab
// a spacing thick. Before J-bar and collider sides the errors were 0.107 and 0.103 m: the
// water's lowest layers sank through the sheet's far side (or the thin floor's lower half,
// whose normals point down) and single particles' J wandered.
TEST(MpmWorld, APoolInAMeshColliderCupHasHydrostaticPressure) {
  const double depth = 0.08;
  const CupPool open = cupPool(false), closed = cupPool(true);
  std::printf("pool in a mesh cup: pressure head RMS error %.4g m open, %.4g m closed (depth %.3g m); "
              "most crowded slab %.2f and %.2f layers\n",
              open.headRms, closed.headRms, depth, open.crowdedLayers, closed.crowdedLayers);
  EXPECT_LT(open.headRms, 0.2 * depth);
  EXPECT_LT(closed.headRms, 0.25 * depth);
}

// J-bar and the collider side field are paid for only by scenes that have a fluid or a mesh
// collider: the plan's p2g says so, and its buffers grow by exactly 2 floats a node with a
// fluid (fluid mass, m J) and 3 more with a collider (the mass moment), the node count read
// from grid_update's description (n^3 = N nodes).
TEST(MpmWorld, JBarAndTheColliderSideFieldCostOnlyTheScenesThatHaveThem) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.45, 0.3, 0.45), 5, 5, 5, h, 0);
  Material water = makeMaterial(MaterialKind::kFluid, "water");
  MpmWorld solid(p, bodies, {elastic(5e4)}, unitDomain(h, 0));
  MpmWorld fluid(p, bodies, {water}, unitDomain(h, 0));
  MpmWorld cup(p, bodies, {water}, unitDomain(h, 0));
  cup.setColliders({colliderDesc("sheet")}, {sheetSoup(0.3, 0.7, 0.2, 0.3, 0.7)});
  const auto entry = [](const MpmWorld& w, const std::string& name) {
    for (const PlanEntry& e : w.planAll())
      if (e.name == name) return e;
    ADD_FAILURE() << "no pass " << name;
    return PlanEntry{};
  };
  const std::string grid = entry(solid, "grid_update").touches;
  const std::size_t at = grid.find("^3 = ");
  ASSERT_NE(at, std::string::npos) << grid;
  const std::size_t nodes = std::stoul(grid.substr(at + 5));
  EXPECT_EQ(entry(solid, "p2g").reason.find("J-bar"), std::string::npos);
  EXPECT_NE(entry(fluid, "p2g").reason.find("J-bar"), std::string::npos);
  EXPECT_EQ(entry(fluid, "p2g").reason.find("side field"), std::string::npos);
  EXPECT_NE(entry(cup, "p2g").reason.find("side field"), std::string::npos);
  EXPECT_EQ(entry(fluid, "p2g").heldBytes - entry(solid, "p2g").heldBytes, 2 * sizeof(float) * nodes);
  EXPECT_EQ(entry(cup, "p2g").heldBytes - entry(fluid, "p2g").heldBytes, 3 * sizeof(float) * nodes);
}

// Water thrown down at a sheet at 9 m/s (8^3 particles, substeps auto, the sheet from wall to
// wall) splashes on it, hits the walls, and stays above the sheet and finite for 0.3 s. A hard
// case for the sheet's boundary: a projection that kept particles half a spacing (or one) from
// the sheet instead of at the shell's surface 0.75 dx from it inverted J at 8-9 m/s (bf88f1c
// managed 10 m/s, not 12).
TEST(MpmWorld, WaterThrownHardAtASheetStaysAboveItAndFinite) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  BodyInit down;
  down.velocity = Vec3(0.0, -9.0, 0.0);
  addBox(p, bodies, Vec3(0.465, 0.43, 0.465), 8, 8, 8, h, 0, down);
  MpmWorld w(p, bodies, {makeMaterial(MaterialKind::kFluid, "water")}, unitDomain(h, 0));
  w.setColliders({colliderDesc("sheet")}, {sheetSoup(-0.1, 1.1, 0.4, -0.1, 1.1)});  // wall to wall
  int below = 0;
  float lowest = 1.0f;
  while (w.time() < 0.3) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    for (float y : w.particles().y) lowest = std::min(lowest, y);
  }
  for (float y : w.particles().y) below += y < 0.4f;
  std::printf("water thrown at a sheet: %d of %zu below it at the end, lowest ever %.4f m\n", below,
              w.particles().size(), lowest);
  EXPECT_EQ(below, 0);
  EXPECT_GT(lowest, 0.4f);
}

// Water sketched into a collider's shell (its lowest layer 5 mm above a sheet whose shell
// reaches 15 mm) starts on the shell's surface, before the first step: the step that moves it
// there is not counted as energy growth (it was, at step 0: lifting the water out of the shell
// added potential energy in a closed system), and after 0.2 s every particle is above the shell.
TEST(MpmWorld, WaterSketchedIntoAColliderStartsOnItsSurface) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.405, 0.405, 0.405), 10, 6, 10, h, 0);
  MpmWorld w(p, bodies, {makeMaterial(MaterialKind::kFluid, "water")}, unitDomain(h, 0));
  w.setColliders({colliderDesc("sheet")}, {sheetSoup(-0.1, 1.1, 0.4, -0.1, 1.1)});
  while (w.time() < 0.2) ASSERT_TRUE(w.step()) << w.guard().message();
  float lowest = 1.0f;
  for (float y : w.particles().y) lowest = std::min(lowest, y);
  EXPECT_GE(lowest, 0.4f + 0.015f - 1e-4f);
}

// A keyframed collider moves what rests on it: a box whose top rises from 0.2 to 0.5 m over
// 1 s (0.3 m/s) lifts the block set on it by the same 0.3 m (bottom on the top within the
// boundary's reach, 0-2.5 cm), and the collider's velocity enters the boundary, so the block
// rides up with it (at 0.5 s already half-way) instead of sinking into the rising top.
TEST(MpmWorld, AKeyframedColliderLiftsTheBlockOnIt) {
  MeshCollider lift = colliderDesc("lift");
  ColliderKeyframe k0, k1;
  k0.t = 0.0;
  k1.t = 1.0;
  k1.position = Vec3(0.0, 0.3, 0.0);
  lift.keyframes = {k0, k1};
  const std::vector<TriangleSoup> mesh = {boxSoup(Vec3(0.3, 0.0, 0.3), Vec3(0.7, 0.2, 0.7))};
  const Drop half = dropBlock({lift}, mesh, 0.5, 0.21);
  EXPECT_GT(half.lowest, 0.35 - 0.002);
  EXPECT_LT(half.lowest, 0.35 + 0.025);
  const Drop top = dropBlock({lift}, mesh, 1.3, 0.21);
  EXPECT_GT(top.lowest, 0.5 - 0.002);
  EXPECT_LT(top.lowest, 0.5 + 0.025);
  EXPECT_NEAR(top.centre - top.lowest, 0.035, 0.005);
}

namespace {

// An 8^3 elastic block (h = 1 cm) on the ground at x 0.4-0.47, and a 3 x 10 x 12 plate of
// particles carried as a tool whose first layer is at x = plateX.
struct BlockAndPlate {
  std::unique_ptr<MpmWorld> w;
  int tool = -1;
};
BlockAndPlate blockAndPlate(double plateX) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.4, 0.005, 0.45), 8, 8, 8, h, 0);
  BlockAndPlate s;
  s.w = std::make_unique<MpmWorld>(p, bodies, std::vector<Material>{elastic(1e5)}, unitDomain(h, 0));
  ParticleArrays plate;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 10; ++j)
      for (int k = 0; k < 12; ++k) plate.push(float(plateX + i * h), float(0.005 + j * h), float(0.435 + k * h), 9, 0);
  s.tool = s.w->addBody(plate, BodyRange{}, /*kinematic=*/true);
  return s;
}

}  // namespace

// A tool (a carried body driven step by step, as tool strokes are) pushes material and is not
// pushed back: a plate moving at 0.5 m/s along +x for 0.6 s reaches every target exactly, and
// the block in its way (4 cm ahead; the plate's held nodes reach 1.5 dx = 3 cm beyond its
// particles, so contact starts after about 0.02 m of travel) ends up moving at the plate's
// speed (within 0.1 m/s) and pushed by the plate's travel less that gap: 0.3 - 0.02 m, within
// 3 cm (the gap is known to one grid cell).
TEST(MpmWorld, ACarriedToolPushesABlockAtItsOwnSpeedAndIsNotPushedBack) {
  BlockAndPlate setup = blockAndPlate(0.33);
  MpmWorld& w = *setup.w;
  const int tool = setup.tool;
  const double x0 = w.pose(0).centre.x();
  Vec3 target = w.pose(tool).centre;
  const double speed = 0.5, dt = w.dt();
  const int steps = int(std::lround(0.6 / dt));
  for (int s = 0; s < steps; ++s) {
    target.x() += speed * dt;
    w.setKinematicTarget(tool, target);
    ASSERT_TRUE(w.step()) << w.guard().message();
    ASSERT_LT((w.pose(tool).centre - target).norm(), 1e-5);
  }
  EXPECT_NEAR(w.velocity(0).x(), speed, 0.1);
  EXPECT_NEAR(w.pose(0).centre.x() - x0, speed * 0.6 - 0.02, 0.03);
}

// `substeps auto` follows a carried body's speed too: a tool holds the nodes it touches at its
// own velocity, so material there moves that fast. A tool carried 0.25 m in one step of 1/60 s
// (15 m/s) needs at least dt v / (C dx) substeps by the velocity bound (C = velocityCourant);
// before, only dynamic particles counted, and the soft block of mpm_tool_sudden inverted within
// four substeps.
TEST(MpmWorld, SubstepsAutoFollowsACarriedToolsSpeed) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.4, 0.005, 0.45), 4, 4, 4, h, 0);
  MpmParams q = unitDomain(h, 0);
  MpmWorld w(p, bodies, {elastic(1e4)}, q);
  const int still = w.substepsForNextStep();
  ParticleArrays tool;
  tool.push(0.2f, 0.05f, 0.5f, 9, 0);
  const int b = w.addBody(tool, BodyRange{}, /*kinematic=*/true);
  w.setKinematicTarget(b, w.pose(b).centre + Vec3(0.25, 0.0, 0.0));
  const double v = 0.25 / q.dt;
  const int needed = int(std::ceil(q.dt * v / (q.velocityCourant * w.dx())));
  EXPECT_GE(w.substepsForNextStep(), needed);
  EXPECT_LT(still, needed);  // the wave bound alone would allow fewer
}

// A collider mesh far larger than the domain does not exhaust memory: its distance field's
// voxel grows until the narrow band fits the budget (ColliderSdf::kMaxBandVoxels = 2e7 by
// default, 0.5 GB at most; 1e6 here to keep the test fast): a 10 m x 10 m sheet, which at
// dx/2 = 1 cm would need 7e6 band voxels, gets sqrt(100 m^2 x 7 / 1e6) = 2.6 cm voxels,
// setColliders says so, and the block still rests on it (bottom above 0.38 m after 0.5 s).
TEST(MpmWorld, AHugeColliderMeshGetsACoarserFieldAndAWarningNotAnAllocationFailure) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  addBox(p, bodies, Vec3(0.465, 0.43, 0.465), 8, 8, 8, h, 0);
  MpmParams q = unitDomain(h, 0);
  MpmWorld w(p, bodies, {elastic(1e5)}, q);
  const std::vector<std::string> none = w.setColliders({colliderDesc("sheet")}, {sheetSoup(0.3, 0.7, 0.4, 0.3, 0.7)}, 1e6);
  EXPECT_TRUE(none[0].empty()) << none[0];
  const std::vector<std::string> notes = w.setColliders({colliderDesc("plain")}, {sheetSoup(-5, 5, 0.4, -5, 5)}, 1e6);
  ASSERT_EQ(notes.size(), 1u);
  EXPECT_NE(notes[0].find("collider 'plain'"), std::string::npos) << notes[0];
  EXPECT_NE(notes[0].find("voxels instead"), std::string::npos) << notes[0];
  const ColliderSdf big(sheetSoup(-5, 5, 0.4, -5, 5), 1.0, 0.01, 0.03, 1e6);
  EXPECT_NEAR(big.voxel(), std::sqrt(100.0 * 7.0 / 1e6), 1e-9);
  EXPECT_NEAR(big.area(), 100.0, 1e-9);
  for (int s = 0; s < 30; ++s) ASSERT_TRUE(w.step()) << w.guard().message();
  double lowest = 1e9;
  for (float y : w.particles().y) lowest = std::min(lowest, double(y));
  EXPECT_GT(lowest, 0.38);
}

// A tool pushes and never pulls (PhyVR's one-sided tool boundary): a plate set against a block's
// face and carried away from it at 0.5 m/s for 0.3 s leaves the block where it was (its centre
// moves less than 5 mm; a sticky plate drags it along by about 0.15 m), while the same plate
// carried into the block pushes it (the test above).
TEST(MpmWorld, ACarriedToolMovingAwayDoesNotDragTheMaterialItTouched) {
  BlockAndPlate setup = blockAndPlate(0.37);
  MpmWorld& w = *setup.w;
  const int tool = setup.tool;
  for (int s = 0; s < 10; ++s) ASSERT_TRUE(w.step()) << w.guard().message();  // settle against the plate
  const double x0 = w.pose(0).centre.x();
  Vec3 target = w.pose(tool).centre;
  for (int s = 0; s < 18; ++s) {
    target.x() -= 0.5 * w.dt();
    w.setKinematicTarget(tool, target);
    ASSERT_TRUE(w.step()) << w.guard().message();
  }
  EXPECT_NEAR(w.pose(0).centre.x(), x0, 0.005);
}

namespace physketch::mpm {
namespace {

// A tool's own friction (a tool stroke with friction=mu: Material::FrictionRule::kOwn) decides its
// held nodes' Coulomb friction, not the touched material's. In zero gravity a plate comes down onto
// a floating 8^3 elastic block (0.1 m/s) while sliding along +x (0.3 m/s); the contact normal is
// vertical but for the plate's edges (MPM's mass-gradient normal tilts there), so friction is what
// carries the block along x: measured 4.5 mm for friction 0 and 45 mm for friction 2; with the
// block's own friction (0.5) deciding, both moved 20 mm. A factor 4 between them fails that.
TEST(MpmWorld, AToolsOwnFrictionDecidesWhatItDrags) {
  const auto dragged = [](double mu) {
    const double h = 0.01;
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    addBox(p, bodies, Vec3(0.4, 0.3, 0.4), 8, 8, 8, h, 0);
    Material tool = elastic(1e5);
    tool.name = "tool";
    tool.staticFriction = tool.dynamicFriction = mu;
    tool.frictionRule = Material::FrictionRule::kOwn;
    MpmParams q = unitDomain(h, 0);
    q.gravity = Vec3::Zero();
    MpmWorld w(p, bodies, {elastic(1e5), tool}, q);
    ParticleArrays plate;
    for (int i = 0; i < 6; ++i)
      for (int j = 0; j < 2; ++j)
        for (int k = 0; k < 6; ++k) plate.push(float(0.415 + i * h), float(0.405 + j * h), float(0.415 + k * h), 9, 1);
    const int b = w.addBody(plate, BodyRange{}, /*kinematic=*/true);
    const double x0 = w.pose(0).centre.x();
    Vec3 target = w.pose(b).centre;
    for (int s = 0; s < 15; ++s) {
      target += w.dt() * Vec3(0.3, -0.1, 0.0);
      w.setKinematicTarget(b, target);
      EXPECT_TRUE(w.step()) << w.guard().message();
    }
    return w.pose(0).centre.x() - x0;
  };
  const double none = dragged(0.0), grip = dragged(2.0);
  std::printf("block dragged %.5f m (friction 0), %.5f m (friction 2)\n", none, grip);
  EXPECT_GT(grip, 4.0 * std::abs(none));
  EXPECT_GT(grip, 0.03);
}


// A cup sketched as a fixed body: a floor and four walls one voxel thick around a 10 x 10-voxel
// interior (h = 1 cm), with 8 x 5 x 8 voxels of water set in it. Returns the water's lowest
// particle above the floor's top face, its centre's height above that face, and its width
// across x and z (particle centre to centre), after 1 s at rest.
struct FixedCupPool {
  double lowest = 1e9, centre = 1e9, widthX = 0.0, widthZ = 0.0;
};
FixedCupPool fixedCupPool() {
  const double h = 0.01;
  const Vec3 corner(0.4, 0.2, 0.4);
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  BodyRange cup;
  cup.first = 0;
  cup.stroke = 0;
  cup.init.fixed = true;
  for (int i = 0; i < 12; ++i)
    for (int j = 0; j < 9; ++j)
      for (int k = 0; k < 12; ++k)
        if (j == 0 || i == 0 || i == 11 || k == 0 || k == 11)
          p.push(float(corner.x() + i * h), float(corner.y() + j * h), float(corner.z() + k * h), 0, 1);
  cup.count = std::int32_t(p.size());
  bodies.push_back(cup);
  const std::size_t first = p.size();
  addBox(p, bodies, corner + Vec3(2 * h, h, 2 * h), 8, 5, 8, h, 0);
  Material water = makeMaterial(MaterialKind::kFluid, "water");
  MpmWorld w(p, bodies, {water, elastic(5e5)}, unitDomain(h, 0));
  FixedCupPool out;
  if (!runUntil(w, 1.0)) return out;
  const ParticleArrays& r = w.particles();
  const double floorTop = corner.y() + 0.5 * h;
  double lo[3] = {1e9, 1e9, 1e9}, hi[3] = {-1e9, -1e9, -1e9}, sumY = 0.0;
  for (std::size_t i = first; i < r.size(); ++i) {
    const double x[3] = {r.x[i], r.y[i], r.z[i]};
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], x[a]), hi[a] = std::max(hi[a], x[a]);
    sumY += x[1];
  }
  out.lowest = lo[1] - floorTop;
  out.centre = sumY / double(r.size() - first) - floorTop;
  out.widthX = hi[0] - lo[0];
  out.widthZ = hi[2] - lo[2];
  return out;
}

// The water spreads to the cup's walls and floor: its particles span the 10 cm interior to
// within half a voxel of each wall (measured 9.5 cm; the wall's faces, not its voxel centres,
// bound it), its lowest sits on the floor's face (within a quarter voxel; measured 0), and its
// centre is half the depth that its volume, 320 voxels over the 100-voxel floor, fills (1.6
// cm), within -1 voxel (the lowest layer crowds onto the floor's face: measured 0.87 cm) and
// +1/2 voxel. When the cup held every grid node its particles' stencils touch, as sticky, the
// water stood 7 cm wide and 2.5 cm high and never moved; none of it may leave the interior.
TEST(MpmWorld, WaterFillsACupSketchedAsAFixedBodyToItsWalls) {
  const double h = 0.01, inside = 10 * h, depth = 320 * h / 100;
  const FixedCupPool pool = fixedCupPool();
  std::printf("water in a fixed cup: lowest %.4f m above the floor, centre %.4f m, width %.4f x %.4f m\n",
              pool.lowest, pool.centre, pool.widthX, pool.widthZ);
  EXPECT_GE(pool.lowest, -1e-4);
  EXPECT_LE(pool.lowest, 0.25 * h);
  EXPECT_GE(pool.centre, 0.5 * depth - h);
  EXPECT_LE(pool.centre, 0.5 * depth + 0.5 * h);
  for (double width : {pool.widthX, pool.widthZ}) {
    EXPECT_GE(width, inside - h);
    EXPECT_LE(width, inside + 1e-4);
  }
}

}  // namespace
}  // namespace physketch::mpm

// APIC and MLS-MPM conserve angular momentum (Jiang et al. 2015, §5.3): a particle's is
// m x_p x v_p plus its affine field's, m (B_p^T : eps) with B_p = C_p D_p, D_p = dx^2/4 I for
// quadratic B-splines, and a symmetric stress exerts no torque. Oracle: nothing outside acts on
// a block spinning about a tilted axis in zero gravity, away from every wall, so the total about
// the origin stays; for every material (water, honey, corotated and neo-Hookean jelly, sand,
// snow, clay), within 3e-6 of itself over 30 steps (float round-off; measured at most 9e-7).
// The particles' sum alone is not conserved: a spinning inviscid fluid's affine part hands its
// share to the particles as the block comes apart (water 0.34 % of the total here; the block of
// AViscousFluidResistsShearButNotRotation without viscosity: +11.8 % about z in 0.5 s, its
// affine part 0.00041 -> 0.00016 of a total 0.00256 that stays to 1e-5). A P2G with C^T for C
// (the affine transfer turning the spin's share the wrong way) fails it: drift 0.031, in the
// fluids' and in the solids' branch alike.
TEST(MpmWorld, TheParticlesAndTheirAffineFieldsKeepTheAngularMomentum) {
  const double h = 0.01;
  std::vector<Material> mats = {makeMaterial(MaterialKind::kFluid, "water"), makeMaterial(MaterialKind::kFluid, "honey"),
                                elastic(5e4), elastic(5e4, ElasticModel::kNeoHookean),
                                makeMaterial(MaterialKind::kSand, "sand"), makeMaterial(MaterialKind::kSnow, "snow"),
                                makeMaterial(MaterialKind::kPlasticine, "clay")};
  mats[1].fluid.viscosity = 50.0;
  for (const Material& m : mats) {
    MpmParams q = unitDomain(h, 0);
    q.gravity = Vec3::Zero();
    ParticleArrays p;
    std::vector<BodyRange> bodies;
    BodyInit spin;
    spin.spin = Vec3(1.0, 2.0, 4.0);
    spin.velocity = Vec3(0.1, 0.2, -0.1);
    addBox(p, bodies, Vec3(0.46, 0.46, 0.46), 8, 8, 8, h, 0, spin);
    MpmWorld w(p, bodies, {m}, q);
    const auto angular = [&] {  // the particles' sum, and their affine fields'
      const ParticleArrays& s = w.particles();
      Eigen::Vector3d L = Eigen::Vector3d::Zero(), affine = Eigen::Vector3d::Zero();
      const double d = w.dx() * w.dx() / 4.0;
      for (std::size_t i = 0; i < s.size(); ++i) {
        const Eigen::Vector3d x(s.x[i], s.y[i], s.z[i]), v(s.vx[i], s.vy[i], s.vz[i]);
        const Eigen::Matrix3d C = w.affineVelocity(i).cast<double>();
        L += s.mass[i] * x.cross(v);
        affine += (s.mass[i] * d) * Eigen::Vector3d(C(2, 1) - C(1, 2), C(0, 2) - C(2, 0), C(1, 0) - C(0, 1));
      }
      return std::pair{L, affine};
    };
    const auto [L0, affine0] = angular();
    const Eigen::Vector3d total0 = L0 + affine0;
    double drift = 0.0, particles = 0.0;
    for (int s = 0; s < 30; ++s) {
      ASSERT_TRUE(w.step()) << m.name << ": " << w.guard().message();
      const auto [L, affine] = angular();
      drift = std::max(drift, (L + affine - total0).norm() / total0.norm());
      particles = std::max(particles, (L - L0).norm() / total0.norm());
    }
    std::printf("%s spinning in zero gravity: angular momentum drift %.2g, the particles' sum alone %.2g\n",
                m.name.c_str(), drift, particles);
    EXPECT_LT(drift, 3e-6) << m.name;
    // Where the affine part carries a share (the fluids, sand), the particles' sum alone moves:
    // the case exercises it (water 3.4e-3, sand 4.0e-3, honey 2.2e-4).
    if (m.kind == MaterialKind::kFluid || m.kind == MaterialKind::kSand) {
      EXPECT_GT(particles, 1e-4) << m.name;
    }
  }
}

namespace {

// A 12^3 block (h = 1 cm) of material 0 thrown at the ground at `speed` m/s from 2 cm above it.
MpmWorld thrownBlock(const Material& m, double speed, int substeps) {
  const double h = 0.01;
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  BodyInit down;
  down.velocity = Vec3(0.0, -speed, 0.0);
  addBox(p, bodies, Vec3(0.44, 0.02, 0.44), 12, 12, 12, h, 0, down);
  return MpmWorld(p, bodies, {m}, unitDomain(h, substeps));
}

Material snow(double E, double xi) {
  Material m = makeMaterial(MaterialKind::kSnow, "pack");
  m.elastic.youngs = E;
  m.snow.hardening = xi;
  return m;
}

}  // namespace

// Snow compacted by an impact hardens (e^(xi (1 - J_p)), Stomakhin et al. 2013) within one step,
// and its wave speed with it: `substeps auto` takes the bound again after each substep and cuts
// the rest of the step finer where it no longer holds. Snow of the default E and xi thrown at
// the ground at 8 m/s: the impact's steps take more substeps than the bound at their start asks
// (the oracle: a count fixed at that start bound is stopped by the guard as the hardened snow
// outruns it: cfl, or here an inversion; the impact is in the first step, which the old choice,
// once per step, ran at that count: scenes/hard/mpm_snow_compressed stopped so, cfl at 57 m/s),
// the run goes on without a trip for 0.3 s, and it is the same on 1 and 2 threads (the cut is
// taken from the particles' state: the same bits, the same cut).
TEST(MpmWorld, SubstepsAutoCutsTheRestOfAStepFinerWhereSnowHardensWithinIt) {
  const Material pack = snow(1.4e5, 10.0);
  MpmWorld w = thrownBlock(pack, 8.0, 0);
  const int atStart = w.substepsForNextStep();
  int most = 0, grew = 0;
  tbb::task_arena two(2);
  two.execute([&] {
    while (w.time() < 0.3) {
      const int planned = w.substepsForNextStep();
      ASSERT_TRUE(w.step()) << w.guard().message();
      most = std::max(most, w.lastSubsteps());
      grew += w.lastSubsteps() > planned;
    }
  });
  std::printf("substeps auto: %d at the start, at most %d in a step, %d steps cut finer within\n", atStart, most, grew);
  EXPECT_GT(grew, 0);
  EXPECT_GT(most, atStart);
  {
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    MpmWorld single = thrownBlock(pack, 8.0, 0);
    while (single.time() < 0.3) ASSERT_TRUE(single.step()) << single.guard().message();
    EXPECT_EQ(single.stateHash(), w.stateHash()) << "1 and 2 threads differ where a step was cut finer";
  }
  MpmWorld fixed = thrownBlock(pack, 8.0, atStart);
  bool ran = true;
  while (ran && fixed.time() < 0.3) ran = fixed.step();
  ASSERT_FALSE(ran) << "snow hardened by its impact ran at the substeps its start needs";
  const GuardKind k = fixed.guard().kind;
  EXPECT_TRUE(k == GuardKind::kCfl || k == GuardKind::kInverted) << fixed.guard().message();
}

// Snow's plastic volume ratio J_p is clamped at max(1 - 10 / xi, 0.01), where its hardening
// stops at e^10 (snowClamp): snow compacted past it gives up volume without resisting, which the
// guard names (compression, in the plasticity pass, with the clamp as its bound and the
// material's hardening as the knob). Soft snow (E = 2e3 Pa) of xi = 30 (clamp 2/3) thrown at
// 15 m/s reaches it; thrown at 8 m/s its J_p falls only to 0.685, and the guard keeps quiet.
TEST(MpmWorld, TheGuardNamesSnowCompactedToItsClamp) {
  MpmWorld w = thrownBlock(snow(2e3, 30.0), 15.0, 0);
  bool ran = true;
  while (ran && w.time() < 0.3) ran = w.step();
  ASSERT_FALSE(ran);
  const GuardRecord& g = w.guard();
  EXPECT_EQ(g.kind, GuardKind::kCompression) << g.message();
  EXPECT_EQ(g.pass, "plasticity") << g.message();
  EXPECT_EQ(g.material, "pack");
  EXPECT_GE(g.particle, 0);
  EXPECT_EQ(g.body, 0);
  EXPECT_EQ(g.stroke, w.particles().stroke[std::size_t(g.particle)]);
  EXPECT_NEAR(g.bound, 1.0 - 10.0 / 30.0, 1e-6);  // float
  EXPECT_LE(g.value, g.bound);
  EXPECT_NE(g.hint.find("'hardening'"), std::string::npos) << g.message();
  // The same snow thrown at 8 m/s stays above the clamp (J_p 0.685 at least): no trip.
  MpmWorld slower = thrownBlock(snow(2e3, 30.0), 8.0, 0);
  EXPECT_TRUE(runUntil(slower, 0.3));
}

// A fixed-corotated gel (E = 5e4 Pa, c_p about 8 m/s) thrown at the ground at 15 m/s flattens
// cells to J <= 0 however short the step (the hard scene mpm_inverted_corotated: cfl 0.5, 0.25
// and 0.1 all invert), so under `substeps auto` the guard's advice is the model, not the step;
// neo-Hookean, whose pressure lambda ln J is unbounded as J -> 0, takes the same impact.
TEST(MpmWorld, AGelCrushedFasterThanItsWavesIsAdvisedTheModelNotTheStep) {
  MpmWorld w = thrownBlock(elastic(5e4), 15.0, 0);
  bool ran = true;
  while (ran && w.time() < 0.1) ran = w.step();
  ASSERT_FALSE(ran);
  EXPECT_EQ(w.guard().kind, GuardKind::kInverted) << w.guard().message();
  // The model first; the step's knob only as the fallback for a speed the step did not foresee.
  const std::string& hint = w.guard().hint;
  ASSERT_NE(hint.find("model=neohookean"), std::string::npos) << w.guard().message();
  ASSERT_NE(hint.find("'cfl'"), std::string::npos) << w.guard().message();
  EXPECT_LT(hint.find("model=neohookean"), hint.find("'cfl'")) << w.guard().message();
  MpmWorld neo = thrownBlock(elastic(5e4, ElasticModel::kNeoHookean), 15.0, 0);
  EXPECT_TRUE(runUntil(neo, 0.1));
}
