"""The simulated world of the ball: flight and table bounce (policies.ball_model), the net, the floor
and the racket, stepped at a fixed tick with swept (between-tick) contact detection.

Lab world frame (docs/architecture.md): metres, z up, table top at z = 0.76, x in [-1.37, 1.37]
(robot's half x < 0), net in the plane x = 0, 0.1525 m high, y in [-0.915, 0.915].

Contacts (docs/ball_physics.md, sec. 3):
* table  -- in the integrator (eqs. 3-6), only where the contact point is on the table; a ball
            past the edges falls to the floor;
* net    -- the ball surface reaches the plane x = 0 below the net's top: normal velocity
            reversed with ``net_restitution``, tangential velocity scaled by ``1 - net_friction``
            (the net absorbs most of the speed); the rally outcome is "net";
* racket -- a disk (centre, unit normal, radius) moving with its own velocity; swept contact:
            the signed distance of the ball centre to the racket plane, interpolated over the
            tick, first reaches the ball radius inside the disk; the impulse is eqs. (4)-(6) in
            the racket's frame (restitution 0.78 and friction 0.25: Muelling et al.'s WAM
            simulator values, RobotLearning/traj-gen-and-tracking ``loadTennisTableValues.m``);
* floor  -- the ball stops (event "floor").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from policies.ball_model import BallParams, TableGeometry, check_states, simulate, surface_contact

__all__ = ["BallWorld", "ContactEvent", "EventKind", "RacketParams", "RacketState", "WorldOptions", "classify_return"]


@dataclass(frozen=True)
class RacketParams:
    """The racket as a disk: radius and the contact's restitution / Coulomb friction."""

    radius_m: float = 0.075
    restitution: float = 0.78
    friction: float = 0.25

    def __post_init__(self):
        if not (self.radius_m > 0 and 0 <= self.restitution <= 1 and self.friction >= 0):
            raise ValueError(f"RacketParams need radius_m > 0, restitution in [0, 1], friction >= 0; got {self}")


@dataclass(frozen=True)
class WorldOptions:
    """Geometry and contact parameters of the world (lab defaults)."""

    table: TableGeometry = field(default_factory=TableGeometry)  # and the net (height, span)
    net_restitution: float = 0.05
    net_friction: float = 0.8
    floor_z_m: float = 0.0
    racket: RacketParams = field(default_factory=RacketParams)
    dt_s: float = 1e-3

    def __post_init__(self):
        if not (0 < self.dt_s <= 0.01):
            raise ValueError(f"WorldOptions.dt_s must be in (0, 0.01] s, got {self.dt_s!r}")
        if not (0 <= self.net_restitution <= 1 and 0 <= self.net_friction <= 1):
            raise ValueError(f"WorldOptions: bad net parameters in {self}")


@dataclass(frozen=True)
class RacketState:
    """Racket disk at one instant: centre_m (3,), unit normal (3,) and velocity_mps (3,), world frame."""

    center_m: np.ndarray
    normal: np.ndarray
    velocity_mps: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        for name in ("center_m", "normal", "velocity_mps"):
            v = np.asarray(getattr(self, name), float)
            if v.shape != (3,) or not np.isfinite(v).all():
                raise ValueError(f"RacketState.{name} must be a finite (3,) vector, got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        norm = np.linalg.norm(self.normal)
        if norm < 1e-9:
            raise ValueError(f"RacketState.normal must be non-zero, got {self.normal!r}")
        object.__setattr__(self, "normal", self.normal / norm)

    @classmethod
    def from_pose(cls, T_world_racket, velocity_mps=(0.0, 0.0, 0.0)) -> "RacketState":
        """From a (4, 4) racket-frame pose whose z axis is the racket face normal."""
        T = np.asarray(T_world_racket, float)
        if T.shape != (4, 4):
            raise ValueError(f"T_world_racket must have shape (4, 4), got {T.shape}")
        return cls(T[:3, 3].copy(), T[:3, 2].copy(), np.asarray(velocity_mps, float))


class EventKind(StrEnum):
    TABLE = "table"
    NET = "net"
    RACKET = "racket"
    FLOOR = "floor"


@dataclass(frozen=True)
class ContactEvent:
    """A contact: kind, time, ball centre (3,) at contact, and the side of the net (x > 0: opponent)."""

    kind: EventKind
    t_s: float
    position_m: np.ndarray
    velocity_after_mps: np.ndarray

    @property
    def opponent_side(self) -> bool:
        return bool(self.position_m[0] > 0.0)


def classify_return(events: list[ContactEvent], table: TableGeometry = TableGeometry()) -> str:
    """Outcome after the last racket hit: "landed_in" (first bounce on the opponent's half),
    "net", "missed_table" (floor first), "own_side" (bounced on the robot's half), "no_hit", "in_flight"."""
    hits = [i for i, e in enumerate(events) if e.kind == EventKind.RACKET]
    if not hits:
        return "no_hit"
    for e in events[hits[-1] + 1:]:
        if e.kind == EventKind.NET:
            return "net"
        if e.kind == EventKind.FLOOR:
            return "missed_table"
        if e.kind == EventKind.TABLE:
            inside = table.contains_xy(e.position_m[:2])
            return "landed_in" if (e.opponent_side and inside) else "own_side"
    return "in_flight"


class BallWorld:
    """One ball in the lab, stepped at ``options.dt_s``; the racket (if any) is given per step."""

    def __init__(self, params: BallParams | None = None, options: WorldOptions = WorldOptions()):
        self.params = params or BallParams.load()  # fitted defaults, data/ball_params.yaml
        self.options = options
        self.state = np.zeros(9)
        self.t_s = 0.0
        self.events: list[ContactEvent] = []
        self.done = False

    def reset(self, state, t_s: float = 0.0) -> None:
        """Start a ball from ``state`` (9,) [p, v, w] at ``t_s``."""
        s, single = check_states(state)
        if not single:
            raise ValueError(f"reset takes one state of shape (9,), got shape {s.shape}")
        self.state, self.t_s, self.events, self.done = s[0].copy(), float(t_s), [], False

    # -- propagation with table events -------------------------------------------------------------
    def _fly(self, state: np.ndarray, t0: float, duration: float) -> np.ndarray:
        if duration <= 0:
            return state.copy()
        out, bounce = simulate(state, [t0 + duration], self.params, self.options.table, t0_s=t0,
                               dt_s=self.options.dt_s)
        if bounce[4] > 0:
            self.events.append(ContactEvent(EventKind.TABLE, float(bounce[0]), bounce[1:4].copy(), out[0, 3:6].copy()))
        return out[0]

    def _net_crossing(self, p0: np.ndarray, p1: np.ndarray) -> float | None:
        """Fraction of the tick at which the ball surface reaches the net plane below its top, or None."""
        r = self.params.radius_m
        side = np.sign(p0[0])
        if side == 0 or abs(p0[0]) <= r:
            return None
        d0, d1 = side * p0[0] - r, side * p1[0] - r
        if d1 > 0:
            return None
        s = d0 / (d0 - d1)
        p = p0 + s * (p1 - p0)
        table = self.options.table
        top = table.surface_z_m + table.net_height_m
        if table.surface_z_m <= p[2] <= top + r and abs(p[1]) <= table.net_half_span_m:
            return float(s)
        return None

    def _racket_crossing(self, p0, p1, a: RacketState, b: RacketState) -> tuple[float, np.ndarray, np.ndarray] | None:
        """Swept ball-disk contact over the tick: (fraction, contact normal towards the ball, racket velocity)."""
        r = self.params.radius_m
        s_grid = np.linspace(0.0, 1.0, 17)
        c = a.center_m + s_grid[:, None] * (b.center_m - a.center_m)
        n = a.normal + s_grid[:, None] * (b.normal - a.normal)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        p = p0 + s_grid[:, None] * (p1 - p0)
        d = np.sum((p - c) * n, axis=1)
        if abs(d[0]) <= r:  # already touching at the tick start: only act if approaching
            k = 0
        else:
            side = np.sign(d[0])
            reach = np.nonzero(side * d <= r)[0]
            if reach.size == 0:
                return None
            k = int(reach[0])
        side = np.sign(d[0]) if d[0] != 0 else 1.0
        if k > 0:  # bisect |d| = r between grid points k-1 and k
            lo, hi = s_grid[k - 1], s_grid[k]
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                nm = a.normal + mid * (b.normal - a.normal)
                nm /= np.linalg.norm(nm)
                dm = np.dot(p0 + mid * (p1 - p0) - (a.center_m + mid * (b.center_m - a.center_m)), nm)
                lo, hi = (mid, hi) if side * dm > r else (lo, mid)
            s = hi
        else:
            s = 0.0
        nrm = a.normal + s * (b.normal - a.normal)
        nrm /= np.linalg.norm(nrm)
        pc = p0 + s * (p1 - p0)
        cc = a.center_m + s * (b.center_m - a.center_m)
        radial = (pc - cc) - np.dot(pc - cc, nrm) * nrm
        if np.linalg.norm(radial) > self.options.racket.radius_m:
            return None
        vel = a.velocity_mps + s * (b.velocity_mps - a.velocity_mps)
        return float(s), side * nrm, vel

    # -- one tick ------------------------------------------------------------------------------------
    def step(self, racket_start: RacketState | None = None, racket_end: RacketState | None = None) -> list[ContactEvent]:
        """Advance one tick; the racket moves from ``racket_start`` to ``racket_end`` (linearly) during it.

        Returns the events of this tick (also appended to :attr:`events`).
        """
        n_before = len(self.events)
        if self.done:
            return []
        dt, s0, t0 = self.options.dt_s, self.state, self.t_s
        s1 = self._fly(s0, t0, dt)
        candidates = []
        f_net = self._net_crossing(s0[:3], s1[:3])
        if f_net is not None:
            candidates.append((f_net, EventKind.NET, None))
        if racket_start is not None:
            hit = self._racket_crossing(s0[:3], s1[:3], racket_start, racket_end or racket_start)
            if hit is not None and np.dot(s0[3:6] - hit[2], hit[1]) < 0:  # only when approaching the face
                candidates.append((hit[0], EventKind.RACKET, hit))
        if candidates:
            frac, kind, hit = min(candidates, key=lambda c: c[0])
            del self.events[n_before:]  # re-fly to the contact instead
            tau = frac * dt
            sc = self._fly(s0, t0, tau)
            v, w = sc[3:6], sc[6:9]
            if kind == EventKind.NET:
                side = np.sign(s0[0])
                keep = 1.0 - self.options.net_friction
                v = np.array([-self.options.net_restitution * v[0], keep * v[1], keep * v[2]])
                sc[0] = side * self.params.radius_m
            else:
                _, normal, vel = hit
                rp = self.options.racket
                v, w = surface_contact(v, w, normal, self.params, restitution=rp.restitution, friction=rp.friction,
                                       surface_velocity=vel)
            sc = np.concatenate([sc[:3], v, w])
            self.events.append(ContactEvent(kind, t0 + tau, sc[:3].copy(), v.copy()))
            s1 = self._fly(sc, t0 + tau, dt - tau)
        self.state, self.t_s = s1, t0 + dt
        if self.state[2] <= self.options.floor_z_m + self.params.radius_m:
            self.state[2] = self.options.floor_z_m + self.params.radius_m
            self.events.append(ContactEvent(EventKind.FLOOR, self.t_s, self.state[:3].copy(), self.state[3:6].copy()))
            self.state[3:] = 0.0
            self.done = True
        return self.events[n_before:]

    def run(self, duration_s: float, racket=None) -> tuple[np.ndarray, np.ndarray]:
        """Step for ``duration_s`` (or until the floor); ``racket(t_s) -> RacketState | None`` optional.

        Returns times (K,) and states (K, 9), including the start.
        """
        n = int(round(duration_s / self.options.dt_s))
        times, states = [self.t_s], [self.state.copy()]
        for _ in range(n):
            if self.done:
                break
            a = racket(self.t_s) if racket else None
            b = racket(self.t_s + self.options.dt_s) if racket else None
            self.step(a, b)
            times.append(self.t_s)
            states.append(self.state.copy())
        return np.asarray(times), np.asarray(states)
