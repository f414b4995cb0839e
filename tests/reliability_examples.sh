#!/usr/bin/env bash
# Every example of issue 12, rerun through a kfuse binary (the release build by default), with
# a table: exit status, seconds, peak RSS and the first error line of each run.
#
#   tests/reliability_examples.sh [path/to/kfuse]     (default: $CARGO_TARGET_DIR/release/kfuse)
#
# A run passes when it ends in one `error:` line and exit 1 or 2 (or 130 after a signal), or
# succeeds where success is right; it fails on a panic (101), an abort (134), a run over
# LIMIT_S seconds (killed: a hang) or over 1 GB peak RSS. Needs bash, python3, GNU time.
# Not run by CI (the cases that CI covers are tests in tests/cli_reliability.rs,
# tests/cli_memory.rs, tests/capture_cli.rs and the crates' corpus tests); it is the manual
# check that the issue's own examples end as the issue asks.
set -u
KFUSE=${1:-${CARGO_TARGET_DIR:-target}/release/kfuse}
KFUSE=$(realpath "$KFUSE")
HERE=$(cd "$(dirname "$0")" && pwd)
LIMIT_S=${LIMIT_S:-20}
W=$(mktemp -d /tmp/kfuse-examples.XXXXXX)
trap 'rm -rf "$W"' EXIT
cd "$W" || exit 1
FAILS=0
printf '| # | example | expected | exit | s | peak MB | result | first line |\n|---|---|---|---|---|---|---|---|\n'

# run NAME EXPECT(fail|ok|any) CMD...: one table row.
N=0
run() {
    local name=$1 expect=$2
    shift 2
    N=$((N + 1))
    local start end rc peak line verdict
    start=$(date +%s.%N)
    /usr/bin/time -f '%M' -o "$W/time.txt" timeout -s KILL "$LIMIT_S" "$@" >"$W/out.txt" 2>"$W/err.txt"
    rc=$?
    end=$(date +%s.%N)
    peak=$(( $(tail -n 1 "$W/time.txt" | tr -dc '0-9' || echo 0) / 1024 ))
    line=$(grep -m1 -E '^(error|warning)' "$W/err.txt" | cut -c1-150 | tr '|' '/')
    [ -z "$line" ] && line=$(head -n 1 "$W/err.txt" | cut -c1-150 | tr '|' '/')
    local errors
    errors=$(grep -c '^error' "$W/err.txt")
    verdict=ok
    if grep -q 'panicked' "$W/err.txt" || [ $rc -eq 101 ]; then verdict=PANIC
    elif [ $rc -eq 134 ] || [ $rc -eq 137 ] || [ $rc -eq 124 ]; then verdict="KILLED/HANG($rc)"
    elif [ "$peak" -gt 1024 ]; then verdict="OVER-1GB"
    elif [ "$expect" = fail ] && { [ $rc -eq 0 ] || [ "$errors" -ne 1 ]; }; then verdict="WRONG(exit $rc, $errors error lines)"
    elif [ "$expect" = ok ] && [ $rc -ne 0 ]; then verdict="WRONG(exit $rc)"
    fi
    [ "$verdict" = ok ] || FAILS=$((FAILS + 1))
    printf '| %d | %s | %s | %d | %.1f | %d | %s | %s |\n' "$N" "$name" "$expect" "$rc" \
        "$(echo "$end - $start" | bc)" "$peak" "$verdict" "$line"
}

# Inputs: the synthetic Kinect frame (kfuse demo), rigs with one field changed.
"$KFUSE" demo --out demo >/dev/null 2>&1 || { echo "kfuse demo failed"; exit 1; }
I=demo/input
rig_with() { # rig_with OUT PYTHON-EXPR-ON-r
    python3 - "$I/rig.json" "$1" "$2" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
exec(sys.argv[3])
json.dump(r, open(sys.argv[2], "w"))
EOF
}
rig_with rig_m.json 'r["depth_camera"]["fx"] = 0.00365; r["depth_camera"]["fy"] = 0.00365'
rig_with rig_tiny.json 'r["depth_camera"]["fx"] = 1e-300'
rig_with rig_mm.json 'r["depth_camera"]["fx"] = 3.65; r["depth_camera"]["fy"] = 3.65'
rig_with rig_T_mm.json 'r["color_from_depth"]["translation_m"] = [x * 1000 for x in r["color_from_depth"]["translation_m"]]'
rig_with rig_30000.json 'r["color_camera"]["width"] = 30000; r["color_camera"]["height"] = 30000'
F="--color $I/color.png --depth $I/depth.png --no-figures"

# --- Work and memory driven by a number in the input
run "fuse, depth fx in metres (0.00365)" fail "$KFUSE" fuse --rig rig_m.json $F --out o1
run "fuse, depth fx 1e-300" fail "$KFUSE" fuse --rig rig_tiny.json $F --out o2
run "fuse, depth fx in millimetres (3.65)" fail "$KFUSE" fuse --rig rig_mm.json $F --out o3
run "fuse, fx in metres, --force (bounded work)" any "$KFUSE" fuse --rig rig_m.json $F --force --out o3f
run "fuse --hole-radius 30" any "$KFUSE" fuse --rig $I/rig.json $F --hole-radius 30 --out o4
run "fuse --hole-radius 1e9" fail "$KFUSE" fuse --rig $I/rig.json $F --hole-radius 1e9 --out o5
run "fuse --gpu auto, fx in metres" fail "$KFUSE" fuse --rig rig_m.json $F --gpu auto --out o6
run "fuse --gpu auto --hole-radius 1e9" fail "$KFUSE" fuse --rig $I/rig.json $F --gpu auto --hole-radius 1e9 --out o7
mkdir -p viewdir && cp $I/color.png $I/depth.png viewdir/ && cp rig_m.json viewdir/rig.json
run "view, fx in metres (error line, then the error panel; no display here)" any env -u DISPLAY -u WAYLAND_DISPLAY "$KFUSE" view viewdir
python3 - <<'EOF'
import struct, zlib
def el(ty, data):
    b = struct.pack("<II", ty, len(data)) + data
    return b + b"\0" * (-len(b) % 8)
def mat(name, body):
    head = b"MATLAB 5.0 MAT-file, crafted".ljust(116, b" ") + b"\0" * 8 + struct.pack("<H", 0x0100) + b"IM"
    open(name, "wb").write(head + body)
def array(dims, n_bytes_declared):
    a = el(6, bytes([6, 0, 0, 0, 0, 0, 0, 0])) + el(5, struct.pack("<ii", *dims)) + el(1, b"D")
    a += struct.pack("<II", 9, n_bytes_declared)  # miDOUBLE, declared size, no data
    return struct.pack("<II", 14, len(a)) + a
mat("crafted184.mat", array((1000, 1000), 8_000_000)[:56])      # 184 bytes, declares 8 MB
mat("huge_dims.mat", array((2147483647, 2147483647), 0x7fffffff))
for n, name in [(200_000_000, "bomb_small.mat"), (2_000_000_000, "bomb_2g.mat")]:
    body = el(6, bytes([9, 0, 0, 0, 0, 0, 0, 0])) + el(5, struct.pack("<ii", 1, n)) + el(1, b"z")
    body += struct.pack("<II", 2, n)
    z = zlib.compressobj(9)
    c = z.compress(struct.pack("<II", 14, len(body) + n) + body)
    zeros = bytes(1 << 20)
    for _ in range(n >> 20):
        c += z.compress(zeros)
    c += z.flush()
    mat(name, struct.pack("<II", 15, len(c)) + c)
import os
open("random.mat", "wb").write(os.urandom(4096))
EOF
ls -l crafted184.mat bomb_small.mat bomb_2g.mat | awk '{print "#", $5, $9}' >&2
for m in crafted184.mat huge_dims.mat bomb_small.mat bomb_2g.mat; do
    run "fuse --mat $m ($(stat -c %s $m) bytes)" fail "$KFUSE" fuse --mat $m --out om
done
run "undistort, rig declaring 30000x30000" fail "$KFUSE" undistort --rig rig_30000.json --camera color $I/color.png --out u1
mkdir -p boards && cp $I/color.png boards/b1.png
run "calibrate --board 1000x1000" fail "$KFUSE" calibrate --color 'boards/*.png' --board 1000x1000 --out c1.json
run "calibrate --board 100000x100000" fail "$KFUSE" calibrate --color 'boards/*.png' --board 100000x100000 --out c2.json
python3 - <<'EOF'
import struct, zlib
w = h = 15000
def chunk(t, d):
    return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xffffffff)
z = zlib.compressobj(9)
raw = b""
row = b"\0" + bytes(w * 3)
c = b"".join(z.compress(row) for _ in range(h)) + z.flush()
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)) + chunk(b"IDAT", c) + chunk(b"IEND", b"")
open("big15000.png", "wb").write(png)
EOF
run "fuse, 15000x15000 PNG ($(( $(stat -c %s big15000.png) / 1024 )) KB) as colour" fail "$KFUSE" fuse --rig $I/rig.json --color big15000.png --depth $I/depth.png --out o8

# --- Panics and accepted nonsense (capture on the simulated sensor)
run "capture calib --interval inf" fail "$KFUSE" capture calib --backend sim --interval inf --out cap1
run "capture scene --interval 1e30" fail "$KFUSE" capture scene --backend sim --interval 1e30 --out cap2
run "capture scene --interval NaN" fail "$KFUSE" capture scene --backend sim --interval NaN --out cap3
run "capture scene --interval=-1" fail "$KFUSE" capture scene --backend sim --interval=-1 --out cap4
run "capture scene --sim-iso-drop=-0.5" fail "$KFUSE" capture scene --backend sim --interval 0 --sim-iso-drop=-0.5 --out cap5
run "capture scene --sim-iso-drop NaN" fail "$KFUSE" capture scene --backend sim --interval 0 --sim-iso-drop NaN --out cap6

# --- Outputs that are not all-or-nothing
"$KFUSE" fuse --rig $I/rig.json $F --out reuse >/dev/null 2>&1
echo stale >reuse/stale_from_user.txt
run "fuse, reused --out (user's file kept, own outputs replaced)" ok "$KFUSE" fuse --rig $I/rig.json $F --resample nearest --out reuse
echo "#   reused --out afterwards: $(ls reuse | tr '\n' ' ')" >&2
mkdir -p dirout/summary.json && echo keep >dirout/summary.json/mine.txt
run "fuse, --out holds a folder named summary.json" fail "$KFUSE" fuse --rig $I/rig.json $F --out dirout
[ -f dirout/summary.json/mine.txt ] || { echo "#   user's summary.json/mine.txt LOST" >&2; FAILS=$((FAILS + 1)); }
echo x >afile
run "fuse --out naming an existing file" fail "$KFUSE" fuse --rig $I/rig.json $F --out afile
run "fuse --out at a mount point (/dev/shm)" ok "$KFUSE" fuse --rig $I/rig.json $F --out /dev/shm
if [ -f /dev/shm/.kfuse-manifest.json ]; then
    python3 -c 'import json,os; m=json.load(open("/dev/shm/.kfuse-manifest.json")); [os.remove("/dev/shm/"+f) for f in m.get("files", [])]' 2>/dev/null
    rm -f /dev/shm/.kfuse-manifest.json
fi
# A run killed at random moments leaves --out whole or absent, and no staging.
for delay in 0.2 0.5 0.9 1.4; do
    "$KFUSE" fuse --rig $I/rig.json --color $I/color.png --depth $I/depth.png --out killed >/dev/null 2>&1 &
    pid=$!
    sleep $delay
    kill -KILL $pid 2>/dev/null
    wait $pid 2>/dev/null
done
run "fuse after 4 killed runs (staging removed, --out whole)" ok "$KFUSE" fuse --rig $I/rig.json $F --out killed
left=$(find . -maxdepth 1 -name '.*partial*' -o -maxdepth 1 -name '.*staging*' | wc -l)
echo "#   staging folders left after the next run: $left" >&2
for sig in INT TERM; do
    "$KFUSE" fuse --rig $I/rig.json --color $I/color.png --depth $I/depth.png --out sig$sig >/dev/null 2>"$W/sig.txt" &
    pid=$!
    sleep 0.6
    kill -$sig $pid
    wait $pid
    echo "#   SIG$sig during fuse: exit $?, --out exists: $([ -e sig$sig ] && echo yes || echo no), $(grep -m1 error "$W/sig.txt")" >&2
done
mkdir -p cal && cp $I/color.png cal/c1.png
run "calibrate --out in a missing folder" fail "$KFUSE" calibrate --color 'cal/*.png' --out nofolder/rig.json
run "calibrate, bad --opencv-yaml folder" fail "$KFUSE" calibrate --color 'cal/*.png' --out cal_rig.json --opencv-yaml nofolder/r.yaml
[ -e cal_rig.json ] && { echo "#   cal_rig.json LEFT" >&2; FAILS=$((FAILS + 1)); }
run "calibrate --out naming an input image" fail "$KFUSE" calibrate --color 'cal/*.png' --out cal/c1.png
mkdir -p ua ub && cp $I/color.png ua/x.png && cp $I/color.png ub/x.png
run "undistort, two inputs with one base name" fail "$KFUSE" undistort --rig $I/rig.json --camera color ua/x.png ub/x.png --out und
[ -e und ] && { echo "#   und/ written by a refused undistort" >&2; FAILS=$((FAILS + 1)); }

# --- Captured data
run "capture record (sim, 3 frames)" ok "$KFUSE" capture record --backend sim --frames 3 --output r.kfrec
"$KFUSE" capture record --backend sim --frames 100000 --output rint.kfrec >/dev/null 2>&1 &
pid=$!
# Interrupt once frames are being written (the file passes 4 MB), at most 30 s.
for _ in $(seq 300); do
    [ "$(stat -c %s rint.kfrec 2>/dev/null || echo 0)" -gt 4000000 ] && break
    sleep 0.1
done
kill -INT $pid
wait $pid
echo "#   SIGINT during capture record: exit $?, files: $(ls -a | grep -c 'rint')" >&2
run "replay of the Ctrl-C'd recording, no flags" ok "$KFUSE" capture scene --interval 0 --replay rint.kfrec --out rsc
python3 - <<'EOF'
import random
b = bytearray(open("r.kfrec", "rb").read())
random.seed(12)
for _ in range(200):
    i = random.randrange(64, len(b))
    b[i] ^= 1 << random.randrange(8)
open("flipped.kfrec", "wb").write(b)
b = open("r.kfrec", "rb").read()
open("cut.kfrec", "wb").write(b[: len(b) // 2])
v1 = bytearray(b); v1[8:12] = (1).to_bytes(4, "little")
open("v1.kfrec", "wb").write(v1)
EOF
run "replay with 200 bit flips" fail "$KFUSE" capture scene --interval 0 --replay flipped.kfrec --out rfl
run "replay of a truncated recording (names --allow-truncated)" fail "$KFUSE" capture scene --interval 0 --replay cut.kfrec --out rcut
run "replay of a version-1 recording" fail "$KFUSE" capture scene --interval 0 --replay v1.kfrec --out rv1
if "$KFUSE" capture calib --backend sim --count 1 --interval 0 --out jp >/dev/null 2>&1; then
    j=$(ls jp/color_*.jpg | head -n 1)
    head -c $(( $(stat -c %s "$j") / 10 )) "$j" >trunc.jpg
    python3 - "$I/rig.json" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
r["color_camera"]["width"], r["color_camera"]["height"] = 1920, 1080
json.dump(r, open("rig_1080.json", "w"))
EOF
    run "fuse, JPEG truncated to 10 %" fail "$KFUSE" fuse --rig rig_1080.json --color trunc.jpg --depth $I/depth.png --out ojpg
fi
run "capture scene --name ../../x" fail "$KFUSE" capture scene --backend sim --interval 0 --name ../../x --out cap7
run "capture scene --name /abs/x" fail "$KFUSE" capture scene --backend sim --interval 0 --name "$W/absx" --out cap8

# --- Messages
run "fuse --mat random bytes (.mat)" fail "$KFUSE" fuse --mat random.mat --out om2
run "fuse --mat a PNG" fail "$KFUSE" fuse --mat $I/color.png --out om3
rig_with rig_rot.json 'r["color_from_depth"]["rotation"] = [[1, 0, 0], [0, 5, 0], [0, 0, 1]]'
run "fuse, rig rotation not a rotation" fail "$KFUSE" fuse --rig rig_rot.json $F --out o9
run "calibrate --square 1e308m" fail "$KFUSE" calibrate --color 'cal/*.png' --square 1e308m --out c3.json
for s in 1e40 NaN 0 -1; do
    run "fuse --depth-scale $s" fail "$KFUSE" fuse --rig $I/rig.json $F --depth-scale=$s --out ods
done
run "fuse --engine gpu (no XDG_RUNTIME_DIR line)" ok env -u XDG_RUNTIME_DIR -u WAYLAND_DISPLAY "$KFUSE" fuse --rig $I/rig.json $F --engine gpu --out ogpu
grep -q XDG_RUNTIME_DIR "$W/err.txt" && { echo "#   XDG_RUNTIME_DIR line printed" >&2; FAILS=$((FAILS + 1)); }
mkdir -p lit && cp $I/color.png 'lit/shot[1].png'
run "calibrate --color 'shot[1].png' (literal name; no board: fails on detection, not on the name)" fail "$KFUSE" calibrate --color 'lit/shot[1].png' --out lit.json
grep -q "no file matches" "$W/err.txt" && { echo "#   shot[1].png not found" >&2; FAILS=$((FAILS + 1)); }
SHARED=${KFUSE_SHARED_DATA:-$HERE/../../shared/data}
if [ -d "$SHARED/synthetic-calib/color" ]; then
    mkdir -p dup/a dup/b
    for i in 01 02 03 04; do cp "$SHARED/synthetic-calib/color/color_$i.png" dup/a/; done
    for i in 05 06 07 08; do cp "$SHARED/synthetic-calib/color/color_$i.png" "dup/b/color_$(printf %02d $((10#$i - 4))).png"; done
    run "calibrate, a/color_01.png and b/color_01.png (report figures)" ok "$KFUSE" calibrate --color 'dup/a/*.png' --color 'dup/b/*.png' --board auto --out dup.json --report dupr
    echo "#   corner figures: $(ls dupr | grep -c '^corners_') for 8 images" >&2
fi

echo
echo "cases: $N, not as expected: $FAILS"
[ "$FAILS" -eq 0 ]
