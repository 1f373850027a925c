"""An arm's joint limits without its kinematics: what a robot-side bridge checks commands against.

:class:`JointLimits` carries the joint names and the position, velocity and acceleration limits that
:class:`robot_models.ArmKinematics` has, read from the same robot configuration (the URDF's
``<limit lower upper>`` of the joints from ``base_link`` to ``flange_link``, narrowed by ``limits.q_min`` /
``q_max``, and ``limits.qdot_max_rad_s`` of ``data/robot/*.yaml``), but needs only numpy,
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

__all__ = ["MAX_JOINTS", "JointLimits", "UrdfJoint", "check_joint_angles", "config_limits", "urdf_chain", "urdf_joint_limits"]

MAX_JOINTS = 16  #: the most movable joints an arm may have (the robot link's and the lab truth stream's vectors)


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


@dataclass(frozen=True)
class UrdfJoint:
    """One movable joint of a URDF chain: name, ``kind`` (``revolute`` or ``prismatic``), limits (rad or m;
    rad/s or m/s), parent and child link."""

    name: str
    kind: str
    lower: float
    upper: float
    velocity: float
    parent: str
    child: str


def _parse_urdf(path: Path):
    try:
        return ET.parse(path).getroot()
    except OSError as exc:
        raise ValueError(f"cannot read URDF {str(path)!r}: {exc.strerror or exc}") from None
    except ET.ParseError as exc:
        raise ValueError(f"{path}: not a valid URDF ({exc})") from None


def _movable(joint, path: Path) -> UrdfJoint:
    kind, name = joint.get("type"), joint.get("name")
    if kind == "continuous":
        raise ValueError(f"{path}: joint {name!r} is 'continuous': it has no position limits; make it a revolute "
                         "joint with <limit lower= upper=> in the URDF")
    if kind not in ("revolute", "prismatic"):
        raise ValueError(f"{path}: joint {name!r} is {kind!r}; only revolute and prismatic joints with limits are supported")
    limit = joint.find("limit")
    try:
        lower, upper, velocity = (float(limit.get(k)) for k in ("lower", "upper", "velocity"))
    except (AttributeError, TypeError, ValueError):
        raise ValueError(f"{path}: joint {name!r} needs <limit lower= upper= velocity=> numbers") from None
    if not (np.isfinite([lower, upper, velocity]).all() and lower < upper and velocity > 0):
        raise ValueError(f"{path}: joint {name!r} limits must be finite with lower < upper and velocity > 0, got "
                         f"lower={lower:g} upper={upper:g} velocity={velocity:g}")
    parent, child = joint.find("parent"), joint.find("child")
    return UrdfJoint(name, kind, lower, upper, velocity, parent.get("link") if parent is not None else "",
                     child.get("link") if child is not None else "")


def urdf_chain(path: str | Path, base_link: str, flange_link: str) -> list[UrdfJoint]:
    """The movable joints from ``base_link`` to ``flange_link`` of a URDF, base first.

    Raises ValueError naming the file and the link or joint: a link not in the URDF (the links present are
    listed), a flange that does not hang below the base, a joint without limits (``continuous``, no
    ``<limit>``) or of another type than revolute and prismatic.
    """
    path = Path(path)
    root = _parse_urdf(path)
    links = [link.get("name") for link in root.iter("link")]
    for field, link in (("base_link", base_link), ("flange_link", flange_link)):
        if link not in links:
            shown = links if len(links) <= 30 else links[:30] + ["..."]
            raise ValueError(f"{path}: {field}: link {link!r} is not in the URDF; links: {shown}")
    up = {j.find("child").get("link"): j for j in root.iter("joint") if j.find("child") is not None}

    def to_root(link):  # [(link, joint above it)], the link first, up to the root
        path_up, seen = [], set()
        while link in up and link not in seen:
            seen.add(link)
            path_up.append((link, up[link]))
            link = up[link].find("parent").get("link")
        return path_up, link

    flange_up, _ = to_root(flange_link)
    base_up, _ = to_root(base_link)
    above_base = {base_link} | {j.find("parent").get("link") for _, j in base_up}
    chain, common = [], None
    for link, joint in flange_up:  # flange side, up to the first link the base also hangs from
        if link in above_base:
            common = link
            break
        if joint.get("type") != "fixed":
            chain.append(joint)
        if joint.find("parent").get("link") in above_base:
            common = joint.find("parent").get("link")
            break
    if common is None and flange_link not in above_base:
        raise ValueError(f"{path}: flange_link: link {flange_link!r} is not connected to base_link {base_link!r}")
    for link, joint in base_up:  # the base must be fixed to that common link: no joint moves it
        if link == common:
            break
        if joint.get("type") != "fixed":
            raise ValueError(f"{path}: base_link: link {base_link!r} is moved by joint {joint.get('name')!r}; the base must be "
                             "fixed to the links the arm hangs from")
    if not chain:
        raise ValueError(f"{path}: no movable joint between {base_link!r} and {flange_link!r}")
    if len(chain) > MAX_JOINTS:
        raise ValueError(f"{path}: {len(chain)} movable joints between {base_link!r} and {flange_link!r}; rt2 takes arms of "
                         f"at most {MAX_JOINTS} (the robot link and the lab truth stream carry no more)")
    return [_movable(j, path) for j in reversed(chain)]


def urdf_joint_limits(path: str | Path, base_link: str | None = None, flange_link: str | None = None
                      ) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
    """Names and limits of the movable joints of a URDF: those from ``base_link`` to ``flange_link`` (base
    first), or without the links every movable joint in file order (Pinocchio's order for a serial arm).

    Returns ``(joint_names, q_min (n,), q_max (n,), velocity (n,))`` (rad or m). Raises ValueError naming the
    file and joint for a joint that is not a revolute or prismatic joint with a complete ``<limit>``.
    """
    path = Path(path)
    if base_link is not None and flange_link is not None:
        joints = urdf_chain(path, base_link, flange_link)
    else:
        joints = [_movable(j, path) for j in _parse_urdf(path).iter("joint") if j.get("type") != "fixed"]
    if not joints:
        raise ValueError(f"{path}: no revolute joint found")
    arr = np.array([[j.lower, j.upper, j.velocity] for j in joints], dtype=float)
    return tuple(j.name for j in joints), arr[:, 0].copy(), arr[:, 1].copy(), arr[:, 2].copy()


def config_limits(config: RobotConfig, names, q_min: np.ndarray, q_max: np.ndarray, kinds=None):
    """The position limits of ``config``: the URDF's ``q_min``, ``q_max`` (n,) narrowed by ``limits.q_min`` /
    ``limits.q_max``. Raises ValueError naming the file and field for a count that differs from the URDF's
    joints or an override beyond the URDF's range (rad, or m for a ``prismatic`` joint of ``kinds``)."""
    n = len(names)
    if config.n_joints != n:
        raise ValueError(f"{config.where}: q_home_rad: {config.n_joints} values, but the URDF has {n} joints from "
                         f"{config.base_link!r} to {config.flange_link!r}: {list(names)}")
    lo, hi = np.array(q_min, float), np.array(q_max, float)
    for field, given, sign in (("limits.q_min", config.q_min, -1.0), ("limits.q_max", config.q_max, 1.0)):
        if given is None:
            continue
        urdf = q_min if sign < 0 else q_max
        for j, value in enumerate(given):
            if sign * (value - urdf[j]) > 1e-12:
                unit = "m" if kinds is not None and kinds[j] == "prismatic" else "rad"
                raise ValueError(f"{config.where}: {field}: {names[j]} = {value:g} {unit} is beyond the URDF's range "
                                 f"[{q_min[j]:g}, {q_max[j]:g}] {unit}")
        (lo if sign < 0 else hi)[:] = given
    if (lo > hi).any():
        j = int(np.argmax(lo > hi))
        raise ValueError(f"{config.where}: limits: {names[j]} has q_min {lo[j]:g} above q_max {hi[j]:g}")
    return lo, hi


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
    qdddot_max: np.ndarray | None = None  #: optional jerk limits (n,) rad/s^3; None: the motion rule's

    def __post_init__(self):
        n = len(self.joint_names)
        for name in ("q_min", "q_max", "qdot_max", "qddot_max", "qdddot_max"):
            if name == "qdddot_max" and self.qdddot_max is None:
                continue
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
        joints = urdf_chain(config.urdf_path, config.base_link, config.flange_link)
        names = tuple(j.name for j in joints)
        q_min, q_max = config_limits(config, names, np.array([j.lower for j in joints]),
                                     np.array([j.upper for j in joints]), [j.kind for j in joints])
        qdot = [j.velocity for j in joints] if config.qdot_max_rad_s is None else config.qdot_max_rad_s
        return cls(names, q_min, q_max, np.asarray(qdot, float),
                   np.asarray(config.qddot_max_rad_s2, float), config.qdddot_max_rad_s3)

    def check_q(self, q, name: str = "q", *, limits: bool = True, tol_rad: float = 1e-9) -> np.ndarray:
        """As :meth:`robot_models.WamKinematics.check_q`: q (n,) or (N, n) rad, validated; ValueError naming ``name``."""
        return check_joint_angles(self.joint_names, self.q_min, self.q_max, q, name, limits=limits, tol_rad=tol_rad)
