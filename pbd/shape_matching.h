// Shape-matching math (Müller et al. 2005, "Meshless deformations based on
// shape matching"), as small pure functions: positions and masses in, goal
// transform out. Testable alone; the world calls them once per body.
#pragma once

#include <cstdint>

#include "core/math.h"

namespace physketch::pbd {

// Rotation part of A (the polar factor R of A = R S) by the iterative method of
// Müller et al. 2016, "A robust method to extract the rotational part of
// deformations", warm-started from q, with Newton's step where the Hessian of
// tr(R^T A) allows it (shape_matching.cpp). Robust for rank-deficient A (flat or
// linear bodies keep the previous rotation about their free axes) and never a
// reflection. Returns the updated unit quaternion.
Quat extractRotation(const Mat3& A, Quat q, int maxIterations = 20);

// Rest shape of one body in the solver's arrays. Element k of the body is array
// element index[k] when `index` is set (a body's member list), else element k.
struct BodyView {
  std::int32_t n = 0;
  const std::int32_t* index = nullptr;
  const float* px = nullptr;  // current (predicted) positions (m)
  const float* py = nullptr;
  const float* pz = nullptr;
  const float* rx = nullptr;  // rest offsets q_i from the rest centre of mass (m)
  const float* ry = nullptr;
  const float* rz = nullptr;
  const float* mass = nullptr;  // particle masses (kg)
  std::size_t at(std::int32_t k) const { return static_cast<std::size_t>(index ? index[k] : k); }
};

// Optimal rigid transform (Müller 2005 Eq. 5-7): c = sum m p / sum m,
// A_pq = sum m (p - c) q^T, R = polar(A_pq) (warm-started from q).
// Sums are accumulated in double in particle order, so the result is independent
// of thread count. Goal positions are g_i = R q_i + c.
void matchRigid(const BodyView& body, Quat& q, Vec3& c);

// A rigid body's pose and inverse mass properties, for position-level contact.
struct RigidPose {
  Vec3 c = Vec3::Zero();           // centre of mass (m)
  Quat q = Quat::Identity();       // rest -> world rotation
  double invMass = 0.0;            // 1/kg
  Mat3 invInertiaRest = Mat3::Zero();  // inverse inertia tensor in the rest frame (1/(kg m^2))
};

// Inertia tensor of point masses at rest offsets r_i, each particle a cube of
// edge `spacing` (its own inertia m s^2/6 keeps lines and single particles invertible).
Mat3 restInertia(const BodyView& body, double spacing);

// Applies a position correction of `magnitude` metres along unit `dir` at world
// point `p` of the body, with zero compliance: the generalized inverse mass
// w = 1/M + (r x n)^T I^-1 (r x n) splits it between translation and rotation
// (Müller et al. 2020, "Detailed rigid body simulation with extended position
// based dynamics", Eq. 2-9). Moves the point by exactly `magnitude` along dir to
// first order. Returns the position impulse lambda = magnitude / w (kg m).
double applyPointCorrection(RigidPose& body, const Vec3& p, const Vec3& dir, double magnitude);

// The generalized inverse mass w = 1/M + (r x n)^T I^-1 (r x n) of a body at world
// point p along unit n (1/kg): a position impulse lambda moves p by lambda * w along n.
double generalizedInverseMass(const RigidPose& body, const Vec3& p, const Vec3& n);

}  // namespace physketch::pbd
