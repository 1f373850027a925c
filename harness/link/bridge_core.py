"""What every robot-side bridge of the link does, whatever the controller behind it (docs/robot_link.md).

:class:`BridgeCore` owns the two sockets (ROUTER for requests, PUB for states and events) and the
controller-independent half of "What a bridge must do": decoding and validating requests against the
schema, one reply per request echoing ``id``, ``error`` replies that are logged and published as
``rejected`` events, ``clock`` stamps, the ``welcome``, and the watchdog (no ``trajectory``, ``hold`` or
``heartbeat`` for ``watchdog_s`` while tracking or holding -> hold, mode ``watchdog``, one ``watchdog_hold``
event). A concrete bridge supplies the robot clock (:meth:`BridgeCore.robot_ns`), what the robot is
(:meth:`BridgeCore.welcome_fields`), how a validated trajectory reaches the controller
(:meth:`BridgeCore.apply_trajectory`) and how it holds (:meth:`BridgeCore.hold`), and runs its own loop
calling :meth:`BridgeCore.start_intake` once, then :meth:`BridgeCore.serve_requests`,
:meth:`BridgeCore.publish_state` and :meth:`BridgeCore.watchdog`, waking on :attr:`BridgeCore.requests`.

The control loop never waits on a peer (docs/robot_link.md, "What a peer cannot do"): the ROUTER socket
belongs to an *intake thread* that receives, unpacks and validates every request
(``protocol.decode_request``: aborted as soon as a frame cannot be a request, so a hostile frame costs no
more than the largest valid one; the GIL can pass to the control thread between lists) and answers
``hello``, ``clock`` and ``heartbeat`` itself; after a frame that took more than
:data:`INTAKE_DUTY_FREE_S` it rests as long (at most half of the CPU and GIL go to peers). Only validated ``trajectory`` and ``hold`` requests reach
the control thread, which applies them within a time budget per wake (:data:`REQUEST_BUDGET_S`). Frames
over ``protocol.MAX_MESSAGE_BYTES`` are refused by ZeroMQ before they are received (``ZMQ_MAXMSGSIZE``:
the peer is disconnected), and at most :data:`RCVHWM` frames wait per peer. Rejections are logged and
published one by one up to :data:`REJECT_BURST` a second; beyond that they are counted per reason and
summarised once a second.

Implementations: ``bridge_sim.SimBridge`` (the simulated WAM) and ``bridge_ros.RosBridge`` (ROS ``wam_node``).
Imports only the protocol and pyzmq, so that it runs under a system Python (``bridge_ros``).
"""

from __future__ import annotations

import collections
import gc
import logging
import sys
import threading
import time
import uuid

import zmq

from harness.common.ratelimit import RateLimit
from harness.link import protocol
from harness.link.protocol import ProtocolError

__all__ = ["BridgeCore", "check_endpoint", "default_state_bind"]

log = logging.getLogger("rt2.robot.link.bridge")
MAX_REQUESTS_PER_WAKE = 64  #: the intake thread answers replies between at most this many requests
REQUEST_BUDGET_S = 0.002  #: the control thread applies queued requests for at most this long per wake
RCVHWM = 8  #: frames queued per peer before ZeroMQ stops reading from it (bounds memory: 8 x 4 MiB)
REJECT_BURST = 10  #: rejections logged/published one by one per second; the rest are counted and summarised
ID_PEEK_BYTES = 64 << 10  #: the id of a refused frame is read back only from frames up to this size
INTAKE_DUTY_FREE_S = 0.002  #: after a request that took longer to take in, the intake thread rests as long
SWITCH_INTERVAL_S = 0.0005  #: the GIL passes between the intake and control threads at least this often
REQUESTS = ("hello", "trajectory", "hold", "heartbeat", "clock")


def check_endpoint(name: str, value) -> str:
    """``value`` if it is a ZeroMQ endpoint (tcp://, ipc://, inproc://), else ValueError naming ``name``."""
    if not isinstance(value, str) or not value.startswith(("tcp://", "ipc://", "inproc://")):
        raise ValueError(f"{name} must be a ZeroMQ endpoint like tcp://127.0.0.1:7650, got {value!r}")
    return value


def default_state_bind(bind: str) -> str:
    """The state endpoint when none is given: the command port + 1, or a free port when that is ``*``."""
    head, _, port = bind.rpartition(":")
    return f"{head}:{int(port) + 1}" if bind.startswith("tcp://") and port.isdigit() else f"{head}:*"


class BridgeCore:
    """The sockets, requests and watchdog of a bridge (see the module docstring); subclass it.

    bind, state_bind : ZeroMQ endpoints (``*`` = a free port; ``state_bind=None``: :func:`default_state_bind`).
    watchdog_s : hold after this long without ``trajectory``, ``hold`` or ``heartbeat``.
    Endpoints are bound at construction (``command_endpoint``, ``state_endpoint`` name the actual ports).
    """

    def __init__(self, bind: str, state_bind: str | None, watchdog_s: float, *, context=None):
        self.watchdog_s = float(watchdog_s)
        self.bridge_id = uuid.uuid4().hex[:12]  # tells the harness that a restarted bridge is a new robot session
        self._ctx = context or zmq.Context.instance()
        self._router = self._ctx.socket(zmq.ROUTER)
        self._router.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_MESSAGE_BYTES)  # larger: refused unread
        self._router.setsockopt(zmq.RCVHWM, RCVHWM)
        self._pub = self._ctx.socket(zmq.PUB)
        # the control thread's end (``requests``) and the intake thread's end of the in-process pipe
        self.requests = self._ctx.socket(zmq.PAIR)
        self._intake_end = self._ctx.socket(zmq.PAIR)
        for sock in (self._router, self._pub, self.requests, self._intake_end):
            sock.setsockopt(zmq.LINGER, 0)
        pipe = f"inproc://rt2-bridge-{self.bridge_id}"
        self.requests.bind(pipe)
        self._intake_end.connect(pipe)
        state_bind = default_state_bind(bind) if state_bind is None else state_bind
        self._intake: threading.Thread | None = None
        self._switch_before: float | None = None  # the process's switch interval, restored by close()
        self._intake_stop = threading.Event()
        try:
            self._router.bind(bind)
            self._pub.bind(state_bind)
        except zmq.ZMQError as exc:
            self.close()
            raise ValueError(f"cannot bind the robot link at {bind} / {state_bind}: {exc}") from None
        self.command_endpoint = self._router.getsockopt_string(zmq.LAST_ENDPOINT)
        self.state_endpoint = self._pub.getsockopt_string(zmq.LAST_ENDPOINT)
        self.mode = "idle"
        self.cmd_id = -1
        self.seq = 0
        self.rejects = RateLimit(REJECT_BURST)  # rejections: 10 a second one by one, the rest counted
        self._queue: collections.deque = collections.deque()  # (ident, request, t_recv_ns) for the control thread
        self._pending_events: collections.deque = collections.deque()  # rejection reasons to publish
        self._last_contact_ns: int | None = None
        self._stop = False
        self._n_joints: int | None = None

    @property
    def rejected(self) -> int:
        """Requests rejected so far."""
        return self.rejects.total

    @property
    def n_joints(self) -> int:
        """The arm's joint count: every joint vector of the session has it (the ``welcome``'s ``joint_names``)."""
        if self._n_joints is None:
            self._n_joints = len(self.welcome_fields()["joint_names"])
        return self._n_joints

    # -- what a concrete bridge supplies ------------------------------------------------------------
    def robot_ns(self) -> int:
        """The robot clock now, integer ns (called from the intake thread too)."""
        raise NotImplementedError

    def welcome_fields(self) -> dict:
        """``robot``, ``joint_names``, ``control_rate_hz``, ``q_min``, ``q_max``, ``qdot_max`` of the ``welcome``."""
        raise NotImplementedError

    def apply_trajectory(self, msg: dict) -> None:
        """Check a decoded ``trajectory`` against the limits and hand it to the controller; ValueError refuses it."""
        raise NotImplementedError

    def hold(self, mode: str) -> None:
        """Hold the present position from now on and set ``self.mode = mode``; ValueError if the controller refused."""
        raise NotImplementedError

    # -- loop pieces --------------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask the serving loop to return after the present iteration (signal handlers call this)."""
        self._stop = True

    def start_intake(self) -> None:
        """Start the intake thread (requests are answered from then on); the serving loop calls it once."""
        if self._intake is None:
            # scoped to the serving: close() restores the interval and unfreezes what this froze
            self._switch_before = sys.getswitchinterval()
            sys.setswitchinterval(min(self._switch_before, SWITCH_INTERVAL_S))
            gc.freeze()  # what exists now (modules, compiled kernels) is never traversed by a collection again

            self._intake = threading.Thread(target=self._intake_loop, name="robot-link intake", daemon=True)
            self._intake.start()

    def close(self) -> None:
        self._intake_stop.set()
        if self._intake is not None and self._intake is not threading.current_thread():
            self._intake.join(timeout=2.0)
        rest = self.rejects.flush()  # rejections of the last period, whose summary the control loop had not written yet
        if rest:
            log.warning("rejected: %s", rest)
        if self._intake is None or not self._intake.is_alive():
            self._router.close(linger=0)
            self._intake_end.close(linger=0)
        for sock in (self._pub, self.requests):
            sock.close(linger=0)
        if self._switch_before is not None:
            sys.setswitchinterval(self._switch_before)
            gc.unfreeze()
            self._switch_before = None

    def serve_requests(self, budget_s: float = REQUEST_BUDGET_S) -> None:
        """Apply the validated ``trajectory`` / ``hold`` requests the intake thread queued, for at most
        ``budget_s`` (the rest wait for the next wake), and publish the pending rejection events."""
        while self.requests.poll(0):
            self.requests.recv()  # wake-ups: the work is in the queue
        while self._pending_events:
            self.event("rejected", self._pending_events.popleft())
        deadline = time.monotonic() + budget_s
        while self._queue and time.monotonic() < deadline:
            self._apply(*self._queue.popleft())

    def publish_state(self, t_ns: int, q: list, qdot: list, effort: list | None, sim: dict | None = None) -> None:
        """One ``state`` on PUB: robot time ``t_ns``, q (n,) rad, qdot (n,) rad/s, effort (n,) N m or None
        (n: the arm's joints, as in the ``welcome``)."""
        self.seq += 1
        self._pub.send(protocol.encode("state", n_joints=self.n_joints, seq=self.seq, t_ns=int(t_ns), q=q, qdot=qdot,
                                       effort=effort, mode=self.mode, cmd_id=self.cmd_id, sim=sim))

    def event(self, event: str, reason: str) -> None:
        """One ``event`` on PUB, stamped with the robot clock now (control thread only)."""
        self._pub.send(protocol.encode("event", t_ns=self.robot_ns(), event=event, reason=reason[:1000]))

    def watchdog(self) -> None:
        """Hold (mode ``watchdog``, one ``watchdog_hold`` event) after ``watchdog_s`` without a command or heartbeat;
        publish the summary of rate-limited rejections once a second."""
        summary = self.rejects.summary()
        if summary:
            log.warning("rejected: %s", summary)
            self.event("rejected", summary)
        if self.mode not in ("track", "hold") or self._last_contact_ns is None:
            return
        silent_s = (self.robot_ns() - self._last_contact_ns) * 1e-9
        if silent_s > self.watchdog_s:
            reason = f"no command or heartbeat for {silent_s:.3f} s (limit {self.watchdog_s:g} s): holding position"
            try:
                self.hold("watchdog")
            except ValueError as exc:  # the controller refused: say so, and do not retry every iteration
                self.mode = "watchdog"
                reason += f"; the controller refused the hold: {exc}"
            log.warning("watchdog: %s", reason)
            self.event("watchdog_hold", reason)

    # -- the intake thread: owns the ROUTER socket ---------------------------------------------------
    def _intake_loop(self) -> None:
        router, pipe = self._router, self._intake_end
        poller = zmq.Poller()
        poller.register(router, zmq.POLLIN)
        poller.register(pipe, zmq.POLLIN)
        try:
            while not self._intake_stop.is_set():
                if not poller.poll(50):
                    continue
                self._forward_replies()
                for _ in range(MAX_REQUESTS_PER_WAKE):
                    if not router.poll(0):
                        break
                    t0 = time.perf_counter()
                    self._take(router.recv_multipart())
                    self._forward_replies()
                    spent = time.perf_counter() - t0
                    if spent > INTAKE_DUTY_FREE_S:  # a costly frame: leave the GIL and the CPU to the control loop
                        time.sleep(min(spent, 0.05))
        except zmq.ZMQError as exc:  # the context is being torn down
            if not self._intake_stop.is_set():
                log.error("robot link intake stopped: %s", exc)
        finally:
            router.close(linger=0)
            pipe.close(linger=0)

    def _forward_replies(self) -> None:
        while self._intake_end.poll(0):
            self._router.send_multipart(self._intake_end.recv_multipart())

    def _take(self, frames: list[bytes]) -> None:
        t_recv = self.robot_ns()
        ident = frames[0]
        if len(frames) != 2:
            self._refuse(ident, None, f"expected one message frame, got {len(frames) - 1}")
            return
        try:
            msg = protocol.decode_request(frames[1], REQUESTS, self.n_joints)
        except ProtocolError as exc:
            small = len(frames[1]) <= ID_PEEK_BYTES
            self._refuse(ident, protocol.request_id(frames[1]) if small else None, str(exc))
            return
        rid, kind = msg["id"], msg["type"]
        if kind == "hello":
            self._send(ident, "welcome", id=rid, bridge_id=self.bridge_id, state_endpoint=self.state_endpoint,
                       watchdog_s=self.watchdog_s, t_ns=self.robot_ns(), **self.welcome_fields())
            log.info("hello from %s", msg["client"])
        elif kind == "clock":
            self._send(ident, "clock_reply", id=rid, t0_ns=msg["t0_ns"], t1_ns=t_recv, t2_ns=self.robot_ns())
        elif kind == "heartbeat":
            self._last_contact_ns = t_recv
            self._send(ident, "ok", id=rid, t_ns=self.robot_ns())
        else:  # trajectory, hold: the control thread's
            self._queue.append((ident, msg, t_recv))
            self._intake_end.send(b"")

    def _send(self, ident: bytes, msg_type: str, **fields) -> None:
        self._router.send_multipart([ident, protocol.encode(msg_type, **fields)])

    def _refuse(self, ident: bytes, rid, reason: str) -> None:
        """A rejection on the intake thread: the reply at once, the event through the control thread."""
        self._send(ident, "error", id=rid, reason=reason[:1000])
        if self.rejects.note(reason):
            log.warning("rejected: %s", reason)
            self._pending_events.append(reason)

    # -- the control thread: applies what the intake thread validated -------------------------------
    def _reply(self, ident: bytes, msg_type: str, **fields) -> None:
        self.requests.send_multipart([ident, protocol.encode(msg_type, **fields)])

    def _apply(self, ident: bytes, msg: dict, t_recv: int) -> None:
        rid, kind = msg["id"], msg["type"]
        try:
            if kind == "trajectory":
                self.apply_trajectory(msg)
            else:
                self.hold("hold")
        except ValueError as exc:
            self._reject(ident, rid, f"{kind} {rid}: {exc}")
            return
        self._last_contact_ns = t_recv  # what keeps the watchdog quiet (with heartbeat; not hello, not clock)
        self._reply(ident, "ok", id=rid, t_ns=self.robot_ns())

    def _reject(self, ident: bytes, rid, reason: str) -> None:
        self._reply(ident, "error", id=rid, reason=reason[:1000])
        if self.rejects.note(reason):
            log.warning("rejected: %s", reason)
            self.event("rejected", reason)
