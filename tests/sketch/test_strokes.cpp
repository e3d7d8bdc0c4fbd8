// Stroke file parser: every record, and each error class with its file:line:field message.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

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

const std::string kHead = "physketch-strokes 1\n";

}  // namespace

TEST(StrokeFile, ParsesEveryRecord) {
  const StrokeFile f = parseStrokes(kHead +
                                        "snap 0.01\n"                                              // 2
                                        "mirror x 0.1\n"                                           // 3
                                        "stroke create capsule 0.05 wood orient=follow length=0.1 body=chair\n"  // 4
                                        "sample 0 0.004 0.5 0\n"                                   // 5
                                        "sample 0.1 0.1 0.5 0 0.5 # half pressure\n"               // 6
                                        "mirror off\n"                                             // 7
                                        "stroke remove cube 0.02 axis=1,0,0\n"                     // 8
                                        "sample 0.1 0 0.2 0\n"                                     // 9
                                        "primitive torus stone 0.2  0 0.5 0  0.1 0.03 rot=1,0,0,90\n"  // 10
                                        "stamp meshes/cube.obj stone 0.3 scale=0.1 at=0,0.5,0\n"   // 11
                                        "undo 2\n"                                                 // 12
                                        "redo\n"                                                   // 13
                                        "play 1.5\n",                                              // 14
                                    "dir/ok.strokes");
  ASSERT_EQ(f.operations.size(), 4u);
  const Operation& a = f.operations[0];
  EXPECT_EQ(a.line, 4);
  EXPECT_EQ(a.stroke.brush, BrushShape::kCapsule);
  EXPECT_EQ(a.stroke.orient, Orientation::kFollow);
  EXPECT_DOUBLE_EQ(a.stroke.length, 0.1);
  EXPECT_EQ(a.body, "chair");
  EXPECT_EQ(a.mirror.axis, 0);
  EXPECT_DOUBLE_EQ(a.mirror.offset, 0.1);
  EXPECT_DOUBLE_EQ(a.stroke.samples[0].position.x(), 0.0);  // snapped to 1 cm
  EXPECT_DOUBLE_EQ(a.stroke.samples[1].pressure, 0.5);
  const Operation& b = f.operations[1];
  EXPECT_EQ(b.stroke.op, StrokeOp::kRemove);
  EXPECT_TRUE(b.material.empty());
  EXPECT_EQ(b.mirror.axis, -1);
  EXPECT_TRUE(b.stroke.axis.isApprox(Vec3::UnitX()));
  const Operation& c = f.operations[2];
  EXPECT_EQ(c.kind, Operation::Kind::kPrimitive);
  EXPECT_EQ(c.primitive.kind, PrimitiveKind::kTorus);
  EXPECT_DOUBLE_EQ(c.primitive.dims.y(), 0.03);
  EXPECT_TRUE((c.primitive.rotation * Vec3::UnitZ()).isApprox(-Vec3::UnitY(), 1e-12));
  const Operation& d = f.operations[3];
  EXPECT_EQ(d.kind, Operation::Kind::kStamp);
  EXPECT_EQ(d.stamp.path, "dir/meshes/cube.obj");
  EXPECT_DOUBLE_EQ(d.stamp.scale, 0.1);
  // undo 2 removed the stamp and the torus; redo brought the torus back.
  EXPECT_EQ(f.active, (std::vector<int>{0, 1, 2}));
  ASSERT_TRUE(f.play.has_value());
  EXPECT_DOUBLE_EQ(f.playTime(), 1.5);
}

TEST(StrokeFile, PlayDefaultsToTheEndOfTheLastActiveOperation) {
  const StrokeFile f = parseStrokes(kHead + "stroke create sphere 0.1 w\nsample 0 0 0 0\nsample 2.5 0 0 0\n", "p");
  EXPECT_DOUBLE_EQ(f.playTime(), 2.5);
}

TEST(StrokeFile, UnknownRecord) {
  auto e = strokeError(kHead + "stroke create sphere 0.05 wood\nsampel 0 0 0 0\n");
  EXPECT_EQ(e.line(), 3);
  EXPECT_NE(std::string(e.what()).find("unknown record 'sampel'"), std::string::npos);
}

TEST(StrokeFile, MissingAndExtraField) {
  auto e = strokeError(kHead + "stroke create sphere 0.05\n");
  EXPECT_EQ(e.line(), 2);
  EXPECT_EQ(e.field(), "material");
  e = strokeError(kHead + "stroke create sphere 0.05 wood\nsample 0 1 2\n");
  EXPECT_EQ(e.field(), "z");
  e = strokeError(kHead + "stroke create sphere 0.05 wood\nsample 0 1 2 3 1 4\n");
  EXPECT_NE(std::string(e.what()).find("extra field '4'"), std::string::npos);
  e = strokeError(kHead + "stroke remove sphere 0.05 wood\nsample 0 0 0 0\n");
  EXPECT_EQ(e.field(), "material");  // remove takes no material
  e = strokeError(kHead + "primitive box wood 0 0 0 0 1 1\n");
  EXPECT_EQ(e.field(), "sz");
}

TEST(StrokeFile, NaNInfNegativeAndZeroSize) {
  for (const char* size : {"nan", "-0.1", "0", "inf", "1e999", "abc", "2000"}) {
    auto e = strokeError(kHead + "stroke create sphere " + size + " wood\nsample 0 0 0 0\n");
    EXPECT_EQ(e.line(), 2) << size;
    EXPECT_EQ(e.field(), "size") << size;
  }
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.1 wood\nsample 0 nan 0 0\n").field(), "x");
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.1 wood\nsample 0 0 0 0 1.5\n").field(), "pressure");
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.1 wood\nsample 0 0 0 0 0\n").field(), "pressure");
  EXPECT_EQ(strokeError(kHead + "primitive sphere w 0 0 0 0 -1\n").field(), "radius");
  EXPECT_EQ(strokeError(kHead + "primitive torus w 0 0 0 0 0.1 0.2\n").field(), "minor_radius");
  EXPECT_EQ(strokeError(kHead + "stamp m.obj w 0 scale=-2\n").field(), "scale");
  EXPECT_EQ(strokeError(kHead + "snap 0\n").field(), "step");
}

TEST(StrokeFile, NonMonotonicTime) {
  auto e = strokeError(kHead + "stroke create sphere 0.1 wood\nsample 0.5 0 0 0\nsample 0.5 0 0 0.1\n");
  EXPECT_EQ(e.line(), 4);
  EXPECT_EQ(e.field(), "t");
  e = strokeError(kHead + "stroke create sphere 0.1 wood\nsample 0.5 0 0 0\nstroke create sphere 0.1 wood\nsample 0.4 0 0 0\n");
  EXPECT_EQ(e.line(), 5);
  e = strokeError(kHead + "stroke create sphere 0.1 wood\nsample 0.5 0 0 0\nprimitive sphere w 0.2 0 0 0 1\n");
  EXPECT_EQ(e.line(), 4);
  EXPECT_EQ(e.field(), "t");
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.1 wood\nsample -1 0 0 0\n").field(), "t");
}

TEST(StrokeFile, UnknownOperationBrushPrimitiveAndOption) {
  EXPECT_EQ(strokeError(kHead + "stroke paint sphere 0.1 wood\nsample 0 0 0 0\n").field(), "op");
  EXPECT_EQ(strokeError(kHead + "stroke create cone 0.1 wood\nsample 0 0 0 0\n").field(), "brush");
  EXPECT_EQ(strokeError(kHead + "primitive pyramid w 0 0 0 0 1\n").field(), "kind");
  auto e = strokeError(kHead + "stroke create sphere 0.1 wood colour=red\nsample 0 0 0 0\n");
  EXPECT_EQ(e.field(), "colour");
  EXPECT_NE(std::string(e.what()).find("unknown option"), std::string::npos);
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.1 wood orient=sideways\nsample 0 0 0 0\n").field(), "orient");
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.1 wood axis=0,0\nsample 0 0 0 0\n").field(), "axis");
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.1 wood axis=0,0,0\nsample 0 0 0 0\n").field(), "axis");
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.1 w body=a body=b\nsample 0 0 0 0\n").field(), "body");
  EXPECT_EQ(strokeError(kHead + "primitive box w 0 0 0 0 1 1 1 rot=1,0,0\n").field(), "rot");
  EXPECT_EQ(strokeError(kHead + "mirror w 0\n").field(), "axis");
}

TEST(StrokeFile, EmptyStrokeAndSampleOutsideStroke) {
  auto e = strokeError(kHead + "stroke create sphere 0.1 wood\nstroke create sphere 0.1 wood\nsample 0 0 0 0\n");
  EXPECT_EQ(e.line(), 2);
  EXPECT_NE(std::string(e.what()).find("no samples"), std::string::npos);
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.1 wood\n").line(), 2);  // at end of file
  e = strokeError(kHead + "sample 0 0 0 0\n");
  EXPECT_NE(std::string(e.what()).find("outside a stroke"), std::string::npos);
  e = strokeError(kHead + "primitive sphere w 0 0 0 0 1\nsample 0 0 0 0\n");
  EXPECT_EQ(e.line(), 3);
}

TEST(StrokeFile, UndoPastTheBeginningAndRedoWithNothingUndone) {
  auto e = strokeError(kHead + "primitive sphere w 0 0 0 0 1\nundo 2\n");
  EXPECT_EQ(e.line(), 3);
  EXPECT_EQ(e.field(), "count");
  EXPECT_NE(std::string(e.what()).find("past the beginning"), std::string::npos);
  e = strokeError(kHead + "primitive sphere w 0 0 0 0 1\nundo\nprimitive sphere w 0 0 0 0 1\nredo\n");
  EXPECT_EQ(e.line(), 5);  // a new operation after undo clears the redo history
  EXPECT_EQ(strokeError(kHead + "undo 0\n").field(), "count");
  EXPECT_EQ(strokeError(kHead + "play 1\nplay 2\n").line(), 3);
}

TEST(StrokeFile, NotUtf8AndHugeFilesAreRejectedWithoutReadingThem) {
  auto e = strokeError(kHead + "stroke create sphere 0.1 w\xff\xfe\n");
  EXPECT_EQ(e.line(), 2);
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("physketch_strokes_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  // A 1 GB file (sparse: no disk used) is refused by size before any line is read.
  const fs::path huge = dir / "huge.strokes";
  { std::ofstream(huge) << kHead; }
  fs::resize_file(huge, 1ull << 30);
  try {
    loadStrokes(huge.string());
    ADD_FAILURE() << "1 GB file accepted";
  } catch (const InputError& e2) {
    EXPECT_NE(std::string(e2.what()).find("limit"), std::string::npos) << e2.what();
  }
  // A 20 MB single line is refused at its 4097th byte.
  const fs::path longLine = dir / "long.strokes";
  {
    std::ofstream out(longLine);
    out << kHead << "stroke " << std::string(20u << 20, 'x') << "\n";
  }
  try {
    loadStrokes(longLine.string());
    ADD_FAILURE() << "20 MB line accepted";
  } catch (const InputError& e2) {
    EXPECT_EQ(e2.line(), 2);
    EXPECT_NE(std::string(e2.what()).find("longer than 4096"), std::string::npos);
  }
  fs::remove_all(dir);
}

TEST(StrokeFile, StructuralErrorsNameAField) {
  EXPECT_EQ(strokeError(kHead + "stroke create sphere 0.05 wood\nsampel 0 0 0 0\n").field(), "record");
  auto e = strokeError(kHead + "stroke create sphere 0.1 wood\n");
  EXPECT_EQ(e.line(), 2);
  EXPECT_EQ(e.field(), "samples") << e.what();
  EXPECT_EQ(strokeError(kHead + "sample 0 0 0 0\n").field(), "record");
  EXPECT_EQ(strokeError(kHead + "play 1\nplay 2\n").field(), "record");
}

TEST(StrokeFile, AByteOrderMarkAndWindowsLineEndsAreAccepted) {
  const StrokeFile f = parseStrokes("\xEF\xBB\xBF" "physketch-strokes 1\r\nstroke create sphere 0.1 wood\r\n"
                                    "sample\t0\t0 0.5 0\r\n",
                                    "bom.strokes");
  ASSERT_EQ(f.operations.size(), 1u);
  EXPECT_DOUBLE_EQ(f.operations[0].stroke.samples[0].position.y(), 0.5);
  auto e = strokeError(kHead + "stroke create sphere 0.1 wood\nsample 0 0 0.5\r0\n");
  EXPECT_EQ(e.line(), 3);
  EXPECT_EQ(e.field(), "text");
}

// --- Create options (vel, spin, fixed) and tool strokes ---

TEST(StrokeFile, CreateOperationsTakeVelSpinAndFixed) {
  const StrokeFile f = parseStrokes(kHead +
                                        "stroke create sphere 0.1 wood vel=1,2,3 spin=0,6.28,0\n"  // 2
                                        "sample 0 0 0.5 0\n"                                       // 3
                                        "primitive box stone 0.1  0 0.02 0  1 0.04 1 fixed\n"      // 4
                                        "stamp m.obj wood 0.2 at=0,0.5,0 vel=0,0,-2\n"             // 5
                                        "primitive sphere wood 0.3  0 0.5 0  0.1\n",               // 6
                                    "v.strokes");
  ASSERT_EQ(f.operations.size(), 4u);
  const Operation& s = f.operations[0];
  ASSERT_TRUE(s.velocity && s.spin);
  EXPECT_TRUE(s.velocity->isApprox(Vec3(1, 2, 3)));
  EXPECT_TRUE(s.spin->isApprox(Vec3(0, 6.28, 0)));
  EXPECT_FALSE(s.fixed);
  EXPECT_TRUE(f.operations[1].fixed);
  EXPECT_FALSE(f.operations[1].velocity.has_value());
  EXPECT_TRUE(f.operations[2].velocity->isApprox(Vec3(0, 0, -2)));
  EXPECT_FALSE(f.operations[3].velocity || f.operations[3].spin || f.operations[3].fixed);
}

TEST(StrokeFile, VelSpinAndFixedErrorsNameTheirField) {
  struct Case {
    std::string text;
    int line;
    const char* field;
  };
  const std::string create = "stroke create sphere 0.1 wood ";
  for (const Case& c : std::vector<Case>{
           {"stroke remove sphere 0.1 fixed\nsample 0 0 0 0\n", 2, "fixed"},
           {"stroke move sphere 0.1 vel=1,0,0\nsample 0 0 0 0\n", 2, "vel"},
           {create + "vel=1,0\nsample 0 0 0 0\n", 2, "vel"},
           {create + "vel=2000,0,0\nsample 0 0 0 0\n", 2, "vel"},
           {create + "spin=0,nan,0\nsample 0 0 0 0\n", 2, "spin"},
           {create + "fixed vel=0,1,0\nsample 0 0 0 0\n", 2, "vel"},
           {create + "fixed=1\nsample 0 0 0 0\n", 2, "fixed"},
           {create + "fixed fixed\nsample 0 0 0 0\n", 2, "fixed"},
           {"primitive sphere w 0 0 0 0 0.1 fixed 3\n", 2, "fixed"},  // positional after a flag
           {"stroke create sphere 0.1 fixed\nsample 0 0 0 0\n", 2, "material"},  // 'fixed' is not a material
       }) {
    const InputError e = strokeError(kHead + c.text);
    EXPECT_EQ(e.line(), c.line) << c.text << " -> " << e.what();
    EXPECT_EQ(e.field(), c.field) << c.text << " -> " << e.what();
  }
}

TEST(StrokeFile, ABodysPartsShareItsMotion) {
  const StrokeFile f = parseStrokes(kHead +
                                        "primitive box w 0  0 0.3 0  0.5 0.04 0.3 body=t vel=1,0,0\n"  // 2
                                        "primitive box w 0  0 0.1 0  0.05 0.2 0.05 body=t\n"           // 3
                                        "primitive box w 0  0 0.1 0.2  0.05 0.2 0.05 body=t vel=1,0,0\n"  // 4
                                        "primitive box w 0  1 0.1 0  0.05 0.2 0.05 body=u fixed\n"      // 5
                                        "primitive box w 0  1 0.3 0  0.05 0.2 0.05 body=u\n",           // 6
                                    "b.strokes");
  EXPECT_TRUE(f.operations[1].velocity && f.operations[1].velocity->isApprox(Vec3(1, 0, 0)));
  EXPECT_FALSE(f.operations[1].written.velocity);
  EXPECT_TRUE(f.operations[4].fixed);
  auto e = strokeError(kHead + "primitive sphere w 0 0 0.5 0 0.1 body=t vel=1,0,0\n"
                               "primitive sphere w 0 0 0.7 0 0.1 body=t vel=2,0,0\n");
  EXPECT_EQ(e.line(), 3);
  EXPECT_EQ(e.field(), "vel");
  EXPECT_NE(std::string(e.what()).find("line 2"), std::string::npos) << e.what();
  e = strokeError(kHead + "primitive sphere w 0 0 0.5 0 0.1 body=t fixed\n"
                          "primitive sphere w 0 0 0.7 0 0.1 body=t spin=0,1,0\n");
  EXPECT_EQ(e.line(), 3);
  EXPECT_EQ(e.field(), "spin");
  // A part that is undone does not count.
  EXPECT_NO_THROW(parseStrokes(kHead + "primitive sphere w 0 0 0.5 0 0.1 body=t vel=1,0,0\nundo\n"
                                       "primitive sphere w 0 0 0.7 0 0.1 body=t vel=2,0,0\n",
                               "u.strokes"));
}

TEST(StrokeFile, ToolStrokesActAfterPlay) {
  const StrokeFile f = parseStrokes(kHead +
                                        "primitive sphere w 0  0 0.5 0  0.1\n"  // 2
                                        "stroke create sphere 0.1 w\n"          // 3
                                        "sample 0.5 0 0.5 0\n"                  // 4
                                        "stroke tool cube 0.1 friction=0.3 axis=1,0,0\n"  // 5
                                        "sample 1.0 -0.4 0.05 0\n"              // 6
                                        "sample 2.0 0.4 0.05 0\n",              // 7
                                    "t.strokes");
  const Operation& tool = f.operations[2];
  EXPECT_EQ(tool.stroke.op, StrokeOp::kTool);
  EXPECT_TRUE(tool.material.empty());
  ASSERT_TRUE(tool.stroke.toolFriction.has_value());
  EXPECT_DOUBLE_EQ(*tool.stroke.toolFriction, 0.3);
  // play defaults to the end of the last operation that is not a tool.
  EXPECT_DOUBLE_EQ(f.playTime(), 0.5);
  auto e = strokeError(kHead + "stroke tool cube 0.1\nsample 0.5 0 0 0\nplay 1\n");
  EXPECT_EQ(e.line(), 3);
  EXPECT_EQ(e.field(), "t");
  EXPECT_NE(std::string(e.what()).find("before play"), std::string::npos) << e.what();
  EXPECT_NO_THROW(parseStrokes(kHead + "play 1\nstroke tool cube 0.1\nsample 1 0 0 0\n", "t.strokes"));
  EXPECT_EQ(strokeError(kHead + "play 0\nstroke tool cube 0.1 wood\nsample 1 0 0 0\n").field(), "material");
  EXPECT_EQ(strokeError(kHead + "play 0\nstroke tool cube 0.1 body=b\nsample 1 0 0 0\n").field(), "body");
  EXPECT_EQ(strokeError(kHead + "play 0\nstroke tool cube 0.1 fixed\nsample 1 0 0 0\n").field(), "fixed");
  EXPECT_EQ(strokeError(kHead + "play 0\nstroke tool cube 0.1 friction=-1\nsample 1 0 0 0\n").field(), "friction");
  EXPECT_EQ(strokeError(kHead + "stroke create cube 0.1 w friction=0.2\nsample 1 0 0 0\n").field(), "friction");
}

TEST(StrokeFile, UsesListsWhatTheOperationsInEffectUse) {
  const StrokeFile f = parseStrokes(kHead +
                                        "primitive sphere stone 0  0 0.5 0  0.1\n"          // 2
                                        "primitive sphere wood 0  0 0.5 0  0.1 spin=0,1,0\n"  // 3
                                        "primitive sphere water 0  0 0.5 0  0.1\n"          // 4
                                        "undo\n"                                            // 5
                                        "primitive sphere wood 0  0 0.5 0  0.1 fixed\n"     // 6
                                        "stroke remove sphere 0.1\n"                        // 7
                                        "sample 0.1 0 0 0\n"                                // 8
                                        "play 0.2\n"                                        // 9
                                        "stroke tool sphere 0.1\n"                          // 10
                                        "sample 0.3 0 0 0\n",                               // 11
                                    "u.strokes");
  const SketchUses u = usesOf(f);
  ASSERT_EQ(u.materials.size(), 2u);  // water was undone; wood counted once
  EXPECT_EQ(u.materials[0].material, "stone");
  EXPECT_EQ(u.materials[0].at.line, 2);
  EXPECT_EQ(u.materials[1].material, "wood");
  EXPECT_EQ(u.materials[1].at.line, 3);
  EXPECT_EQ(u.materials[1].at.file, "u.strokes");
  EXPECT_EQ(u.velocity.line, 3);
  EXPECT_EQ(u.velocity.field, "spin");
  EXPECT_EQ(u.fixedBody.line, 6);
  EXPECT_EQ(u.toolStroke.line, 10);
  EXPECT_FALSE(usesOf(parseStrokes(kHead + "primitive sphere w 0 0 0.5 0 0.1\n", "p")).velocity.used());
}

TEST(StrokeFile, TheDocsExampleParses) {
  // The first fenced block after the stroke file's heading in docs/formats.md.
  std::ifstream in(std::string(PHYSKETCH_SOURCE_DIR) + "/docs/formats.md");
  std::string line, text;
  bool inSection = false, inBlock = false;
  while (std::getline(in, line)) {
    if (line.rfind("## Stroke file", 0) == 0) inSection = true;
    else if (inSection && line.rfind("```", 0) == 0 && inBlock) break;
    else if (inSection && line.rfind("```", 0) == 0) inBlock = true;
    else if (inBlock) text += line + "\n";
  }
  ASSERT_FALSE(text.empty());
  const StrokeFile f = parseStrokes(text, "doc.strokes");
  EXPECT_EQ(f.operations.size(), 9u);
  EXPECT_EQ(f.operations.back().stroke.op, StrokeOp::kTool);
}
