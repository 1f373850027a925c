"""Ball flight, bounce, prediction and state estimation (policies.ball_model, policies.ball_estimation)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from policies import (
    BallEKF,
    BallParams,
    EstimatorOptions,
    FitInfo,
    TableGeometry,
    acceleration,
    fit_initial_state,
    make_state,
    predict,
    predict_batch,
    simulate,
    surface_contact,
)

NO_AIR = BallParams(air_density_kg_m3=0.0)
HIGH_TABLE = TableGeometry(surface_z_m=-100.0)  # never reached


def _state(p=(0.0, 0.0, 1.0), v=(4.0, 0.3, 1.5), w=(0.0, 0.0, 0.0)):
    return make_state(p, v, w)


# --------------------------------------------------------------------------- smoke
def test_smoke_predict():
    pos, vel = predict(_state(), [0.0, 0.1, 0.2])
    assert pos.shape == (3, 3) and vel.shape == (3, 3)
    np.testing.assert_allclose(pos[0], [0.0, 0.0, 1.0])


def test_params_load_default_file_and_roundtrip(tmp_path):
    fitted = BallParams.load()  # data/ball_params.yaml, written by `rt2 sim fit-flight --save-params`
    assert fitted.mass_kg == pytest.approx(0.0027)
    path = tmp_path / "p.yaml"
    fitted.save(path, header="test")
    assert BallParams.load(path) == fitted


# --------------------------------------------------------------------------- shapes / batching
def test_batch_matches_single_and_numpy_twin():
    rng = np.random.default_rng(0)
    states = np.column_stack([rng.uniform(-1, 1, (5, 2)), rng.uniform(0.9, 1.2, 5), rng.uniform(-6, 6, (5, 3)),
                              rng.uniform(-80, 80, (5, 3))])
    t = np.linspace(0, 0.8, 41)
    params = BallParams(drag_spin_coefficient=0.6, spin_saturation=1.0, spin_decay_per_s=0.3)
    out_nb, b_nb = simulate(states, t, params)
    out_np, b_np = simulate(states, t, params, method="numpy")
    assert out_nb.shape == (5, 41, 9) and b_nb.shape == (5, 5)
    np.testing.assert_allclose(out_nb, out_np, atol=1e-9)
    np.testing.assert_allclose(b_nb, b_np, atol=1e-9)
    pos, _ = predict_batch(states, t, params)
    single, _ = predict(states[2], t, params)
    np.testing.assert_allclose(pos[2], single, atol=1e-12)


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("state, match", [
    (np.full(9, np.nan), "finite"),
    (np.zeros(8), r"shape \(9,\)"),
    (np.zeros((2, 3)), r"shape \(9,\)"),
])
def test_bad_state(state, match):
    with pytest.raises(ValueError, match=match):
        predict(state, [0.1])


def test_bad_times_and_options():
    with pytest.raises(ValueError, match="non-decreasing"):
        predict(_state(), [0.2, 0.1])
    with pytest.raises(ValueError, match="t0_s"):
        predict(_state(), [0.1], t0_s=0.5)
    with pytest.raises(ValueError, match="unknown integrator"):
        simulate(_state(), [0.1], method="euler")
    with pytest.raises(ValueError, match="table_restitution"):
        BallParams(table_restitution=1.5)
    with pytest.raises(ValueError, match="unknown BallParams"):
        BallParams().replace(drag=0.3)


def test_bad_params_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("ball_params:\n  drag_coeficient: 0.4\n")
    with pytest.raises(ValueError, match="drag_coeficient"):
        BallParams.load(bad)


def test_estimator_bad_observations():
    t = np.linspace(0, 0.1, 10)
    X = np.zeros((10, 3))
    with pytest.raises(ValueError, match="strictly increasing"):
        fit_initial_state(np.r_[t[:5], t[4], t[6:]], X)
    with pytest.raises(ValueError, match="finite"):
        fit_initial_state(t, np.where(np.arange(30).reshape(10, 3) == 4, np.nan, X))
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        fit_initial_state(t, X[:, :2])


# --------------------------------------------------------------------------- accuracy: physics
def test_ballistic_closed_form_without_air():
    s = _state()
    t = np.linspace(0, 0.5, 11)
    pos, vel = predict(s, t, NO_AIR, HIGH_TABLE, dt_s=5e-3)
    g = NO_AIR.gravity_mps2
    expected = s[:3] + np.outer(t, s[3:6]) - 0.5 * g * np.outer(t**2, [0, 0, 1])
    np.testing.assert_allclose(pos, expected, atol=1e-12)
    energy = 0.5 * np.sum(vel**2, axis=1) + g * pos[:, 2]
    np.testing.assert_allclose(energy, energy[0], rtol=1e-12)


def test_drag_slows_and_magnus_topspin_dips():
    s = _state(v=(5.0, 0.0, 1.0))
    t = [0.4]
    _, v_air = predict(s, t, BallParams(lift_coefficient=0.0), HIGH_TABLE)
    _, v_vac = predict(s, t, NO_AIR, HIGH_TABLE)
    assert np.linalg.norm(v_air) < np.linalg.norm(v_vac)
    top = _state(v=(5.0, 0.0, 1.0), w=(0.0, 60.0, 0.0))  # +y spin on a +x ball: topspin
    back = _state(v=(5.0, 0.0, 1.0), w=(0.0, -60.0, 0.0))
    p_top, _ = predict(top, t, BallParams(), HIGH_TABLE)
    p_none, _ = predict(s, t, BallParams(), HIGH_TABLE)
    p_back, _ = predict(back, t, BallParams(), HIGH_TABLE)
    assert p_top[0, 2] < p_none[0, 2] - 0.02 < p_back[0, 2] - 0.04
    a = acceleration(top)
    assert a[2] < -BallParams().gravity_mps2  # Magnus pushes down on topspin


def test_bounce_restitution_and_event_time():
    params = BallParams(table_friction=0.0)
    table = TableGeometry()
    z0 = table.surface_z_m + params.radius_m + 0.3
    s = _state(p=(0.0, 0.0, z0), v=(0.0, 0.0, 0.0))
    out, bounce = simulate(s, [0.3], params.replace(air_density_kg_m3=0.0), table)
    t_hit = np.sqrt(2 * 0.3 / params.gravity_mps2)
    assert bounce[0] == pytest.approx(t_hit, abs=1e-9)
    assert bounce[3] == pytest.approx(table.surface_z_m + params.radius_m, abs=1e-9)
    v_after = params.gravity_mps2 * t_hit * params.table_restitution
    assert out[0, 5] == pytest.approx(v_after - params.gravity_mps2 * (0.3 - t_hit), abs=1e-9)


def test_bounce_spin_velocity_coupling():
    params = BallParams()
    n = np.array([0.0, 0.0, 1.0])
    v = np.array([4.0, 0.0, -3.0])
    # mu = 0.6: every case ends rolling (impulse alpha/(1+alpha) |slip| < mu (1+e) |v_n|)
    v_none, _ = surface_contact(v, np.zeros(3), n, params, restitution=0.9, friction=0.6)
    v_top, w_top = surface_contact(v, [0, 80.0, 0], n, params, restitution=0.9, friction=0.6)
    v_back, w_back = surface_contact(v, [0, -80.0, 0], n, params, restitution=0.9, friction=0.6)
    assert v_none[2] == pytest.approx(2.7)
    assert v_none[0] == pytest.approx(4.0 * (1 - 0.4))  # rolling, thin shell: loses 2/5 of the slip
    assert v_back[0] < v_none[0] < v_top[0]  # backspin brakes, topspin keeps speed
    assert w_back[1] > -80.0  # friction on the slip reduces backspin
    # rolling limit: a large friction ends with zero slip at the contact point
    v_r, w_r = surface_contact(v, np.zeros(3), n, params, restitution=0.9, friction=5.0)
    assert v_r[0] - params.radius_m * w_r[1] == pytest.approx(0.0, abs=1e-12)


def test_ball_off_table_falls_through():
    table = TableGeometry()
    s = _state(p=(2.0, 0.0, 1.0), v=(1.0, 0.0, 0.0))  # beyond the +x edge
    out, bounce = simulate(s, [0.6], BallParams(), table)
    assert bounce[4] == 0 and out[0, 2] < table.surface_z_m


# --------------------------------------------------------------------------- statistics: estimation
@pytest.fixture(scope="module")
def noisy_flight():
    rng = np.random.default_rng(7)
    params = BallParams(drag_spin_coefficient=0.5)
    truth = _state(p=(1.7, 0.1, 1.0), v=(-5.5, 0.2, 0.8), w=(0.0, -60.0, 10.0))
    t = np.arange(40) / 180.0
    out, _ = simulate(truth, t, params)
    X = out[:, :3] + rng.normal(0, 0.001, (40, 3))
    return params, truth, t, X, out


def test_fitter_recovers_state_and_spin(noisy_flight):
    params, truth, t, X, out = noisy_flight
    est, info = fit_initial_state(t, X, params, options=EstimatorOptions(spin_prior_std_rad_s=200.0))
    assert info.success and info.rms_m < 0.0015
    assert isinstance(info, FitInfo) and info.residuals_m.shape == (len(t), 3) and info.component is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        info.rms_m = 0.0
    assert est.t_s == pytest.approx(t[-1])
    np.testing.assert_allclose(est.position, out[-1, :3], atol=0.002)
    np.testing.assert_allclose(est.velocity, out[-1, 3:6], atol=0.05)
    sd = np.sqrt(np.diag(est.covariance))
    # spin perpendicular to the velocity is observed through the Magnus curvature
    assert abs(est.spin[1] - out[-1, 7]) < 4 * sd[7] and sd[7] < 25.0
    pos, _ = est.predict([t[-1] + 0.3])
    truth_pos, _ = predict(truth, [t[-1] + 0.3], params)
    assert np.linalg.norm(pos[0] - truth_pos[0]) < 0.03


def test_ekf_tracks_through_bounce(noisy_flight):
    params, truth, _, _, _ = noisy_flight
    rng = np.random.default_rng(3)
    t = np.arange(140) / 180.0  # through the bounce on the robot's half
    out, bounce = simulate(truth, t, params)
    assert bounce[4] >= 1 and bounce[0] < t[-1]
    X = out[:, :3] + rng.normal(0, 0.001, (140, 3))
    X[60] += 0.2  # one tracker outlier: gated
    ekf = BallEKF(params)
    for ti, xi in zip(t, X):
        est = ekf.update(ti, xi)
    assert ekf.n_rejected >= 1
    assert np.linalg.norm(est.position - out[-1, :3]) < 0.005
    assert np.linalg.norm(est.velocity - out[-1, 3:6]) < 0.15


# --------------------------------------------------------------------------- real data
def test_real_flight_is_fitted_to_millimetres(real_data):
    from harness.experiments.studies.fit_flight import load_flights

    f = [f for f in load_flights(real_data / "mpi_launcher_trajectories") if f.set_name == "mn5008_backspin"][0]
    pre = f.X[:, 2] > f.X[:, 2].min() + 0.01  # before the bounce
    n = int(np.argmin(pre)) if not pre.all() else len(pre)
    est, info = fit_initial_state(f.t_s[:n], f.X[:n], BallParams.load(),
                                  options=EstimatorOptions(spin_prior_std_rad_s=200.0))
    assert info.rms_m < 0.004
    assert info.state_t0[7] < -20.0  # backspin on a +x flight: w_y < 0


# -- the table and net: one definition ------------------------------------------------------------
def test_table_geometry_is_the_one_definition_of_table_and_net():
    from harness.sim import lab
    from harness.calib.check import TABLE_CORNERS_M
    from harness.logs.foxglove_scene import TABLE as LOGGED_TABLE
    from harness.sim.physics import WorldOptions

    t = TableGeometry()
    assert (t.surface_z_m, t.x_max_m, t.y_max_m) == (0.76, 1.37, 0.7625)
    assert (t.thickness_m, t.net_height_m, t.net_half_span_m) == (0.025, 0.1525, 0.915)
    assert (lab.TABLE_TOP_Z_M, lab.TABLE_HALF_LENGTH_M, lab.TABLE_HALF_WIDTH_M) == (t.surface_z_m, t.x_max_m, t.y_max_m)
    assert (lab.TABLE_THICKNESS_M, lab.NET_HEIGHT_M, lab.NET_HALF_SPAN_M) == (t.thickness_m, t.net_height_m, t.net_half_span_m)
    assert LOGGED_TABLE == t and WorldOptions().table == t
    assert np.array_equal(TABLE_CORNERS_M, t.corners_m())
    assert np.array_equal(t.corners_m()[:, :2], [[-1.37, -0.7625], [1.37, -0.7625], [1.37, 0.7625], [-1.37, 0.7625]])


@pytest.mark.parametrize("field", ["thickness_m", "net_height_m", "net_half_span_m"])
def test_table_geometry_rejects_a_non_positive_size(field):
    with pytest.raises(ValueError, match=f"TableGeometry.{field} must be > 0, got 0.0"):
        TableGeometry(**{field: 0.0})
