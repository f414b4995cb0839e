"""kfuse.Recording against `kfuse fuse --recording` on a recording of the simulated sensor
(`kfuse capture record --backend sim`, as tests/cli_sequence.rs makes one): the same frames,
numbers, sensor times, colour partners and lost frames as index.json, and depth that
registers to the CLI's depth/NNNNNN.png exactly."""

import io
import json
import subprocess

import numpy as np
import pytest
from PIL import Image

import kfuse
from conftest import kfuse_binary

# Depth packets lost by the simulated sensor: 0.3 % of ~90 packets per frame loses a
# sub-image in a few frames of 30, so the lost-frame list is not empty.
ISO_DROP = 0.003
FRAMES = 30


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rec")
    rec = tmp / "s.kfrec"
    subprocess.run([str(kfuse_binary()), "capture", "record", "--backend", "sim", "--frames",
                    str(FRAMES), "--sim-iso-drop", str(ISO_DROP), "--output", str(rec)],
                   check=True, capture_output=True)
    out = tmp / "seq"
    subprocess.run([str(kfuse_binary()), "fuse", "--recording", str(rec), "--out", str(out)],
                   check=True, capture_output=True)
    return rec, out, json.loads((out / "index.json").read_text())


def test_frames_times_and_lost_frames_equal_index_json(recorded):
    rec_path, _, ix = recorded
    rec = kfuse.Recording(rec_path)
    frames = list(rec)
    assert len(frames) == len(ix["frames"]) == FRAMES
    for f, e in zip(frames, ix["frames"]):
        assert f.number == e["number"]
        assert f.depth_sequence == e["depth_sequence"]
        assert f.depth_time_ticks == e["depth_time_ticks"]
        assert f"{f.depth_time:.6f}" == e["depth_time_s"]
        if e["color"] is None:
            assert f.color_jpeg is None and f.color_time_ticks is None
        else:
            assert f.color_time_ticks == e["color"]["time_ticks"]
            assert f.color_jpeg[:2] == b"\xff\xd8"
    assert rec.lost == ix["missing"]
    assert len(rec.lost) > 0, "the simulated losses made no gap: raise ISO_DROP"
    # Iteration is over; another next() stays at the end.
    assert next(iter(rec), None) is None


def test_depth_registers_to_the_cli_depth_pngs(recorded):
    _, out, ix = recorded
    reg = kfuse.Registration(kfuse.Rig.load(out / "kinect_params.json"))
    n = 0
    for f, e in zip(kfuse.Recording(recorded[0]), ix["frames"]):
        assert f.depth.dtype == np.float32 and f.depth.shape == (424, 512)
        z = reg.register(f.depth).astype(np.float64)
        # png16_value's rule (the CLI's writer): round half up to mm, 0 = no sample.
        mm = np.where(np.isnan(z), 0, np.clip(np.floor(z * 1e3 + 0.5), 1, 65535)).astype(np.uint16)
        png = np.asarray(Image.open(out / e["files"][0])).astype(np.uint16)
        assert np.array_equal(mm, png), e["files"][0]
        assert np.count_nonzero(png) > 100_000
        n += 1
    assert n == FRAMES


def test_color_is_the_sensor_jpeg_unmirrored(recorded):
    frame = next(iter(kfuse.Recording(recorded[0])))
    rgb = frame.color()
    assert rgb.shape == (1080, 1920, 3) and rgb.dtype == np.uint8
    # Pillow decodes the sensor's (mirrored) JPEG independently; flipped left-right it is
    # kfuse's image up to the IDCT's rounding (two decoders differ by a level or two).
    pil = np.asarray(Image.open(io.BytesIO(frame.color_jpeg)).convert("RGB"))[:, ::-1]
    diff = np.abs(pil.astype(int) - rgb.astype(int))
    assert diff.mean() < 0.5 and np.percentile(diff, 99.9) <= 3
    # Not vacuous: unflipped it is far off (the scene is not symmetric).
    assert np.abs(pil[:, ::-1].astype(int) - rgb.astype(int)).mean() > 5


def test_not_a_recording_is_one_clear_error(tmp_path):
    bogus = tmp_path / "x.kfrec"
    bogus.write_bytes(b"not a recording")
    with pytest.raises(ValueError, match="x.kfrec"):
        kfuse.Recording(bogus)
    with pytest.raises(OSError, match="missing.kfrec"):
        kfuse.Recording(tmp_path / "missing.kfrec")


def test_ctrl_c_between_frames_is_keyboard_interrupt_and_loses_nothing(recorded):
    """SIGINT while Recording reads (deterministic: the sender thread can only run while the
    main thread is inside kfuse with the GIL released, because the switch interval is made
    longer than the test): next() raises KeyboardInterrupt from kfuse's check between
    events, and iterating on yields every frame, none lost or repeated."""
    import os
    import signal
    import sys
    import threading
    import time

    rec = kfuse.Recording(recorded[0])
    old_interval, old_handler = sys.getswitchinterval(), signal.getsignal(signal.SIGINT)
    sent = threading.Event()

    def sender():
        time.sleep(0.001)  # gives the GIL back; it returns only when kfuse releases it
        os.kill(os.getpid(), signal.SIGINT)
        sent.set()

    signal.signal(signal.SIGINT, signal.default_int_handler)
    sys.setswitchinterval(100.0)
    try:
        t = threading.Thread(target=sender)
        t.start()
        with pytest.raises(KeyboardInterrupt):
            next(rec)
    finally:
        sys.setswitchinterval(old_interval)
        signal.signal(signal.SIGINT, old_handler)
    t.join()
    assert sent.is_set()
    numbers = [f.number for f in rec]
    assert numbers == [e["number"] for e in recorded[2]["frames"]]
