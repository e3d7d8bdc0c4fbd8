#include "pbd/constraints.h"

#include <cmath>

#include "pbd/parallel.h"

namespace physketch::pbd {

namespace {

void solveRange(DistanceConstraints& c, std::size_t lo, std::size_t hi, float* px, float* py, float* pz,
                const float* invMass, double invH2) {
  for (std::size_t k = lo; k < hi; ++k) {
    const auto a = static_cast<std::size_t>(c.i[k]), b = static_cast<std::size_t>(c.j[k]);
    const double wa = invMass[a], wb = invMass[b];
    const double dx = double(px[a]) - px[b], dy = double(py[a]) - py[b], dz = double(pz[a]) - pz[b];
    const double len = std::sqrt(dx * dx + dy * dy + dz * dz);
    const double alpha = c.compliance[k] * invH2;
    const double w = wa + wb + alpha;
    if (len == 0.0 || w == 0.0) continue;  // coincident ends have no gradient; two fixed ends cannot move
    const double C = len - c.rest[k];
    const double dlambda = (-C - alpha * c.lambda[k]) / w;
    c.lambda[k] = static_cast<float>(c.lambda[k] + dlambda);
    const double nx = dx / len, ny = dy / len, nz = dz / len;
    px[a] = static_cast<float>(px[a] + wa * dlambda * nx);
    py[a] = static_cast<float>(py[a] + wa * dlambda * ny);
    pz[a] = static_cast<float>(pz[a] + wa * dlambda * nz);
    px[b] = static_cast<float>(px[b] - wb * dlambda * nx);
    py[b] = static_cast<float>(py[b] - wb * dlambda * ny);
    pz[b] = static_cast<float>(pz[b] - wb * dlambda * nz);
  }
}

}  // namespace

void solveDistances(DistanceConstraints& c, float* px, float* py, float* pz, const float* invMass, double h) {
  const double invH2 = 1.0 / (h * h);
  const std::size_t n = c.size();
  for (std::size_t lo = 0; lo < n;) {
    std::size_t hi = lo + 1;
    if (c.colour[lo] >= 0)
      while (hi < n && c.colour[hi] == c.colour[lo]) ++hi;
    forRange(hi - lo, [&](std::size_t a, std::size_t b) { solveRange(c, lo + a, lo + b, px, py, pz, invMass, invH2); });
    lo = hi;
  }
}

}  // namespace physketch::pbd
