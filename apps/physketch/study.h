// physketch study: what accuracy costs in time. Runs a scene once per setting of the knobs
// it is asked to vary (the cartesian product), measures each run's error against the answer
// the scene declares (`expect` records) or against a converged fine run, and its wall time per
// frame; writes study.csv, study.md, study.png and study.json (docs/accuracy.md).
//
// The pieces are here so tests can check them without the binary: knob parsing, the
// product, the error norms (study_error.cpp) and the Pareto front (study_plot.cpp).
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/math.h"
#include "core/scene.h"
#include "core/solver.h"
#include "render/mesh.h"

namespace physketch::sketch {
struct Sketch;
}

namespace physketch::app {

// --- knobs and settings ------------------------------------------------------

// One knob and the values it takes, from `--vary KNOB=V1,V2,...`.
struct KnobValues {
  std::string knob;
  std::vector<double> values;
};

// One run's override of the scene: (knob, value) in the order the knobs were given.
using Setting = std::vector<std::pair<std::string, double>>;

// Parses `KNOB=V1,V2,...`. Throws InputError naming the argument and the knob for an unknown
// or reserved knob (grid), a value that is
// not a number, an empty list or value, a value out of the knob's range (iterations 0), or a
// value given twice.
KnobValues parseVary(const std::string& arg);
// Checks that no knob is varied twice. Throws InputError.
void checkDistinctKnobs(const std::vector<KnobValues>& knobs);
// Parses one setting `KNOB=V,KNOB=V` (--only, --reference-at), with the same checks.
Setting parseSetting(const std::string& arg, const std::string& option);
// Every combination: the last knob varies fastest. Throws InputError past kMaxSettings.
std::vector<Setting> cartesianProduct(const std::vector<KnobValues>& knobs);
constexpr std::size_t kMaxSettings = 10000;
// "iterations=4,substeps=8" (values as %.10g): the --only argument that names the setting.
std::string settingText(const Setting& s);
// Applies a setting to a scene: iterations, substeps, dt (s), voxel (m; the workspace edge
// becomes 151 voxels, centre kept), grid_dx and cfl (solver mpm); the meshing knobs leave the
// scene alone (meshingOf). Throws InputError naming `option` when the result is not a
// valid scene (1/fps not a whole number of dt steps, a workspace over 1000 m).
void applySetting(const Setting& s, SceneDesc& scene, const std::string& option);

// The meshing knobs (smoothing, mesh_resolution): how a run meshes its frames, not what it
// simulates. A study meshes every frame when a setting has one of them or the scene expects
// a surface (expect sphere); the meshing time counts in the time per frame.
bool isMeshingKnob(const std::string& knob);
struct MeshingSetting {
  bool varied = false;              // the setting has a meshing knob
  int smoothing = 0;                // run --smooth
  double fluidVoxelFraction = 0.5;  // run --mesh-resolution
};
MeshingSetting meshingOf(const Setting& s);

// --- error norms (study_error.cpp) -------------------------------------------

// What a run recorded at every frame (frame 0 = t = 0), enough for every norm.
struct Trajectory {
  std::vector<double> t;                  // s, per frame
  std::vector<std::vector<Vec3>> centres;  // per frame, per body: centre of mass (m)
  std::vector<Vec3> velocity0;            // per body at t = 0 (m/s)
  std::vector<double> reach;              // per body: centre to farthest particle + a radius (m)
  std::vector<bool> dynamic0;             // per body: dynamic at t = 0 (not fixed, kinematic)
  std::vector<std::string> names;         // per body (sketch names; "after play N" for later bodies)
  double maxDisplacement = 0.0;           // m: largest particle displacement from t = 0 over the run
  double maxSpeed = 0.0;                  // m/s: largest particle speed over the run (frames)
  double spacing = 0.0;                   // m: the particle spacing (voxel size)
  std::vector<double> front;              // m, per frame: the largest x of any dynamic particle (centre)
  Vec3 lo0 = Vec3::Zero(), hi0 = Vec3::Zero();  // m: the dynamic particles' centres' extent at t = 0
  std::size_t dynamic0Count = 0;          // dynamic particles at t = 0 (their volume: count x spacing^3)
  std::vector<double> hydrostatic;        // m, per frame, when the scene expects it: hydrostaticError
  // The last frame's surfaces (every body's, in world coordinates, as frames mesh them), when the
  // run meshes (a meshing knob, expect sphere); empty otherwise.
  render::TriangleMesh surface;
};

// Recording a run as a study measures it: observeStart once at t = 0 (velocities, reaches, names,
// the extent of the dynamic particles), then observe at every frame including frame 0 (centres,
// largest displacement from x0 and speed, front, hydrostatic error when expected).
void observeStart(const Solver& solver, const sketch::Sketch& sk, Trajectory& tr);
void observe(const Solver& solver, const std::vector<Vec3>& x0, const SceneDesc& scene, Trajectory& tr);

// Tait's equation of state integrated down a column at rest: the pressure (Pa) at depth d (m)
// below the free surface of a fluid of rest density rho0, bulk modulus K and exponent gamma
// (p = K / gamma ((rho / rho0)^gamma - 1)) under gravity g: dp/dd = rho g, which gives
// p = K / gamma ((1 + (gamma - 1) rho0 g d / K)^(gamma / (gamma - 1)) - 1) (gamma = 1: K (e^(rho0 g d / K) - 1)).
double hydrostaticPressure(double d, double rho0, double g, double bulk, double gamma);
// expect hydrostatic, at one frame: RMS over the fluid particles that have a pressure (MPM
// fluid) of (p - hydrostaticPressure(y_top - y)) / (rho0 g), in metres of head; y_top is the
// highest such particle's y plus h/2, rho0 = mass / h^3. NaN when no particle has a pressure.
double hydrostaticError(const Solver& solver, const SceneDesc& scene, double spacing);

// The frame window of free fall of each body (docs/accuracy.md): frames f >= 1 before the
// body's bounding sphere (radius `reach`), moving on its analytic parabola, first comes within
// one particle spacing of the ground plane or of another body's sphere (moving on its own
// parabola, or still when not dynamic). Returns, per body, the number of frames in the window
// (frames 1..n); 0 for bodies that are not dynamic. Sampled 100 times per frame interval.
std::vector<int> freefallWindow(const Trajectory& tr, const Vec3& gravity, double groundY);
// RMS over dynamic bodies and the frames of their windows of |c(t) - (c0 + v0 t + g t^2/2)| (m).
// Throws InputError naming `expectLine` of `scenePath` when no body has a frame of free fall.
double freefallError(const Trajectory& tr, const Vec3& gravity, double groundY, const std::string& scenePath,
                     int expectLine);
// |c_y(T) - y| (m) of the named body at the last frame. Throws InputError for an unknown body.
double heightError(const Trajectory& tr, const Expectation& e, const std::string& scenePath);
// The angle theta(t) (rad) of a simple pendulum, theta'' = -(g/L) sin theta, from theta0 and
// theta'0 (rad/s) at t = 0, at each of `times` (s, ascending), by RK4 with steps of 1e-4 s or less.
std::vector<double> pendulumAngle(double theta0, double omega0, double gOverL, const std::vector<double>& times);
// expect pendulum BODY PX PY PZ: RMS over frames 1.. of |c(t) - p(t)| (m), p(t) the bob of a simple
// pendulum about the pivot P of length L = |c0 - P| in the plane of gravity and c0 - P, released
// at c0's angle with the body's velocity at t = 0 (pendulumAngle). Throws InputError naming the
// record for an unknown or non-dynamic body, no gravity, or a pivot at the body's centre.
double pendulumError(const Trajectory& tr, const Expectation& e, const Vec3& gravity, const std::string& scenePath);
// printf-formats one number ("nan" for NaN), for tables and messages.
std::string fmt(const char* format, double v);
// Martin & Moyce 1952's surge front (../shared/data/martin-moyce-1952-front.csv): rows (T, Z).
const std::vector<std::pair<double, double>>& martinMoyceFront();
// expect dam_break A: a x the RMS over the published rows with T <= min(3, the run's last T) of
// Z_run(T) - Z, Z_run linear in T between frames; Z = (front + h/2 - (x0_min - h/2)) / a (the
// back wall is the column's face at t = 0), T = t sqrt(2 |g| / a). Throws InputError naming
// the record when gravity does not point down y, or the frames are too sparse (a frame step above
// 0.25 in T) or too few (under 3 published rows covered).
double damBreakError(const Trajectory& tr, const Expectation& e, const Vec3& gravity, const std::string& scenePath);
// Lube et al. 2005's run-out of a 2-D granular column of aspect ratio a = H0 / L0 (lengths
// from the extent at t = 0 plus one spacing): dL / L0 = 1.2 a for a <= 1.8, 1.9 a^(2/3) for
// a >= 2.8, linear in a between the two.
double lubeRunout(double aspect);
// expect runout: |(front_last + h/2 - (x0_min - h/2) - L0) - L0 lubeRunout(H0 / L0)| (m).
double runoutError(const Trajectory& tr, const Expectation& e, const Vec3& gravity, const std::string& scenePath);
// Huppert 1982 (J. Fluid Mech. 121, 43-58): the front of an axisymmetric viscous gravity current
// of constant volume V (m^3) on a rigid no-slip floor, r_N = 0.894 (rho g V^3 t / (3 mu))^(1/8) (m).
double huppertFront(double rho, double mu, double g, double volume, double t);
// expect viscous_spread: RMS over the frames with t >= half the last frame's time of
// (front + h/2 - (x0_min + x0_max) / 2) - huppertFront(rho, mu, g, count0 h^3, t), with the
// scene's one fluid material's density and viscosity (m).
double viscousSpreadError(const Trajectory& tr, const Expectation& e, const SceneDesc& scene);
// expect hydrostatic: the last frame's hydrostaticError. Throws InputError naming the record
// when no particle has a pressure (no fluid, or solver pbd) or gravity is zero.
double hydrostaticRunError(const Trajectory& tr, const Expectation& e, const SceneDesc& scene);
// expect sphere CX CY CZ R: RMS over the last frame's surface vertices of |v - C| - R (m).
// Throws InputError naming the record when nothing was meshed.
double sphereError(const Trajectory& tr, const Expectation& e, const std::string& scenePath);
// The scene's error: the largest of its expect records' errors (all in m).
double analyticError(const Trajectory& tr, const SceneDesc& scene);
// RMS over frames 1.. and the bodies dynamic at t = 0 in the reference (present in both) of
// the distance between centres of mass (m). NaN when the runs have different frame counts.
// When the runs meshed their frames (a meshing study): the symmetric RMS distance between the
// last frames' surfaces instead (render::rmsSurfaceDistance; NaN when either is empty).
double fineError(const Trajectory& run, const Trajectory& reference);

// --- Pareto front (study_plot.cpp) -------------------------------------------

struct CostPoint {
  double ms = 0.0;     // wall time per frame (ms)
  double error = 0.0;  // m
};
// Whether each point is on the Pareto front of (time, error), both minimised: no other point
// is as good in both and better in one. Points with a NaN coordinate are never on it and
// dominate nothing. O(n log n).
std::vector<bool> paretoFront(const std::vector<CostPoint>& points);

// study.png: error against wall time per frame, log-log, one marker per setting, the front's
// points filled and joined in order of time. Points with error 0 (the fine reference itself)
// sit on the bottom edge as open triangles; NaN points (unstable runs) are left out. Returns
// the PNG file's bytes (kPlotWidth x kPlotHeight, drawn with Cairo).
struct PlotPoint {
  double ms = 0.0, error = 0.0;
  bool front = false;
  std::string label;  // the setting, printed next to front points
};
std::string studyPlotPng(const std::vector<PlotPoint>& points, const std::string& title, const std::string& errorLabel);

// --- the command --------------------------------------------------------------

struct StudyOptions {
  std::string program = "physketch";  // argv[0], for --emit-commands
  std::string scene;
  std::vector<std::string> vary;      // KNOB=V1,V2,...
  std::string reference;              // analytic | fine | "" (analytic when the scene declares one)
  std::string referenceAt;            // KNOB=V,...: the fine reference (default: finest of each knob)
  std::string outDir = "study";
  int jobs = 1;
  int threads = 0;                    // per run; 0: cores / jobs
  int repeat = 1;
  bool emitCommands = false;
  std::string only;                   // one setting: run it and write OUT/part.json
  std::string collect;                // DIR: merge DIR/parts/*/part.json
  bool quiet = false;
};
int runStudy(const StudyOptions& options);

// --- run --budget MS (study_budget.cpp; docs/accuracy.md, "A time budget") ----------------

// One calibrated setting: its solver time per frame and its error against the reference over
// the calibration frames (RMS of body centres, m; NaN when the guard stopped it).
struct BudgetCandidate {
  Setting setting;
  double msPerFrame = 0.0;
  double error = 0.0;
  std::string status = "ok";
};
// The most accurate candidate that ran stably within the budget; when none fits, the fastest
// stable one (fits = false). Ties: the earlier candidate. Returns the index, or -1 when no
// candidate is stable.
std::ptrdiff_t chooseWithinBudget(const std::vector<BudgetCandidate>& candidates, double budgetMs, bool& fits);

struct BudgetChoice {
  // "calibration", or the study folder the rows came from (run --budget MS --from-study DIR).
  std::string source = "calibration";
  Setting setting;
  bool fits = false;
  double predictedMs = 0.0;     // the chosen candidate's calibrated ms per frame
  double predictedError = 0.0;  // its calibrated error (m)
  int calibrationFrames = 0;    // frames 1..K of the scene the calibration ran
  Setting reference;            // the fine run the errors are measured against
  std::vector<BudgetCandidate> candidates;
  // From a study: its rows are whole runs, so the prediction is for the whole run, and the run's
  // own error is measured against the same answer: the scene's expect records (analytic) or the
  // study's reference trajectory (fine).
  bool analytic = false;
  std::optional<Trajectory> referenceTrajectory;
  int studyThreads = 0;
  std::string norm;             // what the errors measure, in words
};
// Runs frames 0..maxFrames-1 of the scene with one setting (study's runner); its solver ms
// per frame and status ("ok" or "unstable: ...").
Trajectory calibrationRun(const std::string& scenePath, const Setting& setting, int threads, int maxFrames,
                          double& msPerFrame, std::string& status);
// Calibrates a PBD scene for a solver time per frame: for iterations 1, 2 and 4, runs the
// scene's first K frames (a fifth of them, at least 5) with substeps 1, 2, 4, ... until a
// setting is over the budget, then the substep count interpolated between the last two to fill
// it; the errors against a finer run (twice the most substeps tried, 4 iterations). An MPM
// scene with 'substeps auto': the Courant number C = 1, 1/2, 1/4, ... the same way (time about
// 1/C), errors against half the smallest C tried. Throws InputError for an MPM scene with fixed
// substeps or a budget that is not a positive number.
BudgetChoice calibrateBudget(const std::string& scenePath, double budgetMs, int threads, bool quiet);

// study.json (written next to study.csv): the study's rows with the scene's digest, so that run
// --budget --from-study can choose from them. Version of its layout:
constexpr int kStudyJsonVersion = 1;
// FNV-1a 64 of the scene file's bytes and its stroke file's, as 16 hex digits: which scene a
// study measured. Throws InputError when either cannot be read.
std::string sceneDigest(const SceneDesc& scene);
// Chooses from DIR/study.json's rows as chooseWithinBudget does. Throws InputError naming the
// file for a missing or malformed study.json, another scene (digest), a study that varied a
// meshing knob (the budget is the solver's time) or a budget that is not a positive number.
BudgetChoice budgetFromStudy(const SceneDesc& scene, const std::string& dir, double budgetMs);
// The run's error in the norm its BudgetChoice was predicted in (from a study only); NaN when
// the run was stopped.
double budgetRunError(const BudgetChoice& b, const Trajectory& run, const SceneDesc& scene);

// Plot size of study.png (pixels).
constexpr int kPlotWidth = 900;
constexpr int kPlotHeight = 600;

}  // namespace physketch::app
