"""End-to-end calibration check on rendered data with exact truth (``rt2 calib check``).

1. Intrinsics: per camera, ``n_board_views`` rendered ChArUco views (the lab behind, read noise) ->
   ``calibrate_intrinsics`` -> focal length (%) and principal point (px) against the true camera.
2. Extrinsics: a wand (three orange balls at 0 / 130 / 390 mm on a black rod) waved through the
   workspace, rendered by every camera, balls found by rt2's own detector (``tracker.BallDetector``
   with the hand-made orange model), labelled by their order along the wand -> ``calibrate_wand``
   with the intrinsics of step 1 -> world frame from the table's four corners "clicked" in the images
   (true projections + ``click_noise_px``) -> camera centres (mm) and rotations (deg) against the
   true rig; wand lengths on held-out frame sets.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from harness.calib.compare import compare_to_truth
from harness.calib.rendered import board_background, random_board_poses, render_board_view
from policies.ball_model import TableGeometry
from tracker import Camera, Rig
from tracker.calibration.board import BoardSpec, detect_charuco
from tracker.calibration.extrinsics import WandOptions, apply_world, calibrate_wand, order_wand_points, triangulate_views
from tracker.calibration.intrinsics import IntrinsicsOptions, calibrate_intrinsics

__all__ = ["CheckConfig", "TABLE_CORNERS_M", "WAND_OFFSETS_M", "render_wand_detections", "run_check"]

WAND_OFFSETS_M = np.array([0.0, 0.13, 0.39])
#: the table top's four corners, lab frame (the lab's TableGeometry)
TABLE_CORNERS_M = TableGeometry().corners_m()
BOARD = BoardSpec(9, 7, 0.03, 0.022, "DICT_4X4_50")


@dataclass(frozen=True)
class CheckConfig:
    rig: str = "lab4_vga"
    seed: int = 0
    n_board_views: int = 60
    n_wand_frames: int = 300
    click_noise_px: float = 0.3
    fix_k3: bool = True


def calibrate_rendered_intrinsics(truth: Rig, cfg: CheckConfig, rng) -> list:
    cams, rows = [], {}
    for cam in truth:
        bg = board_background(truth, cam.name)
        poses = random_board_poses(cam, BOARD, cfg.n_board_views, rng)
        views = [detect_charuco(render_board_view(cam, bg, BOARD, R, t, rng), BOARD) for R, t in poses]
        res = calibrate_intrinsics(views, BOARD, cam.image_size, IntrinsicsOptions(fix_k3=cfg.fix_k3), camera=cam.name)
        cams.append(Camera(cam.name, res.K, res.distortion, np.eye(3), np.zeros(3), cam.image_size))
        rows[cam.name] = {"rms_px": res.rms_px, "views_used": int(res.kept.sum()), "std_fx": res.std["fx"], "std_cx": res.std["cx"]}
    return cams, rows


def wand_poses(workspace_m, n_frames, rng) -> np.ndarray:
    """(F, 3, 3) ball centres: the wand's first ball uniform in the (shrunk) workspace, direction random."""
    lo, hi = np.asarray(workspace_m[0]) + 0.3, np.asarray(workspace_m[1]) - 0.3
    X0 = rng.uniform(lo, hi, (n_frames, 3))
    u = rng.normal(size=(n_frames, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return X0[:, None] + WAND_OFFSETS_M[None, :, None] * u[:, None]


def render_wand_detections(truth: Rig, balls_m: np.ndarray, seed: int) -> np.ndarray:
    """Render each frame set of the wand and detect its balls -> (n_cams, F, 3, 2) labelled pixels (NaN: not 3 found)."""
    from harness.sim.render import Ball, Capsule, Renderer, RenderOptions, Scene
    from tracker import BallDetector, DetectorOptions
    from tracker.detection.synthetic import hand_made_model

    renderer = Renderer(truth, RenderOptions(shading="flat"), seed=seed)  # LED-lit balls glow evenly (no lit-top bias)
    det = BallDetector(hand_made_model(), DetectorOptions(max_candidates=6, max_seeds=24))
    F = len(balls_m)
    uv = np.full((len(truth), F, 3, 2), np.nan)
    for f in range(F):
        X = balls_m[f]
        u = (X[-1] - X[0]) / np.linalg.norm(X[-1] - X[0])
        rod = Capsule(X[0] - 0.05 * u, X[-1] + 0.05 * u, 0.006, "robot_black")
        scene = Scene(balls=tuple(Ball(x) for x in X), capsules=(rod,), frame_index=f)
        for c, img in enumerate(renderer.render(scene)):
            d = det.detect(img)
            uv[c, f] = order_wand_points(d.uv_px, WAND_OFFSETS_M)
    return uv


def run_check(cfg: CheckConfig) -> dict:
    from tracker.rig_files import resolve_rig

    truth = resolve_rig(cfg.rig)
    rng = np.random.default_rng(cfg.seed)
    cams, intr = calibrate_rendered_intrinsics(truth, cfg, rng)
    intr_rig = Rig([Camera(c.name, c.K, c.distortion, t.R_world_to_cam, t.t_world_to_cam_m, c.image_size) for c, t in zip(cams, truth)])
    intr_cmp = compare_to_truth(intr_rig, truth)
    ws = truth.workspace_m if truth.workspace_m is not None else np.array([[-2.0, -1.0, 0.8], [0.5, 1.0, 1.8]])
    balls = wand_poses(ws, cfg.n_wand_frames, rng)
    uv = render_wand_detections(truth, balls, cfg.seed)
    found = float(np.mean(~np.isnan(uv).any(axis=-1)))
    cv2.setRNGSeed(cfg.seed)
    res = calibrate_wand(cams, uv, WAND_OFFSETS_M, WandOptions())
    # world frame: the table corners clicked in every camera that sees them
    click = truth.project(TABLE_CORNERS_M) + rng.normal(0, cfg.click_noise_px, (len(truth), 4, 2))
    for c, cam in enumerate(truth):
        click[c][~cam.in_image(click[c])] = np.nan
    Xc = triangulate_views(cams, res.R, res.t, click)
    R, t, resid = apply_world(res.R, res.t, Xc, TABLE_CORNERS_M)
    rig = Rig([Camera(c.name, c.K, c.distortion, R[i], t[i], c.image_size) for i, c in enumerate(cams)],
              workspace_m=truth.workspace_m, description=f"calibrated from rendered data (rt2 calib check --rig {cfg.rig} --seed {cfg.seed})")
    ext = compare_to_truth(rig, truth)
    ext_aligned = compare_to_truth(rig, truth, align=True)
    total = (res.total_m - WAND_OFFSETS_M[-1]) * 1000
    return {"rig": cfg.rig, "seed": cfg.seed, "cameras": len(truth), "intrinsics": {"per_camera": intr, "vs_truth": intr_cmp},
            "wand": {"detected_fraction": found, "fit_frames": int(len(res.fit_frames)), "reprojection_px": res.reproj_px,
                     "holdout_total_error_mm": {"mean": float(np.nanmean(total)), "std": float(np.nanstd(total)),
                                                "robust_std": float(1.4826 * np.nanmedian(np.abs(total - np.nanmedian(total)))),
                                                "max_abs": float(np.nanmax(np.abs(total))), "n": int(np.isfinite(total).sum())}},
            "table_fit_residual_mm": (resid * 1000).round(2).tolist(),
            "extrinsics_vs_truth": ext, "extrinsics_vs_truth_aligned": ext_aligned, "rig_obj": rig}
