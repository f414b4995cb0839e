"""kfuse.Registration's engine and options (issue 46): engine="gpu" (lavapipe where no GPU)
gives the CPU's bits, the keywords of kfuse.fuse mean what they mean there (kfuse.fuse of the
same frame is the independent reference, tolerance 0), and out= is written in place."""

import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

import kfuse
from conftest import KINECT


def rig():
    return kfuse.Rig.load(KINECT / "rig.json")


def same_bits(a, b):
    """Float arrays equal bit for bit (NaN where the other is NaN): tolerance 0."""
    return np.array_equal(np.isnan(a), np.isnan(b)) and np.array_equal(
        a.view(np.uint32)[~np.isnan(a)], b.view(np.uint32)[~np.isnan(b)])


def gpu_registration(**options):
    try:
        return kfuse.Registration(rig(), engine="gpu", **options)
    except RuntimeError as e:
        if os.environ.get("KFUSE_REQUIRE_GPU") == "1":
            raise
        pytest.skip(f"no GPU adapter (set VK_DRIVER_FILES to lavapipe's ICD): {e}")


def test_gpu_registration_is_bit_identical_to_cpu(fused):
    gpu = gpu_registration()
    cpu = kfuse.Registration(rig(), engine="cpu")
    assert (gpu.engine, cpu.engine) == ("gpu", "cpu")
    assert gpu.engine_used.startswith("gpu: ") and cpu.engine_used == "cpu"
    reference = kfuse.fuse(rig(), fused["color"], fused["depth_mm"], engine="cpu")
    d = fused["depth_mm"]
    # Two different frames through the same registrations, into new arrays and into out=
    # arrays holding stale values: every result equals fuse's of that frame.
    far = np.where(d > 0, d + 300, 0).astype(np.uint16)
    for frame in (d, far, d):
        ref = reference if frame is d else kfuse.fuse(rig(), fused["color"], frame)
        zs, masks = [], []
        for reg in (cpu, gpu):
            z = reg.register(frame)
            mask = reg.hole_mask()
            z_out = np.full((1080, 1920), -1.0, np.float32)
            m_out = np.ones((1080, 1920), np.bool_)
            assert reg.register(frame, out=z_out) is z_out
            assert reg.hole_mask(out=m_out) is m_out
            assert same_bits(z, z_out) and np.array_equal(mask, m_out), reg.engine
            zs.append(z)
            masks.append(mask)
        assert same_bits(zs[0], ref.zbuffer) and same_bits(zs[1], ref.zbuffer)
        assert np.array_equal(masks[0], ref.hole_mask) and np.array_equal(masks[1], ref.hole_mask)
        # Not vacuous: the desk covers much of the colour image and has disocclusions.
        assert np.count_nonzero(~np.isnan(zs[1])) > 100_000 and masks[1].sum() > 1_000
    # H6 of the last frame, on either engine, is fuse's.
    for reg in (cpu, gpu):
        rgb, valid = reg.color_on_depth(fused["color"])
        assert np.array_equal(rgb, reference.color_on_depth), reg.engine
        assert np.array_equal(valid, reference.color_on_depth_valid), reg.engine


def test_depth_range_leaves_out_the_samples_outside_as_fuse_does(fused):
    """depth_range= is fuse's --depth-range: the z-buffer and the hole mask are fuse's with
    the same range (tolerance 0), and no z-buffer value lies outside the range's depths
    carried into the colour camera (within the 52 mm baseline, checked loosely: the
    registered z is the colour camera's)."""
    d = fused["depth_mm"]
    whole = kfuse.Registration(rig()).register(d)
    for arg in ((0.8005, 1.5005), "800.5mm..1500.5mm"):
        reg = kfuse.Registration(rig(), depth_range=arg)
        z = reg.register(d)
        ref = kfuse.fuse(rig(), fused["color"], d, linear=False, depth_range=arg)
        assert same_bits(z, ref.zbuffer), arg
        assert np.array_equal(reg.hole_mask(), ref.hole_mask), arg
        kept = ~np.isnan(z)
        # The range removes samples: fewer pixels than without it, but still many.
        assert 10_000 < kept.sum() < np.count_nonzero(~np.isnan(whole)), arg
        assert np.nanmin(z) > 0.8005 - 0.1 and np.nanmax(z) < 1.5005 + 0.1, arg
    gpu = gpu_registration(depth_range=(0.8005, 1.5005))
    cpu = kfuse.Registration(rig(), depth_range=(0.8005, 1.5005))
    assert same_bits(gpu.register(d), cpu.register(d))
    assert np.array_equal(gpu.hole_mask(), cpu.hole_mask())


def test_bad_engine_and_options_are_value_errors():
    with pytest.raises(ValueError, match="^engine: "):
        kfuse.Registration(rig(), engine="cuda")
    with pytest.raises(ValueError, match="^engine: "):
        kfuse.Registration(rig(), engine=3)
    for bad in ("0.8..1.5", "2m..1m", (1.5, 0.8), 3):
        with pytest.raises(ValueError, match="^depth_range"):
            kfuse.Registration(rig(), depth_range=bad)
    assert kfuse.Registration(rig(), engine=kfuse.Engine("cpu")).engine == "cpu"


NO_ADAPTER_SCRIPT = """
import sys, warnings, kfuse
rig = kfuse.Rig.load(sys.argv[1])
try:
    kfuse.Registration(rig, engine="gpu")
    print("GPU-RAN")
except RuntimeError as e:
    print("GPU-ERROR", e)
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    r = kfuse.Registration(rig, engine="auto")
    print("AUTO", r.engine, [str(x.message) for x in w])
"""


def test_without_an_adapter_gpu_is_an_error_and_auto_picks_the_cpu(tmp_path):
    env = dict(os.environ, VK_DRIVER_FILES=str(tmp_path / "none.json"), WGPU_BACKEND="vulkan",
               VK_ICD_FILENAMES=str(tmp_path / "none.json"))
    run = subprocess.run([sys.executable, "-c", NO_ADAPTER_SCRIPT, str(KINECT / "rig.json")],
                         env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    gpu = next(line for line in lines if line.startswith("GPU-"))
    assert gpu.startswith("GPU-ERROR no GPU adapter found"), run.stdout
    auto = next(line for line in lines if line.startswith("AUTO"))
    assert auto.startswith("AUTO cpu ") and "no GPU adapter found" in auto, auto
    assert "registering on the CPU" in auto, auto


def test_auto_picks_the_gpu_when_there_is_one(fused):
    gpu_registration()  # skips without an adapter
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        reg = kfuse.Registration(rig(), engine="auto")
    assert reg.engine == "gpu" and reg.engine_used.startswith("gpu: ")
