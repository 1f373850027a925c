"""``WamClient``: :class:`robot_models.robot_interface.WamInterface` over the robot link (docs/robot_link.md).

The client keeps a DEALER socket for requests (main thread) and, on a background thread, the SUB socket
of the state stream plus a second DEALER that sends a ``heartbeat`` every ``heartbeat_s``. States go into
a buffer that :meth:`WamClient.advance_to` hands out in order; :meth:`WamClient.read_state` gives the
latest. Link loss -- no state for ``timeout_s`` or no reply to a request in ``request_timeout_s`` -- ends
the client: every later call raises :class:`LinkLostError` naming the address and how long it was silent.

Commands are checked against the joint and velocity limits and the motion-safety rule (implied velocity,
acceleration and jerk, start at the arm, end at rest: ``robot_models.motion_limits.check_motion``) before
they leave the harness; the robot checks them again and answers ``error`` with a reason, raised here as
``ValueError``. Malformed stream messages, states older than the latest, and states no robot
can be in (angles beyond the joint limits by more than 0.1 rad, velocities beyond 3x the limits) are
dropped, logged and counted (``dropped``), never shown as a robot state.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections import deque

import numpy as np
import zmq

from harness.link import protocol
from harness.link.clock import ClockEstimate, RoundTripClock
from harness.link.protocol import ProtocolError
from robot_models.motion_limits import check_motion, state_at
from robot_models.robot_interface import JointSamples, JointState, check_joint_trajectory

__all__ = ["LinkLostError", "WamClient"]

log = logging.getLogger("rt2.robot.link.client")


#: a reported angle may pass a joint limit by a zero offset and a hard stop's give, not by more
STATE_MARGIN_RAD = 0.1
#: a reported velocity may overshoot the velocity limit (noise, a stop), not by this factor
STATE_QDOT_FACTOR = 3.0


class LinkLostError(ConnectionError):
    """The robot link stopped answering; the message names the address and the silence."""


def _state_address(command_address: str, state_endpoint: str) -> str:
    """The state endpoint as reachable from here: a wildcard host is replaced by the command address's host."""
    host = command_address.rpartition(":")[0]
    head, _, port = state_endpoint.rpartition(":")
    if head in ("tcp://0.0.0.0", "tcp://*", "tcp://[::]"):
        return f"{host}:{port}"
    return state_endpoint


class WamClient:
    """A WAM behind a bridge at ``address`` (``tcp://HOST:PORT``, the bridge's command endpoint).

    kinematics : :class:`robot_models.WamKinematics` whose limits are checked before sending (default: the
        lab's WAM); its joint names must be the robot's.
    timeout_s : no state for this long = link lost (default 0.25 s; the robot streams at 250-500 Hz)
    heartbeat_s : heartbeat period (the robot's watchdog holds after 0.3 s without one); None: a listener
        that never heartbeats, so it cannot keep a robot moving whose commanding client has died
    request_timeout_s : no reply to a request for this long = link lost
    connect_timeout_s : how long the first ``hello`` and the first state may take
    buffer_s : states kept for :meth:`advance_to` (older ones are dropped when nobody asks for them)

    The robot clock's offset from the harness clock (``time.monotonic_ns``) is estimated at connection
    (:meth:`sync_clock`, ``clock.estimate()``); call :meth:`sync_clock` again to refresh it.
    """

    def __init__(self, address: str, *, kinematics=None, timeout_s: float = 0.25, heartbeat_s: float = 0.1,
                 request_timeout_s: float = 0.4, connect_timeout_s: float = 5.0, client_name: str = "rt2",
                 buffer_s: float = 120.0, context=None):
        if not isinstance(address, str) or not address.startswith(("tcp://", "ipc://", "inproc://")):
            raise ValueError(f"robot address must be a ZeroMQ endpoint like tcp://127.0.0.1:7650, got {address!r}")
        for name, v in (("timeout_s", timeout_s), ("heartbeat_s", 1.0 if heartbeat_s is None else heartbeat_s),
                        ("request_timeout_s", request_timeout_s), ("connect_timeout_s", connect_timeout_s)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < float(v) <= 60:
                raise ValueError(f"{name} must be in (0, 60] s, got {v!r}")
        if kinematics is None:
            from robot_models import WamKinematics

            kinematics = WamKinematics.default()
        self.address, self.kinematics = address, kinematics
        self.timeout_s, self.request_timeout_s = float(timeout_s), float(request_timeout_s)
        self.heartbeat_s = None if heartbeat_s is None else float(heartbeat_s)
        self._ctx = context or zmq.Context.instance()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._ids = itertools.count(1)
        self._req = self._socket(zmq.DEALER)
        self._req.connect(address)
        self.lost: str | None = None
        self.dropped = 0  #: malformed stream messages dropped
        self.events: list[dict] = []  #: robot events (watchdog_hold, rejected, ...), as received
        self.clock = RoundTripClock()
        self.last_request_id = 0  #: the id of the latest request sent
        self.last_command_id: int | None = None  #: the id of the latest trajectory the robot accepted
        self._last_trajectory: tuple | None = None  # (t_s, q) of that trajectory, robot clock
        self.command_started: dict[int, int] = {}  #: trajectory id -> arrival (harness clock ns) of the first state tracking it
        self.n_joints: int | None = None  #: the arm's joint count, from the welcome (every vector of the session has it)
        welcome = self._request("hello", float(connect_timeout_s), client=str(client_name))
        self.robot_info = welcome
        if tuple(welcome["joint_names"]) != tuple(kinematics.joint_names):
            self.close()
            raise ValueError(f"robot at {address} has joints {welcome['joint_names']}, the kinematics "
                             f"{list(kinematics.joint_names)}")
        self.control_rate_hz = float(welcome["control_rate_hz"])
        self.n_joints = len(welcome["joint_names"])
        self.bridge_id = welcome["bridge_id"]
        self._lock = threading.Condition()
        self._buffer: deque = deque(maxlen=int(buffer_s * self.control_rate_hz))
        self._latest: dict | None = None
        self._truth: deque = deque(maxlen=self._buffer.maxlen)  # (t_ns, q_true) of a simulated robot
        self._arrivals: deque = deque(maxlen=self._buffer.maxlen)  # (seq, t_ns, arrival on the harness clock ns)
        self._last_state_mono = time.monotonic()
        self._cursor_s = -np.inf
        self._thread = threading.Thread(target=self._listen, name=f"robot-link {address}",
                                         args=(_state_address(address, welcome["state_endpoint"]),), daemon=True)
        self._thread.start()
        with self._lock:
            ok = self._lock.wait_for(lambda: self._latest is not None or self.lost, timeout=float(connect_timeout_s))
        if not ok or self._latest is None:
            reason = self.lost or f"no joint state from {address} within {connect_timeout_s:g} s"
            self.close()
            raise LinkLostError(reason)
        self.sync_clock()

    # -- sockets ----------------------------------------------------------------------------------
    def _socket(self, kind):
        sock = self._ctx.socket(kind)
        sock.setsockopt(zmq.LINGER, 0)
        return sock

    def _lose(self, reason: str) -> None:
        if self.lost is None:
            self.lost = reason
            log.error("robot link lost: %s", reason)

    def _check(self) -> None:
        if self.lost is not None:
            raise LinkLostError(self.lost)

    def _request(self, msg_type: str, timeout_s: float | None = None, **fields) -> dict:
        """Send one request and wait for its reply; ``error`` replies raise ValueError."""
        self._check()
        rid = next(self._ids)
        self.last_request_id = rid
        self._req.send(protocol.encode(msg_type, n_joints=self.n_joints, id=rid, **fields))
        deadline = time.monotonic() + (self.request_timeout_s if timeout_s is None else timeout_s)
        while True:
            left_ms = (deadline - time.monotonic()) * 1000
            if left_ms <= 0 or not self._req.poll(max(1, int(left_ms))):
                self._lose(f"robot at {self.address} did not answer a {msg_type!r} request within "
                           f"{(self.request_timeout_s if timeout_s is None else timeout_s):g} s")
                self._check()
            try:
                reply = protocol.decode(self._req.recv(), expect=("welcome", "ok", "error", "clock_reply"))
            except ProtocolError as exc:
                self.dropped += 1
                log.warning("dropped a malformed reply from %s: %s", self.address, exc)
                continue
            if reply["id"] is not None and reply["id"] != rid:
                continue  # a late reply to an earlier request
            if reply["type"] == "error":
                raise ValueError(f"robot at {self.address} refused the {msg_type}: {reply['reason']}")
            return reply

    def _listen(self, state_address: str) -> None:
        sub, hb = self._socket(zmq.SUB), self._socket(zmq.DEALER)
        try:
            sub.setsockopt(zmq.SUBSCRIBE, b"")
            sub.connect(state_address)
            hb.connect(self.address)
            hb_ids = itertools.count(1)
            next_hb = time.monotonic()
            while not self._stop.is_set():
                now = time.monotonic()
                if self.heartbeat_s is not None and now >= next_hb:
                    hb.send(protocol.encode("heartbeat", id=next(hb_ids)))
                    next_hb = now + self.heartbeat_s
                while hb.poll(0):
                    hb.recv()
                if sub.poll(5):
                    while sub.poll(0):
                        self._receive(sub.recv())
                        now = time.monotonic()  # a backlog of states never holds the heartbeat back
                        if self.heartbeat_s is not None and now >= next_hb:
                            hb.send(protocol.encode("heartbeat", id=next(hb_ids)))
                            next_hb = now + self.heartbeat_s
                elif self._latest is not None and time.monotonic() - self._last_state_mono > self.timeout_s:
                    # (before the first state the constructor waits up to connect_timeout_s)
                    with self._lock:
                        self._lose(f"no joint state from the robot at {self.address} for "
                                   f"{time.monotonic() - self._last_state_mono:.3f} s (limit {self.timeout_s:g} s)")
                        self._lock.notify_all()
                    return
        finally:
            sub.close(linger=0)
            hb.close(linger=0)

    def _receive(self, frame: bytes) -> None:
        rx_ns = time.monotonic_ns()
        try:
            msg = protocol.decode(frame, expect=("state", "event"), n_joints=self.n_joints)
        except ProtocolError as exc:
            self.dropped += 1
            log.warning("dropped a malformed stream message from %s: %s", self.address, exc)
            return
        if msg["type"] == "event":
            self.events.append(msg)
            log.info("robot event %s: %s", msg["event"], msg["reason"])
            return
        bad = self._out_of_range(msg)
        if bad:
            self.dropped += 1
            log.warning("dropped a state at robot time %d ns from %s: %s", msg["t_ns"], self.address, bad)
            return
        with self._lock:
            if self._latest is not None and msg["t_ns"] <= self._latest["t_ns"]:
                self.dropped += 1
                log.warning("dropped a state at robot time %d ns, not after the previous %d ns", msg["t_ns"],
                            self._latest["t_ns"])
                return
            if msg["cmd_id"] >= 0 and msg["cmd_id"] not in self.command_started:
                self.command_started[msg["cmd_id"]] = rx_ns
            self._latest = msg
            self._last_state_mono = time.monotonic()
            self._buffer.append(msg)
            self._arrivals.append((msg["seq"], msg["t_ns"], rx_ns))
            if msg["sim"] is not None and "q_true" in msg["sim"]:
                self._truth.append((msg["t_ns"], msg["sim"]["q_true"]))
            self._lock.notify_all()

    def _out_of_range(self, msg: dict) -> str:
        """Why a well-formed state cannot be a robot's (joints beyond the limits plus a margin), or ''."""
        q, qd = np.asarray(msg["q"]), np.asarray(msg["qdot"])
        k = self.kinematics
        out = (q < k.q_min - STATE_MARGIN_RAD) | (q > k.q_max + STATE_MARGIN_RAD)
        if out.any():
            j = int(np.argmax(out))
            return (f"q: {k.joint_names[j]} = {q[j]:.4g} rad is outside its limits [{k.q_min[j]:g}, {k.q_max[j]:g}] "
                    f"by more than {STATE_MARGIN_RAD} rad")
        fast = np.abs(qd) > STATE_QDOT_FACTOR * k.qdot_max
        if fast.any():
            j = int(np.argmax(fast))
            return f"qdot: {k.joint_names[j]} = {qd[j]:.4g} rad/s exceeds {STATE_QDOT_FACTOR} x its limit {k.qdot_max[j]:g}"
        return ""

    # -- WamInterface -----------------------------------------------------------------------------
    @property
    def t_s(self) -> float:
        """Robot time of the latest state received, s."""
        return self._latest["t_ns"] * 1e-9

    @property
    def mode(self) -> str:
        """The robot's mode in the latest state: idle, track, hold or watchdog."""
        return self._latest["mode"]

    def sim_info(self) -> dict | None:
        """A simulated robot's truth at the latest state (``--publish-truth``): ``q_true`` (n_joints,) rad, ``bias_rad``
        (n_joints,) its zero offsets, ``offset_ns`` its clock minus the host's monotonic clock; None from a real robot."""
        sim = self._latest.get("sim")
        return dict(sim) if sim else None

    def sim_true_q(self) -> np.ndarray | None:
        """(n_joints,) rad: a simulated robot's true joints at the latest state (bridges run with ``--publish-truth``), else None.

        Simulated scenes need them (where the ball on the end effector really is); a policy never reads them.
        """
        sim = self._latest.get("sim")
        q = None if not sim else sim.get("q_true")
        return None if q is None else np.array(q, dtype=float)

    def take_sim_truth(self) -> tuple[np.ndarray, np.ndarray]:
        """A simulated robot's true joints since the last call: t_s (m,) robot clock, q_true (m, n_joints) rad."""
        with self._lock:
            out = list(self._truth)
            self._truth.clear()
        if not out:
            return np.zeros(0), np.zeros((0, self.n_joints))
        return np.array([t for t, _ in out], dtype=np.float64) * 1e-9, np.array([q for _, q in out], dtype=float)

    def take_arrivals(self) -> np.ndarray:
        """(n, 3) int64 of the states received since the last call: seq, robot stamp t_ns, arrival (harness clock) ns."""
        with self._lock:
            out = list(self._arrivals)
            self._arrivals.clear()
        return np.array(out, dtype=np.int64).reshape(-1, 3)

    def read_state(self) -> JointState:
        """The latest reported state (robot clock)."""
        self._check()
        m = self._latest
        return JointState(m["t_ns"] * 1e-9, np.array(m["q"]), np.array(m["qdot"]))

    def command_trajectory(self, t_s, q, qdot=None) -> float:
        """Send a trajectory (robot clock); limits and the motion-safety rule are checked here first
        (ValueError naming the sample, joint and limit; nothing sent). Returns the robot time (s) at which the
        robot took it (its reply's stamp): after ``t_s[0]``, the arm took it over part-way."""
        self._check()
        now = self.t_s
        t, Q, Qd = check_joint_trajectory(self.kinematics, t_s, q, qdot, now_s=now)
        check_motion(self.kinematics, t, Q, Qd, now_s=now, start=self._start_state(max(float(t[0]), now)))
        t_ns = np.round(t * 1e9).astype(np.int64)
        reply = self._request("trajectory", t_ns=t_ns.tolist(), q=Q.tolist(), qdot=None if Qd is None else Qd.tolist())
        self.last_command_id = self.last_request_id
        self._last_trajectory = (t, Q)
        return reply["t_ns"] * 1e-9

    def _start_state(self, t_on: float) -> tuple[np.ndarray, np.ndarray]:
        """Where the arm is driven at ``t_on``: by this client's latest trajectory while the robot tracks
        (reports mode ``track``), else the reported state (a held or idle arm stays where it is)."""
        m = self._latest
        if self._last_trajectory is not None and m["mode"] == "track" and t_on >= self._last_trajectory[0][0]:
            return state_at(*self._last_trajectory, t_on)
        return np.array(m["q"], float), np.array(m["qdot"], float)

    def hold(self) -> None:
        """Hold: the robot ramps down to rest within its deceleration limits (the robot's ``hold`` request)."""
        self._request("hold")
        self._last_trajectory = None

    def advance_to(self, t_s: float) -> JointSamples:
        """Wait until the robot clock reaches the last tick at or before ``t_s``; the states since the last call."""
        t = float(t_s)
        if not np.isfinite(t) or t < self._cursor_s - 1e-12:
            raise ValueError(f"advance_to({t_s!r}): time must be finite and not before the last one asked, "
                             f"{self._cursor_s:.6g} s")
        tick_ns = int(np.floor(t * self.control_rate_hz + 1e-9)) * int(round(1e9 / self.control_rate_hz))
        with self._lock:
            while self.lost is None and self._latest["t_ns"] < tick_ns:
                self._lock.wait(self.timeout_s)
            self._check()
            out = []
            while self._buffer and self._buffer[0]["t_ns"] <= tick_ns:
                out.append(self._buffer.popleft())
        self._cursor_s = t
        return self._samples(out)

    def take_buffered(self) -> JointSamples:
        """Every state received but not yet handed out (also after a link loss: nothing received is lost)."""
        with self._lock:
            out = list(self._buffer)
            self._buffer.clear()
        return self._samples(out)

    def _samples(self, msgs: list[dict]) -> JointSamples:
        n = self.n_joints
        if not msgs:
            return JointSamples(np.zeros(0), np.zeros((0, n)), np.zeros((0, n)))
        return JointSamples(np.array([m["t_ns"] for m in msgs], dtype=np.float64) * 1e-9,
                            np.array([m["q"] for m in msgs]), np.array([m["qdot"] for m in msgs]))

    # -- clock ------------------------------------------------------------------------------------
    def sync_clock(self, n: int = 16) -> ClockEstimate:
        """``n`` NTP-style exchanges over the request socket; returns the updated offset estimate."""
        for _ in range(int(n)):
            t0 = time.monotonic_ns()
            r = self._request("clock", t0_ns=t0)
            self.clock.add(t0, r["t1_ns"], r["t2_ns"], time.monotonic_ns())
        return self.clock.estimate()

    # -- lifetime ---------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the heartbeat and the stream (the robot's watchdog then holds) and close the sockets."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self._req.close(linger=0)
        if self.lost is None:
            self.lost = f"client for {self.address} closed"

    def __enter__(self) -> "WamClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"WamClient({self.address!r}, bridge={getattr(self, 'bridge_id', None)!r}, lost={self.lost!r})"
