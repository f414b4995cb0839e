"""Registration.cloud against the cloud.ply `kfuse fuse` writes (read by an independent PLY
reader, tests/plyfile.py)."""

import numpy as np
import pytest

import kfuse
from conftest import KINECT
from plyfile import read_ply

# Points: tolerance 0 (bit for bit): cloud() calls the CLI's H1 (backproject_cloud) with the
# same ray table on the same depth, and PLY stores float32, the arrays' type.
POINT_TOLERANCE_M = 0.0


@pytest.fixture(scope="module")
def cli_cloud(fused):
    v = read_ply(fused["out"] / "cloud.ply")["vertex"]
    points = np.stack([v["x"], v["y"], v["z"]], axis=1)
    colors = np.stack([v["red"], v["green"], v["blue"]], axis=1)
    return points, colors


def test_cloud_points_and_colors_equal_fuse_cloud_ply(fused, cli_cloud):
    reg = kfuse.Registration(kfuse.Rig.load(KINECT / "rig.json"))
    points, colors = reg.cloud(fused["depth_mm"], fused["color"])
    cli_points, cli_colors = cli_cloud
    assert points.dtype == np.float32 and points.shape == cli_points.shape
    assert colors.dtype == np.uint8 and colors.shape == cli_colors.shape
    # One point per valid depth pixel: the desk frame has about 210 000.
    assert points.shape[0] == np.count_nonzero(fused["depth_mm"]) > 200_000
    assert np.abs(points - cli_points).max() <= POINT_TOLERANCE_M
    assert np.array_equal(points.view(np.uint32), cli_points.view(np.uint32))
    assert np.array_equal(colors, cli_colors)
    # Not vacuous: most points are coloured, some are black (occluded or outside the image).
    black = (colors == 0).all(axis=1)
    assert 0 < black.sum() < 0.5 * len(colors)


def test_cloud_without_color_has_the_same_points_and_no_colors(fused, cli_cloud):
    reg = kfuse.Registration(kfuse.Rig.load(KINECT / "rig.json"))
    points, colors = reg.cloud(fused["depth_mm"])
    assert colors is None
    assert np.array_equal(points.view(np.uint32), cli_cloud[0].view(np.uint32))
    # No frame was registered.
    with pytest.raises(ValueError, match="call register"):
        reg.hole_mask()


def test_cloud_points_are_the_pinhole_back_projection(fused):
    """Independent check of H1 on the desk frame: each point projects back through the depth
    camera's model (K and OpenCV distortion, numpy here) onto its own pixel, and its z is the
    pixel's depth in metres."""
    rig = kfuse.Rig.load(KINECT / "rig.json")
    points, _ = kfuse.Registration(rig).cloud(fused["depth_mm"])
    depth = fused["depth_mm"]
    v, u = np.nonzero(depth)
    np.testing.assert_allclose(points[:, 2], depth[v, u] * 1e-3, rtol=0, atol=1e-6)
    K, (k1, k2, p1, p2, k3) = rig.depth.K, rig.depth.dist
    x, y = points[:, 0] / points[:, 2], points[:, 1] / points[:, 2]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    pu = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
    pv = K[1, 1] * yd + K[1, 2]
    # 1e-3 px: float32 rays and the iterative undistortion behind them.
    assert np.abs(pu - u).max() < 1e-3 and np.abs(pv - v).max() < 1e-3


def test_cloud_rejects_a_wrong_color_array(fused):
    reg = kfuse.Registration(kfuse.Rig.load(KINECT / "rig.json"))
    with pytest.raises(ValueError, match=r"^color: expected a C-contiguous uint8 \(1080, 1920, 3\)"):
        reg.cloud(fused["depth_mm"], np.zeros((1080, 1920), np.uint8))
