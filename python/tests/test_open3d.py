"""The Open3D helpers: no hard dependency (ImportError with a clear message when Open3D is
absent, tested always by hiding it), and, where Open3D imports, the same data as the arrays."""

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
    try:
        import open3d
    except ImportError as e:  # visible in pytest -rs
        pytest.skip(f"Open3D not importable here ({e}); the ImportError path is tested above")
    return open3d


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
