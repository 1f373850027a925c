"""The tracking service: assembled frame sets in, one observation per frame set out on every stream.

    service = TrackingService(rig, Tracker(rig, "rt2"), publisher=Publisher(...), log=LiveLog(...))
    summary = service.run(framesets, stop=threading.Event(), duration_s=5.0)

``framesets`` is any iterable of :class:`~harness.live.frames.AssembledFrameSet` (a list, a
generator reading a session log) or an assembler with ``get(timeout_s)`` (``None`` on a timeout);
the loop never depends on where the frame sets come from. Per frame set: the tracker
(``Tracker.process_with_info``), the tennicam and rt2 messages (:mod:`harness.live.publish`), the
session log (:mod:`harness.live.session_log`, on its own thread), the live view (throttled), the
figures (:mod:`harness.live.stats`) and, every ``status_period_s``, a status line.

Nothing here restarts a camera or a socket: a camera without frames shows up as ``None`` images
with the assembler's note, the tracker goes on with the others, and the figures report it.
"""

from __future__ import annotations

import math
import resource
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np

from harness.common.gc_pauses import GcPauses, frozen_gc
from harness.live.frames import AssembledFrameSet
from harness.live.publish import rich_message, tennicam_message
from harness.live.stats import LiveStats, process_per_set
from harness.logs.codecs import to_json_value
from tracker import FrameSet

__all__ = ["ServiceOptions", "TrackingService"]


@dataclass(frozen=True)
class ServiceOptions:
    """status_period_s : seconds between status lines (0 = none); get_timeout_s : how long one
    ``get`` of an assembler waits before the loop checks for a stop or the end of the run;
    switch_interval_s : Python's thread switch interval while the service runs (``sys.setswitchinterval``;
    None = leave it): the camera, assembly, log and view threads share one interpreter lock, and the
    default 5 ms would let any of them hold a frame set back that long; gc_freeze : collect once and
    ``gc.freeze()`` what is alive when the run starts (undone at its end), so the collections that the
    per-frame-set allocations trigger never walk the tracker's, the rig's and the libraries' objects"""

    status_period_s: float = 1.0
    get_timeout_s: float = 0.1
    switch_interval_s: float | None = 0.0005
    gc_freeze: bool = True

    def __post_init__(self):
        if not (isinstance(self.status_period_s, (int, float)) and 0 <= self.status_period_s < math.inf):
            raise ValueError(f"status_period_s must be >= 0 seconds, got {self.status_period_s!r}")
        if not (isinstance(self.get_timeout_s, (int, float)) and 0 < self.get_timeout_s <= 10):
            raise ValueError(f"get_timeout_s must be in (0, 10] seconds, got {self.get_timeout_s!r}")
        sw = self.switch_interval_s
        if sw is not None and not (isinstance(sw, (int, float)) and 1e-6 <= sw <= 0.1):
            raise ValueError(f"switch_interval_s must be in [1e-6, 0.1] seconds or None, got {sw!r}")


#: the made-up ball of :func:`warm_up`: a 40 mm ball's radius, metres
WARM_UP_BALL_RADIUS_M = 0.02


def warm_up(tracker, rig, *, n: int = 3) -> None:
    """Run ``tracker`` on ``n`` made-up frame sets (an orange disk of a ball's size where a ball at the
    centre of the rig's workspace would be: the first a full-frame search that confirms it, the next window
    searches around its prediction; a full-frame search after its frame set (``TrackerOptions.defer_full_frame``)
    is waited for, so the next set runs the windows at its ball), then two frame sets without it (the windows'
    full-frame fallback); build and encode their messages without sending them, and forget them, so the first real
    frame sets do not pay for compiled kernels (loaded from numba's cache or compiled), first-call allocations and
    lazy imports."""
    import json

    import cv2

    lo, hi = np.asarray(rig.workspace_m, float) if getattr(rig, "workspace_m", None) is not None else (np.zeros(3), np.ones(3))
    X = (lo + hi) / 2
    uv = np.asarray(rig.project(X), float).reshape(len(rig), 2)
    images = []
    for cam, (u, v) in zip(rig, uv):
        w, h = cam.image_size
        img = np.zeros((h, w, 3), np.uint8)
        depth = float(cam.depth(X[None])[0])
        if np.isfinite(u) and np.isfinite(v) and depth > 0:  # a ball's size there: confirmed, so the next sets predict
            diameter_px = (cam.K[0, 0] + cam.K[1, 1]) * WARM_UP_BALL_RADIUS_M / depth
            radius_px = max(2, int(round((diameter_px - 3.8) / 2)))  # a hard disc's blob is ~3.8 px wider than a ball's
            cv2.circle(img, (int(round(u)), int(round(v))), radius_px, (255, 120, 0), -1)
        images.append(img)
    n_cams = len(images)
    blank = tuple(np.zeros_like(img) for img in images)
    for k in range(n + 2):  # then two without the ball: the windows' fallback (on its own thread when deferred) and its end
        t = time.monotonic()
        afs = AssembledFrameSet(FrameSet(float(k) * 1e-3, tuple(images) if k < n else blank, k), k, np.full(n_cams, t),
                                np.full(n_cams, np.nan), t)
        obs, info = tracker.process_with_info(afs.frameset)
        tracker.settle()  # a full-frame search after the set ends before the next: the next one takes up its ball
        json.dumps(rich_message(k, afs, obs, t_first_host_s=t, camera_names=rig.names, info=info), allow_nan=False)
        json.dumps(tennicam_message(k, _time_ns(afs.frameset.t_s), 0.0, obs.position_m), allow_nan=False)
    tracker.reset(clear_stats=True)


def first_host_stamp(afs: AssembledFrameSet) -> float:
    """The earliest host arrival stamp of the set's frames (``time.monotonic()`` s); the assembly time
    when no frame arrived at all."""
    t = np.asarray(afs.t_host_s, float)
    ok = np.isfinite(t)
    return float(t[ok].min()) if ok.any() else float(afs.t_assembled_s)


class TrackingService:
    """Run ``tracker`` on frame sets and publish, log, view and count each result.

    rig : the tracker's rig (camera names, order); tracker : a :class:`tracker.Tracker`
    publisher : :class:`~harness.live.publish.Publisher` or None; log : :class:`~harness.live.session_log.LiveLog`
    or None; view : :class:`~harness.live.foxglove_view.LiveView` or None
    status : callable taking one line of text (e.g. ``print``), or None
    """

    def __init__(self, rig, tracker, *, publisher=None, log=None, view=None, options: ServiceOptions | None = None,
                 status=None):
        self.rig, self.tracker = rig, tracker
        self.publisher, self.log, self.view = publisher, log, view
        self.options = ServiceOptions() if options is None else options
        if not isinstance(self.options, ServiceOptions):
            raise ValueError(f"options must be a ServiceOptions, got {type(self.options).__name__}")
        self.status = status
        self.log_error: str | None = None  # the log failed (disk full, ...): tracking and publishing went on
        self.stats = LiveStats(rig.names)
        self._gc_pauses = GcPauses()
        self.num = 0
        self._names = rig.names

    # -- one frame set --------------------------------------------------------------------------
    def step(self, afs: AssembledFrameSet):
        """Track, publish, log and count one frame set; returns its ``BallObservation``."""
        if not isinstance(afs, AssembledFrameSet):
            raise ValueError(f"the service takes AssembledFrameSet objects, got {type(afs).__name__}")
        t_taken = time.monotonic()
        full0 = self._full_frame_searches()
        obs, info = self.tracker.process_with_info(afs.frameset)
        num = self.num
        self.num += 1
        t_first = first_host_stamp(afs)
        t_done = t_tracked = time.monotonic()
        if self.publisher is not None:  # a message only for a stream that is on (``--publish-rt2 none``)
            on = self.publisher.addresses
            t_publish = time.monotonic()  # the one publication stamp of both streams (publish.LATENCY)
            rich = (rich_message(num, afs, obs, t_first_host_s=t_first, camera_names=self._names, t_publish_s=t_publish, info=info)
                    if "rt2" in on else None)
            tennicam = (tennicam_message(num, _time_ns(afs.frameset.t_s), t_publish - t_first, obs.position_m)
                        if "tennicam" in on else None)
            self.publisher.publish(tennicam, rich)  # complete messages: the transport only sends
            t_done = time.monotonic()
        latency = t_done - t_first  # the figures: to the messages handed to the sockets (the stages' sum)
        t_asm = float(afs.t_assembled_s)
        self.stats.add(afs, obs, latency, t_done,
                       (t_asm - t_first, t_taken - t_asm, t_tracked - t_taken, t_done - t_tracked, math.nan),
                       full_frame=self._full_frame_searches() > full0)
        if self.log is not None and self.log_error is None:
            try:
                self.log.write(num, self.log.log_time(t_first), afs, obs, info)
            except Exception as exc:  # the robot keeps its stream: stop logging, say so, go on
                self.log_error = f"{type(exc).__name__}: {exc}"
                if self.status is not None:
                    self.status(f"the session log failed at frame set {num}; tracking and publishing go on without it: {self.log_error}")
        if self.view is not None:
            self.view.update(num, afs, obs, info)
        self.stats.stage("after", time.monotonic() - t_done)
        return obs

    def _full_frame_searches(self) -> int:
        """The tracker's count of full-frame searches so far (0 for a tracker that does not count them)."""
        return int(getattr(getattr(self.tracker, "stats", None), "full_frame_searches", 0) or 0)

    # -- the loop -------------------------------------------------------------------------------
    def _frames(self, source, stop: threading.Event, deadline: float):
        if hasattr(source, "get") and callable(source.get):
            while not stop.is_set() and time.monotonic() < deadline:
                afs = source.get(self.options.get_timeout_s)
                if afs is None:
                    finished = getattr(source, "finished", False)  # a property or a method
                    if finished() if callable(finished) else finished:
                        return
                    yield None
                else:
                    yield afs
            return
        for afs in source:
            if stop.is_set() or time.monotonic() >= deadline:
                return
            yield afs

    def run(self, source, *, stop: threading.Event | None = None, duration_s: float | None = None) -> dict:
        """Process frame sets until ``source`` ends, ``stop`` is set or ``duration_s`` has passed;
        returns :meth:`summary`. The log is finished (closed with its footer) on the way out, whatever
        ended the run."""
        stop = stop if stop is not None else threading.Event()
        if duration_s is not None and not (isinstance(duration_s, (int, float)) and duration_s > 0):
            raise ValueError(f"duration_s must be a positive number of seconds, got {duration_s!r}")
        deadline = math.inf if duration_s is None else time.monotonic() + float(duration_s)
        period = self.options.status_period_s
        next_status = time.monotonic() + period if period > 0 else math.inf
        error = None
        old_switch = sys.getswitchinterval()
        if self.options.switch_interval_s is not None:
            sys.setswitchinterval(self.options.switch_interval_s)
        use0 = resource.getrusage(resource.RUSAGE_SELF)
        counters0 = self.tracker.stats.as_dict()
        try:  # everything alive now (rig, tracker, model, sockets) leaves the collector's generations
            with frozen_gc(self._gc_pauses, freeze=self.options.gc_freeze):
                for afs in self._frames(source, stop, deadline):
                    if afs is not None:
                        self.step(afs)
                    if time.monotonic() >= next_status:
                        next_status = time.monotonic() + period
                        if self.status is not None:
                            self.status(self.stats.status_line() + _assembly_status(source))
        except BaseException as exc:
            error = f"{type(exc).__name__}: {exc}"
            raise
        finally:
            self._process = process_per_set(use0, resource.getrusage(resource.RUSAGE_SELF), self.stats.n)
            self._tracker_stats = {k: v - counters0[k] for k, v in self.tracker.stats.as_dict().items()}
            sys.setswitchinterval(old_switch)
            self.finish(error=error, source=source)
        return self.summary()

    def summary(self) -> dict:
        s = self.stats.summary()
        s["tracker"] = self.tracker.kind
        s["cameras"] = list(self._names)
        if self.publisher is not None:
            s["published"] = dict(self.publisher.sent)
            s["publish_failed"] = dict(self.publisher.failed)
            s["addresses"] = dict(self.publisher.addresses)
        if self.view is not None:
            s["view"] = {"port": self.view.port, "sent": dict(self.view.sent), "error": self.view.error}
        if self.log is not None:
            s["log"] = {"path": str(self.log.path), "dropped": self.log.dropped, "error": self.log_error}
        s["gc"] = self._gc_pauses.summary()
        if self._process is not None:
            s["process_per_set"] = self._process  # CPU ms, page faults, context switches per frame set (the run)
        if self._tracker_stats is not None:  # the tracker's counters over the run (tracker.TrackerStats)
            s["tracker_stats"] = self._tracker_stats
        if self._assembly is not None:
            s["assembly"] = self._assembly
            if isinstance(self._assembly, dict) and "dropped_framesets" in self._assembly:
                s["skipped_framesets"] = self._assembly["dropped_framesets"]
                s["max_backlog"] = self._assembly.get("backlog")
        return s

    _assembly = None
    _finished = False
    _process = None
    _tracker_stats = None

    def finish(self, *, error: str | None = None, source=None) -> None:
        """Record the assembler's figures (if it has ``stats()``) and close the log with the summary."""
        if self._finished:
            return
        self._finished = True
        if source is not None and hasattr(source, "stats") and callable(source.stats):
            try:
                self._assembly = to_json_value(source.stats(), "assembly figures", lenient=True)
            except Exception as exc:  # figures only: never lose the log over them
                self._assembly = {"error": f"{type(exc).__name__}: {exc}"}
        if self.log is not None:
            try:
                self.log.close(figures=to_json_value(self.summary(), "live summary", lenient=True), error=error or self.log_error)
            except Exception as exc:  # reported in the summary (``log.error``); the run's figures stand
                what = f"closing it: {type(exc).__name__}: {exc}"
                self.log_error = what if self.log_error is None else f"{self.log_error}; {what}"


def _assembly_status(source) -> str:
    """The assembler's drops for the status line: frame sets the tracker did not take in time, and
    per camera frames dropped from its queue / arrived too late (nothing where the source has no stats)."""
    stats = getattr(source, "stats", None)
    if not callable(stats):
        return ""
    try:
        a = stats()
        drops = " ".join(f"{d}/{l}" for d, l in zip(a.dropped, a.late))
        return (f", sets skipped {a.dropped_framesets} (backlog {a.backlog}), "
                f"frames dropped/late per camera {drops}")
    except Exception:  # figures only
        return ""


def _time_ns(t_s: float) -> int:
    """The tennicam ``time``: the frame set's capture time (host CLOCK_MONOTONIC seconds) in ns."""
    return int(round(float(t_s) * 1e9)) if math.isfinite(t_s) else 0
