"""``rt2 sim fit-flight`` on the real MPI-IS launcher flights (harness.experiments.studies.fit_flight).

Data: ../shared/data/real/mpi_launcher_trajectories, from github.com/intelligent-soft-robots/
ball_prediction @ 6532302 (BSD-3-Clause).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness import cli
from harness.experiments.studies import fit_flight as ff


@pytest.fixture(scope="module")
def flights_dir(real_data):
    return real_data / "mpi_launcher_trajectories"


def test_loader_reads_all_flights(flights_dir):
    flights = ff.load_flights(flights_dir)
    assert len(flights) == 88
    counts = {s: sum(f.set_name == s for f in flights) for s in ff.SETS}
    assert counts == {"mn5008_backspin": 15, "mn5008_topspin": 15, "mn5008_no_spin": 10, "no_spin_robot_simple": 48}
    assert all(f.X.shape == (len(f.t_s), 3) and f.t_s[0] == 0.0 for f in flights)
    assert flights[0].launch["wheel_3"] == 2800.0  # backspin: faster bottom wheel


def test_split_is_seeded_and_stratified(flights_dir):
    flights = ff.load_flights(flights_dir)
    fit_a, held_a = ff.split_flights(flights, seed=3)
    fit_b, held_b = ff.split_flights(flights, seed=3)
    assert [(f.set_name, f.traj) for f in held_a] == [(f.set_name, f.traj) for f in held_b]
    assert {f.set_name for f in held_a} == set(ff.SETS)
    assert len(fit_a) + len(held_a) == 88
    _, held_c = ff.split_flights(flights, seed=4)
    assert [(f.set_name, f.traj) for f in held_a] != [(f.set_name, f.traj) for f in held_c]


def test_bad_data_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        ff.load_flights(tmp_path / "missing")
    (tmp_path / "mn5008_backspin.csv").write_text("a,b,c\n1,2,3\n")
    with pytest.raises(ValueError, match="mn5008_backspin.csv"):
        ff.load_flights(tmp_path)


def test_cli_rejects_bad_option(capsys):
    assert cli.main(["sim", "fit-flight", "--max-per-set", "1"]) == 2
    assert "--max-per-set" in capsys.readouterr().err


def test_subset_runs_and_reproduces_with_same_seed(flights_dir, tmp_path):
    args = ["sim", "fit-flight", "--data", str(flights_dir), "--seed", "2", "--max-per-set", "3", "--max-nfev", "25"]
    assert cli.main(args + ["--json", str(tmp_path / "a.json")]) == 0
    assert cli.main(args + ["--json", str(tmp_path / "b.json")]) == 0
    a = json.loads((tmp_path / "a.json").read_text())
    b = json.loads((tmp_path / "b.json").read_text())
    assert a == b
    assert {r["model"] for r in a} == {"baseline", "full", "full-iso", "full-ekf", "full-launcher", "full-launcher-mix",
                                       "full-launcher-recognised", "full-known-spin"}
    assert all({"horizon_ms", "median_cm", "p90_cm"} <= set(r) for r in a)
    assert sorted({r["horizon_ms"] for r in a}) == [100, 200, 300]
    # sanity: errors grow with the horizon and stay within a table length
    base = [r["median_cm"] for r in a if r["model"] == "baseline"]
    assert base == sorted(base) and base[-1] < 50.0


@pytest.fixture(scope="module")
def full_study(flights_dir):
    """The whole seed-0 study (~2.5 min on a loaded 2-core machine), shared by the slow tests."""
    return ff.run_study(flights_dir, seed=0, progress=False)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured 2026-11-22/23/24 (seed 0): full (k-means spin mixture) 5.75-6.08 cm vs "
                   "baseline 4.64-4.65 cm median at 300 ms -- a launcher-blind spin from 20 samples (110 ms) does not pay "
                   "off; see docs/ball_physics.md")
def test_full_fit_beats_baseline_at_300ms(full_study):
    out = full_study
    rows = {(r["model"], r["horizon_ms"]): r for r in out["rows"]}
    assert rows[("full", 300)]["median_cm"] < rows[("baseline", 300)]["median_cm"]
    fitted = out["params"]["full"]
    assert 0.85 <= fitted.table_restitution <= 0.97 and 0.1 <= fitted.drag_coefficient <= 0.7
    assert np.isfinite(list(out["fits"]["full"]["values"].values())).all()


@pytest.mark.slow
def test_launcher_spin_prior_meets_the_spin_goal(full_study):
    """The goal of the spin estimate (median 1.0 / 2.5 / 4.0 cm at +100/200/300 ms from 20 samples on the
    held-out flights), measured 2026-11-24: 0.71 / 1.46 / 2.30; it also beats the no-spin baseline."""
    rows = {(r["model"], r["horizon_ms"]): r["median_cm"] for r in full_study["rows"]}
    for h, goal in zip(ff.HORIZONS_MS, ff.SPIN_GOAL_CM):
        assert rows[(ff.SPIN_GOAL_MODEL, h)] <= goal
        assert rows[(ff.SPIN_GOAL_MODEL, h)] < rows[("baseline", h)]
    assert full_study["launcher_prior_min_std_rad_s"] in ff.LAUNCHER_PRIOR_MIN_STD_GRID_RAD_S
    # not told the setting: recognised from the launch velocity (28/29 on 2026-11-24), the goal still holds
    assert int(full_study["launcher_recognised"].split("/")[0]) >= 25
    for h, goal in zip(ff.HORIZONS_MS, ff.SPIN_GOAL_CM):
        assert rows[("full-launcher-recognised", h)] <= goal


def test_launcher_setting_is_recognised_from_the_launch_velocity(flights_dir):
    """Each launcher setting launches at its own velocity (4.2-5.8 m/s along x, std ~0.1): a Gaussian per
    setting learned on the fit flights recognises the held-out flights' settings (seed 0: 28 of 29)."""
    fit, held = ff.split_flights(ff.load_flights(flights_dir), seed=0)
    model = ff.launch_velocity_model(fit)
    assert set(model) == {ff.launcher_setting(f) for f in fit} and sum(w for w, _, _ in model.values()) == pytest.approx(1)
    right = sum(ff.recognise_setting(f.t_s[:ff.N_OBSERVED], f.X[:ff.N_OBSERVED], model) == ff.launcher_setting(f)
                for f in held)
    assert right >= 25, right
    # the recognition looks at the launch only: a flight shifted in time and space is recognised the same
    f = held[0]
    assert ff.recognise_setting(f.t_s[:20] + 3.0, f.X[:20] + 0.5, model) == ff.recognise_setting(f.t_s[:20], f.X[:20], model)


def test_launcher_priors_come_from_the_given_flights_only():
    """The prior of a setting is the mean/covariance of the spins of *its* flights; leave-one-out drops one."""
    launch = {"wheel_1": 350.0, "wheel_3": 2800.0}
    fl = [ff.Flight("a", k, np.zeros(1), np.zeros((1, 3)), launch) for k in range(3)]
    fl.append(ff.Flight("b", 0, np.zeros(1), np.zeros((1, 3)), {}))
    spins = np.array([[0.0, -50.0, 0.0], [0.0, -60.0, 0.0], [0.0, -70.0, 0.0], [0.0, 40.0, 0.0]])
    priors = ff.launcher_spin_priors(fl, spins, 2.0)
    assert set(priors) == {ff.launcher_setting(fl[0]), (("set", "b"),)}
    assert priors[ff.launcher_setting(fl[0])][0][1] == pytest.approx(-60.0)
    assert priors[ff.launcher_setting(fl[0])][1][1][1] == pytest.approx(200 / 3 + 4.0)
    loo = ff.launcher_spin_priors(fl, spins, 2.0, exclude=0)
    assert loo[ff.launcher_setting(fl[0])][0][1] == pytest.approx(-65.0)
    with pytest.raises(ValueError, match="launcher setting"):
        ff._launcher_options(ff.Flight("c", 0, np.zeros(1), np.zeros((1, 3)), {"wheel_1": 1.0}), priors,
                             ff.EstimatorOptions())


def test_known_spin_diagnostic_recovers_the_spin_of_a_simulated_flight():
    """The ``full-known-spin`` row takes each flight's spin from all its samples; on a simulated flight
    with a bounce and 2 mm noise that spin is the true one within a few rad/s."""
    from policies.ball_estimation import EstimatorOptions
    from policies.ball_model import BallParams, TableGeometry, simulate

    params, table = BallParams.load(), TableGeometry()
    true_spin = np.array([0.0, 60.0, 10.0])  # topspin with some sidespin
    t = np.arange(0.0, 0.7, 1 / 180)
    states, bounce = simulate(np.r_[1.2, 0.0, 1.0, -4.5, 0.1, 0.6, true_spin], t, params, table)
    assert np.isfinite(bounce[0])  # the flight bounces on the table
    X = states[:, :3] + np.random.default_rng(0).normal(0.0, 0.002, (len(t), 3))
    flight = ff.Flight("sim", 0, t, X, {})
    spin = ff.whole_flight_spin(flight, params, table, EstimatorOptions(position_noise_m=0.002))
    assert np.linalg.norm(spin - true_spin) < 8.0, spin
