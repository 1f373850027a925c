"""The robot link's ROS bridge (harness/link/bridge_ros.py) against a fake wam_node on a loopback roscore.

Needs Debian's ROS packages for the system Python (/usr/bin/python3: rospy, sensor_msgs, std_srvs, genpy, plus
python3-zmq, -msgpack, -numpy, -scipy, -yaml) and ``roscore`` on PATH; skipped with the reason otherwise.
One roscore on a free 127.0.0.1 port, tests/harness/link/fake_wam_node.py and the bridge run as their own process groups
for the module and are killed at its end, whatever happened; the harness side is the venv's WamClient.
"""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from harness.link import WamClient, protocol

ROOT = Path(__file__).resolve().parents[3]
SYSTEM_PYTHON = "/usr/bin/python3"
ROS_MODULES = "rospy, rosgraph, genpy, genmsg, sensor_msgs.msg, std_srvs.srv, zmq, msgpack, numpy, scipy, yaml"
#: the bridge's watchdog here: wam_node's 0.3 s would hold whenever the loaded test machine delays a heartbeat
WATCHDOG_S = 0.6
BARRETT_RTJOINTPOS_MD5 = "6db71b8c4d3c870c701b3f89e85b7a36"  # wam_msgs/RTJointPos as published by barrett-ros-pkg


def _ros_missing() -> str:
    if shutil.which("roscore") is None:
        return "roscore is not on PATH (Debian: apt-get install ros-core)"
    if not os.access(SYSTEM_PYTHON, os.X_OK):
        return f"{SYSTEM_PYTHON} not found"
    probe = subprocess.run([SYSTEM_PYTHON, "-c", f"import {ROS_MODULES}"], capture_output=True, text=True, timeout=60)
    if probe.returncode != 0:
        return (f"{SYSTEM_PYTHON} cannot import the ROS bridge's modules ({probe.stderr.strip().splitlines()[-1:]}); "
                "Debian: python3-rospy python3-sensor-msgs python3-std-srvs python3-genpy python3-zmq python3-msgpack "
                "python3-scipy python3-yaml")
    return ""


MISSING = _ros_missing()
pytestmark = pytest.mark.skipif(bool(MISSING), reason=MISSING or "ROS present")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ros_env(port: int, home: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME", "VIRTUAL_ENV")}
    env.update(ROS_MASTER_URI=f"http://127.0.0.1:{port}", ROS_IP="127.0.0.1", ROS_HOSTNAME="127.0.0.1",
               ROS_HOME=str(home), ROS_LOG_DIR=str(home / "log"), PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    return env


class Group:
    """Processes started in their own sessions (process groups); :meth:`stop_all` ends every group."""

    def __init__(self, env: dict, logdir: Path):
        self.env, self.logdir, self.procs = env, logdir, []

    def start(self, name: str, cmd: list[str], **kw) -> subprocess.Popen:
        err = open(self.logdir / f"{name}.err", "w")
        proc = subprocess.Popen(cmd, cwd=ROOT, env=self.env, stderr=err, start_new_session=True, text=True, **kw)
        self.procs.append((name, proc, err))
        return proc

    def log(self, name: str) -> str:
        return (self.logdir / f"{name}.err").read_text()

    def stop_all(self) -> None:
        for _, proc, _ in reversed(self.procs):
            try:
                os.killpg(proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        for _, proc, err in reversed(self.procs):
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pass
            try:  # the group may hold children (roscore: rosmaster, rosout) that outlive the leader
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait(timeout=10)
            err.close()


def _wait_port(port: int, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise RuntimeError(f"roscore did not listen on 127.0.0.1:{port} within {timeout_s} s")


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """roscore + fake wam_node + bridge; yields (ready line of the bridge, the fake's log path, the group)."""
    home = tmp_path_factory.mktemp("ros")
    port = _free_port()
    group = Group(_ros_env(port, home), home)
    try:
        group.start("roscore", ["roscore", "-p", str(port)], stdout=subprocess.DEVNULL)
        _wait_port(port, 30)
        fake_log = home / "fake_wam_node.log"
        group.start("fake", [SYSTEM_PYTHON, "tests/harness/link/fake_wam_node.py", "--ns", "/wam", "--log", str(fake_log)],
                    stdout=subprocess.DEVNULL)
        bridge = group.start("bridge", [SYSTEM_PYTHON, "-m", "harness.link.bridge_ros", "--address",
                                        "tcp://127.0.0.1:*", "--ns", "/wam", "--wait", "40", "--watchdog", str(WATCHDOG_S),
                                        "--ready-json"],
                             stdout=subprocess.PIPE)
        ready, _, _ = select.select([bridge.stdout], [], [], 60)
        line = bridge.stdout.readline() if ready else ""
        if not line:
            raise RuntimeError(f"the ROS bridge did not start:\n{group.log('bridge')[-2000:]}\n"
                               f"fake wam_node:\n{group.log('fake')[-1000:]}")
        yield json.loads(line), fake_log, group
    finally:
        group.stop_all()


def _client(address: str, **kw) -> WamClient:
    """A client with link-loss limits for a loaded 2-core machine, where roscore, the fake wam_node and the bridge
    (three Python processes) can each be kept from running for a few hundred ms."""
    return WamClient(address, timeout_s=2.0, request_timeout_s=2.0, **kw)


def _fake_lines(path: Path, after: float) -> list[str]:
    return [ln.split(" ", 1)[1] for ln in path.read_text().splitlines() if float(ln.split(" ", 1)[0]) >= after]


# -- smoke: the types and the stream --------------------------------------------------------------------------
def test_generated_types_are_barretts(lab):
    ready, _, _ = lab
    assert ready["rtjointpos_md5"] == BARRETT_RTJOINTPOS_MD5
    assert "generated from" in ready["types"] and ready["types"].endswith("ros_defs")


def test_states_stream_at_the_wam_node_rate(lab):
    ready, _, _ = lab
    with _client(ready["command"]) as wam:
        assert wam.robot_info["robot"] == "WAM via ROS wam_node at /wam"
        assert wam.control_rate_hz == 250.0 and wam.robot_info["watchdog_s"] == WATCHDOG_S
        t0 = wam.t_s
        wam.advance_to(t0)  # hands out the states buffered since the connection
        s = wam.advance_to(t0 + 1.0)
    dt = np.diff(s.t_s)
    assert (dt > 0).all()  # robot stamps, strictly increasing
    # ~250 states in 1 s, stamped when the fake publishes (as wam_node does): a loaded machine delays single
    # ticks and makes up for them, or skips ticks when 0.1 s late; it never adds any
    assert 120 < len(s) <= 252
    assert 0.0035 < (s.t_s[-1] - s.t_s[0]) / (len(s) - 1) < 0.0085
    assert np.isfinite(s.q).all() and s.q.shape[1] == 7


# -- commands ---------------------------------------------------------------------------------------------------
def test_trajectory_is_followed_by_the_arm(lab):
    ready, fake_log, _ = lab
    since = time.time()
    with _client(ready["command"]) as wam:
        q0 = wam.read_state().q
        q1 = q0.copy()
        q1[6] += 0.2 if q0[6] < 2.5 else -0.2
        t0 = wam.t_s + 0.1
        wam.command_trajectory([t0, t0 + 0.5], np.stack([q0, q1]), np.zeros((2, 7)))
        during = wam.advance_to(t0 + 0.5)
        after = wam.advance_to(t0 + 1.5)
        assert wam.mode == "track"
    assert np.abs(after.q[-1] - q1).max() < 0.005  # arrived and holds q[-1]
    inside = (during.t_s > t0) & (during.t_s < t0 + 0.5)
    s = (during.t_s[inside] - t0) / 0.5
    ref = q0[6] + (q1[6] - q0[6]) * (3 * s**2 - 2 * s**3)  # the cubic Hermite with zero end velocities
    err = np.abs(during.q[inside, 6] - ref)
    # the fake's 30 ms lag at <= 0.6 rad/s: ~0.02 rad; a starved fake or bridge may fall behind for a moment
    assert np.median(err) < 0.03 and err.max() < 0.1
    assert any(ln.startswith("mode rt (jnt_pos_cmd)") for ln in _fake_lines(fake_log, since))


def test_out_of_limits_command_is_refused_before_leaving_the_harness(lab):
    ready, _, _ = lab
    with _client(ready["command"]) as wam:
        q0 = wam.read_state().q
        bad = q0.copy()
        bad[3] = 3.9  # joint_4 beyond 3.1 rad
        t0 = wam.t_s + 0.1
        with pytest.raises(ValueError, match=r"joint_4 = 3.9 rad is outside its limits"):
            wam.command_trajectory([t0, t0 + 0.5], np.stack([q0, bad]))
        wam.advance_to(t0 + 0.3)
        assert not [e for e in wam.events if e["event"] == "rejected"]  # nothing reached the bridge
        # sent anyway (a client that skips the check): the bridge refuses it, the arm does not move
        sock = zmq.Context.instance().socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(ready["command"])
        try:
            t_ns = [int((wam.t_s + 0.1) * 1e9), int((wam.t_s + 0.6) * 1e9)]
            sock.send(protocol.encode("trajectory", id=77, t_ns=t_ns, q=[q0.tolist(), bad.tolist()], qdot=None))
            assert sock.poll(5000)
            reply = protocol.decode(sock.recv())
        finally:
            sock.close()
        assert reply["type"] == "error" and reply["id"] == 77
        assert "joint_4 = 3.9 rad is outside its limits [-0.9, 3.1] rad" in reply["reason"]
        s = wam.advance_to(wam.t_s + 0.7)
        assert np.abs(s.q - q0).max() < 0.005
        assert any(e["event"] == "rejected" and "trajectory 77" in e["reason"] for e in wam.events)


def test_watchdog_holds_when_the_client_goes_silent(lab):
    ready, fake_log, _ = lab
    since = time.time()
    with _client(ready["command"], heartbeat_s=None) as listener:  # sends no heartbeat: cannot keep it moving
        cmd = _client(ready["command"])
        q0 = cmd.read_state().q
        goal = q0.copy()
        goal[0] += 0.6 if q0[0] < 1.0 else -0.6
        t0 = cmd.t_s + 0.1
        cmd.command_trajectory([t0, t0 + 4.0], np.stack([q0, goal]), np.zeros((2, 7)))
        cmd.advance_to(t0 + 0.5)
        t_silent = cmd.t_s
        cmd.close()  # heartbeats stop, as when the commanding process dies
        s = listener.advance_to(t_silent + WATCHDOG_S + 1.2)
        held = [e for e in listener.events if e["event"] == "watchdog_hold"]
        assert listener.mode == "watchdog"
    assert len(held) == 1
    # WATCHDOG_S after the last heartbeat, which left up to one heartbeat period (0.1 s) before t_silent
    assert WATCHDOG_S - 0.11 < held[0]["t_ns"] * 1e-9 - t_silent < WATCHDOG_S + 1.0
    assert WATCHDOG_S <= float(re.search(r"for ([0-9.]+) s", held[0]["reason"]).group(1)) < WATCHDOG_S + 1.0
    assert abs(s.q[-1, 0] - q0[0]) < 0.35  # well short of the 0.6 rad goal (0.2 rad at t_silent + WATCHDOG_S)
    last = s.t_s > s.t_s[-1] - 0.3
    assert np.ptp(s.q[last, 0]) < 0.002  # and still
    assert "hold_joint_pos(True)" in _fake_lines(fake_log, since)


TAKE_STATE = """
import json, sys, time, zmq, rospy
from harness.link import protocol
from harness.link.bridge_ros import RosBridge
from harness.link.ros_msgs import DEFINITIONS_DIR, load_wam_types
from robot_models.limits import JointLimits
rospy.init_node("rt2_take_state_test", anonymous=True, disable_signals=True)
b = RosBridge(JointLimits.from_config(), load_wam_types("shipped"), bind="tcp://127.0.0.1:*", ns="/nowam")
sub = zmq.Context.instance().socket(zmq.SUB)
sub.setsockopt(zmq.SUBSCRIBE, b"")
sub.connect(b.state_endpoint)
time.sleep(0.5)  # the subscription reaches the PUB socket
e = b.epoch_ns
names = tuple(f"wam_j{i}" for i in (7, 6, 5, 4, 3, 2, 1))
q = tuple(i / 10 for i in range(7))
taken = [b.take_state(e + 10_000_000, names, q, (), ()),
         b.take_state(e + 14_000_000, names, tuple(x + 0.004 for x in q), (), ()),
         b.take_state(e + 14_000_000, names, q, (), ()),
         b.take_state(e + 18_000_000, ("a",) * 7, q, (), ()),
         b.take_state(e + 22_000_000, (), q, q, q),
         b.take_state(e + 26_000_000, names[:6], q[:6], (), ()),
         b.take_state(e + 30_000_000, (), q[:3] + (float("nan"),) + q[4:], (), ())]
states = []
while sub.poll(500):
    m = protocol.decode(sub.recv())
    if m["type"] == "state":
        states.append(m)
try:
    load_wam_types("/no/such/defs")
    bad = ""
except ValueError as exc:
    bad = str(exc)
print(json.dumps({"taken": taken, "dropped": b.dropped, "states": states, "bad_definitions": bad,
                  "dir_md5": load_wam_types(str(DEFINITIONS_DIR)).RTJointPos._md5sum}))
b.close()
"""


def test_joint_states_become_protocol_states(lab):
    """Names pick and order the joints; no velocity -> backward difference; stamps not after the last, unknown
    names, too few joints and NaN are dropped. Runs the bridge's conversion in a system-Python process."""
    _, _, group = lab
    run = subprocess.run([SYSTEM_PYTHON, "-c", TAKE_STATE], cwd=ROOT, env=group.env, capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["taken"] == [True, True, False, False, True, False, False] and out["dropped"] == 4
    s = out["states"]
    assert [m["t_ns"] for m in s] == [10_000_000, 14_000_000, 22_000_000]
    np.testing.assert_allclose(s[0]["q"], [0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0])  # by name: wam_j1 is the last
    np.testing.assert_allclose(s[0]["qdot"], 0.0)
    np.testing.assert_allclose(s[1]["qdot"], 1.0, rtol=1e-6)  # 0.004 rad in 4 ms
    assert s[0]["effort"] is None and s[0]["mode"] == "idle" and s[0]["cmd_id"] == -1
    np.testing.assert_allclose(s[2]["q"], [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6])  # no names: by order
    np.testing.assert_allclose(s[2]["effort"], s[2]["q"])
    assert [m["seq"] for m in s] == [1, 2, 3]
    assert "--definitions must be auto, shipped or a directory, got '/no/such/defs'" in out["bad_definitions"]
    assert out["dir_md5"] == BARRETT_RTJOINTPOS_MD5


# -- clock --------------------------------------------------------------------------------------------------------
def test_clock_estimate_finds_the_ros_clock(lab):
    ready, _, _ = lab
    with _client(ready["command"]) as wam:
        est = wam.sync_clock(32)
        latest_ns = wam.read_state().t_s * 1e9
        now_mono = time.monotonic_ns()
        # the robot clock is ROS time (the wall clock here) minus the bridge's epoch; the harness clock is monotonic
        truth_ns = time.time_ns() - time.monotonic_ns() - ready["epoch_ns"]
    assert abs(est.offset_ns - truth_ns) < est.uncertainty_ns + 1e6
    assert est.uncertainty_ns < 5e6
    delay_ms = (now_mono + est.offset_ns - latest_ns) / 1e6  # the latest state's age in harness time
    assert -1 < delay_ms < 200


# -- bad input -----------------------------------------------------------------------------------------------------
def test_without_a_ros_master_the_bridge_exits_2_with_one_line(tmp_path):
    env = _ros_env(_free_port(), tmp_path)
    run = subprocess.run([SYSTEM_PYTHON, "-m", "harness.link.bridge_ros", "--address", "tcp://127.0.0.1:*"],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [f"bridge_ros: no ROS master at ROS_MASTER_URI={env['ROS_MASTER_URI']}"]


@pytest.mark.parametrize("args,message", [
    (["--address", "localhost:7650"], "--address must be a ZeroMQ endpoint like tcp://127.0.0.1:7650, got 'localhost:7650'"),
    (["--watchdog", "0"], "--watchdog must be in [0.01, 10] s, got 0.0"),
    (["--robot-config", "no/such.yaml"], "no/such.yaml"),
])
def test_bad_options_exit_2_with_one_line(tmp_path, args, message):
    run = subprocess.run([SYSTEM_PYTHON, "-m", "harness.link.bridge_ros", *args], cwd=ROOT,
                         env=_ros_env(_free_port(), tmp_path), capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], run.stderr
