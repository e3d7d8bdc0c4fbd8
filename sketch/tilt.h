// Reading Tilt Brush / Open Brush sketches (.tilt) and turning them into stroke files
// (docs/formats.md, "Importing Open Brush sketches").
//
// A .tilt file is a 16-byte header ("tilT", header size, version 1, two reserved words)
// followed by a zip archive whose offsets count from the start of the file. The archive
// holds metadata.json (the brush GUID of every brush index, "BrushIndex") and data.sketch:
//
//   u32 sentinel 0xc576a5cd, u32 version, u32 reserved; u32 n, n bytes of more header;
//   i32 strokes; per stroke:
//     i32 brush index, f32 r g b a, f32 brush size, u32 stroke mask, u32 point mask,
//     stroke extensions in bit order (0x1 flags u32, 0x2 scale f32, 0x4 group u32,
//       0x8 seed u32; another bit: a u32 when it lies in the low 16 bits, else a u32
//       length and that many bytes),
//     i32 points; per point: f32 x y z (decimetres), f32 qx qy qz qw, then point
//       extensions in bit order (0x1 pressure f32 in [0, 1], 0x2 timestamp u32 ms,
//       another bit: a u32).
// (The layout of the open-source tilt-brush-toolkit, Python/tiltbrush/tilt.py.) All
// numbers are little-endian.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/math.h"

namespace physketch::sketch {

struct TiltPoint {
  Vec3 position = Vec3::Zero();  // decimetres, Tilt Brush's canvas frame (Unity: y up, left-handed)
  double pressure = 1.0;         // [0, 1]; 1 when the stroke records none
  std::uint32_t timestampMs = 0; // ms since the sketch began; 0 when the stroke records none
};

struct TiltStroke {
  int brushIndex = 0;              // into TiltSketch::brushes
  Vec3 color = Vec3::Ones();       // linear RGB in [0, 1] (alpha is dropped)
  double size = 0.0;               // brush size, decimetres, times the `scale` extension when present
  bool hasPressure = false;
  bool hasTimestamps = false;
  std::vector<TiltPoint> points;
};

struct TiltSketch {
  std::vector<std::string> brushes;  // BrushIndex: brush GUIDs
  std::vector<TiltStroke> strokes;   // in the file's order (the order they were drawn)
};

// Reads a .tilt file. Throws InputError naming the file and what is wrong: not a .tilt
// (bad header), not a zip, a missing member, metadata.json that is not JSON or has no
// BrushIndex, and in data.sketch a bad sentinel, a count out of range, a truncated
// stroke or point (naming both), a non-finite number, a negative size, a pressure outside
// [0, 1] or a brush index outside BrushIndex.
TiltSketch readTilt(const std::string& path);

// The same from the two members' bytes (`path` names the file in errors).
TiltSketch parseTilt(const std::string& dataSketch, const std::string& metadataJson, const std::string& path);

// The name of a Tilt Brush / Open Brush brush GUID ("Marker", "Wire", ...), or "" when unknown.
std::string tiltBrushName(const std::string& guid);

}  // namespace physketch::sketch
