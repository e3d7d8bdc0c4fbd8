// The one translation unit of mpm/ that includes OpenVDB (its headers cost ~3 s to parse);
// meshToLevelSet and meshToUnsignedDistanceField are instantiated inside libopenvdb.
#include "mpm/collider_sdf.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>

#include <cmath>
#include <limits>
#include <mutex>
#include <vector>

#include "core/error.h"

namespace physketch::mpm {

namespace {
constexpr float kHalfWidth = 3.0f;  // narrow band half-width in voxels (OpenVDB's default)
}

struct ColliderSdf::Impl {
  openvdb::FloatGrid::Ptr grid;
  double voxel = 0.0;
  float shift = 0.0f;  // subtracted from the stored value: an open sheet's half-thickness
  float outside = 0.0f;  // the value outside the band (on the outside)
};

ColliderSdf::ColliderSdf(const TriangleSoup& mesh, double scale, double voxel, double thickness, double maxBandVoxels)
    : impl_(std::make_unique<Impl>()) {
  if (mesh.triangles.empty() || mesh.vertices.empty()) throw RuntimeError("ColliderSdf: the mesh has no triangles");
  if (!(voxel > 0.0) || !std::isfinite(voxel) || !(scale > 0.0) || !std::isfinite(scale) || !(thickness >= 0.0) ||
      !(maxBandVoxels >= 1.0))
    throw RuntimeError("ColliderSdf: voxel, scale and thickness must be finite, voxel and scale > 0");
  for (const auto& t : mesh.triangles) {
    const Vec3 a = scale * mesh.vertices[std::size_t(t[0])], b = scale * mesh.vertices[std::size_t(t[1])],
               c = scale * mesh.vertices[std::size_t(t[2])];
    area_ += 0.5 * (b - a).cross(c - a).norm();
  }
  // Band voxels ~ area / voxel^2 x (2 half-widths + the shell): grow the voxel until they fit.
  const double across = 2.0 * kHalfWidth + 1.0;
  if (area_ * across / (voxel * voxel) > maxBandVoxels) voxel = std::sqrt(area_ * across / maxBandVoxels);
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
  std::vector<openvdb::Vec3s> points;
  points.reserve(mesh.vertices.size());
  lo_ = Vec3::Constant(std::numeric_limits<double>::infinity());
  hi_ = -lo_;
  for (const Vec3& v : mesh.vertices) {
    const Vec3 p = scale * v;
    points.emplace_back(float(p.x()), float(p.y()), float(p.z()));
    lo_ = lo_.cwiseMin(p);
    hi_ = hi_.cwiseMax(p);
  }
  std::vector<openvdb::Vec3I> triangles;
  triangles.reserve(mesh.triangles.size());
  for (const auto& t : mesh.triangles) triangles.emplace_back(openvdb::Index32(t[0]), openvdb::Index32(t[1]), openvdb::Index32(t[2]));
  const auto xform = openvdb::math::Transform::createLinearTransform(voxel);
  impl_->voxel = voxel;
  if (mesh.closed) {
    impl_->grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*xform, points, triangles, kHalfWidth);
  } else {
    // The band must reach past the shell: half the thickness plus the usual half-width.
    const float band = kHalfWidth + float(0.5 * thickness / voxel);
    const std::vector<openvdb::Vec4I> quads;
    impl_->grid = openvdb::tools::meshToUnsignedDistanceField<openvdb::FloatGrid>(*xform, points, triangles, quads, band);
    impl_->shift = float(0.5 * thickness);
  }
  impl_->outside = impl_->grid->background() - impl_->shift;
  const double grow = (kHalfWidth + 1.0) * voxel + 0.5 * thickness;
  reach_ = grow;
  lo_ -= Vec3::Constant(grow);
  hi_ += Vec3::Constant(grow);
}

double ColliderSdf::voxel() const { return impl_->voxel; }
double ColliderSdf::halfThickness() const { return double(impl_->shift); }

ColliderSdf::~ColliderSdf() = default;
ColliderSdf::ColliderSdf(ColliderSdf&&) noexcept = default;
ColliderSdf& ColliderSdf::operator=(ColliderSdf&&) noexcept = default;

bool ColliderSdf::sample(const Vec3& local, double& phi, Vec3& gradient) const {
  const double inv = 1.0 / impl_->voxel;
  // OpenVDB's cell-centred index space: voxel (i,j,k) holds the value at (i,j,k) * voxel.
  const Vec3 u = local * inv;
  const Vec3 f(std::floor(u.x()), std::floor(u.y()), std::floor(u.z()));
  const Vec3 t = u - f;
  const openvdb::Coord base(int(f.x()), int(f.y()), int(f.z()));
  // Unregistered (the tree never changes after construction): a registered accessor costs a
  // concurrent hash-map insert and erase per sample.
  openvdb::FloatGrid::ConstUnsafeAccessor acc = impl_->grid->getConstUnsafeAccessor();
  double c[2][2][2];
  bool anyInBand = false;
  using Leaf = openvdb::FloatGrid::TreeType::LeafNodeType;
  constexpr int kLast = int(Leaf::DIM) - 1;
  const Leaf* leaf = (base.x() & kLast) < kLast && (base.y() & kLast) < kLast && (base.z() & kLast) < kLast
                         ? acc.probeConstLeaf(base)
                         : nullptr;
  if (leaf) {
    // All eight corners in one leaf (most samples): read it directly, one tree walk in all.
    const openvdb::Index first = Leaf::coordToOffset(base);
    for (int a = 0; a < 2; ++a)
      for (int b = 0; b < 2; ++b)
        for (int d = 0; d < 2; ++d) {
          const openvdb::Index n = first + openvdb::Index(a) * Leaf::DIM * Leaf::DIM + openvdb::Index(b) * Leaf::DIM + openvdb::Index(d);
          c[a][b][d] = double(leaf->getValue(n) - impl_->shift);
          anyInBand |= leaf->isValueOn(n) || c[a][b][d] < 0.0;
        }
  } else {
    for (int a = 0; a < 2; ++a)
      for (int b = 0; b < 2; ++b)
        for (int d = 0; d < 2; ++d) {
          const openvdb::Coord ijk = base.offsetBy(a, b, d);
          c[a][b][d] = double(acc.getValue(ijk) - impl_->shift);
          anyInBand |= acc.isValueOn(ijk) || c[a][b][d] < 0.0;
        }
  }
  if (!anyInBand) {
    phi = double(impl_->outside);
    gradient = Vec3::Zero();
    return false;
  }
  const auto lerp = [](double p, double q, double s) { return p + s * (q - p); };
  double cx[2], cy[2], cz[2];  // the field bilinear on the cell's faces x = i, y = i, z = i
  for (int i = 0; i < 2; ++i) {
    cx[i] = lerp(lerp(c[i][0][0], c[i][0][1], t.z()), lerp(c[i][1][0], c[i][1][1], t.z()), t.y());
    cy[i] = lerp(lerp(c[0][i][0], c[0][i][1], t.z()), lerp(c[1][i][0], c[1][i][1], t.z()), t.x());
    cz[i] = lerp(lerp(c[0][0][i], c[0][1][i], t.y()), lerp(c[1][0][i], c[1][1][i], t.y()), t.x());
  }
  phi = lerp(cx[0], cx[1], t.x());
  gradient = Vec3(cx[1] - cx[0], cy[1] - cy[0], cz[1] - cz[0]) * inv;  // exact gradient of the trilinear field
  return true;
}

std::size_t ColliderSdf::bytes() const { return impl_ && impl_->grid ? std::size_t(impl_->grid->memUsage()) : 0; }

}  // namespace physketch::mpm
