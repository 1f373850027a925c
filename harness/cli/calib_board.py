"""``rt2 calib board``: every camera's pose from a ChArUco board seen by several cameras at once.

One synchronised video (or image folder) per camera: frame k of every source is frame set k. Without
``--intrinsics`` each camera's intrinsics are calibrated first from its own video (as
``rt2 calib intrinsics`` does). Writes the rig YAML (camera 0 = world), a JSON report and the
optional exports.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.calib.compare import compare_rigs
from harness.calib.exports import add_export_arguments, read_anipose_toml, save_calibration
from harness.calib.inputs import load_board, load_intrinsics
from harness.calib.intrinsics import detect_views, intrinsics_camera
from harness.cli.calib_intrinsics import format_intrinsics
from tracker import Camera, Rig
from tracker.calibration.board_rig import calibrate_board_rig
from tracker.calibration.intrinsics import IntrinsicsOptions, calibrate_intrinsics

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("--videos", required=True, nargs="+", help="one synchronised video or image folder per camera")
    parser.add_argument("--board", required=True, help="board spec (.yaml, or caliscope's charuco.toml)")
    parser.add_argument("--out", required=True, help="rig file to write")
    parser.add_argument("--intrinsics", nargs="+", default=None, help="rig / OpenCV files with the cameras' intrinsics (default: calibrate from the videos)")
    parser.add_argument("--names", default=None, help="comma-separated camera names (default: the video stems)")
    parser.add_argument("--fix-k3", action="store_true", help="when calibrating intrinsics: hold k3 at 0")
    parser.add_argument("--every", type=int, default=1, help="use every n-th frame set")
    parser.add_argument("--holdout-every", type=int, default=5, help="hold out every n-th frame set for the square-size check")
    parser.add_argument("--reference", default=None, help="a reference calibration to compare with: rt2 rig file or aniposelib / caliscope .toml")
    add_export_arguments(parser)


def run(args) -> int:
    if args.holdout_every < 0:  # 0 and 1: none held out
        raise ValueError(f"--holdout-every must be >= 0 (0: none held out), got {args.holdout_every}")
    spec = load_board(args.board)
    names = args.names.split(",") if args.names else [Path(v).stem for v in args.videos]
    if len(names) != len(args.videos) or len(set(names)) != len(names):
        raise ValueError(f"--names must give {len(args.videos)} distinct names, got {names}")
    ref = None
    if args.reference:
        ref = read_anipose_toml(args.reference) if str(args.reference).endswith(".toml") else Rig.load(args.reference)
    given = load_intrinsics(args.intrinsics, names=names) if args.intrinsics else None
    views, cams, lines, mirrored = [], [], [], []
    for c, (src, name) in enumerate(zip(args.videos, names)):
        v, size, mir, _ = detect_views(src, spec, every=args.every)
        views.append(v)
        mirrored.append(mir)
        if given is not None:
            cams.append(given[c])
        else:
            res = calibrate_intrinsics(v, spec, size, IntrinsicsOptions(fix_k3=args.fix_k3), camera=name)
            cams.append(intrinsics_camera(name, res))
            lines.append(format_intrinsics(name, res, len(v), mir))
    F = min(len(v) for v in views)
    if any(len(v) != F for v in views):
        raise ValueError(f"the sources hold different frame counts {[len(v) for v in views]} for {names}; they must be synchronised")
    from tracker.calibration.board_rig import BoardRigOptions

    res = calibrate_board_rig(cams, views, spec, BoardRigOptions(holdout_every=args.holdout_every))
    rig = Rig([Camera(c.name, c.K, c.distortion, res.R[i], res.t[i], c.image_size) for i, c in enumerate(cams)],
              description=f"ChArUco board calibration from {len(args.videos)} synchronised sources ({len(res.fit_frames)} frame sets)")
    sq = res.square_m * 1000
    report = {"cameras": names, "mirrored": dict(zip(names, mirrored)), "fit_frames": int(len(res.fit_frames)),
              "holdout_frames": int(len(res.holdout_frames)), "reprojection_px": res.reproj_px,
              "shared_frame_sets": {f"{names[i]}-{names[j]}": k for (i, j), k in res.shared.items()},
              "square_mm": {"known": spec.square_m * 1000, "n": int(len(sq)),
                            "median": float(np.median(sq)) if len(sq) else None,
                            "iqr": float(np.subtract(*np.percentile(sq, [75, 25]))) if len(sq) else None}}
    if ref is not None:
        report["reference"] = compare_rigs(rig, ref)
    written = save_calibration(rig, report, args, error=float(np.mean([v["rms_px"] for v in res.reproj_px.values()])))
    for ln in lines:
        print(ln)
    print(f"{len(names)} cameras, {report['fit_frames']} frame sets fitted, {report['holdout_frames']} held out; world: {names[0]}")
    for n_, r in res.reproj_px.items():
        print(f"  {n_:>10s}: rms {r['rms_px']:.2f} px, median {r['median_px']:.2f} px, {r['observations']} corners"
              + (" (board seen mirrored)" if report["mirrored"][n_] else ""))
    s = report["square_mm"]
    if s["n"]:
        print(f"square size triangulated on held-out frame sets: median {s['median']:.2f} mm (known {s['known']:.1f}), IQR {s['iqr']:.2f} mm, n {s['n']}")
    if ref is not None:
        print("against the reference: " + ", ".join(f"{p}: rot {d['rotation_deg']:.2f} deg, baseline {d['baseline_m'] * 1000:.0f} vs "
                                                     f"{d['baseline_ref_m'] * 1000:.0f} mm" for p, d in report["reference"]["pairs"].items()))
    print("wrote " + ", ".join(written))
    return 0
