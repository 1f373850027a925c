"""The lab geometry (renderer) and the robot's mount (kinematics) describe the same lab."""

import numpy as np

from harness.sim import lab
from robot_models import load_robot_config


def test_robot_base_on_the_floor_under_the_mount():
    mount = load_robot_config().mount_xyz_m
    assert np.allclose(lab.ROBOT_BASE_M[:2], mount[:2])
    assert lab.ROBOT_BASE_M[2] == 0.0
