// The scene: how to run a sketch (docs/formats.md, "Scene file").
#pragma once

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

enum class SolverKind { kPbd };

struct SceneDesc {
  std::string path;          // the scene file, as given
  std::string strokesPath;   // resolved relative to the scene file's folder
  int strokesLine = 0;       // line of the 'strokes' record (for messages)
  // Workspace: a cube of edge workspaceSize (m) centred at workspaceCenter,
  // mapped onto the 151^3 sketch grid (Phys-Sketch Eq. 4-5).
  Vec3 workspaceCenter{0.0, 0.5, 0.0};
  double workspaceSize = 1.0;
  SolverKind solver = SolverKind::kPbd;
  double dt = 1.0 / 60.0;    // s, one solver step
  int substeps = 4;          // substeps per step
  int iterations = 4;        // constraint iterations per substep
  Vec3 gravity{0.0, -9.81, 0.0};  // m/s^2
  double groundY = 0.0;      // m, height of the ground plane (y up)
  double duration = 2.0;     // s of simulated time
  double fps = 30.0;         // frames per simulated second; 1/fps is a whole number of steps
  std::vector<Material> materials;
  Camera camera;
  int width = 640, height = 480;  // image size (pixels)
  bool writeFrames = true;
  bool writeReport = true;

  int stepsPerFrame() const;  // (1/fps)/dt, validated to be whole when parsed
  int frameCount() const;     // frames including frame 0 at t = 0
};

// Parses and validates a scene file. Throws InputError naming file:line:field.
SceneDesc loadScene(const std::string& path);
SceneDesc parseScene(const std::string& text, const std::string& path);

}  // namespace physketch
