"""The robot half of the accuracy experiment over the robot link: the same seeded motion, run by a robot
behind a bridge in real time, sampled at the camera frames through the clock-offset estimate.

:func:`harness.experiments.accuracy.motion.simulate_motion` runs the simulated WAM in process on one clock.
:func:`motion_over_link` commands the same seeded trajectory (same seeds, same pieces) to the robot at
``WamClient``, records its states, and builds the same :class:`RobotMotion`:

* the trajectory starts at robot time ``T0 + start_s`` (``T0`` a whole number of ticks ahead of the
  robot clock), so a simulated robot with the same seed runs it tick for tick as in process;
* frame ``k`` is exposed at robot time ``r_k = T0 + start_s + k / rate`` (the simulated lab: what the
  cameras see there, from the bridge's true joints, ``--publish-truth``); the camera stamps it on the
  harness clock, ``c_k = r_k - true_offset + clock error`` (the in-process model's camera clock error;
  ``true_offset``, the robot clock's true relation to the host's, is simulation truth from the bridge);
* the ground truth pairs the *reported* joints with ``c_k`` through the *estimated* robot clock offset
  (:func:`harness.link.clock.pair_joint_states`), as an experiment on a real robot must.

Times in the returned motion are shifted by ``-T0`` so they read as in process (``t_s = start_s + k /
rate``); ``info["link"]`` records the offset estimate, its error and ``T0``. ``q_command`` is the commanded
trajectory interpolated at the frames (the in-process run logs the simulator's clamped reference).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from harness.experiments.accuracy.motion import MotionOptions, RobotMotion, plan_motion, seed_streams
from harness.link.client import LinkLostError, WamClient
from harness.link.clock import ClockEstimate, pair_joint_states

__all__ = ["link_motion_source", "motion_over_link", "robot_seed_of"]

log = logging.getLogger(__name__)


def robot_seed_of(seed: int) -> int:
    """The simulated robot's seed :func:`simulate_motion` uses for session ``seed`` (``rt2 robot serve --seed``)."""
    return int(seed_streams(seed)[1].generate_state(1)[0])


def motion_over_link(wam: WamClient, n_frames: int, rate_hz: float, *, seed: int,
                     options: MotionOptions = MotionOptions(), clock: ClockEstimate | None = None,
                     lead_s: float = 0.3) -> RobotMotion:
    """Run the seeded accuracy motion on the robot behind ``wam`` (see the module docstring).

    The robot must be a simulated one serving its truth (``rt2 robot serve --sim --publish-truth``): the
    simulated cameras need the true joints and the true clock relation (``WamClient.sim_info``); the
    ground truth uses only reported joints and ``clock``, the offset estimate (default ``wam.clock.estimate()``).
    """
    kin = wam.kinematics
    sim = wam.sim_info()
    if not sim or "offset_ns" not in sim:
        raise ValueError(f"the robot at {wam.address} publishes no simulation truth: the accuracy experiment's simulated "
                         "cameras need it (serve it with `rt2 robot serve --sim --publish-truth`)")
    true_offset_ns = float(sim["offset_ns"])
    plan = plan_motion(kin, n_frames, rate_hz, seed=seed, options=options)  # the same as simulate_motion's
    t_frames, offset_s, jitter_s = plan.t_frames_s, plan.offset_s, plan.jitter_s
    t_cmd, q_cmd, qd_cmd, info = plan.t_cmd_s, plan.q_cmd, plan.qdot_cmd, plan.info
    dt = 1.0 / wam.control_rate_hz
    t0 = _command_ahead(wam, t_cmd + options.start_s, q_cmd, qd_cmd, lead_s)
    s = wam.advance_to(t0 + t_frames[-1] + abs(offset_s) + 0.05)
    held = [e for e in wam.events if e["event"] == "watchdog_hold" and e["t_ns"] * 1e-9 >= t0]
    if held:
        raise ValueError(f"the robot at {wam.address} stopped the motion: {held[0]['reason']} (this machine too "
                         "busy to send heartbeats in time?)")
    t_true, q_true_all = wam.take_sim_truth()
    if t_true.size < 2 or t_true[0] > t0 + t_frames[0] or t_true[-1] < t0 + t_frames[-1]:
        raise ValueError("the robot published no true joints over the motion; serve it with --publish-truth")
    est = wam.clock.estimate() if clock is None else clock
    truth = ClockEstimate(float(true_offset_ns), 0.0, 1, 0.0)
    r = t_frames + t0  # exposure instants, robot clock
    c_harness = (r * 1e9 - true_offset_ns) * 1e-9 + offset_s + jitter_s  # the cameras' stamps, harness clock
    h = 0.5 * dt

    def true_q(t_robot):
        return pair_joint_states((t_robot * 1e9 - true_offset_ns) * 1e-9, t_true, q_true_all, truth)

    qt = true_q(r)
    q_ref = np.stack([np.interp(r, t_cmd + options.start_s + t0, q_cmd[:, j]) for j in range(q_cmd.shape[1])], axis=1)
    qr = pair_joint_states(c_harness, s.t_s, s.q, est)
    qdr = pair_joint_states(c_harness, s.t_s, s.qdot, est)
    if np.isnan(qr).any():
        raise ValueError("a frame's stamp falls outside the recorded joint states (clock estimate off by > 50 ms?)")
    p_plus = kin.positions(true_q(r + h), check_limits=False)
    p_minus = kin.positions(true_q(r - h), check_limits=False)
    ball_true = kin.positions(qt, check_limits=False)
    gt_world = kin.positions(qr, check_limits=False)
    err_mm = np.linalg.norm(gt_world - ball_true, axis=1) * 1e3
    t_camera_robot = c_harness + est.offset_ns * 1e-9 - t0  # the stamps as the experiment maps them, robot clock - T0
    at_exposure = pair_joint_states((r * 1e9 - true_offset_ns) * 1e-9, s.t_s, s.q, truth)
    shift_mm = np.linalg.norm(gt_world - kin.positions(at_exposure, check_limits=False), axis=1) * 1e3
    speed = np.linalg.norm(p_plus - p_minus, axis=1) / (2 * h)
    info.update({
        "trajectory_seed": plan.trajectory_seed, "robot_seed": plan.robot_seed,
        "clock": {"offset_ms": round(offset_s * 1e3, 4), "jitter_std_ms": round(float(np.std(jitter_s)) * 1e3, 4),
                  "gt_shift_mm": {"median": round(float(np.median(shift_mm)), 4), "max": round(float(shift_mm.max()), 4)}},
        "ball_speed_mps": {"median": float(np.median(speed)), "max": float(np.max(speed))},
        "link": {"address": wam.address, "bridge_id": wam.bridge_id, "t0_robot_s": float(t0),
                 "robot_clock_estimate": est.to_dict(),
                 "estimate_error_ms": round((est.offset_ns - float(true_offset_ns)) / 1e6, 4)},
        "gt_vs_true_mm": {"median": float(np.median(err_mm)), "p99": float(np.percentile(err_mm, 99)),
                          "max": float(err_mm.max())},
    })
    return RobotMotion(
        t_s=t_frames, t_camera_s=t_camera_robot, q_true=qt, q_reported=qr, qdot_reported=qdr,
        q_command=q_ref, ball_true_world_m=ball_true, ball_velocity_world_mps=(p_plus - p_minus) / (2 * h),
        links_world_m=kin.link_points(qt, check_limits=False), gt_world_m=gt_world,
        T_base_to_world=np.array(kin.T_base_to_world), bias_rad=np.array(sim["bias_rad"], float), info=info,
    )


def _robot_now_s(wam: WamClient) -> float:
    """The robot's time now: the host clock through the offset estimate (the latest state received can lag on a busy
    host), never before that state."""
    try:
        est = wam.clock.estimate()
    except ValueError:  # no clock exchange yet
        return wam.t_s
    return max(wam.t_s, (time.monotonic_ns() + est.offset_ns) * 1e-9)


def _command_ahead(wam: WamClient, t_rel_s, q, qdot, lead_s: float, tries: int = 3) -> float:
    """Command the trajectory ``t_rel_s + T0`` with ``T0`` a whole number of ticks ``lead_s`` ahead of the robot
    clock, so that the robot takes it over before its first sample (as the in-process run does); returns ``T0``.

    A command that reaches the robot after its start is refused (the arm would have to jump to where the
    trajectory is by then) or taken over late: refused, it is sent again ahead of a fresh clock reading with twice
    the lead (``tries`` in all); taken over late, the run stops with ValueError (the arm moved on another path)."""
    dt = 1.0 / wam.control_rate_hz
    t_rel = np.asarray(t_rel_s, float)
    t_first = float(t_rel[0])
    for attempt in range(tries):
        lead = lead_s * 2 ** attempt
        t0 = float(np.ceil((_robot_now_s(wam) + lead) / dt) * dt)  # whole ticks: the robot samples as in process
        try:
            t_taken = wam.command_trajectory(t_rel + t0, q, qdot)
        except ValueError:
            if _robot_now_s(wam) <= t0 + t_first:
                raise  # refused for another reason than lateness
            log.warning("the motion reached the robot after its start (lead %.2f s); sending it again", lead)
            continue
        if t_taken > t0 + t_first + 0.5 * dt:
            raise ValueError(f"the robot at {wam.address} took the motion over {(t_taken - t0 - t_first) * 1e3:.0f} ms "
                             "after its start (this machine too busy?): the arm did not run the planned motion")
        return t0
    raise ValueError(f"the motion reached the robot at {wam.address} after its start {tries} times (the last time "
                     f"{lead:g} s ahead): this machine is too busy to command it")


def link_motion_source(address: str, *, state_timeout_s: float = 0.25):
    """``run_accuracy``'s ``motion_source`` for the robot at ``address``; ``"sim"`` starts ``rt2 robot serve --sim
    --publish-truth`` with the session's robot seed as a separate process for the run (and stops it after).
    state_timeout_s : no joint state for this long = link lost (:class:`harness.link.client.WamClient`'s ``timeout_s``)."""
    if not isinstance(address, str) or not (address == "sim" or address.startswith(("tcp://", "ipc://"))):
        raise ValueError(f"--robot must be a bridge address like tcp://127.0.0.1:7650 or 'sim', got {address!r}")

    def run_on(addr: str, kin, config) -> RobotMotion:
        try:
            wam = WamClient(addr, kinematics=kin, timeout_s=state_timeout_s)
        except LinkLostError as exc:  # no robot there: a bad address (exit 2)
            raise ValueError(f"robot link: {exc}") from None
        with wam:  # a link lost from here on is a failure at run time (LinkLostError: exit 1)
            wam.sync_clock(32)
            return motion_over_link(wam, config.n_frames, config.rate_hz, seed=config.seed, options=config.motion)

    def source(kin, config) -> RobotMotion:
        if address != "sim":
            return run_on(address, kin, config)
        from harness.link.spawn_bridge import SimBridgeProcess

        # --batch 5: the bridge wakes every 10 ms (same stamps, less CPU; the motion is commanded ahead of time)
        with SimBridgeProcess("--seed", str(robot_seed_of(config.seed)), "--publish-truth", "--batch", "5") as bridge:
            return run_on(bridge.address, kin, config)

    return source
