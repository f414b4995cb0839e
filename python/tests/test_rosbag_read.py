"""kfuse reads bags another writer wrote (issue 48, item 3): a rosbag2 bag (MCAP storage)
written by `rosbags.rosbag2.Writer` with the Humble typestore, laid out as iai_kinect2
publishes (`/kinect2/sd/image_depth`, `/kinect2/hd/image_color/compressed`, each camera's
`camera_info` as a single camera: R = I, P = K [I | 0], the pose only in `/tf_static`, through
`kinect2_link`), its messages built from the simulated recording's arrays (kfuse.Recording's
decoder depth, the kfuse layout's JPEGs, the rig's numbers). `kfuse fuse --recording BAG` must
give the `.kfrec`'s registered depth PNGs, and `kfuse rig import BAG` the rig.

Missing readers skip, or fail where KFUSE_REQUIRE_ROSBAGS=1 (.ci/run installs them)."""

import json
import os
import subprocess

import numpy as np
import pytest
from PIL import Image

import kfuse
from conftest import kfuse_binary

FRAMES = 4
# A tick of the sensor's clock in nanoseconds (0.125 ms).
NS_PER_TICK = 125_000
# The rig read back from the bag: through a quaternion and a chain of two transforms, a few
# roundings of 1e-16 each.
TOL = 1e-9
# 16UC1 depth is the decoder's millimetres rounded: as crates/sequence/tests/bag_read.rs
# states, values equal on at least this share of the pixels with a sample in both…
MIN_EQUAL_SHARE = 0.999
# …off by more than 1 mm (occlusion edges) on at most this share…
MAX_EDGE_SHARE = 0.0005
# …and this share of the recording's samples may appear or vanish.
MAX_COVERAGE_CHANGE = 0.01
# A JPEG flipped losslessly (DCT domain) decodes to the mirrored original's pixels flipped
# within this many levels (the decoder's IDCT rounding; measured: 2, at 9 of 6.2 M samples)…
JPEG_FLIP_LEVELS = 2
# …at fewer than this share of the samples.
JPEG_FLIP_SHARE = 1e-4


def need(module):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as e:
        if os.environ.get("KFUSE_REQUIRE_ROSBAGS") == "1":
            pytest.fail(f"KFUSE_REQUIRE_ROSBAGS=1 but {module} does not import ({e})")
        pytest.skip(f"{module} not importable here ({e})")


def run(*a, check=True):
    return subprocess.run([str(kfuse_binary()), *map(str, a)], check=check, capture_output=True,
                          text=True)


def quaternion(R):
    """(x, y, z, w) of a rotation matrix (Shepperd's method)."""
    t = np.trace(R)
    if t > 0:
        s = 2 * np.sqrt(1 + t)
        return ((R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4)
    i = int(np.argmax(np.diag(R)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2 * np.sqrt(1 + R[i, i] - R[j, j] - R[k, k])
    q = np.zeros(4)
    q[i] = s / 4
    q[j] = (R[j, i] + R[i, j]) / s
    q[k] = (R[k, i] + R[i, k]) / s
    q[3] = (R[k, j] - R[j, k]) / s
    return tuple(q)


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("read")
    rec = tmp / "s.kfrec"
    run("capture", "record", "--backend", "sim", "--frames", FRAMES, "--output", rec)
    run("fuse", "--recording", rec, "--engine", "cpu", "--write", "color", "--out", tmp / "seq")
    ix = json.loads((tmp / "seq" / "index.json").read_text())
    rig = kfuse.Rig.load(tmp / "seq" / "kinect_params.json")
    frames = list(kfuse.Recording(rec))
    return {"tmp": tmp, "seq": tmp / "seq", "ix": ix, "rig": rig, "frames": frames}


def write_bag(source, path, depth_encoding, ros1=False, rgb8=False):
    """The recording as iai_kinect2 would publish it, written by rosbags: a rosbag2 folder
    (MCAP, Humble typestore), or with `ros1` a ROS 1 bag (`rosbags.rosbag1.Writer`, Noetic
    typestore, uncompressed chunks). With `rgb8` the colour is a raw `Image` on
    /kinect2/hd/image_color (the recording's decoded colour)."""
    rosbag2 = need("rosbags.rosbag2")
    rosbag1 = need("rosbags.rosbag1")
    typesys = need("rosbags.typesys")
    ts = typesys.get_typestore(typesys.Stores.ROS1_NOETIC if ros1 else typesys.Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in ts.types:
        # Noetic's store lacks tf2_msgs; its one-line definition, as ROS 1 ships it.
        ts.register(typesys.get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                               "tf2_msgs/msg/TFMessage"))
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    Header = T["std_msgs/msg/Header"]
    Img = T["sensor_msgs/msg/Image"]
    Comp = T["sensor_msgs/msg/CompressedImage"]
    Info = T["sensor_msgs/msg/CameraInfo"]
    Roi = T["sensor_msgs/msg/RegionOfInterest"]
    TF = T["tf2_msgs/msg/TFMessage"]
    TS = T["geometry_msgs/msg/TransformStamped"]
    Tr = T["geometry_msgs/msg/Transform"]
    V3 = T["geometry_msgs/msg/Vector3"]
    Q = T["geometry_msgs/msg/Quaternion"]
    rig = source["rig"]
    ir_frame, rgb_frame = "kinect2_ir_optical_frame", "kinect2_rgb_optical_frame"

    def header(ticks, frame):
        ns = ticks * NS_PER_TICK
        stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
        if ros1:
            return Header(seq=ticks % 2**32, stamp=stamp, frame_id=frame)
        return Header(stamp=stamp, frame_id=frame)

    def info(cam, ticks, frame):
        K = np.asarray(cam.K, dtype=np.float64)
        P = np.hstack([K, np.zeros((3, 1))])
        mats = {"d": np.asarray(cam.dist, dtype=np.float64).ravel(), "k": K.ravel(),
                "r": np.eye(3).ravel(), "p": P.ravel()}
        if ros1:  # ROS 1 names them D, K, R, P
            mats = {k.upper(): v for k, v in mats.items()}
        return Info(header=header(ticks, frame), height=cam.height, width=cam.width,
                    distortion_model="plumb_bob", binning_x=0, binning_y=0,
                    roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False), **mats)

    def transform(parent, child, R, t, ticks):
        x, y, z, w = quaternion(np.asarray(R))
        t = np.ravel(t)
        return TS(header=header(ticks, parent), child_frame_id=child,
                  transform=Tr(translation=V3(x=t[0], y=t[1], z=t[2]),
                               rotation=Q(x=x, y=y, z=z, w=w)))

    frames = source["frames"]
    first = frames[0].depth_time_ticks
    writer = (rosbag1.Writer(path) if ros1 else
              rosbag2.Writer(path, version=8, storage_plugin=rosbag2.StoragePlugin.MCAP))
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    with writer as w:
        c = {}
        for topic, typ in (("/tf_static", "tf2_msgs/msg/TFMessage"),
                           ("/kinect2/sd/camera_info", "sensor_msgs/msg/CameraInfo"),
                           ("/kinect2/hd/camera_info", "sensor_msgs/msg/CameraInfo"),
                           ("/kinect2/sd/image_depth", "sensor_msgs/msg/Image"),
                           ("/kinect2/hd/image_color", "sensor_msgs/msg/Image")
                           if rgb8 else
                           ("/kinect2/hd/image_color/compressed", "sensor_msgs/msg/CompressedImage")):
            c[topic] = w.add_connection(topic, typ, typestore=ts)

        def put(topic, msg, ticks):
            w.write(c[topic], ticks * NS_PER_TICK, serialize(msg, msg.__msgtype__))

        # iai_kinect2's tree: kinect2_link -> rgb optical (identity) -> ir optical
        # (X_rgb = R X_ir + T: the rig's color_from_depth).
        put("/tf_static", TF(transforms=[
            transform("kinect2_link", rgb_frame, np.eye(3), np.zeros(3), first),
            transform(rgb_frame, ir_frame, rig.R, rig.T, first),
        ]), first)
        for f in frames:
            t = f.depth_time_ticks
            put("/kinect2/sd/camera_info", info(rig.depth, t, ir_frame), t)
            put("/kinect2/hd/camera_info", info(rig.color, t, rgb_frame), t)
            mm = np.asarray(f.depth, dtype=np.float32)
            h, wd = mm.shape
            if depth_encoding == "16UC1":
                # Round half up, as a driver's 16-bit millimetres.
                data = np.floor(mm.astype(np.float64) + 0.5).clip(0, 65535).astype("<u2")
                step = wd * 2
            else:
                # Metres as kfuse's pipeline makes them: float32 mm × float32 1e-3.
                data = (mm * np.float32(1e-3)).astype("<f4")
                step = wd * 4
            put("/kinect2/sd/image_depth",
                Img(header=header(t, ir_frame), height=h, width=wd, encoding=depth_encoding,
                    is_bigendian=0, step=step, data=np.frombuffer(data.tobytes(), np.uint8)), t)
            if f.color_time_ticks is not None and rgb8:
                rgb = np.ascontiguousarray(f.color())
                ch, cw, _ = rgb.shape
                put("/kinect2/hd/image_color",
                    Img(header=header(f.color_time_ticks, rgb_frame), height=ch, width=cw,
                        encoding="rgb8", is_bigendian=0, step=cw * 3,
                        data=np.frombuffer(rgb.tobytes(), np.uint8)), f.color_time_ticks)
            elif f.color_time_ticks is not None:
                jpeg = (source["seq"] / "color" / f"{f.number:06d}.jpg").read_bytes()
                put("/kinect2/hd/image_color/compressed",
                    Comp(header=header(f.color_time_ticks, rgb_frame), format="jpeg",
                         data=np.frombuffer(jpeg, np.uint8)), f.color_time_ticks)
    return path


def depth_pngs(folder, ix):
    return [np.asarray(Image.open(folder / e["files"][0]), dtype=np.int64) for e in ix["frames"]]


@pytest.mark.parametrize("ros1", [False, True], ids=["rosbag2", "ros1"])
@pytest.mark.parametrize("encoding", ["32FC1", "16UC1"])
def test_a_rosbags_bag_fuses_to_the_recordings_registered_depth(source, encoding, ros1):
    name = f"{encoding}_{'ros1' if ros1 else 'rosbag2'}"
    bag = write_bag(source, source["tmp"] / (f"{name}.bag" if ros1 else name), encoding, ros1)
    out = source["tmp"] / f"fused_{name}"
    r = run("fuse", "--recording", bag, "--engine", "cpu", "--out", out, check=False)
    assert r.returncode == 0, r.stderr
    assert "camera_infos and /tf_static" in r.stderr, r.stderr
    ix = json.loads((out / "index.json").read_text())
    want = source["ix"]
    assert len(ix["frames"]) == len(want["frames"]) == len(source["frames"]) >= FRAMES - 1
    for a, b in zip(ix["frames"], want["frames"]):
        assert a["depth_time_ticks"] == b["depth_time_ticks"]
        assert (a.get("color") or {}).get("time_ticks") == (b.get("color") or {}).get("time_ticks")
    for x, y in zip(depth_pngs(out, ix), depth_pngs(source["seq"], want)):
        assert x.shape == y.shape == (1080, 1920)
        if encoding == "32FC1":
            # The same float32 metres as the recording's decoder gives: the same PNG.
            np.testing.assert_array_equal(x, y)
            continue
        both = (x > 0) & (y > 0)
        d = np.abs(x - y)[both]
        assert both.sum() > 100_000
        assert (d == 0).mean() >= MIN_EQUAL_SHARE
        assert (d > 1).mean() <= MAX_EDGE_SHARE
        assert ((x > 0) != (y > 0)).sum() / (y > 0).sum() <= MAX_COVERAGE_CHANGE


@pytest.mark.parametrize("ros1", [False, True], ids=["rosbag2", "ros1"])
def test_rig_import_of_a_rosbags_bag_is_the_rig(source, ros1):
    bag = write_bag(source, source["tmp"] / ("rig.bag" if ros1 else "bag_rig"), "16UC1", ros1)
    out = source["tmp"] / f"bag_rig_{ros1}.json"
    run("rig", "import", bag, "--out", out)
    got, rig = kfuse.Rig.load(out), source["rig"]
    for a, b in ((got.depth, rig.depth), (got.color, rig.color)):
        assert (a.width, a.height) == (b.width, b.height)
        np.testing.assert_allclose(a.K, b.K, rtol=0, atol=TOL)
        np.testing.assert_allclose(a.dist, b.dist, rtol=0, atol=TOL)
    np.testing.assert_allclose(got.R, rig.R, rtol=0, atol=TOL)
    np.testing.assert_allclose(np.ravel(got.T), np.ravel(rig.T), rtol=0, atol=TOL)
    assert np.linalg.norm(np.ravel(rig.T)) > 0.01, "a rig without baseline tests nothing"


def test_two_depth_topics_are_a_clear_error_listing_them(source, tmp_path):
    bag = write_bag(source, tmp_path / "bag", "16UC1")
    # A bare .mcap file with a second depth topic: rosbags writes into a new folder.
    rosbag2 = need("rosbags.rosbag2")
    typesys = need("rosbags.typesys")
    ts = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
    two = tmp_path / "two"
    with rosbag2.Reader(bag) as r, rosbag2.Writer(two, version=8,
                                                  storage_plugin=rosbag2.StoragePlugin.MCAP) as w:
        conns = {}
        for conn, t, raw in r.messages():
            for topic in ([conn.topic, "/kinect2/qhd/image_depth"]
                          if conn.topic.endswith("image_depth") else [conn.topic]):
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, conn.msgtype, typestore=ts)
                w.write(conns[topic], t, raw)
    out = tmp_path / "out"
    r = run("fuse", "--recording", two, "--engine", "cpu", "--out", out, check=False)
    assert r.returncode != 0
    line = r.stderr.strip().splitlines()[-1]
    assert "/kinect2/sd/image_depth" in line and "/kinect2/qhd/image_depth" in line, r.stderr
    assert "--depth-topic" in line, r.stderr
    assert not out.exists()
    r = run("fuse", "--recording", two, "--depth-topic", "/kinect2/sd/image_depth", "--engine",
            "cpu", "--out", out, check=False)
    assert r.returncode == 0, r.stderr


def test_a_compressed_ros1_bag_is_one_clear_line(source, tmp_path):
    rosbag1 = need("rosbags.rosbag1")
    bag = tmp_path / "bz2.bag"
    w = rosbag1.Writer(bag)
    w.set_compression(rosbag1.Writer.CompressionFormat.BZ2)
    with w:
        conn = w.add_connection("/kinect2/sd/image_depth", "sensor_msgs/msg/Image",
                                typestore=need("rosbags.typesys").get_typestore(
                                    need("rosbags.typesys").Stores.ROS1_NOETIC))
        w.write(conn, 1, b"\0" * 40)
    out = tmp_path / "out"
    r = run("fuse", "--recording", bag, "--engine", "cpu", "--out", out, check=False)
    assert r.returncode != 0
    line = r.stderr.strip().splitlines()[-1]
    assert "bz2.bag" in line and "bz2" in line and "rosbag decompress" in line, r.stderr
    assert not out.exists()


def test_a_truncated_ros1_bag_is_one_clear_line(source, tmp_path):
    bag = write_bag(source, tmp_path / "full.bag", "16UC1", ros1=True)
    cut = tmp_path / "cut.bag"
    data = bag.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    out = tmp_path / "out"
    r = run("fuse", "--recording", cut, "--engine", "cpu", "--out", out, check=False)
    assert r.returncode != 0
    line = r.stderr.strip().splitlines()[-1]
    assert "cut.bag" in line and "truncated" in line, r.stderr
    assert not out.exists()


@pytest.mark.parametrize("ros1", [False, True], ids=["rosbag2", "ros1"])
def test_kfuse_recording_reads_a_bag_as_the_kfrec(source, ros1):
    bag = write_bag(source, source["tmp"] / ("py.bag" if ros1 else "py_bag"), "32FC1", ros1)
    r = kfuse.Recording(bag)
    assert r.info["depth_topic"] == "/kinect2/sd/image_depth"
    assert r.info["color_topic"] == "/kinect2/hd/image_color/compressed"
    got, want = list(r), source["frames"]
    assert len(got) == len(want) >= FRAMES - 1
    for a, b in zip(got, want):
        assert a.depth_time_ticks == b.depth_time_ticks
        assert a.color_time_ticks == b.color_time_ticks
        # float32 mm -> the bag's float32 metres -> mm: within float32 rounding.
        np.testing.assert_allclose(a.depth, b.depth, rtol=1e-6, atol=0)
        assert a.depth.shape == (424, 512)
        jpeg = (source["seq"] / "color" / f"{b.number:06d}.jpg").read_bytes()
        assert a.color_jpeg == jpeg
        # The bag's JPEG is the sensor's flipped in the DCT domain; decoding it and decoding the
        # mirrored original then flipping the pixels round the IDCT differently at a few pixels.
        d = np.abs(a.color().astype(int) - b.color().astype(int))
        assert d.max() <= JPEG_FLIP_LEVELS and (d > 0).mean() < JPEG_FLIP_SHARE
        with pytest.raises(ValueError, match="no raw frame"):
            a.raw_depth


def test_a_raw_rgb8_colour_topic_fuses_and_refuses_jpeg_outputs(source, tmp_path):
    bag = write_bag(source, tmp_path / "rgb", "32FC1", rgb8=True)
    out = tmp_path / "out"
    r = run("fuse", "--recording", bag, "--engine", "cpu", "--write", "color-on-depth", "--out",
            out, check=False)
    assert r.returncode == 0, r.stderr
    ix = json.loads((out / "index.json").read_text())
    assert all(e.get("color") for e in ix["frames"])
    for x, y in zip(depth_pngs(out, ix), depth_pngs(source["seq"], source["ix"])):
        np.testing.assert_array_equal(x, y)
    tum = tmp_path / "tum"
    r = run("fuse", "--recording", bag, "--engine", "cpu", "--layout", "tum", "--out", tum,
            check=False)
    assert r.returncode != 0
    line = r.stderr.strip().splitlines()[-1]
    assert "/kinect2/hd/image_color" in line and "raw sensor_msgs/Image" in line, r.stderr
    assert not tum.exists()
