// libFuzzer target for the stroke and scene parsers (and the voxelizer behind them).
// The contract under test: any input gives either a parse result or an InputError —
// never a crash, a hang, an unbounded allocation or another exception type.
// Built and run by fuzz/run.sh (clang, -fsanitize=fuzzer,address,undefined); not part of ctest.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "core/error.h"
#include "core/scene.h"
#include "sketch/strokes.h"
#include "sketch/voxelize.h"

using namespace physketch;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  // First byte picks the parser; the rest is the file text.
  const std::string text(reinterpret_cast<const char*>(data) + 1, size - 1);
  try {
    if (data[0] % 2 == 0) {
      const sketch::StrokeFile f = sketch::parseStrokes("physketch-strokes 1\n" + text, "fuzz.strokes");
      // Voxelize small sketches too: brushes, primitives, remove/move/mirror paths.
      Material m;
      m.name = "w";
      const sketch::GridMapping map(Vec3(0, 0.5, 0), 1.0);
      std::size_t samples = 0;
      for (const auto& op : f.operations) samples += op.stroke.samples.size();
      if (samples < 64) sketch::voxelize(f, map, {m});
    } else {
      parseScene("physketch-scene 1\n" + text, "fuzz.scene");
    }
  } catch (const InputError&) {
    // Expected for bad input.
  }
  return 0;
}
