#!/usr/bin/env bash
# Checks that the README's commands work on a brand-new Debian 12 system: builds a minimal
# bookworm root with debootstrap (minbase plus only the packages listed in BASE_PACKAGES),
# copies in a clean clone of the repository's committed HEAD (not the working tree), and runs
# `make test && make demo` inside it with chroot. Ends with one line:
#   check-fresh-root: PASS ...   or   check-fresh-root: FAIL ...
# Not part of ctest: it needs root, network access to a Debian mirror and 10-30 min.
#
# Usage: scripts/check-fresh-root.sh [--dir DIR] [--keep] [--rebuild]
#   --dir DIR   where the roots live (default /var/tmp/physketch-fresh-root, or $PHYSKETCH_FRESH_ROOT)
#   --keep      keep DIR afterwards: DIR/base (the pristine minbase root) is then reused by the
#               next run, which skips debootstrap (about 3-5 min); DIR/run (the root the check ran
#               in, with the build and the installed packages) stays for inspection.
#               Without --keep, DIR is deleted at the end.
#   --rebuild   ignore a kept DIR/base and debootstrap a new one.
# Every run starts from a fresh copy of DIR/base, so a reused base still checks a brand-new
# system: the packages scripts/install-deps.sh installs never reach DIR/base.
#
# Environment:
#   PHYSKETCH_DEBIAN_MIRROR  Debian mirror URL (default: the first bookworm mirror in the host's
#                            /etc/apt/sources.list and sources.list.d/*.{list,sources})
#   PHYSKETCH_FRESH_ROOT     default for --dir
set -euo pipefail

SUITE=bookworm
# What a developer starts from: a compiler, build tools, GoogleTest and git (python3, which
# the hard-scene test needs, comes from scripts/install-deps.sh like every other dependency).
BASE_PACKAGES=g++,make,cmake,ninja-build,libgtest-dev,googletest,git,ca-certificates
CHECK_COMMAND='make test && make demo'

dir=${PHYSKETCH_FRESH_ROOT:-/var/tmp/physketch-fresh-root}
keep=0
rebuild=0
while (($#)); do
  case "$1" in
    --dir) dir=${2:?--dir needs a directory}; shift 2 ;;
    --dir=*) dir=${1#--dir=}; shift ;;
    --keep) keep=1; shift ;;
    --rebuild) rebuild=1; shift ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    *) echo "check-fresh-root: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done

log() { printf 'check-fresh-root: %s\n' "$*" >&2; }
fail() { log "FAIL: $*"; exit 1; }

[[ $(id -u) -eq 0 ]] || fail "needs root (debootstrap, mount, chroot)"
repo=$(git -C "$(dirname "$0")/.." rev-parse --show-toplevel)
head=$(git -C "$repo" rev-parse HEAD)
[[ "$dir" == /* ]] || dir=$PWD/$dir
[[ "$dir" != / ]] || fail "--dir must not be /"
base=$dir/base
run=$dir/run

# The mirror the host's apt uses: `deb URI bookworm ...` lines and deb822 stanzas whose Suites
# name bookworm exactly (this skips bookworm-security and bookworm-updates).
host_mirror() {
  local f
  for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list; do
    [[ -f "$f" ]] || continue
    sed 's/\[[^]]*\]//' "$f" | awk -v s="$SUITE" '$1 == "deb" && $3 == s { print $2; exit }'
  done
  for f in /etc/apt/sources.list.d/*.sources; do
    [[ -f "$f" ]] || continue
    awk -v s="$SUITE" 'BEGIN { RS = ""; FS = "\n" }
      { uri = ""; ok = 0; en = 1
        for (i = 1; i <= NF; i++) {
          if ($i ~ /^URIs:/) { split($i, a, /[ \t]+/); uri = a[2] }
          if ($i ~ /^Suites:/) { n = split($i, a, /[ \t]+/); for (j = 2; j <= n; j++) if (a[j] == s) ok = 1 }
          if ($i ~ /^Enabled:[ \t]*no/) en = 0 }
        if (ok && en && uri != "") { print uri; exit } }' "$f"
  done
}
mirror=${PHYSKETCH_DEBIAN_MIRROR:-$(host_mirror | sed -n 1p)}
mirror=${mirror:-http://deb.debian.org/debian}

# --- mounts, always undone on exit -------------------------------------------------------
mounted=()
mount_into() { # root: /proc, /sys, /dev, /dev/pts of the host, recorded for cleanup
  local r=$1
  mount -t proc proc "$r/proc" && mounted+=("$r/proc")
  mount -t sysfs sysfs "$r/sys" && mounted+=("$r/sys")
  mount --bind /dev "$r/dev" && mounted+=("$r/dev")
  mount --bind /dev/pts "$r/dev/pts" && mounted+=("$r/dev/pts")
}
unmount_all() {
  local i m
  for ((i = ${#mounted[@]} - 1; i >= 0; i--)); do
    m=${mounted[i]}
    if mountpoint -q "$m"; then umount "$m" 2>/dev/null || umount -l "$m" || log "could not unmount $m"; fi
  done
  mounted=()
}
# Deletes a root only when nothing is mounted below it (rm must never reach the host's /dev).
remove_root() {
  local r=$1
  [[ -e "$r" ]] || return 0
  if grep -q " ${r}/" /proc/self/mounts; then log "not removing $r: something is still mounted there"; return 1; fi
  rm -rf --one-file-system "$r"
}
cleanup() {
  local rc=$?
  unmount_all
  if ((keep == 0)); then
    remove_root "$run" && remove_root "$base" && rmdir "$dir" 2>/dev/null || true
  fi
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM HUP

secs() { date +%s; }
fmt() { printf '%dm%02ds' $(($1 / 60)) $(($1 % 60)); }
t_start=$(secs)

if ! command -v debootstrap >/dev/null 2>&1; then
  log "installing debootstrap on the host"
  DEBIAN_FRONTEND=noninteractive apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends debootstrap >/dev/null
fi

# --- 1. the pristine base root (reused when kept and complete) -----------------------------
mkdir -p "$dir"
t0=$(secs)
if ((rebuild == 1)) || [[ ! -f "$base/.physketch-base-ok" ]] ||
   [[ "$(cat "$base/.physketch-base-ok")" != "$SUITE $BASE_PACKAGES" ]]; then
  remove_root "$base"
  log "debootstrap --variant=minbase $SUITE from $mirror into $base (+ $BASE_PACKAGES)"
  if ! debootstrap --variant=minbase --include="$BASE_PACKAGES" "$SUITE" "$base" "$mirror" \
       >"$dir/debootstrap.log" 2>&1; then
    tail -n 30 "$dir/debootstrap.log" >&2
    fail "debootstrap failed (log: $dir/debootstrap.log)"
  fi
  rm -f "$base"/var/cache/apt/archives/*.deb
  echo "$SUITE $BASE_PACKAGES" >"$base/.physketch-base-ok"
  log "base root ready in $(fmt $(($(secs) - t0)))"
else
  log "reusing the base root $base (--rebuild to make a new one)"
fi
t_base=$(($(secs) - t0))

# --- 2. a fresh copy of it, with a clean clone of HEAD ------------------------------------
t0=$(secs)
remove_root "$run"
cp -a "$base" "$run"
cp -L /etc/resolv.conf "$run/etc/resolv.conf"   # name resolution for apt inside the root
# A real clone of the committed HEAD: no untracked or ignored files, no build folder.
git clone -q --no-local --no-checkout "$repo" "$run/root/physketch"
git -C "$run/root/physketch" fetch -q "$repo" "$head"
git -C "$run/root/physketch" checkout -q --detach "$head"
t_copy=$(($(secs) - t0))

# --- 3. the README's commands, as root inside the new system ------------------------------
mount_into "$run"
log "running '$CHECK_COMMAND' in $run/root/physketch at ${head:0:12} (log: $dir/check.log)"
t0=$(secs)
set +e
chroot "$run" /usr/bin/env -i HOME=/root LANG=C.UTF-8 TERM=dumb \
  PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
  /bin/bash -c "cd /root/physketch && { $CHECK_COMMAND; }" 2>&1 | tee "$dir/check.log"
rc=${PIPESTATUS[0]}
set -e
t_check=$(($(secs) - t0))
unmount_all

# make demo must actually have written frames and a report.
frames=0
if [[ -d "$run/root/physketch/out/hello/frames" ]]; then
  frames=$(find "$run/root/physketch/out/hello/frames" -name '*.png' | wc -l)
fi
if ((rc == 0)) && { ((frames == 0)) || [[ ! -s "$run/root/physketch/out/hello/report.json" ]]; }; then
  log "make demo exited 0 but wrote no frames or no report.json"
  rc=1
fi

summary="${head:0:12} $SUITE from $mirror; base $(fmt "$t_base"), copy+clone $(fmt "$t_copy"),"
summary+=" '$CHECK_COMMAND' $(fmt "$t_check") ($frames frames), total $(fmt $(($(secs) - t_start)))"
((keep == 0)) || summary+="; kept $dir"
if ((rc == 0)); then
  log "PASS: $summary"
else
  log "FAIL (exit $rc): $summary; see $dir/check.log"
  exit 1
fi
