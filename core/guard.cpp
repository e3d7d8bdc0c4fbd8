#include "core/guard.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace physketch {

const char* toString(GuardKind kind) {
  switch (kind) {
    case GuardKind::kNone: return "none";
    case GuardKind::kNaN: return "nan";
    case GuardKind::kExplosion: return "explosion";
    case GuardKind::kPenetration: return "penetration";
    case GuardKind::kInverted: return "inverted";
    case GuardKind::kCfl: return "cfl";
    case GuardKind::kCompression: return "compression";
    case GuardKind::kEnergyGrowth: return "energy_growth";
  }
  return "?";
}

std::string GuardRecord::message() const {
  if (!tripped()) return "stable";
  std::ostringstream os;
  os << "stability guard: " << toString(kind) << " at step " << step;
  if (substep >= 0) os << " substep " << substep;
  os << " in pass '" << pass << "', particle " << particle << " (body " << body << ", stroke " << stroke;
  if (!material.empty()) os << ", material " << material;
  os << "): value " << value << ", bound " << bound << ". " << hint;
  return os.str();
}

namespace {

// True when some particle may fail: a branch-free pass the compiler vectorizes (x - x is 0
// for a finite x and NaN otherwise; the speed test is run on every particle, prescribed
// or not). Only then does checkParticles scan particle by particle for the first offender.
bool anySuspect(const ParticleArrays& p, double maxSpeed) {
  const std::size_t n = p.size();
  const float max2 = static_cast<float>(maxSpeed * maxSpeed);
  float nonFinite = 0.0f, fastest = 0.0f;
  for (std::size_t i = 0; i < n; ++i) {
    nonFinite += (p.x[i] - p.x[i]) + (p.y[i] - p.y[i]) + (p.z[i] - p.z[i]) + (p.vx[i] - p.vx[i]) +
                 (p.vy[i] - p.vy[i]) + (p.vz[i] - p.vz[i]);
    const float s2 = p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
    fastest = s2 > fastest ? s2 : fastest;
  }
  return nonFinite != 0.0f || !(fastest <= max2 * 0.999f);  // NaN sum, or near/above the bound
}

}  // namespace

GuardRecord checkParticles(const ParticleArrays& p, double maxSpeed) {
  GuardRecord r;
  if (!anySuspect(p, maxSpeed)) return r;
  const std::size_t n = p.size();
  const double maxSpeed2 = maxSpeed * maxSpeed;
  const auto fill = [&](std::size_t i, GuardKind k, double value, double bound, const char* hint) {
    r.kind = k;
    r.particle = static_cast<std::int32_t>(i);
    r.body = p.group(i);
    r.stroke = p.stroke.empty() ? -1 : p.stroke[i];
    r.value = value;
    r.bound = bound;
    r.hint = hint;
  };
  for (std::size_t i = 0; i < n; ++i) {
    if (phase::has(p.phase[i], phase::kRemoved)) continue;
    const float x = p.x[i], y = p.y[i], z = p.z[i], vx = p.vx[i], vy = p.vy[i], vz = p.vz[i];
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z) || !std::isfinite(vx) || !std::isfinite(vy) ||
        !std::isfinite(vz)) {
      fill(i, GuardKind::kNaN, std::nan(""), 0.0,
           "A non-finite value usually comes from a degenerate constraint; lower 'dt' or raise 'substeps'.");
      return r;
    }
    // Prescribed particles move as the input says: their speed is not the solver's.
    if (!phase::dynamic(p.phase[i])) continue;
    const double s2 = double(vx) * vx + double(vy) * vy + double(vz) * vz;
    if (s2 > maxSpeed2) {
      fill(i, GuardKind::kExplosion, std::sqrt(s2), maxSpeed,
           "Speed above the bound: raise 'substeps' or 'iterations', or lower 'dt'.");
      return r;
    }
  }
  return r;
}

GuardRecord EnergyWatch::check(const ParticleArrays& p, const Vec3& gravity, double spacing, bool closed,
                               const std::string& hint) {
  GuardRecord r;
  if (!closed) {
    armed_ = false;  // work from outside: a new reference once it stops
    return r;
  }
  // Sums in double, in id order: the same state gives the same sums for any thread count.
  double kinetic = 0.0, potential = 0.0, mass = 0.0, lowest = std::numeric_limits<double>::infinity(), most = -1.0;
  std::size_t mostAt = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (!phase::dynamic(p.phase[i]) || phase::has(p.phase[i], phase::kRemoved)) continue;
    const double m = p.mass[i];
    const double k = 0.5 * m * (double(p.vx[i]) * p.vx[i] + double(p.vy[i]) * p.vy[i] + double(p.vz[i]) * p.vz[i]);
    const double height = -(gravity.x() * p.x[i] + gravity.y() * p.y[i] + gravity.z() * p.z[i]);  // J/kg
    kinetic += k;
    potential += m * height;
    mass += m;
    lowest = std::min(lowest, height);
    if (k > most) {
      most = k;
      mostAt = i;
    }
  }
  if (mass <= 0.0 || !std::isfinite(kinetic + potential)) return r;  // nothing to watch, or NaN: the NaN check's
  const double energy = kinetic + potential;
  if (!armed_) {
    armed_ = true;
    ref_ = energy;
    const double available = kinetic + (potential - mass * lowest);
    allowed_ = available + 0.5 * mass * 0.25 + mass * gravity.norm() * 2.0 * spacing;
    return r;
  }
  if (energy <= ref_ + allowed_) return r;
  r.kind = GuardKind::kEnergyGrowth;
  r.particle = static_cast<std::int32_t>(mostAt);
  r.body = p.group(mostAt);
  r.stroke = p.stroke.empty() ? -1 : p.stroke[mostAt];
  r.value = energy;
  r.bound = ref_ + allowed_;
  r.hint = hint;
  return r;
}

}  // namespace physketch
