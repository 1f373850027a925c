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

Everything here is a plain function of arrays; the caller validates. The outcome of one racket state
(contact, then flight to the first bounce and over the net) is evaluated ~15 times per solve, at every
re-plan: ``method="fast"`` runs it as one compiled kernel (:func:`_outcome_nb`), ``"reference"``
composes the public ball model (:func:`policies.ball_model.surface_contact` and ``simulate``); the two
agree to rounding (tests/policies/test_hitting_planner.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy.optimize import least_squares

from policies._ball_integrate import _step_nb
from policies.ball_model import BallParams, TableGeometry, simulate, surface_contact
from checks.numba_cache import key_cache_on_callees

__all__ = ["METHODS", "ReturnSolution", "mirror_law", "solve_return"]

METHODS = ("fast", "reference")  #: how a racket state's outcome is evaluated (module docstring)
_FLIGHT_GRID_S = np.arange(0.0, 1.2, 0.01)  # flight samples of the outgoing ball, s after contact
_FLIGHT_DT_S = 5e-3  # integration step of the outgoing flight


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


def _outcome_reference(p, v_in, w_in, n, s, params, restitution, friction, plane):
    """Landing xy (2,), net-crossing height (m, NaN if never crossed), v_out (3,), for racket (n, s n):
    the public ball model (contact, then the flight sampled on ``_FLIGHT_GRID_S``)."""
    v_out, w_out = surface_contact(v_in, w_in, n, params, restitution=restitution, friction=friction,
                                   surface_velocity=s * n)
    state = np.concatenate([p, v_out, w_out])
    traj, bounce = simulate(state, _FLIGHT_GRID_S, params, plane, dt_s=_FLIGHT_DT_S)
    x = traj[:, 0]
    cross = np.nonzero((x[:-1] < 0.0) & (x[1:] >= 0.0))[0]
    if cross.size:
        k = int(cross[0])
        f = -x[k] / (x[k + 1] - x[k])
        z_net = float(traj[k, 2] + f * (traj[k + 1, 2] - traj[k, 2]))
    else:
        z_net = np.nan
    return bounce[1:3], z_net, v_out


@numba.njit(cache=True)
def _outcome_nb(p, v_in, w_in, yaw, pitch, speed, c, tb, restitution, friction, grid, dt, out):
    """:func:`_outcome_reference` as one kernel, for the racket normal (yaw, pitch) and speed.

    The contact is eqs. (4)-(6) of ``surface_contact`` written out; the flight takes the same steps as
    ``simulate`` on ``grid`` (``_step_nb``), and stops once it has both the first bounce and the net
    crossing (what follows cannot change them). out (7,) <- [landing x, y, net-crossing z (NaN if
    none), v_out (3,), 1 if it bounced else 0]."""
    n0 = np.cos(pitch) * np.cos(yaw)
    n1 = np.cos(pitch) * np.sin(yaw)
    n2 = np.sin(pitch)
    r, alpha = c[7], c[6]
    s = np.empty(9)
    s[0], s[1], s[2] = p[0], p[1], p[2]
    vr0, vr1, vr2 = v_in[0] - speed * n0, v_in[1] - speed * n1, v_in[2] - speed * n2
    vn = vr0 * n0 + vr1 * n1 + vr2 * n2
    if vn < 0.0:  # approaching the racket: normal impulse (4), Coulomb friction on the slip (5), spin (6)
        jn = -(1.0 + restitution) * vn
        wn0 = w_in[1] * n2 - w_in[2] * n1  # w x n
        wn1 = w_in[2] * n0 - w_in[0] * n2
        wn2 = w_in[0] * n1 - w_in[1] * n0
        sl0, sl1, sl2 = vr0 - vn * n0 - r * wn0, vr1 - vn * n1 - r * wn1, vr2 - vn * n2 - r * wn2
        slip = np.sqrt(sl0 * sl0 + sl1 * sl1 + sl2 * sl2)
        jt = min(friction * jn, slip * alpha / (1.0 + alpha))
        j0 = j1 = j2 = 0.0
        if slip > 0.0:
            j0, j1, j2 = -jt * sl0 / slip, -jt * sl1 / slip, -jt * sl2 / slip
        s[3], s[4], s[5] = v_in[0] + jn * n0 + j0, v_in[1] + jn * n1 + j1, v_in[2] + jn * n2 + j2
        s[6] = w_in[0] - (n1 * j2 - n2 * j1) / (alpha * r)  # w - (n x J_t) / (alpha r)
        s[7] = w_in[1] - (n2 * j0 - n0 * j2) / (alpha * r)
        s[8] = w_in[2] - (n0 * j1 - n1 * j0) / (alpha * r)
    else:
        for i in range(3):
            s[3 + i] = v_in[i]
            s[6 + i] = w_in[i]
    for i in range(3):
        out[3 + i] = s[3 + i]
    out[0] = out[1] = out[2] = np.nan
    out[6] = 0.0
    k1, k2, k3, k4 = np.empty(9), np.empty(9), np.empty(9), np.empty(9)
    tmp, nxt = np.empty(9), np.empty(9)
    t = 0.0
    x_prev, z_prev = s[0], s[2]
    for q in range(grid.shape[0]):
        tq = grid[q]
        while t < tq:  # simulate_nb's stepping, to the sample
            h = min(dt, tq - t)
            if tq - (t + h) < 1e-12:
                h = tq - t
            tc = _step_nb(s, h, c, tb, k1, k2, k3, k4, tmp, nxt)
            if tc >= 0.0 and out[6] == 0.0:  # nxt holds the state at the first contact
                out[0], out[1], out[6] = nxt[0], nxt[1], 1.0
            t = t + h if h < tq - t else tq
        if q > 0 and np.isnan(out[2]) and x_prev < 0.0 and s[0] >= 0.0:
            f = -x_prev / (s[0] - x_prev)
            out[2] = z_prev + f * (s[2] - z_prev)
        if out[6] == 1.0 and not np.isnan(out[2]):
            break
        x_prev, z_prev = s[0], s[2]


def _outcome_function(p, v_in, w_in, params, restitution, friction, plane, method):
    """x = (yaw, pitch, speed) of the racket -> (landing xy (2,), net-crossing z, v_out (3,)) by ``method``."""
    if method == "reference":
        return lambda x: _outcome_reference(p, v_in, w_in, _normal(x[0], x[1]), x[2], params, restitution, friction,
                                            plane)
    c, tb, out = params.coefficients(), plane.as_array(), np.empty(7)
    e, mu = float(restitution), float(friction)

    def outcome(x):
        _outcome_nb(p, v_in, w_in, float(x[0]), float(x[1]), float(x[2]), c, tb, e, mu, _FLIGHT_GRID_S, _FLIGHT_DT_S,
                    out)
        return out[0:2].copy(), float(out[2]), out[3:6].copy()

    return outcome


def solve_return(p, v_in, w_in, target_xy, params: BallParams, table: TableGeometry, *, restitution: float,
                 friction: float, net_top_z_m: float, net_clearance_m: float, max_nfev: int = 40,
                 warm_start: ReturnSolution | None = None, method: str = "fast") -> ReturnSolution:
    """Racket normal and velocity that send the ball at p (3,) with v_in (3,), w_in (3,) to land at
    target_xy (2,) on the table top, crossing the net plane ``net_clearance_m`` above ``net_top_z_m``.

    warm_start : a previous solution for a nearby ball (re-planning), used as the initial guess.
    method : "fast" (compiled outcome) or "reference" (the public ball model); same solution to rounding.
    Raises ValueError when no racket state does it (e.g. a ball moving away from the robot)."""
    if method not in METHODS:
        raise ValueError(f"unknown return method {method!r}; valid: {list(METHODS)}")
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

    outcome = _outcome_function(p, v_in, w_in, params, restitution, friction, plane, method)

    def resid(x):
        xy, zn, _ = outcome(x)
        if not np.isfinite(xy).all() or not np.isfinite(zn):
            return np.full(3, 5.0)
        return np.array([xy[0] - target_xy[0], xy[1] - target_xy[1], zn - z_net])

    res = least_squares(resid, x0, x_scale=scale * 0.1, max_nfev=max_nfev, xtol=1e-8, ftol=1e-8)
    n = _normal(res.x[0], res.x[1])
    xy, zn, v_out = outcome(res.x)
    return ReturnSolution(n, res.x[2] * n, np.asarray(xy, float), float(zn - net_top_z_m), v_out,
                          float(np.linalg.norm(res.fun)))


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
