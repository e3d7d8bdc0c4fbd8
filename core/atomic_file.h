// Atomic file output: write under a temporary name in the target's directory, then rename it
// over the target. A reader sees the old file or the complete new one, never a partial file,
// and a failed write (exception, full disk, failed rename) leaves neither a partial target
// nor a temporary behind. Used for every file physketch writes (frames, meshes, report.json).
//
// Atomic against the process failing, not against power loss: nothing is fsync'ed, since a
// disk flush per frame would cost more than rendering it, and every output can be re-made.
#pragma once

#include <cstdio>
#include <string>

namespace physketch {

// A streamed atomic write (PNG, OBJ): write to file(), then commit().
class AtomicFile {
 public:
  // Creates "<path>.tmp.<pid>.<n>" (n counts the writers this process has opened, so two
  // writers of one target never share a temporary) for binary writing, with the permissions
  // a plain fopen would give (0666 less the umask). Throws RuntimeError naming `path`.
  explicit AtomicFile(std::string path);
  // Removes the temporary file unless commit() succeeded (e.g. an exception between the
  // constructor and commit()).
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  std::FILE* file() const { return file_; }
  const std::string& tmpPath() const { return tmpPath_; }
  // Flushes, closes and renames onto the target. On failure removes the temporary and throws
  // RuntimeError naming `path` (a full disk surfaces here as a failed write or close).
  // Throws if called twice or after fail().
  void commit();
  // Closes and removes the temporary file, then throws RuntimeError("<path>: <what>").
  [[noreturn]] void fail(const std::string& what);

 private:
  void discard() noexcept;  // closes and removes the temporary, if still there

  std::string path_;
  std::string tmpPath_;
  std::FILE* file_ = nullptr;
  bool finished_ = false;  // committed or discarded: the temporary no longer exists
};

// Writes `bytes` to `path` atomically (small text files such as report.json).
// Throws RuntimeError naming `path`; on failure no temporary is left behind.
void writeFileAtomic(const std::string& path, const std::string& bytes);

}  // namespace physketch
