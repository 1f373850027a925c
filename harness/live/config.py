"""What ``rt2 track``'s live service runs with: :class:`TrackConfig`, checked once when it is made.

    config = TrackConfig(source=("sim",), rate_hz=200.0, publish=None, duration_s=5.0)
    with open_service(config) as live:          # harness.live.run
        live.assembler.start()
        summary = live.service.run(live.assembler, duration_s=config.duration_s)

``rt2 track`` (:mod:`harness.cli.track`) and ``rt2 bench live`` build it from their options; Python
callers build it directly. A bad value raises :class:`ConfigError`, a ``ValueError`` that names the
field (``rate_hz must be a positive number of frames per second, got 0``); the command line shows the
same message with its own flag names (:meth:`ConfigError.render`: ``--rate-hz must be ...``).
Checks that need the file system (the rig, the model, the log and output paths) are
:meth:`TrackConfig.check_paths`, which :func:`harness.live.run.open_service` runs before it opens anything.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, fields
from pathlib import Path

from harness.logs.writer import LogError, check_log_images

__all__ = ["DEFAULT_MAX_BACKLOG", "DEFAULT_WORKERS", "NEXT_PORT", "SIM_RENDER", "ConfigError", "TrackConfig", "check_output_path"]

#: frame sets that may wait for the tracker before the oldest is skipped (``max_backlog``); chosen with
#: ``rt2 bench live --max-backlog 1`` and ``3`` against the default (README, "Latency first")
DEFAULT_MAX_BACKLOG = 1
#: detector threads of the rt2 kinds by default: a full-frame search (a new ball, a lost one) runs two cameras at a
#: time (OpenCV releases the interpreter lock); measured with `rt2 bench live` (README, "The per-frame cost")
DEFAULT_WORKERS = 2
#: where the sim source renders (``sim_render``): auto = a child process unless prerendered or from a truth stream
SIM_RENDER = ("auto", "process", "thread")
#: ``publish_rt2`` value: rt2's stream on the port after the tennicam one
NEXT_PORT = "next"


class ConfigError(ValueError):
    """A bad :class:`TrackConfig` value. ``field`` is the field at fault; the message names fields as
    ``{field}`` placeholders, filled in with the field names themselves (``str``) or with a caller's
    names for them (:meth:`render`, e.g. the command line's flags)."""

    def __init__(self, field: str, template: str):
        self.field, self.template = field, template
        super().__init__(self.render({}))

    def render(self, names: dict) -> str:
        """The message with each ``{field}`` placeholder replaced by ``names.get(field, field)``."""
        known = {f.name for f in fields(TrackConfig)}
        return re.sub(r"\{(\w+)\}", lambda m: names.get(m.group(1), m.group(1)) if m.group(1) in known or m.group(1) in names else m.group(0),
                      self.template)


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _whole(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


@dataclass(frozen=True)
class TrackConfig:
    """Everything ``rt2 track`` runs with (docs/live.md; the flag of each field in ``rt2 track --help``).

    Cameras and frame sets:
    rig : rig file or name in data/rigs; source : the source spec words (``("sim",)``, ``("replay", LOG)``,
    ``("opencv", "0,1,2,3")``, ...); rate_hz : frame rate of sim/replay sources and the assembler, Hz;
    seed : the sim source's scene and noise; prerender_s : sim only, seconds rendered up front and looped
    (None = render live); truth_stream : sim only, a lab truth stream address (None = off); scene : the
    lab truth scene; max_behind_s : with a truth stream, how far behind the cameras may fall, seconds;
    sim_rig : sim only, the rig the cameras render with (None = ``rig``); sim_render : one of
    :data:`SIM_RENDER`; sim_render_nice : sim only, the render process's
    CPU priority below the tracker's (os.nice 0-19; None = the sim source's default, 10); sim_ball : the sim source's
    own scene's ball, "orange" or "white" (for a white-ball model); queue_s : frames buffered per camera, seconds of the frame rate;
    max_backlog : frame sets that may wait for the tracker (whole number, at most the queue's length)

    Tracker:
    tracker : the kind (``tracker.TRACKER_KINDS``); model_path : rt2 kinds' segmentation model (None =
    the shipped one); workers : detector threads, 1..64 (None = :data:`DEFAULT_WORKERS` for the rt2 kinds,
    whose full-frame searches then run two cameras at a time, 1 for rtblob; :attr:`tracker_workers`); roi : the rt2 kinds' window search (None = the
    kind's default; False = full frame every frame set); full_frame_pyramid : the rt2 kind's full-frame search of a camera
    whose ball is large at a reduced resolution (``tracker.TrackerOptions.full_frame_pyramid``; on here, off offline);
    defer_full_frame : the rt2 kind's full-frame searches after their frame set was reported, their ball steering the
    next frame set's windows (``tracker.TrackerOptions.defer_full_frame``; off offline). None = auto: on for a model
    without a learned stage, off with one (a learned stage's windows fall back to full frames often, and while such a
    search runs the frame sets are reported unsearched: on lab4_vga with the white stage the ok share fell from 63 to
    34 %; docs/pipeline.md, "Full frames after the frame set");
    motion_cue : the rt2 kind's full-frame candidates only where the frame moved against the camera's background
    (``tracker.TrackerOptions.motion_cue`` with its default :class:`tracker.MotionOptions`; off by default)

    Outputs:
    publish : the tennicam stream's address (None = off); publish_rt2 : rt2's stream's address,
    :data:`NEXT_PORT` (the tennicam port + 1) or None (off); foxglove_port : the live view's port (None =
    off) on foxglove_host; log_path : the session log (.mcap; None = none), log_overwrite : replace one
    that exists, log_images : "all", "none" or every N-th frame set, log_image_format : "jpeg", "png", "raw";
    duration_s : stop after this many seconds (None = when the source ends or on a stop);
    status_period_s : seconds between status lines (0 = none)
    """

    rig: str = "lab4_vga"
    source: tuple = ("sim",)
    rate_hz: float = 200.0
    seed: int = 0
    prerender_s: float | None = None
    truth_stream: str | None = None
    scene: str = "accuracy"
    max_behind_s: float = 0.1
    sim_rig: str | None = None
    sim_render: str = "auto"
    sim_render_nice: int | None = None
    sim_ball: str = "orange"
    queue_s: float = 0.25
    max_backlog: int = DEFAULT_MAX_BACKLOG
    tracker: str = "rt2"
    model_path: str | None = None
    workers: int | None = None
    roi: bool | None = None
    full_frame_pyramid: bool = True
    defer_full_frame: bool | None = None
    motion_cue: bool = False
    publish: str | None = "tcp://127.0.0.1:7660"
    publish_rt2: str | None = NEXT_PORT
    foxglove_port: int | None = None
    foxglove_host: str = "127.0.0.1"
    log_path: str | None = None
    log_overwrite: bool = False
    log_images: str = "20"
    log_image_format: str = "jpeg"
    duration_s: float | None = None
    status_period_s: float = 1.0

    def __post_init__(self):
        from tracker.pipeline import TRACKER_KINDS

        object.__setattr__(self, "source", tuple(str(s) for s in self.source))
        sim = bool(self.source) and self.source[0] == "sim"
        src = " ".join(self.source)
        if not _number(self.rate_hz) or not self.rate_hz > 0:
            raise ConfigError("rate_hz", f"{{rate_hz}} must be a positive number, got {self.rate_hz}")
        if not _whole(self.seed) or self.seed < 0:  # the sim source's seeds are numpy's: none below 0
            raise ConfigError("seed", f"{{seed}} must be a whole number >= 0, got {self.seed!r}")
        if self.prerender_s is not None:
            if not sim:
                raise ConfigError("prerender_s", f"{{prerender_s}} applies to the sim source only, got {{source}} {src}")
            if not (_number(self.prerender_s) and 0 < self.prerender_s <= 10):
                raise ConfigError("prerender_s", f"{{prerender_s}} must be in (0, 10] seconds, got {self.prerender_s}")
        if not (_number(self.queue_s) and 0 < self.queue_s <= 10):
            raise ConfigError("queue_s", f"{{queue_s}} must be in (0, 10] seconds, got {self.queue_s}")
        n = self.queue_len
        if not _whole(self.max_backlog) or not 1 <= self.max_backlog <= n:
            raise ConfigError("max_backlog", f"{{max_backlog}} must be a whole number of frame sets in [1, {n}] "
                                             f"({{queue_s}} x {{rate_hz}}), got {self.max_backlog!r}")
        if not sim and (self.truth_stream or self.sim_rig):
            raise ConfigError("truth_stream" if self.truth_stream else "sim_rig",
                              f"{{truth_stream}} and {{sim_rig}} apply to the sim source only, got {{source}} {src}")
        if self.truth_stream:
            if self.prerender_s is not None:
                raise ConfigError("prerender_s", "{prerender_s} cannot go with {truth_stream} (the lab is rendered as the truth arrives)")
            if not (_number(self.max_behind_s) and 0 < self.max_behind_s <= 3600):
                raise ConfigError("max_behind_s", f"{{max_behind_s}} must be in (0, 3600] seconds, got {self.max_behind_s}")
        if self.sim_ball not in ("orange", "white"):
            raise ConfigError("sim_ball", f"{{sim_ball}} must be 'orange' or 'white', got {self.sim_ball!r}")
        if self.sim_ball != "orange" and (not sim or self.truth_stream):
            raise ConfigError("sim_ball", f"{{sim_ball}} applies to the sim source's own scene only, got {{source}} {src}"
                                          + (" with {truth_stream}" if sim else ""))
        if self.sim_render not in SIM_RENDER:
            raise ConfigError("sim_render", f"{{sim_render}} must be one of {SIM_RENDER}, got {self.sim_render!r}")
        if self.sim_render != "auto" and not sim:
            raise ConfigError("sim_render", f"{{sim_render}} applies to the sim source only, got {{source}} {src}")
        if self.sim_render == "process" and (self.prerender_s is not None or self.truth_stream):
            raise ConfigError("sim_render", "{sim_render} process cannot go with {prerender_s} or {truth_stream} "
                                            "(those render in the service's process)")
        if self.sim_render_nice is not None:
            if not _whole(self.sim_render_nice) or not 0 <= self.sim_render_nice <= 19:
                raise ConfigError("sim_render_nice", f"{{sim_render_nice}} must be a whole number in [0, 19], got {self.sim_render_nice!r}")
            if not sim:
                raise ConfigError("sim_render_nice", f"{{sim_render_nice}} applies to the sim source only, got {{source}} {src}")
        if self.tracker not in TRACKER_KINDS:
            raise ConfigError("tracker", f"unknown {{tracker}} {self.tracker!r}; valid: {', '.join(TRACKER_KINDS)}")
        if self.workers is not None and (not _whole(self.workers) or not 1 <= self.workers <= 64):
            raise ConfigError("workers", f"{{workers}} must be a whole number in [1, 64], got {self.workers!r}")
        if self.model_path is not None and self.tracker == "rtblob":
            raise ConfigError("model_path", "{model_path} applies to the rt2 kinds only (rtblob matches a colour and a template, it has no model)")
        if self.roi is not None and not isinstance(self.roi, bool):
            raise ConfigError("roi", f"{{roi}} must be True, False or None (the kind's default), got {self.roi!r}")
        if not isinstance(self.full_frame_pyramid, bool):
            raise ConfigError("full_frame_pyramid", f"{{full_frame_pyramid}} must be True or False, got {self.full_frame_pyramid!r}")
        if self.defer_full_frame is not None and not isinstance(self.defer_full_frame, bool):
            raise ConfigError("defer_full_frame", f"{{defer_full_frame}} must be True, False or None (auto), got {self.defer_full_frame!r}")
        if not isinstance(self.motion_cue, bool):
            raise ConfigError("motion_cue", f"{{motion_cue}} must be True or False, got {self.motion_cue!r}")
        if self.duration_s is not None and not (_number(self.duration_s) and self.duration_s > 0):
            raise ConfigError("duration_s", f"{{duration_s}} must be a positive number of seconds, got {self.duration_s}")
        if not (_number(self.status_period_s) and self.status_period_s >= 0):
            raise ConfigError("status_period_s", f"{{status_period_s}} must be >= 0 seconds, got {self.status_period_s}")
        if self.foxglove_port is not None and not (_whole(self.foxglove_port) and 0 <= self.foxglove_port <= 65535):
            raise ConfigError("foxglove_port", f"{{foxglove_port}} must be a port number 0..65535 or None, got {self.foxglove_port!r}")
        if not isinstance(self.log_overwrite, bool):
            raise ConfigError("log_overwrite", f"{{log_overwrite}} must be True or False, got {self.log_overwrite!r}")
        try:
            check_log_images(self.log_images)
        except LogError:
            raise ConfigError("log_images", f"{{log_images}} must be 'all', 'none' or a positive integer N (every N-th frame set), "
                                            f"got {self.log_images!r}") from None

    @property
    def queue_len(self) -> int:
        """Frames each camera's queue holds (and frame sets the assembler's input holds): ``queue_s`` at ``rate_hz``, at least 8."""
        return max(8, math.ceil(self.queue_s * self.rate_hz))

    @property
    def tracker_workers(self) -> int:
        """The tracker's detector threads: ``workers``, or by default :data:`DEFAULT_WORKERS` for the rt2
        kinds and 1 for rtblob (which runs its cameras in its own loop)."""
        if self.workers is not None:
            return int(self.workers)
        return 1 if self.tracker == "rtblob" else DEFAULT_WORKERS

    def check_paths(self) -> None:
        """The checks that need the file system, before anything is opened: the model exists; the log
        and its folder can be written and do not replace a file unless ``log_overwrite``."""
        if self.model_path is not None and not Path(self.model_path).is_file():
            raise ConfigError("model_path", f"{{model_path}} {str(self.model_path)!r}: no such file (train one with `rt2 train --out MODEL.npz`)")
        if self.log_path:
            check_output_path("log_path", self.log_path)
            if Path(self.log_path).exists() and not self.log_overwrite:
                raise ConfigError("log_path", f"{{log_path}} {self.log_path!r} exists; pass {{log_overwrite}} to replace it")


def check_output_path(field: str, value) -> None:
    """Refuse an output path that is a folder or lies under a file (:class:`ConfigError` naming ``field``);
    missing folders are created when the file is written."""
    p = Path(value)
    if p.is_dir():
        raise ConfigError(field, f"{{{field}}} {str(value)!r} is a folder; give a file name")
    parent = next((q for q in p.parents if q.exists()), None)
    if parent is not None and not parent.is_dir():
        raise ConfigError(field, f"{{{field}}} {str(value)!r}: {str(parent)!r} is a file, not a folder")
