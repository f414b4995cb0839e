"""kfuse.fuse against `kfuse fuse` on data/kinect: the arrays against the CLI's files, and
`.save()` against the CLI's folder byte for byte."""

import json

import numpy as np
import pytest
from PIL import Image

import kfuse
from conftest import KINECT
from plyfile import read_ply

# summary.json fields that differ by design between two runs of the same frame:
# "inputs" is provenance (the CLI names its --rig/--color/--depth files, Python says the
# frame came from arrays) and "summary"."timings_ms" is each run's own stage timings.
PROVENANCE_FIELDS = ("inputs",)
TIMING_FIELDS = ("timings_ms",)


@pytest.fixture(scope="module")
def frame(fused):
    rig = kfuse.Rig.load(KINECT / "rig.json")
    return kfuse.fuse(rig, fused["color"], fused["depth_mm"])


def bits(a):
    return a.view(np.uint32)


def test_fuse_arrays_equal_the_cli_files(fused, frame):
    out = fused["out"]
    for name in ("zbuffer", "nearest", "linear", "filled"):
        mine, cli = getattr(frame, name), kfuse.read_depth(out / f"depth_{name}.exr")
        assert mine.shape == (1080, 1920) and mine.dtype == np.float32, name
        assert np.array_equal(np.isnan(mine), np.isnan(cli)), name
        assert np.array_equal(bits(mine)[~np.isnan(mine)], bits(cli)[~np.isnan(cli)]), name
    assert np.count_nonzero(~np.isnan(frame.zbuffer)) > 100_000
    assert np.array_equal(frame.hole_mask, np.asarray(Image.open(out / "hole_mask.png")) > 0)
    assert np.array_equal(frame.color_on_depth,
                          np.asarray(Image.open(out / "color_on_depth.png").convert("RGB")))
    assert frame.color_on_depth_valid.shape == (424, 512) and frame.color_on_depth_valid.any()

    v = read_ply(out / "cloud.ply")["vertex"]
    points, colors = frame.cloud
    assert np.array_equal(bits(points), bits(np.stack([v["x"], v["y"], v["z"]], axis=1)))
    assert np.array_equal(colors, np.stack([v["red"], v["green"], v["blue"]], axis=1))

    for name in ("mesh", "mesh_clean"):
        ply = read_ply(out / f"{name}.ply")
        vertices, faces, uvs = getattr(frame, name)
        pv = ply["vertex"]
        assert np.array_equal(bits(vertices), bits(np.stack([pv["x"], pv["y"], pv["z"]], axis=1)))
        assert np.array_equal(bits(uvs), bits(np.stack([pv["s"], pv["t"]], axis=1)))
        assert faces.dtype == np.uint32 and faces.shape[1] == 3
        assert np.array_equal(faces, ply["face"]["vertex_indices"].astype(np.uint32))
        assert len(faces) > 300_000, name
    assert len(frame.mesh_clean[1]) < len(frame.mesh[1])

    cli_summary = json.loads((out / "summary.json").read_text())["summary"]
    mine = frame.summary
    for k in TIMING_FIELDS:
        assert mine.pop(k) is not None and cli_summary.pop(k) is not None
    assert mine == cli_summary


def test_save_writes_the_cli_files_byte_for_byte(fused, frame, tmp_path):
    out = fused["out"]
    saved = frame.save(tmp_path / "py")
    assert saved == tmp_path / "py"
    cli_names = sorted(p.name for p in out.iterdir())
    assert sorted(p.name for p in saved.iterdir()) == cli_names
    assert len(cli_names) >= 20
    for name in cli_names:
        if name == "summary.json":
            continue
        assert (saved / name).read_bytes() == (out / name).read_bytes(), name
    mine, cli = (json.loads((d / "summary.json").read_text()) for d in (saved, out))
    for k in PROVENANCE_FIELDS:
        assert mine.pop(k) != cli.pop(k)
    for k in TIMING_FIELDS:
        mine["summary"].pop(k)
        cli["summary"].pop(k)
    assert mine == cli
    # The rest of the text is laid out as the CLI lays it out (same serialiser).
    assert list(mine) == list(cli)


def test_save_refuses_an_existing_folder_unless_overwrite(frame, tmp_path):
    dest = tmp_path / "again"
    frame.save(dest)
    (dest / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        frame.save(dest)
    frame.save(dest, overwrite=True)
    # The user's file stays, as with `kfuse fuse --out` into a used folder.
    assert (dest / "notes.txt").read_text() == "mine"
    assert (dest / "cloud.ply").is_file()


def test_fuse_nearest_only_has_no_linear(fused):
    rig = kfuse.Rig.load(KINECT / "rig.json")
    f = kfuse.fuse(rig, fused["color"], fused["depth_mm"], linear=False)
    assert f.linear is None
    assert f.summary["points"] == np.count_nonzero(fused["depth_mm"])


@pytest.mark.parametrize("arg", ["color", "depth"])
def test_fuse_rejects_wrong_arrays(fused, arg):
    rig = kfuse.Rig.load(KINECT / "rig.json")
    args = {"color": fused["color"], "depth": fused["depth_mm"]}
    args[arg] = args[arg].astype(np.float64)
    with pytest.raises(ValueError, match=f"^{arg}: expected a C-contiguous"):
        kfuse.fuse(rig, args["color"], args["depth"])


def test_depth_range_keeps_exactly_the_samples_inside(fused):
    """depth_range= is `kfuse fuse --depth-range`: the samples outside are not samples. The
    kept samples are counted here from the millimetre image itself (ends half a millimetre off
    the integer values, so no sample sits on an end), against the fusion's count and cloud."""
    rig = kfuse.Rig.load(KINECT / "rig.json")
    d = fused["depth_mm"]
    inside = int(np.count_nonzero((d >= 801) & (d <= 1500)))
    outside = int(np.count_nonzero(d > 0)) - inside
    assert inside > 10_000 and outside > 10_000, (inside, outside)
    for arg in ((0.8005, 1.5005), "800.5mm..1500.5mm", "0.8005..1.5005m"):
        f = kfuse.fuse(rig, fused["color"], d, linear=False, depth_range=arg)
        assert f.summary["valid_depth_pixels"] == inside, arg
        points, _ = f.cloud
        assert points.shape[0] <= inside
        assert points[:, 2].min() >= 0.8005 - 1e-6 and points[:, 2].max() <= 1.5005 + 1e-6, arg
    whole = kfuse.fuse(rig, fused["color"], d, linear=False)
    assert whole.summary["valid_depth_pixels"] == inside + outside
    for bad in ("0.8..1.5", "2m..1m", (1.5, 0.8), 3):
        with pytest.raises(ValueError, match="depth_range"):
            kfuse.fuse(rig, fused["color"], d, depth_range=bad)
