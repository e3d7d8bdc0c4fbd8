// Math types. Eigen is used for setup, small per-body matrices and tests; the
// per-particle hot loops run over the float arrays of ParticleArrays instead
// (an array of Vector3f does not vectorise across particles: docs/architecture.md).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace physketch {

using Vec3 = Eigen::Vector3d;
using Vec3f = Eigen::Vector3f;
using Vec3i = Eigen::Vector3i;
using Mat3 = Eigen::Matrix3d;
using Mat4f = Eigen::Matrix4f;
using Quat = Eigen::Quaterniond;

}  // namespace physketch
