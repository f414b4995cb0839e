#!/usr/bin/env bash
# The GPU measurements on a machine lent with a GPU (issue 33), from a bundle prepared here: no
# Rust toolchain is needed there, only bash, python3 and a Vulkan driver.
#
#   benches/device.sh --prepare OUT [--kfuse BIN] [--bench-exe PACKAGE/BENCH=EXE]...
#   OUT/device.sh [--quick] [--frames N] [--results FILE]
#
# --prepare OUT (here): builds, in the bench profile (`cargo bench --no-run`, `cargo build
#   --profile bench`), the kfuse binary and the GPU criterion benches (fusion-gpu/decode,
#   kfuse/fusion_gpu), strips them and copies them with the four decoder test vectors the
#   decode bench reads (from $KFUSE_SHARED_DATA or ../shared/data, kinect-v2-vectors), this
#   script, benches/sequence_e2e.sh and benches/render_tables.py into OUT; prints its size
#   (the device tool carries 64 MiB). --kfuse BIN and --bench-exe take already-built
#   executables instead and build nothing (the tests use the test build's kfuse binary).
# run mode (on the device, from the bundle): prints the adapter's name, runs each bench
#   executable of the bundle (criterion defaults; --quick: tiny times), then the sequence end
#   to end on the GPU (`kfuse capture record --backend sim`, N frames, default 300, --quick 10;
#   `fuse --recording --engine gpu`, 2 threads) and writes FILE (default
#   results/device-run.json in the bundle), the format of benches/results/last-run.json, which
#   `render_tables.py render FILE BENCHMARKS.md` renders into the GPU tables.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
GPU_BENCHES="fusion-gpu/decode kfuse/fusion_gpu"
# The files of kinect-v2-vectors that crates/fusion-gpu/benches/decode.rs reads.
VECTOR_FILES="inputs/p0_tables_response.bin tables/xtable.f32 tables/ztable.f32 frames/scene.raw"
# What the device tool carries with a working tree (its README).
# KFUSE_BUNDLE_LIMIT_MIB raises it for tests only (tests/device_script.rs bundles the test build,
# whose unstripped-size executables are larger than the bench profile's).
BUNDLE_LIMIT_MIB=${KFUSE_BUNDLE_LIMIT_MIB:-64}
# run_all.sh's IDLE_LOAD: below it at most half a core was busy over the last minute.
IDLE_LOAD=0.5

usage() { awk 'NR == 1 { next } /^#/ { sub(/^# ?/, ""); print; next } { exit }' "$0"; }
die() { echo "device.sh: $*" >&2; exit 1; }

prepare() {
  local out=$1 kfuse=$2; shift 2
  local root; root=$(cd "$HERE/.." && pwd)
  [ -f "$root/Cargo.toml" ] || die "--prepare runs from the repository's benches/ ($root has no Cargo.toml)"
  local data=${KFUSE_SHARED_DATA:-$root/../shared/data}/kinect-v2-vectors
  [ -d "$data" ] || die "no decoder test vectors at $data: set KFUSE_SHARED_DATA to the shared data folder"
  local -A exes=()
  local built=0
  local spec
  for spec in "$@"; do exes[${spec%%=*}]=${spec#*=}; done
  if [ -z "$kfuse" ]; then
    built=1
    local target=${CARGO_TARGET_DIR:-$root/target}
    mkdir -p "$(dirname "$out")"
    (cd "$root" && cargo build --workspace --profile bench --bin kfuse) || die "the build of kfuse failed"
    kfuse=$target/release/kfuse
    [ -x "$kfuse" ] || kfuse=$target/bench/kfuse
    # Only the two GPU benches' targets (`--bench decode` also builds kinect-usb's CPU decode).
    (cd "$root" && cargo bench --workspace --bench decode --bench fusion_gpu --no-run --message-format=json-render-diagnostics) \
      >"$out.build.json" || die "the bench build failed (run: cargo bench --workspace --bench decode --bench fusion_gpu --no-run)"
    (cd "$root" && cargo metadata --no-deps --format-version 1) >"$out.metadata.json"
    local b
    for b in $GPU_BENCHES; do
      exes[$b]=$(python3 - "$b" "$out.build.json" "$out.metadata.json" <<'PY'
import json, sys
names = {p["manifest_path"]: p["name"] for p in json.load(open(sys.argv[3]))["packages"]}
for line in open(sys.argv[2]):
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m["target"]["kind"] == ["bench"] and m.get("executable") \
            and f'{names.get(m["manifest_path"])}/{m["target"]["name"]}' == sys.argv[1]:
        print(m["executable"])
PY
)
      [ -n "${exes[$b]}" ] || die "cargo built no executable for the bench $b"
    done
    rm -f "$out.build.json" "$out.metadata.json"
  fi
  [ -x "$kfuse" ] || die "the kfuse binary $kfuse is not an executable"
  rm -rf "$out"
  mkdir -p "$out/bin" "$out/data/kinect-v2-vectors" "$out/results"
  cp "$kfuse" "$out/bin/kfuse"
  for b in "${!exes[@]}"; do
    [ -x "${exes[$b]}" ] || die "bench executable ${exes[$b]} ($b) is not an executable"
    mkdir -p "$out/bin/benches/${b%%/*}"
    cp "${exes[$b]}" "$out/bin/benches/$b"
  done
  # Debug info and symbols are most of a binary's size; the device only runs them (the bundle
  # must fit the device tool's 64 MiB).
  find "$out/bin" -type f -exec strip --strip-all {} +
  local f
  for f in $VECTOR_FILES; do
    mkdir -p "$out/data/kinect-v2-vectors/$(dirname "$f")"
    cp "$data/$f" "$out/data/kinect-v2-vectors/$f"
  done
  cp "$HERE/device.sh" "$HERE/sequence_e2e.sh" "$HERE/render_tables.py" "$out/"
  if [ "$built" = 1 ]; then
    echo "bench profile ([profile.bench] of Cargo.toml), stripped (no debug info, no symbols)" >"$out/profile"
  else
    echo "executables given to --prepare (not the bench build), stripped (no debug info, no symbols)" >"$out/profile"
  fi
  git -C "$root" rev-parse HEAD >"$out/commit" 2>/dev/null || echo unknown >"$out/commit"
  local mib; mib=$(du -sm "$out" | cut -f1)
  echo "bundle: $out, $mib MiB (limit $BUNDLE_LIMIT_MIB MiB)"
  [ "$mib" -le "$BUNDLE_LIMIT_MIB" ] || die "the bundle $out is $mib MiB, over the device tool's $BUNDLE_LIMIT_MIB MiB"
}

run() {
  local quick=$1 frames=$2 results=$3
  [ -x "$HERE/bin/kfuse" ] || die "$HERE is not a bundle (no bin/kfuse): prepare one with benches/device.sh --prepare OUT"
  command -v python3 >/dev/null || die "python3 is needed to collect the results"
  RUN_DIR=$(mktemp -d); trap 'rm -rf "$RUN_DIR"' EXIT; local run=$RUN_DIR
  mkdir -p "$run/criterion" "$run/logs"
  local meta=$run/meta.txt
  : >"$meta"
  m() { printf '%s=%s\n' "$1" "$2" >>"$meta"; }
  local crit=(--noplot)
  [ "$quick" = 1 ] && crit=(--warm-up-time 0.1 --measurement-time 0.2 --sample-size 10 --noplot)
  # The adapter: what `fuse --engine gpu` prints for a one-frame recording.
  "$HERE/bin/kfuse" capture record --backend sim --frames 1 --out "$run/one.kfrec" 2>/dev/null
  local adapter
  adapter=$("$HERE/bin/kfuse" fuse --recording "$run/one.kfrec" --engine gpu --out "$run/one" 2>&1 >/dev/null \
    | sed -n 's/^GPU adapter: //p' | head -n1)
  [ -n "$adapter" ] || die "no GPU adapter: kfuse fuse --engine gpu found none (check the Vulkan driver)"
  echo "adapter: $adapter"
  m mode "$([ "$quick" = 1 ] && echo quick || echo full)"
  m criterion_args "${crit[*]}"
  m profile "$(cat "$HERE/profile" 2>/dev/null || echo "bench profile (benches/device.sh --prepare)")"
  m gpu_adapter "$adapter"
  m cpu "$(grep -m1 '^model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//')"
  m cores "$(nproc)"
  m memory_gib "$(awk '/^MemTotal:/ { printf "%.1f", $2 / 1048576 }' /proc/meminfo)"
  m os "$(. /etc/os-release 2>/dev/null && echo "${PRETTY_NAME:-unknown}") / Linux $(uname -r)"
  m commit "$(cat "$HERE/commit")"
  # No wait for an idle machine (the device's time is short): the header says whether it was.
  m idle_threshold "$IDLE_LOAD"
  m waited_s 0
  m idle_reached "$(awk -v l="$(cut -d' ' -f1 /proc/loadavg)" -v t="$IDLE_LOAD" 'BEGIN { print (l < t) ? "yes" : "no" }')"
  m load_start "$(cut -d' ' -f1-3 /proc/loadavg)"
  m start "$(date -u '+%Y-%m-%d %H:%M')"
  local exe target
  for exe in "$HERE"/bin/benches/*/*; do
    [ -x "$exe" ] || continue
    target=${exe#"$HERE/bin/benches/"}
    mkdir -p "$run/criterion/$target" "$run/logs/${target%%/*}"
    echo "== bench $target"
    if (cd "$run" && KFUSE_SHARED_DATA="$HERE/data" CRITERION_HOME="$run/criterion/$target" \
        "$exe" --bench "${crit[@]}") >"$run/logs/$target.log" 2>&1; then
      m "bench.$target" ok
    else
      m "bench.$target" "failed: exit $?"; tail -n 5 "$run/logs/$target.log"
    fi
  done
  echo "== sequence_e2e, GPU, $frames frames"
  m step.sequence_e2e.frames "$frames"
  m step.sequence_e2e.engine gpu
  m step.sequence_e2e.load_start "$(cut -d' ' -f1-3 /proc/loadavg)"
  m step.sequence_e2e.start "$(date -u '+%H:%M:%S')"
  if KFUSE_SEQ_WORK=$run KFUSE_SEQ_ENGINE=gpu KFUSE_SEQ_LAYOUTS=kfuse KFUSE_SEQ_THREADS=2 \
      bash "$HERE/sequence_e2e.sh" "$HERE/bin/kfuse" "$frames" >"$run/logs/step-sequence_e2e.log" 2>&1; then
    m step.sequence_e2e ok
  else
    m step.sequence_e2e "failed: exit $?"
  fi
  cat "$run/logs/step-sequence_e2e.log"
  m end "$(date -u '+%Y-%m-%d %H:%M')"
  m load_end "$(cut -d' ' -f1-3 /proc/loadavg)"
  mkdir -p "$(dirname "$results")"
  python3 "$HERE/render_tables.py" collect --meta "$meta" --criterion "$run/criterion" --log "$run/logs" --out "$results"
  python3 - "$results" "$adapter" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
r["tool"] = "benches/device.sh"
r["gpu_adapter"] = sys.argv[2]
json.dump(r, open(sys.argv[1], "w"), indent=1, sort_keys=True)
for t, b in sorted(r["benches"].items()):
    for name, x in sorted(b["results"].items()):
        print(f"{t} {name}: median {x['median_ns'] / 1e6:.2f} ms "
              f"({x['low_ns'] / 1e6:.2f}-{x['high_ns'] / 1e6:.2f} ms, 95 %)")
PY
  echo "== done: $results"
}

MODE=run QUICK=0 FRAMES= RESULTS= OUT= KFUSE= BENCH_EXES=()
while [ $# -gt 0 ]; do
  case "$1" in
    --prepare) MODE=prepare; OUT=${2:?--prepare needs an output folder}; shift ;;
    --kfuse) KFUSE=${2:?--kfuse needs an executable}; shift ;;
    --bench-exe) BENCH_EXES+=("${2:?--bench-exe needs PACKAGE/BENCH=EXE}"); shift ;;
    --quick) QUICK=1 ;;
    --frames) FRAMES=${2:?--frames needs a number}; shift ;;
    --results) RESULTS=${2:?--results needs a file}; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "device.sh: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
if [ "$MODE" = prepare ]; then
  prepare "$OUT" "$KFUSE" "${BENCH_EXES[@]}"
else
  [ -n "$FRAMES" ] || FRAMES=$([ "$QUICK" = 1 ] && echo 10 || echo 300)
  [[ $FRAMES =~ ^[1-9][0-9]*$ ]] || die "--frames '$FRAMES' is not a positive whole number"
  run "$QUICK" "$FRAMES" "${RESULTS:-$HERE/results/device-run.json}"
fi
