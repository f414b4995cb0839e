"""kfuse.Device against `kfuse capture` on the simulated sensor (`--backend sim`, a static,
noise-free scene, so every frame is the same): a frame's depth and IR round to the CLI's
scene PNGs exactly, its colour is the sensor's JPEG unmirrored (checked with Pillow), the
serial is the one kinect_params.json records, a recording made from Python replays through
kfuse.Recording with the same depth, and no sensor is an OSError with the CLI's message."""

import json
import subprocess
import threading

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


def test_record_releases_the_gil(tmp_path):
    """While record() streams 30 frames, another Python thread runs: with the GIL held it
    would not run at all until record() returned."""
    ticks = 0
    stop = threading.Event()

    def count():
        nonlocal ticks
        while not stop.is_set():
            ticks += 1

    with kfuse.Device("sim") as dev:
        t = threading.Thread(target=count)
        t.start()
        try:
            dev.record(tmp_path / "g.kfrec", 30)
            during = ticks
        finally:
            stop.set()
            t.join()
    assert during > 1000, during


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
