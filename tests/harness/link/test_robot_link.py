"""The robot link: protocol validation, WamClient against `rt2 robot serve --sim` in its own process
(real ZeroMQ sockets on 127.0.0.1, free ports), limits, malformed messages on both sides, the watchdog."""

from __future__ import annotations

import logging
import math
import subprocess
import sys
import threading
import time

import msgpack
import numpy as np
import pytest
import zmq

from harness.link import ProtocolError, WamClient, protocol
from robot_models import WamKinematics
from robot_models.robot_interface import JointSamples, WamInterface
from tests.harness.link.robot_link_util import ROOT, BridgeProcess, STARVED_OK

Q7 = [0.0, 0.1, 0.0, 1.5, 0.0, 0.0, 0.0]


# -- protocol ------------------------------------------------------------------------------------
def test_protocol_round_trip():
    frame = protocol.encode("trajectory", id=3, t_ns=[0, 2_000_000], q=[Q7, Q7], qdot=None)
    msg = protocol.decode(frame, expect=("trajectory",))
    assert msg == {"v": protocol.VERSION, "type": "trajectory", "id": 3, "t_ns": [0, 2_000_000], "q": [Q7, Q7],
                   "qdot": None}


@pytest.mark.parametrize("msg, match", [
    ({"v": 2, "type": "hold", "id": 1}, "version 2 not supported"),
    ({"v": 1, "type": "explode", "id": 1}, "unknown message type 'explode'"),
    ({"v": 1, "type": "hold"}, "missing field 'id'"),
    ({"v": 1, "type": "hold", "id": 1, "force": 9}, r"unknown field\(s\) \['force'\]"),
    ({"v": 1, "type": "hold", "id": True}, "id must be a 64-bit integer, got True"),
    ({"v": 1, "type": "trajectory", "id": 1, "t_ns": [0, 1], "q": [Q7, Q7[:6]], "qdot": None}, r"q\[1\] must be 7 finite"),
    ({"v": 1, "type": "trajectory", "id": 1, "t_ns": [0, 1], "q": [Q7, [float("nan")] * 7], "qdot": None}, "finite"),
    ({"v": 1, "type": "trajectory", "id": 1, "t_ns": [0, 1, 2], "q": [Q7, Q7], "qdot": None}, "q has 2 rows, t_ns has 3"),
    ({"v": 1, "type": "trajectory", "id": 1, "t_ns": [0], "q": [Q7], "qdot": None}, "2..20000 samples, got 1"),
    ({"v": 1, "type": "trajectory", "id": 1, "t_ns": [0.5, 1], "q": [Q7, Q7], "qdot": None}, "list of integers"),
    ({"v": 1, "type": "state", "seq": 1, "t_ns": 0, "q": Q7, "qdot": Q7, "effort": None, "mode": "dance",
      "cmd_id": 0, "sim": None}, "mode 'dance'"),
    ([1, 2, 3], "must be a map"),
])
def test_protocol_rejects_malformed(msg, match):
    with pytest.raises(ProtocolError, match=match):
        protocol.decode(msgpack.packb(msg))


def _valid_by_the_rule(value, kind):
    """The protocol's rule, element by element: a list of ints (kind 'ints'), or of rows of 7 finite ints or
    floats (kind 'mat'); bool is not a number."""
    def number(x, ints_only):
        if isinstance(x, bool) or not isinstance(x, int if ints_only else (int, float)):
            return False
        return -(1 << 63) <= x < (1 << 63) if ints_only else math.isfinite(x)

    if not isinstance(value, (list, tuple)):
        return False
    if kind == "ints":
        return all(number(x, True) for x in value)
    return all(isinstance(r, (list, tuple)) and len(r) == 7 and all(number(x, False) for x in r) for r in value)


_ROWS = [list(np.linspace(-1, 1, 7))] * 40


@pytest.mark.parametrize("kind, value", [
    ("mat", _ROWS), ("mat", [[0, 1, 2, 3, 4, 5, 6]] * 3), ("mat", [[0, 1.5, 2, 3, 4, 5, 6], (0.0,) * 7]),
    ("mat", _ROWS[:5] + [[True] + [0.0] * 6]), ("mat", [[True] * 7] * 2), ("mat", _ROWS[:3] + [[float("inf")] * 7]),
    ("mat", _ROWS[:3] + [["1.0"] + [0.0] * 6]), ("mat", _ROWS[:3] + [[None] * 7]), ("mat", _ROWS[:3] + [[0.0] * 6]),
    ("mat", _ROWS[:3] + [[[0.0]] * 7]), ("mat", [[2**70] + [0.0] * 6] * 2), ("mat", _ROWS[:3] + [[0.0] * 8]),
    ("mat", [np.float64(0.5)] * 7), ("mat", [[np.float64(0.5)] * 7] * 2), ("mat", []), ("mat", "not a matrix"),
    ("ints", list(range(0, 10**9, 10**6))), ("ints", [0, True, 2]), ("ints", [0, 1.5]), ("ints", [0, 2**63]),
    ("ints", [0, -(2**63)]), ("ints", [0, "1"]), ("ints", []),
])
def test_protocol_array_check_is_the_element_rule(kind, value):
    """Joint matrices and time lists are checked in one array conversion (a trajectory is ~10,000 numbers) and
    element by element only when that is unsure: the decision is always the element-by-element rule's."""
    expect = _valid_by_the_rule(value, kind)
    try:
        protocol._check_field("trajectory", "q", kind, value, 7)
        accepted = True
    except ProtocolError:
        accepted = False
    assert accepted == expect, value


def test_protocol_rejects_garbage_and_wrong_place():
    with pytest.raises(ProtocolError, match="not a msgpack message"):
        protocol.decode(b"\xc1\xff\x00garbage")
    with pytest.raises(ProtocolError, match="exceeds the limit"):
        protocol.decode(b"\x00" * (protocol.MAX_MESSAGE_BYTES + 1))
    with pytest.raises(ProtocolError, match="not expected here"):
        protocol.decode(protocol.encode("hold", id=1), expect=("state",))
    with pytest.raises(ProtocolError, match="mode"):  # a sender cannot emit what a receiver rejects
        protocol.encode("state", seq=1, t_ns=0, q=Q7, qdot=Q7, effort=None, mode="x", cmd_id=0, sim=None)


# -- against the bridge process ------------------------------------------------------------------
@pytest.fixture(scope="module")
def bridge():
    b = BridgeProcess("--seed", "3", "--publish-truth")
    yield b
    b.stop()


@pytest.fixture(scope="module")
def kin():
    return WamKinematics.default()


def test_client_is_a_wam_interface_streaming_at_the_robot_rate(bridge, kin):
    with WamClient(bridge.address, kinematics=kin, **STARVED_OK) as wam:
        assert isinstance(wam, WamInterface) and wam.control_rate_hz == 500.0 and wam.n_joints == 7
        t0 = wam.read_state().t_s
        s = wam.advance_to(t0 + 0.4)
        assert isinstance(s, JointSamples) and s.q.shape == (len(s), 7)
        s = wam.advance_to(t0 + 0.8)  # the second call: only ticks after the first call's time, none missing
        assert len(s) == 200 and s.t_s[0] == pytest.approx(t0 + 0.402, abs=1e-9)
        assert np.allclose(np.diff(s.t_s), 0.002) and s.t_s[-1] <= t0 + 0.8 + 1e-9
        assert wam.dropped == 0
        with pytest.raises(ValueError, match="not before the last one asked"):
            wam.advance_to(t0)


def test_command_moves_the_robot(bridge, kin):
    with WamClient(bridge.address, kinematics=kin, **STARVED_OK) as wam:
        st = wam.read_state()
        q_target = np.clip(st.q + 0.1, kin.q_min + 0.05, kin.q_max - 0.05)
        # rest to rest (qdot 0 at both samples: a cubic Hermite), as the motion-safety rule asks
        wam.command_trajectory([st.t_s + 0.05, st.t_s + 0.5], np.stack([st.q, q_target]), np.zeros((2, 7)))
        s = wam.advance_to(st.t_s + 1.2)
        assert wam.mode == "track"
        assert np.abs(wam.sim_true_q() - q_target).max() < 2e-3  # the simulator's truth: where the arm went
        # reported q = true q + a per-joint zero offset (0.2-0.5 deg std) + encoder noise
        assert np.abs(s.q[-1] - q_target).max() < np.deg2rad(1.5)
        assert np.abs(s.qdot[-1]).max() < 0.06  # at rest: the reported velocity's encoder noise is ~0.01 rad/s


def test_limits_refused_before_leaving_the_harness(bridge, kin):
    with WamClient(bridge.address, kinematics=kin, **STARVED_OK) as wam:
        st = wam.read_state()
        q_bad = st.q.copy()
        q_bad[3] = kin.q_max[3] + 0.2
        with pytest.raises(ValueError, match="q"):
            wam.command_trajectory([st.t_s + 0.1, st.t_s + 0.5], np.stack([st.q, q_bad]))
        with pytest.raises(ValueError, match="velocity limit"):
            wam.command_trajectory([st.t_s + 0.1, st.t_s + 0.5], np.stack([st.q, st.q]),
                                   np.full((2, 7), 50.0))
        wam.advance_to(wam.t_s + 0.1)
        assert not [e for e in wam.events if e["event"] == "rejected"]  # the robot never saw them


def _raw_request(address: str, frame: bytes) -> dict:
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    try:
        sock.send(frame)
        assert sock.poll(3000), "no reply from the bridge"
        return msgpack.unpackb(sock.recv())
    finally:
        sock.close()


def test_malformed_and_out_of_range_requests_are_rejected_never_applied(bridge, kin):
    with WamClient(bridge.address, kinematics=kin, heartbeat_s=None, **STARVED_OK) as listener:
        before = listener.read_state()
        cmd_before = listener._latest["cmd_id"]
        q_far = before.q.copy()
        q_far[1] = kin.q_max[1] + 0.5
        t_ns = int(before.t_s * 1e9)
        cases = [
            (b"\x93\x01\x02\x03", "a map"),
            (msgpack.packb({"v": 9, "type": "hold", "id": 1}), "version 9"),
            (msgpack.packb({"v": 1, "type": "trajectory", "id": 7, "t_ns": [t_ns + 10**8, t_ns + 5 * 10**8],
                            "q": [before.q.tolist(), [float("inf")] * 7], "qdot": None}), "finite"),
            (protocol.encode("trajectory", id=8, t_ns=[t_ns + 10**8, t_ns + 5 * 10**8],
                             q=[before.q.tolist(), q_far.tolist()], qdot=None), "trajectory 8: q"),
            (protocol.encode("trajectory", id=9, t_ns=[t_ns - 10**9, t_ns - 5 * 10**8],
                             q=[before.q.tolist(), before.q.tolist()], qdot=None), "not after the robot clock"),
        ]
        for (frame, match), rid in zip(cases, (None, 1, 7, 8, 9)):
            reply = _raw_request(bridge.address, frame)
            assert reply["type"] == "error" and match in reply["reason"] and reply["id"] == rid, reply
        listener.advance_to(listener.t_s + 0.2)
        assert listener._latest["cmd_id"] == cmd_before  # nothing applied
        rejected = [e["reason"] for e in listener.events if e["event"] == "rejected"]
        assert len(rejected) == len(cases)
        log = bridge.log_text()  # the robot side logged every reason
        assert "rejected: trajectory 8: q" in log and "rejected: protocol version 9" in log


def test_robot_holds_when_the_commanding_process_dies(bridge, kin):
    """A client process commands a slow 3 s movement and is killed; the watchdog holds 0.3 s after its last heartbeat."""
    script = (
        "import sys, time, numpy as np\n"
        "from harness.link import WamClient\n"
        f"w = WamClient({bridge.address!r}, **{STARVED_OK!r})\n"
        "s = w.read_state(); q1 = s.q.copy(); q1[0] += 0.6\n"
        "w.command_trajectory([s.t_s + 0.02, s.t_s + 3.0], np.stack([s.q, q1]), np.zeros((2, 7)))\n"
        "print('commanded', flush=True)\n"
        "time.sleep(30)\n")
    with WamClient(bridge.address, kinematics=kin, heartbeat_s=None, **STARVED_OK) as listener:
        proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE, text=True)
        try:
            assert proc.stdout.readline().strip() == "commanded"
            listener.advance_to(listener.t_s + 0.3)
            assert listener.mode == "track"
            q_moving = listener.read_state().q
            proc.kill()
            t_kill = listener.t_s
            proc.wait()
            s = listener.advance_to(t_kill + 0.8)
        finally:
            proc.kill()
        holds = [e for e in listener.events if e["event"] == "watchdog_hold"]
        # the last heartbeat left up to 0.1 s before the kill; the watchdog holds 0.3 s after it
        assert holds and 0.15 <= holds[-1]["t_ns"] * 1e-9 - t_kill <= 0.45, holds
        assert listener.mode == "watchdog"
        assert np.abs(s.q[-1, 0] - q_moving[0]) < 0.25  # stopped well short of the 0.6 rad goal
        assert np.abs(s.qdot[-1]).max() < 0.06


# -- the client side rejects malformed states -----------------------------------------------------
class FakeBridge(threading.Thread):
    """A robot on real sockets that answers like a bridge but streams some malformed states."""

    def __init__(self, bad_frames):
        super().__init__(daemon=True)
        ctx = zmq.Context.instance()
        self.router, self.pub = ctx.socket(zmq.ROUTER), ctx.socket(zmq.PUB)
        self.router.bind("tcp://127.0.0.1:*")
        self.pub.bind("tcp://127.0.0.1:*")
        self.address = self.router.getsockopt_string(zmq.LAST_ENDPOINT)
        self.bad_frames, self.stop = list(bad_frames), threading.Event()

    def run(self):
        k, seq, t0 = WamKinematics.default(), 0, time.monotonic_ns()
        first_heartbeat = None  # the client's SUB is connected by then: bad frames start 50 states later
        while not self.stop.is_set():
            while self.router.poll(0):
                ident, frame = self.router.recv_multipart()
                msg = protocol.decode(frame)
                now = time.monotonic_ns() - t0
                if msg["type"] == "hello":
                    reply = protocol.encode("welcome", id=msg["id"], robot="fake", bridge_id="fake",
                                            joint_names=list(k.joint_names), control_rate_hz=500.0,
                                            q_min=list(k.q_min), q_max=list(k.q_max), qdot_max=list(k.qdot_max),
                                            state_endpoint=self.pub.getsockopt_string(zmq.LAST_ENDPOINT),
                                            watchdog_s=0.3, t_ns=now)
                elif msg["type"] == "clock":
                    reply = protocol.encode("clock_reply", id=msg["id"], t0_ns=msg["t0_ns"], t1_ns=now, t2_ns=now)
                else:
                    if msg["type"] == "heartbeat" and first_heartbeat is None:
                        first_heartbeat = seq
                    reply = protocol.encode("ok", id=msg["id"], t_ns=now)
                self.router.send_multipart([ident, reply])
            seq += 1
            t_ns = seq * 2_000_000
            self.pub.send(protocol.encode("state", seq=seq, t_ns=t_ns, q=Q7, qdot=[0.0] * 7, effort=None,
                                          mode="idle", cmd_id=-1, sim=None))
            if first_heartbeat is not None and seq > first_heartbeat + 50 and self.bad_frames:
                self.pub.send(self.bad_frames.pop(0))
            time.sleep(0.002)
        self.router.close(0)
        self.pub.close(0)


def test_client_drops_malformed_states(caplog):
    bad = [msgpack.packb({"v": 1, "type": "state", "seq": 1, "t_ns": 10**12, "q": [float("nan")] * 7, "qdot": Q7,
                          "effort": None, "mode": "idle", "cmd_id": -1, "sim": None}),
           msgpack.packb({"v": 0, "type": "state"}), b"\xff\xfe",
           protocol.encode("state", seq=1, t_ns=2_000_000, q=[0.0, 0.1, 0.0, 1.4, 0.0, 0.0, 0.0], qdot=Q7, effort=None, mode="idle",
                           cmd_id=-1, sim=None),  # valid, but older than what came before
           protocol.encode("state", seq=1, t_ns=10**13, q=[0.0, 0.1, 0.0, 9.0, 0.0, 0.0, 0.0], qdot=Q7, effort=None,
                           mode="idle", cmd_id=-1, sim=None),  # joint_4 far beyond its limit
           protocol.encode("state", seq=1, t_ns=10**13, q=Q7, qdot=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 500.0], effort=None,
                           mode="idle", cmd_id=-1, sim=None)]
    fake = FakeBridge(bad)
    fake.start()
    try:
        with caplog.at_level(logging.WARNING, logger="rt2.robot.link.client"):
            with WamClient(fake.address) as wam:
                s = wam.advance_to(wam.t_s + 0.4)
                assert np.isfinite(s.q).all() and np.allclose(s.q, Q7) and (np.diff(s.t_s) > 0).all()
                assert wam.dropped == 6
        text = caplog.text
        assert "finite" in text and "version 0" in text and "not a msgpack" in text and "not after the previous" in text
        assert "joint_4 = 9 rad is outside its limits" in text and "joint_7 = 500 rad/s exceeds" in text
    finally:
        fake.stop.set()
        fake.join(5)


# -- rt2 robot check --------------------------------------------------------------------------------
def test_robot_check_measures_the_link(bridge, tmp_path):
    from harness.cli import main
    from harness.cli.robot_check import check_link

    r = check_link(bridge.address, duration_s=1.0, move_rad=0.05)
    assert r["control_rate_hz"] == 500.0 and r["states_lost"] == 0 and r["dropped_malformed"] == 0
    assert r["state_rate_hz"] == pytest.approx(500.0, rel=0.01) and r["stamp_interval_ms"]["max"] == 2.0
    assert r["clock"]["uncertainty_ms"] < 1.0 and r["delivery_ms"]["p50"] < 20
    m = r["move"]
    assert 0 <= m["motion_onset_after_start_ms"] <= 30 and m["amplitude_rad"] == pytest.approx(0.05)
    assert main(["robot", "check", "--robot", "tcp://127.0.0.1:1", "--duration", "0.5"]) == 2  # nobody there


def test_robot_check_cli_bad_input(capsys):
    from harness.cli import main

    assert main(["robot", "check", "--move", "--move-rad", "2"]) == 2
    assert "--move-rad must be in (0, 0.2]" in capsys.readouterr().err
