"""Seeded smooth joint trajectories that move a robot frame (the ball mount) through a box in the lab.

For the accuracy experiment (paper Sec. "Evaluation on the Real Robot Platform": a ball on the end
effector, ground truth from the kinematics). Algorithm:

1. draw via points uniformly in ``box_world_m`` and, per point, a tool-axis direction within
   ``tool_cone_deg`` of ``tool_axis_world`` (default: ball on top of the flange, seen by ceiling cameras);
2. solve IK (robot_models.ik) from the previous via configuration; keep the point if IK succeeds and the
   rest-to-rest quintic from the previous configuration keeps the frame within the box grown by
   ``box_margin_m`` (a joint-space move can swing out of the box, or into the table);
3. time it: ``method="spline"`` fits a C2 cubic spline through all via configurations, at rest at both
   ends, with knot spacing from the limits and one uniform time scaling so that
   ``|qdot| <= speed_fraction * qdot_max`` and ``|qddot| <= accel_fraction * qddot_max`` everywhere;
   ``method="quintic"`` moves rest-to-rest between via points with ``s = 10 u^3 - 15 u^4 + 6 u^5``
   (peak speed 1.875 dq/T, peak acceleration 5.7735 dq/T^2). A spline that leaves the joint limits or
   the grown box falls back to quintic (``info["method"]`` says which was used);
4. sample at ``sample_rate_hz``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from harness.common.seeding import rng_from
from robot_models.robot_interface import JointTrajectory
from robot_models.ik import IkOptions, solve_ik

__all__ = ["BALL_BOX_WORLD_M", "TRAJECTORY_METHODS", "TrajectoryOptions", "random_via_trajectory"]

#: Default box for the ball (lab world, m): above the robot's table end, inside the arm's reach.
BALL_BOX_WORLD_M = ((-1.55, -0.45, 0.95), (-1.05, 0.45, 1.40))
TRAJECTORY_METHODS = ("spline", "quintic")
_QUINTIC_PEAK_VEL = 1.875  # max of ds/du for s = 10u^3 - 15u^4 + 6u^5
_QUINTIC_PEAK_ACC = 5.773502691896258  # max of |d2s/du2| = 10 / sqrt(3)


@dataclass(frozen=True)
class TrajectoryOptions:
    """Options of :func:`random_via_trajectory`."""

    n_via: int = 8  #: via points after the start configuration
    frame: str = "ball_mount"  #: the frame moved through the box
    method: str = "spline"  #: a key of TRAJECTORY_METHODS
    speed_fraction: float = 0.4  #: share of the velocity limits used at most
    accel_fraction: float = 0.4  #: share of the acceleration limits used at most
    min_segment_s: float = 0.3  #: shortest time between via points
    sample_rate_hz: float = 500.0
    tool_axis_world: tuple | None = (0.0, 0.0, 1.0)  #: preferred frame z axis; None: position only
    tool_cone_deg: float = 30.0  #: via-point z axes are uniform within this cone around tool_axis_world
    box_margin_m: float = 0.10  #: the frame may leave the box by at most this much between via points
    tries_per_via: int = 30
    #: IK for via points; the wide limit margin leaves room for the spline to swing between them
    ik: IkOptions = field(default_factory=lambda: IkOptions(restarts=3, limit_margin_rad=0.2))

    def __post_init__(self):
        if self.method not in TRAJECTORY_METHODS:
            raise ValueError(f"unknown trajectory method {self.method!r}; valid: {list(TRAJECTORY_METHODS)}")
        if self.n_via < 1 or self.tries_per_via < 1:
            raise ValueError(f"n_via and tries_per_via must be >= 1, got {self.n_via}, {self.tries_per_via}")
        for name in ("speed_fraction", "accel_fraction"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"TrajectoryOptions.{name} must be in (0, 1], got {getattr(self, name)!r}")
        for name in ("min_segment_s", "sample_rate_hz"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TrajectoryOptions.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0 <= self.tool_cone_deg <= 180 or self.box_margin_m < 0:
            raise ValueError(f"tool_cone_deg must be in [0, 180] and box_margin_m >= 0, got "
                             f"{self.tool_cone_deg!r}, {self.box_margin_m!r}")


def _cone_direction(axis: np.ndarray, cone_deg: float, rng: np.random.Generator) -> np.ndarray:
    """Unit vector uniform on the spherical cap of half-angle ``cone_deg`` around unit ``axis``."""
    cos_max = np.cos(np.deg2rad(cone_deg))
    cos_t = rng.uniform(cos_max, 1.0)
    phi = rng.uniform(0, 2 * np.pi)
    sin_t = np.sqrt(max(0.0, 1 - cos_t**2))
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    return cos_t * axis + sin_t * (np.cos(phi) * u + np.sin(phi) * v)


def _quintic(q_via: np.ndarray, knots: np.ndarray, t: np.ndarray):
    """Rest-to-rest quintic blends between consecutive via configurations; q, qd, qdd (n, 7) at ``t``."""
    seg = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(knots) - 2)
    T = (knots[seg + 1] - knots[seg])[:, None]
    u = np.clip((t - knots[seg])[:, None] / T, 0.0, 1.0)
    dq = q_via[seg + 1] - q_via[seg]
    s = u**3 * (10 - 15 * u + 6 * u**2)
    ds = 30 * u**2 * (1 - u) ** 2
    dds = 60 * u * (1 - u) * (1 - 2 * u)
    return q_via[seg] + s * dq, ds * dq / T, dds * dq / T**2


def _quintic_durations(dq: np.ndarray, vmax: np.ndarray, amax: np.ndarray, t_min: float) -> np.ndarray:
    """(n_seg,) shortest rest-to-rest quintic durations keeping each joint within vmax, amax."""
    adq = np.abs(dq)
    return np.maximum(t_min, np.maximum(_QUINTIC_PEAK_VEL * adq / vmax, np.sqrt(_QUINTIC_PEAK_ACC * adq / amax)).max(1))


def _sample_times(end_s: float, dt: float) -> np.ndarray:
    """0, dt, 2 dt, ... and exactly ``end_s`` last (the last step may be shorter)."""
    t = np.arange(0.0, end_s, dt)
    return np.append(t[: -1 if end_s - t[-1] < 1e-9 else None], end_s)


def _in_box(points: np.ndarray, box: np.ndarray, margin: float) -> bool:
    return bool(((points >= box[0] - margin) & (points <= box[1] + margin)).all())


def random_via_trajectory(kin, box_world_m=BALL_BOX_WORLD_M, *, q_start=None,
                          options: TrajectoryOptions = TrajectoryOptions(), seed: int | None = None,
                          rng: np.random.Generator | None = None) -> tuple[JointTrajectory, dict]:
    """A seeded smooth joint trajectory from ``q_start`` (7,) (default ``kin.q_home``) through random via points.

    box_world_m : (2, 3) ``[[x, y, z] min, [x, y, z] max]`` lab world, m, for ``options.frame``.
    Returns ``(trajectory, info)``: the trajectory starts at t_s = 0 and at ``q_start`` at rest (shift it
    to the robot clock with ``JointTrajectory.shifted``); info holds ``via_world_m (n_via, 3)``,
    ``via_q (n_via + 1, 7)``, ``knot_t_s``, ``method``, ``rejected`` (candidate points refused),
    ``peak_qdot_ratio`` / ``peak_qddot_ratio`` (of the full limits) and ``max_box_excursion_m``.
    Raises ValueError if the box cannot be reached (too few via points found).
    """
    if not isinstance(options, TrajectoryOptions):
        raise ValueError(f"options must be TrajectoryOptions, got {options!r}")
    box = np.asarray(box_world_m, dtype=float)
    if box.shape != (2, 3) or not np.isfinite(box).all() or (box[1] <= box[0]).any():
        raise ValueError(f"box_world_m must be [[min x, y, z], [max x, y, z]] with min < max, got {np.asarray(box_world_m).tolist()}")
    kin.frame_id(options.frame)
    q0 = kin.check_q(kin.q_home if q_start is None else q_start, "q_start")
    if q0.ndim != 1:
        raise ValueError(f"q_start must have shape ({kin.n_joints},), got {q0.shape}")
    rng = rng_from(seed, rng, "random_via_trajectory")  # required: never OS entropy
    axis = None
    if options.tool_axis_world is not None:
        axis = np.asarray(options.tool_axis_world, float)
        axis = axis / np.linalg.norm(axis)
    vmax = options.speed_fraction * kin.qdot_max
    amax = options.accel_fraction * kin.qddot_max
    check_dt = 0.02
    via_q, via_p, rejected = [q0], [], 0
    while len(via_p) < options.n_via:
        if rejected >= options.tries_per_via * options.n_via:
            raise ValueError(f"only {len(via_p)} of {options.n_via} via points reachable in box {box.tolist()} "
                             f"after {rejected} rejected candidates; is the box inside the workspace?")
        p = rng.uniform(box[0], box[1])
        normal = None if axis is None else _cone_direction(axis, options.tool_cone_deg, rng)
        q, info = solve_ik(kin, p, options.frame, normal_world=normal, q0=via_q[-1], options=options.ik, rng=rng)
        if info.success:
            T = _quintic_durations((q - via_q[-1])[None], vmax, amax, options.min_segment_s)
            t = np.linspace(0.0, T[0], max(2, int(T[0] / check_dt) + 1))
            path = kin.positions(_quintic(np.stack([via_q[-1], q]), np.array([0.0, T[0]]), t)[0], options.frame)
            if _in_box(path, box, options.box_margin_m):
                via_q.append(q)
                via_p.append(p)
                continue
        rejected += 1
    Qv = np.stack(via_q)
    knots = np.concatenate([[0.0], np.cumsum(_quintic_durations(np.diff(Qv, axis=0), vmax, amax, options.min_segment_s))])
    method = options.method
    dt = 1.0 / options.sample_rate_hz
    if method == "spline":
        # knot spacing from the quintic timing, then one uniform time scaling (vel ~ 1/r, acc ~ 1/r^2)
        spline = CubicSpline(knots, Qv, bc_type="clamped", axis=0)
        t_chk = np.union1d(np.arange(0.0, knots[-1], dt), knots)  # accel is linear between knots
        r = max(1.0, (np.abs(spline(t_chk, 1)) / vmax).max(), np.sqrt((np.abs(spline(t_chk, 2)) / amax).max()))
        knots_s = knots * r
        spline = CubicSpline(knots_s, Qv, bc_type="clamped", axis=0)
        t = _sample_times(knots_s[-1], dt)
        q, qd, qdd = spline(t), spline(t, 1), spline(t, 2)
        pts = kin.positions(q, options.frame, check_limits=False)
        if kin.within_limits(q).all() and _in_box(pts, box, options.box_margin_m):
            knots = knots_s
        else:
            method = "quintic"
    if method == "quintic":
        t = _sample_times(knots[-1], dt)
        q, qd, qdd = _quintic(Qv, knots, t)
        pts = kin.positions(q, options.frame)
    excursion = np.maximum(box[0] - pts, pts - box[1]).max()
    traj = JointTrajectory(t, q, qd, qdd)
    return traj, {
        "via_world_m": np.stack(via_p), "via_q": Qv, "knot_t_s": knots, "method": method, "rejected": rejected,
        "peak_qdot_ratio": float((np.abs(qd) / kin.qdot_max).max()),
        "peak_qddot_ratio": float((np.abs(qdd) / kin.qddot_max).max()),
        "max_box_excursion_m": float(max(0.0, excursion)),
    }
