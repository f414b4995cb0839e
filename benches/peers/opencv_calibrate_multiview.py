#!/usr/bin/env python3
"""OpenCV 5's cv2.calibrateMultiview on the corners kfuse detected (issue 32's peer).

Reads the `detections` of `kfuse calibrate --camera/--shots --report DIR` (DIR/report.json,
format kfuse-multi-detections: per camera its image size and per view id its corners
[id, x, y], 0-based pixels), calibrates every camera jointly with calibrateMultiview
(pinhole, OpenCV's 5-coefficient model k1 k2 p1 p2 k3, as kfuse's default) and writes its rig:

    {"format": "opencv-calibrate-multiview", "opencv": VERSION, "rms_px": ...,
     "reference": NAME, "cameras": [{"name", "width", "height", "fx", "fy", "cx", "cy",
     "k1", "k2", "p1", "p2", "k3",
     "camera_from_reference": {"rotation": 3x3, "translation_m": [3]}}],
     "views_used": N, "views_left_out_partial": N}

The reference is camera 0 of the call: the report's reference camera is put first.
calibrateMultiview takes whole boards only (every frame the same points), so a view with a
partial board is left out for that camera (counted in views_left_out_partial).

    opencv_calibrate_multiview.py REPORT.json OUT.json
"""
import json
import sys

import cv2
import numpy as np


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: opencv_calibrate_multiview.py REPORT.json OUT.json")
    report = json.load(open(sys.argv[1]))
    det = report.get("detections", report)
    if det.get("format") != "kfuse-multi-detections":
        sys.exit(f"{sys.argv[1]}: no kfuse-multi-detections in it")
    board = det["board"]
    cols, rows, square = board["cols"], board["rows"], board["square_m"]
    n_points = cols * rows
    cams = det["cameras"]
    reference = report.get("reference", cams[0]["name"])
    order = sorted(range(len(cams)), key=lambda i: cams[i]["name"] != reference)
    cams = [cams[i] for i in order]
    view_ids = sorted({v["view_id"] for c in cams for v in c["views"]})
    frame = {v: k for k, v in enumerate(view_ids)}
    obj = np.zeros((n_points, 3), np.float32)
    for i in range(n_points):
        obj[i] = (square * (i % cols), square * (i // cols), 0.0)
    image_points = np.zeros((len(cams), len(view_ids), n_points, 2), np.float32)
    mask = np.zeros((len(cams), len(view_ids)), np.uint8)
    partial = 0
    for ci, c in enumerate(cams):
        for v in c["views"]:
            corners = v["corners"]
            if len(corners) != n_points:
                partial += 1
                continue
            k = frame[v["view_id"]]
            for cid, x, y in corners:
                image_points[ci, k, int(cid)] = (x, y)
            mask[ci, k] = 1
    # Frames no camera saw whole are dropped (calibrateMultiview needs each frame seen).
    keep = [k for k in range(len(view_ids)) if mask[:, k].any()]
    image_points = image_points[:, keep]
    mask = np.ascontiguousarray(mask[:, keep])
    obj_points = [obj] * len(keep)
    sizes = [(c["width"], c["height"]) for c in cams]
    models = np.full((len(cams), 1), cv2.CALIB_MODEL_PINHOLE, np.uint8)
    flags_intr = np.zeros((len(cams), 1), np.int32)
    img = [[image_points[ci, k] for k in range(len(keep))] for ci in range(len(cams))]
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, Ks, dists, Rs, Ts = cv2.calibrateMultiview(
        obj_points, img, sizes, mask, models, None, None, None, None,
        flags_intr, 0, criteria)
    out = []
    for ci, c in enumerate(cams):
        K = np.asarray(Ks[ci], float)
        d = np.asarray(dists[ci], float).ravel().tolist() + [0.0] * 5
        R = np.asarray(Rs[ci], float)
        if R.shape != (3, 3):
            R, _ = cv2.Rodrigues(R.reshape(3))
        t = np.asarray(Ts[ci], float).reshape(3)
        out.append({
            "name": c["name"], "width": c["width"], "height": c["height"],
            "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
            "k1": d[0], "k2": d[1], "p1": d[2], "p2": d[3], "k3": d[4],
            "camera_from_reference": {"rotation": R.tolist(), "translation_m": t.tolist()},
        })
    json.dump({
        "format": "opencv-calibrate-multiview", "opencv": cv2.__version__, "rms_px": float(rms),
        "reference": cams[0]["name"], "cameras": out, "views_used": int(mask.sum()),
        "views_left_out_partial": partial,
    }, open(sys.argv[2], "w"), indent=1)


if __name__ == "__main__":
    main()
