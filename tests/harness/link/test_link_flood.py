"""A peer cannot stall the bridge's control loop (docs/robot_link.md, "What a peer cannot do").

- ``protocol.decode_request`` (the bridge's intake) accepts and refuses what ``protocol.decode`` does, on a table
  of hostile frames, and gives up early on shapes no request has;
- ``RateLimit``: the first rejections of a second one by one, the rest counted per reason;
- under a flood of 64 frames of 4 MiB, 2000 small bad frames and 8 of 50 MB from one peer, a good client keeps
  its joint states, every bad frame is answered, the bridge's memory stays bounded and its log is rate-limited
  (``realtime``: run alone; the strict timing figures are ``rt2 bench link-flood``'s).
"""

from __future__ import annotations

import time

import msgpack
import numpy as np
import pytest

from harness.link import ProtocolError, protocol
from harness.common.ratelimit import RateLimit
from harness.link.flood import flood_frames, measure_flood
from tests.harness.link.robot_link_util import BridgeProcess

ROW = [0.1, 0.2, 0.3, 1.5, 0.0, 0.0, 0.0]
REQ = ("hello", "trajectory", "hold", "heartbeat", "clock")


def _traj(**over):
    msg = {"v": 1, "type": "trajectory", "id": 3, "t_ns": [0, 2_000_000, 4_000_000], "q": [ROW] * 3, "qdot": None}
    msg.update(over)
    return msgpack.packb(msg, use_bin_type=True)


HOSTILE = [
    b"", b"\xc1", b"\x93\x01\x02\x03", msgpack.packb([ROW] * 10), msgpack.packb({"v": 1}),
    _traj(), _traj(qdot=[ROW] * 3), _traj(q=[ROW, ROW]), _traj(q=[ROW, ROW, ROW[:6]]), _traj(q=[ROW, ROW, [True] * 7]),
    _traj(q=[ROW, ROW, ROW + [1.0]]), _traj(q=[ROW, ROW, [float("nan")] * 7]), _traj(q=[[ROW] * 3] * 3),
    _traj(q=[ROW, ROW, ["a"] * 7]), _traj(t_ns=[0, 1, [2]]), _traj(t_ns=[ROW, ROW, ROW]), _traj(extra={"a": 1}),
    _traj(q=[ROW, None, ROW]), _traj(q=[None, None, None]), _traj(t_ns=[0, 1, 2.5]),
    msgpack.packb({"v": 1, "type": "hold", "id": 2}), msgpack.packb({"v": 1, "type": "hello", "id": 1, "client": "x"}),
    msgpack.packb({"v": 1, "type": "state", "seq": 1, "t_ns": 0, "q": ROW, "qdot": ROW, "effort": None, "mode": "idle",
                   "cmd_id": 0, "sim": None}),
    msgpack.packb({"v": 1, "type": "trajectory", "id": 1, "t_ns": [0, 1], "q": [[ROW] * 7] * 2, "qdot": None}),
    # as many samples as joints: t_ns is a list of 7 numbers too (the intake once took it for a joint vector)
    _traj(t_ns=list(range(0, 14_000_000, 2_000_000)), q=[ROW] * 7), _traj(t_ns=list(range(7)), q=[ROW] * 7, qdot=[ROW] * 7),
    _traj(q=[[0] * 7, ROW, [1] * 7]), _traj(q=[[0] * 7] * 3), _traj(q=[[0] * 7] * 3, qdot=[ROW, [0] * 7, ROW]),
    _traj(t_ns=list(range(7)), q=[[0] * 7] * 7), _traj(t_ns=[0.0] * 7, q=[ROW] * 7),
    # another arm's vectors: 6 joints
    _traj(q=[ROW[:6]] * 3), _traj(t_ns=list(range(6)), q=[ROW[:6]] * 6),
]

#: a six-joint arm's session (a UR10): the same frames and its own
HOSTILE_6 = HOSTILE + [_traj(q=[ROW[:6]] * 3, qdot=[ROW[:6]] * 3), _traj(q=[ROW[:6], ROW[:6], ROW]),
                       _traj(t_ns=list(range(6)), q=[[0] * 6] * 6), _traj(q=[[0] * 6, ROW[:6], [1] * 6])]


@pytest.mark.parametrize("n_joints, frame", [(7, f) for f in HOSTILE] + [(6, f) for f in HOSTILE_6],
                         ids=[f"7-{i}" for i in range(len(HOSTILE))] + [f"6-{i}" for i in range(len(HOSTILE_6))])
def test_intake_decoding_accepts_and_refuses_what_decode_does(n_joints, frame):
    try:
        ref = protocol.decode(frame, expect=REQ, n_joints=n_joints)
    except ProtocolError:
        ref = None
    try:
        got = protocol.decode_request(frame, REQ, n_joints)
    except ProtocolError:
        got = None
    assert (ref is None) == (got is None), (ref, got)
    if ref is not None:
        for k, v in ref.items():
            assert np.array_equal(np.asarray(got[k], dtype=object if k == "type" else None), np.asarray(v)), k


def test_the_trajectories_of_every_arm_pass_the_intake():
    """A valid trajectory of n samples for an arm of n joints (each count 1..MAX_JOINTS) arrives whole."""
    for n in range(1, protocol.MAX_JOINTS + 1):
        for samples in sorted({2, max(n, 2), n + 1}):
            q = np.linspace(0.0, 1.0, samples * n).reshape(samples, n)
            t_ns = list(range(0, 2_000_000 * samples, 2_000_000))
            frame = protocol.encode("trajectory", n_joints=n, id=5, t_ns=t_ns, q=q.tolist(), qdot=None)
            got = protocol.decode_request(frame, REQ, n)
            assert got["t_ns"] == t_ns and np.array_equal(got["q"], q), (n, samples)
            assert protocol.decode(frame, REQ, n_joints=n)["t_ns"] == t_ns
            if n < protocol.MAX_JOINTS:
                with pytest.raises(ProtocolError, match=f"{n + 1}"):
                    protocol.decode(frame, REQ, n_joints=n + 1)


@pytest.mark.parametrize("n", [0, 17, -1, 7.0, True, None, "7"])
def test_a_bad_joint_count_is_refused_by_name(n):
    frame = protocol.encode("hold", id=1)
    with pytest.raises(ValueError, match="n_joints"):
        protocol.decode_request(frame, REQ, n)


def test_intake_decoding_gives_up_early_on_shapes_no_request_has():
    big, _ = flood_frames(1, 0, seed=0)
    assert len(big) == protocol.MAX_MESSAGE_BYTES
    nasty = msgpack.packb({"v": 1, "type": "trajectory", "q": [[0] * 200] * 20000})  # 4 MB of nested lists
    for frame in (big, nasty):
        t0 = time.perf_counter()
        with pytest.raises(ProtocolError):
            protocol.decode_request(frame, REQ, 7)
        if frame is nasty:
            assert time.perf_counter() - t0 < 0.05  # refused after two rows, not after 4 million numbers


def test_reject_log_counts_per_reason_beyond_its_burst():
    now = [0.0]
    rl = RateLimit(burst=3, period_s=1.0, clock=lambda: now[0])
    shown = [rl.note(f"trajectory {i}: sample {i}: joint_1 velocity {i}.5 rad/s") for i in range(10)]
    shown += [rl.note("not a msgpack message (ValueError: x)") for _ in range(5)]
    assert shown[:3] == [True] * 3 and not any(shown[3:])
    assert rl.summary() is None  # not a second yet
    now[0] = 1.5
    text = rl.summary()
    assert text.startswith("12 more messages rejected in 1.5 s") and "7 x trajectory N: sample N" in text
    assert "5 x not a msgpack message" in text and rl.total == 15
    assert rl.summary() is None and rl.note("x") is True  # a new second: shown again
    rl.note("y"), rl.note("z"), rl.note("w")  # the 4th of this second: counted
    now[0] = 3.0
    assert rl.note("v") is True  # a note in a new period keeps the last one's summary for summary()
    assert rl.summary().startswith("1 more messages rejected in 1.5 s: 1 x w")


def test_reject_log_flush_reports_what_the_last_period_counted():
    """At shutdown the bridge flushes the counts whose period has not passed (a stop right after a flood lost them)."""
    now = [0.0]
    rl = RateLimit(burst=2, period_s=1.0, clock=lambda: now[0])
    for i in range(6):
        rl.note(f"bad frame {i}")
    now[0] = 0.4
    assert rl.summary() is None  # the period is not over
    assert rl.flush().startswith("4 more messages rejected in 0.4 s: 4 x bad frame N")
    assert rl.flush() is None and rl.summary() is None  # reported once


@pytest.mark.realtime
def test_a_flooding_peer_does_not_cut_off_a_good_client():
    with BridgeProcess("--batch", "1") as bridge:
        res = measure_flood(bridge.address, bridge.ready["pid"], client_timeout_s=1.0)
        log = bridge.stop()
    assert res["replies"] == 64 + 2000  # every bad frame answered (the 50 MB ones refused unread)
    assert res["link_lost"] is None, res
    # tolerances from measurement on the shared 2-core machine (load ~20): rate 0.998, gaps up to ~200 ms;
    # rt2 bench link-flood gives the figures against the goals (>= 95 % of the rate, gaps <= 20 ms)
    assert res["rate_share"] >= 0.9 and res["max_gap_ms"] < 1000, res
    assert res["rss_peak_over_idle_mb"] <= 100, res
    assert len(log.splitlines()) < 300  # 2064 rejections, logged one by one only 10 a second
    assert "more messages rejected in" in log
