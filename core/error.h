// Errors shared by every module.
//
// InputError is what a user can fix: it names the file, the 1-based line and the
// field of the record that is wrong. The CLI maps it to exit code 1.
// RuntimeError is a failure of the run itself (EGL unavailable, disk full, an
// unstable simulation); the CLI maps it to exit code 2.
#pragma once

#include <stdexcept>
#include <string>

namespace physketch {

class InputError : public std::runtime_error {
 public:
  // file: path as the user gave it; line: 1-based, 0 when the whole file is meant;
  // field: the record field at fault, empty when the whole line is meant.
  InputError(std::string file, int line, std::string field, const std::string& what);

  const std::string& file() const { return file_; }
  int line() const { return line_; }
  const std::string& field() const { return field_; }
  // The message without the "file:line: field 'x':" prefix.
  const std::string& reason() const { return reason_; }

 private:
  std::string file_;
  int line_;
  std::string field_;
  std::string reason_;
};

class RuntimeError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace physketch
