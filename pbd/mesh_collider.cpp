// Mesh colliders (pbd/mesh_collider.h): Bullet's BVH finds the triangles near a query, our
// double-precision tests answer it. The only translation unit that includes Bullet.
#include "pbd/mesh_collider.h"

#include <algorithm>
#include <array>
#include <cfloat>
#include <cmath>
#include <limits>
#include <map>
#include <string>
#include <utility>

#include <BulletCollision/CollisionShapes/btBvhTriangleMeshShape.h>
#include <BulletCollision/CollisionShapes/btTriangleCallback.h>
#include <BulletCollision/CollisionShapes/btTriangleIndexVertexArray.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.h"

namespace physketch::pbd {
namespace {

// Where on a triangle (a, b, c) its closest point to a query lies: the feature whose
// pseudonormal decides inside and outside.
enum class Feature : std::uint8_t { kVertexA, kVertexB, kVertexC, kEdgeAB, kEdgeBC, kEdgeCA, kFace };

struct ClosestOnTriangle {
  Vec3 point;
  Feature feature;
};

// Closest point of triangle (a, b, c) to p by its Voronoi regions (Ericson 2005, "Real-Time
// Collision Detection" §5.1.5). A zero-area triangle falls through to its edges.
ClosestOnTriangle closestOnTriangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return {a, Feature::kVertexA};
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return {b, Feature::kVertexB};
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return {a + (d1 / (d1 - d3)) * ab, Feature::kEdgeAB};
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return {c, Feature::kVertexC};
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return {a + (d2 / (d2 - d6)) * ac, Feature::kEdgeCA};
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return {b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b), Feature::kEdgeBC};
  const double sum = va + vb + vc;
  if (!(sum > 0)) {  // degenerate: the nearest of the three edges
    auto onSegment = [&p](const Vec3& s, const Vec3& e) {
      const Vec3 d = e - s;
      const double len2 = d.squaredNorm();
      const double u = len2 > 0 ? std::clamp((p - s).dot(d) / len2, 0.0, 1.0) : 0.0;
      return Vec3(s + u * d);
    };
    const Vec3 e[3] = {onSegment(a, b), onSegment(b, c), onSegment(c, a)};
    const Feature f[3] = {Feature::kEdgeAB, Feature::kEdgeBC, Feature::kEdgeCA};
    int k = 0;
    for (int i = 1; i < 3; ++i)
      if ((p - e[i]).squaredNorm() < (p - e[k]).squaredNorm()) k = i;
    return {e[k], f[k]};
  }
  const double v = vb / sum, w = vc / sum;
  return {a + v * ab + w * ac, Feature::kFace};
}

// Smallest t in [0, 1] with |o + t d - centre| = r, for o outside that sphere; -1 if none.
double firstOnSphere(const Vec3& o, const Vec3& d, const Vec3& centre, double r) {
  const Vec3 m = o - centre;
  const double A = d.squaredNorm(), B = m.dot(d), C = m.squaredNorm() - r * r;
  if (!(A > 0) || B >= 0) return -1;  // not moving, or moving away
  const double disc = B * B - A * C;
  if (disc < 0) return -1;
  const double t = (-B - std::sqrt(disc)) / A;
  return t >= 0 && t <= 1 ? t : -1;
}

// Smallest t in [0, 1] at which o + t d is at distance r from segment [e0, e1], touching it
// away from its ends (the ends are firstOnSphere's); -1 if none. o is farther than r.
double firstOnCylinder(const Vec3& o, const Vec3& d, const Vec3& e0, const Vec3& e1, double r) {
  const Vec3 axis = e1 - e0;
  const double len2 = axis.squaredNorm();
  if (!(len2 > 0)) return -1;
  // Components perpendicular to the axis: |m_perp + t d_perp|^2 = r^2.
  const Vec3 m = o - e0;
  const Vec3 mp = m - (m.dot(axis) / len2) * axis, dp = d - (d.dot(axis) / len2) * axis;
  const double A = dp.squaredNorm(), B = mp.dot(dp), C = mp.squaredNorm() - r * r;
  if (!(A > 0) || B >= 0) return -1;
  const double disc = B * B - A * C;
  if (disc < 0) return -1;
  const double t = (-B - std::sqrt(disc)) / A;
  if (t < 0 || t > 1) return -1;
  const double u = (m + t * d).dot(axis) / len2;
  return u >= 0 && u <= 1 ? t : -1;
}

struct Collider {
  MeshCollider desc;
  bool closed = false;
  std::vector<Vec3> local;                        // vertices, local frame (file * scale, m)
  std::vector<std::array<std::int32_t, 3>> tris;  // as given
  std::vector<Vec3> faceNormal;                   // unit, per triangle, by its winding
  // Angle-weighted pseudonormals (Bærentzen & Aanæs 2005), closed meshes only: per edge
  // (3 per triangle, edge k from corner k to k + 1) the sum of its two faces' normals; per
  // vertex the sum of its faces' normals weighted by the face's angle there.
  std::vector<Vec3> edgeNormal, vertexNormal;
  Vec3 lo, hi;     // local bounds of the vertices
  double eps = 0;  // slack (m) for the float BVH's rounding, added to every query box
  // Bullet's copy (float): vertices and indices it points into, the mesh interface, the BVH.
  std::vector<btScalar> bulletVertices;
  std::vector<int> bulletIndices;
  std::unique_ptr<btTriangleIndexVertexArray> array;
  std::unique_ptr<btBvhTriangleMeshShape> shape;
  ColliderPose pose0, pose1;

  const Vec3& corner(int tri, int k) const { return local[static_cast<std::size_t>(tris[tri][k])]; }
  Vec3 pseudonormal(int tri, Feature f) const {
    switch (f) {
      case Feature::kVertexA: return vertexNormal[static_cast<std::size_t>(tris[tri][0])];
      case Feature::kVertexB: return vertexNormal[static_cast<std::size_t>(tris[tri][1])];
      case Feature::kVertexC: return vertexNormal[static_cast<std::size_t>(tris[tri][2])];
      case Feature::kEdgeAB: return edgeNormal[3 * static_cast<std::size_t>(tri) + 0];
      case Feature::kEdgeBC: return edgeNormal[3 * static_cast<std::size_t>(tri) + 1];
      case Feature::kEdgeCA: return edgeNormal[3 * static_cast<std::size_t>(tri) + 2];
      case Feature::kFace: break;
    }
    return faceNormal[static_cast<std::size_t>(tri)];
  }
  bool boxOverlaps(const Vec3& boxLo, const Vec3& boxHi) const {
    return (boxLo.array() <= hi.array() + eps).all() && (boxHi.array() >= lo.array() - eps).all();
  }
};

btVector3 bt(const Vec3& v) {
  return btVector3(static_cast<btScalar>(v.x()), static_cast<btScalar>(v.y()), static_cast<btScalar>(v.z()));
}

void computeNormals(Collider& c) {
  const std::size_t nt = c.tris.size();
  c.faceNormal.resize(nt);
  for (std::size_t t = 0; t < nt; ++t) {
    const Vec3 n = (c.corner(static_cast<int>(t), 1) - c.corner(static_cast<int>(t), 0))
                       .cross(c.corner(static_cast<int>(t), 2) - c.corner(static_cast<int>(t), 0));
    const double len = n.norm();
    c.faceNormal[t] = len > 0 ? Vec3(n / len) : Vec3::Zero();
  }
  if (!c.closed) return;
  // Edges by their two vertices; a closed manifold soup has two faces per edge.
  std::map<std::pair<std::int32_t, std::int32_t>, Vec3> edgeSum;
  c.vertexNormal.assign(c.local.size(), Vec3::Zero());
  for (std::size_t t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      const std::int32_t a = c.tris[t][k], b = c.tris[t][(k + 1) % 3];
      // emplace with an explicit zero: map::operator[] would value-initialise the Vec3,
      // which Eigen leaves uninitialised.
      edgeSum.emplace(std::make_pair(std::min(a, b), std::max(a, b)), Vec3::Zero()).first->second += c.faceNormal[t];
      const Vec3 e1 = (c.corner(static_cast<int>(t), (k + 1) % 3) - c.corner(static_cast<int>(t), k)).normalized();
      const Vec3 e2 = (c.corner(static_cast<int>(t), (k + 2) % 3) - c.corner(static_cast<int>(t), k)).normalized();
      const double angle = std::acos(std::clamp(e1.dot(e2), -1.0, 1.0));
      c.vertexNormal[static_cast<std::size_t>(a)] += angle * c.faceNormal[t];
    }
  c.edgeNormal.resize(3 * nt);
  for (std::size_t t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      const std::int32_t a = c.tris[t][k], b = c.tris[t][(k + 1) % 3];
      c.edgeNormal[3 * t + static_cast<std::size_t>(k)] = edgeSum.at({std::min(a, b), std::max(a, b)});
    }
}

std::unique_ptr<Collider> buildCollider(MeshCollider desc, const TriangleSoup& soup) {
  const std::string who = "ColliderSet: collider '" + desc.name + "': ";
  if (!(desc.scale > 0) || !std::isfinite(desc.scale)) throw RuntimeError(who + "scale must be finite and > 0");
  if (soup.triangles.empty()) throw RuntimeError(who + "mesh has no triangles");
  if (soup.vertices.size() > static_cast<std::size_t>(std::numeric_limits<int>::max()) / 3 ||
      soup.triangles.size() > static_cast<std::size_t>(std::numeric_limits<int>::max()) / 3)
    throw RuntimeError(who + "mesh too large");
  auto c = std::make_unique<Collider>();
  c->desc = std::move(desc);
  c->closed = soup.closed;
  c->tris = soup.triangles;
  c->local.reserve(soup.vertices.size());
  for (const Vec3& v : soup.vertices) {
    if (!v.allFinite()) throw RuntimeError(who + "mesh has a non-finite vertex");
    c->local.push_back(c->desc.scale * v);
  }
  for (const auto& t : c->tris)
    for (std::int32_t v : t)
      if (v < 0 || static_cast<std::size_t>(v) >= c->local.size()) throw RuntimeError(who + "triangle index out of range");
  c->lo = c->hi = c->local[static_cast<std::size_t>(c->tris[0][0])];
  for (const auto& t : c->tris)
    for (std::int32_t v : t) {
      c->lo = c->lo.cwiseMin(c->local[static_cast<std::size_t>(v)]);
      c->hi = c->hi.cwiseMax(c->local[static_cast<std::size_t>(v)]);
    }
  // Bullet keeps the vertices in float; a query box grows by a few float ulps of the
  // largest coordinate so that rounding never drops a triangle at the box's edge.
  c->eps = 8 * FLT_EPSILON * std::max(c->lo.cwiseAbs().maxCoeff(), c->hi.cwiseAbs().maxCoeff()) + 1e-12;
  computeNormals(*c);

  c->bulletVertices.reserve(3 * c->local.size());
  for (const Vec3& v : c->local)
    for (int k = 0; k < 3; ++k) c->bulletVertices.push_back(static_cast<btScalar>(v[k]));
  c->bulletIndices.reserve(3 * c->tris.size());
  for (const auto& t : c->tris) c->bulletIndices.insert(c->bulletIndices.end(), t.begin(), t.end());
  c->array = std::make_unique<btTriangleIndexVertexArray>(
      static_cast<int>(c->tris.size()), c->bulletIndices.data(), static_cast<int>(3 * sizeof(int)),
      static_cast<int>(c->local.size()), c->bulletVertices.data(), static_cast<int>(3 * sizeof(btScalar)));
  // Quantized AABB compression: 16 bytes per node instead of 64 (stack.md §6 measured it).
  c->shape = std::make_unique<btBvhTriangleMeshShape>(c->array.get(), /*useQuantizedAabbCompression=*/true);
  return c;
}

// The nearest triangle of one collider to q (local frame) within `reach`: Bullet's BVH
// reports the triangles whose boxes meet q's box, in a fixed order; ties keep the lower index.
struct NearestCallback final : btTriangleCallback {
  const Collider& c;
  Vec3 q;
  double best2;
  int triangle = -1;
  ClosestOnTriangle found{};
  NearestCallback(const Collider& collider, const Vec3& query, double reach)
      : c(collider), q(query), best2(reach * reach) {}
  void processTriangle(btVector3*, int, int t) override {
    const ClosestOnTriangle r = closestOnTriangle(q, c.corner(t, 0), c.corner(t, 1), c.corner(t, 2));
    const double d2 = (q - r.point).squaredNorm();
    if (d2 < best2 || (d2 == best2 && triangle >= 0 && t < triangle)) best2 = d2, triangle = t, found = r;
  }
};

// The first touch of a sphere (centre a -> b, radius r, local frame) with the triangles
// the BVH reports along the sweep (mesh_collider.h, ColliderSet::sweep).
struct SweepCallback final : btTriangleCallback {
  const Collider& c;
  Vec3 a, d;
  double r;
  double best = 2;  // > 1: no hit yet
  int triangle = -1;
  Vec3 normal = Vec3::Zero();
  SweepCallback(const Collider& collider, const Vec3& from, const Vec3& to, double radius)
      : c(collider), a(from), d(to - from), r(radius) {}

  void offer(double t, int tri, const Vec3& n) {
    if (t < 0 || t > 1) return;
    if (t < best || (t == best && tri < triangle)) best = t, triangle = tri, normal = n;
  }

  void processTriangle(btVector3*, int, int t) override {
    const Vec3 p[3] = {c.corner(t, 0), c.corner(t, 1), c.corner(t, 2)};
    const Vec3& n = c.faceNormal[static_cast<std::size_t>(t)];
    if (n.isZero()) return;  // no area: its edges belong to its neighbours
    const double side = (a - p[0]).dot(n);
    const Vec3 out = side >= 0 ? n : Vec3(-n);  // face normal on a's side
    const double startGap = std::abs(side);
    const double dn = d.dot(out);  // < 0: approaching the plane
    const bool overlapping = (a - closestOnTriangle(a, p[0], p[1], p[2]).point).norm() < r;
    if (overlapping || r == 0) {
      // Only the centre crossing the triangle (ray against triangle) counts.
      if (!(dn < 0)) return;
      const double s = startGap / -dn;
      if (s > 1) return;
      if (inTriangle(a + s * d, p, n)) offer(s, t, out);
      return;
    }
    // The sphere starts clear of the triangle: its first touch is the first touch of the
    // centre with the triangle grown by r (faces moved out by r, edge cylinders, corner spheres).
    if (dn < 0) {
      const double s = (startGap - r) / -dn;
      const Vec3 touch = a + s * d - r * out;
      if (s >= 0 && s <= 1 && inTriangle(touch, p, n)) offer(s, t, out);
    }
    for (int k = 0; k < 3; ++k) {
      const double s = firstOnSphere(a, d, p[k], r);
      if (s >= 0) offer(s, t, ((a + s * d) - p[k]).normalized());
      const Vec3 &e0 = p[k], &e1 = p[(k + 1) % 3];
      const double u = firstOnCylinder(a, d, e0, e1, r);
      if (u >= 0) {
        const Vec3 centre = a + u * d, axis = (e1 - e0).normalized();
        const Vec3 foot = e0 + (centre - e0).dot(axis) * axis;
        offer(u, t, (centre - foot).normalized());
      }
    }
  }

  // Whether x, a point on the triangle's plane, lies inside the triangle (edges included).
  static bool inTriangle(const Vec3& x, const Vec3 p[3], const Vec3& n) {
    for (int k = 0; k < 3; ++k)
      if ((p[(k + 1) % 3] - p[k]).cross(x - p[k]).dot(n) < 0) return false;
    return true;
  }
};

}  // namespace

struct ColliderSet::Impl {
  std::vector<std::unique_ptr<Collider>> colliders;
  double t0 = 0, t1 = 0;

  // The contact of q (world) with collider ci within reach, if any.
  bool nearest(std::size_t ci, const Vec3& world, double reach, MeshContact& out) const {
    const Collider& c = *colliders[ci];
    const Vec3 q = c.pose1.rotation.transpose() * (world - c.pose1.position);
    const Vec3 slack = Vec3::Constant(reach + c.eps);
    if (!c.boxOverlaps(q - slack, q + slack)) return false;
    NearestCallback cb(c, q, reach);
    c.shape->processAllTriangles(&cb, bt(q - slack), bt(q + slack));
    if (cb.triangle < 0) return false;
    const Vec3 toQ = q - cb.found.point;
    const double dist = toQ.norm();
    const bool inside = c.closed && toQ.dot(c.pseudonormal(cb.triangle, cb.found.feature)) < 0;
    Vec3 n;
    if (dist > 1e-12 * (1 + c.hi.cwiseAbs().maxCoeff())) {
      n = inside ? Vec3(-toQ / dist) : Vec3(toQ / dist);
    } else {  // on the surface: the feature's outward pseudonormal, or an open sheet's face normal
      n = c.closed ? c.pseudonormal(cb.triangle, cb.found.feature).normalized()
                   : c.faceNormal[static_cast<std::size_t>(cb.triangle)];
    }
    out.collider = static_cast<std::int32_t>(ci);
    out.triangle = cb.triangle;
    out.point = c.pose1.rotation * cb.found.point + c.pose1.position;
    out.normal = c.pose1.rotation * n;
    out.distance = inside ? -dist : dist;
    return true;
  }
};

ColliderSet::ColliderSet(std::vector<MeshCollider> colliders, const std::vector<TriangleSoup>& meshes)
    : impl_(std::make_unique<Impl>()) {
  if (colliders.size() != meshes.size())
    throw RuntimeError("ColliderSet: " + std::to_string(colliders.size()) + " colliders but " +
                       std::to_string(meshes.size()) + " meshes");
  for (std::size_t i = 0; i < colliders.size(); ++i)
    impl_->colliders.push_back(buildCollider(std::move(colliders[i]), meshes[i]));
  setSubstep(0.0, 0.0);
}

ColliderSet::~ColliderSet() = default;
ColliderSet::ColliderSet(ColliderSet&&) noexcept = default;
ColliderSet& ColliderSet::operator=(ColliderSet&&) noexcept = default;

std::size_t ColliderSet::size() const { return impl_->colliders.size(); }
const MeshCollider& ColliderSet::collider(std::size_t c) const { return impl_->colliders.at(c)->desc; }
bool ColliderSet::moving(std::size_t c) const { return !impl_->colliders.at(c)->desc.keyframes.empty(); }
const ColliderPose& ColliderSet::startPose(std::size_t c) const { return impl_->colliders.at(c)->pose0; }
const ColliderPose& ColliderSet::endPose(std::size_t c) const { return impl_->colliders.at(c)->pose1; }

void ColliderSet::setSubstep(double t0, double t1) {
  if (!std::isfinite(t0) || !std::isfinite(t1) || t1 < t0)
    throw RuntimeError("ColliderSet::setSubstep: need finite t0 <= t1");
  impl_->t0 = t0, impl_->t1 = t1;
  for (auto& c : impl_->colliders) {
    c->desc.poseAt(t0, c->pose0.rotation, c->pose0.position);
    c->desc.poseAt(t1, c->pose1.rotation, c->pose1.position);
  }
}

Vec3 ColliderSet::surfaceVelocity(std::size_t ci, const Vec3& world) const {
  const Collider& c = *impl_->colliders.at(ci);
  const double h = impl_->t1 - impl_->t0;
  if (!(h > 0) || c.desc.keyframes.empty()) return Vec3::Zero();
  const Vec3 local = c.pose1.rotation.transpose() * (world - c.pose1.position);
  const Vec3 before = c.pose0.rotation * local + c.pose0.position;
  return (world - before) / h;
}

bool ColliderSet::closest(const Vec3& p, double reach, MeshContact& contact) const {
  bool any = false;
  MeshContact best;
  for (std::size_t c = 0; c < impl_->colliders.size(); ++c) {
    MeshContact m;
    if (impl_->nearest(c, p, reach, m) && (!any || m.distance < best.distance)) best = m, any = true;
  }
  if (any) contact = best;
  return any;
}

void ColliderSet::contacts(const float* x, const float* y, const float* z, std::size_t n, double radius,
                           double margin, std::vector<MeshContact>& out) const {
  out.clear();
  if (!(radius >= 0) || !(margin >= 0) || !std::isfinite(radius + margin))
    throw RuntimeError("ColliderSet::contacts: radius and margin must be finite and >= 0");
  if (n == 0 || impl_->colliders.empty()) return;
  const double reach = radius + margin;
  const std::size_t chunks = (n + kChunk - 1) / kChunk;
  std::vector<std::vector<MeshContact>> found(chunks);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t k = r.begin(); k != r.end(); ++k) {
      const std::size_t end = std::min(n, (k + 1) * kChunk);
      for (std::size_t i = k * kChunk; i < end; ++i) {
        const Vec3 p(x[i], y[i], z[i]);
        for (std::size_t c = 0; c < impl_->colliders.size(); ++c) {
          MeshContact m;
          if (!impl_->nearest(c, p, reach, m) || !(m.distance < reach)) continue;
          m.particle = static_cast<std::int32_t>(i);
          found[k].push_back(m);
        }
      }
    }
  });
  std::size_t total = 0;
  for (const auto& f : found) total += f.size();
  out.reserve(total);
  for (const auto& f : found) out.insert(out.end(), f.begin(), f.end());
}

SweepHit ColliderSet::sweep(const Vec3& from, const Vec3& to, double radius) const {
  SweepHit hit;
  if (!(radius >= 0) || !std::isfinite(radius) || !from.allFinite() || !to.allFinite())
    throw RuntimeError("ColliderSet::sweep: need finite positions and a finite radius >= 0");
  for (std::size_t ci = 0; ci < impl_->colliders.size(); ++ci) {
    const Collider& c = *impl_->colliders[ci];
    // Relative motion in the collider's frame: from at its start pose, to at its end pose.
    const Vec3 a = c.pose0.rotation.transpose() * (from - c.pose0.position);
    const Vec3 b = c.pose1.rotation.transpose() * (to - c.pose1.position);
    const Vec3 grow = Vec3::Constant(radius + c.eps);
    if (!c.boxOverlaps(a.cwiseMin(b) - grow, a.cwiseMax(b) + grow)) continue;
    SweepCallback cb(c, a, b, radius);
    // Bullet's box cast walks the BVH along the segment; it normalises the direction, so a
    // (near) standing particle asks for the box around it instead.
    if ((b - a).norm() > 1e-9 * (1 + c.hi.cwiseAbs().maxCoeff()))
      c.shape->performConvexcast(&cb, bt(a), bt(b), bt(-grow), bt(grow));
    else
      c.shape->processAllTriangles(&cb, bt(a.cwiseMin(b) - grow), bt(a.cwiseMax(b) + grow));
    if (cb.triangle < 0 || (hit.hit && !(cb.best < hit.fraction))) continue;
    hit.hit = true;
    hit.fraction = cb.best;
    hit.collider = static_cast<std::int32_t>(ci);
    hit.triangle = cb.triangle;
    hit.centre = c.pose1.rotation * (a + cb.best * (b - a)) + c.pose1.position;
    hit.normal = c.pose1.rotation * cb.normal;
  }
  return hit;
}

}  // namespace physketch::pbd
