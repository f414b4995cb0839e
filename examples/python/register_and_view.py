"""Load the bundled data/kinect frame, register it with kfuse, save an overlay PNG (matplotlib,
Agg) and, when Open3D is installed, build its coloured point cloud.

    python examples/python/register_and_view.py [OUT.png]

Prints one JSON line: registered pixels, hole pixels, cloud points, where the PNG went.
"""

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

import kfuse  # noqa: E402

KINECT = Path(__file__).resolve().parents[2] / "data" / "kinect"


def main():
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("register_overlay.png")
    rig = kfuse.Rig.load(KINECT / "rig.json")
    depth_mm = np.asarray(Image.open(KINECT / "desk_depth.png")).astype(np.uint16)
    color = np.ascontiguousarray(np.asarray(Image.open(KINECT / "desk_color.jpg").convert("RGB")))
    reg = kfuse.Registration(rig)
    z = reg.register(depth_mm)
    holes = reg.hole_mask()
    points, colors = reg.cloud(depth_mm, color)

    fig = plt.figure(figsize=(19.2, 10.8), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.imshow(color)
    ax.imshow(np.ma.masked_invalid(z), cmap="turbo", alpha=0.5)
    ax.imshow(np.ma.masked_where(~holes, holes), cmap="autumn", alpha=0.8)
    ax.set_axis_off()
    fig.savefig(out, dpi=100)
    plt.close(fig)

    o3d_points = None
    try:
        o3d_points = len(kfuse.to_open3d(points, colors).points)
    except ImportError as e:
        print(f"no Open3D cloud: {e}", file=sys.stderr)
    print(json.dumps({"registered_pixels": int(np.count_nonzero(~np.isnan(z))),
                      "hole_pixels": int(holes.sum()), "cloud_points": int(len(points)),
                      "open3d_points": o3d_points, "overlay": str(out)}))


if __name__ == "__main__":
    main()
