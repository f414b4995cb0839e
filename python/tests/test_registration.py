"""kfuse.Registration against the CLI's own outputs, byte for byte, and its input checks."""

import numpy as np
import pytest
from PIL import Image

import kfuse
from conftest import KINECT


@pytest.fixture(scope="module")
def reg():
    return kfuse.Registration(kfuse.Rig.load(KINECT / "rig.json"))


def test_register_equals_fuse_zbuffer_bit_for_bit(fused, reg):
    z = reg.register(fused["depth_mm"])
    cli = kfuse.read_depth(fused["out"] / "depth_zbuffer.exr")
    assert z.dtype == np.float32 and z.shape == (1080, 1920)
    # Same NaN pattern and identical bits everywhere else (tolerance 0: the same z-buffer).
    assert np.array_equal(np.isnan(z), np.isnan(cli))
    assert np.array_equal(z.view(np.uint32)[~np.isnan(z)], cli.view(np.uint32)[~np.isnan(cli)])
    # Not vacuous: the desk frame covers a large part of the colour image.
    assert np.count_nonzero(~np.isnan(z)) > 100_000
    # The 16-bit PNG fuse writes is the same z-buffer rounded to mm (png16_value's rule).
    png = np.asarray(Image.open(fused["out"] / "depth_zbuffer.png")).astype(np.uint16)
    mm = np.where(np.isnan(z), 0, np.clip(np.floor(z.astype(np.float64) * 1e3 + 0.5), 1, 65535))
    assert np.array_equal(png, mm.astype(np.uint16))


def test_hole_mask_equals_fuse(fused, reg):
    reg.register(fused["depth_mm"])
    mask = reg.hole_mask()
    cli = np.asarray(Image.open(fused["out"] / "hole_mask.png")) > 0
    assert mask.dtype == np.bool_ and mask.shape == cli.shape
    assert np.array_equal(mask, cli)
    assert mask.any()


def test_color_on_depth_equals_fuse(fused, reg):
    reg.register(fused["depth_mm"])
    rgb, valid = reg.color_on_depth(fused["color"])
    cli = np.asarray(Image.open(fused["out"] / "color_on_depth.png").convert("RGB"))
    assert rgb.shape == (424, 512, 3) and valid.shape == (424, 512)
    assert np.array_equal(rgb, cli)
    assert valid.sum() > 50_000


def test_register_takes_float32_millimetres_as_the_decoder_gives_them(fused, reg):
    """float32 mm (kfuse.Decoder's and Recording's depth, converted as fuse --recording
    converts it) against the same integers in uint16 (converted as a 16-bit PNG): the two
    conversions differ by float32 rounding (one ulp, < 1e-6 m), so z agrees to 1e-6 m where
    both have a sample, and a rounding-level move flips the winner of at most
    FLIPPED_PIXELS_MAX of the ~184 000 z-buffer pixels (6 on this frame)."""
    FLIPPED_PIXELS_MAX = 50
    z16 = reg.register(fused["depth_mm"])
    z32 = reg.register(fused["depth_mm"].astype(np.float32))
    assert (np.isnan(z16) != np.isnan(z32)).sum() <= FLIPPED_PIXELS_MAX
    both = ~np.isnan(z16) & ~np.isnan(z32)
    assert both.sum() > 100_000 and np.abs(z16 - z32)[both].max() <= 1e-6
    with pytest.raises(ValueError, match=r"^depth: expected a C-contiguous float32 \(424, 512\)"):
        reg.register(np.zeros((512, 424), np.float32))


def test_register_calls_are_independent(fused, reg):
    """A second frame replaces the first: no state leaks between frames."""
    empty = np.zeros((424, 512), np.uint16)
    z_empty = reg.register(empty)
    assert np.isnan(z_empty).all()
    z = reg.register(fused["depth_mm"])
    assert np.count_nonzero(~np.isnan(z)) > 100_000


@pytest.mark.parametrize(
    "bad, what",
    [
        (np.zeros((424, 512), np.float64), "float64"),
        (np.zeros((424, 512), np.int32), "int32"),
        (np.zeros((512, 424), np.uint16), "(512, 424)"),
        (np.zeros((424, 512, 1), np.uint16), "(424, 512, 1)"),
        (np.zeros((424, 1024), np.uint16)[:, ::2], "not C-contiguous"),
        (np.asfortranarray(np.zeros((424, 512), np.uint16)), "not C-contiguous"),
        ([[0] * 512] * 424, "list"),
    ],
)
def test_register_rejects_wrong_arrays_with_value_error(reg, bad, what):
    with pytest.raises(ValueError) as e:
        reg.register(bad)
    msg = str(e.value)
    assert msg.startswith("depth: expected a C-contiguous uint16 (424, 512)"), msg
    assert what in msg, msg


@pytest.mark.parametrize(
    "bad, what",
    [
        (np.zeros((1080, 1920, 3), np.float32), "float32"),
        (np.zeros((1080, 1920), np.uint8), "(1080, 1920)"),
        (np.zeros((1080, 1920, 4), np.uint8), "(1080, 1920, 4)"),
        (np.zeros((1080, 3840, 3), np.uint8)[:, ::2], "not C-contiguous"),
    ],
)
def test_color_on_depth_rejects_wrong_arrays_with_value_error(fused, reg, bad, what):
    reg.register(fused["depth_mm"])
    with pytest.raises(ValueError) as e:
        reg.color_on_depth(bad)
    msg = str(e.value)
    assert msg.startswith("color: expected a C-contiguous uint8 (1080, 1920, 3)"), msg
    assert what in msg, msg


def test_hole_mask_before_register_is_a_value_error():
    fresh = kfuse.Registration(kfuse.Rig.load(KINECT / "rig.json"))
    with pytest.raises(ValueError, match="call register"):
        fresh.hole_mask()


def test_out_arrays_are_filled_in_place_with_the_same_result(fused, reg):
    """register(out=) / hole_mask(out=) write into the caller's arrays (no new array per frame)
    and give exactly what the allocating calls give; stale content is overwritten."""
    z = reg.register(fused["depth_mm"])
    mask = reg.hole_mask()
    z_out = np.full((1080, 1920), 7.0, np.float32)
    m_out = np.ones((1080, 1920), np.bool_)
    got = reg.register(fused["depth_mm"], out=z_out)
    assert got is z_out
    assert np.array_equal(z_out.view(np.uint32), z.view(np.uint32))
    got = reg.hole_mask(out=m_out)
    assert got is m_out and np.array_equal(m_out, mask)
    # The next frame replaces the whole array (an empty frame: NaN everywhere, no holes).
    reg.register(np.zeros((424, 512), np.uint16), out=z_out)
    assert np.isnan(z_out).all()


@pytest.mark.parametrize(
    "bad, what",
    [
        (np.zeros((1080, 1920), np.float64), "float64"),
        (np.zeros((1920, 1080), np.float32), "(1920, 1080)"),
        (np.zeros((1080, 3840), np.float32)[:, ::2], "not C-contiguous"),
    ],
)
def test_register_out_rejects_wrong_arrays_with_value_error(fused, reg, bad, what):
    with pytest.raises(ValueError) as e:
        reg.register(fused["depth_mm"], out=bad)
    msg = str(e.value)
    assert msg.startswith("out: expected a C-contiguous writable float32 (1080, 1920)"), msg
    assert what in msg, msg


def test_register_out_refuses_a_read_only_array(fused, reg):
    ro = np.zeros((1080, 1920), np.float32)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="read-only"):
        reg.register(fused["depth_mm"], out=ro)
    assert (ro == 0).all()
    m = np.zeros((1080, 1920), np.bool_)
    m.flags.writeable = False
    with pytest.raises(ValueError, match="read-only"):
        reg.hole_mask(out=m)


def test_depth_in_another_unit_is_refused_as_fuse_refuses_it(fused, reg):
    """kfuse fuse's unit rule (a median depth outside 0.2-15 m) for Python too: metres given
    as millimetres (even with flying pixels of 25 "mm", which fooled the earlier test of the
    largest sample) and a 65535 fill raise ValueError naming depth, the median and the fix;
    nothing is registered (the last frame stays); centimetres get fuse's Kinect warning.
    force=True registers them."""
    mm = fused["depth_mm"]
    metres = mm.astype(np.float32) / 1000.0
    metres.ravel()[::200] = 25.0  # flying pixels at 25 "mm"
    reg.register(mm)
    mask_before = reg.hole_mask()
    with pytest.raises(ValueError, match=r"^depth: median depth 0\.00288\d* m is under 0\.2 m.*pass depth \* 1000"):
        reg.register(metres)
    # Nothing registered: the last frame is still the millimetre one.
    assert np.array_equal(reg.hole_mask(), mask_before) and mask_before.any()
    # Centimetres: the desk's median 2.887 m reads 0.289 m, inside the 0.2-15 m band of every
    # depth camera but nearer than a Kinect measures: fuse's warning, as the CLI gives it.
    centimetres = (mm // 10).astype(np.uint16)
    with pytest.warns(UserWarning, match=r"^depth: median depth 0\.28\d* m is nearer than the Kinect v2 measures \(0\.5 m\): centimetres\?"):
        reg.register(centimetres)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        reg.register(mm)
    fill = np.full_like(mm, 65535)
    with pytest.raises(ValueError, match=r"median depth 65\.535 m is over 15 m.*65535 fill"):
        reg.register(fill)
    rig = kfuse.Rig.load(KINECT / "rig.json")
    with pytest.raises(ValueError, match="median depth 65.535 m"):
        kfuse.fuse(rig, fused["color"], fill)
    forced = kfuse.Registration(rig, force=True)
    assert np.isnan(forced.register(metres)).all()  # why the check matters: nothing lands
    # Forced, the fill fuses as the 65.5 m wall the check stood in front of.
    far = kfuse.fuse(rig, fused["color"], fill, force=True).zbuffer
    assert np.count_nonzero(~np.isnan(far)) > 100_000 and abs(np.nanmedian(far) - 65.535) < 0.1
