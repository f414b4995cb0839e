"""Shared fixtures: the repository's bundled sample frame and `kfuse fuse` run on it once."""

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

REPO = Path(__file__).resolve().parents[2]
KINECT = REPO / "data" / "kinect"


def kfuse_binary() -> Path:
    """The built CLI: $KFUSE_BIN, else $CARGO_TARGET_DIR/{debug,release}/kfuse."""
    if os.environ.get("KFUSE_BIN"):
        return Path(os.environ["KFUSE_BIN"])
    target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    for profile in ("debug", "release"):
        b = target / profile / "kfuse"
        if b.is_file():
            return b
    pytest.fail(f"no kfuse binary under {target}; build it with `cargo build` or set KFUSE_BIN")


@pytest.fixture(scope="session")
def fused(tmp_path_factory):
    """`kfuse fuse` on data/kinect with the colour as a lossless PNG (a JPEG decoder of
    Pillow and of the CLI may differ by one level; a PNG is the same bytes to both)."""
    tmp = tmp_path_factory.mktemp("fuse")
    color = np.asarray(Image.open(KINECT / "desk_color.jpg").convert("RGB"))
    color_png = tmp / "color.png"
    Image.fromarray(color).save(color_png)
    out = tmp / "out"
    subprocess.run(
        [str(kfuse_binary()), "fuse", "--rig", str(KINECT / "rig.json"), "--color", str(color_png),
         "--depth", str(KINECT / "desk_depth.png"), "--engine", "cpu", "--no-figures",
         "--out", str(out)],
        check=True, capture_output=True,
    )
    depth_mm = np.asarray(Image.open(KINECT / "desk_depth.png")).astype(np.uint16)
    return {"out": out, "color": np.ascontiguousarray(color), "depth_mm": depth_mm}
