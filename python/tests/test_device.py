"""kfuse.Device against `kfuse capture` on the simulated sensor (`--backend sim`, a static,
noise-free scene, so every frame is the same): a frame's depth and IR round to the CLI's
scene PNGs exactly, its colour is the sensor's JPEG unmirrored (checked with Pillow), the
serial is the one kinect_params.json records, a recording made from Python replays through
kfuse.Recording with the same depth, and no sensor is an OSError with the CLI's message."""

import concurrent.futures
import gc
import json
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from PIL import Image

import kfuse
from conftest import kfuse_binary


def png16(values):
    """kfuse_io::images::png16_value: round half away from zero (Rust's f64::round, not
    NumPy's half-to-even: a float32 depth of 3078.5 mm is 3079), 1..=65535, non-positive/NaN
    -> 0."""
    v = np.asarray(values, dtype=np.float64)
    out = np.clip(np.floor(v + 0.5), 1, 65535)
    return np.where(np.isfinite(v) & (v > 0), out, 0).astype(np.uint16)


@pytest.fixture(scope="module")
def cli_scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene")
    subprocess.run([str(kfuse_binary()), "capture", "scene", "--backend", "sim", "--interval", "0",
                    "--out", str(out), "--name", "s"], check=True, capture_output=True)
    return out


@pytest.fixture(scope="module")
def frame():
    with kfuse.Device("sim") as dev:
        return dev.info, dev.next_frame()


def test_depth_and_ir_round_to_the_cli_scene_pngs(cli_scene, frame):
    _, f = frame
    assert f.depth.dtype == np.float32 and f.depth.shape == (424, 512)
    assert f.ir.dtype == np.float32 and f.ir.shape == (424, 512)
    cli_depth = np.asarray(Image.open(cli_scene / "s_depth.png"))
    cli_ir = np.asarray(Image.open(cli_scene / "s_ir.png"))
    assert (cli_depth > 0).sum() > 100_000, "the simulated scene has depth"
    np.testing.assert_array_equal(png16(f.depth), cli_depth)
    np.testing.assert_array_equal(png16(f.ir), cli_ir)


def test_color_is_the_sensor_jpeg_unmirrored(frame):
    _, f = frame
    c = f.color()
    assert c.dtype == np.uint8 and c.shape == (1080, 1920, 3)
    import io
    pil = np.asarray(Image.open(io.BytesIO(f.color_jpeg)).convert("RGB"))
    # Two JPEG decoders (Pillow's libjpeg, the image crate's) differ by rounding only: a
    # mean of at most 1 level; an unmirrored frame compared with a mirrored one differs by
    # tens of levels on this scene.
    diff = np.abs(c.astype(np.int16) - pil[:, ::-1].astype(np.int16))
    assert diff.mean() <= 1.0, diff.mean()
    assert np.abs(c.astype(np.int16) - pil.astype(np.int16)).mean() > 5.0


def test_serial_and_params_are_the_cli_ones(cli_scene, frame, tmp_path):
    info, _ = frame
    cli = json.loads((cli_scene / "kinect_params.json").read_text())
    assert info["serial"] == cli["serial"] and info["firmware"] == cli["firmware"]
    with kfuse.Device("sim") as dev:
        written = dev.write_params(tmp_path)
        assert json.loads(written.read_text()) == cli
        # An existing kinect_params.json (here the user's own text) is not replaced silently.
        written.write_text("my notes")
        with pytest.raises(FileExistsError, match="kinect_params.json: exists; pass overwrite=True"):
            dev.write_params(tmp_path)
        assert written.read_text() == "my notes"
        assert dev.write_params(tmp_path, overwrite=True) == written
    assert json.loads(written.read_text()) == cli
    rig = kfuse.Rig.from_kinect_params(written)
    assert rig.depth.width == 512 and rig.color.width == 1920


def test_a_python_recording_replays_with_the_same_depth(tmp_path, frame):
    _, f = frame
    path = tmp_path / "py.kfrec"
    with kfuse.Device("sim") as dev:
        done = dev.record(path, 5)
    assert done["frames"] == 5 and done["stopped_by"] is None
    frames = list(kfuse.Recording(path))
    assert len(frames) == 5
    for r in frames:
        np.testing.assert_array_equal(r.depth, f.depth)


# The interpreter's thread switch interval during the GIL test, seconds: longer than the test,
# so this thread never gives the GIL up on a timer (test_recording.py's rule). The counter
# thread can then run only where this thread blocks: inside record() if kfuse releases the GIL
# there, else only before and after the call. (With a short interval the GIL is passed on a
# timer at the call's edges: a record() holding the GIL still let the counter tick 75 068
# times during the call, measured, so no tick threshold separates the two reliably.)
GIL_SWITCH_INTERVAL_S = 100.0
# The counter's sleep between ticks, s: it gives the GIL back each time, so that record()
# takes it back at once for its Ctrl-C check per frame.
TICK_S = 0.0005
# Ticks the counter must make during record(): a record() holding the GIL left it at 0 or 1
# (measured, 8 runs: the one tick comes as the call returns), one releasing it lets it tick
# for most of the call (30 frames of the simulated sensor, 0.2 s or more: hundreds of ticks).
MIN_TICKS_DURING_RECORD = 10


def test_record_releases_the_gil(tmp_path):
    """While record() streams 30 frames, another Python thread runs. Only the ticks made
    while this thread is inside the call count (`in_call`), and this thread keeps the GIL
    except where it blocks (a switch interval longer than the test): with the GIL held in
    record() the count stays at 0 or 1."""
    ticks = 0
    in_call = False
    stop = threading.Event()

    def count():
        nonlocal ticks
        while not stop.is_set():
            if in_call:
                ticks += 1
            time.sleep(TICK_S)

    old_interval = sys.getswitchinterval()
    with kfuse.Device("sim") as dev:
        t = threading.Thread(target=count)
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
        try:
            t.start()
            in_call = True
            dev.record(tmp_path / "g.kfrec", 30)
            in_call = False
        finally:
            in_call = False
            stop.set()
            t.join()
            sys.setswitchinterval(old_interval)
    assert ticks >= MIN_TICKS_DURING_RECORD, ticks


def test_record_refuses_an_existing_file_unless_overwrite(tmp_path):
    """record() over an existing file (a text file, a PNG, an earlier recording) is a
    FileExistsError naming the path, as Rig.save and Calibration.save refuse, and the old
    file is left byte for byte (no temporary file is left beside it either); with
    overwrite=True it is replaced by a recording."""
    text = tmp_path / "notes.txt"
    text.write_bytes(b"my notes\n")
    png = tmp_path / "photo.png"
    Image.fromarray(np.arange(64, dtype=np.uint8).reshape(8, 8)).save(png)
    with kfuse.Device("sim") as dev:
        earlier = tmp_path / "earlier.kfrec"
        dev.record(earlier, 2)
        for path in (text, png, earlier):
            before = path.read_bytes()
            listing = sorted(tmp_path.iterdir())
            with pytest.raises(FileExistsError) as e:
                dev.record(path, 3)
            assert str(path) in str(e.value) and "overwrite=True" in str(e.value)
            assert path.read_bytes() == before
            assert sorted(tmp_path.iterdir()) == listing
        done = dev.record(text, 3, overwrite=True)
    assert done["frames"] == 3
    assert len(list(kfuse.Recording(text))) == 3
    with kfuse.Device("sim") as dev:
        with pytest.raises(ValueError, match="is a folder"):
            dev.record(tmp_path, 1, overwrite=True)


def _fds_open_on(path):
    """The file descriptors of this process open on `path` (Linux: /proc/self/fd)."""
    fd_dir = "/proc/self/fd"
    if not os.path.isdir(fd_dir):
        pytest.skip("no /proc/self/fd: cannot count open files here")
    found = []
    for fd in os.listdir(fd_dir):
        try:
            if os.readlink(os.path.join(fd_dir, fd)) == str(path):
                found.append(fd)
        except OSError:
            pass
    return found


def test_device_and_recording_work_from_another_thread_and_drop_there(tmp_path):
    """A Device and a Recording made in this thread are used from a ThreadPoolExecutor worker
    (the results equal this thread's), and the last reference dropped in the worker closes
    them: no PanicException, no unraisable error, the recording's file descriptor closed."""
    path = (tmp_path / "t.kfrec").resolve()
    unraisable = []
    old_hook = sys.unraisablehook
    sys.unraisablehook = unraisable.append
    try:
        with concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
            dev = kfuse.Device("sim")
            here = dev.next_frame().depth
            there = pool.submit(lambda: dev.next_frame().depth).result()
            np.testing.assert_array_equal(there, here)
            assert pool.submit(dev.record, path, 2).result()["frames"] == 2
            # The last reference, to a device still open, dropped in the worker.
            holder = [dev]
            del dev
            pool.submit(holder.clear).result()

            rec = kfuse.Recording(path)
            first = next(rec)
            rest = pool.submit(lambda: [f.number for f in rec]).result()
            assert [first.number] + rest == [f.number for f in kfuse.Recording(path)]
            assert len(rest) >= 1
            del rec
            gc.collect()
            # A recording dropped in the worker while its file is open (nothing read yet).
            holder = [kfuse.Recording(path)]
            assert len(_fds_open_on(path)) == 1, "the recording's file is not open once"
            pool.submit(holder.clear).result()
            gc.collect()
            assert _fds_open_on(path) == []
    finally:
        sys.unraisablehook = old_hook
    assert unraisable == [], [str(u.exc_value) for u in unraisable]


# How often the main thread looks whether another thread's record() holds the Device, s.
POLL_S = 0.005


def test_a_call_while_another_thread_records_is_a_runtime_error(tmp_path):
    """One call at a time: while a worker's record() of 30 frames (about a second at 30 Hz)
    holds the Device, a call from this thread is a RuntimeError naming the class and the rule
    (not a hang, not a panic), and the recording is not disturbed by it."""
    with kfuse.Device("sim") as dev, concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
        job = pool.submit(dev.record, tmp_path / "busy.kfrec", 30)
        refused = None
        while not job.done():
            try:
                dev.info
            except RuntimeError as e:
                refused = e
                break
            time.sleep(POLL_S)
        assert job.result()["frames"] == 30
        assert dev.info["serial"]  # usable again once the other call returned
    assert refused is not None, "the record() ended before this thread saw it running"
    msg = str(refused)
    assert "kfuse.Device" in msg and "another thread" in msg and "one call at a time" in msg, msg
    assert "\n" not in msg


def test_no_sensor_is_an_oserror_with_the_cli_message(tmp_path):
    cli = subprocess.run([str(kfuse_binary()), "capture", "scene", "--backend", "absent",
                          "--interval", "0", "--out", str(tmp_path / "x")],
                         capture_output=True, text=True)
    assert cli.returncode != 0
    errors = [line for line in cli.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, cli.stderr
    with pytest.raises(OSError) as e:
        kfuse.Device("absent")
    assert str(e.value) == errors[0][len("error: "):]
    assert not (tmp_path / "x").exists()


def test_bad_arguments_are_value_errors(tmp_path):
    with pytest.raises(ValueError, match="backend"):
        kfuse.Device("firewire")
    with kfuse.Device("sim") as dev:
        with pytest.raises(ValueError, match="timeout"):
            dev.next_frame(timeout=0)
        with pytest.raises(ValueError, match="frames"):
            dev.record(tmp_path / "n.kfrec", 0)
        assert not (tmp_path / "n.kfrec").exists()
    with pytest.raises(ValueError, match="closed"):
        dev.next_frame()


def test_a_simulated_ring_lists_and_opens_each_sensor_as_the_cli(tmp_path):
    """kfuse.devices and Device(sim_sensors=3, serial=...) against `kfuse devices` and
    `kfuse capture scene --device SERIAL` on the same ring: the same lines, and the second
    sensor's depth (another pose: not the first sensor's) rounds to the CLI's PNG exactly."""
    cli = subprocess.run([str(kfuse_binary()), "devices", "--backend", "sim", "--sim-sensors", "3"],
                         check=True, capture_output=True, text=True)
    listed = kfuse.devices("sim", sim_sensors=3)
    assert [d["line"] for d in listed] == cli.stdout.strip().splitlines()
    serials = [d["serial"] for d in listed]
    assert len(set(serials)) == 3, serials
    out = tmp_path / "ring"
    subprocess.run([str(kfuse_binary()), "capture", "scene", "--backend", "sim", "--sim-sensors", "3",
                    "--device", serials[1], "--interval", "0", "--out", str(out), "--name", "s"],
                   check=True, capture_output=True)
    [png] = list(out.rglob("s_depth.png"))
    with kfuse.Device("sim", serial=serials[1], sim_sensors=3) as dev:
        assert dev.info["serial"] == serials[1]
        second = dev.next_frame().depth
    with kfuse.Device("sim", sim_sensors=3) as dev:
        assert dev.info["serial"] == serials[0]
        first = dev.next_frame().depth
    np.testing.assert_array_equal(png16(second), np.asarray(Image.open(png)))
    assert np.abs(png16(second).astype(int) - png16(first).astype(int)).mean() > 10, "same pose"
    with pytest.raises(ValueError, match="sim_sensors"):
        kfuse.Device("sim", sim_sensors=9)
    with pytest.raises(OSError, match="no Kinect v2 with serial nope"):
        kfuse.Device("sim", serial="nope", sim_sensors=3)


def test_recording_into_a_missing_folder_is_a_file_not_found_error(tmp_path):
    """The CLI's record refuses a missing folder; from Python it is FileNotFoundError (an
    OSError with errno and the path), and nothing is created."""
    target = tmp_path / "no" / "such" / "rec.kfrec"
    with kfuse.Device("sim") as dev:
        with pytest.raises(FileNotFoundError) as e:
            dev.record(target, 2)
    assert str(e.value.filename) == str(target) and e.value.errno == 2
    assert not (tmp_path / "no").exists()


def test_an_unplugged_sensor_is_an_oserror_with_the_cli_message(tmp_path):
    """`kfuse capture record --sim-unplug-after 3` stops with one error line saying how many
    frames the file kept; Device(sim_unplug_after=3).record raises OSError with that message
    (for its own path), and both files replay with the 3 frames the sensor sent."""
    cli_path = tmp_path / "cli.kfrec"
    cli = subprocess.run([str(kfuse_binary()), "capture", "record", "--backend", "sim",
                          "--sim-unplug-after", "3", "--frames", "10", "--out", str(cli_path)],
                         capture_output=True, text=True)
    assert cli.returncode == 1, cli.stderr
    errors = [line for line in cli.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, cli.stderr
    py_path = tmp_path / "py.kfrec"
    with kfuse.Device("sim", sim_unplug_after=3) as dev:
        with pytest.raises(OSError) as e:
            dev.record(py_path, 10)
    expected = errors[0][len("error: "):].replace(str(cli_path), str(py_path))
    assert str(e.value) == expected
    assert "disappeared" in expected and "3 complete depth frames" in expected
    assert len(list(kfuse.Recording(str(cli_path)))) == 3
    assert len(list(kfuse.Recording(str(py_path)))) == 3


def test_next_frame_on_an_unplugged_sensor_is_an_oserror(tmp_path):
    with kfuse.Device("sim", sim_unplug_after=2) as dev:
        taken = 0
        with pytest.raises(OSError, match="disappeared"):
            for _ in range(10):
                dev.next_frame()
                taken += 1
        assert taken == 2
    with pytest.raises(ValueError, match="sim_unplug_after"):
        kfuse.Device("usb", sim_unplug_after=2)
