// End to end: the physketch binary on the bundled scene and on broken input.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

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

}  // namespace

TEST(Cli, HelloSceneWritesFramesAndReport) {
  const fs::path dir = freshDir("hello");
  const fs::path out = dir / "out";
  const std::string scene = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/hello.scene";
  const Result r = runCli("run '" + scene + "' --out '" + out.string() + "' --frames 4 --threads 2", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  for (int i = 0; i < 4; ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%04d.png", i);
    const fs::path f = out / "frames" / name;
    ASSERT_TRUE(fs::exists(f)) << f;
    EXPECT_GT(fs::file_size(f), 1000u);
    std::ifstream in(f, std::ios::binary);
    char sig[8];
    in.read(sig, 8);
    EXPECT_EQ(std::string(sig + 1, 3), "PNG");
  }
  EXPECT_FALSE(fs::exists(out / "frames" / "frame_0004.png"));
  const std::string rep = slurp(out / "report.json");
  EXPECT_NE(rep.find("\"status\": \"ok\""), std::string::npos) << rep;
  EXPECT_NE(rep.find("\"per_operation\""), std::string::npos);
  EXPECT_NE(rep.find("\"shape_match\""), std::string::npos);
  EXPECT_NE(rep.find("\"written\": 4"), std::string::npos);
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
    ASSERT_EQ(runCli("run '" + scene + "' -q --frames 12 --threads " + std::to_string(t) + " --out '" +
                         (dir / ("t" + std::to_string(t))).string() + "'",
                     dir)
                  .code,
              0);
  for (int i = 0; i < 12; i += 11) {  // frame 11 is t = 0.37 s: the bodies are falling and landing
    char name[32];
    std::snprintf(name, sizeof name, "frame_%04d.png", i);
    EXPECT_EQ(slurp(dir / "t1" / "frames" / name), slurp(dir / "t2" / "frames" / name)) << name;
  }
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
  fs::remove_all(dir);
}
