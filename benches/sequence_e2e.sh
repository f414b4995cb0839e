#!/usr/bin/env bash
# Sequence benchmark through the binary (issue 15): a 300-frame simulated recording
# (`kfuse capture record --backend sim`) through `kfuse fuse --recording` end to end, with 1
# and 2 worker threads, in the kfuse layout (registered depth only: decode + register + write
# registered depth) and the TUM layout (plus the JPEG copies and lists). Prints frames/s, the
# per-stage seconds from index.json and the load average before each run (the machine is
# shared: state it with the figures).
#
#   benches/sequence_e2e.sh [KFUSE_BINARY] [FRAMES]
#
# KFUSE_SEQ_ENGINE (default cpu) is passed as `--engine`, KFUSE_SEQ_LAYOUTS (default "kfuse tum")
# and KFUSE_SEQ_THREADS (default "1 2") choose the runs (benches/device.sh: gpu, kfuse, 2).
# Default binary: $CARGO_TARGET_DIR/release/kfuse (build it with `cargo build --release -p kfuse`).
# The recording (~3.2 MB a frame) and the outputs go to a temporary folder under
# $KFUSE_SEQ_WORK (default $TMPDIR or /tmp), deleted on exit. benches/run_all.sh runs this with
# its own build's binary and collects the lines printed here (benches/render_tables.py).
set -euo pipefail
bin=${1:-${CARGO_TARGET_DIR:-target}/release/kfuse}
frames=${2:-300}
work=$(mktemp -d -p "${KFUSE_SEQ_WORK:-${TMPDIR:-/tmp}}")
trap 'rm -rf "$work"' EXIT
"$bin" capture record --backend sim --frames "$frames" --out "$work/s.kfrec" 2>/dev/null
echo "recording: $frames frames, $(du -m "$work/s.kfrec" | cut -f1) MB"
for layout in ${KFUSE_SEQ_LAYOUTS:-kfuse tum}; do
  for threads in ${KFUSE_SEQ_THREADS:-1 2}; do
    out="$work/out-$layout-$threads"
    load=$(cut -d' ' -f1-3 /proc/loadavg)
    t0=$(date +%s.%N)
    "$bin" fuse --recording "$work/s.kfrec" --layout "$layout" --threads "$threads" --engine "${KFUSE_SEQ_ENGINE:-cpu}" --out "$out" >/dev/null 2>"$work/err"
    t1=$(date +%s.%N)
    python3 - "$out/index.json" "$layout" "$threads" "$t0" "$t1" "$load" <<'PY'
import json, sys
ix = json.load(open(sys.argv[1]))
layout, threads, t0, t1, load = sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5]), sys.argv[6]
n = len(ix["frames"])
s = ix["stage_s"]
per = lambda k: 1e3 * s[k] / max(n, 1)
print(f"layout {layout:5} threads {threads}: {n} frames, {n / ix['wall_s']:.1f} frames/s in the pipeline "
      f"({n / (t1 - t0):.1f} frames/s process, start-up included); per frame ms: read {per('read'):.2f} "
      f"decode {per('decode'):.2f} register {per('register'):.2f} encode {per('encode'):.2f} "
      f"write {per('write'):.2f}; missing {len(ix['missing'])}; load before {load}")
PY
    du -sm "$out" | awk '{print "  output: " $1 " MB"}'
  done
done
