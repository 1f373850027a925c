"""The ball-filter contract: what a filter takes (tracker observations) and what it gives (state, prediction).

Shared by the two filters of docs/filters.md: ``raw`` (every observation accepted, the paper's RT2
configuration) and ``ransac_kalman`` (the paper's RTBlob heuristics, sec. 3.2). Checking of one
observation happens here, once, so both filters flag the same bad input the same way.

Types that cross into the hitting policy and the playing sessions:

* :class:`FilterUpdate` -- the verdict on one observation (accepted, and why);
* :class:`FilterState` -- the current ball state (time, position, velocity, spin if modelled, 6x6
  covariance of [position, velocity]);
* :class:`BallTrajectoryPrediction` -- predicted positions, velocities and position covariances at
  query times, with :meth:`~BallTrajectoryPrediction.crossing` for the crossing of a plane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from tracker.observation import BallObservation

__all__ = [
    "MAX_ABS_POSITION_M",
    "BallFilter",
    "BallTrajectoryPrediction",
    "FilterState",
    "FilterUpdate",
    "Measurement",
    "check_measurement",
    "check_query_times",
    "check_spin_prior",
    "measurement_noise",
]


#: Coordinates beyond this are not a table-tennis ball in any lab frame: flagged as invalid input
#: (a sanity bound on the numbers, far above the tens of metres of RTBlob's worst outliers).
MAX_ABS_POSITION_M = 1000.0


@dataclass(frozen=True)
class FilterUpdate:
    """Verdict on one observation.

    accepted : the observation's position was used by the filter
    reason : why, e.g. ``"accepted"``, ``"no position"``, ``"rejected: 4.2 sigma"``, ``"time not increasing"``
    distance_sigma : Mahalanobis distance of the innovation (``ransac_kalman`` once initialised), else NaN
    pending : the verdict is deferred (``ransac_kalman`` buffering its RANSAC window; ``accepted`` is
        then False, RANSAC decides when the window is full)
    """

    accepted: bool
    reason: str
    distance_sigma: float = math.nan
    pending: bool = False


@dataclass(frozen=True)
class FilterState:
    """The filtered ball state at time ``t_s`` (world frame, or the frame of the observations).

    t_s : time of the state, seconds (clock of ``BallObservation.t_s``)
    position : (3,) m;  velocity : (3,) m/s
    spin : (3,) rad/s when the filter models it (``raw``), else None
    acceleration : (3,) m/s^2, the total acceleration the filter's model gives at ``t_s``
    covariance : (6, 6) covariance of [position, velocity]
    n_used : observations the estimate rests on since the last (re)initialisation
    """

    t_s: float
    position: np.ndarray
    velocity: np.ndarray
    spin: np.ndarray | None
    acceleration: np.ndarray
    covariance: np.ndarray
    n_used: int

    @property
    def position_covariance(self) -> np.ndarray:
        """(3, 3) m^2."""
        return self.covariance[0:3, 0:3]


@dataclass(frozen=True)
class BallTrajectoryPrediction:
    """Predicted ball trajectory at query times.

    t_s : (M,) query times, seconds
    position_m : (M, 3) predicted ball centres
    velocity_mps : (M, 3) predicted velocities
    covariance_m2 : (M, 3, 3) covariance of each predicted position
    """

    t_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    covariance_m2: np.ndarray

    @property
    def position_std_m(self) -> np.ndarray:
        """(M, 3) per-axis standard deviations."""
        return np.sqrt(np.maximum(np.diagonal(self.covariance_m2, axis1=1, axis2=2), 0.0))

    def crossing(self, value_m: float, axis: int = 0) -> tuple[float, np.ndarray, np.ndarray] | None:
        """First crossing of the plane ``position[axis] = value_m`` (either direction).

        Linear interpolation between the two bracketing query times; returns ``(t_s, position (3,),
        covariance (3, 3))`` or None if the predicted trajectory does not cross the plane.
        """
        if axis not in (0, 1, 2) or not np.isfinite(value_m):
            raise ValueError(f"crossing needs axis in (0, 1, 2) and a finite value_m, got axis={axis!r}, "
                             f"value_m={value_m!r}")
        d = self.position_m[:, axis] - value_m
        hit = np.flatnonzero(d[:-1] * d[1:] <= 0.0)
        hit = hit[(d[hit] != 0.0) | (d[hit + 1] != 0.0)]
        if hit.size == 0:
            return None
        i = int(hit[0])
        s = 0.0 if d[i] == d[i + 1] else d[i] / (d[i] - d[i + 1])
        lerp = lambda a: a[i] + s * (a[i + 1] - a[i])  # noqa: E731
        return float(lerp(self.t_s)), lerp(self.position_m), lerp(self.covariance_m2)


@runtime_checkable
class BallFilter(Protocol):
    """One ball filter: feed observations in arrival order, read the state and predictions.

    ``reset()`` starts a new ball. ``update(obs)`` never raises on bad observation content (NaN,
    wrong shapes, times going backwards): it returns a rejected :class:`FilterUpdate` naming the
    problem. ``state()`` and ``predict()`` return None before the filter has enough data.
    """

    name: str

    def reset(self) -> None: ...

    def update(self, obs: BallObservation) -> FilterUpdate: ...

    def state(self) -> FilterState | None: ...

    def predict(self, t_query_s: np.ndarray) -> BallTrajectoryPrediction | None: ...


# --------------------------------------------------------------------------- boundary checks


@dataclass(frozen=True)
class Measurement:
    """A checked observation: time, (3,) position, (3, 3) noise covariance, and a note on the noise."""

    t_s: float
    z_m: np.ndarray
    R_m2: np.ndarray
    note: str = ""


def measurement_noise(covariance_m2, floor_std_m: float, default_std_m: float) -> tuple[np.ndarray, str]:
    """(3, 3) measurement covariance: the tracker's, eigenvalues floored at ``floor_std_m**2``.

    Without a covariance (None) the default isotropic ``default_std_m``; a malformed one (wrong
    shape, NaN, not symmetric) is replaced by the default and named in the returned note.
    """
    default = np.eye(3) * max(default_std_m, floor_std_m) ** 2
    if covariance_m2 is None:
        return default, ""
    try:
        C = np.asarray(covariance_m2, float)
    except (TypeError, ValueError):
        return default, "malformed covariance ignored"
    if C.shape != (3, 3) or not np.isfinite(C).all() or not np.allclose(C, C.T, rtol=1e-6, atol=1e-12):
        return default, f"malformed covariance (shape {C.shape}) ignored"
    w, V = np.linalg.eigh(C)
    w = np.maximum(w, floor_std_m**2)
    return (V * w) @ V.T, ""


def check_measurement(obs, last_t_s: float | None, floor_std_m: float,
                      default_std_m: float) -> tuple[Measurement | None, FilterUpdate | None]:
    """Check one observation -> ``(measurement, None)`` or ``(None, rejection)``.

    Raises ``ValueError`` only when ``obs`` is not a BallObservation at all (a programming error).
    """
    if not isinstance(obs, BallObservation):
        raise ValueError(f"update expects a tracker.BallObservation, got {type(obs).__name__}: {obs!r:.80}")
    try:
        t = float(obs.t_s)
    except (TypeError, ValueError):
        return None, FilterUpdate(False, f"invalid time {obs.t_s!r}")
    if not math.isfinite(t):
        return None, FilterUpdate(False, f"invalid time {t!r}")
    if obs.position_m is None:
        return None, FilterUpdate(False, "no position")
    try:
        z = np.asarray(obs.position_m, float)
    except (TypeError, ValueError):
        return None, FilterUpdate(False, f"invalid position {obs.position_m!r:.60}")
    if z.shape != (3,):
        return None, FilterUpdate(False, f"invalid position shape {z.shape}, expected (3,)")
    if not np.isfinite(z).all():
        return None, FilterUpdate(False, f"non-finite position {z.tolist()}")
    if (np.abs(z) > MAX_ABS_POSITION_M).any():
        return None, FilterUpdate(False, f"invalid position {z.tolist()}: beyond {MAX_ABS_POSITION_M:g} m")
    if last_t_s is not None and t <= last_t_s:
        return None, FilterUpdate(False, f"time not increasing: t_s={t!r} after {last_t_s!r}")
    R, note = measurement_noise(obs.covariance_m2, floor_std_m, default_std_m)
    return Measurement(t, z.copy(), R, note), None


def check_query_times(t_query_s, t_state_s: float) -> np.ndarray:
    """t_query_s : (M,) finite non-decreasing times >= the state time -> float array; else ValueError."""
    try:
        t = np.asarray(t_query_s, float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"t_query_s must be numeric, got {t_query_s!r:.80}") from exc
    if t.ndim == 0:
        t = t[None]
    if t.ndim != 1 or t.size == 0:
        raise ValueError(f"t_query_s must have shape (M,) with M >= 1, got shape {t.shape}")
    if not np.isfinite(t).all():
        raise ValueError(f"t_query_s must be finite, got {t[~np.isfinite(t)][:3]!r}")
    if (np.diff(t) < 0).any():
        i = int(np.argmax(np.diff(t) < 0))
        raise ValueError(f"t_query_s must be non-decreasing; t_query_s[{i + 1}] = {t[i + 1]!r} < {t[i]!r}")
    if t[0] < t_state_s - 1e-9:
        raise ValueError(f"t_query_s must start at or after the state time {t_state_s!r}; got {t[0]!r}")
    return t


def check_spin_prior(mean_rad_s, cov_rad2_s2, owner: str) -> None:
    """A filter's spin prior option: mean (3,) finite rad/s; covariance None or (3, 3) symmetric positive
    definite rad^2/s^2. ValueError naming ``owner`` and quoting the value otherwise."""
    from policies.ball_estimation import check_spin_cov

    try:
        m = np.asarray(mean_rad_s, float)
    except (TypeError, ValueError):
        m = None
    if m is None or m.shape != (3,) or not np.isfinite(m).all():
        raise ValueError(f"{owner}.spin_prior_mean_rad_s must be 3 finite numbers, got {mean_rad_s!r}")
    if cov_rad2_s2 is not None:
        check_spin_cov(cov_rad2_s2, f"{owner}.spin_prior_cov_rad2_s2")
