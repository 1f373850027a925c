"""Building blocks of the ``ransac_kalman`` filter: the Kalman transition kernel (numba vs numpy),
its bounce, RANSAC of a quadratic track, and the measurement-noise floor (docs/filters.md, sec. 3)."""

from __future__ import annotations

import numpy as np
import pytest

from policies.ball_model import BallParams, TableGeometry, simulate
from policies.filters import _ballistic
from policies.filters._base import measurement_noise
from policies.filters._ransac import ransac_quadratic
from policies.filters import RansacInfo

PARAMS = BallParams.load()
TABLE = TableGeometry()


def coeffs(k_drag=PARAMS.k_drag, q_acc=1.0, q_jerk=1.0, max_step=0.005, frac=0.1, floor=0.05, a_var=1.0,
           spin=(0.0, 0.0, 0.0)):
    c = _ballistic.coefficients(PARAMS, TABLE, q_acc=q_acc, q_jerk=q_jerk, bounce_frac=frac, bounce_floor_mps=floor,
                                accel_prior_var=a_var, max_step_s=max_step, spin_rad_s=spin)
    c[1] = k_drag
    return c


def random_states(rng, n):
    """Balls flying from the opponent's side towards the robot's half (lab frame), some bouncing."""
    p = np.stack([rng.uniform(0.5, 1.5, n), rng.uniform(-0.4, 0.4, n), rng.uniform(0.85, 1.2, n)], axis=1)
    v = np.stack([rng.uniform(-7, -3, n), rng.uniform(-0.5, 0.5, n), rng.uniform(-2, 1, n)], axis=1)
    a = rng.normal(0, 1.0, (n, 3))
    x = np.concatenate([p, v, a], axis=1)
    L = rng.normal(0, 0.05, (n, 9, 9))
    P = L @ np.transpose(L, (0, 2, 1)) + np.eye(9) * 1e-4
    return x, P


# --------------------------------------------------------------------------- transition kernel


@pytest.mark.parametrize("spin", [(0.0, 0.0, 0.0), (8.0, -55.0, 5.0)])
def test_numba_kernel_matches_numpy_reference(spin):
    rng = np.random.default_rng(0)
    x, P = random_states(rng, 12)
    c = coeffs(spin=spin)
    t_query = np.array([0.0, 0.0031, 0.05, 0.05, 0.2, 0.45, 0.7])
    n_bounced = 0
    for i in range(len(x)):
        X_nb, P_nb, b_nb = _ballistic.propagate_nb(x[i], P[i], 0.0, t_query, c)
        X_np, P_np, b_np = _ballistic.propagate_np(x[i], P[i], 0.0, t_query, c)
        assert b_nb == b_np
        n_bounced += b_nb > 0
        np.testing.assert_allclose(X_nb, X_np, rtol=0, atol=1e-10)
        np.testing.assert_allclose(P_nb, P_np, rtol=1e-9, atol=1e-12)
    assert n_bounced >= 3  # the comparison covered the bounce branch


def test_kernel_is_exact_for_drag_free_ballistics():
    x0 = np.array([1.0, 0.2, 3.0, -4.0, 0.3, 1.0, 0.0, 0.0, 0.0])
    t = np.array([0.1, 0.25, 0.4])
    X, _, nb = _ballistic.propagate_nb(x0, np.eye(9), 0.0, t, coeffs(k_drag=0.0))
    assert nb == 0  # stays above the table plane (z0 = 3 m)
    expect = x0[0:3] + np.outer(t, x0[3:6]) - 0.5 * PARAMS.gravity_mps2 * np.outer(t**2, [0, 0, 1])
    np.testing.assert_allclose(X[:, 0:3], expect, atol=1e-12)


def test_kernel_follows_the_spin_free_ball_model_through_the_bounce():
    """With a = 0 and no noise, the mean (eqs. F1, F3) stays within 1.5 cm of eqs. 1-6 over 0.6 s."""
    state = np.array([1.8, 0.1, 1.05, -5.5, -0.1, 0.3, 0.0, 0.0, 0.0])
    t = np.linspace(0.0, 0.6, 61)
    truth, bounce = simulate(state, t, PARAMS, TABLE)
    x0 = np.concatenate([state[0:6], np.zeros(3)])
    X, _, nb = _ballistic.propagate_nb(x0, np.eye(9) * 1e-6, 0.0, t, coeffs(q_acc=0.0, q_jerk=0.0))
    assert nb == 1 and np.isfinite(bounce[0]) and bounce[0] < 0.6
    assert np.max(np.linalg.norm(X[:, 0:3] - truth[:, 0:3], axis=1)) < 0.015
    assert np.max(np.abs(X[-1, 3:6] - truth[-1, 3:6])) < 0.1


def test_bounce_map_flips_vz_and_inflates_the_covariance():
    c = coeffs()
    x = np.array([0.0, 0.0, 0.781, -5.0, 0.5, -3.0, 0.5, -0.4, 0.2])
    P = np.eye(9) * 1e-4
    xb, Pb = _ballistic.bounce_np(x, P.copy(), c)
    e, mu = PARAMS.table_restitution, PARAMS.table_friction
    assert xb[5] == pytest.approx(-e * x[5])
    slip = np.hypot(x[3], x[4])
    jt = min(mu * (1 + e) * 3.0, PARAMS.inertia_factor / (1 + PARAMS.inertia_factor) * slip)
    np.testing.assert_allclose(xb[3:5], x[3:5] * (1 - jt / slip))
    assert xb[6] == xb[7] == 0.0 and xb[8] == x[8]  # horizontal unexplained acceleration reset
    assert (np.diag(Pb)[3:8] > np.diag(P)[3:8]).all() and (np.linalg.eigvalsh(Pb) > 0).all()
    xn, Pn = x.copy(), P.copy()
    _ballistic._bounce_nb(xn, Pn, c)
    np.testing.assert_allclose(xn, xb, atol=1e-14)
    np.testing.assert_allclose(Pn, Pb, atol=1e-14)


def test_bounce_with_a_spin_prior_is_the_ball_models_bounce():
    """With the spin prior's mean, the mean velocity after the bounce is that of the ball model's
    eqs. (4)-(6) (policies.ball_model.surface_contact) for a ball with that spin; the unexplained
    acceleration's horizontal part becomes the spin's acceleration at the new velocity."""
    from policies.ball_model import surface_contact

    for spin in ((0.0, -60.0, 0.0), (0.0, 45.0, 3.0), (10.0, 5.0, -4.0)):
        c = coeffs(spin=spin)
        x = np.array([0.0, 0.0, 0.781, 5.0, 0.3, -3.0, 0.1, 0.2, -1.0])
        xb, _ = _ballistic.bounce_np(x, np.eye(9) * 1e-4, c)
        v_model, _ = surface_contact(x[3:6], np.array(spin), np.array([0.0, 0.0, 1.0]), PARAMS,
                                     restitution=PARAMS.table_restitution, friction=PARAMS.table_friction)
        np.testing.assert_allclose(xb[3:6], v_model, atol=1e-12)
        a_new = _ballistic.spin_acceleration_np(xb[3:6], c)
        np.testing.assert_allclose(xb[6:8], a_new[0:2], atol=1e-14)
        assert xb[8] == pytest.approx(x[8] - _ballistic.spin_acceleration_np(x[3:6], c)[2] + a_new[2])
        xn, Pn = x.copy(), np.eye(9) * 1e-4
        _ballistic._bounce_nb(xn, Pn, c)
        np.testing.assert_allclose(xn, xb, atol=1e-14)
    # the spin's acceleration is eq. (1)'s spin terms: the model's acceleration with minus without the spin
    from policies.ball_model import acceleration

    v, w = np.array([5.0, 0.3, -3.0]), np.array([0.0, -60.0, 0.0])
    np.testing.assert_allclose(_ballistic.spin_acceleration_np(v, coeffs(spin=tuple(w))),
                               acceleration(np.r_[0, 0, 0, v, w], PARAMS) - acceleration(np.r_[0, 0, 0, v, 0, 0, 0], PARAMS),
                               atol=1e-12)


def test_no_bounce_outside_the_table():
    x0 = np.array([0.0, 1.2, 1.0, -3.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # |y| > 0.7625: falls past the side
    X, _, nb = _ballistic.propagate_nb(x0, np.eye(9) * 1e-6, 0.0, np.array([0.6]), coeffs())
    assert nb == 0 and X[0, 5] < 0.0 and X[0, 2] < TABLE.surface_z_m


def test_covariance_grows_with_the_process_noise():
    x0 = np.array([1.0, 0.0, 1.5, -5.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    t = np.array([0.2])
    _, P0, _ = _ballistic.propagate_nb(x0, np.eye(9) * 1e-6, 0.0, t, coeffs(k_drag=0.0, q_acc=0.0, q_jerk=0.0))
    _, P1, _ = _ballistic.propagate_nb(x0, np.eye(9) * 1e-6, 0.0, t, coeffs(k_drag=0.0, q_acc=1.0, q_jerk=0.0))
    # white acceleration of PSD q on v, no drag: position variance grows by q t^3 / 3 (Bar-Shalom 6.2)
    assert P1[0, 0, 0] - P0[0, 0, 0] == pytest.approx(0.2**3 / 3, rel=1e-9)


# --------------------------------------------------------------------------- RANSAC of a quadratic track


def quadratic_track(rng, n=14, noise=0.002):
    t = np.sort(rng.uniform(0.0, 0.08, n)) + 10.0
    coef = np.array([[1.8, 0.1, 1.0], [-5.0, 0.2, 1.5], [0.3, -0.05, -4.9]])
    tau = t - t[0]
    X = coef[0] + tau[:, None] * coef[1] + tau[:, None] ** 2 * coef[2]
    return t, X + rng.normal(0, noise, X.shape), coef


def test_ransac_finds_the_inliers_and_the_track():
    rng = np.random.default_rng(1)
    t, X, coef = quadratic_track(rng)
    bad = np.array([1, 5, 6, 11])
    X[bad] += rng.normal(0, 1.0, (4, 3))
    track, info = ransac_quadratic(t, X, inlier_threshold_m=0.02, min_inliers=8, iterations=100, rng=rng)
    expected = np.ones(len(t), bool)
    expected[bad] = False
    np.testing.assert_array_equal(info.inliers, expected)
    assert info.rms_m < 0.004
    assert isinstance(info, RansacInfo) and info.n_inliers == expected.sum() and info.iterations == 100
    np.testing.assert_allclose(track.position(t[[0]])[0], coef[0], atol=0.005)
    np.testing.assert_allclose(track.velocity(t[[0]])[0], coef[1], atol=0.3)


def test_ransac_without_consensus_returns_none():
    rng = np.random.default_rng(2)
    t = np.sort(rng.uniform(0, 0.08, 12))
    X = rng.uniform(-1, 1, (12, 3))
    track, info = ransac_quadratic(t, X, inlier_threshold_m=0.02, min_inliers=8, iterations=100, rng=rng)
    assert track is None and info.n_inliers < 8


def test_ransac_is_deterministic_given_the_generator():
    t, X, _ = quadratic_track(np.random.default_rng(3))
    X[[2, 3]] += 0.5
    a = ransac_quadratic(t, X, inlier_threshold_m=0.02, min_inliers=8, iterations=30, rng=np.random.default_rng(9))
    b = ransac_quadratic(t, X, inlier_threshold_m=0.02, min_inliers=8, iterations=30, rng=np.random.default_rng(9))
    np.testing.assert_array_equal(a[0].coef, b[0].coef)
    np.testing.assert_array_equal(a[1].inliers, b[1].inliers)


# --------------------------------------------------------------------------- measurement noise


def test_measurement_noise_floor_default_and_malformed():
    C = np.diag([1e-8, 4e-6, 9e-6])
    R, note = measurement_noise(C, 0.002, 0.003)
    np.testing.assert_allclose(np.linalg.eigvalsh(R), [4e-6, 4e-6, 9e-6])
    assert note == ""
    R, note = measurement_noise(None, 0.002, 0.003)
    np.testing.assert_allclose(R, np.eye(3) * 9e-6)
    for bad in (np.eye(2), np.full((3, 3), np.nan), np.array([[1, 2, 0], [0, 1, 0], [0, 0, 1.0]]), "x"):
        R, note = measurement_noise(bad, 0.002, 0.003)
        assert "malformed covariance" in note and np.allclose(R, np.eye(3) * 9e-6)
