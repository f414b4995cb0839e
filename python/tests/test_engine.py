"""kfuse.Engine and fuse(engine=...): the GPU path (lavapipe where no GPU) equals the CPU path,
and without an adapter "gpu" is a RuntimeError with the CLI's message while "auto" falls back."""

import os
import subprocess
import sys

import numpy as np
import pytest

import kfuse
from conftest import KINECT, kfuse_binary


def test_engine_names():
    assert [kfuse.Engine(n).name for n in ("cpu", "GPU", "auto")] == ["cpu", "gpu", "auto"]
    assert kfuse.Engine("gpu") == kfuse.Engine("gpu") and kfuse.Engine("gpu") != kfuse.Engine("cpu")
    with pytest.raises(ValueError, match="^engine: "):
        kfuse.Engine("cuda")
    with pytest.raises(ValueError, match="^engine: "):
        kfuse.fuse(kfuse.Rig.load(KINECT / "rig.json"), np.zeros((1080, 1920, 3), np.uint8),
                   np.zeros((424, 512), np.uint16), engine=3)


def test_gpu_equals_cpu(fused):
    rig = kfuse.Rig.load(KINECT / "rig.json")
    try:
        gpu = kfuse.fuse(rig, fused["color"], fused["depth_mm"], engine=kfuse.Engine("gpu"))
    except RuntimeError as e:
        if os.environ.get("KFUSE_REQUIRE_GPU") == "1":
            raise
        pytest.skip(f"no GPU adapter (set VK_DRIVER_FILES to lavapipe's ICD): {e}")
    cpu = kfuse.fuse(rig, fused["color"], fused["depth_mm"], engine="cpu")
    assert gpu.engine_used.startswith("gpu: ") and cpu.engine_used == "cpu"
    # Tolerance 0: the engines are exact (the CLI's own GPU tests hold the same).
    for name in ("zbuffer", "nearest", "filled"):
        g, c = getattr(gpu, name), getattr(cpu, name)
        assert np.array_equal(np.isnan(g), np.isnan(c)), name
        assert np.array_equal(g.view(np.uint32)[~np.isnan(g)], c.view(np.uint32)[~np.isnan(c)]), name
    assert np.array_equal(gpu.hole_mask, cpu.hole_mask)
    assert np.array_equal(gpu.color_on_depth, cpu.color_on_depth)
    assert np.count_nonzero(~np.isnan(gpu.zbuffer)) > 100_000


NO_ADAPTER_SCRIPT = """
import sys, warnings, numpy as np, kfuse
rig = kfuse.Rig.load(sys.argv[1])
color, depth = np.zeros((1080, 1920, 3), np.uint8), np.full((424, 512), 1500, np.uint16)
try:
    kfuse.fuse(rig, color, depth, engine="gpu")
    print("GPU-RAN")
except RuntimeError as e:
    print("GPU-ERROR", e)
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    f = kfuse.fuse(rig, color, depth, engine="auto")
    print("AUTO", f.engine_used.split(" ")[0], [str(x.message) for x in w])
"""


def test_no_adapter_gpu_is_the_cli_error_and_auto_falls_back(tmp_path):
    # No Vulkan driver at all: an ICD list naming a file that does not exist.
    env = dict(os.environ, VK_DRIVER_FILES=str(tmp_path / "none.json"), WGPU_BACKEND="vulkan",
               VK_ICD_FILENAMES=str(tmp_path / "none.json"))
    run = subprocess.run([sys.executable, "-c", NO_ADAPTER_SCRIPT, str(KINECT / "rig.json")],
                         env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    gpu = next(line for line in lines if line.startswith("GPU-"))
    assert gpu.startswith("GPU-ERROR no GPU adapter found"), run.stdout
    # The CLI's message, word for word, in the same environment.
    cli = subprocess.run(
        [str(kfuse_binary()), "fuse", "--rig", str(KINECT / "rig.json"), "--color",
         str(KINECT / "desk_color.jpg"), "--depth", str(KINECT / "desk_depth.png"), "--engine",
         "gpu", "--no-figures", "--out", str(tmp_path / "cli")],
        env=env, capture_output=True, text=True, timeout=120)
    assert cli.returncode != 0
    message = gpu.removeprefix("GPU-ERROR ")
    assert message in cli.stderr, (message, cli.stderr)
    auto = next(line for line in lines if line.startswith("AUTO"))
    assert auto.startswith("AUTO cpu ") and "no GPU adapter found" in auto, auto
