#include "sketch/solids.h"

#include <algorithm>
#include <cmath>

namespace physketch::sketch {

bool Solid::containsLocal(const Vec3& p) const {
  switch (shape) {
    case SolidShape::kSphere: return p.squaredNorm() <= a * a;
    case SolidShape::kCube: return p.cwiseAbs().maxCoeff() <= a;
    case SolidShape::kBox: return std::abs(p.x()) <= a && std::abs(p.y()) <= b && std::abs(p.z()) <= c;
    case SolidShape::kEllipsoid: {
      const double u = p.x() / a, v = p.y() / b, w = p.z() / c;
      return u * u + v * v + w * w <= 1.0;
    }
    case SolidShape::kCylinder: return p.x() * p.x() + p.y() * p.y() <= a * a && std::abs(p.z()) <= b;
    case SolidShape::kCapsule: {
      const double z = std::clamp(p.z(), -b, b);
      return p.x() * p.x() + p.y() * p.y() + (p.z() - z) * (p.z() - z) <= a * a;
    }
    case SolidShape::kTorus: {
      const double q = std::sqrt(p.x() * p.x() + p.y() * p.y()) - a;
      return q * q + p.z() * p.z() <= b * b;
    }
  }
  return false;
}

double Solid::boundingRadius() const {
  switch (shape) {
    case SolidShape::kSphere: return a;
    case SolidShape::kCube: return a * std::sqrt(3.0);
    case SolidShape::kBox: return std::sqrt(a * a + b * b + c * c);
    case SolidShape::kEllipsoid: return std::max({a, b, c});
    case SolidShape::kCylinder: return std::sqrt(a * a + b * b);
    case SolidShape::kCapsule: return a + b;
    case SolidShape::kTorus: return a + b;
  }
  return 0.0;
}

double Solid::volume() const {
  switch (shape) {
    case SolidShape::kSphere: return 4.0 / 3.0 * M_PI * a * a * a;
    case SolidShape::kCube: return 8.0 * a * a * a;
    case SolidShape::kBox: return 8.0 * a * b * c;
    case SolidShape::kEllipsoid: return 4.0 / 3.0 * M_PI * a * b * c;
    case SolidShape::kCylinder: return M_PI * a * a * 2.0 * b;
    case SolidShape::kCapsule: return M_PI * a * a * 2.0 * b + 4.0 / 3.0 * M_PI * a * a * a;
    case SolidShape::kTorus: return 2.0 * M_PI * M_PI * a * b * b;
  }
  return 0.0;
}

Mat3 frameFromAxis(const Vec3& axis) {
  const Vec3 z = axis.normalized();
  // Pick the world axis least aligned with z as the seed for x: deterministic and well conditioned.
  const Vec3 seed = std::abs(z.x()) < 0.9 ? Vec3::UnitX() : Vec3::UnitY();
  const Vec3 x = (seed - seed.dot(z) * z).normalized();
  const Vec3 y = z.cross(x);
  Mat3 r;
  r.col(0) = x;
  r.col(1) = y;
  r.col(2) = z;
  return r;
}

}  // namespace physketch::sketch
