"""Motion safety of the robot link (docs/robot_link.md, "Motion safety"): one rule at both ends.

A table of hostile trajectories -- steps, teleports, 1 ms jitter, a joint limit approached at full speed, a
velocity step, a trajectory ending at speed, a qdot that does not fit its positions -- sent raw to
`rt2 robot serve --sim` in its own process (bypassing the client's check): each is answered ``error`` naming
the sample, the joint and the limit, and the simulated arm's ACTUAL motion (its true joints, ``--publish-truth``)
shows it never moved. The same table through ``WamClient`` is refused before anything is sent. Legitimate
trajectories (rest to rest; a hold at full speed) are executed, and the arm's true motion stays within the
velocity and acceleration limits, never reaches a hard stop, and a hold stops it without reversing.
"""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
import zmq

from harness.link import WamClient, protocol
from robot_models import WamKinematics
from robot_models.motion_limits import DEFAULT_RULE, MotionRule, check_motion, state_at, stop_ramp
from tests.harness.link.robot_link_util import BridgeProcess, STARVED_OK

DT = 0.002


@pytest.fixture(scope="module")
def kin():
    return WamKinematics.default()


def _smooth(q0, q1, t0, duration_s, dt=DT):
    """Rest-to-rest minimum-jerk move sampled every dt: t (N,), q (N, 7), qdot (N, 7)."""
    t = t0 + np.arange(0.0, duration_s + 1e-9, dt)
    s = (t - t0) / duration_s
    shape = 10 * s**3 - 15 * s**4 + 6 * s**5
    dshape = (30 * s**2 - 60 * s**3 + 30 * s**4) / duration_s
    dq = np.asarray(q1) - np.asarray(q0)
    return t, np.asarray(q0) + shape[:, None] * dq, dshape[:, None] * dq


def hostile(kin, q, t0):
    """name -> (t_s, q, qdot, what the refusal names), all starting from the arm at rest at ``q`` at robot time t0."""
    out = {}
    q_step = q.copy()
    q_step[0] += 2.0  # the reported case: joint_1 by 2 rad in 2 ms, qdot nil
    q_step = np.minimum(q_step, kin.q_max - 0.01)
    out["step"] = ([t0, t0 + 0.002, t0 + 0.5], np.stack([q, q_step, q_step]), None, "joint_1 velocity")
    far = q.copy()
    far[2] += 0.5  # a smooth trajectory that starts 0.5 rad away from the arm
    t, Q, Qd = _smooth(far, far + np.r_[0, 0, 0.1, 0, 0, 0, 0], t0, 0.5)
    out["teleport"] = (t, Q, Qd, "joint_3 starts")
    t, Q, _ = _smooth(q, q + np.r_[0, 0, 0, 0, 0.3, 0, 0], t0, 0.6)
    jitter = np.random.default_rng(0).uniform(-0.001, 0.001, t.shape)
    jitter[0] = jitter[-1] = 0.0
    tj = t + jitter  # 1 ms jitter on 2 ms stamps: still increasing, the positions of the unjittered times
    out["jitter_1ms"] = (tj, Q, None, "joint_5")
    # joint_1 toward its upper limit at full speed, stopping at the limit within one sample
    q_near = q.copy()
    q_near[0] = kin.q_max[0] - 0.3
    ramp_t = t0 + np.arange(0, 0.1 + 1e-9, DT)
    Q = np.repeat(q_near[None], ramp_t.size, 0)
    Q[:, 0] = np.minimum(q_near[0] + 3.2 * (ramp_t - t0), kin.q_max[0])
    out["limit_at_full_speed"] = (ramp_t, Q, None, "joint_1")
    lin_t = np.array([t0, t0 + 0.5])
    out["velocity_step"] = (lin_t, np.stack([q, q + np.r_[0.5, 0, 0, 0, 0, 0, 0]]), np.full((2, 7), 0.0) + np.r_[1.0, 0, 0, 0, 0, 0, 0],
                            "joint_1 starts at 1 rad/s")
    t, Q, Qd = _smooth(q, q + np.r_[0, 0.4, 0, 0, 0, 0, 0], t0, 0.6)
    cut = t.size // 2  # the second half cut off: it ends at full speed and the robot would hold the last sample
    out["ends_moving"] = (t[:cut], Q[:cut], Qd[:cut], "joint_2 ends moving")
    t = t0 + np.arange(0, 0.2, DT)
    Qd = np.zeros((t.size, 7))
    Qd[1:-1:2, 3] = 3.0  # positions at rest, qdot saying otherwise: the Hermite reference would wiggle
    out["qdot_not_the_positions"] = (t, np.repeat(q[None], t.size, 0), Qd, "joint_4")
    return out


def _raw_trajectory(address, rid, t, Q, Qd):
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    try:
        sock.send(protocol.encode("trajectory", id=rid, t_ns=np.round(np.asarray(t) * 1e9).astype(np.int64).tolist(),
                                  q=np.asarray(Q).tolist(), qdot=None if Qd is None else np.asarray(Qd).tolist()))
        assert sock.poll(5000), "no reply from the bridge"
        return msgpack.unpackb(sock.recv())
    finally:
        sock.close()


def _check_actual_motion(kin, q_true, what):
    """The simulated arm's true joints (n, 7) at 500 Hz: velocities and accelerations within the limits, no hard stop."""
    v = np.diff(q_true, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    assert (np.abs(v) <= kin.qdot_max * 1.001).all(), f"{what}: velocity {np.abs(v).max(0)} over {kin.qdot_max}"
    assert (np.abs(a) <= kin.qddot_max * 1.01).all(), f"{what}: acceleration {np.abs(a).max(0)} over {kin.qddot_max}"
    assert ((q_true > kin.q_min + 1e-6) & (q_true < kin.q_max - 1e-6)).all(), f"{what}: reached a hard stop"


# -- the rule itself -------------------------------------------------------------------------------
def test_the_rule_refuses_the_hostile_table_and_names_sample_joint_and_limit(kin):
    q = np.asarray(kin.q_home, float)
    for name, (t, Q, Qd, needle) in hostile(kin, q, 1.0).items():
        with pytest.raises(ValueError, match="sample") as info:
            check_motion(kin, np.asarray(t), Q, Qd, now_s=1.0, start=(q, np.zeros(7)))
        assert needle in str(info.value), (name, str(info.value))
        assert "limit" in str(info.value), (name, str(info.value))


def test_the_rule_accepts_smooth_moves_and_its_own_hold(kin):
    q = np.asarray(kin.q_home, float)
    t, Q, Qd = _smooth(q, q + np.r_[0.5, -0.3, 0.4, 0.3, 0.2, 0.3, 0.3], 1.0, 0.8)
    kin.check_q(Q)  # inside the joint limits
    check_motion(kin, t, Q, Qd, now_s=1.0, start=(q, np.zeros(7)))
    check_motion(kin, t, Q, None, now_s=1.0, start=(q, np.zeros(7)))  # the robot's spline through q alone
    mid = t.size // 2  # taken over half-way (the part before now ignored): from where that trajectory drives the arm
    check_motion(kin, t, Q, Qd, now_s=float(t[mid]) + 0.001, start=state_at(t, Q, float(t[mid]) + 0.001))
    th, Qh, Qdh = stop_ramp(kin, 2.0, Q[mid], Qd[mid], DT)  # a hold from the middle of the move
    assert np.allclose(Qdh[-1], 0.0) and th[-1] > th[0]
    check_motion(kin, th, Qh, Qdh, now_s=2.0, start=(Q[mid], Qd[mid]))
    decel = np.abs(np.diff(Qdh, axis=0) / DT)
    assert (decel <= DEFAULT_RULE.hold_decel_share * kin.qddot_max + 1e-9).all()


def test_a_trajectory_accepted_now_is_accepted_later(kin):
    """The bridge's clock is ahead of the client's: whatever ``now`` inside the trajectory, the executed part of
    an accepted trajectory is accepted (the segment holding ``now`` is checked whole, never cut into a sliver)."""
    q = np.asarray(kin.q_home, float)
    t, Q, Qd = _smooth(q, q + np.r_[0.5, -0.3, 0.4, 0.3, 0.2, 0.3, 0.3], 1.0, 0.8)
    rng = np.random.default_rng(0)
    for now in np.concatenate([t[:-1] + 1e-7, rng.uniform(t[0], t[-1], 200)]):
        for qdot in (Qd, None):
            check_motion(kin, t, Q, qdot, now_s=float(now), start=state_at(t, Q, float(now)))


def test_rule_options_are_validated():
    with pytest.raises(ValueError, match="MotionRule.tol"):
        MotionRule(tol=-1)
    with pytest.raises(ValueError, match="hold_decel_share"):
        MotionRule(hold_decel_share=0)


# -- against the bridge process: the simulated arm's actual motion -----------------------------------------
@pytest.fixture(scope="module")
def bridge():
    # the watchdog at 2 s, as STARVED_OK's link limits: a client starved of CPU for 0.3 s under the parallel suite sent no
    # heartbeat while its legitimate move waited to start, the bridge held the arm and the move never ran (the arm's
    # true joints all still); the watchdog has its own tests (test_robot_link.py)
    b = BridgeProcess("--seed", "5", "--publish-truth", "--watchdog", "2")
    yield b
    b.stop()


def test_hostile_trajectories_never_reach_the_arm(bridge, kin):
    with WamClient(bridge.address, kinematics=kin, heartbeat_s=None, **STARVED_OK) as listener:
        listener.advance_to(listener.t_s + 0.05)
        listener.take_sim_truth()
        q = listener.sim_true_q()
        t0 = listener.t_s + 0.2
        cases = hostile(kin, q, t0)
        for rid, (name, (t, Q, Qd, needle)) in enumerate(cases.items(), start=100):
            reply = _raw_trajectory(bridge.address, rid, t, Q, Qd)
            assert reply["type"] == "error" and reply["id"] == rid, (name, reply)
            assert needle in reply["reason"] and "sample" in reply["reason"] and "limit" in reply["reason"], \
                (name, reply["reason"])
        listener.advance_to(t0 + 0.8)
        _, q_true = listener.take_sim_truth()
        assert np.abs(q_true - q).max() < 1e-9  # the arm never moved
        assert listener._latest["cmd_id"] == -1 and listener.mode == "idle"
        rejected = [e for e in listener.events if e["event"] == "rejected"]
        assert len(rejected) == len(cases)


def test_the_client_refuses_the_same_table_before_sending(bridge, kin):
    with WamClient(bridge.address, kinematics=kin, **STARVED_OK) as wam:
        wam.advance_to(wam.t_s + 0.05)
        q = wam.read_state().q  # the client checks against the reported state (what it knows)
        t0 = wam.t_s + 0.2
        for name, (t, Q, Qd, needle) in hostile(kin, q, t0).items():
            with pytest.raises(ValueError, match="sample") as info:
                wam.command_trajectory(t, Q, Qd)
            assert needle in str(info.value), (name, str(info.value))
        wam.advance_to(wam.t_s + 0.1)
        assert not [e for e in wam.events if e["event"] == "rejected"]  # the robot never saw them


def test_a_smooth_move_and_a_hold_at_full_speed_stay_within_the_limits(bridge, kin):
    """Joint 1 at 0.84 x its velocity limit, then a hold at the peak: the arm follows the move and ramps
    down within its deceleration limit, without reversing (the old hold braked and sprang back)."""
    with WamClient(bridge.address, kinematics=kin, **STARVED_OK) as wam:
        move_and_hold_at_full_speed(wam, kin)


def move_and_hold_at_full_speed(wam, kin) -> None:
    """The first joint of any arm at 0.84 x its velocity limit, a hold at the peak, the arm's true motion checked."""
    wam.advance_to(wam.t_s + 0.05)
    wam.take_sim_truth()
    q = wam.read_state().q
    stroke = 0.84 * kin.qdot_max[0] * 1.4 / 1.875  # the WAM: 2.0 rad
    target = q.copy()
    target[0] -= stroke
    # far enough ahead for a loaded machine: the bridge's clock runs on, and a trajectory whose start has passed when it
    # is judged no longer starts at the arm (refused: no teleports; 0.1 s ahead was too little under a parallel suite)
    t0 = wam.t_s + 1.0
    t, Q, Qd = _smooth(q, target, t0, 1.4)  # min-jerk: peak 1.875 x stroke / 1.4 (the WAM: 2.7 rad/s, 5.9 rad/s^2)
    wam.command_trajectory(t, Q, Qd)
    wam.advance_to(t0 + 0.7)  # the peak speed
    wam.hold()
    wam.advance_to(t0 + 1.9)
    t_true, q_true = wam.take_sim_truth()
    moving = t_true >= t0 - 0.01
    _check_actual_motion(kin, q_true[moving], "move + hold")
    v1 = np.diff(q_true[moving, 0]) / DT
    assert v1.min() < -0.78 * kin.qdot_max[0]  # it did get to full speed (the WAM: 2.5 rad/s)
    # and stopped without reversing: the servo's lag springs back a little, more at a higher deceleration (the
    # WAM's 6.8 rad/s^2: under 0.02 rad/s), and never by 0.1 % of the stroke (the WAM: 0.43 mrad of 2 rad)
    assert v1.max() < 0.02 * max(1.0, kin.qddot_max[0] / 6.8)
    assert (np.clip(v1, 0.0, None) * DT).sum() < 1e-3 * stroke
    assert abs(v1[-1]) < 1e-3
