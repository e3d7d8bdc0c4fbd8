// Per-pass timing owned by the world that runs the passes (never a global).
#pragma once

#include <chrono>
#include <string>
#include <vector>

namespace physketch {

class Profile {
 public:
  struct Entry {
    std::string name;      // pass name, as printed in the plan
    double seconds = 0.0;  // accumulated wall time (s)
    long calls = 0;        // times the pass ran
  };

  // Registers a pass and returns its id; registering a name twice returns the first id.
  int add(const std::string& name);
  void record(int id, double seconds) {
    entries_[static_cast<std::size_t>(id)].seconds += seconds;
    entries_[static_cast<std::size_t>(id)].calls += 1;
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
