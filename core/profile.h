// Passes and their timing. A solver describes its step as one table of passes (an
// enum class plus a PassSpec per enumerator, in enum order); the same table drives
// the step, the printed plan and the Profile, so the plan is the step.
#pragma once

#include <chrono>
#include <cstddef>
#include <string>
#include <type_traits>
#include <vector>

namespace physketch {

// How often a pass runs within one solver step: once, once per substep, or once per
// constraint iteration of every substep (the passes a PBD iteration interleaves).
enum class Cadence { kPerStep, kPerSubstep, kPerIteration };

struct PassSpec {
  const char* name;   // as printed in the plan, the profile and guard records
  Cadence cadence;
  const char* does;   // one line: what the pass computes (paper, equation)
};

// One pass of the plan. plan() lists the passes that have work in the current state;
// planAll() lists every pass of the table, the others with on = false and why.
struct PlanEntry {
  int pass = 0;            // the solver's enum value
  std::string name;
  bool on = true;          // has work now: the step runs it
  long perStep = 0;        // calls per step (0 when off)
  std::string runs;        // how often, in words ("substeps = 4")
  std::string does;        // from the PassSpec
  std::string reason;      // why it is on (which bodies, materials or options need it), or why it is off
  std::string touches;     // what it works on ("31655 particles in 3 bodies"); empty when off
  std::size_t heldBytes = 0;  // what the pass's own buffers hold now (their capacity), kept between steps
};

// Bytes the containers hold (capacity x element size), for PlanEntry::heldBytes.
template <class... C>
std::size_t heldBytes(const C&... c) {
  return (std::size_t(0) + ... + (c.capacity() * sizeof(typename C::value_type)));
}

// Per-pass wall time and call counts, owned by the world that runs the passes (never a global).
class Profile {
 public:
  struct Entry {
    std::string name;      // pass name, as printed in the plan
    double seconds = 0.0;  // accumulated wall time (s)
    long calls = 0;        // times the pass ran
  };

  Profile() = default;
  // One entry per pass of a table, in enum order: entry k is enumerator k.
  template <std::size_t N>
  explicit Profile(const PassSpec (&table)[N]) {
    for (const PassSpec& s : table) entries_.push_back(Entry{s.name, 0.0, 0});
  }

  // Registers a pass by name (for stages without a table, e.g. rendering) and returns its id;
  // registering a name twice returns the first id.
  int add(const std::string& name);
  void record(int id, double seconds) {
    entries_[static_cast<std::size_t>(id)].seconds += seconds;
    entries_[static_cast<std::size_t>(id)].calls += 1;
  }
  template <class E, class = std::enable_if_t<std::is_enum_v<E>>>
  void record(E pass, double seconds) {
    record(static_cast<int>(pass), seconds);
  }
  template <class E, class = std::enable_if_t<std::is_enum_v<E>>>
  const Entry& operator[](E pass) const {
    return entries_.at(static_cast<std::size_t>(pass));
  }
  const std::vector<Entry>& entries() const { return entries_; }
  double total() const;
  void clearTimes();

 private:
  std::vector<Entry> entries_;
};

// Times one scope into a Profile entry.
class ScopedPass {
 public:
  ScopedPass(Profile& profile, int id) : profile_(profile), id_(id), start_(std::chrono::steady_clock::now()) {}
  template <class E, class = std::enable_if_t<std::is_enum_v<E>>>
  ScopedPass(Profile& profile, E pass) : ScopedPass(profile, static_cast<int>(pass)) {}
  ~ScopedPass() {
    profile_.record(id_, std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count());
  }
  ScopedPass(const ScopedPass&) = delete;
  ScopedPass& operator=(const ScopedPass&) = delete;

 private:
  Profile& profile_;
  int id_;
  std::chrono::steady_clock::time_point start_;
};

// Seconds since an arbitrary epoch, for coarse timing in the app and benches.
inline double nowSeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace physketch
