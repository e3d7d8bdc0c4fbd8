// The scene: how to run a sketch (docs/formats.md, "Scene file").
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "core/material.h"
#include "core/math.h"

namespace physketch {

struct Camera {
  Vec3 eye{1.6, 1.1, 1.9};   // m
  Vec3 target{0.0, 0.3, 0.0};  // m
  Vec3 up{0.0, 1.0, 0.0};
  double fovYDeg = 40.0;     // vertical field of view (degrees)
};

// One pose of a moving mesh collider (a `keyframe` record).
struct ColliderKeyframe {
  double t = 0.0;                    // s of simulated time (0 = the start of the simulation, at 'play')
  Vec3 position = Vec3::Zero();      // m
  Mat3 rotation = Mat3::Identity();  // local -> world
  int line = 0;
};

// A triangle mesh that material collides with but never moves (`collider` record), or that
// follows its keyframes. world = rotation * (scale * p) + position.
struct MeshCollider {
  std::string name;
  std::string path;  // resolved relative to the scene file's folder; checked to exist when parsed
  int line = 0;
  double scale = 1.0;
  Mat3 rotation = Mat3::Identity();  // rot=
  Vec3 position = Vec3::Zero();      // at= (m); unused when there are keyframes
  // friction=: Coulomb coefficient (static = dynamic) of contacts with this collider; unset:
  // the touching material's static_friction / dynamic_friction.
  std::optional<double> friction;
  std::vector<ColliderKeyframe> keyframes;  // strictly increasing t; empty: static

  // Pose at simulated time t (s): the static pose, or the keyframes interpolated — position
  // linearly, rotation by slerp — held at the first before it and at the last after it.
  void poseAt(double t, Mat3& rotationOut, Vec3& positionOut) const;
};

// The answer a scene declares (`expect` record), which `physketch study` measures a
// run's error against (docs/formats.md, "Expected answers"; docs/accuracy.md, the norms).
// `physketch run` ignores it.
struct Expectation {
  enum class Kind { kFreefall, kRest, kHeight, kDamBreak, kRunout, kHydrostatic, kPendulum, kSphere, kViscousSpread };
  Kind kind = Kind::kFreefall;
  std::string body;   // kHeight, kPendulum: the body's name (body=NAME, or "stroke N" written stroke_N)
  double value = 0.0; // kHeight: the final height of its centre of mass (m); kDamBreak: the column's width a (m);
                      // kSphere: the radius (m)
  Vec3 point = Vec3::Zero();  // kPendulum: the pivot (m); kSphere: the centre (m)
  int line = 0;
};
const char* toString(Expectation::Kind kind);

struct SceneDesc {
  std::string path;          // the scene file, as given
  std::string strokesPath;   // resolved relative to the scene file's folder
  int strokesLine = 0;       // line of the 'strokes' record (for messages)
  // Workspace: a cube of edge workspaceSize (m) centred at workspaceCenter,
  // mapped onto the 151^3 sketch grid (Phys-Sketch Eq. 4-5).
  Vec3 workspaceCenter{0.0, 0.5, 0.0};
  double workspaceSize = 1.0;
  SolverKind solver = SolverKind::kPbd;
  int solverLine = 0;        // line of the 'solver' record, 0 = the default
  double dt = 1.0 / 60.0;    // s, one solver step
  int substeps = 4;          // substeps per step
  bool substepsAuto = false; // `substeps auto` (mpm): the fewest per step that meet the time-step bounds
  int substepsLine = 0;      // line of the 'substeps' record, 0 = the default
  int iterations = 4;        // constraint iterations per substep
  Vec3 gravity{0.0, -9.81, 0.0};  // m/s^2
  // solver mpm: how each domain wall acts (`walls`), in the order x-, x+, y-, y+, z-, z+
  // (y- is the floor; the ground plane, when inside the domain, acts as it does), and the
  // grid spacing as a multiple of the particle spacing (`grid_dx`, default 2: 8 per cell).
  enum class Wall { kSticky, kSlip, kSeparate };
  Wall walls[6] = {Wall::kSeparate, Wall::kSeparate, Wall::kSeparate, Wall::kSeparate, Wall::kSeparate, Wall::kSeparate};
  int wallsLine = 0;          // line of the 'walls' record, 0 = the default
  double gridDx = 2.0;
  int gridDxLine = 0;         // line of the 'grid_dx' record, 0 = the default
  // solver mpm: fluid particle shifting (`particle_shift`): once a step, fluid particles closer
  // than this many particle spacings are pushed apart (0 = off, the default; at 0.8 the
  // particles of a sheet thinner than a grid cell no longer gather onto one another).
  double particleShift = 0.0;
  int particleShiftLine = 0;
  // solver mpm: the Courant number C of `substeps auto` (`cfl`): h <= C dx / c_p and
  // h <= C dx / |v|max; 0.5 by default, in (0, 1].
  double cfl = 0.5;
  int cflLine = 0;
  // solver mpm: real-world scale k = simulated size / real size (PhysGen3D §A.4, `scale`),
  // applied when the scene is parsed: g' = k g and, holding each body's mass fixed, density'
  // = density / k^3, stresses (E, bulk modulus, yield stress, sand cohesion) / k, dynamic
  // viscosity / k; so every wave speed and the motion scale with the length and time is
  // unchanged. The values before scaling are kept for the plan.
  double scale = 1.0;
  int scaleLine = 0;
  Vec3 gravityUnscaled{0.0, -9.81, 0.0};
  std::vector<Material> materialsUnscaled;
  // solver pbd: sleeping (`sleep`): a rigid, soft, rope or cloth body whose every point has moved slower than
  // sleepSpeed for sleepTime seconds, with what it touches, rests until something moving
  // touches it. On by default; sleepSpeed 0 = auto: two particle spacings per second (so a body
  // still for the default 0.5 s stays within one spacing).
  bool sleep = true;
  double sleepSpeed = 0.0;   // m/s
  double sleepTime = 0.5;    // s
  int sleepLine = 0;
  // solver pbd: fluids' warm start (`warm_start F [AVERAGES]`, pbd/fluid.h FluidSolver::
  // warmStart): each substep's density solve starts from F of the last one's multipliers,
  // averaged AVERAGES times over neighbours. 0 = off (the default).
  double warmStart = 0.0;
  int warmSmoothing = 4;
  int warmStartLine = 0;
  double groundY = 0.0;      // m, height of the ground plane (y up)
  double duration = 2.0;     // s of simulated time
  double fps = 30.0;         // frames per simulated second; 1/fps is a whole number of steps
  std::vector<Material> materials;
  std::vector<MeshCollider> colliders;
  Camera camera;
  int width = 640, height = 480;  // image size (pixels)
  bool writeFrames = true;
  bool writeReport = true;
  std::vector<Expectation> expectations;  // `expect` records, in file order

  // The (sketch) body an `expect height` names: "stroke_3" in the file means "stroke 3".
  static std::string expectedBodyName(const std::string& field);

  int stepsPerFrame() const;  // (1/fps)/dt, validated to be whole when parsed
  int frameCount() const;     // frames including frame 0 at t = 0
};

// Parses and validates a scene file. Throws InputError naming file:line:field. What
// depends on the solver (kinds, parameters and features it simulates) is checked
// afterwards, against what the sketch uses: checkSupport() in core/support.h.
SceneDesc loadScene(const std::string& path);
SceneDesc parseScene(const std::string& text, const std::string& path);

}  // namespace physketch
