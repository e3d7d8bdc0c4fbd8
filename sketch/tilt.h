// Reading Tilt Brush / Open Brush sketches (.tilt) and turning them into stroke files
// (docs/formats.md, "Importing Open Brush sketches").
//
// A .tilt file is a 16-byte header ("tilT", header size, version 1, two reserved words)
// followed by a zip archive whose offsets count from the end of that header (Tilt Brush and
// Open Brush; from the start of the file is accepted too). The archive holds metadata.json
// (the brush GUID of every brush index, "BrushIndex"; Open Brush adds "Layers": name,
// visibility and, since 2025, a transform [[tx,ty,tz],[qx,qy,qz,qw],s] per layer) and
// data.sketch:
//
//   u32 sentinel 0xc576a5cd, u32 version, u32 reserved; u32 n, n bytes of more header;
//   i32 strokes; per stroke:
//     i32 brush index, f32 r g b a, f32 brush size, u32 stroke mask, u32 point mask,
//     stroke extensions in bit order (0x1 flags u32, 0x2 scale f32, 0x4 group u32,
//       0x8 seed u32, 0x10 layer u32 (Open Brush); another bit: a u32 when it lies in the
//       low 16 bits, else a u32 length and that many bytes),
//     i32 points; per point: f32 x y z (decimetres, in the frame of the stroke's layer),
//       f32 qx qy qz qw, then point extensions in bit order (0x1 pressure f32 >= 0: a
//       controller's is in [0, 1], Open Brush's scripted strokes write larger ones; 0x2
//       timestamp u32 ms, another bit: a u32).
// (The layout of the open-source tilt-brush-toolkit, Python/tiltbrush/tilt.py.) All
// numbers are little-endian.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/math.h"

namespace physketch::sketch {

struct TiltPoint {
  Vec3 position = Vec3::Zero();  // decimetres, its layer's frame (Unity: y up, left-handed)
  double pressure = 1.0;         // >= 0 (above 1 from Open Brush's scripts); 1 when the stroke records none
  std::uint32_t timestampMs = 0; // ms since the sketch began; 0 when the stroke records none
};

struct TiltStroke {
  int brushIndex = 0;              // into TiltSketch::brushes
  Vec3 color = Vec3::Ones();       // linear RGB in [0, 1] (alpha is dropped)
  double size = 0.0;               // brush size, decimetres, times |the `scale` extension| when present
  bool negativeScale = false;      // the `scale` extension was negative (Open Brush allows it)
  std::uint32_t layer = 0;         // the `layer` extension (Open Brush), 0 without
  bool hasPressure = false;
  bool hasTimestamps = false;
  std::vector<TiltPoint> points;
};

// An Open Brush layer (metadata.json "Layers"): a stroke's points are in its layer's frame,
// canvas = translation + rotation (scale p), and its size scales with it.
struct TiltLayer {
  std::string name;
  bool visible = true;
  Vec3 translation = Vec3::Zero();  // decimetres
  Quat rotation = Quat::Identity();  // unit
  double scale = 1.0;                // > 0 (Open Brush reads 0 as 1, and so do we)
};

struct TiltSketch {
  std::vector<std::string> brushes;  // BrushIndex: brush GUIDs
  std::vector<TiltLayer> layers;     // Layers (Open Brush); empty: one visible layer, no transform
  std::vector<TiltStroke> strokes;   // in the file's order (the order they were drawn)
};

// Reads a .tilt file, or a folder named X.tilt holding metadata.json and data.sketch (Open
// Brush saves that form too). Throws InputError naming the file and what is wrong: not a .tilt
// (bad header), not a zip, a missing member, metadata.json that is not JSON or has no
// BrushIndex, and in data.sketch a bad sentinel, a count out of range, a truncated
// stroke or point (naming both), a non-finite number, a negative size, a negative pressure,
// a brush index outside BrushIndex, or a layer transform that is not three finite parts
// (a translation, a non-zero quaternion, a scale >= 0).
TiltSketch readTilt(const std::string& path);

// The same from the two members' bytes (`path` names the file in errors).
TiltSketch parseTilt(const std::string& dataSketch, const std::string& metadataJson, const std::string& path);

// The name of a Tilt Brush / Open Brush brush GUID ("Marker", "Wire", ...), or "" when unknown.
std::string tiltBrushName(const std::string& guid);

}  // namespace physketch::sketch
