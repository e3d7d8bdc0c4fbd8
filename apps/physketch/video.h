// physketch run --video: DIR/video.mp4 from DIR/frames/frame_NNNN.png through ffmpeg, an
// optional run-time tool (not a build dependency): without it the run says so and goes on.
#pragma once

#include <string>

namespace physketch::app {

// The first executable regular file `name` in the ':'-separated directories of `path` (an
// empty entry is the current directory, as in POSIX); "" when there is none.
std::string findOnPath(const std::string& name, const std::string& path);

struct VideoResult {
  std::string codec;  // "libx264" or "mpeg4"
  int frames = 0;
};

// Runs `ffmpeg` on framesDir/frame_%04d.png (frame 0 first) at `fps` frames per second and
// writes `output` atomically (ffmpeg writes "<output>.tmp.mp4", renamed when it succeeds):
// H.264 (libx264) when this ffmpeg has it, else MPEG-4 part 2; yuv420p pixels (what players
// expect), odd image sizes padded to even by one row or column. Throws RuntimeError with
// ffmpeg's messages when it fails (no output file is left).
VideoResult makeVideo(const std::string& ffmpeg, const std::string& framesDir, double fps, int frames,
                      const std::string& output);

}  // namespace physketch::app
