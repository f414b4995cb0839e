"""The Open3D helpers: no hard dependency (ImportError with a clear message when Open3D is
absent, tested always by hiding it), and, where Open3D imports, the same data as the arrays."""

import os
import sys

import numpy as np
import pytest

import kfuse
from conftest import KINECT


@pytest.fixture(scope="module")
def frame(fused):
    return kfuse.fuse(kfuse.Rig.load(KINECT / "rig.json"), fused["color"], fused["depth_mm"])


def test_without_open3d_each_helper_is_a_clear_import_error(frame, monkeypatch):
    # None in sys.modules makes `import open3d` fail, as on a machine without it.
    monkeypatch.setitem(sys.modules, "open3d", None)
    points = np.zeros((3, 3), np.float32)
    for call in (lambda: kfuse.to_open3d(points), frame.cloud_to_open3d, frame.mesh_to_open3d):
        with pytest.raises(ImportError, match=r"^to_open3d needs Open3D, which kfuse does not "
                                              r"depend on: pip install open3d-cpu"):
            call()


def open3d_or_skip():
    """Open3D, or a visible skip; a failure where KFUSE_REQUIRE_OPEN3D=1 (.ci/run sets it and
    installs open3d-cpu into its venv)."""
    try:
        import open3d
    except ImportError as e:
        if os.environ.get("KFUSE_REQUIRE_OPEN3D") == "1":
            pytest.fail(f"KFUSE_REQUIRE_OPEN3D=1 but Open3D does not import ({e}): "
                        "pip install open3d-cpu (it needs Debian's libusb-1.0-0)")
        # visible in pytest -rs
        pytest.skip(f"Open3D not importable here ({e}); the ImportError path is tested above")
    return open3d


def test_open3d_cloud_holds_the_reference_points_and_colours(frame, fused):
    """The PointCloud's contents against values computed here, not by kfuse's helpers: one
    point per depth sample (the count of non-zero depth pixels), each the back-projection of
    its pixel (undistorted ray x z, the NumPy reference of test_reference.py; float32 rounding
    < 1e-6 relative), and as colour the H6 colour of its depth pixel / 255 (float64, 1e-12)."""
    o3d = open3d_or_skip()
    from test_reference import Reference
    pcd = frame.cloud_to_open3d()
    depth_mm = fused["depth_mm"]
    n = np.count_nonzero(depth_mm)
    assert isinstance(pcd, o3d.geometry.PointCloud)
    assert len(pcd.points) == len(pcd.colors) == n > 100_000
    ref = Reference(depth_mm.astype(np.float64) / 1000.0)
    pts = np.asarray(pcd.points)
    assert (np.abs(pts - ref.points).max(axis=1) / ref.points[:, 2]).max() < 1e-6
    # Colours: the colour-on-depth image (black where not trusted) at each valid depth pixel,
    # row-major, scaled to [0, 1].
    rgb = frame.color_on_depth.reshape(-1, 3)[ref.idx].astype(np.float64) / 255.0
    assert np.abs(np.asarray(pcd.colors) - rgb).max() < 1e-12
    assert np.asarray(pcd.colors).any(axis=1).mean() > 0.5  # not all black
    # The same from the free helper, with and without colours.
    pts_only = kfuse.to_open3d(frame.cloud[0])
    assert len(pts_only.points) == n and len(pts_only.colors) == 0
    err = np.abs(np.asarray(pts_only.points) - ref.points).max(axis=1) / ref.points[:, 2]
    assert err.max() < 1e-6


def test_open3d_cloud_and_mesh_hold_the_arrays(frame, fused):
    o3d = open3d_or_skip()
    points, colors = frame.cloud
    pcd = frame.cloud_to_open3d()
    assert isinstance(pcd, o3d.geometry.PointCloud)
    # float32 -> float64 is exact; colours / 255 round-trip exactly through * 255.
    assert np.array_equal(np.asarray(pcd.points), points.astype(np.float64))
    assert np.array_equal(np.rint(np.asarray(pcd.colors) * 255).astype(np.uint8), colors)
    vertices, faces, uvs = frame.mesh_clean
    mesh = frame.mesh_to_open3d()
    assert isinstance(mesh, o3d.geometry.TriangleMesh)
    assert np.array_equal(np.asarray(mesh.vertices), vertices.astype(np.float64))
    assert np.array_equal(np.asarray(mesh.triangles), faces.astype(np.int32))
    assert np.array_equal(np.asarray(mesh.triangle_uvs), uvs[faces.reshape(-1)].astype(np.float64))
    assert len(frame.mesh_to_open3d(clean=False).triangles) == len(frame.mesh[1])
    reg = kfuse.Registration(kfuse.Rig.load(KINECT / "rig.json"))
    p, c = reg.cloud(fused["depth_mm"], fused["color"])
    assert np.array_equal(np.asarray(kfuse.to_open3d(p, c).points), p.astype(np.float64))
    assert len(kfuse.to_open3d(p).colors) == 0
