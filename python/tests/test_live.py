"""`kfuse serve` (issue 49) heard by an independent client: the `eclipse-zenoh` package
subscribes to a served simulated sensor and `rosbags` deserialises its messages (its Jazzy
typestore: the CDR reader and the RIHS01 type hashes are rosbags' own, nothing of kfuse's).

Checked: every key is rmw_zenoh's (`<domain>/<topic>/<pkg>::msg::dds_::<Type>_/<rosbags'
RIHS01 hash>`); the types; the values against what `kfuse capture scene` of the same simulated
sensor wrote (the ring's scene is static: every frame is the same frame) and against the rig it
wrote (`true_rig.json`); the header stamps against the status message's host times and the
clock; rmw_zenoh's attachment; the latched CameraInfo answered to a Zenoh query.

Without `eclipse-zenoh` or `rosbags` it skips, or fails where KFUSE_REQUIRE_ZENOH=1 (.ci/run
installs both and sets it)."""

import json
import os
import socket
import struct
import subprocess
import threading
import time

import numpy as np
import pytest
from PIL import Image

from conftest import kfuse_binary

SENSORS = 3
INDEX = 1  # the ring's second sensor: not the rig's reference
SERIAL = "000000000002"
NS = f"kinect2/sn_{SERIAL}"
DOMAIN = 0
# How long to wait for every topic (a sensor starts in a few seconds; a loaded machine).
WAIT_S = 60.0


def need(module):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as e:
        if os.environ.get("KFUSE_REQUIRE_ZENOH") == "1":
            pytest.fail(f"KFUSE_REQUIRE_ZENOH=1 but {module} does not import ({e}): "
                        "pip install eclipse-zenoh rosbags")
        pytest.skip(f"{module} not importable here ({e})")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    zenoh = need("zenoh")
    typesys = need("rosbags.typesys")
    tmp = tmp_path_factory.mktemp("live")
    cap = tmp / "cap"
    subprocess.run([str(kfuse_binary()), "capture", "scene", "--backend", "sim", "--sim-sensors",
                    str(SENSORS), "--device", "all", "--interval", "0", "--out", str(cap)],
                   check=True, capture_output=True)
    port = free_port()
    err = open(tmp / "serve.stderr", "wb")
    proc = subprocess.Popen(
        [str(kfuse_binary()), "serve", "--backend", "sim", "--sim-sensors", str(SENSORS),
         "--device", SERIAL, "--listen", f"tcp/127.0.0.1:{port}", "--no-multicast"],
        stdout=subprocess.DEVNULL, stderr=err)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    got = {}
    lock = threading.Lock()

    def take(sample):
        key = str(sample.key_expr)
        att = sample.attachment.to_bytes() if sample.attachment is not None else None
        with lock:
            got.setdefault(key, []).append((sample.payload.to_bytes(), att, time.time_ns()))
            del got[key][:-8]  # the newest few per key

    # The session connects before the serve listens: Zenoh retries the endpoint.
    session = zenoh.open(conf)
    subs = [session.declare_subscriber(f"{DOMAIN}/{NS}/**", take),
            session.declare_subscriber(f"{DOMAIN}/tf_static/**", take)]
    ts = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    yield {"zenoh": zenoh, "session": session, "got": got, "lock": lock, "ts": ts, "cap": cap,
           "proc": proc, "stderr": tmp / "serve.stderr"}
    for s in subs:
        s.undeclare()
    session.close()
    proc.terminate()
    proc.wait(timeout=30)
    err.close()


def key(ts, topic, msgtype):
    pkg, _, name = msgtype.split("/")
    return f"{DOMAIN}/{topic}/{pkg}::msg::dds_::{name}_/{ts.hash_rihs01(msgtype)}"


TOPICS = {
    "sd/image_depth": "sensor_msgs/msg/Image",
    "sd/image_ir": "sensor_msgs/msg/Image",
    "hd/image_color/compressed": "sensor_msgs/msg/CompressedImage",
    "sd/camera_info": "sensor_msgs/msg/CameraInfo",
    "hd/camera_info": "sensor_msgs/msg/CameraInfo",
}


def wait_all(s):
    """Every topic's messages, once each has a few (the newest per key)."""
    ts = s["ts"]
    keys = [key(ts, f"{NS}/{t}", m) for t, m in TOPICS.items()]
    keys += [key(ts, "tf_static", "tf2_msgs/msg/TFMessage"), f"{DOMAIN}/{NS}/kfuse/status"]
    deadline = time.time() + WAIT_S
    while time.time() < deadline:
        with s["lock"]:
            if all(len(s["got"].get(k, [])) >= 3 for k in keys[:-2]) and all(
                    s["got"].get(k) for k in keys[-2:]):
                return {k: list(s["got"][k]) for k in keys}, keys
        assert s["proc"].poll() is None, s["stderr"].read_text()
        time.sleep(0.1)
    with s["lock"]:
        pytest.fail(f"not every key arrived within {WAIT_S} s: got {sorted(s['got'])}; "
                    f"serve: {s['stderr'].read_text()}")


def stamp_ns(h):
    return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


def test_keys_types_and_values(served):
    ts = served["ts"]
    got, keys = wait_all(served)
    unexpected = [k for k in served["got"] if k not in keys]
    assert not unexpected, f"keys that are no rmw_zenoh topic key of kfuse's: {unexpected}"
    cap = served["cap"]
    msgs = {t: [ts.deserialize_cdr(p, m) for p, _, _ in got[key(ts, f"{NS}/{t}", m)]]
            for t, m in TOPICS.items()}
    png = np.asarray(Image.open(cap / SERIAL / "scene_depth.png")).astype(np.uint16)
    for d in msgs["sd/image_depth"]:
        assert (d.encoding, d.height, d.width, d.step, d.is_bigendian) == ("16UC1", 424, 512, 1024, 0)
        assert d.header.frame_id == f"kinect2_{SERIAL}_ir_optical_frame"
        depth = np.frombuffer(bytes(d.data), dtype="<u2").reshape(424, 512)
        assert np.array_equal(depth, png), "the depth differs from the capture's PNG"
    for ir in msgs["sd/image_ir"]:
        assert (ir.encoding, ir.height, ir.width) == ("16UC1", 424, 512)
        assert np.count_nonzero(np.frombuffer(bytes(ir.data), dtype="<u2")) > 100_000
    jpeg = (cap / SERIAL / "scene_color.jpg").read_bytes()
    for c in msgs["hd/image_color/compressed"]:
        assert c.format == "jpeg"
        assert c.header.frame_id == f"kinect2_{SERIAL}_rgb_optical_frame"
        assert bytes(c.data) == jpeg, "the JPEG differs from the capture's"
    rig = json.loads((cap / "true_rig.json").read_text())
    cams = {c["name"]: c for c in rig["cameras"]}
    for topic, cam, size in [("sd/camera_info", f"{SERIAL}.depth", (512, 424)),
                             ("hd/camera_info", f"{SERIAL}.color", (1920, 1080))]:
        c = cams[cam]
        want_k = [c["fx"], 0.0, c["cx"], 0.0, c["fy"], c["cy"], 0.0, 0.0, 1.0]
        for m in msgs[topic]:
            assert (m.width, m.height) == size
            assert m.distortion_model == "plumb_bob"
            assert np.allclose(m.k, want_k, rtol=0, atol=1e-9), (topic, m.k, want_k)
            want_d = [c.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")]
            assert np.allclose(m.d, want_d, rtol=0, atol=1e-12), (topic, m.d, want_d)
    tf = ts.deserialize_cdr(got[key(ts, "tf_static", "tf2_msgs/msg/TFMessage")][-1][0],
                            "tf2_msgs/msg/TFMessage")
    frames = {(t.header.frame_id, t.child_frame_id): t.transform for t in tf.transforms}
    colour = frames[(f"kinect2_{SERIAL}_rgb_optical_frame", f"kinect2_{SERIAL}_ir_optical_frame")]
    # The simulated Kinect's colour camera sits ~52 mm beside the depth camera (scene orientation).
    t = colour.translation
    assert 0.04 < abs(t.x) < 0.065 and abs(t.y) < 0.01 and abs(t.z) < 0.01, t
    # Not the reference sensor: its depth camera's pose in the reference sensor's frame too.
    ring = frames[("kinect2_000000000001_ir_optical_frame", f"kinect2_{SERIAL}_ir_optical_frame")]
    q = ring.rotation
    assert abs(q.x**2 + q.y**2 + q.z**2 + q.w**2 - 1) < 1e-9


def test_stamps_status_and_attachments(served):
    ts = served["ts"]
    got, _ = wait_all(served)
    depth_key = key(ts, f"{NS}/sd/image_depth", "sensor_msgs/msg/Image")
    status = [json.loads(p) for p, _, _ in got[f"{DOMAIN}/{NS}/kfuse/status"]]
    for s in status:
        assert s["format"] == "kfuse-live-status" and s["serial"] == SERIAL
        assert s["frame_bytes"] > 2 * 424 * 1024
    stamps = {}
    seqs = []
    for payload, att, received_ns in got[depth_key]:
        d = ts.deserialize_cdr(payload, "sensor_msgs/msg/Image")
        t = stamp_ns(d.header)
        # The host arrival time on the serving side: before it reached us, and recent.
        assert t <= received_ns and received_ns - t < 5_000_000_000, (t, received_ns)
        stamps[t] = d
        # rmw_zenoh's attachment: int64 sequence number, int64 source time, GID of 16.
        assert att is not None and len(att) == 33 and att[16] == 16
        seq, source_ns = struct.unpack("<qq", att[:16])
        assert source_ns >= t
        seqs.append(seq)
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    # The status of a frame names its depth stamp, and a sensor timestamp of its own clock.
    with served["lock"]:
        recent = [json.loads(p) for p, _, _ in served["got"][f"{DOMAIN}/{NS}/kfuse/status"]]
    matched = [s for s in recent if s["depth_host_ns"] in stamps]
    assert matched, (sorted(stamps), [s["depth_host_ns"] for s in recent])
    for s in matched:
        assert isinstance(s["depth_time_ticks"], int)
    # Camera infos carry the depth frame's stamp.
    info = [ts.deserialize_cdr(p, "sensor_msgs/msg/CameraInfo")
            for p, _, _ in got[key(ts, f"{NS}/sd/camera_info", "sensor_msgs/msg/CameraInfo")]]
    assert any(stamp_ns(i.header) in stamps for i in info)


def test_latched_camera_info_answers_a_query(served):
    ts = served["ts"]
    wait_all(served)
    k = key(ts, f"{NS}/hd/camera_info", "sensor_msgs/msg/CameraInfo")
    replies = list(served["session"].get(k, timeout=10.0))
    ok = [r.ok for r in replies if r.ok is not None]
    assert ok, replies
    m = ts.deserialize_cdr(ok[0].payload.to_bytes(), "sensor_msgs/msg/CameraInfo")
    assert (m.width, m.height) == (1920, 1080)
