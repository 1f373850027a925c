"""``rt2 calib intrinsics``: one camera's K and distortion from ChArUco images or a video.

Writes a one-camera rig file (identity extrinsics; the wand / board commands place it) and a JSON
report next to it (per-view errors, rejected views, coverage, standard deviations).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.calib.exports import add_export_arguments, save_calibration
from harness.calib.inputs import load_board
from harness.calib.intrinsics import detect_views, intrinsics_camera
from tracker import Rig
from tracker.calibration.intrinsics import IntrinsicsOptions, calibrate_intrinsics

__all__ = ["add_arguments", "format_intrinsics", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("--images", required=True, help="a video file or a folder of images of the ChArUco board")
    parser.add_argument("--board", required=True, help="board spec (.yaml with columns, rows, square_m, marker_m, dictionary; or caliscope's charuco.toml)")
    parser.add_argument("--out", required=True, help="rig file to write (one camera, identity extrinsics)")
    parser.add_argument("--name", default=None, help="camera name (default: the video / folder stem)")
    parser.add_argument("--model", default="plumb_bob", choices=["plumb_bob", "rational_polynomial"])
    parser.add_argument("--fix-k3", action="store_true", help="hold k3 at 0 (few views or narrow lens)")
    parser.add_argument("--every", type=int, default=1, help="use every n-th frame (default 1)")
    parser.add_argument("--max-frames", type=int, default=None, help="use at most this many frames")
    parser.add_argument("--mirror", choices=["auto", "no", "yes"], default="auto",
                        help="the board appears mirrored (seen from behind): detect in the flipped image; 'auto' tries both")
    add_export_arguments(parser)


def run(args) -> int:
    spec = load_board(args.board)
    name = args.name or Path(args.images).stem
    views, size, mirrored, names = detect_views(args.images, spec, every=args.every, max_frames=args.max_frames, mirror=args.mirror)
    opts = IntrinsicsOptions(model=args.model, fix_k3=args.fix_k3)
    res = calibrate_intrinsics(views, spec, size, opts, camera=name)
    cam = intrinsics_camera(name, res)
    rig = Rig([cam], description=f"intrinsics of {name} from {args.images} ({int(res.kept.sum())} ChArUco views"
                                  f"{', board seen mirrored' if mirrored else ''})")
    report = {
        "camera": name, "images": str(args.images), "board": str(args.board), "image_size": list(size), "mirrored": mirrored,
        "model": res.model, "K": res.K.tolist(), "distortion": res.distortion.tolist(), "std": res.std,
        "rms_px": res.rms_px, "views": len(views), "views_used": int(res.kept.sum()),
        "view_rms_px": {names[i]: (None if np.isnan(e) else round(float(e), 4)) for i, e in enumerate(res.view_rms_px)},
        "rejected": {names[i]: why for i, why in res.rejected.items()},
        "coverage_cells": res.coverage.tolist(), "coverage_fraction": res.coverage_fraction,
    }
    written = save_calibration(rig, report, args, error=res.rms_px)
    print(format_intrinsics(name, res, len(views), mirrored))
    print("wrote " + ", ".join(written))
    return 0


def format_intrinsics(name, res, n_views: int, mirrored: bool = False) -> str:
    s = res.std
    K = res.K
    lines = [
        f"camera {name}: {int(res.kept.sum())} of {n_views} views used, RMS reprojection error {res.rms_px:.3f} px"
        + (" (board seen mirrored: detected in the flipped image)" if mirrored else ""),
        f"  fx {K[0, 0]:.2f} +- {s['fx']:.2f}  fy {K[1, 1]:.2f} +- {s['fy']:.2f}  cx {K[0, 2]:.2f} +- {s['cx']:.2f}  cy {K[1, 2]:.2f} +- {s['cy']:.2f} px",
        "  distortion (" + res.model + ") " + ", ".join(f"{n} {v:+.4f} +- {s[n]:.4f}" for n, v in zip(list(s)[4:], res.distortion)),
    ]
    reasons: dict[str, int] = {}
    for why in res.rejected.values():
        key = "too few corners" if "corners" in why else ("high error" if "RMS" in why else why)
        reasons[key] = reasons.get(key, 0) + 1
    if reasons:
        lines.append("  not used: " + ", ".join(f"{n} views ({k})" for k, n in reasons.items()))
    lines.append(f"  coverage: corners in {100 * res.coverage_fraction:.0f} % of {res.coverage.size} image cells (rows top to bottom):")
    lines += ["    " + " ".join(f"{c:5d}" for c in row) for row in res.coverage]
    return "\n".join(lines)
