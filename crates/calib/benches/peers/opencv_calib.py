#!/usr/bin/env python3
"""Times OpenCV's checkerboard calibration on the views of kfuse's criterion bench
(`crates/calib/benches/calib.rs`), optionally in the same run as that bench.

The views: 25 IR (512x424) + 25 colour (1920x1080) images of `synthetic-calib/` (the 15
rendered poses cycled, `ir_{i % 15 + 1:02}.png`, exactly as the Rust bench loads them). PNG
decoding is excluded on both sides (the images are decoded once, before timing).

Setup (CPU-only wheel):

    python3 -m venv /tmp/peers-venv
    /tmp/peers-venv/bin/pip install opencv-contrib-python-headless numpy
    /tmp/peers-venv/bin/python crates/calib/benches/peers/opencv_calib.py [--kfuse] [--threads N] [--json FILE]

`--kfuse` first runs `cargo bench -p calib --bench calib` (criterion; uses `CARGO_TARGET_DIR`)
and prints its medians beside OpenCV's, so both are measured back to back under the same
machine load. `--threads N` sets `cv2.setNumThreads` (default: OpenCV's default, all cores;
kfuse's rayon also uses all cores). `--json FILE` also writes OpenCV's figures as JSON for
`benches/run_all.sh` (`{"versions", "threads", "results": {bench name: {"median_ms", "min_ms",
"cpu_ms"}}}`, the names those of the criterion bench).

What is timed (median and minimum wall-clock of repeated runs, and median process CPU time):

* detection: `findChessboardCorners(ADAPTIVE_THRESH | NORMALIZE_IMAGE)` + `cornerSubPix`
  (window (4,4) IR / (5,5) colour, EPS|COUNT 30, 1e-3) — the settings of
  `synthetic-calib/opencv_reference.json` — per image and over all 50 images;
* `calibrateCamera` on the 25 IR views (standard 5-coefficient model) — kfuse's
  "mono 25 views (IR corners)";
* stereo from corners: `calibrateCamera` for each camera, then `stereoCalibrate`
  (`CALIB_USE_INTRINSIC_GUESS`, joint refinement of both cameras and R, T) — kfuse's
  "stereo 25 pairs from corners" (which also initialises and refines both cameras);
* end to end: detection of the 50 images + the stereo above — kfuse's "end to end".
"""

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

PATTERN = (7, 5)
SQUARE_MM = 40.0
CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-3)


def timed(fn, repeats, warmup=1):
    for _ in range(warmup):
        fn()
    wall, cpu = [], []
    for _ in range(repeats):
        c = time.process_time()
        t = time.perf_counter()
        fn()
        wall.append((time.perf_counter() - t) * 1e3)
        cpu.append((time.process_time() - c) * 1e3)
    return statistics.median(wall), min(wall), statistics.median(cpu)


def detect(img, win):
    ok, corners = cv2.findChessboardCorners(img, PATTERN, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    return cv2.cornerSubPix(img, corners, win, (-1, -1), CRITERIA)


def object_points():
    obj = np.zeros((PATTERN[0] * PATTERN[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0 : PATTERN[0], 0 : PATTERN[1]].T.reshape(-1, 2) * SQUARE_MM
    return obj


def detect_all(irs, colors):
    ir = [detect(im, (4, 4)) for im in irs]
    co = [detect(im, (5, 5)) for im in colors]
    return ir, co


def align(ir, co):
    """OpenCV may return a view's corners in reverse order; make each colour view start at the
    same board corner as its IR partner (the cameras are rotated by ~1.5 deg only)."""
    out = []
    for a, b in zip(ir, co):
        da = a[-1, 0] - a[0, 0]
        db = b[-1, 0] - b[0, 0]
        out.append(b[::-1].copy() if float(np.dot(da, db)) < 0 else b)
    return out


def stereo(ir, co, ir_size, co_size):
    obj = [object_points()] * len(ir)
    _, k1, d1, _, _ = cv2.calibrateCamera(obj, ir, ir_size, None, None)
    _, k2, d2, _, _ = cv2.calibrateCamera(obj, co, co_size, None, None)
    res = cv2.stereoCalibrate(obj, ir, co, k1, d1, k2, d2, ir_size, flags=cv2.CALIB_USE_INTRINSIC_GUESS, criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-6))
    return res


def run_kfuse():
    """Runs the Rust criterion bench and returns {bench name: median ms}."""
    root = Path(__file__).resolve().parents[4]  # crates/calib/benches/peers -> workspace root
    cmd = ["cargo", "bench", "-p", "calib", "--bench", "calib", "--", "--warm-up-time", "1", "--measurement-time", "5"]
    print("running:", " ".join(cmd), file=sys.stderr)
    out = subprocess.run(cmd, cwd=root, capture_output=True, text=True, check=True).stdout
    unit = {"ns": 1e-6, "µs": 1e-3, "us": 1e-3, "ms": 1.0, "s": 1e3}
    time_re = re.compile(r"time:\s+\[\S+ \S+ (\S+) (\S+) \S+ \S+\]")
    results, name = {}, None
    for line in out.splitlines():
        m = time_re.search(line)
        head = line[: m.start()].strip() if m else line.strip()
        if head and not line.startswith(" "):
            name = head
        if m and name:
            results[name] = float(m.group(1)) * unit[m.group(2)]
    return results


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--kfuse", action="store_true", help="also run kfuse's criterion bench first, in the same run")
    ap.add_argument("--threads", type=int, default=None, help="cv2.setNumThreads (default: OpenCV's default)")
    ap.add_argument("--json", type=Path, help="also write OpenCV's figures here as JSON (for benches/run_all.sh)")
    ap.add_argument("--data", default=None, help="shared data folder (default: $KFUSE_SHARED_DATA or ../shared/data)")
    args = ap.parse_args()
    here = Path(__file__).resolve()
    data = Path(args.data or os.environ.get("KFUSE_SHARED_DATA") or here.parents[4] / ".." / "shared" / "data").resolve()
    syn = data / "synthetic-calib"
    if not syn.is_dir():
        sys.exit(f"synthetic-calib not found under {data}; pass --data or set KFUSE_SHARED_DATA")

    kfuse = run_kfuse() if args.kfuse else None
    if args.threads is not None:
        cv2.setNumThreads(args.threads)

    irs = [cv2.imread(str(syn / f"ir/ir_{i % 15 + 1:02}.png"), cv2.IMREAD_GRAYSCALE) for i in range(25)]
    colors = [cv2.imread(str(syn / f"color/color_{i % 15 + 1:02}.png"), cv2.IMREAD_GRAYSCALE) for i in range(25)]
    ir_size, co_size = irs[0].shape[::-1], colors[0].shape[::-1]
    ir, co = detect_all(irs, colors)
    if any(c is None for c in ir + co):
        sys.exit(f"OpenCV missed boards: IR {[i for i, c in enumerate(ir) if c is None]}, colour {[i for i, c in enumerate(co) if c is None]}")
    co = align(ir, co)
    obj = [object_points()] * 25

    rows = []
    rows.append(("detect 512x424 (rendered IR)", timed(lambda: detect(irs[0], (4, 4)), 50, 3)))
    rows.append(("detect 1920x1080 (rendered colour)", timed(lambda: detect(colors[0], (5, 5)), 30, 3)))
    rows.append(("calibration/mono 25 views (IR corners)", timed(lambda: cv2.calibrateCamera(obj, ir, ir_size, None, None), 10)))
    rows.append(("calibration/stereo 25 pairs from corners", timed(lambda: stereo(ir, co, ir_size, co_size), 10)))

    def e2e():
        a, b = detect_all(irs, colors)
        return stereo(a, align(a, b), ir_size, co_size)

    rows.append(("calibration/end to end: detect 25 IR + 25 colour 1080p, stereo", timed(e2e, 5)))

    res = stereo(ir, co, ir_size, co_size)
    gt = json.loads((syn / "ground_truth.json").read_text())
    t_err = np.linalg.norm(res[6].ravel() - np.array(gt["stereo"]["T_mm"]))
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads; stereo rms {res[0]:.4f} px, |dT| {t_err:.4f} mm (sanity)")
    print(f"{'benchmark':66} {'OpenCV median':>14} {'min':>9} {'CPU':>9}" + (f" {'kfuse median':>13}" if kfuse else ""))
    for name, (med, mn, cpu) in rows:
        line = f"{name:66} {med:11.1f} ms {mn:6.1f} ms {cpu:6.1f} ms"
        if kfuse is not None:
            k = kfuse.get(name) or kfuse.get(name.split("/", 1)[-1])
            line += f" {k:10.1f} ms" if k is not None else "          n/a"
        print(line)
    if args.json:
        out = {
            "versions": {"opencv": cv2.__version__, "numpy": np.__version__},
            "threads": cv2.getNumThreads(),
            "sanity": {"stereo_rms_px": float(res[0]), "dT_mm": float(t_err)},
            "results": {name: {"median_ms": med, "min_ms": mn, "cpu_ms": cpu} for name, (med, mn, cpu) in rows},
        }
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
