// A Tilt Brush / Open Brush sketch (sketch/tilt.h) as a stroke file and a scene that
// runs it (docs/formats.md, "Importing Open Brush sketches"; `physketch import-tilt`).
//
// What the conversion does, in order:
//  - units and frame: a point (x, y, z) in decimetres of Tilt Brush's left-handed, y-up
//    frame becomes (x, y, -z) / 10 m in ours (right-handed, y up);
//  - placement: scaled uniformly (`fit`: the sketch's bounding box, brush widths
//    included, spans `fit` of the workspace edge along its longest side; or an explicit
//    `scale`), centred over the workspace in x and z, its lowest point one voxel above the
//    workspace floor (the ground of the scene written with it);
//  - brushes: every stroke becomes a `sphere` brush stroke (a tube) whose diameter is the
//    brush size times the stroke's `scale` extension; Tilt Brush's flat brushes turn with
//    the controller at every point, which one stroke axis cannot follow;
//  - pressure p becomes 0.2 + 0.8 p (a point drawn at zero pressure still draws);
//  - thickening (on by default): where a stroke is thinner than two particle spacings
//    (2.02 h), it is widened to that, its wider parts kept as drawn;
//  - materials: one rigid material per colour (8-bit RGB; coarser steps while there would
//    be more than 64), named c_RRGGBB, with that colour and `density`;
//  - timing: times in seconds from the sketch's first timestamp; strokes keep the file's
//    order (the order they were drawn, which later strokes' voxels respect); a stroke that
//    starts before the previous one ends (two hands, mirror painting, or a file out of time
//    order) is delayed until 1 ms after it, keeping its own durations; a point whose time
//    does not increase gets 1 ms after the one before; a stroke without timestamps gets
//    10 ms per point after the previous stroke;
//  - bodies (`join`): `touching` (the default) makes strokes whose voxels touch
//    (26-neighbours) one body whatever their colour, `material` only when they share a
//    material, `none` leaves one body per stroke;
//  - a stroke without points is skipped (counted);
//  - Open Brush layers: a stroke's points and size are taken through its layer's transform
//    (canvas = translation + rotation (scale p), size x scale) before all of the above;
//    strokes on layers hidden in Open Brush are left out (counted) unless `hiddenLayers`;
//  - a pressure above 1 (Open Brush's scripted strokes) counts as 1, the full width (counted);
//    a negative `scale` extension (a mirrored stroke) gives the width of |scale| (counted).
#pragma once

#include <cstdint>
#include <string>

#include "core/math.h"
#include "sketch/tilt.h"

namespace physketch::sketch {

enum class TiltJoin { kTouching, kMaterial, kNone };

struct TiltImportOptions {
  Vec3 workspaceCenter{0.0, 0.5, 0.0};  // m
  double workspaceSize = 1.0;           // m, (0, 1000]
  double fit = 0.8;                     // longest side / workspace edge, (0, 0.98]; when scale == 0
  double scale = 0.0;                   // > 0: metres per Tilt Brush metre instead of fitting
  TiltJoin join = TiltJoin::kTouching;
  bool thicken = true;
  bool hiddenLayers = false;            // also strokes on layers hidden in Open Brush
  double density = 600.0;               // kg/m^3 of every material
  std::string strokesName = "sketch.strokes";  // what the scene's `strokes` record names
  std::string source;                   // the .tilt file, named in the header comments and errors
};

struct TiltImport {
  std::string strokes;  // the stroke file's text
  std::string scene;    // the scene's text
  double scale = 0.0;   // metres per Tilt Brush metre used
  int strokesRead = 0, strokesWritten = 0, skippedEmpty = 0;
  int skippedHidden = 0;     // strokes on hidden layers left out
  int layerMoved = 0;        // strokes taken through a layer transform that is not the identity
  int pressureAboveOne = 0;  // points whose pressure above 1 counted as 1
  int negativeScale = 0;     // strokes whose negative scale extension gave |scale|
  int thickened = 0;     // strokes widened to two particle spacings
  int delayed = 0;       // strokes moved later so that times never go back
  int pointsNudged = 0;  // points whose time did not increase
  int bodies = 0;        // bodies in the sketch after joining (those that hold particles)
  int materials = 0;
  std::int64_t particles = 0;
};

// Throws InputError naming `options.source` when the sketch has no stroke with points, an
// option is out of range, or (explicit scale) the sketch does not fit the workspace.
TiltImport importTilt(const TiltSketch& sketch, const TiltImportOptions& options);

const char* toString(TiltJoin join);
// "touching", "material" or "none"; false for another word.
bool parseTiltJoin(const std::string& word, TiltJoin& out);

}  // namespace physketch::sketch
