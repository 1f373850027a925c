"""``rt2 calib wand``: every camera's pose from a wand waved through the volume (bundle adjustment).

Input: a folder of per-camera 2D detection CSVs (``timestamp;u1;v1;u2;v2;...``, the ewand layout,
one file per camera in the order of ``--intrinsics``) or an rt2 session log (``.mcap``) whose
``/camera/<name>/detections`` hold the wand's balls (labelled here by their order along the wand).
Writes the rig YAML (camera 0 = world, or the frame of ``--world-points``), a JSON report and the
optional exports (OpenCV FileStorage, aniposelib calibration.toml). The calibration is
:func:`harness.calib.wand.calibrate_recording`; this module parses the options and prints.
"""

from __future__ import annotations

import numpy as np

from harness.calib.exports import add_export_arguments, save_calibration
from harness.calib.wand import calibrate_recording

__all__ = ["add_arguments", "format_report", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("--recording", required=True, help="folder of per-camera detection CSVs, or a session log (.mcap) with detections")
    parser.add_argument("--intrinsics", required=True, nargs="+", help="rt2 rig files and/or OpenCV FileStorage files, in camera order")
    parser.add_argument("--wand", default=None, help="spacings between consecutive balls, metres, e.g. 0.13,0.26")
    parser.add_argument("--ball", action="store_true",
                        help="a single ball instead of a wand (no length in it: needs --world-points for the scale)")
    parser.add_argument("--out", required=True, help="rig file to write")
    parser.add_argument("--world-points", default=None,
                        help="YAML list of {world_m: [x, y, z], pixels: {camera: [u, v], ...}}: >= 3 points (e.g. table corners) fixing the world frame")
    parser.add_argument("--reference", default=None, nargs="+",
                        help="a reference calibration to compare with (rt2 rig file or OpenCV files, camera order as --intrinsics): relative rotations, baselines, wand lengths")
    parser.add_argument("--holdout-every", type=int, default=5, help="hold out every n-th frame set for the wand-length check (default 5)")
    parser.add_argument("--every", type=int, default=1, help="use every n-th frame set (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of OpenCV's RANSAC (same seed, same result)")
    add_export_arguments(parser)


def run(args) -> int:
    if args.holdout_every < 0:  # 0 and 1: none held out
        raise ValueError(f"--holdout-every must be >= 0 (0: none held out), got {args.holdout_every}")
    cal = calibrate_recording(args.recording, args.intrinsics, wand=args.wand, ball=args.ball, world_points=args.world_points,
                              reference=args.reference, holdout_every=args.holdout_every, every=args.every, seed=args.seed)
    written = save_calibration(cal.rig, cal.report, args, error=cal.error_px)
    if args.ball:
        rep = cal.report
        print(f"{len(rep['cameras'])} cameras from a single ball ({rep['frames']} frame sets); scale and world frame from "
              f"{rep['world']['points']} points, residual {np.round(cal.world_residual_m * 1000, 1).tolist()} mm")
        for n, r in rep["reprojection_px"].items():
            print(f"  {n:>12s}: rms {r['rms_px']:.2f} px, median {r['median_px']:.2f} px, {r['observations']} obs")
    else:
        print(format_report(cal.report))
    print("wrote " + ", ".join(written))
    return 0


def format_report(rep: dict) -> str:
    lines = [f"{len(rep['cameras'])} cameras, {rep['fit_frames']} frame sets fitted, {rep['holdout_frames']} held out; world: "
             + (rep["world"] if isinstance(rep["world"], str) else f"{rep['world']['points']} points, residual {rep['world']['fit_residual_mm']} mm")]
    lines.append("reprojection error per camera (fitted frames; held-out median):")
    for n, r in rep["reprojection_px"].items():
        lines.append(f"  {n:>12s}: rms {r['rms_px']:.2f} px, median {r['median_px']:.2f} px, {r['observations']} obs, "
                     f"{r['outliers']} outliers; held-out median {r['holdout_median_px']:.2f} px")
    lines.append("wand lengths on held-out frame sets (mm): " + _lengths_line(rep["holdout_wand_mm"]))
    ref = rep.get("reference")
    if ref:
        lines.append("against the reference rig: " + ", ".join(
            f"{p}: rot {d['rotation_deg']:.3f} deg, baseline {d['baseline_m'] * 1000:.1f} vs {d['baseline_ref_m'] * 1000:.1f} mm"
            for p, d in ref["pairs"].items()))
        lines.append("  reference rig's wand lengths on the same frames (mm): " + _lengths_line(ref["holdout_wand"]))
    return "\n".join(lines)


def _lengths_line(rows: dict) -> str:
    return "; ".join(f"{k} known {v['known']:.1f}: median {v.get('median', float('nan')):.2f}, IQR {v.get('iqr', float('nan')):.2f}, "
                     f"error {v.get('error_mean', float('nan')):+.2f} +- {v.get('error_std', float('nan')):.2f} (n {v['n']})" for k, v in rows.items())
