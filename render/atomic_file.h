// Private helper of the render module: write a file under a temporary name in the same
// directory, then rename it over the target, so that a reader never sees a partial file
// and a failed write leaves nothing behind. Not installed, not used outside render/.
#pragma once

#include <cstdio>
#include <string>

namespace physketch::render::detail {

class AtomicFile {
 public:
  // Opens "<path>.tmp.<pid>" for binary writing. Throws RuntimeError naming `path`.
  explicit AtomicFile(std::string path);
  // Removes the temporary file unless commit() succeeded.
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  std::FILE* file() const { return file_; }
  // Flushes, closes and renames onto the target. Throws RuntimeError naming `path`
  // (e.g. disk full surfaces here as a failed write or close).
  void commit();
  // Closes and removes the temporary file, then throws RuntimeError("<path>: <what>").
  [[noreturn]] void fail(const std::string& what);

 private:
  std::string path_;
  std::string tmpPath_;
  std::FILE* file_ = nullptr;
  bool finished_ = false;
};

}  // namespace physketch::render::detail
