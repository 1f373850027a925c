"""The WAM interface that policies and experiments talk to, and the joint-trajectory types it uses.

It lives in ``robot_models`` (which imports nothing else of rt2) so that ``policies`` can type its robot
argument. Contract of :class:`WamInterface` (implemented in process by :class:`harness.sim.robot.SimulatedWam`
and over the network by :class:`harness.link.WamClient`, docs/robot_link.md; a real robot
backend implements the same members):

* **Units and frames.** Joint angles rad, velocities rad/s, times s. Joint order is the URDF's
  ``joint_1 .. joint_7``. Cartesian quantities are not part of this interface; compute them with
  :class:`robot_models.WamKinematics` (lab world frame) from the reported ``q``.
* **Clock.** ``t_s`` is the robot's own clock: 0 at session start, advancing in ticks of
  ``1 / control_rate_hz`` (500 Hz: 2 ms). ``read_state().t_s`` is the time of the latest tick.
* **read_state()** returns the *reported* state of the latest tick: encoder angles, which include
  the calibration zero offset and encoder quantisation/noise, and a filtered velocity. Never the truth.
* **command_trajectory(t_s, q, qdot=None)** takes an absolute-time joint trajectory, strictly
  increasing ``t_s`` (N >= 2), ``q`` (N, 7) within the joint limits and optional ``qdot`` (N, 7)
  within the velocity limits (else interpolated by a cubic spline). Invalid input raises
  ``ValueError`` and leaves the current command untouched. The new trajectory **replaces** the
  current one from ``max(t_s[0], now)`` on; before ``t_s[0]`` the previous reference goes on
  (or the robot holds). The part of a trajectory before the current time is ignored; a trajectory
  that ends before the current time is rejected. After ``t_s[-1]`` the robot holds ``q[-1]``. Jumps
  between the current state and the new reference are not teleported: the joint controller closes them
  within its velocity and acceleration limits.
* **advance_to(t_s)** runs the control loop up to the last tick at or before ``t_s`` (a real
  backend blocks until its clock gets there) and returns the reported samples of the ticks passed.
  Asking for a time before the current one raises ``ValueError``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["JointSamples", "JointState", "JointTrajectory", "WamInterface", "check_joint_trajectory"]


@dataclass(frozen=True)
class JointState:
    """Joint state at one tick. t_s : s (robot clock); q : (7,) rad; qdot : (7,) rad/s."""

    t_s: float
    q: np.ndarray
    qdot: np.ndarray


@dataclass(frozen=True)
class JointSamples:
    """Joint states of consecutive ticks. t_s : (n,) s; q : (n, 7) rad; qdot : (n, 7) rad/s."""

    t_s: np.ndarray
    q: np.ndarray
    qdot: np.ndarray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass(frozen=True)
class JointTrajectory:
    """A joint-space trajectory to command. t_s : (N,) s, strictly increasing; q, qdot, qddot : (N, 7)."""

    t_s: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    qddot: np.ndarray | None = None

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    def shifted(self, dt_s: float) -> "JointTrajectory":
        """The same trajectory with times ``t_s + dt_s`` (returns a new object)."""
        return JointTrajectory(self.t_s + float(dt_s), self.q, self.qdot, self.qddot)


@runtime_checkable
class WamInterface(Protocol):
    """What experiments need from a WAM, simulated or real (see the module docstring for the contract)."""

    control_rate_hz: float
    n_joints: int

    def read_state(self) -> JointState: ...

    def command_trajectory(self, t_s, q, qdot=None) -> None: ...

    def advance_to(self, t_s: float) -> JointSamples: ...


def check_joint_trajectory(kin, t_s, q, qdot=None, *, now_s: float | None = None, vel_tol: float = 1e-6):
    """Validate a commanded trajectory at the interface boundary; returns float arrays ``(t_s, q, qdot|None)``.

    kin : :class:`robot_models.WamKinematics` (limits). ``now_s``: current robot time; a trajectory
    ending at or before it is rejected. Raises ValueError naming the argument, sample and joint.
    """
    n_j = kin.n_joints
    try:
        t = np.asarray(t_s, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"t_s must be numeric times in seconds, got {t_s!r}") from exc
    if t.ndim != 1 or t.shape[0] < 2:
        raise ValueError(f"t_s must have shape (N,) with N >= 2, got shape {t.shape}")
    if not np.isfinite(t).all():
        raise ValueError("t_s must be finite")
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise ValueError(f"t_s must be strictly increasing; t_s[{i + 1}] = {float(t[i + 1])!r} <= t_s[{i}] = {float(t[i])!r}")
    if now_s is not None and t[-1] <= now_s:
        raise ValueError(f"trajectory ends at t_s = {t[-1]:.6g} s, not after the robot clock {now_s:.6g} s")
    Q = np.asarray(q, dtype=float) if np.ndim(q) else None
    if Q is None or Q.shape != (t.shape[0], n_j):
        raise ValueError(f"q must have shape ({t.shape[0]}, {n_j}) to match t_s, got shape {np.shape(q)}")
    kin.check_q(Q, "q")
    Qd = None
    if qdot is not None:
        Qd = np.asarray(qdot, dtype=float)
        if Qd.shape != Q.shape:
            raise ValueError(f"qdot must have shape {Q.shape} like q, got shape {Qd.shape}")
        if not np.isfinite(Qd).all():
            raise ValueError("qdot must be finite")
        over = np.abs(Qd) > kin.qdot_max * (1 + vel_tol)
        if over.any():
            i, j = (int(v) for v in np.argwhere(over)[0])
            raise ValueError(f"qdot[{i}]: {kin.joint_names[j]} = {Qd[i, j]:.4g} rad/s exceeds its velocity "
                             f"limit {kin.qdot_max[j]:g} rad/s")
    return t, Q, Qd
