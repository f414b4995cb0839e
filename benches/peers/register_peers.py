#!/usr/bin/env python3
"""Times depth-to-colour registration in OpenCV and Open3D on kfuse's benchmark frame.

The frame (a Kinect-size synthetic scene: 512x424 depth, 1920x1080 colour) is written by the
Rust bench:

    KFUSE_WRITE_PEER_FRAME=1 cargo bench --bench fusion_cpu -- --warm-up-time 1 --measurement-time 3

into `$CARGO_TARGET_DIR/peer-frame/` (default `target/peer-frame/`): `depth.png` (16-bit,
millimetres, 0 = no sample), `color.png`, `rig.json` (kfuse rig file: both cameras with
Brown-Conrady distortion, `color_from_depth` rotation + translation in metres).

Setup (CPU-only wheels):

    python3 -m venv /tmp/peers-venv
    /tmp/peers-venv/bin/pip install opencv-contrib-python-headless open3d-cpu numpy
    /tmp/peers-venv/bin/python benches/peers/register_peers.py [FRAME_DIR] [--json FILE]

`--json FILE` also writes the figures as JSON for `benches/run_all.sh`
(`{"versions": {...}, "results": {name: {"median_ms", "min_ms", "cpu_ms"}}}`).

What is timed (median and minimum wall-clock and median process CPU time of repeated runs, one frame, single-threaded where the library allows):

* OpenCV `registerDepth` (`cv2.rgbd` in 4.x, `cv2` in 5.x): depth (mm, uint16) -> colour camera, z-buffered, with the
  colour camera's distortion; it assumes an undistorted depth image (the depth lens is ignored).
* Open3D (tensor API): `PointCloud.create_from_depth_image` (pinhole, no distortion) followed by
  `project_to_depth_image` into the colour camera (no distortion), reported separately and summed.
* kfuse from Python (issue 31), when the venv has the package (`benches/run_all.sh` builds
  `python/` into it with the bench profile): `kfuse.Registration(rig).register(depth_mm)` then
  `.hole_mask()` on the CPU engine, the uint16 array in and both NumPy arrays out (all cores:
  `register_parallel_into` and `hole_mask_parallel` through `geometry::fusion::register_on`),
  and the same with `out=` arrays reused from frame to frame (the z-buffer registered straight
  into the array, no copy). Compare with the Rust bench's `register+holes/rayon` of the same
  run: the difference is what the call from Python costs (the millimetre-to-metre conversion
  and unit check, clearing the caller's array whole (`register+holes/rayon_into`), the GIL).

Compare with kfuse's `register+holes/single` (registration + hole mask, with both lenses'
distortion) in the criterion report.
"""

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np


def median_ms(fn, repeats=30, warmup=3):
    for _ in range(warmup):
        fn()
    times, cpu = [], []
    for _ in range(repeats):
        c = time.process_time()
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
        cpu.append((time.process_time() - c) * 1e3)
    return statistics.median(times), min(times), statistics.median(cpu)


def camera_matrix(cam):
    return np.array([[cam["fx"], cam.get("skew", 0.0), cam["cx"]], [0.0, cam["fy"], cam["cy"]], [0.0, 0.0, 1.0]])


def main():
    default = Path(os.environ.get("CARGO_TARGET_DIR", Path(__file__).resolve().parents[2] / "target")) / "peer-frame"
    ap = argparse.ArgumentParser(description="OpenCV and Open3D registration on kfuse's bench frame")
    ap.add_argument("frame_dir", nargs="?", type=Path, default=default)
    ap.add_argument("--json", type=Path, help="also write the figures here as JSON (for benches/run_all.sh)")
    args = ap.parse_args()
    frame_dir = args.frame_dir
    if not (frame_dir / "rig.json").is_file():
        sys.exit(f"{frame_dir / 'rig.json'} not found: write the frame first with "
                 "KFUSE_WRITE_PEER_FRAME=1 cargo bench --bench fusion_cpu")
    rig = json.loads((frame_dir / "rig.json").read_text())
    dcam, ccam = rig["depth_camera"], rig["color_camera"]
    extr = np.eye(4)
    extr[:3, :3] = np.array(rig["color_from_depth"]["rotation"])
    extr[:3, 3] = np.array(rig["color_from_depth"]["translation_m"])

    import cv2

    depth_mm = cv2.imread(str(frame_dir / "depth.png"), cv2.IMREAD_UNCHANGED)
    assert depth_mm is not None and depth_mm.dtype == np.uint16, "depth.png must be 16-bit"
    print(f"frame: depth {depth_mm.shape[1]}x{depth_mm.shape[0]}, colour {ccam['width']}x{ccam['height']}, "
          f"{int((depth_mm > 0).sum())} valid depth pixels")
    results = {}

    cv2.setNumThreads(1)
    kd, kc = camera_matrix(dcam), camera_matrix(ccam)
    dist_c = np.array([ccam["k1"], ccam["k2"], ccam["p1"], ccam["p2"], ccam.get("k3", 0.0)])
    size = (ccam["width"], ccam["height"])

    # OpenCV 4 (contrib) has it in cv2.rgbd; OpenCV 5 moved it into the main 3d module.
    register_depth = getattr(getattr(cv2, "rgbd", None), "registerDepth", None) or cv2.registerDepth

    def cv_register():
        return register_depth(kd, kc, dist_c, extr, depth_mm, size, depthDilation=False)

    out = cv_register()
    results["opencv registerDepth (1 thread)"] = median_ms(cv_register)
    print(f"opencv: {int(np.count_nonzero(out))} registered pixels, version {cv2.__version__}")

    import open3d as o3d

    o3d_depth = o3d.t.geometry.Image(o3d.core.Tensor(depth_mm))
    kd_t = o3d.core.Tensor(kd, dtype=o3d.core.Dtype.Float64)
    kc_t = o3d.core.Tensor(kc, dtype=o3d.core.Dtype.Float64)
    eye = o3d.core.Tensor(np.eye(4), dtype=o3d.core.Dtype.Float64)
    extr_t = o3d.core.Tensor(extr, dtype=o3d.core.Dtype.Float64)

    def o3d_cloud():
        return o3d.t.geometry.PointCloud.create_from_depth_image(o3d_depth, kd_t, eye, depth_scale=1000.0, depth_max=10.0)

    pcd = o3d_cloud()

    def o3d_project():
        return pcd.project_to_depth_image(size[0], size[1], kc_t, extr_t, depth_scale=1000.0, depth_max=10.0)

    img = o3d_project()
    print(f"open3d: {pcd.point.positions.shape[0]} points, "
          f"{int(np.count_nonzero(np.asarray(img.as_tensor().numpy())))} registered pixels, version {o3d.__version__}")
    a = median_ms(o3d_cloud)
    b = median_ms(o3d_project)
    results["open3d create_from_depth_image"] = a
    results["open3d project_to_depth_image"] = b
    results["open3d total"] = tuple(x + y for x, y in zip(a, b))

    try:
        import kfuse
    except ImportError:
        kfuse = None
        print("kfuse (Python) not installed in this venv: its rows are left out")
    if kfuse is not None:
        reg = kfuse.Registration(kfuse.Rig.load(frame_dir / "rig.json"), engine="cpu")

        def kfuse_register():
            return reg.register(depth_mm), reg.hole_mask()

        z, holes = kfuse_register()
        print(f"kfuse (Python): {int(np.isfinite(z).sum())} registered pixels, {int(holes.sum())} hole pixels")
        results["kfuse python register+hole_mask (all cores)"] = median_ms(kfuse_register)
        z_out = np.empty_like(z)
        holes_out = np.empty_like(holes)

        def kfuse_register_into():
            return reg.register(depth_mm, out=z_out), reg.hole_mask(out=holes_out)

        kfuse_register_into()
        assert np.array_equal(np.isnan(z_out), np.isnan(z)) and np.array_equal(z_out[np.isfinite(z)], z[np.isfinite(z)])
        assert np.array_equal(holes_out, holes)
        results["kfuse python register+hole_mask out= (all cores)"] = median_ms(kfuse_register_into)

    # CPU ms sums all threads of the process: compare it with the Rust bench's "cpu-time"
    # lines on a machine shared with other jobs, where wall-clock times include waiting.
    print(f"{'method':40s} {'median ms':>10s} {'min ms':>10s} {'CPU ms':>10s}")
    for k, (med, mn, c) in results.items():
        print(f"{k:40s} {med:10.2f} {mn:10.2f} {c:10.2f}")
    if args.json:
        out = {
            "versions": {"opencv": cv2.__version__, "open3d": o3d.__version__, "numpy": np.__version__}
            | ({"kfuse": kfuse.__version__} if kfuse is not None and hasattr(kfuse, "__version__") else {}),
            "frame": str(frame_dir),
            "results": {k: {"median_ms": med, "min_ms": mn, "cpu_ms": c} for k, (med, mn, c) in results.items()},
        }
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
