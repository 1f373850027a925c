"""Wand and ball recordings for ``rt2 calib wand``: the wand's ball offsets, its detections from CSV folders or
a session log, clicked world points, the report of a wand calibration, and the calibration itself.

    cal = calibrate_recording("wand_csvs/", ["data/rigs/lab4_vga.yaml"], wand="0.13,0.26", seed=0)
    cal.rig.save("out/rig.yaml"); cal.report  # reprojection per camera, held-out wand lengths, ...
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from harness.calib.compare import compare_rigs, length_rows, wand_lengths
from harness.calib.inputs import load_intrinsics, read_detection_csvs
from tracker import Camera, Rig
from tracker.calibration.extrinsics import WandOptions, apply_world, calibrate_wand, order_wand_points, triangulate_views
from checks.files import load_yaml_checked

__all__ = ["RecordingCalibration", "calibrate_recording", "parse_wand", "read_world_points", "recording_uv",
           "wand_report", "wand_uv_from_log"]


def parse_wand(text: str) -> np.ndarray:
    """'0.13,0.26' -> ball offsets along the wand [0, 0.13, 0.39] (metres)."""
    try:
        gaps = np.array([float(x) for x in str(text).split(",") if x.strip()])
    except ValueError:
        raise ValueError(f"--wand must be comma-separated spacings in metres (e.g. 0.13,0.26), got {text!r}") from None
    if len(gaps) < 1 or not np.isfinite(gaps).all() or (gaps <= 0).any() or (gaps > 5).any():
        raise ValueError(f"--wand spacings must be positive lengths in metres (<= 5), got {text!r}")
    return np.concatenate([[0.0], np.cumsum(gaps)])


def wand_uv_from_log(path, names, offsets) -> np.ndarray:
    """(n_cams, F, M, 2) wand balls from a session log's detections (frames where a camera saw exactly M candidates)."""
    from harness.logs.reader import SessionLogReader
    from harness.logs.topics import detections_topic

    per = {n: {} for n in names}
    with SessionLogReader(path) as log:
        topics = [detections_topic(n) for n in names]
        missing = [n for n, t in zip(names, topics) if t not in log.topics()]
        if missing:
            raise ValueError(f"{path}: no detections of cameras {missing} (topics {[detections_topic(n) for n in missing]})")
        for msg in log.messages(topics):
            det = msg.data
            per[det.camera][int(det.frame_index)] = order_wand_points(det.uv_px, offsets)
    frames = sorted(set().union(*[set(v) for v in per.values()]))
    uv = np.full((len(names), len(frames), len(offsets), 2), np.nan)
    for c, n in enumerate(names):
        for f, fi in enumerate(frames):
            if fi in per[n]:
                uv[c, f] = per[n][fi]
    return uv


def read_world_points(path, names):
    """World points with their clicked pixels -> (X_world (P, 3), uv (n_cams, P, 2) NaN where not clicked)."""
    path = Path(path)
    data = load_yaml_checked(path, "world points file")
    if not isinstance(data, list) or len(data) < 3:
        raise ValueError(f"{path}: expected a list of >= 3 points {{world_m: [x, y, z], pixels: {{camera: [u, v]}}}}")
    X = np.full((len(data), 3), np.nan)
    uv = np.full((len(names), len(data), 2), np.nan)
    for k, item in enumerate(data):
        if not isinstance(item, dict) or "world_m" not in item or not isinstance(item.get("pixels"), dict):
            raise ValueError(f"{path}: point {k} needs world_m and pixels")
        X[k] = np.asarray(item["world_m"], float)
        for cam, px in item["pixels"].items():
            if cam not in names:
                raise ValueError(f"{path}: point {k} names camera {cam!r}; cameras: {names}")
            uv[names.index(cam), k] = np.asarray(px, float)
    return X, uv


def recording_uv(path, cams, offsets):
    src = Path(path)
    names = [c.name for c in cams]
    if src.is_dir():
        files = sorted(src.glob("*.csv"))
        if len(files) != len(cams):
            raise ValueError(f"{src}: {len(files)} CSV files for {len(cams)} cameras {names}; need one per camera, sorted like --intrinsics")
        _, uv = read_detection_csvs(files)
        if uv.shape[2] != len(offsets):
            raise ValueError(f"{src}: the CSVs hold {uv.shape[2]} balls per row but --wand describes {len(offsets)}")
        return uv
    if src.suffix == ".mcap" and src.is_file():
        return wand_uv_from_log(src, names, offsets)
    raise ValueError(f"--recording {str(src)!r}: expected a folder of detection CSVs or an .mcap session log")


def wand_report(res, offsets, rig, world) -> dict:
    rows = length_rows(res.lengths_m, res.total_m, offsets)
    return {"cameras": rig.names, "fit_frames": int(len(res.fit_frames)), "holdout_frames": int(len(res.holdout_frames)),
            "reprojection_px": res.reproj_px, "holdout_wand_mm": rows, "pair_support": {f"{i}-{j}": v for (i, j), v in res.pair_support.items()},
            "world": world or "camera 0", "bundle": {"cost_initial": res.bundle.cost_initial, "cost_final": res.bundle.cost_final, "nfev": res.bundle.nfev}}


@dataclass(frozen=True)
class RecordingCalibration:
    """What :func:`calibrate_recording` found.

    rig : the cameras' poses (camera 0 = world, or the frame of the world points); report : the JSON report
    (``rt2 calib wand`` writes it beside the rig); error_px : the mean of the cameras' rms reprojection errors
    (the exports' error field); world_residual_m : (P,) distances of the world points after fitting the
    frame, metres (None without world points)
    """

    rig: Rig
    report: dict
    error_px: float
    world_residual_m: np.ndarray | None = None


def calibrate_recording(recording, intrinsics, *, wand: str | None = None, ball: bool = False, world_points=None,
                        reference=None, holdout_every: int = 5, every: int = 1, seed: int = 0) -> RecordingCalibration:
    """Every camera's pose from a wand (``wand``: spacings in metres, '0.13,0.26') or a single ball (``ball``;
    needs ``world_points`` for the scale) waved through the volume: bundle adjustment, then the world frame of
    ``world_points`` (YAML, :func:`read_world_points`) and the comparison with a ``reference`` calibration.

    recording : folder of per-camera detection CSVs or a session log (.mcap); intrinsics, reference : rig /
    OpenCV files in camera order (:func:`harness.calib.inputs.load_intrinsics`); holdout_every : every n-th
    frame set held out for the wand-length check; every : use every n-th frame set; seed : OpenCV's RANSAC seed
    (same seed, same result). Bad input raises ``ValueError`` naming the option (``--wand``, ``--every``, ...)."""
    if (wand is None) == (not ball):
        raise ValueError("give either --wand SPACINGS (e.g. 0.13,0.26) or --ball")
    if ball and not world_points:
        raise ValueError("--ball needs --world-points: a single ball carries no length, the scale comes from known points")
    offsets = np.zeros(1) if ball else parse_wand(wand)
    cams = load_intrinsics(intrinsics)
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        raise ValueError(f"camera names repeat in --intrinsics: {names}")
    if every < 1:
        raise ValueError(f"--every must be >= 1, got {every}")
    ref = Rig(load_intrinsics(reference)) if reference else None
    uv = recording_uv(recording, cams, offsets)[:, :: every]
    cv2.setRNGSeed(int(seed))
    if ball:
        return _calibrate_ball(recording, world_points, cams, uv[:, :, 0])
    res = calibrate_wand(cams, uv, offsets, WandOptions(holdout_every=holdout_every))
    R, t = res.R, res.t
    world, resid = None, None
    if world_points:
        Xw, uvw = read_world_points(world_points, names)
        R, t, resid = apply_world(R, t, _world_points_in_cam0(cams, R, t, uvw, world_points), Xw)
        world = {"points": len(Xw), "fit_residual_mm": (resid * 1000).round(2).tolist()}
    rig = Rig([Camera(name=c.name, K=c.K, distortion=c.distortion, R_world_to_cam=R[i], t_world_to_cam_m=t[i],
                      image_size=c.image_size) for i, c in enumerate(cams)],
              description=f"wand calibration from {recording} ({len(res.fit_frames)} frame sets)")
    report = wand_report(res, offsets, rig, world)
    if ref is not None:
        report["reference"] = compare_rigs(rig, ref)
        report["reference"]["holdout_wand"] = wand_lengths(ref, uv[:, res.holdout_frames], offsets)
    return RecordingCalibration(rig, report, float(np.mean([v["rms_px"] for v in res.reproj_px.values()])), resid)


def _world_points_in_cam0(cams, R, t, uvw, world_points) -> np.ndarray:
    """The clicked world points triangulated in camera 0's frame; each must be clicked in two cameras."""
    Xc = triangulate_views(cams, R, t, uvw)
    if np.isnan(Xc).any():
        bad = [k for k in range(len(Xc)) if np.isnan(Xc[k]).any()]
        raise ValueError(f"{world_points}: points {bad} are clicked in fewer than two cameras")
    return Xc


def _calibrate_ball(recording, world_points, cams, uv) -> RecordingCalibration:
    """uv : (n_cams, F, 2) the ball's pixels; scale and world frame from the world points."""
    from tracker.calibration.ball import apply_similarity, calibrate_ball

    names = [c.name for c in cams]
    R, t, bres = calibrate_ball(cams, uv)
    Xw, uvw = read_world_points(world_points, names)
    R, t, scale, resid = apply_similarity(R, t, _world_points_in_cam0(cams, R, t, uvw, world_points), Xw)
    rig = Rig([Camera(name=c.name, K=c.K, distortion=c.distortion, R_world_to_cam=R[i], t_world_to_cam_m=t[i],
                      image_size=c.image_size) for i, c in enumerate(cams)],
              description=f"single-ball calibration from {recording}, scale and frame from {world_points}")
    reproj = {}
    for c, n in enumerate(names):
        e = bres.residual_px[c][bres.inlier[c]]
        reproj[n] = {"rms_px": float(np.sqrt(np.mean(e ** 2))), "median_px": float(np.median(e)), "observations": int(e.size)}
    report = {"cameras": names, "mode": "ball", "frames": int(uv.shape[1]), "reprojection_px": reproj,
              "world": {"points": len(Xw), "scale": scale, "fit_residual_mm": (resid * 1000).round(2).tolist()}}
    return RecordingCalibration(rig, report, float(np.mean([v["rms_px"] for v in reproj.values()])), resid)
