"""The table-tennis ball: flight with drag and Magnus lift, table bounce, and trajectory prediction.

A pure model shared by the hitting policy (which predicts where the ball will be) and the
simulated world in ``harness.sim.physics`` (which moves it). Equations (docs/ball_physics.md):

(1) flight   ``dv/dt = -g z - k_d(S) |v| v + k_m (w x v)``, ``k_d(S) = rho (C_D + C_DS S) A / (2 m)``,
             spin parameter ``S = r |w| / |v|``, ``k_m = rho C_L A r / (2 m)``, ``A = pi r^2`` -- the
             Magnus form of the MPI-IS ``ball_models`` package (github.com/intelligent-soft-robots/
             ball_models, ``ball_trajectory.cpp``), lift coefficient ``C_L`` per unit ``S``; the drag
             growing with spin (``C_DS``) is the rotating-sphere effect (Achenbach 1972; Nathan 2008),
             fitted to the MPI launcher flights (docs/ball_physics.md); both spin terms are scaled by
             ``f = 1 / (1 + c_sat S)`` so that lift and spin drag saturate at large ``S`` (as measured
             for spinning spheres, e.g. Nathan 2008), ``c_sat = 0`` gives the linear MPI-IS form;
(2) spin     ``dw/dt = -lambda w`` (exponential decay);
(3) contact  ball centre reaches the surface plane, ``z = surface_z + r``, moving down;
(4)-(6) bounce: Coulomb impulse at the contact point (Garwin 1969; Nakashima et al. 2010,
             "Modeling of rebound phenomenon of a rigid ball with friction and elastic effects",
             ACC): normal ``v_n' = -e v_n``; tangential impulse ``J_t = -min(mu (1+e)|v_n|,
             alpha/(1+alpha) |s|) s/|s|`` on the contact slip ``s = v_t - r (w x n)``;
             ``w' = w - (n x J_t) / (alpha r)``; ``alpha = I / (m r^2) = 2/3`` for a thin shell.

State layout: ``state : (9,) or (n, 9) = [x, y, z, vx, vy, vz, wx, wy, wz]`` in the world frame
(m, m/s, rad/s). Topspin on a ball flying along +x is ``wy > 0``; it dips (eq. 1).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from policies import _ball_integrate as _bi
from checks.files import load_yaml_checked

__all__ = [
    "BallParams",
    "TableGeometry",
    "acceleration",
    "make_state",
    "predict",
    "predict_batch",
    "simulate",
    "surface_contact",
    "DEFAULT_PARAMS_PATH",
]

DEFAULT_PARAMS_PATH = Path(__file__).resolve().parents[1] / "data" / "ball_params.yaml"
INTEGRATORS = ("numba", "numpy")


@dataclass(frozen=True)
class BallParams:
    """Physical parameters of ball flight and table bounce (SI units).

    Defaults are published values: ITTF ball (2.7 g, 40 mm), C_D = 0.47 and C_L = 1.47 in the
    form of eq. (1) (MPI-IS ``ball_prediction`` config), table e = 0.9 and mu = 0.25
    (Nakashima et al. 2010). The values fitted to real flights live in ``data/ball_params.yaml``
    and are loaded with :meth:`load`.
    """

    mass_kg: float = 0.0027
    radius_m: float = 0.02
    air_density_kg_m3: float = 1.18
    drag_coefficient: float = 0.47
    drag_spin_coefficient: float = 0.0
    lift_coefficient: float = 1.47
    spin_saturation: float = 0.0
    spin_decay_per_s: float = 0.0
    table_restitution: float = 0.9
    table_friction: float = 0.25
    table_spin_transfer: float = 1.0
    inertia_factor: float = 2.0 / 3.0
    gravity_mps2: float = 9.81

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not np.isfinite(value):
                raise ValueError(f"BallParams.{f.name} must be a finite number, got {value!r}")
        for name in ("mass_kg", "radius_m", "inertia_factor"):
            if getattr(self, name) <= 0:
                raise ValueError(f"BallParams.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("air_density_kg_m3", "drag_coefficient", "drag_spin_coefficient", "spin_saturation",
                     "spin_decay_per_s", "table_friction"):
            if getattr(self, name) < 0:
                raise ValueError(f"BallParams.{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.table_spin_transfer <= 1.0:
            raise ValueError(f"BallParams.table_spin_transfer must be in [0, 1], got {self.table_spin_transfer!r}")
        if not 0.0 <= self.table_restitution <= 1.0:
            raise ValueError(f"BallParams.table_restitution must be in [0, 1], got {self.table_restitution!r}")

    @property
    def area_m2(self) -> float:
        return float(np.pi * self.radius_m**2)

    @property
    def k_drag(self) -> float:
        """Drag factor of eq. (1), 1/m: ``|a_drag| = k_drag |v|^2``."""
        return 0.5 * self.air_density_kg_m3 * self.drag_coefficient * self.area_m2 / self.mass_kg

    @property
    def k_magnus(self) -> float:
        """Magnus factor of eq. (1), dimensionless: ``a_magnus = k_magnus (w x v)``."""
        return 0.5 * self.air_density_kg_m3 * self.lift_coefficient * self.area_m2 * self.radius_m / self.mass_kg

    @property
    def k_drag_spin(self) -> float:
        """Spin-drag factor of eq. (1), 1/m: extra ``|a_drag| = k_drag_spin r |w| |v|``."""
        return 0.5 * self.air_density_kg_m3 * self.drag_spin_coefficient * self.area_m2 / self.mass_kg

    def coefficients(self) -> np.ndarray:
        """(11,) packed ``[g, k_drag, k_magnus, spin_decay, e, mu, alpha, r, k_drag_spin r, c_sat, kappa]``."""
        return np.array(
            [self.gravity_mps2, self.k_drag, self.k_magnus, self.spin_decay_per_s, self.table_restitution,
             self.table_friction, self.inertia_factor, self.radius_m, self.k_drag_spin * self.radius_m,
             self.spin_saturation, self.table_spin_transfer], float)

    def replace(self, **changes) -> "BallParams":
        """A copy with some fields changed (unknown names raise ``ValueError``)."""
        names = {f.name for f in dataclasses.fields(self)}
        bad = sorted(set(changes) - names)
        if bad:
            raise ValueError(f"unknown BallParams field(s) {bad}; valid: {sorted(names)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return {f.name: float(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @classmethod
    def load(cls, path: str | Path | None = None) -> "BallParams":
        """Read the ``ball_params:`` mapping of a YAML file (default ``data/ball_params.yaml``).

        Missing fields keep their published defaults; unknown or non-numeric ones raise ``ValueError``.
        """
        path = Path(path) if path is not None else DEFAULT_PARAMS_PATH
        if not path.is_file():
            raise FileNotFoundError(f"ball parameter file not found: {path}")
        doc = load_yaml_checked(path, "ball parameter file")
        if not isinstance(doc, dict) or not isinstance(doc.get("ball_params"), dict):
            raise ValueError(f"{path}: expected a top-level mapping 'ball_params:', got {type(doc).__name__}")
        values = doc["ball_params"]
        names = {f.name for f in dataclasses.fields(cls)}
        bad = sorted(set(values) - names)
        if bad:
            raise ValueError(f"{path}: unknown field(s) {bad} in ball_params; valid: {sorted(names)}")
        try:
            return cls(**{k: float(v) for k, v in values.items()})
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path}: ball_params: {exc}") from exc

    def save(self, path: str | Path, *, header: str = "", extra: dict | None = None) -> None:
        """Write ``ball_params:`` (and an optional ``extra`` mapping, e.g. fit provenance) as YAML."""
        doc = {"ball_params": self.to_dict()}
        if extra:
            doc.update(extra)
        text = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
        Path(path).write_text(text + yaml.safe_dump(doc, sort_keys=False))


@dataclass(frozen=True)
class TableGeometry:
    """The table and net (world frame): the one definition of their geometry, used by the ball
    model, the policy, the simulated world, the renderer and the logged 3D scene.

    The playing surface is a horizontal rectangle at height ``surface_z_m``; bounces happen only
    where the contact point lies inside its extent. Defaults are the lab frame
    (docs/architecture.md) and the ITTF table: top at z = 0.76 m, x in [-1.37, 1.37],
    y in [-0.7625, 0.7625], a 25 mm top; the net at x = 0, its top ``net_height_m`` = 0.1525 m
    above the surface, spanning y in [-``net_half_span_m``, ``net_half_span_m``] (0.915 m).
    """

    surface_z_m: float = 0.76
    x_min_m: float = -1.37
    x_max_m: float = 1.37
    y_min_m: float = -0.7625
    y_max_m: float = 0.7625
    thickness_m: float = 0.025
    net_height_m: float = 0.1525
    net_half_span_m: float = 0.915

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or np.isnan(v):
                raise ValueError(f"TableGeometry.{f.name} must be a number, got {v!r}")
        if not (self.x_min_m < self.x_max_m and self.y_min_m < self.y_max_m):
            raise ValueError(f"TableGeometry needs x_min < x_max and y_min < y_max, got {self}")
        for name in ("thickness_m", "net_height_m", "net_half_span_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TableGeometry.{name} must be > 0, got {getattr(self, name)!r}")

    def as_array(self) -> np.ndarray:
        return np.array([self.surface_z_m, self.x_min_m, self.x_max_m, self.y_min_m, self.y_max_m], float)

    def corners_m(self) -> np.ndarray:
        """(4, 3) the playing surface's corners, world frame: (x_min, y_min), (x_max, y_min),
        (x_max, y_max), (x_min, y_max), all at ``surface_z_m``."""
        x0, x1, y0, y1, z = self.x_min_m, self.x_max_m, self.y_min_m, self.y_max_m, self.surface_z_m
        return np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)

    def contains_xy(self, xy) -> np.ndarray:
        """xy : (..., 2) world x, y -> (...,) bool, inside the surface's extent."""
        xy = np.asarray(xy, float)
        return (self.x_min_m <= xy[..., 0]) & (xy[..., 0] <= self.x_max_m) & (self.y_min_m <= xy[..., 1]) & (
            xy[..., 1] <= self.y_max_m)


# --------------------------------------------------------------------------- validation


def check_states(state, name: str = "state") -> tuple[np.ndarray, bool]:
    """-> ((n, 9) float array, was_single)."""
    try:
        arr = np.asarray(state, float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric, got {state!r:.80}") from exc
    single = arr.ndim == 1
    arr2 = arr[None] if single else arr
    if arr2.ndim != 2 or arr2.shape[1] != 9:
        raise ValueError(f"{name} must have shape (9,) or (n, 9) [p, v, w], got shape {arr.shape}")
    if not np.isfinite(arr2).all():
        idx = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{name} must be finite; found {arr[idx]!r} at index {idx}")
    return arr2, single


def _check_times(t_query, name: str = "t_query") -> np.ndarray:
    try:
        t = np.asarray(t_query, float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric, got {t_query!r:.80}") from exc
    if t.ndim != 1 or t.size == 0:
        raise ValueError(f"{name} must have shape (M,) with M >= 1, got shape {t.shape}")
    if not np.isfinite(t).all():
        raise ValueError(f"{name} must be finite, got {t[~np.isfinite(t)][:3]!r}")
    if (np.diff(t) < 0).any():
        i = int(np.argmax(np.diff(t) < 0))
        raise ValueError(f"{name} must be non-decreasing; {name}[{i + 1}] = {t[i + 1]!r} < {name}[{i}] = {t[i]!r}")
    return t


def make_state(position, velocity, spin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """position (3,) m, velocity (3,) m/s, spin (3,) rad/s (world frame) -> state (9,)."""
    parts = [np.asarray(x, float) for x in (position, velocity, spin)]
    for name, p in zip(("position", "velocity", "spin"), parts):
        if p.shape != (3,):
            raise ValueError(f"{name} must have shape (3,), got shape {p.shape}")
    return check_states(np.concatenate(parts))[0][0]


# --------------------------------------------------------------------------- physics


def acceleration(state, params: BallParams | None = None) -> np.ndarray:
    """Linear acceleration of eq. (1): state (9,) or (n, 9) -> (3,) or (n, 3) m/s^2, world frame."""
    s, single = check_states(state)
    params = params or BallParams()
    a = _bi.deriv_np(s, params.coefficients())[:, 3:6]
    return a[0] if single else a


def surface_contact(velocity, spin, normal, params: BallParams, *, restitution: float, friction: float,
                    surface_velocity=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Impulsive contact of the ball with a surface (table or racket), eqs. (4)-(6).

    velocity : (n, 3) or (3,) ball velocity before contact, m/s, world frame
    spin : (n, 3) or (3,) ball angular velocity, rad/s
    normal : (n, 3) or (3,) unit surface normal pointing towards the ball's side
    surface_velocity : (n, 3) or (3,) velocity of the surface at the contact point, m/s
    restitution, friction : e (normal) and Coulomb mu of this surface
    Returns (velocity', spin') with the shapes of the inputs. Balls that move away from the
    surface (relative normal velocity >= 0) are returned unchanged.
    """
    v, w, n, u = (np.atleast_2d(np.asarray(x, float)) for x in (velocity, spin, normal, surface_velocity))
    single = np.ndim(velocity) == 1
    for name, x in (("velocity", v), ("spin", w), ("normal", n), ("surface_velocity", u)):
        if x.ndim != 2 or x.shape[1] != 3 or not np.isfinite(x).all():
            raise ValueError(f"{name} must be finite with shape (3,) or (n, 3), got {np.asarray(x).shape}")
    nn = np.linalg.norm(n, axis=1, keepdims=True)
    if (np.abs(nn - 1.0) > 1e-6).any():
        raise ValueError(f"normal must be unit length, got norms {nn.ravel()[:4]}")
    if not (0.0 <= restitution <= 1.0 and friction >= 0.0):
        raise ValueError(f"need 0 <= restitution <= 1 and friction >= 0, got e={restitution!r}, mu={friction!r}")
    r, alpha = params.radius_m, params.inertia_factor
    v_rel = v - u
    vn = np.sum(v_rel * n, axis=1, keepdims=True)
    approaching = vn < 0.0
    jn = -(1.0 + restitution) * np.minimum(vn, 0.0)  # eq. (4): normal impulse per unit mass
    slip_v = v_rel - vn * n - r * np.cross(w, n)  # contact-point slip velocity
    slip = np.linalg.norm(slip_v, axis=1, keepdims=True)
    jt = np.minimum(friction * jn, slip * alpha / (1.0 + alpha))  # eq. (5): sliding or rolling
    unit = np.divide(slip_v, slip, out=np.zeros_like(slip_v), where=slip > 0)
    j_t = -jt * unit
    v_new = np.where(approaching, v + jn * n + j_t, v)
    w_new = np.where(approaching, w - np.cross(n, j_t) / (alpha * r), w)  # eq. (6)
    return (v_new[0], w_new[0]) if single else (v_new, w_new)


# --------------------------------------------------------------------------- integration


def simulate(state, t_query, params: BallParams | None = None, table: TableGeometry | None = None, *,
             t0_s: float = 0.0, dt_s: float = 1e-3, method: str = "numba") -> tuple[np.ndarray, np.ndarray]:
    """Integrate eqs. (1)-(6) from ``state`` at time ``t0_s`` to each query time.

    state : (9,) or (n, 9) [p, v, w] at ``t0_s``, world frame
    t_query : (M,) non-decreasing times >= t0_s, seconds
    Returns ``states`` (M, 9) or (n, M, 9) at the query times, and ``first_bounce`` (5,) or (n, 5)
    ``[t_s, x, y, z, n_bounces]`` of the first table contact (NaN time/position if none).
    ``method``: "numba" (compiled kernel) or "numpy" (vectorised reference; same grid and events).
    """
    s, single = check_states(state)
    t = _check_times(t_query)
    if not np.isfinite(t0_s) or t[0] < t0_s - 1e-12:
        raise ValueError(f"t_query must start at or after t0_s = {t0_s!r}; got t_query[0] = {t[0]!r}")
    if not (np.isfinite(dt_s) and 0 < dt_s <= 0.05):
        raise ValueError(f"dt_s must be in (0, 0.05] s, got {dt_s!r}")
    if method not in INTEGRATORS:
        raise ValueError(f"unknown integrator method {method!r}; valid: {list(INTEGRATORS)}")
    params = params or BallParams()
    table = table or TableGeometry()
    rel = np.maximum(t - t0_s, 0.0)
    run = _bi.simulate_nb if method == "numba" else _bi.simulate_np
    out, bounce = run(np.ascontiguousarray(s), rel, params.coefficients(), table.as_array(), float(dt_s))
    bounce[:, 0] += t0_s
    return (out[0], bounce[0]) if single else (out, bounce)


def predict(state, t_query, params: BallParams | None = None, table: TableGeometry | None = None, *,
            t0_s: float = 0.0, dt_s: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Predicted positions (M, 3) and velocities (M, 3) at ``t_query`` (M,) from ``state`` (9,) at ``t0_s``."""
    s, single = check_states(state)
    if not single:
        raise ValueError(f"predict takes one state of shape (9,), got shape {s.shape}; use predict_batch")
    out, _ = simulate(s[0], t_query, params, table, t0_s=t0_s, dt_s=dt_s)
    return out[:, 0:3], out[:, 3:6]


def predict_batch(states, t_query, params: BallParams | None = None, table: TableGeometry | None = None, *,
                  t0_s: float = 0.0, dt_s: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Batched :func:`predict`: states (n, 9) -> positions (n, M, 3), velocities (n, M, 3)."""
    s, _ = check_states(states, "states")
    out, _ = simulate(s, t_query, params, table, t0_s=t0_s, dt_s=dt_s)
    return out[..., 0:3], out[..., 3:6]
