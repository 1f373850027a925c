"""`rt2 calib robot`: the robot base -> camera world registration from a session log (the accuracy run's log)."""

from __future__ import annotations

import numpy as np
import yaml

from harness.cli import main


def test_robot_registration_matches_the_accuracy_run(accuracy_session, tmp_path, capsys):
    result, out_dir = accuracy_session
    out = tmp_path / "robot.yaml"
    code = main(["calib", "robot", "--log", str(out_dir / "session.mcap"), "--out", str(out), "--bootstrap", "50"])
    assert code == 0, capsys.readouterr().err
    got = yaml.safe_load(out.read_text())
    reg = result.figures["registration"]
    # the same frames and the same robust fit as the experiment's own registration
    assert np.allclose(got["T_base_to_world"], reg["T_base_to_world"], atol=1e-6)
    assert got["inliers"] == reg["inliers"]
    assert got["std_rotation_deg"] > 0 and all(s > 0 for s in got["std_translation_mm"])
    assert abs(got["vs_nominal_mount"]["rotation_deg"] - reg["vs_true_mount"]["rotation_deg"]) < 1e-3
    assert abs(got["vs_nominal_mount"]["translation_mm"] - 10 * reg["vs_true_mount"]["translation_cm"]) < 1e-2


def test_same_seed_same_uncertainty(accuracy_session):
    from harness.experiments.accuracy.robot_registration import register_from_log

    _, out_dir = accuracy_session
    a = register_from_log(out_dir / "session.mcap", bootstrap=20, seed=3)
    b = register_from_log(out_dir / "session.mcap", bootstrap=20, seed=3)
    assert a == b


def test_bad_logs_are_named(tmp_path, accuracy_session, capsys):
    _, out_dir = accuracy_session
    code = main(["calib", "robot", "--log", str(tmp_path / "missing.mcap")])
    assert code == 2 and "no such file" in capsys.readouterr().err
    code = main(["calib", "robot", "--log", str(out_dir / "session.mcap"), "--tracker", "nobody"])
    assert code == 2 and "no observations of tracker 'nobody'" in capsys.readouterr().err
