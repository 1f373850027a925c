"""Frame-set assembly: per-camera frames that arrive at different times, some late, some lost, become
one :class:`~harness.live.frames.AssembledFrameSet` per trigger, without ever blocking the tracker.

Threads: one reader per source (``source.read(timeout)`` into a bounded per-camera queue; full =
drop the oldest, counted per camera) and one assembler (groups frames, emits sets into a bounded
output queue; full = drop the oldest set, counted). ``get(timeout_s)`` only waits for that output,
and is woken only when a set is there (or the assembly ends), never by the readers' frames.

Cameras that are the views of one paced software feed (``sim``, ``replay`` and ``video`` in real time:
:class:`~harness.live.sources._feed.PacedFeed`) have no reader threads: the feed hands each frame set
to the assembler in the thread that stamped it (:meth:`~harness.live.sources._feed.PacedFeed.connect`),
where it is placed and, when complete, emitted at once. Between a frame's arrival stamp and the
tracker's queue there is then no thread hand-over (four reader wake-ups and the assembler's, each
waiting for the interpreter lock and a core, were the tail of the ``assembly`` stage on a busy machine);
the assembler thread only times out sets with a missing camera.

Matching (``AssemblyOptions.match``):

* ``"frame_id"``: frames with the same frame id form a set (hardware-triggered cameras count
  triggers alike);
* ``"time"``: a frame joins the open set whose reference time (its first frame's capture time) is
  within half a period of its own capture time, else it opens a new set.

A set is emitted when every camera has a frame in it, or when each missing camera is known not to
deliver one: it has moved past the set (sent a later frame: the frame was lost), ended, failed, or
stalled (the other cameras are ``stall_s`` ahead of its last frame); at the latest ``max_wait_s``
after the set's first frame arrived. A missing camera's image is None and the set carries a note
saying why. A frame that arrives after its set was emitted is late: counted and discarded.

Capture time ``FrameSet.t_s``: the median over the cameras in the set of each frame's capture-time
estimate on the host's monotonic clock: ``t_device_s + offset`` where the camera gives device stamps
and its clock offset is estimated (:mod:`.sources.clock`; the offset includes the smallest transfer
latency), else the arrival stamp ``t_host_s``. With ``clock="device"`` the device stamps are taken
as they are (the cameras share one clock: PTP-synchronised cameras, or a recording stamped on one
machine), falling back to the arrival stamp for frames without one. Sets are emitted in capture order,
and ``t_s`` increases strictly: an estimate at or before the previous set's (arrival jitter) is moved
just after it and counted (``clamped_times``).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from harness.live.frames import AssembledFrameSet, Frame, SourceError
from harness.live.sources._feed import PacedFeed
from harness.live.sources.clock import ClockOffset, ClockOffsetEstimator
from tracker import FrameSet

__all__ = ["AssemblyOptions", "AssemblyStats", "CLOCKS", "ClockOffset", "FrameSetAssembler", "MATCH_MODES"]

MATCH_MODES = ("frame_id", "time")
CLOCKS = ("host", "device")


@dataclass(frozen=True)
class AssemblyOptions:
    """How frames are grouped.

    rate_hz : the cameras' frame rate (period = 1 / rate_hz)
    match : ``"frame_id"`` or ``"time"`` (see the module docstring)
    max_wait_s : longest wait for a missing camera after a set's first frame arrived; None = two periods
        (one period plus the scheduling jitter of Python threads on a loaded machine)
    stall_s : a camera is not waited for once the others are this far ahead of its last frame (in
        frame ids x period, or capture time); None = ten periods
    queue_len : frames buffered per camera
    output_len : the backlog bound: assembled sets waiting for ``get`` at most. When a new set finds it
        full, the oldest waiting set is skipped and counted (``dropped_framesets``): the newest frame set
        wins, and a consumer that falls behind gets a set at most ``output_len`` sets behind the newest
        rather than every set late (a robot gains nothing from a stale position, loses little with one
        frame set fewer). ``rt2 track --max-backlog`` sets it (default 1, chosen with ``rt2 bench live``)
    read_timeout_s : how long a reader thread blocks in ``source.read`` before checking for close
    clock_window : frames per camera in the clock-offset window
    clock : capture times on the ``"host"`` clock (device stamps mapped by each camera's estimated
        offset) or the ``"device"`` clock as stamped (cameras that share one clock)
    lossless : False (live) = full queues drop their oldest; True (a recording replayed as fast as
        possible) = full queues make the readers and the assembler wait instead, a camera that leads
        the others is held back, and a set waits for every camera until it moves past it or ends (no
        ``max_wait_s``, no stall): nothing is dropped, the consumer sets the pace. Never for live
        cameras: a slow consumer would stall them.
    """

    rate_hz: float = 200.0
    match: str = "frame_id"
    max_wait_s: float | None = None
    stall_s: float | None = None
    queue_len: int = 8
    output_len: int = 4
    read_timeout_s: float = 0.05
    clock_window: int = 400
    lossless: bool = False
    clock: str = "host"

    def __post_init__(self):
        if not (isinstance(self.rate_hz, (int, float)) and math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"AssemblyOptions.rate_hz must be > 0, got {self.rate_hz!r}")
        if self.match not in MATCH_MODES:
            raise ValueError(f"AssemblyOptions.match must be one of {MATCH_MODES}, got {self.match!r}")
        if self.clock not in CLOCKS:
            raise ValueError(f"AssemblyOptions.clock must be one of {CLOCKS}, got {self.clock!r}")
        for name in ("max_wait_s", "stall_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ValueError(f"AssemblyOptions.{name} must be None or > 0 s, got {v!r}")
        if self.queue_len < 1 or self.output_len < 1 or self.clock_window < 2 or not self.read_timeout_s > 0:
            raise ValueError(f"AssemblyOptions: queue_len, output_len >= 1, clock_window >= 2, read_timeout_s > 0; got "
                             f"{self.queue_len!r}, {self.output_len!r}, {self.clock_window!r}, {self.read_timeout_s!r}")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def wait_s(self) -> float:
        return self.max_wait_s if self.max_wait_s is not None else 2.0 * self.period_s

    @property
    def stall_after_s(self) -> float:
        return self.stall_s if self.stall_s is not None else 10.0 * self.period_s


@dataclass(frozen=True)
class AssemblyStats:
    """Counters since start; per-camera tuples are in source (rig) order.

    framesets : sets assembled; complete / incomplete : of which every camera / not every camera had a frame
    delivered : sets handed out by ``get``; dropped_framesets : sets skipped because the backlog was full
        (the consumer was slower than the cameras; a newer set took the place of the oldest waiting one)
    waiting : sets assembled and waiting for ``get`` now; backlog : the bound on ``waiting`` (``output_len``).
        ``framesets == delivered + dropped_framesets + waiting`` at every moment
    frames : frames received; late : frames that arrived after their set had been emitted (discarded)
    dropped : frames dropped from a full per-camera queue (the assembler fell behind)
    missing : sets emitted without this camera's frame
    ended : the source is exhausted or failed; errors : the failure message, or None
    clock_offsets : :class:`~harness.live.sources.clock.ClockOffset` per camera, None without device stamps
    clamped_times : sets whose capture-time estimate came out at or before the previous set's (arrival
        jitter without device stamps) and was moved just after it, so ``t_s`` always increases
    sources : per camera, the source's own counters (its ``stats()`` where it has one, else None): sim,
        replay and video report their shared feed's :class:`~harness.live.sources._feed.FeedStats`
        (late and skipped frame sets: the renderer could not keep up), pylon its grab errors
    """

    framesets: int
    complete: int
    incomplete: int
    delivered: int
    dropped_framesets: int
    frames: tuple
    late: tuple
    dropped: tuple
    missing: tuple
    ended: tuple
    errors: tuple
    clock_offsets: tuple
    sources: tuple = ()
    clamped_times: int = 0
    waiting: int = 0
    backlog: int = 0


@dataclass
class _Pending:
    order: float  # frame id, or reference capture time
    frames: list
    t_first_s: float  # host monotonic when its first frame was assembled
    t_capture: list = field(default_factory=list)


class FrameSetAssembler:
    """Assemble frame sets from ``sources`` (one :class:`~harness.live.frames.FrameSource` per rig camera,
    in rig order). Use as a context manager, or ``start()`` / ``close()``.

    ``get(timeout_s)`` returns the next :class:`AssembledFrameSet`, or None on a timeout or when
    every source has ended and everything was delivered (then ``finished`` is True).
    """

    def __init__(self, sources, options: AssemblyOptions = AssemblyOptions()):
        self.sources = list(sources)
        if not self.sources:
            raise ValueError("FrameSetAssembler needs at least one source, got none")
        if not isinstance(options, AssemblyOptions):
            raise ValueError(f"options must be an AssemblyOptions, got {type(options).__name__}")
        self.options = options
        n = len(self.sources)
        self._n = n
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)  # the assembler thread and the readers
        self._out = threading.Condition(self._lock)  # get(): a set is ready or the assembly ended
        self._stop = threading.Event()
        self._inputs = [deque() for _ in range(n)]
        self._output: deque = deque()
        self._pending: list[_Pending] = []
        self._clocks = [ClockOffsetEstimator(options.clock_window) for _ in range(n)]
        self._has_device = [False] * n
        self._last_order = [-math.inf] * n  # last frame id / capture time assembled per camera
        self._first_order = math.inf  # order of the first frame of all
        self._emitted_order = -math.inf
        self._set_number = 0
        self._ended = [False] * n
        self._errors: list[str | None] = [None] * n
        self._frames = [0] * n
        self._late = [0] * n
        self._dropped = [0] * n
        self._missing = [0] * n
        self._framesets = self._complete = self._delivered = self._dropped_sets = 0
        self._last_t_s, self._clamped = -math.inf, 0
        self._threads: list[threading.Thread] = []
        self._started = False
        self._t_start = 0.0
        self.pushed_by_feed = [False] * n  # camera i's frames come straight from its feed's pacer (no reader)

    # -- lifetime ---------------------------------------------------------------------------------
    def start(self) -> "FrameSetAssembler":
        if self._started:
            return self
        self._started = True
        self._t_start = time.monotonic()
        self._connect_feeds()
        for i, src in enumerate(self.sources):
            try:
                src.start()
            except SourceError as exc:
                self._fail(i, str(exc))
                continue
            if self.pushed_by_feed[i]:
                continue
            t = threading.Thread(target=self._read_loop, args=(i, src), name=f"read {src.name}", daemon=True)
            self._threads.append(t)
        self._threads.append(threading.Thread(target=self._assemble_loop, name="assembler", daemon=True))
        for t in self._threads:
            t.start()
        return self

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            self._cond.notify_all()
            self._out.notify_all()
        for t in self._threads:
            t.join(timeout=2.0 + self.options.read_timeout_s)
        for src in self.sources:
            try:
                src.close()
            except Exception:  # noqa: BLE001 - closing must reach every source
                pass

    def __enter__(self) -> "FrameSetAssembler":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- readers ----------------------------------------------------------------------------------
    def _fail(self, i: int, message: str) -> None:
        with self._lock:
            self._ended[i] = True
            self._errors[i] = message
            self._cond.notify_all()
            self._out.notify_all()

    # -- feeds that push their frame sets -------------------------------------------------------------
    def _connect_feeds(self) -> None:
        """Connect every paced feed whose cameras are all among the sources (live only: a lossless
        assembly paces its readers) so that it pushes its frame sets (the module docstring)."""
        if self.options.lossless:
            return
        groups: dict[int, tuple] = {}
        for i, src in enumerate(self.sources):
            feed = getattr(src, "feed", None)
            if isinstance(feed, PacedFeed) and isinstance(getattr(src, "feed_index", None), int):
                groups.setdefault(id(feed), (feed, {}))[1][src.feed_index] = i
        for feed, mapping in groups.values():
            if sorted(mapping) == list(range(len(feed.cameras))) and feed.connect(_FeedSink(self, feed, mapping)):
                for i in mapping.values():
                    self.pushed_by_feed[i] = True

    def _put_frames(self, frames) -> None:
        """Frames ``[(i, Frame), ...]`` of one frame set, in the feed's thread: placed, and the set emitted
        when complete (the assembler thread is woken only when a set is left waiting for a camera)."""
        now = time.monotonic()
        with self._lock:
            if self._stop.is_set():
                return
            for i, frame in frames:
                self._place(i, frame, now)
            self._emit_ready(now)
            if self._pending:  # a camera is missing: the assembler thread times the set out
                self._cond.notify_all()

    def _ended_pushed(self, cameras, message: str | None) -> None:
        with self._lock:
            for i in cameras:
                self._ended[i] = True
                if message is not None:
                    self._errors[i] = message
            self._cond.notify_all()
            self._out.notify_all()

    def _read_loop(self, i: int, src) -> None:
        q, qlen = self._inputs[i], self.options.queue_len
        while not self._stop.is_set():
            try:
                frame = src.read(self.options.read_timeout_s)
            except Exception as exc:  # noqa: BLE001 - a failed camera becomes None frames with a note
                self._fail(i, f"{type(exc).__name__}: {exc}" if not isinstance(exc, SourceError) else str(exc))
                return
            if frame is None:
                if src.exhausted:
                    with self._lock:
                        self._ended[i] = True
                        self._cond.notify_all()
                        self._out.notify_all()
                    return
                continue
            with self._cond:
                while self.options.lossless and len(q) >= qlen and not self._stop.is_set():
                    self._cond.wait(0.1)
                if len(q) >= qlen:
                    q.popleft()
                    self._dropped[i] += 1
                q.append(frame)
                self._cond.notify_all()

    # -- assembly ---------------------------------------------------------------------------------
    def _capture_time(self, i: int, frame: Frame) -> float:
        if frame.t_device_s is None:
            return frame.t_host_s
        clock = self._clocks[i]
        clock.add(frame.t_host_s, frame.t_device_s)
        self._has_device[i] = True
        if self.options.clock == "device":
            return frame.t_device_s
        mapped = clock.to_host(frame.t_device_s)
        return frame.t_host_s if mapped is None else mapped

    def _place(self, i: int, frame: Frame, now: float) -> None:
        self._frames[i] += 1
        t_cap = self._capture_time(i, frame)
        half = 0.5 * self.options.period_s
        if self.options.match == "frame_id":
            order = float(frame.frame_id)
            self._first_order = min(self._first_order, order)
            self._last_order[i] = max(self._last_order[i], order)
            if order <= self._emitted_order:
                self._late[i] += 1
                return
            target = next((p for p in self._pending if p.order == order), None)
            if target is not None and target.frames[i] is not None:
                self._late[i] += 1  # a second frame with the same id: keep the first
                return
        else:
            order = t_cap
            self._first_order = min(self._first_order, order)
            self._last_order[i] = max(self._last_order[i], order)
            if order <= self._emitted_order + half:
                self._late[i] += 1
                return
            near = [p for p in self._pending if p.frames[i] is None and abs(p.order - order) <= half]
            target = min(near, key=lambda p: abs(p.order - order)) if near else None
        if target is None:
            target = _Pending(order, [None] * self._n, now, [math.nan] * self._n)
            self._pending.append(target)
            self._pending.sort(key=lambda p: p.order)
        target.frames[i] = frame
        target.t_capture[i] = t_cap

    def _why_missing(self, i: int, p: _Pending, now: float) -> str | None:
        """Why camera i will not fill set p (a note), or None while it still may."""
        time_mode = self.options.match == "time"
        half = 0.5 * self.options.period_s if time_mode else 0.0
        if self._ended[i] and not self._inputs[i]:  # its last frames may still wait in its queue
            return f"failed: {self._errors[i]}" if self._errors[i] else "ended"
        if self._last_order[i] > p.order + half:
            return "frame lost (a later frame arrived)"
        # Stalled: the other cameras have moved on by stall_s while this one sent nothing (measured in
        # frame ids or capture time, not wall time, so a pause of every camera is no stall).
        base = self._last_order[i] if self._last_order[i] > -math.inf else self._first_order
        ahead = max(self._last_order) - base
        limit = self.options.stall_after_s * (1.0 if time_mode else self.options.rate_hz)
        if ahead > limit and not self.options.lossless:
            return (f"stalled (the others are {ahead * 1e3:.0f} ms ahead)" if time_mode
                    else f"stalled (the others are {ahead:.0f} frames ahead)")
        if now - p.t_first_s > self.options.wait_s and not self.options.lossless:
            return f"no frame in time (waited {self.options.wait_s * 1e3:.1f} ms)"
        return None

    def _emit_ready(self, now: float) -> None:
        while self._pending:
            p = self._pending[0]
            notes = []
            for i in range(self._n):
                if p.frames[i] is None:
                    why = self._why_missing(i, p, now)
                    if why is None:
                        return  # the oldest set still waits; later sets wait behind it (capture order)
                    notes.append(f"camera {i} ({self.sources[i].name}): {why}")
            self._pending.pop(0)
            self._emit(p, notes, now)

    def _emit(self, p: _Pending, notes: list, now: float) -> None:
        present = [f for f in p.frames if f is not None]
        t_s = float(np.median([t for t in p.t_capture if not math.isnan(t)]))
        if t_s <= self._last_t_s:  # arrival jitter would put this set before the previous one
            t_s = math.nextafter(self._last_t_s, math.inf)
            self._clamped += 1
        self._last_t_s = t_s
        frame_id = int(p.order) if self.options.match == "frame_id" else self._set_number
        images = tuple(None if f is None else f.image for f in p.frames)
        t_host = np.array([math.nan if f is None else f.t_host_s for f in p.frames])
        t_dev = np.array([math.nan if f is None or f.t_device_s is None else f.t_device_s for f in p.frames])
        out = AssembledFrameSet(FrameSet(t_s, images, self._set_number), frame_id, t_host, t_dev,
                                time.monotonic(), tuple(notes))
        self._emitted_order = max(self._emitted_order, p.order)
        self._set_number += 1
        while self.options.lossless and len(self._output) >= self.options.output_len and not self._stop.is_set():
            self._cond.wait(0.1)  # releases the lock: get() can take a set
        self._framesets += 1  # counted with the append, so framesets = delivered + skipped + waiting holds
        if len(present) == self._n:
            self._complete += 1
        for i, f in enumerate(p.frames):
            if f is None:
                self._missing[i] += 1
        if len(self._output) >= self.options.output_len:  # the newest wins: skip the oldest waiting set
            self._output.popleft()
            self._dropped_sets += 1
        self._output.append(out)
        self._out.notify_all()  # the consumer in get()

    def _next_deadline(self, now: float) -> float:
        """Seconds until the oldest pending set times out (stalls show with the next arrival)."""
        if not self._pending:
            return self.options.read_timeout_s
        return max(1e-4, self._pending[0].t_first_s + self.options.wait_s - now + 1e-4)

    def _throttled(self, i: int) -> bool:
        """Lossless only: hold back camera i's frames while it leads the others and enough sets wait
        for them (a camera that is behind always delivers: it fills or moves past the waiting sets)."""
        return (self.options.lossless and len(self._pending) >= 2 * self.options.queue_len
                and self._last_order[i] >= max(self._last_order))

    def _assemble_loop(self) -> None:
        with self._cond:
            while not self._stop.is_set():
                now = time.monotonic()
                for i, q in enumerate(self._inputs):
                    while q and not self._throttled(i):
                        self._place(i, q.popleft(), now)
                self._emit_ready(now)
                if self.options.lossless:
                    self._cond.notify_all()  # readers waiting for room in their queues
                if all(self._ended) and not self._pending and not any(self._inputs):
                    self._out.notify_all()
                    return
                self._cond.wait(self._next_deadline(now))

    # -- consumer side ----------------------------------------------------------------------------
    def get(self, timeout_s: float) -> AssembledFrameSet | None:
        """The next frame set, waiting at most ``timeout_s``; None on a timeout or when finished."""
        if not self._started:
            raise RuntimeError("FrameSetAssembler.get before start(): use it as a context manager or call start()")
        deadline = time.monotonic() + max(0.0, float(timeout_s))
        with self._lock:
            while not self._output:
                if self._finished_locked():
                    return None
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._out.wait(left)
            self._delivered += 1
            if self.options.lossless:
                self._cond.notify_all()  # the assembler may wait for room
            return self._output.popleft()

    def _finished_locked(self) -> bool:
        return all(self._ended) and not self._pending and not any(self._inputs) and not self._output

    @property
    def finished(self) -> bool:
        """Every source has ended and every frame set has been delivered."""
        with self._cond:
            return self._finished_locked()

    def clock_offsets(self) -> tuple:
        """Per camera :class:`ClockOffset` (device clock to host), None where no device stamps."""
        with self._cond:
            return tuple(c.estimate() if has else None for c, has in zip(self._clocks, self._has_device))

    def stats(self) -> AssemblyStats:
        own = tuple(_source_stats(s) for s in self.sources)
        with self._cond:
            return AssemblyStats(
                framesets=self._framesets, complete=self._complete, incomplete=self._framesets - self._complete,
                delivered=self._delivered, dropped_framesets=self._dropped_sets, frames=tuple(self._frames),
                late=tuple(self._late), dropped=tuple(self._dropped), missing=tuple(self._missing),
                ended=tuple(self._ended), errors=tuple(self._errors),
                clock_offsets=tuple(c.estimate() if has else None for c, has in zip(self._clocks, self._has_device)),
                sources=own, clamped_times=self._clamped, waiting=len(self._output), backlog=self.options.output_len)


class _FeedSink:
    """What :meth:`PacedFeed.connect` calls: a feed's frame sets into the assembler (feed camera j -> source i)."""

    def __init__(self, assembler: FrameSetAssembler, feed: PacedFeed, mapping: dict):
        self._assembler, self._feed, self._mapping = assembler, feed, dict(mapping)

    def put_frames(self, pairs) -> None:
        self._assembler._put_frames([(self._mapping[j], frame) for j, frame in pairs])

    def feed_ended(self, error) -> None:
        feed = self._feed
        for j, i in self._mapping.items():  # the message a reader gets from the feed's read()
            msg = None if error is None else f"{feed.name}: camera {feed.names[j]}: {type(error).__name__}: {error}"
            self._assembler._ended_pushed((i,), msg)


def _source_stats(source):
    """A source's own counters, or None (sources need not have any)."""
    stats = getattr(source, "stats", None)
    if not callable(stats):
        return None
    try:
        return stats()
    except Exception as exc:  # noqa: BLE001 - counters must never break the caller
        return {"error": f"{type(exc).__name__}: {exc}"}

