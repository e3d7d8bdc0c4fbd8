// Fixed-chunk parallel loops shared by the PBD passes. Results never depend on the thread
// count: chunk boundaries are fixed multiples of kChunk and every element is written by
// exactly one task.
#pragma once

#include <algorithm>
#include <cstddef>

#include <tbb/parallel_for.h>

namespace physketch::pbd {

// Per-particle loops split into fixed chunks; below this size they run serially
// (threads cost more than they save on small scenes).
constexpr std::size_t kChunk = 4096;

// f(lo, hi) runs on the chunks [j kChunk, min(n, (j+1) kChunk)): fixed boundaries,
// whatever the thread count, so a chunk's index is lo / kChunk.
template <class F>
void forRange(std::size_t n, F&& f) {
  const std::size_t chunks = (n + kChunk - 1) / kChunk;
  if (chunks <= 1) {
    f(std::size_t(0), n);
    return;
  }
  tbb::parallel_for(std::size_t(0), chunks, [&](std::size_t j) { f(j * kChunk, std::min(n, (j + 1) * kChunk)); });
}

// Runs f(k) for k in [0, n): independent units (bodies), each solved serially inside.
template <class F>
void forEach(std::size_t n, F&& f) {
  if (n == 1) {
    f(std::size_t(0));
  } else if (n > 1) {
    tbb::parallel_for(std::size_t(0), n, f);
  }
}

}  // namespace physketch::pbd
