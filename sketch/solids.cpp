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

namespace {

// Interval of t where |o + t d|^2 <= r^2 (restricted to the first `dims` coordinates).
bool quadraticInterval(const Vec3& o, const Vec3& d, double r, int dims, double& t0, double& t1) {
  double A = 0, B = 0, C = -r * r;
  for (int i = 0; i < dims; ++i) {
    A += d[i] * d[i];
    B += 2 * o[i] * d[i];
    C += o[i] * o[i];
  }
  if (A < 1e-300) {  // the line is parallel to the axis: inside everywhere or nowhere
    if (C > 0) return false;
    t0 = -1e300, t1 = 1e300;
    return true;
  }
  const double disc = B * B - 4 * A * C;
  if (disc < 0) return false;
  const double s = std::sqrt(disc);
  t0 = (-B - s) / (2 * A);
  t1 = (-B + s) / (2 * A);
  return true;
}

// Interval where |o_i + t d_i| <= half on one axis.
bool slabInterval(double o, double d, double half, double& t0, double& t1) {
  if (std::abs(d) < 1e-300) {
    if (std::abs(o) > half) return false;
    t0 = -1e300, t1 = 1e300;
    return true;
  }
  const double a = (-half - o) / d, b = (half - o) / d;
  t0 = std::min(a, b), t1 = std::max(a, b);
  return true;
}

bool intersect(double& t0, double& t1, double a0, double a1) {
  t0 = std::max(t0, a0);
  t1 = std::min(t1, a1);
  return t0 <= t1;
}

}  // namespace

bool Solid::lineIntervalLocal(const Vec3& o, const Vec3& d, double& t0, double& t1) const {
  t0 = -1e300, t1 = 1e300;
  double a0, a1;
  switch (shape) {
    case SolidShape::kSphere: return quadraticInterval(o, d, a, 3, t0, t1);
    case SolidShape::kCube:
    case SolidShape::kBox: {
      const Vec3 half = shape == SolidShape::kCube ? Vec3(a, a, a) : Vec3(a, b, c);
      for (int i = 0; i < 3; ++i)
        if (!slabInterval(o[i], d[i], half[i], a0, a1) || !intersect(t0, t1, a0, a1)) return false;
      return true;
    }
    case SolidShape::kEllipsoid: {
      const Vec3 inv(1 / a, 1 / b, 1 / c);
      return quadraticInterval(o.cwiseProduct(inv), d.cwiseProduct(inv), 1.0, 3, t0, t1);
    }
    case SolidShape::kCylinder:
      return quadraticInterval(o, d, a, 2, t0, t1) && slabInterval(o.z(), d.z(), b, a0, a1) &&
             intersect(t0, t1, a0, a1);
    case SolidShape::kCapsule: {
      // Convex hull of the parts: the union of the side cylinder and the two end caps is one interval.
      bool any = false;
      double lo = 1e300, hi = -1e300;
      double c0, c1;
      if (quadraticInterval(o, d, a, 2, c0, c1) && slabInterval(o.z(), d.z(), b, a0, a1) && intersect(c0, c1, a0, a1)) {
        any = true, lo = std::min(lo, c0), hi = std::max(hi, c1);
      }
      for (double zc : {-b, b}) {
        if (quadraticInterval(o - Vec3(0, 0, zc), d, a, 3, c0, c1)) any = true, lo = std::min(lo, c0), hi = std::max(hi, c1);
      }
      t0 = lo, t1 = hi;
      return any;
    }
    case SolidShape::kTorus: return false;  // not convex: callers test cells one by one
  }
  return false;
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
