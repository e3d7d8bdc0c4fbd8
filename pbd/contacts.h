// Contacts: what touches what, found once per substep by the `find_contacts` pass and
// solved by the contact passes' iterations. One array per kind of contact and one loop
// per kind (no virtual call per contact):
//   - body-plane: body-level rigid contact against a plane (today the ground), with the
//     body's candidate particles, so the sweeps touch only particles that can reach the
//     plane instead of every particle of the body;
//   - particle-plane, particle-particle and particle-mesh contacts are the PBD issue's
//     (fluids, soft bodies, ropes, colliders): their arrays live here so every contact
//     kind is generated and solved the same way.
#pragma once

#include <cstdint>
#include <vector>

#include "core/math.h"

namespace physketch::pbd {

struct Plane {
  Vec3 normal = Vec3::UnitY();  // unit, pointing out of the solid side
  double offset = 0.0;          // the plane is normal . x = offset (m)
};

// Rigid body against a plane: candidates[first, first + count) are the body's particles
// within a margin of the plane when the contacts were found.
// What the contact solve leaves for the velocity passes, per contact: whether it touched,
// where (world, after the solve), and the normal speed of that point before the solve.
struct BodyPlaneContacts {
  std::vector<std::int32_t> body, plane, first, count;
  std::vector<std::int32_t> candidates;
  std::vector<std::uint8_t> touched;
  std::vector<Vec3> point;
  std::vector<double> approachSpeed;  // n . v of the contact point before the solve (m/s, < 0 approaching)
  std::vector<double> normalImpulse;  // rigid_contact's normal corrections this substep, summed (kg m)
  std::size_t size() const { return body.size(); }
  void clear() {
    body.clear(), plane.clear(), first.clear(), count.clear(), candidates.clear();
    touched.clear(), point.clear(), approachSpeed.clear(), normalImpulse.clear();
  }
};

// Rigid body a against rigid body b: particle pairs (pa[k] of a, pb[k] of b) within a
// margin of touching when found, pairs [first, first + count) of each body pair.
struct BodyPairContacts {
  std::vector<std::int32_t> a, b, first, count;
  std::vector<std::int32_t> pa, pb;
  std::size_t size() const { return a.size(); }
  void clear() { a.clear(), b.clear(), first.clear(), count.clear(), pa.clear(), pb.clear(); }
};

// Particle i against particle j (different groups, or one self-colliding group).
struct ParticlePairContacts {
  std::vector<std::int32_t> i, j;
  std::size_t size() const { return i.size(); }
  void clear() { i.clear(), j.clear(); }
};

// Particle i against a plane or a triangle mesh: closest point and normal at finding time.
struct ParticleSurfaceContacts {
  std::vector<std::int32_t> i, surface;
  std::vector<Vec3> point, normal;
  std::size_t size() const { return i.size(); }
  void clear() { i.clear(), surface.clear(), point.clear(), normal.clear(); }
};

struct ContactSet {
  std::vector<Plane> planes;             // the ground is planes[0]
  BodyPlaneContacts bodyPlane;
  BodyPairContacts bodyPair;
  ParticlePairContacts particlePair;     // filled by the PBD issue's particle contacts
  ParticleSurfaceContacts particlePlane, particleMesh;
  void clearFound() {
    bodyPlane.clear(), bodyPair.clear(), particlePair.clear(), particlePlane.clear(), particleMesh.clear();
  }
};

}  // namespace physketch::pbd
