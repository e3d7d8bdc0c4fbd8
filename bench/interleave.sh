#!/usr/bin/env bash
# Before/after on a shared, noisy machine: runs two builds' benchmarks alternately, round
# after round, with 1 and 2 threads, so both see the same load. Prints CSV rows with the
# build's label and the round in front of the usual columns; take medians per build.
#   bench/interleave.sh OLD_SRC OLD_BUILD NEW_SRC NEW_BUILD [ROUNDS] [BENCHES...]
# e.g. (an old revision checked out with `git worktree add /tmp/old REV` and built there):
#   bench/interleave.sh /tmp/old /tmp/old/build . build 5 bench_pipeline bench_sketch > both.csv
# Each benchmark runs from its own source folder (it finds scenes/ there).
set -euo pipefail
if (($# < 4)); then sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'; exit 2; fi
old_src=$1 old_build=$2 new_src=$3 new_build=$4
rounds=${5:-5}
shift $(($# < 5 ? 4 : 5))
benches=("$@")
((${#benches[@]})) || benches=(bench_pipeline bench_sketch)
echo "build,round,bench,case,particles,threads,metric,value,unit"
for r in $(seq 1 "$rounds"); do
  for side in old new; do
    if [[ $side == old ]]; then src=$old_src build=$old_build; else src=$new_src build=$new_build; fi
    build=$(cd "$build" && pwd)
    for t in 1 2; do
      for b in "${benches[@]}"; do
        [[ -x $build/bench/$b ]] || { echo "interleave: no $build/bench/$b" >&2; exit 1; }
        (cd "$src" && "$build/bench/$b" --threads "$t") | grep -v '^bench,case' | sed "s/^/$side,$r,/"
      done
    done
  done
done
