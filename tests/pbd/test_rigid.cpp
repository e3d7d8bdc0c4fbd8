// PBD rigid bodies by shape matching: free fall against the integrator's exact
// discrete solution, resting contact, rigidity, rotation extraction, determinism.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include <tbb/global_control.h>

#include "pbd/shape_matching.h"
#include "pbd/world.h"

using namespace physketch;
using namespace physketch::pbd;

namespace {

constexpr double kSpacing = 0.01;  // m: particle diameter 2r
constexpr double kRadius = 0.5 * kSpacing;

std::vector<Material> rigidMaterial(double friction = 0.5) {
  Material m;
  m.name = "rigid";
  m.density = 1000.0;
  m.friction = friction;
  return {m};
}

// Appends an nx*ny*nz lattice box with its lowest corner particle at `corner` (m).
BodyRange addBox(ParticleArrays& p, const Vec3& corner, int nx, int ny, int nz, int stroke = 0) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        const Vec3 x = corner + kSpacing * Vec3(i, j, k);
        p.push(float(x.x()), float(x.y()), float(x.z()), stroke, 0);
      }
  b.count = nx * ny * nz;
  b.stroke = stroke;
  return b;
}

// A bar tilted in the x-y plane, `len` particles long and 3x3 thick.
BodyRange addTiltedBar(ParticleArrays& p, const Vec3& start, int len, double angleRad, int stroke = 0) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  const Vec3 axis(std::cos(angleRad), std::sin(angleRad), 0.0), side(-std::sin(angleRad), std::cos(angleRad), 0.0);
  for (int i = 0; i < len; ++i)
    for (int j = -1; j <= 1; ++j)
      for (int k = -1; k <= 1; ++k) {
        const Vec3 x = start + kSpacing * (i * axis + j * side + k * Vec3::UnitZ());
        p.push(float(x.x()), float(x.y()), float(x.z()), stroke, 0);
      }
  b.count = len * 9;
  b.stroke = stroke;
  return b;
}

PbdParams params(int substeps, int iterations, double groundY = 0.0) {
  PbdParams p;
  p.dt = 1.0 / 60.0;
  p.substeps = substeps;
  p.iterations = iterations;
  p.groundY = groundY;
  p.particleRadius = kRadius;
  return p;
}

}  // namespace

TEST(ShapeMatching, ExtractRotationRecoversPolarFactor) {
  std::mt19937 rng(7);
  std::normal_distribution<double> n(0.0, 1.0);
  for (int trial = 0; trial < 50; ++trial) {
    const Quat r = Quat(n(rng), n(rng), n(rng), n(rng)).normalized();
    Mat3 B;
    for (int i = 0; i < 9; ++i) B(i / 3, i % 3) = 0.3 * n(rng);
    const Mat3 S = Mat3::Identity() + 0.5 * (B + B.transpose()) * 0.5;  // symmetric, positive definite
    const Mat3 A = r.toRotationMatrix() * S;
    const Quat got = extractRotation(A, Quat::Identity(), 200);
    EXPECT_LT((got.toRotationMatrix() - r.toRotationMatrix()).norm(), 1e-6) << "trial " << trial;
  }
}

TEST(ShapeMatching, FlatBodyKeepsWarmStartAboutFreeAxis) {
  // A planar body (all rest offsets in z = 0) gives A_pq with a zero third column:
  // the rotation about the in-plane axes is still determined, the warm start is kept otherwise.
  const Quat warm(Eigen::AngleAxisd(0.3, Vec3::UnitZ()));
  Mat3 A = warm.toRotationMatrix();
  A.col(2).setZero();
  const Quat got = extractRotation(A, warm);
  EXPECT_LT((got.toRotationMatrix() - warm.toRotationMatrix()).norm(), 1e-9);
}

TEST(RigidBody, FreeFallMatchesExactDiscreteSolution) {
  ParticleArrays p;
  const Vec3 corner(0.1, 1.5, -0.2);  // a workspace-sized drop: 1.2 m in 0.5 s
  std::vector<BodyRange> bodies{addBox(p, corner, 3, 4, 2)};
  const int substeps = 3;
  PbdWorld w(p, bodies, rigidMaterial(), params(substeps, 2, -100.0));
  const double g = 9.81, h = (1.0 / 60.0) / substeps;
  double worst = 0.0;
  for (int step = 1; step <= 30; ++step) {
    ASSERT_TRUE(w.step());
    const long n = static_cast<long>(step) * substeps;
    // Symplectic Euler: v_n = -g h n, y_n = y_0 - g h^2 n(n+1)/2.
    const double drop = g * h * h * double(n * (n + 1)) / 2.0;
    for (std::size_t i = 0; i < w.particles().size(); ++i) {
      // Tolerance 1e-4 m (2 % of the particle radius). Positions are float32:
      // near 1.5 m they resolve 0.12 um, and the PBD velocity v = (p - x)/h
      // carries each rounding divided by h (1/180 s), so 90 substeps accumulate
      // tens of um (measured 57 um). A broken integrator is off by millimetres.
      worst = std::max(worst, std::abs(double(w.particles().y[i]) - (p.y[i] - drop)));
      ASSERT_NEAR(w.particles().y[i], p.y[i] - drop, 1e-4) << "step " << step << " particle " << i;
      ASSERT_NEAR(w.particles().x[i], p.x[i], 5e-5);
      ASSERT_NEAR(w.particles().vy[i], -g * h * double(n), 2e-3);
    }
  }
  RecordProperty("max_error_m", std::to_string(worst));
}

TEST(RigidBody, RestingBoxNeitherSinksNorDriftsOverTenSeconds) {
  ParticleArrays p;
  const Vec3 corner(0.0, kRadius, 0.0);  // bottom layer touching the ground exactly
  std::vector<BodyRange> bodies{addBox(p, corner, 10, 10, 10)};
  PbdWorld w(p, bodies, rigidMaterial(), params(4, 4));
  for (int step = 0; step < 600; ++step) ASSERT_TRUE(w.step()) << w.guard().message();
  double maxDev = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    maxDev = std::max(maxDev, std::abs(double(w.particles().y[i]) - p.y[i]));
    maxDev = std::max(maxDev, std::abs(double(w.particles().x[i]) - p.x[i]));
    maxDev = std::max(maxDev, std::abs(double(w.particles().z[i]) - p.z[i]));
  }
  EXPECT_LT(maxDev, 0.05 * kRadius);
}

TEST(RigidBody, TumblingBarStaysRigidAndComesToRestLyingDown) {
  ParticleArrays p;
  std::vector<BodyRange> bodies{addTiltedBar(p, Vec3(0.0, 0.05, 0.0), 40, 0.9)};
  PbdWorld w(p, bodies, rigidMaterial(0.8), params(4, 4));
  // Rest distances from the centre of mass.
  Vec3 c0 = Vec3::Zero();
  for (std::size_t i = 0; i < p.size(); ++i) c0 += Vec3(p.x[i], p.y[i], p.z[i]);
  c0 /= double(p.size());
  std::vector<double> rest(p.size());
  for (std::size_t i = 0; i < p.size(); ++i) rest[i] = (Vec3(p.x[i], p.y[i], p.z[i]) - c0).norm();
  for (int step = 0; step < 240; ++step) {
    ASSERT_TRUE(w.step()) << w.guard().message();
    const auto& q = w.particles();
    Vec3 c = Vec3::Zero();
    for (std::size_t i = 0; i < q.size(); ++i) c += Vec3(q.x[i], q.y[i], q.z[i]);
    c /= double(q.size());
    for (std::size_t i = 0; i < q.size(); ++i) {
      const double d = (Vec3(q.x[i], q.y[i], q.z[i]) - c).norm();
      ASSERT_NEAR(d, rest[i], 0.01 * rest[i] + 1e-6) << "step " << step << " particle " << i;
    }
  }
  // After 4 s the bar has tipped over: its long axis is horizontal and it is at rest.
  const auto& q = w.particles();
  double minY = 1e9, maxY = -1e9, maxSpeed = 0.0;
  for (std::size_t i = 0; i < q.size(); ++i) {
    minY = std::min(minY, double(q.y[i]));
    maxY = std::max(maxY, double(q.y[i]));
    maxSpeed = std::max(maxSpeed, Vec3(q.vx[i], q.vy[i], q.vz[i]).norm());
  }
  EXPECT_NEAR(minY, kRadius, 0.05 * kRadius);
  EXPECT_LT(maxY - minY, 3.5 * kSpacing);  // 3 particles thick when lying flat, 40 long when upright
  EXPECT_LT(maxSpeed, 0.01);
}

TEST(RigidBody, SameResultForOneAndTwoThreadsBitwise) {
  ParticleArrays p;
  std::vector<BodyRange> bodies;
  bodies.push_back(addBox(p, Vec3(-0.3, 0.2, 0.0), 20, 20, 20, 0));  // 8000 particles: parallel chunks
  bodies.push_back(addTiltedBar(p, Vec3(0.2, 0.1, 0.0), 50, 0.7, 1));
  bodies.push_back(addBox(p, Vec3(0.0, 0.4, 0.3), 5, 5, 5, 2));
  auto run = [&](int threads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
    PbdWorld w(p, bodies, rigidMaterial(), params(4, 4));
    std::vector<std::vector<float>> states;
    for (int s = 0; s < 60; ++s) {
      w.step();
      states.push_back(w.particles().y);
      states.push_back(w.particles().x);
    }
    return states;
  };
  const auto one = run(1), two = run(2);
  ASSERT_EQ(one.size(), two.size());
  for (std::size_t s = 0; s < one.size(); ++s) ASSERT_EQ(one[s], two[s]) << "diverged at record " << s;
}

TEST(RigidBody, PlanListsOnlyPassesWithWork) {
  ParticleArrays p;
  std::vector<BodyRange> bodies{addBox(p, Vec3(0, 0.1, 0), 2, 2, 2)};
  PbdWorld w(p, bodies, rigidMaterial(), params(2, 3));
  const auto plan = w.plan();
  std::vector<std::string> names;
  for (const auto& x : plan) names.push_back(x.name);
  EXPECT_EQ(names, (std::vector<std::string>{"integrate", "shape_match", "rigid_contact", "update", "guard"}));
  EXPECT_EQ(plan[2].perStep, 2);  // once per substep
  PbdWorld empty(ParticleArrays{}, {}, rigidMaterial(), params(2, 3));
  EXPECT_TRUE(empty.plan().empty());
}

TEST(RigidBody, GuardStopsTheWorldOnExplosion) {
  ParticleArrays p;
  std::vector<BodyRange> bodies{addBox(p, Vec3(0, 0.5, 0), 2, 2, 2)};
  p.vx.assign(p.size(), 500.0f);  // faster than the 100 m/s bound
  PbdWorld w(p, bodies, rigidMaterial(), params(1, 1));
  EXPECT_FALSE(w.step());
  EXPECT_EQ(w.guard().kind, GuardKind::kExplosion);
  EXPECT_EQ(w.guard().particle, 0);
  const auto before = w.particles().x;
  EXPECT_FALSE(w.step());  // a tripped world does not step
  EXPECT_EQ(w.particles().x, before);
}
