// Stability guard: finds the first particle whose state is not finite, moves
// faster than a bound, or sits deeper inside the ground than a bound, and
// records it with the pass that ran last and the knob to change. The record
// lives in the world's data; a tripped world refuses to step (never a silent reset).
#pragma once

#include <cstdint>
#include <string>

#include "core/particles.h"

namespace physketch {

enum class GuardKind { kNone, kNaN, kExplosion, kPenetration };
const char* toString(GuardKind kind);

struct GuardLimits {
  double maxSpeed = 100.0;        // m/s; faster is an explosion
  double groundY = 0.0;           // m; ground plane height
  double maxPenetration = 0.0;    // m; deeper below groundY + radius is a penetration (<= 0 disables)
  double particleRadius = 0.0;    // m
};

struct GuardRecord {
  GuardKind kind = GuardKind::kNone;
  std::string pass;       // pass that ran last before the check
  std::int64_t step = -1; // solver step (0-based)
  std::int32_t particle = -1;
  std::int32_t body = -1;
  double value = 0.0;     // offending value (speed in m/s, depth in m; NaN for kNaN)
  double bound = 0.0;     // the bound it crossed
  std::string hint;       // the knob to change

  bool tripped() const { return kind != GuardKind::kNone; }
  std::string message() const;
};

// Checks particles in id order and returns the first offender (kind kNone if all pass).
// Deterministic: the same state gives the same record for any thread count.
GuardRecord checkParticles(const ParticleArrays& p, const GuardLimits& limits, const std::string& pass,
                           std::int64_t step);

}  // namespace physketch
