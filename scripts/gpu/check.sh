#!/usr/bin/env bash
# The GPU check (issue 10): --gl-device gpu on NVIDIA's EGL, on a machine that has the NVIDIA
# driver (under /usr/local/nvidia, as on this workplace's lent machines) but none of this
# project's libraries. scripts/gpu/pack.sh makes .gpu/; .gl/ holds Debian 12's libglvnd debs
# (apt-get download libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2). Run from the repo
# root, as root (the debs are unpacked into /), with OUT set to a folder for the results:
#   OUT=/tmp/gpu bash scripts/gpu/check.sh
# Prints the device, the runs' times, the pixel comparison with llvmpipe's frames, bench_render's
# rows (2 and 16 threads) and the render and CLI tests' results with NVIDIA's EGL as the only EGL.
exec > >(tee "$OUT/log.txt") 2>&1
t0=$(date +%s.%N)
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
mkdir -p /tmp/b && tar xzf .gpu/bundle.tgz -C /tmp/b
export LD_LIBRARY_PATH=/tmp/b/lib:/usr/local/nvidia/lib64:/usr/local/nvidia/lib
j=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f $j ] || j=$(find /usr/local/nvidia /usr/share/glvnd /etc/glvnd -name '*nvidia*.json' 2>/dev/null | grep egl | head -1)
echo "vendor json: $j"
export __EGL_VENDOR_LIBRARY_FILENAMES=$j
py() { env -u LD_LIBRARY_PATH python3 "$@"; }  # the carried Debian libraries are not for the machine's python
grep PRETTY /etc/os-release; nproc; lscpu | grep "Model name"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv
ldd /tmp/b/physketch | grep -E "not found"
P=/tmp/b/physketch
T() { local l=$1; shift; if [ -x /usr/bin/time ]; then /usr/bin/time -f "$l: %e s wall, %M KB peak" "$@"; else local s; s=$(date +%s.%N); "$@"; local rc=$?; echo "$l: $(py -c "print(round($(date +%s.%N)-$s,2))") s wall"; return $rc; fi; }
run() { local n=$1; shift; T "$n" $P run "scenes/$n.scene" -q "$@"; echo "rc=$?"; }
run hello --out /tmp/r/hello --gl-device gpu --threads 16
py -c "import json;d=json.load(open('/tmp/r/hello/report.json'));print('device:',d['frames']['device'],'| gl_device:',d['frames']['gl_device'],'| written:',d['frames']['written'])"
run hello --out /tmp/r/hello2 --gl-device gpu --threads 2
echo "hello threads 16 vs 2, frames byte-identical:"; diff -rq /tmp/r/hello/frames /tmp/r/hello2/frames && echo yes
run mix --out /tmp/r/mix --gl-device gpu --threads 16 --frames 12
run jelly --out /tmp/r/jelly --gl-device gpu --threads 16 --frames 12 --look splats
echo "default (cpu), no Mesa on the machine:"; $P run scenes/hello.scene -q --frames 2 --out /tmp/r/cpu; echo "rc=$?"
py scripts/gpu/compare.py .gpu/ref /tmp/r
cp /tmp/r/hello/frames/frame_0030.png "$OUT/hello_gpu_0030.png"; cp /tmp/r/mix/frames/frame_0011.png "$OUT/mix_gpu_0011.png"
cp /tmp/r/jelly/frames/frame_0011.png "$OUT/jelly_splats_gpu_0011.png"; cp /tmp/r/hello/report.json "$OUT/hello_report.json"
for t in 2 16; do T "bench_render threads=$t" /tmp/b/bench_render --threads $t --repeats 5 --gl-device gpu > "$OUT/bench_render_gpu_t$t.csv"; echo "rc=$?"; done
grep -E "frame_dump|splats" "$OUT/bench_render_gpu_t2.csv"
# The tests read data from the source folder they were built in and run the CLI from its build folder.
src=$(strings /tmp/b/tests/test_cli | grep -m1 -oE '^/.*/tests/cli/test_cli\.cpp$' | sed 's|/tests/cli/test_cli.cpp$||')
if [ -n "$src" ] && [ ! -e "$src" ]; then mkdir -p "$(dirname "$src")"; ln -s "$PWD" "$src"; fi
[ -e build/apps/physketch/physketch ] || { mkdir -p build/apps/physketch && cp $P build/apps/physketch/physketch; }
(cd /tmp && echo "== test_render" && timeout 200 /tmp/b/tests/test_render --gtest_brief=1; echo "rc=$?")
(cd /tmp && echo "== test_cli" && timeout 200 /tmp/b/tests/test_cli --gtest_brief=1 --gtest_filter='Cli.*:*Export*:*Video*'; echo "rc=$?")
echo "total $(py -c "print(round($(date +%s.%N)-$t0,1))") s"
