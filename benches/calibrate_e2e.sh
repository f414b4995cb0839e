#!/usr/bin/env bash
# `kfuse calibrate` end to end against OpenCV's own end-to-end script on the same files, in the
# same run (issue 33): 25 IR + 25 colour images of synthetic-calib (its 15 rendered poses
# cycled, as crates/calib/benches/calib.rs loads them), read + detect + calibrate both cameras
# + stereo, timed as whole processes (start-up included) REPS times each, alternating kfuse
# and OpenCV so both see the same machine load. Prints one line per tool (median and minimum
# process seconds; kfuse's stage split from its `--timings` lines; OpenCV's split from its
# script) and the load average before the runs: the machine may be shared, state it. Neither
# side writes figures (`--report` would add kfuse's report figures, which OpenCV has not).
#
#   benches/calibrate_e2e.sh KFUSE_BINARY SHARED_DATA [REPS] [PYTHON]
#
# PYTHON (default python3) must import cv2 and numpy (benches/run_all.sh passes its peers'
# venv); without cv2 the OpenCV line says so and only kfuse is timed.
set -euo pipefail
bin=$1
data=$2
reps=${3:-5}
py=${4:-python3}
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d -p "${TMPDIR:-/tmp}")
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/img"
for i in $(seq 0 24); do
  n=$(printf %02d $((i % 15 + 1)))
  m=$(printf %02d $((i + 1)))
  ln -s "$data/synthetic-calib/ir/ir_$n.png" "$work/img/ir_$m.png"
  ln -s "$data/synthetic-calib/color/color_$n.png" "$work/img/color_$m.png"
done
has_cv=0
"$py" -c 'import cv2, numpy' 2>/dev/null && has_cv=1
load=$(cut -d' ' -f1-3 /proc/loadavg)
: >"$work/kfuse.s"
: >"$work/opencv.s"
for r in $(seq "$reps"); do
  t0=$(date +%s.%N)
  "$bin" calibrate --ir "$work/img/ir_*.png" --color "$work/img/color_*.png" --board 7x5 --square 40mm \
    --out "$work/rig.json" --overwrite --timings >/dev/null 2>"$work/kfuse.err" \
    || { cat "$work/kfuse.err" >&2; exit 1; }
  t1=$(date +%s.%N)
  echo "$t0 $t1" >>"$work/kfuse.s"
  if [ $has_cv = 1 ]; then
    t0=$(date +%s.%N)
    "$py" "$here/peers/opencv_calibrate_e2e.py" --ir "$work/img/ir_*.png" --color "$work/img/color_*.png" \
      --board 7x5 --square 0.04 >"$work/opencv.out"
    t1=$(date +%s.%N)
    echo "$t0 $t1" >>"$work/opencv.s"
  fi
done
python3 - "$work" "$reps" "$load" "$has_cv" <<'PY'
import re, statistics, sys
work, reps, load, has_cv = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4] == "1"
def spans(f):
    return [float(b) - float(a) for a, b in (l.split() for l in open(f) if l.strip())]
k = spans(f"{work}/kfuse.s")
# `--timings` on stderr: "  NAME   12.3 ms   4.5 %  ..." per stage, after "timings: X ms wall".
stages = []
for line in open(f"{work}/kfuse.err"):
    m = re.match(r"^  (\S.*?) +([0-9.]+) ms +[0-9.]+ %", line)
    if m:
        stages.append((m.group(1), float(m.group(2))))
split = ", ".join(f"{n} {ms:.0f}" for n, ms in stages)
print(f"kfuse: 25+25 images, median {statistics.median(k):.3f} s, min {min(k):.3f} s over {reps} processes; "
      f"last run's stages ms: {split}; load before {load}")
if has_cv:
    o = spans(f"{work}/opencv.s")
    print(f"opencv process: median {statistics.median(o):.3f} s, min {min(o):.3f} s over {reps} processes "
          f"(Python start-up and import cv2 included); load before {load}")
    print(open(f"{work}/opencv.out").read().strip())
else:
    print("opencv: not timed (the Python given cannot import cv2 and numpy)")
PY
