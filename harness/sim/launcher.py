"""A seeded ball launcher: serves balls from the opponent's side to a target bounce point on the robot's half.

Each serve draws (from ``rng``) a launch position, a speed, a spin kind and magnitude, and a
target bounce point; the launch direction (azimuth, elevation) is then solved so that the first
table bounce of the simulated flight (policies.ball_model, eqs. 1-6) lands on the target, taking
the flatter of the two solutions. Serves that hit the net or cannot reach the target at that
speed are redrawn. Lab world frame (docs/architecture.md); the robot's half is x < 0.

Spin convention for a ball travelling along the horizontal unit direction ``d``: topspin is
``+|w| (z x d)`` (the top of the ball moves forward, the ball dips), backspin its opposite,
sidespin ``+-|w| z``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from harness.sim.physics import BallWorld, EventKind, WorldOptions
from harness.common.seeding import rng_from
from policies.ball_model import BallParams, TableGeometry, simulate

__all__ = ["BallLauncher", "LauncherOptions", "Serve", "SPIN_KINDS"]

SPIN_KINDS = ("none", "top", "back", "side")


def _check_range(name: str, rng: tuple) -> None:
    if len(rng) != 2 or not (np.isfinite(rng).all() and rng[0] <= rng[1]):
        raise ValueError(f"LauncherOptions.{name} must be (low, high) with low <= high, got {rng!r}")


@dataclass(frozen=True)
class LauncherOptions:
    """Distributions of a serve (uniform within each range; spin kind by ``spin_probabilities``)."""

    # A served-ball distribution like a ball launcher aimed at the robot's forehand (as in the WAM
    # table-tennis experiments the paper reports): launched from |y| < 0.1 m at 4.0-5.5 m/s, bouncing
    # within 15 cm of the centre line at x -0.9..-0.5 m, so that the balls pass the robot's hitting
    # region (x ~ -1.3 m) within |y| < 0.25 m. Slower serves cannot reach the robot's half from x >= 1.6 m.
    x_range_m: tuple = (1.6, 2.0)
    y_range_m: tuple = (-0.1, 0.1)
    z_range_m: tuple = (0.9, 1.2)
    speed_range_mps: tuple = (4.0, 5.5)
    spin_probabilities: tuple = (0.25, 0.25, 0.25, 0.25)  #: for SPIN_KINDS
    spin_range_rad_s: tuple = (20.0, 80.0)
    bounce_x_range_m: tuple = (-0.9, -0.5)
    bounce_y_range_m: tuple = (-0.15, 0.15)
    bounce_tolerance_m: float = 0.01
    max_attempts: int = 50

    def __post_init__(self):
        for name in ("x_range_m", "y_range_m", "z_range_m", "speed_range_mps", "spin_range_rad_s",
                     "bounce_x_range_m", "bounce_y_range_m"):
            _check_range(name, getattr(self, name))
        p = np.asarray(self.spin_probabilities, float)
        if p.shape != (len(SPIN_KINDS),) or (p < 0).any() or not np.isclose(p.sum(), 1.0):
            raise ValueError(f"spin_probabilities must be {len(SPIN_KINDS)} non-negative numbers summing to 1 "
                             f"(for {SPIN_KINDS}), got {self.spin_probabilities!r}")
        if self.speed_range_mps[0] <= 0 or self.max_attempts < 1 or self.bounce_tolerance_m <= 0:
            raise ValueError(f"LauncherOptions need positive speeds, tolerance and max_attempts, got {self}")


@dataclass(frozen=True)
class Serve:
    """One served ball: ``state`` (9,) [p, v, w] at launch (t = 0), what was drawn, and the bounce reached."""

    state: np.ndarray
    speed_mps: float
    spin_kind: str
    target_bounce_xy_m: np.ndarray
    bounce_m: np.ndarray
    attempts: int = 1
    notes: tuple = field(default=())


class BallLauncher:
    """Serves seeded balls; ``BallLauncher(seed=0).serve()`` is reproducible."""

    def __init__(self, params: BallParams | None = None, options: LauncherOptions = LauncherOptions(), *,
                 world: WorldOptions = WorldOptions(), seed: int | None = None,
                 rng: np.random.Generator | None = None):
        self.rng = rng_from(seed, rng, "BallLauncher")  # required: never OS entropy
        self.params = params or BallParams.load()  # fitted defaults, data/ball_params.yaml
        self.options = options
        self.world = world

    @property
    def table(self) -> TableGeometry:
        return self.world.table

    def _state(self, p0, speed, azimuth, elevation, kind, spin_mag) -> np.ndarray:
        d = np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
        horiz = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
        axis = {"none": np.zeros(3), "top": np.cross([0.0, 0.0, 1.0], horiz), "back": -np.cross([0.0, 0.0, 1.0], horiz),
                "side": np.array([0.0, 0.0, 1.0])}[kind]
        return np.concatenate([p0, speed * d, spin_mag * axis])

    def _bounce_xy(self, states: np.ndarray) -> np.ndarray:
        """(n, 9) -> (n, 2) first table-plane contact x, y (NaN if none within 1.5 s)."""
        wide = TableGeometry(self.table.surface_z_m, -10.0, 10.0, -10.0, 10.0)
        _, bounce = simulate(states, [1.5], self.params, wide, dt_s=2e-3)
        return bounce[:, 1:3]

    def _aim(self, p0, speed, kind, spin_mag, target) -> tuple[float, float] | None:
        azimuth0 = float(np.arctan2(target[1] - p0[1], target[0] - p0[0]))
        elevations = np.radians(np.linspace(-35.0, 60.0, 96))
        batch = np.array([self._state(p0, speed, azimuth0, el, kind, spin_mag) for el in elevations])
        reach = -(self._bounce_xy(batch)[:, 0] - p0[0])  # distance travelled towards -x
        want = p0[0] - target[0]
        ok = np.nonzero(np.isfinite(reach) & (reach >= want))[0]
        if ok.size == 0:
            return None
        el0 = float(elevations[ok[0]])  # flattest elevation that reaches the target

        def resid(x):
            return self._bounce_xy(self._state(p0, speed, x[0], x[1], kind, spin_mag)[None])[0] - target

        try:
            res = least_squares(resid, [azimuth0, el0], x_scale=[0.05, 0.05], xtol=1e-10, max_nfev=40)
        except ValueError:  # NaN residuals: the trial never reached the table plane
            return None
        if not np.isfinite(res.fun).all() or np.linalg.norm(res.fun) > self.options.bounce_tolerance_m:
            return None
        return float(res.x[0]), float(res.x[1])

    def serve(self) -> Serve:
        """Draw one serve; redraws until it bounces on the target without touching the net."""
        o, rng = self.options, self.rng
        for attempt in range(1, o.max_attempts + 1):
            p0 = np.array([rng.uniform(*o.x_range_m), rng.uniform(*o.y_range_m), rng.uniform(*o.z_range_m)])
            speed = float(rng.uniform(*o.speed_range_mps))
            kind = SPIN_KINDS[int(rng.choice(len(SPIN_KINDS), p=np.asarray(o.spin_probabilities, float)))]
            spin_mag = 0.0 if kind == "none" else float(rng.uniform(*o.spin_range_rad_s))
            if kind == "side":
                spin_mag *= rng.choice([-1.0, 1.0])
            target = np.array([rng.uniform(*o.bounce_x_range_m), rng.uniform(*o.bounce_y_range_m)])
            aim = self._aim(p0, speed, kind, spin_mag, target)
            if aim is None:
                continue
            state = self._state(p0, speed, aim[0], aim[1], kind, spin_mag)
            world = BallWorld(self.params, self.world)
            world.reset(state)
            while not world.done and world.t_s < 2.0 and not world.events:
                world.step()
            first = world.events[0] if world.events else None
            if first is None or first.kind != EventKind.TABLE or first.opponent_side:
                continue
            return Serve(state, speed, kind, target, first.position_m, attempt)
        raise ValueError(f"no feasible serve in {o.max_attempts} attempts with {o}; widen the speed or target ranges")

    def serve_many(self, n: int) -> list[Serve]:
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        return [self.serve() for _ in range(n)]
