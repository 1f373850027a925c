"""robot_models.limits: the joint limits without Pinocchio (for the robot link's ROS bridge), and the light imports.

JointLimits must agree with WamKinematics (the same robot configuration through two parsers), and the
modules a robot-side bridge imports must not pull in Pinocchio, numba or OpenCV (docs/robot_link.md).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from robot_models import JointLimits, WamKinematics, check_joint_trajectory
from robot_models.limits import urdf_joint_limits

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def kin():
    return WamKinematics.default()


def test_limits_agree_with_the_kinematics(kin):
    lim = JointLimits.from_config()
    assert lim.joint_names == kin.joint_names and lim.n_joints == kin.n_joints
    np.testing.assert_array_equal(lim.q_min, kin.q_min)
    np.testing.assert_array_equal(lim.q_max, kin.q_max)
    np.testing.assert_array_equal(lim.qdot_max, kin.qdot_max)


def test_trajectory_checks_agree_with_the_kinematics(kin):
    lim = JointLimits.from_config()
    rng = np.random.default_rng(3)
    q = rng.uniform(kin.q_min - 0.2, kin.q_max + 0.2, size=(40, 2, 7))
    kinds = set()
    for pair in q:  # the same accept / refuse, with the same message, for in- and out-of-limit pairs
        outcomes = []
        for model in (kin, lim):
            try:
                t, Q, _ = check_joint_trajectory(model, [0.0, 1.0], pair, now_s=0.5)
                outcomes.append(("ok", Q.tolist()))
            except ValueError as exc:
                outcomes.append(("refused", str(exc)))
        assert outcomes[0] == outcomes[1]
        kinds.add(outcomes[0][0])
    assert kinds == {"ok", "refused"}  # both cases were compared


def test_bad_limits_and_urdf_name_the_problem(tmp_path):
    with pytest.raises(ValueError, match=r"JointLimits.q_min must be 2 finite numbers"):
        JointLimits(("a", "b"), [0.0], [1.0, 1.0], [1.0, 1.0])
    with pytest.raises(ValueError, match=r"need q_min <= q_max and qdot_max, qddot_max > 0"):
        JointLimits(("a",), [1.0], [0.0], [1.0], [1.0])
    with pytest.raises(ValueError, match=r"JointLimits.qddot_max \(acceleration limits"):
        JointLimits(("a",), [0.0], [1.0], [1.0])
    bad = tmp_path / "bad.urdf"
    bad.write_text('<robot name="r"><joint name="j" type="revolute"><limit lower="-1" upper="x"/></joint></robot>')
    with pytest.raises(ValueError, match=r"bad.urdf: joint 'j' needs <limit lower= upper= velocity=> numbers"):
        urdf_joint_limits(bad)
    bad.write_text('<robot name="r"><joint name="p" type="floating"/></robot>')
    with pytest.raises(ValueError, match=r"joint 'p' is 'floating'; only revolute and prismatic"):
        urdf_joint_limits(bad)
    bad.write_text('<robot name="r"><joint name="c" type="continuous"/></robot>')
    with pytest.raises(ValueError, match=r"joint 'c' is 'continuous': it has no position limits"):
        urdf_joint_limits(bad)
    bad.write_text("<robot")
    with pytest.raises(ValueError, match=r"bad.urdf: not a valid URDF"):
        urdf_joint_limits(bad)
    with pytest.raises(FileNotFoundError):
        JointLimits.from_config(tmp_path / "missing.yaml")


def test_bridge_modules_import_without_heavy_dependencies():
    code = ("import sys; import harness.link.bridge_core, harness.link.ros_msgs, robot_models.limits, "
            "robot_models.robot_interface; from robot_models.joint_reference import PiecewiseReference; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'pinocchio', 'numba', 'cv2', 'torch'}), "
            "sorted(m for m in sys.modules if m.startswith('harness.sim')))")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[] []"  # no heavy dependency, and nothing of the simulator
