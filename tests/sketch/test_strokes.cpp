// Stroke file parser: each error class gives its file:line:field message.
#include <gtest/gtest.h>

#include "core/error.h"
#include "sketch/strokes.h"

using namespace physketch;
using namespace physketch::sketch;

namespace {

InputError strokeError(const std::string& text) {
  try {
    parseStrokes(text, "bad.strokes");
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), "bad.strokes");
    return e;
  }
  ADD_FAILURE() << "expected InputError for:\n" << text;
  return InputError("", 0, "", "");
}

}  // namespace

TEST(StrokeFile, ParsesStrokesAndSamples) {
  const StrokeFile f = parseStrokes(
      "physketch-strokes 1\n"
      "stroke create sphere 0.05 wood\n"
      "sample 0 0 0.5 0\n"
      "sample 0.1 0.1 0.5 0 # comment\n"
      "stroke create cube 0.02 stone\n"
      "sample 0.1 0 0.2 0\n",
      "ok.strokes");
  ASSERT_EQ(f.strokes.size(), 2u);
  EXPECT_EQ(f.strokes[0].brush, BrushShape::kSphere);
  EXPECT_DOUBLE_EQ(f.strokes[0].size, 0.05);
  EXPECT_EQ(f.strokes[0].samples.size(), 2u);
  EXPECT_EQ(f.strokes[0].samples[1].line, 4);
  EXPECT_EQ(f.strokes[1].brush, BrushShape::kCube);
  EXPECT_EQ(f.strokes[1].material, "stone");
  EXPECT_EQ(f.strokes[1].id, 1);
}

TEST(StrokeFile, UnknownKeyword) {
  auto e = strokeError("physketch-strokes 1\nstroke create sphere 0.05 wood\nsampel 0 0 0 0\n");
  EXPECT_EQ(e.line(), 3);
  EXPECT_NE(std::string(e.what()).find("unknown record 'sampel'"), std::string::npos);
}

TEST(StrokeFile, MissingAndExtraField) {
  auto e = strokeError("physketch-strokes 1\nstroke create sphere 0.05\n");
  EXPECT_EQ(e.line(), 2);
  EXPECT_EQ(e.field(), "material");
  e = strokeError("physketch-strokes 1\nstroke create sphere 0.05 wood\nsample 0 1 2\n");
  EXPECT_EQ(e.field(), "z");
  e = strokeError("physketch-strokes 1\nstroke create sphere 0.05 wood\nsample 0 1 2 3 4\n");
  EXPECT_NE(std::string(e.what()).find("extra field '4'"), std::string::npos);
}

TEST(StrokeFile, NaNNegativeAndZeroSize) {
  for (const char* size : {"nan", "-0.1", "0", "inf", "1e999", "abc"}) {
    auto e = strokeError(std::string("physketch-strokes 1\nstroke create sphere ") + size + " wood\nsample 0 0 0 0\n");
    EXPECT_EQ(e.line(), 2) << size;
    EXPECT_EQ(e.field(), "size") << size;
  }
  auto e = strokeError("physketch-strokes 1\nstroke create sphere 0.1 wood\nsample 0 nan 0 0\n");
  EXPECT_EQ(e.field(), "x");
}

TEST(StrokeFile, NonMonotonicTime) {
  auto e = strokeError(
      "physketch-strokes 1\nstroke create sphere 0.1 wood\nsample 0.5 0 0 0\nsample 0.5 0 0 0.1\n");
  EXPECT_EQ(e.line(), 4);
  EXPECT_EQ(e.field(), "t");
  e = strokeError(
      "physketch-strokes 1\nstroke create sphere 0.1 wood\nsample 0.5 0 0 0\n"
      "stroke create sphere 0.1 wood\nsample 0.4 0 0 0\n");
  EXPECT_EQ(e.line(), 5);
  e = strokeError("physketch-strokes 1\nstroke create sphere 0.1 wood\nsample -1 0 0 0\n");
  EXPECT_EQ(e.field(), "t");
}

TEST(StrokeFile, UnknownOperationAndBrushAndEmptyStroke) {
  EXPECT_EQ(strokeError("physketch-strokes 1\nstroke paint sphere 0.1 wood\nsample 0 0 0 0\n").field(), "op");
  EXPECT_EQ(strokeError("physketch-strokes 1\nstroke create cone 0.1 wood\nsample 0 0 0 0\n").field(), "brush");
  auto e = strokeError("physketch-strokes 1\nstroke create sphere 0.1 wood\nstroke create sphere 0.1 wood\n"
                       "sample 0 0 0 0\n");
  EXPECT_EQ(e.line(), 2);
  EXPECT_NE(std::string(e.what()).find("no samples"), std::string::npos);
  e = strokeError("physketch-strokes 1\nsample 0 0 0 0\n");
  EXPECT_NE(std::string(e.what()).find("before any"), std::string::npos);
}
