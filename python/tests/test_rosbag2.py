"""`kfuse fuse --recording --layout rosbag2 --points` (issue 48) read back by independent
readers: the bag of a simulated recording against the kfuse layout of the same recording
(index.json, the depth PNGs, the colour JPEGs, the PLY clouds), the rig it was fused with,
kfuse.Recording's decoder depth, and the host clock around `kfuse capture record` (stamps are
Unix time: the recording's last frame at its file's modification time).

Readers: `rosbags` (rosbag2 folder reader and its Humble and Jazzy typestores) and `mcap` with
`mcap_ros2.decoder`; neither shares code with kfuse. Missing readers skip, or fail where
KFUSE_REQUIRE_ROSBAGS=1 (.ci/run installs them and sets it)."""

import json
import os
import re
import subprocess
import time
from collections import Counter

import numpy as np
import pytest
from PIL import Image

import kfuse
from conftest import kfuse_binary

# A short recording: every message of every frame is read and re-serialised twice.
FRAMES = 6
# Depth packets lost by the simulated sensor (as test_recording.py): a lost frame must leave
# no message behind.
ISO_DROP = 0.003
# A tick of the sensor's clock in nanoseconds (0.125 ms).
NS_PER_TICK = 125_000
# Geometry compared at 1e-9: the bag's float64 values are the rig's, through a quaternion
# (tf) or a rectification product (camera_info), a few roundings of 1e-16 each.
TOL = 1e-9

TYPES = {
    "sd/image_depth": "sensor_msgs/msg/Image",
    "sd/image_ir": "sensor_msgs/msg/Image",
    "hd/image_depth_rect": "sensor_msgs/msg/Image",
    "hd/image_color/compressed": "sensor_msgs/msg/CompressedImage",
    "sd/camera_info": "sensor_msgs/msg/CameraInfo",
    "hd/camera_info": "sensor_msgs/msg/CameraInfo",
    "sd/points": "sensor_msgs/msg/PointCloud2",
}


def need(module):
    """The module, or a visible skip; a failure where KFUSE_REQUIRE_ROSBAGS=1."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as e:
        if os.environ.get("KFUSE_REQUIRE_ROSBAGS") == "1":
            pytest.fail(f"KFUSE_REQUIRE_ROSBAGS=1 but {module} does not import ({e}): "
                        "pip install rosbags mcap mcap-ros2-support")
        pytest.skip(f"{module} not importable here ({e})")


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bag")
    rec = tmp / "s.kfrec"
    run = lambda *a: subprocess.run([str(kfuse_binary()), *map(str, a)], check=True,
                                    capture_output=True)
    before = time.time_ns()
    run("capture", "record", "--backend", "sim", "--frames", FRAMES, "--sim-iso-drop", ISO_DROP,
        "--output", rec)
    after = time.time_ns()
    run("fuse", "--recording", rec, "--engine", "cpu", "--layout", "rosbag2", "--points",
        "--out", tmp / "bag")
    run("fuse", "--recording", rec, "--engine", "cpu", "--write", "color,cloud", "--out", tmp / "seq")
    ix = json.loads((tmp / "seq" / "index.json").read_text())
    ns = "/kinect2/sn_" + re.sub(r"[^A-Za-z0-9_]", "_", kfuse.Recording(rec).info["serial"])
    return {"rec": rec, "bag": tmp / "bag", "seq": tmp / "seq", "ix": ix, "ns": ns,
            "rig": kfuse.Rig.load(tmp / "seq" / "kinect_params.json"),
            "recorded": (before, after)}


def host_ns(bag, ticks):
    """A sensor time in host time by the layout's rule: the last frame at the recording file's
    modification time, the others by the sensor's spacing."""
    last = bag["ix"]["frames"][-1]["depth_time_ticks"]
    return os.stat(bag["rec"]).st_mtime_ns + (ticks - last) * NS_PER_TICK


@pytest.fixture(scope="module")
def messages(bag):
    """Every message through rosbags: (topic, type, log time ns, raw CDR bytes), bag order."""
    rosbag2 = need("rosbags.rosbag2")
    with rosbag2.Reader(bag["bag"]) as r:
        return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in r.messages()]


def typestores():
    typesys = need("rosbags.typesys")
    return [typesys.get_typestore(s) for s in (typesys.Stores.ROS2_HUMBLE, typesys.Stores.ROS2_JAZZY)]


def decoded(bag, messages, rel):
    ts = typestores()[0]
    topic = rel if rel.startswith("/") else f"{bag['ns']}/{rel}"
    return [(t, ts.deserialize_cdr(raw, ty)) for top, ty, t, raw in messages if top == topic]


def test_folder_metadata_topics_counts_and_qos(bag, messages):
    rosbag2 = need("rosbags.rosbag2")
    meta = (bag["bag"] / "metadata.yaml").read_text()
    assert re.search(r"^  version: 5$", meta, re.M), meta[:200]
    assert (bag["bag"] / "bag_0.mcap").is_file()
    frames = bag["ix"]["frames"]
    assert len(frames) >= FRAMES - 2 and bag["ix"]["missing"], "no lost frame: raise ISO_DROP"
    colors = {f["color"]["sequence"] for f in frames if f["color"]}
    want = {f"{bag['ns']}/{rel}": ty for rel, ty in TYPES.items()}
    want["/tf_static"] = "tf2_msgs/msg/TFMessage"
    with rosbag2.Reader(bag["bag"]) as r:
        assert {c.topic: c.msgtype for c in r.connections} == want
        qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
        metacount = {c.topic: c.msgcount for c in r.connections}
    counts = Counter(top for top, *_ in messages)
    for rel in TYPES:
        n = len(colors) if rel.startswith("hd/image_color") else len(frames)
        assert counts[f"{bag['ns']}/{rel}"] == n, rel
    assert counts["/tf_static"] == 1
    assert metacount == dict(counts)
    interfaces = need("rosbags.interfaces")
    for topic, q in qos.items():
        assert len(q) == 1 and q[0].reliability == interfaces.QosReliability.RELIABLE
        latched = interfaces.QosDurability.TRANSIENT_LOCAL
        assert (q[0].durability == latched) == (topic == "/tf_static"), topic


def test_timestamps_are_the_kfuse_index_times_in_host_time(bag, messages):
    frames = bag["ix"]["frames"]
    depth_ns = [host_ns(bag, f["depth_time_ticks"]) for f in frames]
    color_ns = []
    for f in frames:
        if f["color"] and (not color_ns or color_ns[-1] != host_ns(bag, f["color"]["time_ticks"])):
            color_ns.append(host_ns(bag, f["color"]["time_ticks"]))
    # Host time: every frame was received while `kfuse capture record` ran (tolerance: none,
    # the run's own start and end bound it).
    before, after = bag["recorded"]
    assert all(before <= t <= after for t in depth_ns + color_ns), (before, depth_ns, after)
    for rel in TYPES:
        got = decoded(bag, messages, rel)
        want = color_ns if rel.startswith("hd/image_color") else depth_ns
        assert [t for t, _ in got] == want, rel
        stamps = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for _, m in got]
        assert stamps == want, rel
    (t, tf), = decoded(bag, messages, "/tf_static")
    assert t == depth_ns[0]


def test_depth_equals_the_kfuse_layout_pngs_and_the_decoder(bag, messages):
    frames = bag["ix"]["frames"]
    rect = decoded(bag, messages, "hd/image_depth_rect")
    assert len(rect) == len(frames)
    for (_, m), f in zip(rect, frames):
        assert (m.encoding, m.is_bigendian, m.width, m.height, m.step) == ("16UC1", 0, 1920, 1080, 3840)
        png = np.asarray(Image.open(bag["seq"] / f["files"][0])).astype(np.uint16)
        got = np.frombuffer(bytes(m.data), "<u2").reshape(1080, 1920)
        assert np.array_equal(got, png), f["files"][0]
        assert np.count_nonzero(png) > 100_000
    # sd/image_depth: kfuse.Recording's decoder depth (float32 mm), rounded half up here.
    sd = decoded(bag, messages, "sd/image_depth")
    ir = decoded(bag, messages, "sd/image_ir")
    rec = list(kfuse.Recording(bag["rec"]))
    assert [r.number for r in rec] == [f["number"] for f in frames]
    for (_, m), (_, i), r in zip(sd, ir, rec):
        assert (m.encoding, m.width, m.height, m.step) == ("16UC1", 512, 424, 1024)
        d = r.depth.astype(np.float64)
        want = np.where(d > 0, np.clip(np.floor(d + 0.5), 1, 65535), 0).astype(np.uint16)
        got = np.frombuffer(bytes(m.data), "<u2").reshape(424, 512)
        assert np.array_equal(got, want)
        # IR: every pixel with a depth measurement had light back (the decoder drops depth
        # of pixels whose amplitude is too low).
        assert (i.encoding, i.width, i.height, i.step) == ("16UC1", 512, 424, 1024)
        amp = np.frombuffer(bytes(i.data), "<u2").reshape(424, 512)
        assert np.all(amp[got > 0] > 0) and amp.max() > 100


def test_jpeg_bytes_equal_the_kfuse_layout_jpegs(bag, messages):
    jpegs = [f for f in bag["ix"]["frames"] if f["color"]]
    seen, files = set(), []
    for f in jpegs:
        if f["color"]["sequence"] not in seen:
            seen.add(f["color"]["sequence"])
            files.append(next(n for n in f["files"] if n.startswith("color/")))
    got = decoded(bag, messages, "hd/image_color/compressed")
    assert len(got) == len(files) > 0
    for (_, m), name in zip(got, files):
        assert m.format == "jpeg"
        assert bytes(m.data) == (bag["seq"] / name).read_bytes(), name


def read_ply(path):
    """A binary little-endian PLY of float x y z (and uchar red green blue) as a numpy record
    array, read here, not by kfuse."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    head = raw[:end].decode()
    n = int(re.search(r"^element vertex (\d+)$", head, re.M).group(1))
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if "property uchar red" in head:
        fields += [("r", "u1"), ("g", "u1"), ("b", "u1")]
    return np.frombuffer(raw, np.dtype(fields), count=n, offset=end)


def test_points_equal_the_kfuse_layouts_ply_clouds(bag, messages):
    frames = bag["ix"]["frames"]
    clouds = decoded(bag, messages, "sd/points")
    assert len(clouds) == len(frames)
    point = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    for (_, m), f in zip(clouds, frames):
        assert [(x.name, x.offset, x.datatype, x.count) for x in m.fields] == [
            ("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("rgb", 12, 7, 1)]
        assert (m.height, m.point_step, m.is_bigendian, m.is_dense) == (1, 16, False, True)
        assert m.row_step == 16 * m.width and len(m.data) == m.row_step
        assert m.header.frame_id.endswith("_ir_optical_frame")
        ply = read_ply(bag["seq"] / next(n for n in f["files"] if n.startswith("cloud/")))
        got = np.frombuffer(bytes(m.data), point)
        assert len(got) == len(ply) > 100_000
        # The same float32s (tolerance 0: both are the one cloud kfuse computes per frame).
        for axis in "xyz":
            assert np.array_equal(got[axis], ply[axis]), axis
        assert np.all(np.isfinite(got["z"])) and got["z"].min() > 0
        # rgb: the float32 whose bits are 0x00RRGGBB (PCL's packing), black without colour.
        if "r" in ply.dtype.names:
            want = (ply["r"].astype(np.uint32) << 16) | (ply["g"].astype(np.uint32) << 8) | ply["b"]
            assert np.array_equal(got["rgb"], want)
            assert np.count_nonzero(want) > 100_000
        else:
            assert not f["color"] and not np.any(got["rgb"])


def test_camera_info_is_the_rig(bag, messages):
    rig = bag["rig"]
    sd = decoded(bag, messages, "sd/camera_info")
    hd = decoded(bag, messages, "hd/camera_info")
    assert len(sd) == len(hd) == len(bag["ix"]["frames"])
    (_, d), (_, c) = sd[0], hd[0]
    for m, cam in ((d, rig.depth), (c, rig.color)):
        assert (m.width, m.height, m.distortion_model) == (cam.width, cam.height, "plumb_bob")
        np.testing.assert_allclose(m.k.reshape(3, 3), cam.K, rtol=0, atol=TOL)
        np.testing.assert_allclose(m.d, cam.dist, rtol=0, atol=TOL)
        P = m.p.reshape(3, 4)
        np.testing.assert_allclose(P[:, :3], cam.K, rtol=0, atol=TOL)
        R = m.r.reshape(3, 3)
        np.testing.assert_allclose(R @ R.T, np.eye(3), rtol=0, atol=TOL)
    # ROS's stereo convention: t_i = K_i^-1 P_i[:, 3] in the first camera's rectified frame;
    # X_2 = R_2^T (R_1 X_1 - t_1 + t_2) must be the rig's X_color = R X_depth + T.
    t1 = np.linalg.solve(d.k.reshape(3, 3), d.p.reshape(3, 4)[:, 3])
    t2 = np.linalg.solve(c.k.reshape(3, 3), c.p.reshape(3, 4)[:, 3])
    R1, R2 = d.r.reshape(3, 3), c.r.reshape(3, 3)
    np.testing.assert_allclose(R2.T @ R1, rig.R, rtol=0, atol=TOL)
    np.testing.assert_allclose(R2.T @ (t2 - t1), np.ravel(rig.T), rtol=0, atol=TOL)
    assert np.linalg.norm(np.ravel(rig.T)) > 0.01, "a rig without baseline tests nothing"
    # Every message carries the same values.
    for lst in (sd, hd):
        assert all(np.array_equal(m.p, lst[0][1].p) for _, m in lst)


def test_tf_static_is_the_rigs_extrinsics(bag, messages):
    rig = bag["rig"]
    (_, tf), = decoded(bag, messages, "/tf_static")
    (t,) = tf.transforms
    assert t.header.frame_id.endswith("_rgb_optical_frame")
    assert t.child_frame_id.endswith("_ir_optical_frame")
    q = t.transform.rotation
    x, y, z, w = q.x, q.y, q.z, q.w
    assert abs(x * x + y * y + z * z + w * w - 1) < TOL
    R = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    np.testing.assert_allclose(R, rig.R, rtol=0, atol=TOL)
    v = t.transform.translation
    np.testing.assert_allclose([v.x, v.y, v.z], np.ravel(rig.T), rtol=0, atol=TOL)
    # The depth messages are in the child frame, the colour ones in the parent.
    (_, sd), *_ = decoded(bag, messages, "sd/image_depth")
    (_, hd), *_ = decoded(bag, messages, "hd/image_depth_rect")
    assert (sd.header.frame_id, hd.header.frame_id) == (t.child_frame_id, t.header.frame_id)


def test_cdr_bytes_are_what_rosbags_serialises_humble_and_jazzy(messages):
    assert messages
    for ts in typestores():
        for topic, ty, _, raw in messages:
            again = bytes(ts.serialize_cdr(ts.deserialize_cdr(raw, ty), ty))
            assert again == raw, (topic, len(again), len(raw))


def test_mcap_reader_schemas_summary_and_decoded_values(bag, messages):
    reader_mod = need("mcap.reader")
    ros2 = need("mcap_ros2.decoder")
    stores = typestores()
    with open(bag["bag"] / "bag_0.mcap", "rb") as fh:
        reader = reader_mod.make_reader(fh, decoder_factories=[ros2.DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes, "no summary / chunk index"
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert summary.statistics.message_count == len(messages)
        for schema in summary.schemas.values():
            assert schema.encoding == "ros2msg"
            for ts in stores:
                assert schema.data.decode() == ts.generate_msgdef(schema.name, ros_version=2)[0], schema.name
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr"
            assert "offered_qos_profiles" in ch.metadata
        got = Counter()
        rect_first = None
        for _, channel, message, msg in reader.iter_decoded_messages():
            got[channel.topic] += 1
            assert message.log_time == message.publish_time
            if rect_first is None and channel.topic.endswith("hd/image_depth_rect"):
                rect_first = np.frombuffer(bytes(msg.data), "<u2").reshape(msg.height, msg.width)
        assert got == Counter(top for top, *_ in messages)
        # Seeking through the index: messages from the last frame's time on only.
        last = host_ns(bag, bag["ix"]["frames"][-1]["depth_time_ticks"])
        tail = [m.log_time for _, _, m in reader.iter_messages(starting_at=last)]
        assert tail and min(tail) >= last and len(tail) < len(messages)
    png = np.asarray(Image.open(bag["seq"] / bag["ix"]["frames"][0]["files"][0])).astype(np.uint16)
    assert np.array_equal(rect_first, png)


def test_options_the_layout_cannot_take_are_one_clear_error(bag, tmp_path):
    out = tmp_path / "x"
    r = subprocess.run([str(kfuse_binary()), "fuse", "--recording", str(bag["rec"]), "--layout",
                        "rosbag2", "--write", "color", "--out", str(out)], capture_output=True, text=True)
    assert r.returncode != 0 and "drop --write" in r.stderr, r.stderr
    assert not out.exists()


def test_capture_record_format_rosbag2_writes_the_same_topics(tmp_path):
    """`kfuse capture record --format rosbag2`: the sensor straight into a bag (staged .kfrec,
    converted by the rosbag2 layout's writer), read with rosbags; nothing else left behind."""
    rosbag2 = need("rosbags.rosbag2")
    out = tmp_path / "live"
    before = time.time_ns()
    r = subprocess.run([str(kfuse_binary()), "capture", "record", "--backend", "sim", "--frames", "4",
                        "--format", "rosbag2", "--points", "--out", str(out)],
                       capture_output=True, text=True)
    after = time.time_ns()
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["live"], "staged recording left behind"
    assert {"metadata.yaml", "live_0.mcap"} <= {p.name for p in out.iterdir()}
    ts = typestores()[0]
    with rosbag2.Reader(out) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        ns = next(t for t in topics if t.endswith("/sd/image_depth")).rsplit("/sd/", 1)[0]
        want = {f"{ns}/{rel}": ty for rel, ty in TYPES.items()}
        want["/tf_static"] = "tf2_msgs/msg/TFMessage"
        assert topics == want
        got = [(c.topic, t, ts.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()]
    rect = [(t, m) for top, t, m in got if top == f"{ns}/hd/image_depth_rect"]
    assert 3 <= len(rect) <= 4
    for t, m in rect:
        assert t == m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        assert before <= t <= after, (before, t, after)
        assert np.count_nonzero(np.frombuffer(bytes(m.data), "<u2")) > 100_000
    counts = Counter(top for top, *_ in got)
    assert counts[f"{ns}/sd/points"] == counts[f"{ns}/sd/image_depth"] == len(rect)


def test_capture_record_format_rosbag2_bad_output_is_one_line(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    r = subprocess.run([str(kfuse_binary()), "capture", "record", "--backend", "sim", "--frames", "1",
                        "--format", "rosbag2", "--out", str(f)], capture_output=True, text=True)
    assert r.returncode != 0 and "is a file" in r.stderr and "folder" in r.stderr, r.stderr
    assert f.read_text() == "x"
    r = subprocess.run([str(kfuse_binary()), "capture", "record", "--backend", "sim", "--frames", "1",
                        "--points", "--out", str(tmp_path / "x.kfrec")], capture_output=True, text=True)
    assert r.returncode != 0 and "--format rosbag2" in r.stderr, r.stderr
    assert not (tmp_path / "x.kfrec").exists()
