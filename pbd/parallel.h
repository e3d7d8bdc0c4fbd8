// The PBD passes' parallel loops: the shared fixed-unit loops of core/parallel.h.
#pragma once

#include "core/parallel.h"

namespace physketch::pbd {

using physketch::forChunks;
using physketch::forEach;
using physketch::forRange;
using physketch::kChunk;

}  // namespace physketch::pbd
