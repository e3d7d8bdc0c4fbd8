#include "core/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>

#include "core/error.h"

namespace physketch {
namespace {

// Writers opened by this process so far: with the pid, makes each temporary name unique even
// for two threads writing the same target.
std::atomic<unsigned long> gWriterCount{0};

}  // namespace

AtomicFile::AtomicFile(std::string path) : path_(std::move(path)) {
  // The same directory keeps rename() atomic (no cross-filesystem copy).
  tmpPath_ = path_ + ".tmp." + std::to_string(static_cast<long>(::getpid())) + "." +
             std::to_string(gWriterCount.fetch_add(1, std::memory_order_relaxed));
  // O_EXCL: never write through a name some other process already holds (a stale temporary
  // of a killed run with a recycled pid makes this fail loudly instead).
  const int fd = ::open(tmpPath_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
  if (fd < 0) throw RuntimeError(path_ + ": cannot open for writing: " + std::strerror(errno));
  file_ = ::fdopen(fd, "wb");
  if (!file_) {
    const int e = errno;
    ::close(fd);
    std::remove(tmpPath_.c_str());
    throw RuntimeError(path_ + ": cannot open for writing: " + std::strerror(e));
  }
}

AtomicFile::~AtomicFile() { discard(); }

void AtomicFile::discard() noexcept {
  if (file_) std::fclose(file_);
  file_ = nullptr;
  if (!finished_) std::remove(tmpPath_.c_str());
  finished_ = true;
}

void AtomicFile::commit() {
  if (finished_) throw RuntimeError(path_ + ": commit after the file was committed or discarded");
  // fclose flushes the stdio buffer: a full disk may first show up here, so check both.
  errno = 0;
  const bool writeOk = std::fflush(file_) == 0 && !std::ferror(file_);
  const int writeErrno = errno;
  const bool closeOk = std::fclose(file_) == 0;
  const int closeErrno = errno;
  file_ = nullptr;
  if (!writeOk || !closeOk) {
    discard();
    const int e = !writeOk ? writeErrno : closeErrno;
    throw RuntimeError(path_ + ": write failed: " + (e ? std::strerror(e) : "stream error"));
  }
  if (std::rename(tmpPath_.c_str(), path_.c_str()) != 0) {
    const int e = errno;
    discard();
    throw RuntimeError(path_ + ": cannot rename temporary file into place: " + std::strerror(e));
  }
  finished_ = true;
}

void AtomicFile::fail(const std::string& what) {
  discard();
  throw RuntimeError(path_ + ": " + what);
}

void writeFileAtomic(const std::string& path, const std::string& bytes) {
  AtomicFile out(path);
  if (std::fwrite(bytes.data(), 1, bytes.size(), out.file()) != bytes.size()) {
    out.fail(std::string("write failed: ") + std::strerror(errno));
  }
  out.commit();
}

}  // namespace physketch
