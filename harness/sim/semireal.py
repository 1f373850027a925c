"""Semi-real frame sets: a real recorded, calibrated camera session with a ball of known 3D flight drawn in.

The session is the real 4-camera caliscope recording (``../shared/data/real/caliscope_4cam``: four
1280x720 webcams, a hand-held ChArUco board, caliscope's calibration in ``camera_array.toml``). Its
frames are the backgrounds, its calibration is the rig (the lens model the ball is drawn with and
the one the trackers get), and one ball per frame set flies by the project's ball physics
(:func:`policies.ball_model.simulate`: gravity, drag, Magnus; free flight, no table in this room).
Per camera the ball is drawn with that camera's lens, the image's local light, sharpness and noise
(:func:`harness.sim.render.composite.draw_ball`), or, with ``SemiRealOptions.real_balls``, a real white ball
cut from the real rally frames is pasted there (:class:`harness.sim.real_balls.RealBalls`: the projected
centre, the apparent size at its depth, its smear laid along the projected flight).

World frame: caliscope's (camera ``cameras.1`` at the origin); ``+y`` is up (cameras 0, 2 and 3 hang
above the board and look down along ``-y``). Workspace (:func:`common_view_box`): the box of the points
all cameras see (5th-95th percentile of a 5 cm grid, each point inside every image by ``VIEW_MARGIN_PX``).

Frame set ``f`` of seed ``s`` depends only on ``(s, f)`` (``default_rng([s, f])``): the background
frame set, the flight, the noise. Frames are decoded once per process and kept in memory (only the
``backgrounds`` frame sets used: 12 x 4 x 2.8 MB by default). With moving backgrounds
(``SemiRealOptions.moving_backgrounds``, the default for the real balls) frame ``j`` of a flight lies on the
session's real frame set ``k0 + j`` (its 48 frame sets in their time order, ``k0`` drawn per flight), so
the people and the board move as they did; the frame sets a flight needs are decoded when it starts and
kept (at most all 48 x 4 x 2.8 MB). The session's frames come 6 per second: the scene moves ~17 times faster than at the
flight's 100 Hz.
"""

from __future__ import annotations

import csv
import tomllib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from checks.files import MAX_CONFIG_BYTES, read_text_capped
from harness.sim.real_balls import RealBalls
from harness.sim.render.composite import draw_ball, edge_blur_px
from harness.sim.render.scene_state import Ball
from tracker.rig_files import read_anipose_toml
from policies.ball_model import simulate
from tracker import Camera, Rig
from tracker.calibration.poses import rigid_fit, rotation_angle_deg

__all__ = ["DEFAULT_RALLY", "DEFAULT_SESSION", "EXPOSURES", "SemiRealOptions", "SemiRealSession", "aligned_rig", "ball_options", "common_view_box", "session_frames", "session_rig"]

#: the caliscope session shipped beside the project (``../shared`` next to the repository)
DEFAULT_SESSION = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "caliscope_4cam"
#: the real rally frames whose white balls are cut and pasted (``SemiRealOptions.real_balls``)
DEFAULT_RALLY = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "phone_rally"
#: ``SemiRealOptions.exposure``: "tracking" = ``tracking_exposure_s`` in every camera; "recorded" =
#: each webcam's own shutter from ``camera_array.toml`` (``exposure`` = log2 seconds: -7 -> 7.8 ms)
EXPOSURES = ("tracking", "recorded")
UP_WORLD = np.array([0.0, 1.0, 0.0])  #: caliscope's world frame: +y is up (module docstring)
VIEW_MARGIN_PX = 40.0
LIFT_M = 20.0  #: flights are integrated this high above the physics' table, so they never meet it


def common_view_box(rig: Rig, *, margin_px: float = VIEW_MARGIN_PX, step_m: float = 0.05) -> np.ndarray:
    """(2, 3) [min, max] box, world frame, of the points every camera of ``rig`` sees (module docstring)."""
    centres = np.array([c.center_world for c in rig])
    lo, hi = centres.min(axis=0) - 1.5, centres.max(axis=0) + 1.5
    axes = [np.arange(lo[k], hi[k] + 1e-9, step_m) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    seen = np.ones(len(grid), bool)
    for cam in rig:
        seen &= (cam.depth(grid) > 0.2) & cam.in_image(cam.project(grid), margin_px)
    if seen.sum() < 8:
        raise ValueError(f"the cameras of rig {rig.description!r} share no view (fewer than 8 points of a {step_m} m grid)")
    return np.percentile(grid[seen], [5, 95], axis=0)


def session_rig(folder=DEFAULT_SESSION) -> Rig:
    """The session's rig: caliscope's calibration (``camera_array.toml``) with the :func:`common_view_box`
    workspace; checks that the videos and timestamps are there (a clear error naming the file if not)."""
    folder = Path(folder)
    toml = folder / "camera_array.toml"
    if not toml.is_file():
        raise FileNotFoundError(f"semi-real session {str(folder)!r}: no camera_array.toml (expected the caliscope_4cam folder of ../shared/data/real)")
    rig = read_anipose_toml(toml)
    for name in [f"cam_{i}.mp4" for i in range(len(rig))] + ["timestamps.csv"]:
        if not (folder / "calibration" / "extrinsic" / name).is_file():
            raise FileNotFoundError(f"semi-real session {str(folder)!r}: missing calibration/extrinsic/{name}")
    return Rig(rig.cameras, workspace_m=common_view_box(rig), description=f"caliscope_4cam (real calibration, {folder})")


def session_frames(folder=DEFAULT_SESSION) -> int:
    """The number of frame sets of the session (rows of ``timestamps.csv`` by sync index), without decoding a frame."""
    folder = Path(folder)
    toml = folder / "camera_array.toml"
    if not toml.is_file():
        raise FileNotFoundError(f"semi-real session {str(folder)!r}: no camera_array.toml (expected the caliscope_4cam folder of ../shared/data/real)")
    return len(_frame_times(folder / "calibration" / "extrinsic" / "timestamps.csv", len(read_anipose_toml(toml))))


def aligned_rig(other: Rig, session: Rig) -> tuple[Rig, dict]:
    """``other`` (another calibration of the session's cameras, same order, e.g. ``rt2 calib board`` of its
    videos, whose world frame is its first camera) moved into the session's world frame by the rigid fit
    of its camera centres onto the session's (no scale: a scale error stays); with the session's workspace.
    Returns the rig and what differs: per camera the rotation (deg) and centre (mm) after the fit."""
    if len(other) != len(session):
        raise ValueError(f"the trackers' calibration has {len(other)} cameras, the session {len(session)} {session.names}")
    for a, b in zip(other, session):
        if tuple(a.image_size) != tuple(b.image_size):
            raise ValueError(f"the trackers' calibration camera {a.name!r} is {a.image_size[0]}x{a.image_size[1]} px, "
                             f"the session's {b.name!r} {b.image_size[0]}x{b.image_size[1]}")
    A, t, _ = rigid_fit(np.array([c.center_world for c in other]), np.array([c.center_world for c in session]))
    cams = []
    for c in other:  # world' = A world + t  ->  R' = R A^T, t' = t_c - R A^T t
        R = c.R_world_to_cam @ A.T
        cams.append(Camera(name=c.name, K=c.K, distortion=c.distortion, R_world_to_cam=R, t_world_to_cam_m=c.t_world_to_cam_m - R @ t,
                           image_size=c.image_size))
    rig = Rig(cams, workspace_m=session.workspace_m, description=f"{other.description} (aligned to the session's world frame)")
    diff = {"rotation_deg": [round(float(rotation_angle_deg(a.R_world_to_cam, b.R_world_to_cam)), 3) for a, b in zip(rig, session)],
            "centre_mm": [round(1000 * float(np.linalg.norm(a.center_world - b.center_world)), 1) for a, b in zip(rig, session)]}
    return rig, diff


@dataclass(frozen=True)
class SemiRealOptions:
    """How the ball is drawn into the real frames.

    ball_colour : "orange" or "white" (the scene's reflectances, :data:`harness.sim.render.scene_state.COLOURS`)
    speed_mps : (lo, hi) launch speed range, m/s (uniform; direction uniform on the sphere)
    spin_rps : spin sigma per axis, revolutions per second (Magnus)
    exposure : one of ``EXPOSURES``; tracking_exposure_s : the shutter of "tracking", seconds
    sync : "exact" (the ball drawn at the frame set's time in every camera) or "recorded" (at each
        camera's own frame time from ``timestamps.csv``: the session's real sync error, up to ~10 ms)
    backgrounds : real frame sets used as backgrounds, evenly spaced over the session
    real_balls : None (the ball is drawn) or a COCO set of one video whose balls are cut and pasted
        (:class:`harness.sim.real_balls.RealBalls`, e.g. ``DEFAULT_RALLY``; ``ball_colour`` must be "white")
    crop_frames : the ``"START:STOP"`` range of ``real_balls``' time order whose balls are used (None: all)
    moving_backgrounds : flights run over the session's frame sets in time order (module docstring); None =
        True with ``real_balls``, False for the drawn ball (whose published figures used still backgrounds)
    """

    ball_colour: str = "orange"
    speed_mps: tuple = (1.0, 6.0)
    spin_rps: float = 10.0
    exposure: str = "tracking"
    tracking_exposure_s: float = 0.002
    sync: str = "exact"
    backgrounds: int = 12
    real_balls: object = None
    crop_frames: str | None = None
    moving_backgrounds: bool | None = None

    @property
    def moving(self) -> bool:
        """Whether flights run over the session's frame sets in time order (``moving_backgrounds`` resolved)."""
        return self.real_balls is not None if self.moving_backgrounds is None else bool(self.moving_backgrounds)

    def __post_init__(self):
        if self.ball_colour not in ("orange", "white"):
            raise ValueError(f"ball_colour must be 'orange' or 'white', got {self.ball_colour!r}")
        lo, hi = self.speed_mps
        if not (0 <= lo <= hi < 50):
            raise ValueError(f"speed_mps must be (lo, hi) with 0 <= lo <= hi < 50 m/s, got {self.speed_mps!r}")
        if self.exposure not in EXPOSURES:
            raise ValueError(f"unknown exposure {self.exposure!r}; valid: {list(EXPOSURES)}")
        if not 0 < self.tracking_exposure_s <= 0.1:
            raise ValueError(f"tracking_exposure_s must be in (0, 0.1] s, got {self.tracking_exposure_s!r}")
        if self.sync not in ("exact", "recorded"):
            raise ValueError(f"unknown sync {self.sync!r}; valid: ['exact', 'recorded']")
        if isinstance(self.backgrounds, bool) or not isinstance(self.backgrounds, int) or self.backgrounds < 1:
            raise ValueError(f"backgrounds must be a positive integer, got {self.backgrounds!r}")
        if self.real_balls is not None and self.ball_colour != "white":
            raise ValueError(f"real_balls are the real white balls: ball_colour must be 'white', got {self.ball_colour!r}")
        if self.crop_frames is not None and self.real_balls is None:
            raise ValueError("crop_frames chooses among real_balls' frames; real_balls is None (the ball is drawn)")
        if self.moving_backgrounds not in (None, True, False):
            raise ValueError(f"moving_backgrounds must be None, True or False, got {self.moving_backgrounds!r}")


def ball_options(ball: str | None, crops=None, crop_frames: str | None = None) -> dict:
    """The command-line choice of the ball (``--ball``, ``--ball-crops``, ``--crop-frames``) as :class:`SemiRealOptions`
    fields: ``{}`` for the drawn orange ball (None or "orange"), the real white rally balls pasted for "white"
    (``crops``: their COCO set, default ``DEFAULT_RALLY``; ``crop_frames``: a ``START:STOP`` range of its time
    order). Refuses, naming the option, what does not apply or does not exist."""
    from checks.time_order import parse_range

    if ball not in (None, "orange", "white"):
        raise ValueError(f"--ball must be orange or white, got {ball!r}")
    if ball != "white":
        for name, value in (("--ball-crops", crops), ("--crop-frames", crop_frames)):
            if value is not None:
                raise ValueError(f"{name} applies to --ball white only")
        return {}
    if crop_frames is not None:
        parse_range(crop_frames, "--crop-frames")
    crops = Path(DEFAULT_RALLY if crops is None else crops)
    if not (crops.is_file() or (crops / "annotations.json").is_file()):
        raise FileNotFoundError(f"--ball-crops {str(crops)!r}: no COCO annotations.json there (the real rally frames are ../shared/data/real/phone_rally)")
    return {"ball_colour": "white", "real_balls": str(crops), "crop_frames": crop_frames}


class SemiRealSession:
    """The caliscope session as a source of semi-real frame sets (module docstring).

    folder : the session folder (``camera_array.toml``, ``calibration/extrinsic/cam_<i>.mp4``, ``timestamps.csv``)
    options : :class:`SemiRealOptions`; seed : the frame sets' seed
    """

    def __init__(self, folder=DEFAULT_SESSION, options: SemiRealOptions | None = None, *, seed: int = 0):
        folder = Path(folder)
        options = SemiRealOptions() if options is None else options
        if not isinstance(options, SemiRealOptions):
            raise ValueError(f"options must be a SemiRealOptions, got {type(options).__name__}")
        self.folder, self.options, self.seed = folder, options, int(seed)
        self.rig = rig = session_rig(folder)
        toml = folder / "camera_array.toml"
        self._videos = [folder / "calibration" / "extrinsic" / f"cam_{i}.mp4" for i in range(len(rig))]
        self._times = _frame_times(folder / "calibration" / "extrinsic" / "timestamps.csv", len(rig))  # (n_frames, n_cams) s
        n = len(self._times)
        self.frame_indices = np.unique(np.linspace(0, n - 1, min(options.backgrounds, n)).round().astype(int))
        self._frames = _decode(self._videos, self.frame_indices, [c.image_size for c in rig])  # {index: [images]}
        self._blur: dict[int, list] = {}
        self.real = None if options.real_balls is None else RealBalls(options.real_balls, options.crop_frames)
        if options.exposure == "recorded":
            data = tomllib.loads(read_text_capped(toml, MAX_CONFIG_BYTES, "calibration file"))
            cams = data.get("cameras", data)
            self.exposures_s = np.array([2.0 ** float(cams[str(i)]["exposure"]) for i in range(len(rig))])
        else:
            self.exposures_s = np.full(len(rig), options.tracking_exposure_s)

    def __repr__(self) -> str:
        ball = f"real {self.options.ball_colour} balls ({len(self.real.crops)} crops)" if self.real else f"{self.options.ball_colour} ball"
        return f"SemiRealSession({self.folder.name}, {len(self.frame_indices)} background frame sets, {ball})"

    @property
    def n_frames(self) -> int:
        """Frame sets of the session (its time order: ``timestamps.csv``'s sync index)."""
        return len(self._times)

    def ball_state(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """A ball flying through the workspace at a random time of a random physics flight: its
        position (3,) and velocity (3,) at mid-exposure, world frame."""
        o, (lo, hi) = self.options, self.rig.workspace_m
        R = _lab_from_world()
        for _ in range(100):
            p0 = rng.uniform(lo, hi)
            d = rng.standard_normal(3)
            v0 = rng.uniform(*o.speed_mps) * d / np.linalg.norm(d)
            w0 = 2 * np.pi * o.spin_rps * rng.standard_normal(3)
            t = rng.uniform(0.0, 0.25)
            state = np.concatenate([R @ p0 + [0, 0, LIFT_M], R @ v0, R @ w0])
            s = simulate(state, np.array([t]))[0][0]
            p = R.T @ (s[:3] - [0, 0, LIFT_M])
            if ((p >= lo) & (p <= hi)).all():
                return p, R.T @ s[3:6]
        return p0, v0  # a flight that left the box 100 times: its launch state (the ball at rest time 0)

    def frameset(self, f: int):
        """Frame set ``f``: images (n_cams (H, W, 3) uint8), per camera a one-ball tuple of
        :class:`~harness.sim.render.truth.BallTruth`, the ball's centre (1, 3) and the background frame set's index."""
        rng = np.random.default_rng([self.seed, f])
        k = int(self.frame_indices[rng.integers(len(self.frame_indices))])
        p, v = self.ball_state(rng)
        return (*self._draw(k, p, v, rng)[:2], p[None, :], k)

    def flight(self, n: int, frames: int, rate_hz: float) -> tuple[int, np.ndarray, np.ndarray]:
        """Flight ``n`` (stream ``[seed, n, 0]``): its background frame set index and the ball's positions and
        velocities (frames, 3), world frame, every ``1 / rate_hz`` s. The flight passes a random point of the
        workspace at its middle (launched ``frames / 2`` frames earlier, back along its launch velocity).
        With moving backgrounds the index is the first of ``frames`` consecutive frame sets (module docstring)."""
        rng = np.random.default_rng([self.seed, n, 0])
        o, (lo, hi), R = self.options, self.rig.workspace_m, _lab_from_world()
        if o.moving:
            if frames > self.n_frames:
                raise ValueError(f"a flight of {frames} frame sets over moving backgrounds needs as many of the session's "
                                 f"frame sets; {self.folder} has {self.n_frames}")
            k = int(rng.integers(self.n_frames - frames + 1))
            self._decode_range(k, k + frames)
        else:
            k = int(self.frame_indices[rng.integers(len(self.frame_indices))])
        mid = rng.uniform(lo, hi)
        d = rng.standard_normal(3)
        v0 = rng.uniform(*o.speed_mps) * d / np.linalg.norm(d)
        w0 = 2 * np.pi * o.spin_rps * rng.standard_normal(3)
        t = np.arange(frames) / float(rate_hz)
        state = np.concatenate([R @ (mid - v0 * t[-1] / 2) + [0, 0, LIFT_M], R @ v0, R @ w0])
        s = simulate(state, t)[0]
        return k, (s[:, :3] - [0, 0, LIFT_M]) @ R, s[:, 3:6] @ R

    def flight_frameset(self, n: int, j: int, flight, *, crop: bool = False) -> tuple:
        """Frame ``j`` of flight ``n`` (``flight`` = :meth:`flight`'s result; noise stream ``[seed, n, j + 1]``),
        as :meth:`frameset` returns it; ``crop=True`` appends the pasted real ball's source frame name (None: drawn)."""
        k, P, V = flight
        if self.options.moving:
            self._decode_range(k, k + len(P))  # (decoded by :meth:`flight` in this process; a no-op then)
            k = k + j
        images, truths, source = self._draw(k, P[j], V[j], np.random.default_rng([self.seed, n, j + 1]))
        return (images, truths, P[j][None, :], k, source) if crop else (images, truths, P[j][None, :], k)

    def background(self, k: int) -> list:
        """The session's own frame set ``k`` (n_cams (H, W, 3) uint8, no ball drawn): what a fixed camera saw before a
        flight that starts on frame set ``k + 1`` (a motion cue's background, ``rt2 eval framesets``)."""
        if not 0 <= k < self.n_frames:
            raise ValueError(f"frame set {k} is not in the session {self.folder} (0 .. {self.n_frames - 1})")
        self._decode_range(k, k + 1)
        return [im.copy() for im in self._frames[k]]

    def _decode_range(self, start: int, stop: int) -> None:
        """Decode the frame sets ``start .. stop - 1`` not decoded yet (moving backgrounds); they stay in memory."""
        missing = [k for k in range(start, stop) if k not in self._frames]
        if missing:
            self._frames.update(_decode(self._videos, missing, [c.image_size for c in self.rig]))

    def _frame_blur(self, k: int) -> list:
        """Per camera :func:`~harness.sim.render.composite.edge_blur_px` of frame set ``k`` (the drawn ball's defocus), cached."""
        if k not in self._blur:
            self._blur[k] = [edge_blur_px(cv2.cvtColor(im, cv2.COLOR_RGB2GRAY)) for im in self._frames[k]]
        return self._blur[k]

    def _draw(self, k: int, p: np.ndarray, v: np.ndarray, rng) -> tuple[list, list, str | None]:
        times = self._times[k]
        dt = times - np.median(times) if self.options.sync == "recorded" else np.zeros(len(self.rig))
        balls = [Ball(position_m=p + dt[i] * v, velocity_mps=v, colour=self.options.ball_colour) for i in range(len(self.rig))]
        if self.real is not None:  # one real ball for all cameras: its crop by the flight's smear over its size
            ratios = []
            for cam, ball, T in zip(self.rig, balls, self.exposures_s):
                smear, d = RealBalls.smear_px(cam, ball, float(T))
                ratios.append(np.hypot(*smear) / d if d > 0 else np.nan)
            finite = [r for r in ratios if np.isfinite(r)]
            look = self.real.choose(float(np.median(finite)) if finite else float("nan"), rng)
        source = None if self.real is None else look.crop.source
        images, truths = [], []
        for i, (cam, ball) in enumerate(zip(self.rig, balls)):
            if self.real is not None:
                img, truth, _ = self.real.paste(self._frames[k][i], cam, ball, float(self.exposures_s[i]), look, rng)
            else:
                img, truth = draw_ball(self._frames[k][i], cam, ball, float(self.exposures_s[i]), rng,
                                       light_dir_world=UP_WORLD + 0.3 * np.array([1.0, 0.0, 1.0]), frame_blur_px=self._frame_blur(k)[i])
            images.append(img)
            truths.append((truth,))
        return images, truths, source


def _lab_from_world() -> np.ndarray:
    """Rotation world -> the physics' lab frame (z up): lab x = world x, lab z = world +y."""
    return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _frame_times(path: Path, n_cams: int) -> np.ndarray:
    """(n_frames, n_cams) frame times, seconds, from caliscope's timestamps.csv (rows in sync_index order)."""
    if not path.is_file():
        raise FileNotFoundError(f"semi-real session: missing {path}")
    rows: dict[int, dict[int, float]] = {}
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            try:
                rows.setdefault(int(r["sync_index"]), {})[int(r["cam_id"])] = float(r["frame_time"])
            except (KeyError, ValueError):
                raise ValueError(f"{path}: each row needs sync_index, cam_id and frame_time numbers, got {r}") from None
    out = np.array([[rows[s].get(c, np.nan) for c in range(n_cams)] for s in sorted(rows)])
    if not np.isfinite(out).all():
        raise ValueError(f"{path}: some sync_index rows miss a camera's frame_time")
    return out


def _decode(videos, indices, sizes) -> dict[int, list[np.ndarray]]:
    """{frame index: [RGB image per camera]} for ``indices``, each video read once from the start."""
    want = set(int(i) for i in indices)
    frames = {i: [] for i in sorted(want)}
    for path, (w, h) in zip(videos, sizes):
        cap = cv2.VideoCapture(str(path))
        got = 0
        try:
            for i in range(max(want) + 1):
                ok, bgr = cap.read()
                if not ok:
                    raise ValueError(f"{path}: could not decode frame {i} (the session needs frames up to {max(want)})")
                if i in want:
                    if bgr.shape[:2] != (h, w):
                        raise ValueError(f"{path}: frame {i} is {bgr.shape[1]}x{bgr.shape[0]}, the calibration says {w}x{h}")
                    frames[i].append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
                    got += 1
        finally:
            cap.release()
    return frames
