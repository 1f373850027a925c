"""Robot configuration: which URDF, how the arm is mounted in the lab, and the limits Barrett does not publish.

File format (``data/robot/wam.yaml``, documented in docs/robot.md)::

    format: rt2.robot
    version: 1
    description: free text
    urdf: ../../robot_models/wam7.urdf        # relative to this file (or absolute)
    mount: {xyz_m: [x, y, z], rpy_rad: [roll, pitch, yaw]}   # pose of URDF `base` in the lab world
    limits:
      qdot_max_rad_s: [7 values]               # velocity limits
      qddot_max_rad_s2: [7 values]             # acceleration limits
    q_home_rad: [7 values]                     # rest posture: IK null-space target, simulator start
    render: {link_radii_m: [8 values]}         # capsule radius per segment of Kinematics.link_points
    simulator: {...}                           # options of harness.sim.robot.SimulatedWam (read there)

Every field but ``format``/``version`` has a default (the values below). Lengths metres, angles
radians, roll-pitch-yaw as in URDF: ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import reprlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from checks.files import load_yaml_checked

__all__ = ["DEFAULT_CONFIG_PATH", "DEFAULT_URDF_PATH", "RobotConfig", "load_robot_config", "mount_transform"]

FORMAT = "rt2.robot"
VERSION = 1
DEFAULT_URDF_PATH = Path(__file__).resolve().parent / "wam7.urdf"
DEFAULT_CONFIG_PATH = Path(__file__).resolve().parents[1] / "data" / "robot" / "wam.yaml"

_TOP_KEYS = {"format", "version", "description", "urdf", "mount", "limits", "q_home_rad", "render", "simulator"}


def _tup(values) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


@dataclass(frozen=True)
class RobotConfig:
    """Validated robot configuration (see module docstring). Arrays are tuples so the object is hashable."""

    urdf_path: Path = DEFAULT_URDF_PATH
    #: pose of the URDF ``base`` in the lab world: upright on a 0.70 m pedestal, 0.38 m behind the
    #: robot's table end, base x towards the opponent (docs/robot.md, "Mount")
    mount_xyz_m: tuple = (-1.75, 0.0, 0.70)
    mount_rpy_rad: tuple = (0.0, 0.0, 0.0)
    #: measured on a table-tennis WAM; Barrett publishes none
    qdot_max_rad_s: tuple = (3.2, 6.3, 10.0, 10.0, 24.0, 19.0, 27.0)
    qddot_max_rad_s2: tuple = (6.8, 11.5, 17.0, 21.5, 84.0, 110.0, 100.0)
    #: ready posture: racket near (-1.35, 0, 1.1) m facing the opponent (+x)
    q_home_rad: tuple = (-0.1, 0.4, -0.26, 2.32, 0.87, 0.88, 2.07)
    #: capsule radii for base->link_1, link_1->link_2, ..., link_7->flange (estimates of the WAM's covers)
    link_radii_m: tuple = (0.10, 0.10, 0.10, 0.055, 0.05, 0.045, 0.04, 0.04)
    #: raw ``simulator`` mapping, validated by harness.sim.robot.SimWamOptions
    simulator: dict = field(default_factory=dict, hash=False, compare=False)
    description: str = ""

    def __post_init__(self):
        for name, n in (("mount_xyz_m", 3), ("mount_rpy_rad", 3), ("qdot_max_rad_s", 7),
                        ("qddot_max_rad_s2", 7), ("q_home_rad", 7), ("link_radii_m", 8)):
            value = getattr(self, name)
            try:
                arr = np.asarray(value, dtype=float)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{name} must be {n} numbers, got {reprlib.repr(value)}") from exc
            if arr.shape != (n,):
                raise ValueError(f"{name} must have {n} values, got {arr.size} ({reprlib.repr(value)})")
            if not np.isfinite(arr).all():
                raise ValueError(f"{name} must be finite, got {reprlib.repr(value)}")
            object.__setattr__(self, name, _tup(arr))
        for name in ("qdot_max_rad_s", "qddot_max_rad_s2", "link_radii_m"):
            if min(getattr(self, name)) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        object.__setattr__(self, "urdf_path", Path(self.urdf_path))

    @property
    def T_base_to_world(self) -> np.ndarray:
        """(4, 4) pose of the URDF base in the lab world: ``X_world = T @ X_base``."""
        return mount_transform(self.mount_xyz_m, self.mount_rpy_rad)


def mount_transform(xyz_m, rpy_rad) -> np.ndarray:
    """(4, 4) homogeneous transform from a translation (3,) in metres and URDF roll-pitch-yaw (3,) in radians."""
    r, p, y = (float(v) for v in rpy_rad)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    T = np.eye(4)
    T[:3, :3] = [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                 [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                 [-sp, cp * sr, cp * cr]]
    T[:3, 3] = [float(v) for v in xyz_m]
    return T


def load_robot_config(path: str | Path | None = None) -> RobotConfig:
    """Read and validate a robot YAML file (default ``data/robot/wam.yaml``).

    Raises FileNotFoundError if ``path`` does not exist and ValueError naming the file and field for
    anything malformed (unknown keys included, so a misspelt field fails loudly).
    """
    path = Path(path) if path is not None else DEFAULT_CONFIG_PATH
    if not path.is_file():
        raise FileNotFoundError(f"robot config not found: {path}")
    doc = load_yaml_checked(path, "robot config")  # capped, alias-free (docs/reliability.md)
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a mapping at top level, got {type(doc).__name__}")
    if doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise ValueError(f"{path}: expected format: {FORMAT} and version: {VERSION}, "
                         f"got format: {doc.get('format')!r}, version: {doc.get('version')!r}")
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise ValueError(f"{path}: unknown field(s) {unknown}; valid: {sorted(_TOP_KEYS)}")
    kw: dict[str, Any] = {"description": str(doc.get("description", "") or "")}
    if doc.get("urdf") is not None:
        urdf = Path(str(doc["urdf"]))
        kw["urdf_path"] = (urdf if urdf.is_absolute() else path.parent / urdf).resolve()
    sections = {"mount": {"xyz_m": "mount_xyz_m", "rpy_rad": "mount_rpy_rad"},
                "limits": {"qdot_max_rad_s": "qdot_max_rad_s", "qddot_max_rad_s2": "qddot_max_rad_s2"},
                "render": {"link_radii_m": "link_radii_m"}}
    for section, fields in sections.items():
        sub = doc.get(section)
        if sub is None:
            continue
        if not isinstance(sub, dict):
            raise ValueError(f"{path}: {section} must be a mapping, got {sub!r}")
        bad = sorted(set(sub) - set(fields))
        if bad:
            raise ValueError(f"{path}: unknown field(s) {bad} in {section}; valid: {sorted(fields)}")
        for key, attr in fields.items():
            if key in sub:
                kw[attr] = sub[key]
    if doc.get("q_home_rad") is not None:
        kw["q_home_rad"] = doc["q_home_rad"]
    sim = doc.get("simulator")
    if sim is not None and not isinstance(sim, dict):
        raise ValueError(f"{path}: simulator must be a mapping, got {sim!r}")
    kw["simulator"] = dict(sim or {})
    try:
        return RobotConfig(**kw)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
