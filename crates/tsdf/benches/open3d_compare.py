#!/usr/bin/env python3
"""kfuse's TSDF against Open3D's VoxelBlockGrid on the same depth, in one run (issue 50).

Run by hand, not by CI (it needs Open3D):

    python3 -m venv /work/.cache/helper-b-venv
    /work/.cache/helper-b-venv/bin/pip install open3d-cpu numpy pillow
    cargo build --release -p kfuse-tsdf --example ring_frames
    /work/.cache/helper-b-venv/bin/python crates/tsdf/benches/open3d_compare.py \
        --bin $CARGO_TARGET_DIR/release/examples/ring_frames --sets 1 10

The example `ring_frames` writes the simulated ring's noisy depth (pinhole cameras: Open3D has
no distortion model) as 16-bit mm PNGs with the cameras and poses; both TSDFs integrate those
same files with the same voxel size, truncation, depth scale and depth max; each is timed per
frame (integration only: reading the PNGs is outside) and for mesh extraction; both meshes are
measured by the example against the scene's analytic surfaces.
"""

import argparse
import json
import pathlib
import subprocess
import tempfile
import time

import numpy as np
import open3d as o3d
import open3d.core as o3c

# Block resolution of Open3D's grid: 8 voxels a side, kfuse's BLOCK_SIDE (Open3D's examples
# use 16; `--o3d-block 16` measures that).
BLOCK_RESOLUTION = 8
# Open3D's extraction keeps voxels of weight at least this (its default, 3.0, needs three frames;
# each frame adds 1): 0.5, every observed voxel, as kfuse's marching cubes (weight > 0).
WEIGHT_THRESHOLD = 0.5
# Blocks Open3D pre-allocates: 100 000 (a ring at 5 mm needs ~10 000; the hash map grows, but
# a rehash inside the timed loop would not be integration).
BLOCK_COUNT = 100_000


def run_json(cmd):
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def open3d_fuse(frames_dir, voxel, trunc_m, block_res, out_ply):
    doc = json.loads((frames_dir / "frames.json").read_text())
    cams = doc["cameras"]
    device = o3c.Device("CPU:0")
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight"),
        attr_dtypes=(o3c.float32, o3c.float32),
        attr_channels=((1), (1)),
        voxel_size=voxel,
        block_resolution=block_res,
        block_count=BLOCK_COUNT,
        device=device,
    )
    mult = trunc_m / voxel
    loaded = []
    for f in doc["frames"]:
        c = cams[f["sensor"]]
        depth = o3d.t.io.read_image(str(frames_dir / f["path"])).to(device)
        k = o3c.Tensor(
            [[c["fx"], 0, c["cx"]], [0, c["fy"], c["cy"]], [0, 0, 1]], o3c.float64
        )
        ext = o3c.Tensor(np.array(c["depth_from_world"]), o3c.float64)
        loaded.append((depth, k, ext))
    times = []
    for depth, k, ext in loaded:
        t = time.perf_counter()
        coords = vbg.compute_unique_block_coordinates(
            depth, k, ext, doc["depth_scale"], doc["depth_max_m"], mult
        )
        vbg.integrate(coords, depth, k, ext, doc["depth_scale"], doc["depth_max_m"], mult)
        times.append((time.perf_counter() - t) * 1e3)
    t = time.perf_counter()
    mesh = vbg.extract_triangle_mesh(weight_threshold=WEIGHT_THRESHOLD)
    extract_ms = (time.perf_counter() - t) * 1e3
    legacy = mesh.to_legacy()
    o3d.io.write_triangle_mesh(str(out_ply), legacy, write_ascii=True)
    return {
        "frames": len(times),
        "integrate_ms_per_frame": sum(times) / len(times),
        "integrate_ms_first": times[0],
        "extract_ms": extract_ms,
        "vertices": len(legacy.vertices),
        "faces": len(legacy.triangles),
    }


def fastest(a, b):
    """`a` with each timing the lower of `a`'s and `b`'s."""
    out = dict(a)
    for key in ("integrate_ms_per_frame", "integrate_ms_first", "extract_ms"):
        out[key] = min(a[key], b[key])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", required=True, help="the ring_frames example binary")
    ap.add_argument("--sets", type=int, nargs="+", default=[1, 10])
    ap.add_argument("--voxels", type=float, nargs="+", default=[0.005, 0.01])
    ap.add_argument("--repeat", type=int, default=3, help="alternating runs of each; the fastest")
    ap.add_argument("--o3d-block", type=int, default=BLOCK_RESOLUTION)
    ap.add_argument("--work", help="folder for frames and meshes (default: a temporary one)")
    a = ap.parse_args()
    print(f"open3d {o3d.__version__}")
    with tempfile.TemporaryDirectory() as tmp:
        work = pathlib.Path(a.work or tmp)
        rows = []
        for sets in a.sets:
            frames_dir = work / f"sets{sets}"
            run_json([a.bin, "dump", str(frames_dir), "--sets", str(sets)])
            for voxel in a.voxels:
                kf_ply = frames_dir / f"kfuse_{voxel}.ply"
                o3_ply = frames_dir / f"open3d_{voxel}.ply"
                kf = o3 = None
                # Alternating runs, the fastest of each kept: the machine is shared, and a
                # burst of other load should not land on one library only.
                for _ in range(a.repeat):
                    k = run_json([a.bin, "fuse", str(frames_dir), str(voxel), str(kf_ply)])
                    o = open3d_fuse(frames_dir, voxel, k["truncation_m"], a.o3d_block, o3_ply)
                    kf = k if kf is None else fastest(kf, k)
                    o3 = o if o3 is None else fastest(o3, o)
                for name, r, ply in (("kfuse", kf, kf_ply), ("Open3D", o3, o3_ply)):
                    m = run_json([a.bin, "measure", str(ply), str(voxel)])
                    row = {"method": name, "sets": sets, "voxel_mm": voxel * 1e3, **r, **m}
                    row.pop("integrate_ms", None)
                    rows.append(row)
                    print(
                        f"{name:7} sets {sets:3} voxel {voxel*1e3:4.0f} mm: "
                        f"{r['integrate_ms_per_frame']:7.1f} ms/frame "
                        f"(first {r['integrate_ms_first']:6.1f}), extract "
                        f"{r['extract_ms']:7.1f} ms, {m['vertices']:7} vertices, median "
                        f"{m['median_mm']:.2f} mm, p95 {m['p95_mm']:.2f} mm, "
                        f"completeness {m['completeness']:.3f}",
                        flush=True,
                    )
        print(json.dumps(rows))


if __name__ == "__main__":
    main()
