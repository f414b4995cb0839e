#!/usr/bin/env python3
"""OpenCV's end-to-end stereo calibration of an image set, as a user's script does it: read
every image (cv2.imread), detect (findChessboardCorners with ADAPTIVE_THRESH | NORMALIZE_IMAGE,
then cornerSubPix: window (4,4) IR / (5,5) colour, EPS|COUNT 30, 1e-3 — the settings of
synthetic-calib/opencv_reference.json), calibrateCamera for each camera (5 coefficients), then
stereoCalibrate (CALIB_USE_INTRINSIC_GUESS). The counterpart of `kfuse calibrate --ir … --color …`
in benches/calibrate_e2e.sh, which runs both on the same files in the same run.

    opencv_calibrate_e2e.py --ir 'DIR/ir_*.png' --color 'DIR/color_*.png' --board 7x5 --square 0.04

Prints one line: `opencv: N pairs, S s in the script (read R s, detect D s, calibrate C s),
rms IR/colour/stereo px`. Pairs where either camera finds no board are left out of the fits.
"""

import argparse
import glob
import time

import cv2
import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ir", required=True)
    ap.add_argument("--color", required=True)
    ap.add_argument("--board", default="7x5")
    ap.add_argument("--square", type=float, default=0.04)
    a = ap.parse_args()
    cols, rows = (int(v) for v in a.board.split("x"))
    t0 = time.perf_counter()
    ir_files, color_files = sorted(glob.glob(a.ir)), sorted(glob.glob(a.color))
    ir = [cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in ir_files]
    color = [cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in color_files]
    t1 = time.perf_counter()
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 1e-3)

    def detect(img, win):
        ok, c = cv2.findChessboardCorners(img, (cols, rows), flags)
        if not ok:
            return None
        return cv2.cornerSubPix(img, c, win, (-1, -1), crit)

    det = [(detect(i, (4, 4)), detect(c, (5, 5))) for i, c in zip(ir, color)]
    t2 = time.perf_counter()
    obj = np.zeros((cols * rows, 3), np.float32)
    obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * a.square
    pairs = [(d, c) for d, c in det if d is not None and c is not None]
    objs = [obj] * len(pairs)
    ir_pts, color_pts = [p[0] for p in pairs], [p[1] for p in pairs]
    rms_ir, k1, d1, _, _ = cv2.calibrateCamera(objs, ir_pts, ir[0].shape[::-1], None, None)
    rms_c, k2, d2, _, _ = cv2.calibrateCamera(objs, color_pts, color[0].shape[::-1], None, None)
    rms_s, *_ = cv2.stereoCalibrate(objs, ir_pts, color_pts, k1, d1, k2, d2, ir[0].shape[::-1],
                                    flags=cv2.CALIB_USE_INTRINSIC_GUESS)
    t3 = time.perf_counter()
    print(f"opencv: {len(pairs)} pairs, {t3 - t0:.3f} s in the script (read {t1 - t0:.3f} s, detect {t2 - t1:.3f} s, "
          f"calibrate {t3 - t2:.3f} s), rms {rms_ir:.3f}/{rms_c:.3f}/{rms_s:.3f} px, OpenCV {cv2.__version__}, "
          f"threads {cv2.getNumThreads()}")


if __name__ == "__main__":
    main()
