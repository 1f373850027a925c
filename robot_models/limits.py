"""The WAM's joint limits without its kinematics: what a robot-side bridge checks commands against.

:class:`JointLimits` carries the joint names and the position and velocity limits that
:class:`robot_models.WamKinematics` has, read from the same robot configuration (the URDF's
``<limit lower upper>`` and ``limits.qdot_max_rad_s`` of ``data/robot/wam.yaml``), but needs only numpy,
PyYAML and the standard library's XML parser -- no Pinocchio. ``check_joint_trajectory`` accepts
either. The robot link's bridge for ROS ``wam_node`` (``harness.link.bridge_ros``), which runs
under a system Python with Debian's ROS packages, uses it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from robot_models.config import RobotConfig, load_robot_config

__all__ = ["JointLimits", "check_joint_angles", "urdf_joint_limits"]


def check_joint_angles(joint_names, q_min: np.ndarray, q_max: np.ndarray, q, name: str = "q", *,
                       limits: bool = True, tol_rad: float = 1e-9) -> np.ndarray:
    """Validate one configuration or a batch; returns a float array of the same shape.

    q : (n,) or (N, n) joint angles, rad, n = len(joint_names); q_min, q_max : (n,) rad. Raises ValueError
    naming ``name`` for a wrong length, non-finite values, or (with ``limits``) a joint outside
    ``[q_min - tol, q_max + tol]``.
    """
    n = len(joint_names)
    try:
        arr = np.asarray(q, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric joint angles, got {q!r}") from exc
    if arr.ndim not in (1, 2) or arr.shape[-1] != n:
        raise ValueError(f"{name} must have length {n} (or shape (N, {n})), got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist() if arr.size <= 14 else 'non-finite values'}")
    if limits:
        low = arr < q_min - tol_rad
        high = arr > q_max + tol_rad
        if low.any() or high.any():
            idx = np.argwhere(low | high)[0]
            j = int(idx[-1])
            val = float(arr[tuple(idx)])
            row = f" (row {int(idx[0])})" if arr.ndim == 2 else ""
            raise ValueError(f"{name}{row}: {joint_names[j]} = {val:.6g} rad is outside its limits "
                             f"[{q_min[j]:g}, {q_max[j]:g}] rad")
    return arr


def urdf_joint_limits(path: str | Path) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
    """Names and limits of the movable joints of a URDF, in file order (Pinocchio's order for a serial arm).

    Returns ``(joint_names, q_min (n,) rad, q_max (n,) rad, velocity (n,) rad/s)``. Raises ValueError naming
    the file and joint for a joint that is not a revolute joint with a complete ``<limit>``.
    """
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except OSError as exc:
        raise ValueError(f"cannot read URDF {str(path)!r}: {exc.strerror or exc}") from None
    except ET.ParseError as exc:
        raise ValueError(f"{path}: not a valid URDF ({exc})") from None
    names, rows = [], []
    for joint in root.iter("joint"):
        kind, name = joint.get("type"), joint.get("name")
        if kind == "fixed":
            continue
        if kind != "revolute":
            raise ValueError(f"{path}: joint {name!r} is {kind!r}; only revolute joints with limits are supported")
        limit = joint.find("limit")
        try:
            rows.append([float(limit.get(k)) for k in ("lower", "upper", "velocity")])
        except (AttributeError, TypeError, ValueError):
            raise ValueError(f"{path}: joint {name!r} needs <limit lower= upper= velocity=> numbers") from None
        names.append(name)
    if not names:
        raise ValueError(f"{path}: no revolute joint found")
    arr = np.array(rows, dtype=float)
    return tuple(names), arr[:, 0].copy(), arr[:, 1].copy(), arr[:, 2].copy()


@dataclass(frozen=True, eq=False)
class JointLimits:
    """Joint names and limits of the arm. q_min, q_max : (n,) rad; qdot_max : (n,) rad/s; qddot_max : (n,)
    rad/s^2 (read-only arrays).

    Has the members ``check_joint_trajectory`` and ``robot_models.motion_limits.check_motion`` use
    (``n_joints``, ``joint_names``, ``qdot_max``, ``qddot_max``, ``check_q``), like
    :class:`robot_models.WamKinematics`. Build with :meth:`from_config`.
    """

    joint_names: tuple
    q_min: np.ndarray
    q_max: np.ndarray
    qdot_max: np.ndarray
    qddot_max: np.ndarray = None

    def __post_init__(self):
        n = len(self.joint_names)
        for name in ("q_min", "q_max", "qdot_max", "qddot_max"):
            if name == "qddot_max" and self.qddot_max is None:
                raise ValueError(f"JointLimits.qddot_max (acceleration limits, rad/s^2) must be given: {n} numbers")
            arr = np.array(getattr(self, name), dtype=float)
            if arr.shape != (n,) or not np.isfinite(arr).all():
                raise ValueError(f"JointLimits.{name} must be {n} finite numbers, got {getattr(self, name)!r}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if (self.q_min > self.q_max).any() or (self.qdot_max <= 0).any() or (self.qddot_max <= 0).any():
            raise ValueError(f"JointLimits: need q_min <= q_max and qdot_max, qddot_max > 0, got {self.q_min}, {self.q_max}, "
                             f"{self.qdot_max}, {self.qddot_max}")
        object.__setattr__(self, "joint_names", tuple(self.joint_names))

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @classmethod
    def from_config(cls, config: RobotConfig | str | Path | None = None) -> "JointLimits":
        """The limits of a :class:`RobotConfig` or robot YAML path (default ``data/robot/wam.yaml``): position
        limits from its URDF, velocity and acceleration limits from ``limits.qdot_max_rad_s`` / ``qddot_max_rad_s2``
        (as ``WamKinematics.from_config``)."""
        if not isinstance(config, RobotConfig):
            config = load_robot_config(config)
        if not config.urdf_path.is_file():
            raise FileNotFoundError(f"URDF not found: {config.urdf_path}")
        names, q_min, q_max, _ = urdf_joint_limits(config.urdf_path)
        if len(names) != len(config.qdot_max_rad_s):
            raise ValueError(f"{config.urdf_path}: {len(names)} joints, but qdot_max_rad_s has {len(config.qdot_max_rad_s)}")
        return cls(names, q_min, q_max, np.asarray(config.qdot_max_rad_s, float),
                   np.asarray(config.qddot_max_rad_s2, float))

    def check_q(self, q, name: str = "q", *, limits: bool = True, tol_rad: float = 1e-9) -> np.ndarray:
        """As :meth:`robot_models.WamKinematics.check_q`: q (n,) or (N, n) rad, validated; ValueError naming ``name``."""
        return check_joint_angles(self.joint_names, self.q_min, self.q_max, q, name, limits=limits, tol_rad=tol_rad)
