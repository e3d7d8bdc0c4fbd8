#include "sketch/brush.h"

#include <algorithm>
#include <cmath>

namespace physketch::sketch {

bool createsParticles(const Operation& op) {
  return op.kind != Operation::Kind::kStroke || op.stroke.op == StrokeOp::kCreate;
}

void interpolateSegment(const Vec3& prev, const Vec3& cur, double particleDiameter, std::vector<Vec3>& out) {
  out.clear();
  const Vec3 travel = cur - prev;  // V * dt
  const double dist = travel.norm();
  if (dist == 0.0 || particleDiameter <= 0.0) {
    out.push_back(cur);
    return;
  }
  const Vec3 dir = travel / dist;
  const long iMax = std::lround(dist / particleDiameter);  // Eq. 6
  out.reserve(static_cast<std::size_t>(iMax) + 1);
  for (long i = 0; i <= iMax; ++i) out.push_back(cur - double(i) * particleDiameter * dir);  // Eq. 7
}

std::vector<Stamp> stampsOf(const Stroke& s, double h) {
  std::vector<Stamp> out;
  std::vector<Vec3> pts;
  const auto& sm = s.samples;
  // Before the first move the brush points along the stroke's first direction of travel.
  Vec3 dir = s.axis;
  for (std::size_t k = 1; k < sm.size(); ++k) {
    const Vec3 d = sm[k].position - sm[k - 1].position;
    if (d.norm() > 0) {
      dir = d.normalized();
      break;
    }
  }
  out.push_back({sm[0].position, dir, sm[0].pressure, sm[0].t});
  for (std::size_t k = 1; k < sm.size(); ++k) {
    const Vec3 seg = sm[k].position - sm[k - 1].position;
    const double len = seg.norm();
    if (len > 0) dir = seg / len;
    interpolateSegment(sm[k - 1].position, sm[k].position, h, pts);
    for (std::size_t i = 0; i < pts.size(); ++i) {
      // Pressure varies linearly along the segment, like the position.
      const double a = len > 0 ? std::min(1.0, double(i) * h / len) : 0.0;
      out.push_back({pts[i], dir, sm[k].pressure + a * (sm[k - 1].pressure - sm[k].pressure), sm[k].t});
    }
  }
  return out;
}

Solid brushSolid(const Stroke& s, const Vec3& position, double pressure, const Vec3& direction, double voxelSize) {
  Solid b;
  b.centre = position;
  const double size = s.size * pressure;
  const Vec3 axis = s.orient == Orientation::kFollow ? direction : s.axis;
  b.rotation = frameFromAxis(axis);
  switch (s.brush) {
    case BrushShape::kSphere:
      b.shape = SolidShape::kSphere, b.a = 0.5 * size;
      break;
    case BrushShape::kCube:
      b.shape = SolidShape::kCube, b.a = 0.5 * size;  // with the default axis (y) the frame is an axis permutation
      break;
    case BrushShape::kCylinder:
      b.shape = SolidShape::kCylinder, b.a = 0.5 * size, b.b = 0.5 * (s.length > 0 ? s.length : size);
      break;
    case BrushShape::kDisc:
      // A disc is a cylinder one cell thick unless given a thickness: the "extrusion plane" of §4.2.
      b.shape = SolidShape::kCylinder, b.a = 0.5 * size, b.b = 0.5 * (s.length > 0 ? s.length : voxelSize);
      break;
    case BrushShape::kCapsule:
      b.shape = SolidShape::kCapsule, b.a = 0.5 * size, b.b = 0.5 * (s.length > 0 ? s.length : size);
      break;
  }
  return b;
}

Solid primitiveSolid(const Primitive& p) {
  Solid solid;
  solid.centre = p.centre;
  solid.rotation = p.rotation;
  switch (p.kind) {
    case PrimitiveKind::kBox:
      solid.shape = SolidShape::kBox;
      solid.a = 0.5 * p.dims.x(), solid.b = 0.5 * p.dims.y(), solid.c = 0.5 * p.dims.z();
      break;
    case PrimitiveKind::kSphere:
      solid.shape = SolidShape::kSphere, solid.a = p.dims.x();
      break;
    case PrimitiveKind::kEllipsoid:
      solid.shape = SolidShape::kEllipsoid;
      solid.a = p.dims.x(), solid.b = p.dims.y(), solid.c = p.dims.z();
      break;
    case PrimitiveKind::kCylinder:
      solid.shape = SolidShape::kCylinder, solid.a = p.dims.x(), solid.b = 0.5 * p.dims.y();
      break;
    case PrimitiveKind::kCapsule:
      solid.shape = SolidShape::kCapsule, solid.a = p.dims.x(), solid.b = 0.5 * p.dims.y();
      break;
    case PrimitiveKind::kTorus:
      solid.shape = SolidShape::kTorus, solid.a = p.dims.x(), solid.b = p.dims.y();
      break;
  }
  return solid;
}

double smallestFeature(const Operation& op, double h) {
  switch (op.kind) {
    case Operation::Kind::kStroke: {
      const Stroke& s = op.stroke;
      double f = s.size * std::min_element(s.samples.begin(), s.samples.end(), [](auto& a, auto& b) {
                            return a.pressure < b.pressure;
                          })->pressure;
      // A disc that follows the stroke sweeps a solid; a fixed one dragged sideways leaves a sheet.
      if (s.brush == BrushShape::kCylinder || s.brush == BrushShape::kCapsule ||
          (s.brush == BrushShape::kDisc && s.orient == Orientation::kFixed))
        f = std::min(f, s.length > 0 ? s.length : (s.brush == BrushShape::kDisc ? h : s.size));
      return f;
    }
    case Operation::Kind::kPrimitive: {
      const Primitive& p = op.primitive;
      switch (p.kind) {
        case PrimitiveKind::kBox: return p.dims.minCoeff();
        case PrimitiveKind::kSphere: return 2 * p.dims.x();
        case PrimitiveKind::kEllipsoid: return 2 * p.dims.minCoeff();
        case PrimitiveKind::kCylinder: return std::min(2 * p.dims.x(), p.dims.y());
        case PrimitiveKind::kCapsule: return 2 * p.dims.x();
        case PrimitiveKind::kTorus: return 2 * p.dims.y();
      }
      return 0.0;
    }
    case Operation::Kind::kStamp: return 1e300;
  }
  return 0.0;
}

Vec3i mirrorCell(const Vec3i& cell, const Mirror& mirror, const GridMapping& m) {
  if (mirror.axis < 0) return cell;
  Vec3 p = m.center();
  p[mirror.axis] = mirror.offset;
  const long twice = std::lround(2.0 * m.toGrid(p)[mirror.axis]);  // plane at a cell centre or face
  Vec3i out = cell;
  out[mirror.axis] = static_cast<int>(twice - cell[mirror.axis]);
  return out;
}

Vec3 mirrorPoint(const Vec3& point, const Mirror& mirror) {
  Vec3 p = point;
  if (mirror.axis >= 0) p[mirror.axis] = 2.0 * mirror.offset - p[mirror.axis];
  return p;
}

}  // namespace physketch::sketch
