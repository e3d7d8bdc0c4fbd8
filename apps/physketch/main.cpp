// physketch CLI entry point: argument parsing only; the work is in run.cpp.
#include <CLI/CLI.hpp>

#include <iostream>
#include <string>
#include <vector>

#include "apps/physketch/app.h"
#include "apps/physketch/study.h"

int main(int argc, char** argv) {
  using namespace physketch::app;
  CLI::App cli{
      "physketch: turns scripted 3D brush strokes into physically simulated objects and renders them off-screen.\n\n"
      "A scene file (how to run) names a stroke file (what was drawn: strokes, primitives, mesh stamps,\n"
      "removes, moves, mirror, undo). Everything drawn before 'play' is voxelized into a 151^3 grid; each\n"
      "stroke (or named body) becomes a body of its stroke's material and falls under gravity onto the\n"
      "ground; what is drawn after 'play' happens while the bodies move. Every frame is rendered to PNG.\n"
      "Materials carry a kind and parameters (docs/formats.md has the table). The default solver, pbd\n"
      "(position-based, one particle system), simulates rigid, soft (and elastic), fluid, rope and cloth,\n"
      "all touching each other; 'solver mpm' (MLS-MPM) simulates elastic, sand, snow, plasticine and\n"
      "fluid (rigid and soft as elastic). A scene that asks a solver for a kind or option it does not\n"
      "simulate is refused at load time with the record that asks.\n"
      "Frames are drawn off-screen through EGL: Mesa's software device (llvmpipe, CPU) when present,\n"
      "else the surfaceless platform, else another EGL device; report.json names the one used.\n"
      "File formats: docs/formats.md. Examples: scenes/hello.scene (rigid), jelly (soft), mix (fluid among\n"
      "solids), honey (two fluids), rope, cloth, tool, ramp (mesh colliders), play (sketching after play),\n"
      "mpm (sand, jelly and water under solver mpm); scenes/hard/ and scenes/study/ for the stability\n"
      "suite and the accuracy studies.\n\n"
      "Examples:\n"
      "  physketch run scenes/hello.scene --out out/hello      # frames in out/hello/frames, report.json\n"
      "  physketch run scenes/hello.scene --frames 10 --threads 1\n"
      "  physketch run scenes/hello.scene --export mesh,particles,vdb --video   # for Blender, Houdini, a player\n"
      "  physketch plan scenes/hello.scene                     # the passes a step runs, and why\n"
      "  physketch run scenes/play.scene --validate            # check the state after every pass\n"
      "  physketch lint scenes/hello.scene                     # check a sketch without simulating it\n"
      "  physketch study scenes/study/drop.scene --vary substeps=1,2,4,8 --out out/study  # error vs time\n"
      "  physketch import-tilt sketch.tilt -o sketch.strokes    # an Open Brush sketch in, with sketch.scene\n\n"
      "Exit codes: 0 success, 1 bad input (the message names file:line:field), 2 runtime failure\n"
      "(e.g. the stability guard tripped: the message and report.json name the pass, particle, stroke,\n"
      "material, value, bound and the setting to change)."};
  cli.set_version_flag("--version", std::string("physketch ") + PHYSKETCH_VERSION);
  cli.require_subcommand(1);

  RunOptions run;
  auto* runCmd = cli.add_subcommand("run", "Voxelize, simulate and render a scene; write DIR/frames/frame_NNNN.png and DIR/report.json");
  runCmd->add_option("scene", run.scene, "Scene file (physketch-scene 1)")->required();
  runCmd->add_option("--out,-o", run.outDir, "Output folder (created if missing)")->capture_default_str();
  runCmd->add_option("--frames,-n", run.frames, "Number of frames to write, frame 0 at t = 0 (default: duration*fps + 1)")
      ->check(CLI::Range(1, 1000000));
  runCmd->add_option("--threads,-j", run.threads, "Worker threads (default: all cores); results do not depend on it")
      ->check(CLI::Range(1, 1024));
  runCmd->add_flag("--quiet,-q", run.quiet, "No progress line on stderr");
  runCmd->add_flag("--validate", run.validate,
                   "Check the solver's state after every pass (not once per step): slower, names the pass at once");
  std::vector<std::string> exports;
  runCmd->add_option("--export", exports,
                     "Also write, per frame: mesh (DIR/meshes/frame_NNNN/BODY.obj and .ply), particles "
                     "(DIR/particles/frame_NNNN.ply), vdb (DIR/vdb/frame_NNNN.vdb); a comma list or repeated")
      ->delimiter(',')
      ->check(CLI::IsMember({"mesh", "particles", "vdb"}));
  runCmd->add_flag("--video", run.video,
                   "Also make DIR/video.mp4 from the frames with ffmpeg (libx264, else mpeg4) if ffmpeg is on PATH; "
                   "without it, say so and go on");
  runCmd->add_option("--smooth", run.smooth,
                     "Smooth the surfaces of deforming bodies: N iterations of mean-curvature flow, volume kept "
                     "(report.json: frames.smoothing); 0 = off")
      ->check(CLI::Range(0, 100));
  runCmd->add_option("--fluid-surface", run.fluidSurface,
                     "How fluids are meshed: 'kernels' (anisotropic kernels, Yu & Turk 2013 on PhyVR's particle grid: a "
                     "resting pool is flat, the fluid's volume kept; report.json: frames.fluid_surface) or 'cells' (the "
                     "particles' cells, as deforming solids, cheaper and blocky)")
      ->capture_default_str()
      ->check(CLI::IsMember({"kernels", "cells"}));
  runCmd->add_option("--solid-surface", run.solidSurface,
                     "How deforming solids are meshed: 'cells' (the particles' lattice cells; --smooth smooths them) or "
                     "'grid' (solver mpm only: a level of the MPM grid's mass, PhyVR 4.1: smooth and cheap, rounder "
                     "at edges, one grid spacing of detail; report.json: frames.solid_surface)")
      ->capture_default_str()
      ->check(CLI::IsMember({"cells", "grid"}));
  runCmd->add_option("--mesh-resolution", run.meshResolution,
                     "Voxel edge of a fluid surface's kernel field, in particle spacings: smaller is finer and slower "
                     "(docs/accuracy.md, \"Meshing knobs\"; the study knob mesh_resolution)")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 1.0));
  runCmd->add_option("--look", run.look,
                     "How bodies are drawn: 'meshes' (surfaces: rigid rest meshes, deforming cells, rope tubes, fluid kernels) or "
                     "'splats' (one Gaussian splat per particle, stretched by the solver's deformation gradient F under "
                     "mpm, by its kernel for a fluid; lit by the surface's normal, casting no shadow; docs/formats.md). Per material: look=splats in its record")
      ->capture_default_str()
      ->check(CLI::IsMember({"meshes", "splats"}));
  runCmd->add_option("--splat-detail", run.splatDetail,
                     "Splats per particle along each axis (1-4): each drawn particle becomes N^3 smaller splats "
                     "across its cell, placed and stretched by F (appearance particles finer than the simulation's, "
                     "as VR-Doh decouples them); costs N^3 the drawing")
      ->capture_default_str()
      ->check(CLI::Range(1, 4));
  runCmd->add_option("--gl-device", run.glDevice,
                     "Which EGL display draws the frames: 'cpu' (Mesa's llvmpipe first: the same pixels on every machine "
                     "with the same Mesa; else whatever EGL offers) or 'gpu' (a hardware EGL device only, e.g. NVIDIA's "
                     "through libglvnd; an error when there is none). report.json: frames.device says which one drew")
      ->capture_default_str()
      ->check(CLI::IsMember({"cpu", "gpu"}));
  runCmd->add_option("--guard", run.guard,
                     "When the stability guard trips: 'stop' the run (exit 2, report.json: guard), or 'warn': log the "
                     "event and go on where the state can go on (a particle too fast or too deep, fluid compression, "
                     "energy growth, CFL; NaN and inverted elements always stop). report.json: status 'warned', "
                     "guard_warnings (the first record of each kind, with the frame, and how many steps tripped it)")
      ->capture_default_str()
      ->check(CLI::IsMember({"stop", "warn"}));
  auto* budgetOpt = runCmd->add_option("--budget", run.budgetMs,
                     "Pick substeps and iterations (pbd), or the Courant number of 'substeps auto' (mpm), so that the "
                     "solver takes about MS milliseconds per frame on this machine, from a short calibration of the scene's first frames; prints the error expected "
                     "(report.json: budget; docs/accuracy.md)")
      ->check(CLI::PositiveNumber);
  runCmd->add_option("--from-study", run.budgetFrom,
                     "With --budget: choose from the whole-run rows of 'physketch study SCENE ... --out DIR' (DIR/study.json) "
                     "instead of calibrating; after the run, measure its error against the study's answer and print it "
                     "beside the prediction")
      ->needs(budgetOpt);

  PlanOptions plan;
  auto* planCmd = cli.add_subcommand("plan", "Print the passes one step runs for a scene, how often and why");
  planCmd->add_option("scene", plan.scene, "Scene file")->required();
  planCmd->add_flag("--all", plan.all, "Also list the passes that are off, each with why (nothing is run or allocated for them)");
  planCmd->add_option("--after", plan.afterDir, "Output folder of a finished run: add its measured ms per frame to each pass");

  std::string lintPath;
  auto* lintCmd = cli.add_subcommand("lint", "Parse and voxelize only: particles per stroke and material, memory estimate, warnings; exit 1 on any error");
  lintCmd->add_option("scene", lintPath, "Scene file")->required();

  ImportTiltOptions tilt;
  std::vector<double> tiltWorkspace;
  auto* tiltCmd = cli.add_subcommand(
      "import-tilt",
      "Turn an Open Brush / Tilt Brush sketch (.tilt) into a stroke file and a scene that runs it.\n"
      "Units (decimetres) and frame (left-handed) are converted, the sketch is scaled to fit the workspace\n"
      "and set on its floor, every stroke becomes a sphere-brush stroke as wide as the brush, one rigid\n"
      "material per colour, times kept (strokes drawn at the same time, by two hands or a mirror, are\n"
      "played one after the other), strokes thinner than two particles thickened, and touching strokes\n"
      "joined into one body. docs/formats.md, \"Importing Open Brush sketches\".\n\n"
      "Example:\n"
      "  physketch import-tilt sketch.tilt -o out/sketch.strokes   # also writes out/sketch.scene\n"
      "  physketch run out/sketch.scene --out out/sketch");
  tiltCmd->add_option("file", tilt.input, "The .tilt file")->required();
  tiltCmd->add_option("-o,--output", tilt.output, "Stroke file to write (default: FILE's name with .strokes, in the current folder)");
  tiltCmd->add_option("--scene", tilt.scene, "Scene file to write (default: the stroke file's name with .scene)");
  tiltCmd->add_option("--join", tilt.join,
                      "Which strokes become one body: touching (strokes whose voxels touch, any colour), material "
                      "(touching and of one colour) or none (one body per stroke)")
      ->capture_default_str();
  tiltCmd->add_flag("--no-thicken", tilt.noThicken,
                    "Keep strokes thinner than two particle spacings as drawn (they become wire-thin chains)");
  tiltCmd->add_flag("--hidden-layers", tilt.hiddenLayers,
                    "Also import strokes on layers hidden in Open Brush (left out by default, as the artist hid them)");
  tiltCmd->add_option("--fit", tilt.fit, "The sketch's longest side as a fraction of the workspace edge, (0, 0.98]")
      ->capture_default_str();
  tiltCmd->add_option("--scale", tilt.scale, "Metres per Tilt Brush metre instead of fitting (1: real size)")
      ->check(CLI::PositiveNumber);
  tiltCmd->add_option("--workspace", tiltWorkspace, "CX,CY,CZ,SIZE: the scene's workspace (default 0,0.5,0,1)")
      ->delimiter(',')
      ->expected(4);
  tiltCmd->add_option("--density", tilt.density, "Density of every material (kg/m^3)")->capture_default_str();
  tiltCmd->add_flag("--quiet,-q", tilt.quiet, "No summary on stdout");

  StudyOptions study;
  study.program = argv[0];
  auto* studyCmd = cli.add_subcommand(
      "study",
      "What accuracy costs in time: run the scene once per setting of the knobs varied (every combination),\n"
      "measure each run's error and wall time per frame; write DIR/study.csv, study.md, study.png and study.json\n"
      "(error against time per frame, log-log, the Pareto front marked). Knobs: iterations, substeps,\n"
      "dt (s), voxel (m: the voxel size; the workspace edge becomes 151 voxels), grid_dx and cfl (solver\n"
      "mpm), sleep (solver pbd: the sleep speed in m/s, 0 = off), warm_start (solver pbd: the fluids' carried\n"
      "multipliers, 0 = off), smoothing and mesh_resolution (meshing:\n"
      "every frame is meshed and the last frame's surface measured, e.g. against 'expect sphere'). Error: against the\n"
      "scene's 'expect' records (--reference analytic, the default when it has one) or against a fine\n"
      "run (--reference fine: the finest value of each knob, or --reference-at). docs/accuracy.md.");
  studyCmd->add_option("scene", study.scene, "Scene file (not with --collect)");
  studyCmd->add_option("--vary", study.vary, "KNOB=V1,V2,... (repeat for more knobs; every combination runs)")
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
  studyCmd->add_option("--reference", study.reference, "analytic (the scene's expect records) or fine (a converged run)");
  studyCmd->add_option("--reference-at", study.referenceAt,
                       "KNOB=V,...: the fine reference's setting (default: the finest value of each varied knob)");
  studyCmd->add_option("--out,-o", study.outDir, "Output folder (created if missing)")->capture_default_str();
  studyCmd->add_option("--jobs", study.jobs, "Settings run side by side (each gives the numbers it gives alone)")
      ->check(CLI::Range(1, 1024));
  studyCmd->add_option("--threads", study.threads, "Worker threads per run (default: all cores / jobs)")
      ->check(CLI::Range(1, 1024));
  studyCmd->add_option("--repeat", study.repeat, "Runs per setting; the time is their median")->check(CLI::Range(1, 1000));
  studyCmd->add_flag("--emit-commands", study.emitCommands,
                     "Print one command per setting (a job list for GNU parallel or a Slurm array) that writes "
                     "DIR/parts/K/part.json; write DIR/plan.json; run nothing");
  studyCmd->add_option("--only", study.only, "KNOB=V,...: run this one setting and write DIR/part.json");
  studyCmd->add_option("--collect", study.collect, "DIR of --emit-commands: merge DIR/parts into DIR/study.{csv,md,png}");
  studyCmd->add_flag("--quiet,-q", study.quiet, "No progress lines on stderr");

  // CLI11 reports a word that is not a subcommand as "A subcommand is required": name it instead.
  if (argc > 1 && argv[1][0] != '-') {
    std::string known;
    bool found = false;
    for (const CLI::App* c : {runCmd, planCmd, lintCmd, studyCmd, tiltCmd}) {
      found = found || c->check_name(argv[1]);
      known += (known.empty() ? "" : ", ") + c->get_name();
    }
    if (!found) {
      std::cerr << "physketch: unknown subcommand '" << argv[1] << "' (known: " << known << "; see --help)\n";
      return kExitBadInput;
    }
  }
  try {
    cli.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = cli.exit(e);
    return rc == 0 ? kExitOk : kExitBadInput;
  }
  for (const std::string& e : exports) {
    run.exportMesh = run.exportMesh || e == "mesh";
    run.exportParticles = run.exportParticles || e == "particles";
    run.exportVdb = run.exportVdb || e == "vdb";
  }
  if (*runCmd) return runScene(run);
  if (*planCmd) return printPlan(plan);
  if (*lintCmd) return lintScene(lintPath);
  if (*studyCmd) return runStudy(study);
  if (*tiltCmd) {
    if (tiltWorkspace.size() == 4) {
      tilt.workspaceCenter = physketch::Vec3(tiltWorkspace[0], tiltWorkspace[1], tiltWorkspace[2]);
      tilt.workspaceSize = tiltWorkspace[3];
    }
    return importTilt(tilt);
  }
  return kExitBadInput;
}
