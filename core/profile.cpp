#include "core/profile.h"

namespace physketch {

int Profile::add(const std::string& name) {
  for (std::size_t i = 0; i < entries_.size(); ++i)
    if (entries_[i].name == name) return static_cast<int>(i);
  entries_.push_back(Entry{name, 0.0, 0});
  return static_cast<int>(entries_.size() - 1);
}

double Profile::total() const {
  double t = 0.0;
  for (const auto& e : entries_) t += e.seconds;
  return t;
}

void Profile::clearTimes() {
  for (auto& e : entries_) {
    e.seconds = 0.0;
    e.calls = 0;
  }
}

}  // namespace physketch
