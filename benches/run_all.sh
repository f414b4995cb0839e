#!/usr/bin/env bash
# Every benchmark of the workspace and every peer, back to back, into one results file and the
# tables of BENCHMARKS.md (issue 17): a figure in a generated table is always one this printed.
#
#   benches/run_all.sh [--quick] [--max-wait SECONDS] [--idle-load LOAD] [--no-peers] [--only STEPS]
#
# --quick: short criterion times, 1 repetition of detect_stages, a 60-frame recording (tests the
#   script; the tables say "quick mode").
# --only STEPS: for testing the script, run only these comma-separated steps: `benches` (every
#   criterion bench and its peers), `bench:PACKAGE/BENCH` (one bench and its peers),
#   `detect_stages`, `sequence_e2e`, `calibrate_e2e`, `viewer_frame_time`. Everything is still built; the
#   results and the document go to $CARGO_TARGET_DIR/run_all/{last-run.json,BENCHMARKS.md},
#   never to the repository's files (a partial run is not a run of the tables).
#
# 1. builds every criterion bench of the workspace (`cargo metadata`: every `[[bench]]` target
#    of every member, so a bench added later is included with no change here), the workspace's
#    binaries and examples and the viewer's frame-time test, in one profile, the bench profile
#    (= release, see PROFILE_FLAGS below);
# 2. sets up a throwaway venv (OpenCV, Open3D, numpy from PyPI) in $KFUSE_BENCH_VENV
#    (default ~/.cache/kfuse-bench-venv) unless --no-peers, and builds kfuse's Python package
#    (python/, release) into it;
# 3. waits until the machine is idle (1-minute load average below IDLE_LOAD), at most
#    --max-wait seconds, then runs anyway and records that it was not idle;
# 4. runs each bench (criterion defaults, or short times with --quick) and right after it the
#    peers measured on the same input: fusion_cpu → benches/peers/register_peers.py (on the
#    frame the bench wrote), calib → crates/calib/benches/peers/opencv_calib.py, decode →
#    libfreenect2 if LIBFREENECT2_BUILD names an executable (else its recorded row,
#    benches/results/libfreenect2-recorded.json, is shown with its date);
# 5. then the measurements that are not criterion benches, each into the results file and a
#    table: `crates/calib/examples/detect_stages.rs` (detection time per stage and image class,
#    one thread, KFUSE_REPS repetitions, default 5; skipped with a note without the shared
#    data), `benches/sequence_e2e.sh` with the kfuse binary of this build (a FRAMES-frame
#    simulated recording, default 300, under the run folder, deleted after; kfuse and TUM
#    layouts, 1 and 2 threads), `benches/calibrate_e2e.sh` (`kfuse calibrate` of 25 IR + 25
#    colour images end to end against OpenCV's end-to-end script on the same files, whole
#    processes alternated, CALIB_REPS times each, default 5; skipped without the shared data)
#    and the viewer's frame-time test
#    (`crates/viewer/tests/frame_time.rs`, the 3D view's textured mesh on the wgpu adapter);
# 6. writes benches/results/last-run.json (machine, date UTC, commit + dirty flag, load at start
#    and end, every criterion median with its 95 % interval, the peers' and the steps' figures)
#    and rewrites
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
ONLY=

usage() { awk 'NR == 1 { next } /^#/ { sub(/^# ?/, ""); print; next } { exit }' "$0"; }
while [ $# -gt 0 ]; do
  case "$1" in
    --quick) QUICK=1 ;;
    --no-peers) PEERS=0 ;;
    --max-wait) MAX_WAIT_S=${2:?--max-wait needs a number of seconds}; shift ;;
    --idle-load) IDLE_LOAD=${2:?--idle-load needs a load average}; shift ;;
    --only) ONLY=${2:?--only needs a comma-separated list of steps}; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "run_all.sh: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
[[ $MAX_WAIT_S =~ ^[0-9]+$ ]] || { echo "run_all.sh: --max-wait '$MAX_WAIT_S' is not a whole number of seconds" >&2; exit 2; }
STEPS_KNOWN="benches bench:PACKAGE/BENCH detect_stages sequence_e2e calibrate_e2e viewer_frame_time"
IFS=, read -ra SELECTED <<<"$ONLY"
for s in "${SELECTED[@]}"; do
  case "$s" in
    benches|bench:*/*|detect_stages|sequence_e2e|calibrate_e2e|viewer_frame_time) ;;
    *) echo "run_all.sh: --only: unknown step '$s' (known: $STEPS_KNOWN)" >&2; exit 2 ;;
  esac
done
want() { # STEP: whether this run runs STEP (every step without --only)
  [ -z "$ONLY" ] && return 0
  local s
  for s in "${SELECTED[@]}"; do
    [ "$s" = "$1" ] && return 0
    [ "$s" = benches ] && [[ $1 == bench:* ]] && return 0
  done
  return 1
}
[[ $IDLE_LOAD =~ ^[0-9]+(\.[0-9]+)?$ ]] || { echo "run_all.sh: --idle-load '$IDLE_LOAD' is not a number" >&2; exit 2; }
command -v python3 >/dev/null || { echo "run_all.sh: python3 is needed to collect the results and write the tables" >&2; exit 1; }

# The build profile of every bench: `[profile.bench]` of Cargo.toml, which is the release
# profile users build (`cargo build --release`: opt-level 3, the default codegen units and
# thin-local LTO, line tables only) (issue 33: the dev profile at opt-level 3 this used before
# doubled register+holes/single, 3.42 ms against 1.63 ms in release, by its many codegen units
# and the workspace crates' missing cross-crate inlining). A release build of the whole stack
# (eframe, wgpu, winit) is the price; CI's tests keep the dev profile.
PROFILE_DESC="bench profile = release (opt-level 3, default codegen units, no LTO beyond thin-local, line tables only)"
PROFILE_FLAGS=(--profile bench)
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
  for b in $rest; do BENCHES+=("$pkg/$b"); done
done <<<"$members"
[ ${#BENCHES[@]} -gt 0 ] || { echo "run_all.sh: cargo metadata lists no bench target" >&2; exit 1; }

# detect_stages: repetitions of every image (the hand-taken issue-14 table used 5); the
# sequence: frames of the simulated recording (300: the issue's 10 s at 30 frames/s, ~950 MB).
if [ "$QUICK" = 1 ]; then
  CRIT_ARGS=(--warm-up-time 1 --measurement-time 2 --sample-size 10 --noplot)
  DETECT_REPS=1
  SEQ_FRAMES=60
  CALIB_REPS=1
else
  CRIT_ARGS=(--noplot)
  DETECT_REPS=${KFUSE_REPS:-5}
  SEQ_FRAMES=300
  CALIB_REPS=5
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
# The workspace's binaries (kfuse, for the sequence), its examples (detect_stages) and the
# viewer's frame-time test, in the same profile and with --workspace, so that features unify as
# in the bench build and its crates are reused rather than rebuilt with other features.
cargo build --workspace --bins --examples --message-format=json-render-diagnostics "${PROFILE_FLAGS[@]}" \
  >"$RUN/build-bins.json" 2>>"$RUN/logs/build.log" \
  && cargo test --workspace --test frame_time --no-run --message-format=json-render-diagnostics "${PROFILE_FLAGS[@]}" \
  >>"$RUN/build-bins.json" 2>>"$RUN/logs/build.log" \
  || { tail -n 30 "$RUN/logs/build.log"; echo "run_all.sh: the build of the binaries, examples or the frame-time test failed (log: $RUN/logs/build.log)" >&2; exit 1; }
# "kind/name executable" of the kfuse binary, the detect_stages example and the frame_time test.
ARTIFACTS=$(python3 - "$RUN/build-bins.json" <<'PY'
import json, sys
for line in open(sys.argv[1]):
    m = json.loads(line)
    t = m.get("target", {})
    if m.get("reason") == "compiler-artifact" and m.get("executable") and \
            (t.get("kind"), t.get("name")) in ((["bin"], "kfuse"), (["example"], "detect_stages"), (["test"], "frame_time")):
        print(f'{t["kind"][0]}/{t["name"]} {m["executable"]}')
PY
)
artifact() { awk -v k="$1" '$1 == k { print $2 }' <<<"$ARTIFACTS"; }
KFUSE_BIN=$(artifact bin/kfuse)
DETECT_STAGES=$(artifact example/detect_stages)
FRAME_TIME=$(artifact test/frame_time)
for a in "kfuse binary:$KFUSE_BIN" "detect_stages example:$DETECT_STAGES" "frame_time test:$FRAME_TIME"; do
  [ -x "${a#*:}" ] || { echo "run_all.sh: cargo built no ${a%%:*} (messages: $RUN/build-bins.json)" >&2; exit 1; }
done

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
  # kfuse from Python (issue 31) in the same venv, built with the release settings (python/'s
  # [profile.release] is the workspace's), so that register_peers.py times it beside OpenCV
  # and Open3D in one process, on the frame the Rust bench measured.
  echo "== building the Python package (python/) into $VENV, release"
  "$VENV/bin/pip" install --disable-pip-version-check -q maturin \
    && (cd python && VIRTUAL_ENV="$VENV" PATH="$VENV/bin:$PATH" maturin develop --release -q) \
    && "$VENV/bin/python" -c 'import kfuse' \
    || { echo "run_all.sh: the Python package (python/) does not build into $VENV (above)" >&2; exit 1; }
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
[ -n "$ONLY" ] && meta only "$ONLY"
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
  want "bench:$target" || continue
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

# The measurements that are not criterion benches: each writes its log to logs/step-NAME.log,
# which render_tables.py collect reads; meta step.NAME is its status, step.NAME.KEY its facts.
run_step() { # NAME DIR COMMAND...: runs COMMAND in DIR, its output to the step's log
  local name=$1 dir=$2; shift 2
  local log=$RUN/logs/step-$name.log
  echo "== $name (load $(load_now))"
  meta "step.$name.start" "$(date -u '+%H:%M:%S')"
  meta "step.$name.load_start" "$(load_now)"
  if (cd "$dir" && "$@") >"$log" 2>&1; then
    meta "step.$name" ok
  else
    meta "step.$name" "failed: exit $? (log: ${log#"$ROOT"/})"
    tail -n 5 "$log"
  fi
}
if want detect_stages; then
  if [ -d "$DATA/synthetic-calib" ] && [ -d "$DATA/calib-corpus" ]; then
    meta step.detect_stages.reps "$DETECT_REPS"
    # One thread: the stage times of one image, without the junction fit's rayon split.
    run_step detect_stages crates/calib env RAYON_NUM_THREADS=1 KFUSE_REPS="$DETECT_REPS" KFUSE_SHARED_DATA="$DATA" "$DETECT_STAGES"
  else
    echo "== detect_stages: SKIPPED, no shared data at $DATA (synthetic-calib, calib-corpus); its table will say so"
    meta step.detect_stages "skipped: no shared data at $DATA"
  fi
fi
if want sequence_e2e; then
  # The recording (~3.2 MB a frame) lives under the run folder and is deleted with it below.
  meta step.sequence_e2e.frames "$SEQ_FRAMES"
  mkdir -p "$RUN/sequence"
  run_step sequence_e2e "$ROOT" env KFUSE_SEQ_WORK="$RUN/sequence" benches/sequence_e2e.sh "$KFUSE_BIN" "$SEQ_FRAMES"
  rm -rf "$RUN/sequence"
fi
if want calibrate_e2e; then
  if [ -d "$DATA/synthetic-calib" ]; then
    meta step.calibrate_e2e.reps "$CALIB_REPS"
    run_step calibrate_e2e "$ROOT" benches/calibrate_e2e.sh "$KFUSE_BIN" "$DATA" "$CALIB_REPS" "$PY"
  else
    echo "== calibrate_e2e: SKIPPED, no shared data at $DATA (synthetic-calib); its table will say so"
    meta step.calibrate_e2e "skipped: no shared data at $DATA"
  fi
fi
if want viewer_frame_time; then
  run_step viewer_frame_time crates/viewer "$FRAME_TIME" frame_time_kinect_textured_mesh --exact --nocapture --test-threads 1
fi

meta end "$(date -u '+%Y-%m-%d %H:%M')"
meta load_end "$(load_now)"

if [ -n "$ONLY" ]; then
  RESULTS=$RUN/last-run.json
  DOC=$RUN/BENCHMARKS.md
  cp BENCHMARKS.md "$DOC"
else
  RESULTS=benches/results/last-run.json
  DOC=BENCHMARKS.md
  mkdir -p benches/results
fi
python3 benches/render_tables.py collect --meta "$META" --criterion "$RUN/criterion" --log "$RUN/logs" \
  "${PEER_ARGS[@]}" --recorded benches/results/libfreenect2-recorded.json --out "$RESULTS"
python3 benches/render_tables.py render "$RESULTS" "$DOC"
echo "== done: $RESULTS and $DOC (logs in $RUN/logs)"
