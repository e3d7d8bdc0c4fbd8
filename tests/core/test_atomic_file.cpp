// AtomicFile / writeFileAtomic: the target appears complete or not at all, and no temporary
// is left after any failure. The oracle is the directory listing and the bytes read back.
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <csignal>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <stdexcept>
#include <string>

#include "core/atomic_file.h"
#include "core/error.h"

namespace physketch {
namespace {

namespace fs = std::filesystem;

// A fresh, empty folder per test.
fs::path tempDir(const std::string& name) {
  const fs::path dir =
      fs::path(::testing::TempDir()) / ("physketch_atomic_" + name + "_" + std::to_string(static_cast<long>(::getpid())));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::set<std::string> listing(const fs::path& dir) {
  std::set<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.insert(e.path().filename().string());
  return names;
}

std::string readAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writePlain(const fs::path& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

// Binary content with every byte value, a NUL and no trailing newline: nothing is translated.
std::string sampleBytes(std::size_t n) {
  std::string s(n, '\0');
  for (std::size_t i = 0; i < n; ++i) s[i] = static_cast<char>((i * 131u + 7u) & 0xffu);
  return s;
}

TEST(AtomicFile, WritesExactBytesAndLeavesOnlyTheTarget) {
  const fs::path dir = tempDir("write");
  const std::string bytes = sampleBytes(100000);
  writeFileAtomic((dir / "report.json").string(), bytes);
  EXPECT_EQ(readAll(dir / "report.json"), bytes);
  EXPECT_EQ(listing(dir), std::set<std::string>{"report.json"});

  writeFileAtomic((dir / "empty.txt").string(), "");
  EXPECT_TRUE(fs::exists(dir / "empty.txt"));
  EXPECT_EQ(fs::file_size(dir / "empty.txt"), 0u);
  fs::remove_all(dir);
}

TEST(AtomicFile, ReplacesAnExistingTarget) {
  const fs::path dir = tempDir("replace");
  writePlain(dir / "f", "old contents, longer than the new ones");
  writeFileAtomic((dir / "f").string(), "new");
  EXPECT_EQ(readAll(dir / "f"), "new");
  EXPECT_EQ(listing(dir), std::set<std::string>{"f"});
  fs::remove_all(dir);
}

// The target gets the permissions a plain fopen/ofstream would give it (0666 less the umask),
// not the 0600 of a mkstemp temporary.
TEST(AtomicFile, TargetHasThePermissionsOfAPlainWrite) {
  const fs::path dir = tempDir("mode");
  writePlain(dir / "plain", "x");
  writeFileAtomic((dir / "atomic").string(), "x");
  struct stat plain {}, atomic {};
  ASSERT_EQ(::stat((dir / "plain").c_str(), &plain), 0);
  ASSERT_EQ(::stat((dir / "atomic").c_str(), &atomic), 0);
  EXPECT_EQ(atomic.st_mode & 07777, plain.st_mode & 07777);
  fs::remove_all(dir);
}

TEST(AtomicFile, MissingDirectoryThrowsNamingThePathAndCreatesNothing) {
  const fs::path dir = tempDir("nodir");
  const std::string target = (dir / "no" / "such" / "report.json").string();
  try {
    writeFileAtomic(target, "{}");
    ADD_FAILURE() << "expected RuntimeError";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find(target), std::string::npos) << e.what();
  }
  EXPECT_TRUE(listing(dir).empty());
  fs::remove_all(dir);
}

// rename() onto a non-empty directory fails (EISDIR/ENOTEMPTY) after the whole file was
// written: the temporary must be removed and the directory left alone.
TEST(AtomicFile, FailedRenameRemovesTheTemporary) {
  const fs::path dir = tempDir("rename");
  fs::create_directories(dir / "frame.png" / "inside");
  try {
    writeFileAtomic((dir / "frame.png").string(), sampleBytes(5000));
    ADD_FAILURE() << "expected RuntimeError";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("rename"), std::string::npos) << e.what();
  }
  EXPECT_EQ(listing(dir), std::set<std::string>{"frame.png"});
  EXPECT_TRUE(fs::is_directory(dir / "frame.png" / "inside"));
  fs::remove_all(dir);
}

// An exception between the constructor and commit(): the destructor removes the temporary
// and the old target is untouched.
TEST(AtomicFile, ExceptionBeforeCommitKeepsTheOldTargetAndLeavesNoTemporary) {
  const fs::path dir = tempDir("throw");
  writePlain(dir / "mesh.obj", "old");
  std::string tmp;
  try {
    AtomicFile out((dir / "mesh.obj").string());
    tmp = out.tmpPath();
    ASSERT_GE(std::fputs("half a mesh", out.file()), 0);
    std::fflush(out.file());
    EXPECT_TRUE(fs::exists(tmp));  // the temporary really existed before the throw
    EXPECT_EQ(fs::path(tmp).parent_path(), dir);
    throw std::logic_error("encoder failed");
  } catch (const std::logic_error&) {
  }
  EXPECT_FALSE(tmp.empty());
  EXPECT_EQ(readAll(dir / "mesh.obj"), "old");
  EXPECT_EQ(listing(dir), std::set<std::string>{"mesh.obj"});
  fs::remove_all(dir);
}

TEST(AtomicFile, FailRemovesTheTemporaryAndThrowsNamingThePath) {
  const fs::path dir = tempDir("fail");
  const std::string target = (dir / "f.png").string();
  AtomicFile out(target);
  std::fputs("partial", out.file());
  try {
    out.fail("PNG encoding failed");
    ADD_FAILURE() << "expected RuntimeError";
  } catch (const RuntimeError& e) {
    EXPECT_EQ(std::string(e.what()), target + ": PNG encoding failed");
  }
  EXPECT_TRUE(listing(dir).empty());
  EXPECT_THROW(out.commit(), RuntimeError);  // nothing left to commit
  EXPECT_TRUE(listing(dir).empty());
  fs::remove_all(dir);
}

TEST(AtomicFile, CommitTwiceThrows) {
  const fs::path dir = tempDir("twice");
  AtomicFile out((dir / "f").string());
  std::fputs("once", out.file());
  out.commit();
  EXPECT_THROW(out.commit(), RuntimeError);
  EXPECT_EQ(readAll(dir / "f"), "once");
  EXPECT_EQ(listing(dir), std::set<std::string>{"f"});
  fs::remove_all(dir);
}

// Two writers of one target open at once get distinct temporaries; the last commit wins.
TEST(AtomicFile, ConcurrentWritersOfOneTargetDoNotShareATemporary) {
  const fs::path dir = tempDir("two");
  const std::string target = (dir / "f").string();
  AtomicFile a(target);
  AtomicFile b(target);
  EXPECT_NE(a.tmpPath(), b.tmpPath());
  std::fputs("from a", a.file());
  std::fputs("from b", b.file());
  a.commit();
  b.commit();
  EXPECT_EQ(readAll(dir / "f"), "from b");
  EXPECT_EQ(listing(dir), std::set<std::string>{"f"});
  fs::remove_all(dir);
}

// A full disk, simulated with the file-size limit: writes past RLIMIT_FSIZE fail with EFBIG
// (SIGXFSZ ignored), exactly where ENOSPC would surface. Runs `write` under a 1000-byte limit
// and returns the RuntimeError's message ("" when nothing was thrown).
template <typename Write>
std::string underFileSizeLimit(Write write) {
  struct rlimit saved {};
  if (::getrlimit(RLIMIT_FSIZE, &saved) != 0) return "getrlimit failed";
  struct rlimit small = saved;
  small.rlim_cur = 1000;  // bytes
  const auto oldHandler = std::signal(SIGXFSZ, SIG_IGN);
  if (::setrlimit(RLIMIT_FSIZE, &small) != 0) return "setrlimit failed";
  std::string what;
  try {
    write();
  } catch (const RuntimeError& e) {
    what = e.what();
  }
  ::setrlimit(RLIMIT_FSIZE, &saved);
  std::signal(SIGXFSZ, oldHandler);
  return what;
}

// Large write: fwrite itself comes up short.
TEST(AtomicFile, FullDiskDuringTheWriteKeepsTheOldTargetAndLeavesNoTemporary) {
  const fs::path dir = tempDir("full");
  writePlain(dir / "report.json", "old");
  const std::string what =
      underFileSizeLimit([&] { writeFileAtomic((dir / "report.json").string(), sampleBytes(1 << 20)); });
  EXPECT_NE(what.find("report.json"), std::string::npos) << what;
  EXPECT_EQ(readAll(dir / "report.json"), "old");
  EXPECT_EQ(listing(dir), std::set<std::string>{"report.json"});
  fs::remove_all(dir);
}

// Small write: the bytes wait in stdio's buffer (4 KiB), so the failure first shows in commit's
// flush. The target must not appear truncated.
TEST(AtomicFile, FullDiskAtCommitKeepsTheOldTargetAndLeavesNoTemporary) {
  const fs::path dir = tempDir("full_commit");
  writePlain(dir / "frame.png", "old");
  bool buffered = false;
  const std::string what = underFileSizeLimit([&] {
    AtomicFile out((dir / "frame.png").string());
    const std::string bytes = sampleBytes(3000);
    buffered = std::fwrite(bytes.data(), 1, bytes.size(), out.file()) == bytes.size();
    out.commit();
  });
  EXPECT_TRUE(buffered);  // otherwise this test does not reach commit's check
  EXPECT_NE(what.find("write failed"), std::string::npos) << what;
  EXPECT_EQ(readAll(dir / "frame.png"), "old");
  EXPECT_EQ(listing(dir), std::set<std::string>{"frame.png"});
  fs::remove_all(dir);
}

}  // namespace
}  // namespace physketch
