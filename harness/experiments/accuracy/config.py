"""Configuration of the accuracy experiment: one frozen dataclass, stored in the session log's metadata.

``AccuracyConfig.to_dict()`` is what the log records as ``config``; ``AccuracyConfig.from_dict`` reads
it back for re-evaluation (unknown keys raise and name the field). ``QUICK_FRAMES`` / ``DEFAULT_FRAMES``
size ``--quick`` and the default run.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path

import numpy as np

from harness.experiments.accuracy.motion import MotionOptions
from harness.experiments.accuracy.registration import RegistrationOptions
from harness.experiments.accuracy.rig_error import CalibrationErrorOptions
from harness.experiments.accuracy.session_scene import SceneOptions
from harness.experiments.accuracy.stats import TRACKER_KINDS

__all__ = ["AccuracyConfig", "DEFAULT_FRAMES", "DEFAULT_LOG_IMAGES", "QUICK_FRAMES", "REGISTER_LAYOUTS", "RTBLOB_SETUPS"]

#: frames of ``rt2 accuracy --quick`` (about a minute on the 2-core machine) and of the default run
QUICK_FRAMES = 500
DEFAULT_FRAMES = 4000
#: default ``--log-images``: every 50th frame set (4 Hz at 200 Hz) as lossless PNG; detections always
DEFAULT_LOG_IMAGES = 50
#: which frames register the robot base to the camera world: "interleaved" = blocks of
#: ``register_block_s`` spread evenly over the run (the registration sees the same workspace as the scored
#: frames); "first" = the first ``register_fraction`` of the run (the layout before 2026-11-22)
REGISTER_LAYOUTS = ("interleaved", "first")
#: how RTBlob is set up: "calibrated" = disk radius and reference colour from the rig and the rendered
#: ball (harness.experiments.accuracy.calibration, a fair set-up); "default" = RTBlobOptions() as it comes
RTBLOB_SETUPS = ("calibrated", "default")


@dataclass(frozen=True)
class AccuracyConfig:
    """Everything that fixes an accuracy run (with the seed, the same config gives the same figures).

    seed : seeds the trajectory, the robot's bias and noise, the scene and the sensor noise
    n_frames, rate_hz : camera frame sets and their rate (Hz); the run lasts n_frames / rate_hz seconds
    rig : rig name or path (``tracker.rig_files.resolve_rig``)
    model : segmentation model (.npz) of the rt2 trackers; None = ``data/models/ball_seg_default.npz``
    trackers : kinds run on the same frames, a subset of ("rt2", "rt2-paper", "rtblob")
    eps_px : the rt2 estimators' consistency threshold (None = RobustOptions' default)
    register_fraction : the share of frames used to register the robot base to the camera world
    register_layout : one of REGISTER_LAYOUTS; register_block_s : block length of "interleaved", seconds
    warmup_s : before each segment (but the first) its trackers are run, freshly reset, over the frames of
        this much time before its start, and those outputs are dropped, so a segment starts with trackers
        in the state of a continuous session (at most ``segment_frames`` frames; 0 = no warm-up)
    segment_frames : frames per independent segment: trackers are reset at each segment's start, so a
        segment can run in any worker process and the result does not depend on ``--workers``
    inject_faults : camera faults of :class:`harness.experiments.accuracy.faults.FaultPlan`
    rtblob_setup : one of RTBLOB_SETUPS
    robot : the arm carrying the ball: a shipped arm's name (``wam``, ``panda``, ``ur10``, ``xarm7``) or a robot
        config's path (``robot_models.load_robot_config``)
    motion : the robot's trajectory, ground-truth sampling and camera-to-robot clock error (MotionOptions)
    scene : what the cameras see besides the ball (SceneOptions)
    calibration_error : the error of the rig the trackers get (the renderer uses the true rig), see
        :mod:`harness.experiments.accuracy.rig_error`
    """

    seed: int = 0
    n_frames: int = DEFAULT_FRAMES
    rate_hz: float = 200.0
    rig: str = "lab4_vga"
    model: str | None = None
    trackers: tuple = TRACKER_KINDS
    eps_px: float | None = None
    register_fraction: float = 0.3
    register_layout: str = "interleaved"
    register_block_s: float = 0.25
    segment_frames: int = 500
    warmup_s: float = 0.5
    inject_faults: bool = False
    rtblob_setup: str = "calibrated"
    robot: str = "wam"
    motion: MotionOptions = field(default_factory=MotionOptions)
    scene: SceneOptions = field(default_factory=SceneOptions)
    registration: RegistrationOptions = field(default_factory=RegistrationOptions)
    calibration_error: CalibrationErrorOptions = field(default_factory=CalibrationErrorOptions)

    def __post_init__(self):
        for name, low in (("seed", 0), ("n_frames", 20), ("segment_frames", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise ValueError(f"AccuracyConfig.{name} must be an integer >= {low}, got {v!r}")
        if not (isinstance(self.rate_hz, (int, float)) and 1.0 <= self.rate_hz <= 10000.0):
            raise ValueError(f"AccuracyConfig.rate_hz must be in [1, 10000] Hz, got {self.rate_hz!r}")
        trackers = tuple(self.trackers)
        bad = [t for t in trackers if t not in TRACKER_KINDS]
        if not trackers or bad or len(set(trackers)) != len(trackers):
            raise ValueError(f"AccuracyConfig.trackers must be distinct kinds of {list(TRACKER_KINDS)}, got {list(trackers)}")
        object.__setattr__(self, "trackers", trackers)
        if self.eps_px is not None and not (isinstance(self.eps_px, (int, float)) and 0 < self.eps_px < 1000):
            raise ValueError(f"AccuracyConfig.eps_px must be a positive number of pixels or None, got {self.eps_px!r}")
        if not (isinstance(self.register_fraction, (int, float)) and 0.05 <= self.register_fraction <= 0.9):
            raise ValueError(f"AccuracyConfig.register_fraction must be in [0.05, 0.9], got {self.register_fraction!r}")
        w = self.warmup_s
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not 0 <= w <= 60:
            raise ValueError(f"AccuracyConfig.warmup_s must be in [0, 60] s, got {w!r}")
        if self.register_layout not in REGISTER_LAYOUTS:
            raise ValueError(f"unknown AccuracyConfig.register_layout {self.register_layout!r}; valid: {list(REGISTER_LAYOUTS)}")
        b = self.register_block_s
        if isinstance(b, bool) or not isinstance(b, (int, float)) or not 0 < b <= 3600:
            raise ValueError(f"AccuracyConfig.register_block_s must be in (0, 3600] s, got {b!r}")
        if self.rtblob_setup not in RTBLOB_SETUPS:
            raise ValueError(f"unknown AccuracyConfig.rtblob_setup {self.rtblob_setup!r}; valid: {list(RTBLOB_SETUPS)}")
        if not isinstance(self.robot, str) or not self.robot:
            raise ValueError(f"AccuracyConfig.robot must be an arm's name or a robot config's path, got {self.robot!r}")
        if self.model is not None and not isinstance(self.model, str):
            raise ValueError(f"AccuracyConfig.model must be a path string or None, got {self.model!r}")
        for name, cls in _NESTED.items():
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f"AccuracyConfig.{name} must be a {cls.__name__}, got {type(getattr(self, name)).__name__}")

    @property
    def register_mask(self) -> np.ndarray:
        """(n_frames,) bool: the frames that register the robot; the others are scored.

        "first": frames < round(register_fraction * n_frames). "interleaved": the run is cut into blocks of
        ``round(register_block_s * rate_hz)`` frames (at most a tenth of the run, so short runs get ten blocks)
        and block j registers when floor((j + 1) f) > floor(j f) (f = register_fraction): a share f of the
        blocks, evenly spread, the first block scored.
        """
        k = np.arange(self.n_frames)
        if self.register_layout == "first":
            return k < int(round(self.register_fraction * self.n_frames))
        block = max(1, min(int(round(self.register_block_s * self.rate_hz)), self.n_frames // 10))
        j = k // block
        f = float(self.register_fraction)
        return np.floor((j + 1) * f + 1e-9) > np.floor(j * f + 1e-9)

    @property
    def n_register(self) -> int:
        """How many frames register the robot (:attr:`register_mask`)."""
        return int(self.register_mask.sum())

    @property
    def registration_tracker(self) -> str:
        """The tracker whose positions register the robot base to the camera world (rt2 when run)."""
        return "rt2" if "rt2" in self.trackers else self.trackers[0]

    @property
    def warmup_frames(self) -> int:
        """Frames tracked (and dropped) before each segment's start: round(warmup_s * rate_hz), at most a segment."""
        return min(int(round(self.warmup_s * self.rate_hz)), self.segment_frames)

    def segments(self) -> list[tuple[int, int]]:
        """[(first frame, last frame + 1)] of the independent segments."""
        s = self.segment_frames
        return [(a, min(a + s, self.n_frames)) for a in range(0, self.n_frames, s)]

    def model_path(self) -> Path:
        from tracker.pipeline import DEFAULT_MODEL

        return DEFAULT_MODEL if self.model is None else Path(self.model)

    def with_(self, **changes) -> "AccuracyConfig":
        return replace(self, **changes)

    def idealised(self, *, calibration: bool = True, clock: bool = True) -> "AccuracyConfig":
        """This config without the realism effects named: ``calibration`` = the trackers get the true
        rig; ``clock`` = camera and robot clocks agree exactly (``rt2 accuracy --ideal`` does both)."""
        out = self
        if calibration:
            out = replace(out, calibration_error=replace(out.calibration_error, enabled=False))
        if clock:
            out = replace(out, motion=replace(out.motion, clock_offset_std_s=0.0, clock_jitter_std_s=0.0))
        return out

    @property
    def realism(self) -> str:
        """One line: which realism effects are on (for headers and figure titles)."""
        cal = self.calibration_error
        parts = [f"calibration error {cal.target_reprojection_px:g} px" if cal.enabled and cal.target_reprojection_px
                 else "calibration error (as drawn)" if cal.enabled else "exact calibration"]
        m = self.motion
        parts.append(f"clock offset ~{m.clock_offset_std_s * 1e3:g} ms, jitter {m.clock_jitter_std_s * 1e3:g} ms"
                     if m.clock_offset_std_s or m.clock_jitter_std_s else "synchronised clocks")
        return ", ".join(parts)

    def to_dict(self) -> dict:
        return _to_plain(self)

    @classmethod
    def from_dict(cls, data: dict, where: str = "config") -> "AccuracyConfig":
        """Inverse of :meth:`to_dict`; unknown or misspelt keys raise ``ValueError`` naming ``where``.

        A config logged before the calibration and clock errors existed (no ``calibration_error`` key)
        is read as it ran: exact calibration, synchronised clocks, registration on the first frames, no
        warm-up of the segments."""
        if isinstance(data, dict) and "calibration_error" not in data:
            data = {"register_layout": "first", "warmup_s": 0.0, **data, "calibration_error": {"enabled": False}}
            if isinstance(data.get("motion"), dict):
                data["motion"] = {"clock_offset_std_s": 0.0, "clock_jitter_std_s": 0.0, **data["motion"]}
        return _from_plain(cls, data, where)


_NESTED = {"motion": MotionOptions, "scene": SceneOptions, "registration": RegistrationOptions,
           "calibration_error": CalibrationErrorOptions}


def _to_plain(obj):
    if is_dataclass(obj):
        return {f.name: _to_plain(getattr(obj, f.name)) for f in fields(obj)}
    if isinstance(obj, (tuple, list)):
        return [_to_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _to_tuple(v):
    return tuple(_to_tuple(x) for x in v) if isinstance(v, list) else v


def _from_plain(cls, data, where: str):
    if not isinstance(data, dict):
        raise ValueError(f"{where} must be a mapping, got {type(data).__name__}")
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {unknown}; valid: {sorted(known)}")
    kwargs = {}
    for name, value in data.items():
        nested = _NESTED.get(name) if cls is AccuracyConfig else None
        if nested is not None:
            kwargs[name] = _from_plain(nested, value, f"{where}.{name}")
        else:
            kwargs[name] = _to_tuple(value)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
