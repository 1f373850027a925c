"""Playing sessions (harness/experiments/play): Wilson intervals, tracker profiles, the synthetic source's statistics,
closed-loop sessions end to end (deterministic by seed, independent of --workers), the session log,
no attempt instead of a crash, and bad input at the command line.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.experiments.play.experiment import ball_seeds, wilson_interval
from harness.experiments.play.profiles import PAPER_PROFILES, PROFILES, TrackerProfile, load_profiles, profile_for

JSON_KEYS = {"tracker", "filter", "balls", "successes", "success_rate", "ci_low", "ci_high"}


# ----------------------------------------------------------------------------- Wilson interval
def test_wilson_interval_matches_the_formula():
    for k, n in ((0, 10), (7, 10), (350, 500), (500, 500)):
        z = 1.959963984540054
        p = k / n
        centre = (p + z * z / (2 * n)) / (1 + z * z / n)
        half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
        lo, hi = wilson_interval(k, n)
        assert lo == pytest.approx(centre - half, abs=1e-9) and hi == pytest.approx(centre + half, abs=1e-9)
    with pytest.raises(ValueError, match="need 0 <= successes <= n"):
        wilson_interval(3, 0)


def test_ball_seeds_are_prefix_stable():
    a, b = ball_seeds(7, 3), ball_seeds(7, 5)
    for (s1, t1), (s2, t2) in zip(a, b):
        assert s1.generate_state(2).tolist() == s2.generate_state(2).tolist()
        assert t1.generate_state(2).tolist() == t2.generate_state(2).tolist()


# ----------------------------------------------------------------------------- profiles
def test_profiles_defaults_and_file(tmp_path):
    assert profile_for("rtblob").rate_hz == pytest.approx(profile_for("rt2").rate_hz / 3)
    with pytest.raises(ValueError, match="unknown tracker 'vicon'"):
        profile_for("vicon")
    p = tmp_path / "prof.json"
    p.write_text(json.dumps({"rt2": {"noise_std_m": 0.004, "p_miss": 0.2}}))
    got = load_profiles(p)
    assert got["rt2"].noise_std_m == 0.004 and got["rt2"].p_miss == 0.2 and got["rtblob"] == PROFILES["rtblob"]
    assert load_profiles(p, PAPER_PROFILES)["rtblob"] == PAPER_PROFILES["rtblob"]  # on top of another set
    assert PAPER_PROFILES["rtblob"].p_outlier > 0 and PROFILES["rtblob"].p_outlier == 0  # the paper's vs our lab's RTBlob
    p.write_text(json.dumps({"rt2": {"noise_mm": 4}}))
    with pytest.raises(ValueError, match=r"prof\.json: tracker 'rt2': unknown field\(s\) \['noise_mm'\]"):
        load_profiles(p)
    with pytest.raises(ValueError, match="p_miss \\+ p_outlier \\+ p_wild must be <= 1"):
        TrackerProfile("rt2", 180.0, p_miss=0.6, p_outlier=0.6)


# ----------------------------------------------------------------------------- synthetic source statistics
def test_synthetic_source_rates_and_noise():
    from harness.sim.lab import lab4_vga_rig
    from harness.experiments.play.sources import SyntheticSource

    prof = TrackerProfile("rtblob", 60.0, noise_std_m=0.004, p_miss=0.1, p_outlier=0.2, p_wild=0.05)
    src = SyntheticSource(lab4_vga_rig(), prof)
    src.reset(np.random.SeedSequence(3))
    x = np.array([-1.3, 0.0, 1.1])  # seen by all four cameras
    n = 1500
    obs = [src.observe(k, 0.01 * k, x, np.zeros(3), None) for k in range(n)]
    miss = np.mean([o.position_m is None for o in obs])
    err = np.array([np.linalg.norm(o.position_m - x) for o in obs if o.position_m is not None])
    for rate, want in ((miss, 0.1), (np.mean((err > 0.2) & (err < 0.35)) * (1 - miss), 0.2), (np.mean(err > 1.0) * (1 - miss), 0.05)):
        assert abs(rate - want) < 4 * np.sqrt(want * (1 - want) / n)  # binomial, 4 sigma
    inliers = err[err < 0.05]
    assert np.sqrt(np.mean(inliers**2) / 3) == pytest.approx(0.004, rel=0.1)  # per-axis RMS
    far = src.observe(n, 0.0, np.array([5.0, 0.0, 1.0]), np.zeros(3), None)  # outside every camera
    assert far.position_m is None and far.status == "too_few_observations"


# ----------------------------------------------------------------------------- sessions end to end
def _play(tmp_path, name, *extra):
    out = tmp_path / name
    code = main(["play", "--balls", "3", "--seed", "4", "--out", str(out), "--json", str(out / "r.json"), "--quiet",
                 "--no-figure", *extra])
    assert code == 0
    return json.loads((out / "r.json").read_text())


@pytest.fixture(scope="module")
def default_play(tmp_path_factory):
    """The default session (3 balls, seed 4, one worker, no log): both tests below need it, played once."""
    return _play(tmp_path_factory.mktemp("play"), "a", "--no-log")


def test_session_json_deterministic_and_independent_of_workers(default_play, tmp_path, capsys):
    a = default_play
    b = _play(tmp_path, "b", "--no-log", "--workers", "2")
    assert a == b  # same seed -> same results, whatever the number of workers
    (row,) = a
    assert JSON_KEYS <= set(row) and row["balls"] == 3 and row["source"] == "synthetic"
    assert row["ci_low"] <= row["success_rate"] <= row["ci_high"]
    assert sum(row["outcomes"].values()) == 3 and row["profiles"] == "vision"
    assert "rt2        raw" in capsys.readouterr().out
    (paper,) = _play(tmp_path, "p", "--no-log", "--profiles", "paper", "--tracker", "rtblob")
    assert paper["profiles"] == "paper" and paper["balls"] == 3


def test_session_log_has_every_ball(tmp_path):
    from harness.logs import SessionLogReader

    (row,) = _play(tmp_path, "log", "--balls", "1")
    with SessionLogReader(row["log"]) as log:
        assert log.metadata("session")["kind"] == "play"
        topics = set(log.topics())
        assert {"/ground_truth/ball", "/robot/joint_states", "/robot/command", "/tracker/rt2/ball", "/figures/ball",
                "/figures/filter"} <= topics
        ball = log.figures()["ball"]
        assert ball["outcome"] in {"landed_in", "net", "missed_table", "own_side", "no_hit", "no_attempt", "in_flight"}
        if ball["attempted"]:
            assert "/figures/plan" in topics
    # section 6: the logged observations replayed through each filter
    out = tmp_path / "re.json"
    assert main(["reevaluate", row["log"], "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert len(rows) == (1 if ball["n_plans"] else 0)
    for r in rows:
        for key in ("raw_first_plan_error_m", "raw_commit_error_m", "ransac_kalman_commit_error_m"):
            assert key in r
        assert r["raw_commit_error_m"] is not None and r["raw_commit_error_m"] < 0.05  # rt2 + raw at the commit point


def test_ball_that_never_arrives_is_no_attempt():
    from harness.sim.launcher import Serve
    from harness.sim.lab import lab4_vga_rig
    from harness.experiments.play.session import PlaySession
    from harness.experiments.play.sources import SyntheticSource
    from policies.filters import make_filter
    from policies.promp import ProMP
    from robot_models import WamKinematics

    kin = WamKinematics.default()
    promp = ProMP.load(Path(__file__).resolve().parents[3] / "data" / "promp" / "wam_hitting.npz")
    prof = PROFILES["rt2"]
    session = PlaySession(kin, promp, SyntheticSource(lab4_vga_rig(), prof), lambda: make_filter("raw"), prof)
    state = np.array([-0.5, 0.0, 1.0, 3.0, 0.0, 2.0, 0.0, 0.0, 0.0])  # hit back towards the opponent: never comes
    serve = Serve(state, 3.6, "none", np.zeros(2), np.zeros(3))
    result, _ = session.run(serve, np.random.SeedSequence(0))
    assert result.outcome == "no_attempt" and not result.success and "does not reach" in result.reason


# ----------------------------------------------------------------------------- modelled planning time
def test_late_commands_reach_the_robot_after_the_latency():
    """A command made at t reaches the simulated WAM at t + latency, not before; states are read at once."""
    from harness.experiments.play.session import _LateCommands
    from harness.sim.robot import SimulatedWam
    from robot_models import WamKinematics

    kin = WamKinematics.default()
    wam = SimulatedWam(kin, seed=0)
    late = _LateCommands(wam, 0.05)
    q0 = wam.advance_to(0.1).q_ref[-1]  # the rest posture it holds
    late.now_s = 0.1
    t = np.arange(0.11, 0.5, 0.002)  # starts before the command can arrive: delivered at once it would move by 0.15
    target = q0 + np.r_[0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    ramp = np.clip((t - 0.11) / 0.3, 0.0, 1.0)[:, None]
    late.command_trajectory(t, q0 + ramp * (target - q0))
    assert np.allclose(late.read_state().q, wam.read_state().q)
    late.deliver(0.149)
    samples = wam.advance_to(0.15)
    assert np.allclose(samples.q_ref[-1], q0)  # at rest: no reference but the rest posture
    late.deliver(0.15)
    samples = wam.advance_to(0.45)
    assert samples.q_ref[-1][0] > q0[0] + 0.1  # following the delivered ramp


def test_plan_latency_plans_ahead_and_is_reproducible(default_play, tmp_path):
    """With a modelled planning time every plan is made for (step time + latency), the same seed gives the
    same figures, and a policy that needs long enough to plan misses balls the instantaneous one plays."""
    slow = _play(tmp_path, "slow", "--no-log", "--plan-latency-ms", "300")
    assert slow == _play(tmp_path, "slow2", "--no-log", "--plan-latency-ms", "300")
    fast = default_play  # the same session without a planning time
    assert slow[0]["plan_latency_ms"] == 300.0 and fast[0]["plan_latency_ms"] == 0.0
    assert slow[0]["successes"] < fast[0]["successes"]
    from harness.experiments.play.session import SessionOptions

    with pytest.raises(ValueError, match=r"plan_latency_s must be a number of seconds in \[0, 0.5\], got 0.8"):
        SessionOptions(plan_latency_s=0.8)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("argv, match", [
    (["--balls", "0"], "--balls must be >= 1"),
    (["--seed", "-1"], "--seed must be >= 0, got -1"),
    (["--filter", "median"], "unknown filter 'median'"),
    (["--tracker", "vicon"], "unknown tracker 'vicon'"),
    (["--workers", "0"], "--workers must be >= 1"),
    (["--log-images", "5"], "--log-images needs --source vision"),
    (["--promp", "/nonexistent/promp.npz"], "no such file"),
    (["--scene", "busy"], "unknown --scene 'busy'"),
    (["--plan-latency-ms", "-5"], "--plan-latency-ms must be in [0, 500], got -5"),
    (["--plan-latency-ms", "30", "--live"], "--plan-latency-ms models planning time in process"),
])
def test_bad_arguments_exit_2(argv, match, tmp_path, capsys):
    assert main(["play", "--balls", "1", "--out", str(tmp_path), "--quiet", *argv]) == 2
    assert match in capsys.readouterr().err


def test_promp_of_another_robot_exit_2(tmp_path, capsys):
    import dataclasses

    from policies.promp import ProMP

    promp = ProMP.load(Path(__file__).resolve().parents[3] / "data" / "promp" / "wam_hitting.npz")
    other = dataclasses.replace(promp, robot_id="kuka_iiwa").save(tmp_path / "kuka.npz")
    assert main(["play", "--balls", "1", "--no-log", "--out", str(tmp_path), "--quiet", "--promp", str(other)]) == 2
    assert "field 'robot_id' is 'kuka_iiwa' but 'wam7' was expected" in capsys.readouterr().err


# ----------------------------------------------------------------------------- rt2 play profile
def test_measure_profile_counts_misses_outliers_and_noise():
    from harness.sim.lab import lab4_vga_rig
    from harness.experiments.play.measure import measure_profile
    from tracker import BallObservation, Status

    rng = np.random.default_rng(0)
    x = np.array([-1.3, 0.0, 1.1])

    def obs(p):
        return BallObservation(0.0, p, None, 4 if p is not None else 0, np.ones(4, bool),
                               Status.OK if p is not None else Status.NO_CONSENSUS, 0.0, "rt2")

    samples = [(0.0, x, obs(x + 0.002 * rng.standard_normal(3))) for _ in range(800)]
    samples += [(0.0, x, obs(None))] * 100 + [(0.0, x, obs(x + [0.3, 0, 0]))] * 80 + [(0.0, x, obs(x + [5.0, 0, 0]))] * 20
    samples += [(0.0, np.array([9.0, 0, 1.0]), obs(None))] * 50  # unseen by the rig: not counted
    r = measure_profile(samples, lab4_vga_rig())
    assert r["frames_seen"] == 1000
    assert r["p_miss"] == pytest.approx(0.1) and r["p_outlier"] == pytest.approx(0.08) and r["p_wild"] == pytest.approx(0.02)
    assert r["noise_std_m"] == pytest.approx(0.002, rel=0.1)
    assert r["outlier_offset_m"] == pytest.approx([0.3, 0.3])  # p10-p90 of the outliers' errors
    with pytest.raises(ValueError, match="no frame sets"):
        measure_profile([], lab4_vga_rig())
