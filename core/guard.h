// Stability guard: the record of the first particle whose state is not finite,
// moves faster than a bound, or (solver-specific) sits where it must not, with the
// pass that produced it and the knob to change. The record lives in the world's
// data; a tripped world refuses to step (never a silent reset).
//
// The checks here are the ones every solver shares (NaN/Inf, speed). What a solver
// owns (its ground, its colliders, MPM's J) it checks itself and reports with the
// same record. Solvers check once per step; when that check trips they replay the
// step from its saved start with a check after every pass, so the record names the
// pass that produced the bad value (`--validate` checks after every pass always).
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "core/math.h"
#include "core/particles.h"

namespace physketch {

// kInverted: a deformation gradient with J = det F <= 0 (MPM); kCfl: a particle moved more than
// one grid cell in a substep, or the time-step bound needs more substeps than allowed (MPM);
// kCompression: a fluid's mean compression rho/rho0 - 1 above the bound (PBD fluids: the
// density constraint no longer holds the fluid incompressible), or snow's plastic volume ratio
// J_p at its lower clamp (MPM: its hardening stops growing there); kEnergyGrowth: a closed system
// (no body carried, nothing added, removed or thrown since the reference) gained more
// mechanical energy than it had available (EnergyWatch).
enum class GuardKind { kNone, kNaN, kExplosion, kPenetration, kInverted, kCfl, kCompression, kEnergyGrowth };
const char* toString(GuardKind kind);

struct GuardRecord {
  GuardKind kind = GuardKind::kNone;
  std::string pass;         // pass whose output first failed the check
  std::int64_t step = -1;   // solver step (0-based)
  int substep = -1;         // substep within the step (0-based), -1 for per-step passes
  std::int32_t particle = -1;
  std::int32_t body = -1;   // group of the particle, -1 if none
  std::int32_t stroke = -1; // operation that created it
  std::string material;     // its material's name
  double value = 0.0;       // offending value (speed in m/s, depth in m; NaN for kNaN)
  double bound = 0.0;       // the bound it crossed
  std::string hint;         // the knob to change

  bool tripped() const { return kind != GuardKind::kNone; }
  std::string message() const;
};

// What a solver does when the guard trips (physketch run --guard): stop the run (the default), or,
// for a kind whose state is still worth continuing from, record the event and go on (warn).
enum class GuardPolicy { kStop, kWarn };
// The kinds a run may continue past under GuardPolicy::kWarn: a particle too fast, too deep in
// a collider or the ground, a fluid over-compressed, energy growth, a particle moving more than a
// grid cell in a substep. NaN/Inf and an inverted deformation gradient (J <= 0) always stop: the
// state they leave cannot be stepped meaningfully; so does `substeps auto` needing over 1000.
bool recoverable(GuardKind kind);

// The events a run continued past under GuardPolicy::kWarn: the first record of each kind in
// full (the pass named by a replay, as when the run stops), and how many steps tripped each kind.
class GuardLog {
 public:
  GuardPolicy policy = GuardPolicy::kStop;
  // Whether a record of this kind is logged and the run goes on.
  bool warns(GuardKind kind) const { return policy == GuardPolicy::kWarn && recoverable(kind); }
  // Whether a record of this kind is logged already (a later one is only counted: no replay).
  bool seen(GuardKind kind) const { return count(kind) > 0; }
  void add(const GuardRecord& r);
  long count(GuardKind kind) const { return counts_[static_cast<std::size_t>(kind)]; }
  long total() const;
  const std::vector<GuardRecord>& first() const { return first_; }  // in the order the kinds first tripped

 private:
  std::vector<GuardRecord> first_;
  long counts_[8] = {};
};

// One solver step under the guard, the control flow both solvers share. The solver supplies:
//   run(checkEachPass) -> bool   the step's passes; with checks after every pass it stops at the
//                                first failing one, sets `guard` and returns false
//   endChecks() -> GuardRecord   the end-of-step checks (unvalidated steps)
//   wholeChecks() -> GuardRecord checks with no pass of their own (energy), after a validated step
//   restore()                    back to the state at the step's start
//   settle()                     what follows the passes (carried bodies come to rest at targets)
//   finish()                     completes a tripped record: material, "Fix:" advice
// An unvalidated step that trips is replayed with a check after every pass, so the record names
// the pass (the step is deterministic). Under policy warn a recoverable record is logged, the step
// completed unchecked (rerun from its start when the guard stopped it midway) and the function
// returns true; a kind already logged is only counted (no replay). Returns whether the run goes on.
template <class Run, class EndChecks, class WholeChecks, class Restore, class Settle, class Finish>
bool guardedStep(GuardRecord& guard, GuardLog& log, bool validate, bool checks, std::int64_t step, Run run,
                 EndChecks endChecks, WholeChecks wholeChecks, Restore restore, Settle settle, Finish finish) {
  bool midway = false;  // the guard stopped the step at a pass: the state is not the step's end
  const auto trip = [&](GuardRecord r) {
    r.pass = "guard";
    r.step = step;
    guard = std::move(r);
  };
  if (validate) {
    if (!run(true)) midway = true;
    else if (checks) {
      GuardRecord r = wholeChecks();
      if (r.tripped()) trip(std::move(r));
    }
  } else {
    run(false);
    GuardRecord r = checks ? endChecks() : GuardRecord{};
    if (r.tripped()) {
      if (log.warns(r.kind) && log.seen(r.kind)) {
        trip(std::move(r));  // logged in full before: counted, the step kept as it ran
      } else {
        restore();
        midway = true;
        if (run(true)) {  // cannot happen for a deterministic step; keep the first record
          trip(std::move(r));
          midway = false;
        }
      }
    }
  }
  settle();
  if (!guard.tripped()) return true;
  finish();
  if (!log.warns(guard.kind)) return false;
  log.add(guard);
  guard = GuardRecord{};
  if (midway) {
    restore();
    run(false);
    settle();
  }
  return true;
}

// The checks every solver shares, over particles in id order; returns the first
// offender (kind kNone if all pass) with its particle, body, stroke, value, bound and
// hint filled in (pass, step, substep and material are the caller's to fill).
//  - NaN/Inf in position or velocity, for every particle still in the simulation;
//  - speed above maxSpeed, for particles the solver moves (not prescribed ones:
//    their motion is the input's).
// Deterministic: the same state gives the same record for any thread count.
GuardRecord checkParticles(const ParticleArrays& p, double maxSpeed);

// The settings a guard record's advice names, with this run's values.
struct KnobState {
  int substeps = 1;        // the substeps of the step that tripped (what 'substeps auto' chose, if auto)
  int iterations = 0;      // solver iterations per substep; 0: the solver has none (MPM)
  bool substepsAuto = false;
  double cfl = 0.0;        // the Courant number 'substeps auto' uses
};
// "raise 'substeps' from 4 to at least 7": the knob that would fix the record, with values.
// How much finer: a CFL record by its ratio value / bound (cells moved per substep), every
// other kind by a factor 2. Solvers with iterations are told substeps first (more substeps
// damp what more iterations do not, docs/accuracy.md), except for fluid compression, which
// the density iterations fix. Appended to the record's cause by the solver when it trips.
std::string knobAdvice(const GuardRecord& r, const KnobState& k);

// Energy growth in a closed system, for every solver. The mechanical energy of the dynamic
// particles, E = sum m (v^2 / 2 - g . x), can only fall in a closed system (no work from
// outside: no carried or tool body moving, nothing added, removed or given a velocity) whose
// stored energy (elastic, compression) starts at zero, as a sketch's does: it starts at rest
// shape. A solver that gains energy there is unstable even when no particle is yet fast
// enough for the speed bound (a cloth swept in the wrong order gained 7.9 times its released
// energy before any particle reached 100 m/s). The bound is E_ref + the energy that was
// available at the reference, E_avail = KE + (PE - PE at the lowest particle), i.e. the energy
// may at most double what could have moved anything, plus a floor of M (0.5 m/s)^2 / 2 + M |g|
// 2 h (h: the particle spacing) for push-out of a sketch's contacts at rest and zero gravity.
// Reference: the first check after construction or after the solver's last outside event.
// The terms of E over a set of dynamic particles (or bodies: a solver may sum a rigid body's
// terms from its centre-of-mass motion instead of its particles).
struct EnergySums {
  double kinetic = 0.0;    // J, sum m v^2 / 2
  double potential = 0.0;  // J, sum m h, h = -g . x (J/kg)
  double mass = 0.0;       // kg
  double lowest = std::numeric_limits<double>::infinity();  // J/kg, the lowest h of any of them
  void add(const EnergySums& o) {
    kinetic += o.kinetic;
    potential += o.potential;
    mass += o.mass;
    lowest = lowest < o.lowest ? lowest : o.lowest;
  }
};
// Over every dynamic particle, or over the dynamic ones among ids. One vectorized pass; the
// same state gives the same sums for any thread count.
EnergySums energySums(const ParticleArrays& p, const Vec3& gravity);
EnergySums energySums(const ParticleArrays& p, const Vec3& gravity, const std::vector<std::int32_t>& ids);

class EnergyWatch {
 public:
  // Forget the reference (an outside event: the next check takes a new one).
  void reset() { armed_ = false; }
  // Take the reference now, from sums of the current state: a solver arms at the start of the
  // first step after an event, so that growth within that step is caught too (a check that
  // finds the watch disarmed takes its reference after the step instead).
  void arm(const EnergySums& sums, const Vec3& gravity, double spacing);
  // closed: no body moves by prescription now. Returns a tripped record (kind kEnergyGrowth,
  // value E, bound, the particle with the most kinetic energy; the caller adds the hint, which
  // names its own knobs) or an empty one. Costs one vectorized sum over the particles.
  GuardRecord check(const ParticleArrays& p, const Vec3& gravity, double spacing, bool closed);
  // The same from sums the solver made (p is read only to name the offender when it trips).
  GuardRecord check(const EnergySums& sums, const ParticleArrays& p, const Vec3& gravity, double spacing, bool closed);
  bool armed() const { return armed_; }
  double reference() const { return ref_; }
  double bound() const { return ref_ + allowed_; }

 private:
  bool armed_ = false;
  double ref_ = 0.0, allowed_ = 0.0;
};

}  // namespace physketch
