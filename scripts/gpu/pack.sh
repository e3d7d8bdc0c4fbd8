#!/usr/bin/env bash
# Packs what the GPU check (scripts/gpu/check.sh) needs on a machine with an NVIDIA driver but
# none of this project's libraries: the built binaries, every library they load except glibc,
# libstdc++ and libglvnd (the machine has the first two; the glvnd debs are carried in .gl/),
# and llvmpipe reference frames of the scenes the check draws, made here with the same binary.
#   scripts/gpu/pack.sh [BUILD_DIR]      (writes .gpu/, which .gitignore ignores, as .gl/)
# Then, on the GPU machine, from the repo root with .gpu and .gl beside it: bash scripts/gpu/check.sh
set -euo pipefail
build=${1:-build}
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/lib" "$stage/tests" .gpu
bins=("$build/apps/physketch/physketch" "$build/bench/bench_render")
cp "${bins[@]}" "$stage/"
cp "$build/tests/test_render" "$build/tests/test_cli" "$stage/tests/"
strip "$stage"/physketch "$stage"/bench_render "$stage"/tests/*
for b in "${bins[@]}" "$build/tests/test_render" "$build/tests/test_cli"; do ldd "$b" | awk '/=>/ {print $3}'; done | sort -u |
  grep -vE '/(libc|libm|libpthread|libdl|librt|ld-linux-x86-64|libEGL|libGLdispatch|libOpenGL|libstdc\+\+|libgcc_s)\.so' |
  while read -r lib; do cp -L "$lib" "$stage/lib/"; done
tar czf .gpu/bundle.tgz -C "$stage" .
# llvmpipe references: the frames check.sh compares (the simulation does not depend on the
# thread count, so only the rasteriser differs).
ref=$(mktemp -d)
"$build/apps/physketch/physketch" run scenes/hello.scene -q --out "$ref/hello"
"$build/apps/physketch/physketch" run scenes/mix.scene -q --frames 12 --out "$ref/mix"
"$build/apps/physketch/physketch" run scenes/jelly.scene -q --frames 12 --look splats --out "$ref/jelly"
rm -rf .gpu/ref
for f in hello/frame_0000 hello/frame_0030 hello/frame_0060 mix/frame_0000 mix/frame_0011 jelly/frame_0000 jelly/frame_0011; do
  mkdir -p ".gpu/ref/${f%%/*}"
  cp "$ref/${f%%/*}/frames/${f#*/}.png" ".gpu/ref/${f%%/*}/"
done
rm -rf "$ref"
du -sh .gpu
