"""``rt2 calib wand``: every camera's pose from a wand waved through the volume (bundle adjustment).

Input: a folder of per-camera 2D detection CSVs (``timestamp;u1;v1;u2;v2;...``, the ewand layout,
one file per camera in the order of ``--intrinsics``) or an rt2 session log (``.mcap``) whose
``/camera/<name>/detections`` hold the wand's balls (labelled here by their order along the wand).
Writes the rig YAML (camera 0 = world, or the frame of ``--world-points``), a JSON report and the
optional exports (OpenCV FileStorage, aniposelib calibration.toml).
"""

from __future__ import annotations


import cv2
import numpy as np

from harness.calib.compare import compare_rigs, wand_lengths
from harness.calib.exports import add_export_arguments, save_calibration
from harness.calib.inputs import load_intrinsics
from harness.calib.wand import parse_wand, read_world_points, recording_uv, wand_report
from tracker import Camera, Rig
from tracker.calibration.extrinsics import WandOptions, apply_world, calibrate_wand, triangulate_views

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
    if (args.wand is None) == (not args.ball):
        raise ValueError("give either --wand SPACINGS (e.g. 0.13,0.26) or --ball")
    if args.ball and not args.world_points:
        raise ValueError("--ball needs --world-points: a single ball carries no length, the scale comes from known points")
    offsets = np.zeros(1) if args.ball else parse_wand(args.wand)
    cams = load_intrinsics(args.intrinsics)
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        raise ValueError(f"camera names repeat in --intrinsics: {names}")
    if args.every < 1:
        raise ValueError(f"--every must be >= 1, got {args.every}")
    ref = Rig(load_intrinsics(args.reference)) if args.reference else None
    uv = recording_uv(args.recording, cams, offsets)[:, :: args.every]
    cv2.setRNGSeed(int(args.seed))
    if args.ball:
        return _run_ball(args, cams, uv[:, :, 0])
    res = calibrate_wand(cams, uv, offsets, WandOptions(holdout_every=args.holdout_every))
    R, t = res.R, res.t
    world = None
    if args.world_points:
        Xw, uvw = read_world_points(args.world_points, names)
        Xc = triangulate_views(cams, R, t, uvw)
        if np.isnan(Xc).any():
            bad = [k for k in range(len(Xw)) if np.isnan(Xc[k]).any()]
            raise ValueError(f"{args.world_points}: points {bad} are clicked in fewer than two cameras")
        R, t, resid = apply_world(R, t, Xc, Xw)
        world = {"points": len(Xw), "fit_residual_mm": (resid * 1000).round(2).tolist()}
    rig = Rig([Camera(name=c.name, K=c.K, distortion=c.distortion, R_world_to_cam=R[i], t_world_to_cam_m=t[i],
                      image_size=c.image_size) for i, c in enumerate(cams)],
              description=f"wand calibration from {args.recording} ({len(res.fit_frames)} frame sets)")
    report = wand_report(res, offsets, rig, world)
    if ref is not None:
        report["reference"] = compare_rigs(rig, ref)
        report["reference"]["holdout_wand"] = wand_lengths(ref, uv[:, res.holdout_frames], offsets)
    written = save_calibration(rig, report, args, error=float(np.mean([v["rms_px"] for v in res.reproj_px.values()])))
    print(format_report(report))
    print("wrote " + ", ".join(written))
    return 0


def _run_ball(args, cams, uv) -> int:
    from tracker.calibration.ball import apply_similarity, calibrate_ball

    names = [c.name for c in cams]
    R, t, bres = calibrate_ball(cams, uv)
    Xw, uvw = read_world_points(args.world_points, names)
    Xc = triangulate_views(cams, R, t, uvw)
    if np.isnan(Xc).any():
        bad = [k for k in range(len(Xw)) if np.isnan(Xc[k]).any()]
        raise ValueError(f"{args.world_points}: points {bad} are clicked in fewer than two cameras")
    R, t, scale, resid = apply_similarity(R, t, Xc, Xw)
    rig = Rig([Camera(name=c.name, K=c.K, distortion=c.distortion, R_world_to_cam=R[i], t_world_to_cam_m=t[i],
                      image_size=c.image_size) for i, c in enumerate(cams)],
              description=f"single-ball calibration from {args.recording}, scale and frame from {args.world_points}")
    reproj = {}
    for c, n in enumerate(names):
        e = bres.residual_px[c][bres.inlier[c]]
        reproj[n] = {"rms_px": float(np.sqrt(np.mean(e ** 2))), "median_px": float(np.median(e)), "observations": int(e.size)}
    report = {"cameras": names, "mode": "ball", "frames": int(uv.shape[1]), "reprojection_px": reproj,
              "world": {"points": len(Xw), "scale": scale, "fit_residual_mm": (resid * 1000).round(2).tolist()}}
    written = save_calibration(rig, report, args, error=float(np.mean([v["rms_px"] for v in reproj.values()])))
    print(f"{len(names)} cameras from a single ball ({uv.shape[1]} frame sets); scale and world frame from {len(Xw)} points, "
          f"residual {np.round(resid * 1000, 1).tolist()} mm")
    for n, r in reproj.items():
        print(f"  {n:>12s}: rms {r['rms_px']:.2f} px, median {r['median_px']:.2f} px, {r['observations']} obs")
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
