"""Wand and ball recordings for ``rt2 calib wand``: the wand's ball offsets, its detections from CSV folders or
a session log, clicked world points, and the report of a wand calibration."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.calib.compare import length_rows
from harness.calib.inputs import read_detection_csvs
from tracker.calibration.extrinsics import order_wand_points
from checks.files import load_yaml_checked

__all__ = ["parse_wand", "read_world_points", "recording_uv", "wand_report", "wand_uv_from_log"]


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
