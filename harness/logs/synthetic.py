"""A synthetic session to exercise logs: camera-like frames, detections, tracker output, ground truth, arm.

Shared by the tests and ``rt2 bench log``. Everything is precomputed by :func:`make_session` (seeded),
so :func:`write_session` only calls the writer and a benchmark times the writer alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tracker.observation import BallObservation, Status

__all__ = ["SyntheticSession", "make_session", "camera_frame", "write_session"]

GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class SyntheticSession:
    """Per frame set k: t_s[k], ball_m[k] (3,), q[k], qdot[k], q_cmd[k] (7,), links_T[k] (8, 4, 4) world
    poses of the arm's frames, tf_T[k] (8, 4, 4) each frame's pose in its parent (the first in the world),
    uv_px[k] (n_cams, 2), scores[k] (n_cams,), observations[k] {tracker: obs};
    frames[c][v] the v-th pre-made (H, W, 3) uint8 RGB frame of camera c (frame set k uses v = k % n_variants).
    """

    rate_hz: float
    cameras: tuple
    t_s: np.ndarray
    ball_m: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    q_cmd: np.ndarray
    links_T: np.ndarray
    tf_T: np.ndarray
    uv_px: np.ndarray
    scores: np.ndarray
    observations: tuple
    frames: tuple

    @property
    def n_framesets(self) -> int:
        return len(self.t_s)


def camera_frame(image_size, ball_uv, rng: np.random.Generator, noise_sigma: float = 2.0) -> np.ndarray:
    """(H, W, 3) uint8 RGB frame that compresses like a camera image: lit gradient, table, sensor noise, ball."""
    w, h = image_size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.stack([60 + 60 * xx / w, 70 + 50 * yy / h, 80 + 30 * (xx + yy) / (w + h)], axis=-1)
    img[int(0.6 * h): int(0.85 * h), int(0.15 * w): int(0.85 * w)] = (20, 60, 140)  # table
    img += rng.normal(0.0, noise_sigma, img.shape).astype(np.float32)
    out = np.clip(img, 0, 255).astype(np.uint8)
    cv2.circle(out, (int(ball_uv[0]), int(ball_uv[1])), max(3, w // 100), (250, 140, 30), -1)
    return out


def _chain(q: np.ndarray) -> np.ndarray:
    """(n, 7) joint angles -> (n, 8, 4, 4) world poses of the base and 7 link frames of a toy arm behind the table."""
    n = len(q)
    T = np.tile(np.eye(4), (n, 8, 1, 1))
    T[:, 0, :3, 3] = (-1.9, 0.0, 0.9)
    for j in range(7):  # 7 links: a loop over the chain, batched over frame sets
        c, s = np.cos(q[:, j]), np.sin(q[:, j])
        step = np.tile(np.eye(4), (n, 1, 1))
        if j % 2 == 0:  # alternate z and y joint axes
            step[:, 0, 0], step[:, 0, 1], step[:, 1, 0], step[:, 1, 1] = c, -s, s, c
        else:
            step[:, 0, 0], step[:, 0, 2], step[:, 2, 0], step[:, 2, 2] = c, s, -s, c
        step[:, :3, 3] = (0.0, 0.0, 0.15)
        T[:, j + 1] = T[:, j] @ step
    return T


def make_session(seconds: float, *, rate_hz: float = 200.0, n_cameras: int = 4, image_size=(640, 480),
                 n_variants: int = 8, trackers=("rt2", "rtblob"), seed: int = 0) -> SyntheticSession:
    """Precompute a seeded synthetic session of ``seconds`` at ``rate_hz`` frame sets per second."""
    rng = np.random.default_rng(seed)
    n = max(1, int(round(seconds * rate_hz)))
    t = np.arange(n) / rate_hz
    # Balls fly from the opponent (x > 0) towards the robot, one per 1 s, ballistic in z.
    tau = t % 1.0
    ball = np.stack([2.0 - 3.5 * tau, 0.3 * np.sin(2 * np.pi * t / 7), 1.1 + 2.0 * tau - 0.5 * GRAVITY_M_S2 * tau**2], axis=1)
    phase = rng.uniform(0, 2 * np.pi, 7)
    q = 0.5 * np.sin(2 * np.pi * 0.5 * t[:, None] + phase)
    qdot = 0.5 * 2 * np.pi * 0.5 * np.cos(2 * np.pi * 0.5 * t[:, None] + phase)
    w, h = image_size
    cams = tuple(f"cam{i}" for i in range(n_cameras))
    uv = np.stack([w / 2 + 0.4 * w * np.sin(t[:, None] + np.arange(n_cameras)), h / 2 + 0.3 * h * np.cos(2 * t[:, None] + np.arange(n_cameras))], axis=-1)
    scores = rng.uniform(0.5, 1.0, (n, n_cameras))
    noise = rng.normal(0, 0.002, (n, len(trackers), 3))
    obs = []
    for k in range(n):
        per = {}
        for j, name in enumerate(trackers):
            lost = rng.random() < 0.02
            per[name] = BallObservation(
                t_s=float(t[k]), position_m=None if lost else ball[k] + noise[k, j],
                covariance_m2=None if lost else np.diag([4e-6, 4e-6, 9e-6]), support=0 if lost else n_cameras,
                inliers=np.full(n_cameras, not lost), status=Status.NO_CONSENSUS if lost else Status.OK,
                latency_s=float(rng.uniform(1e-3, 3e-3)), tracker=name, uv_px=uv[k].copy(),
                notes=("synthetic",) if lost else ())
        obs.append(per)
    frames = tuple(tuple(camera_frame(image_size, uv[v % n, c], rng) for v in range(n_variants)) for c in range(n_cameras))
    links = _chain(q)
    rel = links.copy()
    rel[:, 1:] = np.linalg.inv(links[:, :-1]) @ links[:, 1:]
    return SyntheticSession(rate_hz=rate_hz, cameras=cams, t_s=t, ball_m=ball, q=q, qdot=qdot, q_cmd=q + 0.01,
                            links_T=links, tf_T=rel, uv_px=uv, scores=scores, observations=tuple(obs), frames=frames)


def write_session(writer, s: SyntheticSession, *, images: bool = True, scene: bool = True, progress=None) -> None:
    """Write every frame set of ``s`` through ``writer`` (a SessionLogWriter or BackgroundLogWriter)."""
    names = ("world", "base") + tuple(f"link_{j}" for j in range(1, 8))  # frame names of robot_models.kinematics
    n_var = len(s.frames[0]) if s.frames else 1
    for k in range(s.n_framesets):
        t = float(s.t_s[k])
        for c, cam in enumerate(s.cameras):
            if images:
                writer.write_image(t, cam, s.frames[c][k % n_var], k)
            writer.write_detections(t, cam, s.uv_px[k, c][None], s.scores[k, c:c + 1], k)
        for name, ob in s.observations[k].items():
            writer.write_observation(t, name, ob, k)
        writer.write_ground_truth(t, s.ball_m[k], s.q[k], s.qdot[k], s.q_cmd[k], k)
        if scene:
            writer.write_transforms(t, list(zip(names[:-1], names[1:], s.tf_T[k])))
            writer.write_scene_arm(t, s.links_T[k, :, :3, 3])
            writer.write_scene_balls(t, s.ball_m[k], {n: o.position_m for n, o in s.observations[k].items()})
        if progress is not None:
            progress.update(1)
