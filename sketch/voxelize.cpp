#include "sketch/voxelize.h"

#include <algorithm>
#include <cmath>

#include "core/error.h"

namespace physketch::sketch {
namespace {

// Thrown inside stampBrush when the cap is reached; voxelize() turns it into an
// InputError that names the stroke.
struct CapReached {};

}  // namespace

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

std::int32_t stampBrush(Sketch& sk, BrushShape shape, double size, const Vec3& position, std::int32_t strokeId,
                        std::int16_t materialId) {
  const GridMapping& m = sk.mapping;
  const double h = m.voxelSize();
  const double half = 0.5 * size;                 // m
  const Vec3 g = m.toGrid(position);              // continuous grid coords of the brush centre
  const double halfCells = half / h;
  const Vec3i lo(static_cast<int>(std::ceil(g.x() - halfCells)), static_cast<int>(std::ceil(g.y() - halfCells)),
                 static_cast<int>(std::ceil(g.z() - halfCells)));
  const Vec3i hi(static_cast<int>(std::floor(g.x() + halfCells)), static_cast<int>(std::floor(g.y() + halfCells)),
                 static_cast<int>(std::floor(g.z() + halfCells)));
  std::int32_t created = 0;
  auto take = [&](const Vec3i& c) {
    if (!GridMapping::inGrid(c)) return;  // Alg. 1: only cells of M
    std::int32_t& cell = sk.grid.at(c);
    if (cell >= 0) return;                // one particle per voxel, never two at one place
    if (static_cast<std::int64_t>(sk.particles.size()) >= kMaxParticles) throw CapReached{};
    const Vec3 q = m.toWorld(c);          // Eq. 5
    cell = sk.particles.push(static_cast<float>(q.x()), static_cast<float>(q.y()), static_cast<float>(q.z()),
                             strokeId, materialId);
    sk.cells.push_back(c);
    ++created;
  };
  bool any = false;
  const double r2 = halfCells * halfCells;
  for (int k = lo.z(); k <= hi.z(); ++k)
    for (int j = lo.y(); j <= hi.y(); ++j)
      for (int i = lo.x(); i <= hi.x(); ++i) {
        const Vec3 d(i - g.x(), j - g.y(), k - g.z());  // cell centre relative to the brush, in cells
        const bool inside = shape == BrushShape::kSphere ? d.squaredNorm() <= r2
                                                         : d.cwiseAbs().maxCoeff() <= halfCells;
        if (!inside) continue;
        any = true;
        take(Vec3i(i, j, k));
      }
  // A brush smaller than a cell covers no cell centre: it still marks the cell it is in.
  if (!any) take(m.discretize(position));
  return created;
}

Sketch voxelize(const StrokeFile& file, const GridMapping& mapping, const std::vector<Material>& materials) {
  Sketch sk(mapping);
  std::vector<Vec3> points;
  const double d = mapping.voxelSize();  // d_particle: one particle per voxel
  for (const Stroke& s : file.strokes) {
    const int mat = findMaterial(materials, s.material);
    if (mat < 0) {
      std::string known;
      for (const auto& mm : materials) known += (known.empty() ? "" : ", ") + mm.name;
      throw InputError(file.path, s.line, "material",
                       "unknown material '" + s.material + "' (the scene defines: " +
                           (known.empty() ? std::string("none") : known) + ")");
    }
    for (const Sample& smp : s.samples) {
      if (!mapping.contains(smp.position)) {
        const Vec3 g = mapping.toGrid(smp.position);
        int axis = 0;
        for (int a = 0; a < 3; ++a)
          if (g[a] < -0.5 || g[a] >= kGridSize - 0.5) { axis = a; break; }
        const char* names[] = {"x", "y", "z"};
        const double lo = mapping.center()[axis] - 0.5 * mapping.size();
        throw InputError(file.path, smp.line, names[axis],
                         "sample outside the workspace (" + std::string(names[axis]) + " must be in [" +
                             std::to_string(lo) + ", " + std::to_string(lo + mapping.size()) + "))");
      }
    }
    StrokeSummary sum;
    sum.id = s.id;
    sum.line = s.line;
    sum.material = static_cast<std::int16_t>(mat);
    sum.first = static_cast<std::int32_t>(sk.particles.size());
    try {
      for (std::size_t k = 0; k < s.samples.size(); ++k) {
        if (k == 0) {
          points.assign(1, s.samples[0].position);
        } else {
          interpolateSegment(s.samples[k - 1].position, s.samples[k].position, d, points);
        }
        for (const Vec3& p : points) {
          sum.count += stampBrush(sk, s.brush, s.size, p, s.id, static_cast<std::int16_t>(mat));
          ++sum.stamps;
        }
      }
    } catch (const CapReached&) {
      throw InputError(file.path, s.line, "", "stroke " + std::to_string(s.id) + " crosses the particle cap of " +
                                                  std::to_string(kMaxParticles) +
                                                  " (20 % of the 151^3 grid); use a smaller brush or fewer strokes");
    }
    sk.strokes.push_back(sum);
  }
  return sk;
}

}  // namespace physketch::sketch
