#include "apps/physketch/video.h"

#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fcntl.h>

#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <vector>

#include "core/error.h"

extern char** environ;

namespace physketch::app {
namespace {

struct ChildResult {
  int status = -1;     // exit code, or -1 when it did not exit normally
  std::string output;  // stdout and stderr together
};

// Runs argv[0] (a path) with argv, no shell (file names may hold spaces or quotes), with stdin
// from /dev/null and stdout + stderr captured.
ChildResult runChild(const std::vector<std::string>& argv) {
  int fds[2];
  if (pipe(fds) != 0) throw RuntimeError(std::string("pipe failed: ") + std::strerror(errno));
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_adddup2(&actions, fds[1], 1);
  posix_spawn_file_actions_adddup2(&actions, fds[1], 2);
  posix_spawn_file_actions_addclose(&actions, fds[0]);
  posix_spawn_file_actions_addclose(&actions, fds[1]);
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  pid_t pid = 0;
  const int rc = posix_spawn(&pid, argv[0].c_str(), &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  close(fds[1]);
  if (rc != 0) {
    close(fds[0]);
    throw RuntimeError("cannot run " + argv[0] + ": " + std::strerror(rc));
  }
  ChildResult r;
  char buf[4096];
  for (;;) {
    const ssize_t n = read(fds[0], buf, sizeof buf);
    if (n > 0) {
      r.output.append(buf, static_cast<std::size_t>(n));
    } else if (n == 0 || errno != EINTR) {
      break;
    }
  }
  close(fds[0]);
  int status = 0;
  while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  r.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

// The last lines of a tool's output, for an error message.
std::string tail(const std::string& text, std::size_t maxChars = 600) {
  return text.size() <= maxChars ? text : "..." + text.substr(text.size() - maxChars);
}

std::string number(double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

}  // namespace

std::string findOnPath(const std::string& name, const std::string& path) {
  std::size_t start = 0;
  for (;;) {
    const std::size_t end = path.find(':', start);
    std::string dir = path.substr(start, end == std::string::npos ? std::string::npos : end - start);
    if (dir.empty()) dir = ".";
    const std::string candidate = dir + "/" + name;
    struct stat st {};
    if (stat(candidate.c_str(), &st) == 0 && S_ISREG(st.st_mode) && access(candidate.c_str(), X_OK) == 0) {
      return candidate;
    }
    if (end == std::string::npos) return "";
    start = end + 1;
  }
}

VideoResult makeVideo(const std::string& ffmpeg, const std::string& framesDir, double fps, int frames,
                      const std::string& output) {
  VideoResult result;
  result.frames = frames;
  // Which encoders this ffmpeg was built with: Debian's has libx264, minimal builds may not.
  const ChildResult encoders = runChild({ffmpeg, "-hide_banner", "-encoders"});
  result.codec = encoders.status == 0 && encoders.output.find(" libx264 ") != std::string::npos ? "libx264" : "mpeg4";

  const std::string tmp = output + ".tmp.mp4";
  std::vector<std::string> argv = {ffmpeg, "-hide_banner", "-loglevel", "error", "-nostdin", "-y",
                                   "-framerate", number(fps), "-start_number", "0",
                                   "-i", framesDir + "/frame_%04d.png",
                                   // yuv420p halves the chroma resolution: both sizes must be even.
                                   "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                                   "-c:v", result.codec, "-pix_fmt", "yuv420p"};
  // mpeg4's default bit rate (200 kb/s) smears a 640x480 frame; -q:v 3 is near transparent.
  if (result.codec == "mpeg4") argv.insert(argv.end(), {"-q:v", "3"});
  argv.insert(argv.end(), {"-f", "mp4", tmp});
  const ChildResult encode = runChild(argv);
  std::error_code ec;
  if (encode.status != 0 || !std::filesystem::is_regular_file(tmp, ec)) {
    std::filesystem::remove(tmp, ec);
    throw RuntimeError("ffmpeg (" + ffmpeg + ") failed to make " + output + " (exit " + std::to_string(encode.status) +
                       "): " + tail(encode.output));
  }
  std::filesystem::rename(tmp, output, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw RuntimeError("cannot rename the video to " + output + ": " + ec.message());
  }
  return result;
}

}  // namespace physketch::app
