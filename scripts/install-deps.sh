#!/usr/bin/env bash
# Installs the Debian 12 packages physketch needs to build, test and run.
# Idempotent and quiet when everything is present: it asks dpkg first and
# only calls apt-get (as root, or through sudo) for what is missing.
set -euo pipefail

PACKAGES=(
  # Toolchain. `make bench` times each benchmark with GNU time (/usr/bin/time, package time).
  # g++ pulls in libasan/libubsan, which `make sanitize` needs.
  cmake ninja-build g++ make pkg-config ccache time
  libeigen3-dev
  libopenvdb-dev libboost-iostreams-dev   # FindOpenVDB needs Boost.Iostreams but the package does not pull it in
  libtbb-dev
  libcgal-dev
  # Mesh colliders (pbd/mesh_collider.cpp), found with pkg-config `bullet` (the float build;
  # never the float64 one). Its only dependency is the runtime library libbullet3.24.
  libbullet-dev
  # EGL surfaceless + Mesa llvmpipe. find_package(OpenGL COMPONENTS EGL OpenGL) needs glvnd's
  # libOpenGL.so (libopengl-dev): libgl-dev and libegl-dev do not pull it in, so a minimal root
  # without it stops at configure with "missing: OPENGL_opengl_LIBRARY".
  libegl-dev libgl-dev libopengl-dev libegl-mesa0 libgl1-mesa-dri
  libpng-dev
  zlib1g-dev      # render/png.cpp deflates PNG frames in bands with zlib directly (find_package(ZLIB))
  libcairo2-dev   # physketch study draws study.png with Cairo (found through pkg-config 'cairo')
  libgtest-dev
  nlohmann-json3-dev libcli11-dev
  libzip-dev      # physketch import-tilt reads .tilt sketches (zip archives); pulls in zlib1g-dev
  python3         # scripts/hard.py runs the hard-case suite (ctest hard_scenes, make hard)
)

missing=()
for p in "${PACKAGES[@]}"; do
  status=$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)
  [[ "$status" == "install ok installed" ]] || missing+=("$p")
done

if ((${#missing[@]} == 0)); then
  exit 0
fi

echo "install-deps: installing ${#missing[@]} missing package(s): ${missing[*]}" >&2
SUDO=()
if [[ $(id -u) -ne 0 ]]; then
  if command -v sudo >/dev/null 2>&1; then SUDO=(sudo); else
    echo "install-deps: not root and no sudo; install these packages as root: ${missing[*]}" >&2
    exit 1
  fi
fi
export DEBIAN_FRONTEND=noninteractive
"${SUDO[@]}" apt-get update -qq
"${SUDO[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "install-deps: done" >&2
