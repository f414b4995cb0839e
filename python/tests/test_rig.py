"""kfuse.Rig: the formats of `kfuse rig import`, OpenCV's layouts, save/load round trip."""

import json
from pathlib import Path

import numpy as np
import pytest

import kfuse
from conftest import KINECT

# serde_json's default (fast) float parser may land 1 ulp off the correctly rounded value
# (202.52220153808594 reads as 202.5222015380859): a relative tolerance of 4 ulp of f64.
ULPS = 4 * np.finfo(np.float64).eps
# A rotation read from rig JSON is re-orthonormalised (measured: 1.3e-16 on the lab's rigs).
R_READ_TOL = 4 * np.finfo(np.float64).eps


def test_rig_json_values_in_opencv_layout():
    rig = kfuse.Rig.load(KINECT / "rig.json")
    doc = json.loads((KINECT / "rig.json").read_text())
    d = doc["depth_camera"]
    K = rig.depth.K
    assert K.shape == (3, 3) and K.dtype == np.float64
    want = [[d["fx"], d["skew"], d["cx"]], [0, d["fy"], d["cy"]], [0, 0, 1]]
    assert np.allclose(K, want, rtol=ULPS, atol=0)
    assert K[1, 0] == 0 and K[2, 2] == 1
    c = doc["color_camera"]
    assert np.allclose(rig.color.dist, [c["k1"], c["k2"], c["p1"], c["p2"], c["k3"]], rtol=ULPS, atol=0)
    assert (rig.depth.width, rig.depth.height, rig.color.width, rig.color.height) == (512, 424, 1920, 1080)
    R = rig.R
    # A rotation: orthonormal with determinant +1 (tolerance: f64 rounding of a unit matrix).
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and abs(np.linalg.det(R) - 1) < 1e-12
    assert rig.T.shape == (3,)


def test_kinect_params_import_matches_bundled_rig():
    """data/kinect/rig.json is `kfuse rig import data/kinect/kinect_params.json` (data/README)."""
    a = kfuse.Rig.load(KINECT / "kinect_params.json")
    b = kfuse.Rig.load(KINECT / "rig.json")
    for cam in ("depth", "color"):
        # 1e-9 px: the JSON is written with enough digits to round-trip f64 to ~1e-12.
        assert np.allclose(getattr(a, cam).K, getattr(b, cam).K, rtol=0, atol=1e-9)
        assert np.allclose(getattr(a, cam).dist, getattr(b, cam).dist, rtol=0, atol=1e-12)
    assert np.allclose(a.R, b.R, atol=1e-12) and np.allclose(a.T, b.T, atol=1e-12)


def test_save_round_trip_and_refuses_overwrite(tmp_path):
    rig = kfuse.Rig.load(KINECT / "rig.json")
    out = tmp_path / "rig.json"
    rig.save(out)
    back = kfuse.Rig.load(out)
    assert np.allclose(back.depth.K, rig.depth.K, rtol=ULPS, atol=0)
    assert np.allclose(back.T, rig.T, rtol=ULPS, atol=0)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        rig.save(out)
    rig.save(out, overwrite=True)


def test_missing_file_is_os_error(tmp_path):
    with pytest.raises(OSError, match="nope.json"):
        kfuse.Rig.load(tmp_path / "nope.json")


def test_garbage_is_value_error_naming_the_file(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text("{\"format\": \"kfuse-rig\", \"version\": 1}")
    with pytest.raises(ValueError, match="bad.json"):
        kfuse.Rig.load(p)


def test_implausible_rig_needs_force(tmp_path):
    doc = json.loads((KINECT / "rig.json").read_text())
    doc["color_from_depth"]["translation_m"] = [-52.0, 0.0, 0.0]  # mm written as metres
    p = tmp_path / "mm.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="force=True"):
        kfuse.Rig.load(p)
    assert kfuse.Rig.load(p, force=True).T[0] == -52.0


def _cli_import(tmp_path, *sources):
    """`kfuse rig import SOURCES --out tmp`: (exit code, stderr, the rig written or None)."""
    import subprocess

    from conftest import kfuse_binary

    out = tmp_path / "cli-rig.json"
    r = subprocess.run([str(kfuse_binary()), "rig", "import", *map(str, sources), "--out", str(out)],
                       capture_output=True, text=True)
    return r.returncode, r.stderr, (kfuse.Rig.load(out) if r.returncode == 0 else None)


def _shared(*parts):
    import os

    from conftest import REPO

    root = Path(os.environ.get("KFUSE_SHARED_DATA", REPO.parent / "shared" / "data"))
    p = root.joinpath(*parts)
    if not p.exists():
        if os.environ.get("KFUSE_REQUIRE_SHARED_DATA") == "1":
            pytest.fail(f"KFUSE_REQUIRE_SHARED_DATA=1 but {p} is missing")
        pytest.skip(f"no {p} (shared data absent)")
    return p


@pytest.mark.parametrize("name", ["Calib_Results_stereo.mat", "KinectData.mat"])
def test_load_equals_cli_rig_import(tmp_path, name):
    """The lab's Bouguet and KinectData.mat files: Rig.load gives what `kfuse rig import`
    writes (through its JSON: the tolerance of the JSON's float parsing, ULPS)."""
    src = _shared("kinect-lab", name)
    code, err, cli = _cli_import(tmp_path, src)
    assert code == 0, err
    py = kfuse.Rig.load(src)
    for cam in ("depth", "color"):
        assert np.allclose(getattr(py, cam).K, getattr(cli, cam).K, rtol=ULPS, atol=0)
        assert np.allclose(getattr(py, cam).dist, getattr(cli, cam).dist, rtol=ULPS, atol=1e-300)
    # R is re-orthonormalised when the rig JSON is read: entries move by up to ~1 ulp of 1.0.
    assert np.allclose(py.R, cli.R, rtol=0, atol=R_READ_TOL)
    assert np.allclose(py.T, cli.T, rtol=ULPS, atol=1e-300)


def test_error_message_equals_cli(tmp_path):
    """A file of no format kfuse reads: the CLI's one-line message, word for word."""
    p = tmp_path / "notes.txt"
    p.write_text("hello: world\n")
    code, err, _ = _cli_import(tmp_path, p)
    assert code != 0
    with pytest.raises(ValueError) as e:
        kfuse.Rig.load(p)
    assert str(e.value) in err, (str(e.value), err)


def test_a_camera_past_the_50_mpx_limit_is_refused_even_with_force(tmp_path):
    """A colour camera of 16384 x 16384 (each side within the 16384-px limit, 268 Mpx) made
    Registration/fuse abort the interpreter on allocation. geometry's camera limit (50 Mpx, the
    largest image kfuse reads) is a hard one: ValueError even with force=True, naming the size;
    a camera of exactly 50 Mpx still loads."""
    doc = json.loads((KINECT / "rig.json").read_text())
    for w, h in [(16384, 16384), (8000, 6251)]:
        doc["color_camera"]["width"], doc["color_camera"]["height"] = w, h
        p = tmp_path / f"huge-{w}.json"
        p.write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=rf"{w}x{h} is over kfuse's camera limit \(16384 px per side, 50 Mpx\)"):
            kfuse.Rig.load(p, force=True)
    doc["color_camera"]["width"], doc["color_camera"]["height"] = 8000, 6250
    p = tmp_path / "limit.json"
    p.write_text(json.dumps(doc))
    c = kfuse.Rig.load(p, force=True).color
    assert (c.width, c.height) == (8000, 6250)
