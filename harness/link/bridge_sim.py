"""The robot side of the link for the simulated WAM: :class:`SimBridge` runs a :class:`SimulatedWam` in real time.

One control loop (docs/robot_link.md, "What a bridge must do"; requests are received, unpacked and validated
by the intake thread of ``bridge_core``, which never holds this loop up):

1. run the control ticks the robot clock has reached (``SimulatedWam.step``) and publish one ``state``
   per tick on the PUB socket, stamped with the tick's robot time;
2. apply the ``trajectory`` and ``hold`` requests the intake thread validated (within a time budget per
   wake); a malformed or out-of-range request is answered ``error`` with the reason, logged (rate-limited),
   and never reaches the simulated robot;
3. the watchdog: no valid ``trajectory``, ``hold`` or ``heartbeat`` for ``watchdog_s`` (0.3 s, the command timeout of ``wam_node``) while
   tracking or holding -> hold the present position, mode ``watchdog``, one ``event`` ``watchdog_hold``.

Robot clock: ``t_robot_ns = monotonic_ns() - epoch_ns + clock_skew_ns``, so tick ``k`` (robot time
``k / rate``) runs when the robot clock passes it. ``clock_skew_ns`` exists to test the clock-offset
estimate against a known skew; ``epoch_ns`` is reported on the ready line for the same reason.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import zmq

from harness.link.bridge_core import BridgeCore, check_endpoint, default_state_bind
from harness.sim.robot.simulated_wam import SimulatedWam
from robot_models.motion_limits import check_motion, stop_ramp
from robot_models.robot_interface import check_joint_trajectory

__all__ = ["BridgeOptions", "SimBridge"]


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
    truth_bind: str | None = None  #: also publish the lab truth stream here (harness.sim.lab_truth)

    def __post_init__(self):
        for name in ("bind",) + tuple(n for n in ("state_bind", "truth_bind") if getattr(self, n) is not None):
            check_endpoint(f"BridgeOptions.{name}", getattr(self, name))
        if not 0.01 <= float(self.watchdog_s) <= 10:
            raise ValueError(f"BridgeOptions.watchdog_s must be in [0.01, 10] s, got {self.watchdog_s!r}")
        if isinstance(self.batch_ticks, bool) or not isinstance(self.batch_ticks, int) or not 1 <= self.batch_ticks <= 50:
            raise ValueError(f"BridgeOptions.batch_ticks must be an integer in [1, 50], got {self.batch_ticks!r}")
        if not isinstance(self.clock_skew_ns, int) or abs(self.clock_skew_ns) > 10**12:
            raise ValueError(f"BridgeOptions.clock_skew_ns must be an int of at most 1000 s, got {self.clock_skew_ns!r}")

    def resolved_state_bind(self) -> str:
        return default_state_bind(self.bind) if self.state_bind is None else self.state_bind


def _warm_up(wam: SimulatedWam) -> None:
    """Run the command and tick paths once on a throwaway simulator, so that compiling the tracking kernel
    and first uses of the spline code happen before the clock starts, not as a stall in the control loop."""
    spare = SimulatedWam(wam.kinematics, wam.options, seed=0, q0=wam.true_state().q)
    q = spare.true_state().q
    spare.command_trajectory([0.002, 0.01, 0.02], np.stack([q, q, q]))
    spare.step(6)
    spare.command_trajectory([0.014, 0.03], np.stack([q, q]), np.zeros((2, q.size)))
    spare.step(10)


class SimBridge(BridgeCore):
    """Serve ``wam`` over the robot link in real time (see the module docstring).

    wam : a fresh :class:`SimulatedWam` (clock at 0); options : :class:`BridgeOptions`.
    Endpoints are bound at construction (``command_endpoint``, ``state_endpoint`` name the actual ports).
    """

    def __init__(self, wam: SimulatedWam, options: BridgeOptions = BridgeOptions(), *, context=None):
        if not isinstance(wam, SimulatedWam) or wam.t_s != 0:
            raise ValueError(f"SimBridge needs a fresh SimulatedWam, got {wam!r}")
        super().__init__(options.bind, options.resolved_state_bind(), options.watchdog_s, context=context)
        self.wam, self.options = wam, options
        self.kin = wam.kinematics
        self.dt_ns = int(round(1e9 / wam.control_rate_hz))
        self._truth_pub = None
        if options.truth_bind is not None:
            from harness.sim.lab_truth import TruthError, TruthPublisher

            try:
                self._truth_pub = TruthPublisher(options.truth_bind, context=self._ctx)
            except TruthError:
                self.close()
                raise
        self.truth_endpoint = None if self._truth_pub is None else self._truth_pub.address
        _warm_up(wam)
        self.epoch_ns = time.monotonic_ns()
        self._ticks = 0  # control ticks run (the robot time of the latest is _ticks * dt_ns)
        self.wam_origin_ns = 0  # robot time of the simulator's time 0 (a subclass may start a new simulator later)
        # simulation truth for --publish-truth: the zero offsets, and robot clock minus host monotonic clock
        self._bias = np.asarray(wam.bias_rad, float).tolist()
        self._true_offset_ns = options.clock_skew_ns - self.epoch_ns

    # -- clock ------------------------------------------------------------------------------------
    def robot_ns(self) -> int:
        """The robot clock now, ns (0 at the bridge's start, plus the injected skew)."""
        return time.monotonic_ns() - self.epoch_ns + self.options.clock_skew_ns

    # -- loop -------------------------------------------------------------------------------------
    def serve(self, duration_s: float | None = None) -> None:
        """Run until :meth:`stop` (or for ``duration_s`` of robot time); closes the sockets at the end."""
        end_ns = None if duration_s is None else self.robot_ns() + int(duration_s * 1e9)
        poller = zmq.Poller()
        poller.register(self.requests, zmq.POLLIN)
        self.event("started", f"simulated WAM at {self.wam.control_rate_hz:g} Hz, bridge {self.bridge_id}")
        self.start_intake()
        try:
            while not self._stop and (end_ns is None or self.robot_ns() < end_ns):
                self._run_ticks()
                wait_ms = ((self._ticks + self.options.batch_ticks) * self.dt_ns - self.robot_ns()) / 1e6
                poller.poll(timeout=max(1, math.ceil(wait_ms)))  # sleeps (a tick runs <= 1 ms late), never spins
                self.serve_requests()  # what the intake thread validated, within a time budget
                self.watchdog()
        finally:
            self.event("stopping", "bridge shutting down")
            self.close()

    def close(self) -> None:
        super().close()
        if getattr(self, "_truth_pub", None) is not None:
            self._truth_pub.close()

    def _run_ticks(self) -> None:
        target = self.robot_ns() // self.dt_ns
        n = target - self._ticks
        if n <= 0:
            return
        samples = self.wam.step(int(n))
        self._ticks += int(n)
        self._publish_states(samples)

    def _publish_states(self, samples) -> None:
        """One ``state`` per sample of ``self.wam`` (stamped ``wam_origin_ns`` + the simulator's own time)."""
        truth = samples.q_true if self.options.publish_truth else None
        for i in range(len(samples)):
            t_ns = self.wam_origin_ns + int(round(samples.t_s[i] * 1e9))
            if self._truth_pub is not None:  # the lab truth stream: true joints on the host clock
                self._truth_pub.publish(t_ns - self._true_offset_ns, samples.q_true[i])
            sim = None if truth is None else {"q_true": truth[i].tolist(), "bias_rad": self._bias,
                                              "offset_ns": self._true_offset_ns}
            self.publish_state(t_ns, samples.q[i].tolist(), samples.qdot[i].tolist(), None, sim)

    # -- BridgeCore ---------------------------------------------------------------------------------
    def welcome_fields(self) -> dict:
        k = self.kin
        return {"robot": "rt2 simulated WAM" if k.name == "wam" else f"rt2 simulated arm {k.name}",
                "joint_names": list(k.joint_names),
                "control_rate_hz": float(self.wam.control_rate_hz), "q_min": np.asarray(k.q_min, float).tolist(),
                "q_max": np.asarray(k.q_max, float).tolist(), "qdot_max": np.asarray(k.qdot_max, float).tolist()}

    def apply_trajectory(self, msg: dict) -> None:
        t_s = (np.asarray(msg["t_ns"], dtype=np.int64) - self.wam_origin_ns) * 1e-9
        now = self.wam.t_s
        t, Q, Qd = check_joint_trajectory(self.kin, t_s, msg["q"], msg["qdot"], now_s=now)
        if t[0] > now:  # it takes over later: from where the present reference drives the arm then
            start = self.wam.reference_at(t[0])
        else:
            st = self.wam.true_state()
            start = (st.q, st.qdot)
        check_motion(self.kin, t, Q, Qd, now_s=now, start=start)  # robot_models.motion_limits: the shared rule
        self.wam.command_trajectory(t, Q, Qd)
        self.cmd_id, self.mode = int(msg["id"]), "track"

    def hold(self, mode: str) -> None:
        """Stop where the arm gets to from now on: its (true) velocity ramps down to rest within the
        deceleration limits (``robot_models.motion_limits.stop_ramp``), then it holds that position."""
        st = self.wam.true_state()
        t, q, qd = stop_ramp(self.kin, self.wam.t_s, np.clip(st.q, self.kin.q_min, self.kin.q_max), st.qdot,
                             1.0 / self.wam.control_rate_hz)
        self.wam.command_trajectory(t, q, qd)
        self.mode = mode
