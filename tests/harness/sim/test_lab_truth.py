"""The lab truth stream (harness/sim/lab_truth.py): message, publisher/subscriber, scene provider."""

import time

import msgpack
import numpy as np
import pytest

from harness.experiments.accuracy.truth_scene import LabTruthScene
from harness.sim.lab_truth import (TruthError, TruthPublisher, TruthSubscriber, decode_truth,
                                            encode_truth)

Q = np.linspace(-0.3, 0.3, 7)


def _wait(pred, timeout_s=10.0):
    t_end = time.monotonic() + timeout_s
    while not pred() and time.monotonic() < t_end:
        time.sleep(0.01)
    return pred()


def _publish_until_received(pub, sub, t0_ns, n, *, balls=()):
    """Publish n samples 2 ms apart from t0_ns, once the subscriber is connected (PUB/SUB loses what is sent
    before: one sample just before t0_ns is re-sent until it arrives)."""
    j = 0
    while sub.received == 0:
        j += 1
        pub.publish(t0_ns - 1_000_000 + j, Q, balls)
        time.sleep(0.02)
    for i in range(n):
        pub.publish(t0_ns + i * 2_000_000, Q + i * 0.01, balls)
    assert _wait(lambda: sub.latest_t_ns is not None and sub.latest_t_ns >= t0_ns + (n - 1) * 2_000_000)


def test_message_round_trip_and_version():
    s = decode_truth(encode_truth(123, Q, [[1, 2, 3]], seq=7))
    assert s.t_ns == 123 and s.seq == 7 and np.allclose(s.q, Q) and s.balls.shape == (1, 3)
    assert decode_truth(encode_truth(5, Q)).balls.shape == (0, 3)


@pytest.mark.parametrize("msg, match", [
    ({"v": 2, "t_ns": 1, "q": list(Q), "balls": [], "seq": 1}, "version 2"),
    ({"v": 1, "t_ns": 1, "q": list(Q) * 3, "balls": [], "seq": 1}, "1..16 finite angles"),
    ({"v": 1, "t_ns": 1, "q": [], "balls": [], "seq": 1}, "1..16 finite angles"),
    ({"v": 1, "t_ns": 1, "q": [list(Q)], "balls": [], "seq": 1}, "1..16 finite angles"),
    ({"v": 1, "t_ns": 1.5, "q": list(Q), "balls": [], "seq": 1}, "'t_ns' must be an integer"),
    ({"v": 1, "t_ns": 1, "q": list(Q), "balls": [[0, 0]], "seq": 1}, "balls"),
    ({"v": 1, "t_ns": 1, "q": list(Q), "seq": 1}, "exactly the fields"),
])
def test_malformed_messages_are_named(msg, match):
    with pytest.raises(TruthError, match=match):
        decode_truth(msgpack.packb(msg))
    with pytest.raises(TruthError, match="not msgpack"):
        decode_truth(b"\xc1")


def test_subscriber_interpolates_joints_and_keeps_balls():
    with TruthPublisher("tcp://127.0.0.1:*") as pub, TruthSubscriber(pub.address) as sub:
        t0 = 10_000_000_000
        _publish_until_received(pub, sub, t0, 5, balls=[[0.0, 0.5, 1.0]])
        s = sub.at(t0 + 3_000_000, wait_s=1.0)  # halfway between samples 1 and 2
        assert np.allclose(s.q, Q + 0.015)
        assert np.allclose(s.balls, [[0.0, 0.5, 1.0]])
        assert np.allclose(sub.at(t0, wait_s=0.0).q, Q)
        with pytest.raises(TruthError, match="behind the requested instant"):
            sub.at(t0 + 1_000_000_000, wait_s=0.05)  # nothing that late: a bounded wait, then a clear error
        with pytest.raises(TruthError, match="before the oldest sample"):
            sub.at(1, wait_s=0.0)
        assert sub.malformed == 0


def test_a_subscriber_keeps_only_its_arms_joint_count():
    """A six-joint arm's truth (a UR10 served by `rt2 robot serve --sim --robot ur10`) reaches a six-joint
    subscriber; a seven-joint one counts it malformed and says why."""
    with TruthPublisher("tcp://127.0.0.1:*") as pub, TruthSubscriber(pub.address, n_joints=6) as six, \
            TruthSubscriber(pub.address) as seven:
        t0 = 10_000_000_000
        q6 = Q[:6]
        for i in range(200):
            pub.publish(t0 + i * 2_000_000, q6 + 0.01 * i)
            if six.received >= 5 and seven.malformed >= 5:
                break
            time.sleep(0.01)
        assert six.received >= 5 and six.malformed == 0
        t = six.latest_t_ns  # a PUB/SUB subscriber may miss the first samples (it joins late): the newest it holds
        assert np.allclose(six.at(t, wait_s=0.0).q, q6 + 0.01 * ((t - t0) // 2_000_000))
        assert seven.received == 0 and seven.malformed >= 5
        assert "6 joints" in seven.last_error and "has 7" in seven.last_error
    for bad in (0, 17, 6.0, True, "7"):
        with pytest.raises(TruthError, match="n_joints"):
            TruthSubscriber("tcp://127.0.0.1:9", n_joints=bad)


def test_silent_stream_is_a_one_line_error():
    with TruthSubscriber("tcp://127.0.0.1:9") as sub:
        with pytest.raises(TruthError, match=r"tcp://127.0.0.1:9 sent nothing in 0.2 s"):
            sub.wait_first(0.2)
    with pytest.raises(TruthError, match="ZeroMQ endpoint"):
        TruthSubscriber("localhost:7652")


def test_scene_provider_puts_the_ball_on_the_true_end_effector():
    from robot_models import WamKinematics, load_robot_config

    kin = WamKinematics.from_config(load_robot_config())
    q = np.asarray(kin.q_home, float)
    with TruthPublisher("tcp://127.0.0.1:*") as pub:
        provider = LabTruthScene(pub.address, "accuracy-clean", seed=3, first_wait_s=10.0)
        provider._sub = TruthSubscriber(pub.address)
        t0, j = time.monotonic_ns(), 0
        while provider._sub.received == 0:
            j += 1
            pub.publish(t0 - 1_000_000 + j, q)
            time.sleep(0.02)
        for i in range(1, 50):
            pub.publish(t0 + i * 2_000_000, q)
        scene = provider((t0 + 40_000_000) * 1e-9, 4)
        provider.close()
    ball = kin.positions(q[None], check_limits=False)[0]
    assert len(scene.balls) == 1 and np.allclose(scene.balls[0].position_m, ball)
    assert np.allclose(scene.balls[0].velocity_mps, 0.0) and scene.frame_index == 4
    with pytest.raises(ValueError, match="unknown lab truth scene 'nope'"):
        LabTruthScene("tcp://127.0.0.1:9", "nope")


def test_the_simulated_bridge_publishes_its_true_joints_on_the_host_clock():
    """`rt2 robot serve --sim --truth-stream` (its own process, robot clock skewed by 5 ms): the lab truth at a host
    time equals the true joints the robot reports in its states (--publish-truth) at robot time host + offset."""
    from harness.link import WamClient
    from harness.link.spawn_bridge import SimBridgeProcess

    with SimBridgeProcess("--publish-truth", "--clock-skew-ms", "5", "--truth-stream", "tcp://127.0.0.1:*") as bridge:
        with TruthSubscriber(bridge.ready["truth"]) as sub, WamClient(bridge.address) as wam:
            sub.wait_first(20.0)
            q_cmd = wam.read_state().q + np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.2])
            t0 = wam.t_s + 0.1
            wam.command_trajectory([t0, t0 + 0.4], np.stack([wam.read_state().q, q_cmd]), np.zeros((2, 7)))  # it moves
            wam.advance_to(t0 + 0.3)
            t_robot, q_true = wam.take_sim_truth()
            offset_ns = wam.sim_info()["offset_ns"]
        assert offset_ns == bridge.ready["clock_skew_ns"] - bridge.ready["epoch_monotonic_ns"]
        # robot samples in the moving stretch, mapped to the host clock: the truth stream says the same joints
        pick = np.flatnonzero((t_robot > t0 + 0.05) & (t_robot < t0 + 0.25))[::10]
        assert pick.size >= 5
        assert q_true[pick[-1], 6] - q_true[pick[0], 6] > 0.01  # it moved
        for i in pick:
            t_host_ns = int(round(t_robot[i] * 1e9)) - offset_ns
            assert np.allclose(sub.at(t_host_ns, wait_s=1.0).q, q_true[i], atol=1e-9)


def test_sim_cameras_on_the_host_clock_stamp_the_exposure_and_arrive_later():
    """SimOptions(clock="host"): frame set k is exposed at origin + k / rate on the host clock, rendered from
    provider(t_exposure, k) only once that instant has passed, stamped with it, and arrives after it."""
    from harness.live.sources.sim import SimOptions, open_sim
    from harness.sim.render import Scene
    from tracker.rig_files import resolve_rig

    asked = []

    def provider(t_host_s, k):
        asked.append((t_host_s, k, time.monotonic()))
        return Scene()

    sources, feed = open_sim(resolve_rig("lab4_vga"), SimOptions(rate_hz=50.0, clock="host", duration_s=0.2,
                                                                 max_behind_s=60.0), scene_provider=provider)
    try:
        for s in sources:
            s.start()
        frames = []
        while not sources[0].exhausted and len(frames) < 10:
            f = sources[0].read(5.0)
            if f is not None:
                frames.append(f)
    finally:
        for s in sources:
            s.close()
    assert [f.frame_id for f in frames] == list(range(10))
    t_dev = np.array([f.t_device_s for f in frames])
    assert np.allclose(np.diff(t_dev), 0.02, atol=1e-9)  # the exposure grid
    assert all(f.t_host_s >= f.t_device_s for f in frames)  # arrives after its exposure
    assert all(called >= t for t, _, called in asked)  # never rendered before its exposure instant
    assert np.allclose([t for t, _, _ in asked[:10]], t_dev)
    with pytest.raises(ValueError, match="clock must be 'scene' or 'host'"):
        SimOptions(clock="camera")
