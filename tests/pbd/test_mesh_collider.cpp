// Mesh colliders (pbd/mesh_collider.h) against oracles that share no code with them:
// closed forms for a cube and an open plane, a brute force over every triangle (projection
// onto the plane or the edges) and the generalized winding number for a torus, the first
// touch of a swept sphere with a wall in closed form and, for any segment, found by sphere
// tracing along it; keyframed poses and surface velocities from the interpolation's closed form.
#include <gtest/gtest.h>

#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "core/error.h"
#include "pbd/mesh_collider.h"

using namespace physketch;
using namespace physketch::pbd;

namespace {

constexpr double kPi = 3.14159265358979323846;

// The 12 outward triangles of the cube [-h, h]^3 (corners: bit 0 = x, 1 = y, 2 = z positive).
TriangleSoup cube(double h) {
  TriangleSoup s;
  for (int i = 0; i < 8; ++i) s.vertices.emplace_back(i & 1 ? h : -h, i & 2 ? h : -h, i & 4 ? h : -h);
  s.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  s.closed = true;
  return s;
}

// An open n x n grid of quads (two triangles each) over [-1, 1]^2 in the plane z = 0.
TriangleSoup plane(int n) {
  TriangleSoup s;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) s.vertices.emplace_back(-1 + 2.0 * i / n, -1 + 2.0 * j / n, 0);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const int a = j * (n + 1) + i, b = a + 1, c = a + n + 1, d = c + 1;
      s.triangles.push_back({a, b, d});
      s.triangles.push_back({a, d, c});
    }
  return s;
}

// A closed torus about the y axis (ring radius R, tube radius r), wound outward.
TriangleSoup torus(double R, double r, int nu, int nv) {
  TriangleSoup s;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const double u = 2 * kPi * i / nu, v = 2 * kPi * j / nv;
      s.vertices.emplace_back((R + r * std::cos(v)) * std::cos(u), r * std::sin(v), (R + r * std::cos(v)) * std::sin(u));
    }
  auto id = [nu, nv](int i, int j) { return ((i + nu) % nu) * nv + (j + nv) % nv; };
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      s.triangles.push_back({id(i, j), id(i, j + 1), id(i + 1, j + 1)});
      s.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i + 1, j)});
    }
  // Orient outward: the first face's normal must point away from its tube centre.
  const auto& t = s.triangles[0];
  const Vec3 a = s.vertices[t[0]], b = s.vertices[t[1]], c = s.vertices[t[2]];
  const Vec3 centre = (a + b + c) / 3, tube(R * centre.x() / std::hypot(centre.x(), centre.z()), 0,
                                            R * centre.z() / std::hypot(centre.x(), centre.z()));
  if ((b - a).cross(c - a).dot(centre - tube) < 0)
    for (auto& tri : s.triangles) std::swap(tri[1], tri[2]);
  s.closed = true;
  return s;
}

MeshCollider staticCollider(double scale, const Mat3& R, const Vec3& at) {
  MeshCollider c;
  c.name = "c";
  c.scale = scale;
  c.rotation = R;
  c.position = at;
  return c;
}

// Brute-force closest point of a triangle, written apart from the code under test: the
// projection onto the plane if it falls inside, else the nearest of the three edges.
Vec3 bruteClosest(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 n = (b - a).cross(c - a).normalized();
  const Vec3 proj = p - (p - a).dot(n) * n;
  const Vec3 v[3] = {a, b, c};
  bool inside = true;
  for (int k = 0; k < 3; ++k)
    if ((v[(k + 1) % 3] - v[k]).cross(proj - v[k]).dot(n) < 0) inside = false;
  if (inside) return proj;
  Vec3 best = a;
  double bestD = 1e300;
  for (int k = 0; k < 3; ++k) {
    const Vec3 e = v[(k + 1) % 3] - v[k];
    const double u = std::clamp((p - v[k]).dot(e) / e.squaredNorm(), 0.0, 1.0);
    const Vec3 q = v[k] + u * e;
    if ((p - q).norm() < bestD) bestD = (p - q).norm(), best = q;
  }
  return best;
}

// Generalized winding number (sum of signed solid angles, Van Oosterom & Strackee 1983):
// 1 inside a closed outward mesh, 0 outside.
double winding(const Vec3& p, const TriangleSoup& s) {
  double sum = 0;
  for (const auto& t : s.triangles) {
    const Vec3 a = s.vertices[t[0]] - p, b = s.vertices[t[1]] - p, c = s.vertices[t[2]] - p;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    sum += 2 * std::atan2(a.dot(b.cross(c)), la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb);
  }
  return sum / (4 * kPi);
}

struct Points {
  std::vector<float> x, y, z;
  Vec3 at(std::size_t i) const { return Vec3(x[i], y[i], z[i]); }  // the float position, exactly
};

Points randomPoints(std::size_t n, const Vec3& lo, const Vec3& hi, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  Points p;
  for (std::size_t i = 0; i < n; ++i) {
    p.x.push_back(static_cast<float>(lo.x() + (hi.x() - lo.x()) * u(rng)));
    p.y.push_back(static_cast<float>(lo.y() + (hi.y() - lo.y()) * u(rng)));
    p.z.push_back(static_cast<float>(lo.z() + (hi.z() - lo.z()) * u(rng)));
  }
  return p;
}

const Mat3 kTilt = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();

}  // namespace

// A cube of half-edge 0.3 m (file half-edge 0.15, scale 2), rotated and moved. In its frame
// the signed distance is |max(|q| - h, 0)| outside and -min(h - |q_i|) inside; the closest
// point clamps q to the box outside and moves it to the nearest face inside, the way out.
// Positions are exact floats and the mesh's corners exact, so only rounding in the pose
// separates the two: 1e-9 m.
TEST(MeshCollider, CubeContactsMatchTheClosedFormInsideAndOut) {
  const double h = 0.3, radius = 0.05, margin = 0.02, reach = radius + margin;
  const Vec3 at(0.2, 0.5, -0.1);
  ColliderSet set({staticCollider(2.0, kTilt, at)}, {cube(0.15)});
  const Points pts = randomPoints(20000, at - Vec3::Constant(0.5), at + Vec3::Constant(0.5), 1);
  std::vector<MeshContact> found;
  set.contacts(pts.x.data(), pts.y.data(), pts.z.data(), pts.x.size(), radius, margin, found);

  std::size_t k = 0, expectedCount = 0, insideCount = 0;
  for (std::size_t i = 0; i < pts.x.size(); ++i) {
    const Vec3 q = kTilt.transpose() * (pts.at(i) - at);
    const Vec3 excess = (q.cwiseAbs() - Vec3::Constant(h)).cwiseMax(0.0);
    const bool inside = (q.cwiseAbs().array() < h).all();
    Vec3 closest = q.cwiseMax(-h).cwiseMin(h), normal;
    double sd;
    int face = 0;
    if (inside) {
      (Vec3::Constant(h) - q.cwiseAbs()).minCoeff(&face);
      sd = -(h - std::abs(q[face]));
      closest[face] = q[face] > 0 ? h : -h;
      normal = Vec3::Unit(face) * (q[face] > 0 ? 1 : -1);
    } else {
      sd = excess.norm();
      normal = (q - closest).normalized();
    }
    const bool near = std::abs(sd) < reach;  // deeper inside than reach is not asked for
    const bool ambiguous = std::abs(std::abs(sd) - reach) < 1e-7;
    const bool hasContact = k < found.size() && found[k].particle == static_cast<std::int32_t>(i);
    if (ambiguous) {
      if (hasContact) ++k;
      continue;
    }
    ASSERT_EQ(hasContact, near) << "point " << i << " signed distance " << sd;
    if (!near) continue;
    ++expectedCount, insideCount += inside;
    const MeshContact& m = found[k++];
    EXPECT_EQ(m.collider, 0);
    EXPECT_NEAR(m.distance, sd, 1e-9) << "point " << i;
    // Two faces equally near (a diagonal inside the box): either way out is right.
    Vec3 sorted = Vec3::Constant(h) - q.cwiseAbs();
    std::sort(sorted.data(), sorted.data() + 3);
    if (inside && sorted[1] - sorted[0] < 1e-6) continue;
    EXPECT_LT((m.point - (kTilt * closest + at)).norm(), 1e-9) << "point " << i;
    if (std::abs(sd) > 1e-6) {
      EXPECT_LT((m.normal - kTilt * normal).norm(), 1e-6) << "point " << i;
    }
  }
  EXPECT_EQ(k, found.size()) << "contacts reported that no point asked for";
  EXPECT_GT(expectedCount, 3000u);
  EXPECT_GT(insideCount, 500u) << "the case must exercise the inside of the cube";
}

// An open plane has no inside: the normal points to the particle's side, the distance is
// positive on both sides, and beyond the border the closest point is on the border.
TEST(MeshCollider, OpenPlaneContactsMatchTheClosedForm) {
  const double radius = 0.15, margin = 0.05, reach = radius + margin;
  const Mat3 R = Eigen::AngleAxisd(0.4, Vec3(0, 1, 1).normalized()).toRotationMatrix();
  const Vec3 at(0, 1, 0);
  ColliderSet set({staticCollider(1.0, R, at)}, {plane(8)});
  Points pts = randomPoints(20000, Vec3(-1.3, -1.3, -0.3), Vec3(1.3, 1.3, 0.3), 2);
  for (std::size_t i = 0; i < pts.x.size(); ++i) {  // place them in the plane's frame
    const Vec3 w = R * pts.at(i) + at;
    pts.x[i] = static_cast<float>(w.x()), pts.y[i] = static_cast<float>(w.y()), pts.z[i] = static_cast<float>(w.z());
  }
  std::vector<MeshContact> found;
  set.contacts(pts.x.data(), pts.y.data(), pts.z.data(), pts.x.size(), radius, margin, found);
  std::size_t k = 0, below = 0, border = 0;
  for (std::size_t i = 0; i < pts.x.size(); ++i) {
    const Vec3 q = R.transpose() * (pts.at(i) - at);
    const Vec3 closest(std::clamp(q.x(), -1.0, 1.0), std::clamp(q.y(), -1.0, 1.0), 0.0);
    const double d = (q - closest).norm();
    const bool hasContact = k < found.size() && found[k].particle == static_cast<std::int32_t>(i);
    if (std::abs(d - reach) < 1e-7) {
      if (hasContact) ++k;
      continue;
    }
    ASSERT_EQ(hasContact, d < reach) << "point " << i;
    if (d >= reach) continue;
    const MeshContact& m = found[k++];
    EXPECT_NEAR(m.distance, d, 1e-9);
    EXPECT_LT((m.point - (R * closest + at)).norm(), 1e-9);
    if (d > 1e-6) {
      EXPECT_LT((m.normal - R * (q - closest) / d).norm(), 1e-6);
    }
    below += q.z() < 0, border += closest != Vec3(q.x(), q.y(), 0);
  }
  EXPECT_EQ(k, found.size());
  EXPECT_GT(below, 1000u) << "both sides of the sheet are exercised";
  EXPECT_GT(border, 500u) << "points beyond the border are exercised";
}

// A torus (non-convex, 1152 triangles, rotated and scaled): the distance equals a brute force
// over every triangle and the sign equals the winding number's verdict.
TEST(MeshCollider, TorusDistanceAndSideMatchBruteForceAndWindingNumber) {
  const TriangleSoup soup = torus(0.5, 0.2, 48, 12);
  const double scale = 0.8, reach = 0.12;
  const Vec3 at(-0.3, 0.4, 0.2);
  ColliderSet set({staticCollider(scale, kTilt, at)}, {soup});
  const Points pts = randomPoints(3000, at - Vec3::Constant(0.7), at + Vec3::Constant(0.7), 3);
  std::size_t near = 0, inside = 0;
  for (std::size_t i = 0; i < pts.x.size(); ++i) {
    const Vec3 q = kTilt.transpose() * (pts.at(i) - at) / scale;  // file coordinates
    double best = 1e300;
    Vec3 bestPoint = Vec3::Zero();
    for (const auto& t : soup.triangles) {
      const Vec3 c = bruteClosest(q, soup.vertices[t[0]], soup.vertices[t[1]], soup.vertices[t[2]]);
      if ((q - c).norm() < best) best = (q - c).norm(), bestPoint = c;
    }
    const double d = scale * best;
    const bool in = winding(q, soup) > 0.5;
    const double sd = in ? -d : d;
    MeshContact m;
    const bool got = set.closest(pts.at(i), reach, m);
    if (std::abs(d - reach) < 1e-7) continue;
    ASSERT_EQ(got, d < reach) << "point " << i << " distance " << d;
    if (!got) continue;
    ++near, inside += in;
    EXPECT_NEAR(m.distance, sd, 1e-9) << "point " << i;
    EXPECT_LT((m.point - (kTilt * (scale * bestPoint) + at)).norm(), 1e-9) << "point " << i;
    // The way out: from the particle to the surface when inside, away from it outside.
    if (d > 1e-6) {
      EXPECT_GT(m.normal.dot(pts.at(i) - m.point) * (in ? -1 : 1), 0.999 * d);
    }
  }
  EXPECT_GT(near, 400u);
  EXPECT_GT(inside, 100u);
}

// Fixed chunks: the same contacts, in the same order, for 1 and 2 threads.
TEST(MeshCollider, ContactsAreTheSameForOneAndTwoThreads) {
  ColliderSet set({staticCollider(1.0, kTilt, Vec3::Zero())}, {torus(0.5, 0.2, 64, 16)});
  const Points pts = randomPoints(30000, Vec3::Constant(-0.8), Vec3::Constant(0.8), 4);
  std::vector<MeshContact> one, two;
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    set.contacts(pts.x.data(), pts.y.data(), pts.z.data(), pts.x.size(), 0.05, 0.01, one);
  }
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 2);
    set.contacts(pts.x.data(), pts.y.data(), pts.z.data(), pts.x.size(), 0.05, 0.01, two);
  }
  ASSERT_EQ(one.size(), two.size());
  ASSERT_GT(one.size(), 1000u);
  for (std::size_t k = 0; k < one.size(); ++k) {
    EXPECT_EQ(one[k].particle, two[k].particle);
    EXPECT_EQ(one[k].triangle, two[k].triangle);
    EXPECT_EQ(one[k].distance, two[k].distance);
    EXPECT_EQ(one[k].point, two[k].point);
  }
}

namespace {

// A wall one triangle thick: the quad x = 0, |y|, |z| <= 1 (two triangles, open).
TriangleSoup wall() {
  TriangleSoup s;
  s.vertices = {Vec3(0, -1, -1), Vec3(0, 1, -1), Vec3(0, 1, 1), Vec3(0, -1, 1)};
  s.triangles = {{0, 1, 2}, {0, 2, 3}};
  return s;
}

}  // namespace

// A sphere of radius r moving along +x at 2 r, 20 r and 200 r per substep towards the wall
// touches it when its centre reaches x = -r: fraction (-r - x0) / dx, normal -x. Started
// against the wall (overlapping), only the centre crossing x = 0 counts. Moving away, or
// passing beside the wall, is no hit.
TEST(MeshCollider, SweepCatchesAThinWallAtTwoAndTwentyRadiiPerSubstep) {
  const double r = 0.01;
  ColliderSet set({staticCollider(1.0, Mat3::Identity(), Vec3::Zero())}, {wall()});
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0, 1);
  for (double speed : {2.0, 20.0, 200.0}) {
    for (int trial = 0; trial < 200; ++trial) {
      const double dx = speed * r;
      const double x0 = -r - u(rng) * dx;  // clear of the wall, reaching it within the substep
      const Vec3 from(x0, -0.5 + u(rng), -0.5 + u(rng));
      // Sideways by up to 0.2 m: the touch stays inside the 2 m wall.
      const Vec3 lateral(0, 0.4 * (u(rng) - 0.5) * std::min(1.0, dx), 0.4 * (u(rng) - 0.5) * std::min(1.0, dx));
      const SweepHit hit = set.sweep(from, from + Vec3(dx, 0, 0) + lateral, r);
      ASSERT_TRUE(hit.hit) << "speed " << speed << " trial " << trial;
      EXPECT_NEAR(hit.fraction, (-r - x0) / dx, 1e-9);
      EXPECT_NEAR(hit.centre.x(), -r, 1e-9);
      EXPECT_LT((hit.normal - Vec3(-1, 0, 0)).norm(), 1e-12);
    }
    // Overlapping at the start (centre 0.4 r from the wall), moving through it.
    const SweepHit through = set.sweep(Vec3(-0.4 * r, 0.2, 0.1), Vec3(-0.4 * r + speed * r, 0.2, 0.1), r);
    ASSERT_TRUE(through.hit);
    EXPECT_NEAR(through.fraction, 0.4 / speed, 1e-9);
    EXPECT_FALSE(set.sweep(Vec3(-0.4 * r, 0, 0), Vec3(-0.4 * r - speed * r, 0, 0), r).hit) << "moving away";
    EXPECT_FALSE(set.sweep(Vec3(-r, 1 + 1.5 * r, 0), Vec3(speed * r, 1 + 1.5 * r, 0), r).hit) << "beside the wall";
  }
}

// What the solver will do with a hit: stop at the touching centre. A particle flying at
// 20 radii per substep for 30 substeps never gets past the wall; without the sweep it would.
TEST(MeshCollider, AParticleStoppedBySweepsNeverCrossesTheWall) {
  const double r = 0.01;
  ColliderSet set({staticCollider(1.0, Mat3::Identity(), Vec3::Zero())}, {wall()});
  for (double speed : {2.0, 20.0}) {
    Vec3 x(-0.137, 0.3, -0.2);
    const Vec3 step(speed * r, 0.001, 0);
    bool stopped = false;
    for (int s = 0; s < 30 && !stopped; ++s) {
      const SweepHit hit = set.sweep(x, x + step, r);
      x = hit.hit ? hit.centre : Vec3(x + step);
      stopped = hit.hit;
      ASSERT_LE(x.x(), -r + 1e-9) << "crossed at substep " << s << ", speed " << speed;
    }
    EXPECT_TRUE(stopped);
  }
}

// Any segment against the torus: the first touch equals sphere tracing along the segment with
// the brute-force distance (the BVH cast must report every triangle the sphere can reach, and
// faces, edges and corners must all be caught). Grazing paths are left out.
TEST(MeshCollider, SweepMatchesSphereTracingWithBruteForceDistance) {
  const TriangleSoup soup = torus(0.5, 0.2, 24, 8);  // coarse: many edge and corner hits
  ColliderSet set({staticCollider(1.0, Mat3::Identity(), Vec3::Zero())}, {soup});
  auto distance = [&soup](const Vec3& p) {
    double best = 1e300;
    for (const auto& t : soup.triangles)
      best = std::min(best, (p - bruteClosest(p, soup.vertices[t[0]], soup.vertices[t[1]], soup.vertices[t[2]])).norm());
    return best;
  };
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> u(-1, 1);
  const double r = 0.03;
  int hits = 0, misses = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const Vec3 from(0.8 * u(rng), 0.35 * u(rng), 0.8 * u(rng));
    const Vec3 to = from + 0.5 * Vec3(u(rng), u(rng), u(rng));
    if (distance(from) <= r * 1.01 || winding(from, soup) > 0.5) continue;  // start clear and outside
    // Sphere tracing: the distance is 1-Lipschitz, so stepping by (distance - r) never steps
    // past the first touch. A path that creeps along the surface without converging grazes
    // it and is left out.
    const double len = (to - from).norm();
    double t = 0, first = -1;
    bool grazing = true;
    for (int it = 0; it < 20000; ++it) {
      const double gap = distance(from + t * (to - from)) - r;
      if (gap < 1e-12) {
        first = t, grazing = false;
        break;
      }
      t += gap / len;
      if (t > 1) {
        grazing = false;
        break;
      }
    }
    if (grazing) continue;
    const SweepHit hit = set.sweep(from, to, r);
    ASSERT_EQ(hit.hit, first >= 0) << "trial " << trial;
    if (!hit.hit) {
      ++misses;
      continue;
    }
    ++hits;
    EXPECT_NEAR(hit.fraction, first, 1e-6) << "trial " << trial;
    EXPECT_NEAR(distance(hit.centre), r, 1e-6) << "trial " << trial;
  }
  EXPECT_GT(hits, 40);
  EXPECT_GT(misses, 40);
}

namespace {

// Keyframes at t = 0.5 and 1.5: position p0 -> p1, rotation Ra -> Rz(1.2) Ra. The closed
// form between them: p(t) = p0 + u (p1 - p0), R(t) = Rz(1.2 u) Ra, u = t - 0.5 (slerp of a
// rotation about a fixed axis turns at a constant rate about that axis).
const Vec3 kP0(0.1, 0.2, 0.3), kP1(0.5, -0.1, 0.7);
const Mat3 kRa = Eigen::AngleAxisd(0.3, Vec3(1, 0, 1).normalized()).toRotationMatrix();
constexpr double kTurn = 1.2;

Mat3 rotZ(double a) { return Eigen::AngleAxisd(a, Vec3::UnitZ()).toRotationMatrix(); }
Vec3 posAt(double t) { return kP0 + std::clamp(t - 0.5, 0.0, 1.0) * (kP1 - kP0); }
Mat3 rotAt(double t) { return rotZ(kTurn * std::clamp(t - 0.5, 0.0, 1.0)) * kRa; }

MeshCollider keyframed() {
  MeshCollider c;
  c.name = "mover";
  c.keyframes.push_back({0.5, kP0, kRa, 1});
  c.keyframes.push_back({1.5, kP1, rotZ(kTurn) * kRa, 2});
  return c;
}

}  // namespace

// Poses at both ends of a substep and the surface velocity of a material point. The point
// at x at t1 was at p(t0) + Rz(-1.2 h)(x - p(t1)) at t0 (rigid motion about a fixed axis), so
// the substep velocity is exact to rounding; it also agrees with the instantaneous
// v + w x (x - p) at the substep's middle to O(h^2) (bound: |w|^2 |x - p| h^2 / 24 + slack).
TEST(MeshCollider, KeyframedPoseAndSurfaceVelocityMatchTheInterpolationClosedForm) {
  ColliderSet set({keyframed()}, {cube(0.1)});
  EXPECT_TRUE(set.moving(0));
  const double t0 = 0.8, h = 0.01, t1 = t0 + h;
  set.setSubstep(t0, t1);
  EXPECT_LT((set.startPose(0).position - posAt(t0)).norm(), 1e-12);
  EXPECT_LT((set.endPose(0).position - posAt(t1)).norm(), 1e-12);
  EXPECT_LT((set.startPose(0).rotation - rotAt(t0)).norm(), 1e-12);
  EXPECT_LT((set.endPose(0).rotation - rotAt(t1)).norm(), 1e-12);

  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  for (int k = 0; k < 50; ++k) {
    const Vec3 x = posAt(t1) + Vec3(u(rng), u(rng), u(rng));
    const Vec3 before = posAt(t0) + rotZ(-kTurn * h) * (x - posAt(t1));
    const Vec3 v = set.surfaceVelocity(0, x);
    EXPECT_LT((v - (x - before) / h).norm(), 1e-9);
    const double tm = t0 + h / 2;
    const Vec3 xm = posAt(tm) + rotZ(-kTurn * h / 2) * (x - posAt(t1));
    const Vec3 instantaneous = (kP1 - kP0) + (kTurn * Vec3::UnitZ()).cross(xm - posAt(tm));
    EXPECT_LT((v - instantaneous).norm(), kTurn * kTurn * 0.6 * h * h / 24 + 1e-9);
  }

  // Contacts use the end pose: a point 0.05 m out of the moved cube's +x face.
  const Vec3 probe = posAt(t1) + rotAt(t1) * Vec3(0.15, 0.02, -0.03);
  MeshContact m;
  ASSERT_TRUE(set.closest(probe, 0.1, m));
  EXPECT_NEAR(m.distance, 0.05, 1e-9);
  EXPECT_LT((m.normal - rotAt(t1) * Vec3::UnitX()).norm(), 1e-9);

  // Held after the last keyframe: the poses agree and nothing moves.
  set.setSubstep(2.0, 2.1);
  EXPECT_LT((set.endPose(0).position - kP1).norm(), 1e-12);
  EXPECT_EQ(set.surfaceVelocity(0, Vec3(1, 2, 3)), Vec3::Zero());
}

// A wall moving at 20 radii per substep catches a particle at rest: in the wall's frame the
// particle comes at it. The wall (turned half a turn about y, so its frame is not the world's)
// moves from x = 0 at t = 0 to x = 0.2 = 20 r at t = 1; the substep is [0, 1]. The resting
// centre at x = 0.015 is touched when 0.2 t = 0.015 - r, and at the end pose that contact
// sits at x = 0.2 + r: the wall carries the particle.
TEST(MeshCollider, AMovingWallCatchesAParticleAtRest) {
  const double r = 0.01;
  MeshCollider c;
  c.name = "pusher";
  c.keyframes.push_back({0.0, Vec3::Zero(), Eigen::AngleAxisd(kPi, Vec3::UnitY()).toRotationMatrix(), 1});
  c.keyframes.push_back({1.0, Vec3(0.2, 0, 0), Eigen::AngleAxisd(kPi, Vec3::UnitY()).toRotationMatrix(), 2});
  ColliderSet set({c}, {wall()});
  set.setSubstep(0.0, 1.0);
  const Vec3 rest(0.015, 0.1, 0.2);
  const SweepHit hit = set.sweep(rest, rest, r);
  ASSERT_TRUE(hit.hit);
  EXPECT_NEAR(hit.fraction, (0.015 - r) / 0.2, 1e-9);
  EXPECT_LT((hit.centre - Vec3(0.2 + r, 0.1, 0.2)).norm(), 1e-9);
  EXPECT_LT((hit.normal - Vec3::UnitX()).norm(), 1e-9);
  EXPECT_LT((set.surfaceVelocity(0, hit.centre) - Vec3(0.2, 0, 0)).norm(), 1e-9);
}

TEST(MeshCollider, CallerBugsAreRuntimeErrors) {
  EXPECT_THROW(ColliderSet({staticCollider(1.0, Mat3::Identity(), Vec3::Zero())}, {}), RuntimeError);
  TriangleSoup bad = cube(0.1);
  bad.triangles[3][1] = 8;
  EXPECT_THROW(ColliderSet({staticCollider(1.0, Mat3::Identity(), Vec3::Zero())}, {bad}), RuntimeError);
  EXPECT_THROW(ColliderSet({staticCollider(0.0, Mat3::Identity(), Vec3::Zero())}, {cube(0.1)}), RuntimeError);
  ColliderSet ok({staticCollider(1.0, Mat3::Identity(), Vec3::Zero())}, {cube(0.1)});
  EXPECT_THROW(ok.setSubstep(1.0, 0.5), RuntimeError);
}
