"""Comparing a calibration with a reference or the truth: frame-free (relative poses) and frame-aligned figures."""

from __future__ import annotations

import numpy as np

from tracker import Rig
from tracker.calibration.extrinsics import triangulate_views
from tracker.calibration.poses import rigid_fit, rotation_angle_deg

__all__ = ["compare_rigs", "compare_to_truth", "length_rows", "wand_lengths"]


def compare_rigs(rig: Rig, ref: Rig) -> dict:
    """Per camera pair: angle between relative rotations, baselines (no common world frame needed)."""
    a, b = rig.stacked(), ref.stacked()
    if len(rig) != len(ref):
        raise ValueError(f"reference rig has {len(ref)} cameras, the calibration {len(rig)}")
    pairs = {}
    for i in range(len(rig)):
        for j in range(i + 1, len(rig)):
            Ra, Rb = a["R"][j] @ a["R"][i].T, b["R"][j] @ b["R"][i].T
            pairs[f"{rig.names[i]}-{rig.names[j]}"] = {
                "rotation_deg": float(rotation_angle_deg(Ra, Rb)),
                "baseline_m": float(np.linalg.norm(a["center"][j] - a["center"][i])),
                "baseline_ref_m": float(np.linalg.norm(b["center"][j] - b["center"][i])),
            }
    return {"pairs": pairs}


def compare_to_truth(rig: Rig, truth: Rig, *, align: bool = False) -> dict:
    """Per camera: focal length error (%), principal point error (px), centre error (mm), rotation error (deg).

    align : first fit a rigid transform of the calibration's camera centres onto the truth's
    (for calibrations whose world frame is camera 0); scale is not fitted, so scale errors show.
    """
    a, b = rig.stacked(), truth.stacked()
    C, Rw = a["center"].copy(), a["R"].copy()
    if align:
        A, t, _ = rigid_fit(C, b["center"])
        C = C @ A.T + t
        Rw = Rw @ A.T
    out = {}
    for i, n in enumerate(rig.names):
        Ka, Kb = a["K"][i], b["K"][i]
        out[n] = {"focal_pct": float(100 * max(abs(Ka[0, 0] / Kb[0, 0] - 1), abs(Ka[1, 1] / Kb[1, 1] - 1))),
                  "principal_px": float(np.hypot(Ka[0, 2] - Kb[0, 2], Ka[1, 2] - Kb[1, 2])),
                  "centre_mm": float(1000 * np.linalg.norm(C[i] - b["center"][i])),
                  "rotation_deg": float(rotation_angle_deg(Rw[i], b["R"][i]))}
    worst = {k: max(v[k] for v in out.values()) for k in ("focal_pct", "principal_px", "centre_mm", "rotation_deg")}
    return {"cameras": out, "worst": worst, "aligned": align}


def wand_lengths(rig: Rig, uv: np.ndarray, offsets) -> dict:
    """Wand lengths (mm stats) triangulated with ``rig`` from (n, F, M, 2) detections."""
    n, F, M, _ = uv.shape
    st = rig.stacked()
    X = triangulate_views(rig.cameras, st["R"], st["t"], uv.reshape(n, -1, 2)).reshape(F, M, 3)
    return length_rows(np.linalg.norm(np.diff(X, axis=1), axis=2), np.linalg.norm(X[:, -1] - X[:, 0], axis=1), offsets)


def length_rows(gaps_m: np.ndarray, total_m: np.ndarray, offsets) -> dict:
    """Stats (mm) of triangulated wand lengths: gaps_m (F, M-1) consecutive balls, total_m (F,) first to last,
    against the known spacings of ``offsets`` (M,) -> {"ball1-ball2": ..., ..., "ball1-ballM": ...}."""
    known = np.diff(offsets)
    rows = {f"ball{k + 1}-ball{k + 2}": _length_stats(gaps_m[:, k], known[k]) for k in range(len(known))}
    rows[f"ball1-ball{len(offsets)}"] = _length_stats(total_m, offsets[-1] - offsets[0])
    return rows


def _length_stats(values_m, known_m) -> dict:
    v = values_m[np.isfinite(values_m)] * 1000
    if not len(v):
        return {"known": known_m * 1000, "n": 0}
    e = v - known_m * 1000
    q25, q75 = np.percentile(v, [25, 75])
    return {"known": round(known_m * 1000, 3), "n": int(len(v)), "median": float(np.median(v)), "iqr": float(q75 - q25),
            "error_mean": float(e.mean()), "error_std": float(e.std()), "error_abs_median": float(np.median(np.abs(e)))}
