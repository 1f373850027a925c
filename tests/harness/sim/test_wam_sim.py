"""The simulated WAM behind the WAM interface: tracking, limits, encoders, bias, determinism, contract."""

from __future__ import annotations

import numpy as np
import pytest

from harness.sim.robot import SimulatedWam, SimWamOptions
from harness.sim.robot._tracking import track_numba, track_numpy
from robot_models import WamKinematics, load_robot_config
from robot_models.robot_interface import JointState, WamInterface

EXACT = dict(zero_offset_std_deg=0.0, encoder_noise_std_rad=0.0, encoder_counts_per_rev=10**9)


@pytest.fixture(scope="module")
def kin():
    return WamKinematics.default()


def _smooth(kin, t0=0.1, duration=2.0, amp=0.3, n=41):
    """A smooth rest-to-rest move (t_s (n,), q (n, 7), qdot (n, 7)) from q_home by +-amp."""
    t = np.linspace(t0, t0 + duration, n)
    u = (t - t0) / duration
    s = u**3 * (10 - 15 * u + 6 * u**2)
    ds = 30 * u**2 * (1 - u) ** 2 / duration
    dq = amp * np.array([1, -1, 1, -1, 1, -1, 1.0])
    dq = np.where(kin.q_home + dq > kin.q_max, -dq, dq)
    return t, kin.q_home + s[:, None] * dq, ds[:, None] * dq


# -- smoke -------------------------------------------------------------------------------------------
def test_smoke_state_and_protocol(kin):
    sim = SimulatedWam(kin, seed=0)
    assert isinstance(sim, WamInterface)
    st = sim.read_state()
    assert isinstance(st, JointState) and st.t_s == 0.0 and st.q.shape == (7,) and st.qdot.shape == (7,)
    np.testing.assert_allclose(sim.true_state().q, kin.q_home)
    s = sim.advance_to(0.1)
    assert len(s) == 50 and s.q.shape == (50, 7) and s.q_true.shape == (50, 7)
    np.testing.assert_allclose(s.t_s, np.arange(1, 51) * 0.002)
    assert sim.read_state().t_s == pytest.approx(0.1)


def test_options_from_the_robot_file():
    opts = SimWamOptions.from_mapping(load_robot_config().simulator)
    assert opts == SimWamOptions()


# -- accuracy: tracking -------------------------------------------------------------------------------
def test_tracking_error_bounded_for_smooth_trajectory(kin):
    t, q, qd = _smooth(kin)
    sim = SimulatedWam(kin, SimWamOptions(**EXACT), seed=0)
    sim.command_trajectory(t, q, qd)
    s = sim.advance_to(3.0)
    err = np.abs(s.q_true - s.q_ref).max()
    assert 1e-5 < err < 3e-3  # finite bandwidth: a lag, but bounded (peak qddot ~ 0.17 rad/s^2 * 0.1 / omega^2)
    np.testing.assert_allclose(s.q_true[-1], q[-1], atol=1e-5)  # settles on the final point
    np.testing.assert_allclose(s.q, s.q_true, atol=1e-8)  # exact encoders report the truth
    assert (sim.saturated_ticks == 0).all()


def test_perfect_feedforward_tracks_closely(kin):
    t, q, qd = _smooth(kin)
    sim = SimulatedWam(kin, SimWamOptions(feedforward_gain=1.0, **EXACT), seed=0)
    sim.command_trajectory(t, q, qd)
    s = sim.advance_to(3.0)
    assert np.abs(s.q_true - s.q_ref).max() < 1e-5


# -- limits ------------------------------------------------------------------------------------------------
def test_velocity_and_acceleration_limits_respected(kin):
    # a 1 rad step in the reference on every joint: the controller saturates
    t = np.array([0.01, 0.012, 3.0])
    target = np.clip(kin.q_home + 1.0, kin.q_min + 0.3, kin.q_max - 0.3)  # room for the saturated overshoot
    q = np.stack([kin.q_home, target, target])
    sim = SimulatedWam(kin, SimWamOptions(**EXACT), seed=0)
    sim.command_trajectory(t, q, np.zeros_like(q))
    s = sim.advance_to(3.5)
    assert (np.abs(s.qdot_true) <= kin.qdot_max + 1e-12).all()
    acc = np.diff(np.vstack([np.zeros(7), s.qdot_true]), axis=0) / sim.dt_s
    assert (np.abs(acc) <= kin.qddot_max * (1 + 1e-9)).all()
    assert (sim.saturated_ticks > 0).all() and (sim.limit_ticks == 0).all()
    np.testing.assert_allclose(s.q_true[-1], target, atol=1e-3)


def test_joints_stay_within_limits(kin):
    # the reference spline swings past joint_4's upper limit between knots, and arrives there fast
    t = np.array([0.0, 0.3, 0.6])
    q = np.stack([kin.q_home, kin.q_home, kin.q_home])
    q[1, 3] = kin.q_max[3] - 0.01
    qd = np.zeros_like(q)
    qd[1, 3] = kin.qdot_max[3]
    sim = SimulatedWam(kin, SimWamOptions(feedforward_gain=1.0, **EXACT), seed=0)
    sim.command_trajectory(t, q, qd)
    s = sim.advance_to(1.0)
    assert (s.q_ref <= kin.q_max).all()
    assert s.q_true[:, 3].max() == pytest.approx(kin.q_max[3], abs=0.02)  # it did get there
    assert (s.q_true >= kin.q_min).all() and (s.q_true <= kin.q_max).all()
    assert sim.limit_ticks[3] > 0 and sim.limit_ticks.sum() == sim.limit_ticks[3]  # counted, on joint_4 only


# -- contract --------------------------------------------------------------------------------------------
def test_new_trajectory_replaces_old_from_its_start(kin):
    sim = SimulatedWam(kin, SimWamOptions(**EXACT), seed=0)
    t, q, qd = _smooth(kin, t0=0.0, duration=2.0)
    sim.command_trajectory(t, q, qd)
    sim.advance_to(0.5)
    q_new = np.stack([kin.q_home, kin.q_home])
    sim.command_trajectory([1.0, 1.5], q_new)  # starts in the future: the old one runs until 1.0 s
    s = sim.advance_to(2.0)
    from scipy.interpolate import CubicHermiteSpline

    old = CubicHermiteSpline(t, q, qd, axis=0)
    before = s.t_s < 1.0 - 1e-9
    np.testing.assert_allclose(s.q_ref[before], old(s.t_s[before]), atol=1e-12)
    np.testing.assert_allclose(s.q_ref[~before], kin.q_home[None].repeat((~before).sum(), 0), atol=1e-12)
    # a trajectory that started in the past replaces the reference from now on
    sim.command_trajectory([1.0, 2.5], np.stack([kin.q_home, q[-1]]))
    s = sim.advance_to(2.2)
    frac = (s.t_s - 1.0) / 1.5
    np.testing.assert_allclose(s.q_ref, kin.q_home + frac[:, None] * (q[-1] - kin.q_home), atol=1e-12)
    s = sim.advance_to(3.0)  # after its end the robot holds the last point
    np.testing.assert_allclose(s.q_ref[s.t_s > 2.5], q[-1][None].repeat((s.t_s > 2.5).sum(), 0))


# -- determinism ---------------------------------------------------------------------------------------
def _session(kin, seed, chunks):
    sim = SimulatedWam(kin, seed=seed)
    t, q, qd = _smooth(kin)
    sim.command_trajectory(t, q, qd)
    parts = [sim.advance_to(c) for c in chunks]
    return np.concatenate([p.q for p in parts]), np.concatenate([p.qdot for p in parts]), sim.bias_rad


def test_same_seed_same_session_however_chunked(kin):
    a = _session(kin, 3, [2.5])
    b = _session(kin, 3, [0.3, 0.301, 1.7, 2.5])
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    c = _session(kin, 4, [2.5])
    assert not np.array_equal(a[2], c[2]) and not np.array_equal(a[0], c[0])


def test_numba_kernel_matches_numpy_reference(kin):
    rng = np.random.default_rng(0)
    n = 400
    q_ref = kin.q_home + np.cumsum(rng.normal(0, 0.02, (n, 7)), axis=0)
    qd_ref = rng.normal(0, 2, (n, 7))
    qdd_ref = rng.normal(0, 30, (n, 7))
    args = (kin.q_home.copy(), np.zeros(7), q_ref, qd_ref, qdd_ref, 2 * np.pi * np.array([6, 6, 8, 8, 12, 12, 12.0]),
            1.0, 0.9, np.asarray(kin.qdot_max), np.asarray(kin.qddot_max), np.asarray(kin.q_min),
            np.asarray(kin.q_max), 0.002)
    a, b = track_numpy(*args), track_numba(*args)
    assert a[2].sum() > 0  # the random reference does saturate
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-12)
    t, q, qd = _smooth(kin)
    runs = []
    for backend in ("numpy", "numba"):
        sim = SimulatedWam(kin, SimWamOptions(backend=backend), seed=1)
        sim.command_trajectory(t, q, qd)
        runs.append(sim.advance_to(2.5))
    np.testing.assert_allclose(runs[0].q, runs[1].q, atol=1e-12)


# -- statistics ---------------------------------------------------------------------------------------
def test_zero_offset_bias_statistics(kin):
    std_deg = np.array([1.0, 0.5, 0.3, 0.3, 0.2, 0.2, 0.2])
    opts = SimWamOptions(zero_offset_std_deg=std_deg, encoder_noise_std_rad=0.0)
    bias = np.stack([SimulatedWam(kin, opts, seed=s).bias_rad for s in range(400)])
    z = bias / np.deg2rad(std_deg)
    # 400 draws: the std of a unit normal is within ~4 sigma of 1 (sigma ~ 1/sqrt(800)), the mean within 4/sqrt(400)
    assert np.all(np.abs(z.std(0) - 1) < 0.15)
    assert np.all(np.abs(z.mean(0)) < 0.2)
    # and the bias stays fixed through the session: reported - true is constant but for quantisation
    sim = SimulatedWam(kin, opts, seed=5)
    t, q, qd = _smooth(kin)
    sim.command_trajectory(t, q, qd)
    s = sim.advance_to(2.5)
    res = opts.resolution_rad
    assert np.all(np.abs(s.q - s.q_true - sim.bias_rad) <= res / 2 + 1e-15)


def test_quantisation_and_noise_statistics(kin):
    t, q, qd = _smooth(kin, amp=0.5)
    for noise in (0.0, 2e-4):
        opts = SimWamOptions(zero_offset_std_deg=0.0, encoder_noise_std_rad=noise, encoder_counts_per_rev=64)
        sim = SimulatedWam(kin, opts, seed=2)
        sim.command_trajectory(t, q, qd)
        s = sim.advance_to(2.2)
        err = s.q - s.q_true
        moving = np.abs(s.qdot_true).max(1) > 0.05  # uniform quantisation error needs the joints to move
        res = opts.resolution_rad
        if noise == 0.0:
            assert np.all(np.abs(err) <= res / 2 + 1e-15)
        expected = np.sqrt(res**2 / 12 + noise**2)
        np.testing.assert_allclose(err[moving].std(0), expected, rtol=0.15)
        np.testing.assert_allclose(err[moving].mean(0), 0, atol=0.2 * expected.max())


# -- bad input -----------------------------------------------------------------------------------------
def test_bad_trajectories_rejected_and_current_kept(kin):
    sim = SimulatedWam(kin, SimWamOptions(**EXACT), seed=0)
    t, q, qd = _smooth(kin)
    sim.command_trajectory(t, q, qd)
    q2 = q.copy()
    q2[5, 3] = 3.3
    bad_qd = qd.copy()
    bad_qd[3, 1] = 50.0
    cases = [
        ((np.array([0.1, 0.3, 0.2]), q[:3], None), r"t_s must be strictly increasing; t_s\[2\] = 0.2 <= t_s\[1\] = 0.3"),
        ((t, q[:, :6], None), r"q must have shape \(41, 7\) to match t_s, got shape \(41, 6\)"),
        ((t, q, qd[:-1]), r"qdot must have shape \(41, 7\) like q"),
        ((t[:1], q[:1], None), r"t_s must have shape \(N,\) with N >= 2"),
        ((t, q2, None), r"q \(row 5\): joint_4 = 3.3 rad is outside its limits"),
        ((t, q, bad_qd), r"qdot\[3\]: joint_2 = 50 rad/s exceeds its velocity limit 6.3"),
        ((t * np.nan, q, None), r"t_s must be finite"),
    ]
    for (tt, qq, qqd), match in cases:
        with pytest.raises(ValueError, match=match):
            sim.command_trajectory(tt, qq, qqd)
    s = sim.advance_to(3.0)
    np.testing.assert_allclose(s.q_true[-1], q[-1], atol=1e-5)  # the valid trajectory still ran
    with pytest.raises(ValueError, match=r"trajectory ends at t_s = 2.1 s, not after the robot clock 3 s"):
        sim.command_trajectory(t, q, qd)
    with pytest.raises(ValueError, match="not before the robot clock"):
        sim.advance_to(1.0)
    with pytest.raises(ValueError, match="n_ticks must be a non-negative integer"):
        sim.step(-1)


def test_bad_options(kin):
    with pytest.raises(ValueError, match=r"unknown SimWamOptions.backend 'cuda'; valid: \['numba', 'numpy'\]"):
        SimWamOptions(backend="cuda")
    with pytest.raises(ValueError, match=r"bandwidth_hz must be one number or 7"):
        SimWamOptions(bandwidth_hz=(1, 2))
    with pytest.raises(ValueError, match="too high"):
        SimWamOptions(bandwidth_hz=100.0)
    with pytest.raises(ValueError, match=r"wam.yaml: unknown field\(s\) \['bandwith_hz'\]"):
        SimWamOptions.from_mapping({"bandwith_hz": 5}, where="wam.yaml")
    with pytest.raises(ValueError, match="q0: joint_1"):
        SimulatedWam(kin, q0=np.full(7, 2.7))
