// Builders of test bodies for the PBD tests: lattice boxes, bars and balls of particles at
// the test spacing, as the sketch would make them.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/SVD>

#include "core/material.h"
#include "core/particles.h"
#include "pbd/world.h"

namespace physketch::pbd::test {

inline constexpr double kSpacing = 0.01;  // m: particle diameter 2r
inline constexpr double kRadius = 0.5 * kSpacing;
inline constexpr double kDensity = 1000.0;
inline const double kParticleMass = kDensity * kSpacing * kSpacing * kSpacing;

// The rotation maximizing tr(R^T A) over SO(3), from Eigen's SVD A = U S V^T:
// R = U diag(1, 1, det(U V^T)) V^T (the sign on the smallest singular value). The tests' oracle
// for a polar decomposition and for a best rigid fit (A = sum m (x - c)(q - c0)^T).
inline Mat3 polarRotation(const Mat3& A) {
  const Eigen::JacobiSVD<Mat3> svd(A, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 D = Mat3::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
  return svd.matrixU() * D * svd.matrixV().transpose();
}

inline std::vector<Material> rigidMaterial(double friction = 0.5) {
  Material m;
  m.name = "rigid";
  m.density = kDensity;
  m.staticFriction = m.dynamicFriction = friction;
  return {m};
}

// Appends an nx*ny*nz lattice box with its lowest corner particle at `corner` (m).
inline BodyRange addBox(ParticleArrays& p, const Vec3& corner, int nx, int ny, int nz, int stroke = 0,
                        std::int16_t material = 0) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        const Vec3 x = corner + kSpacing * Vec3(i, j, k);
        p.push(float(x.x()), float(x.y()), float(x.z()), stroke, material);
      }
  b.count = nx * ny * nz;
  b.stroke = stroke;
  return b;
}

// A cube of side^3 particles at kSpacing centred at `centre`, turned by R: the next body.
inline void addTurnedCube(ParticleArrays& p, std::vector<BodyRange>& bodies, const Vec3& centre, const Mat3& R, int side) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  for (int k = 0; k < side; ++k)
    for (int j = 0; j < side; ++j)
      for (int i = 0; i < side; ++i) {
        const Vec3 x = centre + R * (kSpacing * (Vec3(i, j, k) - Vec3::Constant(0.5 * (side - 1))));
        p.push(float(x.x()), float(x.y()), float(x.z()), int(bodies.size()), 0);
      }
  b.count = side * side * side;
  b.stroke = int(bodies.size());
  bodies.push_back(b);
}

// A bar tilted in the x-y plane, `len` particles long and 3x3 thick.
inline BodyRange addTiltedBar(ParticleArrays& p, const Vec3& start, int len, double angleRad, int stroke = 0) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  const Vec3 axis(std::cos(angleRad), std::sin(angleRad), 0.0), side(-std::sin(angleRad), std::cos(angleRad), 0.0);
  for (int i = 0; i < len; ++i)
    for (int j = -1; j <= 1; ++j)
      for (int k = -1; k <= 1; ++k) {
        const Vec3 x = start + kSpacing * (i * axis + j * side + k * Vec3::UnitZ());
        p.push(float(x.x()), float(x.y()), float(x.z()), stroke, 0);
      }
  b.count = len * 9;
  b.stroke = stroke;
  return b;
}

// A lattice ball of radius `cells` particle spacings around `centre`.
inline BodyRange addBall(ParticleArrays& p, const Vec3& centre, int cells, int stroke = 0, std::int16_t material = 0) {
  BodyRange b;
  b.first = static_cast<std::int32_t>(p.size());
  for (int k = -cells; k <= cells; ++k)
    for (int j = -cells; j <= cells; ++j)
      for (int i = -cells; i <= cells; ++i)
        if (i * i + j * j + k * k <= cells * cells) {
          const Vec3 x = centre + kSpacing * Vec3(i, j, k);
          p.push(float(x.x()), float(x.y()), float(x.z()), stroke, material);
        }
  b.count = static_cast<std::int32_t>(p.size()) - b.first;
  b.stroke = stroke;
  return b;
}

// Steps until `body` is asleep, at most `maxSteps`: the step it fell asleep in, or -1 (not asleep
// by then, or a step the guard stopped: w.guard() says which).
inline int stepUntilAsleep(PbdWorld& w, int body, int maxSteps) {
  for (int s = 0; s < maxSteps; ++s) {
    if (!w.step()) return -1;
    if (w.asleep(body)) return s;
  }
  return -1;
}

// Whether every particle's velocity is exactly 0 (a sleeper's).
inline bool allExactlyAtRest(const ParticleArrays& p) {
  for (std::size_t i = 0; i < p.size(); ++i)
    if (p.vx[i] != 0.0f || p.vy[i] != 0.0f || p.vz[i] != 0.0f) return false;
  return true;
}

// Steps until the body, having bounced (its centre moving up faster than `rising` m/s), starts
// down again: the top of its first bounce above `rest` (m), or -1 if it never moved up within
// 2 s (or the guard stopped it). A soft body's centre wobbles: its tests ask for a clear rise.
inline double firstBounceApex(PbdWorld& w, int body, double rest, double rising = 0.0) {
  bool bounced = false;
  double apex = 0.0;
  for (int s = 0; s < 120; ++s) {
    if (!w.step()) return -1.0;
    if (!bounced && w.velocity(body).y() > rising) bounced = true;
    if (bounced) apex = std::max(apex, w.pose(body).centre.y() - rest);
    if (bounced && w.velocity(body).y() < 0.0) break;  // past the top of the first bounce
  }
  return bounced ? apex : -1.0;
}

}  // namespace physketch::pbd::test
