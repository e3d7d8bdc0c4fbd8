#include <png.h>

#include <csetjmp>
#include <cstdio>

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
constexpr int kRowFilter = PNG_FILTER_SUB;

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
// behaviour); the caller owns every resource. Returns false with err filled on failure.
bool encode(std::FILE* file, const Image& image, PngErrorText* err) {
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
  png_set_compression_level(png, kCompressionLevel);
  png_set_filter(png, PNG_FILTER_TYPE_BASE, kRowFilter);
  png_set_IHDR(png, info, static_cast<png_uint_32>(image.width), static_cast<png_uint_32>(image.height), 8,
               PNG_COLOR_TYPE_RGBA, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  const std::size_t stride = static_cast<std::size_t>(image.width) * 4;
  for (int y = 0; y < image.height; ++y) {
    png_write_row(png, image.rgba.data() + static_cast<std::size_t>(y) * stride);
  }
  png_write_end(png, info);
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
  AtomicFile out(path);
  PngErrorText err;
  if (!encode(out.file(), image, &err)) out.fail(std::string("PNG encoding failed: ") + err.text);
  out.commit();
}

}  // namespace physketch::render
