"""A paced feed: one producer thread emits frame sets into per-camera bounded queues; one
:class:`FeedCamera` view per camera is the :class:`~harness.live.frames.FrameSource`.

Used by the backends whose frames come from software (``sim``, ``replay``, ``video``): they yield
:class:`FeedItem` objects (one per frame set) and the feed emits item k at
``t0 + t_sched_s / speed`` on the host's monotonic clock, stamping ``t_host_s`` at emission. With
``speed=None`` items are emitted as fast as the readers take them (lossless: the feed waits while a
camera's queue is full). In real time a full queue drops its oldest frame and counts it, like a
camera whose driver buffers overflow.

An item that the producer delivers more than ``late_tolerance_s`` after it was due is emitted at
once and counted in ``late``. With ``slide=True`` (replay, video) the schedule then restarts from
that item (``t0`` slides), so a producer that cannot keep up runs slower than real time, visibly,
rather than bursting; with ``slide=False`` (sim) the schedule stays fixed and the producer is
expected to skip ahead itself (``schedule_now()`` tells it where the clock is).

A consumer of every camera of a paced (``speed`` not None) feed may :meth:`PacedFeed.connect` a sink
before it starts: each frame set is then handed to the sink in the pacer's thread at emission, all
cameras at once, instead of going through the per-camera queues and one reader thread per camera
(:class:`harness.live.assembly.FrameSetAssembler` does so: the frame set is assembled in the thread
that stamped it, with no thread hand-over between the stamp and the tracker's queue).
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from harness.live.frames import Frame, SourceError

__all__ = ["FeedCamera", "FeedItem", "FeedStats", "PacedFeed"]

_END = object()


@dataclass(frozen=True)
class FeedItem:
    """One frame set from a software source.

    frame_ids : per camera of the feed, the frame id
    t_sched_s : emission time, seconds from the start of the feed's schedule (ignored when ``speed=None``)
    t_device_s : per camera, the recorded capture time in seconds (a device stamp), or None
    images : per camera, (H, W, 3) uint8 RGB or None (this camera has no frame in this set)
    """

    frame_ids: tuple
    t_sched_s: float
    t_device_s: tuple
    images: tuple


@dataclass(frozen=True)
class FeedStats:
    """Counters of a feed.

    emitted : frame sets emitted
    late : frame sets the producer delivered later than ``late_tolerance_s`` after they were due
    dropped : per camera of the feed, frames dropped from a full queue (the reader was too slow)
    rate_hz : frame sets emitted per second since the first one
    skipped : frame sets the producer skipped to catch up with the clock (sim)
    """

    emitted: int
    late: int
    dropped: tuple
    rate_hz: float
    skipped: int = 0


class PacedFeed:
    """Run ``produce()`` (an iterator of :class:`FeedItem`) and emit its items at their schedule.

    name : for messages (e.g. ``"sim"``, ``"replay run.mcap"``)
    cameras : rig indices of the feed's cameras, in the order of ``FeedItem`` entries
    names : the rig's names of those cameras
    speed : 1.0 = real time, 2.0 = twice as fast, None = as fast as the readers take frames (lossless)
    queue_len : frames buffered per camera
    prefetch : items produced ahead in a second thread (0 = the pacing thread produces them itself);
        used by ``sim`` to render ahead while the pacer sleeps
    late_tolerance_s : how late an item may be delivered before it counts as late
    """

    def __init__(self, name: str, cameras, names, produce: Callable[[], Iterator[FeedItem]], *,
                 speed: float | None = 1.0, queue_len: int = 8, prefetch: int = 0,
                 late_tolerance_s: float = 0.005, slide: bool = True):
        if speed is not None and not (isinstance(speed, (int, float)) and speed > 0 and np.isfinite(speed)):
            raise ValueError(f"{name}: speed must be a positive number or None (as fast as possible), got {speed!r}")
        if int(queue_len) < 1 or int(prefetch) < 0:
            raise ValueError(f"{name}: queue_len must be >= 1 and prefetch >= 0, got {queue_len!r}, {prefetch!r}")
        self.name = name
        self.cameras = tuple(int(c) for c in cameras)
        self.names = tuple(names)
        self._produce = produce
        self.speed = speed
        self.queue_len = int(queue_len)
        self.prefetch = int(prefetch)
        self.late_tolerance_s = float(late_tolerance_s)
        self.slide = bool(slide)
        self._t0: float | None = None
        self._queues = [deque() for _ in self.cameras]
        self._dropped = [0] * len(self.cameras)
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._ended = False
        self._error: BaseException | None = None
        self._emitted = 0
        self._late = 0
        self._t_first: float | None = None
        self._t_last: float | None = None
        self._threads: list[threading.Thread] = []
        self._started = False
        self._open_views = 0
        self.skipped = 0  # counted by producers that skip ahead (sim)
        self._closers: list = []
        self._sink = None

    def connect(self, sink) -> bool:
        """Hand emitted frames to ``sink`` instead of the per-camera queues; returns whether it did.

        sink : ``sink.put_frames(pairs)`` with ``pairs`` a list of ``(j, Frame)`` (j = camera of this feed),
        called in the pacer's thread once per frame set; ``sink.feed_ended(error)`` once when the feed ends
        (``error``: None, or the exception the producer raised). Only for a paced feed (``speed`` not None:
        the sink must never block) that has not started; else False (read the views instead)."""
        with self._cond:
            if self._started or self.speed is None or self._sink is not None:
                return False
            self._sink = sink
            return True

    # -- lifetime ---------------------------------------------------------------------------------
    def start(self) -> None:
        with self._cond:
            if self._started:
                return
            self._started = True
        items: Callable[[], Iterator[FeedItem]] = self._produce
        if self.prefetch:
            ahead: queue.Queue = queue.Queue(maxsize=self.prefetch)
            t = threading.Thread(target=self._run_prefetch, args=(ahead,), name=f"{self.name} producer", daemon=True)
            self._threads.append(t)
            items = lambda: self._drain(ahead)  # noqa: E731
        t = threading.Thread(target=self._run, args=(items,), name=f"{self.name} pacer", daemon=True)
        self._threads.append(t)
        for t in self._threads:
            t.start()

    def close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=5.0)
        while self._closers:
            self._closers.pop()()

    def closing(self) -> bool:
        """Whether :meth:`close` was called: a producer stops at once."""
        return self._stop.is_set()

    def wait_closing(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` seconds or until :meth:`close` is called; returns whether it was."""
        return self._stop.wait(timeout_s)

    def add_closer(self, fn: Callable[[], None]) -> None:
        """Call ``fn`` when the feed closes (after its threads have stopped), e.g. to end a child process."""
        self._closers.append(fn)

    def _attach(self) -> None:
        with self._cond:
            self._open_views += 1

    def _detach(self) -> None:
        with self._cond:
            self._open_views -= 1
            last = self._open_views <= 0
        if last:
            self.close()

    # -- producer side ----------------------------------------------------------------------------
    def _run_prefetch(self, ahead: queue.Queue) -> None:
        try:
            for item in self._produce():
                while not self._stop.is_set():
                    try:
                        ahead.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if self._stop.is_set():
                    return
        except BaseException as exc:  # handed to the readers as a SourceError
            ahead.put((_END, exc))
            return
        ahead.put((_END, None))

    def _drain(self, ahead: queue.Queue) -> Iterator[FeedItem]:
        while not self._stop.is_set():
            try:
                item = ahead.get(timeout=0.1)
            except queue.Empty:
                continue
            if isinstance(item, tuple) and item and item[0] is _END:
                if item[1] is not None:
                    raise item[1]
                return
            yield item

    @property
    def origin_s(self) -> float | None:
        """Host monotonic time of schedule time 0 (``t_sched_s = 0``), None before the first emission."""
        return self._t0

    def schedule_now(self) -> float | None:
        """Where the schedule is now (seconds of ``t_sched_s``), or None before the first emission."""
        t0 = self._t0
        return None if t0 is None or self.speed is None else (time.monotonic() - t0) * self.speed

    def _run(self, items: Callable[[], Iterator[FeedItem]]) -> None:
        try:
            for item in items():
                if self._stop.is_set():
                    break
                if self.speed is not None:
                    now = time.monotonic()
                    if self._t0 is None:
                        self._t0 = now - item.t_sched_s / self.speed
                    due = self._t0 + item.t_sched_s / self.speed
                    if due > now:
                        if self._stop.wait(due - now):
                            break
                    elif now - due > self.late_tolerance_s and self._emitted:
                        self._late += 1
                        if self.slide:
                            self._t0 = now - item.t_sched_s / self.speed  # the schedule restarts here
                self._emit(item)
        except BaseException as exc:  # noqa: BLE001 - reported to the readers, never lost
            with self._cond:
                self._error = exc
        with self._cond:
            self._ended = True
            self._cond.notify_all()
        if self._sink is not None:
            self._sink.feed_ended(self._error)

    def _emit(self, item: FeedItem) -> None:
        t_host = time.monotonic()
        if self._sink is not None:
            pairs = [(j, Frame(self.cameras[j], int(item.frame_ids[j]), item.t_device_s[j], t_host, image))
                     for j, image in enumerate(item.images) if image is not None]
            with self._cond:
                self._emitted += 1
                self._t_first = t_host if self._t_first is None else self._t_first
                self._t_last = t_host
            self._sink.put_frames(pairs)
            return
        with self._cond:
            for j, image in enumerate(item.images):
                if image is None:
                    continue
                q = self._queues[j]
                if len(q) >= self.queue_len:
                    if self.speed is None:
                        while len(q) >= self.queue_len and not self._stop.is_set():
                            self._cond.wait(0.1)
                        if self._stop.is_set():
                            return
                    else:
                        q.popleft()
                        self._dropped[j] += 1
                q.append(Frame(self.cameras[j], int(item.frame_ids[j]), item.t_device_s[j], t_host, image))
            self._emitted += 1
            self._t_first = t_host if self._t_first is None else self._t_first
            self._t_last = t_host
            self._cond.notify_all()

    # -- reader side ------------------------------------------------------------------------------
    def read(self, j: int, timeout_s: float) -> Frame | None:
        deadline = time.monotonic() + max(0.0, float(timeout_s))
        with self._cond:
            q = self._queues[j]
            while not q:
                if self._ended:
                    if self._error is not None:
                        err = self._error
                        raise SourceError(f"{self.name}: camera {self.names[j]}: "
                                          f"{type(err).__name__}: {err}") from err
                    return None
                left = deadline - time.monotonic()
                if left <= 0 or self._stop.is_set():
                    return None
                self._cond.wait(left)
            frame = q.popleft()
            self._cond.notify_all()
            return frame

    def exhausted(self, j: int) -> bool:
        with self._cond:
            return self._ended and self._error is None and not self._queues[j]

    def stats(self) -> FeedStats:
        with self._cond:
            span = (self._t_last - self._t_first) if self._t_first is not None else 0.0
            rate = (self._emitted - 1) / span if span > 0 else 0.0
            return FeedStats(self._emitted, self._late, tuple(self._dropped), rate, self.skipped)

    def views(self) -> list["FeedCamera"]:
        return [FeedCamera(self, j) for j in range(len(self.cameras))]


class FeedCamera:
    """The :class:`~harness.live.frames.FrameSource` of one camera of a :class:`PacedFeed`.

    ``start`` starts the shared feed (once); the feed stops when every view is closed.
    """

    def __init__(self, feed: PacedFeed, j: int):
        self.feed = feed
        self._j = j
        self.camera = feed.cameras[j]
        self.name = f"{feed.name}:{feed.names[j]}"
        self.feed_index = j  # this camera's place in the feed's cameras (``j`` of :meth:`PacedFeed.connect`)
        self._closed = False
        feed._attach()

    def start(self) -> None:
        self.feed.start()

    def stats(self):
        """The shared feed's :class:`FeedStats` (late / skipped frame sets, drops, achieved rate)."""
        return self.feed.stats()

    def read(self, timeout_s: float) -> Frame | None:
        return self.feed.read(self._j, timeout_s)

    @property
    def exhausted(self) -> bool:
        return self.feed.exhausted(self._j)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.feed._detach()
