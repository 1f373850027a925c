"""Robot configuration file (data/robot/wam.yaml): defaults, overrides and validation."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from robot_models import DEFAULT_CONFIG_PATH, RobotConfig, WamKinematics, load_robot_config


def _write(tmp_path, doc, name="robot.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc))
    return path


def _default_doc():
    return yaml.safe_load(DEFAULT_CONFIG_PATH.read_text())


# -- smoke -------------------------------------------------------------------------------------------
def test_default_file_equals_dataclass_defaults():
    cfg = load_robot_config()
    ref = RobotConfig()
    for name in ("mount_xyz_m", "mount_rpy_rad", "qdot_max_rad_s", "qddot_max_rad_s2", "q_home_rad", "link_radii_m"):
        assert getattr(cfg, name) == getattr(ref, name), name
    assert cfg.urdf_path.resolve() == ref.urdf_path.resolve()
    assert cfg.simulator["control_rate_hz"] == 500.0


def test_overrides_reach_the_kinematics(tmp_path):
    doc = _default_doc()
    doc["urdf"] = str(RobotConfig().urdf_path)
    doc["mount"] = {"xyz_m": [0.0, 1.0, 2.0], "rpy_rad": [np.pi, 0.0, 0.0]}
    doc["limits"]["qdot_max_rad_s"] = [1, 2, 3, 4, 5, 6, 7]
    kin = WamKinematics.from_config(_write(tmp_path, doc))
    np.testing.assert_allclose(kin.qdot_max, [1, 2, 3, 4, 5, 6, 7])
    np.testing.assert_allclose(kin.fk(kin.q_home, "base"), np.diag([1.0, -1.0, -1.0, 1.0]) + np.array(
        [[0, 0, 0, 0], [0, 0, 0, 1.0], [0, 0, 0, 2.0], [0, 0, 0, 0]]), atol=1e-12)


# -- bad input -----------------------------------------------------------------------------------------
def test_missing_file():
    with pytest.raises(FileNotFoundError, match="robot config not found"):
        load_robot_config("/nonexistent/robot.yaml")


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.update(format="rt2.rig"), r"expected format: rt2.robot"),
    (lambda d: d.update(mounting={}), r"unknown field\(s\) \['mounting'\]"),
    (lambda d: d["mount"].update(xyz=[0, 0, 0]), r"unknown field\(s\) \['xyz'\] in mount"),
    (lambda d: d["limits"].update(qdot_max_rad_s=[1, 2, 3]), r"qdot_max_rad_s must have 7 values \(one per joint, as q_home_rad\), got 3"),
    (lambda d: d["limits"].update(qddot_max_rad_s2=[1, 2, 3, 4, 5, 6, -1]), r"qddot_max_rad_s2 must be positive"),
    (lambda d: d.update(q_home_rad=["a"] * 7), r"q_home_rad must be a list of numbers"),
    (lambda d: d.update(mount=[1, 2]), r"mount must be a mapping"),
])
def test_bad_fields_name_file_and_field(tmp_path, mutate, match):
    doc = _default_doc()
    mutate(doc)
    path = _write(tmp_path, doc, "broken.yaml")
    with pytest.raises(ValueError, match="broken.yaml"):
        load_robot_config(path)
    with pytest.raises(ValueError, match=match):
        load_robot_config(path)


def test_home_outside_limits_rejected(tmp_path):
    doc = _default_doc()
    doc["urdf"] = str(RobotConfig().urdf_path)
    doc["q_home_rad"] = [0, 0, 0, 3.5, 0, 0, 0]
    with pytest.raises(ValueError, match=r"q_home_rad: joint_4 = 3.5 rad is outside its limits"):
        WamKinematics.from_config(_write(tmp_path, doc))


def test_invalid_yaml(tmp_path):
    path = tmp_path / "x.yaml"
    path.write_text("format: [unclosed")
    with pytest.raises(ValueError, match="x.yaml: not valid YAML"):
        load_robot_config(path)
