"""A simulated arm (the WAM by default) behind :class:`robot_models.robot_interface.WamInterface`: tracking,
limits, encoders and zero offsets. Any arm of ``data/robot/`` runs here with its own gains and limits: the
``simulator`` section of its robot config (``SimWamOptions.from_mapping(config.simulator, n_joints=n)``).

Error model (defaults in :class:`SimWamOptions`, the ``simulator`` section of ``data/robot/wam.yaml``
and docs/robot.md):

* true joints follow the commanded reference (clamped into the joint limits) through a per-joint
  second-order loop of finite bandwidth with velocity and acceleration saturation and hard stops
  (harness/sim/robot/_tracking.py);
* reported ``q = quantise(q_true + bias) + noise``: ``bias`` (7,) is a per-joint zero offset drawn once
  per session from N(0, zero_offset_std), the dominant real error; quantisation is one count of a
  ``encoder_counts_per_rev`` motor encoder seen through the joint's gear ratio; noise is Gaussian;
* reported ``qdot`` is the first difference of the reported ``q``, low-passed at ``velocity_filter_hz``.

Both the true state (where the ball really is) and the reported one (what an experiment logs) are kept.
Randomness: ``seed`` spawns two independent streams, one for the bias (drawn at construction) and one
for the noise, drawn tick by tick in order, so a seed gives the same session however ``advance_to`` is
chunked.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from scipy.signal import lfilter

from robot_models.joint_reference import PiecewiseReference
from harness.sim.robot._tracking import TRACKERS
from robot_models.robot_interface import JointSamples, JointState, check_joint_trajectory

__all__ = ["SimSamples", "SimWamOptions", "SimulatedWam"]

_N = 7  #: the WAM's joints: the per-joint defaults below are its
#: per-joint defaults of an arm of another joint count whose robot config does not give them (one value for all)
OTHER_ARM_DEFAULTS = {"bandwidth_hz": 8.0, "gear_ratio": 100.0, "encoder_noise_std_rad": 2e-5, "zero_offset_std_deg": 0.2}


def _per_joint(value, name: str, n: int) -> tuple[float, ...]:
    arr = np.asarray(value, dtype=float)
    arr = np.full(n, float(arr)) if arr.ndim == 0 else arr
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise ValueError(f"SimWamOptions.{name} must be one number or {n} finite numbers (one per joint), got {value!r}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class SimWamOptions:
    """Simulator parameters. Per-joint fields take one number or ``n_joints`` (the defaults are the WAM's 7)."""

    control_rate_hz: float = 500.0  #: WAM control loop rate
    bandwidth_hz: tuple = (6.0, 6.0, 8.0, 8.0, 12.0, 12.0, 12.0)  #: closed-loop natural frequency per joint
    damping_ratio: float = 1.0  #: closed-loop damping (1 = critical)
    feedforward_gain: float = 0.9  #: share of the reference acceleration fed forward (1 = perfect model)
    encoder_counts_per_rev: int = 4096  #: motor encoder counts per motor revolution
    gear_ratio: tuple = (42.0, 28.25, 28.25, 18.0, 9.7, 9.7, 14.93)  #: motor revs per joint rev
    encoder_noise_std_rad: tuple = (2e-5,) * _N  #: Gaussian noise on the reported angle
    zero_offset_std_deg: tuple = (0.5, 0.5, 0.3, 0.3, 0.2, 0.2, 0.2)  #: per-session zero-offset bias std
    velocity_filter_hz: float = 100.0  #: low-pass cut-off of the reported velocity
    backend: str = "numba"  #: tracking kernel, a key of harness.sim.robot._tracking.TRACKERS
    n_joints: int = _N  #: the arm's joints (from its kinematics, not its YAML file)

    def __post_init__(self):
        if isinstance(self.n_joints, bool) or not isinstance(self.n_joints, int) or self.n_joints < 1:
            raise ValueError(f"SimWamOptions.n_joints must be an integer >= 1, got {self.n_joints!r}")
        for name in ("bandwidth_hz", "gear_ratio", "encoder_noise_std_rad", "zero_offset_std_deg"):
            object.__setattr__(self, name, _per_joint(getattr(self, name), name, self.n_joints))
        for name in ("control_rate_hz", "damping_ratio", "velocity_filter_hz"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"SimWamOptions.{name} must be > 0, got {getattr(self, name)!r}")
        if min(self.bandwidth_hz) <= 0 or min(self.gear_ratio) <= 0:
            raise ValueError(f"SimWamOptions bandwidth_hz and gear_ratio must be > 0, got "
                             f"{self.bandwidth_hz}, {self.gear_ratio}")
        if min(self.encoder_noise_std_rad) < 0 or min(self.zero_offset_std_deg) < 0:
            raise ValueError("SimWamOptions noise and zero-offset std must be >= 0")
        if not 0 <= float(self.feedforward_gain) <= 1.5:
            raise ValueError(f"SimWamOptions.feedforward_gain must be in [0, 1.5], got {self.feedforward_gain!r}")
        if int(self.encoder_counts_per_rev) < 1:
            raise ValueError(f"SimWamOptions.encoder_counts_per_rev must be >= 1, got {self.encoder_counts_per_rev!r}")
        if self.backend not in TRACKERS:
            raise ValueError(f"unknown SimWamOptions.backend {self.backend!r}; valid: {sorted(TRACKERS)}")
        if 2 * np.pi * max(self.bandwidth_hz) / self.control_rate_hz > 0.5:  # keeps the Euler loop stable
            raise ValueError(f"SimWamOptions.bandwidth_hz {max(self.bandwidth_hz)} is too high for a "
                             f"{self.control_rate_hz} Hz loop (at most control_rate_hz / (4 pi))")

    @property
    def resolution_rad(self) -> np.ndarray:
        """(7,) joint angle of one encoder count, rad."""
        return 2 * np.pi / (self.encoder_counts_per_rev * np.asarray(self.gear_ratio))

    @classmethod
    def from_mapping(cls, mapping: dict, where: str = "simulator", *, n_joints: int = _N) -> "SimWamOptions":
        """Options from a mapping such as ``RobotConfig.simulator`` for an arm of ``n_joints``; unknown keys
        raise, naming ``where``. Per-joint fields it does not give are the WAM's for 7 joints, else
        :data:`OTHER_ARM_DEFAULTS`."""
        valid = {f.name for f in fields(cls)} - {"n_joints"}
        unknown = sorted(set(mapping) - valid)
        if unknown:
            raise ValueError(f"{where}: unknown field(s) {unknown}; valid: {sorted(valid)}")
        try:
            fill = {} if n_joints == _N else {k: v for k, v in OTHER_ARM_DEFAULTS.items() if k not in mapping}
            return cls(**{**mapping, **fill}, n_joints=n_joints)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from exc


@dataclass(frozen=True)
class SimSamples(JointSamples):
    """Reported samples plus the simulator's truth: q_true, qdot_true, q_ref : (n, 7)."""

    q_true: np.ndarray = None
    qdot_true: np.ndarray = None
    q_ref: np.ndarray = None


class SimulatedWam:
    """Simulated WAM (see module docstring). Satisfies :class:`robot_models.robot_interface.WamInterface`.

    kinematics : :class:`robot_models.WamKinematics` (limits, home posture)
    q0 : (n,) rad true start posture (default ``kinematics.q_home``), at rest
    """

    def __init__(self, kinematics, options: SimWamOptions = SimWamOptions(), *, seed: int = 0, q0=None):
        if not isinstance(options, SimWamOptions):
            raise ValueError(f"options must be SimWamOptions, got {options!r}")
        n = kinematics.n_joints
        if options.n_joints != n:
            raise ValueError(f"SimulatedWam: the options are for {options.n_joints} joints, the arm has {n} "
                             "(SimWamOptions.from_mapping(config.simulator, n_joints=kin.n_joints))")
        self.kinematics = kinematics
        self.options = options
        self.control_rate_hz = float(options.control_rate_hz)
        self.dt_s = 1.0 / self.control_rate_hz
        self.n_joints = n
        bias_seq, noise_seq = np.random.SeedSequence(seed).spawn(2)
        self.bias_rad = np.deg2rad(options.zero_offset_std_deg) * np.random.default_rng(bias_seq).standard_normal(n)
        self.bias_rad.setflags(write=False)
        self._noise_rng = np.random.default_rng(noise_seq)
        self._track = TRACKERS[options.backend]
        self._omega = 2 * np.pi * np.asarray(options.bandwidth_hz)
        self._res = options.resolution_rad
        self._alpha = float(np.exp(-2 * np.pi * options.velocity_filter_hz * self.dt_s))
        q_start = kinematics.check_q(kinematics.q_home if q0 is None else q0, "q0")
        if q_start.ndim != 1:
            raise ValueError(f"q0 must have shape ({n},), got {q_start.shape}")
        self._tick = 0
        self._q = q_start.copy()
        self._qd = np.zeros(n)
        self._reference = PiecewiseReference(q_start)
        self._q_meas = self._measure(self._q[None])[0]
        self._qd_meas = np.zeros(n)
        self.saturated_ticks = np.zeros(n, dtype=np.int64)  #: per joint, ticks with a saturated command
        self.limit_ticks = np.zeros(n, dtype=np.int64)  #: per joint, ticks spent against a hard stop

    # -- clock -----------------------------------------------------------------------------------
    @property
    def t_s(self) -> float:
        """Robot time of the latest tick, s."""
        return self._tick * self.dt_s

    def _measure(self, q_true: np.ndarray) -> np.ndarray:
        """Reported angles of true angles (n, 7): quantise(q + bias) + noise."""
        counts = np.round((q_true + self.bias_rad) / self._res)
        noise = self._noise_rng.standard_normal(q_true.shape) * np.asarray(self.options.encoder_noise_std_rad)
        return counts * self._res + noise

    # -- interface -------------------------------------------------------------------------------
    def read_state(self) -> JointState:
        """Reported state of the latest tick (bias, quantisation, noise included)."""
        return JointState(self.t_s, self._q_meas.copy(), self._qd_meas.copy())

    def true_state(self) -> JointState:
        """The simulator's true state of the latest tick (for ground truth, never shown to a policy)."""
        return JointState(self.t_s, self._q.copy(), self._qd.copy())

    def command_trajectory(self, t_s, q, qdot=None) -> None:
        """Replace the reference from ``max(t_s[0], now)`` on (contract: robot_models/robot_interface.py)."""
        t, Q, Qd = check_joint_trajectory(self.kinematics, t_s, q, qdot, now_s=self.t_s)
        self._reference.replace_from(t, Q, Qd, self.t_s)

    def reference_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Where the present reference drives the arm at robot time ``t_s``: ``(q (7,) rad, qdot (7,) rad/s)``
        (true joint coordinates, clamped into the joint limits like the ticks' reference)."""
        q, qd, _ = self._reference.evaluate(np.array([float(t_s)]))
        return np.clip(q[0], self.kinematics.q_min, self.kinematics.q_max), qd[0]

    def step(self, n_ticks: int = 1) -> SimSamples:
        """Run ``n_ticks`` control ticks; returns their samples."""
        if int(n_ticks) != n_ticks or n_ticks < 0:
            raise ValueError(f"n_ticks must be a non-negative integer, got {n_ticks!r}")
        return self._run(int(n_ticks))

    def advance_to(self, t_s: float) -> SimSamples:
        """Run every tick up to the last one at or before ``t_s``; returns the samples of the ticks run."""
        t = float(t_s)
        if not np.isfinite(t) or t < self.t_s - 1e-12:
            raise ValueError(f"advance_to({t_s!r}): time must be finite and not before the robot clock "
                             f"{self.t_s:.6g} s")
        target_tick = int(np.floor(t * self.control_rate_hz + 1e-9))
        return self._run(max(target_tick - self._tick, 0))

    def _run(self, n: int) -> SimSamples:
        if n == 0:
            empty = np.zeros((0, self.n_joints))
            return SimSamples(np.zeros(0), empty, empty, q_true=empty, qdot_true=empty, q_ref=empty)
        t_all = (self._tick + np.arange(n + 1)) * self.dt_s  # the current tick and the n ticks to run
        q_ref, qd_ref, qdd_ref = self._reference.evaluate(t_all)
        t = t_all[1:]
        kin, opt = self.kinematics, self.options
        # the reference is clamped into the joint limits (a spline may swing past them between knots)
        over = (q_ref < kin.q_min) | (q_ref > kin.q_max)
        q_ref = np.clip(q_ref, kin.q_min, kin.q_max)
        qd_ref[over] = 0.0
        qdd_ref[over] = 0.0
        q_true, qd_true, sat = self._track(
            self._q, self._qd, q_ref[:-1], qd_ref[:-1], qdd_ref[:-1], self._omega, float(opt.damping_ratio),
            float(opt.feedforward_gain), np.asarray(kin.qdot_max), np.asarray(kin.qddot_max),
            np.asarray(kin.q_min), np.asarray(kin.q_max), self.dt_s)
        q_meas = self._measure(q_true)
        # reported velocity: first difference, then y[k] = alpha y[k-1] + (1 - alpha) x[k]
        raw = np.diff(np.vstack([self._q_meas[None], q_meas]), axis=0) / self.dt_s
        qd_meas, _ = lfilter([1 - self._alpha], [1.0, -self._alpha], raw, axis=0,
                             zi=(self._alpha * self._qd_meas)[None])
        self._tick += n
        self._q, self._qd = q_true[-1].copy(), qd_true[-1].copy()
        self._q_meas, self._qd_meas = q_meas[-1].copy(), qd_meas[-1].copy()
        self.saturated_ticks += sat
        self.limit_ticks += ((q_true <= kin.q_min) | (q_true >= kin.q_max)).sum(axis=0)
        return SimSamples(t, q_meas, qd_meas, q_true=q_true, qdot_true=qd_true, q_ref=q_ref[1:])

    def __repr__(self) -> str:
        return f"SimulatedWam(t_s={self.t_s:.3f}, backend={self.options.backend!r})"
