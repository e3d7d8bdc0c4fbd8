// End to end: physketch run --export mesh,particles,vdb, --video (with no ffmpeg, a stand-in
// ffmpeg that records its arguments, and the real one when installed) and --smooth.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace fs = std::filesystem;

namespace {

struct Result {
  int code = -1;
  std::string err;
};

// Runs the CLI with arguments and an optional environment prefix ("PATH=... "), capturing stderr.
Result runCli(const std::string& args, const fs::path& dir, const std::string& env = "") {
  const fs::path errFile = dir / "stderr.txt";
  const std::string cmd = env + std::string(PHYSKETCH_CLI) + " " + args + " 2> '" + errFile.string() + "' > /dev/null";
  const int status = std::system(cmd.c_str());
  Result r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream in(errFile);
  std::stringstream ss;
  ss << in.rdbuf();
  r.err = ss.str();
  return r;
}

fs::path freshDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("physketch_test_export_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void writeText(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

const std::string kHello = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.scene";

int countOf(const std::string& text, const std::string& what) {
  int n = 0;
  for (std::size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

std::vector<std::array<double, 3>> objVertices(const fs::path& p) {
  std::ifstream in(p);
  std::vector<std::array<double, 3>> v;
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("v ", 0) != 0) continue;
    std::istringstream ls(line.substr(2));
    std::array<double, 3> x{};
    ls >> x[0] >> x[1] >> x[2];
    v.push_back(x);
  }
  return v;
}

// Rotates v by the unit quaternion (w, x, y, z), or by its inverse.
std::array<double, 3> rotate(const std::array<double, 4>& q, const std::array<double, 3>& v, bool inverse) {
  const double w = q[0], s = inverse ? -1.0 : 1.0, x = s * q[1], y = s * q[2], z = s * q[3];
  // v' = v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
  const std::array<double, 3> u{x, y, z};
  auto cross = [](const std::array<double, 3>& a, const std::array<double, 3>& b) {
    return std::array<double, 3>{a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
  };
  const auto t = cross(u, v);
  const auto t2 = cross(u, t);
  return {v[0] + 2 * w * t[0] + 2 * t2[0], v[1] + 2 * w * t[1] + 2 * t2[1], v[2] + 2 * w * t[2] + 2 * t2[2]};
}

// The element count of the first "element NAME N" header line.
long plyCount(const std::string& bytes, const std::string& element) {
  const std::string key = "element " + element + " ";
  const std::size_t at = bytes.find(key);
  if (at == std::string::npos) return -1;
  return std::stol(bytes.substr(at + key.size()));
}

}  // namespace

// Every export of a 3-frame run: the files exist where docs/formats.md says; the particle file
// has one record per particle of report.json's bodies; a falling rigid body's OBJ at frame 2 is
// its frame-0 OBJ moved by the pose report.json gives (an oracle outside the mesh code); the
// .vdb files start with OpenVDB's magic number (test_export reads them back with OpenVDB).
TEST(CliExport, MeshParticlesAndVdbPerFrame) {
  const fs::path dir = freshDir("all");
  const fs::path out = dir / "out";
  const Result r = runCli("run '" + kHello + "' --out '" + out.string() + "' --frames 3 --export mesh --export particles,vdb", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const nlohmann::json rep = nlohmann::json::parse(slurp(out / "report.json"));
  ASSERT_EQ(rep["bodies"].size(), 3u);
  long particles = 0;
  for (const auto& b : rep["bodies"]) particles += b["particles"].get<long>();
  EXPECT_EQ(rep["exports"]["kinds"], nlohmann::json({"mesh", "particles", "vdb"}));

  EXPECT_TRUE(fs::exists(out / "meshes" / "materials.mtl"));
  for (int f = 0; f < 3; ++f) {
    char stem[32];
    std::snprintf(stem, sizeof stem, "frame_%04d", f);
    for (const char* body : {"0000_stroke_0", "0001_stroke_1", "0002_stroke_2"}) {
      EXPECT_TRUE(fs::exists(out / "meshes" / stem / (std::string(body) + ".obj"))) << stem << " " << body;
      EXPECT_TRUE(fs::exists(out / "meshes" / stem / (std::string(body) + ".ply"))) << stem << " " << body;
    }
    const std::string ply = slurp(out / "particles" / (std::string(stem) + ".ply"));
    EXPECT_EQ(ply.rfind("ply\nformat binary_little_endian 1.0\n", 0), 0u);
    EXPECT_EQ(plyCount(ply, "vertex"), particles);
    EXPECT_NE(ply.find("comment material 0 wood\n"), std::string::npos);
    const std::string vdb = slurp(out / "vdb" / (std::string(stem) + ".vdb"));
    ASSERT_GE(vdb.size(), 8u);
    EXPECT_EQ(vdb.substr(0, 4), std::string("\x20\x42\x44\x56", 4));  // OPENVDB_MAGIC 0x56444220, little-endian
  }
  const std::string obj = slurp(out / "meshes" / "frame_0000" / "0002_stroke_2.obj");
  EXPECT_NE(obj.find("mtllib ../materials.mtl\n"), std::string::npos);
  EXPECT_NE(obj.find("\nusemtl "), std::string::npos);

  // world = R (rest - rest centre) + c, so v2 = R2 R0^-1 (v0 - c0) + c2.
  const auto pose = [&](int frame) { return rep["poses"][frame]["bodies"][2].get<std::vector<double>>(); };
  const std::vector<double> p0 = pose(0), p2 = pose(2);
  ASSERT_EQ(p0.size(), 7u);
  ASSERT_GT(std::abs(p2[1] - p0[1]), 1e-3) << "the body must have moved for the check to mean something";
  const auto v0 = objVertices(out / "meshes" / "frame_0000" / "0002_stroke_2.obj");
  const auto v2 = objVertices(out / "meshes" / "frame_0002" / "0002_stroke_2.obj");
  ASSERT_EQ(v0.size(), v2.size());
  ASSERT_GT(v0.size(), 100u);
  double worst = 0.0;
  for (std::size_t i = 0; i < v0.size(); ++i) {
    const std::array<double, 3> d{v0[i][0] - p0[0], v0[i][1] - p0[1], v0[i][2] - p0[2]};
    const auto rest = rotate({p0[3], p0[4], p0[5], p0[6]}, d, true);
    const auto now = rotate({p2[3], p2[4], p2[5], p2[6]}, rest, false);
    for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(now[c] + p2[c] - v2[i][c]));
  }
  EXPECT_LT(worst, 1e-5);  // float32 positions of a 1 m scene
  fs::remove_all(dir);
}

// A rope is drawn as thick as its brush (docs/formats.md: size/2 is its contact and render
// radius). A straight rope of brush size 0.04 m in zero gravity, exported at frame 0: every
// vertex of its tube lies 0.02 m from the rope's line (the end caps' centres on it), where the
// voxel's half spacing (0.0033 m here) was drawn before. Tolerance 1e-5 m: float32 positions.
TEST(CliExport, ARopeTubeIsAsThickAsItsBrush) {
  const fs::path dir = freshDir("rope");
  writeText(dir / "r.strokes", "physketch-strokes 1\nstroke create sphere 0.04 cord\nsample 0  -0.2 0.3 0\n"
                               "sample 1  0.2 0.3 0\nplay 1\n");
  writeText(dir / "r.scene", "physketch-scene 1\nstrokes r.strokes\nworkspace 0 0.5 0 1.0\ngravity 0 0 0\n"
                             "material cord rope density=500\nduration 0.05\noutput report\n");
  const fs::path out = dir / "out";
  const Result r = runCli("run '" + (dir / "r.scene").string() + "' -q --frames 1 --export mesh --out '" + out.string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto v = objVertices(out / "meshes" / "frame_0000" / "0000_stroke_0.obj");
  ASSERT_GT(v.size(), 100u);
  int onAxis = 0, onSurface = 0;
  double worst = 0.0;
  for (const auto& x : v) {
    const double d = std::hypot(x[1] - 0.3, x[2]);
    if (d < 1e-5) {
      ++onAxis;
    } else {
      ++onSurface;
      worst = std::max(worst, std::abs(d - 0.02));
    }
  }
  EXPECT_LE(onAxis, 2);  // the caps' centres
  EXPECT_GT(onSurface, 100);
  EXPECT_LT(worst, 1e-5);
  fs::remove_all(dir);
}

// A cloth is drawn along its lattice (render::sheetMesh) as thick as its disc (`length`): a
// 0.3 m disc of thickness 0.03 m dropped flat on the ground, after 1 s, is a closed slab (every
// edge of the exported OBJ shared by two faces, vertices welded by position) from the ground
// (y = 0: its particles rest at their contact radius, 0.015 m) to 0.03 m, within 1e-4 m. The
// voxel cells it was meshed from before were 6.6 mm thick, 13 mm above the ground, and broke
// into strips wherever rows of particles fell in different cell layers.
TEST(CliExport, AClothIsAClosedSheetAsThickAsItsDisc) {
  const fs::path dir = freshDir("cloth");
  writeText(dir / "c.strokes", "physketch-strokes 1\nstroke create disc 0.30 linen length=0.03\n"
                               "sample 0  -0.15 0.10 0\nsample 1  0.15 0.10 0\nplay 1\n");
  writeText(dir / "c.scene", "physketch-scene 1\nstrokes c.strokes\nworkspace 0 0.5 0 1.0\n"
                             "material linen cloth density=300\nduration 1\noutput report\n");
  const fs::path out = dir / "out";
  const Result r = runCli("run '" + (dir / "c.scene").string() + "' -q --export mesh --out '" + out.string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const fs::path obj = out / "meshes" / "frame_0030" / "0000_stroke_0.obj";
  const auto v = objVertices(obj);
  ASSERT_GT(v.size(), 100u);
  double lo = 1e9, hi = -1e9;
  for (const auto& x : v) lo = std::min(lo, x[1]), hi = std::max(hi, x[1]);
  EXPECT_NEAR(lo, 0.0, 1e-4);
  EXPECT_NEAR(hi, 0.03, 1e-4);
  // Faces "f a//a b//b c//c" (1-based); weld by position, then count directed edges.
  std::map<std::array<double, 3>, long> weld;
  std::vector<long> id(v.size());
  for (std::size_t i = 0; i < v.size(); ++i) id[i] = weld.emplace(v[i], long(i)).first->second;
  std::map<std::pair<long, long>, int> edges;
  std::ifstream in(obj);
  std::string line;
  long faces = 0;
  while (std::getline(in, line)) {
    if (line.rfind("f ", 0) != 0) continue;
    std::istringstream ls(line.substr(2));
    std::string tok;
    std::vector<long> f;
    while (ls >> tok) f.push_back(id[std::size_t(std::stol(tok.substr(0, tok.find('/'))) - 1)]);
    ASSERT_EQ(f.size(), 3u);
    for (int e = 0; e < 3; ++e) ++edges[{f[std::size_t(e)], f[std::size_t((e + 1) % 3)]}];
    ++faces;
  }
  ASSERT_GT(faces, 100);
  long unpaired = 0;
  for (const auto& [e, n] : edges)
    if (n != 1 || edges.count({e.second, e.first}) == 0) ++unpaired;
  EXPECT_EQ(unpaired, 0) << "of " << edges.size() << " directed edges";
  fs::remove_all(dir);
}

// --solid-surface grid: MPM solids meshed from the grid's mass (PhyVR §4.1). The oracle for the
// volume is the particles' (count x h^3 at rest; the search meets it to 0.2 %, report.json says
// how far each mesh was: within 0.5 % allows the float sums); the exported mesh's vertices lie
// within the body's box grown by one grid spacing (dx = 2 h: the field's reach past the
// particles), and under PBD, which has no grid, the option is an error naming the solver.
TEST(CliSolidSurface, GridMeshesMpmSolidsFromTheGridMassAndPbdHasNone) {
  const fs::path dir = freshDir("grid");
  writeText(dir / "m.strokes", "physketch-strokes 1\nprimitive box jelly 0  0 0.3 0  0.12 0.12 0.12\n");
  writeText(dir / "m.scene", "physketch-scene 1\nstrokes m.strokes\nworkspace 0 0.5 0 1.0\nsolver mpm\nsubsteps auto\n"
                             "material jelly elastic preset=soft\nduration 0.1\noutput report\n");
  const fs::path out = dir / "out";
  Result r = runCli("run '" + (dir / "m.scene").string() + "' -q --out '" + out.string() +
                        "' --frames 2 --export mesh --solid-surface grid",
                    dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const nlohmann::json rep = nlohmann::json::parse(slurp(out / "report.json"));
  ASSERT_TRUE(rep["frames"].contains("solid_surface")) << rep["frames"].dump();
  EXPECT_EQ(rep["frames"]["solid_surface"]["method"], "grid");
  EXPECT_EQ(rep["frames"]["solid_surface"]["surfaces"], 2);
  EXPECT_LT(rep["frames"]["solid_surface"]["max_volume_change_percent"].get<double>(), 0.5);
  const auto v = objVertices(out / "meshes" / "frame_0000" / "0000_stroke_0.obj");
  ASSERT_GT(v.size(), 100u);
  const double h = 1.0 / 151.0, reach = 0.06 + 2.0 * h;  // the box's half edge + dx
  double lowest = 1.0;
  for (const auto& p : v) {
    EXPECT_LT(std::max({std::abs(p[0]), std::abs(p[1] - 0.3), std::abs(p[2])}), reach);
    lowest = std::min(lowest, p[1]);
  }
  EXPECT_LT(lowest, 0.3 - 0.05);  // it encloses the box, not a part of it

  r = runCli("run '" + kHello + "' -q --out '" + (dir / "pbd").string() + "' --frames 1 --solid-surface grid", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("--solid-surface grid"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("solver pbd"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("hello.scene:5: field 'solver'"), std::string::npos) << r.err;  // its solver record
  EXPECT_FALSE(fs::exists(dir / "pbd"));
  fs::remove_all(dir);
}

TEST(CliExport, UnknownExportKindIsBadInput) {
  const fs::path dir = freshDir("bad");
  const Result r = runCli("run '" + kHello + "' --out '" + (dir / "out").string() + "' --frames 1 --export mesh,gltf", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("gltf"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "out"));
  fs::remove_all(dir);
}

// Same input, same bytes: frames and every export, with 1 and 2 threads. A .vdb file holds a
// random UUID that OpenVDB makes for every file it writes (36 characters after the 21-byte
// header of magic, file version, library version and the grid-offsets flag): it is blanked
// before comparing.
TEST(CliExport, OutputsAreByteIdenticalForOneAndTwoThreads) {
  const fs::path dir = freshDir("det");
  for (int t : {1, 2}) {
    const Result r = runCli("run '" + kHello + "' --out '" + (dir / std::to_string(t)).string() + "' --frames 2 --threads " +
                                std::to_string(t) + " --export mesh,particles,vdb --smooth 2",
                            dir);
    ASSERT_EQ(r.code, 0) << r.err;
  }
  int compared = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir / "1")) {
    if (!e.is_regular_file() || e.path().filename() == "report.json") continue;
    const fs::path other = dir / "2" / fs::relative(e.path(), dir / "1");
    ASSERT_TRUE(fs::exists(other)) << other;
    std::string a = slurp(e.path()), b = slurp(other);
    if (e.path().extension() == ".vdb") {
      ASSERT_GT(a.size(), 57u);
      ASSERT_EQ(a[21 + 8], '-') << "the UUID is where OpenVDB 10 puts it";
      a.replace(21, 36, 36, 'x');
      if (b.size() > 57) b.replace(21, 36, 36, 'x');
    }
    EXPECT_TRUE(a == b) << e.path() << " differs";
    ++compared;
  }
  EXPECT_EQ(compared, 2 /*png*/ + 1 /*mtl*/ + 2 * 3 * 2 /*obj, ply*/ + 2 /*particles*/ + 2 /*vdb*/);
  fs::remove_all(dir);
}

// ---- --video

// A stand-in for ffmpeg: answers -encoders (with or without libx264), records its arguments
// and writes a small file where it was asked to write the video; or fails.
fs::path fakeFfmpeg(const fs::path& dir, bool withX264, bool fail) {
  const fs::path bin = dir / "bin";
  fs::create_directories(bin);
  const fs::path script = bin / "ffmpeg";
  std::string text = "#!/bin/sh\n";
  text += "if [ \"$2\" = \"-encoders\" ]; then echo ' V....D mpeg4   MPEG-4 part 2';";
  if (withX264) text += " echo ' V....D libx264   libx264 H.264 / AVC';";
  text += " exit 0; fi\n";
  text += "echo \"$@\" > '" + (dir / "args.txt").string() + "'\n";
  if (fail) text += "echo 'Invalid data found when processing input' >&2\nexit 1\n";
  text += "for last; do :; done\necho fake-mp4 > \"$last\"\n";
  writeText(script, text);
  fs::permissions(script, fs::perms::owner_all | fs::perms::group_read | fs::perms::group_exec);
  return bin;
}

TEST(CliVideo, WithoutFfmpegSaysSoOnceAndSucceeds) {
  const fs::path dir = freshDir("noffmpeg");
  const fs::path out = dir / "out";
  fs::create_directories(dir / "empty");
  const Result r = runCli("run '" + kHello + "' --out '" + out.string() + "' --frames 3 --video", dir,
                          "PATH='" + (dir / "empty").string() + "' ");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(countOf(r.err, "ffmpeg is not on PATH"), 1) << r.err;
  EXPECT_FALSE(fs::exists(out / "video.mp4"));
  EXPECT_TRUE(fs::exists(out / "frames" / "frame_0002.png"));
  const nlohmann::json rep = nlohmann::json::parse(slurp(out / "report.json"));
  EXPECT_EQ(rep["frames"]["video"]["written"], false);
  fs::remove_all(dir);
}

TEST(CliVideo, CallsFfmpegWithTheScenesFpsAndH264WhenItHasIt) {
  for (bool x264 : {true, false}) {
    const fs::path dir = freshDir(x264 ? "x264" : "mpeg4");
    const fs::path out = dir / "out";
    const fs::path bin = fakeFfmpeg(dir, x264, false);
    const Result r = runCli("run '" + kHello + "' --out '" + out.string() + "' --frames 3 --video", dir,
                            "PATH='" + bin.string() + ":/usr/bin:/bin' ");
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(slurp(out / "video.mp4"), "fake-mp4\n");
    const std::string args = slurp(dir / "args.txt");
    EXPECT_NE(args.find("-framerate 30 "), std::string::npos) << args;  // hello.scene: fps 30
    EXPECT_NE(args.find("-i " + (out / "frames").string() + "/frame_%04d.png"), std::string::npos) << args;
    EXPECT_NE(args.find(x264 ? "-c:v libx264" : "-c:v mpeg4"), std::string::npos) << args;
    EXPECT_NE(args.find("-pix_fmt yuv420p"), std::string::npos) << args;
    const nlohmann::json rep = nlohmann::json::parse(slurp(out / "report.json"));
    EXPECT_EQ(rep["frames"]["video"]["codec"], x264 ? "libx264" : "mpeg4");
    std::vector<std::string> left;
    for (const auto& e : fs::directory_iterator(out)) left.push_back(e.path().filename().string());
    std::sort(left.begin(), left.end());
    EXPECT_EQ(left, (std::vector<std::string>{"frames", "report.json", "video.mp4"}));  // no temporary left
    fs::remove_all(dir);
  }
}

TEST(CliVideo, FailingFfmpegIsARuntimeErrorWithItsMessage) {
  const fs::path dir = freshDir("ffmpegfails");
  const fs::path out = dir / "out";
  const fs::path bin = fakeFfmpeg(dir, true, true);
  const Result r = runCli("run '" + kHello + "' --out '" + out.string() + "' --frames 2 --video", dir,
                          "PATH='" + bin.string() + ":/usr/bin:/bin' ");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("Invalid data found"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out / "video.mp4"));
  EXPECT_FALSE(fs::exists(out / "video.mp4.tmp.mp4"));
  fs::remove_all(dir);
}

TEST(CliVideo, NeedsFramesInTheScenesOutput) {
  const fs::path dir = freshDir("noframes");
  fs::copy_file(std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.strokes", dir / "hello.strokes");
  std::string scene = slurp(kHello);
  scene.replace(scene.find("output frames report"), 20, "output report");
  writeText(dir / "r.scene", scene);
  const Result r = runCli("run '" + (dir / "r.scene").string() + "' --out '" + (dir / "out").string() + "' --frames 1 --video", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("field 'output'"), std::string::npos) << r.err;
  fs::remove_all(dir);
}

// The real ffmpeg, when this machine has one (it is an optional run-time tool, not a build
// dependency): an MP4 file (an 'ftyp' box first) appears.
TEST(CliVideo, RealFfmpegMakesAnMp4) {
  const char* path = std::getenv("PATH");
  std::string found;
  std::istringstream dirs(path ? path : "");
  for (std::string d; std::getline(dirs, d, ':');)
    if (!d.empty() && ::access((d + "/ffmpeg").c_str(), X_OK) == 0) found = d + "/ffmpeg";
  if (found.empty()) GTEST_SKIP() << "ffmpeg is not installed here; the stand-in tests cover the call";
  const fs::path dir = freshDir("realffmpeg");
  const fs::path out = dir / "out";
  const Result r = runCli("run '" + kHello + "' --out '" + out.string() + "' --frames 4 --video", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string mp4 = slurp(out / "video.mp4");
  ASSERT_GT(mp4.size(), 8u);
  EXPECT_EQ(mp4.substr(4, 4), "ftyp");
  fs::remove_all(dir);
}
