"""The robot side of the accuracy experiment: the simulated WAM moving the ball, sampled at the camera clock.

Paper Sec. 3.2 ("Evaluation on the Real Robot Platform"): a ball is fixed to the end effector, the arm
moves, and the kinematics of the joint angles the robot *reports* is the ground truth. Timing model:

* the commanded trajectory is a chain of seeded :func:`harness.sim.trajectories.random_via_trajectory`
  pieces (each starts where the previous one came to rest) moving the ``ball_mount`` frame through
  ``box_world_m``, long enough to cover every frame;
* the :class:`harness.sim.robot.SimulatedWam` runs it at 500 Hz (ticks ``j / 500`` s); the command starts
  at ``start_s`` and the first camera frame is taken at the same instant;
* the cameras expose frame ``k`` centred on ``t_k = start_s + k / rate_hz`` (robot clock); the frame set
  is delivered with the camera's timestamp ``t_camera_k = t_k + offset + jitter_k``: the camera clock
  mapped to the robot clock is off by a constant ``offset`` ~ N(0, ``clock_offset_std_s``) drawn per
  session and a per-frame ``jitter_k`` ~ N(0, ``clock_jitter_std_s``) (both 0: synchronised clocks);
* where the ball really is at ``t_k``: FK of the TRUE joint angles, linearly interpolated between the
  two ticks around ``t_k`` (the arm moves continuously); its velocity, for motion blur, is the central
  difference of that over +-1 ms;
* the ground truth the experiment uses: FK of the REPORTED joint angles (zero-offset bias, encoder
  quantisation and noise included), linearly interpolated to the frame's timestamp ``t_camera_k`` from
  the 500 Hz samples (``gt_sampling="interpolate"``, what an offline analysis of time-stamped logs
  does) or the last tick at or before it (``"hold"``, what a live loop reading the robot at frame
  arrival gets). A clock error thus moves the ground truth along the path by speed x error
  (0.4 m/s x 2 ms = 0.8 mm).

Ground truth is in the robot BASE frame (the camera world frame is what registration has to find);
:attr:`RobotMotion.gt_world_m` maps it into the world with the nominal mount, for logs and viewers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from harness.sim.robot.simulated_wam import SimulatedWam, SimWamOptions
from harness.sim.trajectories import BALL_BOX_WORLD_M, TrajectoryOptions, random_via_trajectory

__all__ = ["GT_SAMPLINGS", "MotionOptions", "MotionPlan", "RobotMotion", "plan_motion", "seed_streams", "simulate_motion", "world_to_base"]

GT_SAMPLINGS = ("interpolate", "hold")


@dataclass(frozen=True)
class MotionOptions:
    """Options of :func:`simulate_motion`.

    box_world_m : (2, 3) box the ball mount moves through, lab world, metres (the cameras' sweet spot)
    via_per_piece : via points per trajectory piece (pieces are chained until every frame is covered)
    speed_fraction, accel_fraction : share of the WAM's joint velocity / acceleration limits used
    start_s : robot time of the first frame and of the start of the command, seconds
    gt_sampling : "interpolate" or "hold" (see the module docstring)
    clock_offset_std_s, clock_jitter_std_s : camera-to-robot clock error, seconds: a constant offset
        drawn per session and a per-frame jitter (0, 0: synchronised clocks)
    """

    box_world_m: tuple = BALL_BOX_WORLD_M
    via_per_piece: int = 6
    speed_fraction: float = 0.4
    accel_fraction: float = 0.4
    start_s: float = 0.1
    gt_sampling: str = "interpolate"
    clock_offset_std_s: float = 0.002
    clock_jitter_std_s: float = 0.0003

    def __post_init__(self):
        box = np.asarray(self.box_world_m, float)
        if box.shape != (2, 3) or not np.isfinite(box).all() or (box[1] <= box[0]).any():
            raise ValueError(f"MotionOptions.box_world_m must be [[min x, y, z], [max x, y, z]] with min < max, got {self.box_world_m!r}")
        if isinstance(self.via_per_piece, bool) or not isinstance(self.via_per_piece, int) or self.via_per_piece < 1:
            raise ValueError(f"MotionOptions.via_per_piece must be an integer >= 1, got {self.via_per_piece!r}")
        for name in ("speed_fraction", "accel_fraction"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 < v <= 1):
                raise ValueError(f"MotionOptions.{name} must be in (0, 1], got {v!r}")
        if not (isinstance(self.start_s, (int, float)) and 0 <= self.start_s < 10):
            raise ValueError(f"MotionOptions.start_s must be in [0, 10) s, got {self.start_s!r}")
        for name in ("clock_offset_std_s", "clock_jitter_std_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= 0.05:
                raise ValueError(f"MotionOptions.{name} must be in [0, 0.05] s, got {v!r}")
        if self.gt_sampling not in GT_SAMPLINGS:
            raise ValueError(f"unknown MotionOptions.gt_sampling {self.gt_sampling!r}; valid: {list(GT_SAMPLINGS)}")


@dataclass(frozen=True)
class RobotMotion:
    """The robot at each camera frame (n frames, rows in frame order). Angles rad, lengths m.

    t_s : (n,) frame times (mid-exposure) on the robot clock
    t_camera_s : (n,) the frames' timestamps (camera clock mapped to the robot clock: t_s + clock error);
        the ground truth is sampled at these, and the frame sets are delivered with them
    q_true, q_reported, qdot_reported, q_command : (n, 7) true / reported / commanded joints at t_s
    ball_true_world_m : (n, 3) where the ball really is (FK of q_true), world
    ball_velocity_world_mps : (n, 3) its velocity, world
    links_world_m : (n, 9, 3) base, link_1..7, flange origins of the TRUE arm, world (for rendering)
    gt_world_m : (n, 3) ground truth: FK of the reported joints, world through the nominal mount
    T_base_to_world : (4, 4) the mount (in simulation the true one)
    bias_rad : (7,) the simulated zero-offset bias of this session
    info : trajectory facts (pieces, via points, method, peak velocity ratios)
    """

    t_s: np.ndarray
    t_camera_s: np.ndarray
    q_true: np.ndarray
    q_reported: np.ndarray
    qdot_reported: np.ndarray
    q_command: np.ndarray
    ball_true_world_m: np.ndarray
    ball_velocity_world_mps: np.ndarray
    links_world_m: np.ndarray
    gt_world_m: np.ndarray
    T_base_to_world: np.ndarray
    bias_rad: np.ndarray
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def gt_base_m(self) -> np.ndarray:
        """(n, 3) ground truth in the robot base frame (what registration maps into the camera world)."""
        return world_to_base(self.gt_world_m, self.T_base_to_world)


def world_to_base(X_world, T_base_to_world) -> np.ndarray:
    """X_world : (n, 3) world points -> (n, 3) in the base frame, ``R^T (X - t)``.

    Used by the live run and by re-evaluation on the logged world positions, so both get the same bits.
    """
    T = np.asarray(T_base_to_world, float)
    return (np.asarray(X_world, float) - T[:3, 3]) @ T[:3, :3]


def _chain_trajectory(kin, duration_s: float, options: MotionOptions, rng: np.random.Generator):
    """Concatenate seeded via-point pieces (each at rest at both ends) until ``duration_s`` is covered."""
    topt = TrajectoryOptions(n_via=options.via_per_piece, speed_fraction=options.speed_fraction,
                             accel_fraction=options.accel_fraction)
    t_parts, q_parts, qd_parts, infos = [], [], [], []
    q_start, t_end = kin.q_home, 0.0
    while t_end < duration_s:
        traj, info = random_via_trajectory(kin, options.box_world_m, q_start=q_start, options=topt, rng=rng)
        skip = 1 if t_parts else 0  # the piece starts where the previous one rests: drop the repeated sample
        t_parts.append(traj.t_s[skip:] + t_end)
        q_parts.append(traj.q[skip:])
        qd_parts.append(traj.qdot[skip:])
        infos.append(info)
        q_start, t_end = traj.q[-1], t_end + traj.t_s[-1]
    info = {
        "pieces": len(infos),
        "via_points": int(sum(len(i["via_world_m"]) for i in infos)),
        "methods": [i["method"] for i in infos],
        "peak_qdot_ratio": float(max(i["peak_qdot_ratio"] for i in infos)),
        "peak_qddot_ratio": float(max(i["peak_qddot_ratio"] for i in infos)),
        "duration_s": float(t_end),
    }
    return np.concatenate(t_parts), np.concatenate(q_parts), np.concatenate(qd_parts), info


@dataclass(frozen=True)
class MotionPlan:
    """What a seeded session commands and how its cameras stamp frames, before any robot runs it.

    t_frames_s : (n,) exposure instants (robot clock, from ``start_s``); offset_s : the session's camera clock
    offset; jitter_s : (n,) per-frame jitter (or 0.0); t_cmd_s, q_cmd, qdot_cmd : (m,), (m, 7), (m, 7) the
    commanded trajectory from 0; info : the trajectory's pieces; trajectory_seed, robot_seed : the streams' seeds.
    """

    t_frames_s: np.ndarray
    offset_s: float
    jitter_s: np.ndarray | float
    t_cmd_s: np.ndarray
    q_cmd: np.ndarray
    qdot_cmd: np.ndarray
    info: dict
    trajectory_seed: int
    robot_seed: int


def seed_streams(seed: int) -> tuple:
    """The independent streams of session ``seed``: (trajectory, robot, camera clock) ``SeedSequence`` s."""
    return tuple(np.random.SeedSequence([int(seed), 1]).spawn(3))


def plan_motion(kin, n_frames: int, rate_hz: float, *, seed: int, options: MotionOptions = MotionOptions()) -> MotionPlan:
    """The seeded trajectory and camera clock of session ``seed``: the same for the in-process WAM
    (:func:`simulate_motion`) and a robot over the link (:mod:`harness.experiments.accuracy.link_motion`)."""
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 2:
        raise ValueError(f"n_frames must be an integer >= 2, got {n_frames!r}")
    if not (isinstance(rate_hz, (int, float)) and 1.0 <= rate_hz <= 10000.0):
        raise ValueError(f"rate_hz must be a frame rate in [1, 10000] Hz, got {rate_hz!r}")
    if not isinstance(options, MotionOptions):
        raise ValueError(f"options must be MotionOptions, got {type(options).__name__}")
    traj_seq, robot_seq, clock_seq = seed_streams(seed)
    t_frames = options.start_s + np.arange(int(n_frames)) / float(rate_hz)
    clock_rng = np.random.default_rng(clock_seq)
    offset_s = float(clock_rng.normal(0.0, options.clock_offset_std_s)) if options.clock_offset_std_s > 0 else 0.0
    jitter_s = clock_rng.normal(0.0, options.clock_jitter_std_s, int(n_frames)) if options.clock_jitter_std_s > 0 else 0.0
    jitter_s = np.clip(jitter_s, -0.25 / rate_hz, 0.25 / rate_hz)  # timestamps stay increasing at any frame rate
    duration = t_frames[-1] - options.start_s + 0.01
    t_cmd, q_cmd, qd_cmd, info = _chain_trajectory(kin, duration, options, np.random.default_rng(traj_seq))
    return MotionPlan(t_frames, offset_s, jitter_s, t_cmd, q_cmd, qd_cmd, info,
                      int(traj_seq.generate_state(1)[0]), int(robot_seq.generate_state(1)[0]))


def _interp_rows(t_query: np.ndarray, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Linear interpolation of the rows of ``Y`` (m, d) sampled at increasing ``t`` (m,), vectorised."""
    j = np.clip(np.searchsorted(t, t_query, side="right") - 1, 0, len(t) - 2)
    w = ((t_query - t[j]) / (t[j + 1] - t[j]))[:, None]
    return Y[j] * (1.0 - w) + Y[j + 1] * w


def _hold_rows(t_query: np.ndarray, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """The last sample at or before each query time (zero-order hold)."""
    j = np.clip(np.searchsorted(t, t_query + 1e-12, side="right") - 1, 0, len(t) - 1)
    return Y[j]


def simulate_motion(kin, n_frames: int, rate_hz: float, *, seed: int, options: MotionOptions = MotionOptions(),
                    sim_options: SimWamOptions | None = None) -> RobotMotion:
    """Run the simulated WAM along a seeded trajectory and sample it at ``n_frames`` camera frames.

    kin : :class:`robot_models.WamKinematics` (with its mount); rate_hz : camera frame rate
    seed : seeds the trajectory and the robot's bias and noise (independent streams)
    sim_options : :class:`harness.sim.robot.SimWamOptions` (default: SimWamOptions())
    """
    plan = plan_motion(kin, n_frames, rate_hz, seed=seed, options=options)
    t_frames, offset_s, t_cmd, q_cmd, qd_cmd, info = (plan.t_frames_s, plan.offset_s, plan.t_cmd_s, plan.q_cmd,
                                                      plan.qdot_cmd, plan.info)
    t_camera = t_frames + offset_s + plan.jitter_s
    robot_seed = plan.robot_seed
    sim = SimulatedWam(kin, sim_options if sim_options is not None else SimWamOptions(), seed=robot_seed, q0=q_cmd[0])
    true0, rep0 = sim.true_state(), sim.read_state()
    sim.command_trajectory(t_cmd + options.start_s, q_cmd, qd_cmd)
    s = sim.advance_to(max(t_frames[-1], t_camera[-1]) + 3 * sim.dt_s)
    t = np.concatenate([[true0.t_s], s.t_s])
    q_true = np.vstack([true0.q[None], s.q_true])
    q_rep = np.vstack([rep0.q[None], s.q])
    qd_rep = np.vstack([rep0.qdot[None], s.qdot])
    q_ref = np.vstack([q_cmd[:1], s.q_ref])
    # the true arm between ticks: linear in q (2 ms ticks); the reported one as the options say
    qt = _interp_rows(t_frames, t, q_true)
    sample = _interp_rows if options.gt_sampling == "interpolate" else _hold_rows
    qr, qdr = sample(t_camera, t, q_rep), sample(t_camera, t, qd_rep)  # matched by the camera's timestamps
    h = 0.5 * sim.dt_s
    p_plus = kin.positions(_interp_rows(t_frames + h, t, q_true), check_limits=False)
    p_minus = kin.positions(_interp_rows(t_frames - h, t, q_true), check_limits=False)
    ball_true = kin.positions(qt, check_limits=False)
    gt_world = kin.positions(qr, check_limits=False)
    err_mm = np.linalg.norm(gt_world - ball_true, axis=1) * 1e3
    shift_mm = np.linalg.norm(gt_world - kin.positions(sample(t_frames, t, q_rep), check_limits=False), axis=1) * 1e3
    info.update({
        "trajectory_seed": plan.trajectory_seed,
        "clock": {"offset_ms": round(offset_s * 1e3, 4), "jitter_std_ms": round(float(np.std(t_camera - t_frames - offset_s)) * 1e3, 4),
                  "gt_shift_mm": {"median": round(float(np.median(shift_mm)), 4), "max": round(float(shift_mm.max()), 4)}},
        "robot_seed": robot_seed,
        "gt_vs_true_mm": {"median": float(np.median(err_mm)), "p99": float(np.percentile(err_mm, 99)),
                          "max": float(err_mm.max())},
        "ball_speed_mps": {"median": float(np.median(np.linalg.norm(p_plus - p_minus, axis=1) / (2 * h))),
                           "max": float(np.max(np.linalg.norm(p_plus - p_minus, axis=1) / (2 * h)))},
    })
    return RobotMotion(
        t_s=t_frames, t_camera_s=t_camera, q_true=qt, q_reported=qr, qdot_reported=qdr, q_command=_interp_rows(t_frames, t, q_ref),
        ball_true_world_m=ball_true, ball_velocity_world_mps=(p_plus - p_minus) / (2 * h),
        links_world_m=kin.link_points(qt, check_limits=False), gt_world_m=gt_world,
        T_base_to_world=np.array(kin.T_base_to_world), bias_rad=np.array(sim.bias_rad), info=info,
    )
