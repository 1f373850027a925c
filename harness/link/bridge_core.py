"""What every robot-side bridge of the link does, whatever the controller behind it (docs/robot_link.md).

:class:`BridgeCore` owns the two sockets (ROUTER for requests, PUB for states and events) and the
controller-independent half of "What a bridge must do": decoding and validating requests against the
schema, one reply per request echoing ``id``, ``error`` replies that are logged and published as
``rejected`` events, ``clock`` stamps, the ``welcome``, and the watchdog (no ``trajectory``, ``hold`` or
``heartbeat`` for ``watchdog_s`` while tracking or holding -> hold, mode ``watchdog``, one ``watchdog_hold``
event). A concrete bridge supplies the robot clock (:meth:`BridgeCore.robot_ns`), what the robot is
(:meth:`BridgeCore.welcome_fields`), how a validated trajectory reaches the controller
(:meth:`BridgeCore.apply_trajectory`) and how it holds (:meth:`BridgeCore.hold`), and runs its own loop
calling :meth:`BridgeCore.serve_requests`, :meth:`BridgeCore.publish_state` and :meth:`BridgeCore.watchdog`.

Implementations: ``bridge_sim.SimBridge`` (the simulated WAM) and ``bridge_ros.RosBridge`` (ROS ``wam_node``).
Imports only the protocol and pyzmq, so that it runs under a system Python (``bridge_ros``).
"""

from __future__ import annotations

import logging
import uuid

import zmq

from harness.link import protocol
from harness.link.protocol import ProtocolError

__all__ = ["BridgeCore", "check_endpoint", "default_state_bind"]

log = logging.getLogger("rt2.robot.link.bridge")
MAX_REQUESTS_PER_WAKE = 64  #: a flood of requests never starves the control loop
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
        self._pub = self._ctx.socket(zmq.PUB)
        for sock in (self._router, self._pub):
            sock.setsockopt(zmq.LINGER, 0)
        state_bind = default_state_bind(bind) if state_bind is None else state_bind
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
        self.rejected = 0
        self._last_contact_ns: int | None = None
        self._stop = False

    # -- what a concrete bridge supplies ------------------------------------------------------------
    def robot_ns(self) -> int:
        """The robot clock now, integer ns."""
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

    def close(self) -> None:
        for sock in (self._router, self._pub):
            sock.close(linger=0)

    def serve_requests(self) -> None:
        """Answer the requests waiting on the ROUTER socket (at most :data:`MAX_REQUESTS_PER_WAKE`)."""
        for _ in range(MAX_REQUESTS_PER_WAKE):
            if not self._router.poll(0):
                break
            self._handle(self._router.recv_multipart())

    def publish_state(self, t_ns: int, q: list, qdot: list, effort: list | None, sim: dict | None = None) -> None:
        """One ``state`` on PUB: robot time ``t_ns``, q (7,) rad, qdot (7,) rad/s, effort (7,) N m or None."""
        self.seq += 1
        self._pub.send(protocol.encode("state", seq=self.seq, t_ns=int(t_ns), q=q, qdot=qdot, effort=effort,
                                       mode=self.mode, cmd_id=self.cmd_id, sim=sim))

    def event(self, event: str, reason: str) -> None:
        """One ``event`` on PUB, stamped with the robot clock now."""
        self._pub.send(protocol.encode("event", t_ns=self.robot_ns(), event=event, reason=reason))

    def watchdog(self) -> None:
        """Hold (mode ``watchdog``, one ``watchdog_hold`` event) after ``watchdog_s`` without a command or heartbeat."""
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

    # -- requests -----------------------------------------------------------------------------------
    def _reply(self, ident: bytes, msg_type: str, **fields) -> None:
        self._router.send_multipart([ident, protocol.encode(msg_type, **fields)])

    def _handle(self, frames: list[bytes]) -> None:
        t_recv = self.robot_ns()
        ident = frames[0]
        if len(frames) != 2:
            self._reject(ident, None, f"expected one message frame, got {len(frames) - 1}")
            return
        try:
            msg = protocol.decode(frames[1], expect=REQUESTS)
        except ProtocolError as exc:
            self._reject(ident, protocol.request_id(frames[1]), str(exc))
            return
        rid, kind = msg["id"], msg["type"]
        if kind == "trajectory":
            try:
                self.apply_trajectory(msg)
            except ValueError as exc:
                self._reject(ident, rid, f"trajectory {rid}: {exc}")
                return
        if kind in ("trajectory", "hold", "heartbeat"):  # what keeps the watchdog quiet (not hello, not clock)
            self._last_contact_ns = t_recv
        if kind == "hello":
            self._reply(ident, "welcome", id=rid, bridge_id=self.bridge_id, state_endpoint=self.state_endpoint,
                        watchdog_s=self.watchdog_s, t_ns=self.robot_ns(), **self.welcome_fields())
            log.info("hello from %s", msg["client"])
        elif kind == "clock":
            self._reply(ident, "clock_reply", id=rid, t0_ns=msg["t0_ns"], t1_ns=t_recv, t2_ns=self.robot_ns())
        else:
            if kind == "hold":
                try:
                    self.hold("hold")
                except ValueError as exc:
                    self._reject(ident, rid, f"hold {rid}: {exc}")
                    return
            self._reply(ident, "ok", id=rid, t_ns=self.robot_ns())

    def _reject(self, ident: bytes, rid, reason: str) -> None:
        self.rejected += 1
        log.warning("rejected: %s", reason)
        self._reply(ident, "error", id=rid, reason=reason)
        self.event("rejected", reason)
