"""``ransac_kalman``: the paper's RTBlob outlier heuristics (sec. 3.2) as a ball filter.

"To detect and filter outliers, the RANSAC algorithm was used on a set of initial observations
fitting a second order polynomial. Once a set of candidate positions is found, a Kalman filter is
used to predict the ball trajectory and subsequent ball observations are rejected if they are more
than 3 standard deviations away from the mean position predicted by the Kalman filter."

1. Buffer the first ``init_samples`` observations; RANSAC a per-axis quadratic in time on them
   (:mod:`policies.filters._ransac`); too few inliers -> slide the window and try again.
2. Initialise a filterpy ``KalmanFilter`` over ``[p, v, a]`` (``a``: acceleration the model does
   not explain) from the inliers: prior at the first inlier, then filter the inliers in order.
3. Each new observation: propagate with :mod:`policies.filters._ballistic` (gravity as control
   input, linearised drag, the table bounce); reject it when the innovation is more than
   ``gate_sigma`` standard deviations from the prediction (Mahalanobis distance of the 3D
   innovation under ``S = H P H^T + R`` by default, or any single axis with ``gate="per_axis"``).
4. Lost ball: after ``max_consecutive_rejections`` rejections in a row, RANSAC again on the last
   ``init_samples`` observations (accepted or not) and re-initialise from its inliers.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import numpy as np

from policies.ball_model import BallParams, TableGeometry, acceleration
from policies.filters import _ballistic
from policies.filters._base import (
    BallTrajectoryPrediction,
    FilterState,
    FilterUpdate,
    Measurement,
    check_measurement,
    check_query_times,
    check_spin_prior,
)
from policies.filters._ransac import RansacInfo, ransac_quadratic
from tracker.observation import BallObservation

__all__ = ["GATES", "RansacKalmanFilter", "RansacKalmanOptions"]

GATES = ("mahalanobis", "per_axis")
_H = np.hstack([np.eye(3), np.zeros((3, 6))])


@dataclass(frozen=True)
class RansacKalmanOptions:
    """Options of :class:`RansacKalmanFilter` (SI units; docs/filters.md, sec. 3).

    init_samples : observations RANSAC starts from (the paper's "set of initial observations")
    min_inliers : RANSAC succeeds with at least this many inliers among them
    inlier_threshold_m : Euclidean distance to the quadratic within which an observation is an inlier
    ransac_iterations : candidate triples drawn per RANSAC run
    gate_sigma : reject an observation farther than this many standard deviations (the paper's 3)
    gate : "mahalanobis" (3D innovation) or "per_axis" (any axis beyond gate_sigma)
    max_consecutive_rejections : more rejections in a row -> lost: re-initialise with RANSAC
    position_noise_floor_m, default_position_noise_m : measurement std floor, and std without covariance
    accel_noise_mps2 : sqrt PSD of the white acceleration noise on v, m/s^2/sqrt(Hz)
    accel_walk_mps3 : sqrt PSD of the random walk of the unexplained acceleration, m/s^3/sqrt(Hz)
    accel_prior_std_mps2 : prior std of the unexplained acceleration (initialisation and after a bounce)
    init_velocity_std_mps : prior std of the velocity from the RANSAC quadratic at the first inlier
    predict_accel_noise_mps2 : sqrt PSD of the white acceleration noise used when predicting (the
        unexplained-acceleration state carries the model error; see docs/filters.md for the coverage)
    bounce_velocity_std_frac, bounce_velocity_floor_mps : velocity std added at a bounce, per axis,
        ``frac |v'| + floor``
    max_step_s : longest propagation step
    spin_prior_mean_rad_s, spin_prior_cov_rad2_s2 : optional spin prior (world frame, rad/s and (3, 3)
        rad^2/s^2; e.g. a launcher's, docs/ball_physics.md sec. 5). The filter has no spin state: the
        prior of its unexplained acceleration becomes the acceleration this spin causes at the initial
        velocity (Magnus lift and spin drag, eq. 1) with the spin covariance mapped through it added,
        and the table bounce uses the mean spin (docs/filters.md, sec. 3.4).
        Default: no spin (zero mean, no covariance): zero-mean acceleration prior, spin-free bounce.
    seed : seed of RANSAC's random triples; the generator restarts at every :meth:`reset`
    """

    init_samples: int = 12
    min_inliers: int = 8
    inlier_threshold_m: float = 0.03
    ransac_iterations: int = 100
    gate_sigma: float = 3.0
    gate: str = "mahalanobis"
    max_consecutive_rejections: int = 6
    position_noise_floor_m: float = 0.002
    default_position_noise_m: float = 0.003
    accel_noise_mps2: float = 1.0
    accel_walk_mps3: float = 1.0
    accel_prior_std_mps2: float = 1.0
    init_velocity_std_mps: float = 1.0
    predict_accel_noise_mps2: float = 0.2
    bounce_velocity_std_frac: float = 0.1
    bounce_velocity_floor_mps: float = 0.05
    max_step_s: float = 0.005
    spin_prior_mean_rad_s: tuple = (0.0, 0.0, 0.0)
    spin_prior_cov_rad2_s2: tuple | None = None
    seed: int = 0

    def __post_init__(self):
        if self.gate not in GATES:
            raise ValueError(f"RansacKalmanOptions.gate must be one of {list(GATES)}, got {self.gate!r}")
        if not (isinstance(self.init_samples, int) and self.init_samples >= 4):
            raise ValueError(f"RansacKalmanOptions.init_samples must be an int >= 4, got {self.init_samples!r}")
        if not (isinstance(self.min_inliers, int) and 3 <= self.min_inliers <= self.init_samples):
            raise ValueError(f"RansacKalmanOptions.min_inliers must be an int in [3, init_samples="
                             f"{self.init_samples}], got {self.min_inliers!r}")
        for name in ("ransac_iterations", "max_consecutive_rejections"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"RansacKalmanOptions.{name} must be an int >= 1, got {v!r}")
        for name in ("inlier_threshold_m", "gate_sigma", "position_noise_floor_m", "default_position_noise_m",
                     "accel_prior_std_mps2", "init_velocity_std_mps", "max_step_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"RansacKalmanOptions.{name} must be a finite number > 0, got {v!r}")
        for name in ("accel_noise_mps2", "accel_walk_mps3", "predict_accel_noise_mps2", "bounce_velocity_std_frac",
                     "bounce_velocity_floor_mps"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"RansacKalmanOptions.{name} must be a finite number >= 0, got {v!r}")
        check_spin_prior(self.spin_prior_mean_rad_s, self.spin_prior_cov_rad2_s2, "RansacKalmanOptions")


class RansacKalmanFilter:
    """The paper's RTBlob heuristics: RANSAC start, Kalman filter with 3-sigma gating, bounce, re-initialisation.

    Implements :class:`policies.filters.BallFilter`; build it with ``make_filter("ransac_kalman", ...)``.
    ``counters`` holds accepted / rejected / reinitialisations since the last reset.
    """

    name = "ransac_kalman"

    def __init__(self, params: BallParams | None = None, table: TableGeometry | None = None,
                 options: RansacKalmanOptions = RansacKalmanOptions()):
        from filterpy.kalman import KalmanFilter

        self.params = params or BallParams.load()  # fitted defaults, data/ball_params.yaml
        self.table = table or TableGeometry()
        self.options = options
        o, p, tb = options, self.params, self.table
        self._coeffs = _ballistic.coefficients(
            p, tb, q_acc=o.accel_noise_mps2**2, q_jerk=o.accel_walk_mps3**2, bounce_frac=o.bounce_velocity_std_frac,
            bounce_floor_mps=o.bounce_velocity_floor_mps, accel_prior_var=o.accel_prior_std_mps2**2,
            max_step_s=o.max_step_s, spin_rad_s=tuple(float(w) for w in o.spin_prior_mean_rad_s))
        assert self._coeffs.shape == (_ballistic.N_COEFFS,)
        self._predict_coeffs = self._coeffs.copy()
        self._predict_coeffs[10] = o.predict_accel_noise_mps2**2
        self._kf = KalmanFilter(dim_x=9, dim_z=3)
        self._kf.H = _H.copy()
        self.reset()

    # ------------------------------------------------------------------ protocol

    def reset(self) -> None:
        self._rng = np.random.default_rng(self.options.seed)
        self._recent: collections.deque[Measurement] = collections.deque(maxlen=self.options.init_samples)
        self._t: float | None = None  # time of the Kalman state; None = not initialised
        self._last_t: float | None = None
        self._consecutive = 0
        self._n_used = 0
        self.counters = {"accepted": 0, "rejected": 0, "pending": 0, "invalid": 0, "no_position": 0, "initialised": 0,
                         "reinitialised": 0, "ransac_failed": 0}
        self.last_ransac: RansacInfo | None = None

    def update(self, obs: BallObservation) -> FilterUpdate:
        o = self.options
        m, rejection = check_measurement(obs, self._last_t, o.position_noise_floor_m, o.default_position_noise_m)
        if rejection is not None:
            self.counters["no_position" if rejection.reason == "no position" else "invalid"] += 1
            return rejection
        upd = self._update(m)
        self.counters["pending" if upd.pending else "accepted" if upd.accepted else "rejected"] += 1
        return upd

    def _update(self, m: Measurement) -> FilterUpdate:
        o = self.options
        self._last_t = m.t_s
        self._recent.append(m)
        note = f" ({m.note})" if m.note else ""
        if self._t is None:  # 1. collecting the initial set
            if len(self._recent) < o.init_samples:
                return FilterUpdate(False, f"buffered for RANSAC ({len(self._recent)}/{o.init_samples}){note}",
                                    pending=True)
            ok, inlier = self._initialise("initialised")
            if not ok:
                return FilterUpdate(False, f"no RANSAC consensus yet ({self.last_ransac.n_inliers}/"
                                           f"{o.init_samples} inliers){note}", pending=True)
            return FilterUpdate(inlier, ("initialised by RANSAC" if inlier else "rejected by RANSAC at initialisation")
                                + note)
        # 3. propagate and gate
        self._propagate_to(m.t_s)
        kf = self._kf
        y = m.z_m - kf.x[0:3]
        S = kf.P[0:3, 0:3] + m.R_m2
        d = float(math.sqrt(max(y @ np.linalg.solve(S, y), 0.0)))
        if o.gate == "mahalanobis":
            outside = d > o.gate_sigma
        else:
            outside = bool((np.abs(y) > o.gate_sigma * np.sqrt(np.diag(S))).any())
        if not outside:
            kf.update(m.z_m, R=m.R_m2)
            self._consecutive = 0
            self._n_used += 1
            return FilterUpdate(True, "accepted" + note, d)
        self._consecutive += 1
        if self._consecutive >= o.max_consecutive_rejections:  # 4. lost: RANSAC on the recent observations
            ok, inlier = self._initialise("reinitialised")
            if ok:
                verdict = "" if inlier else ", this observation rejected"
                return FilterUpdate(inlier, f"lost after {o.max_consecutive_rejections} rejections: reinitialised "
                                            f"by RANSAC{verdict}" + note, d)
        return FilterUpdate(False, f"rejected: {d:.1f} sigma > {o.gate_sigma:g}" + note, d)

    def state(self) -> FilterState | None:
        if self._t is None:
            return None
        x, P = self._kf.x, self._kf.P
        v = x[3:6]
        acc = x[6:9] - self.params.k_drag * np.linalg.norm(v) * v
        acc[2] -= self.params.gravity_mps2
        return FilterState(t_s=self._t, position=x[0:3].copy(), velocity=v.copy(), spin=None, acceleration=acc,
                           covariance=P[0:6, 0:6].copy(), n_used=self._n_used)

    def predict(self, t_query_s) -> BallTrajectoryPrediction | None:
        """Propagate the Kalman mean and covariance (flight, bounce, process noise) to t_query_s (M,)."""
        if self._t is None:
            return None
        t = check_query_times(t_query_s, self._t)
        X, Ps, _ = _ballistic.propagate_nb(self._kf.x.copy(), self._kf.P.copy(), self._t, t, self._predict_coeffs)
        return BallTrajectoryPrediction(t_s=t, position_m=X[:, 0:3].copy(), velocity_mps=X[:, 3:6].copy(),
                                        covariance_m2=Ps[:, 0:3, 0:3].copy())

    # ------------------------------------------------------------------ internals

    def _propagate_to(self, t_s: float) -> None:
        X, Ps, _ = _ballistic.propagate_nb(self._kf.x, self._kf.P, self._t, np.array([t_s]), self._coeffs)
        self._kf.x, self._kf.P = X[0], Ps[0]
        self._t = t_s

    def _spin_acceleration_prior(self, v0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean (3,) and covariance (3, 3) of the acceleration the spin prior adds at velocity v0 (eq. 1)."""
        o = self.options
        w0 = np.asarray(o.spin_prior_mean_rad_s, float)
        if o.spin_prior_cov_rad2_s2 is None and not w0.any():
            return np.zeros(3), np.zeros((3, 3))
        step = 1e-3  # rad/s, forward differences of the (smooth) lift and spin drag in the spin
        states = np.tile(np.concatenate([np.zeros(3), v0, w0]), (5, 1))
        states[0, 6:9] = 0.0
        states[2:5, 6:9] += np.eye(3) * step
        acc = acceleration(states, self.params)  # (5, 3): no spin, the prior mean, and 3 nudges
        J = (acc[2:5] - acc[1]).T / step  # d acceleration / d spin, (3, 3)
        cov_w = np.zeros((3, 3)) if o.spin_prior_cov_rad2_s2 is None else np.asarray(o.spin_prior_cov_rad2_s2, float)
        return acc[1] - acc[0], J @ cov_w @ J.T

    def _initialise(self, counter: str) -> tuple[bool, bool]:
        """RANSAC on the buffered observations; on success (re)start the Kalman filter from the inliers.

        Returns (success, whether the newest observation is an inlier).
        """
        o = self.options
        ms = list(self._recent)
        t = np.array([m.t_s for m in ms])
        X = np.array([m.z_m for m in ms])
        track, info = ransac_quadratic(t, X, inlier_threshold_m=o.inlier_threshold_m, min_inliers=o.min_inliers,
                                       iterations=o.ransac_iterations, rng=self._rng)
        self.last_ransac = info
        if track is None:
            self.counters["ransac_failed"] += 1
            return False, False
        inl = [m for m, keep in zip(ms, info.inliers) if keep]
        # 2. prior at the first inlier: its position, the quadratic's velocity, the unexplained
        # acceleration of the spin prior (zero without one)
        first = inl[0]
        v0 = track.velocity([first.t_s])[0]
        a0, cov_a = self._spin_acceleration_prior(v0)
        x0 = np.concatenate([first.z_m, v0, a0])
        P0 = np.zeros((9, 9))
        P0[0:3, 0:3] = first.R_m2
        P0[3:6, 3:6] = np.eye(3) * o.init_velocity_std_mps**2
        P0[6:9, 6:9] = np.eye(3) * o.accel_prior_std_mps2**2 + cov_a
        kf = self._kf
        kf.x, kf.P = x0, P0
        self._t = first.t_s
        for m in inl[1:]:  # filter the inliers in order, no gating: RANSAC chose them
            self._propagate_to(m.t_s)
            kf.update(m.z_m, R=m.R_m2)
        self._n_used = len(inl)
        self._consecutive = 0
        self.counters[counter] += 1
        # the Kalman state is at the last inlier; bring it to the newest observation's time
        if self._t < ms[-1].t_s:
            self._propagate_to(ms[-1].t_s)
        return True, bool(info.inliers[-1])
