#!/usr/bin/env python3
"""Runs the hard scenes (scenes/hard/NAME.scene) and checks the outcome each one declares in NAME.expect.

NAME.expect, one `key = value` a line (# starts a comment):
  breaks    = what breaks a naive solver in this scene (for docs/stability.md)
  outcome   = pass | stopped
  metric    = min_C B | max_C B | end_C B (C = x, y, z) | max_drift B | max_ydrift | max_sidedrift
              | max_speed | end_speed   (outcome pass)
  threshold = > X | < X                                                   (outcome pass)
  guard     = KIND [PASS]   the guard's kind (nan, explosion, ...) and optionally its pass (outcome stopped)
  ci_frames = N             the frames to run instead when the runner is given --frames (ctest): fewer
                            for scenes too slow for the sanitizer build at that length, more for one
                            whose metric needs the time (a pile must land and settle); make hard runs
                            them in full
Metrics come from the run's report.json: poses[frame].bodies[body] = [x, y, z, qw, qx, qy, qz] in m.
  min_C B      lowest centre coordinate C (x, y or z) of body B over all frames (m); max_C B the highest
  end_C B      centre coordinate C of body B at the last frame (m)
  max_drift B  largest distance of body B's centre from its frame-0 position (m)
  max_ydrift   largest |y - y0| of any body's centre (m)
  max_sidedrift largest distance in x-z of any body's centre from its frame-0 position (m): a stack that
               settles straight down through the gaps it was drawn with does not count, one that creeps does
  max_speed    largest frame-to-frame centre speed of any body (m/s)
  end_speed    largest centre speed of any body between the last two frames (m/s): has it come to rest
A scene whose run crashes, hangs past --timeout, or whose declaration is missing or invalid fails.
Exit status: 0 when every scene holds its declaration, 1 otherwise.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

METRICS = {f"{m}_{c}": True for m in ("min", "max", "end") for c in "xyz"}
METRICS.update(max_drift=True, max_ydrift=False, max_sidedrift=False, max_speed=False, end_speed=False)
KEYS = {"breaks", "outcome", "metric", "threshold", "guard", "ci_frames"}


class DeclError(Exception):
    pass


def read_expect(path):
    """Parses NAME.expect; raises DeclError naming file:line: field for anything wrong."""
    if not os.path.exists(path):
        raise DeclError(f"{path}:0: missing: every hard scene declares its outcome in NAME.expect")
    d = {}
    with open(path) as f:
        for n, raw in enumerate(f, 1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            if "=" not in line:
                raise DeclError(f"{path}:{n}: expected 'key = value'")
            k, v = (s.strip() for s in line.split("=", 1))
            if k not in KEYS:
                raise DeclError(f"{path}:{n}: field '{k}': unknown (one of {', '.join(sorted(KEYS))})")
            d[k] = (v, n)
    for k in ("breaks", "outcome"):
        if k not in d:
            raise DeclError(f"{path}:0: field '{k}': missing")
    outcome, n = d["outcome"]
    if outcome not in ("pass", "stopped"):
        raise DeclError(f"{path}:{n}: field 'outcome': '{outcome}' is not pass or stopped")
    e = {"breaks": d["breaks"][0], "outcome": outcome, "ci_frames": 0}
    if "ci_frames" in d:
        v, n = d["ci_frames"]
        if not v.isdigit() or int(v) < 1:
            raise DeclError(f"{path}:{n}: field 'ci_frames': '{v}' is not a positive whole number")
        e["ci_frames"] = int(v)
    if outcome == "pass":
        for k in ("metric", "threshold"):
            if k not in d:
                raise DeclError(f"{path}:0: field '{k}': missing (outcome pass needs it)")
        words, n = d["metric"][0].split(), d["metric"][1]
        if not words or words[0] not in METRICS or len(words) != (2 if METRICS[words[0]] else 1):
            raise DeclError(f"{path}:{n}: field 'metric': '{d['metric'][0]}' is not one of min_C B, max_C B, "
                            "end_C B (C = x, y, z), max_drift B, max_ydrift, max_sidedrift, max_speed")
        body = None
        if METRICS[words[0]]:
            if not words[1].isdigit():
                raise DeclError(f"{path}:{n}: field 'metric': body '{words[1]}' is not an index")
            body = int(words[1])
        t, n = d["threshold"][0].split(), d["threshold"][1]
        try:
            value = float(t[1]) if len(t) == 2 and t[0] in ("<", ">") else float("nan")
        except ValueError:
            value = float("nan")
        if not math.isfinite(value):
            raise DeclError(f"{path}:{n}: field 'threshold': '{d['threshold'][0]}' is not '< X' or '> X'")
        e.update(metric=words[0], body=body, op=t[0], threshold=value, metric_text=d["metric"][0])
    else:
        if "guard" not in d:
            raise DeclError(f"{path}:0: field 'guard': missing (outcome stopped needs the diagnosis)")
        g = d["guard"][0].split()
        if len(g) not in (1, 2):
            raise DeclError(f"{path}:{d['guard'][1]}: field 'guard': expected 'KIND [PASS]'")
        e.update(kind=g[0], gpass=g[1] if len(g) == 2 else None)
    return e


def scene_fps(scene):
    with open(scene) as f:
        for raw in f:
            w = raw.split("#", 1)[0].split()
            if len(w) == 2 and w[0] == "fps":
                return float(w[1])
    return 30.0  # the format's default


def measure(e, rep, fps):
    poses = [f["bodies"] for f in rep.get("poses", [])]
    if not poses:
        raise DeclError("report.json has no poses")
    m, b = e["metric"], e["body"]
    if b is not None and b >= len(poses[0]):
        raise DeclError(f"metric body {b} does not exist ({len(poses[0])} bodies)")
    vals = [c for frame in poses for body in frame for c in body[:3]]
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals):
        return float("nan")
    if m[:4] in ("min_", "max_", "end_") and m[4:] in ("x", "y", "z"):
        axis = "xyz".index(m[4])
        series = [f[b][axis] for f in poses]
        return {"min_": min, "max_": max, "end_": lambda s: s[-1]}[m[:4]](series)
    if m == "max_drift":
        return max(math.dist(f[b][:3], poses[0][b][:3]) for f in poses)
    if m == "max_ydrift":
        return max(abs(f[i][1] - poses[0][i][1]) for f in poses for i in range(len(f)) if i < len(poses[0]))
    if m == "max_sidedrift":
        return max(math.hypot(f[i][0] - poses[0][i][0], f[i][2] - poses[0][i][2])
                   for f in poses for i in range(len(f)) if i < len(poses[0]))
    if m == "max_speed":
        best = 0.0
        for a, c in zip(poses, poses[1:]):
            for i in range(min(len(a), len(c))):
                best = max(best, math.dist(a[i][:3], c[i][:3]) * fps)
        return best
    if m == "end_speed":
        if len(poses) < 2:
            raise DeclError("end_speed needs two frames")
        a, c = poses[-2], poses[-1]
        return max((math.dist(a[i][:3], c[i][:3]) * fps for i in range(min(len(a), len(c)))), default=0.0)
    raise DeclError(f"unknown metric {m}")


def run_scene(exe, scene, frames, timeout):
    """Returns (exit code or 'timeout', report dict or None, stderr tail)."""
    with tempfile.TemporaryDirectory(prefix="hard_") as out:
        cmd = [exe, "run", scene, "--out", out, "--quiet", "--threads", "1"]
        if frames:
            cmd += ["--frames", str(frames)]
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return "timeout", None, f"no result within {timeout} s"
        rep = None
        p = os.path.join(out, "report.json")
        if os.path.exists(p):
            with open(p) as f:
                rep = json.load(f)
        return r.returncode, rep, r.stderr.strip()[-300:]


def judge(e, code, rep, fps):
    """Returns (ok, measured text, margin text, outcome text)."""
    if code == "timeout":
        return False, "hang", "-", "FAIL (timeout)"
    if code not in (0, 2) or rep is None:
        return False, f"exit {code}", "-", "FAIL (crash or error)"
    guard = rep.get("guard")
    if e["outcome"] == "stopped":
        if code != 2 or not guard:
            return False, "not stopped", "-", "FAIL (guard did not trip)"
        got = f"{guard['kind']} in {guard['pass']}"
        ok = guard["kind"] == e["kind"] and (e["gpass"] is None or guard["pass"] == e["gpass"])
        return ok, got, "-", "STOPPED" if ok else "FAIL (other diagnosis)"
    if code == 2:
        return False, f"guard: {guard['kind']} in {guard['pass']}" if guard else "exit 2", "-", "FAIL (guard tripped)"
    v = measure(e, rep, fps)
    if not math.isfinite(v):
        return False, "NaN", "-", "FAIL (NaN in poses)"
    margin = (e["threshold"] - v) if e["op"] == "<" else (v - e["threshold"])
    return margin > 0, f"{v:.4g}", f"{margin:.4g}", "PASS" if margin > 0 else "FAIL (metric)"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--exe", required=True, help="the physketch binary")
    ap.add_argument("--dir", default="scenes/hard", help="folder of NAME.scene + NAME.expect")
    ap.add_argument("--frames", type=int, default=0, help="frames per scene (0: the scene's full length)")
    ap.add_argument("--timeout", type=float, default=300, help="seconds per scene before it counts as a hang")
    ap.add_argument("--doc", help="write the measured table into this markdown file (docs/stability.md)")
    a = ap.parse_args()
    names = sorted(f[:-6] for f in os.listdir(a.dir) if f.endswith(".scene"))
    if not names:
        print(f"error: {a.dir}: no .scene files", file=sys.stderr)
        return 1
    rows, failed = [], 0
    for name in names:
        scene = os.path.join(a.dir, name + ".scene")
        try:
            e = read_expect(os.path.join(a.dir, name + ".expect"))
            frames = e["ci_frames"] if a.frames and e["ci_frames"] else a.frames
            code, rep, err = run_scene(a.exe, scene, frames, a.timeout)
            ok, got, margin, outcome = judge(e, code, rep, scene_fps(scene))
        except DeclError as x:
            e, ok, got, margin, outcome, err = {"breaks": "-", "outcome": "?"}, False, "-", "-", f"FAIL ({x})", ""
        failed += not ok
        if e["outcome"] == "pass":
            metric, thr = e["metric_text"], f"{e['op']} {e['threshold']:g}"
        elif e["outcome"] == "stopped":
            metric, thr = "guard trips", e["kind"] + (f" in {e['gpass']}" if e["gpass"] else "")
        else:
            metric, thr = "-", "-"
        rows.append((name, e["breaks"], metric, thr, got, margin, outcome))
        print(f"{name:24s} {outcome:28s} measured {got} (threshold {thr}, margin {margin})", flush=True)
        if not ok and err:
            print(f"    {err}", flush=True)
    if a.doc:
        write_doc(a.doc, rows, a.frames)
    print(f"{len(names) - failed}/{len(names)} hard scenes hold their declaration")
    return 1 if failed else 0


def write_doc(path, rows, frames):
    head = ("# Stability: the hard scenes\n\n"
            "Each scene in `scenes/hard/` breaks a naive solver in the way the second column says, and declares in\n"
            "`NAME.expect`, before it runs, whether it must PASS its metric or be STOPPED by the stability guard with\n"
            "a named diagnosis (only scenes beyond their settings). `scripts/hard.py` (documented at its top) computes\n"
            "the metrics from report.json. Regenerate this table with `make hard` (full length); ctest runs the same\n"
            "scenes at a few frames (`hard_scenes`). Margin: threshold distance in the metric's unit (m or m/s),\n"
            "positive when the scene holds.\n\n"
            f"Run: {'full length' if not frames else f'{frames} frames'}, 1 thread.\n\n"
            "| scene | what breaks naive solvers | metric | threshold | measured | margin | outcome |\n"
            "|---|---|---|---|---|---|---|\n")
    with open(path, "w") as f:
        f.write(head)
        for r in rows:
            f.write("| " + " | ".join(str(c).replace("|", "/") for c in r) + " |\n")


if __name__ == "__main__":
    sys.exit(main())
