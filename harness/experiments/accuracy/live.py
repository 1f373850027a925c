"""The accuracy experiment on live streams: robot, cameras + tracker, and the experiment as three processes.

    rt2 accuracy --live --robot tcp://HOST:7650 --tracker-stream tcp://HOST:7661   # processes you started
    rt2 accuracy --live                                  # starts the simulated bridge and rt2 track itself

Processes and clocks (docs/accuracy.md, "Live"):

* the robot behind its bridge (``rt2 robot serve --sim --truth-stream ADDR``, or a lab's): joint states on
  the robot clock; the simulated bridge also publishes the lab truth stream (true joints on the host clock);
* ``rt2 track --source sim --truth-stream ADDR --scene accuracy``: each camera frame is exposed on the
  host clock, rendered from the robot's true pose at that instant, stamped with the exposure time and
  tracked; rt2's stream (:7661) carries each observation with its capture time, latency and candidates;
* this process (:func:`run_live_accuracy`): estimates the robot clock offset (NTP-style over the link),
  picks the experiment's first frame on the cameras' grid a little ahead, commands the session's seeded
  motion (:func:`harness.experiments.accuracy.motion.plan_motion`, the in-process run's) so that it starts at that
  frame, reads the observations of the next ``n_frames`` frame sets from the stream, pairs each capture
  time with the reported joint states through the clock estimate (the ground truth), and runs the
  in-process run's registration, statistics, figures and session log code on them.

The stream side (reading rt2's stream, the cameras' clocks, the latency budget) is :mod:`.live_stream`.

The log (``session.mcap``, kind ``accuracy``) has every observation, the candidates the estimator saw, the
ground truth per frame set, every joint state of the motion (``/robot/joint_states``, robot stamps mapped
to the host clock), and the clocks (metadata ``live``: the robot clock estimate with its uncertainty,
the cameras' offsets from frame stamps vs arrival) and the latency budget; ``rt2 reevaluate`` re-runs it.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from harness.experiments.accuracy.config import AccuracyConfig
from harness.experiments.accuracy.evaluate import TrackRecord, evaluate
from harness.experiments.accuracy.frames import FrameResult
from harness.experiments.accuracy.live_stream import (StreamSilent, TrackerStream, camera_offsets, candidates_from_message,
                                          latency_budget, motion_onset_ms, observation_from_message, wait_first)
from harness.experiments.accuracy.motion import RobotMotion, plan_motion
from harness.experiments.accuracy.session_scene import SCENES, SessionScene
from harness.experiments.accuracy.accuracy_log import AccuracyLogWriter
from harness.experiments.accuracy.rig_error import estimated_rig
from harness.common.outputs import check_output_dir
from tracker.rig_files import resolve_rig
from harness.link.clock import ClockEstimate, pair_joint_states
from harness.logs.codecs import to_json_value
from robot_models import WamKinematics, load_robot_config

__all__ = ["run_live_accuracy", "run_live_local", "scene_name"]


def scene_name(options) -> str:
    """The ``rt2 accuracy --scene`` name of a SceneOptions preset."""
    for name, preset in SCENES.items():
        if preset == options:
            return name
    raise ValueError("the live accuracy run needs one of the --scene presets " + str(sorted(SCENES)))


def run_live_accuracy(config: AccuracyConfig, out_dir, *, robot: str, tracker_stream: str, log: bool = True,
                      stream_timeout_s: float = 10.0, lead_s: float = 0.5, link_timeout_s: float = 1.0, status=print,
                      tracker_alive=None):
    """Run the experiment on live streams (module docstring); returns an :class:`~harness.experiments.accuracy.experiment.AccuracyResult`.

    robot : the bridge's command address; tracker_stream : rt2's stream of ``rt2 track`` (its tracker must be
    ``config.trackers[0]``, the only tracker); stream_timeout_s : how long a silent stream may be silent
    lead_s : the experiment's first frame is at least this far ahead of the command
    link_timeout_s : robot states silent this long = link lost (1 s: this process also parses the tracker
        stream, and a loaded machine can hold a thread back for a few hundred ms; the robot's own watchdog
        still holds it 0.3 s after the last heartbeat)
    tracker_alive : None, or a callable returning None while the tracker's process runs, else why it stopped
        (the one-command form: an exited ``rt2 track`` is reported at once, not after the stream timeout)
    """
    from harness.experiments.accuracy.experiment import AccuracyResult, _against_truth, write_outputs
    from harness.link.client import LinkLostError, WamClient

    _check_config(config)
    kind = config.trackers[0]
    # the cameras' clock error is real here (their own stamps), not the in-process model's
    config = config.idealised(calibration=False, clock=True)
    out = check_output_dir(out_dir, "--out")
    t_wall = time.perf_counter()
    rig = resolve_rig(config.rig)
    box = rig.workspace_m if rig.workspace_m is not None else config.motion.box_world_m
    tracker_rig, cal_error = estimated_rig(rig, config.calibration_error, seed=config.seed, workspace_m=box)
    kin = WamKinematics.from_config(load_robot_config())
    n, period = config.n_frames, 1.0 / config.rate_hz
    plan = plan_motion(kin, n, config.rate_hz, seed=config.seed, options=config.motion)
    stream = TrackerStream(tracker_stream, tracker_alive)
    try:
        m0, _ = wait_first(stream, stream_timeout_s)
        if m0["tracker"] != kind:
            raise ValueError(f"the tracker stream at {tracker_stream} runs tracker {m0['tracker']!r}, the experiment "
                             f"scores {kind!r} (--trackers)")
        if list(m0["cameras"]) != list(rig.names):
            raise ValueError(f"the tracker stream's cameras {m0['cameras']} are not rig {config.rig!r}'s {list(rig.names)}")
        switch = sys.getswitchinterval()
        sys.setswitchinterval(0.0005)  # the link's heartbeat and state threads never wait 5 ms for this one
        try:
            try:
                wam = WamClient(robot, kinematics=kin, timeout_s=link_timeout_s)
            except LinkLostError as exc:  # no robot there: a bad address (exit 2)
                raise ValueError(f"robot link: {exc}") from None
            with wam:  # a link lost from here on is a failure at run time (LinkLostError: exit 1)
                est = wam.sync_clock(32)
                status(f"robot at {robot}: clock offset {est.offset_ns / 1e6:+.3f} ms +- {est.uncertainty_ns / 1e6:.3f} ms")
                msgs, t_recv, h0, f0, t0_robot, command, s, truth = _run_motion(
                    wam, stream, plan, config, est, period, lead_s, stream_timeout_s, status)
                est = wam.clock.estimate()
        finally:
            sys.setswitchinterval(switch)
    finally:
        stream.close()
    # -- frames, ground truth -------------------------------------------------------------------------------
    by_k = {m["frame_id"] - f0: (m, t) for m, t in zip(msgs, t_recv)}
    ks = np.array(sorted(k for k in by_k if 0 <= k < n), int)
    status(f"received {ks.size} of {n} frame sets of the motion; the cameras were "
           f"{t_recv[-1] - msgs[-1]['t_s']:.1f} s behind real time at its last one")
    if ks.size < n // 2:
        raise ValueError(f"only {ks.size} of {n} frame sets of the motion came from the tracker stream: the cameras "
                         "skipped frames (run rt2 track with --max-behind large enough to render every frame)")
    c = h0 + np.arange(n) * period  # the frames' exposures, host clock (the cameras' grid)
    for k in ks:
        c[k] = by_k[k][0]["t_s"]
    qr = pair_joint_states(c, s.t_s, s.q, est)
    qdr = pair_joint_states(c, s.t_s, s.qdot, est)
    if np.isnan(qr).any():
        raise ValueError("a frame's capture time falls outside the recorded joint states (robot clock estimate off?)")
    t_rel = c - h0 + config.motion.start_s  # as in process: start_s + k / rate
    q_ref = np.stack([np.interp(c + est.offset_ns * 1e-9, plan.t_cmd_s + config.motion.start_s + t0_robot,
                                plan.q_cmd[:, j]) for j in range(plan.q_cmd.shape[1])], axis=1)
    gt_world = kin.positions(qr, check_limits=False)
    motion_info = dict(plan.info)
    if truth is not None:  # a simulated robot: where the ball really was (summary only)
        t_true, q_true_all, true_offset_ns = truth
        exact = ClockEstimate(float(true_offset_ns), 0.0, 1, 0.0)
        h = 0.5e-3
        qt = pair_joint_states(c, t_true, q_true_all, exact)
        p_plus = kin.positions(pair_joint_states(c + h, t_true, q_true_all, exact), check_limits=False)
        p_minus = kin.positions(pair_joint_states(c - h, t_true, q_true_all, exact), check_limits=False)
        ball_true, vel = kin.positions(qt, check_limits=False), (p_plus - p_minus) / (2 * h)
        err_mm = np.linalg.norm(gt_world - ball_true, axis=1) * 1e3
        motion_info["gt_vs_true_mm"] = {"median": float(np.median(err_mm)), "p99": float(np.percentile(err_mm, 99)),
                                        "max": float(err_mm.max())}
        motion_info["robot_clock_error_ms"] = round((est.offset_ns - true_offset_ns) / 1e6, 4)
    else:
        qt, ball_true, vel = qr, gt_world, np.zeros_like(gt_world)
        motion_info["gt_vs_true_mm"] = {"median": float("nan"), "p99": float("nan"), "max": float("nan")}
    speed = np.linalg.norm(vel, axis=1)
    motion_info["ball_speed_mps"] = {"median": float(np.median(speed)), "max": float(np.max(speed))}
    cams = [by_k[k][0] for k in ks]
    budget = latency_budget(cams, np.array([by_k[k][1] for k in ks]), command)
    camera_clock = camera_offsets(cams, rig.names)
    live = {"robot": robot, "tracker_stream": tracker_stream, "first_frame_id": int(f0), "t0_host_s": float(h0),
            "t0_robot_s": float(t0_robot), "frames_received": int(ks.size), "robot_clock_estimate": est.to_dict(),
            "camera_clock_offsets": camera_clock, "latency_budget": budget,
            "clock_note": "capture times are the cameras' exposure stamps on the host clock (CLOCK_MONOTONIC); joint "
                          "states are paired with them through the robot clock estimate (robot minus host)"}
    motion_info["live"] = live
    motion_info["clock"] = {"offset_ms": 0.0, "jitter_std_ms": 0.0, "gt_shift_mm": {"median": 0.0, "max": 0.0}}
    motion = RobotMotion(t_s=t_rel, t_camera_s=t_rel, q_true=qt, q_reported=qr, qdot_reported=qdr, q_command=q_ref,
                         ball_true_world_m=ball_true, ball_velocity_world_mps=vel,
                         links_world_m=kin.link_points(qt, check_limits=False), gt_world_m=gt_world,
                         T_base_to_world=np.array(kin.T_base_to_world), bias_rad=np.zeros(7), info=motion_info)
    # -- observations, scoring ------------------------------------------------------------------------------
    records = {kind: TrackRecord.empty(n)}
    from harness.experiments.accuracy.accuracy_log import candidates_per_camera

    k_cand = candidates_per_camera(kind)
    frames = []
    for k in ks:
        m = by_k[k][0]
        obs = replace(observation_from_message(m), t_s=float(t_rel[k]))  # the delivered stamp, as the robot's time
        records[kind].put(int(k), obs)
        frames.append(FrameResult(int(k), float(t_rel[k]), float(t_rel[k]), {kind: obs},
                                  {kind: candidates_from_message(m, len(rig), k_cand)}, None, ()))
    figures, errors = evaluate(config, records, motion.gt_world_m, np.ones(n, bool), motion.T_base_to_world, rig.names)
    timing = {"wall_s": round(time.perf_counter() - t_wall, 2),
              "latency_ms": {kind: budget["arrival_to_publish_ms"]}}
    events = SessionScene(kin.link_radii_m, motion.T_base_to_world[:3, 3], config.scene, seed=config.seed).events
    truth_fig = _against_truth(config, records, motion, figures) if truth is not None else {}
    result = AccuracyResult(config, figures["rows"], figures, errors, timing, motion.info, {},
                            scene_events=events.summary(float(t_rel[-1]), float(t_rel[0])), calibration_error=cal_error,
                            truth=truth_fig)
    write_outputs(result, out)
    if log:
        writer = AccuracyLogWriter(out / "session.mcap", config, tracker_rig, motion, kin, true_rig=rig,
                                   calibration_error=cal_error, log_images="none", overwrite=True)
        try:
            writer.writer.write_metadata("live", to_json_value(live, "live", lenient=True))
            # every joint state of the motion too (robot stamps on the host clock via the estimate), in time order
            t_state = s.t_s - est.offset_ns * 1e-9 - h0 + config.motion.start_s
            keep = np.flatnonzero(t_state >= 0)
            i = 0
            for fr in frames:
                while i < keep.size and t_state[keep[i]] <= fr.t_s:
                    j = keep[i]
                    writer.writer.write_ground_truth(float(t_state[j]), None, s.q[j], s.qdot[j])
                    i += 1
                writer.write_frame(fr)
            writer.finish(figures, extra={"timing": timing, "live": to_json_value(live, "live", lenient=True)})
        except BaseException as exc:
            writer.close(error=f"{type(exc).__name__}: {exc}")
            raise
        result.paths["log"] = out / "session.mcap"
    return result


def _check_config(config: AccuracyConfig) -> None:
    if not isinstance(config, AccuracyConfig):
        raise ValueError(f"config must be an AccuracyConfig, got {type(config).__name__}")
    if len(config.trackers) != 1 or config.trackers[0] == "rtblob":
        raise ValueError(f"the live accuracy run scores the one rt2 tracker of `rt2 track` (--trackers rt2 or "
                         f"rt2-paper), got --trackers {' '.join(config.trackers)}")
    if config.inject_faults:
        raise ValueError("--inject-faults is not available with --live (the cameras are another process)")
    if config.eps_px is not None:
        raise ValueError("--eps-px is not available with --live (rt2 track runs its tracker's default threshold)")
    scene_name(config.scene)


def _run_motion(wam, stream, plan, config, est, period, lead_s, timeout_s, status, lag_ok_s: float = 1.0):
    """Pick the first frame on the cameras' grid, command the motion to start there, collect its frame sets."""
    start_s = config.motion.start_s
    n = config.n_frames
    # the newest frame set (where the cameras' grid is), once the cameras are less than lag_ok_s behind real
    # time: a renderer slower than real time falls behind during the motion and must not reach its
    # --max-behind (where it skips to the present) before the motion's last frame
    t_give_up = time.monotonic() + timeout_s
    while True:
        got = stream.latest(timeout_s)
        if got is None:
            raise StreamSilent(f"the tracker stream at {stream.address} went silent for {timeout_s:g} s")
        latest, t_got = got
        lag = t_got - float(latest["t_s"])
        if lag < lag_ok_s:
            break
        if time.monotonic() > t_give_up:
            raise ValueError(f"the cameras behind {stream.address} stayed {lag:.1f} s or more behind real time for "
                             f"{timeout_s:g} s (the renderer cannot keep up on this machine)")
        time.sleep(0.05)
    dt = 1.0 / wam.control_rate_hz
    now = time.monotonic()
    m_ahead = math.ceil((now + lead_s - latest["t_s"]) / period)
    f0 = int(latest["frame_id"]) + m_ahead
    h0 = float(latest["t_s"]) + m_ahead * period  # host time of the experiment's frame 0
    t0_robot = round((h0 + est.offset_ns * 1e-9 - start_s) / dt) * dt  # whole ticks, as in process
    t_send = time.monotonic_ns()
    wam.command_trajectory(plan.t_cmd_s + start_s + t0_robot, plan.q_cmd, plan.qdot_cmd)
    ack_ms = (time.monotonic_ns() - t_send) / 1e6
    lead_ms = (t0_robot + start_s - wam.t_s) * 1e3
    status(f"motion commanded: frame 0 = camera frame {f0} at host {h0:.4f} s ({(h0 - now) * 1e3:.0f} ms ahead)")
    msgs, t_recv = [], []
    f_last = f0 + n - 1
    while True:
        got = stream.get(timeout_s)
        if got is None:
            raise StreamSilent(f"the tracker stream at {stream.address} went silent for {timeout_s:g} s during the motion "
                               f"(received up to frame {msgs[-1]['frame_id'] if msgs else 'none'} of {f0}..{f_last})")
        m, t = got
        if m["frame_id"] >= f0:
            msgs.append(m)
            t_recv.append(t)
        if m["frame_id"] >= f_last:
            break
    t_stop = t0_robot + start_s + (n - 1) * period + 0.05
    s = wam.advance_to(max(t_stop, wam.t_s))
    held = [e for e in wam.events if e["event"] == "watchdog_hold" and e["t_ns"] * 1e-9 >= t0_robot]
    if held:
        raise ValueError(f"the robot at {wam.address} stopped the motion: {held[0]['reason']}")
    sim = wam.sim_info()
    truth = None
    if sim and "offset_ns" in sim:
        t_true, q_true = wam.take_sim_truth()
        truth = (t_true, q_true, float(sim["offset_ns"]))
    command = {"command_ack_ms": round(ack_ms, 3), "lead_ms": round(lead_ms, 1),
               "motion_onset_after_start_ms": round(motion_onset_ms(s.t_s, s.q, t0_robot + start_s), 3)}
    return msgs, np.array(t_recv), h0, f0, t0_robot, command, s, truth


def run_live_local(config: AccuracyConfig, out_dir, *, log: bool = True, status=print, clock_skew_ms: float = 0.0,
                   start_timeout_s: float = 900.0):
    """``rt2 accuracy --live`` alone: start the simulated bridge (the session's robot seed, truth stream) and
    ``rt2 track --source sim --truth-stream`` (the trackers' estimated rig, the true lab rendered) as separate
    processes, run :func:`run_live_accuracy` against them, and stop both on the way out (also on errors and
    SIGINT). ``clock_skew_ms``: skew the robot's clock (tests of the clock estimate). The simulated robot's
    watchdog is 2 s here instead of 0.3 s: on a shared, loaded machine the three processes compete for the
    cores and a heartbeat thread can be held back longer than 0.3 s (a real robot keeps wam_node's 0.3 s)."""
    import yaml

    from harness.common.spawn import STOP_GRACE_S, stop_together
    from harness.live.spawn_track import TrackProcess
    from harness.experiments.accuracy.link_motion import robot_seed_of
    from harness.link.spawn_bridge import SimBridgeProcess

    _check_config(config)
    out = check_output_dir(out_dir, "--out")
    rig = resolve_rig(config.rig)
    box = rig.workspace_m if rig.workspace_m is not None else config.motion.box_world_m
    tracker_rig, _ = estimated_rig(rig, config.calibration_error, seed=config.seed, workspace_m=box)
    rig_file = Path(out) / "tracker_rig.yaml"
    rig_file.write_text(yaml.safe_dump(tracker_rig.to_dict(), sort_keys=False))
    scene = scene_name(config.scene)
    # the cameras may fall this far behind real time before they skip: the motion's frames rendered at >= 5 per
    # second after starting at most 1 s behind (run_live_accuracy waits for that)
    max_behind_s = max(10.0, config.n_frames / 5.0 + 2.0)
    status("starting the simulated robot bridge and rt2 track (separate processes)")
    with SimBridgeProcess("--seed", str(robot_seed_of(config.seed)), "--publish-truth", "--batch", "5",
                          "--truth-stream", "tcp://127.0.0.1:*", "--clock-skew-ms", str(clock_skew_ms),
                          "--watchdog", "2") as bridge:  # a simulated robot on a shared machine: see the docstring
        with TrackProcess("--source", "sim", "--truth-stream", bridge.ready["truth"], "--scene",
                          "accuracy" if scene == "default" else f"accuracy-{scene}", "--rig", str(rig_file),
                          "--sim-rig", str(config.rig), "--rate-hz", f"{config.rate_hz:g}", "--seed", str(config.seed),
                          "--tracker", config.trackers[0], "--max-behind", f"{max_behind_s:g}", "--status-period", "0",
                          # every frame set counts here, not its latency: a 0.25 s backlog, as before latency first
                          "--max-backlog", str(max(8, math.ceil(0.25 * config.rate_hz))),
                          timeout_s=start_timeout_s) as track:
            status(f"bridge {bridge.address} (truth {bridge.ready['truth']}, pid {bridge.ready['pid']}), rt2 track stream "
                   f"{track.streams['rt2']} (pid {track.ready['pid']})")
            def track_alive():
                if track.proc.poll() is None:
                    return None
                said = [ln for ln in track.log_text().strip().splitlines() if "error" in ln] or ["(no error printed)"]
                return f"rt2 track stopped (exit code {track.proc.returncode}): {said[-1]}"

            try:
                return run_live_accuracy(config, out, robot=bridge.address, tracker_stream=track.streams["rt2"],
                                         log=log, stream_timeout_s=start_timeout_s, status=status,
                                         tracker_alive=track_alive)
            finally:  # both at once (the `with`s would stop one after the other); after a signal within STOP_GRACE_S
                stop_together([track, bridge], STOP_GRACE_S if isinstance(sys.exc_info()[1], KeyboardInterrupt) else None)
