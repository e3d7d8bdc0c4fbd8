#include "render/atomic_file.h"

#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "core/error.h"

namespace physketch::render::detail {

AtomicFile::AtomicFile(std::string path) : path_(std::move(path)) {
  // The pid keeps two processes writing the same target from sharing a temporary file;
  // the same directory keeps rename() atomic (no cross-filesystem copy).
  tmpPath_ = path_ + ".tmp." + std::to_string(static_cast<long>(::getpid()));
  file_ = std::fopen(tmpPath_.c_str(), "wb");
  if (!file_) {
    throw RuntimeError(path_ + ": cannot open for writing: " + std::strerror(errno));
  }
}

AtomicFile::~AtomicFile() {
  if (file_) std::fclose(file_);
  if (!finished_) std::remove(tmpPath_.c_str());
}

void AtomicFile::commit() {
  // fclose flushes the stdio buffer: a full disk may first show up here, so check both.
  const bool writeOk = std::fflush(file_) == 0 && !std::ferror(file_);
  const int savedErrno = errno;
  const bool closeOk = std::fclose(file_) == 0;
  file_ = nullptr;
  if (!writeOk || !closeOk) {
    std::remove(tmpPath_.c_str());
    throw RuntimeError(path_ + ": write failed: " + std::strerror(writeOk ? errno : savedErrno));
  }
  if (std::rename(tmpPath_.c_str(), path_.c_str()) != 0) {
    const int e = errno;
    std::remove(tmpPath_.c_str());
    throw RuntimeError(path_ + ": cannot rename temporary file into place: " + std::strerror(e));
  }
  finished_ = true;
}

void AtomicFile::fail(const std::string& what) {
  if (file_) std::fclose(file_);
  file_ = nullptr;
  std::remove(tmpPath_.c_str());
  finished_ = true;  // nothing left for the destructor to remove
  throw RuntimeError(path_ + ": " + what);
}

}  // namespace physketch::render::detail
