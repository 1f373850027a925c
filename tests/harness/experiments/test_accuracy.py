"""Unit tests of the accuracy experiment's parts (harness.experiments.accuracy): registration, statistics, config,
faults, the robot's timing model, the scene, the figure. The end-to-end runs are in test_accuracy_run.py."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from harness.experiments.accuracy import AccuracyConfig, FaultPlan, SceneOptions, SessionScene, error_stats, fit_rigid, register_rigid
from harness.experiments.accuracy.figure import plot_histogram
from harness.experiments.accuracy.motion import MotionOptions, simulate_motion, world_to_base
from harness.experiments.accuracy.registration import registration_std, transform_difference
from harness.experiments.accuracy.stats import JSON_KEYS, check_goals, format_table, mode_shares


def _rigid(seed):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = np.random.default_rng(seed).uniform(-2, 2, 3)
    return T


def _apply(T, X):
    return X @ T[:3, :3].T + T[:3, 3]


# -- smoke ------------------------------------------------------------------------------------------
def test_smoke_registration_and_stats():
    X = np.random.default_rng(0).normal(size=(20, 3))
    T, info = register_rigid(X, X + [1.0, 0, 0])
    assert np.allclose(T[:3, 3], [1, 0, 0]) and info.n_inliers == 20
    row = error_stats("rt2", np.array([0.01, 0.02, np.nan]))
    assert list(row) == list(JSON_KEYS)


# -- shapes and batching -----------------------------------------------------------------------------
def test_config_round_trips_through_json():
    c = AccuracyConfig(seed=5, n_frames=100, trackers=("rtblob", "rt2"), eps_px=3.0, inject_faults=True,
                       motion=MotionOptions(gt_sampling="hold"), scene=SceneOptions(shirt="orange"))
    back = AccuracyConfig.from_dict(json.loads(json.dumps(c.to_dict())))
    assert back == c
    assert back.segments()[0] == (0, 100) and c.registration_tracker == "rt2"
    assert AccuracyConfig(n_frames=600, segment_frames=250).segments() == [(0, 250), (250, 500), (500, 600)]


def test_registration_frames_interleave_with_the_scored_ones():
    c = AccuracyConfig(n_frames=4000)  # 200 Hz, blocks of 0.25 s = 50 frames, 30 % register
    m = c.register_mask
    assert m.shape == (4000,) and c.n_register == m.sum() == 1200
    blocks = m.reshape(80, 50)
    assert (blocks.all(axis=1) | ~blocks.any(axis=1)).all()  # whole blocks
    starts = np.flatnonzero(blocks[:, 0])
    assert not blocks[0, 0] and np.diff(starts).max() <= 4  # spread over the whole run, the first block scored
    first = c.with_(register_layout="first")
    assert first.register_mask[:1200].all() and not first.register_mask[1200:].any()
    half = AccuracyConfig(n_frames=48, rate_hz=50.0, register_fraction=0.5)  # short run: blocks of 48 // 10 frames
    assert half.register_mask.reshape(12, 4)[:, 0].tolist() == [False, True] * 6


def test_motion_is_sampled_at_the_camera_clock():
    from robot_models import WamKinematics

    kin = WamKinematics.default()
    m = simulate_motion(kin, 50, 200.0, seed=1)
    assert m.t_s.shape == (50,) and np.allclose(np.diff(m.t_s), 0.005)
    assert m.links_world_m.shape == (50, 9, 3) and m.q_reported.shape == (50, 7)
    assert np.allclose(m.links_world_m[:, 8], kin.positions(m.q_true, "flange", check_limits=False))
    # the true ball is FK of the true joints; ground truth is FK of the reported ones, mm away (bias)
    assert np.allclose(m.ball_true_world_m, kin.positions(m.q_true, check_limits=False))
    gap_mm = np.linalg.norm(m.gt_world_m - m.ball_true_world_m, axis=1) * 1e3
    assert 0.1 < np.median(gap_mm) < 30
    assert np.allclose(world_to_base(m.gt_world_m, m.T_base_to_world) + [-1.75, 0, 0.70], m.gt_world_m)
    held = simulate_motion(kin, 50, 200.0, seed=1, options=MotionOptions(gt_sampling="hold"))
    assert np.array_equal(held.q_true, m.q_true) and not np.array_equal(held.q_reported, m.q_reported)


def test_scene_has_arm_ball_person_and_distractors():
    scene_gen = SessionScene(np.full(8, 0.05), [-1.75, 0, 0.7], SceneOptions(distractors=("white_cup", "orange_box")), seed=2)
    links = np.linspace([-1.75, 0, 0.7], [-1.3, 0.1, 1.2], 9)
    s = scene_gen.scene_at(7, 0.5, links, [-1.28, 0.1, 1.24], [0.5, 0, 0])
    assert len(s.balls) == 1 and np.allclose(s.balls[0].position_m, [-1.28, 0.1, 1.24]) and s.frame_index == 7
    assert len(s.boxes) == 2 and len(s.capsules) >= 10 + 7  # pedestal, 8 links, stick + person
    # the person's build is the same every frame (torso after the 10 arm capsules and 2 legs); the hand moves
    s2 = scene_gen.scene_at(8, 1.5, links, [-1.28, 0.1, 1.24], [0.5, 0, 0])
    assert np.array_equal(s.capsules[12].p0_m, s2.capsules[12].p0_m) and s.capsules[12].radius_m == s2.capsules[12].radius_m
    assert not np.allclose(s.capsules[-1].p1_m, s2.capsules[-1].p1_m)
    assert not np.allclose(scene_gen.hand_target_m(0.5), scene_gen.hand_target_m(1.5))


# -- bad input ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, match", [
    ({"n_frames": 5}, "n_frames"),
    ({"trackers": ("rt2", "kalman")}, "trackers"),
    ({"trackers": ()}, "trackers"),
    ({"eps_px": -1.0}, "eps_px"),
    ({"register_fraction": 0.99}, "register_fraction"),
    ({"rtblob_setup": "magic"}, "rtblob_setup"),
    ({"rate_hz": 0.0}, "rate_hz"),
    ({"register_layout": "random"}, "register_layout"),
    ({"register_block_s": 0.0}, "register_block_s"),
])
def test_bad_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AccuracyConfig(**kwargs)


def test_bad_config_dict_names_the_field():
    d = AccuracyConfig().to_dict()
    with pytest.raises(ValueError, match=r"log.mcap: session metadata.*unknown field\(s\) \['sead'\]"):
        AccuracyConfig.from_dict({**d, "sead": 1}, where="log.mcap: session metadata")
    d["scene"]["distractors"] = ["ufo"]
    with pytest.raises(ValueError, match="unknown SceneOptions.distractors"):
        AccuracyConfig.from_dict(d)


def test_bad_registration_input():
    X = np.zeros((5, 3))
    with pytest.raises(ValueError, match="at least 10 point pairs"):
        register_rigid(X, X)
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        fit_rigid(np.zeros((4, 2)), np.zeros((4, 2)))
    line = np.outer(np.arange(12.0), [1, 0, 0])
    with pytest.raises(ValueError, match="collinear"):
        register_rigid(line, line)
    with pytest.raises(ValueError, match="finite"):
        register_rigid(np.full((12, 3), np.nan), np.zeros((12, 3)))


def test_bad_stats_and_faults_input():
    with pytest.raises(ValueError, match="non-empty 1-D"):
        error_stats("rt2", np.zeros((2, 2)))
    with pytest.raises(ValueError, match="distances >= 0"):
        error_stats("rt2", np.array([-1.0]))
    with pytest.raises(ValueError, match="2 cameras"):
        FaultPlan.default(100, 1)
    with pytest.raises(ValueError, match="gt_sampling"):
        MotionOptions(gt_sampling="nearest")
    with pytest.raises(ValueError, match="held_ball"):
        SceneOptions(held_ball="green")


# -- accuracy on a synthetic scene ----------------------------------------------------------------------
def test_registration_recovers_a_known_transform_despite_outliers():
    rng = np.random.default_rng(4)
    T_true = _rigid(4)
    X = rng.uniform([-0.3, -0.4, -0.2], [0.3, 0.4, 0.3], size=(300, 3))
    Y = _apply(T_true, X) + rng.normal(0, 0.002, X.shape)
    Y[:30] += rng.normal(0, 0.5, (30, 3))  # 10 % wrong tracker positions
    T, info = register_rigid(X, Y)
    rot_deg, trans_m = transform_difference(T, T_true)
    assert rot_deg < 0.05 and trans_m < 0.002
    assert not info.inliers[:30].any() and info.inliers[30:].mean() > 0.97
    assert 0.001 < info.rms_m < 0.004 and info.spread_m[1] > 0.1
    T_plain = fit_rigid(X, Y)  # without trimming the outliers pull the fit
    assert transform_difference(T_plain, T_true)[1] > 5 * trans_m


def test_error_stats_on_hand_made_errors():
    e = np.concatenate([np.full(90, 0.01), np.full(8, 0.30), [25.0, 0.02], [np.nan] * 10])
    r = error_stats("rtblob", e)
    assert r["frac_missing"] == pytest.approx(10 / 110)
    assert r["median_cm"] == pytest.approx(1.0) and r["max_cm"] == pytest.approx(2500.0)
    assert r["frac_over_10cm"] == pytest.approx(9 / 100)
    assert r["mean_cm"] == pytest.approx((90 * 1 + 8 * 30 + 2500 + 2) / 100)
    assert r["p99_cm"] == pytest.approx(np.percentile(e[np.isfinite(e)] * 100, 99), rel=1e-6)
    m = mode_shares(e)
    assert m["20_to_35cm"] == pytest.approx(0.08) and m["over_10m"] == pytest.approx(0.01)
    none = error_stats("rt2", np.full(4, np.nan))
    assert none["frac_missing"] == 1.0 and none["max_cm"] is None
    table = format_table([r, none])
    assert "rtblob" in table and "25-30 cm" in table


def test_goals_say_met_or_not():
    good = error_stats("rt2", np.full(100, 0.005))
    bad = error_stats("rt2", np.r_[np.full(98, 0.005), 0.2, 0.3])
    blob = error_stats("rtblob", np.r_[np.full(90, 0.01), np.full(10, 0.3)])
    assert [ok for _, ok, _ in check_goals([good, blob])] == [True, True, True]
    assert [ok for _, ok, _ in check_goals([bad, blob])] == [False, False, True]


def test_fault_plan_hits_the_evaluation_part():
    plan = FaultPlan.default(400, 4)
    assert plan.no_frame == (2, 180, 200) and plan.wrong_size == (1, 240, 244) and plan.non_monotonic_frame == 300
    images = [np.zeros((48, 64, 3), np.uint8) for _ in range(4)]
    t, out = plan.apply(185, 1.0, images, 0.005)
    assert out[2] is None and images[2] is not None and t == 1.0
    t, out = plan.apply(240, 1.0, images, 0.005)
    assert out[1].shape == (24, 32, 3)
    t, _ = plan.apply(300, 1.0, images, 0.005)
    assert t == pytest.approx(1.0 - 0.0075)
    assert plan.faults_at(185) == ("no_frame",) and plan.faults_at(10) == ()
    assert not FaultPlan.none().active


# -- statistical checks with a seeded RNG -----------------------------------------------------------------
def test_registration_residual_matches_the_noise():
    rng = np.random.default_rng(11)
    T_true = _rigid(11)
    X = rng.uniform(-0.5, 0.5, size=(2000, 3))
    sigma = 0.003
    _, info = register_rigid(X, _apply(T_true, X) + rng.normal(0, sigma, X.shape))
    # residual of a 6-parameter fit to 3-D Gaussian noise: RMS ~ sigma * sqrt(3 (1 - 2 / n))
    assert info.rms_m == pytest.approx(sigma * np.sqrt(3), rel=0.05)
    assert info.n_inliers > 0.995 * len(X)


def test_registration_std_matches_monte_carlo():
    """The first-order uncertainty of the fitted transform at far points, against 400 seeded re-fits of a
    nearly collinear point set (the hard case: the rotation about the line is barely fixed)."""
    rng = np.random.default_rng(5)
    X = rng.uniform([-0.3, -0.02, -0.01], [0.3, 0.02, 0.01], size=(60, 3))
    Q = rng.uniform(-0.5, 0.5, size=(5, 3))
    sigma = 0.002
    predicted = registration_std(X, sigma * np.sqrt(3), Q)
    moved = []
    for _ in range(400):
        T = fit_rigid(X, X + rng.normal(0, sigma, X.shape))
        moved.append(_apply(T, Q) - Q)
    measured = np.sqrt((np.array(moved) ** 2).sum(-1).mean(0))
    np.testing.assert_allclose(predicted, measured, rtol=0.12)
    assert predicted.max() > 3 * sigma  # the lever of a poorly fixed rotation shows


def test_motion_depends_only_on_the_seed():
    from robot_models import WamKinematics

    kin = WamKinematics.default()
    a, b = simulate_motion(kin, 40, 100.0, seed=7), simulate_motion(kin, 40, 100.0, seed=7)
    c = simulate_motion(kin, 40, 100.0, seed=8)
    assert np.array_equal(a.gt_world_m, b.gt_world_m) and np.array_equal(a.q_true, b.q_true)
    assert not np.allclose(a.bias_rad, c.bias_rad)


# -- real data ----------------------------------------------------------------------------------------------
def test_registration_on_real_tracked_ball_positions(real_data):
    """Real ball flights tracked by the MPI-IS multi-camera system (mn5008_no_spin, see its README): nearly
    planar parabolas, real tracker noise. A known rigid motion plus 5 % gross errors is undone exactly."""
    data = np.loadtxt(real_data / "mpi_launcher_trajectories" / "mn5008_no_spin.csv", delimiter=",", skiprows=1)
    X = data[:, 2:5]
    rng = np.random.default_rng(0)
    T_true = _rigid(2)
    Y = _apply(T_true, X)
    bad = rng.random(len(X)) < 0.05
    Y[bad] += rng.normal(0, 0.3, (bad.sum(), 3))
    T, info = register_rigid(X, Y)
    rot_deg, trans_m = transform_difference(T, T_true)
    assert rot_deg < 1e-7 and trans_m < 1e-8
    assert info.n_inliers == (~bad).sum()
    assert info.spread_m[1] > 0.05  # the flights spread sideways: the rotation is fixed


def test_histogram_files(tmp_path):
    rng = np.random.default_rng(0)
    errors = {"rt2": rng.gamma(2, 0.003, 500), "rtblob": np.r_[rng.gamma(2, 0.004, 450), rng.normal(0.28, 0.02, 49), 31.0, np.nan]}
    paths = plot_histogram(errors, [tmp_path / "h.png", tmp_path / "h.pdf"], title="test")
    assert all(p.stat().st_size > 5000 for p in paths)
    assert (tmp_path / "h.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "h.pdf").read_bytes()[:5] == b"%PDF-"
