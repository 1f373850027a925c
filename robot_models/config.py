"""Robot configuration: which URDF, which of its links make the arm, how it is mounted in the lab, its limits.

One YAML file per arm in ``data/robot/`` (``wam.yaml``, ``panda.yaml``, ``ur10.yaml``, ``xarm7.yaml``; the
format is documented in docs/robots.md)::

    format: rt2.robot
    version: 1
    description: free text
    urdf: ../../robot_models/wam7.urdf        # relative to this file, absolute, or a resource of an
                                               # installed package: {package: NAME, path: PATH}
    base_link: base                            # the URDF link the mount places in the lab
    flange_link: flange                        # the tool flange (UR tool0, Panda panda_link8, ...)
    ball_mount: {xyz_m: [x, y, z], rpy_rad: [r, p, y]}   # the ball's centre, from the flange
    racket: {xyz_m: [x, y, z], rpy_rad: [r, p, y]}       # the racket frame (z = its normal), from the flange
    mount: {xyz_m: [x, y, z], rpy_rad: [roll, pitch, yaw]}   # pose of base_link in the lab world
    limits:
      q_min: [n values]                        # optional: narrower position limits than the URDF's
      q_max: [n values]                        #   (rad, m for a prismatic joint)
      qdot_max_rad_s: [n values]               # velocity limits
      qddot_max_rad_s2: [n values]             # acceleration limits
      qdddot_max_rad_s3: [n values]            # optional jerk limits (default: the motion rule's ramp)
    q_home_rad: [n values]                     # rest posture: IK null-space target, simulator start
    render: {link_radii_m: [n + 1 values]}     # capsule radius per segment of ArmKinematics.link_points
    simulator: {...}                           # options of harness.sim.robot.SimulatedWam (read there)

``n`` is the number of joints from ``base_link`` to ``flange_link``; the lengths are checked against each
other here and against the URDF when the kinematics load it. Every field but ``format``/``version`` has a
default, the WAM's (the values below); a config of another URDF must give ``q_home_rad``,
``limits.qddot_max_rad_s2`` and ``render.link_radii_m`` (a URDF has no such thing), and its velocity limits
default to the URDF's. Lengths metres, angles radians, roll-pitch-yaw as in URDF:
``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import math
import reprlib
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from checks.files import load_yaml_checked

__all__ = ["DEFAULT_CONFIG_PATH", "DEFAULT_ROBOT", "DEFAULT_URDF_PATH", "ROBOT_CONFIG_DIR", "RobotConfig",
           "load_robot_config", "mount_transform", "package_resource", "resolve_robot_config", "robot_names"]

FORMAT = "rt2.robot"
VERSION = 1
DEFAULT_URDF_PATH = Path(__file__).resolve().parent / "wam7.urdf"
ROBOT_CONFIG_DIR = Path(__file__).resolve().parents[1] / "data" / "robot"
DEFAULT_ROBOT = "wam"
DEFAULT_CONFIG_PATH = ROBOT_CONFIG_DIR / f"{DEFAULT_ROBOT}.yaml"

_TOP_KEYS = {"format", "version", "description", "urdf", "base_link", "flange_link", "ball_mount", "racket",
             "mount", "limits", "q_home_rad", "render", "simulator"}
#: per-joint fields: length n (the joints' count); link_radii_m has n + 1
_PER_JOINT = ("q_home_rad", "qdot_max_rad_s", "qddot_max_rad_s2", "qdddot_max_rad_s3", "q_min", "q_max")
_POSITIVE = ("qdot_max_rad_s", "qddot_max_rad_s2", "qdddot_max_rad_s3", "link_radii_m")


def _tup(values) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def _numbers(name: str, value, n: int | None, why: str = "") -> tuple[float, ...]:
    """``value`` as a tuple of finite floats (of length ``n`` when given); ValueError naming ``name``."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be {n if n else 'a list of'} numbers, got {reprlib.repr(value)}") from exc
    if arr.ndim != 1 or (n is not None and arr.shape != (n,)):
        want = f"{n} values{why}" if n is not None else "a list of numbers"
        raise ValueError(f"{name} must have {want}, got {arr.size} ({reprlib.repr(value)})")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {reprlib.repr(value)}")
    return _tup(arr)


@dataclass(frozen=True)
class RobotConfig:
    """Validated robot configuration (see module docstring). Arrays are tuples so the object is hashable.

    The defaults are the WAM of ``data/robot/wam.yaml``. ``name`` is the file's stem (``wam``) and ``path`` the
    file (None for a config made in code); error messages name both.
    """

    urdf_path: Path = DEFAULT_URDF_PATH
    base_link: str = "base"
    flange_link: str = "flange"
    #: the ball's centre on the flange's z (tool) axis: a 40 mm ball on a 25 mm stem
    ball_mount_xyz_m: tuple = (0.0, 0.0, 0.045)
    ball_mount_rpy_rad: tuple = (0.0, 0.0, 0.0)
    #: racket centre 0.16 m along the tool axis; its z (the racket normal) = flange x
    racket_xyz_m: tuple = (0.0, 0.0, 0.16)
    racket_rpy_rad: tuple = (0.0, math.pi / 2, 0.0)
    #: pose of the base link in the lab world: upright on a 0.70 m pedestal, 0.38 m behind the
    #: robot's table end, base x towards the opponent (docs/robot.md, "Mount")
    mount_xyz_m: tuple = (-1.75, 0.0, 0.70)
    mount_rpy_rad: tuple = (0.0, 0.0, 0.0)
    #: optional position limits narrower than the URDF's (None: the URDF's)
    q_min: tuple | None = None
    q_max: tuple | None = None
    #: measured on a table-tennis WAM; Barrett publishes none (None: the URDF's velocity limits)
    qdot_max_rad_s: tuple | None = (3.2, 6.3, 10.0, 10.0, 24.0, 19.0, 27.0)
    qddot_max_rad_s2: tuple = (6.8, 11.5, 17.0, 21.5, 84.0, 110.0, 100.0)
    #: optional jerk limits (None: the motion rule's, qddot_max / jerk_ramp_s)
    qdddot_max_rad_s3: tuple | None = None
    #: ready posture: racket near (-1.35, 0, 1.1) m facing the opponent (+x)
    q_home_rad: tuple = (-0.1, 0.4, -0.26, 2.32, 0.87, 0.88, 2.07)
    #: capsule radii for base->link_1, link_1->link_2, ..., link_7->flange (estimates of the WAM's covers)
    link_radii_m: tuple = (0.10, 0.10, 0.10, 0.055, 0.05, 0.045, 0.04, 0.04)
    #: raw ``simulator`` mapping, validated by harness.sim.robot.SimWamOptions
    simulator: dict = field(default_factory=dict, hash=False, compare=False)
    description: str = ""
    name: str = DEFAULT_ROBOT
    path: Path | None = field(default=None, compare=False)

    def __post_init__(self):
        for name in ("mount_xyz_m", "mount_rpy_rad", "ball_mount_xyz_m", "ball_mount_rpy_rad", "racket_xyz_m",
                     "racket_rpy_rad"):
            object.__setattr__(self, name, _numbers(name, getattr(self, name), 3))
        home = _numbers("q_home_rad", self.q_home_rad, None)
        n = len(home)
        if n == 0:
            raise ValueError("q_home_rad must have one value per joint, got none")
        for name in _PER_JOINT:
            value = getattr(self, name)
            if value is not None or name == "qddot_max_rad_s2":
                object.__setattr__(self, name, _numbers(name, value, n, " (one per joint, as q_home_rad)"))
        object.__setattr__(self, "link_radii_m", _numbers("link_radii_m", self.link_radii_m, n + 1,
                                                          " (one per joint + 1, as q_home_rad)"))
        for name in _POSITIVE:
            value = getattr(self, name)
            if value is not None and min(value) <= 0:
                raise ValueError(f"{name} must be positive, got {value}")
        if self.q_min is not None and self.q_max is not None and any(a > b for a, b in zip(self.q_min, self.q_max)):
            raise ValueError(f"limits.q_min must not exceed limits.q_max, got {self.q_min} and {self.q_max}")
        for name in ("base_link", "flange_link"):
            if not isinstance(getattr(self, name), str) or not getattr(self, name):
                raise ValueError(f"{name} must be a link name, got {getattr(self, name)!r}")
        object.__setattr__(self, "urdf_path", Path(self.urdf_path))

    @property
    def n_joints(self) -> int:
        return len(self.q_home_rad)

    @property
    def where(self) -> str:
        """What error messages name: the file, or ``robot config NAME`` for one made in code."""
        return str(self.path) if self.path is not None else f"robot config {self.name!r}"

    @property
    def T_base_to_world(self) -> np.ndarray:
        """(4, 4) pose of the base link in the lab world: ``X_world = T @ X_base``."""
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


def robot_names() -> list[str]:
    """The arms shipped in ``data/robot/`` (file stems), sorted."""
    return sorted(p.stem for p in ROBOT_CONFIG_DIR.glob("*.yaml"))


def resolve_robot_config(spec: str | Path | None) -> Path:
    """The YAML file of ``--robot NAME|PATH.yaml``: a shipped arm's name, or a path (None: the WAM).

    Raises ValueError listing the shipped arms for an unknown name, FileNotFoundError for a missing file.
    """
    if spec is None:
        return DEFAULT_CONFIG_PATH
    text = str(spec)
    if isinstance(spec, Path) or text.endswith((".yaml", ".yml")) or "/" in text or "\\" in text:
        path = Path(text)
        if not path.is_file():
            raise FileNotFoundError(f"robot config not found: {path}")
        return path
    path = ROBOT_CONFIG_DIR / f"{text}.yaml"
    if not path.is_file():
        raise ValueError(f"unknown robot {text!r}; shipped: {robot_names()} (or give a PATH.yaml; docs/robots.md)")
    return path


def package_resource(package: str, resource: str) -> Path:
    """The file ``resource`` of the installed distribution ``package`` (e.g. a URDF of ``example-robot-data``).

    Looks through the distribution's own file list (no import, no network). Raises ValueError when the
    package is not installed or holds no such file.
    """
    try:
        dist = metadata.distribution(package)
    except metadata.PackageNotFoundError:
        raise ValueError(f"package {package!r} is not installed (for the shipped arms: pip install 'rt2[robots]')") from None
    want = "/" + resource.strip("/")
    for entry in dist.files or ():
        if ("/" + str(entry)).endswith(want):
            return Path(dist.locate_file(entry)).resolve()
    raise ValueError(f"package {package!r} has no file {resource!r}")


def _urdf_path(value, path: Path) -> Path:
    if isinstance(value, dict):
        bad = sorted(set(value) - {"package", "path"})
        if bad or not isinstance(value.get("package"), str) or not isinstance(value.get("path"), str):
            raise ValueError(f"{path}: urdf must be a path or {{package: NAME, path: PATH}}, got {reprlib.repr(value)}")
        try:
            return package_resource(value["package"], value["path"])
        except ValueError as exc:
            raise ValueError(f"{path}: urdf: {exc}") from None
    if not isinstance(value, str):
        raise ValueError(f"{path}: urdf must be a path or {{package: NAME, path: PATH}}, got {reprlib.repr(value)}")
    urdf = Path(value)
    return (urdf if urdf.is_absolute() else path.parent / urdf).resolve()


_SECTIONS = {"mount": {"xyz_m": "mount_xyz_m", "rpy_rad": "mount_rpy_rad"},
             "ball_mount": {"xyz_m": "ball_mount_xyz_m", "rpy_rad": "ball_mount_rpy_rad"},
             "racket": {"xyz_m": "racket_xyz_m", "rpy_rad": "racket_rpy_rad"},
             "limits": {"q_min": "q_min", "q_max": "q_max", "qdot_max_rad_s": "qdot_max_rad_s",
                        "qddot_max_rad_s2": "qddot_max_rad_s2", "qdddot_max_rad_s3": "qdddot_max_rad_s3"},
             "render": {"link_radii_m": "link_radii_m"}}


def load_robot_config(path: str | Path | None = None) -> RobotConfig:
    """Read and validate a robot YAML file: a path, a shipped arm's name (``panda``), or None (the WAM).

    Raises FileNotFoundError if the file does not exist and ValueError naming the file and field for
    anything malformed (unknown keys included, so a misspelt field fails loudly).
    """
    path = resolve_robot_config(path)
    doc = load_yaml_checked(path, "robot config")  # capped, alias-free (docs/reliability.md)
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a mapping at top level, got {type(doc).__name__}")
    if doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise ValueError(f"{path}: expected format: {FORMAT} and version: {VERSION}, "
                         f"got format: {doc.get('format')!r}, version: {doc.get('version')!r}")
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise ValueError(f"{path}: unknown field(s) {unknown}; valid: {sorted(_TOP_KEYS)}")
    kw: dict[str, Any] = {"description": str(doc.get("description", "") or ""), "name": path.stem, "path": path}
    if doc.get("urdf") is not None:
        kw["urdf_path"] = _urdf_path(doc["urdf"], path)
    for key in ("base_link", "flange_link"):
        if key in doc:
            kw[key] = doc[key]
    for section, fields in _SECTIONS.items():
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
    if "urdf_path" in kw and kw["urdf_path"] != DEFAULT_URDF_PATH:  # another arm: what a URDF cannot say is required
        given = {"q_home_rad": "q_home_rad" in kw, "limits.qddot_max_rad_s2": "qddot_max_rad_s2" in kw,
                 "render.link_radii_m": "link_radii_m" in kw}
        missing = [k for k, v in given.items() if not v]
        if missing:
            raise ValueError(f"{path}: {', '.join(missing)} must be given for an arm other than the WAM (a URDF has no "
                             "such field; docs/robots.md)")
        kw.setdefault("qdot_max_rad_s", None)  # the URDF's velocity limits
    sim = doc.get("simulator")
    if sim is not None and not isinstance(sim, dict):
        raise ValueError(f"{path}: simulator must be a mapping, got {sim!r}")
    kw["simulator"] = dict(sim or {})
    try:
        return RobotConfig(**kw)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
