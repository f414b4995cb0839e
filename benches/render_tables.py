#!/usr/bin/env python3
"""Results and tables of `benches/run_all.sh` (Python standard library only: no venv needed).

Two sub-commands:

    render_tables.py collect --meta META --criterion DIR [--log DIR] [--peer NAME=FILE ...]
                             [--recorded FILE] --out RESULTS.json
    render_tables.py render RESULTS.json DOC.md [--out OTHER.md]

`collect` reads the run's facts (META: `key=value` lines written by run_all.sh), criterion's
`DIR/<package>/<bench>/**/new/{benchmark,estimates}.json` (run_all.sh gives every bench target
its own `CRITERION_HOME` there), the bench logs (`DIR/<package>/<bench>.log` under `--log`: the
GPU adapter, the decoder's kernels, the CPU-time probe lines, the PNG sizes), the peers' JSON
outputs and the logs of the steps that are not criterion benches (`step-NAME.log` under
`--log` for every `step.NAME=status` of META: detect_stages, sequence_e2e, viewer_frame_time,
parsed from the lines those programs print), and writes one results file.

`render` rewrites, in DOC, the text between each pair of generated-section markers

    <!-- run_all:begin KEY -->
    ...
    <!-- run_all:end KEY -->

and nothing outside them. KEY is `run` (the run's header), the name of a table in `TABLES`
below (curated rows with ratios to the peer measured in the same run), one of `RENDERERS`
(`detect_stages`, `sequence_e2e`, `viewer_frame_time`: the steps' own tables; `png16`: the
sequence bench's PNG encodings with their sizes), or
`bench:PACKAGE/BENCH` (every criterion result of that bench target, for benches with no
curated table: a new bench needs only such a marker pair). `bench:*` lists the targets found in
the results. An unknown KEY, an unpaired marker or a missing results file is an error with one
line naming the file; DOC is then left as it was (it is replaced atomically).
"""

import argparse
import glob
import json
import os
import re
import sys
import tempfile
from pathlib import Path

SCHEMA = 1

# ---------------------------------------------------------------------------------------------
# Collecting
# ---------------------------------------------------------------------------------------------

# Lines of the bench logs worth keeping with the results (what the bench itself reports about
# the machine, and the CPU-time probe of `benches/support/thread_cpu.rs`).
LOG_FACTS = {
    "gpu_adapter": re.compile(r"^GPU adapter: (.+)$"),
    "gpu_skipped": re.compile(r"^SKIP GPU benches: (.+)$"),
    "decoder_kernels": re.compile(r"^decode bench: default kernels on this CPU: (.+)$"),
}
PNG_SIZE = re.compile(r"^png16/(\S+): (\d+) bytes")
CPU_PROBE = re.compile(r"^cpu-time (\S+): ([0-9.]+) ms per call")
DECODE_PROBE = re.compile(r"^cpu probe (\S+): ([0-9.]+) ms thread CPU time per frame")


def read_meta(path):
    meta = {}
    for n, line in enumerate(Path(path).read_text().splitlines(), 1):
        if not line.strip():
            continue
        if "=" not in line:
            raise ValueError(f"{path}:{n}: expected key=value, got {line!r}")
        k, v = line.split("=", 1)
        meta[k.strip()] = v.strip()
    return meta


def floats(text):
    return [float(x) for x in text.split()] if text else []


def criterion_results(bench_dir):
    """{benchmark id: {median_ns, low_ns, high_ns, mean_ns}} of one bench target's CRITERION_HOME."""
    out = {}
    for bj in sorted(glob.glob(os.path.join(bench_dir, "**", "new", "benchmark.json"), recursive=True)):
        new = os.path.dirname(bj)
        if os.path.basename(os.path.dirname(new)) == "report":
            continue
        est_path = os.path.join(new, "estimates.json")
        if not os.path.exists(est_path):
            continue
        info = json.loads(Path(bj).read_text())
        est = json.loads(Path(est_path).read_text())
        med = est["median"]
        ci = med["confidence_interval"]
        out[info["full_id"]] = {
            "median_ns": med["point_estimate"],
            "low_ns": ci["lower_bound"],
            "high_ns": ci["upper_bound"],
            "confidence_level": ci["confidence_level"],
            "mean_ns": est["mean"]["point_estimate"],
        }
    return out


def log_facts(log_path):
    facts, probe = {}, {}
    if not os.path.exists(log_path):
        return facts, probe
    for line in Path(log_path).read_text(errors="replace").splitlines():
        line = line.strip()
        for key, rx in LOG_FACTS.items():
            m = rx.match(line)
            if m:
                facts[key] = m.group(1)
        m = PNG_SIZE.match(line)
        if m:
            facts.setdefault("png_bytes", {})[m.group(1)] = int(m.group(2))
        m = CPU_PROBE.match(line) or DECODE_PROBE.match(line)
        if m:
            probe[m.group(1)] = float(m.group(2))
    return facts, probe


# ---- the steps that are not criterion benches: their printed lines, parsed -------------------

# crates/calib/examples/detect_stages.rs: "median ms per image over N runs of each image" and a
# table "| images | n | found | response | peaks | subpix | grid | label | final fit | total |".
DETECT_REPS = re.compile(r"^median ms per image over (\d+) runs")
DETECT_STAGES = ("response", "peaks", "subpix", "grid", "label", "final_fit", "total")
# benches/sequence_e2e.sh, one line per run and one for the recording.
SEQ_RECORDING = re.compile(r"^recording: (\d+) frames, (\d+) MB$")
SEQ_RUN = re.compile(
    r"^layout (\S+) +threads (\d+): (\d+) frames, ([0-9.]+) frames/s in the pipeline \(([0-9.]+) frames/s process, "
    r"start-up included\); per frame ms: read ([0-9.]+) decode ([0-9.]+) register ([0-9.]+) encode ([0-9.]+) "
    r"write ([0-9.]+); missing (\d+); load before (.+)$"
)
SEQ_OUTPUT = re.compile(r"^output: (\d+) MB$")
# crates/viewer/tests/frame_time.rs.
VIEWER_FRAME = re.compile(
    r"^3D view frame time: ([0-9.]+) ms/frame \((\d+) textured triangles, (\d+) vertices, (\d+)x(\d+), "
    r"adapter (.*)\); upload ([0-9.]+) ms$"
)
VIEWER_COVER = re.compile(r"^mesh covers ([0-9.]+) % of the view$")
# benches/calibrate_e2e.sh: one line per tool.
CAL_KFUSE = re.compile(
    r"^kfuse: 25\+25 images, median ([0-9.]+) s, min ([0-9.]+) s over (\d+) processes; "
    r"last run's stages ms: (.*); load before (.+)$"
)
CAL_CV_PROCESS = re.compile(r"^opencv process: median ([0-9.]+) s, min ([0-9.]+) s over (\d+) processes")
CAL_CV_SCRIPT = re.compile(
    r"^opencv: (\d+) pairs, ([0-9.]+) s in the script \(read ([0-9.]+) s, detect ([0-9.]+) s, "
    r"calibrate ([0-9.]+) s\), rms (\S+) px, OpenCV (\S+), threads (\d+)$"
)
SKIP_LINE = re.compile(r"^SKIP \S+: (.+)$")


def parse_detect_stages(lines):
    out = {"classes": []}
    for line in lines:
        m = DETECT_REPS.match(line)
        if m:
            out["reps"] = int(m.group(1))
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not line.startswith("|") or len(cells) != 3 + len(DETECT_STAGES) or not cells[1].isdigit():
            continue
        row = {"images": cells[0], "n": int(cells[1]), "found": int(cells[2])}
        row.update({k + "_ms": float(v) for k, v in zip(DETECT_STAGES, cells[3:])})
        out["classes"].append(row)
    return out


def parse_sequence(lines):
    out = {"runs": []}
    for line in lines:
        line = line.strip()
        m = SEQ_RECORDING.match(line)
        if m:
            out["recording_frames"], out["recording_mb"] = int(m.group(1)), int(m.group(2))
        m = SEQ_RUN.match(line)
        if m:
            g = m.groups()
            out["runs"].append({
                "layout": g[0], "threads": int(g[1]), "frames": int(g[2]),
                "pipeline_fps": float(g[3]), "process_fps": float(g[4]),
                "stage_ms": dict(zip(("read", "decode", "register", "encode", "write"), map(float, g[5:10]))),
                "missing": int(g[10]), "load_before": floats(g[11]),
            })
        m = SEQ_OUTPUT.match(line)
        if m and out["runs"]:
            out["runs"][-1]["output_mb"] = int(m.group(1))
    return out


def parse_viewer(lines):
    out = {}
    for line in lines:
        line = line.strip()
        m = VIEWER_FRAME.match(line)
        if m:
            g = m.groups()
            out.update({"ms_per_frame": float(g[0]), "triangles": int(g[1]), "vertices": int(g[2]),
                        "viewport": [int(g[3]), int(g[4])], "adapter": g[5], "upload_ms": float(g[6])})
        m = VIEWER_COVER.match(line)
        if m:
            out["coverage_pct"] = float(m.group(1))
    return out


def parse_calibrate(lines):
    out = {}
    for line in lines:
        line = line.strip()
        m = CAL_KFUSE.match(line)
        if m:
            g = m.groups()
            stages = [s.rsplit(" ", 1) for s in g[3].split(", ") if " " in s]
            out["kfuse"] = {"median_s": float(g[0]), "min_s": float(g[1]), "reps": int(g[2]),
                            "stages_ms": [[n, float(v)] for n, v in stages], "load_before": floats(g[4])}
        m = CAL_CV_PROCESS.match(line)
        if m:
            out["opencv"] = {"median_s": float(m.group(1)), "min_s": float(m.group(2)), "reps": int(m.group(3))}
        m = CAL_CV_SCRIPT.match(line)
        if m and "opencv" in out:
            g = m.groups()
            out["opencv"].update({"pairs": int(g[0]), "script_s": float(g[1]), "read_s": float(g[2]),
                                  "detect_s": float(g[3]), "calibrate_s": float(g[4]), "rms_px": g[5],
                                  "version": g[6], "threads": int(g[7])})
    return out


STEP_PARSERS = {"detect_stages": parse_detect_stages, "sequence_e2e": parse_sequence,
                "calibrate_e2e": parse_calibrate, "viewer_frame_time": parse_viewer}
# What a step's log must yield for its status to stay "ok".
STEP_NEEDS = {"detect_stages": "classes", "sequence_e2e": "runs", "calibrate_e2e": "kfuse",
              "viewer_frame_time": "ms_per_frame"}


def collect_steps(meta, log_dir):
    """{step: {status, start, load_start, facts of meta step.NAME.KEY, parsed figures}}."""
    steps = {}
    for key, value in meta.items():
        if not key.startswith("step."):
            continue
        name, _, sub = key[len("step."):].partition(".")
        entry = steps.setdefault(name, {})
        if not sub:
            entry["status"] = value
        elif sub == "load_start":
            entry["load_start"] = floats(value)
        elif sub in ("reps", "frames"):
            entry[sub] = int(value)
        else:
            entry[sub] = value
    for name, entry in steps.items():
        if name not in STEP_PARSERS:
            raise ValueError(f"meta: unknown step '{name}' (known: {', '.join(STEP_PARSERS)})")
        entry.setdefault("status", "not run")
        log = os.path.join(log_dir or "", f"step-{name}.log")
        if not log_dir or not os.path.exists(log):
            continue
        lines = Path(log).read_text(errors="replace").splitlines()
        entry.update(STEP_PARSERS[name](lines))
        skip = next((m.group(1) for m in map(SKIP_LINE.match, lines) if m), None)
        if entry["status"] == "ok" and skip:
            entry["status"] = f"skipped: {skip}"
        elif entry["status"] == "ok" and not entry.get(STEP_NEEDS[name]):
            entry["status"] = "failed: printed no figures"
    return steps


def collect(args):
    meta = read_meta(args.meta)
    benches = {}
    # run_all.sh lists every bench target it ran as "bench.<package>/<bench>=<status>".
    for key, status in meta.items():
        if not key.startswith("bench."):
            continue
        target = key[len("bench."):]
        pkg, name = target.split("/", 1)
        entry = {"package": pkg, "bench": name, "status": status}
        entry["results"] = criterion_results(os.path.join(args.criterion, pkg, name))
        if args.log:
            facts, probe = log_facts(os.path.join(args.log, pkg, name + ".log"))
            entry.update(facts)
            if probe:
                entry["cpu_probe_ms"] = probe
        benches[target] = entry
    peers = {}
    for spec in args.peer or []:
        name, _, path = spec.partition("=")
        if not os.path.exists(path):
            said = meta.get("peer." + name, "ok")
            peers[name] = {"status": said if said != "ok" else "failed: wrote no results"}
            continue
        data = json.loads(Path(path).read_text())
        data.setdefault("status", "ok")
        peers[name] = data
    for key, status in meta.items():
        if key.startswith("peer.") and key[5:] not in peers:
            peers[key[5:]] = {"status": status}
    if args.recorded:
        for name, data in json.loads(Path(args.recorded).read_text()).items():
            if peers.get(name, {}).get("status") != "ok":
                data = dict(data)
                data["status"] = "recorded"
                peers[name] = data
    results = {
        "schema": SCHEMA,
        "tool": "benches/run_all.sh",
        "mode": meta.get("mode", "full"),
        "criterion_args": meta.get("criterion_args", ""),
        "profile": meta.get("profile", ""),
        "machine": {
            "cpu": meta.get("cpu", "unknown"),
            "cores": int(meta.get("cores", "0") or 0),
            "memory_gib": float(meta.get("memory_gib", "0") or 0),
            "os": meta.get("os", ""),
            "rustc": meta.get("rustc", ""),
        },
        "date_utc": {"start": meta.get("start", ""), "end": meta.get("end", "")},
        "commit": {"hash": meta.get("commit", ""), "dirty": meta.get("dirty", "no") == "yes"},
        "load": {
            "start": floats(meta.get("load_start", "")),
            "end": floats(meta.get("load_end", "")),
            "idle_threshold": float(meta.get("idle_threshold", "nan")),
            "waited_s": int(meta.get("waited_s", "0") or 0),
            "idle_reached": meta.get("idle_reached", "no") == "yes",
        },
        "benches": benches,
        "peers": peers,
        "steps": collect_steps(meta, args.log),
    }
    if meta.get("only"):
        results["only"] = meta["only"]
    tmp = args.out + ".tmp"
    Path(tmp).write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
    os.replace(tmp, args.out)
    n = sum(len(b["results"]) for b in benches.values())
    print(f"collected {n} criterion results from {len(benches)} bench targets and {len(peers)} peers into {args.out}")


# ---------------------------------------------------------------------------------------------
# Tables
# ---------------------------------------------------------------------------------------------

# A source is ("bench", "PACKAGE/BENCH", "criterion id") or ("peer", "PEER", "result name").
REG = "kfuse/fusion_cpu"
GPU = "kfuse/fusion_gpu"
DEC = "kinect-usb/decode"
CAL = "calib/calib"
OPENCV_REG = ("peer", "register_peers", "opencv registerDepth (1 thread)")
OPEN3D_REG = ("peer", "register_peers", "open3d total")
LF2_O2 = ("peer", "libfreenect2", "CpuDepthPacketProcessor, filters on, 1 thread, g++ -O2")
LF2_O3 = ("peer", "libfreenect2", "CpuDepthPacketProcessor, filters on, 1 thread, g++ -O3 -march=native")

# "list" tables: one row per source; each row names, per ratio column, the reference it is
# divided by (a source of the same run), or none ("—").
# "paired" tables: one row per operation, ours beside the peer's, and their ratio.
LF2 = "kfuse / libfreenect2 -O2"
FE = "Fast / Exact"
REG_RATIOS = {"kfuse / OpenCV": OPENCV_REG, "kfuse / Open3D": OPEN3D_REG}
# issue 31: the same registration called from Python (benches/peers/register_peers.py), and
# what the call costs against the Rust bench of the same run.
PY_REG = ("peer", "register_peers", "kfuse python register+hole_mask (all cores)")
PY_REG_OUT = ("peer", "register_peers", "kfuse python register+hole_mask out= (all cores)")
PY_RUST = "Python / Rust `register+holes/rayon`"
# issue 47 item 3: the registration against the memory floor of its outputs (one thread writing
# the 8.3 MB z-buffer and the 2.1 MB mask once, as memset does) in the same run.
MEMSET = ("bench", REG, "memory/fill_outputs")
MEM_RATIO = "kfuse / memset of its outputs"
REG_MEM_RATIOS = {**REG_RATIOS, MEM_RATIO: MEMSET}
PY_RATIO = {"kfuse / OpenCV": OPENCV_REG, "kfuse / Open3D": OPEN3D_REG, PY_RUST: ("bench", REG, "register+holes/rayon")}


def dec(name):
    return ("bench", DEC, "decode_frame/" + name)


GD = "GPU / CPU Fast"


def gd(name):
    return ("bench", "fusion-gpu/decode", "decode/" + name)


SEQ = "kfuse-sequence/sequence"

TABLES = {
    # The per-frame stages of `kfuse fuse --recording` (`crates/sequence/benches/sequence.rs`).
    "sequence_stages": {
        "kind": "list",
        "caption": "The stages of `kfuse fuse --recording`, one frame of the simulated recording, one thread "
        "(`crates/sequence/benches/sequence.rs`)",
        "ratios": [],
        "rows": [
            ("`stage/read_frame` (records, CRC-32, assembly)", ("bench", SEQ, "stage/read_frame"), {}),
            ("`stage/decode` (`Fast`, one thread)", ("bench", SEQ, "stage/decode"), {}),
            ("`stage/register` (`Registration` + z-buffer to 16-bit units)", ("bench", SEQ, "stage/register"), {}),
            ("`stage/write` (one depth PNG of the chosen settings, atomic rename)", ("bench", SEQ, "stage/write"), {}),
        ],
    },
    "registration": {
        "kind": "list",
        "caption": "Depth → colour registration of one Kinect frame (512×424 → 1920×1080); "
        "the peers run on the frame the bench wrote (`KFUSE_WRITE_PEER_FRAME=1`)",
        "ratios": list(REG_RATIOS) + [MEM_RATIO, PY_RUST],
        "rows": [
            ("kfuse `register+holes/single` (1 thread; both lenses' distortion, exact z-buffer, hole mask)", ("bench", REG, "register+holes/single"), REG_MEM_RATIOS),
            ("kfuse `register+holes/single_bits` (the same, mask kept as bits)", ("bench", REG, "register+holes/single_bits"), REG_MEM_RATIOS),
            ("memset of the same outputs (`memory/fill_outputs`: 8.3 MB z-buffer + 2.1 MB mask, 1 thread)", MEMSET, {}),
            ("kfuse `register+holes/rayon` (all cores)", ("bench", REG, "register+holes/rayon"), REG_RATIOS),
            ("OpenCV `registerDepth` (1 thread; colour distortion only, no hole mask)", OPENCV_REG, {}),
            ("Open3D `create_from_depth_image` + `project_to_depth_image` (all cores; no distortion)", OPEN3D_REG, {}),
            ("kfuse from Python `Registration.register` + `.hole_mask()` (all cores; new arrays)", PY_REG, PY_RATIO),
            ("kfuse from Python, the same with `out=` arrays reused", PY_REG_OUT, PY_RATIO),
        ],
    },
    "decode": {
        "kind": "list",
        "caption": "Decoding one raw Kinect v2 depth frame (`frames/scene.raw`) into depth + IR",
        "ratios": [LF2, FE],
        "rows": [
            ("kfuse Fast (default kernels), filters on, 1 thread", dec("fast/filters_on_1_thread"), {LF2: LF2_O2, FE: dec("exact/filters_on_1_thread")}),
            ("kfuse Fast, filters on, 2 threads", dec("fast/filters_on_2_threads"), {LF2: LF2_O2, FE: dec("exact/filters_on_2_threads")}),
            ("kfuse Fast, filters off, 1 thread", dec("fast/filters_off_1_thread"), {FE: dec("exact/filters_off_1_thread")}),
            ("kfuse Fast, portable four-lane kernels, filters on, 1 thread", dec("fast_portable/filters_on_1_thread"), {LF2: LF2_O2, FE: dec("exact/filters_on_1_thread")}),
            ("kfuse Exact (bit-identical to libfreenect2), filters on, 1 thread", dec("exact/filters_on_1_thread"), {LF2: LF2_O2}),
            ("kfuse Exact, filters on, 2 threads", dec("exact/filters_on_2_threads"), {LF2: LF2_O2}),
            ("kfuse Exact, filters off, 1 thread", dec("exact/filters_off_1_thread"), {}),
            ("libfreenect2 `CpuDepthPacketProcessor`, filters on, 1 thread, g++ -O2", LF2_O2, {}),
            ("libfreenect2, filters on, 1 thread, g++ -O3 -march=native", LF2_O3, {}),
        ],
    },
    # issue 15's GPU decoder (`crates/fusion-gpu/benches/decode.rs`, branch gpudec15): shown
    # where BENCHMARKS.md has a `gpu_decode` marker pair.
    "gpu_decode": {
        "kind": "list",
        "caption": "Kinect v2 depth decoding on the GPU (upload of the raw frame and read-back "
        "included) against the CPU `Fast` decoder of the same run",
        "ratios": [GD],
        "rows": [
            ("CPU `Fast` decoder, 2 threads (`decode/cpu_fast_frame`)", gd("cpu_fast_frame"), {}),
            ("GPU decode, depth + IR read back (`decode/gpu_frame`)", gd("gpu_frame"), {GD: gd("cpu_fast_frame")}),
            ("GPU decode without the two filters (`decode/gpu_frame_without_filters`)", gd("gpu_frame_without_filters"), {}),
            ("GPU decode + H1/H2/H7, z-buffer read back (`decode/gpu_decode_register_frame`)", gd("gpu_decode_register_frame"), {GD: gd("cpu_fast_frame")}),
            ("the same streamed, 8 frames, two in flight (`decode/gpu_decode_register_stream`)", gd("gpu_decode_register_stream"), {}),
        ],
    },
    "calib": {
        "kind": "paired",
        "caption": "Checkerboard detection and calibration on the rendered `synthetic-calib` views "
        "(PNG decoding excluded on both sides)",
        "ours": "kfuse",
        "theirs": "OpenCV",
        "rows": [
            ("detection, 512×424 IR", ("bench", CAL, "detect 512x424 (rendered IR)"), ("peer", "opencv_calib", "detect 512x424 (rendered IR)")),
            ("detection, 1920×1080 colour", ("bench", CAL, "detect 1920x1080 (rendered colour)"), ("peer", "opencv_calib", "detect 1920x1080 (rendered colour)")),
            ("mono calibration, 25 IR views", ("bench", CAL, "calibration/mono 25 views (IR corners)"), ("peer", "opencv_calib", "calibration/mono 25 views (IR corners)")),
            ("stereo from corners, 25 pairs", ("bench", CAL, "calibration/stereo 25 pairs from corners"), ("peer", "opencv_calib", "calibration/stereo 25 pairs from corners")),
            ("end to end: detect 25 IR + 25 colour 1080p, stereo", ("bench", CAL, "calibration/end to end: detect 25 IR + 25 colour 1080p, stereo"), ("peer", "opencv_calib", "calibration/end to end: detect 25 IR + 25 colour 1080p, stereo")),
        ],
    },
    "gpu": {
        "kind": "paired",
        "caption": "Fusion stages on the CPU and on the GPU (figures with upload and read-back); the "
        "ratio is GPU / CPU of this run",
        "adapter_of": GPU,
        "ours": "GPU",
        "theirs": "CPU",
        "rows": [
            ("H1 + H2 + H7 (CPU: fused, 1 thread)", ("bench", GPU, "gpu/h1_h2_h7_with_upload_readback"), ("bench", GPU, "cpu/h1_h2_h7_fused_single_thread")),
            ("H1 + H2 + H7 (CPU: fused, rayon)", ("bench", GPU, "gpu/h1_h2_h7_with_upload_readback"), ("bench", GPU, "cpu/h1_h2_h7_fused_rayon")),
            ("H8 plane fill", ("bench", GPU, "gpu/h8_plane_fill_with_upload_readback"), ("bench", GPU, "cpu/h8_plane_fill")),
            ("end to end `run`", ("bench", GPU, "end_to_end/gpu_run"), ("bench", GPU, "end_to_end/cpu_run")),
        ],
    },
}


class Results:
    def __init__(self, data):
        self.d = data

    def value(self, src):
        """(median ms, spread text, note) of a source, or None where this run has no figure."""
        if src is None:
            return None
        kind, owner, name = src
        if kind == "bench":
            r = self.d["benches"].get(owner, {}).get("results", {}).get(name)
            if r is None:
                return None
            return r["median_ns"] / 1e6, f"{fmt_ms(r['low_ns'] / 1e6)} – {fmt_ms(r['high_ns'] / 1e6)}", None
        peer = self.d["peers"].get(owner, {})
        r = peer.get("results", {}).get(name)
        if r is None:
            return None
        spread = [f"min {fmt_ms(r['min_ms'])}"] if r.get("min_ms") is not None else []
        if r.get("cpu_ms") is not None:
            spread.append(f"process CPU {fmt_ms(r['cpu_ms'])}")
        note = f"recorded {peer.get('date', '?')}, not this run" if peer.get("status") == "recorded" else None
        return r["median_ms"], "; ".join(spread) or "—", note

    def status(self, src):
        kind, owner, _ = src
        group = self.d["benches" if kind == "bench" else "peers"].get(owner)
        return "not run" if group is None else (group.get("status", "?") if group.get("status") != "ok" else "no result")


def fmt_ms(ms):
    """Three significant figures in a unit that keeps them readable."""
    if ms is None:
        return "—"
    ms = float(f"{ms:.3g}")  # round first, so that 999.9 ms reads 1.00 s, not 1.00e+03 ms
    for unit, scale in (("s", 1e3), ("ms", 1.0), ("µs", 1e-3), ("ns", 1e-6)):
        if ms >= scale or unit == "ns":
            v = ms / scale
            return f"{sig3(v)} {unit}" if v < 1000 else f"{v:.0f} {unit}"
    raise AssertionError("unreachable")


def sig3(v):
    """Three significant figures, trailing zeros kept (1.30, not 1.3)."""
    return f"{v:#.3g}".rstrip(".")


def fmt_ratio(a, b):
    """a / b with three significant figures, two below 0.1 (0.023×)."""
    if a is None or b is None or b <= 0:
        return "—"
    r = a / b
    return (f"{r:#.2g}".rstrip(".") if r < 0.1 else sig3(r)) + "×"


def header(res):
    d = res.d
    m, load, c = d["machine"], d["load"], d["commit"]
    start, end = d["date_utc"]["start"], d["date_utc"]["end"]
    if start[:10] == end[:10]:
        end = end[11:]
    dirty = " + uncommitted changes" if c["dirty"] else ""
    ls = "/".join(f"{x:.2f}" for x in load["start"]) or "?"
    le = "/".join(f"{x:.2f}" for x in load["end"]) or "?"
    if load["idle_reached"]:
        wait = f"idle (1-min load < {load['idle_threshold']:g}) after {load['waited_s']} s"
    else:
        wait = f"**not idle**: 1-min load stayed ≥ {load['idle_threshold']:g} for the {load['waited_s']} s allowed, run anyway"
    mode = " · **quick mode** (short criterion times: for testing the script, not for comparison)" if d["mode"] == "quick" else ""
    if d.get("only"):
        mode += f" · **partial run** (`--only {d['only']}`: for testing the script)"
    return (
        f"Run {start} → {end} UTC · commit `{c['hash'][:10]}`{dirty} · {m['cpu']}, {m['cores']} cores, "
        f"{m['memory_gib']:.0f} GiB · load (1/5/15 min) {ls} at start, {le} at end; {wait}{mode}"
    )


def render_run(res):
    d = res.d
    lines = [header(res), ""]
    lines.append(f"* profile: {d['profile']}")
    lines.append(f"* criterion arguments: `{d['criterion_args'] or '(defaults)'}`; medians with criterion's 95 % interval")
    lines.append(f"* toolchain: {d['machine']['rustc']}; OS: {d['machine']['os']}")
    for target, b in sorted(d["benches"].items()):
        extra = [f"{len(b['results'])} results", b["status"]]
        for key in ("gpu_adapter", "gpu_skipped", "decoder_kernels"):
            if key in b:
                extra.append(f"{key.replace('_', ' ')}: {b[key]}")
        lines.append(f"* bench `{target}`: " + "; ".join(extra))
    for name, p in sorted(d["peers"].items()):
        extra = [p.get("status", "?")]
        if p.get("versions"):
            extra.append(", ".join(f"{k} {v}" for k, v in sorted(p["versions"].items())))
        if p.get("status") == "recorded":
            extra.append(f"recorded {p.get('date', '?')}")
        lines.append(f"* peer `{name}`: " + "; ".join(extra))
    for name, st in sorted(d.get("steps", {}).items()):
        extra = [st["status"]]
        for key, what in (("reps", "repetitions of every image"), ("frames", "frames recorded")):
            if key in st:
                extra.append(f"{what}: {st[key]}")
        if st.get("start"):
            extra.append(f"started {st['start']} UTC")
        lines.append(f"* step `{name}`: " + "; ".join(extra))
    return lines


def render_list(res, t):
    cols = t["ratios"]
    lines = [f"{t['caption']}. {header(res)}", ""]
    lines.append("| what | median | spread (95 % interval; peers: min, CPU) |" + "".join(f" {c} |" for c in cols))
    lines.append("| --- | --- | --- |" + " --- |" * len(cols))
    recorded = False
    for label, src, refs in t["rows"]:
        v = res.value(src)
        if v is None:
            lines.append(f"| {label} | {res.status(src)} | |" + " — |" * len(cols))
            continue
        med, spread, note = v
        if note:
            label += f" ({note})"
        cells = []
        for col in cols:
            rv = res.value(refs.get(col))
            cells.append(fmt_ratio(med, rv[0]) + (" †" if rv[2] else "") if rv else "—")
            recorded = recorded or bool(rv and rv[2])
        lines.append(f"| {label} | {fmt_ms(med)} | {spread} |" + "".join(f" {c} |" for c in cells))
    if not cols:
        return lines
    lines.append("")
    lines.append("Ratios are time / time: below 1× the first named takes less time.")
    if recorded:
        lines[-1] += " † against a recorded peer figure (its date in its row), not one of this run."
    return lines


def render_paired(res, t):
    ours, theirs = t["ours"], t["theirs"]
    caption = t["caption"]
    if "adapter_of" in t:
        bench = res.d["benches"].get(t["adapter_of"], {})
        caption += f"; GPU adapter: {bench.get('gpu_adapter') or bench.get('gpu_skipped') or 'none found'}"
    lines = [f"{caption}. {header(res)}", ""]
    lines.append(f"| what | {ours} median (95 % interval) | {theirs} median (spread) | {ours} / {theirs} |")
    lines.append("| --- | --- | --- | --- |")
    for label, a_src, b_src in t["rows"]:
        a, b = res.value(a_src), res.value(b_src)
        a_txt = f"{fmt_ms(a[0])} ({a[1]})" if a else res.status(a_src)
        b_txt = f"{fmt_ms(b[0])} ({b[1]})" if b else res.status(b_src)
        if b and b[2]:
            b_txt += f", {b[2]}"
        lines.append(f"| {label} | {a_txt} | {b_txt} | {fmt_ratio(a[0] if a else None, b[0] if b else None)} |")
    lines.append("")
    lines.append(f"{ours} / {theirs} is time / time: below 1× {ours} takes less time.")
    return lines


def render_bench(res, target):
    b = res.d["benches"].get(target)
    if b is None:
        return [f"`{target}` was not run by this run_all ({header(res)})."]
    lines = [f"All criterion results of `{target}` ({b['status']}). {header(res)}", ""]
    lines.append("| benchmark | median | 95 % interval |")
    lines.append("| --- | --- | --- |")
    for name, r in sorted(b["results"].items()):
        lines.append(f"| `{name}` | {fmt_ms(r['median_ns'] / 1e6)} | {fmt_ms(r['low_ns'] / 1e6)} – {fmt_ms(r['high_ns'] / 1e6)} |")
    if not b["results"]:
        lines.append("| (no results) | | |")
    return lines


def step_intro(res, name, caption):
    """(the step's entry or None, the lines above its table: caption, when it ran, the run's header)."""
    st = res.d.get("steps", {}).get(name)
    if st is None:
        return None, [f"{caption}. Not measured: `{name}` was not run by this run_all. {header(res)}"]
    when = ""
    if st.get("start"):
        load = "/".join(f"{x:.2f}" for x in st.get("load_start", [])) or "?"
        when = f" This step ran at {st['start']} UTC, load (1/5/15 min) {load} at its start."
    if st["status"] != "ok":
        return None, [f"{caption}. Not measured: {st['status']}.{when} {header(res)}"]
    return st, [f"{caption}.{when} {header(res)}", ""]


def render_detect_stages(res):
    st, lines = step_intro(
        res, "detect_stages",
        "Where checkerboard detection spends its time (`crates/calib/examples/detect_stages.rs`, one thread: "
        "`RAYON_NUM_THREADS=1`): per image class, the median over every run of every image, ms per image",
    )
    if st is None:
        return lines
    reps = st.get("reps", "?")
    lines[0] = lines[0].replace("every run of", f"{reps} run{'' if reps == 1 else 's'} of", 1)
    lines.append("| images | n | found | ChESS response | peak search | cornerSubPix | grid | label | junction fit | total |")
    lines.append("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for c in st["classes"]:
        ms = " | ".join(f"{c[k + '_ms']:.2f}" for k in DETECT_STAGES)
        lines.append(f"| {c['images']} | {c['n']} | {c['found']} | {ms} |")
    lines.append("")
    lines.append("found: boards detected complete (first run of each image); ms per image, wall.")
    return lines


def render_sequence(res):
    st, lines = step_intro(
        res, "sequence_e2e",
        "`kfuse fuse --recording` end to end (`benches/sequence_e2e.sh` with this run's kfuse binary): a simulated "
        "recording (`kfuse capture record --backend sim`) in the kfuse layout (registered depth only: decode + "
        "register + write) and the TUM layout (plus the JPEG copies and lists)",
    )
    if st is None:
        return lines
    lines[0] = lines[0].replace("a simulated recording", f"a {st.get('recording_frames', '?')}-frame simulated recording "
                                f"of {st.get('recording_mb', '?')} MB", 1)
    lines.append("| layout | threads | frames written (missing) | frames/s (pipeline) | frames/s (process, start-up incl.) "
                 "| read | decode | register | encode | write (ms per frame, wall, summed per stage) | output | "
                 "load before (1/5/15 min) |")
    lines.append("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in st["runs"]:
        stages = " | ".join(f"{r['stage_ms'][k]:.2f}" for k in ("read", "decode", "register", "encode", "write"))
        out = f"{r['output_mb']} MB" if "output_mb" in r else "—"
        load = "/".join(f"{x:.2f}" for x in r["load_before"]) or "?"
        lines.append(f"| {r['layout']} | {r['threads']} | {r['frames']} ({r['missing']}) | {r['pipeline_fps']:.1f} | "
                     f"{r['process_fps']:.1f} | {stages} | {out} | {load} |")
    return lines


def render_calibrate(res):
    st, lines = step_intro(
        res, "calibrate_e2e",
        "`kfuse calibrate` end to end against OpenCV's end-to-end script on the same files (`benches/calibrate_e2e.sh`, "
        "this run's kfuse binary, the peers' Python): 25 IR + 25 colour images of synthetic-calib (15 poses cycled), "
        "read + detect + both cameras + stereo, whole processes alternated, no figures written on either side",
    )
    if st is None:
        return lines
    k, o = st["kfuse"], st.get("opencv")
    lines.append("| tool | processes | median s | min s | split (last kfuse run: its `--timings`; OpenCV: its script) |")
    lines.append("| --- | --- | --- | --- | --- |")
    split = ", ".join(f"{n} {v:.0f} ms" for n, v in k["stages_ms"])
    lines.append(f"| kfuse | {k['reps']} | {k['median_s']:.3f} | {k['min_s']:.3f} | {split} |")
    if o is None:
        lines.append("| OpenCV | — | not timed: the peers' Python has no cv2 | | |")
    else:
        lines.append(f"| OpenCV {o.get('version', '?')} ({o.get('threads', '?')} threads; Python start-up and `import cv2` "
                     f"included) | {o['reps']} | {o['median_s']:.3f} | {o['min_s']:.3f} | read {o.get('read_s', 0) * 1e3:.0f} ms, "
                     f"detect {o.get('detect_s', 0) * 1e3:.0f} ms, calibrate {o.get('calibrate_s', 0) * 1e3:.0f} ms "
                     f"({o.get('pairs', '?')} pairs, RMS IR/colour/stereo {o.get('rms_px', '?')} px) |")
    load = "/".join(f"{x:.2f}" for x in k["load_before"]) or "?"
    lines.append("")
    lines.append(f"Load (1/5/15 min) before the runs: {load}.")
    return lines


def render_png16(res):
    b = res.d["benches"].get(SEQ)
    if b is None:
        return [f"`{SEQ}` was not run by this run_all ({header(res)})."]
    lines = [f"PNG encoding of one registered depth frame (1920×1080, 16 bit; `png16/*` of "
             f"`crates/sequence/benches/sequence.rs`, sizes as that bench printed them). {header(res)}", ""]
    lines.append("| compression | filter | size | encode time (median) | 95 % interval |")
    lines.append("| --- | --- | --- | --- | --- |")
    sizes = b.get("png_bytes", {})
    for c in ("fastest", "fast", "balanced"):
        for f in ("none", "sub", "up", "adaptive"):
            r = b["results"].get(f"png16/{c}_{f}")
            size = f"{sizes[c + '_' + f] / 1e6:.2f} MB" if c + "_" + f in sizes else "—"
            if r is None:
                lines.append(f"| {c} | {f} | {size} | {'no result' if b['status'] == 'ok' else b['status']} | |")
            else:
                lines.append(f"| {c} | {f} | {size} | {fmt_ms(r['median_ns'] / 1e6)} | "
                             f"{fmt_ms(r['low_ns'] / 1e6)} – {fmt_ms(r['high_ns'] / 1e6)} |")
    return lines


def render_viewer(res):
    st, lines = step_intro(
        res, "viewer_frame_time",
        "The viewer's 3D view (`crates/viewer/tests/frame_time.rs`): the Kinect-size textured mesh of the synthetic "
        "scene drawn into an offscreen target with depth buffer, 10 frames while orbiting, each submitted and "
        "waited for (excluding egui's own pass)",
    )
    if st is None:
        return lines
    lines.append("| adapter | viewport | textured triangles | vertices | ms / frame | upload (once per fusion) | mesh covers |")
    lines.append("| --- | --- | --- | --- | --- | --- | --- |")
    w, h = st["viewport"]
    cover = f"{st['coverage_pct']:.1f} % of the view" if "coverage_pct" in st else "—"
    lines.append(f"| {st['adapter']} | {w}×{h} | {st['triangles']} | {st['vertices']} | {st['ms_per_frame']:.2f} | "
                 f"{st['upload_ms']:.1f} ms | {cover} |")
    return lines


RENDERERS = {
    "detect_stages": render_detect_stages,
    "sequence_e2e": render_sequence,
    "calibrate_e2e": render_calibrate,
    "png16": render_png16,
    "viewer_frame_time": render_viewer,
}


def render_key(res, key):
    if key == "run":
        return render_run(res)
    if key in RENDERERS:
        return RENDERERS[key](res)
    if key in TABLES:
        t = TABLES[key]
        return render_list(res, t) if t["kind"] == "list" else render_paired(res, t)
    if key == "bench:*":
        out = []
        for target in sorted(res.d["benches"]):
            out += render_bench(res, target) + [""]
        return out[:-1]
    if key.startswith("bench:"):
        return render_bench(res, key[len("bench:"):])
    raise KeyError(key)


MARKER = re.compile(r"^<!-- run_all:(begin|end) (\S+) -->\s*$")


def render_doc(text, res, doc_name):
    out, open_key = [], None
    for n, line in enumerate(text.splitlines(), 1):
        m = MARKER.match(line)
        if open_key is None:
            out.append(line)
            if m and m.group(1) == "begin":
                key = m.group(2)
                try:
                    body = render_key(res, key)
                except KeyError:
                    raise ValueError(f"{doc_name}:{n}: unknown table '{key}' (known: run, {', '.join([*TABLES, *RENDERERS])}, bench:PACKAGE/BENCH, bench:*)")
                open_key = (key, n)
                out += [""] + body + [""]
            elif m:
                raise ValueError(f"{doc_name}:{n}: 'run_all:end {m.group(2)}' without its begin marker")
        elif m:
            if m.group(1) == "begin" or m.group(2) != open_key[0]:
                raise ValueError(f"{doc_name}:{n}: '{line.strip()}' inside section '{open_key[0]}' opened at line {open_key[1]}; close it first")
            out.append(line)
            open_key = None
    if open_key is not None:
        raise ValueError(f"{doc_name}:{open_key[1]}: section '{open_key[0]}' has no 'run_all:end {open_key[0]}' marker")
    return "\n".join(out) + "\n"


def render(args):
    try:
        res = Results(json.loads(Path(args.results).read_text()))
    except (OSError, json.JSONDecodeError) as e:
        sys.exit(f"{args.results}: cannot read the results ({e}); run benches/run_all.sh first")
    if res.d.get("schema") != SCHEMA:
        sys.exit(f"{args.results}: results schema {res.d.get('schema')} but this renderer reads {SCHEMA}; rerun benches/run_all.sh")
    doc = Path(args.doc)
    try:
        text = render_doc(doc.read_text(), res, str(doc))
    except ValueError as e:
        sys.exit(str(e))
    target = Path(args.out or args.doc)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=".render-")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, target)
    print(f"tables written to {target}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--meta", required=True)
    c.add_argument("--criterion", required=True)
    c.add_argument("--log")
    c.add_argument("--peer", action="append", help="NAME=FILE.json written by a peer script")
    c.add_argument("--recorded", help="JSON of peers recorded earlier, used where this run has none")
    c.add_argument("--out", required=True)
    r = sub.add_parser("render")
    r.add_argument("results")
    r.add_argument("doc")
    r.add_argument("--out", help="write here instead of rewriting DOC")
    args = ap.parse_args()
    collect(args) if args.cmd == "collect" else render(args)


if __name__ == "__main__":
    main()
