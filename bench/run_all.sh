#!/usr/bin/env bash
# Runs every benchmark binary of a build folder and prints one CSV header plus
# their rows. Peak memory of each (GNU time) goes to stderr.
#   bench/run_all.sh [BUILD_DIR]
set -euo pipefail
build=${1:-build}
echo "bench,case,particles,threads,metric,value,unit"
for b in "$build"/bench/bench_*; do
  [[ -x "$b" && -f "$b" ]] || continue
  for t in 1 2; do
    if command -v /usr/bin/time >/dev/null 2>&1; then
      /usr/bin/time -f "$(basename "$b") threads=$t peak_rss_kib=%M wall_s=%e" "$b" --threads "$t"
    else
      "$b" --threads "$t"
    fi
  done
done
