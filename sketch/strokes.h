// Stroke file v1 (docs/formats.md): what the artist did, as a list of
// operations in time order.
//
//   physketch-strokes 1
//   snap 0.01                                  # snap positions to a 1 cm grid ('snap off')
//   mirror x 0                                 # mirror what follows across x = 0 ('mirror off')
//   stroke create sphere 0.06 wood orient=follow body=chair vel=0,1,0 spin=0,3.1,0
//   sample 0.00  -0.2 0.4 0.0  [pressure]      # t(s) x y z (m), pressure in (0, 1]
//   stroke remove cube 0.05
//   stroke move sphere 0.08
//   primitive box wood 1.0  0 0.3 0  0.2 0.1 0.2  rot=0,1,0,30 fixed
//   stamp meshes/cube.obj stone 1.5 scale=0.1 at=0,0.5,0
//   undo 1
//   redo 1
//   play 3.0                                   # end of the sketching stage (s)
//   stroke tool cube 0.1 friction=0.3          # after play: a kinematic pusher
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "core/math.h"
#include "core/support.h"

namespace physketch::sketch {

// kTool: a kinematic brush that pushes material while the simulation runs, without
// creating, removing or grabbing anything (docs/formats.md, "Tool strokes").
enum class StrokeOp { kCreate, kRemove, kMove, kTool };
enum class BrushShape { kSphere, kCube, kCylinder, kDisc, kCapsule };
enum class Orientation { kFixed, kFollow };
enum class PrimitiveKind { kBox, kSphere, kEllipsoid, kCylinder, kCapsule, kTorus };
const char* toString(StrokeOp op);
const char* toString(BrushShape shape);
const char* toString(PrimitiveKind kind);

struct Sample {
  double t = 0.0;         // s, absolute time of the session
  Vec3 position;          // m, world frame (after snapping)
  double pressure = 1.0;  // (0, 1], scales the brush size
  int line = 0;
};

// Mirror plane in force for an operation: position[axis] = offset.
struct Mirror {
  int axis = -1;  // 0, 1, 2 = x, y, z; -1 = off
  double offset = 0.0;
  int line = 0;
};

struct Stroke {
  StrokeOp op = StrokeOp::kCreate;
  BrushShape brush = BrushShape::kSphere;
  double size = 0.0;       // m: diameter (sphere, cylinder, disc, capsule) or edge (cube)
  double length = 0.0;     // m: cylinder/capsule length along the brush axis, disc thickness; 0 = default
  Orientation orient = Orientation::kFixed;
  Vec3 axis = Vec3::UnitY();  // brush axis when fixed (unit)
  // Tool strokes, friction=: Coulomb coefficient (static = dynamic) of the tool's contacts;
  // unset: the touching material's.
  std::optional<double> toolFriction;
  std::vector<Sample> samples;
};

struct Primitive {
  PrimitiveKind kind = PrimitiveKind::kBox;
  double t = 0.0;
  Vec3 centre = Vec3::Zero();        // m
  Vec3 dims = Vec3::Zero();          // m: box full sizes; sphere radius (x); ellipsoid semi-axes;
                                     // cylinder radius, length; capsule radius, length; torus major, minor radius
  Mat3 rotation = Mat3::Identity();  // local -> world (rot=ax,ay,az,deg)
};

struct MeshStamp {
  std::string path;  // resolved relative to the stroke file
  double t = 0.0;
  double scale = 1.0;
  Mat3 rotation = Mat3::Identity();
  Vec3 translation = Vec3::Zero();
};

// One operation that changes the sketch: a stroke, a primitive or a mesh stamp.
struct Operation {
  enum class Kind { kStroke, kPrimitive, kStamp } kind = Kind::kStroke;
  int id = 0;             // 0-based order among operations in the file (the "stroke id" of its particles)
  int line = 0;           // line of the record that started it
  std::string material;   // create/primitive/stamp; empty for remove and move
  std::string body;       // body name (body=NAME); empty = a body of its own
  // Create operations: how the body starts to move, for the whole body. Parts of one named
  // body agree (the parser checks) and each part carries the body's values.
  std::optional<Vec3> velocity;  // vel=, m/s: initial velocity of the body's centre of mass
  std::optional<Vec3> spin;      // spin=, rad/s, world frame: initial angular velocity about the centre of mass
  bool fixed = false;            // the `fixed` flag: a static body (walls, slopes, a table top)
  struct {
    bool velocity = false, spin = false, fixed = false;
  } written;  // which of vel=, spin=, fixed this record gave itself (the rest came from its body)
  Mirror mirror;          // mirror in force when it was recorded
  Stroke stroke;          // kind == kStroke
  Primitive primitive;    // kind == kPrimitive
  MeshStamp stamp;        // kind == kStamp
  double startTime() const;
  double endTime() const;
};

struct StrokeFile {
  std::string path;
  std::vector<Operation> operations;  // every operation in file order, including undone ones
  std::vector<int> active;            // ids of operations in effect after undo/redo, in file order
  std::optional<double> play;         // end of the sketching stage (s), if given
  int playLine = 0;
  // Time at which simulation starts: `play`, or the end of the last active operation that
  // is not a tool stroke (tools act only while the simulation runs).
  double playTime() const;
};

// Parses a stroke file. Throws InputError (file:line:field) on any bad record:
// unknown record, missing/extra field, unknown option, non-finite or non-positive size,
// pressure outside (0, 1], a sample before any stroke, a stroke without samples,
// times that go back, undo past the beginning, redo with nothing undone, vel/spin/fixed
// outside create operations or disagreeing between parts of a body, a tool stroke that
// starts before play.
StrokeFile loadStrokes(const std::string& path);
StrokeFile parseStrokes(const std::string& text, const std::string& path);

// What the operations in effect use (materials, tools, vel/spin, fixed), each at its first
// use: the input of checkSupport (core/support.h).
SketchUses usesOf(const StrokeFile& file);

}  // namespace physketch::sketch
