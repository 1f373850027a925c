"""The robot side of the link for the simulated WAM: :class:`SimBridge` runs a :class:`SimulatedWam` in real time.

One loop, single-threaded (docs/robot_link.md, "What a bridge must do"):

1. run the control ticks the robot clock has reached (``SimulatedWam.step``) and publish one ``state``
   per tick on the PUB socket, stamped with the tick's robot time;
2. answer the requests waiting on the ROUTER socket (``hello``, ``trajectory``, ``hold``, ``heartbeat``,
   ``clock``); a malformed or out-of-range request is answered ``error`` with the reason, logged, and never
   reaches the simulated robot;
3. the watchdog: no valid ``trajectory``, ``hold`` or ``heartbeat`` for ``watchdog_s`` (0.3 s, the command timeout of ``wam_node``) while
   tracking or holding -> hold the present position, mode ``watchdog``, one ``event`` ``watchdog_hold``.

Robot clock: ``t_robot_ns = monotonic_ns() - epoch_ns + clock_skew_ns``, so tick ``k`` (robot time
``k / rate``) runs when the robot clock passes it. ``clock_skew_ns`` exists to test the clock-offset
estimate against a known skew; ``epoch_ns`` is reported on the ready line for the same reason.
"""

from __future__ import annotations

import logging
import math
import time
import uuid
from dataclasses import dataclass

import numpy as np
import zmq

from harness.robot.link import protocol
from harness.robot.link.protocol import ProtocolError
from harness.robot.sim_wam import SimulatedWam
from robot_models.robot_interface import check_joint_trajectory

__all__ = ["BridgeOptions", "SimBridge"]

log = logging.getLogger("rt2.robot.link.bridge")
_MAX_REQUESTS_PER_TICK = 64


@dataclass(frozen=True)
class BridgeOptions:
    """Serving options. ``bind`` / ``state_bind``: ZeroMQ endpoints (``tcp://HOST:PORT``, ``*`` = a free port;
    ``state_bind=None``: command port + 1, or a free port when the command port is ``*``)."""

    bind: str = "tcp://127.0.0.1:7650"
    state_bind: str | None = None
    watchdog_s: float = 0.3  #: hold after this long without a valid request
    clock_skew_ns: int = 0  #: added to the robot clock (tests of the clock-offset estimate)
    publish_truth: bool = False  #: add the simulator's truth to every state (``sim``: q_true, bias_rad, offset_ns)
    batch_ticks: int = 1  #: wake every this many ticks (1: each state as its tick comes; N: less CPU, N-1 ticks later)
    truth_bind: str | None = None  #: also publish the lab truth stream here (harness.live.sources.lab_truth)

    def __post_init__(self):
        for name in ("bind",) + tuple(n for n in ("state_bind", "truth_bind") if getattr(self, n) is not None):
            value = getattr(self, name)
            if not isinstance(value, str) or not value.startswith(("tcp://", "ipc://", "inproc://")):
                raise ValueError(f"BridgeOptions.{name} must be a ZeroMQ endpoint like tcp://127.0.0.1:7650, got {value!r}")
        if not 0.01 <= float(self.watchdog_s) <= 10:
            raise ValueError(f"BridgeOptions.watchdog_s must be in [0.01, 10] s, got {self.watchdog_s!r}")
        if isinstance(self.batch_ticks, bool) or not isinstance(self.batch_ticks, int) or not 1 <= self.batch_ticks <= 50:
            raise ValueError(f"BridgeOptions.batch_ticks must be an integer in [1, 50], got {self.batch_ticks!r}")
        if not isinstance(self.clock_skew_ns, int) or abs(self.clock_skew_ns) > 10**12:
            raise ValueError(f"BridgeOptions.clock_skew_ns must be an int of at most 1000 s, got {self.clock_skew_ns!r}")

    def resolved_state_bind(self) -> str:
        if self.state_bind is not None:
            return self.state_bind
        head, _, port = self.bind.rpartition(":")
        return f"{head}:{int(port) + 1}" if self.bind.startswith("tcp://") and port.isdigit() else f"{head}:*"


def _warm_up(wam: SimulatedWam) -> None:
    """Run the command and tick paths once on a throwaway simulator, so that compiling the tracking kernel
    and first uses of the spline code happen before the clock starts, not as a stall in the control loop."""
    spare = SimulatedWam(wam.kinematics, wam.options, seed=0, q0=wam.true_state().q)
    q = spare.true_state().q
    spare.command_trajectory([0.002, 0.01, 0.02], np.stack([q, q, q]))
    spare.step(6)
    spare.command_trajectory([0.014, 0.03], np.stack([q, q]), np.zeros((2, q.size)))
    spare.step(10)


class SimBridge:
    """Serve ``wam`` over the robot link in real time (see the module docstring).

    wam : a fresh :class:`SimulatedWam` (clock at 0); options : :class:`BridgeOptions`.
    Endpoints are bound at construction (``command_endpoint``, ``state_endpoint`` name the actual ports).
    """

    def __init__(self, wam: SimulatedWam, options: BridgeOptions = BridgeOptions(), *, context=None):
        if not isinstance(wam, SimulatedWam) or wam.t_s != 0:
            raise ValueError(f"SimBridge needs a fresh SimulatedWam, got {wam!r}")
        self.wam, self.options = wam, options
        self.kin = wam.kinematics
        self.dt_ns = int(round(1e9 / wam.control_rate_hz))
        self.bridge_id = uuid.uuid4().hex[:12]  # tells the harness that a restarted bridge is a new robot session
        self._ctx = context or zmq.Context.instance()
        self._router = self._ctx.socket(zmq.ROUTER)
        self._pub = self._ctx.socket(zmq.PUB)
        for sock in (self._router, self._pub):
            sock.setsockopt(zmq.LINGER, 0)
        try:
            self._router.bind(options.bind)
            self._pub.bind(options.resolved_state_bind())
        except zmq.ZMQError as exc:
            self.close()
            raise ValueError(f"cannot bind the robot link at {options.bind} / {options.resolved_state_bind()}: {exc}") from None
        self._truth_pub = None
        if options.truth_bind is not None:
            from harness.live.sources.lab_truth import TruthPublisher, TruthError

            try:
                self._truth_pub = TruthPublisher(options.truth_bind, context=self._ctx)
            except TruthError:
                self.close()
                raise
        self.truth_endpoint = None if self._truth_pub is None else self._truth_pub.address
        self.command_endpoint = self._router.getsockopt_string(zmq.LAST_ENDPOINT)
        self.state_endpoint = self._pub.getsockopt_string(zmq.LAST_ENDPOINT)
        _warm_up(wam)
        self.epoch_ns = time.monotonic_ns()
        self.mode = "idle"
        self.cmd_id = -1
        self.seq = 0
        self.rejected = 0
        self._last_contact_ns: int | None = None
        self._stop = False
        self._ticks = 0  # control ticks run (the robot time of the latest is _ticks * dt_ns)
        # simulation truth for --publish-truth: the zero offsets, and robot clock minus host monotonic clock
        self._bias = np.asarray(wam.bias_rad, float).tolist()
        self._true_offset_ns = options.clock_skew_ns - self.epoch_ns

    # -- clock ------------------------------------------------------------------------------------
    def robot_ns(self) -> int:
        """The robot clock now, ns (0 at the bridge's start, plus the injected skew)."""
        return time.monotonic_ns() - self.epoch_ns + self.options.clock_skew_ns

    # -- loop -------------------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask :meth:`serve` to return after the present iteration (signal handlers call this)."""
        self._stop = True

    def serve(self, duration_s: float | None = None) -> None:
        """Run until :meth:`stop` (or for ``duration_s`` of robot time); closes the sockets at the end."""
        end_ns = None if duration_s is None else self.robot_ns() + int(duration_s * 1e9)
        poller = zmq.Poller()
        poller.register(self._router, zmq.POLLIN)
        self._event("started", f"simulated WAM at {self.wam.control_rate_hz:g} Hz, bridge {self.bridge_id}")
        try:
            while not self._stop and (end_ns is None or self.robot_ns() < end_ns):
                self._run_ticks()
                wait_ms = ((self._ticks + self.options.batch_ticks) * self.dt_ns - self.robot_ns()) / 1e6
                if poller.poll(timeout=max(1, math.ceil(wait_ms))):  # sleeps (a tick runs <= 1 ms late), never spins
                    for _ in range(_MAX_REQUESTS_PER_TICK):  # a flood of requests never starves the control ticks
                        if not self._router.poll(0):
                            break
                        self._handle(self._router.recv_multipart())
                self._watchdog()
        finally:
            self._event("stopping", "bridge shutting down")
            self.close()

    def close(self) -> None:
        for sock in (self._router, self._pub):
            sock.close(linger=0)
        if getattr(self, "_truth_pub", None) is not None:
            self._truth_pub.close()

    def _run_ticks(self) -> None:
        target = self.robot_ns() // self.dt_ns
        n = target - self._ticks
        if n <= 0:
            return
        samples = self.wam.step(int(n))
        self._ticks += int(n)
        truth = samples.q_true if self.options.publish_truth else None
        for i in range(n):
            self.seq += 1
            t_ns = int(round(samples.t_s[i] * 1e9))
            if self._truth_pub is not None:  # the lab truth stream: true joints on the host clock
                self._truth_pub.publish(t_ns - self._true_offset_ns, samples.q_true[i])
            sim = None if truth is None else {"q_true": truth[i].tolist(), "bias_rad": self._bias,
                                              "offset_ns": self._true_offset_ns}
            self._pub.send(protocol.encode("state", seq=self.seq, t_ns=t_ns, q=samples.q[i].tolist(),
                                           qdot=samples.qdot[i].tolist(), effort=None, mode=self.mode,
                                           cmd_id=self.cmd_id, sim=sim))

    def _event(self, event: str, reason: str) -> None:
        self._pub.send(protocol.encode("event", t_ns=self.robot_ns(), event=event, reason=reason))

    # -- requests ---------------------------------------------------------------------------------
    def _reply(self, ident: bytes, msg_type: str, **fields) -> None:
        self._router.send_multipart([ident, protocol.encode(msg_type, **fields)])

    def _handle(self, frames: list[bytes]) -> None:
        t_recv = self.robot_ns()
        ident = frames[0]
        if len(frames) != 2:
            self._reject(ident, None, f"expected one message frame, got {len(frames) - 1}")
            return
        try:
            msg = protocol.decode(frames[1], expect=("hello", "trajectory", "hold", "heartbeat", "clock"))
        except ProtocolError as exc:
            self._reject(ident, protocol.request_id(frames[1]), str(exc))
            return
        rid, kind = msg["id"], msg["type"]
        if kind == "trajectory":
            try:
                self._apply_trajectory(msg)
            except ValueError as exc:
                self._reject(ident, rid, f"trajectory {rid}: {exc}")
                return
        if kind in ("trajectory", "hold", "heartbeat"):  # what keeps the watchdog quiet (not hello, not clock)
            self._last_contact_ns = t_recv
        if kind == "hello":
            k = self.kin
            self._reply(ident, "welcome", id=rid, robot="rt2 simulated WAM", bridge_id=self.bridge_id,
                        joint_names=list(k.joint_names), control_rate_hz=float(self.wam.control_rate_hz),
                        q_min=np.asarray(k.q_min, float).tolist(), q_max=np.asarray(k.q_max, float).tolist(),
                        qdot_max=np.asarray(k.qdot_max, float).tolist(), state_endpoint=self.state_endpoint,
                        watchdog_s=float(self.options.watchdog_s), t_ns=self.robot_ns())
            log.info("hello from %s", msg["client"])
        elif kind == "clock":
            self._reply(ident, "clock_reply", id=rid, t0_ns=msg["t0_ns"], t1_ns=t_recv, t2_ns=self.robot_ns())
        else:
            if kind == "hold":
                self._hold("hold")
            self._reply(ident, "ok", id=rid, t_ns=self.robot_ns())

    def _apply_trajectory(self, msg: dict) -> None:
        t_s = np.asarray(msg["t_ns"], dtype=np.int64) * 1e-9
        t, Q, Qd = check_joint_trajectory(self.kin, t_s, msg["q"], msg["qdot"], now_s=self.wam.t_s)
        self.wam.command_trajectory(t, Q, Qd)
        self.cmd_id, self.mode = int(msg["id"]), "track"

    def _reject(self, ident: bytes, rid, reason: str) -> None:
        self.rejected += 1
        log.warning("rejected: %s", reason)
        self._reply(ident, "error", id=rid, reason=reason)
        self._event("rejected", reason)

    # -- holding ----------------------------------------------------------------------------------
    def _hold(self, mode: str) -> None:
        """Hold the present (true) joint position from now on."""
        q = np.clip(self.wam.true_state().q, self.kin.q_min, self.kin.q_max)
        now = self.wam.t_s
        self.wam.command_trajectory([now, now + 1.0 / self.wam.control_rate_hz], np.stack([q, q]), np.zeros((2, q.size)))
        self.mode = mode

    def _watchdog(self) -> None:
        if self.mode not in ("track", "hold") or self._last_contact_ns is None:
            return
        silent_s = (self.robot_ns() - self._last_contact_ns) * 1e-9
        if silent_s > self.options.watchdog_s:
            self._hold("watchdog")
            reason = f"no command or heartbeat for {silent_s:.3f} s (limit {self.options.watchdog_s:g} s): holding position"
            log.warning("watchdog: %s", reason)
            self._event("watchdog_hold", reason)
