#include "core/particles.h"

namespace physketch {

void ParticleArrays::reserve(std::size_t n) {
  for (auto* a : {&x, &y, &z, &vx, &vy, &vz, &invMass}) a->reserve(n);
  body.reserve(n);
  stroke.reserve(n);
  material.reserve(n);
}

void ParticleArrays::resize(std::size_t n) {
  for (auto* a : {&x, &y, &z, &vx, &vy, &vz}) a->resize(n, 0.0f);
  invMass.resize(n, 0.0f);
  body.resize(n, -1);
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
  invMass.push_back(0.0f);  // static while being sketched (Phys-Sketch §4)
  body.push_back(-1);
  stroke.push_back(strokeId);
  material.push_back(materialId);
  return id;
}

}  // namespace physketch
