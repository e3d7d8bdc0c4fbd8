// physketch import-tilt: an Open Brush / Tilt Brush sketch -> a stroke file and a scene
// (sketch/tilt_import.h has the conversion; docs/formats.md, "Importing Open Brush sketches").
#include <cstdio>
#include <filesystem>

#include "apps/physketch/app.h"
#include "core/atomic_file.h"
#include "core/error.h"
#include "sketch/tilt.h"
#include "sketch/tilt_import.h"

namespace physketch::app {

int importTilt(const ImportTiltOptions& opt) {
  return withExitCodes([&] {
    namespace fs = std::filesystem;
    const fs::path strokes = opt.output.empty() ? fs::path(opt.input).filename().replace_extension(".strokes")
                                                : fs::path(opt.output);
    const fs::path scene = opt.scene.empty() ? fs::path(strokes).replace_extension(".scene") : fs::path(opt.scene);
    if (strokes == scene) throw InputError(opt.output, 0, "-o", "the stroke file and the scene would be the same file");
    sketch::TiltImportOptions o;
    o.source = opt.input;
    o.workspaceCenter = opt.workspaceCenter;
    o.workspaceSize = opt.workspaceSize;
    o.fit = opt.fit;
    o.scale = opt.scale;
    o.thicken = !opt.noThicken;
    o.hiddenLayers = opt.hiddenLayers;
    o.density = opt.density;
    if (!sketch::parseTiltJoin(opt.join, o.join))
      throw InputError(opt.input, 0, "--join", "'" + opt.join + "' is not one of touching, material, none");
    // The scene names the stroke file relative to its own folder.
    const fs::path sceneDir = scene.has_parent_path() ? scene.parent_path() : fs::path(".");
    o.strokesName = fs::relative(fs::absolute(strokes), fs::absolute(sceneDir)).generic_string();
    const sketch::TiltSketch sk = sketch::readTilt(opt.input);
    const sketch::TiltImport r = sketch::importTilt(sk, o);
    for (const fs::path& f : {strokes, scene}) {
      std::error_code ec;
      if (f.has_parent_path()) fs::create_directories(f.parent_path(), ec);
      if (ec) throw RuntimeError("cannot create folder " + f.parent_path().string() + ": " + ec.message());
    }
    writeFileAtomic(strokes.string(), r.strokes);
    writeFileAtomic(scene.string(), r.scene);
    if (!opt.quiet) {
      std::printf("%s: %d strokes read, %d written", opt.input.c_str(), r.strokesRead, r.strokesWritten);
      if (r.skippedEmpty) std::printf(" (%d without points skipped)", r.skippedEmpty);
      if (r.skippedHidden) std::printf(" (%d on hidden layers left out: --hidden-layers imports them)", r.skippedHidden);
      if (r.layerMoved) std::printf("\n%d strokes placed through their Open Brush layer's transform", r.layerMoved);
      if (r.pressureAboveOne) std::printf("\n%d points with a pressure above 1 drawn at full width", r.pressureAboveOne);
      if (r.negativeScale) std::printf("\n%d strokes with a negative scale (mirrored) drawn at |scale|", r.negativeScale);
      std::printf("\nscale %.6g m per Tilt Brush metre (%s), %d materials, %d bodies (join %s), %lld particles\n",
                  r.scale, opt.scale > 0 ? "--scale" : "fitted", r.materials, r.bodies, sketch::toString(o.join),
                  static_cast<long long>(r.particles));
      std::printf("%d strokes thickened to two particle spacings, %d delayed so that times never go back, "
                  "%d points re-timed\n",
                  r.thickened, r.delayed, r.pointsNudged);
      std::printf("wrote %s and %s (physketch run %s)\n", strokes.string().c_str(), scene.string().c_str(),
                  scene.string().c_str());
    }
    return kExitOk;
  });
}

}  // namespace physketch::app
