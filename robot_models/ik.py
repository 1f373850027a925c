"""Damped-least-squares inverse kinematics for a frame position and, optionally, its z-axis direction.

Used to check that the hitting region is reachable with a sensibly pointing racket, and to find via
points for scripted trajectories. Each iteration (Nakamura/Wampler DLS with a null-space posture term)::

    e   = [p_des - p ; w * angle(z, n_des) * unit(z x n_des)]   # position (m), direction (rad) error, clamped
    A   = [J_v ; w * (I - z z^T) J_w]                   # rotation about z itself is left free
    dq  = A^T (A A^T + lambda^2 I)^-1 e + (I - A^T (A A^T + lambda^2 I)^-1 A) k (q_home - q)
    q  <- clip(q + dq, limits)                          # joints pushed against a limit are frozen first

with restarts from random configurations within the limits (seeded) when it stalls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["IkInfo", "IkOptions", "solve_ik"]


@dataclass(frozen=True)
class IkOptions:
    """Options of :func:`solve_ik`. Distances metres, angles radians."""

    tol_m: float = 1e-4  #: position tolerance
    tol_rad: float = 1e-3  #: angle tolerance between the frame's z axis and the requested normal
    max_iters: int = 300  #: iterations per start
    stall_iters: int = 40  #: a start ends when its error has not improved by 1 % for this many iterations
    restarts: int = 12  #: extra random starts after the first one
    damping_m: float = 0.02  #: DLS damping lambda
    max_step_rad: float = 0.25  #: largest joint step per iteration (infinity norm)
    max_error_m: float = 0.05  #: position error is clamped to this length per iteration
    max_error_rad: float = 0.3  #: direction error is clamped to this angle per iteration
    normal_weight_m: float = 0.3  #: w: metres of position error worth one unit of direction error
    posture_gain: float = 0.05  #: k: null-space pull towards the home posture
    limit_margin_rad: float = 0.02  #: solutions stay this far inside the joint limits

    def __post_init__(self):
        for name in ("tol_m", "tol_rad", "damping_m", "max_step_rad", "normal_weight_m", "max_error_m", "max_error_rad"):
            if not getattr(self, name) > 0:
                raise ValueError(f"IkOptions.{name} must be > 0, got {getattr(self, name)!r}")
        if self.max_iters < 1 or self.restarts < 0:
            raise ValueError(f"IkOptions needs max_iters >= 1 and restarts >= 0, got {self.max_iters}, {self.restarts}")


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _solve_from(kin, q, fid, p_des, n_des, low, high, opt: IkOptions):
    """One DLS descent from ``q``; returns (q, position error m, angle error rad, iterations).

    Stops early when the weighted error has not improved by 1 % over ``stall_iters`` iterations.
    """
    lam2 = opt.damping_m**2
    w = opt.normal_weight_m
    n = q.size
    eye3 = np.eye(3)
    best, best_it = np.inf, 0
    for it in range(1, opt.max_iters + 2):  # the last pass only measures the final error
        T, J = kin.fk_and_jacobian(q, fid)
        e_p = p_des - T[:3, 3]
        pos_err = float(np.sqrt(e_p @ e_p))
        if pos_err > opt.max_error_m:  # clamp the task error so one step follows the local linearisation
            e_p = e_p * (opt.max_error_m / pos_err)
        if n_des is None:
            ang_err = 0.0
            A, e = J[:3], e_p
        else:
            z = T[:3, 2]
            ang_err = float(np.arccos(min(1.0, max(-1.0, z @ n_des))))
            axis = _cross(z, n_des)
            s = float(np.sqrt(axis @ axis))
            if s < 1e-9:  # parallel or anti-parallel: any axis perpendicular to z
                axis = _cross(z, eye3[int(np.argmin(np.abs(z)))])
                s = float(np.sqrt(axis @ axis))
            A = np.vstack([J[:3], w * ((eye3 - np.outer(z, z)) @ J[3:])])  # rotation about z left free
            e = np.concatenate([e_p, (w * min(ang_err, opt.max_error_rad) / s) * axis])
        if pos_err < opt.tol_m and ang_err < opt.tol_rad:
            return q, pos_err, ang_err, it
        cost = pos_err + w * ang_err
        if cost < 0.99 * best:
            best, best_it = cost, it
        elif it - best_it > opt.stall_iters:
            break
        if it > opt.max_iters:
            break
        near = pos_err < 10 * opt.tol_m and ang_err < 10 * opt.tol_rad
        free = np.ones(n, bool)
        for _ in range(2):  # active set: joints at a limit and pushed outwards are frozen, then re-solve
            Af = A * free
            X = np.linalg.solve(Af @ Af.T + lam2 * np.eye(A.shape[0]), np.column_stack([e, Af]))
            dq = Af.T @ X[:, 0]
            if not near:  # null-space posture term; off near the goal, where its drift would stall the last digits
                dq += (np.diag(free.astype(float)) - Af.T @ X[:, 1:]) @ (opt.posture_gain * (kin.q_home - q))
            blocked = ((q <= low + 1e-9) & (dq < 0)) | ((q >= high - 1e-9) & (dq > 0))
            if not (blocked & free).any():
                break
            free &= ~blocked
        step = np.abs(dq).max()
        if step > opt.max_step_rad:
            dq *= opt.max_step_rad / step
        q = np.clip(q + dq, low, high)
    return q, pos_err, ang_err, min(it, opt.max_iters)


@dataclass(frozen=True)
class IkInfo:
    """What :func:`solve_ik` found besides the joint angles.

    success : both tolerances met; pos_err_m, angle_err_rad : the returned solution's position error,
    metres, and normal error, radians (0 without a normal); iterations : over all starts; starts :
    how many starts were tried
    """

    success: bool
    pos_err_m: float
    angle_err_rad: float
    iterations: int
    starts: int


def solve_ik(kin, position_world_m, frame: str = "racket", *, normal_world=None, q0=None,
             options: IkOptions = IkOptions(), rng: np.random.Generator | None = None, seed: int | None = 0):
    """Joint angles placing ``frame``'s origin at ``position_world_m`` (3,) m, lab world.

    normal_world : optional (3,) direction (normalised here) for the frame's z axis (the racket normal).
    q0 : (7,) first start (default ``kin.q_home``); later starts are uniform within the limits, from
    ``rng`` (or ``np.random.default_rng(seed)``).
    Returns ``(q (7,), IkInfo)``. On failure ``q`` is the best attempt (least position error).
    """
    fid = kin.frame_id(frame)
    p_des = np.asarray(position_world_m, dtype=float)
    if p_des.shape != (3,) or not np.isfinite(p_des).all():
        raise ValueError(f"position_world_m must be 3 finite numbers, got {np.asarray(position_world_m).tolist()}")
    n_des = None
    if normal_world is not None:
        n_des = np.asarray(normal_world, dtype=float)
        norm = np.linalg.norm(n_des) if n_des.shape == (3,) else 0.0
        if not np.isfinite(norm) or norm < 1e-9:
            raise ValueError(f"normal_world must be a non-zero 3-vector, got {np.asarray(normal_world).tolist()}")
        n_des = n_des / norm
    if not isinstance(options, IkOptions):
        raise ValueError(f"options must be IkOptions, got {options!r}")
    q = kin.check_q(kin.q_home if q0 is None else q0, "q0", limits=False)
    if q.ndim != 1:
        raise ValueError(f"q0 must have shape ({kin.n_joints},), got {q.shape}")
    low = kin.q_min + options.limit_margin_rad
    high = kin.q_max - options.limit_margin_rad
    q = np.clip(q, low, high)
    rng = rng if rng is not None else np.random.default_rng(seed)
    best = None
    total = 0
    for start in range(options.restarts + 1):
        if start > 0:
            q = rng.uniform(low, high)
        q, pos_err, ang_err, its = _solve_from(kin, q, fid, p_des, n_des, low, high, options)
        total += its
        cost = pos_err + options.normal_weight_m * ang_err
        if best is None or cost < best[0]:
            best = (cost, q, pos_err, ang_err)
        if pos_err < options.tol_m and ang_err < options.tol_rad:
            break
    _, q, pos_err, ang_err = best
    success = pos_err < options.tol_m and ang_err < options.tol_rad
    return q, IkInfo(bool(success), float(pos_err), float(ang_err), int(total), start + 1)
