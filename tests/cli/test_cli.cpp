// End to end: the physketch binary on the bundled scene and on broken input.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <png.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/physketch/report.h"

namespace fs = std::filesystem;

namespace {

struct Result {
  int code = -1;
  std::string err;
};

// Runs the CLI with arguments, capturing stderr; returns the exit code.
Result runCli(const std::string& args, const fs::path& dir) {
  const fs::path errFile = dir / "stderr.txt";
  const std::string cmd = std::string(PHYSKETCH_CLI) + " " + args + " 2> '" + errFile.string() + "' > /dev/null";
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
  const fs::path d = fs::temp_directory_path() / ("physketch_test_cli_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

struct Rgba {
  int width = 0, height = 0;
  std::vector<unsigned char> px;
};

Rgba readPng(const fs::path& path) {
  png_image img{};
  img.version = PNG_IMAGE_VERSION;
  Rgba out;
  if (!png_image_begin_read_from_file(&img, path.c_str())) return out;
  img.format = PNG_FORMAT_RGBA;
  out.px.resize(PNG_IMAGE_SIZE(img));
  if (!png_image_finish_read(&img, nullptr, out.px.data(), 0, nullptr)) return Rgba{};
  out.width = int(img.width);
  out.height = int(img.height);
  return out;
}

nlohmann::json readJson(const fs::path& p) { return nlohmann::json::parse(slurp(p)); }

void writeText(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

}  // namespace

TEST(Cli, HelloSceneWritesFramesAndReport) {
  const fs::path dir = freshDir("hello");
  const fs::path out = dir / "out";
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.scene";
  const Result r = runCli("run '" + scene + "' --out '" + out.string() + "' --frames 4 --threads 2", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  std::vector<Rgba> frames;
  for (int i = 0; i < 4; ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%04d.png", i);
    const fs::path f = out / "frames" / name;
    ASSERT_TRUE(fs::exists(f)) << f;
    frames.push_back(readPng(f));
    ASSERT_EQ(frames.back().width, 640) << f;  // decodes, at the scene's image size
    ASSERT_EQ(frames.back().height, 480) << f;
  }
  EXPECT_FALSE(fs::exists(out / "frames" / "frame_0004.png"));
  // stderr is a file here, not a terminal: progress still shows, as plain lines (every few
  // seconds and at the end), not as a carriage-return line.
  EXPECT_NE(r.err.find("frame 4/4  t = 0.100 s"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find('\r'), std::string::npos);
  // The bodies show: hello's materials are lit versions of wood (0.72 0.50 0.30) and
  // friends; the background (0.92 0.94 0.97) and ground are grey. At least 1 % of the
  // image is far from every grey, and the frames change as the bodies fall.
  int coloured = 0;
  for (std::size_t i = 0; i + 3 < frames[0].px.size(); i += 4) {
    const int cr = frames[0].px[i], cg = frames[0].px[i + 1], cb = frames[0].px[i + 2];
    coloured += std::max({cr, cg, cb}) - std::min({cr, cg, cb}) > 40;
  }
  EXPECT_GT(coloured, 640 * 480 / 100);
  EXPECT_NE(frames[0].px, frames[3].px);
  const nlohmann::json rep = readJson(out / "report.json");
  EXPECT_EQ(rep["status"], "ok");
  EXPECT_FALSE(rep["sketch"]["per_operation"].empty());
  std::vector<std::string> passes;
  for (const auto& e : rep["passes"]) passes.push_back(e["pass"]);
  EXPECT_NE(std::find(passes.begin(), passes.end(), "rigid_contact"), passes.end());
  EXPECT_EQ(rep["frames"]["written"], 4);
  // Per-frame body poses: one entry per frame, one pose per body. All three bodies are
  // drawn in the air and fall from rest, so between frames 0 and 1 their centres drop by the integrator's
  // exact discrete free fall g h^2 n(n+1)/2 (n substeps of h in 1/30 s: 6.1 mm for
  // hello's 2 steps x 4 substeps), to double rounding.
  ASSERT_EQ(rep["poses"].size(), 4u);
  const auto& p0 = rep["poses"][0]["bodies"];
  const auto& p1 = rep["poses"][1]["bodies"];
  ASSERT_EQ(p0.size(), rep["bodies"].size());
  const double h = rep["solver"]["dt"].get<double>() / rep["solver"]["substeps"].get<double>();
  const double n = std::round(1.0 / 30.0 / h);
  int falling = 0;
  for (std::size_t b = 0; b < p0.size(); ++b) {
    const double drop = p0[b][1].get<double>() - p1[b][1].get<double>();
    falling += std::abs(drop - 9.81 * h * h * n * (n + 1) / 2) < 1e-9;
  }
  EXPECT_EQ(falling, int(p0.size()));
  EXPECT_EQ(p0.size(), 3u);
  // A shorter run into the same folder leaves no stale frames behind.
  ASSERT_EQ(runCli("run '" + scene + "' --out '" + out.string() + "' --frames 2 -q", dir).code, 0);
  EXPECT_TRUE(fs::exists(out / "frames" / "frame_0001.png"));
  EXPECT_FALSE(fs::exists(out / "frames" / "frame_0002.png"));
  fs::remove_all(dir);
}

TEST(Cli, FramesAreBitIdenticalForOneAndTwoThreads) {
  const fs::path dir = freshDir("threads");
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.scene";
  for (int t : {1, 2})
    ASSERT_EQ(runCli("run '" + scene + "' -q --frames 31 --threads " + std::to_string(t) + " --out '" +
                         (dir / ("t" + std::to_string(t))).string() + "'",
                     dir)
                  .code,
              0);
  // The whole solver state of every frame (poses, bit-exact in the JSON's shortest
  // round-trip form) and the last frame's pixels, when the bodies have landed and come
  // to rest: any divergence between thread counts grows into them.
  const nlohmann::json a = readJson(dir / "t1" / "report.json"), b = readJson(dir / "t2" / "report.json");
  ASSERT_EQ(a["poses"].size(), 31u);
  EXPECT_EQ(a["poses"], b["poses"]);
  EXPECT_EQ(slurp(dir / "t1" / "frames" / "frame_0030.png"), slurp(dir / "t2" / "frames" / "frame_0030.png"));
  fs::remove_all(dir);
}

TEST(Cli, ValidateModeGivesTheSameResult) {
  // --validate checks after every pass; it must not change what the solver computes.
  const fs::path dir = freshDir("validate");
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/play.scene";
  for (const char* v : {"", "--validate"}) {
    // The message keeps stderr: this once exited 1 under ASan and passed on the retry.
    const Result r =
        runCli("run '" + scene + "' -q --frames 20 " + v + " --out '" + (dir / (std::string("o") + v)).string() + "'", dir);
    ASSERT_EQ(r.code, 0) << v << ": " << r.err;
  }
  const nlohmann::json a = readJson(dir / "o" / "report.json"), b = readJson(dir / "o--validate" / "report.json");
  EXPECT_EQ(a["poses"], b["poses"]);
  EXPECT_EQ(b["solver"]["validate"], true);
  fs::remove_all(dir);
}

TEST(Cli, BrokenSceneExitsOneWithFileLineFieldAndWritesNothing) {
  const fs::path dir = freshDir("broken");
  {
    std::ofstream s(dir / "bad.strokes");
    s << "physketch-strokes 1\nstroke create sphere -0.05 wood\nsample 0 0 0.5 0\n";
    std::ofstream sc(dir / "bad.scene");
    sc << "physketch-scene 1\nstrokes bad.strokes\nmaterial wood rigid 600 0.5 1 1 1\n";
  }
  const fs::path out = dir / "out";
  Result r = runCli("run '" + (dir / "bad.scene").string() + "' --out '" + out.string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("bad.strokes:2: field 'size'"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out));

  // A scene naming a stroke file that does not exist: the scene's line is blamed.
  {
    std::ofstream sc(dir / "missing.scene");
    sc << "physketch-scene 1\n\nstrokes nowhere.strokes\n";
  }
  r = runCli("run '" + (dir / "missing.scene").string() + "' --out '" + out.string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("missing.scene:3: field 'path'"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out));
  fs::remove_all(dir);
}

// --gl-device gpu on a machine without a GPU (the project's): exit 2 with EGL's answer and no
// output folder; where a GPU drew, report.json says it was a hardware device, asked for as gpu.
TEST(Cli, GlDeviceGpuDrawsOnAGpuOrFailsBeforeWritingAnything) {
  const fs::path dir = freshDir("gl_device");
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.scene";
  const fs::path out = dir / "out";
  const Result r = runCli("run '" + scene + "' -q --frames 2 --gl-device gpu --out '" + out.string() + "'", dir);
  if (r.code == 0) {
    const nlohmann::json rep = readJson(out / "report.json");
    EXPECT_EQ(rep["frames"]["gl_device"], "gpu");
    const std::string device = rep["frames"]["device"];
    EXPECT_NE(device.find("(hardware"), std::string::npos) << device;
    EXPECT_EQ(device.find("llvmpipe"), std::string::npos) << device;
  } else {
    EXPECT_EQ(r.code, 2) << r.err;
    EXPECT_NE(r.err.find("--gl-device gpu"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out));
  }
  // An unknown device is a usage error that names the option.
  fs::remove_all(out);
  const Result bad = runCli("run '" + scene + "' -q --gl-device vulkan --out '" + out.string() + "'", dir);
  EXPECT_NE(bad.code, 0);
  EXPECT_NE(bad.err.find("--gl-device"), std::string::npos) << bad.err;
  EXPECT_FALSE(fs::exists(out));
  fs::remove_all(dir);
}

TEST(Cli, LintListsOperationsAndWarnsWithoutWritingAnything) {
  const fs::path dir = freshDir("lint");
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/play.scene";
  const std::string out = (dir / "lint.txt").string();
  const int status = std::system((std::string(PHYSKETCH_CLI) + " lint '" + scene + "' > '" + out + "' 2>&1").c_str());
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
  const std::string text = slurp(out);
  EXPECT_NE(text.find("body table"), std::string::npos) << text;
  EXPECT_NE(text.find("after play"), std::string::npos) << text;
  EXPECT_NE(text.find("memory estimate"), std::string::npos) << text;
  // A sketch with an error exits 1.
  {
    std::ofstream s(dir / "e.strokes");
    s << "physketch-strokes 1\nprimitive box wood 0 0 0.5 0 0.1 0.1 0.1\nundo 2\n";
    std::ofstream sc(dir / "e.scene");
    sc << "physketch-scene 1\nstrokes e.strokes\nmaterial wood rigid 600 0.5 1 1 1\n";
  }
  const Result r = runCli("lint '" + (dir / "e.scene").string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("e.strokes:3: field 'count': undo past the beginning"), std::string::npos) << r.err;
  fs::remove_all(dir);
}

// The rope and cloth examples lint (their sketch is fine, with particles counted per kind)
// although solver pbd does not simulate rope and cloth yet: lint ends with the note, run refuses
// them naming the material's line. What pbd never simulates (sand) stays a lint error.
// The rope and cloth examples: lint counts their kinds, and they run. After 2.5 s the rope
// still carries its stone (hung from the fixed beam at 0.68 m by a 0.28 m rope and 3 cm
// of stone: the stone's centre stays above 0.3 m, where it would be on the ground at
// 0.03 m), and the cloth lies draped on the table (top at 0.315 m): its centre stays above
// 0.2 m with the edges hanging down (on the ground it would be below 0.05 m).
TEST(Cli, LintAndRunTheRopeAndClothExamples) {
  const fs::path dir = freshDir("lint_strands");
  for (const std::string kind : {"rope", "cloth"}) {
    const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/" + kind + ".scene";
    const std::string out = (dir / "lint.txt").string();
    const int status = std::system((std::string(PHYSKETCH_CLI) + " lint '" + scene + "' > '" + out + "' 2>&1").c_str());
    ASSERT_TRUE(WIFEXITED(status));
    EXPECT_EQ(WEXITSTATUS(status), 0) << kind;
    const std::string text = slurp(out);
    EXPECT_NE(text.find("kinds:\n"), std::string::npos) << text;
    EXPECT_NE(text.find("  " + kind), std::string::npos) << text;
    EXPECT_EQ(text.find("refuses this scene"), std::string::npos) << text;
    const Result r = runCli("run '" + scene + "' -q --frames 2 --out '" + (dir / kind).string() + "'", dir);
    ASSERT_EQ(r.code, 0) << kind << ": " << r.err;
  }
  const std::string rope = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/rope.scene";
  Result r = runCli("run '" + rope + "' -q --out '" + (dir / "rope").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto ropeRep = readJson(dir / "rope" / "report.json");
  const auto& ropeLast = ropeRep["poses"].back()["bodies"];
  EXPECT_GT(ropeLast[2][1].get<double>(), 0.3) << "the stone fell";
  const std::string cloth = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/cloth.scene";
  r = runCli("run '" + cloth + "' -q --out '" + (dir / "cloth").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto clothRep = readJson(dir / "cloth" / "report.json");
  double clothY = -1.0;
  for (std::size_t b = 0; b < clothRep["sketch"]["bodies"].size(); ++b)
    if (clothRep["sketch"]["bodies"][b]["layout"] == "lattice") clothY = clothRep["poses"].back()["bodies"][b][1].get<double>();
  EXPECT_GT(clothY, 0.2) << "the cloth fell through the table";
  writeText(dir / "s.strokes", "physketch-strokes 1\nprimitive box grit 0  0 0.45 0  0.1 0.1 0.1\n");
  writeText(dir / "s.scene", "physketch-scene 1\nstrokes s.strokes\nmaterial grit sand\n");
  r = runCli("lint '" + (dir / "s.scene").string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("s.scene:3: field 'kind': material 'grit' is kind sand: solver pbd (the default) does not simulate sand"),
            std::string::npos)
      << r.err;
  fs::remove_all(dir);
}

// The two-fluid example runs, past the water's stone landing on the floor (frame 6, where water
// it carried into the ground once stopped the run), and its plan names each fluid's sound
// speed (the density pass takes every fluid material's own parameters).
TEST(Cli, TheTwoFluidExampleRuns) {
  const fs::path dir = freshDir("honey");
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/honey.scene";
  const std::string planFile = (dir / "plan.txt").string();
  const int status = std::system((std::string(PHYSKETCH_CLI) + " plan '" + scene + "' > '" + planFile + "' 2>&1").c_str());
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0);
  const std::string plan = slurp(planFile);
  EXPECT_NE(plan.find("sound speed water auto, honey auto"), std::string::npos) << plan;
  const Result r = runCli("run '" + scene + "' -q --frames 9 --out '" + (dir / "run").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir / "run" / "frames" / "frame_0008.png"));
}

// Every bundled example (scenes/*.scene) runs its first 8 frames (0.27 s at 30 fps) with the exit
// status 0: the guard stops none of them. A change that makes an example stop fails here:
// scenes/honey.scene stopped at frame 6 for a session while its own test ran 2 frames.
// scenes/cap.scene (the 688,590-particle cap) is left out: its own tests and the benchmarks
// run it, and 8 frames of it take minutes under the sanitizers. About 20 s in all here.
TEST(Cli, EveryExampleRunsItsFirstFrames) {
  const fs::path dir = freshDir("examples");
  std::vector<fs::path> scenes;
  for (const auto& e : fs::directory_iterator(fs::path(PHYSKETCH_SOURCE_DIR) / "scenes"))
    if (e.path().extension() == ".scene" && e.path().filename() != "cap.scene") scenes.push_back(e.path());
  std::sort(scenes.begin(), scenes.end());
  EXPECT_GE(scenes.size(), 10u);
  for (const fs::path& scene : scenes) {
    const fs::path out = dir / scene.stem();
    const Result r = runCli("run '" + scene.string() + "' -q --look splats --frames 8 --out '" + out.string() + "'", dir);
    EXPECT_EQ(r.code, 0) << scene.filename() << ": " << r.err;
  }
  fs::remove_all(dir);
}

TEST(Cli, AnUnstableRunExitsTwoAndTheReportNamesTheGuardRecord) {
  // 1000 m/s^2 sideways with 0.1 s steps: the box passes the 100 m/s explosion bound within two steps.
  const fs::path dir = freshDir("unstable");
  {
    std::ofstream s(dir / "u.strokes");
    s << "physketch-strokes 1\nprimitive box wood 0 0 0.9 0 0.1 0.1 0.1\n";
    std::ofstream sc(dir / "u.scene");
    sc << "physketch-scene 1\nstrokes u.strokes\ndt 0.1\nfps 10\ngravity 1000 0 0\n"
          "material wood rigid 600 0.5 1 1 1\noutput report\n";
  }
  const fs::path out = dir / "out";
  const Result r = runCli("run '" + (dir / "u.scene").string() + "' -q --out '" + out.string() + "'", dir);
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("stability guard: explosion at step "), std::string::npos) << r.err;
  const std::string rep = slurp(out / "report.json");
  EXPECT_NE(rep.find("\"status\": \"unstable\""), std::string::npos) << rep;
  EXPECT_NE(rep.find("\"kind\": \"explosion\""), std::string::npos) << rep;
  fs::remove_all(dir);
}

// --guard warn: a recoverable trip (vorticity confinement's energy growth in a spinning blob) is logged
// and the run goes on to its last frame; the log's first record is the one a stopping run reports
// (same frame, pass and particle), the frames before it are the stopping run's, and the run is the
// same for 1 and 2 threads. NaN and inverted elements stop under warn too.
TEST(Cli, GuardWarnLogsRecoverableTripsAndGoesOn) {
  const fs::path dir = freshDir("guard_warn");
  const std::string hard = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hard/";
  auto shortCopy = [&](const std::string& name, const std::string& duration) {
    fs::copy_file(hard + name + ".strokes", dir / (name + ".strokes"));
    std::string text = slurp(hard + name + ".scene");
    const std::size_t at = text.find("\nduration ");
    text = text.substr(0, at) + "\nduration " + duration + text.substr(text.find('\n', at + 1));
    writeText(dir / (name + ".scene"), text);
    return (dir / (name + ".scene")).string();
  };
  const std::string spin = shortCopy("vorticity_spin", "0.5");
  Result r = runCli("run '" + spin + "' -q --out '" + (dir / "stop").string() + "'", dir);
  ASSERT_EQ(r.code, 2) << r.err;
  const auto stop = readJson(dir / "stop" / "report.json");
  const auto& record = stop["guard"];
  ASSERT_EQ(record["kind"], "energy_growth");
  nlohmann::json warned[2];
  for (int threads : {1, 2}) {
    const fs::path out = dir / ("warn" + std::to_string(threads));
    r = runCli("run '" + spin + "' -q --guard warn --threads " + std::to_string(threads) + " --out '" + out.string() + "'", dir);
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.err.find("warning: frame " + std::to_string(record["frame"].get<int>()) + ": stability guard: energy_growth"),
              std::string::npos) << r.err;
    warned[threads - 1] = readJson(out / "report.json");
  }
  const auto& rep = warned[0];
  EXPECT_EQ(rep["status"], "warned");
  EXPECT_EQ(rep["frames"]["written"], rep["frames"]["requested"]);
  ASSERT_GE(rep["guard_warnings"].size(), 1u);
  const auto& first = rep["guard_warnings"][0];
  for (const char* key : {"kind", "frame", "step", "substep", "pass", "particle", "stroke", "material"})
    EXPECT_EQ(first[key], record[key]) << key;
  EXPECT_GE(first["steps_tripped"].get<int>(), 1);
  const int before = record["frame"].get<int>();  // frames 0..before-1 were written by both runs
  for (int f = 0; f < before; ++f) EXPECT_EQ(rep["poses"][f], stop["poses"][f]) << "frame " << f;
  EXPECT_EQ(warned[0]["poses"], warned[1]["poses"]);
  EXPECT_EQ(warned[0]["guard_warnings"], warned[1]["guard_warnings"]);
  // An inverted deformation gradient is not recoverable: warn stops as stop does.
  const std::string steel = shortCopy("mpm_fixed_substeps", "0.2");
  r = runCli("run '" + steel + "' -q --guard warn --out '" + (dir / "steel").string() + "'", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_EQ(readJson(dir / "steel" / "report.json")["guard"]["kind"], "inverted");
  fs::remove_all(dir);
}

// Issue 11's representative plans: a fluid-only PBD scene runs the fluid passes and none of the
// rigid, soft or rope ones; MPM sand + water runs the return mapping for the sand only; MPM
// elastic runs none; a report-only output makes no meshes and no GL context. The expected sets
// follow from what each scene holds (docs/architecture.md's pass tables), not from the plan code.
TEST(Cli, PlansOfRepresentativeScenesListOnlyTheirPasses) {
  const fs::path dir = freshDir("plans");
  auto planOf = [&](const std::string& name, const std::string& scene, const std::string& strokes) {
    writeText(dir / (name + ".strokes"), "physketch-strokes 1\n" + strokes);
    writeText(dir / (name + ".scene"), "physketch-scene 1\nstrokes " + name + ".strokes\nduration 0.1\n" + scene + "output report\n");
    const std::string outFile = (dir / "plan.txt").string();
    EXPECT_EQ(std::system((std::string(PHYSKETCH_CLI) + " plan '" + (dir / (name + ".scene")).string() + "' --all > '" +
                           outFile + "'").c_str()), 0);
    const std::string text = slurp(outFile);
    std::map<std::string, std::string> lines;  // pass -> "on"/"off" and its reason
    std::istringstream in(text);
    std::string last;
    for (std::string line; std::getline(in, line);) {
      if (line.rfind("        ", 0) == 0 && !last.empty()) lines[last] += line;  // the pass's detail line
      for (const char* state : {"  on   ", "  off  "})
        if (line.rfind(state, 0) == 0) {
          const std::string rest = line.substr(7);
          last = rest.substr(0, rest.find(' '));
          lines[last] = std::string(state).substr(2, 3) + rest.substr(rest.find(' '));
        }
    }
    lines["(footer)"] = text.substr(std::min(text.size(), text.rfind("per frame:")));
    return lines;
  };
  auto on = [](const std::map<std::string, std::string>& plan, const std::string& pass) {
    return plan.count(pass) && plan.at(pass).rfind("on ", 0) == 0;
  };
  const auto fluid = planOf("fluid", "material water fluid density=1000\n", "primitive box water 0  0 0.2 0  0.1 0.1 0.1\n");
  for (const char* pass : {"predict", "fluid_neighbors", "particle_contact", "density", "particle_update", "guard"})
    EXPECT_TRUE(on(fluid, pass)) << pass;
  for (const char* pass : {"integrate", "find_contacts", "rigid_contact", "body_contact", "update", "cluster_match", "distance",
                           "plasticity", "restitution", "kinematic", "find_colliders", "collider_contact"}) {
    ASSERT_TRUE(fluid.count(pass)) << pass;
    EXPECT_FALSE(on(fluid, pass)) << pass << ": " << fluid.at(pass);
  }
  EXPECT_NE(fluid.at("(footer)").find("no meshes and no GL context"), std::string::npos) << fluid.at("(footer)");
  for (const auto& [pass, line] : fluid)  // nothing is allocated for a pass that is off
    if (line.rfind("off", 0) == 0) {
      EXPECT_NE(line.find("nothing allocated"), std::string::npos) << pass << ": " << line;
    }
  const auto mixed = planOf("mpm", "solver mpm\nsubsteps auto\nmaterial water fluid\nmaterial grit sand\n",
                            "primitive box water 0  0 0.2 0  0.1 0.1 0.1\nprimitive box grit 0  0.2 0.2 0  0.1 0.1 0.1\n");
  ASSERT_TRUE(on(mixed, "plasticity"));
  EXPECT_NE(mixed.at("plasticity").find("plastic materials grit (sand)"), std::string::npos) << mixed.at("plasticity");
  EXPECT_EQ(mixed.at("plasticity").find("water"), std::string::npos) << mixed.at("plasticity");
  // The sand's 15^3 particles (a 0.1 m box at 1/151 m), not the water's.
  EXPECT_NE(mixed.at("plasticity").find("touches 3375 particles"), std::string::npos) << mixed.at("plasticity");
  EXPECT_NE(mixed.at("p2g").find("touches 6750 particles"), std::string::npos) << mixed.at("p2g");
  const auto elastic = planOf("elastic", "solver mpm\nsubsteps auto\nmaterial jelly elastic preset=soft\n",
                              "primitive box jelly 0  0 0.2 0  0.1 0.1 0.1\n");
  EXPECT_FALSE(on(elastic, "plasticity"));
  for (const char* pass : {"p2g", "grid_update", "g2p", "guard"}) EXPECT_TRUE(on(elastic, pass)) << pass;
  fs::remove_all(dir);
}

TEST(Cli, HelpVersionAndUsageErrors) {
  const fs::path dir = freshDir("help");
  EXPECT_EQ(runCli("--help", dir).code, 0);
  EXPECT_EQ(runCli("--version", dir).code, 0);
  EXPECT_EQ(runCli("run", dir).code, 1);                  // missing scene
  Result unknown = runCli("frobnicate x", dir);           // unknown subcommand: named, with the known ones
  EXPECT_EQ(unknown.code, 1);
  EXPECT_NE(unknown.err.find("unknown subcommand 'frobnicate' (known: run, plan, lint"), std::string::npos) << unknown.err;
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.scene";
  Result r = runCli("plan '" + scene + "'", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  // The plan of a scene that sketches after play names the pass those strokes switch on.
  const std::string play = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/play.scene";
  const std::string planOut = (dir / "plan.txt").string();
  ASSERT_EQ(std::system((std::string(PHYSKETCH_CLI) + " plan '" + play + "' > '" + planOut + "'").c_str()), 0);
  const std::string planText = slurp(planOut);
  EXPECT_NE(planText.find("kinematic"), std::string::npos) << planText;
  EXPECT_NE(planText.find("rigid_contact"), std::string::npos) << planText;
  fs::remove_all(dir);
}

TEST(Cli, AFarCameraSeesABigSceneAndACameraLookingAwayIsAWarning) {
  // Issue: a 100 m workspace viewed from 150 m gave blank frames and exit 0 (the far plane
  // was fixed near 100 m). Near and far now come from the scene's bounds; a frame with
  // nothing in view is a warning in the report and on stderr.
  const fs::path dir = freshDir("camera");
  const std::string common = "physketch-scene 1\nstrokes big.strokes\nworkspace 0 50 0 100\n"
                             "material wood rigid 600 0.5 0.9 0.2 0.1\nimage 160 120\n";
  writeText(dir / "big.strokes", "physketch-strokes 1\nprimitive box wood 0  0 30 0  30 30 30\n");
  writeText(dir / "far.scene", common + "camera 90 100 110  0 30 0  40\n");
  writeText(dir / "away.scene", common + "camera 90 100 110  300 100 400  40\n");
  Result r = runCli("run '" + (dir / "far.scene").string() + "' -q --frames 2 --out '" + (dir / "far").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const Rgba img = readPng(dir / "far" / "frames" / "frame_0001.png");
  int red = 0;  // the box's lit colour is red-dominant: r > g + 60
  for (std::size_t i = 0; i + 3 < img.px.size(); i += 4) red += img.px[i] > img.px[i + 1] + 60;
  EXPECT_GT(red, 160 * 120 / 50) << "the box covers a few per cent of the image from 150 m";
  EXPECT_TRUE(readJson(dir / "far" / "report.json")["warnings"].empty());
  r = runCli("run '" + (dir / "away.scene").string() + "' -q --frames 2 --out '" + (dir / "away").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("show no body"), std::string::npos) << r.err;
  const auto w = readJson(dir / "away" / "report.json")["warnings"];
  ASSERT_EQ(w.size(), 1u);
  EXPECT_NE(w[0].get<std::string>().find("2 of 2 frames"), std::string::npos) << w;
  fs::remove_all(dir);
}

TEST(Cli, TrianglesArePerFrameNotCumulative) {
  const fs::path dir = freshDir("tris");
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.scene";
  for (int n : {2, 6})
    ASSERT_EQ(runCli("run '" + scene + "' -q --frames " + std::to_string(n) + " --out '" + (dir / std::to_string(n)).string() + "'", dir)
                  .code,
              0);
  const auto a = readJson(dir / "2" / "report.json")["frames"], b = readJson(dir / "6" / "report.json")["frames"];
  EXPECT_GT(a["triangles"].get<long>(), 0);
  EXPECT_EQ(a["triangles"], b["triangles"]);  // rigid bodies: the same meshes every frame
  EXPECT_EQ(a["triangles_meshed"], b["triangles_meshed"]);  // meshed once, not per frame
  fs::remove_all(dir);
}

TEST(Cli, VelocitySpinAndFixedFromTheStrokeFileReachTheSolver) {
  // vel= and spin= start a body moving, `fixed` holds one still; checked in the report's
  // poses against the closed form: a body 0.45 m up flies free for 2 frames (1/15 s),
  // its centre moving v t in x (exact for the integrator) and turning w t about y.
  const fs::path dir = freshDir("motion");
  writeText(dir / "m.strokes",
            "physketch-strokes 1\n"
            "primitive box wood 0  0 0.45 0  0.1 0.1 0.1 vel=1.5,0,0 spin=0,2,0\n"
            "primitive box wood 0  0.3 0.2 0  0.1 0.1 0.1 fixed\n");
  writeText(dir / "m.scene", "physketch-scene 1\nstrokes m.strokes\nmaterial wood rigid 600 0.5 0.9 0.2 0.1\noutput report\n");
  const Result r = runCli("run '" + (dir / "m.scene").string() + "' -q --frames 3 --out '" + (dir / "o").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto poses = readJson(dir / "o" / "report.json")["poses"];
  const auto& a0 = poses[0]["bodies"][0];
  const auto& a2 = poses[2]["bodies"][0];
  EXPECT_NEAR(a2[0].get<double>() - a0[0].get<double>(), 1.5 / 15.0, 1e-9);
  const double qw = a2[3].get<double>(), qy = a2[5].get<double>();
  EXPECT_NEAR(2.0 * std::atan2(qy, qw), 2.0 / 15.0, 1e-9);  // a cube: y is a principal axis
  EXPECT_EQ(poses[0]["bodies"][1], poses[2]["bodies"][1]);  // fixed: not a bit moved
  fs::remove_all(dir);
}

TEST(Cli, WhatTheSolverDoesNotSimulateYetIsAnErrorAtLoadTimeNamingTheRecord) {
  const fs::path dir = freshDir("support");
  writeText(dir / "s.strokes", "physketch-strokes 1\nprimitive box water 0  0 0.45 0  0.1 0.1 0.1\n");
  const auto scene = [&](const std::string& name, const std::string& body) {
    writeText(dir / name, "physketch-scene 1\nstrokes s.strokes\n" + body);
    return "run '" + (dir / name).string() + "' -q --out '" + (dir / "o").string() + "'";
  };
  // A kind the solver never simulates: the error names the material's line and the solver that does.
  Result r = runCli(scene("mpm.scene", "solver mpm\nmaterial water rope\n"), dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("solver mpm (line 3) does not simulate rope; solver pbd does"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "o"));
  // Tool strokes run under mpm too (they did not before: the same scene was this error).
  writeText(dir / "t.strokes", "physketch-strokes 1\nprimitive box water 0  0 0.45 0  0.1 0.1 0.1\n"
                               "stroke tool cube 0.1\nsample 0.5  0 0.3 0\nsample 1.0  0.2 0.3 0\n");
  writeText(dir / "tool.scene", "physketch-scene 1\nstrokes t.strokes\nsolver mpm\nsubsteps auto\nmaterial water fluid\n"
                                "duration 0.6\noutput report\n");
  r = runCli("run '" + (dir / "tool.scene").string() + "' -q --out '" + (dir / "t").string() + "'", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  fs::remove_all(dir);
}

TEST(Cli, PlanAllListsThePassesThatAreOffWithWhyAndPlanAfterAddsMeasuredTimes) {
  // Only the effects a scene calls for: hello has no carried body and no bouncing
  // material, so kinematic and restitution are off, and --all says why; --after DIR adds
  // the ms per frame a finished run measured for each pass.
  const fs::path dir = freshDir("planall");
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.scene";
  ASSERT_EQ(runCli("run '" + scene + "' -q --frames 3 --out '" + (dir / "o").string() + "'", dir).code, 0);
  const std::string out = (dir / "plan.txt").string();
  ASSERT_EQ(std::system((std::string(PHYSKETCH_CLI) + " plan '" + scene + "' --all --after '" + (dir / "o").string() +
                         "' > '" + out + "'")
                            .c_str()),
            0);
  const std::string text = slurp(out);
  EXPECT_NE(text.find("off  kinematic  (no body is held"), std::string::npos) << text;
  EXPECT_NE(text.find("off  restitution  (no rigid body's material has restitution > 0"), std::string::npos)
      << text;
  // A scene of rigid bodies pays for no particle-level pass (soft, rope, cloth, fluid), and holds
  // nothing for one: what each pass holds is measured (its buffers' capacity).
  const auto lineOf = [&text](const std::string& start) {
    const std::size_t at = text.find(start);
    return at == std::string::npos ? std::string() : text.substr(at, text.find('\n', at) - at);
  };
  for (const char* off : {"predict", "find_neighbors", "particle_contact", "cluster_match", "distance", "density",
                          "fluid_neighbors", "particle_update"}) {
    const std::string line = lineOf(std::string("off  ") + off + "  (");
    EXPECT_NE(line.find("nothing allocated"), std::string::npos) << off << ": " << line;
  }
  // The rest offsets write_particles reads: 3 floats per particle (31655), 371 KiB.
  EXPECT_NE(text.find("holds 371 KiB at play"), std::string::npos) << text;
  const auto report = readJson(dir / "o" / "report.json");
  for (const auto& pass : report["passes"]) {
    if (pass["pass"].get<std::string>().rfind("render.", 0) == 0) continue;
    EXPECT_TRUE(pass.contains("held_bytes")) << pass;
    if (pass["held_bytes"].get<double>() > 0) {
      EXPECT_GT(pass["calls"].get<double>(), 0) << pass;
    }
    if (pass["pass"] == "write_particles") {
      EXPECT_GE(pass["held_bytes"].get<double>(), 12.0 * 31655) << pass;
    }
  }
  EXPECT_NE(text.find("on   rigid_contact"), std::string::npos) << text;
  EXPECT_NE(text.find("touches 31655 particles in 3 bodies"), std::string::npos) << text;
  EXPECT_NE(text.find("measured"), std::string::npos) << text;
  EXPECT_NE(text.find("render.png  measured"), std::string::npos) << text;
  // Without --all the off passes are not listed; a folder without a report is an input error.
  ASSERT_EQ(std::system((std::string(PHYSKETCH_CLI) + " plan '" + scene + "' > '" + out + "'").c_str()), 0);
  EXPECT_EQ(slurp(out).find("restitution"), std::string::npos);
  const Result r = runCli("plan '" + scene + "' --after '" + (dir / "nothing").string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("report.json"), std::string::npos) << r.err;
  fs::remove_all(dir);
}

TEST(Cli, TheCollideExampleKeepsBodiesOnEachOther) {
  // scenes/collide.scene (the README's example of what rigid bodies do): after 2 s the
  // box thrown onto the fixed table top lies on it (centre above the top at 0.265 m, not
  // on the ground at 0.03 m), and the block dropped onto the other block rests on it
  // (centre above the lower block's top at 0.08 m).
  const fs::path dir = freshDir("collide");
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/collide.scene";
  const Result r = runCli("run '" + scene + "' -q --out '" + (dir / "o").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto rep = readJson(dir / "o" / "report.json");
  EXPECT_EQ(rep["status"], "ok");
  const auto& last = rep["poses"].back()["bodies"];
  ASSERT_EQ(last.size(), 5u);
  EXPECT_EQ(rep["poses"][0]["bodies"][0], last[0]);  // the fixed table top
  EXPECT_GT(last[1][1].get<double>(), 0.265);         // the thrown box, on the table
  EXPECT_GT(last[4][1].get<double>(), 0.08);          // the dropped block, on the other
  fs::remove_all(dir);
}

TEST(Cli, TheJellyExampleRestsSoftBodiesOnTheTable) {
  // scenes/jelly.scene (soft bodies with rigid ones): after 2 s the jelly block lies on the
  // fixed table top (its centre above the top at 0.215 m, over the table), the wooden block
  // dropped onto it lies on the jelly (above the jelly's centre), and the clay lump thrown
  // at the ground kept a dent: its centre lies lower than its 5 cm radius.
  const fs::path dir = freshDir("jelly");
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/jelly.scene";
  const Result r = runCli("run '" + scene + "' -q --out '" + (dir / "o").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto rep = readJson(dir / "o" / "report.json");
  EXPECT_EQ(rep["status"], "ok");
  const auto& last = rep["poses"].back()["bodies"];
  ASSERT_EQ(last.size(), 5u);
  EXPECT_GT(last[1][1].get<double>(), 0.215);                  // jelly on the table
  EXPECT_LT(std::abs(last[1][0].get<double>() + 0.2), 0.15);   // still over it
  EXPECT_GT(last[2][1].get<double>(), last[1][1].get<double>());  // the block on the jelly
  EXPECT_LT(last[4][1].get<double>(), 0.04);                   // the clay flattened
  fs::remove_all(dir);
}

// The sketch part of report.json counts particles per kind and gives each body its layout:
// the rope example's rope is one chain of 1 cm thickness (radius 5 mm), its beam and weight
// voxels. (Prepared for lint: pbd does not simulate ropes yet.)
TEST(Report, TheSketchCountsParticlesPerKindAndGivesEachBodyItsLayout) {
  const physketch::app::Prepared p =
      physketch::app::prepare(std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/rope.scene", 1, /*forLint=*/true);
  const nlohmann::json j = physketch::app::sketchJson(p);
  ASSERT_EQ(j["bodies"].size(), 3u);
  EXPECT_EQ(j["bodies"][0]["layout"], "voxels");
  EXPECT_EQ(j["bodies"][1]["layout"], "chain");
  EXPECT_NEAR(j["bodies"][1]["radius_m"].get<double>(), 0.005, 1e-9);
  EXPECT_EQ(j["bodies"][2]["layout"], "voxels");
  EXPECT_FALSE(j["bodies"][0].contains("radius_m"));
  EXPECT_EQ(j["per_kind"]["rope"], j["bodies"][1]["particles"]);
  EXPECT_EQ(j["per_kind"]["rigid"].get<int>(),
            j["bodies"][0]["particles"].get<int>() + j["bodies"][2]["particles"].get<int>());
  EXPECT_EQ(j["per_material"]["cord"], j["bodies"][1]["particles"]);
  EXPECT_EQ(j["cloth_holes"], 0);
  EXPECT_TRUE(p.notYet.empty()) << p.notYet;  // pbd simulates ropes
}

TEST(Cli, ASceneWithSolverMpmRunsElasticSandAndFluidToFramesAndReport) {
  // The same stroke format, one scene line away: `solver mpm`. Three bodies (elastic, sand,
  // fluid) run 0.1 s; the report names the solver, its plan lists the MPM passes (plasticity
  // for the sand) and each material's particles are meshed into the frames.
  const fs::path dir = freshDir("mpm");
  writeText(dir / "m.strokes",
            "physketch-strokes 1\n"
            "primitive box jelly 0  -0.2 0.3 0  0.08 0.08 0.08 vel=0,-1,0\n"
            "primitive box grit 0   0.0 0.05 0  0.06 0.1 0.06\n"
            "primitive box water 0  0.2 0.05 0  0.06 0.1 0.06\n");
  const std::string head = "physketch-scene 1\nstrokes m.strokes\n";
  const std::string mats =
      "material jelly elastic preset=soft\nmaterial grit sand preset=soft\nmaterial water fluid bulk_modulus=2e4\n"
      "image 160 120\n";
  writeText(dir / "m.scene", head + "solver mpm\nsubsteps auto\n" + mats);
  Result r = runCli("run '" + (dir / "m.scene").string() + "' -q --frames 4 --threads 2 --out '" + (dir / "o").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto rep = readJson(dir / "o" / "report.json");
  EXPECT_EQ(rep["status"], "ok");
  EXPECT_EQ(rep["solver"]["name"], "mpm");
  EXPECT_EQ(rep["solver"]["substeps_auto"], true);
  std::string passes;
  for (const auto& e : rep["solver"]["plan"]) passes += e["pass"].get<std::string>() + " ";
  EXPECT_EQ(passes, "p2g grid_update g2p projection plasticity guard ");
  EXPECT_GT(rep["frames"]["triangles"].get<long>(), 0);
  EXPECT_TRUE(fs::exists(dir / "o" / "frames" / "frame_0003.png"));
  EXPECT_TRUE(rep["warnings"].empty()) << rep["warnings"];  // nothing near the domain's walls
  // The water is meshed from anisotropic kernels by default, once per frame, its volume reported.
  EXPECT_EQ(rep["frames"]["fluid_surface"]["method"], "kernels");
  EXPECT_EQ(rep["frames"]["fluid_surface"]["surfaces"], 4);
  EXPECT_LT(rep["frames"]["fluid_surface"]["max_volume_change_percent"].get<double>(), 10.0);
  // --fluid-surface cells meshes it as the solids are (no kernel report); an unknown method is refused.
  r = runCli("run '" + (dir / "m.scene").string() + "' -q --frames 2 --fluid-surface cells --out '" + (dir / "c").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_FALSE(readJson(dir / "c" / "report.json")["frames"].contains("fluid_surface"));
  // --look splats draws one Gaussian splat per particle: no meshing at all, a splats pass instead.
  r = runCli("run '" + (dir / "m.scene").string() + "' -q --frames 2 --look splats --out '" + (dir / "s").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  std::string splatPasses;
  const auto splatReport = readJson(dir / "s" / "report.json");
  for (const auto& e : splatReport["passes"]) splatPasses += e["pass"].get<std::string>() + " ";
  EXPECT_NE(splatPasses.find("render.splats"), std::string::npos) << splatPasses;
  EXPECT_EQ(splatPasses.find("render.mesh"), std::string::npos) << splatPasses;
  EXPECT_TRUE(fs::exists(dir / "s" / "frames" / "frame_0001.png"));
  // look=splats on one material: that material is drawn as splats and not meshed (no fluid surface
  // for the water), the others stay surfaces (the mesh pass runs, triangles drawn); --export mesh
  // still meshes it (the meshes are written for other tools).
  std::string perMaterial = mats;
  perMaterial.replace(perMaterial.find("bulk_modulus=2e4"), 16, "bulk_modulus=2e4 look=splats");
  writeText(dir / "l.scene", head + "solver mpm\nsubsteps auto\n" + perMaterial);
  r = runCli("run '" + (dir / "l.scene").string() + "' -q --frames 2 --out '" + (dir / "l").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto lookReport = readJson(dir / "l" / "report.json");
  std::string lookPasses;
  for (const auto& e : lookReport["passes"]) lookPasses += e["pass"].get<std::string>() + " ";
  EXPECT_NE(lookPasses.find("render.splats"), std::string::npos) << lookPasses;
  EXPECT_NE(lookPasses.find("render.mesh"), std::string::npos) << lookPasses;
  EXPECT_FALSE(lookReport["frames"].contains("fluid_surface")) << lookReport["frames"];
  EXPECT_GT(lookReport["frames"]["triangles"].get<long>(), 0);
  EXPECT_LT(lookReport["frames"]["triangles"].get<long>(), rep["frames"]["triangles"].get<long>());  // the water's are gone
  r = runCli("run '" + (dir / "l.scene").string() + "' -q --frames 2 --export mesh --out '" + (dir / "le").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(readJson(dir / "le" / "report.json")["frames"]["fluid_surface"]["surfaces"], 2);
  r = runCli("run '" + (dir / "m.scene").string() + "' -q --fluid-surface blobs --out '" + (dir / "b").string() + "'", dir);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("--fluid-surface"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "b"));
  // Thrown at the x+ wall: the run says that material reached the domain's edge, and where.
  writeText(dir / "t.strokes", "physketch-strokes 1\nprimitive box jelly 0  0.3 0.3 0  0.08 0.08 0.08 vel=6,0,0\n");
  writeText(dir / "t.scene", "physketch-scene 1\nstrokes t.strokes\nsolver mpm\nsubsteps auto\n" + mats + "output report\n");
  r = runCli("run '" + (dir / "t.scene").string() + "' -q --frames 4 --out '" + (dir / "t").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("warning: material reached the domain's edge"), std::string::npos) << r.err;
  const auto thrown = readJson(dir / "t" / "report.json");
  ASSERT_EQ(thrown["warnings"].size(), 1u) << thrown["warnings"];
  EXPECT_NE(thrown["warnings"][0].get<std::string>().find("(stroke 0, jelly) at the x+ wall"), std::string::npos)
      << thrown["warnings"];
  // 'substeps auto' is MPM's: under pbd it is an error naming the record's field.
  writeText(dir / "p.scene", head + "substeps auto\n" + mats);
  r = runCli("run '" + (dir / "p.scene").string() + "' -q --out '" + (dir / "p").string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("p.scene:3: field 'count': 'substeps auto' needs solver mpm"), std::string::npos) << r.err;
  // A fixed count above the explicit bound: a warning naming the bound and the material.
  writeText(dir / "w.scene", head + "solver mpm\nsubsteps 2\n" + mats);
  r = runCli("plan '" + (dir / "w.scene").string() + "'", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("w.scene:4: substeps 2:"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("of material 'jelly'"), std::string::npos) << r.err;
  fs::remove_all(dir);
}

// A golden image (issue 10), a regression check beside the analytic render tests: the bundled
// example, sketched, simulated 0.3 s and drawn at 160 x 120, against the reference made by the
// command written in tests/golden/golden.scene. ../shared/stack.md found frames bit-identical
// across EGL platforms and thread counts; the tolerance leaves room for another llvmpipe
// rasterizing an edge differently: at most 0.5 % of the pixels may differ by more than 16/255
// in a channel, and the mean difference must stay below 1/255. It is tight enough to see a
// change of one material's colour (checked below: wood's colour turned blue fails it).
TEST(Cli, TheGoldenSceneMatchesItsReferenceImage) {
  const fs::path dir = freshDir("golden");
  const fs::path golden = fs::path(PHYSKETCH_SOURCE_DIR) / "tests" / "golden";
  const Rgba ref = readPng(golden / "golden_0009.png");
  ASSERT_EQ(ref.width, 160);
  ASSERT_EQ(ref.height, 120);
  struct Diff {
    double mean = 0.0, far = 0.0;  // mean |difference| over channels (of 255); share of pixels off by > 16
  };
  const auto compare = [&](const Rgba& img) {
    Diff d;
    if (img.width != ref.width || img.height != ref.height) return Diff{255.0, 1.0};
    long off = 0;
    double sum = 0.0;
    for (std::size_t p = 0; p < ref.px.size(); p += 4) {
      int worst = 0;
      for (int c = 0; c < 3; ++c) {
        const int e = std::abs(int(img.px[p + std::size_t(c)]) - int(ref.px[p + std::size_t(c)]));
        sum += e;
        worst = std::max(worst, e);
      }
      off += worst > 16;
    }
    d.mean = sum / (3.0 * double(ref.px.size() / 4));
    d.far = double(off) / double(ref.px.size() / 4);
    return d;
  };
  // The scene names its strokes relative to tests/golden; the copies run from dir name them whole.
  const auto render = [&](std::string sceneText, const std::string& name) {
    const std::string rel = "strokes ../../scenes/hello.strokes";
    EXPECT_NE(sceneText.find(rel), std::string::npos);
    sceneText.replace(sceneText.find(rel), rel.size(), "strokes " + (golden / ".." / ".." / "scenes" / "hello.strokes").string());
    writeText(dir / (name + ".scene"), sceneText);
    const Result r = runCli("run '" + (dir / (name + ".scene")).string() + "' -q --frames 10 --threads 2 --out '" +
                                (dir / name).string() + "'",
                            dir);
    EXPECT_EQ(r.code, 0) << r.err;
    return readPng(dir / name / "frames" / "frame_0009.png");
  };
  const std::string text = slurp(golden / "golden.scene");
  const Diff same = compare(render(text, "golden"));
  EXPECT_LE(same.far, 0.005) << "mean " << same.mean;
  EXPECT_LE(same.mean, 1.0) << "far " << same.far;
  std::string blue = text;
  const std::string wood = "material wood   rigid  600    0.6       0.72 0.50 0.30";
  ASSERT_NE(blue.find(wood), std::string::npos);
  blue.replace(blue.find(wood), wood.size(), "material wood   rigid  600    0.6       0.30 0.50 0.72");
  const Diff changed = compare(render(blue, "blue"));
  EXPECT_TRUE(changed.far > 0.005 || changed.mean > 1.0) << "a blue box passed: far " << changed.far << ", mean " << changed.mean;
  fs::remove_all(dir);
}

// A real Tilt Brush sketch (tests/data/tilt/README.md) imports, lints without warnings and
// runs; importing twice writes the same bytes; bad input is exit 1 naming the file or option
// and writes nothing.
TEST(Cli, ImportTiltWritesAStrokeFileAndASceneThatLintAndRun) {
  const fs::path dir = freshDir("tilt");
  const std::string tilt = std::string(PHYSKETCH_SOURCE_DIR) + "/tests/data/tilt/sketch1.tilt";
  const fs::path strokes = dir / "in" / "sketch1.strokes", scene = dir / "in" / "sketch1.scene";
  Result r = runCli("import-tilt '" + tilt + "' -o '" + strokes.string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  ASSERT_TRUE(fs::exists(scene));
  EXPECT_NE(slurp(scene).find("strokes sketch1.strokes\n"), std::string::npos) << slurp(scene);
  const std::string first = slurp(strokes);
  r = runCli("import-tilt '" + tilt + "' -o '" + strokes.string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(slurp(strokes), first) << "the import is not deterministic";
  const std::string lint = (dir / "lint.txt").string();
  const int status = std::system((std::string(PHYSKETCH_CLI) + " lint '" + scene.string() + "' > '" + lint + "' 2>&1").c_str());
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << slurp(lint);
  EXPECT_NE(slurp(lint).find("0 warning(s), no errors"), std::string::npos) << slurp(lint);
  EXPECT_NE(slurp(lint).find("3 bodies"), std::string::npos) << slurp(lint);
  r = runCli("run '" + scene.string() + "' -q --frames 3 --out '" + (dir / "out").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir / "out" / "frames" / "frame_0002.png"));

  // A real 471-stroke artwork (tests/data/tilt/README.md): as drawn, hundreds of wire-thin
  // bodies; with the defaults (touching strokes joined, thin ones thickened) a handful, that
  // lint and run.
  auto bodiesOf = [&](const fs::path& sceneFile) {
    const std::string out = (dir / "lint_bt.txt").string();
    const int st = std::system((std::string(PHYSKETCH_CLI) + " lint '" + sceneFile.string() + "' > '" + out + "' 2>&1").c_str());
    EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0) << slurp(out);
    const std::string text = slurp(out);
    const std::size_t at = text.find(" bodies, play");
    if (at == std::string::npos) return -1;
    const std::size_t from = text.rfind(' ', at - 1) + 1;
    return std::stoi(text.substr(from, at - from));
  };
  const std::string bird = std::string(PHYSKETCH_SOURCE_DIR) + "/tests/data/tilt/Blue_Tit.tilt";
  r = runCli("import-tilt '" + bird + "' -q -o '" + (dir / "bt" / "bird.strokes").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const int joined = bodiesOf(dir / "bt" / "bird.scene");
  r = runCli("import-tilt '" + bird + "' -q --join none --no-thicken -o '" + (dir / "bt" / "apart.strokes").string() + "'",
             dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const int apart = bodiesOf(dir / "bt" / "apart.scene");
  std::printf("Blue_Tit.tilt: %d bodies as drawn, %d imported with the defaults\n", apart, joined);
  EXPECT_GT(apart, 400);
  EXPECT_GE(joined, 1);
  EXPECT_LE(joined, 10);
  r = runCli("run '" + (dir / "bt" / "bird.scene").string() + "' -q --frames 3 --out '" + (dir / "bt" / "out").string() + "'",
             dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir / "bt" / "out" / "frames" / "frame_0002.png"));

  const fs::path bad = dir / "bad";
  r = runCli("import-tilt '" + (dir / "no_such.tilt").string() + "' -o '" + (bad / "x.strokes").string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("no_such.tilt: cannot open the file"), std::string::npos) << r.err;
  writeText(dir / "text.tilt", "physketch-strokes 1\n");
  r = runCli("import-tilt '" + (dir / "text.tilt").string() + "' -o '" + (bad / "x.strokes").string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("text.tilt: field 'header': not a .tilt file"), std::string::npos) << r.err;
  r = runCli("import-tilt '" + tilt + "' --join glue -o '" + (bad / "x.strokes").string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("field '--join': 'glue' is not one of touching, material, none"), std::string::npos) << r.err;
  r = runCli("import-tilt '" + tilt + "' --fit 0 -o '" + (bad / "x.strokes").string() + "'", dir);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("sketch1.tilt: field '--fit': must be in (0, 0.98]"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(bad));
  fs::remove_all(dir);
}

namespace {

// An MPM scene in dir: s.strokes with `strokes`, s.scene with the solver and workspace lines and
// then `records`.
void writeMpmScene(const fs::path& dir, const std::string& strokes, const std::string& records) {
  writeText(dir / "s.strokes", "physketch-strokes 1\n" + strokes);
  writeText(dir / "s.scene", "physketch-scene 1\nstrokes s.strokes\nworkspace 0 0.5 0  1.0\nsolver mpm\n" + records);
}

// The substeps per 1/60 s step the elastic wave bound h <= 0.5 dx / c_p asks of a material of
// Young's modulus E, nu = 0.3 and density rho, on the sketch's grid (dx = 2 h, h = 1 m / 151):
// c_p = sqrt((lambda + 2 mu) / rho), lambda + 2 mu = E (1 - nu) / ((1 + nu)(1 - 2 nu)).
long elasticSubsteps(double E, double rho) {
  const double nu = 0.3, dx = 2.0 / 151.0;
  const double c = std::sqrt(E * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu)) / rho);
  return long(std::ceil((1.0 / 60.0) / (0.5 * dx / c)));
}

}  // namespace

// Under `substeps auto`, a material whose explicit bound h <= 0.5 dx / c_p needs more than 1000
// substeps per step is the scene's error at load time: exit 1, the material's line, its name and
// the count, nothing written. The count's oracle: c_p = sqrt((lambda + 2 mu) / rho) from E and
// nu = 0.3 (lambda + 2 mu = E (1 - nu) / ((1 + nu)(1 - 2 nu))), dx = 2 h with h the sketch's
// voxel (1 m / 151), dt = 1/60 s. E = 5e9 Pa at rho = 1000 kg/m^3: c_p = 2,594 m/s, 6,530
// substeps (under 10,000, so that a check off by a factor of 10 fails here).
TEST(Cli, AnMpmMaterialNeedingMoreThan1000SubstepsIsTheScenesError) {
  const fs::path dir = freshDir("substeps1000");
  writeMpmScene(dir, "primitive box steel 0   0 0.2 0   0.1 0.1 0.1\nplay 0\n",
                "substeps auto\nmaterial steel elastic E=5e9 density=1000\noutput report\n");
  const fs::path out = dir / "out";
  const Result r = runCli("run '" + (dir / "s.scene").string() + "' --out '" + out.string() + "'", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  const long n = elasticSubsteps(5e9, 1000.0);
  EXPECT_NE(r.err.find("s.scene:6:"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("material 'steel' needs " + std::to_string(n) + " MPM substeps"), std::string::npos)
      << r.err << " (expected " << n << ")";
  EXPECT_NE(r.err.find("more than 1000"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out));
  fs::remove_all(dir);
}

// `physketch plan` of an MPM scene at a real-world scale k prints each scaled value beside the
// scene's (PhysGen3D §A.4 as docs/formats.md states it: g' = k g; mass held, so density / k^3;
// stresses / k). k = 0.1: gravity 9.81 -> 0.981 m/s^2, density 1000 -> 1e6 kg/m^3, E 5e5 -> 5e6
// Pa; a fluid's bulk modulus 2e5 -> 2e6 Pa.
TEST(Cli, PlanPrintsTheScaledValuesOfAnMpmSceneAtAScale) {
  const fs::path dir = freshDir("scaleplan");
  writeMpmScene(dir, "primitive box gel 0   0 0.2 0   0.1 0.1 0.1\nprimitive box water 0.5   0.2 0.2 0   0.1 0.1 0.1\nplay 1\n",
                "scale 0.1\nmaterial gel elastic E=5e5 density=1000\nmaterial water fluid bulk_modulus=2e5\noutput report\n");
  const std::string outFile = (dir / "plan.txt").string();
  ASSERT_EQ(std::system((std::string(PHYSKETCH_CLI) + " plan '" + (dir / "s.scene").string() + "' > '" + outFile + "'").c_str()), 0);
  const std::string text = slurp(outFile);
  EXPECT_NE(text.find("real-world scale k = 0.1"), std::string::npos) << text;
  EXPECT_NE(text.find("gravity 9.81 -> 0.981 m/s^2"), std::string::npos) << text;
  EXPECT_NE(text.find("gel: density 1000 -> 1e+06 kg/m^3, E 500000 -> 5e+06 Pa"), std::string::npos) << text;
  EXPECT_NE(text.find("bulk modulus 200000 -> 2e+06 Pa"), std::string::npos) << text;
  fs::remove_all(dir);
}

// Under `substeps auto` report.json says what each frame's steps took (issue 9: the count is
// picked per step and reported). An elastic block (E = 5e5 Pa, nu = 0.3, rho = 1000) resting on
// the ground: its wave bound h <= 0.5 dx / c_p sets every step (the velocity bound of a block at
// rest, 0.5 dx / (|g| dt), is 150x longer), so each step takes N = ceil(dt / h) substeps, with
// c_p = sqrt((lambda + 2 mu) / rho) and dx = 2 / 151 m computed here: 2N a frame at 30 fps.
TEST(Cli, SubstepsAutoReportsWhatEachFramesStepsTook) {
  const fs::path dir = freshDir("substepsreport");
  writeMpmScene(dir, "primitive box gel 0   0 0.05 0   0.1 0.1 0.1\nplay 0\n",
                "substeps auto\nduration 0.2\nfps 30\nmaterial gel elastic E=5e5 density=1000\noutput report\n");
  const fs::path out = dir / "out";
  const Result r = runCli("run '" + (dir / "s.scene").string() + "' -q --out '" + out.string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const nlohmann::json rep = readJson(out / "report.json");
  const long n = elasticSubsteps(5e5, 1000.0);
  const auto& poses = rep.at("poses");
  ASSERT_EQ(poses.size(), 7u);
  EXPECT_FALSE(poses[0].contains("substeps"));  // frame 0 runs no step
  for (std::size_t f = 1; f < poses.size(); ++f) EXPECT_EQ(poses[f].at("substeps").get<long>(), 2 * n) << "frame " << f;
  const auto& taken = rep.at("solver").at("substeps_taken");
  EXPECT_EQ(taken.at("total").get<long>(), 12 * n);
  EXPECT_EQ(taken.at("fewest_in_a_step").get<long>(), n);
  EXPECT_EQ(taken.at("most_in_a_step").get<long>(), n);
  fs::remove_all(dir);
}
