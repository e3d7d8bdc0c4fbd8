#include "core/guard.h"

#include <cmath>
#include <sstream>

namespace physketch {

const char* toString(GuardKind kind) {
  switch (kind) {
    case GuardKind::kNone: return "none";
    case GuardKind::kNaN: return "nan";
    case GuardKind::kExplosion: return "explosion";
    case GuardKind::kPenetration: return "penetration";
  }
  return "?";
}

std::string GuardRecord::message() const {
  if (!tripped()) return "stable";
  std::ostringstream os;
  os << "stability guard: " << toString(kind) << " at step " << step << " after pass '" << pass << "', particle "
     << particle << " (body " << body << "): value " << value << ", bound " << bound << ". " << hint;
  return os.str();
}

GuardRecord checkParticles(const ParticleArrays& p, const GuardLimits& limits, const std::string& pass,
                           std::int64_t step) {
  GuardRecord r;
  const std::size_t n = p.size();
  const double maxSpeed2 = limits.maxSpeed * limits.maxSpeed;
  const double floorY = limits.groundY + limits.particleRadius - limits.maxPenetration;
  for (std::size_t i = 0; i < n; ++i) {
    const float x = p.x[i], y = p.y[i], z = p.z[i], vx = p.vx[i], vy = p.vy[i], vz = p.vz[i];
    const auto fill = [&](GuardKind k, double value, double bound, const char* hint) {
      r.kind = k;
      r.pass = pass;
      r.step = step;
      r.particle = static_cast<std::int32_t>(i);
      r.body = p.body.empty() ? -1 : p.body[i];
      r.value = value;
      r.bound = bound;
      r.hint = hint;
    };
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z) || !std::isfinite(vx) || !std::isfinite(vy) ||
        !std::isfinite(vz)) {
      fill(GuardKind::kNaN, std::nan(""), 0.0,
           "A non-finite value usually comes from a degenerate constraint; lower 'dt' or raise 'substeps'.");
      return r;
    }
    // Static and kinematic particles (inverse mass 0) move as prescribed: their speed and
    // depth are the input's, not the solver's, so only NaN is checked for them.
    if (!p.invMass.empty() && p.invMass[i] == 0.0f) continue;
    const double s2 = double(vx) * vx + double(vy) * vy + double(vz) * vz;
    if (s2 > maxSpeed2) {
      fill(GuardKind::kExplosion, std::sqrt(s2), limits.maxSpeed,
           "Speed above the bound: raise 'substeps' or 'iterations', or lower 'dt'.");
      return r;
    }
    if (limits.maxPenetration > 0.0 && y < floorY) {
      fill(GuardKind::kPenetration, limits.groundY + limits.particleRadius - y, limits.maxPenetration,
           "Particle deep in the ground: raise 'iterations' or 'substeps'.");
      return r;
    }
  }
  return r;
}

}  // namespace physketch
