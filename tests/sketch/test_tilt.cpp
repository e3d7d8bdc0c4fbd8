// Open Brush / Tilt Brush import: the .tilt reader against files written here from the
// documented layout (sketch/tilt.h) and a real Tilt Brush file, and the conversion to a
// stroke file (sketch/tilt_import.h) against closed-form placement, timing and joining.
#include <gtest/gtest.h>
#include <zlib.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "core/error.h"
#include "core/scene.h"
#include "sketch/tilt.h"
#include "sketch/tilt_import.h"
#include "sketch/voxelize.h"

namespace physketch::sketch {
namespace {

namespace fs = std::filesystem;

// --- a writer of the documented layout (independent of the reader) -------------------
struct Bytes {
  std::string b;
  void u32(std::uint32_t v) {
    for (int i = 0; i < 4; ++i) b.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
  }
  void u16(unsigned v) {
    b.push_back(static_cast<char>(v & 0xff));
    b.push_back(static_cast<char>((v >> 8) & 0xff));
  }
  void f32(float f) {
    std::uint32_t v;
    std::memcpy(&v, &f, 4);
    u32(v);
  }
};

struct PointSpec {
  float x, y, z, pressure = 1.0f;
  std::uint32_t ms = 0;
};
struct StrokeSpec {
  int brush = 0;
  float r = 1, g = 1, b = 1, size = 1;
  std::uint32_t strokeMask = 0, pointMask = 0x3;
  float scale = 1;
  std::uint32_t layer = 0;  // written with strokeMask 0x10 (Open Brush)
  std::vector<PointSpec> points;
};

std::string dataSketch(const std::vector<StrokeSpec>& strokes) {
  Bytes o;
  o.u32(0xc576a5cdu);
  o.u32(5);
  o.u32(0);
  o.u32(3);
  o.b += "abc";  // additional header
  o.u32(static_cast<std::uint32_t>(strokes.size()));
  for (const StrokeSpec& s : strokes) {
    o.u32(static_cast<std::uint32_t>(s.brush));
    o.f32(s.r), o.f32(s.g), o.f32(s.b), o.f32(1.0f);
    o.f32(s.size);
    o.u32(s.strokeMask);
    o.u32(s.pointMask);
    if (s.strokeMask & 0x1) o.u32(7);  // flags
    if (s.strokeMask & 0x2) o.f32(s.scale);
    if (s.strokeMask & 0x10) o.u32(s.layer);
    if (s.strokeMask & 0x10000) {  // an unknown, length-prefixed extension
      o.u32(5);
      o.b += "12345";
    }
    o.u32(static_cast<std::uint32_t>(s.points.size()));
    for (const PointSpec& p : s.points) {
      o.f32(p.x), o.f32(p.y), o.f32(p.z);
      o.f32(0), o.f32(0), o.f32(0), o.f32(1);
      if (s.pointMask & 0x1) o.f32(p.pressure);
      if (s.pointMask & 0x2) o.u32(p.ms);
      if (s.pointMask & 0x4) o.u32(99);  // an unknown point extension
    }
  }
  return o.b;
}

const char* kMeta =
    R"({"EnvironmentPreset": "580b4529-ac50-4fe9-b8d2-635765a14893",
        "BrushIndex": ["429ed64a-4e97-4466-84d3-145a861ef684", "4391385a-cf83-4396-9e33-31e4e4930b27"]})";

// A zip of the members (PKWARE APPNOTE: local headers, central directory, end record),
// stored or raw-deflated, after the 16-byte tilT header. `absolute`: offsets count from the
// start of the file instead of the end of the header.
std::string tiltFile(const std::vector<std::pair<std::string, std::string>>& members, bool deflated = false,
                     bool absolute = false) {
  const std::uint32_t base = absolute ? 16 : 0;
  Bytes z, cd;
  for (const auto& [name, data] : members) {
    std::string body = data;
    if (deflated) {
      z_stream s{};
      deflateInit2(&s, 9, Z_DEFLATED, -15, 8, Z_DEFAULT_STRATEGY);
      std::string out(compressBound(static_cast<uLong>(data.size())) + 64, '\0');
      s.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
      s.avail_in = static_cast<uInt>(data.size());
      s.next_out = reinterpret_cast<Bytef*>(out.data());
      s.avail_out = static_cast<uInt>(out.size());
      deflate(&s, Z_FINISH);
      out.resize(s.total_out);
      deflateEnd(&s);
      body = out;
    }
    const std::uint32_t crc = crc32(0, reinterpret_cast<const Bytef*>(data.data()), static_cast<uInt>(data.size()));
    const std::uint32_t offset = static_cast<std::uint32_t>(z.b.size()) + base;
    const unsigned method = deflated ? 8 : 0;
    z.u32(0x04034b50), z.u16(20), z.u16(0), z.u16(method), z.u16(0), z.u16(0x21);
    z.u32(crc), z.u32(static_cast<std::uint32_t>(body.size())), z.u32(static_cast<std::uint32_t>(data.size()));
    z.u16(static_cast<unsigned>(name.size())), z.u16(0);
    z.b += name + body;
    cd.u32(0x02014b50), cd.u16(20), cd.u16(20), cd.u16(0), cd.u16(method), cd.u16(0), cd.u16(0x21);
    cd.u32(crc), cd.u32(static_cast<std::uint32_t>(body.size())), cd.u32(static_cast<std::uint32_t>(data.size()));
    cd.u16(static_cast<unsigned>(name.size())), cd.u16(0), cd.u16(0), cd.u16(0), cd.u16(0), cd.u32(0), cd.u32(offset);
    cd.b += name;
  }
  const std::uint32_t cdOffset = static_cast<std::uint32_t>(z.b.size()) + base;
  z.b += cd.b;
  z.u32(0x06054b50), z.u16(0), z.u16(0), z.u16(static_cast<unsigned>(members.size()));
  z.u16(static_cast<unsigned>(members.size())), z.u32(static_cast<std::uint32_t>(cd.b.size())), z.u32(cdOffset), z.u16(0);
  Bytes head;
  head.b = "tilT";
  head.u16(16), head.u16(1), head.u32(0), head.u32(0);
  return head.b + z.b;
}

fs::path writeTemp(const std::string& name, const std::string& bytes) {
  const fs::path p = fs::temp_directory_path() / ("physketch_tilt_" + std::to_string(::getpid()) + "_" + name);
  std::ofstream(p, std::ios::binary) << bytes;
  return p;
}

std::vector<StrokeSpec> handMade() {
  StrokeSpec a;
  a.brush = 1, a.r = 0.2f, a.g = 0.4f, a.b = 0.6f, a.size = 0.5f;
  a.strokeMask = 0x1 | 0x2 | 0x10000, a.scale = 2.0f, a.pointMask = 0x1 | 0x2 | 0x4;
  a.points.push_back({1, 2, 3, 0.5f, 1000});
  a.points.push_back({1.5f, 2, 3, 0.75f, 1100});
  a.points.push_back({2, 2.5f, 3, 1.0f, 1250});
  StrokeSpec b;
  b.pointMask = 0;
  b.points.push_back({-1, 0, 0});
  b.points.push_back({-1, 0, 1});
  return {a, b};
}

std::string reason(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// --- reading ------------------------------------------------------------------------
TEST(TiltReader, ReadsEveryFieldOfTheDocumentedLayout) {
  const std::string data = dataSketch(handMade());
  for (int variant = 0; variant < 3; ++variant) {
    SCOPED_TRACE(variant);
    const fs::path p = writeTemp("hand.tilt", tiltFile({{"metadata.json", kMeta}, {"data.sketch", data}}, variant == 1,
                                                       variant == 2));
    const TiltSketch sk = readTilt(p.string());
    fs::remove(p);
    ASSERT_EQ(sk.brushes.size(), 2u);
    EXPECT_EQ(tiltBrushName(sk.brushes[0]), "Marker");
    EXPECT_EQ(tiltBrushName(sk.brushes[1]), "Wire");
    ASSERT_EQ(sk.strokes.size(), 2u);
    const TiltStroke& a = sk.strokes[0];
    EXPECT_EQ(a.brushIndex, 1);
    EXPECT_FLOAT_EQ(a.color.y(), 0.4f);
    EXPECT_FLOAT_EQ(a.size, 1.0f);  // 0.5 times the scale extension 2
    EXPECT_TRUE(a.hasPressure);
    EXPECT_TRUE(a.hasTimestamps);
    ASSERT_EQ(a.points.size(), 3u);
    EXPECT_FLOAT_EQ(a.points[2].position.y(), 2.5f);
    EXPECT_FLOAT_EQ(a.points[1].pressure, 0.75f);
    EXPECT_EQ(a.points[2].timestampMs, 1250u);
    const TiltStroke& b = sk.strokes[1];
    EXPECT_FALSE(b.hasPressure);
    EXPECT_FALSE(b.hasTimestamps);
    ASSERT_EQ(b.points.size(), 2u);
    EXPECT_FLOAT_EQ(b.points[1].position.z(), 1.0f);
    EXPECT_EQ(b.points[1].pressure, 1.0);
  }
}

// Every prefix of the stroke data is truncated somewhere: each must be a clear error, never
// a crash or a read past the end (ASan watches), and never a silently shorter sketch.
TEST(TiltReader, EveryTruncationOfTheStrokeDataIsAnError) {
  const std::string data = dataSketch(handMade());
  for (std::size_t n = 0; n < data.size(); ++n) {
    const std::string why = reason([&] { parseTilt(data.substr(0, n), kMeta, "cut.tilt"); });
    ASSERT_NE(why, "") << "a prefix of " << n << " of " << data.size() << " bytes was read";
    EXPECT_NE(why.find("cut.tilt"), std::string::npos) << why;
    // The message says the data ends early (a count larger than the bytes left says so too).
    EXPECT_NE(why.find("truncated"), std::string::npos) << why;
  }
  EXPECT_EQ(reason([&] { parseTilt(data, kMeta, "whole.tilt"); }), "");
  const std::string inPoint = reason([&] { parseTilt(data.substr(0, data.size() - 6), kMeta, "x"); });
  EXPECT_NE(inPoint.find("truncated or corrupt: stroke 2 of 2 has 2 points of 28 bytes, but 50 bytes are left"),
            std::string::npos)
      << inPoint;
}

// Random corruption (seeded): 3,000 mutations of the stroke data (bytes overwritten, inserted
// or deleted) and 200 of the whole file. Each must parse or be an InputError: never another
// exception, a crash or a read out of bounds (the sanitizer build runs this too).
TEST(TiltReader, CorruptedBytesParseOrAreInputErrors) {
  const std::string data = dataSketch(handMade());
  const std::string file = tiltFile({{"metadata.json", kMeta}, {"data.sketch", data}}, true);
  std::mt19937 rng(12345);
  auto mutate = [&](std::string b) {
    const int edits = 1 + static_cast<int>(rng() % 4);
    for (int e = 0; e < edits && !b.empty(); ++e) {
      const std::size_t at = rng() % b.size();
      switch (rng() % 3) {
        case 0: b[at] = static_cast<char>(rng() & 0xff); break;
        case 1: b.insert(b.begin() + static_cast<std::ptrdiff_t>(at), static_cast<char>(rng() & 0xff)); break;
        default: b.erase(at, 1 + rng() % 8); break;
      }
    }
    return b;
  };
  int rejected = 0;
  for (int k = 0; k < 3000; ++k) {
    try {
      parseTilt(mutate(data), kMeta, "m.tilt");
    } catch (const InputError&) {
      ++rejected;
    }
  }
  EXPECT_GT(rejected, 1000);  // most edits break the layout; the rest change values in range
  for (int k = 0; k < 200; ++k) {
    const fs::path p = writeTemp("mut.tilt", mutate(file));
    try {
      readTilt(p.string());
    } catch (const InputError&) {
    }
    fs::remove(p);
  }
}

TEST(TiltReader, TruncatedOrCorruptFilesAreClearErrors) {
  const std::string file = tiltFile({{"metadata.json", kMeta}, {"data.sketch", dataSketch(handMade())}});
  auto errorOf = [](const std::string& bytes) {
    const fs::path p = writeTemp("bad.tilt", bytes);
    const std::string why = reason([&] { readTilt(p.string()); });
    fs::remove(p);
    return why;
  };
  // Cut anywhere: the zip's end record is gone (or the header is).
  for (std::size_t n : {std::size_t(0), std::size_t(10), std::size_t(40), file.size() / 2, file.size() - 5})
    EXPECT_NE(errorOf(file.substr(0, n)), "") << n;
  EXPECT_NE(errorOf("\x89PNG\r\n\x1a\n and more").find("not a .tilt"), std::string::npos);
  std::string v2 = file;
  v2[6] = 2;
  EXPECT_NE(errorOf(v2).find("version 2"), std::string::npos);
  // A flipped byte inside the stored stroke data: the zip's CRC catches it.
  std::string flipped = file;
  flipped[file.find("abc") + 1] ^= 0x5a;
  EXPECT_NE(errorOf(flipped), "");
  EXPECT_NE(errorOf(tiltFile({{"metadata.json", kMeta}})).find("no data.sketch"), std::string::npos);
  EXPECT_NE(errorOf(tiltFile({{"metadata.json", "{oops"}, {"data.sketch", "x"}})).find("not JSON"), std::string::npos);
  EXPECT_NE(errorOf(tiltFile({{"metadata.json", "{}"}, {"data.sketch", "x"}})).find("BrushIndex"), std::string::npos);
  const fs::path missing = fs::temp_directory_path() / "physketch_no_such.tilt";
  EXPECT_NE(reason([&] { readTilt(missing.string()); }).find("cannot open"), std::string::npos);
}

TEST(TiltReader, BadValuesNameTheStrokeAndPoint) {
  auto errorOf = [](std::vector<StrokeSpec> s) { return reason([&] { parseTilt(dataSketch(s), kMeta, "v.tilt"); }); };
  std::vector<StrokeSpec> s = handMade();
  s[1].brush = 2;
  EXPECT_NE(errorOf(s).find("stroke 2 of 2: brush index 2 is not in BrushIndex"), std::string::npos) << errorOf(s);
  s = handMade();
  s[0].points[1].y = std::nanf("");
  EXPECT_NE(errorOf(s).find("stroke 1 of 2, point 2, position is not a finite number"), std::string::npos) << errorOf(s);
  s = handMade();
  s[0].points[2].pressure = -0.5f;
  EXPECT_NE(errorOf(s).find("point 3: pressure -0.5"), std::string::npos) << errorOf(s);
  s = handMade();
  s[1].size = -1;
  EXPECT_NE(errorOf(s).find("negative brush size"), std::string::npos) << errorOf(s);
  std::string bad = dataSketch(handMade());
  bad[0] = 0;
  EXPECT_NE(reason([&] { parseTilt(bad, kMeta, "s"); }).find("sentinel"), std::string::npos);
}

// What Open Brush writes beyond Tilt Brush (read from its SketchWriter and SketchMetadata):
// a layer extension (0x10, u32) on every stroke, metadata.json "Layers" with name, visibility
// and a transform [[t], [q], s] (s = 0 read as 1), pressures above 1 from scripted strokes
// and negative stroke scales. Every value read back as written; a malformed transform is an
// error naming the layer.
TEST(TiltReader, ReadsOpenBrushLayersPressuresAndScales) {
  const std::string meta =
      R"({"BrushIndex": ["429ed64a-4e97-4466-84d3-145a861ef684", "4391385a-cf83-4396-9e33-31e4e4930b27"],
          "ApplicationName": "Open Brush", "SchemaVersion": 2,
          "Layers": [{"Name": "Main Canvas", "Visible": true},
                     {"Name": "moved", "Visible": true, "Transform": [[1, 2, 3], [0, 0.7071068, 0, 0.7071068], 2]},
                     {"Name": "hidden", "Visible": false, "Transform": [[0, 0, 0], [0, 0, 0, 1], 0]}]})";
  std::vector<StrokeSpec> s = handMade();
  s[0].strokeMask |= 0x10, s[0].layer = 1;
  s[0].points[2].pressure = 1.5f;
  s[1].strokeMask = 0x2 | 0x10, s[1].scale = -3.0f, s[1].layer = 2;
  const TiltSketch sk = parseTilt(dataSketch(s), meta, "ob.tilt");
  ASSERT_EQ(sk.layers.size(), 3u);
  EXPECT_EQ(sk.layers[1].name, "moved");
  EXPECT_TRUE(sk.layers[1].visible);
  EXPECT_FALSE(sk.layers[2].visible);
  EXPECT_EQ(sk.layers[1].translation, Vec3(1, 2, 3));
  EXPECT_NEAR(sk.layers[1].rotation.w(), std::sqrt(0.5), 1e-6);
  EXPECT_NEAR(sk.layers[1].rotation.y(), std::sqrt(0.5), 1e-6);
  EXPECT_EQ(sk.layers[1].scale, 2.0);
  EXPECT_EQ(sk.layers[2].scale, 1.0);  // 0 means 1
  EXPECT_EQ(sk.strokes[0].layer, 1u);
  EXPECT_EQ(sk.strokes[1].layer, 2u);
  EXPECT_FLOAT_EQ(sk.strokes[0].points[2].pressure, 1.5f);
  EXPECT_TRUE(sk.strokes[1].negativeScale);
  EXPECT_FLOAT_EQ(sk.strokes[1].size, 3.0f);  // 1 x |-3|
  EXPECT_FALSE(sk.strokes[0].negativeScale);
  std::string badMeta = meta;
  badMeta.replace(badMeta.find("[0, 0.7071068, 0, 0.7071068]"), 28, "[0, 0, 0, 0]");
  const std::string why = reason([&] { parseTilt(dataSketch(s), badMeta, "ob.tilt"); });
  EXPECT_NE(why.find("Layers[1].Transform"), std::string::npos) << why;
}

// Open Brush's folder form: a folder X.tilt holding the members as files reads as the zip
// form does; a folder without data.sketch is an error naming it.
TEST(TiltReader, ReadsASketchSavedAsAFolder) {
  const fs::path dir = fs::temp_directory_path() / ("physketch_tilt_" + std::to_string(::getpid()) + "_folder.tilt");
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(dir / "metadata.json", std::ios::binary) << kMeta;
  std::string why = reason([&] { readTilt(dir.string()); });
  EXPECT_NE(why.find("data.sketch"), std::string::npos) << why;
  std::ofstream(dir / "data.sketch", std::ios::binary) << dataSketch(handMade());
  const TiltSketch sk = readTilt(dir.string());
  fs::remove_all(dir);
  ASSERT_EQ(sk.strokes.size(), 2u);
  EXPECT_EQ(sk.strokes[0].points.size(), 3u);
  EXPECT_FLOAT_EQ(sk.strokes[0].points[1].pressure, 0.75f);
}

// A real sketch made by Tilt Brush (tests/data/tilt/README.md): the expected values were read
// with Python's zipfile and struct, following the toolkit's tilt.py.
TEST(TiltReader, ReadsARealTiltBrushSketch) {
  const TiltSketch sk = readTilt(PHYSKETCH_SOURCE_DIR "/tests/data/tilt/sketch1.tilt");
  ASSERT_EQ(sk.strokes.size(), 5u);
  EXPECT_EQ(tiltBrushName(sk.brushes.at(0)), "TaperedMarker");
  EXPECT_EQ(tiltBrushName(sk.brushes.at(1)), "Wire");
  const std::size_t counts[] = {493, 295, 73, 40, 11};
  for (std::size_t i = 0; i < 5; ++i) EXPECT_EQ(sk.strokes[i].points.size(), counts[i]) << i;
  EXPECT_NEAR(sk.strokes[0].points[0].position.x(), 11.676923751831055, 1e-6);
  EXPECT_NEAR(sk.strokes[0].points[0].position.z(), -2.006084442138672, 1e-6);
  EXPECT_EQ(sk.strokes[0].points[0].timestampMs, 3449626u);
  EXPECT_EQ(sk.strokes[4].points.back().timestampMs, 3906352u);
  EXPECT_NEAR(sk.strokes[1].size, 0.962, 5e-4);
}

// --- converting -----------------------------------------------------------------------
TiltStroke line(const Vec3& a, const Vec3& b, double size, const Vec3& colour, std::uint32_t t0, int points = 11) {
  TiltStroke s;
  s.size = size;
  s.color = colour;
  s.hasTimestamps = true;
  for (int i = 0; i < points; ++i) {
    TiltPoint p;
    p.position = a + (b - a) * (double(i) / (points - 1));
    p.timestampMs = t0 + static_cast<std::uint32_t>(10 * i);
    s.points.push_back(p);
  }
  return s;
}

StrokeFile parsed(const TiltImport& r) { return parseStrokes(r.strokes, "imported.strokes"); }

TEST(TiltImport, FitsTheSketchOnTheWorkspaceFloorInOurFrame) {
  TiltSketch sk;
  sk.brushes = {"x"};
  // Decimetres, Tilt Brush's left-handed frame: a 20 dm bar along x and a 10 dm one along +z.
  sk.strokes = {line({0, 0, 0}, {20, 0, 0}, 1.0, {1, 0, 0}, 0), line({0, 0, 0}, {0, 0, 10}, 1.0, {1, 0, 0}, 500)};
  TiltImportOptions o;
  o.workspaceCenter = Vec3(1, 2, 3);
  o.workspaceSize = 2.0;
  const TiltImport r = importTilt(sk, o);
  const StrokeFile f = parsed(r);
  ASSERT_EQ(f.operations.size(), 2u);
  // The brush-inflated box spans 21 dm in x: scale = 0.8 * 2 m / 2.1 m.
  EXPECT_NEAR(r.scale, 0.8 * 2.0 / 2.1, 1e-12);
  const auto& a = f.operations[0].stroke;
  const auto& b = f.operations[1].stroke;
  EXPECT_NEAR(a.size, r.scale * 0.1, 1e-6);
  const double h = 2.0 / 151;
  // Centred in x: the bar's ends (inflated by the radius) sit symmetrically about x = 1.
  EXPECT_NEAR(a.samples.front().position.x() - a.size / 2 + a.samples.back().position.x() + a.size / 2, 2.0, 2e-6);
  // The lowest point, less the radius, one voxel above the floor (y = 1).
  EXPECT_NEAR(a.samples.front().position.y() - a.size / 2, 1.0 + h, 2e-6);
  // z flipped: Tilt Brush's +z runs to our -z, at the same scale.
  EXPECT_NEAR(b.samples.back().position.z() - b.samples.front().position.z(), -r.scale * 1.0, 2e-6);
  // Centred in z: the box from z = -1 dm - r to 0 + r (ours) sits about z = 3.
  EXPECT_NEAR(b.samples.back().position.z() - b.size / 2 + b.samples.front().position.z() + b.size / 2, 6.0, 2e-6);
}

// Open Brush layers on import: a stroke on a moved layer lands where Open Brush draws it,
// canvas = t + R (s p) (a quarter turn about y, scale 2, a shift), computed here by hand and
// then converted as any point (z flipped, decimetres to metres at scale 1, the shift that sets
// the sketch on the floor taken from the untouched stroke); its width doubles. A stroke on a
// hidden layer is left out and counted, and imported with hiddenLayers. A pressure above 1 is
// the full width (counted); a negative scale gives the width of |scale| (counted).
TEST(TiltImport, OpenBrushLayersPlaceStrokesAndHiddenOnesAreLeftOut) {
  TiltSketch sk;
  sk.brushes = {"x"};
  TiltLayer moved;
  moved.translation = Vec3(1, 0, 2);
  moved.rotation = Quat(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitY()));
  moved.scale = 2.0;
  TiltLayer hidden;
  hidden.visible = false;
  sk.layers = {TiltLayer{}, moved, hidden};
  sk.strokes = {line({0, 0, 0}, {2, 0, 0}, 0.5, {1, 1, 1}, 0), line({0, 0, 0}, {1, 0, 0}, 0.5, {1, 1, 1}, 500),
                line({0, 3, 0}, {1, 3, 0}, 0.5, {1, 1, 1}, 900)};
  sk.strokes[1].layer = 1;
  sk.strokes[2].layer = 2;
  sk.strokes[0].hasPressure = true;
  for (TiltPoint& p : sk.strokes[0].points) p.pressure = 0.5;
  sk.strokes[0].points[3].pressure = 1.7;
  sk.strokes[0].negativeScale = true;
  TiltImportOptions o;
  o.scale = 1.0;
  const TiltImport r = importTilt(sk, o);
  EXPECT_EQ(r.skippedHidden, 1);
  EXPECT_EQ(r.layerMoved, 1);
  EXPECT_EQ(r.pressureAboveOne, 1);
  EXPECT_EQ(r.negativeScale, 1);
  const StrokeFile f = parsed(r);
  ASSERT_EQ(f.operations.size(), 2u);
  const auto& a = f.operations[0].stroke;
  const auto& b = f.operations[1].stroke;
  // The untouched stroke's first point (0, 0, 0) fixes the placement's shift.
  const Vec3 shift = a.samples.front().position;
  // Layer 1: R_y(90 deg) (2 (1, 0, 0)) + (1, 0, 2) = (1, 0, 0) in Tilt Brush's frame; ours:
  // (x, y, -z) / 10 m.
  const Vec3 canvas = moved.translation + moved.rotation.toRotationMatrix() * (2.0 * Vec3(1, 0, 0));
  EXPECT_NEAR((canvas - Vec3(1, 0, 0)).norm(), 0.0, 1e-12);  // the hand value above
  const Vec3 want = shift + 0.1 * Vec3(canvas.x(), canvas.y(), -canvas.z());
  EXPECT_NEAR((b.samples.back().position - want).norm(), 0.0, 2e-6);
  const Vec3 start = shift + 0.1 * Vec3(moved.translation.x(), 0, -moved.translation.z());
  EXPECT_NEAR((b.samples.front().position - start).norm(), 0.0, 2e-6);
  EXPECT_NEAR(b.size, 2.0 * a.size, 1e-6);  // the layer's scale widens it
  // Pressure 0.5 writes 0.2 + 0.8 * 0.5 = 0.6; 1.7 counts as 1.
  EXPECT_NEAR(a.samples[0].pressure, 0.6, 1e-4);
  EXPECT_NEAR(a.samples[3].pressure, 1.0, 1e-4);
  o.hiddenLayers = true;
  EXPECT_EQ(parsed(importTilt(sk, o)).operations.size(), 3u);
}

TEST(TiltImport, AnExplicitScaleKeepsSizesOrRefusesWhatDoesNotFit) {
  TiltSketch sk;
  sk.brushes = {"x"};
  sk.strokes = {line({0, 0, 0}, {3, 4, 0}, 0.5, {1, 1, 1}, 0)};  // 5 dm long
  TiltImportOptions o;
  o.scale = 1.0;  // real size: 0.5 m
  const StrokeFile f = parsed(importTilt(sk, o));
  const auto& s = f.operations[0].stroke;
  EXPECT_NEAR((s.samples.back().position - s.samples.front().position).norm(), 0.5, 3e-6);
  EXPECT_NEAR(s.size, 0.05, 1e-6);
  o.scale = 3.0;  // 1.5 m in a 1 m workspace
  const std::string why = reason([&] { importTilt(sk, o); });
  EXPECT_NE(why.find("field '--scale'"), std::string::npos) << why;
}

TEST(TiltImport, StrokesOverlappingInTimeArePlayedOneAfterTheOther) {
  TiltSketch sk;
  sk.brushes = {"x"};
  // Two hands: the second stroke starts 30 ms into the first (which lasts 100 ms); the third
  // has a repeated timestamp.
  sk.strokes = {line({0, 0, 0}, {5, 0, 0}, 0.5, {1, 1, 1}, 1000), line({0, 3, 0}, {5, 3, 0}, 0.5, {1, 1, 1}, 1030),
                line({0, 6, 0}, {5, 6, 0}, 0.5, {1, 1, 1}, 5000)};
  sk.strokes[2].points[4].timestampMs = sk.strokes[2].points[3].timestampMs;
  const TiltImport r = importTilt(sk, {});
  EXPECT_EQ(r.delayed, 1);
  EXPECT_EQ(r.pointsNudged, 1);
  const StrokeFile f = parsed(r);  // the parser checks that times never go back
  const auto& s0 = f.operations[0].stroke.samples;
  const auto& s1 = f.operations[1].stroke.samples;
  const auto& s2 = f.operations[2].stroke.samples;
  EXPECT_NEAR(s0.front().t, 0.0, 1e-9);
  EXPECT_NEAR(s0.back().t, 0.1, 1e-9);
  EXPECT_NEAR(s1.front().t, 0.101, 1e-9);                // 1 ms after the first ends
  EXPECT_NEAR(s1.back().t - s1.front().t, 0.1, 1e-9);   // its own duration kept
  EXPECT_NEAR(s2.front().t, 4.0, 1e-9);                 // not delayed: it began later
  EXPECT_NEAR(s2[4].t - s2[3].t, 0.001, 1e-9);
  EXPECT_NEAR(s2[5].t - s2[4].t, 0.019, 1e-9);  // its own time again: 20 ms after the repeated one
}

TEST(TiltImport, ThinStrokesAreThickenedToTwoParticleSpacings) {
  TiltSketch sk;
  sk.brushes = {"x"};
  sk.strokes = {line({0, 0, 0}, {10, 0, 0}, 2.0, {1, 1, 1}, 0), line({0, 1, 0}, {10, 1, 0}, 0.01, {1, 1, 1}, 500)};
  sk.strokes[1].hasPressure = true;
  for (std::size_t i = 0; i < sk.strokes[1].points.size(); ++i) sk.strokes[1].points[i].pressure = i * 0.1;
  const double h = 1.0 / 151;
  {
    const TiltImport r = importTilt(sk, {});
    EXPECT_EQ(r.thickened, 1);
    const StrokeFile written = parsed(r);
    const auto& thin = written.operations[1].stroke;
    for (const Sample& s : thin.samples) EXPECT_GE(thin.size * s.pressure, 2.0 * h) << s.line;
    // The lint warning it is meant to silence (features thinner than two spacings) stays away.
    SceneDesc scene = parseScene(r.scene, "s.scene");
    const Sketch vox = voxelize(parsed(r), GridMapping(scene.workspaceCenter, scene.workspaceSize), scene.materials);
    EXPECT_GE(vox.operations[1].minFeature, 2.0 * h);
  }
  TiltImportOptions o;
  o.thicken = false;
  const TiltImport r = importTilt(sk, o);
  EXPECT_EQ(r.thickened, 0);
  const StrokeFile written = parsed(r);
  const auto& thin = written.operations[1].stroke;
  EXPECT_NEAR(thin.size, r.scale * 0.001, 1e-6);
  EXPECT_LT(thin.size, 2.0 * h);
}

TEST(TiltImport, TouchingStrokesBecomeOneBodyAsAsked) {
  TiltSketch sk;
  sk.brushes = {"x"};
  // Two bars crossing at their middles (red, blue), a third 10 dm away from both.
  sk.strokes = {line({0, 0, 0}, {10, 0, 0}, 1.0, {1, 0, 0}, 0), line({5, 0, -5}, {5, 0, 5}, 1.0, {0, 0, 1}, 500),
                line({0, 10, 0}, {10, 10, 0}, 1.0, {1, 0, 0}, 1000)};
  auto bodiesOf = [&](TiltJoin join) {
    TiltImportOptions o;
    o.join = join;
    const TiltImport r = importTilt(sk, o);
    const StrokeFile f = parsed(r);
    std::vector<std::string> names;
    for (const Operation& op : f.operations) names.push_back(op.body);
    return std::make_pair(r.bodies, names);
  };
  const auto touching = bodiesOf(TiltJoin::kTouching);
  EXPECT_EQ(touching.first, 2);
  EXPECT_EQ(touching.second, (std::vector<std::string>{"part_1", "part_1", ""}));
  const auto material = bodiesOf(TiltJoin::kMaterial);
  EXPECT_EQ(material.first, 3);
  EXPECT_EQ(material.second, (std::vector<std::string>{"", "", ""}));
  EXPECT_EQ(bodiesOf(TiltJoin::kNone).first, 3);
}

// What real sketches look like (hundreds of wire-thin strokes, two hands drawing at once): a
// cage of 432 crossing wires 0.02 dm thick, drawn in pairs at the same time, in 12 colours.
// Left as drawn it would be 432 chains one voxel thick; imported it is one body of strokes at
// least two particles thick, each pair played one after the other.
TEST(TiltImport, AWireCageDrawnWithTwoHandsBecomesOneSolidBody) {
  TiltSketch sk;
  sk.brushes = {"x"};
  int k = 0;
  for (int axis = 0; axis < 3; ++axis)
    for (int i = 0; i < 12; ++i)
      for (int j = 0; j < 12; ++j, ++k) {
        Vec3 a = Vec3::Zero(), b = Vec3::Zero();
        a[(axis + 1) % 3] = b[(axis + 1) % 3] = i;
        a[(axis + 2) % 3] = b[(axis + 2) % 3] = j;
        b[axis] = 11;
        const Vec3 colour(k % 12 / 11.0, 0.5, 0.5);
        sk.strokes.push_back(line(a, b, 0.02, colour, static_cast<std::uint32_t>(1000 * (k / 2)), 12));
      }
  const TiltImport r = importTilt(sk, {});
  EXPECT_EQ(r.strokesWritten, 432);
  EXPECT_EQ(r.thickened, 432);
  EXPECT_EQ(r.delayed, 216);  // the second of every pair
  EXPECT_EQ(r.materials, 12);
  EXPECT_EQ(r.bodies, 1);
  TiltImportOptions apart;
  apart.join = TiltJoin::kNone;
  apart.thicken = false;
  EXPECT_EQ(importTilt(sk, apart).bodies, 432);
}

TEST(TiltImport, ColoursBecomeAtMost64Materials) {
  TiltSketch sk;
  sk.brushes = {"x"};
  sk.strokes = {line({0, 0, 0}, {1, 0, 0}, 0.5, {1, 0, 0}, 0), line({0, 2, 0}, {1, 2, 0}, 0.5, {0, 0.5, 1}, 200)};
  TiltImport r = importTilt(sk, {});
  EXPECT_EQ(r.materials, 2);
  EXPECT_NE(r.scene.find("material c_ff0000 rigid"), std::string::npos) << r.scene;
  EXPECT_NE(r.scene.find("material c_0080ff rigid"), std::string::npos) << r.scene;
  // 200 strokes of 200 different greys.
  sk.strokes.clear();
  for (int i = 0; i < 200; ++i)
    sk.strokes.push_back(line({0, i * 0.2, 0}, {1, i * 0.2, 0}, 0.05, Vec3::Constant(i / 199.0), 100 * i, 2));
  r = importTilt(sk, {});
  EXPECT_LE(r.materials, 64);
  EXPECT_GE(r.materials, 32);  // one halving of the 8-bit steps at a time: not coarser than needed
  EXPECT_EQ(parseScene(r.scene, "s").materials.size(), static_cast<std::size_t>(r.materials));
}

TEST(TiltImport, TheRealSketchImportsAndVoxelizesWithoutWarnings) {
  const TiltSketch sk = readTilt(PHYSKETCH_SOURCE_DIR "/tests/data/tilt/sketch1.tilt");
  const TiltImport r = importTilt(sk, {});
  EXPECT_EQ(r.strokesWritten, 5);
  const SceneDesc scene = parseScene(r.scene, "s.scene");
  const Sketch vox = voxelize(parsed(r), GridMapping(scene.workspaceCenter, scene.workspaceSize), scene.materials);
  EXPECT_EQ(static_cast<std::int64_t>(vox.particles.size()), r.particles);
  EXPECT_EQ(static_cast<int>(vox.bodies.size()), r.bodies);
  EXPECT_TRUE(vox.warnings.empty()) << vox.warnings.front();
  // The 471-stroke artwork: four strokes lie inside others and make no particle; the count of
  // bodies the importer reports is still the sketch's.
  const TiltSketch bird = readTilt(PHYSKETCH_SOURCE_DIR "/tests/data/tilt/Blue_Tit.tilt");
  ASSERT_EQ(bird.strokes.size(), 471u);
  const TiltImport rb = importTilt(bird, {});
  const Sketch vb = voxelize(parsed(rb), GridMapping(scene.workspaceCenter, scene.workspaceSize),
                             parseScene(rb.scene, "b.scene").materials);
  EXPECT_EQ(static_cast<int>(vb.bodies.size()), rb.bodies);
  EXPECT_EQ(rb.thickened, 471);
}

// The bundled example (scenes/tilt.scene and .strokes) is what the importer writes from the real
// file with the default options; regenerate it with
//   build/apps/physketch/physketch import-tilt tests/data/tilt/sketch1.tilt -o scenes/tilt.strokes
TEST(TiltImport, TheBundledExampleIsTheImportOfTheRealFile) {
  const TiltSketch sk = readTilt(PHYSKETCH_SOURCE_DIR "/tests/data/tilt/sketch1.tilt");
  TiltImportOptions o;
  o.source = "tests/data/tilt/sketch1.tilt";
  o.strokesName = "tilt.strokes";
  const TiltImport r = importTilt(sk, o);
  auto slurp = [](const std::string& path) {
    std::ifstream in(path);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  };
  EXPECT_EQ(slurp(PHYSKETCH_SOURCE_DIR "/scenes/tilt.strokes"), r.strokes);
  EXPECT_EQ(slurp(PHYSKETCH_SOURCE_DIR "/scenes/tilt.scene"), r.scene);
}

}  // namespace
}  // namespace physketch::sketch
