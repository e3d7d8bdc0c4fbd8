// Fixed-unit parallel loops, shared by every module. Results never depend on the thread
// count: the units are fixed ranges of the index space (multiples of the chunk), each element
// is written by exactly one task, and reductions combine per-unit partials in unit order.
#pragma once

#include <algorithm>
#include <cstddef>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace physketch {

// Per-particle loops split into fixed chunks; below this size they run serially (threads
// cost more than they save on small scenes).
constexpr std::size_t kChunk = 4096;

// Calls f(begin, end) for the fixed units [u chunk, min(n, (u + 1) chunk)), in parallel when
// there is more than one; nothing for n = 0. A unit's index is begin / chunk.
template <class F>
void forChunks(std::size_t n, std::size_t chunk, F&& f) {
  const std::size_t units = (n + chunk - 1) / chunk;
  if (units <= 1) {
    if (n) f(std::size_t(0), n);
    return;
  }
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, units, 1),
      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t u = r.begin(); u != r.end(); ++u) f(u * chunk, std::min(n, (u + 1) * chunk));
      },
      tbb::simple_partitioner());
}

// forChunks with kChunk.
template <class F>
void forRange(std::size_t n, F&& f) {
  forChunks(n, kChunk, std::forward<F>(f));
}

// Runs f(k) for k in [0, n): independent units (bodies, clusters), each solved serially inside.
template <class F>
void forEach(std::size_t n, F&& f) {
  if (n == 1) {
    f(std::size_t(0));
  } else if (n > 1) {
    tbb::parallel_for(std::size_t(0), n, f);
  }
}

}  // namespace physketch
