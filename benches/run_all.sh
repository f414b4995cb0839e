#!/usr/bin/env bash
# Every benchmark of the workspace and every peer, back to back, into one results file and the
# tables of BENCHMARKS.md (issue 17): a figure in a generated table is always one this printed.
#
#   benches/run_all.sh [--quick] [--max-wait SECONDS] [--idle-load LOAD] [--no-peers]
#
# 1. builds every criterion bench of the workspace (`cargo metadata`: every `[[bench]]` target
#    of every member, so a bench added later is included with no change here) in one profile,
#    see PROFILE_FLAGS below;
# 2. sets up a throwaway venv (OpenCV, Open3D, numpy from PyPI) in $KFUSE_BENCH_VENV
#    (default ~/.cache/kfuse-bench-venv) unless --no-peers;
# 3. waits until the machine is idle (1-minute load average below IDLE_LOAD), at most
#    --max-wait seconds, then runs anyway and records that it was not idle;
# 4. runs each bench (criterion defaults, or short times with --quick) and right after it the
#    peers measured on the same input: fusion_cpu → benches/peers/register_peers.py (on the
#    frame the bench wrote), calib → crates/calib/benches/peers/opencv_calib.py, decode →
#    libfreenect2 if LIBFREENECT2_BUILD names an executable (else its recorded row,
#    benches/results/libfreenect2-recorded.json, is shown with its date);
# 5. writes benches/results/last-run.json (machine, date UTC, commit + dirty flag, load at start
#    and end, every criterion median with its 95 % interval, the peers' figures) and rewrites
#    the generated sections of BENCHMARKS.md (`<!-- run_all:begin KEY -->` … `end KEY`, see
#    benches/render_tables.py; nothing outside the markers changes).
#
# LIBFREENECT2_BUILD: an executable (not part of this repository) run as
#   "$LIBFREENECT2_BUILD" VECTORS_DIR
# that decodes VECTORS_DIR/frames/scene.raw with libfreenect2's CpuDepthPacketProcessor and
# prints on stdout one JSON object {"versions": {...}, "results": {NAME: {"median_ms": X,
# "min_ms": Y}}} with the names of benches/results/libfreenect2-recorded.json.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD

# One busy process alone holds the 1-minute load average near 1.0, so below 0.5 at most half a
# core was taken by other work over the last minute: the condition of the "quiet machine" runs
# that BENCHMARKS.md compared before (load 0.6–1.3 with the bench itself running).
IDLE_LOAD=0.5
# How often the load is read while waiting (the 1-minute average moves little faster).
POLL_S=15
MAX_WAIT_S=3600
QUICK=0
PEERS=1

usage() { sed -n '2,30p' "$0" | sed 's/^# \{0,1\}//'; }
while [ $# -gt 0 ]; do
  case "$1" in
    --quick) QUICK=1 ;;
    --no-peers) PEERS=0 ;;
    --max-wait) MAX_WAIT_S=${2:?--max-wait needs a number of seconds}; shift ;;
    --idle-load) IDLE_LOAD=${2:?--idle-load needs a load average}; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "run_all.sh: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
[[ $MAX_WAIT_S =~ ^[0-9]+$ ]] || { echo "run_all.sh: --max-wait '$MAX_WAIT_S' is not a whole number of seconds" >&2; exit 2; }
[[ $IDLE_LOAD =~ ^[0-9]+(\.[0-9]+)?$ ]] || { echo "run_all.sh: --idle-load '$IDLE_LOAD' is not a number" >&2; exit 2; }
command -v python3 >/dev/null || { echo "run_all.sh: python3 is needed to collect the results and write the tables" >&2; exit 1; }

# The build profile of every bench: the dev profile at opt-level 3 without debug info. Its
# dependencies are opt-level 3 already ([profile.dev.package."*"]), so the artifacts of a test
# build are reused and only the workspace crates are rebuilt, instead of a release build of the
# whole GUI stack (eframe, wgpu, winit) that no bench times. The workspace crates drop debug
# assertions and overflow checks as in release; the dependencies keep the dev profile's
# (a full rebuild otherwise).
PROFILE_DESC="dev profile + opt-level 3, no debug info; workspace crates without debug assertions and overflow checks; dependencies opt-level 3 with the dev profile's debug assertions"
PROFILE_FLAGS=(--profile dev --config profile.dev.opt-level=3 --config profile.dev.debug=false)
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
RUN=$TARGET/run_all
rm -rf "$RUN"
mkdir -p "$RUN/criterion" "$RUN/logs" "$RUN/peers"
cargo metadata --no-deps --format-version 1 >"$RUN/metadata.json"
members=$(python3 -c '
import json, sys
d = json.load(open(sys.argv[1]))
for p in d["packages"]:
    benches = [t["name"] for t in p["targets"] if "bench" in t["kind"]]
    print(p["name"], *benches)' "$RUN/metadata.json")
BENCHES=()
while read -r pkg rest; do
  PROFILE_FLAGS+=(--config "profile.dev.package.$pkg.debug-assertions=false"
                  --config "profile.dev.package.$pkg.overflow-checks=false")
  for b in $rest; do BENCHES+=("$pkg/$b"); done
done <<<"$members"
[ ${#BENCHES[@]} -gt 0 ] || { echo "run_all.sh: cargo metadata lists no bench target" >&2; exit 1; }

if [ "$QUICK" = 1 ]; then
  CRIT_ARGS=(--warm-up-time 1 --measurement-time 2 --sample-size 10 --noplot)
else
  CRIT_ARGS=(--noplot)
fi

META=$RUN/meta.txt
: >"$META"
meta() { printf '%s=%s\n' "$1" "$2" >>"$META"; }
load_now() { cut -d' ' -f1-3 /proc/loadavg; }

echo "== building ${#BENCHES[@]} bench targets (${BENCHES[*]})"
# One build of the whole workspace, so that every bench links the same feature-unified crates;
# the benches then run from these executables (a `cargo bench -p` per bench would rebuild the
# crates whose features differ, while the machine should be idle).
cargo bench --workspace --benches --no-run --message-format=json-render-diagnostics "${PROFILE_FLAGS[@]}" \
  >"$RUN/build.json" 2>"$RUN/logs/build.log" \
  || { tail -n 30 "$RUN/logs/build.log"; echo "run_all.sh: the bench build failed (log: $RUN/logs/build.log)" >&2; exit 1; }
# "package/bench executable package_dir" per bench target, from cargo's artifact messages.
EXES=$(python3 - "$RUN/build.json" "$RUN/metadata.json" <<'PY'
import json, os, sys
names = {p["manifest_path"]: p["name"] for p in json.load(open(sys.argv[2]))["packages"]}
for line in open(sys.argv[1]):
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m["target"]["kind"] == ["bench"] and m.get("executable"):
        print(f'{names[m["manifest_path"]]}/{m["target"]["name"]} {m["executable"]} {os.path.dirname(m["manifest_path"])}')
PY
)

PY=python3
if [ "$PEERS" = 1 ]; then
  VENV=${KFUSE_BENCH_VENV:-${XDG_CACHE_HOME:-$HOME/.cache}/kfuse-bench-venv}
  # Open3D's wheel links the system's libusb-1.0 (kfuse itself vendors its own).
  if command -v dpkg >/dev/null && ! dpkg -s libusb-1.0-0 >/dev/null 2>&1; then
    echo "== installing libusb-1.0-0 (Open3D needs it)"
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0; } >/dev/null 2>&1 \
      || { echo "run_all.sh: apt-get install libusb-1.0-0 failed; install it, or pass --no-peers" >&2; exit 1; }
  fi
  if ! "$VENV/bin/python" -c 'import cv2, open3d, numpy' 2>/dev/null; then
    echo "== setting up the peers' venv in $VENV (OpenCV, Open3D, numpy from PyPI)"
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --disable-pip-version-check -q opencv-python-headless open3d-cpu numpy
    "$VENV/bin/python" -c 'import cv2, open3d, numpy' \
      || { echo "run_all.sh: the peers' venv $VENV cannot import cv2, open3d and numpy (above)" >&2; exit 1; }
  fi
  PY=$VENV/bin/python
fi

waited=0
while awk -v l="$(cut -d' ' -f1 /proc/loadavg)" -v t="$IDLE_LOAD" 'BEGIN { exit !(l >= t) }' \
      && [ "$waited" -lt "$MAX_WAIT_S" ]; do
  [ $((waited % 60)) = 0 ] && echo "== waiting for an idle machine: load $(load_now), want < $IDLE_LOAD (${waited}/${MAX_WAIT_S} s)"
  sleep "$POLL_S"
  waited=$((waited + POLL_S))
done
if awk -v l="$(cut -d' ' -f1 /proc/loadavg)" -v t="$IDLE_LOAD" 'BEGIN { exit !(l < t) }'; then
  idle=yes
else
  idle=no
  echo "== not idle after ${waited} s (load $(load_now)): running anyway, the tables will say so"
fi

meta mode "$([ "$QUICK" = 1 ] && echo quick || echo full)"
meta criterion_args "${CRIT_ARGS[*]}"
meta profile "$PROFILE_DESC"
meta cpu "$(grep -m1 '^model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//')"
meta cores "$(nproc)"
meta memory_gib "$(awk '/^MemTotal:/ { printf "%.1f", $2 / 1048576 }' /proc/meminfo)"
meta os "$(. /etc/os-release 2>/dev/null && echo "${PRETTY_NAME:-unknown}") / Linux $(uname -r)"
meta rustc "$(rustc -V)"
meta commit "$(git rev-parse HEAD)"
meta dirty "$([ -n "$(git status --porcelain --untracked-files=no)" ] && echo yes || echo no)"
meta idle_threshold "$IDLE_LOAD"
meta waited_s "$waited"
meta idle_reached "$idle"
meta load_start "$(load_now)"
meta start "$(date -u '+%Y-%m-%d %H:%M')"

DATA=${KFUSE_SHARED_DATA:-$ROOT/../shared/data}
PEER_ARGS=()
run_peer() { # NAME COMMAND...: a peer's JSON goes to $RUN/peers/NAME.json, its text to the log
  local name=$1; shift
  echo "== peer $name"
  if "$@" >"$RUN/logs/peer-$name.log" 2>&1; then
    meta "peer.$name" ok
  else
    meta "peer.$name" "failed: exit $? (log: ${RUN#"$ROOT"/}/logs/peer-$name.log)"
    tail -n 5 "$RUN/logs/peer-$name.log"
  fi
  PEER_ARGS+=(--peer "$name=$RUN/peers/$name.json")
}

for target in "${BENCHES[@]}"; do
  pkg=${target%%/*}
  name=${target#*/}
  mkdir -p "$RUN/criterion/$target" "$RUN/logs/$pkg"
  log=$RUN/logs/$target.log
  echo "== bench $target (load $(load_now))"
  status=ok
  read -r _ exe dir <<<"$(awk -v t="$target" '$1 == t' <<<"$EXES")"
  if [ -z "$exe" ]; then
    status="failed: not built"
  else
    # As `cargo bench` runs it: from the package's folder, with `--bench`.
    (cd "$dir" && KFUSE_WRITE_PEER_FRAME=1 CRITERION_HOME="$RUN/criterion/$target" \
      "$exe" --bench "${CRIT_ARGS[@]}") >"$log" 2>&1 \
      || { status="failed: exit $?"; tail -n 5 "$log"; }
  fi
  meta "bench.$target" "$status"
  [ "$PEERS" = 1 ] || continue
  case "$target" in
    kfuse/fusion_cpu)
      run_peer register_peers "$PY" benches/peers/register_peers.py "$TARGET/peer-frame" --json "$RUN/peers/register_peers.json" ;;
    calib/calib)
      run_peer opencv_calib "$PY" crates/calib/benches/peers/opencv_calib.py --data "$DATA" --json "$RUN/peers/opencv_calib.json" ;;
    kinect-usb/decode)
      if [ -n "${LIBFREENECT2_BUILD:-}" ]; then
        [ -x "$LIBFREENECT2_BUILD" ] || { echo "run_all.sh: LIBFREENECT2_BUILD=$LIBFREENECT2_BUILD is not an executable" >&2; exit 1; }
        run_peer libfreenect2 bash -c '"$1" "$2" >"$3.tmp" && python3 -c "import json,sys; json.load(open(sys.argv[1]))" "$3.tmp" && mv "$3.tmp" "$3"' \
          _ "$LIBFREENECT2_BUILD" "$DATA/kinect-v2-vectors" "$RUN/peers/libfreenect2.json"
      fi ;;
  esac
done

meta end "$(date -u '+%Y-%m-%d %H:%M')"
meta load_end "$(load_now)"

mkdir -p benches/results
python3 benches/render_tables.py collect --meta "$META" --criterion "$RUN/criterion" --log "$RUN/logs" \
  "${PEER_ARGS[@]}" --recorded benches/results/libfreenect2-recorded.json --out benches/results/last-run.json
python3 benches/render_tables.py render benches/results/last-run.json BENCHMARKS.md
echo "== done: benches/results/last-run.json and BENCHMARKS.md (logs in $RUN/logs)"
