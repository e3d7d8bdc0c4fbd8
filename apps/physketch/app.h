// The physketch command line: subcommands run, plan, lint and study (see --help; study: study.h).
#pragma once

#include <iostream>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/math.h"

namespace physketch::app {

// Exit codes of the CLI.
constexpr int kExitOk = 0;
constexpr int kExitBadInput = 1;
constexpr int kExitRuntime = 2;

// Runs a subcommand body and maps its exceptions to the CLI's exit codes:
// InputError -> 1 (bad input, message names file:line:field), anything else -> 2.
template <class F>
int withExitCodes(F&& body) {
  try {
    return body();
  } catch (const InputError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitRuntime;
  }
}

struct RunOptions {
  std::string scene;
  std::string outDir = "out";
  int frames = -1;     // -1: duration * fps + 1
  int threads = 0;     // 0: all cores
  bool quiet = false;
  bool validate = false;  // check the solver's state after every pass, not once per step
  // --export mesh,particles,vdb (docs/formats.md, "Exports"), each written per frame.
  bool exportMesh = false;       // DIR/meshes/frame_NNNN/BODY.obj and .ply
  bool exportParticles = false;  // DIR/particles/frame_NNNN.ply
  bool exportVdb = false;        // DIR/vdb/frame_NNNN.vdb
  bool video = false;            // DIR/video.mp4 through ffmpeg, when it is on PATH
  int smooth = 0;                // smoothing iterations of deforming surfaces (ParticleMeshOptions)
  std::string fluidSurface = "kernels";  // --fluid-surface: kernels (meshFluid) or cells (meshParticles)
  std::string solidSurface = "cells";    // --solid-surface: cells (meshParticles) or grid (the solver's grid mass)
  double meshResolution = 0.5;   // --mesh-resolution: fluid surfaces' field voxels, in particle spacings
  int splatDetail = 1;                   // --splat-detail: splats per particle along each axis (1..4)
  std::string look = "meshes";           // --look: meshes or splats (Gaussian splats per particle)
  std::string guard = "stop";    // --guard: stop at the first trip, or warn and go on (recoverable kinds)
  double budgetMs = 0.0;         // --budget: solver ms per frame to fit (0: the scene's settings)
  std::string budgetFrom;        // --from-study DIR: choose from a study's rows instead of calibrating
  std::string glDevice = "cpu";  // --gl-device: cpu (llvmpipe first) or gpu (a hardware EGL device only)
};

int runScene(const RunOptions& options);
struct PlanOptions {
  std::string scene;
  bool all = false;      // also the passes that are off, each with why
  std::string afterDir;  // a run's output folder: add the measured ms per pass from its report.json
};
int printPlan(const PlanOptions& options);
// Parse and voxelize only: particles per operation, material and body, memory estimate, warnings.
int lintScene(const std::string& scene);

// physketch import-tilt: an Open Brush / Tilt Brush sketch -> a stroke file and a scene that runs it.
struct ImportTiltOptions {
  std::string input;             // FILE.tilt
  std::string output;            // -o: the stroke file (default: the input's name with .strokes, here)
  std::string scene;             // --scene: the scene (default: the stroke file's name with .scene)
  Vec3 workspaceCenter{0.0, 0.5, 0.0};
  double workspaceSize = 1.0;
  double fit = 0.8;
  double scale = 0.0;            // > 0: instead of fitting
  std::string join = "touching";
  bool noThicken = false;
  bool hiddenLayers = false;
  double density = 600.0;
  bool quiet = false;
};
int importTilt(const ImportTiltOptions& options);

}  // namespace physketch::app
