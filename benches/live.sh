#!/usr/bin/env bash
# Live fusion over loopback (issue 49): three `kfuse serve --backend sim` of the simulated ring
# (one process per sensor, each at the sensor's 30 Hz in real time) and `kfuse fuse --live`,
# every process on its own TCP port of 127.0.0.1, multicast scouting off. Two runs on the same
# serves:
#
#   1. match only (`--live-match-only`, MATCH_SECONDS): the sets the transport and the
#      matching deliver per second (each set: one frame per sensor, newer than the last set's, within the default
#      25 ms), their spread, and the latency from the newest frame's arrival on its sensor's
#      "PC" to the match;
#   2. fused: SETS sets fused end to end (frames written, `kfuse fuse --sensor` of them), with
#      the latency from the newest frame's arrival to the fused set's commit and where the time
#      of a set goes (summary.json's timings_ms).
#
# Also: CPU per `serve` (utime + stime over the runs, % of one core), and the bytes per frame
# on the wire (every payload a sensor sent that the fuser received, per depth frame received).
# Prints one JSON object. Run by hand (not yet a step of run_all.sh):
#
#   benches/live.sh [KFUSE_BIN] [SETS] [MATCH_SECONDS]
#
# KFUSE_BIN defaults to $CARGO_TARGET_DIR/release/kfuse (build it with
# `cargo build --release --bin kfuse`), SETS to 10, MATCH_SECONDS to 20.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-${CARGO_TARGET_DIR:-target}/release/kfuse}
SETS=${2:-10}
MATCH_S=${3:-20}
[ -x "$BIN" ] || { echo "no kfuse binary at $BIN" >&2; exit 1; }
dir=$(mktemp -d)
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  [ -n "${KFUSE_BENCH_KEEP:-}" ] || rm -rf "$dir"
}
trap cleanup EXIT

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
cpu_ticks() { awk '{ print $14 + $15 }' "/proc/$1/stat"; }

"$BIN" capture scene --backend sim --sim-sensors 3 --device all --interval 0 \
  --out "$dir/cap" >/dev/null 2>&1
connect=()
for i in 1 2 3; do
  port=$(free_port)
  "$BIN" serve --backend sim --sim-sensors 3 --device "00000000000$i" \
    --listen "tcp/127.0.0.1:$port" --no-multicast 2>"$dir/serve$i.err" &
  pids+=($!)
  connect+=(--connect "tcp/127.0.0.1:$port")
done
# Let the sensors start (each renders its view) before the clock of the CPU figure starts.
sleep 10
ticks0=(); for p in "${pids[@]}"; do ticks0+=("$(cpu_ticks "$p")"); done
t0=$(date +%s.%N)

# MATCH_SECONDS of matching, ended by SIGINT (the run writes live.json and exits 130).
timeout -s INT "$MATCH_S" "$BIN" fuse --live --live-match-only --rig "$dir/cap/true_rig.json" \
  --out "$dir/match" --no-multicast "${connect[@]}" >/dev/null 2>"$dir/match.err" || true
"$BIN" fuse --live --rig "$dir/cap/true_rig.json" --out "$dir/fused" --sets "$SETS" \
  --wait 120 --no-multicast "${connect[@]}" >/dev/null 2>"$dir/fused.err"

t1=$(date +%s.%N)
ticks1=(); for p in "${pids[@]}"; do ticks1+=("$(cpu_ticks "$p")"); done
hz=$(getconf CLK_TCK)
cpu=()
for i in 0 1 2; do
  cpu+=("$(python3 -c "print(round(100 * (${ticks1[$i]} - ${ticks0[$i]}) / $hz / ($t1 - $t0), 1))")")
done

for run in match fused; do
  [ -f "$dir/$run/live.json" ] || { echo "the $run run wrote no live.json:" >&2; cat "$dir/$run.err" >&2; exit 1; }
done
python3 - "$dir" "${cpu[@]}" <<'EOF'
import json, statistics, sys, pathlib, platform, os
d = pathlib.Path(sys.argv[1]); cpu = [float(x) for x in sys.argv[2:5]]
def q(xs, p):
    xs = sorted(xs); return xs[min(len(xs) - 1, int(round(p * (len(xs) - 1))))] if xs else None
m = json.loads((d / "match" / "live.json").read_text())
f = json.loads((d / "fused" / "live.json").read_text())
ms = m["sets"]
span = (ms[-1]["frames"][0]["depth_stamp_ns"] - ms[0]["frames"][0]["depth_stamp_ns"]) / 1e9 if len(ms) > 1 else 0
timings = [json.loads((pathlib.Path(s["out"]) / "summary.json").read_text())["timings_ms"] for s in f["sets"]]
per = lambda k: statistics.median(t[k] for t in timings) if timings else None
recv = [s["counters"] for s in f["sensors"]]
out = {
  "machine": {"cpus": os.cpu_count(), "load_1min": os.getloadavg()[0], "python": platform.python_version()},
  "match_only": {
    "sets": len(ms), "seconds": round(m["elapsed_s"], 1),
    "sets_per_s": round((len(ms) - 1) / span, 1) if span else None,
    "spread_ms_median": q([s["spread_ms"] for s in ms], 0.5),
    "latency_ms_median": q([s["latency_ms"] for s in ms], 0.5),
    "latency_ms_p99": q([s["latency_ms"] for s in ms], 0.99),
    "depth_frames_per_s_per_sensor": [round(s["counters"]["depth"] / m["elapsed_s"], 1) for s in m["sensors"]],
  },
  "fused": {
    "sets": len(f["sets"]),
    "sets_per_s": round(len(f["sets"]) / f["elapsed_s"], 2),
    "latency_ms_median": q([s["latency_ms"] for s in f["sets"]], 0.5),
    "latency_ms_p99": q([s["latency_ms"] for s in f["sets"]], 0.99),
    "set_ms_median": q([s["fuse_ms"] for s in f["sets"]], 0.5),
    "summary_timings_ms_median": {k: per(k) for k in ["sensors", "merge", "consistency", "meshes", "total"]},
  },
  "serve_cpu_percent_of_a_core": cpu,
  "bytes_per_frame": [round(c["bytes"] / max(1, c["depth"])) for c in recv],
  "publisher_dropped": [c["publisher_dropped"] for c in recv],
  "lost": [c["lost"] for c in recv],
}
print(json.dumps(out, indent=2))
EOF
