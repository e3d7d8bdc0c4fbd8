// fluidKernels and meshFluid (render/fluid_surface.h). The grid that replaces the neighbour
// search is a sparse OpenVDB grid of cells (one particle spacing each), so memory follows the
// particles, not the space they spread over. Besides vdb_bridge.cpp, the one translation unit
// that includes OpenVDB; it uses only the grid, its accessors and the library's pre-instantiated
// erosion (tools::erodeActiveValues), so it compiles in seconds.
#include "render/fluid_surface.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/Morphology.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <mutex>
#include <string>

#include "core/error.h"

namespace physketch::render {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Quadratic B-spline stencil of a point X in cell units (node n at n): nodes base + 0..2.
struct Stencil {
  Vec3i base;
  std::array<Vec3, 3> w;  // w[a](axis): weight of node base(axis) + a
};

Stencil stencilAt(const Vec3& X) {
  Stencil s;
  for (int d = 0; d < 3; ++d) {
    const double b = std::floor(X[d] - 0.5);
    const double f = X[d] - b;  // in [0.5, 1.5)
    s.base[d] = static_cast<int>(b);
    s.w[0][d] = 0.5 * (1.5 - f) * (1.5 - f);
    s.w[1][d] = 0.75 - (f - 1.0) * (f - 1.0);
    s.w[2][d] = 0.5 * (f - 0.5) * (f - 0.5);
  }
  return s;
}

// What a particle reads from the cells around X (cell units; node n at n): every node within
// `reach` cells, weighted by its count times Yu & Turk's 1 - (r / reach)^3, which fades to 0 at
// the edge of the neighbourhood so nothing jumps when a particle crosses a cell. Returns the
// weight sum, the weighted mean offset of the nodes from X (the step of the position smoothing),
// their weighted covariance about that mean (Eq. 13), and how full the neighbourhood is (weighted count over weight: 1 deep inside).
struct Gathered {
  double weightSum = 0.0;
  Vec3 meanOffset = Vec3::Zero();
  Mat3 covariance = Mat3::Zero();
  double fullness = 0.0;
};

// Count(lo, hi, out) writes the counts of the nodes of the box [lo, hi] into out, z fastest
// (at most 9^3 of them: reach <= 4).
constexpr int kMaxGatherBox = 9 * 9 * 9;

template <class Count>
Gathered gather(const Vec3& X, double reach, const Count& count) {
  Gathered g;
  Vec3 sum = Vec3::Zero();
  Mat3 second = Mat3::Zero();
  double kernelSum = 0.0;
  const Vec3i lo = (X.array() - reach).ceil().cast<int>(), hi = (X.array() + reach).floor().cast<int>();
  float counts[kMaxGatherBox];
  if ((hi - lo + Vec3i::Ones()).prod() > kMaxGatherBox)  // reach <= 4 (checkOptions) keeps it within
    throw RuntimeError("meshFluid: the gather box exceeds 9^3 nodes (reach above 4)");
  count(lo, hi, counts);
  // Only the nodes of each row within the ball are visited: the row's z range from its
  // squared distance (widened by a node each side; a squared distance clearly beyond the ball,
  // by a margin far above rounding, is skipped before the root and the division, and the test
  // r >= 1 decides at the ends). The nodes, their order and their operations are those of the
  // whole box: outside the ball nothing is added.
  const double beyond = reach * reach * (1.0 + 1e-9);
  const int ny = hi.y() - lo.y() + 1, nz = hi.z() - lo.z() + 1;
  for (int a = lo.x(); a <= hi.x(); ++a)
    for (int b = lo.y(); b <= hi.y(); ++b) {
      const double ex = double(a) - X.x(), ey = double(b) - X.y(), left = beyond - (ex * ex + ey * ey);
      if (left < 0.0) continue;
      const double half = std::sqrt(left);
      const int c0 = std::max(lo.z(), int(std::floor(X.z() - half)) - 1);
      const int c1 = std::min(hi.z(), int(std::ceil(X.z() + half)) + 1);
      const float* row = counts + (std::ptrdiff_t(a - lo.x()) * ny + (b - lo.y())) * nz;  // node (a, b, lo.z)
      for (int c = c0; c <= c1; ++c) {
        const Vec3 d = Vec3(a, b, c) - X;
        if ((d.x() * d.x() + d.y() * d.y()) + d.z() * d.z() > beyond) continue;
        const double r = d.norm() / reach;
        if (r >= 1.0) continue;
        const double k = 1.0 - r * r * r;
        // An empty node's terms are +-0, which change no sum (they start at +0 and never
        // become -0): added anyway, without a branch.
        const double wt = double(row[c - lo.z()]) * k;
        kernelSum += k;
        g.weightSum += wt;
        sum += wt * d;
        // The lower triangle of (wt d) d^T: all the eigensolver below reads.
        const Vec3 wd = wt * d;
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j <= i; ++j) second(i, j) += wd(i) * d(j);
      }
    }
  second = second.selfadjointView<Eigen::Lower>();
  if (g.weightSum > 0.0) {
    g.meanOffset = sum / g.weightSum;
    // About the weighted mean, as Yu & Turk take it: about X a half-empty neighbourhood would
    // keep the second moment of a full one across the surface (d^2 is the same on both sides).
    g.covariance = second / g.weightSum - g.meanOffset * g.meanOffset.transpose();
  }
  g.fullness = kernelSum > 0.0 ? g.weightSum / kernelSum : 0.0;
  return g;
}

void checkOptions(double spacing, const FluidSurfaceOptions& o) {
  auto fail = [](const std::string& what) { throw RuntimeError("meshFluid: " + what); };
  if (!(spacing > 0.0) || !std::isfinite(spacing)) fail("particle spacing must be finite and > 0 m");
  if (!(o.kernelRadius >= 1.0 && o.kernelRadius <= 4.0)) fail("kernelRadius must be in [1, 4] spacings");
  if (!(o.voxelFraction >= 0.1 && o.voxelFraction <= 1.0)) fail("voxelFraction must be in [0.1, 1]");
  // Below 1.5 spacings a full neighbourhood is the particle's node and its six face neighbours
  // at small weights (at 1 exactly they weigh 0, the covariance vanishes and every kernel is NaN).
  if (!(o.reach >= 1.5 && o.reach <= 4.0)) fail("reach must be in [1.5, 4] spacings");
  if (!(o.ka >= 0.0 && o.ka <= 10.0)) fail("ka must be in [0, 10]");
  if (!(o.lambda >= 0.0 && o.lambda <= 1.0)) fail("lambda must be in [0, 1]");
  if (!(o.sigmaMin > 0.0 && o.sigmaMin <= 1.0 && o.sigmaMax >= 1.0 && o.sigmaMax <= 10.0))
    fail("need 0 < sigmaMin <= 1 <= sigmaMax <= 10");
  if (!(o.ratio >= 1.0 && o.ratio <= 100.0)) fail("ratio must be in [1, 100]");
  if (!(o.sprayFullness >= 0.0 && o.sprayFullness <= 1.0)) fail("sprayFullness must be in [0, 1]");
}

}  // namespace

FluidKernels fluidKernels(const std::vector<Vec3>& positions, double spacing, const FluidSurfaceOptions& options) {
  checkOptions(spacing, options);
  const double R = options.kernelRadius;
  FluidKernels k;
  // The undeformed kernel's integral over one cell volume: 4 pi R^3 * int_0^1 (1 - r^2)^3 r^2 dr
  // = 4 pi R^3 * 16 / 315 (R in spacings): the field inside a fluid of one particle per cell.
  k.interiorField = 64.0 * kPi / 315.0 * R * R * R;
  k.fillRadius = spacing;
  const std::size_t n = positions.size();
  k.centre.resize(n);
  k.inverseAxes.resize(n);
  k.weight.assign(n, 1.0);
  if (n == 0) return k;

  Eigen::AlignedBox3d box;
  for (std::size_t i = 0; i < n; ++i) {
    if (!positions[i].allFinite())
      throw RuntimeError("meshFluid: particle " + std::to_string(i) + " position is not finite");
    box.extend(positions[i]);
  }
  const Mat3 ball = Mat3::Identity() / (R * spacing);
  if (!options.anisotropic) {
    for (std::size_t i = 0; i < n; ++i) {
      k.centre[i] = positions[i];
      k.inverseAxes[i] = ball;
    }
    k.interior.assign(n, 0);
    return k;
  }
  // Cell units: node n of the count grid sits at lo + spacing * n.
  const Vec3 lo = box.min();
  if (((box.max() - lo) / spacing).maxCoeff() > 1e8)
    throw RuntimeError("meshFluid: the particles spread over more than 1e8 spacings");
  auto cellUnits = [&](const Vec3& x) -> Vec3 { return (x - lo) / spacing; };
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });

  // 1. Each particle's count on the cells (quadratic B-spline weights: it adds up to 1), in
  //    particle order.
  openvdb::FloatGrid::Ptr count = openvdb::FloatGrid::create(0.0f);
  {
    openvdb::FloatGrid::Accessor acc = count->getAccessor();
    for (const Vec3& x : positions) {
      const Stencil s = stencilAt(cellUnits(x));
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
          for (int c = 0; c < 3; ++c) {
            const openvdb::Coord node(s.base.x() + a, s.base.y() + b, s.base.z() + c);
            acc.setValue(node, acc.getValue(node) + static_cast<float>(s.w[a].x() * s.w[b].y() * s.w[c].z()));
          }
    }
  }
  // 2. Deep nodes: those whose cube of ceil(reach + 1/2) nodes around is all full (count >= 1/2).
  //    A particle whose nearest node is deep sees a full neighbourhood (its kernel is round and
  //    does not move) and is too far from the surface to shape it: it is not gathered.
  openvdb::BoolGrid::Ptr deep = openvdb::BoolGrid::create(false);
  {
    openvdb::BoolGrid::Accessor acc = deep->getAccessor();
    for (auto it = count->cbeginValueOn(); it; ++it)
      if (*it >= 0.5f) acc.setValueOn(it.getCoord(), true);
  }
  openvdb::tools::erodeActiveValues(deep->tree(), static_cast<int>(std::ceil(options.reach + 0.5)),
                                    openvdb::tools::NN_FACE_EDGE_VERTEX, openvdb::tools::IGNORE_TILES);

  // The covariance a particle deep inside sees (every cell holding one particle), on a node:
  // the scale the singular values are measured against.
  const Gathered inside = gather(Vec3(8.0, 8.0, 8.0), options.reach, [](const Vec3i& a, const Vec3i& b, float* out) {
    std::fill_n(out, (b - a + Vec3i::Ones()).prod(), 1.0f);
  });
  const double sigmaInside = inside.covariance(0, 0);

  // 3. Each particle's kernel from its own neighbourhood: independent, so in parallel; the
  //    grids are only read (one accessor per task).
  k.interior.assign(n, 0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 256), [&](const tbb::blocked_range<std::size_t>& range) {
    openvdb::FloatGrid::ConstAccessor countAcc = count->getConstAccessor();
    openvdb::BoolGrid::ConstAccessor deepAcc = deep->getConstAccessor();
    // The box's counts a run along z at a time, from each leaf's buffer (the accessor's
    // getValue per node cost more than the gather's arithmetic).
    auto countAt = [&countAcc](const Vec3i& a, const Vec3i& b, float* out) {
      using Leaf = openvdb::FloatGrid::TreeType::LeafNodeType;
      for (int x = a.x(); x <= b.x(); ++x)
        for (int y = a.y(); y <= b.y(); ++y)
          for (int z = a.z(); z <= b.z();) {
            const openvdb::Coord ijk(x, y, z);
            const int end = std::min(b.z(), (z & ~int(Leaf::DIM - 1)) + int(Leaf::DIM) - 1);  // this leaf's last z
            if (const Leaf* leaf = countAcc.probeConstLeaf(ijk)) {
              const float* v = leaf->buffer().data() + Leaf::coordToOffset(ijk);
              for (int m = 0; m <= end - z; ++m) *out++ = v[m];
            } else {
              const float v = countAcc.getValue(ijk);  // a tile or the background
              for (int m = 0; m <= end - z; ++m) *out++ = v;
            }
            z = end + 1;
          }
    };
    for (std::size_t i = range.begin(); i != range.end(); ++i) {
      const Vec3 X = cellUnits(positions[i]);
      const Vec3 nearest = (X.array() + 0.5).floor();
      k.centre[i] = positions[i];
      k.inverseAxes[i] = ball;
      if (options.skipDeep && deepAcc.isValueOn(openvdb::Coord(int(nearest.x()), int(nearest.y()), int(nearest.z())))) {
        k.interior[i] = 1;
        continue;
      }
      const Gathered at = gather(X, options.reach, countAt);
      if (at.fullness < options.sprayFullness) {
        // Spray: half the radius, 8x the weight (the same integral).
        k.inverseAxes[i] = 2.0 * ball;
        k.weight[i] = 8.0;
        continue;
      }
      // Eq. 10 (the step to the weighted mean, scaled by ka) and Eq. 12 (blended by lambda).
      const Vec3 smoothed = X + options.lambda * options.ka * at.meanOffset;
      k.centre[i] = lo + spacing * smoothed;
      // Eq. 13-15: principal axes and values of the cells' covariance about their weighted mean
      // (Yu & Turk; PhyVR gathers again around the averaged position, which a particle within
      // one cell of it sees nearly the same).
      Eigen::SelfAdjointEigenSolver<Mat3> eig(at.covariance);
      Vec3 s = eig.eigenvalues() / sigmaInside;
      // Eq. 16 (clamped into [sigmaMin, sigmaMax]) and Eq. 17 (within `ratio` of the largest).
      for (int d = 0; d < 3; ++d) s[d] = std::clamp(s[d], options.sigmaMin, options.sigmaMax);
      const double largest = s.maxCoeff();
      for (int d = 0; d < 3; ++d) s[d] = std::max(s[d], largest / options.ratio);
      // Volume-preserving: the axes' product stays R^3, so every kernel has the same integral
      // and the field inside stays interiorField.
      s /= std::cbrt(s.prod());
      const Vec3 invAxis = (R * spacing * s).cwiseInverse();
      k.inverseAxes[i] = invAxis.asDiagonal() * eig.eigenvectors().transpose();
    }
  });
  return k;
}

TriangleMesh meshFluid(const std::vector<Vec3>& positions, double spacing, const FluidSurfaceOptions& options,
                       FluidSurfaceReport* report) {
  const FluidKernels kernels = fluidKernels(positions, spacing, options);
  const double volume = static_cast<double>(positions.size()) * spacing * spacing * spacing;
  double level = 0.0;
  TriangleMesh mesh = meshKernelField(kernels, options.voxelFraction * spacing, 0.5 * kernels.interiorField,
                                      options.keepVolume ? volume : 0.0, &level);
  if (report) {
    report->level = level / kernels.interiorField;
    report->particleVolume = volume;
    report->meshVolume = enclosedVolume(mesh);
  }
  return mesh;
}

}  // namespace physketch::render
