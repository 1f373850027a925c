"""A fake ROS ``wam_node`` for tests/harness/link/test_ros_bridge.py: run with the system Python (rospy), repository root on PYTHONPATH.

    /usr/bin/python3 tests/harness/link/fake_wam_node.py --ns /wam --log FILE

Offers what the robot link's ROS bridge uses of barrett's ``wam_node``:

* ``<ns>/joint_states`` (``sensor_msgs/JointState``, names ``wam_j1 .. wam_j7``, position, velocity, effort)
  at ``--rate-hz`` (250), stamped with ROS time at each tick;
* ``<ns>/jnt_pos_cmd`` (``wam_msgs/RTJointPos``): a message of 7 joints and 7 rate limits switches to
  real-time position control -- the setpoint moves towards the commanded joints no faster than the rate
  limits, and the arm follows the setpoint as a first-order lag of ``--tau-s`` (0.03 s); no message for
  0.3 s (wam_node's command timeout) -> hold the present position;
* services ``<ns>/hold_joint_pos`` (``wam_srvs/Hold``: true holds the present position, false idles),
  ``<ns>/joint_move`` (``wam_srvs/JointMove``: move to 7 joints at 1 rad/s, then hold) and
  ``<ns>/go_home`` (``std_srvs/Empty``: the same to wam_node's ``jp_init``).

Every change of mode and every service call is written as one line to ``--log`` (the test reads it).
"""

from __future__ import annotations

import argparse
import threading
import time

import numpy as np
import rospy
from sensor_msgs.msg import JointState
from std_srvs.srv import Empty, EmptyResponse

from harness.link.ros_msgs import load_wam_types

JP_INIT = np.array([0.0, -1.967, 0.0, 2.5, 0.0, -0.5, 0.0])  # wam_node's start and go_init posture
COMMAND_TIMEOUT_S = 0.3
MOVE_RAD_S = 1.0


class FakeWam:
    def __init__(self, args, types):
        self.dt = 1.0 / args.rate_hz
        self.tau = args.tau_s
        self.q = JP_INIT.copy()
        self.qd = np.zeros(7)
        self.setpoint = self.q.copy()
        self.target = self.q.copy()
        self.rate = np.full(7, MOVE_RAD_S)
        self.mode = "idle"  # idle (gravity compensation), hold, rt (jnt_pos_cmd), move (joint_move / go_home)
        self.last_cmd = 0.0
        self.n_cmds = 0
        self.lock = threading.Lock()
        self.log = open(args.log, "a", buffering=1)
        self.types = types
        ns = args.ns.rstrip("/")
        self.pub = rospy.Publisher(f"{ns}/joint_states", JointState, queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(f"{ns}/jnt_pos_cmd", types.RTJointPos, self.on_cmd, queue_size=1, tcp_nodelay=True)
        rospy.Service(f"{ns}/hold_joint_pos", types.Hold, self.on_hold)
        rospy.Service(f"{ns}/joint_move", types.JointMove, self.on_move)
        rospy.Service(f"{ns}/go_home", Empty, self.on_home)

    def note(self, text: str) -> None:
        self.log.write(f"{time.time():.6f} {text}\n")

    def set_mode(self, mode: str, why: str) -> None:
        if mode != self.mode:
            self.note(f"mode {mode} ({why}) q={np.round(self.q, 4).tolist()}")
        self.mode = mode

    def on_cmd(self, msg) -> None:
        with self.lock:
            if len(msg.joints) != 7 or len(msg.rate_limits) != 7:
                self.note(f"jnt_pos_cmd ignored: {len(msg.joints)} joints, {len(msg.rate_limits)} rate limits")
                return
            if self.mode != "rt":
                self.setpoint = self.q.copy()
            self.target = np.array(msg.joints, float)
            self.rate = np.abs(np.array(msg.rate_limits, float))
            self.last_cmd = time.monotonic()
            self.n_cmds += 1
            self.set_mode("rt", "jnt_pos_cmd")

    def hold_here(self, why: str) -> None:
        self.setpoint = self.q.copy()
        self.target = self.q.copy()
        self.set_mode("hold", why)

    def on_hold(self, req):
        with self.lock:
            self.note(f"hold_joint_pos({bool(req.hold)})")
            if req.hold:
                self.hold_here("hold_joint_pos")
            else:
                self.set_mode("idle", "hold_joint_pos(false)")
        return self.types.Hold._response_class()

    def move_to(self, joints, why: str) -> None:
        self.setpoint = self.q.copy()
        self.target = np.array(joints, float)
        self.rate = np.full(7, MOVE_RAD_S)
        self.set_mode("move", why)

    def on_move(self, req):
        with self.lock:
            self.note(f"joint_move({list(req.joints)})")
            if len(req.joints) != 7:
                return None  # wam_node answers false: the caller gets a service error
            self.move_to(req.joints, "joint_move")
        return self.types.JointMove._response_class()

    def on_home(self, _req):
        with self.lock:
            self.note("go_home()")
            self.move_to(JP_INIT, "go_home")
        return EmptyResponse()

    def tick(self) -> None:
        with self.lock:
            if self.mode == "rt" and time.monotonic() - self.last_cmd > COMMAND_TIMEOUT_S:
                self.hold_here("jnt_pos_cmd timeout")
            if self.mode == "idle":
                self.qd[:] = 0.0
                return
            step = np.clip(self.target - self.setpoint, -self.rate * self.dt, self.rate * self.dt)
            self.setpoint += step
            if self.mode == "move" and np.allclose(self.setpoint, self.target):
                self.hold_here("joint_move done")
            self.qd = (self.setpoint - self.q) / self.tau
            self.q = self.q + self.qd * self.dt

    def run(self) -> None:
        names = [f"wam_j{i}" for i in range(1, 8)]
        next_t = time.monotonic()
        self.note("started")
        while not rospy.is_shutdown():
            self.tick()
            msg = JointState(name=names, position=self.q.tolist(), velocity=self.qd.tolist(),
                             effort=(0.5 * self.qd).tolist())
            msg.header.stamp = rospy.Time.now()
            self.pub.publish(msg)
            next_t += self.dt
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.1:  # far behind on a busy machine: skip ticks instead of bursting
                next_t = time.monotonic()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--ns", default="/wam")
    ap.add_argument("--rate-hz", type=float, default=250.0)
    ap.add_argument("--tau-s", type=float, default=0.03)
    ap.add_argument("--log", required=True)
    args = ap.parse_args()
    types = load_wam_types("shipped")
    rospy.init_node("wam_node", disable_signals=False)
    FakeWam(args, types).run()


if __name__ == "__main__":
    main()
