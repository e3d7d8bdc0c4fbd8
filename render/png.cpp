#include <png.h>
#include <tbb/parallel_for.h>
#include <zlib.h>

#include <algorithm>
#include <atomic>
#include <csetjmp>
#include <cstdio>
#include <vector>

#include "core/atomic_file.h"
#include "core/error.h"
#include "render/renderer.h"

namespace physketch::render {
namespace {

// zlib level 3: measured 31-35 ms for 1280x720 RGBA (docs: stack.md §3); the default level 6
// costs roughly twice that for a few percent smaller frames.
constexpr int kCompressionLevel = 3;
// One row filter (Sub: each byte minus the one four to its left) instead of libpng's default,
// which tries all five per row and keeps the best: on bench_render's 1280x720 frame 12-19 ms
// instead of 42-46 ms, and 107 KB instead of 108 KB (rendered images have long flat runs,
// which Sub turns into zeros). No filter: 9-13 ms but 5-9 % larger files.
constexpr png_byte kSubFilter = 1;  // the filter-type byte that starts a Sub row
// The image data is deflated in bands of this many rows, side by side: each band a run of raw
// deflate blocks ending byte-aligned (Z_SYNC_FLUSH; the last one Z_FINISH), which concatenate
// into one zlib stream (PNG's IDAT) whose Adler-32 is the bands' combined. A fixed band height,
// not one per thread, so the file's bytes do not depend on the thread count. Each band starts
// with an empty window: 128-row bands cost 0.1 % in size on bench_render's frame.
constexpr int kBandRows = 128;

// The zlib stream of the Sub-filtered image (what libpng's png_write_row would make of it,
// but deflated in bands in parallel). Empty on a zlib failure.
std::vector<png_byte> deflateImage(const Image& image) {
  const std::size_t stride = static_cast<std::size_t>(image.width) * 4, row = stride + 1;
  const int bands = (image.height + kBandRows - 1) / kBandRows;
  std::vector<std::vector<png_byte>> parts(static_cast<std::size_t>(bands));
  std::vector<uLong> adler(static_cast<std::size_t>(bands), 0);
  std::vector<std::size_t> lengths(static_cast<std::size_t>(bands), 0);
  std::atomic<bool> ok{true};
  tbb::parallel_for(0, bands, [&](int b) {
    const int y0 = b * kBandRows, y1 = std::min(image.height, y0 + kBandRows);
    std::vector<png_byte> filtered(row * static_cast<std::size_t>(y1 - y0));
    for (int y = y0; y < y1; ++y) {
      const png_byte* in = image.rgba.data() + static_cast<std::size_t>(y) * stride;
      png_byte* out = filtered.data() + static_cast<std::size_t>(y - y0) * row;
      out[0] = kSubFilter;
      for (std::size_t x = 0; x < stride; ++x) out[1 + x] = png_byte(in[x] - (x >= 4 ? in[x - 4] : 0));
    }
    adler[std::size_t(b)] = adler32(adler32(0L, Z_NULL, 0), filtered.data(), static_cast<uInt>(filtered.size()));
    lengths[std::size_t(b)] = filtered.size();
    struct Deflater {  // deflateEnd on every way out
      z_stream z{};
      bool open = false;
      ~Deflater() {
        if (open) deflateEnd(&z);
      }
    } d;
    if (deflateInit2(&d.z, kCompressionLevel, Z_DEFLATED, -15, 8, Z_DEFAULT_STRATEGY) != Z_OK) {
      ok = false;
      return;
    }
    d.open = true;
    std::vector<png_byte>& part = parts[std::size_t(b)];
    // deflateBound is for Z_FINISH; a sync flush adds an empty stored block (5 bytes).
    part.resize(deflateBound(&d.z, static_cast<uLong>(filtered.size())) + 16);
    d.z.next_in = filtered.data();
    d.z.avail_in = static_cast<uInt>(filtered.size());
    d.z.next_out = part.data();
    d.z.avail_out = static_cast<uInt>(part.size());
    const int last = b + 1 == bands;
    const int status = deflate(&d.z, last ? Z_FINISH : Z_SYNC_FLUSH);
    // A sync flush that filled the output may be unfinished: zlib then leaves no room.
    if (status != (last ? Z_STREAM_END : Z_OK) || d.z.avail_in != 0 || d.z.avail_out == 0) ok = false;
    part.resize(part.size() - d.z.avail_out);
  });
  if (!ok) return {};
  // zlib header (deflate, 32 KiB window, FLEVEL 1 "fast": (0x78 * 256 + 0x5E) % 31 == 0), the
  // bands' raw deflate data, and the Adler-32 of all the filtered bytes, big-endian.
  std::vector<png_byte> stream{0x78, 0x5E};
  uLong sum = adler[0];
  for (std::size_t b = 0; b < parts.size(); ++b) {
    stream.insert(stream.end(), parts[b].begin(), parts[b].end());
    if (b > 0) sum = adler32_combine(sum, adler[b], static_cast<z_off_t>(lengths[b]));
  }
  for (int shift = 24; shift >= 0; shift -= 8) stream.push_back(png_byte((sum >> shift) & 0xff));
  return stream;
}

struct PngErrorText {
  char text[256] = {0};
};

void onPngError(png_structp png, png_const_charp message) {
  auto* err = static_cast<PngErrorText*>(png_get_error_ptr(png));
  std::snprintf(err->text, sizeof(err->text), "%s", message);
  // libpng requires the error handler not to return; it unwinds to the setjmp in encode().
  png_longjmp(png, 1);
}

void onPngWarning(png_structp, png_const_charp) {}

// libpng reports errors by longjmp. This function therefore holds no C++ object with a
// destructor between setjmp and the last libpng call (a longjmp across one is undefined
// behaviour); the caller owns every resource. libpng writes the signature, IHDR and the
// chunks' framing and CRCs; the image data is `idat`, deflateImage's stream, written as one
// IDAT chunk. Returns false with err filled on failure.
bool encode(std::FILE* file, const Image& image, const std::vector<png_byte>& idat, PngErrorText* err) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, err, onPngError, onPngWarning);
  if (!png) {
    std::snprintf(err->text, sizeof(err->text), "png_create_write_struct failed");
    return false;
  }
  png_infop info = png_create_info_struct(png);
  if (!info) {
    png_destroy_write_struct(&png, nullptr);
    std::snprintf(err->text, sizeof(err->text), "png_create_info_struct failed");
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return false;
  }
  png_init_io(png, file);
  png_set_IHDR(png, info, static_cast<png_uint_32>(image.width), static_cast<png_uint_32>(image.height), 8,
               PNG_COLOR_TYPE_RGBA, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  png_write_chunk(png, reinterpret_cast<png_const_bytep>("IDAT"), idat.data(), idat.size());
  png_write_chunk(png, reinterpret_cast<png_const_bytep>("IEND"), nullptr, 0);
  png_destroy_write_struct(&png, &info);
  return true;
}

}  // namespace

void writePng(const std::string& path, const Image& image) {
  if (image.width <= 0 || image.height <= 0 ||
      image.rgba.size() != static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height) * 4) {
    throw RuntimeError(path + ": invalid image " + std::to_string(image.width) + "x" +
                       std::to_string(image.height) + " with " + std::to_string(image.rgba.size()) + " bytes");
  }
  const std::vector<png_byte> idat = deflateImage(image);
  if (idat.empty()) throw RuntimeError(path + ": PNG encoding failed: zlib could not deflate the image");
  if (idat.size() > 0x7fffffffu) throw RuntimeError(path + ": PNG encoding failed: image data over 2 GiB");
  AtomicFile out(path);
  PngErrorText err;
  if (!encode(out.file(), image, idat, &err)) out.fail(std::string("PNG encoding failed: ") + err.text);
  out.commit();
}

}  // namespace physketch::render
