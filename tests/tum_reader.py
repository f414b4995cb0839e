#!/usr/bin/python3
"""Independent reader of a TUM RGB-D export (numpy + Pillow), for tests/cli_sequence.rs.

Reads rgb.txt, depth.txt and associations.txt as the TUM benchmark's tools do, checks the
format (three '#' header lines in the lists, increasing timestamps, every named file present,
timestamps equal to the file names), opens every image, and prints one JSON object:

  {"depth_scale": 5000.0, "rgb": [[t, file], ...], "depth": [[t, file], ...],
   "frames": [{"rgb_t", "rgb_file", "depth_t", "depth_file", "width", "height",
               "valid", "sum_units", "weighted", "min_m", "max_m",
               "rgb_size", "rgb_mean"}, ...]}

"weighted" is sum(value * (index % 9973)) over the row-major 16-bit depth, an exact integer
checksum that a shifted or transposed image changes.
"""
import json
import os
import re
import sys

import numpy as np
from PIL import Image


def read_list(path, fields):
    with open(path) as f:
        lines = f.read().splitlines()
    rows = []
    headers = 0
    for line in lines:
        if line.startswith("#"):
            headers += 1
            continue
        parts = line.split()
        if len(parts) != fields:
            raise SystemExit(f"{path}: line '{line}' has {len(parts)} fields, expected {fields}")
        rows.append(parts)
    return headers, rows


def main():
    root = sys.argv[1]
    with open(os.path.join(root, "README.txt")) as f:
        readme = f.read()
    m = re.search(r"depth scale: ([0-9.]+) units per metre", readme)
    if not m:
        raise SystemExit("README.txt does not state the depth scale")
    scale = float(m.group(1))
    out = {"depth_scale": scale}
    for name in ("rgb", "depth"):
        headers, rows = read_list(os.path.join(root, f"{name}.txt"), 2)
        if headers != 3:
            raise SystemExit(f"{name}.txt: {headers} header lines, TUM has 3")
        times = [float(t) for t, _ in rows]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise SystemExit(f"{name}.txt: timestamps do not increase")
        for t, file in rows:
            if not os.path.exists(os.path.join(root, file)):
                raise SystemExit(f"{name}.txt names {file}, which is missing")
            stem = os.path.splitext(os.path.basename(file))[0]
            if stem != t:
                raise SystemExit(f"{name}.txt: {file} listed at {t}")
        out[name] = rows
    _, assoc = read_list(os.path.join(root, "associations.txt"), 4)
    frames = []
    for rgb_t, rgb_file, depth_t, depth_file in assoc:
        d = Image.open(os.path.join(root, depth_file))
        if d.mode not in ("I;16", "I;16B", "I"):
            raise SystemExit(f"{depth_file}: mode {d.mode}, expected 16-bit grey")
        a = np.array(d, dtype=np.int64)
        flat = a.reshape(-1)
        weights = np.arange(flat.size, dtype=np.int64) % 9973
        valid = flat > 0
        metres = flat[valid] / scale
        c = Image.open(os.path.join(root, rgb_file))
        if c.format != "JPEG":
            raise SystemExit(f"{rgb_file}: {c.format}, expected the sensor's JPEG")
        rgb = np.array(c.convert("RGB"), dtype=np.float64)
        frames.append({
            "rgb_t": rgb_t,
            "rgb_file": rgb_file,
            "depth_t": depth_t,
            "depth_file": depth_file,
            "width": int(a.shape[1]),
            "height": int(a.shape[0]),
            "valid": int(valid.sum()),
            "sum_units": int(flat.sum()),
            "weighted": int((flat * weights).sum()),
            "min_m": float(metres.min()) if metres.size else 0.0,
            "max_m": float(metres.max()) if metres.size else 0.0,
            "rgb_size": [int(rgb.shape[1]), int(rgb.shape[0])],
            "rgb_mean": [float(v) for v in rgb.reshape(-1, 3).mean(axis=0)],
        })
    out["frames"] = frames
    json.dump(out, sys.stdout)


main()
