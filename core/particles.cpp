#include "core/particles.h"

namespace physketch {

void ParticleArrays::reserve(std::size_t n) {
  for (auto* a : {&x, &y, &z, &vx, &vy, &vz, &mass}) a->reserve(n);
  phase.reserve(n);
  stroke.reserve(n);
  material.reserve(n);
}

void ParticleArrays::resize(std::size_t n) {
  for (auto* a : {&x, &y, &z, &vx, &vy, &vz, &mass}) a->resize(n, 0.0f);
  phase.resize(n, phase::make(-1, phase::kPrescribed));
  stroke.resize(n, -1);
  material.resize(n, 0);
}

std::int32_t ParticleArrays::push(float px, float py, float pz, std::int32_t strokeId, std::int16_t materialId) {
  const auto id = static_cast<std::int32_t>(x.size());
  x.push_back(px);
  y.push_back(py);
  z.push_back(pz);
  vx.push_back(0.0f);
  vy.push_back(0.0f);
  vz.push_back(0.0f);
  mass.push_back(0.0f);
  phase.push_back(phase::make(-1, phase::kPrescribed));  // static while being sketched (Phys-Sketch §4)
  stroke.push_back(strokeId);
  material.push_back(materialId);
  return id;
}

Mat4f BodyPose::model() const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  const Mat3 R = rotation.toRotationMatrix();
  m.topLeftCorner<3, 3>() = R;
  m.topRightCorner<3, 1>() = centre - R * restCentre;
  return m.cast<float>();
}

const char* toString(BodyMode mode) {
  switch (mode) {
    case BodyMode::kDynamic: return "dynamic";
    case BodyMode::kKinematic: return "kinematic";
    case BodyMode::kFixed: return "fixed";
    case BodyMode::kEmpty: return "empty";
  }
  return "?";
}

const char* toString(BodyLayout layout) {
  switch (layout) {
    case BodyLayout::kVoxels: return "voxels";
    case BodyLayout::kChain: return "chain";
    case BodyLayout::kLattice: return "lattice";
  }
  return "?";
}

}  // namespace physketch
