"""Options of the hitting policy (:class:`policies.hitting.HittingPolicy`); see docs/play.md."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PLANNERS", "HittingOptions"]

PLANNERS = ("fast", "reference")  #: HittingOptions.planner (policies._hitting_motion / _hitting_return METHODS)


@dataclass(frozen=True)
class HittingOptions:
    """Lengths m, times s, lab world frame. Defaults: the simulated lab (docs/play.md).

    region_min_m, region_max_m : box where hitting candidates may lie (the robot's hitting region)
    horizon_s, candidate_dt_s : how far ahead the ball is predicted, and the spacing of candidate times
    min_lead_s : a new movement (or a re-planned reference) starts at least this long after now
    min_time_scale : shortest movement as a fraction of the ProMP's nominal duration (faster ones
        would need more acceleration than the demonstrations used)
    max_time_scalings : a candidate whose movement breaks the velocity/acceleration limits is retried
        this often, slowed by the factor that fixes it (starting earlier), if it can still start in time
    max_mahalanobis2 : a best candidate further than this (squared Mahalanobis distance of decision
        rule S2; chi^2 with 3 dof at 0.9999 by default) is out of the racket's reach: no plan
    max_candidates : best-ranked candidates tried before giving up on this step
    target_xy_m : where the return should land on the opponent's half; net_clearance_m : how far above
        the net's top (the policy's ``TableGeometry.net_height_m``) the return should cross
    racket_restitution, racket_friction : the policy's model of the racket contact (the world's values)
    max_return_residual_m : the refined return must meet its three targets this closely
    commit_before_hit_s : no re-planning closer than this to the hit (the commit point)
    replan_period_s : at most one plan per this period
    control_rate_hz : sampling rate of the commanded trajectory (the WAM's control loop)
    limit_margin : commanded velocities and accelerations stay within this fraction of the WAM's limits
    planner : "fast" (compiled return outcome, reduced conditioning) or "reference" (the public ball model and
        the ProMP API in sequence): the same plans to rounding, ~2.4x apart in time per planning step
        (``rt2 bench policy``)
    """

    region_min_m: tuple = (-1.75, -0.8, 0.85)
    region_max_m: tuple = (-1.0, 0.8, 1.5)
    horizon_s: float = 1.2
    candidate_dt_s: float = 0.004
    min_lead_s: float = 0.01
    min_time_scale: float = 0.9
    max_time_scalings: int = 2
    max_mahalanobis2: float = 21.1
    max_candidates: int = 3
    target_xy_m: tuple = (0.6, 0.0)
    net_clearance_m: float = 0.3
    racket_restitution: float = 0.78
    racket_friction: float = 0.25
    max_return_residual_m: float = 0.05
    commit_before_hit_s: float = 0.06
    replan_period_s: float = 0.02
    control_rate_hz: float = 500.0
    limit_margin: float = 1.0
    planner: str = "fast"

    def __post_init__(self):
        for name in ("region_min_m", "region_max_m"):
            v = np.asarray(getattr(self, name), float)
            if v.shape != (3,) or not np.isfinite(v).all():
                raise ValueError(f"HittingOptions.{name} must be 3 finite numbers, got {getattr(self, name)!r}")
        if not (np.asarray(self.region_min_m) < np.asarray(self.region_max_m)).all():
            raise ValueError(f"HittingOptions.region_min_m must be below region_max_m, got {self.region_min_m}, "
                             f"{self.region_max_m}")
        t = np.asarray(self.target_xy_m, float)
        if t.shape != (2,) or not np.isfinite(t).all() or t[0] <= 0:
            raise ValueError(f"HittingOptions.target_xy_m must be (x > 0, y) on the opponent's half, got {self.target_xy_m!r}")
        for name in ("horizon_s", "candidate_dt_s", "max_mahalanobis2", "max_return_residual_m",
                     "replan_period_s", "control_rate_hz"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
                raise ValueError(f"HittingOptions.{name} must be a finite number > 0, got {v!r}")
        for name in ("min_lead_s", "net_clearance_m", "racket_friction", "commit_before_hit_s"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                raise ValueError(f"HittingOptions.{name} must be a finite number >= 0, got {v!r}")
        if not 0 < self.min_time_scale <= 1:
            raise ValueError(f"HittingOptions.min_time_scale must be in (0, 1], got {self.min_time_scale!r}")
        if not 0 < self.racket_restitution <= 1:
            raise ValueError(f"HittingOptions.racket_restitution must be in (0, 1], got {self.racket_restitution!r}")
        if self.planner not in PLANNERS:
            raise ValueError(f"HittingOptions.planner must be one of {list(PLANNERS)}, got {self.planner!r}")
        if not 0 < self.limit_margin <= 1:
            raise ValueError(f"HittingOptions.limit_margin must be in (0, 1], got {self.limit_margin!r}")
        if isinstance(self.max_time_scalings, bool) or not isinstance(self.max_time_scalings, int) or self.max_time_scalings < 0:
            raise ValueError(f"HittingOptions.max_time_scalings must be a non-negative integer, got {self.max_time_scalings!r}")
        if isinstance(self.max_candidates, bool) or not isinstance(self.max_candidates, int) or self.max_candidates < 1:
            raise ValueError(f"HittingOptions.max_candidates must be a positive integer, got {self.max_candidates!r}")
