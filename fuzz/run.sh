#!/usr/bin/env bash
# Builds the libFuzzer target for the stroke and scene parsers with clang and runs it.
# A benchmark-style script, not part of ctest.
#   fuzz/run.sh [SECONDS]   (default 60)
# Exit status is non-zero when the fuzzer finds a crash, a leak or an uncaught exception;
# the reproducer is left in fuzz/out/.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-60}
if ! command -v clang++-14 >/dev/null 2>&1 || ! dpkg-query -W -f='${Status}' libclang-rt-14-dev 2>/dev/null | grep -q "ok installed"; then
  echo "fuzz: installing clang-14 and libclang-rt-14-dev" >&2
  SUDO=(); [[ $(id -u) -ne 0 ]] && SUDO=(sudo)
  "${SUDO[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${SUDO[@]}" apt-get install -y -qq --no-install-recommends clang-14 libclang-rt-14-dev >/dev/null
fi
mkdir -p fuzz/out fuzz/corpus
bin=fuzz/out/fuzz_parsers
# Every source of core/ and sketch/ (the parsers and the voxelizer need most of them; a
# hand-kept list went stale as sketch/ grew and the link failed).
clang++-14 -std=c++17 -O1 -g -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
  -I. -I/usr/include/eigen3 \
  fuzz/fuzz_parsers.cpp core/*.cpp sketch/*.cpp \
  -frounding-math -lgmp -lmpfr -ltbb $(pkg-config --libs libzip) -o "$bin"
# Seed corpus: the bundled example files (first byte 0 = strokes, 1 = scene).
for f in scenes/*.strokes; do { printf '\0'; tail -n +2 "$f"; } > "fuzz/corpus/$(basename "$f").seed"; done
for f in scenes/*.scene; do { printf '\1'; tail -n +2 "$f"; } > "fuzz/corpus/$(basename "$f").seed"; done
"$bin" -max_total_time="$seconds" -max_len=4096 -timeout=10 -rss_limit_mb=2048 \
  -artifact_prefix=fuzz/out/ fuzz/corpus 2>&1 | tail -n 20
