"""``rt2 sim fit-flight`` on the real MPI-IS launcher flights (harness.studies.fit_flight).

Data: ../shared/data/real/mpi_launcher_trajectories, from github.com/intelligent-soft-robots/
ball_prediction @ 6532302 (BSD-3-Clause).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness import cli
from harness.studies import fit_flight as ff


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
    assert {r["model"] for r in a} == {"baseline", "full", "full-iso", "full-ekf", "full-known-spin"}
    assert all({"horizon_ms", "median_cm", "p90_cm"} <= set(r) for r in a)
    assert sorted({r["horizon_ms"] for r in a}) == [100, 200, 300]
    # sanity: errors grow with the horizon and stay within a table length
    base = [r["median_cm"] for r in a if r["model"] == "baseline"]
    assert base == sorted(base) and base[-1] < 50.0


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured 2026-11-22/23 (seed 0): full 6.01-6.08 cm vs baseline 4.64-4.65 cm median at "
                   "300 ms -- spin from 20 samples (110 ms) is too noisy to pay off; see docs/ball_physics.md")
def test_full_fit_beats_baseline_at_300ms(flights_dir):
    out = ff.run_study(flights_dir, seed=0, progress=False)
    rows = {(r["model"], r["horizon_ms"]): r for r in out["rows"]}
    assert rows[("full", 300)]["median_cm"] < rows[("baseline", 300)]["median_cm"]
    fitted = out["params"]["full"]
    assert 0.85 <= fitted.table_restitution <= 0.97 and 0.1 <= fitted.drag_coefficient <= 0.7
    assert np.isfinite(list(out["fits"]["full"]["values"].values())).all()


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
    spin = ff._whole_flight_spin(flight, params, table, EstimatorOptions(position_noise_m=0.002))
    assert np.linalg.norm(spin - true_spin) < 8.0, spin
