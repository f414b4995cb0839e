"""kfuse.calibrate against the rendered stereo set's exact truth and against `kfuse calibrate`
itself; Rig.from_kinect_params against Rig.load.

Needs ../shared/data/synthetic-calib (or $KFUSE_SHARED_DATA/synthetic-calib): skipped visibly
without it, a failure where KFUSE_REQUIRE_SHARED_DATA=1."""

import glob
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import kfuse
from conftest import KINECT, REPO, kfuse_binary

# The library's acceptance bars on the rendered set (issue 3; crates/calib/tests/synthetic.rs):
# focal lengths within 0.1 % of the truth, the principal point within 0.5 px. Measured
# (2026-12, this run's joint fit): IR fx 365.0043 (0.0012 %), colour fx 1059.982 (0.0017 %),
# principal points within 0.04 px.
F_REL_TOL = 1e-3
PP_TOL_PX = 0.5
# Honest σ: each of fx, fy, cx, cy within 3σ of the truth (the Rust test's rule).
SIGMAS = 3.0
# |T - truth|: measured 0.007 mm; 0.1 mm is twice OpenCV 5's joint stereoCalibrate error on
# these images (0.046 mm, opencv_reference.json), the README's bar to beat, with margin.
T_TOL_MM = 0.1


def synthetic_dir() -> Path:
    root = Path(os.environ.get("KFUSE_SHARED_DATA", REPO.parent / "shared" / "data"))
    d = root / "synthetic-calib"
    if not (d / "ground_truth.json").is_file():
        if os.environ.get("KFUSE_REQUIRE_SHARED_DATA") == "1":
            pytest.fail(f"KFUSE_REQUIRE_SHARED_DATA=1 but {d}/ground_truth.json is missing")
        pytest.skip(f"no rendered calibration set at {d} (shared data absent)")
    return d


def patterns(d: Path):
    return str(d / "ir" / "ir_*.png"), str(d / "color" / "color_*.png")


@pytest.fixture(scope="module")
def stereo():
    """kfuse.calibrate on the rendered set's files, held-out check on (what --report makes)."""
    d = synthetic_dir()
    ir, color = patterns(d)
    return kfuse.calibrate(ir=ir, color=color, held_out=True)


def test_intrinsics_and_pose_match_the_ground_truth(stereo):
    gt = json.loads((synthetic_dir() / "ground_truth.json").read_text())
    for fit, key in ((stereo.ir, "ir"), (stereo.color, "color")):
        t = gt["cameras"][key]
        K, S = fit.K, fit.K_std
        assert K.shape == (3, 3) and fit.dist.shape == (5,) and fit.dist_std.shape == (5,)
        got = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
        sigma = {"fx": S[0, 0], "fy": S[1, 1], "cx": S[0, 2], "cy": S[1, 2]}
        for p in ("fx", "fy"):
            err = abs(got[p] / t[p] - 1)
            print(f"{key} {p} {got[p]:.4f} vs {t[p]} ({100 * err:.4f} %, {abs(got[p] - t[p]) / sigma[p]:.2f} σ)")
            assert err < F_REL_TOL, (key, p, got[p], t[p])
        pp = np.hypot(got["cx"] - t["cx"], got["cy"] - t["cy"])
        print(f"{key} principal point error {pp:.4f} px")
        assert pp < PP_TOL_PX
        for p in got:
            assert 0 < sigma[p] and abs(got[p] - t[p]) < SIGMAS * sigma[p], (key, p, got[p], t[p], sigma[p])
        # Both images of every pose show the board: no view left out, 35 corners each.
        assert [v["corners"] for v in fit.views] == [35] * 15
        assert all(v["rejected"] is None for v in fit.views)
    assert stereo.rejected_views == []
    assert stereo.board == (7, 5, 0.04, True)  # README: 7x5 inner corners, 40 mm, top-left black
    dT = np.linalg.norm(stereo.rig.T * 1000 - np.array(gt["stereo"]["T_mm"]))
    print(f"|dT| {dT:.4f} mm, rms {stereo.rms_px:.4f} px")
    assert dT < T_TOL_MM
    assert [p["used"] for p in stereo.pairs] == [True] * 15
    # The rig's cameras are the fits' (the joint fit's intrinsics).
    assert np.array_equal(stereo.rig.depth.K, stereo.ir.K) and np.array_equal(stereo.rig.color.dist, stereo.color.dist)


def _cli(*args):
    r = subprocess.run([str(kfuse_binary()), "calibrate", *map(str, args)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    return r


@pytest.mark.parametrize("board", ["auto", "7x5"])
def test_text_equals_cli_output_byte_for_byte(tmp_path, board):
    """The same files, the same board: the rig file kfuse calibrate --out writes, byte for byte,
    and (with --report / held_out=True) its report.json less the timings."""
    ir, color = patterns(synthetic_dir())
    out, rep = tmp_path / "rig.json", tmp_path / "report"
    _cli("--ir", ir, "--color", color, "--board", board, "--out", out, "--report", rep)
    cal = kfuse.calibrate(ir=ir, color=color, board=board, held_out=True)
    assert cal.text.encode() == out.read_bytes()
    want = json.loads((rep / "report.json").read_text())
    del want["timings_ms"]
    assert cal.report == want
    assert cal.report["held_out"]["errors"][0]["what"] == "IR"
    saved = tmp_path / "py-rig.json"
    cal.save(saved)
    assert saved.read_bytes() == out.read_bytes()
    with pytest.raises(FileExistsError, match="overwrite=True"):
        cal.save(saved)
    # The saved rig reads back as the Calibration's rig.
    assert np.array_equal(kfuse.Rig.load(saved).T, cal.rig.T)


def test_one_camera_equals_cli(tmp_path):
    ir, _ = patterns(synthetic_dir())
    out = tmp_path / "ir.json"
    _cli("--ir", ir, "--out", out)
    cal = kfuse.calibrate(ir=ir)
    assert cal.rig is None and cal.color is None and cal.pairs is None
    assert cal.text.encode() == out.read_bytes()
    assert cal.rms_px == cal.ir.rms_px
    # The camera file's text went through serde_json's parser (its fast float parsing may land
    # 1 ulp off, see test_rig.ULPS): the fit's value within 4 ulp.
    assert cal.rms_px == pytest.approx(json.loads(out.read_text())["calibration"]["rms_px"], rel=4 * np.finfo(float).eps, abs=0)


def test_arrays_in_memory_give_the_files_result(stereo):
    d = synthetic_dir()
    ir, color = patterns(d)
    load = lambda p: [np.asarray(Image.open(f)) for f in sorted(glob.glob(p))]  # noqa: E731
    mem = kfuse.calibrate(ir=load(ir), color=load(color), held_out=True)
    # The same pixels (8-bit grey PNGs, read by Pillow here and by the library there): the same
    # detection and fit, to the last bit.
    for a, b in ((mem.ir, stereo.ir), (mem.color, stereo.color)):
        assert np.array_equal(a.K, b.K) and np.array_equal(a.dist, b.dist)
        assert np.array_equal(a.K_std, b.K_std)
    assert np.array_equal(mem.rig.R, stereo.rig.R) and np.array_equal(mem.rig.T, stereo.rig.T)
    assert mem.rms_px == stereo.rms_px
    # In-memory images are named by their place in the list.
    assert mem.ir.views[0]["name"] == "ir[0]" and mem.pairs[14]["color"] == "color[14]"


def test_wrong_dtype_or_shape_is_value_error_naming_the_argument():
    d = synthetic_dir()
    img = np.asarray(Image.open(d / "ir" / "ir_01.png"))
    with pytest.raises(ValueError, match=r"ir\[1\]: expected a C-contiguous uint8 \(H, W\) NumPy array, got float32"):
        kfuse.calibrate(ir=[img, img.astype(np.float32)])
    rgb = np.asarray(Image.open(d / "color" / "color_01.png").convert("RGB"))
    with pytest.raises(ValueError, match=r"color\[0\]: expected .* uint8 \(H, W\).*shape \(1080, 1920, 3\)"):
        kfuse.calibrate(color=[rgb])
    with pytest.raises(ValueError, match=r"ir\[0\]: .*not C-contiguous"):
        kfuse.calibrate(ir=[img[:, ::2]])
    with pytest.raises(ValueError, match="give ir and/or color"):
        kfuse.calibrate()
    with pytest.raises(ValueError, match="all files or all arrays"):
        kfuse.calibrate(ir=[img, str(d / "ir" / "ir_02.png")])


def test_board_not_found_is_the_library_message(tmp_path):
    """A 9x6 board asked of 7x5 images: ValueError with the message `kfuse calibrate` prints."""
    ir, _ = patterns(synthetic_dir())
    r = subprocess.run([str(kfuse_binary()), "calibrate", "--ir", ir, "--board", "9x6", "--out",
                        str(tmp_path / "x.json")], capture_output=True, text=True)
    assert r.returncode != 0
    with pytest.raises(ValueError) as e:
        kfuse.calibrate(ir=ir, board="9x6")
    assert "you asked for 9x6" in str(e.value)
    assert str(e.value) in r.stdout + r.stderr, (str(e.value), r.stderr)


def test_square_in_metres_equals_square_with_unit():
    ir, _ = patterns(synthetic_dir())
    a = kfuse.calibrate(ir=ir, square=0.04)
    b = kfuse.calibrate(ir=ir, square="40mm")
    assert a.text == b.text
    with pytest.raises(ValueError, match="between 0.1 mm and 1 m"):
        kfuse.calibrate(ir=ir, square=40)
    with pytest.raises(ValueError, match="give a unit"):
        kfuse.calibrate(ir=ir, square="40")


def test_from_kinect_params_is_rig_load_of_it_and_refuses_other_formats():
    a = kfuse.Rig.from_kinect_params(KINECT / "kinect_params.json")
    b = kfuse.Rig.load(KINECT / "kinect_params.json")
    for cam in ("depth", "color"):
        assert np.array_equal(getattr(a, cam).K, getattr(b, cam).K)
        assert np.array_equal(getattr(a, cam).dist, getattr(b, cam).dist)
    assert np.array_equal(a.R, b.R) and np.array_equal(a.T, b.T)
    with pytest.raises(ValueError, match=r'rig.json: is JSON of format "kfuse-rig", not a kinect_params.json.*Rig.load'):
        kfuse.Rig.from_kinect_params(KINECT / "rig.json")
    with pytest.raises(OSError, match="nope.json"):
        kfuse.Rig.from_kinect_params(KINECT / "nope.json")


def test_a_mirrored_kinect_params_is_loaded_with_a_warning(tmp_path):
    """A version-1 kinect_params.json (images mirrored as the sensor streams them) loads with a
    UserWarning saying so and how to convert it, as `kfuse rig import` notes it (issue 51: no
    word); the version-2 file (images as the scene is) loads silently."""
    import warnings

    params = json.loads((KINECT / "kinect_params.json").read_text())
    assert params["version"] == 2 and params["image_orientation"] == "scene"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = kfuse.Rig.load(KINECT / "kinect_params.json")
    v1 = dict(params, version=1)
    del v1["image_orientation"]
    path = tmp_path / "kinect_params.json"
    path.write_text(json.dumps(v1))
    for load in (kfuse.Rig.load, kfuse.Rig.from_kinect_params):
        with pytest.warns(UserWarning, match=r"kinect_params.json: the parameters of mirrored images.*--mirror"):
            mirrored = load(path)
        # The same factory numbers make the same rig (as `kfuse rig import` of either file):
        # the notice is what tells them apart.
        for cam in ("depth", "color"):
            assert np.array_equal(getattr(mirrored, cam).K, getattr(scene, cam).K)
        assert np.array_equal(mirrored.T, scene.T)


def test_help_teaches_the_arguments():
    """help(kfuse.calibrate) says what --help says: the image forms, the board and the unit."""
    doc = kfuse.calibrate.__doc__
    for want in ("glob pattern", "uint8 (H, W)", '"auto"', "metres (0.04)", "held_out", "ValueError"):
        assert want in doc, want
    assert "kinect_params.json" in kfuse.Rig.from_kinect_params.__doc__


def test_save_refuses_an_input_image_even_with_overwrite(tmp_path):
    """Calibration.save over one of the images it was calibrated from is refused, with
    overwrite=True too and through another spelling of the path (`..`, a link), as `kfuse
    calibrate --out` refuses it: ValueError naming the path and the input, the image left
    byte for byte. (Copies of the rendered IR images: a broken save must not damage the
    shared data.)"""
    images = tmp_path / "ir"
    images.mkdir()
    for f in sorted((synthetic_dir() / "ir").glob("ir_*.png")):
        (images / f.name).write_bytes(f.read_bytes())
    cal = kfuse.calibrate(ir=str(images / "ir_*.png"))
    target = images / "ir_03.png"
    before = target.read_bytes()
    link = tmp_path / "link.png"
    link.symlink_to(target)
    for spelling in (target, tmp_path / "ir" / ".." / "ir" / "ir_03.png", link):
        with pytest.raises(ValueError) as e:
            cal.save(spelling, overwrite=True)
        msg = str(e.value)
        assert str(spelling) in msg and "is one of the input images" in msg and "ir_03.png" in msg, msg
        assert target.read_bytes() == before
        assert link.is_symlink()
    assert sorted(p.name for p in images.iterdir()) == sorted(p.name for p in (synthetic_dir() / "ir").glob("ir_*.png"))
    # Another existing file is replaced with overwrite=True, as before.
    other = tmp_path / "old.json"
    other.write_text("{}")
    cal.save(other, overwrite=True)
    assert other.read_text() == cal.text
