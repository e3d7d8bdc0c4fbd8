#include "core/error.h"

namespace physketch {
namespace {
std::string format(const std::string& file, int line, const std::string& field, const std::string& what) {
  std::string s = file;
  if (line > 0) s += ":" + std::to_string(line);
  s += ": ";
  if (!field.empty()) s += "field '" + field + "': ";
  return s + what;
}
}  // namespace

InputError::InputError(std::string file, int line, std::string field, const std::string& what)
    : std::runtime_error(format(file, line, field, what)),
      file_(std::move(file)),
      line_(line),
      field_(std::move(field)),
      reason_(what) {}

}  // namespace physketch
