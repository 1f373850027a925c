"""The racket state that returns the ball to the opponent's court: the mirror law, refined on the ball model.

Given the ball at the hitting point (position p, velocity v_in, spin w_in; lab world frame) and a
landing target on the opponent's half, find the racket's unit normal n and velocity v_r at contact.

1. Desired outgoing velocity (ballistic guess, no drag): the flight to the landing point
   (x_t, y_t, table top) passes over the net (x = 0) at height z_net; with the horizontal
   direction d = (x_t - p)_xy / |.| and horizontal speed u, the two heights fix u and v_z
   (gravity only). This is the initial guess of step 3.
2. Mirror law (the racket moves along its normal, v_r = s n; restitution e, friction ignored):
       n = (v_out - v_in) / |v_out - v_in|                                          (R1)
       s = (v_out . n + e v_in . n) / (1 + e)                                       (R2)
   (the normal component of the relative velocity reverses with e:
   (v_out - v_r) . n = -e (v_in - v_r) . n, and the tangential component is kept).
3. Refinement on the same physics the world uses: (n as two angles, s) are adjusted by
   least squares so that the exact contact of ``policies.ball_model.surface_contact`` (Coulomb
   friction, spin) followed by the flight of eqs. (1)-(2) crosses the net plane at z_net and
   lands at (x_t, y_t). The policy's racket model (restitution, friction) is an option; its
   defaults are the simulated world's values.

Everything here is a plain function of arrays; the caller validates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from policies.ball_model import BallParams, TableGeometry, simulate, surface_contact

__all__ = ["ReturnSolution", "mirror_law", "solve_return"]

_FLIGHT_GRID_S = np.arange(0.0, 1.2, 0.01)  # flight samples of the outgoing ball, s after contact


@dataclass(frozen=True)
class ReturnSolution:
    """normal (3,) unit, racket_velocity_mps (3,) = speed * normal, and the predicted outcome:
    landing_xy_m (2,), net_clearance_m (ball centre height above the net top where it crosses x = 0),
    v_out_mps (3,) ball velocity after contact, residual_m (norm of the refinement's residuals)."""

    normal: np.ndarray
    racket_velocity_mps: np.ndarray
    landing_xy_m: np.ndarray
    net_clearance_m: float
    v_out_mps: np.ndarray
    residual_m: float


def _ballistic_v_out(p, target_xy, z_table, z_net, g):
    """Drag-free outgoing velocity from p (3,) landing at target_xy at height z_table, passing x = 0 at z_net."""
    d = np.array([target_xy[0] - p[0], target_xy[1] - p[1]])
    L = float(np.linalg.norm(d))
    d = d / max(L, 1e-9)
    s_net = L * (0.0 - p[0]) / max(target_xy[0] - p[0], 1e-9)  # horizontal distance to the net plane
    # z(s) = p_z + a s - b s^2 with a = vz/u, b = g / (2 u^2); two conditions, linear in (a, b)
    A = np.array([[s_net, -s_net**2], [L, -L**2]])
    rhs = np.array([z_net - p[2], z_table - p[2]])
    a, b = np.linalg.solve(A, rhs)
    b = max(b, 1e-3)
    u = np.sqrt(g / (2.0 * b))
    return np.array([u * d[0], u * d[1], a * u])


def mirror_law(v_in, v_out, restitution: float) -> tuple[np.ndarray, float]:
    """(R1)-(R2): racket normal (3,) and speed along it for a ball turning from v_in into v_out."""
    n = np.asarray(v_out, float) - np.asarray(v_in, float)
    n = n / np.linalg.norm(n)
    s = (float(v_out @ n) + restitution * float(v_in @ n)) / (1.0 + restitution)
    return n, s


def _angles(n):
    return np.array([np.arctan2(n[1], n[0]), np.arcsin(np.clip(n[2], -1.0, 1.0))])


def _normal(yaw, pitch):
    return np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])


def _outcome(p, v_in, w_in, n, s, params, restitution, friction, plane):
    """Landing xy (2,), net-crossing height (m, NaN if never crossed), v_out (3,), for racket (n, s n)."""
    v_out, w_out = surface_contact(v_in, w_in, n, params, restitution=restitution, friction=friction,
                                   surface_velocity=s * n)
    state = np.concatenate([p, v_out, w_out])
    traj, bounce = simulate(state, _FLIGHT_GRID_S, params, plane, dt_s=5e-3)
    x = traj[:, 0]
    cross = np.nonzero((x[:-1] < 0.0) & (x[1:] >= 0.0))[0]
    if cross.size:
        k = int(cross[0])
        f = -x[k] / (x[k + 1] - x[k])
        z_net = float(traj[k, 2] + f * (traj[k + 1, 2] - traj[k, 2]))
    else:
        z_net = np.nan
    return bounce[1:3], z_net, v_out


def solve_return(p, v_in, w_in, target_xy, params: BallParams, table: TableGeometry, *, restitution: float,
                 friction: float, net_top_z_m: float, net_clearance_m: float, max_nfev: int = 40,
                 warm_start: ReturnSolution | None = None) -> ReturnSolution:
    """Racket normal and velocity that send the ball at p (3,) with v_in (3,), w_in (3,) to land at
    target_xy (2,) on the table top, crossing the net plane ``net_clearance_m`` above ``net_top_z_m``.

    warm_start : a previous solution for a nearby ball (re-planning), used as the initial guess.
    Raises ValueError when no racket state does it (e.g. a ball moving away from the robot)."""
    p, v_in, w_in = (np.asarray(a, float) for a in (p, v_in, w_in))
    target_xy = np.asarray(target_xy, float)
    z_net = net_top_z_m + net_clearance_m
    z_table = table.surface_z_m + params.radius_m
    plane = TableGeometry(table.surface_z_m, -20.0, 20.0, -20.0, 20.0)  # landing anywhere on the plane
    v_out0 = _ballistic_v_out(p, target_xy, z_table, z_net, params.gravity_mps2)
    n0, s0 = mirror_law(v_in, v_out0, restitution)
    if n0[0] <= 0.0:
        raise ValueError(f"no return: the mirror-law normal {np.round(n0, 3).tolist()} faces away from the opponent")
    x0 = np.concatenate([_angles(n0), [s0]])
    if warm_start is not None:
        x0 = np.concatenate([_angles(warm_start.normal), [float(warm_start.racket_velocity_mps @ warm_start.normal)]])
    scale = np.array([1.0, 1.0, 0.3])  # metres of residual per unit: angles of ~1 rad ~ 1 m at the landing

    def resid(x):
        xy, zn, _ = _outcome(p, v_in, w_in, _normal(x[0], x[1]), x[2], params, restitution, friction, plane)
        if not np.isfinite(xy).all() or not np.isfinite(zn):
            return np.full(3, 5.0)
        return np.array([xy[0] - target_xy[0], xy[1] - target_xy[1], zn - z_net])

    res = least_squares(resid, x0, x_scale=scale * 0.1, max_nfev=max_nfev, xtol=1e-8, ftol=1e-8)
    n = _normal(res.x[0], res.x[1])
    xy, zn, v_out = _outcome(p, v_in, w_in, n, res.x[2], params, restitution, friction, plane)
    return ReturnSolution(n, res.x[2] * n, np.asarray(xy, float), float(zn - net_top_z_m), v_out,
                          float(np.linalg.norm(res.fun)))
