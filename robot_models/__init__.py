"""rt2 robot models: any serial arm's kinematics and IK over Pinocchio from its URDF and robot config
(``ArmKinematics``; ``data/robot/*.yaml``: the 7-DOF Barrett WAM, whose URDF is here, the default), and the
robot interface contract (``robot_interface.py``: ``WamInterface`` and the joint types) that policies act through,
and the joint reference a robot side follows between commanded trajectories (``joint_reference.py``).

Imports nothing else of rt2 but its lowest layer, ``checks`` (see docs/architecture.md). Poses are in the lab world frame, metres.

The names below are loaded on first use (PEP 562), so that ``robot_models.robot_interface``,
``robot_models.config``, ``robot_models.limits`` and ``robot_models.joint_reference`` import without Pinocchio: the robot link's ROS
bridge runs them under a system Python that has numpy, SciPy and PyYAML only (docs/robot_link.md).
"""

from checks.lazy import lazy_attributes

_WHERE = {
    "DEFAULT_CONFIG_PATH": "config", "DEFAULT_ROBOT": "config", "DEFAULT_URDF_PATH": "config", "RobotConfig": "config",
    "load_robot_config": "config", "mount_transform": "config", "resolve_robot_config": "config",
    "robot_names": "config", "ArmKinematics": "kinematics",
    "IkInfo": "ik", "IkOptions": "ik", "solve_ik": "ik",
    "LINK_CHAIN": "kinematics", "REQUIRED_FRAMES": "kinematics", "WamKinematics": "kinematics",
    "PiecewiseReference": "joint_reference", "JointLimits": "limits",
    "JointSamples": "robot_interface", "JointState": "robot_interface", "JointTrajectory": "robot_interface",
    "WamInterface": "robot_interface", "check_joint_trajectory": "robot_interface",
}

__all__ = sorted(_WHERE)
__getattr__, __dir__ = lazy_attributes("robot_models", globals(), _WHERE)
