"""The robot side of the link for a WAM behind ROS ``wam_node``: :class:`RosBridge` (docs/robot_link.md, "ROS wam_node").

Runs under the **system Python** with Debian's ROS packages (rospy, sensor_msgs, std_srvs, genpy) and
python3-zmq / python3-msgpack / python3-numpy / python3-scipy / python3-yaml -- not in rt2's virtual
environment, and without Pinocchio, numba or OpenCV::

    python3 -m harness.link.bridge_ros --address tcp://127.0.0.1:7650 --ns /wam

What it does with ``wam_node``'s topics and services:

* ``<ns>/joint_states`` (``sensor_msgs/JointState``, ~250 Hz) -> one ``state`` per message, ``t_ns`` from its
  ``header.stamp`` on the robot clock (ROS time minus the ROS time at the bridge's start); joints picked by
  name (``--joint-names``, wam_node's ``wam_j1 .. wam_j7``) or, with no names, by order; ``velocity`` and
  ``effort`` when the message has them (else a backward difference of positions, and nil);
* ``trajectory`` -> checked (schema, joint and velocity limits of the robot configuration, times after the
  latest state, the motion-safety rule of ``robot_models.motion_limits``), then interpolated on the robot clock like the simulator's reference (cubic Hermite with
  ``qdot``, else a spline; replace from ``max(t0, now)``; hold ``q[-1]`` after the end) and streamed as one
  ``wam_msgs/RTJointPos`` on ``<ns>/jnt_pos_cmd`` per joint state received (the reference one state period
  ahead, ``rate_limits`` = the velocity limits), so ``wam_node``'s 0.3 s command timeout never fires while
  the harness commands;
* ``hold`` and the watchdog -> stop streaming and call ``<ns>/hold_joint_pos`` (``wam_srvs/Hold``, true);
* ``hello``, ``heartbeat``, ``clock`` (stamps on the same ROS clock) as every bridge (``bridge_core``).

ZeroMQ sockets are used by the main loop only: the rospy subscriber thread forwards each joint state
over an in-process socket.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import warnings

import numpy as np
import rosgraph
import rospy
import zmq
from sensor_msgs.msg import JointState as RosJointState

from robot_models.joint_reference import PiecewiseReference
from harness.link.bridge_core import BridgeCore, check_endpoint
from harness.link.ros_msgs import WamRosTypes, load_wam_types
from robot_models.limits import JointLimits
from robot_models.motion_limits import check_motion
from robot_models.robot_interface import check_joint_trajectory

__all__ = ["WAM_NODE_JOINTS", "RosBridge", "main"]

log = logging.getLogger("rt2.robot.link.bridge")
WAM_NODE_JOINTS = tuple(f"wam_j{i}" for i in range(1, 8))  #: the joint names wam_node publishes


class RosBridge(BridgeCore):
    """Serve the WAM behind ``wam_node`` at namespace ``ns`` over the robot link (see the module docstring).

    limits : :class:`robot_models.limits.JointLimits` (what commands are checked against; told in ``welcome``).
    types : the wam_node types (:func:`harness.link.ros_msgs.load_wam_types`).
    rate_hz : the joint-state rate told in ``welcome`` (wam_node: 250). joint_names : the names in the
    JointState messages, in the order of ``limits.joint_names``. rospy must be initialised (``rospy.init_node``).
    """

    def __init__(self, limits: JointLimits, types: WamRosTypes, *, bind: str = "tcp://127.0.0.1:7650",
                 state_bind: str | None = None, watchdog_s: float = 0.3, ns: str = "/wam", rate_hz: float = 250.0,
                 joint_names=WAM_NODE_JOINTS, context=None):
        if len(joint_names) != limits.n_joints:
            raise ValueError(f"joint_names must name {limits.n_joints} joints, got {list(joint_names)}")
        if not 1 <= float(rate_hz) <= 10000:
            raise ValueError(f"rate_hz must be in [1, 10000], got {rate_hz!r}")
        super().__init__(bind, state_bind, watchdog_s, context=context)
        self.limits, self.types, self.ns = limits, types, ns.rstrip("/") or ""
        self.rate_hz = float(rate_hz)
        self.joint_names = tuple(joint_names)
        self._lead_ns = int(round(1e9 / self.rate_hz))  # a command takes effect about one state period later
        self._rate_limits = [float(v) for v in limits.qdot_max]
        self._ref: PiecewiseReference | None = None  # the reference streamed while tracking; None: not streaming
        self._latest_t_ns: int | None = None
        self._latest_q: np.ndarray | None = None
        self._latest_qd: np.ndarray | None = None
        self._orders: dict[tuple, np.ndarray | None] = {}  # JointState.name -> indices of our joints (None: unusable)
        self.dropped = 0  #: joint states not forwarded (not after the previous, unusable names, non-finite)
        self.commands_sent = 0  #: RTJointPos messages published
        self.epoch_ns = rospy.Time.now().to_nsec()  # robot clock 0 = ROS time at the bridge's start
        self._inbox_address = f"inproc://rt2-ros-states-{self.bridge_id}"
        self._inbox = self._ctx.socket(zmq.PULL)
        self._inbox.bind(self._inbox_address)
        self._pushers: list = []
        self._pushers_lock = threading.Lock()
        self._local = threading.local()
        with warnings.catch_warnings():  # rospy warns about queue_size=None, which is wanted here:
            warnings.simplefilter("ignore")  # publishing is synchronous, so no command trails a hold_joint_pos call
            self._cmd_pub = rospy.Publisher(f"{self.ns}/jnt_pos_cmd", types.RTJointPos, queue_size=None,
                                            tcp_nodelay=True)
        self._hold_srv = rospy.ServiceProxy(f"{self.ns}/hold_joint_pos", types.Hold)
        self._sub = rospy.Subscriber(f"{self.ns}/joint_states", RosJointState, self._on_ros_state, queue_size=50,
                                     tcp_nodelay=True)

    # -- clock --------------------------------------------------------------------------------------
    def robot_ns(self) -> int:
        """The robot clock now, ns: ROS time (the clock of wam_node's stamps) minus the ROS time at the start."""
        return rospy.Time.now().to_nsec() - self.epoch_ns

    # -- joint states (rospy thread -> main loop) -----------------------------------------------------
    def _on_ros_state(self, msg) -> None:
        push = getattr(self._local, "push", None)
        if push is None:
            push = self._ctx.socket(zmq.PUSH)
            push.setsockopt(zmq.LINGER, 0)
            push.connect(self._inbox_address)
            with self._pushers_lock:
                self._pushers.append(push)
            self._local.push = push
        stamp = msg.header.stamp.to_nsec() or rospy.Time.now().to_nsec()  # an unstamped message: its receipt
        push.send_pyobj((stamp, tuple(msg.name), tuple(msg.position), tuple(msg.velocity), tuple(msg.effort)))

    def _order(self, names: tuple, n_values: int) -> np.ndarray | None:
        key = (names, n_values)
        if key not in self._orders:
            n = self.limits.n_joints
            if not names:
                idx = np.arange(n) if n_values == n else None
            elif len(names) == n_values and all(j in names for j in self.joint_names):
                idx = np.array([names.index(j) for j in self.joint_names])
            else:
                idx = None
            if idx is None:
                log.error("joint states with names %s and %d positions do not hold the joints %s; dropping them",
                          list(names), n_values, list(self.joint_names))
            self._orders[key] = idx
        return self._orders[key]

    def take_state(self, stamp_ns: int, names: tuple, position: tuple, velocity: tuple, effort: tuple) -> bool:
        """Forward one JointState (stamp on the ROS clock) as a ``state``, and stream the command it calls for."""
        idx = self._order(names, len(position))
        t_ns = int(stamp_ns) - self.epoch_ns
        if idx is None or (self._latest_t_ns is not None and t_ns <= self._latest_t_ns):
            self.dropped += 1
            if idx is not None:
                log.warning("dropped a joint state stamped %d ns, not after the previous %d ns", t_ns, self._latest_t_ns)
            return False
        q = np.asarray(position, float)[idx]
        if len(velocity) == len(position):
            qd = np.asarray(velocity, float)[idx]
        elif self._latest_q is not None:
            qd = (q - self._latest_q) / ((t_ns - self._latest_t_ns) * 1e-9)
        else:
            qd = np.zeros_like(q)
        eff = np.asarray(effort, float)[idx].tolist() if len(effort) == len(position) else None
        if not (np.isfinite(q).all() and np.isfinite(qd).all() and (eff is None or np.isfinite(eff).all())):
            self.dropped += 1
            log.warning("dropped a joint state with non-finite values at %d ns", t_ns)
            return False
        self._latest_t_ns, self._latest_q, self._latest_qd = t_ns, q, qd
        if self._ref is not None:
            q_ref = self._ref.evaluate(np.array([(t_ns + self._lead_ns) * 1e-9]))[0][0]
            self._cmd_pub.publish(self.types.RTJointPos(joints=q_ref.tolist(), rate_limits=self._rate_limits))
            self.commands_sent += 1
        self.publish_state(t_ns, q.tolist(), qd.tolist(), eff)
        return True

    def _drain_inbox(self) -> int:
        n = 0
        while self._inbox.poll(0):
            n += self.take_state(*self._inbox.recv_pyobj())
        return n

    # -- BridgeCore -------------------------------------------------------------------------------------
    def welcome_fields(self) -> dict:
        lim = self.limits
        return {"robot": f"WAM via ROS wam_node at {self.ns or '/'}", "joint_names": list(lim.joint_names),
                "control_rate_hz": self.rate_hz, "q_min": lim.q_min.tolist(), "q_max": lim.q_max.tolist(),
                "qdot_max": lim.qdot_max.tolist()}

    def apply_trajectory(self, msg: dict) -> None:
        if self._latest_q is None:
            raise ValueError(f"no joint state from {self.ns}/joint_states yet")
        now_s = self._latest_t_ns * 1e-9
        t_s = np.asarray(msg["t_ns"], dtype=np.int64) * 1e-9
        t, Q, Qd = check_joint_trajectory(self.limits, t_s, msg["q"], msg["qdot"], now_s=now_s)
        t_on = max(float(t[0]), now_s)
        if self._ref is not None:  # streaming: from where the reference drives the arm at the take-over
            q_ref, qd_ref, _ = self._ref.evaluate(np.array([t_on]))
            start = (q_ref[0], qd_ref[0])
        else:  # held by wam_node: from where it is
            start = (self._latest_q, self._latest_qd)
        check_motion(self.limits, t, Q, Qd, now_s=now_s, start=start)  # robot_models.motion_limits: the shared rule
        if self._ref is None:  # before t[0] the robot holds where it is
            self._ref = PiecewiseReference(np.clip(self._latest_q, self.limits.q_min, self.limits.q_max))
        self._ref.replace_from(t, Q, Qd, now_s)
        self.cmd_id, self.mode = int(msg["id"]), "track"

    def hold(self, mode: str) -> None:
        """Stop streaming and call ``hold_joint_pos(true)``; ValueError when the service fails (wam_node then
        holds on its own command timeout)."""
        self._ref = None
        self.mode = mode
        try:
            self._hold_srv(True)
        except (rospy.ServiceException, rospy.ROSException) as exc:
            raise ValueError(f"{self.ns}/hold_joint_pos failed ({exc}); wam_node holds after its command timeout") from None

    # -- loop ---------------------------------------------------------------------------------------------
    def wait_for_robot(self, timeout_s: float) -> None:
        """Wait for the first joint state and the hold service; ValueError naming what did not come."""
        deadline = rospy.get_time() + timeout_s
        while self._latest_q is None:
            left_ms = (deadline - rospy.get_time()) * 1000
            if left_ms <= 0 or rospy.is_shutdown():
                raise ValueError(f"no sensor_msgs/JointState with the joints {list(self.joint_names)} on "
                                 f"{self.ns}/joint_states within {timeout_s:g} s (is wam_node running? "
                                 f"ROS_MASTER_URI={os.environ.get('ROS_MASTER_URI', '')})")
            if self._inbox.poll(max(1, int(min(left_ms, 50)))):
                self._drain_inbox()
        try:
            rospy.wait_for_service(f"{self.ns}/hold_joint_pos", timeout=max(0.1, deadline - rospy.get_time()))
        except rospy.ROSException:
            raise ValueError(f"service {self.ns}/hold_joint_pos not offered within {timeout_s:g} s") from None

    def serve(self, duration_s: float | None = None) -> None:
        """Run until :meth:`stop`, ROS shutdown or ``duration_s``; holds the robot if it was tracking; closes the sockets."""
        end_ns = None if duration_s is None else self.robot_ns() + int(duration_s * 1e9)
        poller = zmq.Poller()
        poller.register(self.requests, zmq.POLLIN)
        poller.register(self._inbox, zmq.POLLIN)
        self.event("started", f"WAM via ROS wam_node at {self.ns or '/'}, bridge {self.bridge_id}, "
                              f"types {self.types.origin}")
        self.start_intake()
        try:
            while not self._stop and not rospy.is_shutdown() and (end_ns is None or self.robot_ns() < end_ns):
                ready = dict(poller.poll(timeout=20))
                if self._inbox in ready:
                    self._drain_inbox()
                self.serve_requests()  # what the intake thread validated, within a time budget
                self.watchdog()
        finally:
            if self.mode == "track":
                try:
                    self.hold("hold")
                except ValueError as exc:
                    log.error("stopping: %s", exc)
            self.event("stopping", "bridge shutting down")
            self.close()

    def close(self) -> None:
        self._sub.unregister()
        with self._pushers_lock:
            for sock in self._pushers:
                sock.close(linger=0)
        self._inbox.close(linger=0)
        super().close()


def _parse(argv):
    ap = argparse.ArgumentParser(prog="python3 -m harness.link.bridge_ros",
                                 description="The robot link's bridge for a WAM behind ROS wam_node (docs/robot_link.md).")
    ap.add_argument("--address", default="tcp://127.0.0.1:7650", help="command endpoint to bind (tcp://HOST:PORT, * = free port)")
    ap.add_argument("--state-address", default=None, help="state endpoint to bind (default: command port + 1)")
    ap.add_argument("--ns", default="/wam", help="wam_node's namespace (topics <ns>/joint_states, <ns>/jnt_pos_cmd)")
    ap.add_argument("--rate-hz", type=float, default=250.0, help="wam_node's joint-state rate (its PUBLISH_FREQ)")
    ap.add_argument("--watchdog", type=float, default=0.3, help="hold after this many s without a command or heartbeat")
    ap.add_argument("--joint-names", default=",".join(WAM_NODE_JOINTS),
                    help="the JointState names of joint_1..joint_7, comma-separated")
    ap.add_argument("--robot-config", default=None, help="robot YAML whose limits are checked (default data/robot/wam.yaml)")
    ap.add_argument("--definitions", default="auto",
                    help="wam_msgs/wam_srvs: auto (installed ones, else shipped), shipped, or a directory of definitions")
    ap.add_argument("--wait", type=float, default=10.0, help="s to wait for the ROS master, wam_node's states and services")
    ap.add_argument("--ready-json", action="store_true", help="print one JSON line (endpoints, pid, epoch) when serving")
    return ap.parse_args(argv)


def _configure_logging() -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    rt2 = logging.getLogger("rt2")
    rt2.handlers[:] = [handler]
    rt2.setLevel(logging.INFO)
    rt2.propagate = False  # rospy configures the root logger for its own files
    rt2.disabled = False
    logging.getLogger("rt2.robot.link.bridge").disabled = False


def main(argv=None) -> int:
    """Command line (module docstring); one-line errors and exit 2 for bad options or a missing robot."""
    args = _parse(argv)
    try:
        check_endpoint("--address", args.address)
        if args.state_address is not None:
            check_endpoint("--state-address", args.state_address)
        if not 0.01 <= args.watchdog <= 10:
            raise ValueError(f"--watchdog must be in [0.01, 10] s, got {args.watchdog}")
        if not 0 < args.wait <= 600:
            raise ValueError(f"--wait must be in (0, 600] s, got {args.wait}")
        joint_names = tuple(n.strip() for n in args.joint_names.split(","))
        limits = JointLimits.from_config(args.robot_config)
        if not rosgraph.is_master_online():
            raise ValueError(f"no ROS master at ROS_MASTER_URI={os.environ.get('ROS_MASTER_URI', '(unset)')}")
        types = load_wam_types(args.definitions)
        rospy.init_node("rt2_wam_bridge", anonymous=True, disable_signals=True)
        _configure_logging()
        bridge = RosBridge(limits, types, bind=args.address, state_bind=args.state_address, watchdog_s=args.watchdog,
                           ns=args.ns, rate_hz=args.rate_hz, joint_names=joint_names)
    except (ValueError, FileNotFoundError) as exc:
        print(f"bridge_ros: {exc}", file=sys.stderr)
        return 2
    try:
        bridge.wait_for_robot(args.wait)
    except ValueError as exc:
        bridge.close()
        print(f"bridge_ros: {exc}", file=sys.stderr)
        return 2
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: bridge.stop())
    log.info("serving %s (states %s) for wam_node at %s; types %s", bridge.command_endpoint, bridge.state_endpoint,
             args.ns, types.origin)
    if args.ready_json:
        print(json.dumps({"command": bridge.command_endpoint, "state": bridge.state_endpoint, "pid": os.getpid(),
                          "bridge_id": bridge.bridge_id, "epoch_ns": bridge.epoch_ns, "types": types.origin,
                          "rtjointpos_md5": types.RTJointPos._md5sum}), flush=True)
    bridge.serve()
    rospy.signal_shutdown("rt2 bridge stopped")
    log.info("stopped: %d states, %d commands to wam_node, %d requests refused, %d joint states dropped",
             bridge.seq, bridge.commands_sent, bridge.rejected, bridge.dropped)
    return 0


if __name__ == "__main__":
    sys.exit(main())
