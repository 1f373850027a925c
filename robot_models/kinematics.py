"""Forward kinematics and Jacobians of a serial arm over Pinocchio, in the lab world frame.

An :class:`ArmKinematics` holds one Pinocchio ``Model`` (constant) and one ``Data`` workspace reused on
every call (Pinocchio's model/data split), plus the mount ``T_base_to_world`` that places the arm's base
link in the lab. Any URDF serves: its robot config (``data/robot/*.yaml``, robot_models/config.py) names
the base and flange links; the movable joints between them (revolute or prismatic, any number) are the
arm, every other joint of the URDF is locked (a gripper's fingers), and the four frames rt2 speaks of are
``base`` and ``flange`` (those links) and ``ball_mount`` and ``racket`` (offsets from the flange).
``WamKinematics`` is the same class (the WAM is ``data/robot/wam.yaml``, the default).
Every pose it returns is ``T_frame_to_world`` (4, 4): ``X_world = T @ X_frame``.
Single-configuration calls go through Pinocchio; the batched twins (:meth:`fk_batch`,
:meth:`link_points`) multiply the model's own joint placements (robot_models/_batch_fk.py) in a numba
kernel (``method="numba"``) with a vectorised numpy reference (``"numpy"``) and a per-configuration
Pinocchio loop (``"pinocchio"``).
Not thread-safe: one instance per thread (the workspace is shared).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from robot_models._batch_fk import fk_frames_numba, fk_frames_numpy
from robot_models.config import RobotConfig, load_robot_config
from robot_models.limits import check_joint_angles, config_limits, urdf_chain

__all__ = ["ArmKinematics", "FK_METHODS", "JACOBIAN_REFERENCES", "LINK_CHAIN", "REQUIRED_FRAMES", "WamKinematics"]

REQUIRED_FRAMES = ("base", "flange", "ball_mount", "racket")
#: The WAM's frames whose origins :meth:`ArmKinematics.link_points` returns, base to flange (capsule end
#: points); another arm's are its ``link_chain``.
LINK_CHAIN = ("base", "link_1", "link_2", "link_3", "link_4", "link_5", "link_6", "link_7", "flange")
#: ``method=`` of the batched FK: compiled kernel, its vectorised numpy twin, or a Pinocchio loop
FK_METHODS = {"numba": fk_frames_numba, "numpy": fk_frames_numpy, "pinocchio": None}
JACOBIAN_REFERENCES = {"world_aligned": pin.LOCAL_WORLD_ALIGNED, "local": pin.LOCAL, "world": pin.WORLD}
_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}
#: joint kinds of the batched FK tables (robot_models/_batch_fk.py)
REVOLUTE, PRISMATIC = 0, 1


class ArmKinematics:
    """Kinematics of a serial arm of revolute (and prismatic) joints mounted in the lab world.

    Use :meth:`from_config` (a shipped arm's name, a robot YAML or a :class:`RobotConfig`), :meth:`default`
    (the WAM) or :meth:`from_urdf`. Attributes (read-only arrays, n = ``n_joints``): ``q_min``/``q_max`` (n,)
    rad (m for a prismatic joint) from the URDF and its config, ``qdot_max`` (n,) rad/s, ``qddot_max`` (n,)
    rad/s^2, ``qdddot_max`` (n,) rad/s^3 or None, ``q_home`` (n,) rad, ``link_chain`` (the frames of
    :meth:`link_points`, n + 2), ``link_radii_m`` (n + 1,), ``T_base_to_world`` (4, 4), ``joint_names``,
    ``frame_names``, ``name`` (the config's, e.g. ``wam``).
    """

    def __init__(self, model: pin.Model, *, source: str, T_base_to_world=None, qdot_max_rad_s=None,
                 qddot_max_rad_s2=None, q_home_rad=None, link_radii_m=None, qdddot_max_rad_s3=None,
                 aliases: dict | None = None, q_min=None, q_max=None, name: str = "wam"):
        self.model = model
        self.data = model.createData()  # the one workspace, reused every call
        self.source = source
        self.name = name
        n = model.nq
        self.n_joints = n
        self.joint_names = tuple(model.names[1:])
        self.frame_names = tuple(f.name for f in model.frames)
        #: rt2's frame names (base, flange) -> the model's frame ids of the config's links
        self._aliases = dict(aliases or {})
        self.q_min = self._frozen(model.lowerPositionLimit if q_min is None else q_min, "lower limits")
        self.q_max = self._frozen(model.upperPositionLimit if q_max is None else q_max, "upper limits")
        defaults = RobotConfig()

        def default(value, name):
            if value is not None:
                return value
            if n != defaults.n_joints:
                raise ValueError(f"{source}: {name} must be given for an arm of {n} joints (the defaults are the WAM's 7)")
            return getattr(defaults, name)

        self.qdot_max = self._frozen(model.velocityLimit if qdot_max_rad_s is None else qdot_max_rad_s, "qdot_max_rad_s")
        self.qddot_max = self._frozen(default(qddot_max_rad_s2, "qddot_max_rad_s2"), "qddot_max_rad_s2")
        self.qdddot_max = None if qdddot_max_rad_s3 is None else self._frozen(qdddot_max_rad_s3, "qdddot_max_rad_s3")
        self.q_home = self._frozen(np.clip(default(q_home_rad, "q_home_rad"), self.q_min, self.q_max)
                                   if q_home_rad is None else q_home_rad, "q_home_rad")
        self.link_chain = self._link_chain()
        self.link_radii_m = self._frozen(default(link_radii_m, "link_radii_m"), "link_radii_m",
                                         size=len(self.link_chain) - 1)
        T = np.eye(4) if T_base_to_world is None else np.asarray(T_base_to_world, float)
        if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]) or \
                np.abs(T[:3, :3] @ T[:3, :3].T - np.eye(3)).max() > 1e-6 or np.linalg.det(T[:3, :3]) < 0:
            raise ValueError(f"mount must be a (4, 4) rigid transform, got {T.tolist()}")
        T.setflags(write=False)
        self.T_base_to_world = T
        # the URDF root in the lab: the mount places the base link, which may sit below the root (UR's `base`)
        base = model.frames[self.frame_id("base")]
        if base.parentJoint != 0:
            raise ValueError(f"{source}: the base link must be fixed to the URDF's root, not moved by joint "
                             f"{model.names[base.parentJoint]!r}")
        M_base = np.asarray(base.placement.homogeneous)
        T_root = T if np.array_equal(M_base, np.eye(4)) else T @ np.linalg.inv(M_base)
        T_root.setflags(write=False)
        self.T_root_to_world = T_root
        self._mount = pin.SE3(T_root[:3, :3].copy(), T_root[:3, 3].copy())
        self.check_q(self.q_home, "q_home_rad")
        # Batched-FK tables: per joint its parent, placement in the parent (4, 4), unit axis (3,), kind, q index.
        self._parents = np.array([int(p) for p in model.parents], dtype=np.int64)
        self._placements = np.stack([np.asarray(M.homogeneous) for M in model.jointPlacements])
        self._axes = np.zeros((model.njoints, 3))
        self._kinds = np.zeros(model.njoints, dtype=np.int64)
        for j in range(1, model.njoints):
            self._axes[j], self._kinds[j] = self._joint_axis(model.joints[j], model.names[j])
        self._idx_q = np.array([max(int(i), 0) for i in model.idx_qs], dtype=np.int64)
        self._frame_placements = np.stack([np.asarray(f.placement.homogeneous) for f in model.frames])
        self._frame_joints = np.array([int(f.parentJoint) for f in model.frames], dtype=np.int64)

    def _frozen(self, values, name: str, size: int | None = None) -> np.ndarray:
        size = self.n_joints if size is None else size
        arr = np.array(values, dtype=float).reshape(-1)
        if arr.shape != (size,) or not np.isfinite(arr).all():
            raise ValueError(f"{name} must be {size} finite numbers, got {np.asarray(values).tolist()}")
        arr.setflags(write=False)
        return arr

    def _link_chain(self) -> tuple[str, ...]:
        """``base``, the link each joint moves (its body frame), ``flange``: the capsules' end points."""
        bodies = []
        for j in range(1, self.model.njoints):
            names = [f.name for f in self.model.frames if f.parentJoint == j and f.type == pin.FrameType.BODY]
            bodies.append(names[0] if names else self.model.names[j])
        return ("base", *bodies, "flange")

    @staticmethod
    def _joint_axis(joint, name: str) -> tuple[np.ndarray, int]:
        short = joint.shortname()
        for kind, prefix in ((REVOLUTE, "JointModelR"), (PRISMATIC, "JointModelP")):
            for key, axis in _AXES.items():
                if short == f"{prefix}{key}":
                    return np.array(axis), kind
        if short in ("JointModelRevoluteUnaligned", "JointModelPrismaticUnaligned"):
            kind = REVOLUTE if short.startswith("JointModelRevolute") else PRISMATIC
            return np.asarray(joint.axis, float) / np.linalg.norm(joint.axis), kind
        raise ValueError(f"joint {name!r} is {short}; only 1-DOF revolute and prismatic joints are supported")

    # -- construction ----------------------------------------------------------------------------
    @classmethod
    def from_urdf(cls, path: str | Path, *, frames=REQUIRED_FRAMES, mount=None, qdot_max_rad_s=None,
                  qddot_max_rad_s2=None, q_home_rad=None, link_radii_m=None) -> "ArmKinematics":
        """Load a URDF that has rt2's frames itself (the WAM's). ``frames``: names that must exist (ValueError
        lists those present). For any other URDF write a robot config and use :meth:`from_config`.

        mount : (4, 4) ``T_base_to_world`` (default identity); see :func:`robot_models.config.mount_transform`
        qdot_max_rad_s : (n,) overrides the URDF velocity limits; the others default to RobotConfig's.
        """
        path = Path(path)
        model = _build_model(path)
        if model.nq != model.nv or model.nq == 0:
            raise ValueError(f"{path}: expected an arm of 1-DOF joints, got nq={model.nq}, nv={model.nv}")
        present = [f.name for f in model.frames]
        missing = [f for f in frames if not model.existFrame(f)]
        if missing:
            raise ValueError(f"{path}: frame(s) {missing} not found; frames present: {present}")
        return cls(model, source=str(path), T_base_to_world=mount, qdot_max_rad_s=qdot_max_rad_s,
                   qddot_max_rad_s2=qddot_max_rad_s2, q_home_rad=q_home_rad, link_radii_m=link_radii_m)

    @classmethod
    def from_config(cls, config: RobotConfig | str | Path | None = None) -> "ArmKinematics":
        """Kinematics of a :class:`RobotConfig`, a robot YAML path or a shipped arm's name (``wam``, ``panda``,
        ``ur10``, ``xarm7``; default the WAM of ``data/robot/wam.yaml``).

        Raises ValueError naming the config file and the field for a link not in the URDF, a joint without
        limits, a limit override beyond the URDF's range, per-joint values whose count differs from the
        URDF's joints, or a posture outside the limits.
        """
        if not isinstance(config, RobotConfig):
            config = load_robot_config(config)
        try:
            return cls._from_checked_config(config)
        except ValueError as exc:
            text = str(exc)
            raise ValueError(text if text.startswith(config.where) else f"{config.where}: {text}") from None

    @classmethod
    def _from_checked_config(cls, config: RobotConfig) -> "ArmKinematics":
        path = config.urdf_path
        joints = urdf_chain(path, config.base_link, config.flange_link)  # links present, limits present
        names = tuple(j.name for j in joints)
        model = _build_model(path)
        keep = set(names)
        lock = [j for j in range(1, model.njoints) if model.names[j] not in keep]
        if lock:  # joints off the chain (a gripper's fingers): fixed at their neutral position
            model = pin.buildReducedModel(model, lock, pin.neutral(model))
        if tuple(model.names[1:]) != names or model.nq != len(names) or model.nv != len(names):
            raise ValueError(f"{path}: Pinocchio's joints {list(model.names[1:])} differ from the chain {list(names)} "
                             f"from {config.base_link!r} to {config.flange_link!r}")
        q_min, q_max = config_limits(config, names, model.lowerPositionLimit, model.upperPositionLimit,
                                     [j.kind for j in joints])
        aliases = {"base": _body_frame(model, config.base_link), "flange": _body_frame(model, config.flange_link)}
        flange = model.frames[aliases["flange"]]
        for frame, xyz, rpy in (("ball_mount", config.ball_mount_xyz_m, config.ball_mount_rpy_rad),
                                ("racket", config.racket_xyz_m, config.racket_rpy_rad)):
            placement = flange.placement * pin.SE3(pin.rpy.rpyToMatrix(*rpy), np.array(xyz, float))
            if model.existFrame(frame):  # the URDF has it (the WAM's): it must be where the config says
                own = model.frames[model.getFrameId(frame)]
                if own.parentJoint != flange.parentJoint or \
                        not np.allclose(own.placement.homogeneous, placement.homogeneous, atol=1e-9, rtol=0):
                    raise ValueError(f"{frame}: the URDF's own frame {frame!r} is not at the configured offset from "
                                     f"the flange {config.flange_link!r}")
                continue
            model.addFrame(pin.Frame(frame, flange.parentJoint, aliases["flange"], placement, pin.FrameType.OP_FRAME))
        for frame in ("base", "flange"):
            if model.existFrame(frame) and model.getFrameId(frame) != aliases[frame]:
                raise ValueError(f"{frame}_link: the URDF has a frame {frame!r} of its own that is not {frame}_link "
                                 f"{getattr(config, frame + '_link')!r}; name that link as {frame}_link")
        return cls(model, source=str(path), T_base_to_world=config.T_base_to_world,
                   qdot_max_rad_s=config.qdot_max_rad_s, qddot_max_rad_s2=config.qddot_max_rad_s2,
                   qdddot_max_rad_s3=config.qdddot_max_rad_s3, q_home_rad=config.q_home_rad,
                   link_radii_m=config.link_radii_m, aliases=aliases, q_min=q_min, q_max=q_max, name=config.name)

    @classmethod
    def default(cls) -> "ArmKinematics":
        """The WAM of ``data/robot/wam.yaml`` (URDF ``robot_models/wam7.urdf``)."""
        return cls.from_config(None)

    @property
    def reach_bound_m(self) -> float:
        """How far the racket can get from the base link's origin at most, m: the lengths of the chain's steps
        (base to joint 1, joint to joint, last joint to racket) and the prismatic joints' travel added up."""
        base = self.model.frames[self.frame_id("base")].placement.translation
        steps = [np.linalg.norm(self._placements[1][:3, 3] - base)]
        steps += [np.linalg.norm(self._placements[j][:3, 3]) for j in range(2, self.model.njoints)]
        steps.append(np.linalg.norm(self._frame_placements[self.frame_id("racket")][:3, 3]))
        travel = np.maximum(np.abs(self.q_min), np.abs(self.q_max))[self._kinds[1:] == PRISMATIC]
        return float(np.sum(steps) + np.sum(travel))

    # -- validation ------------------------------------------------------------------------------
    def frame_id(self, frame: str) -> int:
        """The model's frame id of ``frame``: rt2's ``base``/``flange`` (the config's links) or any frame name."""
        if isinstance(frame, str) and frame in self._aliases:
            return self._aliases[frame]
        if not isinstance(frame, str) or not self.model.existFrame(frame):
            raise ValueError(f"unknown frame {frame!r}; frames present: {list(self.frame_names)}")
        return self.model.getFrameId(frame)

    def check_q(self, q, name: str = "q", *, limits: bool = True, tol_rad: float = 1e-9) -> np.ndarray:
        """Validate one configuration or a batch; returns a float array of the same shape.

        q : (n,) or (N, n) joint angles, rad. Raises ValueError naming ``name`` for a wrong length,
        non-finite values, or (with ``limits``) a joint outside ``[q_min - tol, q_max + tol]``.
        """
        return check_joint_angles(self.joint_names, self.q_min, self.q_max, q, name, limits=limits, tol_rad=tol_rad)

    def within_limits(self, q, tol_rad: float = 1e-9) -> np.ndarray | bool:
        """True where every joint of ``q`` (n,) or (N, n) is within the URDF limits; bool or (N,) bool."""
        arr = self.check_q(q, limits=False)
        ok = ((arr >= self.q_min - tol_rad) & (arr <= self.q_max + tol_rad)).all(axis=-1)
        return bool(ok) if arr.ndim == 1 else ok

    def clip(self, q) -> np.ndarray:
        """``q`` (n,) or (N, n) clipped into the joint limits."""
        return np.clip(self.check_q(q, limits=False), self.q_min, self.q_max)

    # -- forward kinematics ----------------------------------------------------------------------
    def fk(self, q, frame: str = "ball_mount", *, check_limits: bool = True) -> np.ndarray:
        """(4, 4) ``T_frame_to_world`` of one configuration ``q`` (n,) rad (Pinocchio, reused workspace).

        check_limits : reject joints outside the URDF limits; pass False for *reported* angles, which
        carry the zero-offset bias and may lie just outside.
        """
        fid = self.frame_id(frame)
        q = self.check_q(q, limits=check_limits)
        if q.ndim != 1:
            raise ValueError(f"q must be one configuration of shape ({self.n_joints},), got {q.shape}; use fk_batch")
        return self._fk_unchecked(q, fid)

    def _fk_unchecked(self, q: np.ndarray, fid: int) -> np.ndarray:
        pin.forwardKinematics(self.model, self.data, q)
        return self.T_root_to_world @ pin.updateFramePlacement(self.model, self.data, fid).homogeneous

    def position(self, q, frame: str = "ball_mount", *, check_limits: bool = True) -> np.ndarray:
        """(3,) origin of ``frame`` in the lab world, metres."""
        return self.fk(q, frame, check_limits=check_limits)[:3, 3]

    def fk_batch(self, Q, frame: str = "ball_mount", *, method: str = "numba", check_limits: bool = True) -> np.ndarray:
        """(N, 4, 4) ``T_frame_to_world`` for configurations ``Q`` (N, n) rad.

        method : ``"numba"`` (compiled loop), ``"numpy"`` (vectorised reference) or ``"pinocchio"``
        (a loop of single Pinocchio calls, the ground reference); all agree to 1e-12.
        """
        if method not in FK_METHODS:
            raise ValueError(f"unknown fk method {method!r}; valid: {sorted(FK_METHODS)}")
        fid = self.frame_id(frame)
        Q = self.check_q(Q, "Q", limits=check_limits)
        if Q.ndim != 2:
            raise ValueError(f"Q must have shape (N, {self.n_joints}), got {Q.shape}")
        if method == "pinocchio":
            return np.stack([self._fk_unchecked(q, fid) for q in Q]) if len(Q) else np.zeros((0, 4, 4))
        return self._fk_frames(Q, [fid], method)[:, 0]

    def positions(self, Q, frame: str = "ball_mount", *, check_limits: bool = True) -> np.ndarray:
        """(N, 3) origins of ``frame`` in the lab world for ``Q`` (N, n)."""
        return self.fk_batch(Q, frame, check_limits=check_limits)[:, :3, 3]

    def _fk_frames(self, Q: np.ndarray, fids: list[int], method: str = "numba") -> np.ndarray:
        """(N, len(fids), 4, 4) world poses of frames ``fids`` for trusted ``Q`` (N, nq)."""
        kernel = FK_METHODS[method]
        sel = np.asarray(fids, dtype=np.int64)
        return kernel(np.ascontiguousarray(Q, dtype=float), np.ascontiguousarray(self.T_root_to_world), self._placements,
                      self._axes, self._kinds, self._parents, self._idx_q, self._frame_placements[sel],
                      self._frame_joints[sel])

    def link_points(self, q, frames=None, *, check_limits: bool = True) -> np.ndarray:
        """Origins of ``frames`` (default ``link_chain``: base, the link of each joint, flange) in the lab world, m.

        q : (n,) or (N, n) rad. Returns (len(frames), 3) or (N, len(frames), 3). Consecutive points are
        the end points of capsules of radius ``link_radii_m`` (len(frames) - 1,) for rendering.
        """
        frames = self.link_chain if frames is None else frames
        fids = [self.frame_id(f) for f in frames]
        q = self.check_q(q, limits=check_limits)
        Q = q[None] if q.ndim == 1 else q
        pts = self._fk_frames(Q, fids)[:, :, :3, 3]
        return pts[0] if q.ndim == 1 else pts

    # -- Jacobian --------------------------------------------------------------------------------
    def jacobian(self, q, frame: str = "ball_mount", reference: str = "world_aligned") -> np.ndarray:
        """(6, n) frame Jacobian, rows ``[linear velocity (3); angular velocity (3)]``, per rad/s.

        reference : ``"world_aligned"`` (velocity of the frame origin in lab-world axes, the default),
        ``"local"`` (in the frame's own axes), or ``"world"`` (spatial velocity at the lab-world origin).
        """
        if reference not in JACOBIAN_REFERENCES:
            raise ValueError(f"unknown Jacobian reference {reference!r}; valid: {list(JACOBIAN_REFERENCES)}")
        fid = self.frame_id(frame)
        q = self.check_q(q)
        if q.ndim != 1:
            raise ValueError(f"q must be one configuration of shape ({self.n_joints},), got {q.shape}")
        return self._jacobian_unchecked(q, fid, reference)

    def _jacobian_unchecked(self, q: np.ndarray, fid: int, reference: str) -> np.ndarray:
        J = pin.computeFrameJacobian(self.model, self.data, q, fid, JACOBIAN_REFERENCES[reference])
        if reference == "local":
            return J
        if reference == "world":
            return self._mount.toActionMatrix() @ J
        R = self.T_root_to_world[:3, :3]  # world_aligned in root axes -> lab-world axes
        return np.vstack([R @ J[:3], R @ J[3:]])

    def fk_and_jacobian(self, q: np.ndarray, fid: int) -> tuple[np.ndarray, np.ndarray]:
        """Trusted inner call for solvers: ``(T_frame_to_world (4, 4), world-aligned J (6, n))`` of frame id ``fid``."""
        J = self._jacobian_unchecked(q, fid, "world_aligned")  # also updates data.oMf[fid]
        return self.T_root_to_world @ self.data.oMf[fid].homogeneous, J

    def ik(self, position_world_m, frame: str = "racket", **kwargs):
        """Damped-least-squares IK; see :func:`robot_models.ik.solve_ik`. Returns ``(q (n,), IkInfo)``."""
        from robot_models.ik import solve_ik

        return solve_ik(self, position_world_m, frame, **kwargs)

    def __repr__(self) -> str:
        return f"ArmKinematics({self.name!r}, {self.source!r}, n_joints={self.n_joints})"


#: The WAM's name for :class:`ArmKinematics` (``WamKinematics.default()`` is the WAM).
WamKinematics = ArmKinematics


def _build_model(path: Path) -> pin.Model:
    if not path.is_file():
        raise FileNotFoundError(f"URDF not found: {path}")
    try:
        return pin.buildModelFromUrdf(str(path))
    except Exception as exc:  # Pinocchio raises RuntimeError/ValueError with parser text
        raise ValueError(f"{path}: not a valid URDF ({exc})") from exc


def _body_frame(model: pin.Model, link: str) -> int:
    """The frame id of URDF link ``link`` (its BODY frame)."""
    for i, f in enumerate(model.frames):
        if f.name == link and f.type == pin.FrameType.BODY:
            return i
    raise ValueError(f"link {link!r} has no frame in the model")
