"""The lab truth stream: simulation truth (the robot's TRUE joints, free balls) on the host clock, over ZeroMQ.

A simulated camera that renders a lab driven by other processes (the simulated WAM behind its bridge, a
ball simulation) needs what the lab really looks like at the instant it exposes. The processes that own
the truth publish it here; the ``sim`` camera source subscribes, picks its exposure instants on the
host clock, waits (a bounded time) for the truth at that instant, renders, and stamps the frame with the
exposure time -- arriving later, as a camera with hardware timestamps does (docs/live.md, "Lab truth").

Message (one ZeroMQ frame, msgpack map; version :data:`VERSION`; every field required):

``{"v": 1, "t_ns": int, "q": [n floats], "balls": [[x, y, z], ...], "seq": int}``

* ``t_ns`` : host ``CLOCK_MONOTONIC`` (``time.monotonic_ns()``) at which the sample is true -- the
  publisher maps its own clock onto the host's (the simulated bridge knows its true offset);
* ``q`` : the n TRUE joint angles of the arm (1 <= n <= :data:`MAX_JOINTS`; the WAM's 7), rad, URDF order (never
  what the encoders report); a subscriber keeps only samples of its arm's joint count;
* ``balls`` : free balls (not carried by the robot) in the lab world frame, metres, possibly empty;
* ``seq`` : the publisher's running count; ``t_ns`` strictly increases with it.

Publishers: ``rt2 robot serve --sim --truth-stream ADDR`` (every control tick of the simulated WAM, no
balls), or any process with :class:`TruthPublisher`. Subscribers: :class:`TruthSubscriber` (a background
thread keeps the last samples; :meth:`TruthSubscriber.at` interpolates them at a host time, waiting a
bounded time for a sample at or after it) and the scene provider
:class:`harness.experiments.accuracy.truth_scene.LabTruthScene` (``rt2 track
--source sim --truth-stream ADDR --scene accuracy|accuracy-clean|accuracy-harsh|play``).

    pub = TruthPublisher("tcp://127.0.0.1:*")                  # pub.address: the bound endpoint
    pub.publish(time.monotonic_ns(), q_true, balls=[[x, y, z]])
    with TruthSubscriber(pub.address) as sub:
        sample = sub.at(time.monotonic_ns(), wait_s=0.5)       # TruthSample(t_ns, q (n,), balls (m, 3))
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import msgpack
import numpy as np

from robot_models.limits import MAX_JOINTS

__all__ = ["MAX_JOINTS", "VERSION", "TruthError", "TruthPublisher", "TruthSample", "TruthSubscriber",
           "decode_truth", "encode_truth"]

VERSION = 1
MAX_BALLS = 64
_FIELDS = {"v", "t_ns", "q", "balls", "seq"}


class TruthError(ValueError):
    """A malformed truth message, or a truth stream that is silent or behind (the message says which address)."""


def encode_truth(t_ns: int, q, balls=(), seq: int = 0) -> bytes:
    """One truth message. t_ns : host CLOCK_MONOTONIC ns; q : (n,) true joints, rad; balls : (m, 3) world, m."""
    q = np.asarray(q, float).reshape(-1)
    b = np.asarray(balls, float).reshape(-1, 3) if len(balls) else np.zeros((0, 3))
    if not 1 <= q.size <= MAX_JOINTS or not np.isfinite(q).all() or not np.isfinite(b).all() or len(b) > MAX_BALLS:
        raise TruthError(f"truth sample: q must be 1..{MAX_JOINTS} finite angles and balls at most {MAX_BALLS} finite "
                         f"[x, y, z], got q {q.tolist()}, {len(b)} ball(s)")
    return msgpack.packb({"v": VERSION, "t_ns": int(t_ns), "q": q.tolist(), "balls": b.tolist(), "seq": int(seq)},
                         use_bin_type=True)


@dataclass(frozen=True)
class TruthSample:
    """t_ns : host CLOCK_MONOTONIC ns; q : (n,) true joints, rad; balls : (m, 3) free balls, world, m; seq : count."""

    t_ns: int
    q: np.ndarray
    balls: np.ndarray
    seq: int = 0


def decode_truth(frame: bytes) -> TruthSample:
    """Validate one message (module docstring); raises :class:`TruthError` quoting what was wrong."""
    try:
        msg = msgpack.unpackb(frame, raw=False, strict_map_key=True, max_array_len=4096)
    except Exception as exc:  # noqa: BLE001 - any unpacking failure is a malformed message
        raise TruthError(f"truth message is not msgpack: {exc}") from None
    if not isinstance(msg, dict) or set(msg) != _FIELDS:
        got = sorted(msg) if isinstance(msg, dict) else type(msg).__name__
        raise TruthError(f"truth message must have exactly the fields {sorted(_FIELDS)}, got {got}")
    if msg["v"] != VERSION:
        raise TruthError(f"truth message version {msg['v']!r} is not supported (this rt2 reads version {VERSION})")
    for name in ("t_ns", "seq"):
        if isinstance(msg[name], bool) or not isinstance(msg[name], int):
            raise TruthError(f"truth message field {name!r} must be an integer, got {msg[name]!r}")
    try:
        q = np.array(msg["q"], dtype=float)
        balls = np.array(msg["balls"], dtype=float).reshape(-1, 3) if len(msg["balls"]) else np.zeros((0, 3))
    except (TypeError, ValueError):
        raise TruthError(f"truth message: q must be a list of numbers and balls a list of [x, y, z], got q={msg['q']!r}, "
                         f"balls={msg['balls']!r}") from None
    if (q.ndim != 1 or not 1 <= q.size <= MAX_JOINTS or not np.isfinite(q).all() or not np.isfinite(balls).all()
            or len(balls) > MAX_BALLS):
        raise TruthError(f"truth message: q must be 1..{MAX_JOINTS} finite angles and balls at most {MAX_BALLS} finite "
                         f"[x, y, z], got q={msg['q']!r}, {len(balls)} ball(s)")
    return TruthSample(int(msg["t_ns"]), q, balls, int(msg["seq"]))


class TruthPublisher:
    """PUB socket bound at ``address`` (``tcp://HOST:PORT``, port ``*`` = a free one; :attr:`address` is the
    bound endpoint). :meth:`publish` never blocks (a slow subscriber loses samples, counted by its ``seq``)."""

    def __init__(self, address: str, *, context=None):
        import zmq

        if not isinstance(address, str) or not address.startswith(("tcp://", "ipc://", "inproc://")):
            raise TruthError(f"truth stream address must be a ZeroMQ endpoint like tcp://127.0.0.1:7652, got {address!r}")
        self._sock = (context or zmq.Context.instance()).socket(zmq.PUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.SNDHWM, 10000)
        try:
            self._sock.bind(address)
        except zmq.ZMQError as exc:
            self._sock.close(linger=0)
            raise TruthError(f"cannot bind the lab truth stream at {address}: {exc}") from None
        self.address = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self.seq = 0
        self._noblock = zmq.NOBLOCK
        self._again = zmq.Again

    def publish(self, t_ns: int, q, balls=()) -> None:
        """One sample: t_ns host CLOCK_MONOTONIC ns (strictly increasing), q (n,) true joints, balls (m, 3) world."""
        self.seq += 1
        try:
            self._sock.send(encode_truth(t_ns, q, balls, self.seq), self._noblock)
        except self._again:
            pass

    def close(self) -> None:
        self._sock.close(linger=0)

    def __enter__(self) -> "TruthPublisher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class TruthSubscriber:
    """SUB to a truth stream at ``address``; a background thread keeps the last ``capacity`` samples (default
    65536: 131 s at 500 Hz, so a camera rendering far behind real time still finds its truth; 4 MB).

    :meth:`at` gives the truth at a host time (joints interpolated linearly between the samples around it,
    balls from the nearest sample), waiting up to ``wait_s`` for a sample at or after that time.
    ``n_joints``: the arm's joint count (the WAM's 7 by default); a sample of another count is malformed
    (``last_error`` names both). ``received``, ``malformed`` and ``lost`` (``seq`` jumps) count what came.
    """

    def __init__(self, address: str, *, n_joints: int = 7, capacity: int = 1 << 16, context=None):
        import zmq

        if not isinstance(address, str) or not address.startswith(("tcp://", "ipc://", "inproc://")):
            raise TruthError(f"--truth-stream must be a ZeroMQ endpoint like tcp://127.0.0.1:7652, got {address!r}")
        if isinstance(n_joints, bool) or not isinstance(n_joints, int) or not 1 <= n_joints <= MAX_JOINTS:
            raise TruthError(f"n_joints must be an integer in 1..{MAX_JOINTS}, got {n_joints!r}")
        self.address = address
        self.n_joints = n_joints
        self._sock = (context or zmq.Context.instance()).socket(zmq.SUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.RCVHWM, 100000)
        self._sock.setsockopt(zmq.SUBSCRIBE, b"")
        self._sock.connect(address)
        self._cap = int(capacity)
        self._t = np.zeros(2 * self._cap, np.int64)  # appended in order; halved when full (amortised, no per-sample allocation)
        self._q = np.zeros((2 * self._cap, n_joints))
        self._balls: list = [None] * (2 * self._cap)
        self._n = 0
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self.received = self.malformed = self.lost = 0
        self._last_seq: int | None = None
        self.last_error: str | None = None
        self._thread = threading.Thread(target=self._run, name="lab truth subscriber", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import zmq

        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        while not self._stop.is_set():
            if not poller.poll(100):
                continue
            while True:
                try:
                    frame = self._sock.recv(zmq.NOBLOCK)
                except zmq.Again:
                    break
                except zmq.ZMQError:
                    return
                try:
                    s = decode_truth(frame)
                    if s.q.size != self.n_joints:
                        raise TruthError(f"truth sample with {s.q.size} joints; this subscriber's arm has {self.n_joints}")
                except TruthError as exc:
                    self.malformed += 1
                    self.last_error = str(exc)
                    continue
                self._add(s)

    def _add(self, s: TruthSample) -> None:
        with self._cond:
            if self._n and s.t_ns <= self._t[self._n - 1]:  # out of order or a restarted publisher's stale sample
                self.malformed += 1
                self.last_error = f"truth sample at {s.t_ns} ns is not after the previous one"
                return
            if self._last_seq is not None and s.seq > self._last_seq + 1:
                self.lost += s.seq - self._last_seq - 1
            self._last_seq = s.seq
            if self._n == len(self._t):
                keep = self._cap
                self._t[:keep] = self._t[self._n - keep:self._n]
                self._q[:keep] = self._q[self._n - keep:self._n]
                self._balls[:keep] = self._balls[self._n - keep:self._n]
                self._n = keep
            self._t[self._n], self._q[self._n], self._balls[self._n] = s.t_ns, s.q, s.balls
            self._n += 1
            self.received += 1
            self._cond.notify_all()

    @property
    def latest_t_ns(self) -> int | None:
        with self._cond:
            return int(self._t[self._n - 1]) if self._n else None

    def wait_first(self, timeout_s: float) -> None:
        """Block until a first sample has come; :class:`TruthError` naming the address after ``timeout_s``."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._n > 0, timeout=float(timeout_s)):
                raise TruthError(f"the lab truth stream at {self.address} sent nothing in {timeout_s:g} s (is the "
                                 "simulated robot serving it: rt2 robot serve --sim --truth-stream ADDR?)"
                                 + (f"; last malformed message: {self.last_error}" if self.last_error else ""))

    def at(self, t_ns: int, *, wait_s: float = 0.5) -> TruthSample:
        """The truth at host time ``t_ns`` (see the class docstring). Raises :class:`TruthError` when no sample
        at or after ``t_ns`` arrives within ``wait_s``, or when ``t_ns`` is older than the samples kept."""
        t_ns = int(t_ns)
        with self._cond:
            if not self._cond.wait_for(lambda: self._n > 0 and self._t[self._n - 1] >= t_ns, timeout=float(wait_s)):
                if not self._n:
                    raise TruthError(f"the lab truth stream at {self.address} sent nothing in {wait_s:g} s")
                behind = (t_ns - int(self._t[self._n - 1])) / 1e6
                raise TruthError(f"the lab truth stream at {self.address} is {behind:.1f} ms behind the requested "
                                 f"instant after waiting {wait_s:g} s (publisher stopped or too slow?)")
            t = self._t[:self._n]
            j = int(np.searchsorted(t, t_ns, side="left"))
            if j == 0 and t[0] > t_ns:
                raise TruthError(f"the lab truth stream at {self.address}: host time {t_ns} ns is before the oldest "
                                 f"sample kept ({int(t[0])} ns)")
            if t[j] == t_ns:
                return TruthSample(t_ns, self._q[j].copy(), self._balls[j], j)
            a = (t_ns - t[j - 1]) / (t[j] - t[j - 1])
            q = (1.0 - a) * self._q[j - 1] + a * self._q[j]
            balls = self._balls[j] if a >= 0.5 else self._balls[j - 1]
            return TruthSample(t_ns, q, balls, j)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sock.close(linger=0)

    def __enter__(self) -> "TruthSubscriber":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
