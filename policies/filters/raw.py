"""``raw``: every observation is the truth -- the paper's RT2 configuration, "no heuristics at all" (sec. 3.2).

The state ``[p, v, w]`` comes from the physical ball model of docs/ball_physics.md (flight with
drag and Magnus lift, eqs. 1-2; table bounce, eqs. 3-6), docs/filters.md sec. 2:

1. the first ``init_samples`` observations: plain (non-robust) least squares of the initial state
   through all of them, :func:`policies.ball_estimation.fit_initial_state` with ``robust_scale=None``
   and a Gaussian spin prior (eq. 7);
2. every later observation: an extended Kalman step -- transition = the integrator (so the bounce
   is in it), linearised by batched forward differences; white acceleration and spin noise; the
   update (filterpy's ``update``) takes the tracker's covariance as measurement noise.

What ``raw`` deliberately does not do: no robust loss, no RANSAC, no innovation gate, no
re-initialisation on suspicious data. An outlier moves the estimate by its Kalman gain, like any
observation. (Only a numerical failure -- the fit or the integrator producing non-finite numbers --
restarts the fit from the current observation, so that a session never crashes.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from policies.ball_estimation import EstimatorOptions, fit_initial_state
from policies.ball_model import BallParams, TableGeometry, acceleration, simulate
from policies.filters._base import (
    BallTrajectoryPrediction,
    FilterState,
    FilterUpdate,
    Measurement,
    check_measurement,
    check_query_times,
    check_spin_prior,
)
from tracker.observation import BallObservation

__all__ = ["RawFilter", "RawOptions"]

_H = np.hstack([np.eye(3), np.zeros((3, 6))])
# Forward-difference steps of the state Jacobian: position (m), velocity (m/s), spin (rad/s).
_FD_STEP = np.array([1e-6] * 6 + [1e-4] * 3)


@dataclass(frozen=True)
class RawOptions:
    """Options of :class:`RawFilter` (SI units; docs/filters.md, sec. 2).

    init_samples : observations of the initial least-squares fit
    position_noise_floor_m, default_position_noise_m : measurement std floor, and std without covariance
    accel_noise_mps2 : sqrt PSD of the white acceleration the model misses, m/s^2/sqrt(Hz)
    spin_noise_rad_s2 : sqrt PSD of the spin random walk, rad/s^2/sqrt(Hz)
    spin_prior_std_rad_s : std of the spin prior of the initial fit (eq. 7)
    spin_prior_mean_rad_s, spin_prior_cov_rad2_s2 : mean (3,) of that prior (default 0), and optionally
        its full (3, 3) covariance instead of ``spin_prior_std_rad_s`` -- a launcher's spin prior learned
        from its fitted flights (``rt2 sim fit-flight``, docs/ball_physics.md sec. 5), world frame
    predict_accel_noise_mps2 : sqrt PSD of the white acceleration added to predicted covariances (the
        filter's own ``accel_noise_mps2`` over-covers long horizons; 0.2 gives ~90-95 % coverage of
        the 95 % ellipsoid at +100..300 ms on real and simulated flights, docs/filters.md)
    dt_s : integrator step
    """

    init_samples: int = 10
    position_noise_floor_m: float = 0.002
    default_position_noise_m: float = 0.003
    accel_noise_mps2: float = 0.5
    spin_noise_rad_s2: float = 20.0
    spin_prior_std_rad_s: float = 15.0
    spin_prior_mean_rad_s: tuple = (0.0, 0.0, 0.0)
    spin_prior_cov_rad2_s2: tuple | None = None
    predict_accel_noise_mps2: float = 0.2
    dt_s: float = 2e-3

    def __post_init__(self):
        if not (isinstance(self.init_samples, int) and self.init_samples >= 4):
            raise ValueError(f"RawOptions.init_samples must be an int >= 4, got {self.init_samples!r}")
        for name in ("position_noise_floor_m", "default_position_noise_m", "spin_prior_std_rad_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"RawOptions.{name} must be a finite number > 0, got {v!r}")
        for name in ("accel_noise_mps2", "spin_noise_rad_s2", "predict_accel_noise_mps2"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"RawOptions.{name} must be a finite number >= 0, got {v!r}")
        if not (isinstance(self.dt_s, (int, float)) and 0 < self.dt_s <= 0.01):
            raise ValueError(f"RawOptions.dt_s must be in (0, 0.01] s, got {self.dt_s!r}")
        check_spin_prior(self.spin_prior_mean_rad_s, self.spin_prior_cov_rad2_s2, "RawOptions")


class RawFilter:
    """No outlier heuristics: the physical ball model fitted to every observation since reset.

    Implements :class:`policies.filters.BallFilter`; build it with ``make_filter("raw", ...)``.
    """

    name = "raw"

    def __init__(self, params: BallParams | None = None, table: TableGeometry | None = None,
                 options: RawOptions = RawOptions()):
        self.params = params or BallParams.load()  # fitted defaults, data/ball_params.yaml
        self.table = table or TableGeometry()
        self.options = options
        self.reset()

    def reset(self) -> None:
        self._buffer: list[Measurement] = []
        self._t: float | None = None
        self._x = np.zeros(9)
        self._P = np.zeros((9, 9))
        self._last_t: float | None = None
        self._n_used = 0
        self.counters = {"accepted": 0, "invalid": 0, "no_position": 0, "numerical_failures": 0}

    def _restart(self, first: Measurement) -> None:
        """Forget the estimate (not the counters) and start a new initial fit at ``first``."""
        self._t = None
        self._buffer = [first]
        self._n_used = 1

    def update(self, obs: BallObservation) -> FilterUpdate:
        from filterpy.kalman import update as kalman_update

        o = self.options
        m, rejection = check_measurement(obs, self._last_t, o.position_noise_floor_m, o.default_position_noise_m)
        if rejection is not None:
            self.counters["no_position" if rejection.reason == "no position" else "invalid"] += 1
            return rejection
        self._last_t = m.t_s
        self._n_used += 1
        self.counters["accepted"] += 1
        note = f" ({m.note})" if m.note else ""
        if self._t is None:  # 1. initial least-squares fit
            self._buffer.append(m)
            if len(self._buffer) < o.init_samples:
                return FilterUpdate(True, f"buffered for the initial fit ({len(self._buffer)}/{o.init_samples})" + note)
            try:
                self._initialise()
            except (ValueError, np.linalg.LinAlgError) as exc:  # numerical failure, not a judgement on data
                self._buffer = self._buffer[1:]
                self.counters["numerical_failures"] += 1
                return FilterUpdate(True, f"initial fit failed numerically ({str(exc)[:60]}); window slides" + note)
            return FilterUpdate(True, "initialised" + note)
        # 2. EKF step, no gate
        try:
            x_new, F = self._propagate_with_jacobian(m.t_s)
            P = F @ self._P @ F.T + self._process_noise(m.t_s - self._t)
            x, P = kalman_update(x_new, P, m.z_m, m.R_m2, _H)
            if not (np.isfinite(x).all() and np.isfinite(P).all()):
                raise ValueError("non-finite state")
        except (ValueError, np.linalg.LinAlgError) as exc:  # the state blew up: start a new fit from here
            self._restart(m)
            self.counters["numerical_failures"] += 1
            return FilterUpdate(True, f"numerical failure ({str(exc)[:60]}); restarted the fit" + note)
        self._x, self._P = x, 0.5 * (P + P.T)
        self._t = m.t_s
        return FilterUpdate(True, "accepted" + note)

    def state(self) -> FilterState | None:
        if self._t is None:
            return None
        return FilterState(t_s=self._t, position=self._x[0:3].copy(), velocity=self._x[3:6].copy(),
                           spin=self._x[6:9].copy(), acceleration=acceleration(self._x, self.params),
                           covariance=self._P[0:6, 0:6].copy(), n_used=self._n_used)

    def predict(self, t_query_s) -> BallTrajectoryPrediction | None:
        """The ball model from the current state; covariance by the linearised flow plus accumulated noise."""
        if self._t is None:
            return None
        t = check_query_times(t_query_s, self._t)
        batch = np.repeat(self._x[None], 10, axis=0)
        batch[1:] += np.diag(_FD_STEP)
        out, _ = simulate(batch, t, self.params, self.table, t0_s=self._t, dt_s=self.options.dt_s)  # (10, M, 9)
        Phi = np.transpose((out[1:, :, 0:6] - out[0, None, :, 0:6]) / _FD_STEP[:, None, None], (1, 2, 0))  # (M, 6, 9)
        cov = Phi @ self._P @ np.transpose(Phi, (0, 2, 1))
        tau = t - self._t
        q = self.options.predict_accel_noise_mps2**2
        cov[:, 0:3, 0:3] += (q * tau**3 / 3)[:, None, None] * np.eye(3)
        return BallTrajectoryPrediction(t_s=t, position_m=out[0, :, 0:3].copy(), velocity_mps=out[0, :, 3:6].copy(),
                                        covariance_m2=cov[:, 0:3, 0:3].copy())

    # ------------------------------------------------------------------ internals

    def _initialise(self) -> None:
        ms = self._buffer
        R_mean = np.mean([m.R_m2 for m in ms], axis=0)
        sigma = tuple(float(s) for s in np.sqrt(np.diag(R_mean)))
        o = self.options
        opts = EstimatorOptions(position_noise_m=sigma, robust_scale=None,  # plain least squares: no heuristics
                                spin_prior_std_rad_s=o.spin_prior_std_rad_s, spin_prior_mean_rad_s=o.spin_prior_mean_rad_s,
                                spin_prior_cov_rad2_s2=o.spin_prior_cov_rad2_s2, dt_s=o.dt_s)
        est, _ = fit_initial_state([m.t_s for m in ms], [m.z_m for m in ms], self.params, self.table, opts)
        self._x = est.state.copy()
        self._P = 0.5 * (est.covariance + est.covariance.T) + np.eye(9) * 1e-12
        self._t = est.t_s
        self._buffer = []

    def _propagate_with_jacobian(self, t_to: float) -> tuple[np.ndarray, np.ndarray]:
        """State at t_to and d state(t_to) / d state(t) (9, 9), batched forward differences."""
        batch = np.repeat(self._x[None], 10, axis=0)
        batch[1:] += np.diag(_FD_STEP)
        out, _ = simulate(batch, [t_to], self.params, self.table, t0_s=self._t, dt_s=self.options.dt_s)
        end = out[:, 0]
        return end[0], ((end[1:] - end[0]) / _FD_STEP[:, None]).T

    def _process_noise(self, dt: float) -> np.ndarray:
        """Discrete white-noise acceleration per axis on (p, v), random-walk spin."""
        qa, qw = self.options.accel_noise_mps2**2, self.options.spin_noise_rad_s2**2
        Q = np.zeros((9, 9))
        i3 = np.eye(3)
        Q[0:3, 0:3] = dt**3 / 3 * qa * i3
        Q[0:3, 3:6] = Q[3:6, 0:3] = dt**2 / 2 * qa * i3
        Q[3:6, 3:6] = dt * qa * i3
        Q[6:9, 6:9] = dt * qw * i3
        return Q
