"""The experiments with the other shipped arms: `rt2 accuracy --robot X` and `rt2 play --robot X` run, score and
repeat with the same seed; the session log names the arm's joints; the WAM's ProMP is refused for another arm.
(The UR10, 6 joints, runs in `make test`; the 7-joint Panda and xArm7 in the `slow` set.)"""

from __future__ import annotations

import json

import pytest

from harness.cli import main

SLOW_7 = [pytest.param(name, marks=pytest.mark.slow) for name in ("panda", "xarm7")]


def _needs_robot_data():
    pytest.importorskip("example_robot_data", reason="example-robot-data is not installed (pip install 'rt2[robots]')")


def _accuracy(tmp_path, name, tag):
    out = tmp_path / tag
    argv = ["accuracy", "--robot", name, "--frames", "40", "--trackers", "rt2", "--workers", "1", "--no-log",
            "--seed", "1", "--out", str(out), "--json", str(out / "rows.json")]
    assert main(argv) == 0
    return json.loads((out / "rows.json").read_text()), json.loads((out / "summary.json").read_text())


@pytest.mark.parametrize("name", ["ur10", *SLOW_7])
def test_accuracy_with_another_arm_scores_and_repeats(tmp_path, name, capsys):
    _needs_robot_data()
    rows, summary = _accuracy(tmp_path, name, "a")
    assert summary["config"]["robot"] == name and f"robot {name}:" in capsys.readouterr().out
    (rt2,) = rows
    assert rt2["tracker"] == "rt2" and rt2["p99_cm"] < 5.0  # the ball on that arm's flange, tracked to centimetres
    again, _ = _accuracy(tmp_path, name, "b")
    assert again == rows  # same seed, same figures


def _play(tmp_path, name, tag, *extra):
    # one ball (3 s of play each; two made the test twice as long): the arm, its joints in the log and the seed are
    # what is checked here, the same for every ball (a session of many balls: tests/harness/experiments/test_play.py)
    out = tmp_path / tag
    argv = ["play", "--robot", name, "--balls", "1", "--seed", "3", "--quiet", "--no-figure", "--out", str(out),
            "--json", str(out / "r.json"), *extra]
    assert main(argv) == 0
    return json.loads((out / "r.json").read_text())


@pytest.mark.parametrize("name", ["ur10", *SLOW_7])
def test_play_with_another_arm_is_seeded_and_logs_its_joints(tmp_path, name):
    _needs_robot_data()
    from harness.logs import SessionLogReader
    from robot_models import ArmKinematics

    (row,) = _play(tmp_path, name, "a")
    assert row["balls"] == 1 and sum(row["outcomes"].values()) == 1
    with SessionLogReader(row["log"]) as log:
        assert log.metadata("session")["config"]["robot"] == name
        states = next(iter(log.messages(["/robot/joint_states"])))
        assert tuple(states.data.names) == ArmKinematics.from_config(name).joint_names
    (again,) = _play(tmp_path, name, "b", "--no-log")
    assert {k: v for k, v in again.items() if k != "log"} == {k: v for k, v in row.items() if k != "log"}


def test_the_wams_promp_is_refused_for_another_arm(tmp_path, capsys):
    _needs_robot_data()
    from pathlib import Path

    wam = Path(__file__).resolve().parents[3] / "data" / "promp" / "wam_hitting.npz"
    assert main(["play", "--robot", "ur10", "--balls", "1", "--no-log", "--out", str(tmp_path), "--quiet",
                 "--promp", str(wam)]) == 2
    err = capsys.readouterr().err
    assert "'wam7'" in err and "'ur10'" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("name", ["wam", "panda", "ur10", "xarm7"])
def test_the_arms_capsules_leave_the_mounted_ball_visible(name):
    """The renderer draws each arm's links as capsules; the links at the tool plate never enclose the ball on the
    flange (the xArm7's link7 is its flange: drawn whole, its cap would swallow the ball), on random
    configurations (far links can, where a random configuration folds the arm into itself)."""
    import numpy as np

    from harness.experiments.accuracy.session_scene import SessionScene
    from robot_models import ArmKinematics

    if name != "wam":
        _needs_robot_data()
    kin = ArmKinematics.from_config(name)
    scene = SessionScene(kin.link_radii_m, kin.T_base_to_world[:3, 3])
    rng = np.random.default_rng(0)
    for q in rng.uniform(kin.q_min, kin.q_max, (50, kin.n_joints)):
        ball = kin.position(q, "ball_mount")
        caps = scene.arm_capsules(kin.link_points(q), ball)
        assert len(caps) >= kin.n_joints + 1
        for cap in caps[-3:-1]:  # the last two links; the stick holding the ball (the last cap) ends at its surface
            a, b = np.asarray(cap.p0_m), np.asarray(cap.p1_m)
            s = np.clip((ball - a) @ (b - a) / max((b - a) @ (b - a), 1e-12), 0.0, 1.0)
            assert np.linalg.norm(ball - (a + s * (b - a))) >= cap.radius_m + 0.02, (name, cap)  # the whole 40 mm ball out
