#include "sketch/lint.h"

#include <algorithm>
#include <set>
#include <string>

#include "sketch/brush.h"

namespace physketch::sketch {

void lint(const StrokeFile& file, const std::vector<Material>& materials, const std::vector<CutBody>& cuts,
          Sketch& sk) {
  const double h = sk.mapping.voxelSize();
  const double play = file.playTime();
  auto warn = [&](int line, const std::string& text) {
    sk.warnings.push_back(file.path + ":" + std::to_string(line) + ": " + text);
  };
  // Names of bodies made before play (body=NAME).
  std::set<std::string> namedBefore;
  for (int id : file.active) {
    const Operation& op = file.operations[static_cast<std::size_t>(id)];
    if (!op.body.empty() && op.startTime() <= play) namedBefore.insert(op.body);
  }
  for (const OperationSummary& s : sk.operations) {
    const Operation& op = file.operations[static_cast<std::size_t>(s.id)];
    if (!s.active) {
      // Undo takes operations back in the file, whatever their times: an operation
      // after play that is undone is never drawn while the simulation runs.
      if (file.play && op.startTime() > play)
        warn(s.line, s.what + ": drawn after play and undone, so it never happens (undo takes operations back in "
                              "the file; it is not an event of the simulation)");
      continue;
    }
    if (s.minFeature > 0 && s.minFeature < 2 * h)
      warn(s.line, s.what + ": feature of " + std::to_string(s.minFeature) +
                       " m is thinner than two particle spacings (" + std::to_string(2 * h) + " m)");
    if (s.created > 0 && s.remaining == 0) warn(s.line, s.what + ": every particle it created is removed later");
    if (s.material >= 0 && s.created == 0 && s.moved == 0)
      warn(s.line, s.what + ": creates no particle (all its voxels were already taken)");
    if (s.afterPlay && namedBefore.count(op.body))
      warn(s.line, s.what + ": body=" + op.body + " after play makes a new body; it cannot join the body '" + op.body +
                       "' made before play");
  }
  std::vector<bool> used(materials.size(), false);
  for (auto m : sk.particles.material) used[static_cast<std::size_t>(m)] = true;
  for (const RuntimeOp& r : sk.runtime)
    if (r.kind != RuntimeOp::Kind::kTool)  // a tool's particles have the app's material (none yet)
      for (auto m : r.particles.material) used[static_cast<std::size_t>(m)] = true;
  for (std::size_t m = 0; m < materials.size(); ++m)
    if (!used[m]) sk.warnings.push_back("material '" + materials[m].name + "' is never used");
  // A named body whose strokes do not touch is one rigid body held together by nothing.
  for (const std::string& name : namedBefore) {
    for (std::size_t b = 0; b < sk.bodies.size(); ++b) {
      const BodyRange& r = sk.bodies[b];
      if (sk.bodyNames[b] != name || r.layout != BodyLayout::kVoxels) continue;  // a rope or cloth is one piece as drawn
      const std::vector<int> comp = connectedComponents26(
          std::vector<Vec3i>(sk.cells.begin() + r.first, sk.cells.begin() + r.first + r.count));
      const int parts = *std::max_element(comp.begin(), comp.end()) + 1;
      if (parts > 1)
        sk.warnings.push_back("body '" + name + "' is made of " + std::to_string(parts) +
                              " pieces that do not touch; it still moves as one rigid body");
    }
  }
  for (const CutBody& cut : cuts) {
    std::string list;
    for (int b = cut.firstBody; b < cut.firstBody + cut.pieces; ++b)
      list += (list.empty() ? "'" : ", '") + sk.bodyNames[static_cast<std::size_t>(b)] + "'";
    const std::string& name = sk.bodyNames[static_cast<std::size_t>(cut.firstBody)];
    warn(cut.line, "body '" + name + "' was cut by a remove or move into " + std::to_string(cut.pieces) +
                       " bodies: " + list);
  }
}

}  // namespace physketch::sketch
