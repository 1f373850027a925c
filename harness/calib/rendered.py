"""Rendered calibration data with exact truth: ChArUco board views per camera, wand waves through the lab.

Board views: the lab rendered by the synthetic cameras (``harness.sim.render``, noise off), the board
drawn over it as a textured plane (``harness.sim.render.textured``), then Gaussian read noise
(``noise_dn``, seeded). Poses are spread over the image (a 3 x 3 grid of targets, cycled),
0.4-0.8 of the image width wide, tilted up to ``max_tilt_deg``; boards may leave the image in part.
"""

from __future__ import annotations

import numpy as np

from harness.sim.render.textured import board_plane, draw_textured_plane
from tracker import Camera
from tracker.calibration.board import BoardSpec
from tracker.calibration.poses import rvec_to_R

__all__ = ["board_background", "random_board_poses", "render_board_view"]


def random_board_poses(camera: Camera, spec: BoardSpec, n_views: int, rng: np.random.Generator, *,
                       max_tilt_deg: float = 50.0, width_frac=(0.4, 0.8), margin_px: float = 8.0,
                       min_corners_inside: int = 2) -> list:
    """``n_views`` board -> camera poses (R (3, 3), t (3,) metres), at least ``min_corners_inside`` of the
    board's 4 outline corners in the image (partial views cover the image's edges, as a person does)."""
    W, H = camera.image_size
    bw, bh = spec.size_m
    outline = np.array([[0, 0, 0], [bw, 0, 0], [bw, bh, 0], [0, bh, 0]], float)
    poses = []
    k = 0
    attempts = 0
    while len(poses) < n_views:
        attempts += 1
        if attempts > 200 * n_views:
            raise ValueError(f"camera {camera.name}: cannot place {n_views} board views of {bw:.2f} x {bh:.2f} m in the image")
        gx, gy = k % 3, (k // 3) % 3
        target = np.array([(gx + 0.5 + rng.uniform(-0.3, 0.3)) * W / 3, (gy + 0.5 + rng.uniform(-0.3, 0.3)) * H / 3])
        depth = camera.K[0, 0] * bw / (rng.uniform(*width_frac) * W)
        xn = camera.undistort(target)
        centre = np.array([xn[0], xn[1], 1.0]) * depth
        axis = rng.normal(size=3)
        axis[2] = 0
        axis /= np.linalg.norm(axis)
        tilt = np.radians(rng.uniform(10, max_tilt_deg)) * axis
        roll = np.array([0, 0, rng.uniform(-np.pi / 6, np.pi / 6)])
        R = rvec_to_R(tilt) @ rvec_to_R(roll)
        t = centre - R @ np.array([bw / 2, bh / 2, 0])
        Xc = outline @ R.T + t
        if (Xc[:, 2] < 0.05).any():
            continue
        uv = camera.normalised_to_pixels(Xc[:, :2] / Xc[:, 2:3])
        inside = (uv >= margin_px).all(axis=1) & (uv[:, 0] <= W - 1 - margin_px) & (uv[:, 1] <= H - 1 - margin_px)
        if inside.sum() < min_corners_inside:
            continue
        poses.append((R, t))
        k += 1
    return poses


def board_background(rig, name: str) -> np.ndarray:
    """The empty lab seen by camera ``name`` without sensor noise (RGB uint8)."""
    from harness.sim.render import RenderOptions, Renderer, Scene

    renderer = Renderer(rig.subset([name]), RenderOptions(noise_dn=0.0), seed=0)
    return renderer.render(Scene())[0]


def render_board_view(camera: Camera, background: np.ndarray, spec: BoardSpec, R_board_to_cam, t_board_to_cam_m,
                      rng: np.random.Generator, *, noise_dn: float = 2.0) -> np.ndarray:
    """One RGB image of the board at the given pose (camera frame) over ``background``, with read noise."""
    R_w = camera.R_world_to_cam.T @ R_board_to_cam
    t_w = camera.R_world_to_cam.T @ (np.asarray(t_board_to_cam_m) - camera.t_world_to_cam_m)
    img = draw_textured_plane(background, camera, board_plane(spec, R_w, t_w))
    if noise_dn > 0:
        img = np.clip(img + rng.normal(0, noise_dn, img.shape), 0, 255).astype(np.uint8)
    return img
