// Scene file parsing and validation.
#include <gtest/gtest.h>

#include "core/error.h"
#include "core/scene.h"

using namespace physketch;

namespace {

const char* kGood =
    "physketch-scene 1\n"
    "strokes s.strokes\n"
    "workspace 0 0.5 0 2\n"
    "dt 0.01\n"
    "substeps 2\n"
    "iterations 3\n"
    "fps 25\n"
    "duration 1\n"
    "material wood rigid 600 0.5 1 0.5 0\n";

InputError sceneError(const std::string& extra) {
  try {
    parseScene(std::string(kGood) + extra, "dir/x.scene");
  } catch (const InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected InputError for: " << extra;
  return InputError("", 0, "", "");
}

}  // namespace

TEST(Scene, ParsesValuesAndResolvesStrokePathRelativeToScene) {
  const SceneDesc s = parseScene(kGood, "dir/x.scene");
  EXPECT_EQ(s.strokesPath, "dir/s.strokes");
  EXPECT_DOUBLE_EQ(s.workspaceSize, 2.0);
  EXPECT_EQ(s.substeps, 2);
  EXPECT_EQ(s.iterations, 3);
  EXPECT_EQ(s.stepsPerFrame(), 4);   // (1/25) / 0.01
  EXPECT_EQ(s.frameCount(), 26);     // frames at t = 0, 0.04, ..., 1.0
  ASSERT_EQ(s.materials.size(), 1u);
  EXPECT_EQ(s.materials[0].name, "wood");
  EXPECT_FLOAT_EQ(s.materials[0].color[1], 0.5f);
}

TEST(Scene, EveryErrorNamesLineAndField) {
  // kGood has 9 lines; an appended record is on line 10.
  auto e = sceneError("bogus 1\n");
  EXPECT_EQ(e.line(), 10);
  EXPECT_NE(std::string(e.what()).find("unknown record 'bogus'"), std::string::npos);
  e = sceneError("material stone rigid -1 0.5 1 1 1\n");
  EXPECT_EQ(e.field(), "density");
  e = sceneError("material stone rigid 100 nan 1 1 1\n");
  EXPECT_EQ(e.field(), "friction");
  e = sceneError("material stone jelly 100 0.5 1 1 1\n");
  EXPECT_EQ(e.field(), "kind");
  e = sceneError("material wood rigid 100 0.5 1 1 1\n");
  EXPECT_EQ(e.field(), "name");
  e = sceneError("image 640\n");
  EXPECT_EQ(e.field(), "height");
  e = sceneError("gravity 0 inf 0\n");
  EXPECT_EQ(e.field(), "gy");
  e = sceneError("dt 0.02\n");  // duplicate
  EXPECT_NE(std::string(e.what()).find("first given on line 4"), std::string::npos);
  e = sceneError("camera 0 1 0 0 0 0 40\n");  // looking straight down
  EXPECT_EQ(e.field(), "tx");
}

TEST(Scene, FrameIntervalMustBeWholeStepsAndStrokesIsRequired) {
  try {
    parseScene("physketch-scene 1\nstrokes a\ndt 0.01\nfps 30\n", "y.scene");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 4);
    EXPECT_EQ(e.field(), "frames_per_second");
  }
  try {
    parseScene("physketch-scene 1\ndt 0.01\n", "y.scene");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "strokes");
  }
}

TEST(Scene, UnknownAndDuplicatedRecordsNameTheRecordField) {
  auto e = sceneError("bogus 1\n");
  EXPECT_EQ(e.field(), "record") << e.what();
  e = sceneError("substeps 3\n");
  EXPECT_EQ(e.line(), 10);
  EXPECT_EQ(e.field(), "record") << e.what();
  EXPECT_NE(std::string(e.what()).find("first given on line 5"), std::string::npos) << e.what();
}
