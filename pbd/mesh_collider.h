// Mesh colliders: the triangle meshes of the scene's `collider` records (static or moved
// along keyframes), queried per particle. Bullet does the broad phase (one
// btBvhTriangleMeshShape per collider, never one collision object per particle: a world of
// 80k objects is quadratic, ../shared/stack.md §6) and lives only in mesh_collider.cpp;
// this header exposes std and Eigen types. The exact tests against the triangles the BVH
// reports (closest point, swept sphere) are ours, in double.
//
// Frames: a collider's local frame is its file coordinates times its scale, so
// world = R(t) * local + c(t), (R, c) = MeshCollider::poseAt(t). Queries take world positions
// in metres and answer in world coordinates, against the poses of the current substep set by
// setSubstep(t0, t1): contacts use the end pose (the PBD positions being corrected are
// predicted to t1), sweeps run in the collider's frame from its start pose to its end pose.
//
// Inside and outside (closed meshes only, TriangleSoup::closed): a point is inside when
// (p - q) . n < 0, q its closest point on the surface and n the angle-weighted pseudonormal
// of the feature (face, edge or vertex) q lies on (Bærentzen & Aanæs 2005, "Signed distance
// computation using the angle weighted pseudonormal", Theorem 1: exact for a closed,
// consistently oriented manifold). It needs only the closest feature, which the contact
// query finds anyway, and has none of ray parity's double counts where a ray grazes an edge
// or a vertex. An open mesh has no inside: its normal points to the particle's side.
//
// Threads: the queries are const and may run on several threads at once; setSubstep may not.
//
// Determinism: every query is a pure function of its input (the BVH is traversed in a fixed
// order, ties go to the lower triangle and collider index); contacts() splits particles into
// fixed chunks of kChunk, whatever the thread count, and concatenates them in order.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "core/math.h"
#include "core/scene.h"
#include "core/triangle_soup.h"

namespace physketch::pbd {

// A particle near a collider surface: one per (particle, collider) pair, the closest point.
struct MeshContact {
  std::int32_t particle = 0;  // index into the positions given
  std::int32_t collider = 0;  // index into the scene's colliders
  std::int32_t triangle = 0;  // the triangle the closest point lies on (index into its soup)
  Vec3 point = Vec3::Zero();  // closest point on the surface, world (m), at the end pose
  Vec3 normal = Vec3::Zero();  // unit, world: the way out, from the surface to the particle's side
  // Signed distance of the particle's centre from the surface (m): > 0 outside (or on the
  // particle's side of an open sheet), < 0 inside a closed mesh. The particle is pushed to
  // point + radius * normal, i.e. by depth = radius - distance along normal.
  double distance = 0.0;
};

// The first contact of a swept sphere.
struct SweepHit {
  bool hit = false;
  double fraction = 1.0;      // along the segment, in [0, 1]: centre = from + fraction (to - from)
  std::int32_t collider = -1;
  std::int32_t triangle = -1;
  Vec3 centre = Vec3::Zero();  // the sphere's centre when it touches, world at the end pose (m)
  Vec3 normal = Vec3::Zero();  // unit, world at the end pose, from the surface towards the centre
};

struct ColliderPose {
  Mat3 rotation = Mat3::Identity();  // local -> world
  Vec3 position = Vec3::Zero();      // m
};

class ColliderSet {
 public:
  // Particles per chunk of contacts(): the unit of parallel work, fixed so that the output
  // does not depend on the thread count.
  static constexpr std::size_t kChunk = 2048;

  // One soup per collider, in the scene's order (sketch::readTriangleSoup reads them). A
  // soup with a non-finite vertex, an index out of range or no triangle, a scale that is not
  // finite and > 0, or a count that does not match is a RuntimeError (a caller bug: the
  // reader and the scene parser check user input). The poses start at t0 = t1 = 0.
  ColliderSet(std::vector<MeshCollider> colliders, const std::vector<TriangleSoup>& meshes);
  ~ColliderSet();
  ColliderSet(ColliderSet&&) noexcept;
  ColliderSet& operator=(ColliderSet&&) noexcept;

  std::size_t size() const;
  const MeshCollider& collider(std::size_t c) const;
  bool moving(std::size_t c) const;  // has keyframes

  // The substep [t0, t1] (s of simulated time, t0 <= t1) that the queries work in: poses at
  // both ends from MeshCollider::poseAt.
  void setSubstep(double t0, double t1);
  const ColliderPose& startPose(std::size_t c) const;
  const ColliderPose& endPose(std::size_t c) const;

  // Velocity (m/s) over the substep of the collider's material point that is at `world`
  // at t1: (world - where that point was at t0) / (t1 - t0), the displacement the collider
  // imposes in this substep (for friction against it and for the material it pushes). Zero
  // when t1 = t0 or the collider does not move.
  Vec3 surfaceVelocity(std::size_t c, const Vec3& world) const;

  // Every particle whose centre lies within radius + margin of a collider's surface (end
  // pose), outside or inside: one contact per (particle, collider), at the closest point,
  // written to `out` (cleared first) ordered by particle, then collider. Positions are float
  // SoA (m); n of them. A particle deeper inside a closed mesh than radius + margin is not
  // found (the sweeps keep particles from getting there). radius, margin >= 0 and finite.
  // The BVH is asked only for the triangles whose boxes meet the particle's box of half-size
  // radius + margin: no particle is tested against every triangle.
  void contacts(const float* x, const float* y, const float* z, std::size_t n, double radius, double margin,
                std::vector<MeshContact>& out) const;
  // The same query for one point against every collider: the contact with the smallest
  // signed distance within `reach` (m) of a surface, if any (contact.particle is left as is).
  // A larger reach finds a particle deeper inside a closed mesh (at the cost of a larger box).
  bool closest(const Vec3& p, double reach, MeshContact& contact) const;

  // First touch of a sphere of `radius` whose centre moves from `from` (at t0) to `to` (at
  // t1), against every collider, in each collider's frame (from at its start pose, to at its
  // end pose: a moving wall catches a resting particle). A triangle the sphere already
  // overlaps at `from` is a contact, not a hit; through it, only the centre crossing the
  // triangle itself counts (so a particle resting on a thin wall cannot pass through it).
  SweepHit sweep(const Vec3& from, const Vec3& to, double radius) const;

 private:
  struct Impl;  // Bullet's side, in mesh_collider.cpp
  std::unique_ptr<Impl> impl_;
};

}  // namespace physketch::pbd
