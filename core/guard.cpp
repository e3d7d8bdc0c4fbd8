#include "core/guard.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "core/parallel.h"

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

bool recoverable(GuardKind kind) {
  switch (kind) {
    case GuardKind::kExplosion:
    case GuardKind::kPenetration:
    case GuardKind::kCfl:
    case GuardKind::kCompression:
    case GuardKind::kEnergyGrowth: return true;
    case GuardKind::kNone:
    case GuardKind::kNaN:
    case GuardKind::kInverted: return false;
  }
  return false;
}

void GuardLog::add(const GuardRecord& r) {
  if (!seen(r.kind)) first_.push_back(r);
  ++counts_[static_cast<std::size_t>(r.kind)];
}

long GuardLog::total() const {
  long n = 0;
  for (long c : counts_) n += c;
  return n;
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

std::string knobAdvice(const GuardRecord& r, const KnobState& k) {
  double factor = 2.0;
  if (r.kind == GuardKind::kCfl && r.bound > 0.0 && r.value > r.bound) factor = r.value / r.bound;
  const int s = std::max(1, k.substeps);
  const int more = std::max(s + 1, int(std::ceil(double(s) * factor - 1e-9)));
  std::ostringstream os;
  os.precision(3);
  if (k.substepsAuto) {
    os << "lower 'cfl' from " << k.cfl << " to " << k.cfl / factor << " or less ('substeps auto' chose " << s
       << " substeps for this step)";
    return os.str();
  }
  if (r.kind == GuardKind::kCompression && k.iterations > 0) {
    os << "raise 'iterations' from " << k.iterations << " to at least " << 2 * k.iterations << ", or 'substeps' from "
       << s << " to at least " << more;
    return os.str();
  }
  os << "raise 'substeps' from " << s << " to at least " << more;
  if (k.iterations > 0)
    os << " (more substeps damp what more iterations do not), or 'iterations' from " << k.iterations << " to "
       << 2 * k.iterations;
  else
    os << ", or write 'substeps auto'";
  return os.str();
}

namespace {

// True when some particle may fail: a branch-free pass the compiler vectorizes (x - x is 0
// for a finite x and NaN otherwise; the speed test is run on every particle, prescribed
// or not). Only then does checkParticles scan particle by particle for the first offender.
bool anySuspect(const ParticleArrays& p, double maxSpeed) {
  const std::size_t n = p.size();
  const float max2 = static_cast<float>(maxSpeed * maxSpeed);
  std::vector<std::uint8_t> suspect((n + kChunk - 1) / kChunk, 0);  // per chunk, in parallel
  forRange(n, [&](std::size_t lo, std::size_t hi) {
    float nonFinite = 0.0f, fastest = 0.0f;
    for (std::size_t i = lo; i < hi; ++i) {
      nonFinite += (p.x[i] - p.x[i]) + (p.y[i] - p.y[i]) + (p.z[i] - p.z[i]) + (p.vx[i] - p.vx[i]) +
                   (p.vy[i] - p.vy[i]) + (p.vz[i] - p.vz[i]);
      const float s2 = p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
      fastest = s2 > fastest ? s2 : fastest;
    }
    suspect[lo / kChunk] = nonFinite != 0.0f || !(fastest <= max2 * 0.999f);  // NaN sum, or near/above the bound
  });
  return std::any_of(suspect.begin(), suspect.end(), [](std::uint8_t s) { return s != 0; });
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
           "A non-finite value usually comes from a degenerate constraint.");
      return r;
    }
    // Prescribed particles move as the input says: their speed is not the solver's.
    if (!phase::dynamic(p.phase[i])) continue;
    const double s2 = double(vx) * vx + double(vy) * vy + double(vz) * vz;
    if (s2 > maxSpeed2) {
      fill(i, GuardKind::kExplosion, std::sqrt(s2), maxSpeed,
           "Speed above the bound.");
      return r;
    }
  }
  return r;
}

namespace {

// Blocks of kBlock particles are summed in float across kLanes independent lanes, which the
// compiler vectorizes (a select, not a branch, drops the particles that are not dynamic); the
// blocks run in parallel and are added in double, in order. The order is fixed by the particle
// count alone: the same state gives the same sums for any thread count. Float within a block of 512 loses at
// most ~1e-5 of the sum, far inside the guard's bound (the energy may double what was available).
template <class Id>
EnergySums sumEnergy(const ParticleArrays& p, const Vec3& gravity, std::size_t n, Id id) {
  constexpr std::size_t kLanes = 8, kBlock = 512;
  constexpr std::uint32_t kOut = phase::kPrescribed | phase::kRemoved;
  const float gx = float(gravity.x()), gy = float(gravity.y()), gz = float(gravity.z());
  const float inf = std::numeric_limits<float>::infinity();
  const float *x = p.x.data(), *y = p.y.data(), *z = p.z.data();
  const float *vx = p.vx.data(), *vy = p.vy.data(), *vz = p.vz.data(), *mass = p.mass.data();
  const std::uint32_t* ph = p.phase.data();
  std::vector<EnergySums> blocks((n + kBlock - 1) / kBlock);
  forEach(blocks.size(), [&](std::size_t blockIndex) {
    const std::size_t b = blockIndex * kBlock;
    float k[kLanes] = {}, pe[kLanes] = {}, m[kLanes] = {}, low[kLanes];
    for (float& l : low) l = inf;
    const std::size_t end = std::min(n, b + kBlock);
    auto add = [&](std::size_t at, std::size_t lane) {
      const std::size_t i = id(at);
      const bool dyn = (ph[i] & kOut) == 0;
      const float h = -(gx * x[i] + gy * y[i] + gz * z[i]);
      const float w = dyn ? mass[i] : 0.0f;
      k[lane] += dyn ? w * (vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i]) : 0.0f;
      pe[lane] += dyn ? w * h : 0.0f;
      m[lane] += w;
      low[lane] = dyn ? std::min(low[lane], h) : low[lane];
    };
    std::size_t i = b;
    for (; i + kLanes <= end; i += kLanes)
      for (std::size_t l = 0; l < kLanes; ++l) add(i + l, l);
    for (std::size_t l = 0; i < end; ++i, ++l) add(i, l);
    EnergySums block;
    for (std::size_t l = 0; l < kLanes; ++l) {
      block.kinetic += 0.5 * double(k[l]);
      block.potential += double(pe[l]);
      block.mass += double(m[l]);
      block.lowest = std::min(block.lowest, double(low[l]));
    }
    blocks[blockIndex] = block;
  });
  EnergySums s;
  for (const EnergySums& block : blocks) s.add(block);
  return s;
}

}  // namespace

EnergySums energySums(const ParticleArrays& p, const Vec3& gravity) {
  return sumEnergy(p, gravity, p.size(), [](std::size_t i) { return i; });
}

EnergySums energySums(const ParticleArrays& p, const Vec3& gravity, const std::vector<std::int32_t>& ids) {
  return sumEnergy(p, gravity, ids.size(), [&ids](std::size_t k) { return std::size_t(ids[k]); });
}

void EnergyWatch::arm(const EnergySums& s, const Vec3& gravity, double spacing) {
  if (s.mass <= 0.0 || !std::isfinite(s.kinetic + s.potential)) return;  // nothing to watch yet
  armed_ = true;
  ref_ = s.kinetic + s.potential;
  const double available = s.kinetic + (s.potential - s.mass * s.lowest);
  allowed_ = available + 0.5 * s.mass * 0.25 + s.mass * gravity.norm() * 2.0 * spacing;
}

GuardRecord EnergyWatch::check(const ParticleArrays& p, const Vec3& gravity, double spacing, bool closed) {
  if (!closed) return check(EnergySums{}, p, gravity, spacing, false);  // no sum needed
  return check(energySums(p, gravity), p, gravity, spacing, true);
}

GuardRecord EnergyWatch::check(const EnergySums& s, const ParticleArrays& p, const Vec3& gravity, double spacing,
                               bool closed) {
  GuardRecord r;
  if (!closed) {
    armed_ = false;  // work from outside: a new reference once it stops
    return r;
  }
  if (s.mass <= 0.0 || !std::isfinite(s.kinetic + s.potential)) return r;  // nothing to watch, or NaN: the NaN check's
  const double energy = s.kinetic + s.potential;
  if (!armed_) {
    arm(s, gravity, spacing);
    return r;
  }
  if (energy <= ref_ + allowed_) return r;
  // Tripped (once per run): find the particle with the most kinetic energy, in id order.
  double most = -1.0;
  std::size_t mostAt = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (!phase::dynamic(p.phase[i])) continue;
    const double k = 0.5 * p.mass[i] * (double(p.vx[i]) * p.vx[i] + double(p.vy[i]) * p.vy[i] + double(p.vz[i]) * p.vz[i]);
    if (k > most) {
      most = k;
      mostAt = i;
    }
  }
  r.kind = GuardKind::kEnergyGrowth;
  r.particle = static_cast<std::int32_t>(mostAt);
  r.body = p.group(mostAt);
  r.stroke = p.stroke.empty() ? -1 : p.stroke[mostAt];
  r.value = energy;
  r.bound = ref_ + allowed_;
  return r;
}

}  // namespace physketch
