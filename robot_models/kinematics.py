"""Forward kinematics and Jacobians of the WAM over Pinocchio, in the lab world frame.

A :class:`WamKinematics` holds one Pinocchio ``Model`` (constant) and one ``Data`` workspace reused on
every call (Pinocchio's model/data split), plus the mount ``T_base_to_world`` that places the URDF
``base`` in the lab. Every pose it returns is ``T_frame_to_world`` (4, 4): ``X_world = T @ X_frame``.
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
from robot_models.limits import check_joint_angles

__all__ = ["FK_METHODS", "JACOBIAN_REFERENCES", "LINK_CHAIN", "REQUIRED_FRAMES", "WamKinematics"]

REQUIRED_FRAMES = ("base", "flange", "ball_mount", "racket")
#: Frames whose origins :meth:`WamKinematics.link_points` returns, base to flange (capsule end points).
LINK_CHAIN = ("base", "link_1", "link_2", "link_3", "link_4", "link_5", "link_6", "link_7", "flange")
#: ``method=`` of the batched FK: compiled kernel, its vectorised numpy twin, or a Pinocchio loop
FK_METHODS = {"numba": fk_frames_numba, "numpy": fk_frames_numpy, "pinocchio": None}
JACOBIAN_REFERENCES = {"world_aligned": pin.LOCAL_WORLD_ALIGNED, "local": pin.LOCAL, "world": pin.WORLD}
_AXES = {"RX": (1.0, 0.0, 0.0), "RY": (0.0, 1.0, 0.0), "RZ": (0.0, 0.0, 1.0)}


class WamKinematics:
    """Kinematics of a serial arm of revolute joints (the 7-DOF WAM) mounted in the lab world.

    Use :meth:`default`, :meth:`from_config` or :meth:`from_urdf`. Attributes (read-only arrays):
    ``q_min``/``q_max`` (7,) rad from the URDF, ``qdot_max`` (7,) rad/s, ``qddot_max`` (7,) rad/s^2,
    ``q_home`` (7,) rad, ``link_radii_m`` (8,), ``T_base_to_world`` (4, 4), ``joint_names``, ``frame_names``.
    """

    def __init__(self, model: pin.Model, *, source: str, T_base_to_world=None, qdot_max_rad_s=None,
                 qddot_max_rad_s2=None, q_home_rad=None, link_radii_m=None):
        self.model = model
        self.data = model.createData()  # the one workspace, reused every call
        self.source = source
        n = model.nq
        self.n_joints = n
        self.joint_names = tuple(model.names[1:])
        self.frame_names = tuple(f.name for f in model.frames)
        self.q_min = self._frozen(model.lowerPositionLimit, "lower limits")
        self.q_max = self._frozen(model.upperPositionLimit, "upper limits")
        defaults = RobotConfig()
        self.qdot_max = self._frozen(model.velocityLimit if qdot_max_rad_s is None else qdot_max_rad_s, "qdot_max_rad_s")
        self.qddot_max = self._frozen(defaults.qddot_max_rad_s2 if qddot_max_rad_s2 is None else qddot_max_rad_s2,
                                      "qddot_max_rad_s2")
        self.q_home = self._frozen(np.clip(defaults.q_home_rad, self.q_min, self.q_max) if q_home_rad is None
                                   else q_home_rad, "q_home_rad")
        self.link_radii_m = self._frozen(defaults.link_radii_m if link_radii_m is None else link_radii_m,
                                         "link_radii_m", size=len(LINK_CHAIN) - 1)
        T = np.eye(4) if T_base_to_world is None else np.asarray(T_base_to_world, float)
        if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]) or \
                np.abs(T[:3, :3] @ T[:3, :3].T - np.eye(3)).max() > 1e-6 or np.linalg.det(T[:3, :3]) < 0:
            raise ValueError(f"mount must be a (4, 4) rigid transform, got {T.tolist()}")
        T.setflags(write=False)
        self.T_base_to_world = T
        self._mount = pin.SE3(T[:3, :3].copy(), T[:3, 3].copy())
        self.check_q(self.q_home, "q_home_rad")
        # Batched-FK tables: per joint its parent, placement in the parent (4, 4), unit axis (3,), q index.
        self._parents = np.array([int(p) for p in model.parents], dtype=np.int64)
        self._placements = np.stack([np.asarray(M.homogeneous) for M in model.jointPlacements])
        self._axes = np.zeros((model.njoints, 3))
        for j in range(1, model.njoints):
            self._axes[j] = self._joint_axis(model.joints[j], model.names[j])
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

    @staticmethod
    def _joint_axis(joint, name: str) -> np.ndarray:
        short = joint.shortname()
        for key, axis in _AXES.items():
            if short == f"JointModel{key}":
                return np.array(axis)
        if short == "JointModelRevoluteUnaligned":
            return np.asarray(joint.axis, float) / np.linalg.norm(joint.axis)
        raise ValueError(f"joint {name!r} is {short}; only 1-DOF revolute joints are supported")

    # -- construction ----------------------------------------------------------------------------
    @classmethod
    def from_urdf(cls, path: str | Path, *, frames=REQUIRED_FRAMES, mount=None, qdot_max_rad_s=None,
                  qddot_max_rad_s2=None, q_home_rad=None, link_radii_m=None) -> "WamKinematics":
        """Load a URDF once. ``frames``: names that must exist (ValueError lists those present).

        mount : (4, 4) ``T_base_to_world`` (default identity); see :func:`robot_models.config.mount_transform`
        qdot_max_rad_s : (7,) overrides the URDF velocity limits; the others default to RobotConfig's.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"URDF not found: {path}")
        try:
            model = pin.buildModelFromUrdf(str(path))
        except Exception as exc:  # Pinocchio raises RuntimeError/ValueError with parser text
            raise ValueError(f"{path}: not a valid URDF ({exc})") from exc
        if model.nq != model.nv or model.nq == 0:
            raise ValueError(f"{path}: expected an arm of 1-DOF revolute joints, got nq={model.nq}, nv={model.nv}")
        present = [f.name for f in model.frames]
        missing = [f for f in frames if not model.existFrame(f)]
        if missing:
            raise ValueError(f"{path}: frame(s) {missing} not found; frames present: {present}")
        return cls(model, source=str(path), T_base_to_world=mount, qdot_max_rad_s=qdot_max_rad_s,
                   qddot_max_rad_s2=qddot_max_rad_s2, q_home_rad=q_home_rad, link_radii_m=link_radii_m)

    @classmethod
    def from_config(cls, config: RobotConfig | str | Path | None = None) -> "WamKinematics":
        """Kinematics from a :class:`RobotConfig` or robot YAML path (default ``data/robot/wam.yaml``)."""
        if not isinstance(config, RobotConfig):
            config = load_robot_config(config)
        return cls.from_urdf(config.urdf_path, mount=config.T_base_to_world, qdot_max_rad_s=config.qdot_max_rad_s,
                             qddot_max_rad_s2=config.qddot_max_rad_s2, q_home_rad=config.q_home_rad,
                             link_radii_m=config.link_radii_m)

    @classmethod
    def default(cls) -> "WamKinematics":
        """The WAM of ``data/robot/wam.yaml`` (URDF ``robot_models/wam7.urdf``)."""
        return cls.from_config(None)

    # -- validation ------------------------------------------------------------------------------
    def frame_id(self, frame: str) -> int:
        if not isinstance(frame, str) or not self.model.existFrame(frame):
            raise ValueError(f"unknown frame {frame!r}; frames present: {list(self.frame_names)}")
        return self.model.getFrameId(frame)

    def check_q(self, q, name: str = "q", *, limits: bool = True, tol_rad: float = 1e-9) -> np.ndarray:
        """Validate one configuration or a batch; returns a float array of the same shape.

        q : (7,) or (N, 7) joint angles, rad. Raises ValueError naming ``name`` for a wrong length,
        non-finite values, or (with ``limits``) a joint outside ``[q_min - tol, q_max + tol]``.
        """
        return check_joint_angles(self.joint_names, self.q_min, self.q_max, q, name, limits=limits, tol_rad=tol_rad)

    def within_limits(self, q, tol_rad: float = 1e-9) -> np.ndarray | bool:
        """True where every joint of ``q`` (7,) or (N, 7) is within the URDF limits; bool or (N,) bool."""
        arr = self.check_q(q, limits=False)
        ok = ((arr >= self.q_min - tol_rad) & (arr <= self.q_max + tol_rad)).all(axis=-1)
        return bool(ok) if arr.ndim == 1 else ok

    def clip(self, q) -> np.ndarray:
        """``q`` (7,) or (N, 7) clipped into the joint limits."""
        return np.clip(self.check_q(q, limits=False), self.q_min, self.q_max)

    # -- forward kinematics ----------------------------------------------------------------------
    def fk(self, q, frame: str = "ball_mount", *, check_limits: bool = True) -> np.ndarray:
        """(4, 4) ``T_frame_to_world`` of one configuration ``q`` (7,) rad (Pinocchio, reused workspace).

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
        return self.T_base_to_world @ pin.updateFramePlacement(self.model, self.data, fid).homogeneous

    def position(self, q, frame: str = "ball_mount", *, check_limits: bool = True) -> np.ndarray:
        """(3,) origin of ``frame`` in the lab world, metres."""
        return self.fk(q, frame, check_limits=check_limits)[:3, 3]

    def fk_batch(self, Q, frame: str = "ball_mount", *, method: str = "numba", check_limits: bool = True) -> np.ndarray:
        """(N, 4, 4) ``T_frame_to_world`` for configurations ``Q`` (N, 7) rad.

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
        """(N, 3) origins of ``frame`` in the lab world for ``Q`` (N, 7)."""
        return self.fk_batch(Q, frame, check_limits=check_limits)[:, :3, 3]

    def _fk_frames(self, Q: np.ndarray, fids: list[int], method: str = "numba") -> np.ndarray:
        """(N, len(fids), 4, 4) world poses of frames ``fids`` for trusted ``Q`` (N, nq)."""
        kernel = FK_METHODS[method]
        sel = np.asarray(fids, dtype=np.int64)
        return kernel(np.ascontiguousarray(Q, dtype=float), np.ascontiguousarray(self.T_base_to_world), self._placements,
                      self._axes, self._parents, self._idx_q, self._frame_placements[sel], self._frame_joints[sel])

    def link_points(self, q, frames=LINK_CHAIN, *, check_limits: bool = True) -> np.ndarray:
        """Origins of ``frames`` (default base, link_1..link_7, flange) in the lab world, metres.

        q : (7,) or (N, 7) rad. Returns (len(frames), 3) or (N, len(frames), 3). Consecutive points are
        the end points of capsules of radius ``link_radii_m`` (len(frames) - 1,) for rendering.
        """
        fids = [self.frame_id(f) for f in frames]
        q = self.check_q(q, limits=check_limits)
        Q = q[None] if q.ndim == 1 else q
        pts = self._fk_frames(Q, fids)[:, :, :3, 3]
        return pts[0] if q.ndim == 1 else pts

    # -- Jacobian --------------------------------------------------------------------------------
    def jacobian(self, q, frame: str = "ball_mount", reference: str = "world_aligned") -> np.ndarray:
        """(6, 7) frame Jacobian, rows ``[linear velocity (3); angular velocity (3)]``, per rad/s.

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
        R = self.T_base_to_world[:3, :3]  # world_aligned in base axes -> lab-world axes
        return np.vstack([R @ J[:3], R @ J[3:]])

    def fk_and_jacobian(self, q: np.ndarray, fid: int) -> tuple[np.ndarray, np.ndarray]:
        """Trusted inner call for solvers: ``(T_frame_to_world (4, 4), world-aligned J (6, 7))`` of frame id ``fid``."""
        J = self._jacobian_unchecked(q, fid, "world_aligned")  # also updates data.oMf[fid]
        return self.T_base_to_world @ self.data.oMf[fid].homogeneous, J

    def ik(self, position_world_m, frame: str = "racket", **kwargs):
        """Damped-least-squares IK; see :func:`robot_models.ik.solve_ik`. Returns ``(q (7,), IkInfo)``."""
        from robot_models.ik import solve_ik

        return solve_ik(self, position_world_m, frame, **kwargs)

    def __repr__(self) -> str:
        return f"WamKinematics({self.source!r}, n_joints={self.n_joints})"
