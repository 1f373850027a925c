"""The motion-safety rule per arm: the hostile table of tests/harness/link/test_motion_safety.py, scaled to each
shipped arm's joints and limits, is refused with the limits of both ends of the robot link (the harness's
``ArmKinematics`` and the bridges' ``JointLimits``, read from the same robot config), naming sample and joint;
a smooth move within the limits passes. The WAM's table runs against a live bridge process there, every other
arm's here (the UR10's session carries six-joint vectors), with a move and a hold at full speed."""

from __future__ import annotations

import numpy as np
import pytest

from robot_models import ArmKinematics
from robot_models.limits import JointLimits
from robot_models.motion_limits import check_motion
from tests.harness.link.test_motion_safety import DT, _smooth

ARMS = ("wam", "panda", "ur10", "xarm7")


def _arm(name):
    if name != "wam":
        pytest.importorskip("example_robot_data", reason="example-robot-data is not installed (pip install 'rt2[robots]')")
    return ArmKinematics.from_config(name), JointLimits.from_config(name)


def _unit(n, j, value):
    e = np.zeros(n)
    e[j] = value
    return e


def hostile_scaled(kin, q, t0):
    """name -> (t_s, q, qdot, the joint the refusal names, what it says), from the arm at rest at ``q``, at t0."""
    n, names = kin.n_joints, kin.joint_names
    out = {}
    q_step = np.minimum(q + _unit(n, 0, 2.0), kin.q_max - 0.01)  # joint 0 by up to 2 rad in 2 ms
    out["step"] = ([t0, t0 + 0.002, t0 + 0.5], np.stack([q, q_step, q_step]), None, names[0], "velocity")
    far = q + _unit(n, 2, 0.5)  # a smooth trajectory starting 0.5 rad away from the arm
    t, Q, Qd = _smooth(far, far + _unit(n, 2, 0.1), t0, 0.5)
    out["teleport"] = (t, Q, Qd, names[2], "starts")
    j = min(4, n - 1)
    t, Q, _ = _smooth(q, q + _unit(n, j, 0.3), t0, 0.6)
    jitter = np.random.default_rng(0).uniform(-0.001, 0.001, t.shape)
    jitter[0] = jitter[-1] = 0.0
    out["jitter_1ms"] = (t + jitter, Q, None, names[j], "")
    q_near = q.copy()  # joint 0 towards its upper limit at full speed, stopping at the limit within one sample
    q_near[0] = kin.q_max[0] - 0.3
    ramp_t = t0 + np.arange(0, 0.3 / kin.qdot_max[0] + 0.05, DT)
    Q = np.repeat(q_near[None], ramp_t.size, 0)
    Q[:, 0] = np.minimum(q_near[0] + kin.qdot_max[0] * (ramp_t - t0), kin.q_max[0])
    out["limit_at_full_speed"] = (ramp_t, Q, None, names[0], "")
    v_step = min(3.0 * kin.qddot_max[0] * 0.05, 0.9 * kin.qdot_max[0])  # past the start blend, within the limit
    lin_t = np.array([t0, t0 + 0.5])
    out["velocity_step"] = (lin_t, np.stack([q, q + _unit(n, 0, v_step * 0.5)]), np.stack([_unit(n, 0, v_step)] * 2),
                            names[0], "starts at")
    t, Q, Qd = _smooth(q, q + _unit(n, 1, 0.4), t0, 0.6)
    cut = t.size // 2  # cut half-way: it ends at full speed and the robot would hold the last sample
    out["ends_moving"] = (t[:cut], Q[:cut], Qd[:cut], names[1], "ends moving")
    t = t0 + np.arange(0, 0.2, DT)
    Qd = np.zeros((t.size, n))
    Qd[1:-1:2, 3] = 0.9 * kin.qdot_max[3]  # positions at rest, qdot saying otherwise
    out["qdot_not_the_positions"] = (t, np.repeat(q[None], t.size, 0), Qd, names[3], "")
    return out


@pytest.mark.parametrize("name", ARMS)
def test_each_end_refuses_the_scaled_hostile_table(name):
    kin, limits = _arm(name)
    q = np.asarray(kin.q_home, float)
    table = hostile_scaled(kin, q, 1.0)
    assert len(table) == 7
    for end in (kin, limits):
        for case, (t, Q, Qd, joint, says) in table.items():
            with pytest.raises(ValueError, match="sample") as info:
                check_motion(end, np.asarray(t), Q, Qd, now_s=1.0, start=(q, np.zeros(kin.n_joints)))
            text = str(info.value)
            assert joint in text and says in text and ("limit" in text or "starts" in text), (name, case, text)


@pytest.mark.parametrize("name", ARMS)
def test_each_end_accepts_a_smooth_move_within_the_limits(name):
    kin, limits = _arm(name)
    q = np.asarray(kin.q_home, float)
    target = np.clip(q + 0.2, kin.q_min + 0.05, kin.q_max - 0.05)
    duration = 1.2 * max(1.875 * np.abs(target - q).max() / kin.qdot_max.min(),
                         np.sqrt(5.78 * np.abs(target - q).max() / kin.qddot_max.min()), 0.3)
    t, Q, Qd = _smooth(q, target, 1.0, duration)
    for end in (kin, limits):
        check_motion(end, t, Q, Qd, now_s=1.0, start=(q, np.zeros(kin.n_joints)))
        check_motion(end, t, Q, None, now_s=1.0, start=(q, np.zeros(kin.n_joints)))


def test_an_arms_own_jerk_limits_are_used():
    import dataclasses

    kin, limits = _arm("panda")
    assert kin.qdddot_max is not None and np.array_equal(limits.qdddot_max, kin.qdddot_max)
    q = np.asarray(kin.q_home, float)
    t, Q, Qd = _smooth(q, q + _unit(7, 0, 0.2), 1.0, 0.6)  # peak jerk 60 x 0.2 / 0.6^3 = 56 rad/s^3
    check_motion(limits, t, Q, Qd, now_s=1.0, start=(q, np.zeros(7)))
    strict = dataclasses.replace(limits, qdddot_max=np.full(7, 20.0))  # an arm whose jerk limit is 20 rad/s^3
    with pytest.raises(ValueError, match=r"panda_joint1 jerk .* exceeds its limit 20"):
        check_motion(strict, t, Q, Qd, now_s=1.0, start=(q, np.zeros(7)))


# -- both ends over the link: the arm behind `rt2 robot serve --sim --robot X` in its own process -----------
@pytest.mark.parametrize("name", ["panda", "ur10", "xarm7"])
def test_the_bridge_and_the_client_of_another_arm_refuse_the_scaled_table(name):
    from harness.link import WamClient
    from tests.harness.link.robot_link_util import STARVED_OK, BridgeProcess
    from tests.harness.link.test_motion_safety import _raw_trajectory, move_and_hold_at_full_speed

    kin, _ = _arm(name)
    bridge = BridgeProcess("--robot", name, "--seed", "5", "--publish-truth", "--watchdog", "2")  # as test_motion_safety's bridge
    try:
        with WamClient(bridge.address, kinematics=kin, heartbeat_s=None, **STARVED_OK) as listener:
            assert listener.n_joints == kin.n_joints and listener.robot_info["joint_names"] == list(kin.joint_names)
            listener.advance_to(listener.t_s + 0.05)
            listener.take_sim_truth()
            q = listener.sim_true_q()
            t0 = listener.t_s + 20.0  # far enough ahead for a loaded machine: each case is judged before it starts
            cases = hostile_scaled(kin, q, t0)
            for rid, (case, (t, Q, Qd, joint, _)) in enumerate(cases.items(), start=100):
                reply = _raw_trajectory(bridge.address, rid, t, Q, Qd)  # past the client: the bridge's own check
                assert reply["type"] == "error" and joint in reply["reason"] and "sample" in reply["reason"], (case, reply)
                with pytest.raises(ValueError, match="sample"):
                    listener.command_trajectory(t, Q, Qd)  # the client's check, before sending
            listener.advance_to(listener.t_s + 0.3)
            _, q_true = listener.take_sim_truth()
            assert np.abs(q_true - q).max() < 1e-9  # the arm never moved
        with WamClient(bridge.address, kinematics=kin, **STARVED_OK) as arm:
            move_and_hold_at_full_speed(arm, kin)  # a legitimate move is executed; a hold ramps it down
    finally:
        bridge.stop()


def test_rt2_robot_check_of_a_ur10_and_a_client_of_another_arm(capsys):
    """`rt2 robot check --arm ur10 --move` measures a UR10's link (its last joint moves); a client whose
    kinematics are the WAM's is refused at the hello, naming both joint lists (`rt2 robot check` without
    --arm: one line, exit 2)."""
    _arm("ur10")
    from harness.cli import main
    from harness.link import WamClient
    from tests.harness.link.robot_link_util import BridgeProcess

    bridge = BridgeProcess("--robot", "ur10")
    try:
        with pytest.raises(ValueError, match=r"has joints \['shoulder_pan_joint'.*the kinematics \['joint_1'"):
            WamClient(bridge.address, kinematics=ArmKinematics.from_config("wam"))
        capsys.readouterr()
        assert main(["robot", "check", "--robot", bridge.address, "--arm", "ur10", "--move", "--duration", "0.5"]) == 0
        out = capsys.readouterr().out
        assert "rt2 simulated arm ur10" in out and "(wrist_3_joint, 0.050 rad" in out, out
        assert main(["robot", "check", "--robot", bridge.address, "--duration", "0.5"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "has joints ['shoulder_pan_joint'" in err, err
    finally:
        bridge.stop()
